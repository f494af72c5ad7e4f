//! Renders that survive interruption, and renders split into chunks: a killed (SIGKILL) or
//! interrupted (SIGINT, SIGTERM) render resumed with `--resume`, and chunks 1..N merged with
//! `reframe merge`, must give frames bitwise identical to one uninterrupted process.
mod common;

use common::reframe_ok as run;
use reframe::image::read_image;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

/// The `reframe` command, arguments to come.
fn reframe() -> Command {
    common::reframe::<&str>(&[])
}

/// Every frame of `frames` in `a` and `b`: the same channels and the same bits.
fn assert_identical(a: &Path, b: &Path, frames: std::ops::RangeInclusive<u32>) {
    common::assert_identical(a, b, frames.map(|f| format!("f_{f:04}.exr")));
}

fn leftovers(d: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(d)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.to_string_lossy().contains(".tmp-"))
        .collect()
}

/// Wait until `ready` holds, then send `signal` to `child`; the render must still have been
/// running (otherwise nothing was interrupted and the test proves nothing).
fn interrupt_when(child: &mut Child, signal: &str, ready: impl Fn() -> bool) {
    let start = Instant::now();
    while !ready() {
        assert!(
            child.try_wait().unwrap().is_none(),
            "the render finished before it could be interrupted"
        );
        assert!(start.elapsed() < Duration::from_secs(120), "no checkpoint");
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(child.try_wait().unwrap().is_none(), "finished too early");
    assert!(common::signal(child, signal), "kill -{signal}");
}

const REUSE: [&str; 13] = [
    "render",
    "vase",
    "--method",
    "mis-exact",
    "--window",
    "5",
    "--spp",
    "2",
    "--frames",
    "4-23",
    "--res",
    "160x120",
    "--exr-float",
];

fn with(base: &[&str], more: &[&str]) -> Vec<String> {
    base.iter().chain(more).map(|s| s.to_string()).collect()
}

#[test]
fn killed_render_resumes_to_identical_frames() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let whole = d.join("whole");
    let out = |sub: &str| format!("{}/{sub}/f_####.exr", d.display());
    run(&with(&REUSE, &["--out", &out("whole")])
        .iter()
        .map(String::as_str)
        .collect::<Vec<_>>());
    // SIGKILL once the checkpoint holds some finished frames and frames in flight.
    let killed = d.join("killed");
    let args = with(
        &REUSE,
        &["--out", &out("killed"), "--checkpoint-every", "0"],
    );
    let mut child = reframe().args(&args).spawn().unwrap();
    let state = killed.join("f.checkpoint/state");
    interrupt_when(&mut child, "KILL", || {
        state.exists() && killed.join("f_0006.exr").exists()
    });
    child.wait().unwrap();
    assert!(state.exists(), "no checkpoint after the kill");
    assert!(
        !killed.join("f_0023.exr").exists(),
        "the render had finished"
    );
    // Without --resume the checkpoint is not silently overwritten.
    let o = reframe().args(&args).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("--resume"), "{err}");
    // A resume with other settings is refused, naming the setting.
    let mut other = args.clone();
    other[7] = "3".into(); // --spp 3
    let o = reframe().args(&other).arg("--resume").output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("spp: 3 vs 2") | err.contains("spp: 2 vs 3"),
        "{err}"
    );
    // A checkpoint whose trailer counts other units (edited, its CRC made to match) is said
    // to be damaged, not "of another chunk" (the render is no chunk).
    let kept_state = std::fs::read(&state).unwrap();
    let mut b = kept_state.clone();
    let n = b.len();
    let json = u64::from_le_bytes(b[n - 16..n - 8].try_into().unwrap()) as usize;
    let (start, end) = (n - 20 - json, n - 20);
    let text = String::from_utf8(b[start..end].to_vec()).unwrap();
    let at = start + text.find("\"units\":[").unwrap() + "\"units\":[".len();
    b[at] = if b[at] == b'9' { b'8' } else { b[at] + 1 };
    let crc = crc32fast::hash(&b[start..end]);
    b[end..end + 4].copy_from_slice(&crc.to_le_bytes());
    std::fs::write(&state, &b).unwrap();
    let o = reframe().args(&args).arg("--resume").output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("counts units") && err.contains("it is damaged"),
        "{err}"
    );
    std::fs::write(&state, &kept_state).unwrap();
    // A finished frame deleted or damaged since the stop is refused, naming it, and so is a
    // resume that writes elsewhere (another --out with the same checkpoint).
    let f0 = killed.join("f_0004.exr");
    let kept = std::fs::read(&f0).unwrap();
    // Deleted, garbage, cut in half (its header whole: reading the header alone passed), and
    // another frame of the same render in its place (frame 5's file).
    let half = kept[..kept.len() / 2].to_vec();
    let other = std::fs::read(killed.join("f_0005.exr")).unwrap();
    // Frame 4 of another render with the same seed: of another scene, with another method, at
    // another size (each named by its metadata or its size; they were kept, exit 0).
    let foreign = |scene: &str, method: &str, res: &str| -> Vec<u8> {
        let out = format!("{}/foreign/{scene}-{method}-{res}.exr", d.display());
        run(&[
            "render",
            scene,
            "--method",
            method,
            "--spp",
            "2",
            "--frames",
            "4-4",
            "--res",
            res,
            "--exr-float",
            "--out",
            &out,
        ]);
        std::fs::read(&out).unwrap()
    };
    let foreign = [
        foreign("cornell", "mis-exact", "160x120"),
        foreign("vase", "independent", "160x120"),
        foreign("vase", "mis-exact", "80x60"),
    ];
    for damage in [
        None,
        Some(&b"garbage"[..]),
        Some(&half[..]),
        Some(&other[..]),
        Some(&foreign[0][..]),
        Some(&foreign[1][..]),
        Some(&foreign[2][..]),
    ] {
        match damage {
            None => std::fs::remove_file(&f0).unwrap(),
            Some(b) => std::fs::write(&f0, b).unwrap(),
        }
        let o = reframe().args(&args).arg("--resume").output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            o.status.code() == Some(1)
                && err.contains("frame 4 was finished before the stop")
                && err.contains(&f0.display().to_string()),
            "{err}"
        );
        // A deleted frame is said to be gone (OpenImageIO's words for it named no reason).
        assert_eq!(damage.is_none(), err.contains("is gone"), "{err}");
    }
    std::fs::write(&f0, kept).unwrap();
    let mut png = args.clone();
    let at = png.iter().position(|a| a == "--out").unwrap() + 1;
    png[at] = format!("{}/killed/f_####.png", d.display());
    let o = reframe().args(&png).arg("--resume").output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.status.code() == Some(1) && err.contains("the checkpoint is of --out"),
        "{err}"
    );
    // The resume sweeps the checkpoint's own stale temporary (a process killed while writing
    // it) and nothing else of the folder: it removed every `*.tmp-*` there, a user's file and
    // another machine's temporary frame with them.
    let ck = killed.join("f.checkpoint");
    let theirs = [
        ck.join("plan.tmp-draft.txt"),
        ck.join(".shot_0001.exr.tmp-3999999-0.exr"),
        ck.join("state.tmp-notes"),
    ];
    for f in &theirs {
        std::fs::write(f, b"not reframe's").unwrap();
    }
    let stale = ck.join("state.tmp-3999999");
    std::fs::write(&stale, b"half a state").unwrap();
    let resumed = reframe().args(&args).arg("--resume").output().unwrap();
    assert!(
        resumed.status.success(),
        "{}",
        String::from_utf8_lossy(&resumed.stderr)
    );
    assert!(!stale.exists() && !ck.join("state").exists());
    for f in &theirs {
        assert_eq!(
            std::fs::read(f).unwrap(),
            b"not reframe's",
            "{}",
            f.display()
        );
        std::fs::remove_file(f).unwrap();
    }
    assert_identical(&whole, &killed, 4..=23);
}

