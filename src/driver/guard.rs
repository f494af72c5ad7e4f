//! What keeps a command from damaging what it should not touch: one command per output (an
//! exclusive advisory lock, `flock` through `std::fs::File::try_lock`, released by the kernel
//! when its holder dies, so no stale lock survives a SIGKILL), and inputs that are never outputs.
use crate::image::OutputPattern;
use crate::util::fs::{open_own_file, parent_dir, Temporary};
use anyhow::{anyhow, bail, Result};
use std::collections::HashMap;
use std::fs::File;
use std::io::{Read, Seek, Write};
use std::ops::RangeInclusive;
use std::os::unix::fs::MetadataExt;
use std::path::{Component, Path, PathBuf};

/// An exclusive lock on a lock file, held until dropped; the file (which holds the holder's pid)
/// is removed on release.
pub struct OutputLock {
    path: PathBuf,
    file: Option<File>,
    /// Registered once held, so that a stop by signal removes it too.
    _live: Temporary,
}

impl OutputLock {
    /// Take the lock `path` for `what` (an output, in messages), or refuse at once, naming the
    /// process that holds it. With `frames` (a render's or a merge's, `what` being their
    /// pattern), also refuse while another render holding a lock in the same folder writes a
    /// frame file of the same name under another pattern (`v_####.exr` and `v_0###.exr` both
    /// write `v_0012.exr`, and their locks differ).
    pub fn acquire(path: &Path, what: &str, frames: Option<Frames>) -> Result<OutputLock> {
        let lock = Self::acquire_file(path, what, frames.as_ref().map(|f| &f.frames))?;
        if let Some(ours) = frames {
            // On a refusal the lock goes again (its drop).
            check_other_patterns(path, &ours)?;
        }
        Ok(lock)
    }

    fn acquire_file(
        path: &Path,
        what: &str,
        frames: Option<&RangeInclusive<u32>>,
    ) -> Result<OutputLock> {
        loop {
            // Never through a symbolic link, never blocking on a FIFO, and only a regular file
            // of one name: a lock file planted as a link to another file (or a hard link of
            // one) would have that file's content replaced by a pid.
            let mut f = open_own_file(path, "the lock file")?;
            // Another process checking whether this lock is live holds it for a moment
            // (`check_other_patterns`): a few tries before refusing.
            let held = (0..5).all(|i| {
                if i > 0 {
                    std::thread::sleep(std::time::Duration::from_millis(20));
                }
                f.try_lock().is_err()
            });
            if held {
                // The holder's pid and what it writes (the first line and the rest): outputs of
                // one stem share a lock (`v_####.png` and `v_####.exr`), so it may be another
                // pattern than this command's. Read at most a line's worth of it.
                let mut held = String::new();
                let _ = (&mut f).take(4096).read_to_string(&mut held);
                let (pid, its) = held.split_once('\n').unwrap_or((&held, ""));
                let (pid, its) = (pid.trim(), its.trim());
                // The holder's pattern is its second line (a frames line may follow).
                let its_out = its.lines().next().unwrap_or("");
                let other = !its_out.is_empty() && its_out != what;
                bail!(
                    "another reframe{} is writing {} (its lock is {}{}): wait for it to finish, \
                     or stop it{}",
                    if pid.is_empty() {
                        String::new()
                    } else {
                        format!(" (pid {pid})")
                    },
                    if its.is_empty() { what } else { its },
                    path.display(),
                    if other {
                        format!(", {}", crate::state::key::shared_names(its_out, what))
                    } else {
                        String::new()
                    },
                    if other {
                        ", or give this command an --out of another name"
                    } else {
                        ""
                    }
                );
            }
            // A holder that finished removes the file after this process opened it: then this
            // lock is on a file nobody else will find, and it starts again.
            let same = match (f.metadata(), std::fs::metadata(path)) {
                (Ok(a), Ok(b)) => a.ino() == b.ino() && a.dev() == b.dev(),
                _ => false,
            };
            if !same {
                continue;
            }
            // In one write, so that a reader sees all of it or none. The frames line is last.
            let mut text = format!("{}\n{what}\n", std::process::id());
            if let Some(r) = frames {
                text += &format!("{FRAMES}{}-{}\n", r.start(), r.end());
            }
            let written = f
                .set_len(0)
                .and_then(|()| f.rewind())
                .and_then(|()| f.write_all(text.as_bytes()));
            if let Err(e) = written {
                // A full disk: named, and the lock file this process made not left behind.
                let _ = std::fs::remove_file(path);
                bail!("writing the lock file {}: {e}", path.display());
            }
            return Ok(OutputLock {
                path: path.to_path_buf(),
                file: Some(f),
                _live: Temporary::new(path),
            });
        }
    }
}

