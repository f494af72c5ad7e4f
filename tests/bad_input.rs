//! Bad input through the real binary, from the corpus in `tests/corpus/`: every case must end
//! with a one-line error that names the file and the line or key (or the flag), a non-zero exit,
//! no panic, and its folder exactly as it was (every path, size and modification time); or, for input that loading repairs, render with exactly the
//! warnings the case names (one line per kind of repair), and be refused by strict loading.
//!
//! `tests/corpus/base/` is a small valid scene (`s.toml`, `s.obj`, `s.mtl`). Each folder in
//! `tests/corpus/cases/` holds the files that differ from it and a `case.toml`:
//!
//! ```toml
//! why = "a face refers to vertex 42 of 8"    # what is wrong, one line
//! args = ["--frames", "0-5"]                 # extra flags (optional)
//! remove = ["s.mtl"]                         # base files to leave out (optional)
//! scene = "no-such-scene"                    # the scene argument instead of s.toml (optional)
//! ok = true                                  # the input is fine and must render (optional)
//! expect = ["{dir}/s.obj: line 15: 'f 1 2 42': vertex index 42 is out of range"]
//! warn = ["{dir}/s.obj: line 14: 'l 1 2 3': polyline (l) ignored"]   # with ok: the warnings
//! strict = "{dir}/s.obj: line 14: 'l 1 2 3': polyline"                # with ok: strict's error
//! ```
//!
//! `{dir}` is the folder the case runs in; each `expect` text must appear in the error line.
//! A case that renders prints one `warning:` line per `warn` text, in order, each containing
//! it (none if there is no `warn`). Each is then loaded through the library with
//! `LoadOptions { strict: true }`: with `strict`, that must fail with an error containing it;
//! without, it must load (a scene without warnings is fine under strict loading too).
mod common;

use common::{files_under, par_map, refusal, run_reframe, snapshot};
use reframe::embree::Device;
use reframe::scene::{LoadOptions, Scene};
use serde::Deserialize;
use std::path::{Path, PathBuf};
use std::time::Duration;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Manifest {
    why: String,
    #[serde(default)]
    args: Vec<String>,
    #[serde(default)]
    expect: Vec<String>,
    #[serde(default)]
    remove: Vec<String>,
    scene: Option<String>,
    #[serde(default)]
    ok: bool,
    #[serde(default)]
    warn: Vec<String>,
    strict: Option<String>,
}

fn corpus() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus")
}

/// Copy the base scene and the case's files into `dir`; the arguments to run it with.
fn stage(case: &Path, m: &Manifest, dir: &Path) -> Vec<String> {
    for from in [corpus().join("base"), case.to_path_buf()] {
        for f in files_under(&from) {
            // Kept in its folder: `tex-folder`'s `wood.png/` is a folder (held in git by a
            // `.keep` file inside it).
            let rel = f.strip_prefix(&from).unwrap();
            if rel != Path::new("case.toml") {
                let to = dir.join(rel);
                std::fs::create_dir_all(to.parent().unwrap()).unwrap();
                std::fs::copy(&f, to).unwrap();
            }
        }
    }
    for r in &m.remove {
        std::fs::remove_file(dir.join(r)).unwrap();
    }
    let d = dir.display().to_string();
    let scene = m.scene.clone().unwrap_or_else(|| format!("{d}/s.toml"));
    let mut args: Vec<String> = vec!["render".into(), scene];
    args.extend(m.args.iter().map(|a| a.replace("{dir}", &d)));
    for (flag, value) in [
        ("--spp", "1".to_string()),
        ("--threads", "1".to_string()),
        ("--out", format!("{d}/out/f_####.png")),
    ] {
        if !m.args.iter().any(|a| a == flag) {
            args.extend([flag.to_string(), value]);
        }
    }
    args
}

