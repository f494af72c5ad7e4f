//! Text from input shown on a terminal: file names, scene names and keys come from files and
//! command lines, and a control character in one (an escape sequence in a TOML string, say)
//! would act on the terminal that prints a message (set its title, clear its screen) instead of
//! being read.

/// `s` with every control character written as an escape (`\u{1b}`), a line break as a space
/// (a message is one line), and the characters that reorder text on screen (bidirectional
/// overrides and isolates) escaped too. Tabs stay.
pub fn printable(s: &str) -> String {
    // (`screen_safe`'s escapes hold no line break: those left are the text's own.)
    screen_safe(s).replace('\n', " ")
}

/// Whether `c` acts on a terminal instead of being shown: a control character (an escape
/// sequence's start, a carriage return) or one that reorders text on screen (bidirectional
/// overrides and isolates).
fn acts_on_screen(c: char) -> bool {
    c.is_control() || matches!(c, '\u{202a}'..='\u{202e}' | '\u{2066}'..='\u{2069}')
}

/// `s` as `printable` writes it but with its line breaks kept: what `outln!` and `errln!` print,
/// so that no line reframe prints acts on the terminal, whatever a caller put in it (a table
/// of several lines keeps its lines). Borrowed where nothing needs escaping.
pub fn screen_safe(s: &str) -> std::borrow::Cow<'_, str> {
    if !s
        .chars()
        .any(|c| c != '\n' && c != '\t' && acts_on_screen(c))
    {
        return std::borrow::Cow::Borrowed(s);
    }
    let mut out = String::with_capacity(s.len() + 16);
    for c in s.chars() {
        match c {
            '\n' | '\t' => out.push(c),
            c if acts_on_screen(c) => out.push_str(&format!("\\u{{{:x}}}", c as u32)),
            c => out.push(c),
        }
    }
    std::borrow::Cow::Owned(out)
}

/// Runs of text without a space longer than this are cut in a message (`message`): past any
/// path but the rarest (a user may copy one from a message), far below a megabyte.
const LONGEST_RUN: usize = 1024;

/// `printable(s)` for an error or warning line, with every run of text without a space that
/// is longer than `LONGEST_RUN` characters cut to its first 160 and last 100 characters
/// around `...(N characters)...`: a key, value or name quoted from input can be megabytes long
/// (a line of one TOML key of 10^6 characters made a one-megabyte error line), where a path
/// keeps its start and its file name.
pub fn message(s: &str) -> String {
    let p = printable(s);
    if p.len() <= LONGEST_RUN {
        return p;
    }
    let mut out = String::with_capacity(p.len().min(4096));
    for (k, run) in p.split(' ').enumerate() {
        if k > 0 {
            out.push(' ');
        }
        let n = run.chars().count();
        if n <= LONGEST_RUN {
            out.push_str(run);
            continue;
        }
        let head: String = run.chars().take(160).collect();
        let tail: String = run.chars().skip(n - 100).collect();
        out.push_str(&format!("{head}...({} characters)...{tail}", n - 260));
    }
    out
}

/// A serde message (from TOML or JSON input) in the words of the file's format, not Rust's:
/// serde names the Rust type a value was read into (`invalid type: string "a", expected f64`,
/// `expected struct JsonEntry with 6 elements`), which says nothing to someone who wrote the
/// file. Numbers are "a number" or "a whole number", a struct and a map are `record` (`"a
/// table"` in TOML, `"an object"` in JSON), a sequence is "an array".
pub fn plain_types(msg: &str, record: &str) -> String {
    const WHOLE: [&str; 10] = [
        "u8", "u16", "u32", "u64", "usize", "i8", "i16", "i32", "i64", "isize",
    ];
    let mut out = String::with_capacity(msg.len());
    let mut rest = msg;
    while let Some(at) = rest.find("expected ") {
        let (head, tail) = rest.split_at(at + "expected ".len());
        out.push_str(head);
        let word_end = tail
            .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
            .unwrap_or(tail.len());
        let word = &tail[..word_end];
        rest = &tail[word_end..];
        if word == "f32" || word == "f64" {
            out.push_str("a number");
        } else if WHOLE.contains(&word) {
            out.push_str("a whole number");
        } else if word == "struct" || word == "tuple" {
            // `struct Name` or `tuple struct Name`, and ` with N elements` (a record read from
            // an array: its fields in order).
            let after = rest.trim_start_matches(" struct");
            let name_end = after
                .trim_start()
                .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
                .map_or(after.len(), |e| {
                    e + (after.len() - after.trim_start().len())
                });
            rest = &after[name_end..];
            if let Some(r) = rest.strip_prefix(" with ") {
                if let Some(e) = r.find(" elements") {
                    rest = &r[e + " elements".len()..];
                }
            }
            out.push_str(record);
        } else {
            out.push_str(word);
        }
    }
    out.push_str(rest);
    let out = out
        .replacen("invalid type: map", &format!("invalid type: {record}"), 1)
        .replacen("invalid type: sequence", "invalid type: an array", 1)
        .replace("expected a map", &format!("expected {record}"))
        .replace("expected a sequence", "expected an array")
        // serde_json's word for a key given twice (TOML's is "key").
        .replace("duplicate field `", "duplicate key `");
    let out = dotted_key(&bare_values(&out));
    // A key is a key in both formats (serde says field), a value of a list of names a value
    // (serde says variant); names are quoted as the rest of reframe's messages quote them.
    out.replace("unknown field `", "unknown key `")
        .replace("missing field `", "missing key `")
        .replace("unknown variant `", "unknown value `")
        .replace(
            "trailing characters",
            "more text after the end of the JSON value",
        )
        .replace('`', "'")
}

