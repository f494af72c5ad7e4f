//! End-to-end checks of the independent path tracer: the analytic furnace, determinism across
//! thread counts, and what a render leaves on disk (frames, metadata, statistics).
mod common;

use common::{assert_identical, reframe_ok};
use reframe::driver::{render, render_frame_independent, thread_pool, RenderOptions};
use reframe::embree::Device;
use reframe::integrator::{Integrator, Rays};
use reframe::scene::Scene;

/// Inside a closed sphere of albedo 0.5 and emission 0.5 the radiance is 1 everywhere
/// (L = Le + rho L). The mean of the image must be 1 within a tight tolerance, and so must every
/// 8x8 block (a wrong light pdf or MIS weight shifts some directions more than others).
#[test]
fn furnace_is_one() {
    let device = Device::new().unwrap();
    let scene = Scene::load("furnace", &device).unwrap();
    let integ = Integrator::new(&scene, 64);
    let pool = thread_pool(0).unwrap();
    let cam = scene.camera(0, 64, 64);
    let f = pool.install(|| render_frame_independent(&integ, &cam, 0, 64, 3, false, &|_| {}));
    let n = f.pixels.len() as f64;
    let mean: f64 = f.pixels.iter().map(|p| p.x as f64).sum::<f64>() / n;
    assert!((mean - 1.0).abs() < 0.005, "furnace mean {mean}");
    for p in &f.pixels {
        assert!(
            (p.x - p.y).abs() < 1e-6 && (p.x - p.z).abs() < 1e-6,
            "grey in, grey out"
        );
    }
    for by in 0..8 {
        for bx in 0..8 {
            let mut s = 0.0f64;
            for y in 0..8 {
                for x in 0..8 {
                    s += f.pixels[(by * 8 + y) * 64 + bx * 8 + x].x as f64;
                }
            }
            let m = s / 64.0;
            assert!((m - 1.0).abs() < 0.04, "block ({bx},{by}) mean {m}");
        }
    }
}

/// The CLI's default path length leaves a bright closed room as bright as it is: inside the
/// shipped furnace sphere made of albedo 0.9 and emission 0.1 the radiance is 0.1 / (1 - 0.9) = 1
/// everywhere, of which paths cut at 16 bounces (the default before) carry 1 - 0.9^17 = 0.83.
/// Rendered by `reframe render` with no `--max-depth` and `--exr-float`, the mean must be 1
/// within 1% (its noise at 16 spp on 48 x 48 pixels is about 0.3%).
#[test]
fn a_bright_closed_room_is_not_darkened_by_the_default_depth() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scenes = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    std::fs::copy(scenes.join("furnace.obj"), d.join("furnace.obj")).unwrap();
    std::fs::copy(scenes.join("furnace.toml"), d.join("furnace.toml")).unwrap();
    std::fs::write(
        d.join("furnace.mtl"),
        "newmtl furnace\nKd 0.9 0.9 0.9\nKe 0.1 0.1 0.1\n",
    )
    .unwrap();
    let out = d.join("f_####.exr");
    reframe_ok(&[
        "render",
        d.join("furnace.toml").to_str().unwrap(),
        "--frames",
        "0",
        "--res",
        "48x48",
        "--spp",
        "16",
        "--exr-float",
        "--out",
        out.to_str().unwrap(),
    ]);
    let img = reframe::image::read_image(&d.join("f_0000.exr")).unwrap();
    let n = (img.width * img.height) as f64;
    let mean = img
        .data
        .chunks(img.channels.len())
        .map(|p| p[0] as f64)
        .sum::<f64>()
        / n;
    assert!((mean - 1.0).abs() < 0.01, "mean radiance {mean}, not 1");
}

