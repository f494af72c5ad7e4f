//! `reframe bench`, `reframe reference` and `reframe compare` end to end, at small sizes.
mod common;

use common::reframe_ok as reframe;
use reframe::image::read_image;
use serde_json::{json, Value};
use std::path::Path;

fn json(p: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

#[test]
fn bench_writes_the_cost_model_figures() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bench.json");
    reframe(&[
        "bench",
        "cornell",
        "--res",
        "48x48",
        "--spp",
        "2",
        "--windows",
        "3,7",
        "--repeats",
        "2",
        "--json",
        out.to_str().unwrap(),
    ]);
    let b = json(&out);
    // Every speed-up run timed twice, the reuse and independent renders alternating.
    assert_eq!(b["repeats"].as_u64(), Some(2));
    for r in b["speedup_runs"].as_array().unwrap() {
        for key in ["reuse_seconds_all", "independent_seconds_all"] {
            let all = r[key].as_array().unwrap();
            assert_eq!(all.len(), 2, "{key}");
            assert!(all.iter().all(|t| t.as_f64().unwrap() > 0.0), "{key}");
        }
    }
    for key in ["c_e", "c_l", "c_v_single", "c_v_packet", "ratio"] {
        let v = b[key].as_f64().unwrap_or_else(|| panic!("{key} missing"));
        assert!(v.is_finite() && v > 0.0, "{key} = {v}");
    }
    for n_f in ["3", "7"] {
        let p = b["predicted_speedup"][n_f].as_f64().unwrap();
        let m = b["measured_speedup"][n_f].as_f64().unwrap();
        // Eq. 16 lies between 1 and n_f for any positive costs.
        let n: f64 = n_f.parse().unwrap();
        assert!(p > 1.0 && p < n, "predicted {p} for n_f {n_f}");
        assert!(m.is_finite() && m > 0.0, "measured {m}");
    }
    assert!(b["predicted_speedup"].get("17").is_none());
    // No timed run at all is refused, in one line.
    let o = common::reframe(&["bench", "cornell", "--res", "16x16", "--repeats", "0"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("--repeats 0"), "{err}");
    // Nor more than 101 (a typo would run for days, or fail to allocate), nor a group longer
    // than the scene (which was skipped in silence).
    for (args, want) in [
        (
            ["--repeats", "4294967295"],
            "--repeats 4294967295: at most 101",
        ),
        (
            ["--windows", "99999"],
            "--windows 99999: a group of 99999 frames does not fit",
        ),
        // A window given twice was measured twice, one run's figures lost under its key.
        (["--windows", "3,3"], "--windows 3: given twice"),
        // A speed-up run past the samples a group may hold, refused before the cost passes
        // (it was refused after them, naming the render's --spp and --window).
        (
            ["--speedup-spp", "400000"],
            "--method mis-exact at --speedup-spp 400000 and --windows 3: --spp 400000 with \
             --window 3: 1200000 samples per pixel per group",
        ),
    ] {
        let mut a = vec!["bench", "cornell", "--res", "16x16"];
        if args[0] == "--speedup-spp" {
            a.extend(["--windows", "3"]);
        }
        a.extend(args);
        let o = common::reframe(&a).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert!(
            err.contains(want) && err.trim().lines().count() == 1,
            "{err}"
        );
    }
}

#[test]
fn compare_writes_results_and_charts_and_reuses_the_cached_reference() {
    let dir = tempfile::tempdir().unwrap();
    let (out, cache) = (dir.path().join("cmp"), dir.path().join("cache"));
    let args = |extra: &[&str]| {
        let mut a = vec![
            "compare",
            "cornell",
            "--res",
            "40x40",
            "--frames",
            "4-8",
            "--budgets",
            "1,8",
            "--reuse-budgets",
            "1",
            "--windows",
            "3,5",
            "--reference-spp",
            "64",
            "--out",
            out.to_str().unwrap(),
            "--cache",
            cache.to_str().unwrap(),
        ];
        a.extend_from_slice(extra);
        a.into_iter().map(String::from).collect::<Vec<_>>()
    };
    let run = |a: Vec<String>| reframe(&a.iter().map(String::as_str).collect::<Vec<_>>());
    run(args(&[]));
    let c = json(&out.join("compare.json"));
    assert_eq!(c["reference"]["cached"], false);
    let runs = c["runs"].as_array().unwrap();
    // independent x2, then 4 reuse methods x 2 windows x 1 budget; the steady state renders
    // n_f - 1 frames either side of the measured ones and charges one group's time per frame.
    assert_eq!(runs.len(), 2 + 4 * 2);
    assert_eq!(c["regime"], "steady");
    for r in &runs[2..] {
        let n_f = r["window"].as_u64().unwrap();
        assert_eq!(r["rendered_frames"][0].as_u64(), Some(4 + 1 - n_f));
        assert_eq!(r["rendered_frames"][1].as_u64(), Some(8 + n_f - 1));
        let groups = (5 + n_f - 1) as f64;
        let charged = r["run_seconds"].as_f64().unwrap() * 5.0 / groups;
        assert!((r["seconds"].as_f64().unwrap() - charged).abs() < 1e-9);
    }
    assert!(c["equal_error_speedup"]["mis-cv"]["5"].as_f64().unwrap() > 0.0);
    for r in runs {
        for key in [
            "method", "window", "spp", "seconds", "rmse", "relmse", "flicker",
        ] {
            assert!(!r[key].is_null(), "run without {key}: {r}");
        }
        assert_eq!(r["per_frame"].as_array().unwrap().len(), 5);
    }
    // Eight times the samples: clearly lower error and flicker (variance falls 8-fold).
    let (one, eight) = (&runs[0], &runs[1]);
    assert!(eight["relmse"].as_f64().unwrap() < 0.5 * one["relmse"].as_f64().unwrap());
    assert!(eight["flicker"].as_f64().unwrap() < one["flicker"].as_f64().unwrap());
    assert!(c["equal_error_speedup"]["mis-exact"]["3"].as_f64().unwrap() > 0.0);
    assert!(c["relmse_formula"].as_str().unwrap().contains("R^2 + 0.01"));
    for f in [
        "compare.csv",
        "error_vs_time.png",
        "error_vs_time.svg",
        "speedup_vs_nf.png",
        "speedup_vs_nf.svg",
        "flicker.png",
        "flicker.svg",
        "crops.png",
        "crops.svg",
    ] {
        let p = out.join(f);
        assert!(
            std::fs::metadata(&p)
                .map(|m| m.len() > 100)
                .unwrap_or(false),
            "{f}"
        );
    }
    let csv = std::fs::read_to_string(out.join("compare.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + runs.len());
    // The range regime renders the measured frames only and reports their ends apart; a window
    // whose steady state needs frames the scene lacks is skipped, saying so.
    run(args(&[
        "--regime",
        "range",
        "--methods",
        "independent,mis-cv",
    ]));
    let c = json(&out.join("compare.json"));
    let cv: Vec<&Value> = c["runs"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| r["method"] == "mis-cv")
        .collect();
    assert_eq!(cv.len(), 2);
    for r in cv {
        assert_eq!(r["rendered_frames"][0].as_u64(), Some(4));
        assert!(r["ends_relmse"].as_f64().is_some(), "{r}");
    }
    // (A repeated list flag adds to the list: windows 3, 5 and 21.)
    run(args(&[
        "--windows",
        "21",
        "--methods",
        "independent,mis-cv",
    ]));
    let c = json(&out.join("compare.json"));
    assert_eq!(c["runs"].as_array().unwrap().len(), 2 + 2);
    assert!(c["skipped"][0].as_str().unwrap().contains("n_f 21"), "{c}");
    // Every window skipped: nothing to compare, refused before the reference is rendered, and
    // neither the output folder nor the cache is made.
    let (none, no_cache) = (dir.path().join("none"), dir.path().join("no-cache"));
    let mut a = args(&["--methods", "mis-cv"]);
    a.iter_mut().for_each(|x| {
        if *x == "3,5" {
            *x = "21".into();
        } else if *x == out.to_str().unwrap() {
            *x = none.to_str().unwrap().into();
        } else if *x == cache.to_str().unwrap() {
            *x = no_cache.to_str().unwrap().into();
        }
    });
    let o = common::reframe(&a).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.status.code() == Some(1)
            && err.contains("nothing to compare")
            && !err.contains("reference:"),
        "{err}"
    );
    assert!(!none.exists() && !no_cache.exists());
    // Second time: the reference comes from the cache, and `reframe reference` finds it too.
    run(args(&["--methods", "independent"]));
    assert_eq!(json(&out.join("compare.json"))["reference"]["cached"], true);
    let ref_args: Vec<String> = [
        "reference",
        "cornell",
        "--res",
        "40x40",
        "--frames",
        "4-8",
        "--reference-spp",
        "64",
        "--cache",
        cache.to_str().unwrap(),
    ]
    .map(String::from)
    .to_vec();
    let reference = || reframe(&ref_args);
    let o = reference();
    assert!(String::from_utf8_lossy(&o.stdout).contains("(cached)"));
    // One entry (a folder), beside its lock file.
    let entries: Vec<std::path::PathBuf> = std::fs::read_dir(&cache)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_dir())
        .collect();
    assert_eq!(entries.len(), 1, "{entries:?}");
    // A cached frame replaced by another frame's file (it was taken as it was) is found, said
    // once, and the reference made again, as it was.
    let refdir = entries[0].clone();
    let made = std::fs::read(refdir.join("ref_0005.exr")).unwrap();
    std::fs::copy(refdir.join("ref_0004.exr"), refdir.join("ref_0005.exr")).unwrap();
    let o = reference();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.status.success()
            && err
                .contains("is damaged (frame 5 is not the one that was made); rendering it again"),
        "{err}"
    );
    let again = read_image(&refdir.join("ref_0005.exr")).unwrap();
    let want = read_image_bytes(&made);
    assert_eq!(again.data, want.data, "made again as it was");
    // A description of another reference (copied or edited into this entry: it was read as
    // this one, and compare measured against another scene's images), or with no time, is a
    // damaged cache.
    let info = refdir.join("reference.json");
    let text = std::fs::read(&info).unwrap();
    for (field, value, why) in [
        (
            "spp",
            json!(128),
            "its description's spp is 128, not 64: it is another reference's",
        ),
        (
            "scene",
            json!("vase"),
            "its description's scene is vase, not cornell",
        ),
        (
            "key",
            json!("0123456789abcdef"),
            "its description's key is 0123456789abcdef",
        ),
        (
            "seconds",
            json!(-5.0),
            "its description's seconds, -5, is no time",
        ),
    ] {
        let mut v: Value = serde_json::from_slice(&text).unwrap();
        v[field] = value;
        std::fs::write(&info, serde_json::to_vec_pretty(&v).unwrap()).unwrap();
        let o = reference();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            o.status.success() && err.contains(why) && err.contains("rendering it again"),
            "{field}: {err}"
        );
    }
    // Two frames swapped together with their digests: each file says which frame it is.
    let text = std::fs::read(&info).unwrap();
    let mut v: Value = serde_json::from_slice(&text).unwrap();
    v["digests"].as_array_mut().unwrap().swap(0, 1);
    std::fs::write(&info, serde_json::to_vec_pretty(&v).unwrap()).unwrap();
    let [f4, f5] = ["ref_0004.exr", "ref_0005.exr"].map(|f| refdir.join(f));
    let t = refdir.join("swap.exr");
    std::fs::rename(&f4, &t).unwrap();
    std::fs::rename(&f5, &f4).unwrap();
    std::fs::rename(&t, &f5).unwrap();
    let o = reference();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.status.success() && err.contains("says it is frame 5, not 4"),
        "{err}"
    );
    // A description cut short is a damaged cache too (it had failed every later run); a FIFO
    // in its place is refused at once, where reading it waited for ever.
    let text = std::fs::read(&info).unwrap();
    std::fs::write(&info, &text[..text.len() / 2]).unwrap();
    let o = reference();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.status.success()
            && err.contains("not a reference description")
            && err.contains("rendering it again"),
        "{err}"
    );
    let o = reference();
    assert!(
        String::from_utf8_lossy(&o.stdout).contains("(cached)"),
        "described again"
    );
    std::fs::remove_file(&info).unwrap();
    let ok = std::process::Command::new("mkfifo")
        .arg(&info)
        .status()
        .unwrap();
    assert!(ok.success());
    let o = common::run_reframe(&ref_args, std::time::Duration::from_secs(20));
    assert_eq!(o.code, Some(1), "{}", o.stderr);
    assert!(o.stderr.contains("is a named pipe (FIFO)"), "{}", o.stderr);
    // So is a FIFO, a device or a folder in a cached frame's place (the FIFO and `/dev/zero`
    // hung the reader; each was found only after the whole reference had been rendered again,
    // when its file could not be replaced).
    std::fs::remove_file(&info).unwrap();
    reference();
    let frame = refdir.join("ref_0006.exr");
    for (how, what) in [
        ("fifo", "a named pipe (FIFO)"),
        ("zero", "a character device"),
        ("folder", "a directory"),
    ] {
        std::fs::remove_file(&frame).unwrap();
        match how {
            "fifo" => assert!(std::process::Command::new("mkfifo")
                .arg(&frame)
                .status()
                .unwrap()
                .success()),
            "zero" => std::os::unix::fs::symlink("/dev/zero", &frame).unwrap(),
            _ => std::fs::create_dir(&frame).unwrap(),
        }
        let o = common::run_reframe(&ref_args, std::time::Duration::from_secs(20));
        assert_eq!(o.code, Some(1), "{how}: {}", o.stderr);
        assert!(
            o.stderr
                .contains(&format!("ref_0006.exr: it is {what}, not a regular file"))
                && o.stderr.contains("cannot be made again in its place")
                && !o.stderr.contains("rendering it again"),
            "{how}: {}",
            o.stderr
        );
        if how == "folder" {
            std::fs::remove_dir(&frame).unwrap();
        } else {
            std::fs::remove_file(&frame).unwrap();
        }
        std::fs::write(&frame, b"").unwrap();
    }
}