/// Run one case: whether it was refused (or rendered, as it should), or what went wrong.
fn check(case: &Path) -> Result<bool, String> {
    let text = std::fs::read_to_string(case.join("case.toml")).map_err(|e| e.to_string())?;
    let m: Manifest = toml::from_str(&text).map_err(|e| format!("case.toml: {e}"))?;
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let args = stage(case, &m, dir);
    let inputs = files_under(dir);
    let before = snapshot(dir);
    let o = run_reframe(&args, Duration::from_secs(20));
    let written: Vec<PathBuf> = files_under(dir)
        .into_iter()
        .filter(|p| !inputs.contains(p))
        .collect();
    let why = &m.why;
    if m.ok {
        let want = [dir.join("out/f_0000.png"), dir.join("out/f_0001.png")];
        if o.code != Some(0) || written != want {
            return Err(format!(
                "{why}: should render, exit {:?}, wrote {written:?}: {}",
                o.code, o.stderr
            ));
        }
        let d = dir.display().to_string();
        let warnings: Vec<&str> = o
            .stderr
            .lines()
            .filter(|l| l.starts_with("warning: "))
            .collect();
        let want: Vec<String> = m.warn.iter().map(|w| w.replace("{dir}", &d)).collect();
        if warnings.len() != want.len() || !want.iter().zip(&warnings).all(|(w, l)| l.contains(w)) {
            return Err(format!(
                "{why}: warnings\n  want: {want:?}\n  got:  {warnings:?}"
            ));
        }
        let scene = m.scene.clone().unwrap_or_else(|| format!("{d}/s.toml"));
        let device = Device::new().unwrap();
        let strict = Scene::load_with(&scene, &device, &LoadOptions { strict: true });
        match (&m.strict, strict) {
            (Some(t), Err(e)) if format!("{e:#}").contains(&t.replace("{dir}", &d)) => {}
            (Some(t), r) => {
                let got = r
                    .map(|_| "loaded".to_string())
                    .unwrap_or_else(|e| format!("{e:#}"));
                return Err(format!("{why}: strict\n  want: {t}\n  got:  {got}"));
            }
            (None, Ok(_)) => {}
            (None, Err(e)) => return Err(format!("{why}: strict loading refused it: {e:#}")),
        }
        return Ok(false);
    }
    let line = refusal(&o).map_err(|e| format!("{why}: {e}"))?;
    if !written.is_empty() {
        return Err(format!("{why}: left files behind: {written:?}"));
    }
    let after = snapshot(dir);
    if after != before {
        let changed: Vec<_> = after.iter().filter(|e| !before.contains(e)).collect();
        return Err(format!(
            "{why}: the folder changed (paths, sizes or times): {changed:?}"
        ));
    }
    if m.expect.is_empty() || !m.warn.is_empty() || m.strict.is_some() {
        return Err(format!(
            "{why}: case.toml expects no text (or has warn/strict without ok)"
        ));
    }
    for e in &m.expect {
        let e = e.replace("{dir}", &dir.display().to_string());
        if !line.contains(&e) {
            return Err(format!("{why}:\n  want: {e}\n  got:  {line}"));
        }
    }
    Ok(true)
}

#[test]
fn base_scene_renders() {
    // The corpus is only meaningful if the scene it spoils is fine.
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    for f in files_under(&corpus().join("base")) {
        std::fs::copy(&f, d.join(f.file_name().unwrap())).unwrap();
    }
    let args: Vec<String> = vec![
        "render".into(),
        d.join("s.toml").display().to_string(),
        "--spp".into(),
        "1".into(),
        "--out".into(),
        d.join("o_####.png").display().to_string(),
    ];
    let o = run_reframe(&args, Duration::from_secs(60));
    assert_eq!(o.code, Some(0), "{}", o.stderr);
    assert!(d.join("o_0000.png").exists() && d.join("o_0001.png").exists());
}