/// A floor, a box resting on it, a box hovering 1% of its size above it (a thin contact
/// shadow) and a light, lit by a grey sky too: scaled by `scale` and moved by `shift` (after
/// scaling), rendered at 48x36 with 64 samples and one seed. `Shift::Placed` moves it with an
/// `[[object]]`'s `translate`, `Shift::Written` writes the moved vertices into the OBJ.
fn contact_scene(
    device: &Device,
    d: &std::path::Path,
    scale: f64,
    shift: [f64; 3],
    how: Shift,
) -> Vec<glam::Vec3> {
    // Quads as (corner, edge, edge), counter-clockwise seen from the side they face.
    let floor = ([-1.5, 0.0, 1.5], [3.0, 0.0, 0.0], [0.0, 0.0, -3.0]);
    let light = ([-0.3, 1.8, -0.3], [0.6, 0.0, 0.0], [0.0, 0.0, 0.6]);
    let boxes = [([-0.9, 0.0, -0.6], 0.5), ([0.2, 0.005, -0.4], 0.5)];
    let at = |a: [f64; 3]| -> [f64; 3] { std::array::from_fn(|i| a[i] * scale + shift[i]) };
    let vertex_at = |a: [f64; 3]| -> [f64; 3] {
        match how {
            Shift::Written => at(a),
            Shift::Placed => a.map(|c| c * scale),
        }
    };
    let mut obj = String::from("mtllib s.mtl\n");
    let mut n = 0;
    let mut quad = |obj: &mut String, mat: &str, (c, a, b): ([f64; 3], [f64; 3], [f64; 3])| {
        let p = |u: f64, v: f64| -> String {
            let q = vertex_at(std::array::from_fn(|i| c[i] + u * a[i] + v * b[i]));
            format!("v {:e} {:e} {:e}\n", q[0], q[1], q[2])
        };
        *obj += &format!(
            "usemtl {mat}\n{}{}{}{}",
            p(0., 0.),
            p(1., 0.),
            p(1., 1.),
            p(0., 1.)
        );
        *obj += &format!("f {} {} {} {}\n", n + 1, n + 2, n + 3, n + 4);
        n += 4;
    };
    quad(&mut obj, "grey", floor);
    quad(&mut obj, "light", (light.0, light.2, light.1));
    for (c, e) in boxes {
        let [x, y, z] = c;
        // Five faces (the bottom is never seen), each facing out.
        quad(
            &mut obj,
            "grey",
            ([x, y + e, z], [0.0, 0.0, e], [e, 0.0, 0.0]),
        );
        quad(
            &mut obj,
            "grey",
            ([x, y, z + e], [e, 0.0, 0.0], [0.0, e, 0.0]),
        );
        quad(
            &mut obj,
            "grey",
            ([x + e, y, z], [-e, 0.0, 0.0], [0.0, e, 0.0]),
        );
        quad(&mut obj, "grey", ([x, y, z], [0.0, 0.0, e], [0.0, e, 0.0]));
        quad(
            &mut obj,
            "grey",
            ([x + e, y, z + e], [0.0, 0.0, -e], [0.0, e, 0.0]),
        );
    }
    std::fs::write(d.join("s.obj"), obj).unwrap();
    std::fs::write(
        d.join("s.mtl"),
        "newmtl grey\nKd 0.6 0.6 0.6\nnewmtl light\nKd 0 0 0\nKe 8 8 8\n",
    )
    .unwrap();
    let v = |a: [f64; 3]| {
        let a = at(a);
        format!("[{:e}, {:e}, {:e}]", a[0], a[1], a[2])
    };
    // A top-level key before the tables, or a table of its own after them.
    let (top, objects) = match how {
        Shift::Written => ("obj = \"s.obj\"\n".to_string(), String::new()),
        Shift::Placed => (
            String::new(),
            format!(
                "[[object]]\nobj = \"s.obj\"\ntranslate = [{:e}, {:e}, {:e}]\n",
                shift[0], shift[1], shift[2]
            ),
        ),
    };
    std::fs::write(
        d.join("s.toml"),
        format!(
            "{top}frames = 1\nresolution = [48, 36]\n[environment]\n\
             radiance = [0.3, 0.3, 0.3]\n[[keyframe]]\nframe = 0\nposition = {}\n\
             look_at = {}\nup = [0, 1, 0]\nfov = 50\n{objects}",
            v([0.0, 1.6, 2.6]),
            v([0.0, 0.2, -0.3])
        ),
    )
    .unwrap();
    let scene = Scene::load(d.join("s.toml").to_str().unwrap(), device).unwrap();
    let integ = Integrator::new(&scene, 8);
    let cam = scene.camera(0, 48, 36);
    let pool = thread_pool(0).unwrap();
    pool.install(|| render_frame_independent(&integ, &cam, 0, 64, 1, false, &|_| {}))
        .pixels
}

/// How `contact_scene` is moved from the origin.
#[derive(Clone, Copy, Debug)]
enum Shift {
    /// Its vertices written where they are.
    Written,
    /// Its OBJ at the origin, placed by an `[[object]]`'s `translate`.
    Placed,
}

/// The largest departure of a 4x4 grid of regions (12x9 pixels each) of a 48x36 `img` from
/// those of `base`, as a ratio less one, and the region.
fn worst_region(img: &[glam::Vec3], base: &[glam::Vec3]) -> (f64, usize, usize) {
    let region = |img: &[glam::Vec3], rx: usize, ry: usize| -> f64 {
        let mut sum = 0.0;
        for y in ry * 9..(ry + 1) * 9 {
            for x in rx * 12..(rx + 1) * 12 {
                let p = img[y * 48 + x];
                sum += (p.x + p.y + p.z) as f64;
            }
        }
        sum
    };
    let mut worst = (0.0f64, 0, 0);
    for ry in 0..4 {
        for rx in 0..4 {
            let off = region(img, rx, ry) / region(base, rx, ry) - 1.0;
            if off.abs() > worst.0.abs() {
                worst = (off, rx, ry);
            }
        }
    }
    worst
}

/// A scene renders the same whatever size it is modelled at, near the origin: `contact_scene`
/// scaled by 1e-5 (a scene in units of 100 km), 1e-3 and 1e3, against scale 1, with the same
/// seed. Ray origins are offset off their surfaces by at least `SPAWN_EPS` (7.6e-6) units
/// times a floor that was 1 at every scale: at 1e-5 that is a quarter of the scene, and light
/// leaked into every contact shadow (3% brighter overall, 6-11% in a quarter of the regions).
#[test]
fn a_scene_renders_the_same_at_any_scale() {
    let device = Device::new().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let base = contact_scene(&device, dir.path(), 1.0, [0.0; 3], Shift::Written);
    for scale in [1e-5, 1e-3, 1e3] {
        let img = contact_scene(&device, dir.path(), scale, [0.0; 3], Shift::Written);
        let (off, rx, ry) = worst_region(&img, &base);
        assert!(
            off.abs() < 0.005,
            "scale {scale}: region ({rx}, {ry}) {off:+} off scale 1's"
        );
    }
}

