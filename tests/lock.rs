//! One command per output: a second `render` on the output of one that is running is refused at
//! once, naming the first's pid, and the first finishes with the frames an undisturbed render
//! writes; the lock goes with its holder (also when it is killed).
mod common;

use common::{assert_identical, reframe, reframe_ok};
use std::process::Command;
use std::time::{Duration, Instant};

#[test]
fn a_second_render_on_the_same_output_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let args = |sub: &str| -> Vec<String> {
        [
            "render",
            "vase",
            "--frames",
            "0-5",
            "--res",
            "120x90",
            "--spp",
            "8",
            "--exr-float",
            "--out",
        ]
        .iter()
        .map(|s| s.to_string())
        .chain([d.join(sub).join("f_####.exr").display().to_string()])
        .collect()
    };
    let lock = d.join("a/.f.lock");
    let mut first = reframe(&args("a")).spawn().unwrap();
    let start = Instant::now();
    while !lock.exists() {
        assert!(
            first.try_wait().unwrap().is_none(),
            "finished before the test"
        );
        assert!(start.elapsed() < Duration::from_secs(60), "no lock file");
        std::thread::sleep(Duration::from_millis(5));
    }
    // The first is stopped while the second runs, so that it still holds the lock however
    // slowly the second starts (on a loaded machine the first had finished its 0.3 s render
    // before the second looked, and the second rendered).
    let signal = |sig: &str| {
        let pid = first.id().to_string();
        assert!(Command::new("kill")
            .args([sig, &pid])
            .status()
            .unwrap()
            .success());
    };
    signal("-STOP");
    let t = Instant::now();
    let o = reframe(&args("a")).output().unwrap();
    signal("-CONT");
    let err = String::from_utf8_lossy(&o.stderr);
    // Refused, not made to wait: a refusal naming the first's pid can only come while the
    // first holds the lock (`try_lock` never waits). The bound only catches a hang; a timed
    // bound of one second failed on a loaded two-core machine.
    assert!(t.elapsed() < Duration::from_secs(30), "refused too slowly");
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains(&format!("pid {}", first.id())) && err.trim().lines().count() == 1,
        "{err}"
    );
    assert!(first.wait().unwrap().success());
    assert!(!lock.exists(), "the lock file stays behind");
    reframe_ok(&args("b"));
    assert_identical(
        &d.join("a"),
        &d.join("b"),
        (0..=5).map(|f| format!("f_{f:04}.exr")),
    );
    // A killed holder leaves its lock file, but not its lock.
    let mut killed = reframe(&args("c")).spawn().unwrap();
    let lock = d.join("c/.f.lock");
    while !lock.exists() {
        std::thread::sleep(Duration::from_millis(5));
    }
    killed.kill().unwrap();
    killed.wait().unwrap();
    let mut again = args("c");
    again.push("--resume".into());
    reframe_ok(&again);
}