#[test]
fn corpus_fails_cleanly() {
    let mut cases: Vec<PathBuf> = std::fs::read_dir(corpus().join("cases"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    cases.sort();
    let results = par_map(&cases, |c| check(c));
    let failures: Vec<String> = cases
        .iter()
        .zip(&results)
        .filter_map(|(c, r)| {
            let name = c.file_name().unwrap().to_string_lossy();
            r.as_ref().err().map(|e| format!("{name}: {e}"))
        })
        .collect();
    let refused = results.iter().filter(|r| matches!(r, Ok(true))).count();
    let rendered = results.iter().filter(|r| matches!(r, Ok(false))).count();
    eprintln!(
        "corpus: {} cases: {refused} refused with a one-line error, {rendered} valid and rendered, \
         {} failed",
        cases.len(),
        failures.len()
    );
    assert!(failures.is_empty(), "\n{}", failures.join("\n"));
}

#[test]
fn usage_errors_are_one_line_that_says_what_is_missing() {
    // clap puts a list of missing arguments on the lines below its heading: the one line must
    // carry it (it once read "were not provided: (see --help)").
    for (args, want) in [
        (
            &["merge"][..],
            "required arguments were not provided: <PARTIALS>...",
        ),
        (
            &["render", "--method"],
            "a value is required for '--method <METHOD>'",
        ),
        (
            &["bench", "--spp", "x"],
            "invalid value 'x' for '--spp <SPP>'",
        ),
        // A negative frame is a value, not a flag (clap said "unexpected argument '-1'").
        (
            &["render", "--frames", "-1"],
            "'-1': frames are numbered from 0, never below",
        ),
        // So is a negative number given to any option of any command: its parser refuses it,
        // naming the option (clap said "unexpected argument '-1'", naming none).
        (
            &["render", "--threads", "-1"],
            "invalid value '-1' for '--threads <THREADS>'",
        ),
        (
            &["render", "--window", "-3"],
            "invalid value '-3' for '--window <WINDOW>'",
        ),
        (
            &["bench", "--repeats", "-1"],
            "invalid value '-1' for '--repeats <REPEATS>'",
        ),
        (
            &["compare", "--bias-seeds", "-1"],
            "invalid value '-1' for '--bias-seeds <BIAS_SEEDS>'",
        ),
        (
            &["reference", "--reference-spp", "-8"],
            "invalid value '-8' for '--reference-spp <REFERENCE_SPP>'",
        ),
        (
            &["merge", "--chunks", "-1", "--out", "x/f_####.exr"],
            "invalid value '-1' for '--chunks <CHUNKS>'",
        ),
        // And a value that starts with a negative number but is not one (a size, a list).
        (
            &["render", "--res", "-5x3"],
            "invalid value '-5x3' for '--res <RES>'",
        ),
        (
            &["compare", "--budgets", "-1,2"],
            "invalid value '-1' for '--budgets <BUDGETS>'",
        ),
        (
            &["compare", "--crop", "-1,0,4,4"],
            "invalid value '-1,0,4,4' for '--crop <CROP>'",
        ),
        // An option followed by another still lacks its value.
        (
            &["render", "--res", "--spp", "4"],
            "a value is required for '--res <RES>'",
        ),
    ] {
        let args: Vec<String> = args.iter().map(|a| a.to_string()).collect();
        let line = refusal(&run_reframe(&args, Duration::from_secs(60)))
            .unwrap_or_else(|e| panic!("{args:?}: {e}"));
        assert!(
            line.contains(want) && line.ends_with("(see --help)"),
            "{args:?}: {line}"
        );
    }
}

/// `reframe render s.toml` (16x12, 1 spp) run in the folder `d`.
fn run_from(d: &Path) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_reframe"))
        .current_dir(d)
        .args(["render", "s.toml", "--spp", "1", "--threads", "1"])
        .args(["--res", "16x12", "--out", "out/f_####.png"])
        .output()
        .unwrap()
}

/// Render `s.toml` from its own folder `d`, by its bare name (`reframe render s.toml`, the
/// usual way); it must succeed. Its standard error.
fn render_from(d: &Path) -> String {
    let o = run_from(d);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{err}");
    err
}

/// The corpus runs every case by its absolute path; names in another case are found from the
/// scene's own folder too, named by a bare file name (`reframe render s.toml`, the usual way):
/// the folder of `s.mtl` is then the empty path, which could not be listed, and both the map
/// and the MTL were "no file" (the light's MTL missed, "the scene has no light").
#[test]
fn names_in_another_case_are_found_from_the_scenes_own_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    for from in [
        corpus().join("base"),
        corpus().join("cases/tex-case-mismatch"),
    ] {
        for f in files_under(&from) {
            let rel = f.strip_prefix(&from).unwrap();
            if rel != Path::new("case.toml") {
                std::fs::create_dir_all(d.join(rel).parent().unwrap()).unwrap();
                std::fs::copy(&f, d.join(rel)).unwrap();
            }
        }
    }
    let err = render_from(d);
    for want in [
        "s.obj: line 1: 'mtllib Mats/S.MTL': found 'mats/s.mtl'",
        "mats/s.mtl: line 3: 'map_Kd Textures/Wood.PNG': found 'mats/textures/wood.png'",
    ] {
        assert!(err.contains(want), "{want}: {err}");
    }
}