/// A scene renders the same wherever it is modelled: `contact_scene` moved 10^4 and 10^5 units
/// away (a building at its map position) against the same at the origin. Ray origins are
/// offset by `SPAWN_EPS` times the largest coordinate: at 10^5 units that is 0.8 units, and
/// light leaked under the hovering box (15% brighter overall; 0.6% at 10^4) until the render
/// moved such a scene to the origin (`Scene::origin`). The frames' camera matrices stay in the
/// file's coordinates.
#[test]
fn a_scene_renders_the_same_far_from_the_origin() {
    let device = Device::new().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let base = contact_scene(&device, dir.path(), 1.0, [0.0; 3], Shift::Written);
    let load = || Scene::load(dir.path().join("s.toml").to_str().unwrap(), &device).unwrap();
    // Where the camera at the origin sees the floor's centre.
    let at_origin = load()
        .camera(0, 48, 36)
        .world_to_ndc()
        .project_point3(glam::Vec3::ZERO);
    // The matrices are f32 (OpenEXR's): 3e5 units away they round the eye to 0.03 units.
    let cases = [
        ([1e4, 0.0, -2e4], Shift::Written, 1e-3),
        ([-3e5, 1e5, 7e4], Shift::Written, 0.02),
        ([-3e5, 1e5, 7e4], Shift::Placed, 0.02),
        ([5.1e6, 0.0, 3.3e5], Shift::Placed, 0.2),
        // Fractions f32 cannot hold out there (it rounds to half a unit at 5x10^6): the
        // vertices and the camera are read in f64 and moved before they are rounded.
        ([5.1e6 + 0.3, 0.0, -3.3e5 + 0.7], Shift::Written, 0.2),
        // 10^9 out, f32 cannot tell the camera's position from its look-at (refused as
        // 'look_at coincides with position' until the cameras were checked from the origin);
        // the f32 matrices there are 64 units coarse (the eye and the floor one point): not
        // checked.
        ([1e9, 1e9, 1e9], Shift::Written, f32::INFINITY),
    ];
    for (shift, how, tol) in cases {
        let img = contact_scene(&device, dir.path(), 1.0, shift, how);
        let (off, rx, ry) = worst_region(&img, &base);
        assert!(
            off.abs() < 0.005,
            "moved by {shift:?} ({how:?}): region ({rx}, {ry}) {off:+} off the scene at the origin"
        );
        let cam = load().camera(0, 48, 36);
        // The floor's centre, in the file's coordinates, is where the camera at the origin
        // sees it.
        let floor_centre = glam::Vec3::new(shift[0] as f32, shift[1] as f32, shift[2] as f32);
        let seen = cam.world_to_ndc().project_point3(floor_centre);
        assert!(
            !tol.is_finite() || (seen - at_origin).abs().max_element() < tol,
            "moved by {shift:?}: the matrices put the floor at {seen}, not {at_origin}"
        );
    }
}

/// Rays in 16-wide packets (primary rays in 4x4 pixel blocks, the wavefront's shadow and
/// continuation rays 16 live paths at a time) and one at a time give the same frames up to the
/// rounding of Embree's two kernels: on a closed room, a glossy vase and the instanced
/// production scene, at sizes whose tiles end in partial blocks (37x23: blocks of 1 to 16 lanes),
/// with environment pixels, more than one sample per pixel, and both thread counts.
#[test]
fn packets_give_the_single_ray_frames() {
    let device = Device::new().unwrap();
    let root = env!("CARGO_MANIFEST_DIR");
    for (name, w, h, spp) in [
        ("cornell".to_string(), 37, 23, 3),
        ("vase".to_string(), 64, 48, 2),
        (
            format!("{root}/scenes/production/courtyard.toml"),
            61,
            45,
            2,
        ),
    ] {
        let scene = Scene::load(&name, &device).unwrap();
        let frame = scene.frames / 2;
        let cam = scene.camera(frame, w, h);
        let render = |rays, threads| {
            let mut integ = Integrator::new(&scene, 16);
            integ.primary = rays;
            integ.paths = rays;
            thread_pool(threads)
                .unwrap()
                .install(|| render_frame_independent(&integ, &cam, frame, spp, 7, false, &|_| {}))
        };
        let (single, packet) = (render(Rays::Single, 1), render(Rays::Packet, 2));
        assert_eq!(single.counts, packet.counts, "{name}: ray counts");
        let mut bitwise = 0;
        for (i, (a, b)) in single.pixels.iter().zip(&packet.pixels).enumerate() {
            let close = (*a - *b).abs().max_element() <= 1e-3 * a.abs().max_element().max(1.0);
            assert!(close, "{name}: pixel {i}: {a} single, {b} packet");
            bitwise += (a.to_array().map(f32::to_bits) == b.to_array().map(f32::to_bits)) as usize;
        }
        // Rounding changes a hit now and then; most pixels must agree bit for bit.
        let n = single.pixels.len();
        assert!(
            bitwise * 100 >= n * 99,
            "{name}: {bitwise} of {n} pixels bitwise equal"
        );
        assert_eq!(
            packet.pixels,
            render(Rays::Packet, 1).pixels,
            "{name}: thread counts"
        );
    }
}

#[test]
fn frames_are_identical_for_any_thread_count() {
    let device = Device::new().unwrap();
    let scene = Scene::load("vase", &device).unwrap();
    let integ = Integrator::new(&scene, 16);
    let cam = scene.camera(10, 96, 72);
    let one = thread_pool(1)
        .unwrap()
        .install(|| render_frame_independent(&integ, &cam, 10, 4, 9, false, &|_| {}));
    let three = thread_pool(3)
        .unwrap()
        .install(|| render_frame_independent(&integ, &cam, 10, 4, 9, false, &|_| {}));
    assert!(one
        .pixels
        .iter()
        .zip(&three.pixels)
        .all(|(a, b)| a.to_array().map(f32::to_bits) == b.to_array().map(f32::to_bits)));
    assert_eq!(one.counts, three.counts);
    let other_seed = thread_pool(2)
        .unwrap()
        .install(|| render_frame_independent(&integ, &cam, 10, 4, 10, false, &|_| {}));
    assert!(
        one.pixels != other_seed.pixels,
        "the seed must change the noise"
    );
}

