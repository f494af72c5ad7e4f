//! Cameras from a file and Catmull-Rom keyframes, through `Scene::load` and the renderer:
//!
//! - a JSON and a CSV camera file that give `vase`'s cameras per frame (position, look-at, up,
//!   written from its keyframe path) render frames bitwise identical to `vase`'s, with the
//!   independent tracer and with `mis-cv` reuse;
//! - the same cameras as camera-to-world matrices (scaled: only rotation and translation count)
//!   give every frame's camera within float rounding of the keyframe path's;
//! - `interpolation = "catmull-rom"` passes through every keyframe of `vase-long` exactly and
//!   leaves the straight lines between them;
//! - Blender's camera exporter (`scripts/blender/export_camera.py`, run on a stand-in for
//!   Blender) turns the camera into the Y-up axes of Blender's OBJ exporter, or keeps Blender's
//!   with `--axes z-up`, and prints the `[environment]` lines that show a world's sky as Cycles
//!   maps it;
//! - the scene TOML's misuses (both `camera` and `[[keyframe]]`, neither, `interpolation` with a
//!   camera file, another extension, a missing file, a FIFO) are refused with one line naming
//!   the file and line. Malformed camera files themselves are the unit tests' (in
//!   `src/scene/camera_file.rs`) and the corpus' (`tests/corpus/cases/camera-file-*`).
mod common;

use common::render_in_memory;
use reframe::camera::{Camera, Cameras, Keyframe};
use reframe::driver::RenderOptions;
use reframe::embree::Device;
use reframe::integrator::Integrator;
use reframe::reuse::Method;
use reframe::scene::Scene;
use std::path::Path;
use std::time::{Duration, Instant};

fn scenes() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/scenes"))
}

/// `vase`'s keyframe of every frame.
fn vase_keys(vase: &Scene) -> Vec<Keyframe> {
    let Cameras::Path(path) = &vase.cameras else {
        panic!("vase has keyframes")
    };
    (0..vase.frames).map(|f| path.at(f)).collect()
}

/// A scene in `dir` that is `vase` with `camera` (a camera file's name) for its keyframes and
/// `text` as that file; the TOML's path.
fn vase_with_camera_file(dir: &Path, camera: &str, text: &str) -> String {
    for f in ["vase.obj", "vase.mtl"] {
        std::fs::copy(scenes().join(f), dir.join(f)).unwrap();
    }
    std::fs::write(dir.join(camera), text).unwrap();
    let toml = dir.join("shot.toml");
    std::fs::write(
        &toml,
        format!(
            "obj = \"vase.obj\"\nframes = 48\nresolution = [320, 240]\ncamera = \"{camera}\"\n"
        ),
    )
    .unwrap();
    toml.display().to_string()
}

/// A JSON camera file of `keys` (position, look-at, up), each up scaled by `up_scale`.
fn camera_json(keys: &[Keyframe], up_scale: f32) -> String {
    let entries: Vec<String> = keys
        .iter()
        .map(|k| {
            format!(
                "  {{\"frame\": {}, \"fov\": {}, \"position\": {}, \"look_at\": {}, \"up\": {}}}",
                k.frame,
                k.fov,
                v3(k.position),
                v3(k.look_at),
                v3(k.up * up_scale)
            )
        })
        .collect();
    format!("{{\"frames\": [\n{}\n]}}\n", entries.join(",\n"))
}

fn v3(v: glam::Vec3) -> String {
    format!("[{}, {}, {}]", v.x, v.y, v.z)
}

/// Camera-to-world of `c`, row-major, each axis scaled by `scale`: Blender's convention (the
/// camera looks down -Z, +Y up).
fn matrix(c: &Camera, scale: f32) -> [f32; 16] {
    let (r, u, b, e) = (c.right * scale, c.up * scale, -c.forward * scale, c.eye);
    [
        r.x, u.x, b.x, e.x, r.y, u.y, b.y, e.y, r.z, u.z, b.z, e.z, 0.0, 0.0, 0.0, 1.0,
    ]
}

