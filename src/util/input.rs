//! The one way reframe opens a file it reads as input (a scene TOML, an OBJ, an MTL, and state
//! files such as a partial render): a regular file, found through symlinks, no larger than a
//! cap that is checked before a byte is read, read whole.
//!
//! Why not `std::fs::read`: it blocks for ever on a named pipe with no writer, reads a device
//! such as `/dev/zero` until memory runs out, and says "Is a directory (os error 21)" without
//! naming the path. Here the type is checked with `metadata` (which follows symlinks) before
//! opening; the open itself is non-blocking (`O_NONBLOCK`), so that a FIFO swapped in between
//! the check and the open cannot block it either, and the opened handle is checked again; the
//! size is checked against the cap from that handle, and the read stops one byte past the cap
//! in case the file grows meanwhile.
//!
//! ```
//! use reframe::util::input::read_input;
//! let dir = tempfile::tempdir()?;
//! let p = dir.path().join("a.obj");
//! std::fs::write(&p, "v 0 0 0\n")?;
//! assert_eq!(read_input(&p, "OBJ", 1 << 20)?, b"v 0 0 0\n");
//! let e = read_input(dir.path(), "OBJ", 1 << 20).unwrap_err().to_string();
//! assert!(e.ends_with("is a directory, not a regular file"), "{e}");
//! # anyhow::Ok(())
//! ```
use anyhow::Result;
use std::fs::{File, FileType};
use std::io::{ErrorKind, Read};
use std::os::unix::fs::FileTypeExt;
use std::path::{Path, PathBuf};

/// The largest scene TOML, OBJ or MTL file reframe reads (1 GiB): a larger one is refused before
/// it is read, rather than filling memory.
pub const MAX_INPUT_BYTES: u64 = 1 << 30;

/// Why an input could not be read: it is not there (a caller may go on without it), or it
/// cannot be used (the message says why).
#[derive(Debug)]
pub enum InputError {
    /// No file at the path (nor at the end of its symlinks).
    NotFound(String),
    Refused(String),
}

impl std::fmt::Display for InputError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            InputError::NotFound(m) | InputError::Refused(m) => f.write_str(m),
        }
    }
}

impl std::error::Error for InputError {}

/// What a file of type `t` is, in words.
pub fn kind(t: FileType) -> &'static str {
    if t.is_file() {
        "a file"
    } else if t.is_dir() {
        "a directory"
    } else if t.is_fifo() {
        "a named pipe (FIFO)"
    } else if t.is_socket() {
        "a socket"
    } else if t.is_char_device() {
        "a character device"
    } else if t.is_block_device() {
        "a block device"
    } else {
        "not a regular file"
    }
}

/// For the message of a missing `path`: the names in its folder that differ from its name
/// only in case or in how its accented letters are composed (a scene written on Windows or
/// macOS, which ignore case, naming `Tree.OBJ` for `tree.obj`; an `Ö` typed as one character,
/// stored by macOS as `O` and its accent), each said a folder where it is one; or, for a name
/// written with `\` (a Windows path), the path with `/` where that is there. Said, not taken:
/// which one was meant is the user's to say. Empty where there is none, or the folder cannot
/// be read or is too large to look through.
pub fn other_case(path: &Path) -> String {
    use crate::util::text::folded;
    use unicode_normalization::UnicodeNormalization;
    const MOST_ENTRIES: usize = 100_000;
    let Some(written) = path.to_str() else {
        return String::new();
    };
    if written.contains('\\') {
        let slashed = PathBuf::from(written.replace('\\', "/"));
        if slashed.exists() {
            return format!(
                " ('{}' is there: write '/' between folders)",
                slashed.display()
            );
        }
    }
    let (Some(name), Some(dir)) = (path.file_name().and_then(|n| n.to_str()), path.parent()) else {
        return String::new();
    };
    let dir = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    };
    let Ok(entries) = std::fs::read_dir(dir) else {
        return String::new();
    };
    let wanted = folded(name);
    let mut found: Vec<(String, bool)> = entries
        .take(MOST_ENTRIES)
        .filter_map(|e| {
            let e = e.ok()?;
            let n = e.file_name().into_string().ok()?;
            (n != name && folded(&n) == wanted).then(|| {
                let folder = e.file_type().is_ok_and(|t| t.is_dir());
                let composed = n.nfc().eq(name.nfc());
                (
                    format!("'{n}'{}", if folder { ", a folder," } else { "" }),
                    composed,
                )
            })
        })
        .collect();
    found.sort();
    match found.as_slice() {
        [] => String::new(),
        [(one, true)] => format!(" ({one} is there, its accented letters composed otherwise)"),
        [(one, false)] => format!(" ({one} is there, in another case)"),
        many => {
            let names: Vec<&str> = many.iter().map(|(n, _)| n.as_str()).collect();
            format!(" ({} are there, written otherwise)", names.join(", "))
        }
    }
}