#[test]
fn render_writes_frames_metadata_and_stats() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let device = Device::new().unwrap();
    let scene = Scene::load("cornell", &device).unwrap();
    let opts = RenderOptions {
        spp: 2,
        frames: Some(3..=4),
        resolution: Some((40, 30)),
        out: d.join("c_####.exr").display().to_string(),
        stats: Some(d.join("stats.json")),
        progress: false,
        ..RenderOptions::default()
    };
    let stats = render(&scene, &opts).unwrap();
    assert_eq!(stats.frames, 2);
    assert_eq!(stats.nonfinite_pixels, 0);
    let img = reframe::image::read_image(&d.join("c_0003.exr")).unwrap();
    assert_eq!((img.width, img.height), (40, 30));
    assert!(img.data.iter().any(|&v| v > 0.0), "black frame");
    assert!(d.join("c_0004.exr").exists() && !d.join("c_0002.exr").exists());
    let meta = reframe::image::read_metadata(&d.join("c_0004.exr")).unwrap();
    let get = |k: &str| meta.iter().find(|(n, _)| n == k).map(|(_, v)| v.clone());
    assert_eq!(get("reframe:method").as_deref(), Some("independent"));
    assert_eq!(get("reframe:spp").as_deref(), Some("2"));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("stats.json")).unwrap()).unwrap();
    for key in [
        "method",
        "width",
        "height",
        "frames",
        "spp",
        "seconds",
        "rays",
        "peak_rss_bytes",
        "nonfinite_pixels",
        "black_frames",
    ] {
        assert!(json.get(key).is_some(), "stats lack '{key}'");
    }
    // A lit frame is not black.
    assert_eq!(json["black_frames"], serde_json::json!([]));
    for kind in ["primary", "path", "shadow"] {
        assert!(json["rays"][kind].as_u64().unwrap() > 0, "no {kind} rays");
    }
    assert_eq!(json["rays"]["primary"].as_u64(), Some(2 * 40 * 30 * 2));
    // Nothing but the frames and the stats: no temporary files.
    let mut names: Vec<String> = std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into())
        .collect();
    names.sort();
    assert_eq!(names, ["c_0003.exr", "c_0004.exr", "stats.json"]);
}

/// Run `reframe render ARGS --threads T --out DIR/tT/f_####.exr` for 1 and 2 threads (`{t}` in
/// an argument is replaced by the thread count, `{dir}` by `d`), then assert that frames
/// `frames` are bitwise identical between the two runs. Returns the 1-thread frames.
fn render_with_1_and_2_threads(
    d: &std::path::Path,
    args: &[&str],
    frames: std::ops::RangeInclusive<u32>,
) -> Vec<reframe::image::Image> {
    for t in ["1", "2"] {
        let mut all: Vec<String> = vec!["render".into()];
        all.extend(args.iter().map(|a| {
            a.replace("{t}", t)
                .replace("{dir}", &d.display().to_string())
        }));
        let out = d.join(format!("t{t}/f_####.exr")).display().to_string();
        all.extend(["--exr-float", "--threads", t, "--out", &out].map(String::from));
        reframe_ok(&all);
    }
    let names = || frames.clone().map(|f| format!("f_{f:04}.exr"));
    assert_identical(&d.join("t1"), &d.join("t2"), names());
    names()
        .map(|n| reframe::image::read_image(&d.join("t1").join(n)).unwrap())
        .collect()
}

/// The command line end to end, as a user runs it: same command, same bytes, any thread count.
#[test]
fn cli_is_deterministic() {
    let dir = tempfile::tempdir().unwrap();
    render_with_1_and_2_threads(
        dir.path(),
        &["vase", "--frames", "5", "--res", "48x36", "--spp", "2"],
        5..=5,
    );
}

/// A reuse render through the CLI: bitwise identical for 1 and 2 threads, the reuse statistics
/// and the AOV channels are there.
#[test]
fn reuse_cli_stats_aov_and_determinism() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let args = [
        "vase",
        "--method",
        "mis-exact",
        "--window",
        "3",
        "--frames",
        "10-14",
        "--res",
        "40x30",
        "--spp",
        "1",
        "--aov",
        "--stats",
        "{dir}/s{t}.json",
    ];
    let frames = render_with_1_and_2_threads(d, &args, 10..=14);
    for (f, a) in (10..=14).zip(&frames) {
        for c in ["spp_eff", "lost_reuse"] {
            assert!(
                a.channels.iter().any(|n| n == c),
                "frame {f} lacks channel {c}: {:?}",
                a.channels
            );
        }
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("s1.json")).unwrap()).unwrap();
    assert_eq!(json["window"].as_u64(), Some(3));
    assert!(json["rays"]["visibility"].as_u64().unwrap() > 0);
    assert_eq!(json["nonfinite_pixels"].as_u64(), Some(0));
    // Middle frames belong to 3 groups of 3 frames, each shooting 1 spp: up to 9 samples land.
    let spp = json["mean_effective_spp"].as_f64().unwrap();
    assert!(spp > 3.0 && spp <= 9.0, "mean_effective_spp {spp}");
    let lost = json["lost_reuse_fraction"].as_f64().unwrap();
    assert!((0.0..0.5).contains(&lost), "lost_reuse_fraction {lost}");
    assert_eq!(json["per_frame"].as_array().unwrap().len(), 5);
}

/// The reuse kernel sums a block's splats into each frame in floating point, in the block's
/// order (`film::local`), so its blocks follow the resolution alone
/// (`reuse::shade::block_side`: at 192x192, 32-pixel blocks, 36 of them, which one thread and
/// two share out differently, each window flushed at another time): the frames are the same to
/// the bit (`mis-cv`, whose weights and two folds go through every part of a splat).
#[test]
fn reuse_frames_are_the_same_for_any_thread_count() {
    use reframe::reuse::shade::block_side;
    assert_eq!(block_side(192, 192), 32);
    let dir = tempfile::tempdir().unwrap();
    let args = [
        "vase", "--method", "mis-cv", "--window", "5", "--frames", "20-25", "--res", "192x192",
        "--spp", "1",
    ];
    let d = dir.path();
    render_with_1_and_2_threads(d, &args, 20..=25);
    // Three threads: the 36 blocks do not share out evenly.
    let out = d.join("t3/f_####.exr").display().to_string();
    let three = ["--exr-float", "--threads", "3", "--out", &out];
    reframe_ok(&[&["render"][..], &args, &three].concat());
    let names = (20..=25).map(|f| format!("f_{f:04}.exr"));
    assert_identical(&d.join("t1"), &d.join("t3"), names);
}