fn render(scene: &Scene, method: Method) -> Vec<(u32, Vec<u32>)> {
    let integ = Integrator::new(scene, 8);
    let opts = RenderOptions {
        method,
        window: if method == Method::Independent { 1 } else { 3 },
        spp: 2,
        seed: 5,
        frames: Some(20..=22),
        resolution: Some((32, 24)),
        threads: 2,
        progress: false,
        ..RenderOptions::default()
    };
    render_in_memory(&integ, &opts)
        .0
        .into_iter()
        .map(|(f, d)| (f, d.data.iter().map(|v| v.to_bits()).collect()))
        .collect()
}

#[test]
fn camera_files_of_vase_render_vase_bitwise() {
    let device = Device::new().unwrap();
    let vase = Scene::load("vase", &device).unwrap();
    let keys = vase_keys(&vase);
    let json = camera_json(&keys, 1.0);
    let mut csv = "frame,fov,px,py,pz,lx,ly,lz,ux,uy,uz\n".to_string();
    for k in &keys {
        let (p, l, u) = (k.position, k.look_at, k.up);
        csv += &format!(
            "{},{},{},{},{},{},{},{},{},{},{}\n",
            k.frame, k.fov, p.x, p.y, p.z, l.x, l.y, l.z, u.x, u.y, u.z
        );
    }
    let want_indep = render(&vase, Method::Independent);
    let want_reuse = render(&vase, Method::MisCv);
    assert_eq!(want_indep.len(), 3);
    assert!(want_indep.iter().all(|(_, d)| d.iter().any(|&v| v != 0)));
    for (name, text) in [("shot.json", &json), ("shot.csv", &csv)] {
        let dir = tempfile::tempdir().unwrap();
        let toml = vase_with_camera_file(dir.path(), name, text);
        let s = Scene::load(&toml, &device).unwrap_or_else(|e| panic!("{name}: {e:#}"));
        assert!(s.warnings.is_empty(), "{:?}", s.warnings);
        assert!(matches!(s.cameras, Cameras::PerFrame(ref v) if v.len() == 48));
        // The camera file is an input: no command writes over it.
        assert!(s.inputs.contains(&dir.path().join(name)), "{:?}", s.inputs);
        for f in 0..vase.frames {
            let (a, b) = (s.camera(f, 32, 24), vase.camera(f, 32, 24));
            let bits = |c: &Camera| {
                [c.eye, c.forward, c.right, c.up]
                    .map(|v| v.to_array().map(f32::to_bits))
                    .concat()
            };
            assert_eq!(bits(&a), bits(&b), "{name}: frame {f}");
            assert_eq!(a.tan_half_fov.to_bits(), b.tan_half_fov.to_bits());
        }
        assert!(
            render(&s, Method::Independent) == want_indep,
            "{name}: independent"
        );
        assert!(render(&s, Method::MisCv) == want_reuse, "{name}: mis-cv");
    }
}

#[test]
fn matrix_camera_files_give_the_keyframe_cameras() {
    let device = Device::new().unwrap();
    let vase = Scene::load("vase", &device).unwrap();
    let (w, h) = (320, 240);
    let cams: Vec<Camera> = (0..vase.frames).map(|f| vase.camera(f, w, h)).collect();
    let fov = |f: u32| vase_keys(&vase)[f as usize].fov;
    let num = |m: [f32; 16]| m.map(|v| v.to_string()).join(", ");
    // A scale of 2.5 on the axes: it must drop out.
    let entries: Vec<String> = cams
        .iter()
        .enumerate()
        .map(|(f, c)| {
            format!(
                "{{\"frame\": {f}, \"fov\": {}, \"matrix\": [{}]}}",
                fov(f as u32),
                num(matrix(c, 2.5))
            )
        })
        .collect();
    let json = format!("{{\"frames\": [\n{}\n]}}\n", entries.join(",\n"));
    let mut csv = "frame,fov".to_string();
    for i in 0..16 {
        csv += &format!(",m{}{}", i / 4, i % 4);
    }
    csv += "\n";
    for (f, c) in cams.iter().enumerate() {
        csv += &format!(
            "{f},{},{}\n",
            fov(f as u32),
            num(matrix(c, 1.0)).replace(' ', "")
        );
    }
    for (name, text) in [("shot.json", &json), ("shot.csv", &csv)] {
        let dir = tempfile::tempdir().unwrap();
        let toml = vase_with_camera_file(dir.path(), name, text);
        let s = Scene::load(&toml, &device).unwrap_or_else(|e| panic!("{name}: {e:#}"));
        let mut worst = 0.0f32;
        for (f, want) in cams.iter().enumerate() {
            let got = s.camera(f as u32, w, h);
            assert_eq!(got.eye, want.eye, "{name}: frame {f}");
            assert_eq!(got.tan_half_fov, want.tan_half_fov, "{name}: frame {f}");
            for (a, b) in [
                (got.forward, want.forward),
                (got.right, want.right),
                (got.up, want.up),
            ] {
                worst = worst.max((a - b).abs().max_element());
            }
        }
        // Rounding only: a few units in the last place of unit vectors.
        assert!(worst < 1e-6, "{name}: axes differ by {worst:e}");
        eprintln!("{name}: axes within {worst:e} of the keyframe path's");
    }
}