#[test]
fn interrupted_render_stops_cleanly_and_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (signal, method) in [("INT", "mis"), ("TERM", "independent"), ("HUP", "mis-cv")] {
        let sub = d.join(signal);
        let out = format!("{}/f_####.exr", sub.display());
        let mut args = with(&REUSE, &["--out", &out, "--checkpoint-every", "0"]);
        if method == "independent" {
            args.splice(2..6, ["--method".to_string(), "independent".into()]);
            args[5] = "8".into(); // --spp 8: slow enough to interrupt
        } else {
            args[3] = method.into();
        }
        let whole = d.join(format!("{signal}-whole"));
        let mut wargs = args.clone();
        let n = wargs.len();
        wargs[n - 3] = format!("{}/f_####.exr", whole.display());
        wargs.truncate(n - 2);
        run(&wargs.iter().map(String::as_str).collect::<Vec<_>>());
        let mut child = reframe()
            .args(&args)
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        interrupt_when(&mut child, signal, || sub.join("f_0005.exr").exists());
        let o = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(130), "{signal}: {err}");
        assert!(
            err.contains("resume with:") && err.contains("--resume"),
            "{err}"
        );
        assert!(sub.join("f.checkpoint/state").exists());
        assert!(
            leftovers(&sub).is_empty(),
            "half-written files: {:?}",
            leftovers(&sub)
        );
        assert!(leftovers(&sub.join("f.checkpoint")).is_empty());
        // Every frame file there is complete (it reads), and the render stopped early.
        let written: Vec<_> = std::fs::read_dir(&sub)
            .unwrap()
            .flatten()
            .filter(|e| e.path().extension().is_some_and(|x| x == "exr"))
            .collect();
        assert!(written.len() < 20, "{signal}: nothing was interrupted");
        for e in &written {
            read_image(&e.path()).unwrap();
        }
        // The hint is a command that works; for the independent tracer, with `--aov` added
        // too, which changes nothing it writes (it refused to resume: "other settings").
        let hint = err.lines().find(|l| l.starts_with("resume with:")).unwrap();
        assert!(hint.ends_with("--resume"), "{hint}");
        // Another `--checkpoint` folder, holding none, is refused while this one waits, with
        // or without `--resume`: it rendered over the frames the checkpoint counts finished
        // (which then could not be resumed), or started again without a word.
        let other = d.join(format!("{signal}-other"));
        let before = common::snapshot(&sub);
        for resume in [&[][..], &["--resume"]] {
            let o = reframe()
                .args(&args)
                .args(["--checkpoint", other.to_str().unwrap()])
                .args(resume)
                .output()
                .unwrap();
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(1), "{resume:?}: {err}");
            let want = format!(
                "{} holds the checkpoint of an interrupted render",
                sub.join("f.checkpoint").display()
            );
            assert!(err.contains(&want), "{resume:?}: {err}");
        }
        assert_eq!(
            common::snapshot(&sub),
            before,
            "the refusals changed the output folder"
        );
        assert!(!other.exists(), "the refusals made the other folder");
        if signal == "INT" {
            // Another `--out` of the same stem shares the default folder, holds none of its
            // frames, and renders with a folder of its own.
            let png = format!("{}/f_####.png", sub.display());
            let mut pargs = args.clone();
            let at = pargs.iter().position(|a| *a == out).unwrap();
            pargs[at] = png;
            let o = reframe()
                .args(&pargs)
                .args(["--checkpoint", other.to_str().unwrap()])
                .output()
                .unwrap();
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(0), "{err}");
            assert!(sub.join("f_0004.png").exists() && sub.join("f.checkpoint/state").exists());
        }
        let aov: &[&str] = if method == "independent" {
            &["--aov"]
        } else {
            &[]
        };
        run(&args
            .iter()
            .map(String::as_str)
            .chain(["--resume"])
            .chain(aov.iter().copied())
            .collect::<Vec<_>>());
        assert_identical(&whole, &sub, 4..=23);
    }
}

