//! `--denoise`: Open Image Denoise on every frame (loaded at run time from the runtime that
//! `setup.sh` unpacks). The denoised furnace is nearer its exact radiance than the raw frame and
//! keeps its mean; the raw layer of a denoised render is the undenoised render, bit for bit; PNG
//! output works; a missing library is one line before anything is written. `compare` runs
//! denoised methods beside the plain ones, times their denoising and estimates their bias.
mod common;

use reframe::driver::denoise::Layers;
use reframe::driver::{render, RenderOptions};
use reframe::embree::Device;
use reframe::image::{read_image, Image};
use reframe::reuse::Method;
use reframe::scene::Scene;
use std::path::Path;

fn channel(img: &Image, name: &str) -> Vec<f32> {
    let c = img
        .channel_index(name)
        .unwrap_or_else(|| panic!("no channel {name} in {:?}", img.channels));
    let n = img.channels.len();
    img.data.iter().skip(c).step_by(n).copied().collect()
}

fn rgb(img: &Image, prefix: &str) -> Vec<f32> {
    let (r, g, b) = (
        channel(img, &format!("{prefix}R")),
        channel(img, &format!("{prefix}G")),
        channel(img, &format!("{prefix}B")),
    );
    (0..r.len()).flat_map(|i| [r[i], g[i], b[i]]).collect()
}

fn render_to(scene: &Scene, dir: &Path, name: &str, opts: RenderOptions) -> Image {
    let out = dir.join(format!("{name}_####.exr"));
    let opts = RenderOptions {
        out: out.to_str().unwrap().into(),
        exr_float: true,
        progress: false,
        ..opts
    };
    let stats = render(scene, &opts).unwrap();
    if opts.denoise.is_some() {
        assert!(stats.denoise_seconds > 0.0);
        assert!(stats.denoise_seconds < stats.seconds);
    } else {
        assert_eq!(stats.denoise_seconds, 0.0);
    }
    let f = opts.frames.as_ref().map_or(0, |r| *r.start());
    read_image(&dir.join(format!("{name}_{f:04}.exr"))).unwrap()
}

/// Frame 1 of `scene` at 2 spp, denoised, with its raw radiance and guides as layers.
fn denoised_frame_1(scene: &Scene, dir: &Path) -> Image {
    render_to(
        scene,
        dir,
        "f",
        RenderOptions {
            spp: 2,
            frames: Some(1..=1),
            denoise: Some(Layers::RawAndGuides),
            ..RenderOptions::default()
        },
    )
}

#[test]
fn denoising_the_furnace_brings_it_nearer_one_and_keeps_its_mean() {
    let device = Device::new().unwrap();
    let scene = Scene::load("furnace", &device).unwrap();
    let d = tempfile::tempdir().unwrap();
    let img = denoised_frame_1(&scene, d.path());
    let (den, raw) = (rgb(&img, ""), rgb(&img, "raw."));
    let rms = |v: &[f32]| {
        (v.iter().map(|x| (x - 1.0).powi(2) as f64).sum::<f64>() / v.len() as f64).sqrt()
    };
    let mean = |v: &[f32]| v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64;
    eprintln!(
        "furnace at 2 spp: rms error raw {:.4}, denoised {:.4}; means {:.4} and {:.4}",
        rms(&raw),
        rms(&den),
        mean(&raw),
        mean(&den)
    );
    assert!(rms(&raw) > 0.05, "the raw frame is not noisy: no subject");
    assert!(
        rms(&den) < 0.5 * rms(&raw),
        "{} vs {}",
        rms(&den),
        rms(&raw)
    );
    assert!((mean(&den) / mean(&raw) - 1.0).abs() < 0.01);
    // The guides: a closed diffuse sphere, albedo Kd = 0.5 everywhere, unit normals.
    let albedo = rgb(&img, "albedo.");
    assert!(albedo.iter().all(|&a| (a - 0.5).abs() < 1e-6));
    let (nx, ny, nz) = (
        channel(&img, "normal.X"),
        channel(&img, "normal.Y"),
        channel(&img, "normal.Z"),
    );
    for i in 0..nx.len() {
        let l = (nx[i] * nx[i] + ny[i] * ny[i] + nz[i] * nz[i]).sqrt();
        assert!(l > 0.95 && l <= 1.0 + 1e-5, "normal length {l}");
    }
}