#[test]
fn catmull_rom_keyframes_pass_through_every_keyframe() {
    let device = Device::new().unwrap();
    let dir = tempfile::tempdir().unwrap();
    for f in ["vase.obj", "vase.mtl"] {
        std::fs::copy(scenes().join(f), dir.path().join(f)).unwrap();
    }
    // vase-long: four keyframes whose speed changes at the middle two.
    let long = std::fs::read_to_string(scenes().join("vase-long.toml")).unwrap();
    let toml = dir.path().join("spline.toml");
    let text = long.replace(
        "resolution = [320, 240]",
        "resolution = [320, 240]\ninterpolation = \"catmull-rom\"",
    );
    assert_ne!(text, long);
    std::fs::write(&toml, text).unwrap();
    let spline = Scene::load(toml.to_str().unwrap(), &device).unwrap();
    let linear = Scene::load("vase-long", &device).unwrap();
    let mut apart = 0.0f32;
    for f in 0..linear.frames {
        let (a, b) = (spline.cameras.pose(f), linear.cameras.pose(f));
        if [0, 36, 83, 119].contains(&f) {
            assert_eq!(a, b, "frame {f} is a keyframe");
        } else {
            apart = apart.max((a.eye - b.eye).length());
        }
    }
    // Around the keyframes at 36 and 83 the path rounds the corners: centimetres off the lines.
    assert!(apart > 0.01, "{apart}");
}

/// The one-line error of loading `toml` (text) with a camera file `shot.json` beside it.
/// A stand-in for Blender's Python module, enough for `scripts/blender/export_camera.py`: one
/// frame, a camera at `matrix_world` (rows) with a 50 mm lens on a 36 mm sensor, 320 x 240.
const FAKE_BPY: &str = r#"
import sys
M = [[float(x) for x in r.split()] for r in sys.argv.pop().split(";")]
class Obj: pass
data = Obj(); data.type = "PERSP"; data.shift_x = data.shift_y = 0.0
data.sensor_fit = "AUTO"; data.sensor_width = 36.0; data.sensor_height = 24.0; data.lens = 50.0
cam = Obj(); cam.data = data; cam.matrix_world = M; cam.name = "Camera"
cam.evaluated_get = lambda depsgraph: cam
render = Obj(); render.resolution_x = 320; render.resolution_y = 240
render.pixel_aspect_x = render.pixel_aspect_y = 1.0; render.resolution_percentage = 100
scene = Obj(); scene.name = "Scene"; scene.camera = cam; scene.render = render
scene.frame_start = scene.frame_end = scene.frame_step = 1; scene.frame_set = lambda f: None
context = Obj(); context.scene = scene; context.evaluated_depsgraph_get = lambda: None
path = Obj(); path.abspath = lambda p: p
# A world lit by an Environment Texture, where FAKE_WORLD says so: "" (its default mapping) or
# "ROTATION_DEGREES VECTOR_TYPE" (a Mapping node turning it about Z).
import os, math
if os.environ.get("FAKE_WORLD") is not None:
    env = Obj(); env.type = "TEX_ENVIRONMENT"; env.projection = "EQUIRECTANGULAR"
    env.image = Obj(); env.image.filepath = "//textures/labels.exr"
    vec = Obj(); vec.links = []; env.inputs = {"Vector": vec}
    spec = os.environ["FAKE_WORLD"].split()
    if spec:
        m = Obj(); m.type = "MAPPING"; m.vector_type = spec[1]
        rot = Obj(); rot.default_value = (0.0, 0.0, math.radians(float(spec[0])))
        m.inputs = {"Rotation": rot}
        link = Obj(); link.from_node = m; vec.links = [link]
    bg = Obj(); bg.type = "BACKGROUND"; st = Obj(); st.default_value = 2.0; bg.inputs = {"Strength": st}
    tree = Obj(); tree.nodes = [bg, env]
    world = Obj(); world.use_nodes = True; world.node_tree = tree
    scene.world = world