/// The corpus's base scene in `d`, with the OBJ of `cases/tex-case-mismatch`, whose
/// `mats/s.mtl` names the map `map` (no file is there by that name); returns that case's folder.
fn scene_naming_a_map(d: &Path, map: &str) -> PathBuf {
    for f in files_under(&corpus().join("base")) {
        std::fs::copy(&f, d.join(f.file_name().unwrap())).unwrap();
    }
    let case = corpus().join("cases/tex-case-mismatch");
    std::fs::copy(case.join("s.obj"), d.join("s.obj")).unwrap();
    std::fs::create_dir_all(d.join("mats")).unwrap();
    let mtl = std::fs::read_to_string(case.join("mats/s.mtl")).unwrap();
    std::fs::write(d.join("mats/s.mtl"), mtl.replace("Textures/Wood.PNG", map)).unwrap();
    case
}

/// A name written composed and in capitals (`ÖLFASS Holz.png`, the `Ö` one character) finds a
/// file stored decomposed (an `O` and its accent, as macOS stores names and archives made
/// there keep them) and in small letters: the scene was refused, naming two files whose names
/// printed alike, and only ASCII letters were matched in another case.
#[test]
fn names_are_found_in_another_composition_and_case_of_their_letters() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let case = scene_naming_a_map(d, "\u{d6}LFASS Holz.png");
    // "ölfass holz.png" decomposed: o, combining diaeresis (U+0308), ...
    std::fs::copy(
        case.join("mats/textures/wood.png"),
        d.join("mats/o\u{308}lfass holz.png"),
    )
    .unwrap();
    let err = render_from(d);
    assert!(
        err.contains("'map_Kd \u{d6}LFASS Holz.png': found 'mats/o\u{308}lfass holz.png'"),
        "{err}"
    );
}

/// Two files that both match a map's name in another case (`Wood.png` and `WOOD.png` for
/// `wood.png`, one name to Windows and macOS): none is picked, and the refusal names both,
/// where it said only that there was no file.
#[test]
fn two_files_matching_a_name_in_another_case_are_both_named() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let case = scene_naming_a_map(d, "wood.png");
    for name in ["Wood.png", "WOOD.png"] {
        std::fs::copy(
            case.join("mats/textures/wood.png"),
            d.join("mats").join(name),
        )
        .unwrap();
    }
    let o = run_from(d);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains(
            "'map_Kd wood.png': no file 'mats/wood.png', and 'mats/WOOD.png' and \
             'mats/Wood.png' match it in another case"
        ),
        "{err}"
    );
}

#[test]
fn an_argument_that_is_not_utf8_is_named() {
    // A Latin-1 file name from an old archive: clap's line said only "invalid UTF-8 was
    // detected in one or more arguments".
    use std::os::unix::ffi::OsStrExt;
    let name = std::ffi::OsStr::from_bytes(b"sc\xe9ne.toml");
    let args = [std::ffi::OsStr::new("render"), name];
    let line = refusal(&run_reframe(&args, Duration::from_secs(60))).unwrap();
    assert!(
        line.starts_with("error: argument 2 ('sc\u{fffd}ne.toml'") && line.contains("is not UTF-8"),
        "{line}"
    );
}