/// A frame is denoised alike at any level of light: the furnace lit at 1e-10 (every pixel below
/// the luminance OIDN's auto-exposure counts, where the denoised frame came out zero) and at
/// 1e7 keeps its mean, and its denoised frame is the one at radiance 1 scaled, to 0.1%.
#[test]
fn a_frame_is_denoised_alike_at_any_level_of_light() {
    let device = Device::new().unwrap();
    let d = tempfile::tempdir().unwrap();
    let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    let mut denoised = Vec::new();
    for (i, level) in [1.0f64, 1e-10, 1e7].into_iter().enumerate() {
        let dir = d.path().join(format!("l{i}"));
        std::fs::create_dir(&dir).unwrap();
        for f in ["furnace.obj", "furnace.toml"] {
            std::fs::copy(scenes.join(f), dir.join(f)).unwrap();
        }
        // Kd 0.5 and Ke 0.5 * level: radiance `level` everywhere.
        let ke = 0.5 * level;
        std::fs::write(
            dir.join("furnace.mtl"),
            format!("newmtl furnace\nKd 0.5 0.5 0.5\nKe {ke:e} {ke:e} {ke:e}\n"),
        )
        .unwrap();
        let scene = Scene::load(dir.join("furnace.toml").to_str().unwrap(), &device).unwrap();
        let img = denoised_frame_1(&scene, &dir);
        let mean = |v: &[f32]| v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64;
        let (den, raw) = (rgb(&img, ""), rgb(&img, "raw."));
        eprintln!(
            "radiance {level:e}: means raw {:e}, denoised {:e}",
            mean(&raw),
            mean(&den)
        );
        assert!(
            (mean(&den) / mean(&raw) - 1.0).abs() < 0.01,
            "radiance {level:e}: denoised mean {:e} against raw {:e}",
            mean(&den),
            mean(&raw)
        );
        denoised.push((level, den));
    }
    let (_, one) = &denoised[0];
    for (level, den) in &denoised[1..] {
        let off = den
            .iter()
            .zip(one)
            .map(|(&a, &b)| (a as f64 / level - b as f64).abs())
            .fold(0.0, f64::max);
        assert!(
            off < 1e-3,
            "radiance {level:e}: off the frame at 1 by {off}"
        );
    }
}

#[test]
fn a_denoised_render_differs_from_a_plain_one_only_in_its_rgb() {
    let device = Device::new().unwrap();
    let scene = Scene::load("vase", &device).unwrap();
    let d = tempfile::tempdir().unwrap();
    for method in [Method::Independent, Method::MisCv] {
        let base = RenderOptions {
            method,
            spp: 2,
            window: if method == Method::Independent { 1 } else { 3 },
            frames: Some(20..=22),
            resolution: Some((64, 48)),
            aov: method.reuses(),
            ..RenderOptions::default()
        };
        let plain = render_to(
            &scene,
            d.path(),
            &format!("p{}", method.name()),
            base.clone(),
        );
        let den = render_to(
            &scene,
            d.path(),
            &format!("d{}", method.name()),
            RenderOptions {
                denoise: Some(Layers::RawAndGuides),
                ..base
            },
        );
        assert_eq!(rgb(&den, "raw."), rgb(&plain, ""), "{method:?}");
        for c in plain.channels.iter().skip(3) {
            assert_eq!(channel(&den, c), channel(&plain, c), "{method:?} {c}");
        }
        assert_ne!(
            rgb(&den, ""),
            rgb(&plain, ""),
            "{method:?}: nothing was denoised"
        );
        assert!(rgb(&den, "").iter().all(|v| v.is_finite() && *v >= 0.0));
    }
}

