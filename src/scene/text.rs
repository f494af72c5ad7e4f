//! Text helpers shared by the scene's loaders: strict UTF-8 for the scene TOML (the TOML
//! format requires it), and the lenient reading of OBJ and MTL lines, whose exporters write
//! whatever their platform's encoding was (a Latin-1 byte in a comment or a material name).
//! Control characters other than whitespace mean a binary file, in either.
use super::repairs::{Kind, Repairs};
use anyhow::{anyhow, bail, Result};
use std::borrow::Cow;

/// Largest coordinate accepted for a vertex or the camera: products of two edge vectors (areas,
/// squared distances) must stay finite in f32, and 4 * (2e18)^2 < 3.4e38.
pub const MAX_COORD: f32 = 1e18;

/// Whether a number checked in double precision (a transform, a camera matrix) is past
/// `MAX_COORD` as one read in single precision (a vertex) is: rounded to f32 first, so that
/// every input takes the same numbers (`MAX_COORD as f64` is the float just below 1e18, which
/// refused a translation of 1e18 that a vertex could have).
pub fn past_max_coord(x: f64) -> bool {
    (x as f32).abs() > MAX_COORD
}

/// The largest angle, in degrees, a scene may give (an object's `rotate`, the environment's
/// `rotation`): past it an angle's sine and cosine keep few correct digits in f64, none in f32.
pub const MAX_DEGREES: f64 = 1e6;

/// The narrowest field of view a camera may have, in degrees (3.6 arcseconds, far narrower than
/// any lens): below about 1e-20 degrees a pixel's film area underflows f32 and the reuse
/// methods' film Jacobians come out infinite (every frame black).
pub const MIN_FOV: f32 = 1e-3;

/// What to add to "is not finite" when the values hold an infinity but no NaN: an infinity as
/// the file writes it (`inf`, MSVC's `1.#INF`), or a number written finite but beyond single
/// precision (1e39), which reads as infinite, where the message would otherwise show `inf` for
/// what the file says is a number.
pub fn beyond_f32(values: impl IntoIterator<Item = f32>) -> &'static str {
    let v: Vec<f32> = values.into_iter().collect();
    if v.iter().any(|x| x.is_infinite()) && !v.iter().any(|x| x.is_nan()) {
        " (infinite: an infinity as written, inf or 1.#INF, or a number beyond single precision, \
         about 3.4e38, which reads as inf; coordinates are at most 1e18)"
    } else {
        ""
    }
}

/// Why a vertical field of view (degrees), as read (in double precision), is refused, if it is.
/// The renderer keeps it in single precision, where everything above 179.99998 rounds to 180:
/// such a value is named as given, not as the 180 it would become.
pub fn fov_fault(fov: f64) -> Option<String> {
    if !(fov > 0.0 && fov < 180.0) {
        Some(format!("fov {fov} must be in (0, 180) degrees"))
    } else if fov as f32 >= 180.0 {
        Some(format!(
            "fov {fov} rounds to 180 degrees in single precision: at most {} (and below 180)",
            f32::from_bits(180f32.to_bits() - 1)
        ))
    } else if (fov as f32) < MIN_FOV {
        // Compared as the renderer keeps it: 0.001 in f64 is below the f32 nearest it.
        Some(format!(
            "fov {fov:e} is narrower than {MIN_FOV} degrees, which no lens is (the film area of a \
             pixel would underflow)"
        ))
    } else {
        None
    }
}

/// `bytes` without the end-of-file mark (0x1a, Ctrl-Z) that DOS-era tools put after the last
/// line: refused as a binary file's control character otherwise.
fn without_eof_mark(bytes: &[u8]) -> &[u8] {
    bytes.strip_suffix(b"\x1a").unwrap_or(bytes)
}

