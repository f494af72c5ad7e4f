//! One command per output: a second `render` on the output of one that is running is refused at
//! once, naming the first's pid, and the first finishes with the frames an undisturbed render
//! writes; the lock goes with its holder (also when it is killed).
mod common;

use common::{assert_identical, reframe, reframe_ok};
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
    let t = Instant::now();
    let o = reframe(&args("a")).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(t.elapsed() < Duration::from_secs(1), "refused too slowly");
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
