//! Where the files an OBJ, an MTL or a scene names are: as written, or, for a path written on
//! another machine, with its separators, case or Unicode composition read otherwise (`mtllib`
//! lists with spaces and quotes, `find_named_file`), each folder listed once per load
//! (`Listings`).
use super::text;
use crate::util::text::folded;
use std::borrow::Cow;
use std::collections::HashMap;
use std::os::unix::ffi::OsStrExt;
use std::path::{Path, PathBuf};

/// The files an `mtllib` line names: the whole rest of the line if there is such a file (names
/// with spaces are common in exports), or found from it as `find_named_file` finds a path written
/// on another machine (then `true`); otherwise each word (the OBJ format's list).
pub(super) fn mtl_paths(dir: &Path, rest: &[u8]) -> Vec<(PathBuf, bool)> {
    if let Some(found) = find_mtl(dir, rest) {
        return vec![found];
    }
    let as_written = |name: &[u8]| (dir.join(std::ffi::OsStr::from_bytes(name)), false);
    if !rest.iter().any(|b| b.is_ascii_whitespace() || *b == b'"') {
        return vec![as_written(rest)];
    }
    // The list ends at a comment (`mtllib a.mtl b.mtl # materials`); each name found as one
    // name alone is.
    mtllib_words(rest)
        .into_iter()
        .take_while(|w| !w.starts_with(b"#"))
        .map(|w| find_mtl(dir, &w).unwrap_or_else(|| as_written(&w)))
        .collect()
}

/// The file an `mtllib` name (`name`, its bytes) is, where there is one: as written, or found
/// from it (then `true`) in UTF-8 where it is not (a line read as Latin-1, stored as an
/// archive unpacked on another system writes it) or as `find_named_file` finds it.
pub(super) fn find_mtl(dir: &Path, name: &[u8]) -> Option<(PathBuf, bool)> {
    let whole = dir.join(std::ffi::OsStr::from_bytes(name));
    if whole.exists() {
        return Some((whole, false));
    }
    let name = match std::str::from_utf8(name) {
        Ok(name) => Cow::Borrowed(name),
        Err(_) => Cow::Owned(name.iter().map(|&b| b as char).collect::<String>()),
    };
    let utf8 = dir.join(name.as_ref());
    if utf8 != whole && utf8.is_file() {
        return Some((utf8, true));
    }
    find_named_file(dir, &name).map(|found| (found, true))
}

/// The names of an `mtllib` list: split at white space, where a backslash before a space or
/// tab escapes it (`mtl\ file\ with\ spaces.mtl`, as tinyobjloader reads it), and a name in
/// double quotes is one name (`"my mats.mtl"`).
pub(super) fn mtllib_words(rest: &[u8]) -> Vec<Vec<u8>> {
    let mut words = vec![Vec::new()];
    let quoted = rest.iter().filter(|&&c| c == b'"').count() >= 2;
    let mut bytes = rest.iter().copied().peekable();
    while let Some(b) = bytes.next() {
        match b {
            // A name in double quotes, as some exporters write one with spaces: to the next
            // quote, without them (it had been split at its spaces, and the quotes kept).
            b'"' if quoted && words.last().unwrap().is_empty() => {
                let word = words.last_mut().unwrap();
                for c in bytes.by_ref() {
                    if c == b'"' {
                        break;
                    }
                    word.push(c);
                }
                words.push(Vec::new());
            }
            b'\\' if bytes.peek().is_some_and(|c| *c == b' ' || *c == b'\t') => {
                words.last_mut().unwrap().push(bytes.next().unwrap());
            }
            b if b.is_ascii_whitespace() => {
                if !words.last().unwrap().is_empty() {
                    words.push(Vec::new());
                }
            }
            b => words.last_mut().unwrap().push(b),
        }
    }
    words.retain(|w| !w.is_empty());
    words
}

/// The file that an OBJ or MTL in `dir` names as `name` (from a line read as Latin-1 where
/// `latin1`): as written if it is there, else where `find_named_file` finds it (then `true`: a
/// repair to note), else as written (for the caller to report missing).
pub(crate) fn locate_named_file(dir: &Path, name: &str, latin1: bool) -> (PathBuf, bool) {
    // A name read from a Latin-1 line is held as text; the file may be stored under the bytes
    // the line holds, as the system that wrote the line named it, or under the UTF-8 of the
    // same name, as an archive unpacked elsewhere stores it (`mtllib` names are tried both ways
    // too). From a Latin-1 line the bytes are the path as written, tried first (and before a
    // `\` in it is taken for a Windows separator: the second byte of a Shift-JIS character may
    // be one, `ソ.png`) and the UTF-8 is found elsewhere; from a UTF-8 line (`café.png` stored
    // as Latin-1 bytes) the other way round.
    let high = !name.is_ascii() && name.chars().all(|c| (c as u32) < 0x100);
    let raw = || dir.join(std::ffi::OsStr::from_bytes(&text::latin1_bytes(name)));
    if high && latin1 && raw().exists() {
        return (raw(), false);
    }
    let path = dir.join(name);
    if path.exists() {
        return (path, high && latin1);
    }
    if let Some(found) = find_named_file(dir, name) {
        return (found, true);
    }
    if high && raw().is_file() {
        return (raw(), true);
    }
    (path, false)
}