/// The lock of a folder a command writes into (`--checkpoint`): a hidden file beside it,
/// `.NAME.lock`, so that the folder itself is made only when its first file is.
pub fn folder_lock_path(dir: &Path) -> PathBuf {
    match (dir.file_name(), resolved(dir)) {
        (Some(n), _) => parent_dir(dir).join(format!(".{}.lock", n.to_string_lossy())),
        // `.`, `..`, `/`: beside the folder it resolves to, or in it.
        (None, Some(r)) => match (r.parent(), r.file_name()) {
            (Some(p), Some(n)) => p.join(format!(".{}.lock", n.to_string_lossy())),
            _ => r.join(".checkpoint.lock"),
        },
        (None, None) => dir.join(".checkpoint.lock"),
    }
}

/// The frames a lock's holder writes: `frames` of `pattern`.
pub struct Frames<'a> {
    pub pattern: &'a OutputPattern,
    pub frames: RangeInclusive<u32>,
}

/// How a lock file names its holder's frames, on its last line.
const FRAMES: &str = "frames ";

/// Refuse if another live lock in the folder of the lock `ours_lock` is held by a render whose
/// frame files include one of `ours`'.
fn check_other_patterns(ours_lock: &Path, ours: &Frames) -> Result<()> {
    let Some(((mine, its), holder)) = live_frames_lock(ours_lock, |pattern, theirs| {
        shared_frame(ours, pattern, theirs)
    }) else {
        return Ok(());
    };
    let file = ours.pattern.path(mine);
    bail!(
        "{}, and its frame {its} is {}, frame {mine} of this command's {}: wait for it to \
         finish, or write to other names",
        holder,
        file.file_name()
            .map_or(file.as_os_str(), |n| n)
            .to_string_lossy(),
        ours.pattern
    );
}

/// Refuse a report (`flag`: `--stats`, `--json`) at `path` when a live lock in its folder is
/// held by a render one of whose frames has that name: the report would replace a frame that
/// render wrote, or be replaced by it.
fn check_report_apart(flag: &str, path: &Path) -> Result<()> {
    let Some(name) = path.file_name().map(|n| n.to_string_lossy().into_owned()) else {
        return Ok(());
    };
    let Some((its, holder)) = live_frames_lock(path, |pattern, theirs| {
        let its = if pattern.has_frame_field() {
            pattern.frame_named(&name)?
        } else {
            let literal = pattern.path(*theirs.start());
            (literal.file_name()?.to_string_lossy() == name).then_some(*theirs.start())?
        };
        theirs.contains(&its).then_some(its)
    }) else {
        return Ok(());
    };
    bail!(
        "{flag} {}: {holder}, and {name} is its frame {its}; nothing was written",
        path.display()
    );
}

/// Refuse a report (`flag`) at `path` where a run keeps its state: a name a chunk gives its
/// partial file or its log (`NAME.chunk-K-of-N.partial`, `.partial.log`, which a running chunk
/// renames into place at its end, whatever then sits there), or a file in the checkpoint folder
/// of a running render (its lock, `.NAME.lock` beside the folder, is held).
fn check_report_off_state(flag: &str, path: &Path) -> Result<()> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    if name.ends_with(".partial") || name.ends_with(".partial.log") {
        bail!(
            "{flag} {}: that is named as a chunk's partial file or its log, which a report must \
             not replace; nothing was written",
            path.display()
        );
    }
    let dir = parent_dir(path);
    let lock = folder_lock_path(&dir);
    if let Some(pid) = held_by(&lock) {
        bail!(
            "{flag} {}: that folder is the checkpoint folder of a running reframe (pid {pid}, \
             its lock is {}), which a report must not write into; nothing was written",
            path.display(),
            lock.display()
        );
    }
    Ok(())
}