"#;

/// Blender's camera exporter, run on a stand-in for Blender, lines its camera up with the axes
/// of Blender's OBJ exporter: a camera in front of the origin in Blender (at -5 on Blender's
/// Y, looking along +Y with +Z up, Blender's front view) becomes, by default, reframe's camera at
/// +5 on Z looking down -Z with +Y up, where an OBJ exported with Blender's defaults (Up Y,
/// Forward -Z) puts the scene; `--axes z-up` keeps Blender's axes.
#[test]
fn blender_cameras_line_up_with_blenders_obj_export() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::create_dir(d.join("bpy")).unwrap();
    std::fs::write(d.join("bpy/__init__.py"), FAKE_BPY).unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/blender/export_camera.py");
    // Rotated 90 degrees about X: Blender's camera looks down its -Z, here along world +Y.
    let blender = "1 0 0 0;0 0 -1 -5;0 1 0 0;0 0 0 1";
    let device = Device::new().unwrap();
    for (axes, eye, view, up) in [
        (None, [0.0, 0.0, 5.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]),
        (
            Some("y-up"),
            [0.0, 0.0, 5.0],
            [0.0, 0.0, -1.0],
            [0.0, 1.0, 0.0],
        ),
        (
            Some("z-up"),
            [0.0, -5.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
        ),
    ] {
        let json = d.join("shot.json");
        let mut cmd = std::process::Command::new("python3");
        cmd.arg(&script).arg("--").arg(&json);
        if let Some(a) = axes {
            cmd.args(["--axes", a]);
        }
        // The stand-in takes the matrix from the last argument (and removes it).
        let o = cmd
            .arg(blender)
            .env("PYTHONPATH", d)
            .output()
            .expect("run python3");
        assert!(
            o.status.success(),
            "{axes:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        // `vase`'s geometry with the camera file, for its one frame.
        let toml = vase_with_camera_file(d, "shot.json", &std::fs::read_to_string(&json).unwrap());
        std::fs::write(
            &toml,
            "obj = \"vase.obj\"\nframes = 1\nresolution = [320, 240]\ncamera = \"shot.json\"\n",
        )
        .unwrap();
        let scene = Scene::load(&toml, &device).unwrap();
        let pose = scene.cameras.pose(0);
        let close = |a: glam::Vec3, b: [f32; 3]| (a - glam::Vec3::from(b)).length() < 1e-5;
        assert!(close(pose.eye, eye), "{axes:?}: eye {}", pose.eye);
        assert!(
            close(pose.view.normalize(), view),
            "{axes:?}: view {}",
            pose.view
        );
        let up_perp =
            (pose.up - pose.view.normalize() * pose.up.dot(pose.view.normalize())).normalize();
        assert!(close(up_perp, up), "{axes:?}: up {}", pose.up);
        // 36 mm across 320 pixels at 50 mm: a vertical fov of 2 atan(13.5 / 50).
        let fov = 2.0 * (13.5f32 / 50.0).atan().to_degrees();
        assert!((pose.fov - fov).abs() < 1e-3, "fov {}", pose.fov);
    }
    let o = std::process::Command::new("python3")
        .arg(&script)
        .args(["--", "x.json", "--axes", "x-up", blender])
        .env("PYTHONPATH", d)
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--axes takes y-up or z-up"));
}

fn refusal(toml: &str, device: &Device) -> (String, String) {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for f in ["s.obj", "s.mtl"] {
        let base = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus/base");
        std::fs::copy(base.join(f), d.join(f)).unwrap();
    }
    let entry = "{\"frame\": 0, \"fov\": 45, \"position\": [0, 1, 3], \"look_at\": [0, 0, 0], \
                 \"up\": [0, 1, 0]}";
    std::fs::write(d.join("shot.json"), format!("{{\"frames\": [{entry}]}}")).unwrap();
    let fifo = d.join("fifo.json");
    let ok = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap();
    assert!(ok.success());
    let path = d.join("s.toml");
    std::fs::write(&path, toml).unwrap();
    let start = Instant::now();
    let e = match Scene::load(path.to_str().unwrap(), device) {
        Ok(_) => panic!("loaded:\n{toml}"),
        Err(e) => format!("{e:#}"),
    };
    assert!(start.elapsed() < Duration::from_secs(1), "{e}");
    assert!(!e.contains('\n'), "more than one line: {e}");
    (e, d.display().to_string())
}

#[test]
fn camera_key_misuse_is_refused_with_one_line() {
    let device = Device::new().unwrap();
    let head = "obj = \"s.obj\"\nframes = 1\nresolution = [16, 12]\n";
    let key = "[[keyframe]]\nframe = 0\nposition = [0.0, 1.0, 3.0]\nlook_at = [0.0, 0.0, 0.0]\n\
               up = [0.0, 1.0, 0.0]\nfov = 45.0\n";
    for (toml, want) in [
        (
            format!("{head}camera = \"shot.json\"\n{key}"),
            "{dir}/s.toml: line 4: camera = 'shot.json' and [[keyframe]] tables: give one or the other",
        ),
        (
            head.to_string(),
            "{dir}/s.toml: no camera: give [[keyframe]] tables or camera = \"file.json\" (or .csv)",
        ),
        (
            format!("{head}camera = \"shot.json\"\ninterpolation = \"linear\"\n"),
            "{dir}/s.toml: line 5: interpolation with a camera file",
        ),
        (
            format!("{head}interpolation = \"cubic\"\n{key}"),
            "{dir}/s.toml: line 4 ('interpolation = \"cubic\"'): unknown interpolation \"cubic\", \
             expected \"linear\" or \"catmull-rom\"",
        ),
        (
            format!("{head}camera = \"shot.txt\"\n"),
            "{dir}/s.toml: line 4: camera 'shot.txt': a camera file's name ends in .json or .csv",
        ),
        (
            format!("{head}camera = \"gone.json\"\n"),
            "{dir}/s.toml: line 4: camera 'gone.json': camera file '{dir}/gone.json': no such file",
        ),
        (
            format!("{head}camera = \"fifo.json\"\n"),
            "{dir}/s.toml: line 4: camera 'fifo.json': camera file '{dir}/fifo.json': is a named \
             pipe (FIFO), not a regular file",
        ),
        (
            format!("{head}camera = \"shot.json\"\n").replace("frames = 1", "frames = 2"),
            "{dir}/shot.json: frame 1 is missing: the scene has 2 frames, the file gives 1",
        ),
    ] {
        let (e, dir) = refusal(&toml, &device);
        let want = want.replace("{dir}", &dir);
        assert!(e.starts_with(&want), "\n  want {want}\n  got  {e}");
    }
}

/// The exporter's `[environment]` lines turn the sky as Blender shows it. Cycles maps a
/// direction `d` of Blender's world to the image's `u = (atan2(d.y, d.x) - pi) / (-2 pi)`, after
/// a world Mapping node turns `d` (by `phi` about Z for its Point type, by `-phi` for Texture);
/// that formula, written here, names the label of a lat-long image (yellow at u = 0, green at
/// 0.25, red at 0.5, blue at 0.75) that Blender shows along each of its four horizontal axes,
/// and reframe, looking along those axes through the OBJ exporter's (x, z, -y), must show it.
/// With `rotation = 0` (before the exporter printed it) the sky came out turned by 90 degrees.
#[test]
fn blender_worlds_sky_comes_out_turned_as_blender_shows_it() {
    use reframe::driver::render_frame_independent;
    use reframe::image::{write_image, Image, Metadata, WriteOptions};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::create_dir(d.join("bpy")).unwrap();
    std::fs::write(d.join("bpy/__init__.py"), FAKE_BPY).unwrap();
    let labels = [
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0],
    ];
    let (w, h) = (64u32, 32u32);
    let mut img = Image::new(w, h, &["R", "G", "B"]);
    for y in 0..h {
        for x in 0..w {
            // Each label spans the eighth of the width either side of its u.
            let u = (x as f32 + 0.5) / w as f32;
            let k = ((u * 4.0).round() as usize) % 4;
            let i = 3 * (y * w + x) as usize;
            img.data[i..i + 3].copy_from_slice(&labels[k]);
        }
    }
    write_image(
        &d.join("labels.exr"),
        &img,
        &Metadata::default(),
        &WriteOptions { exr_float: true },
    )
    .unwrap();
    std::fs::write(
        d.join("t.obj"),
        "v 100 100 100\nv 100.1 100 100\nv 100 100.1 100\nf 1 2 3\n",
    )
    .unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/blender/export_camera.py");
    let device = Device::new().unwrap();
    for (world, phi) in [
        ("", 0.0f64),
        ("90 POINT", 90.0),
        ("90 TEXTURE", -90.0),
        ("180 VECTOR", 180.0),
    ] {
        let o = std::process::Command::new("python3")
            .arg(&script)
            .args(["--", d.join("shot.json").to_str().unwrap()])
            .arg("1 0 0 0;0 0 -1 -5;0 1 0 0;0 0 0 1")
            .env("PYTHONPATH", d)
            .env("FAKE_WORLD", world)
            .output()
            .unwrap();
        let out = String::from_utf8_lossy(&o.stdout);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let env = &out[out.find("[environment]").expect("no [environment] printed")..];
        assert!(
            env.contains("image = \"labels.exr\"") && env.contains("intensity = 2"),
            "{env}"
        );
        let env = env.replace("intensity = 2", "intensity = 1");
        for (bx, by) in [(1.0f64, 0.0f64), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0)] {
            let (s, c) = phi.to_radians().sin_cos();
            let (dx, dy) = (c * bx - s * by, s * bx + c * by);
            let u = ((dy.atan2(dx) - std::f64::consts::PI) / (-2.0 * std::f64::consts::PI))
                .rem_euclid(1.0);
            let want = labels[((u * 4.0).round() as usize) % 4];
            // Blender's (x, y, z) is the OBJ's (x, z, -y).
            let toml = format!(
                "obj = \"t.obj\"\nframes = 1\nresolution = [8, 8]\n{env}\n[[keyframe]]\nframe = 0\n\
                 position = [0.0, 0.0, 0.0]\nlook_at = [{bx:?}, 0.0, {:?}]\nup = [0.0, 1.0, 0.0]\nfov = 10.0\n",
                -by
            );
            std::fs::write(d.join("s.toml"), toml).unwrap();
            let scene = Scene::load(d.join("s.toml").to_str().unwrap(), &device).unwrap();
            let integ = Integrator::new(&scene, 1);
            let px =
                render_frame_independent(&integ, &scene.camera(0, 8, 8), 0, 1, 1, false, &|_| {})
                    .pixels;
            let mean = px.iter().sum::<glam::Vec3>() / px.len() as f32;
            assert!(
                (mean - glam::Vec3::from(want)).abs().max_element() < 1e-3,
                "world '{world}', Blender's ({bx}, {by}, 0): reframe shows {mean}, Blender {want:?}"
            );
        }
    }
}