/// `bytes` as UTF-8 where they are UTF-16 or UTF-32 text that says so by its byte order mark
/// (Windows tools' "Unicode" text: Notepad, Excel's "Unicode Text", PowerShell 5's `>`),
/// decoded whole; otherwise as they are (text without a mark in those encodings is refused by
/// `as_text`, naming them, and so is one whose units do not decode). Lines stay lines, so
/// line numbers in messages are the file's.
pub fn from_wide(bytes: Vec<u8>) -> Vec<u8> {
    let units = |b: &[u8], n: usize, le: bool| -> Option<Vec<u32>> {
        b.len().is_multiple_of(n).then(|| {
            b.chunks_exact(n)
                .map(|c| {
                    let mut w = [0u8; 4];
                    w[..n].copy_from_slice(c);
                    if !le {
                        w[..n].reverse();
                    }
                    u32::from_le_bytes(w)
                })
                .collect()
        })
    };
    let text: Option<String> = if let Some(b) = bytes.strip_prefix(b"\xff\xfe\0\0") {
        units(b, 4, true).and_then(|u| u.into_iter().map(char::from_u32).collect())
    } else if let Some(b) = bytes.strip_prefix(b"\0\0\xfe\xff") {
        units(b, 4, false).and_then(|u| u.into_iter().map(char::from_u32).collect())
    } else if let Some(b) = bytes.strip_prefix(b"\xff\xfe") {
        units(b, 2, true).and_then(|u| {
            char::decode_utf16(u.into_iter().map(|u| u as u16))
                .collect::<Result<String, _>>()
                .ok()
        })
    } else if let Some(b) = bytes.strip_prefix(b"\xfe\xff") {
        units(b, 2, false).and_then(|u| {
            char::decode_utf16(u.into_iter().map(|u| u as u16))
                .collect::<Result<String, _>>()
                .ok()
        })
    } else {
        None
    };
    match text {
        Some(t) => t.into_bytes(),
        None => bytes,
    }
}

/// `bytes` as text, or an error naming the line of the first byte that is not text.
pub fn as_text(bytes: &[u8]) -> Result<&str> {
    let bytes = without_eof_mark(bytes);
    utf16(bytes)?;
    let text = std::str::from_utf8(bytes).map_err(|e| {
        anyhow!(
            "line {}: not UTF-8 text (a binary file?)",
            line_at(bytes, e.valid_up_to())
        )
    })?;
    binary(bytes)?;
    Ok(text)
}

/// Refuse UTF-16 text (Excel's "Unicode text", PowerShell 5's redirections) and UTF-32 text:
/// by its byte order mark, or without one by its first characters, ASCII with zero bytes beside
/// each (one for UTF-16, three for UTF-32).
fn utf16(bytes: &[u8]) -> Result<()> {
    let said = |wide: &str, how: &str| {
        anyhow::anyhow!("the file is {wide} text ({how}): save it as UTF-8 or ASCII")
    };
    // UTF-32's little-endian mark starts with UTF-16's.
    if bytes.starts_with(b"\xff\xfe\0\0") || bytes.starts_with(b"\0\0\xfe\xff") {
        return Err(said("UTF-32", "its byte order mark says so"));
    }
    if bytes.starts_with(b"\xff\xfe") || bytes.starts_with(b"\xfe\xff") {
        return Err(said("UTF-16", "its byte order mark says so"));
    }
    let ascii = |x: u8| x != 0 && x.is_ascii();
    if let [a, b, c, d, e, f, g, h, ..] = *bytes {
        if (ascii(a) && [b, c, d, f, g, h] == [0; 6] && ascii(e))
            || ([a, b, c, e, f, g] == [0; 6] && ascii(d) && ascii(h))
        {
            return Err(said(
                "UTF-32",
                "three zero bytes beside each of its first characters",
            ));
        }
    }
    if let [a, b, c, d, ..] = *bytes {
        if (a == 0 && ascii(b) && c == 0 && ascii(d)) || (ascii(a) && b == 0 && ascii(c) && d == 0)
        {
            return Err(said(
                "UTF-16",
                "a zero byte beside each of its first characters",
            ));
        }
    }
    Ok(())
}

/// The first control character that is not whitespace: a sign of a binary file.
fn binary(bytes: &[u8]) -> Result<()> {
    utf16(bytes)?;
    let control = |b: u8| (b < 0x20 && !matches!(b, b'\t' | b'\n' | b'\r' | 0x0c)) || b == 0x7f;
    if let Some(i) = bytes.iter().position(|&b| control(b)) {
        bail!(
            "line {}: control character 0x{:02x} (a binary file?)",
            line_at(bytes, i),
            bytes[i]
        );
    }
    Ok(())
}

/// The repair of a line that is not UTF-8 (outside comments, which are not read).
pub const NOT_UTF8: Kind = Kind {
    one: "line is not UTF-8, read as Latin-1",
    many: "lines are not UTF-8, read as Latin-1",
};