#[test]
fn png_output_gets_the_denoised_frame_and_a_missing_library_is_one_line() {
    let d = tempfile::tempdir().unwrap();
    let run = |args: &[&str], lib: Option<&str>| {
        let mut c = common::reframe(&[
            "render", "furnace", "--spp", "1", "--frames", "0", "--res", "32x32",
        ]);
        c.args(args);
        if let Some(l) = lib {
            c.env("REFRAME_OIDN_LIB", l);
        }
        c.output().unwrap()
    };
    let png = d.path().join("den_####.png");
    let o = run(&["--denoise", "--out", png.to_str().unwrap()], None);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let den = read_image(&d.path().join("den_0000.png")).unwrap();
    let plain_path = d.path().join("plain_####.png");
    let o = run(&["--out", plain_path.to_str().unwrap()], None);
    assert!(o.status.success());
    let plain = read_image(&d.path().join("plain_0000.png")).unwrap();
    // The furnace is 1 everywhere: noise shows as pixels off white in the 8-bit frame.
    let off = |img: &Image| img.data.iter().filter(|&&v| v < 0.97).count();
    assert!(
        off(&den) < off(&plain) / 2,
        "{} vs {}",
        off(&den),
        off(&plain)
    );
    // No library: one line, a failing exit, nothing written (not even the output folder).
    let out = d.path().join("missing/f_####.exr");
    let o = run(
        &["--denoise", "--out", out.to_str().unwrap()],
        Some("/nonexistent/libOpenImageDenoise.so.2"),
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("cannot load Open Image Denoise"), "{err}");
    assert!(!d.path().join("missing").exists());
    // A bare name is a file in the current folder, checked as such (the loader searched its
    // library path for it, and a FIFO of that name was "No such file").
    assert!(std::process::Command::new("mkfifo")
        .arg(d.path().join("libx.so"))
        .status()
        .unwrap()
        .success());
    let o = common::reframe(&[
        "render",
        "furnace",
        "--spp",
        "1",
        "--frames",
        "0",
        "--res",
        "32x32",
        "--denoise",
        "--out",
        "bare/f_####.exr",
    ])
    .current_dir(d.path())
    .env("REFRAME_OIDN_LIB", "libx.so")
    .output()
    .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("'./libx.so': is a named pipe (FIFO)"),
        "{err}"
    );
    // `compare` names its own flag, the method that asked for the denoiser.
    let o = common::reframe(&[
        "compare",
        "furnace",
        "--methods",
        "independent+oidn",
        "--frames",
        "0-2",
        "--res",
        "32x32",
        "--out",
        d.path().join("cmp").to_str().unwrap(),
    ])
    .env("REFRAME_OIDN_LIB", "/nonexistent/libOpenImageDenoise.so.2")
    .output()
    .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success()
            && err.starts_with("error: --methods independent+oidn: cannot load Open Image Denoise"),
        "{err}"
    );
    // Not a denoiser: the library loads but lacks the API.
    let o = run(
        &["--denoise", "--out", out.to_str().unwrap()],
        Some("libm.so.6"),
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(err.contains("is not Open Image Denoise 2"), "{err}");
    // The missing function named as such, without the C string's NUL (`oidnNewDevice\u{0}`).
    assert!(err.contains(": oidnNewDevice: "), "{err}");
    assert!(!d.path().join("missing").exists());
    // A FIFO in its place is refused at once (the loader would wait on it forever).
    let fifo = d.path().join("oidn-fifo");
    assert!(std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap()
        .success());
    let o = run(
        &["--denoise", "--out", out.to_str().unwrap()],
        Some(fifo.to_str().unwrap()),
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("not a regular file"), "{err}");
    // A library cut short (a copy interrupted) is mapped as if whole, and touching a page past
    // its end killed the process with SIGBUS, saying nothing: now one line. Any ELF file cut
    // short shows it (this test's own executable).
    let cut = d.path().join("cut/libOpenImageDenoise.so.2");
    std::fs::create_dir(d.path().join("cut")).unwrap();
    let exe = std::fs::read(std::env::current_exe().unwrap()).unwrap();
    std::fs::write(&cut, &exe[..10_000]).unwrap();
    let o = run(
        &["--denoise", "--out", out.to_str().unwrap()],
        Some(cut.to_str().unwrap()),
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("cut short: its headers reach byte"), "{err}");
    assert!(!d.path().join("missing").exists());
}

