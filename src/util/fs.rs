//! Files written so that a crash never leaves half of one: a temporary name in the same folder,
//! then a rename; the temporary names a killed process leaves behind, and how to clear them;
//! the files a stop by signal removes before it exits (`Temporary`, `exit_removing_temporaries`);
//! and the checks made before a long run that it will be able to write at its end.
use anyhow::{anyhow, Context, Result};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard};

/// The temporary and lock files of this process that exist (or are about to) and are not yet
/// renamed into place or removed.
static LIVE: Mutex<Vec<(u64, PathBuf)>> = Mutex::new(Vec::new());

fn live() -> MutexGuard<'static, Vec<(u64, PathBuf)>> {
    LIVE.lock().unwrap_or_else(|e| e.into_inner())
}

/// A file this process is writing under a temporary name (or holds as a lock, or a folder it
/// created that must not outlive a stop while still empty), registered
/// before the file is created and until the guard is dropped (after the rename), so that a
/// stop by signal at any moment can remove it (`exit_removing_temporaries`).
pub struct Temporary(u64);

impl Temporary {
    pub fn new(path: &Path) -> Temporary {
        let id = unique();
        live().push((id, path.to_path_buf()));
        Temporary(id)
    }
}

impl Drop for Temporary {
    fn drop(&mut self) {
        live().retain(|(id, _)| *id != self.0);
    }
}

/// Make `path` with `create` (a file, a folder) and register it as a `Temporary`, both while
/// the registry is locked. A stop by signal holds the registry from its start until the
/// process is gone, so it either finds what was made and removes it, or keeps it from being
/// made. Registering first and creating after left a frame's temporary file behind when the
/// stop's removals ran in between (2 of 220 renders stopped by two quick interrupts).
pub fn create_registered<T>(
    path: &Path,
    create: impl FnOnce(&Path) -> std::io::Result<T>,
) -> std::io::Result<(Temporary, T)> {
    let mut files = live();
    let made = create(path)?;
    let id = unique();
    files.push((id, path.to_path_buf()));
    Ok((Temporary(id), made))
}

/// Run `f` holding the registry: a stop by signal, which holds it from before its line until
/// the process is gone, sees all that `f` did or none of it (a frame renamed into place and the
/// stop note that counts it).
pub fn holding_registry<T>(f: impl FnOnce() -> T) -> T {
    let _files = live();
    f()
}

/// `create_registered` for a new, empty file: one already there is an error.
pub fn create_temporary(path: &Path) -> std::io::Result<(Temporary, std::fs::File)> {
    create_registered(path, |p| {
        std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(p)
    })
}

/// A folder this process created: registered as a `Temporary` (a stop by signal removes it while
/// it is empty) and removed when dropped if it is still empty, so that an error before anything
/// was written in it (a full disk) leaves no empty folder behind either.
pub struct MadeFolder {
    path: PathBuf,
    _live: Temporary,
}

impl MadeFolder {
    /// Make the folder `path` (and its parents) and register it.
    pub fn create(path: &Path) -> std::io::Result<MadeFolder> {
        let (live, ()) = create_registered(path, create_dir_all)?;
        Ok(MadeFolder {
            path: path.to_path_buf(),
            _live: live,
        })
    }
}

impl Drop for MadeFolder {
    fn drop(&mut self) {
        // Fails, and keeps the folder, when anything is in it.
        let _ = std::fs::remove_dir(&self.path);
    }
}

/// A line of what is in place so far (the frames written), which a stop by signal adds to its
/// message.
static STOP_NOTE: Mutex<Option<String>> = Mutex::new(None);

/// Set what a stop by signal says is in place (`stop_note`).
pub fn set_stop_note(note: String) {
    *STOP_NOTE.lock().unwrap_or_else(|e| e.into_inner()) = Some(note);
}

/// What a stop by signal says is in place, if anything was set and no thread is setting it.
pub fn stop_note() -> Option<String> {
    STOP_NOTE.try_lock().ok().and_then(|n| n.clone())
}

/// Whether a checkpoint of this render is on disk (written by this process, or the one it
/// resumed from), for what a stop at once says.
static CHECKPOINT_IN_PLACE: AtomicBool = AtomicBool::new(false);

/// Whether a checkpoint of this render is on disk (`checkpoint_in_place`): set as one is
/// written or resumed from, cleared as a finished render removes it.
pub fn set_checkpoint_in_place(there: bool) {
    CHECKPOINT_IN_PLACE.store(there, Ordering::SeqCst);
}

