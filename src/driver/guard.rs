//! What keeps a command from damaging what it should not touch: one command per output (an
//! exclusive advisory lock, `flock` through `std::fs::File::try_lock`, released by the kernel
//! when its holder dies, so no stale lock survives a SIGKILL), and inputs that are never outputs.
use crate::util::fs::{open_own_file, parent_dir, Temporary};
use anyhow::{anyhow, bail, Result};
use std::collections::HashMap;
use std::fs::File;
use std::io::{Read, Seek, Write};
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

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
    /// process that holds it.
    pub fn acquire(path: &Path, what: &str) -> Result<OutputLock> {
        loop {
            // Never through a symbolic link, never blocking on a FIFO, and only a regular file
            // of one name: a lock file planted as a link to another file (or a hard link of
            // one) would have that file's content replaced by a pid.
            let mut f = open_own_file(path, "the lock file")?;
            if f.try_lock().is_err() {
                // The holder's pid and what it writes (the first line and the rest): outputs of
                // one stem share a lock (`v_####.png` and `v_####.exr`), so it may be another
                // pattern than this command's. Read at most a line's worth of it.
                let mut held = String::new();
                let _ = (&mut f).take(4096).read_to_string(&mut held);
                let (pid, its) = held.split_once('\n').unwrap_or((&held, ""));
                let (pid, its) = (pid.trim(), its.trim());
                bail!(
                    "another reframe{} is writing {} (its lock is {}): wait for it to finish, or \
                     stop it",
                    if pid.is_empty() {
                        String::new()
                    } else {
                        format!(" (pid {pid})")
                    },
                    if its.is_empty() { what } else { its },
                    path.display()
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
            f.set_len(0)?;
            f.rewind()?;
            write!(f, "{}\n{what}\n", std::process::id())?;
            return Ok(OutputLock {
                path: path.to_path_buf(),
                file: Some(f),
                _live: Temporary::new(path),
            });
        }
    }
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

/// Refuse a folder a command creates (`flag`, `--checkpoint`) at the path of one of its
/// `outputs` (a checkpoint named like a later frame made that frame's write fail at its turn).
pub fn check_folder_apart(flag: &str, dir: &Path, outputs: &[(&str, PathBuf)]) -> Result<()> {
    let Some(d) = resolved(dir) else {
        return Ok(());
    };
    if let Some((other, out)) = outputs
        .iter()
        .find(|(_, o)| resolved(o).as_ref() == Some(&d))
    {
        bail!(
            "{flag} {}: that is also where {other} {} goes; nothing was written",
            dir.display(),
            out.display()
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
    for (flag, out) in outputs {
        crate::util::fs::check_replaceable(&out)
            .map_err(|e| anyhow!("{flag} {e}; nothing was written"))?;
        // A report (--stats, bench's --json) is never written over a run's state.
        if matches!(flag, "--stats" | "--json") && crate::state::is_state_file(&out) {
            bail!(
                "{flag} {}: that is a reframe state file (a checkpoint or a chunk's partial), \
                 which a report must not replace; nothing was written",
                out.display()
            );
        }
        let Some(r) = resolved(&out) else { continue };
        if let Some((_, input)) = inputs.iter().find(|(c, _)| *c == r) {
            bail!(
                "{flag} {}: that is an input of this command ({}); nothing was written",
                out.display(),
                input.display()
            );
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