#[test]
fn chunks_merge_to_identical_frames_for_any_n() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let base = [
        "render",
        "vase",
        "--method",
        "mis-exact",
        "--window",
        "5",
        "--spp",
        "1",
        "--frames",
        "10-21",
        "--res",
        "48x36",
        "--exr-float",
        "--aov",
    ];
    // mis-cv's two folds merge the same way: its accumulators carry both. With 2 native
    // samples, so that the range's first and last frames (one group each) fold by sample
    // index: every chunk must fold them as the whole run does.
    let mut cv_base: Vec<&str> = base
        .iter()
        .map(|a| if *a == "mis-exact" { "mis-cv" } else { a })
        .collect();
    cv_base[7] = "2";
    let cv_whole = d.join("cv-whole");
    let cv_out = format!("{}/f_####.exr", cv_whole.display());
    run(&with(&cv_base, &["--out", &cv_out])
        .iter()
        .map(String::as_str)
        .collect::<Vec<_>>());
    let cv = d.join("cv");
    let cv_sub = format!("{}/f_####.exr", cv.display());
    for k in [2, 3, 1] {
        run(
            &with(&cv_base, &["--out", &cv_sub, "--chunk", &format!("{k}/3")])
                .iter()
                .map(String::as_str)
                .collect::<Vec<_>>(),
        );
    }
    run(&["merge", "--chunks", "3", "--out", &cv_sub]);
    assert_identical(&cv_whole, &cv, 10..=21);
    let whole = d.join("whole");
    let wout = format!("{}/f_####.exr", whole.display());
    run(&with(&base, &["--out", &wout])
        .iter()
        .map(String::as_str)
        .collect::<Vec<_>>());
    // 8 groups: N = 1 (a chunk of everything), 3 (uneven), 8 (one group each).
    for n in [1u32, 3, 8] {
        let sub = d.join(format!("n{n}"));
        let out = format!("{}/f_####.exr", sub.display());
        let mut partials = vec![];
        // Render the chunks in reverse order: the merge must not care.
        for k in (1..=n).rev() {
            let chunk = format!("{k}/{n}");
            let o = run(&with(&base, &["--out", &out, "--chunk", &chunk])
                .iter()
                .map(String::as_str)
                .collect::<Vec<_>>());
            let p = sub.join(format!("f.chunk-{k}-of-{n}.partial"));
            assert!(String::from_utf8_lossy(&o.stdout).contains(&p.display().to_string()));
            assert!(!sub.join("f_0010.exr").exists(), "a chunk wrote frames");
            partials.push(p.display().to_string());
        }
        if n > 1 {
            // One chunk missing: refused, naming it, and nothing written.
            let o = reframe()
                .arg("merge")
                .args(&partials[1..])
                .output()
                .unwrap();
            let err = String::from_utf8_lossy(&o.stderr);
            assert!(
                !o.status.success() && err.contains(&format!("chunk {n}/{n} is missing")),
                "{err}"
            );
            assert!(!sub.join("f_0010.exr").exists());
        }
        run(&["merge"]
            .into_iter()
            .chain(partials.iter().map(String::as_str))
            .collect::<Vec<_>>());
        assert_identical(&whole, &sub, 10..=21);
    }
    // Chunks of different renders do not merge.
    let other = d.join("other");
    let oout = format!("{}/f_####.exr", other.display());
    let mut b2 = base.to_vec();
    b2[7] = "2";
    for k in 1..=2 {
        run(&with(&b2, &["--out", &oout, "--chunk", &format!("{k}/2")])
            .iter()
            .map(String::as_str)
            .collect::<Vec<_>>());
    }
    let o = reframe()
        .args(["merge"])
        .arg(d.join("n3/f.chunk-1-of-3.partial"))
        .arg(other.join("f.chunk-2-of-2.partial"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("not chunks of the same render"),
        "{err}"
    );
    // Chunks given a relative --out and merged from another folder without --out: the frames
    // go beside the partials (where the chunks were told to write them), not under the merge's
    // own folder, and a missing chunk is named there too.
    let ran = d.join("ran");
    std::fs::create_dir(&ran).unwrap();
    for k in 1..=2 {
        let args = with(
            &b2,
            &["--out", "o/f_####.exr", "--chunk", &format!("{k}/2")],
        );
        let o = reframe().args(&args).current_dir(&ran).output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let elsewhere = d.join("elsewhere");
    std::fs::create_dir(&elsewhere).unwrap();
    let second = ran.join("o/f.chunk-2-of-2.partial");
    let o = reframe()
        .arg("merge")
        .arg(&second)
        .current_dir(&elsewhere)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    let first = ran.join("o/f.chunk-1-of-2.partial");
    assert!(
        !o.status.success() && err.contains(&first.display().to_string()),
        "{err}"
    );
    let o = reframe()
        .arg("merge")
        .arg(&first)
        .arg(&second)
        .current_dir(&elsewhere)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(ran.join("o/f_0010.exr").exists() && ran.join("o/f_0021.exr").exists());
    assert!(common::files_under(&elsewhere).is_empty());
    // A truncated partial (a copy cut short) is refused, naming the file.
    let p = d.join("n3/f.chunk-2-of-3.partial");
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
    let o = reframe().arg("merge").arg(&p).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("not a complete"),
        "{err}"
    );
}

#[test]
fn a_killed_chunk_resumes_and_merges_identically() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let base = with(&REUSE, &[]);
    let whole = d.join("whole");
    let wout = format!("{}/f_####.exr", whole.display());
    let mut a = base.clone();
    a.extend(["--out".into(), wout]);
    run(&a.iter().map(String::as_str).collect::<Vec<_>>());
    let sub = d.join("chunks");
    let out = format!("{}/f_####.exr", sub.display());
    let chunk = |k: u32| {
        let mut a = base.clone();
        a.extend([
            "--out".into(),
            out.clone(),
            "--chunk".into(),
            format!("{k}/2"),
            "--checkpoint-every".into(),
            "0".into(),
        ]);
        a
    };
    run(&chunk(2).iter().map(String::as_str).collect::<Vec<_>>());
    let mut child = reframe().args(chunk(1)).spawn().unwrap();
    let state = sub.join("f.chunk-1-of-2.checkpoint/state");
    let log = sub.join("f.chunk-1-of-2.partial.log");
    // Killed once the log holds retired frames: the resume must truncate what came after.
    interrupt_when(&mut child, "KILL", || {
        state.exists() && std::fs::metadata(&log).is_ok_and(|m| m.len() > 300_000)
    });
    child.wait().unwrap();
    let o = reframe()
        .arg("merge")
        .arg(sub.join("f.chunk-2-of-2.partial"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    let mut resume = chunk(1);
    resume.push("--resume".into());
    // The log moved away: the resume says it is missing (it said "shorter than its checkpoint
    // says", of a file that was not there), and goes ahead once it is back.
    let aside = sub.join("log-aside");
    std::fs::rename(&log, &aside).unwrap();
    let o = reframe().args(&resume).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.status.code() == Some(1)
            && err.contains("the chunk log is missing, but its checkpoint says it holds"),
        "{err}"
    );
    assert!(!log.exists(), "the refusal made no log");
    std::fs::rename(&aside, &log).unwrap();
    // A record the checkpoint counts, damaged in the log since: the resume refuses it (the
    // frames in the log are not rendered again), and goes ahead once it is whole again.
    let mut bytes = std::fs::read(&log).unwrap();
    bytes[1000] ^= 0x40;
    std::fs::write(&log, &bytes).unwrap();
    let o = reframe().args(&resume).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.status.code() == Some(1) && err.contains("at byte 0 is damaged"),
        "{err}"
    );
    bytes[1000] ^= 0x40;
    std::fs::write(&log, &bytes).unwrap();
    // Another run's log of the same frames and sizes in its place (another seed's chunk 1/2,
    // whose partial file begins with its log): its records read back whole, but they are not
    // the ones the checkpoint counted (it was resumed and merged as this run's, exit 0).
    let mut other = base.clone();
    other.extend(
        ["--chunk", "1/2", "--seed", "7", "--out"]
            .map(String::from)
            .into_iter()
            .chain([format!("{}/f_####.exr", d.join("other").display())]),
    );
    run(&other.iter().map(String::as_str).collect::<Vec<_>>());
    let theirs = std::fs::read(d.join("other/f.chunk-1-of-2.partial")).unwrap();
    std::fs::write(&log, &theirs[..bytes.len().min(theirs.len())]).unwrap();
    let o = reframe().args(&resume).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.status.code() == Some(1)
            && err.contains("is not the one its checkpoint counted (the log of another run?)"),
        "{err}"
    );
    std::fs::write(&log, &bytes).unwrap();
    run(&resume.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(!log.exists() && !state.exists());
    // Resumed again once complete (a Slurm array resubmitted whole): nothing to do, and the
    // partial file is left as it is.
    let partial = sub.join("f.chunk-1-of-2.partial");
    let before = std::fs::metadata(&partial).unwrap().modified().unwrap();
    let o = run(&resume.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(
        String::from_utf8_lossy(&o.stdout).contains("chunk 1/2 is already complete"),
        "{}",
        String::from_utf8_lossy(&o.stdout)
    );
    assert_eq!(
        std::fs::metadata(&partial).unwrap().modified().unwrap(),
        before
    );
    assert!(!state.exists() && !log.exists());
    // A complete partial damaged since (a bad copy on a shared file system): merge refuses it,
    // and --resume renders the chunk again (it called it complete, so that re-running the
    // chunk never mended the set); the merge below gives the whole render's frames.
    let mut bad = std::fs::read(&partial).unwrap();
    bad[1000] ^= 0x40;
    std::fs::write(&partial, &bad).unwrap();
    let o = reframe()
        .arg("merge")
        .arg(&partial)
        .arg(sub.join("f.chunk-2-of-2.partial"))
        .output()
        .unwrap();
    assert!(!o.status.success());
    let o = run(&resume.iter().map(String::as_str).collect::<Vec<_>>());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("damaged record at byte 0") && err.contains("chunk 1/2 is rendered again"),
        "{err}"
    );
    // Cut short (its trailer gone): said so too, and rendered again.
    let len = std::fs::metadata(&partial).unwrap().len();
    std::fs::OpenOptions::new()
        .write(true)
        .open(&partial)
        .unwrap()
        .set_len(len / 2)
        .unwrap();
    let o = run(&resume.iter().map(String::as_str).collect::<Vec<_>>());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("not a complete reframe state file")
            && err.contains("chunk 1/2 is rendered again"),
        "{err}"
    );
    run(&[
        "merge",
        &sub.join("f.chunk-1-of-2.partial").display().to_string(),
        &sub.join("f.chunk-2-of-2.partial").display().to_string(),
    ]);
    assert_identical(&whole, &sub, 4..=23);
}