/// Whether a checkpoint of this render is on disk: a stop at once keeps it, and says whether
/// there is one (it said "a checkpoint already written is kept" before the first).
pub fn checkpoint_in_place() -> bool {
    CHECKPOINT_IN_PLACE.load(Ordering::SeqCst)
}

static STOPPING: AtomicBool = AtomicBool::new(false);

/// Whether a stop by signal has begun: an error another thread meets now (a temporary file
/// removed under it) is that stop's doing, not worth a line of its own.
pub fn stopping() -> bool {
    STOPPING.load(Ordering::SeqCst)
}

/// Exit with `code`, unless a stop by signal has begun (then that stop's exit is the one that
/// happens): two threads must not run the process's exit at once, and the status must be the
/// one that was printed.
pub fn exit_with(code: i32) -> ! {
    let _files = live();
    std::process::exit(code)
}

/// Remove every registered temporary file and exit with `code`, after `say` (the stop's line)
/// has run. The registry stays locked until the process is gone, so no other thread can
/// register (and then create) a new one in between; a writer that has the file open loses
/// it, which is the point. `say` runs once the registry is held: where the command's own end
/// holds it first (`exit_with`, the work done), that end is the one that happens and the stop
/// says nothing (a merge stopped as it ended had said "interrupted" and exited 0).
pub fn exit_removing_temporaries(code: i32, say: impl FnOnce()) -> ! {
    // The registry first: set before it, `stopping` let the main thread take an error of its
    // own for this stop's doing and exit 130 with neither line said. Errors a stop causes come
    // from its removals, which follow.
    let files = live();
    STOPPING.store(true, Ordering::SeqCst);
    say();
    // Newest first, so that a folder registered before the files in it (a checkpoint folder
    // this process created) is tried once they are gone; only an empty folder is removed.
    for (_, p) in files.iter().rev() {
        if std::fs::remove_file(p).is_err() {
            let _ = std::fs::remove_dir(p);
        }
    }
    // Other threads are still rendering inside Embree and OpenImageIO: no exit handler may run
    // under them (see `sys`).
    crate::sys::exit_now(code)
}

/// Remove the folders this process made that are still registered and empty (an output folder
/// kept by `CreatedDirs::keep`), newest first: a command that ends in an error after it made
/// them (a merge whose first frame could not be written, a full disk) leaves none behind.
/// Files are left alone: their guards remove them.
pub fn remove_empty_made_folders() {
    let files = live();
    for (_, p) in files.iter().rev() {
        if std::fs::symlink_metadata(p).is_ok_and(|m| m.is_dir()) {
            let _ = std::fs::remove_dir(p);
        }
    }
}

/// The folder of `path`, `.` for a bare file name.
pub fn parent_dir(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Distinguishes temporary and probe files of concurrent writers within this process (the pid
/// distinguishes processes).
pub fn unique() -> u64 {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    COUNTER.fetch_add(1, Ordering::Relaxed)
}

/// Folders this process created for an output, removed again (deepest first, each only if still
/// empty) when the guard is dropped, unless `keep` was called first: a command refused after
/// it created its output folder leaves no folder behind. Each is registered as a `Temporary`
/// for as long as the process runs, kept or not, so that a stop by signal before anything was
/// written in it removes it too (an interrupted `compare` left its empty output folder).
#[must_use = "dropping it removes the folders again"]
pub struct CreatedDirs(Vec<(PathBuf, Temporary)>);

impl std::fmt::Debug for CreatedDirs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list()
            .entries(self.0.iter().map(|(p, _)| p))
            .finish()
    }
}