#[test]
fn a_line_break_in_a_frame_name_is_shown_escaped() {
    // Shown as a space, the name read as another file's.
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("f\n_####.png");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_reframe"))
        .args([
            "render", "cornell", "--res", "8x6", "--spp", "1", "--frames", "0-1",
        ])
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8(o.stdout).unwrap();
    let dir = tmp.path().display();
    assert!(
        stdout.contains(&format!(
            "wrote {dir}/f\\u{{a}}_0000.png .. {dir}/f\\u{{a}}_0001.png"
        )),
        "{stdout}"
    );
    assert!(tmp.path().join("f\n_0001.png").exists());
}

#[test]
fn an_output_name_too_long_for_its_temporary_file_is_refused_before_rendering() {
    // 245 bytes fit a file name, but not the temporary name a frame is written under first:
    // the first frame failed after its rendering, leaving an empty checkpoint folder.
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp
        .path()
        .join("o")
        .join(format!("{}_####.exr", "a".repeat(236)));
    let args: Vec<String> = ["render", "cornell", "--res", "16x12", "--spp", "1", "--out"]
        .iter()
        .map(|a| a.to_string())
        .chain([out.display().to_string()])
        .collect();
    let line = refusal(&run_reframe(&args, Duration::from_secs(60))).unwrap();
    assert!(
        line.contains("a frame's file name of 245 bytes is too long"),
        "{line}"
    );
    assert!(!tmp.path().join("o").exists(), "nothing made");
}

/// `merge --chunks N` finds its partials by listing the folder: N named none of the cost (the
/// largest N made 4294967295 paths first and aborted asking for 100 GB).
#[test]
fn merge_with_a_huge_chunk_count_is_refused_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("f_####.exr").display().to_string();
    let args: Vec<String> = ["merge", "--chunks", "4294967295", "--out", &out]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let line = refusal(&run_reframe(&args, Duration::from_secs(60))).unwrap();
    assert!(
        line.contains("none of the partial files is there"),
        "{line}"
    );
}

/// `--cache` naming a file (or a path through one) is said as such: the message was the cache
/// description's "cannot read: Not a directory", naming neither the flag nor the file.
#[test]
fn a_reference_cache_that_is_a_file_is_refused_naming_the_flag() {
    let tmp = tempfile::tempdir().unwrap();
    let file = tmp.path().join("cache");
    std::fs::write(&file, b"x").unwrap();
    for cache in [file.clone(), file.join("sub")] {
        let args: Vec<String> = [
            "reference",
            "vase",
            "--res",
            "16x12",
            "--frames",
            "0-0",
            "--reference-spp",
            "8",
            "--cache",
        ]
        .iter()
        .map(|a| a.to_string())
        .chain([cache.display().to_string()])
        .collect();
        let line = refusal(&run_reframe(&args, Duration::from_secs(60))).unwrap();
        assert_eq!(
            line,
            format!(
                "error: --cache {}: {} is a file, not a folder (the cache is a folder of references)",
                cache.display(),
                file.display()
            )
        );
    }
}

/// A library that aborts while a file is being read (OpenImageIO 2.4 does on some TIFF and PSD
/// files) ends the process as before, by SIGABRT, but names the file: it ended with status 134
/// and nothing said. This test runs itself again as the process that aborts.
#[test]
fn an_abort_while_reading_a_file_names_the_file() {
    const CHILD: &str = "REFRAME_TEST_ABORT_WHILE_READING";
    if std::env::var_os(CHILD).is_some() {
        reframe::sys::keep_stderr();
        reframe::sys::say_aborts();
        let line = reframe::image::crash_line(Path::new("textures/odd.psd"));
        let _reading = reframe::sys::reading(line);
        std::process::abort();
    }
    use std::os::unix::process::ExitStatusExt;
    let o = std::process::Command::new(std::env::current_exe().unwrap())
        .args([
            "an_abort_while_reading_a_file_names_the_file",
            "--exact",
            "--nocapture",
        ])
        .env(CHILD, "1")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.signal(), Some(libc::SIGABRT), "{err}");
    assert!(
        err.contains("error: reading textures/odd.psd crashed the image library (OpenImageIO)"),
        "{err}"
    );
}

