//! What the integration tests share: one way to run the real binary (`reframe_ok` for runs that
//! must succeed, `run_reframe` with a time limit for bad input, and the rules a failed run must
//! follow), one in-memory render (`render_in_memory`, and `reuse_renders`, the seeds of one
//! frame that the reuse z-tests compare), and one bitwise comparison of frame files
//! (`assert_identical`). Each test file uses a part of it.
#![allow(dead_code)]
use reframe::driver::{render_frames, RenderOptions};
use reframe::film::{Developed, MemorySink};
use reframe::integrator::Integrator;
use reframe::reuse::Method;
use reframe::state::checkpoint::Counters;
use std::collections::BTreeMap;
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
pub fn run_reframe<S: AsRef<std::ffi::OsStr>>(args: &[S], limit: Duration) -> Outcome {
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

/// Every file and folder below `d`, recursively, with its size and modification time: what a
/// refused command must leave exactly as it was.
pub fn snapshot(d: &Path) -> Vec<(PathBuf, u64, std::time::SystemTime)> {
    let mut v = Vec::new();
    let Ok(entries) = std::fs::read_dir(d) else {
        return v;
    };
    for e in entries.flatten() {
        let p = e.path();
        if let Ok(m) = std::fs::symlink_metadata(&p) {
            v.push((p.clone(), m.len(), m.modified().unwrap()));
            if m.is_dir() {
                v.extend(snapshot(&p));
            }
        }
    }
    v.sort();
    v
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

/// Send `sig` (`INT`, `TERM`, `KILL`, ...) to `child`; whether it was still there to receive it.
pub fn signal(child: &std::process::Child, sig: &str) -> bool {
    wait_for_handler(child.id(), sig);
    Command::new("kill")
        .args([&format!("-{sig}"), &child.id().to_string()])
        .stderr(Stdio::null())
        .status()
        .unwrap()
        .success()
}

/// Wait (at most 10 s) until process `pid` catches `sig` (its `SigCgt` mask in
/// `/proc/<pid>/status`), so that a signal sent right after start, while a loaded machine is
/// still mapping the binary's libraries, tests the handler and not the default action. Returns
/// at once for a signal that cannot be caught, or once the process is gone.
fn wait_for_handler(pid: u32, sig: &str) {
    let bit = match sig {
        "HUP" => 1,
        "INT" => 2,
        "TERM" => 15,
        _ => return,
    };
    let start = std::time::Instant::now();
    while start.elapsed() < std::time::Duration::from_secs(10) {
        let Ok(status) = std::fs::read_to_string(format!("/proc/{pid}/status")) else {
            return;
        };
        let caught = status
            .lines()
            .find_map(|l| l.strip_prefix("SigCgt:"))
            .and_then(|m| u64::from_str_radix(m.trim(), 16).ok());
        match caught {
            Some(m) if m & (1 << (bit - 1)) != 0 => return,
            None => return,
            _ => std::thread::sleep(std::time::Duration::from_millis(5)),
        }
    }
}

/// The `reframe` command with `args`, ready to run (standard input closed).
pub fn reframe<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_reframe"));
    c.args(args).stdin(Stdio::null());
    c
}

/// Run `reframe` with `args`; fail the test, showing its stderr, unless it succeeds.
pub fn reframe_ok<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> std::process::Output {
    let o = reframe(args).output().expect("start reframe");
    assert!(
        o.status.success(),
        "reframe {:?} failed: {}",
        args.iter()
            .map(|a| a.as_ref().to_owned())
            .collect::<Vec<_>>(),
        String::from_utf8_lossy(&o.stderr)
    );
    o
}

/// Assert that a finished run of the binary was refused (exit 1) with one line that contains
/// `want`.
pub fn assert_refused(o: &std::process::Output, want: &str) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains(want) && err.trim().lines().count() == 1,
        "{err}"
    );
}