/// One line of an OBJ or MTL file: its number, its text, and whether it was not UTF-8 (then
/// read as Latin-1, which maps every byte to one character, so that names stay distinct).
pub struct Line<'a> {
    pub n: usize,
    pub text: Cow<'a, str>,
    pub latin1: bool,
}

/// Whether a text's lines end in a bare CR throughout (the classic Mac OS's line end): it has
/// a CR and no LF.
pub fn bare_cr_lines(bytes: &[u8]) -> bool {
    !bytes.contains(&b'\n') && bytes.contains(&b'\r')
}

/// The lines of an OBJ or MTL file, without a UTF-8 byte order mark or line ends (LF or CRLF;
/// a bare CR, the classic Mac OS's line end, in a file without any LF; a bare CR within a line
/// of a file with LF ends a statement too, the parts keeping the line's number), one at a time
/// (a large OBJ is not copied).
pub fn lines(bytes: &[u8]) -> Result<impl Iterator<Item = Line<'_>>> {
    let bytes = without_eof_mark(bytes);
    binary(bytes)?;
    let bytes = bytes.strip_prefix(b"\xef\xbb\xbf").unwrap_or(bytes);
    let end = if bare_cr_lines(bytes) { b'\r' } else { b'\n' };
    // A bare CR inside a line of a file with LF line ends ends a statement too (an exporter's
    // header comment ending in CR swallowed the vertex after it): the parts keep the line's
    // number, as an editor shows the CR within the line.
    Ok(bytes
        .split(move |&b| b == end)
        .enumerate()
        .flat_map(|(i, l)| {
            let l = l.strip_suffix(b"\r").unwrap_or(l);
            l.split(|&b| b == b'\r').map(move |part| (i, part))
        })
        .map(|(i, l)| {
            let (text, latin1) = match std::str::from_utf8(l) {
                Ok(t) => (Cow::Borrowed(t), false),
                Err(_) => (Cow::Owned(l.iter().map(|&b| b as char).collect()), true),
            };
            Line {
                n: i + 1,
                text,
                latin1,
            }
        }))
}

/// The lines with continuations joined: a statement that ends in `\` goes on in the next line
/// (the OBJ format's rule, used by exporters for long faces); the joined line keeps the number
/// of its first. Comments are left alone, so that a comment ending in `\` (a Windows path)
/// does not swallow the statement below it: a line that is a comment, and a statement of
/// numbers whose comment at its end (`v 1 0 2 # from C:\scans\`) holds the `\`.
pub fn joined<'a>(mut lines: impl Iterator<Item = Line<'a>>) -> impl Iterator<Item = Line<'a>> {
    std::iter::from_fn(move || {
        let mut line = lines.next()?;
        {
            let t = line.text.trim_end();
            if !continues(t, line.latin1) || t.trim_start().starts_with('#') || ends_in_comment(t) {
                return Some(line);
            }
            // The statement grows in one string, and each line is looked at once: what the test
            // above reads of the whole (its first word, its last character, a word from `#`)
            // is kept as it grows. Joined and scanned whole for each line, a face continued
            // over 120,000 lines (480 KB) took 30 s to load.
            let mut s = t[..t.len() - 1].to_string();
            let mut hash_word = s.split_whitespace().any(|w| w.starts_with('#'));
            loop {
                let Some(next) = lines.next() else {
                    line.text = s.into();
                    return Some(line);
                };
                // One space where the lines meet (the blanks around the `\` and at the next
                // line's start separate words, and doubled they showed in messages).
                s.truncate(s.trim_end().len());
                s.push(' ');
                s.push_str(next.text.trim_start());
                line.latin1 |= next.latin1;
                hash_word |= next.text.split_whitespace().any(|w| w.starts_with('#'));
                let t = s.trim_end();
                let comment = hash_word && s.split_whitespace().next().is_some_and(numeric);
                if !continues(t, next.latin1) || t.trim_start().starts_with('#') || comment {
                    line.text = s.into();
                    return Some(line);
                }
                s.truncate(t.len() - 1);
            }
        }
    })
}