/// The handler that names a file whose decoder faults leaves a fault outside a read to the
/// handler there was before: a stack overflow is still reported as one by Rust (and the
/// process still ends by SIGABRT). This test runs itself again as the process that overflows.
#[test]
fn a_stack_overflow_outside_a_read_is_still_reported_as_one() {
    const CHILD: &str = "REFRAME_TEST_STACK_OVERFLOW";
    if std::env::var_os(CHILD).is_some() {
        reframe::sys::keep_stderr();
        reframe::sys::say_aborts();
        fn deeper(n: u64) -> u64 {
            let room = std::hint::black_box([n; 64]);
            room[(n % 64) as usize] + if n == u64::MAX { 0 } else { deeper(n + 1) }
        }
        // A thread of Rust's own, with a small stack and its guard page.
        let t = std::thread::Builder::new()
            .name("deep".into())
            .stack_size(256 << 10)
            .spawn(|| deeper(0))
            .unwrap();
        let _ = t.join();
        return;
    }
    use std::os::unix::process::ExitStatusExt;
    let mut child = std::process::Command::new(std::env::current_exe().unwrap())
        .args([
            "a_stack_overflow_outside_a_read_is_still_reported_as_one",
            "--exact",
            "--nocapture",
        ])
        .env(CHILD, "1")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // A handler that returned to the fault without passing it on would fault for ever.
    let start = std::time::Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > Duration::from_secs(60) {
            let _ = child.kill();
            panic!("the overflowing process did not end");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let mut err = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut err).unwrap();
    assert_eq!(status.signal(), Some(libc::SIGABRT), "{err}");
    assert!(
        err.contains("thread 'deep'") && err.contains("overflowed its stack"),
        "{err}"
    );
    assert!(!err.contains("crashed the image library"), "{err}");
}

/// A `usemtl` name no material has, beside a material's name of about its length, both long:
/// the hint's edit distance took a time in the product of their lengths (two names of 10^5
/// characters took 16 s to load, of 10^6 about half an hour). Long names are compared case
/// aside only; the scene loads at once, with the warning.
#[test]
fn long_unknown_material_names_load_at_once() {
    let tmp = tempfile::tempdir().unwrap();
    let base = corpus().join("base");
    for f in ["s.toml", "s.obj", "s.mtl"] {
        std::fs::copy(base.join(f), tmp.path().join(f)).unwrap();
    }
    let edit = |f: &str, from: &str, to: String| {
        let p = tmp.path().join(f);
        let text = std::fs::read_to_string(&p).unwrap().replace(from, &to);
        std::fs::write(p, text).unwrap();
    };
    edit(
        "s.obj",
        "usemtl floor",
        format!("usemtl {}", "a".repeat(1_000_000)),
    );
    edit(
        "s.mtl",
        "newmtl floor",
        format!("newmtl {}", "b".repeat(1_000_001)),
    );
    let out = tmp
        .path()
        .join("o")
        .join("f_####.png")
        .display()
        .to_string();
    let scene = tmp.path().join("s.toml").display().to_string();
    let args = [
        "render",
        &scene,
        "--spp",
        "1",
        "--threads",
        "1",
        "--out",
        &out,
    ];
    let o = run_reframe(&args, Duration::from_secs(60));
    assert!(!o.timed_out, "still loading after 60 s");
    assert_eq!(o.code, Some(0), "{}", o.stderr);
    assert!(
        o.stderr.contains("usemtl names a material no MTL defines"),
        "{}",
        o.stderr
    );
}