/// What the command line names as an output is replaced by a rename, so it must be a regular
/// file (or new): a FIFO, a device or a symbolic link given as `--stats` is refused before
/// anything is rendered and left as it was. A lock file planted as a symbolic or hard link to
/// another file is refused too, and that file keeps its content. `bench --json` never writes
/// over the scene.
#[test]
fn outputs_and_locks_never_replace_or_write_through_what_is_not_theirs() {
    use std::os::unix::fs::FileTypeExt;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = d.join("s.toml");
    for f in ["s.toml", "s.obj", "s.mtl"] {
        let from = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus/base");
        std::fs::copy(from.join(f), d.join(f)).unwrap();
    }
    let victim = d.join("victim.txt");
    std::fs::write(&victim, "precious\n").unwrap();
    let render = |extra: &[&str]| {
        let mut a: Vec<String> = [
            "render",
            scene.to_str().unwrap(),
            "--spp",
            "1",
            "--threads",
            "1",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        a.extend(extra.iter().map(|s| s.to_string()));
        reframe(&a).output().unwrap()
    };
    let refused = common::assert_refused;
    let out = d.join("o/f_####.png");
    let out = out.to_str().unwrap();
    // --stats as a FIFO and as a symbolic link to another file.
    let fifo = d.join("fifo");
    assert!(Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap()
        .success());
    let link = d.join("link.json");
    std::os::unix::fs::symlink(&victim, &link).unwrap();
    for (p, what) in [
        (&fifo, "is a named pipe (FIFO)"),
        (&link, "is a symbolic link"),
    ] {
        refused(
            &render(&["--out", out, "--stats", p.to_str().unwrap()]),
            what,
        );
    }
    assert!(std::fs::symlink_metadata(&fifo)
        .unwrap()
        .file_type()
        .is_fifo());
    assert!(std::fs::symlink_metadata(&link)
        .unwrap()
        .file_type()
        .is_symlink());
    assert!(
        !d.join("o").exists(),
        "a refused render left its output folder"
    );
    // A lock file planted as a link to the victim.
    std::fs::create_dir(d.join("o")).unwrap();
    let lock = d.join("o/.f.lock");
    std::os::unix::fs::symlink(&victim, &lock).unwrap();
    refused(
        &render(&["--out", out]),
        "is a symbolic link, not a lock file: remove it",
    );
    std::fs::remove_file(&lock).unwrap();
    // A folder in the lock's place: said to be in the way (not explained as a frame's rename).
    std::fs::create_dir(&lock).unwrap();
    refused(
        &render(&["--out", out]),
        "is a directory, not a lock file: remove it",
    );
    std::fs::remove_dir(&lock).unwrap();
    std::fs::hard_link(&victim, &lock).unwrap();
    refused(&render(&["--out", out]), "(a hard link)");
    std::fs::remove_file(&lock).unwrap();
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious\n");
    // With the lock gone, the same render goes ahead.
    reframe_ok(&[
        "render",
        scene.to_str().unwrap(),
        "--spp",
        "1",
        "--out",
        out,
    ]);
    // bench --json naming the scene.
    let before = std::fs::read(&scene).unwrap();
    let o = reframe(&[
        "bench",
        scene.to_str().unwrap(),
        "--res",
        "8x6",
        "--json",
        scene.to_str().unwrap(),
    ])
    .output()
    .unwrap();
    refused(&o, "that is an input of this command");
    assert_eq!(std::fs::read(&scene).unwrap(), before);
}

/// Outputs of one stem share a lock (`f_####.exr` and `f_####.png`): the refusal names what the
/// holder writes, not the refused command's pattern.
#[test]
fn a_refusal_names_what_the_holder_writes() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let args = |ext: &str| -> Vec<String> {
        let out = d.join(format!("f_####.{ext}")).display().to_string();
        "render vase --frames 0-40 --spp 64 --out"
            .split_whitespace()
            .map(String::from)
            .chain([out])
            .collect()
    };
    let mut first = reframe(&args("exr")).spawn().unwrap();
    let lock = d.join(".f.lock");
    let start = Instant::now();
    while !lock.exists() {
        assert!(start.elapsed() < Duration::from_secs(60), "no lock file");
        std::thread::sleep(Duration::from_millis(5));
    }
    let o = reframe(&args("png")).output().unwrap();
    let still_running = first.try_wait().unwrap().is_none();
    first.kill().unwrap();
    first.wait().unwrap();
    assert!(still_running, "the first render finished before the test");
    let err = String::from_utf8_lossy(&o.stderr);
    let held = d.join("f_####.exr").display().to_string();
    assert!(
        o.status.code() == Some(1) && err.contains(&format!("is writing {held} ")),
        "{err}"
    );
    // And why another pattern's lock is this one's, and what to do about it.
    assert!(
        err.contains("lock have this one's names ('f':")
            && err.contains("give this command an --out of another name"),
        "{err}"
    );
}