impl CreatedDirs {
    /// Create `dir` and its missing parents, registered while the registry is locked (as
    /// `create_registered` does). Only the folders this call made are its own: one that
    /// another process made in the meantime (two renders into one new folder) is neither
    /// registered nor removed again, and where a folder cannot be made, those made before it
    /// are removed.
    pub fn create(dir: &Path) -> std::io::Result<CreatedDirs> {
        let mut missing = Vec::new();
        let mut d = Some(dir);
        while let Some(p) = d.filter(|p| !p.as_os_str().is_empty() && !p.exists()) {
            missing.push(p.to_path_buf());
            d = p.parent();
        }
        let mut files = live();
        let mut made = CreatedDirs(Vec::new());
        // Outermost first, each registered as it is made: a stop goes newest first, so it
        // tries the deepest first.
        for p in missing.into_iter().rev() {
            match std::fs::create_dir(&p) {
                Ok(()) => {
                    let id = unique();
                    files.push((id, p.clone()));
                    made.0.push((p, Temporary(id)));
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && p.is_dir() => {}
                Err(e) => {
                    // Those made are removed as `made` drops, deepest first, after the
                    // registry is unlocked; the error is named as `create_dir_all` names it.
                    drop(files);
                    made.0.reverse();
                    return Err(match not_a_folder(dir) {
                        Some(why) => std::io::Error::new(e.kind(), why),
                        None => e,
                    });
                }
            }
        }
        drop(files);
        made.0.reverse();
        // A part of the path that is there but is no folder (a file, a link to nothing): the
        // error that names it.
        create_dir_all(dir)?;
        Ok(made)
    }

    /// The command goes ahead: the folders stay (a stop by signal still removes those that
    /// are empty).
    pub fn keep(mut self) {
        for (_, live) in self.0.drain(..) {
            std::mem::forget(live);
        }
    }
}

impl Drop for CreatedDirs {
    fn drop(&mut self) {
        for (d, _) in &self.0 {
            let _ = std::fs::remove_dir(d);
        }
    }
}

/// `std::fs::create_dir_all`, whose error names the part of the path that is a file (or
/// another thing that is not a folder) where one is: the system's "File exists" named none
/// (`--out s.obj/f_####.exr`, `s.obj` a file, said "cannot create output folder s.obj: File
/// exists").
pub fn create_dir_all(dir: &Path) -> std::io::Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| match not_a_folder(dir) {
        Some(why) => std::io::Error::new(e.kind(), why),
        None => e,
    })
}

/// The first part of `path` (from the root down, `path` itself included) that exists and is not
/// a folder, said as such (`s.obj is a file, not a folder`): why a folder cannot be made there,
/// or a file cannot be opened below it (the system's "File exists" and "Not a directory" named
/// no part).
pub fn not_a_folder(path: &Path) -> Option<String> {
    let mut parts: Vec<&Path> = path.ancestors().collect();
    parts.reverse();
    parts.into_iter().find_map(|p| {
        if p.as_os_str().is_empty() {
            return None;
        }
        let m = match std::fs::metadata(p) {
            Ok(m) => m,
            // A link that leads nowhere: making the folder said only "File exists".
            Err(_) if std::fs::symlink_metadata(p).is_ok_and(|l| l.is_symlink()) => {
                return Some(format!("{} is a symbolic link to nothing", p.display()));
            }
            Err(_) => return None,
        };
        (!m.is_dir()).then(|| {
            let what = crate::util::input::kind(m.file_type());
            format!("{} is {what}, not a folder", p.display())
        })
    })
}

/// Fail unless a file can be created (and removed) in `dir`: creates and deletes a probe file.
pub fn check_writable_dir(dir: &Path) -> Result<()> {
    let probe = dir.join(format!(
        ".reframe-probe-{}-{}",
        std::process::id(),
        unique()
    ));
    let _live = create_temporary(&probe).map_err(|e| {
        // A folder the system keeps (`/proc`, `/sys`) refuses new files with "not found",
        // which read as if the folder were missing.
        let why = if e.kind() == std::io::ErrorKind::NotFound && dir.is_dir() {
            format!("the system makes no new files there ({e})")
        } else {
            e.to_string()
        };
        anyhow!("cannot create files in folder {}: {why}", dir.display())
    })?;
    std::fs::remove_file(&probe)
        .map_err(|e| anyhow!("cannot delete probe file {}: {e}", probe.display()))?;
    Ok(())
}

/// The temporary name `p` is written under before it is renamed into place (the `.tmp-PID`
/// suffix that `remove_stale_tmp` recognises).
pub fn tmp_name(p: &Path) -> PathBuf {
    let mut name = p.file_name().unwrap_or_default().to_os_string();
    name.push(format!(".tmp-{}", std::process::id()));
    p.with_file_name(name)
}