/// Open the regular file at `path` for reading, as `read_input` does, without reading it (for
/// files read piece by piece, such as state files).
pub fn open_input(path: &Path, what: &str, max_bytes: u64) -> Result<File> {
    Ok(open_input_or_missing(path, what, max_bytes)?)
}

/// `open_input`, telling a missing file apart from one that cannot be used.
pub fn open_input_or_missing(path: &Path, what: &str, max_bytes: u64) -> Result<File, InputError> {
    let p = path.display();
    let refuse = |why: String| InputError::Refused(format!("{what} '{p}': {why}"));
    // No file's name holds one (the system's calls end a name there): said so, not as Rust's
    // "file name contained an unexpected NUL byte".
    if path.as_os_str().as_encoded_bytes().contains(&0) {
        return Err(refuse(
            "a file name cannot hold a NUL character (\\u{0} here)".into(),
        ));
    }
    let io = |e: std::io::Error| match e.kind() {
        ErrorKind::NotFound => InputError::NotFound(match path.symlink_metadata() {
            Ok(_) => format!("{what} '{p}': a symbolic link to nothing"),
            Err(_) => format!("{what} '{p}': no such file{}", other_case(path)),
        }),
        _ => refuse(format!("cannot read: {e}")),
    };
    // A regular file only, never blocking (`fs::open_regular`), then within the limit.
    let file = crate::util::fs::open_regular(path).map_err(|e| {
        if crate::util::fs::not_regular(&e) {
            refuse(e.to_string())
        } else {
            io(e)
        }
    })?;
    let len = file.metadata().map_err(io)?.len();
    if len > max_bytes {
        return Err(refuse(format!(
            "{len} bytes, over the limit of {max_bytes} bytes"
        )));
    }
    if lfs_pointer(&file, len) {
        return Err(refuse(
            "a Git LFS pointer, not the file itself (the repository was cloned without Git \
             LFS: run `git lfs pull` in it)"
                .into(),
        ));
    }
    Ok(file)
}

/// Whether `file` (of `len` bytes) is a Git LFS pointer: the few lines a repository holds in
/// place of a large file (`version https://git-lfs.github.com/spec/v1`, the object's hash and
/// size) where it was cloned without Git LFS. Read as an OBJ it had no faces; as a texture,
/// "Not a PNG file"; as an MTL, three unknown statements and grey materials.
fn lfs_pointer(file: &File, len: u64) -> bool {
    use std::os::unix::fs::FileExt;
    const HEAD: &[u8] = b"version https://git-lfs.github.com/spec/";
    // A pointer is about 130 bytes, never over 1 KB.
    if !(HEAD.len() as u64..=1024).contains(&len) {
        return false;
    }
    let mut head = [0u8; HEAD.len()];
    file.read_exact_at(&mut head, 0).is_ok() && head == HEAD
}

/// Read the regular file at `path` whole; `what` names it in messages ("scene file", "OBJ",
/// "MTL", "partial file"). Refuses, with one line naming the path, anything that is not a
/// regular file and any file larger than `max_bytes`.
pub fn read_input(path: &Path, what: &str, max_bytes: u64) -> Result<Vec<u8>> {
    Ok(read_input_or_missing(path, what, max_bytes)?)
}