/// Whether a statement `t` (trimmed at its end) goes on in the next line: it ends in `\`, and
/// that is no second byte of a double-byte character (`latin1`: its line was not UTF-8, and the
/// byte before the `\` is above ASCII: Shift-JIS, GBK and Big5 names such as `表`, `ソ` and
/// `功` end in the byte of `\`, and `usemtl 表` swallowed the face below it). UTF-8 never
/// holds that byte inside a character.
fn continues(t: &str, latin1: bool) -> bool {
    let mut end = t.chars().rev();
    end.next() == Some('\\') && !(latin1 && end.next().is_some_and(|c| !c.is_ascii()))
}

/// Whether the statement `t` is one of numbers with a comment at its end (a word from `#` on).
fn ends_in_comment(t: &str) -> bool {
    let mut words = t.split_whitespace();
    words.next().is_some_and(numeric) && words.any(|w| w.starts_with('#'))
}

impl Line<'_> {
    /// The line as a statement of the file `label`: its keyword and its words (any whitespace
    /// between them); `None` for a blank line or a comment. A line read as Latin-1 is noted as a
    /// repair (a refusal under strict loading).
    pub fn statement(
        &self,
        label: &str,
        repairs: &mut Repairs,
    ) -> Result<Option<(&str, Vec<&str>)>> {
        let text = self.text.as_ref();
        let mut words = text.split_whitespace();
        let Some(key) = words.next() else {
            return Ok(None);
        };
        if key.starts_with('#') {
            return Ok(None);
        }
        if self.latin1 {
            repairs.note(label, self.n, NOT_UTF8, || format!("'{}'", quote(text)))?;
        }
        let mut args: Vec<&str> = words.collect();
        if numeric(key) {
            if let Some(i) = args.iter().position(|w| w.starts_with('#')) {
                args.truncate(i);
            }
        }
        Ok(Some((key, args)))
    }
}

/// Whether the words of statement `key` are numbers (or `off`, or face corners): a word that
/// starts with `#` ends them, a comment at the end of the line (`v 1 2 3 # top`). Names and
/// file names keep their `#` (3ds Max names materials `Material #25`).
fn numeric(key: &str) -> bool {
    matches!(
        key.to_ascii_lowercase().as_str(),
        "v" | "vt"
            | "vn"
            | "vp"
            | "f"
            | "fo"
            | "l"
            | "p"
            | "s"
            | "kd"
            | "ks"
            | "ke"
            | "ka"
            | "ns"
            | "ni"
            | "d"
            | "tr"
            | "tf"
            | "illum"
    )
}

/// The bytes of a line read as Latin-1 (for file names, which are bytes on Unix).
pub fn latin1_bytes(text: &str) -> Vec<u8> {
    text.chars().map(|c| c as u32 as u8).collect()
}

/// What a name written to the end of its line (`usemtl`'s, a map's file) may mean where the
/// whole names nothing: each part before a `#` that follows white space (a comment after the
/// name), longest first, less its trailing white space (`Material #25 # x`: `Material #25`,
/// then `Material`); at most `MOST_COMMENT_HEADS` of them, since each is hashed whole to be
/// looked up (a name of 10^5 ` #` would have cost 10^10 steps).
pub fn before_comments(name: &str) -> impl Iterator<Item = &str> {
    let b = name.as_bytes();
    (1..b.len())
        .rev()
        .filter(move |&i| b[i] == b'#' && matches!(b[i - 1], b' ' | b'\t'))
        .take(MOST_COMMENT_HEADS)
        .map(move |i| name[..i].trim_end())
}

/// How many places a comment may start in a name, counted from its end (`before_comments`).
pub const MOST_COMMENT_HEADS: usize = 16;

/// The rest of `line` after its first word (a name that may hold spaces), trimmed.
pub fn rest(line: &str) -> &str {
    let t = line.trim_start();
    let key = t.split_whitespace().next().unwrap_or("");
    t[key.len()..].trim()
}

/// The first `N` words as numbers (extra words are not looked at).
pub fn numbers<const N: usize>(words: &[&str]) -> Option<[f32; N]> {
    let mut v = [0.0; N];
    for (x, w) in v.iter_mut().zip(words.get(..N)?) {
        *x = number(w)?;
    }
    Some(v)
}

