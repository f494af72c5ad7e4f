//! Signals in every phase of every command: `reference`, `bench` and `compare` (in its
//! reference and in its runs) stop at once on SIGINT or SIGTERM with one line and exit status 130, leaving no
//! temporary or lock file; two SIGINTs in quick succession during a render that writes frames
//! and checkpoints all the time leave no temporary file either, and its checkpoint resumes.
mod common;

use common::{files_under, reframe, signal};
use std::path::Path;
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

/// Wait for `child` at most `limit`; its exit code and stderr.
fn wait(mut child: Child, limit: Duration) -> (Option<i32>, String) {
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let mut err = String::new();
            use std::io::Read;
            child
                .stderr
                .take()
                .unwrap()
                .read_to_string(&mut err)
                .unwrap();
            return (status.code(), err);
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            panic!("still running {limit:?} after the signal");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Start `reframe ARGS` (split at white space) in `dir`, its stderr piped.
fn start(dir: &Path, args: &str) -> Child {
    reframe(&args.split_whitespace().collect::<Vec<_>>())
        .current_dir(dir)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Wait (a minute at most, else fail with `what`) until `p` exists.
fn wait_for(p: &Path, what: &str) {
    let start = Instant::now();
    while !p.exists() {
        assert!(start.elapsed() < Duration::from_secs(60), "{what}");
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Temporary files, probes and the locks of outputs left in `d`. (A reference cache entry's
/// lock, `cache/.ENTRY.lock`, stays by design: a process waiting on it must find the same
/// file when its holder is done.)
fn leftovers(d: &Path) -> Vec<String> {
    files_under(d)
        .into_iter()
        .filter(|p| {
            let in_cache = p.parent().and_then(|q| q.file_name()) == Some("cache".as_ref());
            let n = p.file_name().unwrap().to_string_lossy();
            !(in_cache && n.starts_with('.') && n.ends_with(".lock"))
        })
        .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
        .filter(|n| n.contains(".tmp-") || n.contains("probe") || n.ends_with(".lock"))
        .collect()
}

/// Run `args` in `dir`, send `sig` once it has run `after`, and check that it stops within two
/// seconds with status 130, a last line saying so, and no temporary file.
fn stops_at_once(dir: &Path, args: &[&str], after: Duration, sig: &str) {
    std::fs::create_dir_all(dir).unwrap();
    let child = reframe(args)
        .current_dir(dir)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(after);
    assert!(signal(&child, sig), "{args:?} ended before the signal");
    let sent = Instant::now();
    let (code, err) = wait(child, Duration::from_secs(5));
    let took = sent.elapsed();
    assert_eq!(code, Some(130), "{args:?}: {err}");
    assert!(took < Duration::from_secs(2), "{args:?} took {took:?}");
    // What it printed (compare's lines per run; one may still come while the process exits),
    // and one line saying it stopped.
    let stops = err
        .lines()
        .filter(|l| l.starts_with("interrupted: stopped at once"))
        .count();
    assert_eq!(stops, 1, "{args:?}: {err}");
    assert!(!err.contains("error"), "{args:?}: {err}");
    assert_eq!(leftovers(dir), Vec::<String>::new(), "{args:?}");
    // Nor a folder it made and left empty (an output folder, a cache entry).
    assert_eq!(empty_folders(dir), Vec::<String>::new(), "{args:?}");
}

/// The folders under `d` (not `d` itself) that hold nothing.
fn empty_folders(d: &Path) -> Vec<String> {
    let mut empty = Vec::new();
    let mut todo = vec![d.to_path_buf()];
    while let Some(dir) = todo.pop() {
        let entries: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        if entries.is_empty() && dir != d {
            empty.push(dir.display().to_string());
        }
        todo.extend(entries.into_iter().filter(|p| p.is_dir()));
    }
    empty
}

#[test]
fn every_command_stops_at_once_outside_a_render_loop() {
    let d = tempfile::tempdir().unwrap();
    let d = d.path();
    let second = Duration::from_millis(1000);
    // The reference: a long one, interrupted while it renders.
    stops_at_once(
        &d.join("reference"),
        &[
            "reference",
            "vase",
            "--res",
            "64x48",
            "--frames",
            "10-12",
            "--reference-spp",
            "8192",
            "--cache",
            "cache",
        ],
        second,
        "INT",
    );
    // render, while it loads a texture: an 8192 x 8192 grey PNG that decodes for seconds,
    // with standard error quieted (a codec's own complaints go to /dev/null meanwhile). The
    // interrupt's line went there too: status 130 and not a word.
    let tex = d.join("texture");
    std::fs::create_dir_all(&tex).unwrap();
    let big = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/images/big-grey.png");
    std::fs::write(
        tex.join("s.mtl"),
        format!(
            "newmtl floor\nKd 1 1 1\nmap_Kd {}\nnewmtl light\nKd 0 0 0\nKe 5 5 5\n",
            big.display()
        ),
    )
    .unwrap();
    std::fs::write(
        tex.join("s.obj"),
        "mtllib s.mtl\nv -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nv -0.2 1.9 -0.2\n\
         v 0.2 1.9 -0.2\nv 0.2 1.9 0.2\nv -0.2 1.9 0.2\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
         usemtl floor\nf 1/1 4/4 3/3 2/2\nusemtl light\nf 5 6 7 8\n",
    )
    .unwrap();
    std::fs::write(
        tex.join("s.toml"),
        "obj = \"s.obj\"\nframes = 1\nresolution = [16, 12]\n[[keyframe]]\nframe = 0\n\
         position = [0, 1, 3]\nlook_at = [0, 0, 0]\nup = [0, 1, 0]\nfov = 45\n",
    )
    .unwrap();
    stops_at_once(
        &tex,
        &["render", "s.toml", "--out", "o/f_####.exr"],
        Duration::from_millis(700),
        "INT",
    );
    // bench, while it measures.
    stops_at_once(
        &d.join("bench"),
        &[
            "bench", "vase", "--spp", "64", "--res", "64x48", "--json", "b.json",
        ],
        second,
        "TERM",
    );
    // compare, in its reference and then in its runs (a cached reference).
    let compare = [
        "compare",
        "vase",
        "--res",
        "48x36",
        "--frames",
        "20-22",
        "--regime",
        "range",
        "--methods",
        "independent,mis-cv",
        "--budgets",
        "1,2,4,8,16,32,64,128,256,512,1024",
        "--reuse-budgets",
        "64",
        "--windows",
        "3",
        "--reference-spp",
        "512",
        "--cache",
        "cache",
        "--out",
        "out",
    ];
    stops_at_once(&d.join("compare"), &compare, second, "INT");
    common::reframe_ok(&[
        "reference",
        "vase",
        "--res",
        "48x36",
        "--frames",
        "20-22",
        "--reference-spp",
        "512",
        "--cache",
        d.join("compare/cache").to_str().unwrap(),
    ]);
    stops_at_once(&d.join("compare"), &compare, second, "INT");
}

#[test]
fn two_quick_interrupts_leave_no_temporary_file() {
    // A render that writes a frame and a checkpoint every few milliseconds; the second SIGINT
    // 50 ms after the first lands, now and then, while one of them is being written.
    let d = tempfile::tempdir().unwrap();
    for attempt in 0..6 {
        let dir = d.path().join(format!("r{attempt}"));
        std::fs::create_dir_all(&dir).unwrap();
        let args = [
            "render",
            "vase",
            "--method",
            "mis-cv",
            "--window",
            "3",
            "--spp",
            "1",
            "--res",
            "160x120",
            "--out",
            "out/f_####.exr",
            "--checkpoint-every",
            "0",
            "--exr-float",
        ];
        let child = reframe(&args)
            .current_dir(&dir)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        // Wait until frames are being written.
        wait_for(&dir.join("out/f_0002.exr"), "no frame written");
        std::thread::sleep(Duration::from_millis(7 * attempt as u64));
        assert!(signal(&child, "INT"));
        std::thread::sleep(Duration::from_millis(50));
        // It may have stopped cleanly already; then there is nothing to interrupt again.
        signal(&child, "INT");
        let (code, err) = wait(child, Duration::from_secs(10));
        assert_eq!(code, Some(130), "{err}");
        assert_eq!(
            leftovers(&dir),
            Vec::<String>::new(),
            "attempt {attempt}: {err}"
        );
        // Whatever checkpoint is there is whole: the render resumes from it and finishes.
        let mut resume = args.map(String::from).to_vec();
        resume.push("--resume".into());
        let out = reframe(&resume).current_dir(&dir).output().unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(dir.join("out/f_0047.exr").exists());
    }
}

/// A render stopped at once before its first checkpoint leaves no empty checkpoint folder (it
/// created the folder at start).
#[test]
fn a_stop_before_the_first_checkpoint_leaves_no_checkpoint_folder() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let child = start(
        dir,
        "render vase --method mis-exact --window 5 --spp 16 --res 160x120 --out out/f_####.exr \
         --checkpoint-every 600",
    );
    wait_for(&dir.join("out/f.checkpoint"), "no checkpoint folder");
    std::thread::sleep(Duration::from_millis(200));
    // The first asks for a checkpoint after the group (seconds away at 16 spp), the second
    // stops at once, before it.
    assert!(signal(&child, "INT"));
    std::thread::sleep(Duration::from_millis(50));
    assert!(signal(&child, "INT"));
    let (code, err) = wait(child, Duration::from_secs(10));
    assert_eq!(code, Some(130), "{err}");
    // Said as it is: no checkpoint to keep (it said "a checkpoint already written is kept").
    assert!(
        err.contains("stopping now, before the first checkpoint"),
        "{err}"
    );
    assert!(!dir.join("out/f.checkpoint").exists(), "{err}");
    assert_eq!(leftovers(dir), Vec::<String>::new());
}

/// An interrupt while the last frame renders (or is written) lets the render finish: every frame
/// in place, a line saying the render is complete, status 0, no checkpoint left behind.
#[test]
fn an_interrupt_during_the_last_frame_ends_a_complete_render() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    // Two frames of about a second each here: the signal comes as the second starts.
    let child = start(
        dir,
        "render vase --spp 32 --res 320x240 --frames 0-1 --out out/f_####.exr \
         --checkpoint-every 600",
    );
    wait_for(&dir.join("out/f_0000.exr"), "no frame written");
    assert!(signal(&child, "INT"));
    let (code, err) = wait(child, Duration::from_secs(60));
    assert_eq!(code, Some(0), "{err}");
    assert!(
        err.contains("the interrupt came during the last frames: the render is complete"),
        "{err}"
    );
    assert!(dir.join("out/f_0001.exr").exists(), "{err}");
    assert!(!dir.join("out/f.checkpoint").exists(), "{err}");
    assert_eq!(leftovers(dir), Vec::<String>::new(), "{err}");
}

/// A merge stopped at once says which frames it had written (they are in place, whole, and no
/// checkpoint counts them: its line had said only that nothing was left half-written).
#[test]
fn an_interrupted_merge_says_what_it_wrote() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    common::reframe_ok(&[
        "render",
        "vase",
        "--spp",
        "1",
        "--res",
        "640x480",
        "--chunk",
        "1/1",
        "--exr-float",
        "--out",
        dir.join("c/f_####.exr").to_str().unwrap(),
    ]);
    let child = start(dir, "merge c/f.chunk-1-of-1.partial --out out/f_####.exr");
    wait_for(&dir.join("out/f_0001.exr"), "no frame written");
    assert!(signal(&child, "INT"), "the merge ended before the signal");
    let (code, err) = wait(child, Duration::from_secs(10));
    assert_eq!(code, Some(130), "{err}");
    let line = err
        .lines()
        .find(|l| l.starts_with("interrupted: stopped at once"))
        .unwrap_or_else(|| panic!("{err}"));
    assert!(
        line.contains("frame file(s) written whole before it, the last out/f_00"),
        "{line}"
    );
    assert_eq!(leftovers(dir), Vec::<String>::new());
}