#[test]
fn a_report_never_replaces_a_state_file() {
    // Chunk 1's --stats naming chunk 2's finished partial was written over it (exit 0; the
    // merge then found no partial). A report must not replace any run's state file.
    let dir = tempfile::tempdir().unwrap();
    let out = format!("{}/f_####.exr", dir.path().display());
    let chunk = |k: &str| -> Vec<String> {
        let args = [
            "render", "cornell", "--spp", "1", "--frames", "0-1", "--res", "16x12",
        ];
        let more = ["--chunk", k, "--out", &out];
        args.iter().chain(&more).map(|a| a.to_string()).collect()
    };
    run(&chunk("2/2"));
    let partial = dir.path().join("f.chunk-2-of-2.partial");
    let before = std::fs::read(&partial).unwrap();
    let stats = partial.to_str().unwrap();
    let o = reframe()
        .args(chunk("1/2"))
        .args(["--stats", stats])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("that is a reframe state file"),
        "{err}"
    );
    assert_eq!(std::fs::read(&partial).unwrap(), before);
    run(&chunk("1/2"));
    run(&["merge", "--chunks", "2", "--out", &out]);
}

#[test]
fn a_chunk_never_replaces_another_renders_partial() {
    // `f_####.exr` and `f_####.png` share partial names: a chunk of the PNG sequence at other
    // settings replaced the EXR render's finished chunk (exit 0), and its merge was refused.
    let dir = tempfile::tempdir().unwrap();
    let chunk = |ext: &str, spp: &str, more: &[&str]| -> Vec<String> {
        let out = format!("{}/f_####.{ext}", dir.path().display());
        let args = [
            "render", "cornell", "--frames", "0-1", "--res", "16x12", "--chunk", "1/2", "--spp",
            spp, "--out", &out,
        ];
        args.iter().chain(more).map(|a| a.to_string()).collect()
    };
    run(&chunk("exr", "2", &[]));
    let partial = dir.path().join("f.chunk-1-of-2.partial");
    let before = std::fs::read(&partial).unwrap();
    for resume in [&[][..], &["--resume"]] {
        let o = reframe().args(chunk("png", "1", resume)).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{err}");
        assert!(
            err.contains("partial file of another render, of --out") && err.contains("f_####.exr"),
            "{err}"
        );
        assert!(
            err.contains("have this one's names ('f':")
                && err.contains("give this render an --out of another name"),
            "{err}"
        );
        assert!(std::fs::read(&partial).unwrap() == before);
    }
    // Of the same settings but another --out, it is still another sequence's.
    let o = reframe().args(chunk("png", "2", &[])).output().unwrap();
    assert!(!o.status.success());
    assert!(std::fs::read(&partial).unwrap() == before);
    // The same --out's partial is its own, whatever its settings (a resubmitted array after a
    // change): rendered again with --resume, and again at the first settings, and merged.
    run(&chunk("exr", "1", &["--resume"]));
    run(&chunk("exr", "2", &[]));
    run(&chunk("exr", "2", &[])
        .iter()
        .map(|a| a.replace("1/2", "2/2"))
        .collect::<Vec<_>>());
    let out = format!("{}/f_####.exr", dir.path().display());
    run(&["merge", "--chunks", "2", "--out", &out]);
}

#[test]
fn a_chunk_of_other_frames_never_replaces_a_finished_chunk_of_the_same_out() {
    // Two job arrays over different ranges of one shot given one --out: the second's chunk
    // replaced the first's finished one (a chunk file's name says only which chunk it is),
    // exit 0, and the merge wrote the second range alone.
    let dir = tempfile::tempdir().unwrap();
    let out = format!("{}/f_####.exr", dir.path().display());
    let chunk = |frames: &str, more: &[&str]| -> Vec<String> {
        let args = [
            "render", "cornell", "--frames", frames, "--res", "16x12", "--spp", "1", "--chunk",
            "1/1", "--out", &out,
        ];
        args.iter().chain(more).map(|a| a.to_string()).collect()
    };
    run(&chunk("0-1", &[]));
    let partial = dir.path().join("f.chunk-1-of-1.partial");
    let before = std::fs::read(&partial).unwrap();
    for more in [&[][..], &["--resume"], &["--seed", "3"]] {
        let o = reframe().args(chunk("2-3", more)).output().unwrap();
        common::assert_refused(
            &o,
            "holds chunk 1/1 of frames 0-1 of 'cornell', finished, and this render is of frames 2-3",
        );
        common::assert_refused(&o, "give it another --out, or delete that file");
        assert!(std::fs::read(&partial).unwrap() == before);
    }
    // Deleted, the chunk renders; the same frames at other settings replace it (an array
    // resubmitted after a change), and the merge writes them.
    std::fs::remove_file(&partial).unwrap();
    run(&chunk("2-3", &[]));
    run(&chunk("2-3", &["--seed", "3"]));
    run(&["merge", "--chunks", "1", "--out", &out]);
    assert!(dir.path().join("f_0003.exr").exists() && !dir.path().join("f_0000.exr").exists());
}