/// The pid written in lock file `lock` where a live process holds it; `None` where it does
/// not exist, cannot be read, or nobody holds it.
fn held_by(lock: &Path) -> Option<String> {
    let (f, text) = read_lock(lock)?;
    is_held(&f).then(|| text.lines().next().unwrap_or("?").to_string())
}

/// Lock file `path` opened (not followed if a link, not waited on if a FIFO) and its text
/// (empty where it cannot be read as text): `None` where it is missing or not a regular file.
fn read_lock(path: &Path) -> Option<(File, String)> {
    use std::os::unix::fs::OpenOptionsExt;
    let mut f = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK)
        .open(path)
        .ok()?;
    if !f.metadata().ok()?.is_file() {
        return None;
    }
    let mut text = String::new();
    if (&mut f).take(1 << 16).read_to_string(&mut text).is_err() {
        text.clear();
    }
    Some((f, text))
}

/// Whether a live process holds lock file `f`: a moment's lock here to find out.
fn is_held(f: &File) -> bool {
    if f.try_lock().is_ok() {
        let _ = f.unlock();
        return false;
    }
    true
}

/// Whether `path` is named as the lock files of outputs, checkpoint folders, chunks, `compare`
/// and the reference cache are: `.NAME.lock`.
fn is_lock_name(path: &Path) -> bool {
    path.file_name()
        .map(|n| n.to_string_lossy())
        .is_some_and(|n| n.len() > ".lock".len() && n.starts_with('.') && n.ends_with(".lock"))
}

/// The first lock file in the folder of `beside` (other than `beside` itself, where that is a
/// lock) that is held by a live process writing frames, and for which `matches` (given the
/// holder's pattern and frames) says something: that, and a clause naming the holder. Lock
/// files without a frames line (a chunk's, `compare`'s), unreadable ones and ones nobody holds
/// (their holder was killed) are passed over.
fn live_frames_lock<T>(
    beside: &Path,
    mut matches: impl FnMut(&OutputPattern, &RangeInclusive<u32>) -> Option<T>,
) -> Option<(T, String)> {
    let entries = std::fs::read_dir(parent_dir(beside)).ok()?;
    let own_name = beside.file_name();
    for e in entries.flatten() {
        let name = e.file_name();
        if !is_lock_name(Path::new(&name))
            || Some(name.as_os_str()) == own_name
            || !e.file_type().is_ok_and(|t| t.is_file())
        {
            continue;
        }
        let Some((f, text)) = read_lock(&e.path()) else {
            continue;
        };
        let Some((pid, what, theirs)) = parse_holder(&text) else {
            continue;
        };
        let Ok(pattern) = OutputPattern::parse(what) else {
            continue;
        };
        let Some(found) = matches(&pattern, &theirs) else {
            continue;
        };
        if !is_held(&f) {
            continue;
        }
        let holder = format!(
            "another reframe (pid {pid}) is writing frames {}-{} of {what} (its lock is {})",
            theirs.start(),
            theirs.end(),
            e.path().display()
        );
        return Some((found, holder));
    }
    None
}

/// A lock file's holder: its pid, what it writes and its frames (`None` without a frames line).
fn parse_holder(text: &str) -> Option<(&str, &str, RangeInclusive<u32>)> {
    let (head, last) = text.strip_suffix('\n')?.rsplit_once('\n')?;
    let (a, b) = last.strip_prefix(FRAMES)?.split_once('-')?;
    let (pid, what) = head.split_once('\n')?;
    Some((pid, what, a.parse().ok()?..=b.parse().ok()?))
}