/// `--strict` on the command line: a model that loading repairs (here a polyline beside the
/// faces) renders with one warning line, and is refused with `--strict`, one line, nothing
/// written.
#[test]
fn strict_flag_turns_repairs_into_refusals() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let corpus = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/corpus");
    for f in ["s.toml", "s.mtl"] {
        std::fs::copy(format!("{corpus}/base/{f}"), d.join(f)).unwrap();
    }
    std::fs::copy(
        format!("{corpus}/cases/obj-polyline/s.obj"),
        d.join("s.obj"),
    )
    .unwrap();
    let scene = d.join("s.toml").display().to_string();
    let out = d.join("o/f_####.exr").display().to_string();
    let args = [
        "render", &scene, "--frames", "0", "--spp", "1", "--out", &out,
    ];
    let o = reframe_ok(&args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("warning:") && err.contains("polyline"),
        "{err}"
    );
    std::fs::remove_dir_all(d.join("o")).unwrap();
    let o = common::reframe(&[&args[..], &["--strict"]].concat())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("strict loading"), "{err}");
    assert!(!d.join("o").exists() || common::files_under(&d.join("o")).is_empty());
}

/// The memory a render is refused for passing (`RenderOptions::memory_estimate`) covers what a
/// real render takes beyond the process at start: `mis-cv` with `--aov` at n_f = 9 (its
/// accumulators, 40 bytes per pixel per frame in flight, are most of it), `mis-cv` at a high
/// `--spp` on a small film (the workers' native samples of a tile are most of it), a film of
/// one pixel at 10^5 spp (one pixel's samples, not a full tile's: it was refused as needing
/// 75.9 GB at 3.5x10^5 spp), the independent tracer, and it with `--denoise`; and it does not
/// overstate it more than a few times.
#[test]
fn memory_estimate_covers_a_real_render() {
    use reframe::reuse::Method;
    let d = tempfile::tempdir().unwrap();
    // (method, window, --aov, frames, resolution, spp, --denoise)
    let cases = [
        (Method::MisCv, 9, true, "0-8", (640, 480), 1, false),
        (Method::MisCv, 3, false, "0-2", (64, 64), 256, false),
        (Method::MisExact, 3, false, "0-2", (1, 1), 100_000, false),
        (Method::Independent, 1, false, "0-1", (640, 480), 1, false),
        // The denoiser's images and scratch (a render that fitted without them aborted in
        // the denoiser when memory ran short).
        (Method::Independent, 1, false, "0", (1920, 1440), 1, true),
    ];
    for (k, (method, window, aov, frames, (w, h), spp, denoise)) in cases.into_iter().enumerate() {
        let stats = d.path().join(format!("s{k}.json"));
        let mut args: Vec<String> = vec![
            "render".into(),
            "vase".into(),
            "--method".into(),
            method.name().into(),
            "--window".into(),
            window.to_string(),
            "--frames".into(),
            frames.into(),
            "--res".into(),
            format!("{w}x{h}"),
            "--spp".into(),
            spp.to_string(),
            "--threads".into(),
            "2".into(),
            "--out".into(),
            d.path()
                .join(format!("r{k}/f_####.exr"))
                .display()
                .to_string(),
            "--stats".into(),
            stats.display().to_string(),
        ];
        if aov {
            args.push("--aov".into());
        }
        if denoise {
            args.extend(["--denoise".into(), "--max-depth".into(), "1".into()]);
        }
        reframe_ok(&args);
        let s: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
        let grew = s["peak_rss_bytes"].as_u64().unwrap() - s["startup_rss_bytes"].as_u64().unwrap();
        let opts = RenderOptions {
            method,
            window,
            aov,
            resolution: Some((w, h)),
            spp,
            threads: 2,
            denoise: denoise.then_some(reframe::driver::denoise::Layers::None),
            ..RenderOptions::default()
        };
        let estimate = opts.memory_estimate((w, h));
        assert!(
            estimate >= grew && estimate <= 4 * grew + (64 << 20),
            "{args:?}: estimated {estimate} bytes, the render grew by {grew}"
        );
    }
}