#[test]
fn a_merge_says_which_frames_came_out_black() {
    // A camera 9e17 units from the scene, looking at it: every pixel's ray passes beside it,
    // and its frames are black; the chunks write no frames, so the merge says it.
    let dir = tempfile::tempdir().unwrap();
    let base = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus/base");
    for f in ["s.obj", "s.mtl"] {
        std::fs::copy(base.join(f), dir.path().join(f)).unwrap();
    }
    let toml = std::fs::read_to_string(base.join("s.toml"))
        .unwrap()
        .replace("position = [0.0, 1.0, 3.0]", "position = [0.0, 1.0, 9e17]")
        .replace("look_at = [0.0, 0.0, 0.0]", "look_at = [0.0, 1.0, 0.0]");
    assert!(toml.contains("9e17"));
    let scene = dir.path().join("s.toml");
    std::fs::write(&scene, toml).unwrap();
    let out = format!("{}/f_####.exr", dir.path().display());
    for k in ["1/2", "2/2"] {
        let o = reframe()
            .args([
                "render",
                scene.to_str().unwrap(),
                "--chunk",
                k,
                "--out",
                &out,
            ])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            o.status.success() && !err.contains("came out black"),
            "{err}"
        );
    }
    let o = reframe()
        .args(["merge", "--chunks", "2", "--out", &out])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("warning: every frame (0-1) came out black in every pixel"),
        "{err}"
    );
}

#[test]
fn a_checkpoint_that_cannot_be_written_is_named_with_what_a_resume_does() {
    // Under a file-size limit the checkpoint's write failed, naming its temporary file alone
    // and saying neither what was kept nor what --resume would do.
    let dir = tempfile::tempdir().unwrap();
    let out = format!("{}/f_####.exr", dir.path().display());
    let args = [
        "render",
        "cornell",
        "--method",
        "mis-cv",
        "--window",
        "3",
        "--res",
        "64x48",
        "--spp",
        "8",
        "--frames",
        "0-23",
        "--out",
        &out,
        "--checkpoint-every",
        "0",
    ];
    let quoted: Vec<String> = args.iter().map(|a| format!("'{a}'")).collect();
    let cmd = format!(
        "ulimit -f 120 && exec '{}' {}",
        env!("CARGO_BIN_EXE_reframe"),
        quoted.join(" ")
    );
    let o = Command::new("sh").args(["-c", &cmd]).output().unwrap();
    let state = dir.path().join("f.checkpoint/state");
    common::assert_refused(
        &o,
        &format!(
            "checkpoint not written (no checkpoint of this render is on disk: --resume would \
             start from its beginning): writing {}: File too large",
            state.display()
        ),
    );
    // As said: without the limit, --resume starts over and finishes.
    run(&with(&args, &["--resume"]));
    assert!(dir.path().join("f_0023.exr").exists() && !state.exists());
}

#[test]
fn a_merge_never_writes_over_an_interrupted_renders_frames() {
    // A merge into frames an interrupted render's checkpoint counts finished wrote over them
    // (exit 0), and the render's resume was then refused.
    let dir = tempfile::tempdir().unwrap();
    let (c, o) = (dir.path().join("c"), dir.path().join("o"));
    let args = |out: &Path, more: &[&str]| -> Vec<String> {
        let out = format!("{}/f_####.exr", out.display());
        let base = [
            "render", "cornell", "--frames", "0-5", "--res", "64x48", "--out", &out,
        ];
        base.iter().chain(more).map(|a| a.to_string()).collect()
    };
    run(&args(&c, &["--spp", "1", "--chunk", "1/1"]));
    let render = args(
        &o,
        &["--spp", "512", "--threads", "1", "--checkpoint-every", "0"],
    );
    let mut child = reframe()
        .args(&render)
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    interrupt_when(&mut child, "INT", || o.join("f_0000.exr").exists());
    assert_eq!(child.wait().unwrap().code(), Some(130));
    let first = std::fs::read(o.join("f_0000.exr")).unwrap();
    let partial = c.join("f.chunk-1-of-1.partial");
    let out = format!("{}/f_####.exr", o.display());
    let m = reframe()
        .args(["merge", partial.to_str().unwrap(), "--out", &out])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&m.stderr);
    assert!(!m.status.success(), "{err}");
    assert!(
        err.contains("holds the checkpoint of an interrupted render"),
        "{err}"
    );
    // Nor under another pattern naming the same files (`f_0###.exr`; only the same pattern was
    // refused), a merge or a render alike; a pattern of other names is free.
    let other = format!("{}/f_0###.exr", o.display());
    let same_names = "holds the checkpoint of an interrupted render to --out";
    for args in [
        vec!["merge", partial.to_str().unwrap(), "--out", &other],
        vec![
            "render", "cornell", "--frames", "2-3", "--res", "8x6", "--out", &other,
        ],
    ] {
        let o = reframe().args(&args).output().unwrap();
        common::assert_refused(&o, same_names);
        common::assert_refused(&o, "which writes frames of the same names");
    }
    assert!(std::fs::read(o.join("f_0000.exr")).unwrap() == first);
    let free = format!("{}/g_####.exr", o.display());
    run(&[
        "render", "cornell", "--frames", "2-3", "--res", "8x6", "--out", &free,
    ]);
    // Another extension of the same stem shares the default checkpoint folder: refused with
    // the checkpoint's `--out` named and a way out that works (`--resume` would be refused
    // too: the checkpoint is of another `--out`), which is a folder of its own.
    let png = format!("{}/f_####.png", o.display());
    let own = dir.path().join("own");
    let png_render = [
        "render", "cornell", "--frames", "2-3", "--res", "8x6", "--out", &png,
    ];
    let r = reframe().args(png_render).output().unwrap();
    common::assert_refused(&r, &format!("to --out {out}: resume that render"));
    common::assert_refused(&r, "--checkpoint DIR");
    run(&with(&png_render, &["--checkpoint", own.to_str().unwrap()]));
    // The render resumes; then the merge may write (over finished frames, as asked).
    run(&with(
        &render.iter().map(String::as_str).collect::<Vec<_>>(),
        &["--resume"],
    ));
    run(&["merge", partial.to_str().unwrap(), "--out", &out]);
}