#[test]
fn a_reference_entry_linked_to_another_is_never_written_through() {
    // A cache shared by links: one entry's folder a link to another's. The entry was found
    // damaged (another key's reference) and rendered again through the link, over the other
    // entry, which was then found damaged in turn.
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let reference = |spp: &str| {
        common::reframe(&[
            "reference",
            "cornell",
            "--frames",
            "0-1",
            "--res",
            "8x6",
            "--reference-spp",
            spp,
            "--cache",
            cache.to_str().unwrap(),
        ])
        .output()
        .unwrap()
    };
    let entry = |spp: &str| {
        std::fs::read_dir(&cache)
            .unwrap()
            .map(|e| e.unwrap().path())
            .find(|p| {
                let name = p.file_name().unwrap().to_str().unwrap();
                // The entry's folder, not its lock (`.ENTRY.lock`) beside it.
                !name.starts_with('.') && name.contains(&format!("_{spp}spp_"))
            })
            .unwrap()
    };
    assert!(reference("16").status.success());
    assert!(reference("8").status.success());
    let (e16, e8) = (entry("16"), entry("8"));
    let info16 = std::fs::read(e16.join("reference.json")).unwrap();
    std::fs::remove_dir_all(&e8).unwrap();
    std::os::unix::fs::symlink(&e16, &e8).unwrap();
    let o = reference("8");
    common::assert_refused(&o, "is a symbolic link (to ");
    common::assert_refused(
        &o,
        "an entry is written in a folder of its own, never through a link",
    );
    assert_eq!(std::fs::read(e16.join("reference.json")).unwrap(), info16);
    let o = reference("16");
    assert!(String::from_utf8_lossy(&o.stdout).contains("(cached)"));
    // Linked to a copy of its own entry, it is read.
    let copy = dir.path().join("copy");
    assert!(reference("8").status.code() == Some(1));
    std::fs::remove_file(&e8).unwrap();
    assert!(reference("8").status.success());
    std::fs::rename(&e8, &copy).unwrap();
    std::os::unix::fs::symlink(&copy, &e8).unwrap();
    let o = reference("8");
    assert!(
        String::from_utf8_lossy(&o.stdout).contains("(cached)"),
        "{o:?}"
    );
}