/// `read_input`, telling a missing file apart from one that cannot be used.
pub fn read_input_or_missing(
    path: &Path,
    what: &str,
    max_bytes: u64,
) -> Result<Vec<u8>, InputError> {
    let p = path.display();
    let refuse = |why: String| InputError::Refused(format!("{what} '{p}': {why}"));
    let io = |e: std::io::Error| match e.kind() {
        ErrorKind::NotFound => {
            InputError::NotFound(format!("{what} '{p}': no such file{}", other_case(path)))
        }
        _ => refuse(format!("cannot read: {e}")),
    };
    let mut file = open_input_or_missing(path, what, max_bytes)?;
    let len = file.metadata().map_or(0, |m| m.len());
    // Reserved fallibly: an allocation that fails aborts the process (a 26 MB OBJ under a tight
    // `ulimit -v` ended in a backtrace, exit 134).
    let mut bytes = Vec::new();
    if bytes.try_reserve_exact(len as usize).is_err() {
        let left = crate::util::mem::available_bytes().map_or(String::new(), |a| {
            format!(" ({})", crate::util::mem::size(a))
        });
        return Err(refuse(format!(
            "its {} do not fit in the memory left{left}{}",
            crate::util::mem::size(len),
            crate::util::mem::address_space_note()
        )));
    }
    (&mut file)
        .take(max_bytes + 1)
        .read_to_end(&mut bytes)
        .map_err(io)?;
    if bytes.len() as u64 > max_bytes {
        return Err(refuse(format!(
            "grew past the limit of {max_bytes} bytes while it was read"
        )));
    }
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::{Duration, Instant};

    #[test]
    fn refuses_what_is_not_a_regular_file() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let e = read_input(d, "scene file", 100).unwrap_err().to_string();
        assert_eq!(
            e,
            format!(
                "scene file '{}': is a directory, not a regular file",
                d.display()
            )
        );
        let fifo = d.join("pipe.obj");
        let ok = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap();
        assert!(ok.success());
        let start = Instant::now();
        let e = read_input(&fifo, "OBJ", 100).unwrap_err().to_string();
        assert!(start.elapsed() < Duration::from_secs(1));
        assert!(
            e.ends_with("is a named pipe (FIFO), not a regular file"),
            "{e}"
        );
        let e = read_input(Path::new("/dev/null"), "MTL", 100)
            .unwrap_err()
            .to_string();
        assert!(e.contains("'/dev/null': is a character device"), "{e}");
    }

    #[test]
    fn size_is_capped_and_symlinks_followed() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("a.mtl");
        std::fs::write(&f, "0123456789").unwrap();
        let link = dir.path().join("b.mtl");
        std::os::unix::fs::symlink(&f, &link).unwrap();
        assert_eq!(read_input(&link, "MTL", 10).unwrap(), b"0123456789");
        let e = read_input(&f, "MTL", 9).unwrap_err().to_string();
        assert!(e.ends_with("10 bytes, over the limit of 9 bytes"), "{e}");
        let gone = dir.path().join("c.mtl");
        assert!(matches!(
            read_input_or_missing(&gone, "MTL", 9),
            Err(InputError::NotFound(_))
        ));
        // A dangling symlink is a missing file, said to be a link.
        std::os::unix::fs::symlink(&gone, dir.path().join("d.mtl")).unwrap();
        let e = read_input_or_missing(&dir.path().join("d.mtl"), "MTL", 9).unwrap_err();
        assert!(matches!(e, InputError::NotFound(_)));
        assert!(
            e.to_string()
                .ends_with("d.mtl': a symbolic link to nothing"),
            "{e}"
        );
    }

    #[test]
    fn a_missing_name_is_hinted_at_what_is_there_written_otherwise() {
        let tmp = tempfile::tempdir().unwrap();
        let t = tmp.path();
        std::fs::write(t.join("tree.obj"), b"").unwrap();
        // 'Ö' stored as 'O' and its combining accent.
        std::fs::write(t.join("O\u{308}l.obj"), b"").unwrap();
        std::fs::create_dir(t.join("rock.obj")).unwrap();
        std::fs::create_dir(t.join("models")).unwrap();
        std::fs::write(t.join("models/s.obj"), b"").unwrap();
        let hint = |n: &str| other_case(&t.join(n));
        assert_eq!(hint("Tree.OBJ"), " ('tree.obj' is there, in another case)");
        assert_eq!(
            hint("\u{d6}l.obj"),
            " ('O\u{308}l.obj' is there, its accented letters composed otherwise)"
        );
        assert_eq!(
            hint("ROCK.obj"),
            " ('rock.obj', a folder, is there, in another case)"
        );
        assert!(hint("models\\s.obj").contains("models/s.obj' is there: write '/'"));
        assert_eq!(hint("bush.obj"), "");
    }
}