/// The path a scene file in `dir` names as `name`: as written, or where that is not there, the
/// one path whose parts are the same names in another Unicode composition (a scene written
/// with a composed `ü` beside a folder unpacked from a macOS archive, whose names are
/// decomposed, `u` and a combining diaeresis, or the other way round: the same name, which was
/// "no such file" with a message that showed the two alike).
pub(super) fn scene_named(dir: &Path, name: &str) -> PathBuf {
    use unicode_normalization::UnicodeNormalization;
    let path = dir.join(name);
    if name.is_ascii() || path.exists() {
        return path;
    }
    let mut at = dir.to_path_buf();
    for part in Path::new(name).components() {
        let std::path::Component::Normal(part) = part else {
            at.push(part);
            continue;
        };
        let exact = at.join(part);
        if exact.exists() {
            at = exact;
            continue;
        }
        let Some(want) = part.to_str().map(|p| p.nfc().collect::<String>()) else {
            return path;
        };
        let listed = if at.as_os_str().is_empty() {
            Path::new(".")
        } else {
            &at
        };
        let Ok(entries) = std::fs::read_dir(listed) else {
            return path;
        };
        let same: Vec<std::ffi::OsString> = entries
            .flatten()
            .map(|e| e.file_name())
            .filter(|n| n.to_str().is_some_and(|n| n.nfc().eq(want.chars())))
            .take(2)
            .collect();
        match same.as_slice() {
            [one] => at.push(one),
            _ => return path,
        }
    }
    at
}

/// A file that an OBJ or MTL in `dir` names as `name` but that is not there as written, found
/// where a path written on another machine leads: with Windows separators read as `/`
/// (`textures\wood.png`; a drive's `C:\...` is no path here), then by its file name alone in
/// `dir` (an absolute path of the artist's machine, a folder not shipped along); each of the
/// two also with its letters in another case where exactly one entry of a folder matches that
/// way (`SpiderTex.jpg` for `spidertex.jpg`: Windows and macOS ignore case, so assets made there
/// often name their files in another case than they are stored). `None`: not found (the caller
/// reports the path as written).
pub(super) fn find_named_file(dir: &Path, name: &str) -> Option<PathBuf> {
    named_file_matches(dir, name).ok()
}

/// `find_named_file`, with `Err` holding the files that the name matches equally well in
/// another case or composition (`Wood.png` and `wood.png` beside each other, both `wood.PNG`
/// to Windows) where that is why none was found; empty where nothing matches.
pub(super) fn named_file_matches(dir: &Path, name: &str) -> Result<PathBuf, Vec<PathBuf>> {
    let slashed = name.replace('\\', "/");
    let drive = slashed.len() >= 2
        && slashed.as_bytes()[1] == b':'
        && slashed.as_bytes()[0].is_ascii_alphabetic();
    let relative = !drive && !slashed.starts_with('/');
    if slashed != name && relative {
        let p = dir.join(&slashed);
        if p.is_file() {
            return Ok(p);
        }
    }
    let file = slashed.rsplit('/').next().filter(|f| !f.is_empty());
    if let Some(p) = file.filter(|f| *f != name).map(|f| dir.join(f)) {
        if p.is_file() {
            return Ok(p);
        }
    }
    let mut ambiguous = Vec::new();
    if relative {
        match ignoring_case(dir, &slashed) {
            Ok(Some(p)) => return Ok(p),
            Ok(None) => {}
            Err(several) => ambiguous = several,
        }
    }
    match file.map(|f| ignoring_case(dir, f)) {
        Some(Ok(Some(p))) => Ok(p),
        Some(Err(several)) if ambiguous.is_empty() => Err(several),
        _ => Err(ambiguous),
    }
}

/// The file at relative path `rel` under `dir`, each part of it matched in any case and
/// composition of its letters (`util::text::folded`) where it is not there as written, found where exactly
/// one path that way leads to a file; `Err` with the files (sorted) where several do (a
/// folder of another case that leads nowhere, `TEX/` beside `tex/wood.png`, is no candidate).
pub(super) fn ignoring_case(dir: &Path, rel: &str) -> Result<Option<PathBuf>, Vec<PathBuf>> {
    let parts: Vec<&str> = rel
        .split('/')
        .filter(|p| !p.is_empty() && *p != ".")
        .collect();
    let mut found = Vec::new();
    files_ignoring_case(dir.to_path_buf(), &parts, &mut found);
    match found.len() {
        0 => Ok(None),
        1 => Ok(found.pop()),
        _ => {
            found.sort();
            Err(found)
        }
    }
}