/// Remove the temporary files a killed process left in `dir` (`NAME.tmp-PID...` or
/// `.NAME.tmp-PID...`) whose `NAME` passes `ours`; never one whose `PID` is a process that
/// runs (another render writing that file now, on this machine). Returns how many it removed.
pub fn remove_stale_tmp(dir: &Path, ours: impl Fn(&str) -> bool) -> usize {
    let mut removed = 0;
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if let Some((base, rest)) = name.split_once(".tmp-") {
            // Only the names reframe writes: `NAME.tmp-PID` (`tmp_name`) and a frame's
            // `.NAME.tmp-PID-N.ext`; a user's `state.tmp-notes`, `state.tmp-2024-notes` or
            // `state.tmp-17.bak` is not one of them.
            let digits = rest
                .split(|c: char| !c.is_ascii_digit())
                .next()
                .unwrap_or("");
            let after = &rest[digits.len()..];
            let counter = after
                .strip_prefix('-')
                .map(|a| a.split('.').next().unwrap_or(""));
            let ours_shape = after.is_empty()
                || counter.is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()));
            let Some(pid) = digits.parse::<i32>().ok().filter(|_| ours_shape) else {
                continue;
            };
            let running =
                pid != std::process::id() as i32 && Path::new(&format!("/proc/{pid}")).exists();
            if ours(base.strip_prefix('.').unwrap_or(base)) && !running {
                removed += usize::from(std::fs::remove_file(e.path()).is_ok());
            }
        }
    }
    removed
}

/// Open the file at `p` (through any links) for reading, never blocking: a named pipe put in
/// a file's place (opening one for reading waits for a writer) or a device (`/dev/zero` reads
/// without end) is an error that says what it is (`is a named pipe (FIFO), not a regular
/// file`; `not_regular` tells it apart); a missing file is `NotFound`, as `File::open` says it.
/// Every input that reframe opens itself is opened here (`util::input::open_input`).
pub fn open_regular(p: &Path) -> std::io::Result<std::fs::File> {
    use std::os::unix::fs::OpenOptionsExt;
    let refuse = |t: std::fs::FileType| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("is {}, not a regular file", super::input::kind(t)),
        )
    };
    // Looked at before it is opened (opening a device may act on it: a serial line, a tape),
    // and again after, in case something else took its place in between.
    let t = std::fs::metadata(p)?.file_type();
    if !t.is_file() {
        return Err(refuse(t));
    }
    let f = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(p)?;
    let t = f.metadata()?.file_type();
    if !t.is_file() {
        return Err(refuse(t));
    }
    Ok(f)
}

/// Whether `e` is `open_regular`'s refusal of a file that is not a regular file (its own
/// error, not the system's).
pub fn not_regular(e: &std::io::Error) -> bool {
    e.kind() == std::io::ErrorKind::InvalidInput && e.raw_os_error().is_none()
}

/// The file at `p` (after symbolic links) as the system tells files apart: its device and
/// inode, the same under every name it has; `None` where it cannot be read.
pub fn file_id(p: &Path) -> Option<(u64, u64)> {
    use std::os::unix::fs::MetadataExt;
    let m = std::fs::metadata(p).ok()?;
    Some((m.dev(), m.ino()))
}

/// What is at `p` where that is anything but a regular file, in words ("a symbolic link", "a
/// directory", "a named pipe (FIFO)", ...; a link is not followed); `None` where nothing is
/// there or a regular file is. An output (`check_replaceable`) or a lock file
/// (`driver::guard::check_outputs`) cannot go where this says something is.
pub fn in_the_way(p: &Path) -> Option<&'static str> {
    let t = std::fs::symlink_metadata(p).ok()?.file_type();
    if t.is_file() {
        None
    } else if t.is_symlink() {
        Some("a symbolic link")
    } else {
        Some(super::input::kind(t))
    }
}

/// Fail if `p` exists as anything but a regular file. Outputs are written under a temporary name
/// and renamed into place, and a rename replaces what is there: a device (`/dev/null`), a FIFO,
/// a socket or a symbolic link would be replaced by a plain file, not written through.
pub fn check_replaceable(p: &Path) -> Result<()> {
    let Some(what) = in_the_way(p) else {
        return Ok(());
    };
    anyhow::bail!(
        "{} is {what}: reframe writes a new file and renames it into place, which would replace \
         it, not write through it",
        p.display()
    )
}

/// Write a file atomically: a temporary name in the same folder, then a rename (never over
/// anything but a regular file, `check_replaceable`). The temporary file is removed if either
/// step fails.
pub fn write_atomic(p: &Path, bytes: &[u8]) -> Result<()> {
    check_replaceable(p)?;
    let tmp = tmp_name(p);
    // Synced before the rename: a failed write or flush (a full disk, a quota) is an error here,
    // not a short file in place.
    let written =
        create_registered(&tmp, |p| std::fs::File::create(p)).and_then(|(live, mut f)| {
            std::io::Write::write_all(&mut f, bytes).and_then(|()| f.sync_all())?;
            Ok(live)
        });
    let _live = match written {
        Ok(live) => live,
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            return Err(e).with_context(|| format!("writing {}", p.display()));
        }
    };
    std::fs::rename(&tmp, p).with_context(|| {
        let _ = std::fs::remove_file(&tmp);
        format!("renaming {} to {}", tmp.display(), p.display())
    })
}