/// An image from its file's bytes (through a temporary file).
fn read_image_bytes(bytes: &[u8]) -> reframe::image::Image {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("x.exr");
    std::fs::write(&p, bytes).unwrap();
    read_image(&p).unwrap()
}

#[test]
fn compare_rejects_bad_settings_before_rendering() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("cmp");
    let cache = dir.path().join("cache");
    for (args, needle) in [
        (vec!["--reference-spp", "12"], "multiple of 8"),
        (vec!["--windows", "4"], "odd"),
        (vec!["--frames", "0-99"], "frames 0-23"),
        (vec!["--crop", "30,30,20,20"], "not inside"),
        (vec!["--crop", "4,4,0,3"], "--crop 4,4,0,3: empty"),
        (vec!["--budgets", "0"], "at least one"),
        (
            vec!["--methods", "mis-cv+denoise"],
            "optionally followed by '+oidn'",
        ),
        (
            vec!["--methods", "independent+oidn", "--bias-seeds", "1"],
            "at least 2 seeds",
        ),
        (
            vec!["--methods", "mis-cv,independent,mis-cv"],
            "--methods: mis-cv is given twice",
        ),
        (vec!["--budgets", "1,2,1"], "--budgets: 1 is given twice"),
        (
            vec!["--reuse-budgets", "2,2"],
            "--reuse-budgets: 2 is given twice",
        ),
        (vec!["--windows", "3,5,3"], "--windows: 3 is given twice"),
        (
            vec!["--methods", "independent,"],
            "an empty method name in the list (a comma at its end",
        ),
        // Every run is checked as its render will check it before the reference is rendered
        // (one past the samples a group may hold was refused after the reference and the runs
        // before it, naming the render's flags).
        (
            vec!["--reuse-budgets", "1,400000", "--windows", "3"],
            "--methods havran at --reuse-budgets 400000 and --windows 3: --spp 400000 with \
             --window 3: 1200000 samples per pixel per group",
        ),
    ] {
        let mut a = vec!["compare", "cornell", "--res", "40x40", "--out"];
        a.push(out.to_str().unwrap());
        a.extend(["--cache", cache.to_str().unwrap()]);
        a.extend(args);
        let o = common::reframe(&a).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{a:?} succeeded");
        assert!(err.contains(needle), "{a:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{a:?}: {err}");
        // Nothing made: no output folder, no reference in the cache.
        assert!(!out.exists(), "{a:?}: {out:?} made");
        assert!(!cache.exists(), "{a:?}: a reference was cached");
    }
}