/// A camera's up of any length but zero is a direction: `vase`'s cameras with their up scaled
/// by 1e-19 (the cross product with the view then has a squared length below the smallest
/// normal float) render what they render with a unit up. They rendered black frames, exit 0,
/// the camera's axes NaN.
#[test]
fn a_tiny_up_renders_as_a_unit_up() {
    // As the binary's threads do, where the product underflowed.
    reframe::embree::set_flush_denormals();
    let device = Device::new().unwrap();
    let vase = Scene::load("vase", &device).unwrap();
    let json = camera_json(&vase_keys(&vase), 1e-19);
    let dir = tempfile::tempdir().unwrap();
    let toml = vase_with_camera_file(dir.path(), "shot.json", &json);
    let tiny = Scene::load(&toml, &device).unwrap();
    let (want, got) = (
        render(&vase, Method::Independent),
        render(&tiny, Method::Independent),
    );
    for ((f, a), (_, b)) in want.iter().zip(&got) {
        let (a, b): (Vec<f32>, Vec<f32>) = (
            a.iter().map(|&x| f32::from_bits(x)).collect(),
            b.iter().map(|&x| f32::from_bits(x)).collect(),
        );
        let (sa, sb) = (a.iter().sum::<f32>(), b.iter().sum::<f32>());
        assert!(
            sa > 0.0 && (sa - sb).abs() <= 1e-3 * sa,
            "frame {f}: {sa} against {sb}"
        );
    }
}
