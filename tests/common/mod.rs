//! Running the real binary on bad input, shared by the corpus (`tests/bad_input.rs`) and the
//! mutation test (`tests/mutants.rs`): one run with a time limit, and the rules a failed run
//! must follow.
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// How one run of the binary ended.
pub struct Outcome {
    /// The exit code; `None` when a signal ended it (or the time limit did).
    pub code: Option<i32>,
    pub stderr: String,
    pub timed_out: bool,
}

/// Run `reframe` with `args`, killing it after `limit`.
pub fn run_reframe(args: &[String], limit: Duration) -> Outcome {
    let mut child = Command::new(env!("CARGO_BIN_EXE_reframe"))
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start reframe");
    let mut pipe = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut bytes = Vec::new();
        let _ = pipe.read_to_end(&mut bytes);
        bytes
    });
    let start = Instant::now();
    let mut timed_out = false;
    let status = loop {
        if let Some(s) = child.try_wait().expect("wait for reframe") {
            break s;
        }
        if start.elapsed() > limit {
            timed_out = true;
            let _ = child.kill();
            break child.wait().expect("wait for reframe");
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    let stderr = String::from_utf8_lossy(&reader.join().unwrap()).into_owned();
    Outcome {
        code: status.code(),
        stderr,
        timed_out,
    }
}

/// The rules for a run that refuses its input: exit 1 (an error) or 2 (a usage error), no
/// panic, and exactly one non-empty line on stderr. The line, or what is wrong.
pub fn refusal(o: &Outcome) -> Result<String, String> {
    if o.timed_out {
        return Err("timed out".into());
    }
    if o.stderr.contains("panicked") || o.stderr.contains("RUST_BACKTRACE") {
        return Err(format!("panicked: {}", o.stderr));
    }
    if !matches!(o.code, Some(1 | 2)) {
        return Err(format!(
            "exit code {:?} (want 1 or 2): {}",
            o.code, o.stderr
        ));
    }
    let lines: Vec<&str> = o.stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    match lines[..] {
        [line] => Ok(line.to_string()),
        [] => Err("no error message".into()),
        _ => Err(format!("{} lines, not one: {}", lines.len(), o.stderr)),
    }
}

/// Every file below `d`, recursively.
pub fn files_under(d: &Path) -> Vec<PathBuf> {
    let mut v = Vec::new();
    let Ok(entries) = std::fs::read_dir(d) else {
        return v;
    };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            v.extend(files_under(&p));
        } else {
            v.push(p);
        }
    }
    v.sort();
    v
}

/// `f` over `items` on a few threads (each item runs a process, so threads only wait), in order.
pub fn par_map<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    let workers = std::thread::available_parallelism().map_or(2, |n| n.get().clamp(2, 8));
    let next = std::sync::atomic::AtomicUsize::new(0);
    let mut out: Vec<(usize, R)> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..workers)
            .map(|_| {
                s.spawn(|| {
                    let mut done = Vec::new();
                    loop {
                        let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        let Some(item) = items.get(i) else { break done };
                        done.push((i, f(item)));
                    }
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().unwrap())
            .collect()
    });
    out.sort_by_key(|(i, _)| *i);
    out.into_iter().map(|(_, r)| r).collect()
}