/// An output folder that is a symbolic link to nothing is said as such, by every command that
/// makes one (making it had said only "File exists").
#[test]
fn an_output_folder_linked_to_nothing_is_said_as_such() {
    let tmp = tempfile::tempdir().unwrap();
    let link = tmp.path().join("dl");
    std::os::unix::fs::symlink(tmp.path().join("nowhere"), &link).unwrap();
    let out = link.join("f_####.exr").display().to_string();
    let folder = link.display().to_string();
    let common = ["--res", "16x12", "--spp", "1", "--threads", "1"];
    let runs: Vec<Vec<&str>> = vec![
        [&["render", "cornell"], &common[..], &["--out", &out]].concat(),
        [
            &["render", "cornell", "--chunk", "1/2"],
            &common[..],
            &["--out", &out],
        ]
        .concat(),
        vec!["compare", "cornell", "--out", &folder],
    ];
    for args in runs {
        let line = refusal(&run_reframe(&args, Duration::from_secs(60))).unwrap();
        assert!(
            line.contains("is a symbolic link to nothing"),
            "{args:?}: {line}"
        );
    }
    assert!(
        !tmp.path().join("nowhere").exists(),
        "nothing made through the link"
    );
}

/// A scene whose name holds a `#` renders to the default `--out`, its `#` made `_` (the
/// default output path had two runs of `#` and was refused).
#[test]
fn a_scene_named_with_a_hash_renders_to_the_default_output() {
    let tmp = tempfile::tempdir().unwrap();
    let base = corpus().join("base");
    for f in ["s.obj", "s.mtl"] {
        std::fs::copy(base.join(f), tmp.path().join(f)).unwrap();
    }
    std::fs::copy(base.join("s.toml"), tmp.path().join("shot#2.toml")).unwrap();
    let o = common::reframe(&["render", "shot#2.toml", "--spp", "1", "--threads", "1"])
        .current_dir(tmp.path())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(tmp.path().join("out/shot_2_0000.exr").is_file());
}

/// `merge` with neither partial files nor `--chunks` says both ways (clap named the files only).
#[test]
fn a_merge_of_nothing_names_both_ways_to_name_the_chunks() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("f_####.exr").display().to_string();
    let line = refusal(&run_reframe(
        &["merge", "--out", &out],
        Duration::from_secs(60),
    ))
    .unwrap();
    assert!(line.contains("or give --chunks N"), "{line}");
}

#[test]
fn a_scene_named_with_control_characters_is_shown_escaped_in_every_command() {
    // A scene's name is its file's. The summaries of `render`, `reference` and `bench` printed it
    // raw (an escape sequence cleared the screen, a line break split a summary in two, a
    // right-to-left override reversed the rest of the line), and in the titles of `compare`'s
    // charts a control character made the SVG invalid after every run had been rendered:
    // `compare` failed, left the broken SVG and never wrote `compare.csv` or `compare.json`.
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    for f in ["cornell.obj", "cornell.mtl"] {
        std::fs::copy(scenes.join(f), d.join(f)).unwrap();
    }
    let name = "e\u{1b}[2J\u{1}x\n\u{202e}y";
    std::fs::copy(scenes.join("cornell.toml"), d.join(format!("{name}.toml"))).unwrap();
    let scene = format!("{name}.toml");
    let shown = "e\\u{1b}[2J\\u{1}x \\u{202e}y";
    let commands: [&[&str]; 4] = [
        &[
            "render",
            &scene,
            "--res",
            "8x6",
            "--spp",
            "1",
            "--frames",
            "0",
            "--out",
            "o_####.exr",
        ],
        &[
            "reference",
            &scene,
            "--res",
            "8x6",
            "--frames",
            "3-5",
            "--reference-spp",
            "8",
            "--cache",
            "rc",
        ],
        &[
            "bench",
            &scene,
            "--res",
            "8x6",
            "--spp",
            "1",
            "--windows",
            "3",
            "--repeats",
            "1",
        ],
        &[
            "compare",
            &scene,
            "--res",
            "8x6",
            "--frames",
            "3-5",
            "--reference-spp",
            "8",
            "--cache",
            "rc",
            "--methods",
            "independent",
            "--budgets",
            "1",
            "--out",
            "cmp",
        ],
    ];
    for args in commands {
        let o = common::reframe(args).current_dir(d).output().unwrap();
        let (out, err) = (
            String::from_utf8(o.stdout).unwrap(),
            String::from_utf8(o.stderr).unwrap(),
        );
        assert!(o.status.success(), "{}: {err}", args[0]);
        for text in [&out, &err] {
            assert!(
                !text.contains(['\u{1b}', '\u{1}', '\u{202e}']),
                "{}: {text:?}",
                args[0]
            );
        }
        if args[0] != "compare" {
            // (The render's summary is on standard error, the others' on standard output.)
            let line = [&out, &err]
                .into_iter()
                .flat_map(|t| t.lines())
                .find(|l| l.contains(shown))
                .unwrap_or_else(|| panic!("{}: {out:?}", args[0]));
            assert!(
                line.contains("8x6"),
                "{}: the summary in one line: {line:?}",
                args[0]
            );
        }
    }
    for f in [
        "compare.csv",
        "compare.json",
        "error_vs_time.svg",
        "error_vs_time.png",
    ] {
        assert!(d.join("cmp").join(f).is_file(), "{f}");
    }
    let svg = std::fs::read_to_string(d.join("cmp/error_vs_time.svg")).unwrap();
    assert!(svg.contains(shown), "the title as messages show it");
}

