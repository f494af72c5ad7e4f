//! Text from input shown on a terminal: file names, scene names and keys come from files and
//! command lines, and a control character in one (an escape sequence in a TOML string, say)
//! would act on the terminal that prints a message (set its title, clear its screen) instead of
//! being read.

/// `s` with every control character written as an escape (`\u{1b}`), a line break as a space
/// (a message is one line), and the characters that reorder text on screen (bidirectional
/// overrides and isolates) escaped too. Tabs stay.
pub fn printable(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '\n' => out.push(' '),
            '\t' => out.push(c),
            c if c.is_control()
                || matches!(c, '\u{202a}'..='\u{202e}' | '\u{2066}'..='\u{2069}') =>
            {
                out.push_str(&format!("\\u{{{:x}}}", c as u32))
            }
            c => out.push(c),
        }
    }
    out
}

/// A file name as names are matched in another case: composed (Unicode NFC: an `Ö` written
/// as one character and as `O` and its accent, as macOS stores names and archives made there
/// keep them, are one name) and in lower case (any letter's, not only ASCII's: `Ölfass.png` is
/// `ölfass.png`).
pub fn folded(name: &str) -> String {
    use unicode_normalization::UnicodeNormalization;
    name.nfc().collect::<String>().to_lowercase()
}

#[cfg(test)]
mod tests {
    use super::printable;

    #[test]
    fn control_characters_are_escaped() {
        assert_eq!(
            printable("a\u{1b}]0;PWNED\u{7}\u{1b}[2J\0b\r\nc\td\u{9b}e\u{202e}f"),
            "a\\u{1b}]0;PWNED\\u{7}\\u{1b}[2J\\u{0}b\\u{d} c\td\\u{9b}e\\u{202e}f"
        );
        assert_eq!(printable("Grüße, 日本 #25"), "Grüße, 日本 #25");
    }
}