#[test]
fn compare_runs_denoised_methods_with_their_time_and_bias() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("cmp");
    let cache = d.path().join("cache");
    let o = common::reframe(&[
        "compare",
        "vase",
        "--res",
        "64x48",
        "--frames",
        "20-24",
        "--reference-spp",
        "64",
        "--methods",
        "independent,independent+oidn,mis-cv+oidn",
        "--budgets",
        "1,2",
        "--windows",
        "3",
        "--reuse-budgets",
        "1",
        "--bias-seeds",
        "3",
        "--threads",
        "2",
    ])
    .arg("--out")
    .arg(&out)
    .arg("--cache")
    .arg(&cache)
    .output()
    .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let c: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("compare.json")).unwrap()).unwrap();
    let runs = c["runs"].as_array().unwrap();
    let run = |m: &str, spp: u64| {
        runs.iter()
            .find(|r| r["method"] == m && r["spp"] == spp)
            .unwrap_or_else(|| panic!("no {m} run at {spp} spp"))
    };
    for spp in [1, 2] {
        let (plain, den) = (run("independent", spp), run("independent+oidn", spp));
        assert_eq!(plain["denoise_seconds"], 0.0);
        let ds = den["denoise_seconds"].as_f64().unwrap();
        assert!(ds > 0.0 && ds < den["seconds"].as_f64().unwrap(), "{den}");
        // The denoiser removes most of the error of a 1-2 spp frame (bias included).
        let (e0, e1) = (
            plain["relmse"].as_f64().unwrap(),
            den["relmse"].as_f64().unwrap(),
        );
        assert!(e1 < 0.5 * e0, "relMSE {e1} denoised against {e0}");
    }
    assert!(run("mis-cv+oidn", 1)["denoise_seconds"].as_f64().unwrap() > 0.0);
    // Bias: independent's is zero up to the seeds' noise (the estimator itself is tested on known
    // biases in errors.rs); the denoiser's is part of its error.
    let bias = c["bias"].as_array().unwrap();
    let of = |m: &str| {
        let b = bias
            .iter()
            .find(|b| b["method"] == m)
            .unwrap_or_else(|| panic!("no bias for {m}: {bias:?}"));
        assert_eq!(b["seeds"], 3);
        assert!(Path::new(b["image"].as_str().unwrap()).is_file(), "{b}");
        (
            b["bias_relmse"].as_f64().unwrap(),
            b["relmse"].as_f64().unwrap(),
        )
    };
    let (bi, ei) = of("independent");
    assert!(
        bi.abs() < 0.15 * ei,
        "independent: bias {bi} of relMSE {ei}"
    );
    let (bd, ed) = of("independent+oidn");
    assert!(
        bd.is_finite() && bd < ed,
        "independent+oidn: bias {bd} of relMSE {ed}"
    );
    let (bm, em) = of("mis-cv+oidn");
    assert!(
        bm.is_finite() && bm < em,
        "mis-cv+oidn: bias {bm} of relMSE {em}"
    );
    let t = c["denoised_equal_time_seconds"].as_f64().unwrap();
    assert!(t > c["equal_time_seconds"].as_f64().unwrap());
    for m in ["independent", "independent+oidn", "mis-cv+oidn"] {
        assert!(
            c["denoised_equal_time_flicker"][m].as_f64().unwrap() > 0.0,
            "{m}"
        );
    }
    assert!(c["equal_time_flicker"].get("independent+oidn").is_none());
    // (At this size the denoised error barely falls with time, so the fit may have no speed-up.)
    assert!(c["equal_error_speedup_over_denoised"].is_object());
    for f in ["bias.png", "crops.png", "flicker_denoised.png"] {
        assert!(out.join(f).is_file(), "{f}");
    }
    let csv = std::fs::read_to_string(out.join("compare.csv")).unwrap();
    assert!(csv.lines().next().unwrap().ends_with(",denoise_seconds"));
    assert!(csv.contains("\nmis-cv+oidn,3,1,"), "{csv}");
}