#[test]
fn sequences_named_apart_after_the_frame_number_keep_their_own_chunks() {
    // A stereo pair, `e-####-L.exr` and `e-####-R.exr` with other seeds, rendered in chunks
    // in turn: both once shared one partial file per chunk (the name's stem stopped at the
    // `#`s), so R's chunk 1 silently replaced L's and L's merge was refused.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let args = |eye: &str, seed: &str, more: &[&str]| -> Vec<String> {
        let out = format!("{}/e-####-{eye}.exr", d.display());
        let base = [
            "render", "cornell", "--spp", "1", "--frames", "0-1", "--res", "16x12", "--seed", seed,
            "--out", &out,
        ];
        base.iter().chain(more).map(|a| a.to_string()).collect()
    };
    for k in ["1/2", "2/2"] {
        run(&args("L", "0", &["--chunk", k]));
        run(&args("R", "1", &["--chunk", k]));
    }
    for (eye, seed) in [("L", "0"), ("R", "1")] {
        assert!(d.join(format!("e-{eye}.chunk-1-of-2.partial")).is_file());
        run(&[
            "merge",
            "--chunks",
            "2",
            "--out",
            &format!("{}/e-####-{eye}.exr", d.display()),
        ]);
        // Each merged sequence is its own render's, bitwise.
        let whole = d.join(format!("whole-{eye}"));
        run(&args(eye, seed, &[])
            .into_iter()
            .map(|a| a.replace(&d.display().to_string(), &whole.display().to_string()))
            .collect::<Vec<_>>());
        common::assert_identical(d, &whole, (0..=1).map(|f| format!("e-{f:04}-{eye}.exr")));
    }
}

#[test]
fn a_chunk_log_planted_as_a_link_or_a_fifo_is_refused_and_nothing_is_written() {
    // The chunk's log is truncated and written: a symbolic or hard link planted in its place
    // had the scene's OBJ overwritten with state records (exit 0), a FIFO blocked for ever.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let base = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus/base");
    for f in ["s.toml", "s.obj", "s.mtl"] {
        std::fs::copy(base.join(f), d.join(f)).unwrap();
    }
    let obj = std::fs::read(d.join("s.obj")).unwrap();
    std::fs::create_dir(d.join("o")).unwrap();
    let log = d.join("o/f.chunk-1-of-2.partial.log");
    let out = format!("{}/o/f_####.exr", d.display());
    let scene = d.join("s.toml").display().to_string();
    let args = [
        "render", &scene, "--res", "16x12", "--spp", "1", "--frames", "0-1", "--chunk", "1/2",
        "--out", &out,
    ];
    for (plant, what) in [
        ("symlink", "is a symbolic link"),
        ("hard link", "is a file with other names (a hard link)"),
        ("fifo", "is a named pipe (FIFO)"),
    ] {
        match plant {
            "symlink" => std::os::unix::fs::symlink(d.join("s.obj"), &log).unwrap(),
            "hard link" => std::fs::hard_link(d.join("s.obj"), &log).unwrap(),
            _ => {
                let ok = Command::new("mkfifo").arg(&log).status().unwrap();
                assert!(ok.success());
            }
        }
        let owned: Vec<String> = args.iter().map(|a| a.to_string()).collect();
        let o = common::run_reframe(&owned, Duration::from_secs(20));
        assert_eq!(o.code, Some(1), "{plant}: {}", o.stderr);
        assert!(o.stderr.contains(what), "{plant}: {}", o.stderr);
        assert_eq!(std::fs::read(d.join("s.obj")).unwrap(), obj, "{plant}");
        let left: Vec<_> = std::fs::read_dir(d.join("o"))
            .unwrap()
            .flatten()
            .map(|e| e.path())
            .collect();
        assert!(
            left.len() == 1 && left[0] == log,
            "{plant}: nothing made but what was planted: {left:?}"
        );
        std::fs::remove_file(&log).unwrap();
    }
    run(&args);
}

#[test]
fn a_checkpoint_folder_named_like_a_frame_is_refused_at_once() {
    // It rendered frame 0 and then failed writing frame 1 ("is a directory"), leaving a
    // checkpoint folder named f_0001.exr.
    let dir = tempfile::tempdir().unwrap();
    let out = format!("{}/o/f_####.exr", dir.path().display());
    let ckpt = format!("{}/o/f_0001.exr", dir.path().display());
    let o = reframe()
        .args([
            "render",
            "cornell",
            "--method",
            "mis-exact",
            "--window",
            "3",
            "--spp",
            "1",
        ])
        .args([
            "--frames",
            "0-2",
            "--res",
            "16x12",
            "--out",
            &out,
            "--checkpoint",
            &ckpt,
        ])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success()
            && err.contains("that is also where --out")
            && err.trim().lines().count() == 1,
        "{err}"
    );
    assert!(!dir.path().join("o").exists());
}

#[test]
fn a_render_clears_the_temporary_frames_a_killed_one_left() {
    // A process killed while writing a frame leaves `.NAME.tmp-PID-N.ext`; the next render of
    // the same pattern (holding its lock) removes those of its frames, and nothing else.
    let dir = tempfile::tempdir().unwrap();
    let o = dir.path().join("o");
    std::fs::create_dir(&o).unwrap();
    let (ours, other) = (
        o.join(".f_0001.exr.tmp-4194303-7.exr"),
        o.join(".g_0001.exr.tmp-4194303-7.exr"),
    );
    std::fs::write(&ours, b"half a frame").unwrap();
    std::fs::write(&other, b"another pattern's").unwrap();
    let out = format!("{}/f_####.exr", o.display());
    run(&[
        "render", "cornell", "--spp", "1", "--frames", "0-2", "--res", "16x12", "--out", &out,
    ]);
    assert!(!ours.exists() && other.exists());
    assert!(o.join("f_0001.exr").exists());
}

/// A run's state is its own while it runs: a report (`--stats`) named as a running chunk's log
/// or into a running render's checkpoint folder is refused, and a chunk whose log was replaced
/// under it by another program (a rename over it) fails naming the log and writes no partial
/// file (it had renamed whatever sat at the log's path into place and reported success).
#[test]
fn a_running_chunks_state_is_never_replaced_or_taken_for_its_own() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let sub = d.join("chunks");
    let out = format!("{}/f_####.exr", sub.display());
    let mut chunk = with(&REUSE, &["--out", &out, "--chunk", "1/2"]);
    chunk.extend(["--checkpoint-every".into(), "0".into()]);
    let mut child = reframe()
        .args(&chunk)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let state = sub.join("f.chunk-1-of-2.checkpoint/state");
    let log = sub.join("f.chunk-1-of-2.partial.log");
    let start = Instant::now();
    while !(state.exists() && log.exists()) {
        assert!(
            child.try_wait().unwrap().is_none(),
            "the chunk finished early"
        );
        assert!(start.elapsed() < Duration::from_secs(120), "no checkpoint");
        std::thread::sleep(Duration::from_millis(5));
    }
    let report = |at: &Path| {
        let out = d.join("other/f_####.exr");
        let o = reframe()
            .args([
                "render", "cornell", "--res", "8x6", "--spp", "1", "--frames", "0",
            ])
            .arg("--out")
            .arg(&out)
            .arg("--stats")
            .arg(at)
            .output()
            .unwrap();
        (
            o.status.code(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };
    let (code, err) = report(&log);
    assert!(
        code == Some(1) && err.contains("chunk's partial file or its log"),
        "{err}"
    );
    let (code, err) = report(&state.with_file_name("report.json"));
    assert!(
        code == Some(1) && err.contains("checkpoint folder of a running"),
        "{err}"
    );
    assert!(
        child.try_wait().unwrap().is_none(),
        "the chunk finished early"
    );
    // Another program's file renamed over the log.
    let other = sub.join("other.txt");
    std::fs::write(&other, "not a log\n").unwrap();
    std::fs::rename(&other, &log).unwrap();
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.status.code() == Some(1) && err.contains("was replaced by another file"),
        "{err}"
    );
    assert!(!sub.join("f.chunk-1-of-2.partial").exists());
}