/// A frame of `ours` whose file has the name of frame `its` of `theirs`, within `their_frames`:
/// `(ours, its)`, or `None`. The names compared are file names; the folder is the same (the
/// locks are beside their frames).
fn shared_frame(
    ours: &Frames,
    theirs: &OutputPattern,
    their_frames: &RangeInclusive<u32>,
) -> Option<(u32, u32)> {
    let name = |p: &OutputPattern, f: u32| {
        p.path(f)
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
    };
    let literal = (!theirs.has_frame_field())
        .then(|| name(theirs, *their_frames.start()))
        .flatten();
    ours.frames.clone().find_map(|f| {
        let n = name(ours.pattern, f)?;
        let its = match &literal {
            Some(l) => (*l == n).then_some(*their_frames.start())?,
            None => theirs.frame_named(&n)?,
        };
        their_frames.contains(&its).then_some((f, its))
    })
}

impl Drop for OutputLock {
    fn drop(&mut self) {
        // Removed while still held, so that nobody locks the file being removed unseen.
        let _ = std::fs::remove_file(&self.path);
        self.file.take();
    }
}

/// `p` as it will resolve once written: its folder canonicalised (symlinks, `..`), its name
/// kept. `None` if the folder does not exist.
pub fn resolved(p: &Path) -> Option<PathBuf> {
    if let Ok(c) = p.canonicalize() {
        return Some(c);
    }
    let dir = parent_dir(p).canonicalize().ok()?;
    Some(dir.join(p.file_name()?))
}

/// `resolved` for many paths, most in a few folders (a shot's frames): each folder is
/// canonicalised once, and a path costs one `lstat` (a chunk of a shot of 10^6 frames took 21
/// s to check the merge's outputs, each canonicalised whole, a `readlink` per component).
#[derive(Default)]
pub struct Resolver {
    folders: HashMap<PathBuf, Option<PathBuf>>,
}

impl Resolver {
    /// What `resolved(p)` gives.
    pub fn resolve(&mut self, p: &Path) -> Option<PathBuf> {
        let name = match p.file_name() {
            // `..` and the like: as `resolved` finds them.
            Some(n) if !matches!(p.components().next_back(), Some(Component::ParentDir)) => n,
            _ => return resolved(p),
        };
        let folder = parent_dir(p);
        let dir = self
            .folders
            .entry(folder)
            .or_insert_with_key(|f| f.canonicalize().ok())
            .as_ref()?;
        let path = dir.join(name);
        match std::fs::symlink_metadata(&path) {
            // A link: where it leads, or (leading nowhere) where it is.
            Ok(m) if m.file_type().is_symlink() => Some(path.canonicalize().unwrap_or(path)),
            _ => Some(path),
        }
    }
}

/// Refuse a folder a command creates (`flag`: `--checkpoint` where it was given, else what it
/// is) at the path of one of its `outputs` (a checkpoint named like a later frame made that
/// frame's write fail at its turn).
pub fn check_folder_apart(flag: &str, dir: &Path, outputs: &[(&str, PathBuf)]) -> Result<()> {
    // Where a path is or will be: resolved where its folder exists, else as written, absolute.
    let place = |p: &Path| resolved(p).or_else(|| std::path::absolute(p).ok());
    let Some(d) = place(dir) else {
        return Ok(());
    };
    let mut resolver = Resolver::default();
    if let Some((other, out)) = outputs
        .iter()
        .find(|(_, o)| resolver.resolve(o).as_ref() == Some(&d))
    {
        bail!(
            "{flag} {}: that is also where {other} {} goes; nothing was written",
            dir.display(),
            out.display()
        );
    }
    // A report inside the folder: the folder (a checkpoint) is removed when the run completes,
    // and the report, written last, found no folder after the work was done.
    if let Some((other, out)) = outputs.iter().find(|(f, o)| {
        matches!(*f, "--stats" | "--json") && place(&parent_dir(o)).as_ref() == Some(&d)
    }) {
        bail!(
            "{other} {}: that is inside {flag} {}, which holds the render's \
             checkpoint and is removed when the render completes if reframe made it; put the \
             report elsewhere; nothing was written",
            out.display(),
            dir.display()
        );
    }
    Ok(())
}