/// toml's message for a dotted key where a value is expected (`frames.x = 3`: `frames` becomes
/// a table, whose key serde then fails to read as the value: `invalid type: string "x",
/// expected a borrowed string`) in the file's words.
fn dotted_key(msg: &str) -> String {
    let inner = msg
        .strip_prefix("invalid type: string \"")
        .and_then(|m| m.strip_suffix("\", expected a borrowed string"));
    match inner {
        Some(key) => format!(
            "a dotted key (from '.{key}' on) makes a table of what takes a value here: write it \
             as 'key = value', without the dots"
        ),
        None => msg.to_string(),
    }
}

/// serde's names of a value's Rust kind dropped where it quotes the value: `invalid type:
/// boolean `true`` is `invalid type: true`, `invalid value: integer `-8`` is `invalid value:
/// -8`, `floating point `0.5`` is `0.5` (the value says what it is; a string keeps its quotes).
fn bare_values(msg: &str) -> String {
    let mut out = msg.to_string();
    for lead in ["invalid type: ", "invalid value: "] {
        let Some(at) = out.find(lead) else {
            continue;
        };
        let after = at + lead.len();
        for kind in ["boolean `", "integer `", "floating point `"] {
            if !out[after..].starts_with(kind) {
                continue;
            }
            let value_at = after + kind.len();
            if let Some(end) = out[value_at..].find('`') {
                let value = out[value_at..value_at + end].to_string();
                out.replace_range(after..value_at + end + 1, &value);
            }
            break;
        }
    }
    out
}

/// A command-line error from clap in plain words: a number that did not parse is said by what
/// was expected, not by Rust's parser (`invalid digit found in string` for `--spp nan`,
/// `number too large to fit in target type`, `invalid float literal`).
pub fn plain_parse_errors(line: &str) -> String {
    const WORDS: [(&str, &str); 6] = [
        (
            "cannot parse integer from empty string",
            "empty: expected a whole number, 0 or more",
        ),
        (
            "invalid digit found in string",
            "expected a whole number, 0 or more",
        ),
        ("number too large to fit in target type", "too large"),
        ("number too small to fit in target type", "too small"),
        ("invalid float literal", "expected a number (such as 2.5)"),
        (
            "cannot parse float from empty string",
            "empty: expected a number",
        ),
    ];
    let line = WORDS
        .iter()
        .fold(line.to_string(), |l, (rust, plain)| l.replace(rust, plain));
    // A ranged parser's `-1 is not in 0..=4294967295`: Rust's range syntax, and not the flag's
    // range (which its own check says); a negative count is said as the others are.
    match line.rsplit_once(": ") {
        Some((head, rest)) if rest.starts_with('-') && rest.contains(" is not in 0..=") => {
            let tail = rest.find(" (").map_or("", |i| &rest[i..]);
            format!("{head}: expected a whole number, 0 or more{tail}")
        }
        _ => line,
    }
}

/// A file name as names are matched in another case: composed (Unicode NFC: an `Ö` written
/// as one character and as `O` and its accent, as macOS stores names and archives made there
/// keep them, are one name) and in lower case (any letter's, not only ASCII's: `Ölfass.png` is
/// `ölfass.png`).
pub fn folded(name: &str) -> String {
    use unicode_normalization::UnicodeNormalization;
    name.nfc().collect::<String>().to_lowercase()
}

/// `frames` as ranges, `0-3, 7, 9-12`, at most `shown` of them and a count of the rest.
pub fn ranges(frames: &[u32], shown: usize) -> String {
    let mut runs: Vec<(u32, u32)> = Vec::new();
    for &f in frames {
        match runs.last_mut() {
            Some((_, b)) if *b + 1 == f => *b = f,
            _ => runs.push((f, f)),
        }
    }
    let mut parts: Vec<String> = runs
        .iter()
        .take(shown)
        .map(|&(a, b)| match a == b {
            true => a.to_string(),
            false => format!("{a}-{b}"),
        })
        .collect();
    if runs.len() > shown {
        parts.push(format!("and {} more run(s)", runs.len() - shown));
    }
    parts.join(", ")
}

#[cfg(test)]
mod tests {
    use super::{bare_values, message, plain_types, printable, screen_safe};