/// `key` as the format writes it where it is one of `keys` in another case (exporters differ:
/// `kd`, `KD`, `V`, `USEMTL`), else as it is.
pub fn canonical<'a>(key: &'a str, keys: &[&'static str]) -> &'a str {
    keys.iter()
        .find(|k| k.eq_ignore_ascii_case(key))
        .copied()
        .unwrap_or(key)
}

/// A number of a scene file as a message shows it: as Rust writes it, in exponent form where
/// that would be long (`1e39`, not forty digits).
pub fn shown(x: f64) -> String {
    if x != 0.0 && !(1e-4..1e6).contains(&x.abs()) {
        format!("{x:e}")
    } else {
        format!("{x}")
    }
}

/// `number`, with a number written in digits but past single precision (`1e39`, or `1e400`
/// past double's too, which read as infinite) taken as the largest single of its sign, for values that are capped or clamped
/// anyway (an MTL's `Ke`, `Ns`, `Pr`): an infinity or NaN as written stays what it is.
pub fn number_saturating(word: &str) -> Option<f32> {
    let x = number(word)?;
    // Digits (`1e39`, `1e400`), not an infinity as written (`inf`, `1.#INF`).
    let digits = !word.to_ascii_lowercase().contains("inf") && !word.contains('#');
    if x.is_infinite() && digits {
        return Some(f32::MAX.copysign(x));
    }
    Some(x)
}

/// One number of an OBJ or MTL statement: as Rust reads it, or a non-finite value as
/// Microsoft's C library writes it (`1.#INF00`, `-1.#IND00`, `1.#QNAN0`, `1.#SNAN0` before
/// Visual Studio 2015, `-nan(ind)` and `nan(snan)` since, the C standard's `nan(chars)`), which
/// 3ds Max and other Windows exporters put in files; the loader then treats it as it treats
/// `inf` and `nan` (a normal that is not finite flat-shades its triangles, a position is
/// refused).
pub fn number(word: &str) -> Option<f32> {
    if let Ok(x) = word.parse() {
        return Some(x);
    }
    // The C standard's `nan(n-char-sequence)`: letters, digits and underscores in brackets.
    let unsigned = word.strip_prefix(['+', '-']).unwrap_or(word);
    if let Some(chars) = unsigned
        .get(..4)
        .filter(|nan| nan.eq_ignore_ascii_case("nan("))
        .and_then(|_| unsigned[4..].strip_suffix(')'))
    {
        return chars
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_')
            .then_some(f32::NAN);
    }
    let (mantissa, kind) = word.split_once('#')?;
    let negative = mantissa.starts_with('-');
    let digits = mantissa.trim_start_matches(['+', '-']);
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit() || b == b'.') {
        return None;
    }
    let upper = kind.to_ascii_uppercase();
    let name = upper.trim_end_matches(|c: char| c.is_ascii_digit());
    match name {
        "INF" if negative => Some(f32::NEG_INFINITY),
        "INF" => Some(f32::INFINITY),
        "IND" | "QNAN" | "SNAN" | "NAN" => Some(f32::NAN),
        _ => None,
    }
}

/// Line `n` (1-based) of `bytes`, quoted for a message: `'f 1 2 9'`.
pub fn quote_line(bytes: &[u8], n: usize) -> String {
    let line = bytes.split(|&b| b == b'\n').nth(n.saturating_sub(1));
    format!("'{}'", quote(&String::from_utf8_lossy(line.unwrap_or(b""))))
}

/// The line numbers of byte offsets in one text, each found by a binary search over the
/// text's line starts: a loader that names the line of every entry (a camera file's 30000
/// frames, a scene's `[[object]]` tables) would scan the text from the start for each with
/// `line_at`, which is quadratic in the entries.
pub struct Lines(Vec<usize>);

impl Lines {
    pub fn new(bytes: &[u8]) -> Lines {
        Lines(
            bytes
                .iter()
                .enumerate()
                .filter(|(_, &b)| b == b'\n')
                .map(|(i, _)| i)
                .collect(),
        )
    }

    /// The 1-based line of byte `offset` (`line_at(bytes, offset)`).
    pub fn at(&self, offset: usize) -> usize {
        self.0.partition_point(|&nl| nl < offset) + 1
    }
}

/// 1-based line of the byte at `offset`.
pub fn line_at(bytes: &[u8], offset: usize) -> usize {
    let offset = offset.min(bytes.len());
    bytes[..offset].iter().filter(|&&b| b == b'\n').count() + 1
}