#[test]
fn compare_refuses_a_bias_seed_count_that_would_run_for_days() {
    // --bias-seeds 4294967295 was accepted (every seed renders each denoised method's strip).
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("cmp");
    let out = out.to_str().unwrap();
    let o = common::reframe(&[
        "compare",
        "cornell",
        "--bias-seeds",
        "4294967295",
        "--out",
        out,
    ])
    .output()
    .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("--bias-seeds 4294967295: at most 64") && err.trim().lines().count() == 1,
        "{err}"
    );
    assert!(!dir.path().join("cmp").exists());
}

/// Two `reference` runs of one cache entry at once (two `compare` jobs sharing a cache): one
/// renders it, the other waits for it and reads it from the cache, whichever starts first.
#[test]
fn two_runs_of_one_reference_render_it_once() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let args = [
        "reference",
        "cornell",
        "--res",
        "64x48",
        "--frames",
        "0-1",
        "--reference-spp",
        "512",
        "--threads",
        "1",
        "--cache",
        cache.to_str().unwrap(),
    ];
    let spawn = || {
        common::reframe(&args)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap()
    };
    let (a, b) = (spawn(), spawn());
    let outs: Vec<String> = [a, b]
        .into_iter()
        .map(|c| {
            let o = c.wait_with_output().unwrap();
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
            String::from_utf8_lossy(&o.stdout).into_owned()
        })
        .collect();
    let rendered = outs.iter().filter(|o| o.contains("rendered in")).count();
    assert_eq!(rendered, 1, "{outs:?}");
    assert!(outs.iter().any(|o| o.contains("(cached)")), "{outs:?}");
    // A folder planted at the entry's lock is refused, before anything is rendered: the run had
    // gone on unlocked, so two runs could render (and write) one entry at once.
    let entry = std::fs::read_dir(&cache)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.is_dir())
        .unwrap();
    std::fs::remove_dir_all(&entry).unwrap();
    let name = entry.file_name().unwrap().to_str().unwrap();
    let lock = cache.join(format!(".{name}.lock"));
    std::fs::remove_file(&lock).unwrap();
    std::fs::create_dir(&lock).unwrap();
    let o = common::reframe(&args).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("lock file") && err.contains(name), "{err}");
    assert!(!entry.exists());
}