/// A short render that checkpoints after every unit: two frames of `cornell` at 32 x 24, 1 spp.
const SHORT_CHECKPOINTED: [&str; 10] = [
    "render",
    "cornell",
    "--res",
    "32x24",
    "--spp",
    "1",
    "--frames",
    "0-1",
    "--checkpoint-every",
    "0",
];

/// A process killed while writing its first checkpoint leaves only `state.tmp-PID` in the
/// folder: the next run (with or without `--resume`) removes it, and the folder goes when the
/// render completes (no later run removed it, and the folder outlived every render). A user's
/// file there stays, and so does the folder.
#[test]
fn a_first_checkpoint_left_half_written_is_swept() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ck = d.join("o/f.checkpoint");
    let args = |resume: bool| {
        let mut a = with(
            &SHORT_CHECKPOINTED,
            &["--out", &format!("{}/o/f_####.exr", d.display())],
        );
        if resume {
            a.push("--resume".into());
        }
        a
    };
    for resume in [false, true] {
        std::fs::create_dir_all(&ck).unwrap();
        // A pid no process has (above the largest the kernel gives, 2^22).
        std::fs::write(ck.join("state.tmp-2147483646"), "half a checkpoint").unwrap();
        run(&args(resume).iter().map(String::as_str).collect::<Vec<_>>());
        assert!(
            !ck.exists(),
            "resume {resume}: {:?}",
            common::files_under(&ck)
        );
    }
    std::fs::create_dir_all(&ck).unwrap();
    std::fs::write(ck.join("state.tmp-2147483646"), "half a checkpoint").unwrap();
    std::fs::write(ck.join("notes.txt"), "mine").unwrap();
    run(&args(false).iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(
        common::files_under(&ck),
        [ck.join("notes.txt")],
        "the user's file stays, the temporary goes"
    );
}

/// A checkpoint folder you made for the render (empty, or with its mode or ACLs set up on
/// purpose) is kept when the render completes: the render removes only a folder a run of it
/// made (it removed any folder it left empty).
#[test]
fn a_checkpoint_folder_made_beforehand_is_kept() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ck = d.join("mine");
    std::fs::create_dir(&ck).unwrap();
    let out = format!("{}/o/f_####.exr", d.display());
    let ck_arg = ck.display().to_string();
    let args = with(
        &SHORT_CHECKPOINTED,
        &["--checkpoint", &ck_arg, "--out", &out],
    );
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    run(&args);
    assert!(ck.is_dir(), "the folder made beforehand was removed");
    assert!(
        common::files_under(&ck).is_empty(),
        "{:?}",
        common::files_under(&ck)
    );
    // One the render made goes.
    let made = d.join("made");
    let made_arg = made.display().to_string();
    let mut args = args.to_vec();
    args[11] = &made_arg;
    run(&args);
    assert!(!made.exists());
}

/// `reframe` run as the user `nobody` (`setpriv`), for tests of files another user cannot
/// read: `None` (the test says it is skipped) unless the tests run as root, as CI runs them,
/// and `nobody` can run the binary (a checkout under /root is not theirs to enter).
fn as_nobody() -> Option<impl Fn() -> std::process::Command> {
    let nobody = || {
        let mut c = std::process::Command::new("setpriv");
        c.args(["--reuid=65534", "--regid=65534", "--clear-groups"])
            .arg(env!("CARGO_BIN_EXE_reframe"));
        c
    };
    let root = std::process::Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| o.stdout == b"0\n");
    if !root
        || !nobody()
            .arg("--version")
            .output()
            .is_ok_and(|o| o.status.success())
    {
        eprintln!("skipped: needs root, setpriv, and a binary that another user can run");
        return None;
    }
    Some(nobody)
}

/// A chunk's partial file that cannot be opened (another user's in a shared folder, mode 600)
/// is refused in one line by `--resume`, as `merge` refuses it: it is not damaged, and the chunk
/// rendered again failed only at its end, on the rename. Run as root (as CI runs), the refused
/// user is `nobody` (`setpriv`).
#[test]
fn a_partial_that_cannot_be_opened_is_refused_not_rendered_again() {
    use std::os::unix::fs::PermissionsExt;
    let Some(nobody) = as_nobody() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::set_permissions(d, std::fs::Permissions::from_mode(0o1777)).unwrap();
    let out = format!("{}/o/f_####.exr", d.display());
    let args = with(
        &[
            "render", "cornell", "--res", "16x12", "--spp", "1", "--frames", "0-3",
        ],
        &["--chunk", "1/2", "--out", &out],
    );
    run(&args.iter().map(String::as_str).collect::<Vec<_>>());
    std::fs::set_permissions(d.join("o"), std::fs::Permissions::from_mode(0o1777)).unwrap();
    let partial = d.join("o/f.chunk-1-of-2.partial");
    std::fs::set_permissions(&partial, std::fs::Permissions::from_mode(0o600)).unwrap();
    let before = std::fs::read(&partial).unwrap();
    let o = nobody().args(&args).arg("--resume").output().unwrap();
    common::assert_refused(
        &o,
        "cannot read the chunk's partial file (Permission denied",
    );
    assert_eq!(std::fs::read(&partial).unwrap(), before);
}