#[test]
fn a_file_named_as_a_shipped_scene_is_said_to_be_the_file() {
    // `reframe render cornell` in a folder holding a file `cornell` reads the file: it did so
    // without a word, and its errors named `cornell` as if it were the shipped scene.
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let base = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus/base");
    for f in ["s.obj", "s.mtl"] {
        std::fs::copy(base.join(f), d.join(f)).unwrap();
    }
    std::fs::copy(base.join("s.toml"), d.join("cornell")).unwrap();
    let run = || {
        common::reframe(&[
            "render",
            "cornell",
            "--res",
            "8x6",
            "--spp",
            "1",
            "--out",
            "f_####.png",
        ])
        .current_dir(d)
        .output()
        .unwrap()
    };
    let o = run();
    let err = String::from_utf8(o.stderr).unwrap();
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains(
            "warning: 'cornell' is the file cornell here, not the shipped scene cornell: rename"
        ),
        "{err}"
    );
    // (A line continued in the source had left a run of spaces inside it.)
    assert!(!err.contains("  "), "{err:?}");
    // Broken, it is named as the file.
    std::fs::write(d.join("cornell"), "obj = \"missing.obj\"\n").unwrap();
    let o = run();
    let err = String::from_utf8(o.stderr).unwrap();
    assert!(!o.status.success());
    assert!(
        err.starts_with("error: cornell (a file here, not the shipped scene): "),
        "{err}"
    );
    // A shipped scene's name with no such file here is the shipped scene, without a note.
    std::fs::remove_file(d.join("cornell")).unwrap();
    let o = run();
    let err = String::from_utf8(o.stderr).unwrap();
    assert!(o.status.success() && !err.contains("warning"), "{err}");
}

#[test]
fn a_reuse_render_that_reuses_nothing_says_so() {
    // A film one pixel wide: every reuse falls off the other frames' films, so the method
    // costs its time and reuses nothing; it said nothing (`--window 1` is warned of).
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("f_####.exr");
    let o = common::reframe(&[
        "render",
        "cornell",
        "--method",
        "mis-exact",
        "--window",
        "3",
        "--res",
        "1x20000",
        "--frames",
        "0-2",
        "--spp",
        "1",
        "--out",
        out.to_str().unwrap(),
    ])
    .output()
    .unwrap();
    let err = String::from_utf8(o.stderr).unwrap();
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("% of the reuses were lost") && err.contains("a film 1x20000"),
        "{err}"
    );
    assert!(!err.contains("  "), "{err:?}");
    // An ordinary reuse render is not warned.
    let o = common::reframe(&[
        "render",
        "cornell",
        "--method",
        "mis-exact",
        "--window",
        "3",
        "--res",
        "32x32",
        "--frames",
        "0-2",
        "--spp",
        "1",
        "--out",
        out.to_str().unwrap(),
    ])
    .output()
    .unwrap();
    let err = String::from_utf8(o.stderr).unwrap();
    assert!(o.status.success() && !err.contains("warning"), "{err}");
}