/// Under an address-space limit (`ulimit -v`, as batch systems set for a job's memory) a render
/// either runs or stops with one line that names the limit, at every limit: swept across the
/// band where the libraries, Embree's threads and the frames stop fitting. A failed Embree
/// build used to end in a C++ `terminate` (exit 134) when the scene was released.
#[test]
fn under_an_address_space_limit_a_render_runs_or_says_why() {
    let d = tempfile::tempdir().unwrap();
    let under = |mb: u32, args: &str| {
        let cmd = format!(
            "ulimit -v {}; exec '{}' {args}",
            mb * 1024,
            env!("CARGO_BIN_EXE_reframe")
        );
        std::process::Command::new("bash")
            .args(["-c", &cmd])
            .output()
            .unwrap()
    };
    // Below some limit the process cannot start: the dynamic loader cannot map the libraries,
    // or a library's static constructor (log4cplus, below OpenImageIO) cannot start its thread
    // and aborts before `main`. The sweep starts above the limit where it starts every time.
    let starts = (300..2000)
        .step_by(10)
        .find(|&mb| (0..3).all(|_| under(mb, "--version").status.success()))
        .expect("reframe --version runs under some limit");
    let (mut ran, mut refused) = (0, 0);
    for mb in (starts + 10..starts + 400).step_by(10) {
        let args = format!(
            "render cornell --res 16x12 --spp 1 --frames 0 --threads 2 --out '{}/l{mb}/f_####.exr'",
            d.path().display()
        );
        let o = under(mb, &args);
        let err = String::from_utf8_lossy(&o.stderr);
        match o.status.code() {
            Some(0) => ran += 1,
            // One line; where it fails to allocate or to start a thread, a line that names the
            // limit (what fails first moves with the libraries and the machine: Embree's device
            // or build, the worker pool, the memory check).
            Some(1) => {
                refused += 1;
                assert_eq!(err.trim().lines().count(), 1, "{mb} MB: {err}");
                assert!(err.starts_with("error: "), "{mb} MB: {err}");
                let fault = [
                    "Resource temporarily unavailable",
                    "OUT_OF_MEMORY",
                    "memory",
                ]
                .iter()
                .any(|f| err.contains(f));
                assert!(
                    !fault || err.contains("ulimit -v") || err.contains("lower --res"),
                    "{mb} MB: {err}"
                );
            }
            c => panic!("{mb} MB: exit {c:?}: {err}"),
        }
    }
    // The sweep crossed the band: some limits were too tight, some fitted.
    assert!(ran > 0 && refused > 0, "{ran} ran, {refused} refused");
    // A large OBJ (a 700 x 700 grid of quads and 1.5 million triangles, 45 MB): where reading
    // it or building its mesh does not fit, one line (the lists failed to grow: "memory
    // allocation failed", a backtrace, exit 134).
    let n = 700;
    let mut obj = String::from("mtllib s.mtl\n");
    for j in 0..=n {
        for i in 0..=n {
            let (x, z) = (
                -1.0 + 2.0 * i as f64 / n as f64,
                -1.0 + 2.0 * j as f64 / n as f64,
            );
            obj.push_str(&format!(
                "v {x:.5} {:.3} {z:.5}\n",
                0.001 * ((i * 7 + j * 13) % 5) as f64
            ));
        }
    }
    obj.push_str("v -0.2 1.9 -0.2\nv 0.2 1.9 -0.2\nv 0.2 1.9 0.2\nv -0.2 1.9 0.2\nusemtl floor\n");
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i + 1;
            obj.push_str(&format!("f {a} {} {} {}\n", a + 1, a + n + 2, a + n + 1));
        }
    }
    // And short faces, whose lists take more memory per byte of text than the quads'.
    for _ in 0..1_500_000 {
        obj.push_str(&format!("f 1 2 {}\n", n + 3));
    }
    let l = (n + 1) * (n + 1);
    obj.push_str(&format!(
        "usemtl light\nf {} {} {} {}\n",
        l + 1,
        l + 2,
        l + 3,
        l + 4
    ));
    let base = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus/base");
    std::fs::write(d.path().join("g.obj"), obj).unwrap();
    std::fs::copy(base.join("s.mtl"), d.path().join("s.mtl")).unwrap();
    let toml = std::fs::read_to_string(base.join("s.toml")).unwrap();
    std::fs::write(d.path().join("g.toml"), toml.replace("s.obj", "g.obj")).unwrap();
    let (mut ran, mut refused_reading) = (0, 0);
    for mb in (starts + 50..starts + 900).step_by(40) {
        let args = format!(
            "render '{0}/g.toml' --res 16x12 --spp 1 --frames 0 --threads 1 --out '{0}/g{mb}/f_####.exr'",
            d.path().display()
        );
        let o = under(mb, &args);
        let err = String::from_utf8_lossy(&o.stderr);
        match o.status.code() {
            Some(0) => ran += 1,
            Some(1) => {
                assert_eq!(err.trim().lines().count(), 1, "{mb} MB: {err}");
                refused_reading += err.contains("g.obj: line") as u32;
            }
            c => panic!("{mb} MB, the large OBJ: exit {c:?}: {err}"),
        }
    }
    assert!(
        ran > 0 && refused_reading > 0,
        "{ran} ran, {refused_reading} refused reading the OBJ"
    );
}

/// A frame whose bytes cannot all be written (a full disk, a quota; here a file size limit of
/// 4 KiB, as Slurm passes it on to jobs: reframe ignores SIGXFSZ, whose default action killed it
/// silently with exit 153, so that the write fails with EFBIG) is an error naming the frame,
/// and leaves no file behind: no frame, no temporary, no lock, no empty checkpoint folder. (The
/// formats OpenImageIO writes to disk itself, such as SGI and FITS, are read back before the
/// rename; their probe at start would fail first under this limit.)
/// OpenImageIO 2.4's PNG writer reported success on a truncated file (a 4096-byte PNG was
/// renamed into place, exit 0), and libjpeg ended the process on its own.
#[test]
fn a_frame_that_cannot_be_written_is_an_error_and_leaves_nothing() {
    let dir = tempfile::tempdir().unwrap();
    // `reframe render vase --res 256x192 --spp 1 ARGS --out OUT/f_####.EXT` under a 4 KiB file
    // size limit: its standard error, and what it left in OUT.
    let limited = |args: &str, out: &std::path::Path, ext: &str| {
        let cmd = format!(
            "ulimit -f 4; exec '{}' render vase --res 256x192 --spp 1 {args} --out \
             '{}/f_####.{ext}'",
            env!("CARGO_BIN_EXE_reframe"),
            out.display()
        );
        let o = std::process::Command::new("bash")
            .args(["-c", &cmd])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        assert_eq!(o.status.code(), Some(1), "{ext}: {err}");
        let left: Vec<_> = std::fs::read_dir(out)
            .map(|d| d.map(|e| e.unwrap().file_name()).collect())
            .unwrap_or_default();
        (err, left)
    };
    for ext in ["png", "jpg", "exr", "tif"] {
        let out = dir.path().join(ext);
        let (err, left) = limited("--frames 0-0", &out, ext);
        // Encoded in memory, the write is reframe's and says the system's reason; TIFF is
        // written by libtiff, which says its own.
        let why = if ext == "tif" {
            "Write error"
        } else {
            "File too large"
        };
        assert!(
            err.contains(&format!("cannot write {}/f_0000.{ext}", out.display()))
                && err.contains(why),
            "{ext}: {err}"
        );
        assert!(left.is_empty(), "{ext}: left {left:?}");
        // Nor the folder it made for them, empty.
        assert!(!out.exists(), "{ext}: left its empty folder");
    }
    // A chunk's frames go to its log as they finish: a log that no checkpoint counts is of no
    // use to a later run, and goes too (a 4 KiB NAME.chunk-1-of-1.partial.log was left).
    let (err, left) = limited("--frames 0-1 --chunk 1/1", &dir.path().join("chunk"), "exr");
    assert!(err.contains("File too large"), "{err}");
    assert!(left.is_empty(), "chunk: left {left:?}");
    assert!(
        !dir.path().join("chunk").exists(),
        "chunk: left its empty folder"
    );
}