/// The summary says which run a missing measured speed-up lacks: with a mis-exact run but no
/// independent one it had said "no mis-exact run", listed just above it.
#[test]
fn compare_says_which_run_a_missing_speedup_lacks() {
    let dir = tempfile::tempdir().unwrap();
    let (out, cache) = (dir.path().join("cmp"), dir.path().join("cache"));
    let run = |methods: &str| {
        let o = common::reframe(&[
            "compare",
            "vase",
            "--frames",
            "10-12",
            "--res",
            "16x12",
            "--reference-spp",
            "8",
            "--threads",
            "1",
            "--regime",
            "range",
            "--methods",
            methods,
            "--budgets",
            "1",
            "--reuse-budgets",
            "1",
            "--windows",
            "3",
            "--out",
            out.to_str().unwrap(),
            "--cache",
            cache.to_str().unwrap(),
        ])
        .output()
        .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let text =
            String::from_utf8_lossy(&o.stdout).to_string() + &String::from_utf8_lossy(&o.stderr);
        let line = text
            .lines()
            .find(|l| l.starts_with("same-spp speed-up"))
            .unwrap_or_else(|| panic!("{text}"))
            .to_string();
        line
    };
    let line = run("mis-exact");
    assert!(
        line.contains("n_f 3: ")
            && line.ends_with("x / - (no independent run to measure it against)"),
        "{line}"
    );
    let line = run("independent,mis");
    assert!(line.ends_with("/ - (no mis-exact run)"), "{line}");
}