/// Render `opts` in memory (frames, resolution and all: see `RenderOptions`) with `integ`:
/// frame -> developed frame, and the run's counters. Fails the test if a contribution or a
/// pixel came out NaN or infinite.
pub fn render_in_memory(
    integ: &Integrator,
    opts: &RenderOptions,
) -> (BTreeMap<u32, Developed>, Counters) {
    let mut sink = MemorySink::default();
    let counters = render_frames(integ, opts, &mut sink).expect("render in memory");
    assert_eq!(
        counters.nonfinite_samples, 0,
        "{:?}: non-finite contributions",
        opts.method
    );
    for (f, d) in &sink.0 {
        assert_eq!(
            d.nonfinite, 0,
            "{:?} frame {f}: non-finite pixel",
            opts.method
        );
    }
    (sink.0, counters)
}

/// `k` renders of frame `target` by `method` (1 native spp, group size `window`, seeds from
/// `seed`), the frames `frames` rendered at `w` x `h` in memory on `pool`: the renders a reuse
/// z-test sets against an independent reference.
pub fn reuse_renders(
    integ: &Integrator,
    pool: &rayon::ThreadPool,
    (method, window): (Method, u32),
    (frames, target): (std::ops::RangeInclusive<u32>, u32),
    (w, h): (u32, u32),
    (k, seed): (u64, u64),
) -> Vec<Vec<glam::Vec3>> {
    (0..k)
        .map(|s| {
            let opts = RenderOptions {
                method,
                window,
                spp: 1,
                seed: seed + s,
                frames: Some(frames.clone()),
                resolution: Some((w, h)),
                progress: false,
                ..RenderOptions::default()
            };
            pool.install(|| {
                render_in_memory(integ, &opts)
                    .0
                    .remove(&target)
                    .unwrap()
                    .pixels()
            })
        })
        .collect()
}

/// Assert that the frame files `names` are bitwise identical in folders `a` and `b`: the same
/// channels and the same bits of every value.
pub fn assert_identical(a: &Path, b: &Path, names: impl IntoIterator<Item = String>) {
    let mut n = 0;
    for name in names {
        let (x, y) = (
            reframe::image::read_image(&a.join(&name))
                .unwrap_or_else(|e| panic!("{}: {e}", a.join(&name).display())),
            reframe::image::read_image(&b.join(&name))
                .unwrap_or_else(|e| panic!("{}: {e}", b.join(&name).display())),
        );
        assert_eq!(x.channels, y.channels, "{name}: channels");
        let bits = |v: &[f32]| v.iter().map(|p| p.to_bits()).collect::<Vec<_>>();
        assert!(bits(&x.data) == bits(&y.data), "{name} differs");
        n += 1;
    }
    assert!(n > 0, "no frames compared");
}

/// The corpus's small valid scene (`tests/corpus/base`) in `d`, lit by a grey environment image
/// `e_0000.exr` beside it (named like a frame of `e_####.exr`): the scene file's path and the
/// image's.
#[allow(dead_code)]
pub fn base_scene_with_sky(d: &Path) -> (String, PathBuf) {
    let base = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus/base");
    for f in ["s.obj", "s.mtl"] {
        std::fs::copy(base.join(f), d.join(f)).unwrap();
    }
    let toml = std::fs::read_to_string(base.join("s.toml")).unwrap();
    std::fs::write(
        d.join("s.toml"),
        format!("{toml}[environment]\nimage = \"e_0000.exr\"\n"),
    )
    .unwrap();
    let mut sky = reframe::image::Image::new(4, 2, &["R", "G", "B"]);
    sky.data.fill(0.5);
    let env = d.join("e_0000.exr");
    reframe::image::write_image(
        &env,
        &sky,
        &reframe::image::Metadata::default(),
        &reframe::image::WriteOptions::default(),
    )
    .unwrap();
    (d.join("s.toml").to_str().unwrap().to_string(), env)
}