/// A render whose standard output and error are closed by their reader (piped into `head -1`,
/// a log shipper that exited) finishes its work and exits 0: printing its lines panicked
/// ("failed printing to stdout: Broken pipe", exit 101) once the frames were written.
#[test]
fn a_closed_output_pipe_does_not_stop_a_render() {
    let dir = tempfile::tempdir().unwrap();
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_reframe"))
        .args([
            "render", "vase", "--res", "32x24", "--spp", "2", "--frames", "0-3",
        ])
        .arg("--out")
        .arg(dir.path().join("f_####.png"))
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // The reading ends, closed before the first line.
    drop(child.stdout.take());
    drop(child.stderr.take());
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(0));
    for f in 0..4 {
        assert!(
            dir.path().join(format!("f_{f:04}.png")).is_file(),
            "frame {f}"
        );
    }
}

/// Standard output that cannot be written for another reason than a closed pipe (a full disk
/// under `> file`; here /dev/full) is an error at the end, exit 1: what was printed is lost
/// (the closed-pipe rule had made every failure silent, exit 0 with an empty file).
#[test]
fn a_full_standard_output_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("f_####.png").display().to_string();
    let render = [
        "render", "vase", "--res", "16x12", "--spp", "1", "--frames", "0-0",
    ];
    // A render, and `--help` and `--version` (they exited 0, having written nothing).
    let runs = [
        [&render[..], &["--out", &out]].concat(),
        vec!["--help"],
        vec!["--version"],
        vec!["render", "--help"],
    ];
    for args in &runs {
        let full = std::fs::OpenOptions::new()
            .write(true)
            .open("/dev/full")
            .unwrap();
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_reframe"))
            .args(args)
            .stdout(full)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(
            err.lines()
                .last()
                .is_some_and(|l| l.starts_with("error: writing standard output: No space left")),
            "{args:?}: {err}"
        );
    }
}

/// A scene that spans far more than its details, so that it is not moved to the origin (a room
/// 3x10^5 units out and a marker at the origin), is warned of: its rays leave surfaces 2.3
/// units off them and its light reaches nothing (the room rendered black, without a word).
#[test]
fn a_scene_spread_far_beyond_its_details_is_warned_of() {
    let device = Device::new().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    contact_scene(&device, d, 1.0, [3e5, 0.0, 0.0], Shift::Placed);
    let load = || Scene::load(d.join("s.toml").to_str().unwrap(), &device).unwrap();
    let spread = |s: &Scene| s.warnings.iter().any(|w| w.contains("rays leave surfaces"));
    assert!(
        !spread(&load()),
        "moved to the origin, the room alone is fine"
    );
    let mut toml = std::fs::read_to_string(d.join("s.toml")).unwrap();
    toml += "[[object]]\nobj = \"s.obj\"\nscale = 0.01\n";
    std::fs::write(d.join("s.toml"), toml).unwrap();
    let s = load();
    assert_eq!(s.origin, glam::DVec3::ZERO);
    assert!(spread(&s), "{:?}", s.warnings);
}

/// Values past half float's largest (65504) in a default, half-float EXR are clamped with a
/// warning naming the first frame and a count of all of them at the end (a floor under a light
/// of 1e7 came out at 65504 without a word);
/// `--exr-float` keeps them, and says nothing.
#[test]
fn a_half_float_clamp_is_warned_of() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let base = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus/base");
    for f in ["s.obj", "s.toml"] {
        std::fs::copy(base.join(f), d.join(f)).unwrap();
    }
    std::fs::write(
        d.join("s.mtl"),
        "newmtl floor\nKd 0.5 0.5 0.5\nnewmtl light\nKd 0 0 0\nKe 1e7 1e7 1e7\n",
    )
    .unwrap();
    for (extra, warned) in [(None, true), (Some("--exr-float"), false)] {
        let mut args = vec!["render".to_string(), d.join("s.toml").display().to_string()];
        args.extend(["--spp", "1", "--frames", "0-1", "--out"].map(String::from));
        args.push(d.join("o/f_####.exr").display().to_string());
        args.extend(extra.map(String::from));
        let o = common::reframe_ok(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        let said = err.contains("values beyond ±65504, half float's largest, are clamped to it");
        assert_eq!(said, warned, "{extra:?}: {err}");
        // The first frame is named, and the summary counts both (it named the first only).
        let counted = err.contains("warning: 2 frames had values beyond ±65504 clamped");
        assert_eq!(counted, warned, "{extra:?}: {err}");
    }
}