/// Refuse, before anything is written, any output of a command (`flag`, the path) that
/// resolves to one of its `inputs`, that resolves to another of its outputs (`--stats` naming a
/// frame, say), or that exists as anything but a regular file (`check_replaceable`: a device,
/// a FIFO or a symbolic link would be replaced, not written through), or that is a report
/// (`--stats`, `--json`) naming an existing state file (another chunk's partial, say).
pub fn check_outputs<'a>(
    outputs: impl IntoIterator<Item = (&'a str, PathBuf)>,
    inputs: &[PathBuf],
) -> Result<()> {
    let inputs: Vec<(PathBuf, &PathBuf)> = inputs
        .iter()
        .filter_map(|p| Some((p.canonicalize().ok()?, p)))
        .collect();
    let mut seen: HashMap<PathBuf, (&str, PathBuf)> = HashMap::new();
    let mut resolver = Resolver::default();
    for (flag, out) in outputs {
        // A lock is a file of reframe's own, opened, not renamed into place: what is in its
        // way is to go (the frames' explanation of a rename misled there).
        if flag.starts_with("the lock") {
            if let Some(what) = crate::util::fs::in_the_way(&out) {
                bail!(
                    "{flag} {} is {what}, not a lock file: remove it (reframe makes its lock \
                     files, and removes them when the command ends); nothing was written",
                    out.display()
                );
            }
        }
        crate::util::fs::check_replaceable(&out)
            .map_err(|e| anyhow!("{flag} {e}; nothing was written"))?;
        // A report (--stats, bench's --json) is never written over a run's state, nor over a
        // frame that a running render writes.
        if matches!(flag, "--stats" | "--json") {
            if is_lock_name(&out) {
                bail!(
                    "{flag} {}: that is named as a reframe lock file (.NAME.lock), which a \
                     report must not replace (a running command's lock replaced lets a second \
                     command write its outputs beside it); nothing was written",
                    out.display()
                );
            }
            if crate::state::is_state_file(&out) {
                bail!(
                    "{flag} {}: that is a reframe state file (a checkpoint or a chunk's \
                     partial), which a report must not replace; nothing was written",
                    out.display()
                );
            }
            check_report_apart(flag, &out)?;
            check_report_off_state(flag, &out)?;
        }
        let Some(r) = resolver.resolve(&out) else {
            continue;
        };
        if let Some((_, input)) = inputs.iter().find(|(c, _)| *c == r) {
            bail!(
                "{flag} {}: that is an input of this command ({}); nothing was written",
                out.display(),
                input.display()
            );
        }
        if matches!(flag, "--stats" | "--json") {
            crate::util::fs::check_report_target(flag, &out)?;
        }
        if let Some((other_flag, other)) = seen.get(&r) {
            bail!(
                "{flag} {}: that is also where {other_flag} {} goes; one of them would \
                 overwrite the other, so nothing was written",
                out.display(),
                other.display()
            );
        }
        seen.insert(r, (flag, out));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_resolver_finds_what_resolved_finds() {
        let tmp = tempfile::tempdir().unwrap();
        let t = tmp.path();
        std::fs::create_dir(t.join("real")).unwrap();
        std::fs::write(t.join("real/f_0001.exr"), b"x").unwrap();
        std::os::unix::fs::symlink(t.join("real"), t.join("linked")).unwrap();
        std::os::unix::fs::symlink(t.join("real/f_0001.exr"), t.join("real/f_0002.exr")).unwrap();
        std::os::unix::fs::symlink(t.join("nowhere"), t.join("real/f_0003.exr")).unwrap();
        let paths = [
            "real/f_0001.exr",
            "real/f_0002.exr",
            "real/f_0003.exr",
            "real/f_0004.exr",
            "linked/f_0001.exr",
            "linked/f_0002.exr",
            "linked/../real/f_0004.exr",
            "real/..",
            "real/.",
            "missing/f_0001.exr",
            "real",
        ];
        let mut resolver = Resolver::default();
        for _ in 0..2 {
            for p in paths {
                let p = t.join(p);
                assert_eq!(resolver.resolve(&p), resolved(&p), "{}", p.display());
            }
        }
        assert_eq!(
            resolver.resolve(&t.join("linked/f_0002.exr")),
            Some(t.canonicalize().unwrap().join("real/f_0001.exr"))
        );
    }
}
