//! Files written so that a crash never leaves half of one: a temporary name in the same folder,
//! then a rename; the temporary names a killed process leaves behind, and how to clear them;
//! and the checks made before a long run that it will be able to write at its end.
use anyhow::{anyhow, Context, Result};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

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

/// Fail unless a file can be created (and removed) in `dir`: creates and deletes a probe file.
pub fn check_writable_dir(dir: &Path) -> Result<()> {
    let probe = dir.join(format!(
        ".reframe-probe-{}-{}",
        std::process::id(),
        unique()
    ));
    std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
        .map_err(|e| anyhow!("cannot create files in folder {}: {e}", dir.display()))?;
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
/// `.NAME.tmp-PID...`) whose `NAME` passes `ours`.
pub fn remove_stale_tmp(dir: &Path, ours: impl Fn(&str) -> bool) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if let Some((base, _)) = name.split_once(".tmp-") {
            if ours(base.strip_prefix('.').unwrap_or(base)) {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
}

/// Write a file atomically: a temporary name in the same folder, then a rename.
pub fn write_atomic(p: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = tmp_name(p);
    std::fs::write(&tmp, bytes).with_context(|| format!("writing {}", tmp.display()))?;
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
    if p.is_dir() {
        anyhow::bail!("{flag} {}: that is a folder, not a file", p.display());
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