/// Write pretty JSON atomically.
pub fn write_json<T: Serialize>(p: &Path, v: &T) -> Result<()> {
    let text = serde_json::to_string_pretty(v)?;
    write_atomic(p, (text + "\n").as_bytes())
}

/// The folder of a JSON or stats file must exist and be writable before the work starts.
pub fn check_file_target(flag: &str, p: &Path) -> Result<()> {
    // `-` reads as standard output to a shell user; a file of that name was written instead.
    if p.as_os_str() == "-" {
        anyhow::bail!(
            "{flag} -: a report is written to a file, not to standard output: give a file name \
             (./- for a file named '-')"
        );
    }
    if p.is_dir() {
        anyhow::bail!("{flag} {}: that is a folder, not a file", p.display());
    }
    // `q/` names a folder whether or not there is one (the path's last component drops the
    // slash, and the rename at the end failed after the whole run).
    use std::os::unix::ffi::OsStrExt;
    let bytes = p.as_os_str().as_bytes();
    if bytes.ends_with(b"/")
        || bytes.ends_with(b"/.")
        || bytes.ends_with(b"/..")
        || p.file_name().is_none()
    {
        anyhow::bail!(
            "{flag} {}: that names a folder, not a file: give a file name",
            p.display()
        );
    }
    let dir = parent_dir(p);
    if !dir.is_dir() {
        anyhow::bail!(
            "{flag} {}: folder {} does not exist",
            p.display(),
            dir.display()
        );
    }
    check_writable_dir(&dir).with_context(|| format!("{flag} {}", p.display()))
}

/// Refuse a report (`--stats`, `--json`) at `p` where a file is that is not a reframe report: a
/// report replaces what is there, so only an earlier report (`--stats`'s or `bench --json`'s,
/// known by their keys) or an empty file may be. A frame named by mistake (`--stats
/// out/v_0001.exr`) was replaced, and the render whose checkpoint counted it finished could no
/// longer be resumed; so was any JSON file (a cached reference's description, a camera file,
/// a `compare.json`), since only its first byte was looked at.
pub fn check_report_target(flag: &str, p: &Path) -> Result<()> {
    // A regular file only, looked at before it is opened (`open_regular`).
    let Ok(f) = open_regular(p) else {
        return Ok(());
    };
    use std::io::Read;
    // A report of a long render lists every frame: a few MB. Past this it is no report.
    const MAX_REPORT: u64 = 256 << 20;
    let mut text = Vec::new();
    let read = f.take(MAX_REPORT + 1).read_to_end(&mut text);
    if read.is_ok() && text.iter().all(u8::is_ascii_whitespace) {
        return Ok(());
    }
    let json = read
        .ok()
        .filter(|&n| n as u64 <= MAX_REPORT)
        .and_then(|_| serde_json::from_slice::<serde_json::Value>(&text).ok());
    let has = |k: &str| json.as_ref().is_some_and(|v| v.get(k).is_some());
    let report = has("cost_unit") || (has("method") && has("rays_per_second"));
    if !report {
        anyhow::bail!(
            "{flag} {}: the file there is not a reframe report (an image, another program's \
             JSON, a cached reference's description?), which this would replace: name another \
             file, or remove it",
            p.display()
        );
    }
    Ok(())
}

/// Opens (creating it if need be) a file that reframe owns and rewrites in place, `what` naming
/// it in messages ("the lock file", "the chunk log"): never through a symbolic link, never
/// blocking on a FIFO, and only a regular file of one name, since a link planted there (or a
/// hard link of another file) would have its target's content replaced.
pub fn open_own_file(path: &Path, what: &str) -> Result<std::fs::File> {
    use std::os::unix::fs::{MetadataExt, OpenOptionsExt};
    let f = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK)
        .open(path)
        .map_err(|e| {
            if let Some(kind) = match e.raw_os_error() {
                Some(libc::ELOOP) => Some("a symbolic link"),
                Some(libc::EISDIR) => Some("a folder"),
                _ => None,
            } {
                anyhow!(
                    "{what} {} is {kind}; remove it (reframe makes its own) and run again",
                    path.display()
                )
            } else if let Some(why) = (e.raw_os_error() == Some(libc::ENOTDIR))
                .then(|| not_a_folder(&parent_dir(path)))
                .flatten()
            {
                anyhow!("opening {what} {}: {why}", path.display())
            } else {
                anyhow!("opening {what} {}: {e}", path.display())
            }
        })?;
    let meta = f
        .metadata()
        .with_context(|| format!("{what} {}", path.display()))?;
    if !meta.is_file() || meta.nlink() != 1 {
        anyhow::bail!(
            "{what} {} is {}; remove it (reframe makes its own) and run again",
            path.display(),
            if meta.is_file() {
                "a file with other names (a hard link)"
            } else {
                "not a regular file"
            }
        );
    }
    Ok(f)
}