/// Two renders whose frame files share a name are refused whatever their patterns
/// (`f_####.exr` and `f_0###.exr` both write `f_0030.exr`, a single frame named `f_0007.exr`
/// is frame 7 of both), and so are two renders given one `--checkpoint` folder and a `--stats`
/// report named like a running render's frame; renders whose
/// names never meet run side by side, and a killed holder's lock stops nobody.
#[test]
fn renders_whose_frame_files_meet_are_refused_whatever_their_patterns() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let args = |out: &str, frames: &str, extra: &[&str]| -> Vec<String> {
        let spp = if extra.first() == Some(&"--spp") {
            &[][..]
        } else {
            &["--spp", "1"]
        };
        ["render", "vase", "--res", "48x36", "--frames", frames]
            .iter()
            .chain(spp)
            .chain(extra)
            .map(|s| s.to_string())
            .chain(["--out".to_string(), d.join(out).display().to_string()])
            .collect()
    };
    let long = ["--spp", "4096", "--checkpoint"];
    let mut ck = long.to_vec();
    let ck_dir = d.join("ck").display().to_string();
    ck.push(&ck_dir);
    let mut first = reframe(&args("f_####.exr", "0-40", &ck)).spawn().unwrap();
    // Its lock names its frames once written.
    let lock = d.join(".f.lock");
    let start = Instant::now();
    while !std::fs::read_to_string(&lock).is_ok_and(|t| t.contains("frames 0-40")) {
        assert!(
            first.try_wait().unwrap().is_none(),
            "the first render stopped"
        );
        assert!(start.elapsed() < Duration::from_secs(60), "no lock file");
        std::thread::sleep(Duration::from_millis(5));
    }
    let refusal = |a: Vec<String>| {
        let o = reframe(&a).output().unwrap();
        (
            o.status.code(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };
    let pid = format!("pid {}", first.id());
    let (code, err) = refusal(args("f_0###.exr", "30-31", &[]));
    assert!(
        code == Some(1) && err.contains(&pid) && err.contains("f_0030.exr"),
        "{err}"
    );
    let (code, err) = refusal(args("f_0007.exr", "7-7", &[]));
    assert!(
        code == Some(1) && err.contains(&pid) && err.contains("frame 7"),
        "{err}"
    );
    let (code, err) = refusal(args("g_####.exr", "0-1", &["--checkpoint", &ck_dir]));
    assert!(
        code == Some(1) && err.contains(&pid) && err.contains("checkpoint folder"),
        "{err}"
    );
    // A report named like one of its frames: it would replace the frame, or be replaced.
    let stats = d.join("f_0012.exr").display().to_string();
    let (code, err) = refusal(args("h_####.exr", "0-1", &["--stats", &stats]));
    assert!(
        code == Some(1) && err.contains(&pid) && err.contains("frame 12"),
        "{err}"
    );
    assert!(!d.join("h_0000.exr").exists());
    // A report named as a lock file: the running render's (it was renamed over the lock, and a
    // third render then wrote the same frames beside the first), its checkpoint's, or any
    // other, held or not.
    let locks = [lock.clone(), d.join(".ck.lock"), d.join(".compare.lock")];
    for stats in locks.iter().map(|l| l.display().to_string()) {
        let (code, err) = refusal(args("h_####.exr", "0-1", &["--stats", &stats]));
        assert!(
            code == Some(1) && err.contains("lock file") && err.contains(&stats),
            "{err}"
        );
    }
    assert!(std::fs::read_to_string(&lock)
        .unwrap()
        .contains("frames 0-40"));
    assert!(!d.join("h_0000.exr").exists() && !d.join(".compare.lock").exists());
    // Names that never meet: f_1000.exr and up, and another stem.
    reframe_ok(&args("f_1###.exr", "0-1", &[]));
    reframe_ok(&args("g_####.exr", "0-1", &[]));
    let still_running = first.try_wait().unwrap().is_none();
    first.kill().unwrap();
    first.wait().unwrap();
    assert!(still_running, "the first render finished before the test");
    assert!(lock.exists(), "a killed holder leaves its lock file");
    reframe_ok(&args("f_0###.exr", "30-31", &[]));
    assert!(d.join("f_0030.exr").exists() && d.join("f_1001.exr").exists());
}