    #[test]
    fn a_message_cuts_runs_past_1024_characters_and_nothing_else() {
        let key = "k".repeat(1_000_000);
        let m = message(&format!(
            "s.toml: line 1 ('kkk ...'): unknown field `{key}`, expected"
        ));
        assert!(m.len() < 1000, "{} bytes", m.len());
        assert!(
            m.starts_with("s.toml: line 1 ('kkk ...'): unknown field `kkk"),
            "{m}"
        );
        // The run is the key with its quotes and comma.
        assert!(m.contains("kkk...(999743 characters)...kkk"), "{m}");
        assert!(m.ends_with("kkk`, expected"), "{m}");
        // A path of 1024 characters is kept whole; one past it keeps its start and its name.
        let path = format!("/{}/frame.exr", "d".repeat(1013));
        assert_eq!(path.len(), 1024);
        assert_eq!(
            message(&format!("writing {path} (full)")),
            format!("writing {path} (full)")
        );
        let long = format!("/{}/frame.exr", "d".repeat(1100));
        let m = message(&format!("writing {long} (full)"));
        assert!(
            m.ends_with("ddd/frame.exr (full)") && m.starts_with("writing /ddd"),
            "{m}"
        );
        // Control characters are escaped as `printable` does.
        assert_eq!(message("a\u{1b}[2Jb"), printable("a\u{1b}[2Jb"));
    }

    #[test]
    fn serde_messages_name_no_rust_types() {
        #[derive(serde::Deserialize, Debug)]
        #[serde(deny_unknown_fields)]
        #[allow(dead_code)]
        struct Entry {
            frame: u32,
            fov: f64,
        }
        let said = |r: Result<Entry, serde_json::Error>| {
            plain_types(&r.unwrap_err().to_string(), "an object")
        };
        let m = said(serde_json::from_str(r#"{"frame": 0, "fov": "wide"}"#));
        assert!(
            m.starts_with(r#"invalid type: string "wide", expected a number"#),
            "{m}"
        );
        let m = said(serde_json::from_str(r#"{"frame": -1, "fov": 1}"#));
        assert!(m.contains("expected a whole number"), "{m}");
        let m = said(serde_json::from_str("[1]"));
        assert!(
            m.starts_with("invalid length 1, expected an object at"),
            "{m}"
        );
        let m = said(serde_json::from_str("7"));
        assert!(
            m.starts_with("invalid type: 7, expected an object at"),
            "{m}"
        );
        for m in [m, said(serde_json::from_str("[1]"))] {
            for rust in ["Entry", "struct", "u32", "f64", "elements"] {
                assert!(!m.contains(rust), "{m}");
            }
        }
        // serde's kinds of a quoted value are left out, and a key given twice is a key.
        let m = said(serde_json::from_str(r#"{"frame": true, "fov": 1}"#));
        assert!(
            m.starts_with("invalid type: true, expected a whole number"),
            "{m}"
        );
        let m = said(serde_json::from_str(r#"{"frame": 0.5, "fov": 1}"#));
        assert!(
            m.starts_with("invalid type: 0.5, expected a whole number"),
            "{m}"
        );
        let m = said(serde_json::from_str(
            r#"{"frame": 0, "fov": 1, "frame": 2}"#,
        ));
        assert!(m.starts_with("duplicate key 'frame'"), "{m}");
        // serde's other words for keys and values, and its backticks.
        let m = said(serde_json::from_str(r#"{"frame": 0, "fps": 1}"#));
        assert!(
            m.starts_with("unknown key 'fps', expected 'frame' or 'fov'"),
            "{m}"
        );
        let m = said(serde_json::from_str(r#"{"frame": 0}"#));
        assert!(m.starts_with("missing key 'fov'"), "{m}");
        let m = said(serde_json::from_str(r#"{"frame": 0, "fov": 1} x"#));
        assert!(
            m.starts_with("more text after the end of the JSON value"),
            "{m}"
        );
        // A TOML dotted key where the scene's reader expects a value (toml's words for it; a
        // corpus case renders one).
        let m = plain_types(
            "invalid type: string \"deg\", expected a borrowed string",
            "a table",
        );
        assert!(
            m.starts_with("a dotted key (from '.deg' on) makes a table of what takes a value"),
            "{m}"
        );
        assert_eq!(
            bare_values(r#"invalid type: string "a", expected a number"#),
            r#"invalid type: string "a", expected a number"#
        );
        // Other words after "expected" are kept.
        assert_eq!(plain_types("expected a string", "x"), "expected a string");
        assert_eq!(plain_types("expected f32s", "x"), "expected f32s");
    }

    #[test]
    fn control_characters_are_escaped() {
        assert_eq!(
            printable("a\u{1b}]0;PWNED\u{7}\u{1b}[2J\0b\r\nc\td\u{9b}e\u{202e}f"),
            "a\\u{1b}]0;PWNED\\u{7}\\u{1b}[2J\\u{0}b\\u{d} c\td\\u{9b}e\\u{202e}f"
        );
        assert_eq!(printable("Grüße, 日本 #25"), "Grüße, 日本 #25");
        // What every printed line goes through keeps its lines and tabs.
        assert_eq!(
            screen_safe("a\u{1b}[2J\n\tb\r\u{2067}c\n"),
            "a\\u{1b}[2J\n\tb\\u{d}\\u{2067}c\n"
        );
        assert!(matches!(
            screen_safe("table\n\tGrüße\n"),
            std::borrow::Cow::Borrowed(_)
        ));
    }
}