/// The reuse methods weigh by film densities up to `1/cos^3` of the widest angle off the
/// camera's axis: at a field of view near 180 degrees (or a moderate one on a film of extreme
/// aspect) those overflowed single precision and `mis-exact` wrote pixels of -8.8e12 with exit
/// 0. A film wider than `MAX_REUSE_FILM_EXTENT` is refused by `render`, `compare` and `bench`
/// before anything is traced, the independent tracer renders it, and just inside the limit, on
/// a 200:1 film, the reuse methods' frames are finite and agree with the independent tracer's.
#[test]
fn reuse_methods_refuse_a_film_too_wide_for_their_densities_and_agree_inside_it() {
    use reframe::driver::options::MAX_REUSE_FILM_EXTENT;
    use reframe::reuse::Method;
    let d = tempfile::tempdir().unwrap();
    let scenes = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    for f in ["cornell.obj", "cornell.mtl"] {
        std::fs::copy(scenes.join(f), d.path().join(f)).unwrap();
    }
    let write = |name: &str, fov: f64, (w, h): (u32, u32), (z0, z2): (f32, f32)| {
        let key = |frame: u32, z: f32| {
            format!(
                "[[keyframe]]\nframe = {frame}\nposition = [0.0, 1.0, {z}]\n\
                 look_at = [0.0, 1.0, 0.0]\nup = [0.0, 1.0, 0.0]\nfov = {fov}\n"
            )
        };
        let p = d.path().join(name);
        std::fs::write(
            &p,
            format!(
                "obj = \"cornell.obj\"\nframes = 3\nresolution = [{w}, {h}]\n{}{}",
                key(0, z0),
                key(2, z2)
            ),
        )
        .unwrap();
        p.display().to_string()
    };
    let wide = write("wide.toml", 179.99998, (32, 24), (3.9, 0.9));
    let out = d.path().join("o/f_####.exr").display().to_string();
    for args in [
        vec![
            "render",
            &wide,
            "--method",
            "mis-exact",
            "--window",
            "3",
            "--out",
            &out,
        ],
        vec!["compare", &wide, "--out", &out],
        vec!["bench", &wide, "--windows", "3"],
    ] {
        let o = common::reframe(&args).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(
            err.contains("frame 0's field of view (179.99998 degrees vertical at 32x24)"),
            "{args:?}: {err}"
        );
    }
    assert!(!d.path().join("o").exists());
    common::reframe_ok(&[
        "render", &wide, "--frames", "0", "--spp", "1", "--out", &out,
    ]);

    // 200:1, the film's corner 0.99 of the limit from its centre, inside the box.
    let (w, h) = (400, 2);
    let aspect = (w / h) as f64;
    let tan = 0.99 * MAX_REUSE_FILM_EXTENT as f64 / (1.0 + aspect * aspect).sqrt();
    let fov = 2.0 * tan.atan().to_degrees();
    let device = Device::new().unwrap();
    let scene = Scene::load(&write("strip.toml", fov, (w, h), (0.8, 0.2)), &device).unwrap();
    let integ = Integrator::new(&scene, 8);
    let mean = |method: Method, window: u32| {
        let opts = RenderOptions {
            method,
            window,
            spp: 64,
            frames: Some(0..=2),
            resolution: Some((w, h)),
            threads: 2,
            ..RenderOptions::default()
        };
        let (frames, _) = common::render_in_memory(&integ, &opts);
        let f = &frames[&1];
        f.data.iter().sum::<f32>() as f64 / f.data.len() as f64
    };
    let reference = mean(Method::Independent, 1);
    for method in [Method::MisExact, Method::MisCv] {
        let m = mean(method, 3);
        assert!(
            (m / reference - 1.0).abs() < 0.05,
            "{method:?}: mean {m}, independent {reference}"
        );
    }
}

/// A frame whose values are mostly below half float's normal range (a scene lit at 1e-8), written
/// as a half EXR (the default), says that they keep fewer digits there and that `--exr-float`
/// keeps them: a scene lit at 1e-5 lost a tenth of half its pixels, and its darkest became 0,
/// without a word. The shipped scenes say nothing, and neither does `--exr-float`.
#[test]
fn a_dim_frame_in_half_floats_is_said_to_lose_digits() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for ext in ["obj", "mtl", "toml"] {
        let text = std::fs::read_to_string(format!(
            "{}/scenes/cornell.{ext}",
            env!("CARGO_MANIFEST_DIR")
        ))
        .unwrap();
        std::fs::write(
            d.join(format!("cornell.{ext}")),
            text.replace("Ke 16 16 16", "Ke 1.6e-7 1.6e-7 1.6e-7"),
        )
        .unwrap();
    }
    let scene = d.join("cornell.toml").to_str().unwrap().to_string();
    let render = |scene: &str, more: &[&str]| {
        let o = common::reframe(&[
            "render", scene, "--spp", "1", "--res", "32x24", "--frames", "0",
        ])
        .args(more)
        .arg("--out")
        .arg(d.join("f_####.exr"))
        .output()
        .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stderr).contains("half floats keep fewer digits")
    };
    assert!(render(&scene, &[]));
    assert!(!render(&scene, &["--exr-float"]));
    assert!(!render("cornell", &[]));
}

/// A format whose writer takes tiles only (Maya IFF) writes frames: the start's probe wrote
/// its test frame by scanlines and read it back by a scanline, both of which that writer and
/// reader refuse, so `--out f_####.iff` was refused ("the writer gives no reason"). The frame
/// holds what the PNG of the same render holds.
#[test]
fn a_tiled_only_format_writes_frames() {
    let d = tempfile::tempdir().unwrap();
    let d = d.path();
    let run = |ext: &str| {
        let out = d.join(format!("f_####.{ext}")).display().to_string();
        reframe_ok(&[
            "render",
            "cornell",
            "--res",
            "24x16",
            "--spp",
            "2",
            "--frames",
            "0",
            "--threads",
            "1",
            "--out",
            &out,
        ]);
        reframe::image::read_image(&d.join(format!("f_0000.{ext}"))).unwrap()
    };
    let (iff, png) = (run("iff"), run("png"));
    assert_eq!((iff.width, iff.height), (24, 16));
    assert!(iff.data.iter().any(|&v| v > 0.0), "black frame");
    assert_eq!(iff.data, png.data);
}

/// `--version` names the build by the hash that resumes and merges compare (a merge by another
/// build is refused, quoting both), so that the nodes of a cluster can be checked to run one.
#[test]
fn version_names_the_build() {
    let version = || {
        let o = common::reframe(&["--version"]).output().unwrap();
        assert!(o.status.success());
        String::from_utf8(o.stdout).unwrap()
    };
    let v = version();
    let build = v
        .strip_prefix(&format!("reframe {} (build ", env!("CARGO_PKG_VERSION")))
        .and_then(|r| r.strip_suffix(")\n"))
        .unwrap_or_else(|| panic!("{v:?}"));
    assert!(
        build.len() == 16 && build.chars().all(|c| c.is_ascii_hexdigit()),
        "{v:?}"
    );
    assert_eq!(version(), v);
}