#[test]
fn chunks_rendered_with_denoise_merge_into_the_one_process_denoised_frames() {
    let d = tempfile::tempdir().unwrap();
    let run = |args: &[&str]| common::reframe(args).output().unwrap();
    let (one, chunked) = (d.path().join("one"), d.path().join("chunked"));
    let common = [
        "render",
        "vase",
        "--method",
        "mis-cv",
        "--window",
        "3",
        "--spp",
        "1",
        "--frames",
        "0-4",
        "--res",
        "48x36",
        "--threads",
        "2",
        "--denoise",
        "--denoise-layers",
    ];
    let pattern = |dir: &Path| dir.join("f_####.exr").to_str().unwrap().to_string();
    let o = run(&[&common[..], &["--out", &pattern(&one)]].concat());
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for k in ["1/2", "2/2"] {
        let o = run(&[&common[..], &["--out", &pattern(&chunked), "--chunk", k]].concat());
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let merge = |more: &[&str]| {
        run(&[
            &["merge", "--chunks", "2", "--out", &pattern(&chunked)][..],
            more,
        ]
        .concat())
    };
    // The chunks asked for denoising: without the scene, or with another one, nothing is written.
    for (more, needle) in [
        (&[][..], "name it with --scene"),
        (
            &["--scene", "cornell"][..],
            "not the scene the chunks rendered",
        ),
    ] {
        let o = merge(more);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            !o.status.success() && err.contains(needle),
            "{more:?}: {err}"
        );
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(!chunked.join("f_0000.exr").exists());
    }
    // One denoiser thread in the merge, two in the one-process render: the same frames.
    let o = merge(&["--scene", "vase", "--threads", "1"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // Denoised RGB, raw layer and guides: the frames of one process, bit for bit.
    common::assert_identical(&one, &chunked, (0..5).map(|f| format!("f_{f:04}.exr")));
    let img = read_image(&chunked.join("f_0002.exr")).unwrap();
    assert_ne!(rgb(&img, ""), rgb(&img, "raw."));
}

#[test]
fn merge_never_writes_over_the_scene_it_denoises_with() {
    // The merge's --scene brings its own inputs: an --out pattern that names one of them (here
    // the environment image, e_0000.exr) is refused and the file left as it was (the merge
    // wrote the frame over it, exit 0, before the check took the scene's files).
    let d = tempfile::tempdir().unwrap();
    let (scene, env) = common::base_scene_with_sky(d.path());
    let before = std::fs::read(&env).unwrap();
    let at = |name: &str| d.path().join(name).to_str().unwrap().to_string();
    let out = at("o/f_####.exr");
    common::reframe_ok(&[
        "render",
        &scene,
        "--spp",
        "1",
        "--frames",
        "0",
        "--chunk",
        "1/1",
        "--denoise",
        "--threads",
        "1",
        "--out",
        &out,
    ]);
    let partial = at("o/f.chunk-1-of-1.partial");
    let o = common::reframe(&[
        "merge",
        &partial,
        "--scene",
        &scene,
        "--out",
        &at("e_####.exr"),
    ])
    .output()
    .unwrap();
    common::assert_refused(&o, "that is an input of this command");
    assert_eq!(
        std::fs::read(&env).unwrap(),
        before,
        "the environment image was written over"
    );
    common::reframe_ok(&["merge", &partial, "--scene", &scene]);
    assert!(d.path().join("o/f_0000.exr").exists());
}

/// A frame black in every pixel is black denoised (the denoiser made a pixel of 1e-6 of one); a
/// frame whose light comes from a few very bright points, whose mean the denoiser moves (by a
/// third in red and blue, tinting a grey scene), is warned of once; an ordinary one is not.
#[test]
fn a_black_frame_stays_black_and_a_moved_mean_is_warned() {
    let d = tempfile::tempdir().unwrap();
    let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    // `cornell`'s camera turned away from the box, into the empty scene: black.
    let away = std::fs::read_to_string(scenes.join("cornell.toml"))
        .unwrap()
        .replace(
            "obj = \"cornell.obj\"",
            &format!("obj = {:?}", scenes.join("cornell.obj")),
        )
        .replace("look_at = [0.0, 1.0, 0.0]", "look_at = [0.0, 1.0, 100.0]");
    std::fs::write(d.path().join("away.toml"), away).unwrap();
    let run = |scene: &Path, res: &str, spp: &str, name: &str| {
        let out = d.path().join(format!("{name}_####.exr"));
        let o = common::reframe(&[
            "render",
            scene.to_str().unwrap(),
            "--res",
            res,
            "--spp",
            spp,
            "--frames",
            "0",
            "--denoise",
            "--exr-float",
            "--out",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
        let err = String::from_utf8(o.stderr).unwrap();
        assert!(o.status.success(), "{err}");
        (
            read_image(&d.path().join(format!("{name}_0000.exr"))).unwrap(),
            err,
        )
    };
    let (black, _) = run(&d.path().join("away.toml"), "32x24", "1", "black");
    assert!(rgb(&black, "").iter().all(|&v| v == 0.0));
    let bright = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/denoise_scene/many.toml");
    let (_, err) = run(&bright, "32x24", "8", "bright");
    assert_eq!(
        err.matches("warning: denoising moved frame 0's mean by")
            .count(),
        1,
        "{err}"
    );
    let (_, err) = run(&scenes.join("cornell.toml"), "64x64", "4", "plain");
    assert!(!err.contains("denoising moved"), "{err}");
}