/// A file name from a scene file as a message shows it: as `quote` shortens it, but untrimmed,
/// so that a space at its end (`obj = "s.obj "`, which names no file) shows, where the message
/// read `obj 's.obj': OBJ 's.obj ': no such file`.
pub fn quote_name(name: &str) -> String {
    match name.char_indices().nth(60) {
        Some((i, _)) => format!("{} ...", &name[..i]),
        None => name.to_string(),
    }
}

/// A line as it appears in an error message: trimmed, and cut short if long.
pub fn quote(line: &str) -> String {
    quote_name(line.trim())
}

/// `nearest_name` as the end of a message's detail: ` (did you mean 'floor'?)`, or nothing.
pub fn did_you_mean<'a>(name: &str, defined: impl IntoIterator<Item = &'a str>) -> String {
    nearest_name(name, defined)
        .map(|d| format!(" (did you mean '{}'?)", quote_name(d)))
        .unwrap_or_default()
}

/// The longest name `nearest_name` measures the edit distance of.
const MOST_FUZZY_CHARS: usize = 256;

/// The name of `defined` that `name` most likely meant, where it names none of them: one that
/// differs only in case or surrounding spaces, else the nearest within a few edits, case aside
/// (one for names of up to 5 characters, two up to 12, three beyond; a swap of neighbours is
/// one edit), the first defined on a tie. A hint for a message: `usemtl Floor` against
/// `newmtl floor`, `usemtl flor`, `usemtl Material.01` against `Material.001`, `Kdd` against
/// the MTL statement `Kd`.
pub fn nearest_name<'a>(name: &str, defined: impl IntoIterator<Item = &'a str>) -> Option<&'a str> {
    let folded = name.trim().to_lowercase();
    let lower = name.to_lowercase();
    let chars = name.chars().count();
    let limit = match chars {
        0..=5 => 1,
        6..=12 => 2,
        _ => 3,
    };
    let mut best: Option<(usize, &str)> = None;
    for d in defined {
        if d == name {
            continue;
        }
        if d.trim().to_lowercase() == folded {
            return Some(d);
        }
        // The distance is at least the difference in length: most names are skipped unread.
        // Long names are only compared case aside: the distance takes a time in the product
        // of the lengths (two names of 10^6 characters took half an hour), and a hint of a few
        // edits in so long a name says little.
        if d.chars().count().abs_diff(chars) > limit || chars.max(d.len()) > MOST_FUZZY_CHARS {
            continue;
        }
        let e = strsim::osa_distance(&lower, &d.to_lowercase());
        if e <= limit && e < chars && best.is_none_or(|(b, _)| e < b) {
            best = Some((e, d));
        }
    }
    best.map(|(_, d)| d)
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_documented_fov_limits_are_allowed() {
        for fov in [0.001, 179.99998, 45.0] {
            assert_eq!(fov_fault(fov), None, "{fov}");
        }
        for fov in [0.000999, 1e-30, 179.999995, 180.0, 0.0, -1.0] {
            assert!(fov_fault(fov).is_some(), "{fov}");
        }
    }

    use super::*;

    #[test]
    fn a_near_name_is_found_and_a_far_one_is_not() {
        let defined = [
            "floor",
            "light",
            "Material.001",
            "Material.002",
            "wall_left",
        ];
        let near = |n: &str| nearest_name(n, defined.iter().copied());
        // Case and spaces first, whatever the edits.
        assert_eq!(near("FLOOR"), Some("floor"));
        assert_eq!(near(" light"), Some("light"));
        // One edit in a short name, two in a middling one, a swap counting one.
        assert_eq!(near("flor"), Some("floor"));
        assert_eq!(near("ligth"), Some("light"));
        assert_eq!(near("wall_lft"), Some("wall_left"));
        assert_eq!(near("wal_lef"), Some("wall_left"));
        assert_eq!(near("FLOR"), Some("floor"), "an edit and a case");
        // A tie goes to the first defined.
        assert_eq!(near("Material.003"), Some("Material.001"));
        // Too far, or a name of one letter, or nothing at all.
        assert_eq!(near("ceiling"), None);
        assert_eq!(near("fl"), None);
        assert_eq!(near("x"), None);
        assert_eq!(near(""), None);
        assert_eq!(near("floor"), None, "a defined name is no miss");
        assert_eq!(nearest_name("floor", []), None);
    }

    #[test]
    fn lines_finds_what_line_at_finds() {
        for text in [&b""[..], b"\n", b"a", b"a\nbc\n\nd", b"\n\nx\ny\n"] {
            let lines = Lines::new(text);
            for offset in 0..=text.len() + 2 {
                assert_eq!(
                    lines.at(offset),
                    line_at(text, offset),
                    "{text:?} at {offset}"
                );
            }
        }
    }

    #[test]
    fn text_names_the_line_of_binary_data() {
        assert_eq!(as_text(b"a\nb\n").unwrap(), "a\nb\n");
        // A DOS end-of-file mark after the last line is no part of the text; elsewhere it is
        // a control character.
        assert_eq!(as_text(b"a\nb\n\x1a").unwrap(), "a\nb\n");
        assert_eq!(lines(b"v 1 2 3\n\x1a").unwrap().count(), 2);
        assert!(as_text(b"a\x1a\nb\n").is_err());
        let e = as_text(b"a\nb\n\xff\xfe").unwrap_err().to_string();
        assert!(e.starts_with("line 3: not UTF-8"), "{e}");
        let e = as_text(b"a\n\0").unwrap_err().to_string();
        assert!(e.starts_with("line 2: control character 0x00"), "{e}");
        let e = lines(b"a\n\0").err().unwrap().to_string();
        assert!(e.starts_with("line 2: control character 0x00"), "{e}");
    }

    /// A scene TOML or camera file saved as UTF-16 or UTF-32 (with a byte order mark, or
    /// without one in either byte order) is named so, as an OBJ is, not as binary data (a
    /// UTF-32 file was named UTF-16).
    #[test]
    fn utf16_text_is_named_so() {
        let text = "frame,x\n0,1\n";
        let le: Vec<u8> = text.encode_utf16().flat_map(|u| u.to_le_bytes()).collect();
        let be: Vec<u8> = text.encode_utf16().flat_map(|u| u.to_be_bytes()).collect();
        let bom = [&b"\xff\xfe"[..], &le].concat();
        for bytes in [&bom[..], &le[..], &be[..]] {
            let e = as_text(bytes).unwrap_err().to_string();
            assert!(e.starts_with("the file is UTF-16 text"), "{e}");
        }
        // UTF-32, with a mark or without one in either order, is named so too.
        let le: Vec<u8> = text
            .chars()
            .flat_map(|c| (c as u32).to_le_bytes())
            .collect();
        let be: Vec<u8> = text
            .chars()
            .flat_map(|c| (c as u32).to_be_bytes())
            .collect();
        let bom = [&b"\xff\xfe\0\0"[..], &le].concat();
        for bytes in [&bom[..], &le[..], &be[..]] {
            let e = as_text(bytes).unwrap_err().to_string();
            assert!(e.starts_with("the file is UTF-32 text"), "{e}");
        }
        // With its mark, it is read (`from_wide`) as the same text; a lone surrogate is no
        // UTF-16, left as it is (and refused).
        let le16: Vec<u8> = text.encode_utf16().flat_map(|u| u.to_le_bytes()).collect();
        let be16: Vec<u8> = text.encode_utf16().flat_map(|u| u.to_be_bytes()).collect();
        let marked = [
            bom.clone(),
            [&b"\xff\xfe"[..], &le16].concat(),
            [&b"\xfe\xff"[..], &be16].concat(),
        ];
        for bytes in marked {
            assert_eq!(from_wide(bytes), text.as_bytes());
        }
        let lone = [&b"\xff\xfe"[..], &[0x00, 0xd8, b'a', 0]].concat();
        assert_eq!(from_wide(lone.clone()), lone);
        // Text with a zero byte further in is not UTF-16 (a binary file).
        let e = as_text(b"abcd\0").unwrap_err().to_string();
        assert!(e.starts_with("line 1: control character 0x00"), "{e}");
    }

    #[test]
    fn obj_and_mtl_lines_are_lenient() {
        let l: Vec<Line> = lines(b"\xef\xbb\xbfnewmtl a\r\n# caf\xe9\nnewmtl caf\xe9 2\n")
            .unwrap()
            .collect();
        assert_eq!(l[0].text, "newmtl a");
        assert!(!l[0].latin1 && l[1].latin1);
        assert_eq!(l[2].text, "newmtl caf\u{e9} 2");
        assert_eq!(rest(&l[2].text), "caf\u{e9} 2");
        assert_eq!(latin1_bytes(rest(&l[2].text)), b"caf\xe9 2");
        assert_eq!(rest("usemtl\t\tmy  stone "), "my  stone");
        assert_eq!(numbers::<2>(&["1", "2.5", "x"]), Some([1.0, 2.5]));
        assert_eq!(numbers::<2>(&["1"]), None);
    }

    /// Continued statements, as the format and the comment rules say, line numbers kept.
    #[test]
    fn continued_lines_are_joined_and_comments_end_them() {
        let join = |text: &[u8]| -> Vec<(usize, String)> {
            joined(lines(text).unwrap())
                .map(|l| (l.n, l.text.into_owned()))
                .collect()
        };
        let owned = |v: &[(usize, &str)]| -> Vec<(usize, String)> {
            v.iter().map(|&(n, t)| (n, t.to_string())).collect()
        };
        // A face over three lines, trailing blanks after the `\`, then a vertex.
        assert_eq!(
            join(b"f 1 2 \\  \n3 4\\\n 5\nv 0 0 0\n"),
            owned(&[(1, "f 1 2 3 4 5"), (4, "v 0 0 0"), (5, "")])
        );
        // A comment ending in `\` and a statement of numbers whose comment holds it swallow
        // nothing; a name's `\` goes on.
        assert_eq!(
            join(b"# C:\\scans\\\nv 1 0 2 # C:\\x\\\nv 3 3 3\nusemtl a\\\nb\n"),
            owned(&[
                (1, "# C:\\scans\\"),
                (2, "v 1 0 2 # C:\\x\\"),
                (3, "v 3 3 3"),
                (4, "usemtl a b"),
                (6, "")
            ])
        );
        // A comment that comes in a later line of a statement of numbers ends it there.
        assert_eq!(
            join(b"f 1 2\\\n3 # x\\\nv 1 1 1\n"),
            owned(&[(1, "f 1 2 3 # x\\"), (3, "v 1 1 1"), (4, "")])
        );
        // A line of a `\` alone, and a continuation at the end of the file.
        assert_eq!(
            join(b"\\\nf 1 2 3\nf 4 5\\"),
            owned(&[(1, " f 1 2 3"), (3, "f 4 5")])
        );
        // Shift-JIS names (a line that is not UTF-8) whose last character's second byte is the
        // byte of `\` (`表` is 0x95 0x5C) end there, in a first line and in a line continued;
        // an ASCII `\` in such a line goes on, as does one after `é` in UTF-8.
        assert_eq!(
            join(b"usemtl \x95\\\nf 1 2 3\nf 4 \\\n5 \x95\\\nv 0 0 0\ng a\xe9 \\\nb\n"),
            owned(&[
                (1, "usemtl \u{95}\\"),
                (2, "f 1 2 3"),
                (3, "f 4 5 \u{95}\\"),
                (5, "v 0 0 0"),
                (6, "g a\u{e9} b"),
                (8, "")
            ])
        );
        assert_eq!(
            join("g caf\u{e9}\\\nx\n".as_bytes()),
            owned(&[(1, "g caf\u{e9} x"), (3, "")])
        );
    }

    #[test]
    fn a_bare_cr_in_an_lf_file_ends_a_statement() {
        let l: Vec<(usize, String)> =
            lines(b"mtllib s.mtl\n# exported by X\rv -1 0 -1\nv 1 0 -1\r\n")
                .unwrap()
                .map(|l| (l.n, l.text.into_owned()))
                .collect();
        let want = [
            (1, "mtllib s.mtl"),
            (2, "# exported by X"),
            (2, "v -1 0 -1"),
            (3, "v 1 0 -1"),
            (4, ""),
        ];
        assert_eq!(l, want.map(|(n, t)| (n, t.to_string())));
        // A classic Mac OS file (CR alone) is numbered by its CRs.
        let mac: Vec<usize> = lines(b"v 1 2 3\rv 4 5 6\r").unwrap().map(|l| l.n).collect();
        assert_eq!(mac, [1, 2, 3]);
    }
}