/// A finished frame that cannot be opened at a resume (another user's, mode 600 in a shared
/// folder) is refused saying so, and what mends it: OpenImageIO's words for it were "not an
/// OpenEXR file", and the advice was to render every frame again. Run as root (as CI runs), the
/// render and its resume are `nobody`'s (`setpriv`).
#[test]
fn a_finished_frame_that_cannot_be_opened_is_refused_saying_so() {
    use std::os::unix::fs::PermissionsExt;
    let Some(nobody) = as_nobody() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::set_permissions(d, std::fs::Permissions::from_mode(0o1777)).unwrap();
    let out = format!("{}/f_####.exr", d.display());
    let args = [
        "render",
        "cornell",
        "--res",
        "64x48",
        "--spp",
        "64",
        "--frames",
        "0-23",
        "--threads",
        "1",
        "--checkpoint-every",
        "0",
        "--out",
        &out,
    ];
    let mut child = nobody().args(args).spawn().unwrap();
    let state = d.join("f.checkpoint/state");
    interrupt_when(&mut child, "KILL", || {
        state.exists() && d.join("f_0001.exr").exists()
    });
    child.wait().unwrap();
    let f0 = d.join("f_0000.exr");
    std::fs::set_permissions(&f0, std::fs::Permissions::from_mode(0o000)).unwrap();
    let o = nobody().args(args).arg("--resume").output().unwrap();
    common::assert_refused(&o, "cannot read: Permission denied");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("frame 0 was finished before the stop")
            && err.contains("make it a readable file again"),
        "{err}"
    );
    std::fs::set_permissions(&f0, std::fs::Permissions::from_mode(0o644)).unwrap();
    let o = nobody().args(args).arg("--resume").output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// Two finished frames swapped after the stop, in formats that keep less than EXR: refused on
/// resume (they were taken as finished, and the sequence came out of order), by their cameras
/// where the format keeps them (TIFF keeps `worldtocamera`), else by the hash of each file that
/// the checkpoint keeps (Radiance HDR and JPEG keep no metadata); put back, they resume.
#[test]
fn a_resume_finds_frames_swapped_in_any_format() {
    for (ext, why) in [
        ("tif", "worldToCamera, is not frame 0's"),
        ("hdr", "is not the file this render wrote there"),
        ("jpg", "is not the file this render wrote there"),
    ] {
        frames_swapped_before_resume(ext, why);
    }
}

fn frames_swapped_before_resume(ext: &str, why: &str) {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = format!("{}/f_####.{ext}", d.display());
    let mut args: Vec<&str> =
        "render vase --spp 64 --res 64x48 --threads 1 --checkpoint-every 0 --out"
            .split_whitespace()
            .collect();
    args.push(&out);
    let mut child = reframe().args(&args).spawn().unwrap();
    let frame = |f: u32| d.join(format!("f_{f:04}.{ext}"));
    interrupt_when(&mut child, "INT", || frame(2).exists());
    child.wait().unwrap();
    let swap = || {
        let t = d.join(format!("swap.{ext}"));
        std::fs::rename(frame(0), &t).unwrap();
        std::fs::rename(frame(1), frame(0)).unwrap();
        std::fs::rename(&t, frame(1)).unwrap();
    };
    swap();
    let o = reframe().args(&args).arg("--resume").output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.status.code() == Some(1)
            && err.contains("frame 0 was finished before the stop")
            && err.contains(why),
        "{ext}: {err}"
    );
    swap();
    run(&args.iter().copied().chain(["--resume"]).collect::<Vec<_>>());
    assert!(frame(47).exists());
}

/// A checkpoint folder whose parents are missing has them made, as an output's folder has
/// (it failed on opening the lock file beside it, naming no flag); those made go again when
/// the render completes. Where one cannot be made, the refusal names `--checkpoint`.
#[test]
fn a_checkpoint_folder_gets_its_parents() {
    let d = tempfile::tempdir().unwrap();
    let at = |p: &str| d.path().join(p).to_str().unwrap().to_string();
    let base = [
        "render",
        "vase",
        "--method",
        "mis-exact",
        "--window",
        "3",
        "--spp",
        "1",
        "--res",
        "16x12",
        "--frames",
        "0-4",
        "--threads",
        "1",
    ];
    let (out, ck) = (at("out/v_####.exr"), at("ck/sub/deeper"));
    run(&with(&base, &["--out", &out, "--checkpoint", &ck]));
    assert!(d.path().join("out/v_0004.exr").exists());
    assert!(!d.path().join("ck").exists(), "{:?}", leftovers(d.path()));
    std::fs::write(d.path().join("file"), b"").unwrap();
    let o = reframe()
        .args(with(
            &base,
            &["--out", &out, "--checkpoint", &at("file/sub/c")],
        ))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("--checkpoint ") && err.contains("file is a file, not a folder"),
        "{err}"
    );
}

/// A checkpoint folder you made is kept when a resume completes the render, and one the render
/// made goes (the trailer says which: a resume took every folder holding a checkpoint for one
/// a run had made, and removed yours).
#[test]
fn a_resume_keeps_a_checkpoint_folder_you_made() {
    let d = tempfile::tempdir().unwrap();
    for (name, yours) in [("mine", true), ("made", false)] {
        let ck = d.path().join(name);
        if yours {
            std::fs::create_dir(&ck).unwrap();
        }
        let out = d.path().join(format!("o_{name}/f_####.exr"));
        let args = with(
            &REUSE,
            &[
                "--out",
                out.to_str().unwrap(),
                "--checkpoint",
                ck.to_str().unwrap(),
                "--checkpoint-every",
                "0",
            ],
        );
        let mut child = reframe().args(&args).spawn().unwrap();
        let state = ck.join("state");
        interrupt_when(&mut child, "KILL", || state.exists());
        child.wait().unwrap();
        assert!(state.exists(), "{name}: no checkpoint");
        run(&args
            .iter()
            .map(String::as_str)
            .chain(["--resume"])
            .collect::<Vec<_>>());
        assert_eq!(ck.exists(), yours, "{name}");
        if yours {
            assert_eq!(
                std::fs::read_dir(&ck).unwrap().count(),
                0,
                "{name}: left in it"
            );
        }
    }
}

/// A run killed by SIGKILL before its first checkpoint (no handler runs) leaves its default
/// checkpoint folder empty; the next run to complete took it for one the user made and kept it
/// for good. An empty folder of the default name is now a run's, removed at the end; an empty
/// folder named by `--checkpoint` is still the user's, kept.
#[test]
fn an_empty_default_checkpoint_folder_left_by_a_kill_goes_when_the_render_completes() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // What the killed run left (made here by hand: a kill's timing is not the point).
    std::fs::create_dir(d.join("f.checkpoint")).unwrap();
    std::fs::create_dir(d.join("mine")).unwrap();
    let out = format!("{}/f_####.exr", d.display());
    let args = [
        "render", "cornell", "--frames", "0-1", "--res", "8x6", "--spp", "1",
    ];
    run(&[&args[..], &["--out", &out]].concat());
    assert!(
        !d.join("f.checkpoint").exists(),
        "the empty default folder was kept"
    );
    let mine = d.join("mine");
    let out = format!("{}/g_####.exr", d.display());
    run(&[
        &args[..],
        &["--out", &out, "--checkpoint", mine.to_str().unwrap()],
    ]
    .concat());
    assert!(
        mine.is_dir(),
        "the folder named by --checkpoint was removed"
    );
}