#[cfg(test)]
mod tests {
    use super::{create_temporary, live, remove_stale_tmp};

    /// While a stop by signal holds the registry (from its removals until the process is
    /// gone), no temporary file is made: a file made after its removals would be left behind.
    #[test]
    fn no_temporary_is_made_while_a_stop_holds_the_registry() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join(".f_0001.exr.tmp-1-1.exr");
        let held = live();
        std::thread::scope(|s| {
            let maker = s.spawn(|| create_temporary(&p).map(|(live, _)| live));
            std::thread::sleep(std::time::Duration::from_millis(300));
            assert!(!p.exists(), "made while the registry was held");
            drop(held);
            let live = maker.join().unwrap().unwrap();
            assert!(p.exists());
            assert!(
                super::live().iter().any(|(_, q)| q == &p),
                "made but not registered"
            );
            drop(live);
            assert!(!super::live().iter().any(|(_, q)| q == &p));
        });
    }

    /// Folders made for an output: where a deeper one cannot be made (a name too long), those
    /// made before it are removed again and the error says why; where a folder was there
    /// already, it is not this command's to remove; where all are made, they go again when the
    /// guard drops unless kept.
    #[test]
    fn made_folders_are_removed_again_and_only_those() {
        let d = tempfile::tempdir().unwrap();
        let deep = d.path().join("new").join("inner").join("x".repeat(300));
        let e = super::CreatedDirs::create(&deep).unwrap_err();
        assert_eq!(e.raw_os_error(), Some(36), "{e}"); // ENAMETOOLONG
        assert!(
            !d.path().join("new").exists(),
            "made before the error, left behind"
        );
        assert!(!live().iter().any(|(_, q)| q.starts_with(d.path())));

        std::fs::create_dir(d.path().join("old")).unwrap();
        let made = super::CreatedDirs::create(&d.path().join("old/a/b")).unwrap();
        assert_eq!(
            live()
                .iter()
                .filter(|(_, q)| q.starts_with(d.path()))
                .count(),
            2,
            "registered other than a and b"
        );
        drop(made);
        assert!(d.path().join("old").is_dir() && !d.path().join("old/a").exists());
        super::CreatedDirs::create(&d.path().join("old/a/b"))
            .unwrap()
            .keep();
        assert!(d.path().join("old/a/b").is_dir());
    }

    /// A temporary file of a process that runs (pid 1 runs wherever this does) is another
    /// process's write in progress: kept. One of a process that is gone, or this process's, goes.
    #[test]
    fn stale_temporary_files_go_but_not_those_of_running_processes() {
        let d = tempfile::tempdir().unwrap();
        let names = [
            ".f_0001.exr.tmp-1-3.exr".to_string(),
            ".f_0002.exr.tmp-4194303-3.exr".to_string(),
            format!(".f_0003.exr.tmp-{}-3.exr", std::process::id()),
            ".g_0001.exr.tmp-4194303-3.exr".to_string(),
        ];
        for n in &names {
            std::fs::write(d.path().join(n), b"").unwrap();
        }
        remove_stale_tmp(d.path(), |n| n.starts_with("f_"));
        let left: Vec<bool> = names.iter().map(|n| d.path().join(n).exists()).collect();
        assert_eq!(left, [true, false, false, true]);
        // A checkpoint's temporary is `state.tmp-PID` exactly: a user's `state.tmp-2024-notes`
        // in a folder named by --checkpoint stays.
        let names = [
            "state.tmp-4194303",
            "state.tmp-2024-notes",
            "state.tmp-4194303.bak",
        ];
        for n in names {
            std::fs::write(d.path().join(n), b"").unwrap();
        }
        remove_stale_tmp(d.path(), |n| n == "state");
        let left: Vec<bool> = names.iter().map(|n| d.path().join(n).exists()).collect();
        assert_eq!(left, [false, true, true]);
    }
}