/// Every file `parts` leads to from `at` (`ignoring_case`), into `found`; at most a few, past
/// which the search stops (they are only named in a message).
pub(super) fn files_ignoring_case(at: PathBuf, parts: &[&str], found: &mut Vec<PathBuf>) {
    let Some((part, rest)) = parts.split_first() else {
        if at.is_file() {
            found.push(at);
        }
        return;
    };
    if found.len() >= 8 {
        return;
    }
    let exact = at.join(part);
    if exact.exists() {
        return files_ignoring_case(exact, rest, found);
    }
    // The folder of a bare file name (`s.mtl`, the scene given as `s.toml`) is the empty path,
    // which `read_dir` cannot list: it is the working folder. The name found is joined to `at`,
    // so that a path stays as relative as it was given.
    let listed = if at.as_os_str().is_empty() {
        Path::new(".")
    } else {
        at.as_path()
    };
    let Some(listing) = Listings::of(listed) else {
        return;
    };
    let mut matching: Vec<PathBuf> = match listing.get(&folded(part)) {
        Some(names) => names.iter().map(|n| at.join(n)).collect(),
        None => Vec::new(),
    };
    matching.sort();
    for m in matching {
        files_ignoring_case(m, rest, found);
    }
}

/// A folder's entries with UTF-8 names by their `folded` name.
pub(super) type Listing = HashMap<String, Vec<std::ffi::OsString>>;

thread_local! {
    /// The folders `files_ignoring_case` listed while a `Listings` is held (`None` while none
    /// is).
    static LISTINGS: std::cell::RefCell<Option<HashMap<PathBuf, std::rc::Rc<Listing>>>> =
        const { std::cell::RefCell::new(None) };
}

/// While held (a scene's load holds one), `files_ignoring_case` lists each folder once: an
/// asset whose thousands of names are missing as written, beside a folder of thousands of
/// files, listed and folded the whole folder once per name (4000 of each took 16 s to load).
/// Outside, folders are listed anew each time (the files may have changed between loads).
pub(super) struct Listings {
    outermost: bool,
}

impl Listings {
    pub(super) fn hold() -> Listings {
        LISTINGS.with(|l| {
            let mut l = l.borrow_mut();
            let outermost = l.is_none();
            if outermost {
                *l = Some(HashMap::new());
            }
            Listings { outermost }
        })
    }

    /// The entries of `folder` by folded name; `None` where it cannot be listed.
    fn of(folder: &Path) -> Option<std::rc::Rc<Listing>> {
        let held = LISTINGS.with(|l| {
            let l = l.borrow();
            l.as_ref().map(|cache| cache.get(folder).cloned())
        });
        if let Some(Some(listing)) = held {
            return Some(listing);
        }
        let mut listing = Listing::new();
        for entry in std::fs::read_dir(folder).ok()?.filter_map(|e| e.ok()) {
            let name = entry.file_name();
            if let Some(n) = name.to_str() {
                listing.entry(folded(n)).or_default().push(name);
            }
        }
        let listing = std::rc::Rc::new(listing);
        LISTINGS.with(|l| {
            if let Some(cache) = l.borrow_mut().as_mut() {
                cache.insert(folder.to_path_buf(), listing.clone());
            }
        });
        Some(listing)
    }
}

impl Drop for Listings {
    fn drop(&mut self) {
        if self.outermost {
            LISTINGS.with(|l| *l.borrow_mut() = None);
        }
    }
}

/// `missing`'s message for a file named `name` in `dir` that is not there: where several files
/// of a folder match the name in another case, they are named (none is picked: which one an
/// exporter meant is a guess).
pub(crate) fn missing_file_message(dir: &Path, name: &str, missing: &Path) -> String {
    let several = named_file_matches(dir, name).err().unwrap_or_default();
    if several.is_empty() {
        return format!("no file '{}'", missing.display());
    }
    let list: Vec<String> = several
        .iter()
        .map(|p| format!("'{}'", p.display()))
        .collect();
    format!(
        "no file '{}', and {} match it in another case: rename all but the one meant",
        missing.display(),
        list.join(" and ")
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_load_lists_each_folder_once() {
        // While a load holds `Listings`, a folder is listed at its first lookup in another
        // case and that listing answers every later one (a file added since is not seen);
        // held no more, folders are listed anew.
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::write(d.join("Wood.png"), b"").unwrap();
        let one = Ok(Some(d.join("Wood.png")));
        {
            let _load = Listings::hold();
            assert_eq!(ignoring_case(d, "wood.png"), one);
            std::fs::write(d.join("WOOD.png"), b"").unwrap();
            assert_eq!(ignoring_case(d, "wood.png"), one);
            // A nested hold (a load within a load) keeps the outer one's listings.
            drop(Listings::hold());
            assert_eq!(ignoring_case(d, "wood.png"), one);
        }
        let both = vec![d.join("WOOD.png"), d.join("Wood.png")];
        assert_eq!(ignoring_case(d, "wood.png"), Err(both));
    }
}
