//! The environment light end to end: a white furnace (a closed convex diffuse object of albedo
//! `a` under a uniform environment of radiance 1 has radiance exactly `a`, and the background is
//! exactly 1) for the independent tracer and the reuse methods, and the reuse methods unbiased on
//! an environment-lit scene with background pixels and a bright sun (the z-test of
//! tests/reuse.rs).
mod common;
mod stats;

use common::{render_in_memory, reuse_renders};
use glam::Vec3;
use reframe::driver::{render_frame_independent, thread_pool, RenderOptions};
use reframe::embree::Device;
use reframe::image::{write_image, Image, Metadata, WriteOptions};
use reframe::integrator::Integrator;
use reframe::reuse::Method;
use reframe::scene::Scene;
use reframe::state::key::scene_and_build_hashes;
use stats::{assert_unbiased, block_moments, z_test};

/// A unit cube resting on nothing, wound outwards, in material `box`.
const CUBE: &str = "mtllib s.mtl\n\
    v -0.5 -0.5 -0.5\nv 0.5 -0.5 -0.5\nv 0.5 0.5 -0.5\nv -0.5 0.5 -0.5\n\
    v -0.5 -0.5 0.5\nv 0.5 -0.5 0.5\nv 0.5 0.5 0.5\nv -0.5 0.5 0.5\n\
    usemtl box\n\
    f 1 4 3 2\nf 5 6 7 8\nf 1 5 8 4\nf 2 3 7 6\nf 4 8 7 3\nf 1 2 6 5\n";

fn write_scene(d: &std::path::Path, obj: &str, mtl: &str, toml: &str) -> String {
    std::fs::write(d.join("s.obj"), obj).unwrap();
    std::fs::write(d.join("s.mtl"), mtl).unwrap();
    let p = d.join("s.toml");
    std::fs::write(&p, toml).unwrap();
    p.to_str().unwrap().to_string()
}

fn camera(frames: u32, env: &str) -> String {
    format!(
        "obj = \"s.obj\"\nframes = {frames}\nresolution = [48, 36]\n{env}\n\
         [[keyframe]]\nframe = 0\nposition = [1.6, 1.2, 2.4]\nlook_at = [0.0, 0.0, 0.0]\nup = [0.0, 1.0, 0.0]\nfov = 45.0\n\
         [[keyframe]]\nframe = {}\nposition = [2.3, 1.0, 1.5]\nlook_at = [0.0, 0.1, 0.0]\nup = [0.0, 1.0, 0.0]\nfov = 40.0\n",
        frames - 1
    )
}

#[test]
fn white_furnace_under_a_uniform_environment() {
    let dir = tempfile::tempdir().unwrap();
    let albedo = 0.6;
    let path = write_scene(
        dir.path(),
        CUBE,
        &format!("newmtl box\nKd {albedo} {albedo} {albedo}\n"),
        &camera(
            7,
            "[environment]\nradiance = [0.5, 0.5, 0.5]\nintensity = 2.0",
        ),
    );
    let device = Device::new().unwrap();
    let scene = Scene::load(&path, &device).unwrap();
    assert!(scene.lights.tris.is_empty() && scene.environment.is_some());
    // The environment is part of the scene's identity (cached references, checkpoints): a
    // brighter or bluer one is another scene.
    let hash = |env: &str| {
        let d = tempfile::tempdir().unwrap();
        let p = write_scene(
            d.path(),
            CUBE,
            &format!("newmtl box\nKd {albedo} {albedo} {albedo}\n"),
            &camera(7, env),
        );
        scene_and_build_hashes(&Scene::load(&p, &device).unwrap())
            .unwrap()
            .0
    };
    let base = hash("[environment]\nradiance = [0.5, 0.5, 0.5]\nintensity = 2.0");
    assert_eq!(base, scene_and_build_hashes(&scene).unwrap().0);
    assert_ne!(
        base,
        hash("[environment]\nradiance = [0.5, 0.6, 0.5]\nintensity = 2.0")
    );
    // Turning one colour changes nothing, and is the same scene.
    assert_eq!(
        base,
        hash("[environment]\nradiance = [0.5, 0.5, 0.5]\nintensity = 2.0\nrotation = 10.0")
    );
    assert_ne!(
        base,
        hash("[environment]\nradiance = [0.5, 0.5, 0.5]\nintensity = 2.5")
    );
    let integ = Integrator::new(&scene, 8);
    let pool = thread_pool(0).unwrap();
    let (w, h, target) = (48u32, 36u32, 3u32);
    let ind = pool.install(|| {
        render_frame_independent(
            &integ,
            &scene.camera(target, w, h),
            target,
            16,
            1,
            false,
            &|_| {},
        )
    });
    let independent = ind.pixels;
    // Background pixels see the environment directly: exactly 1. The cube covers a good part.
    let background: Vec<usize> = (0..independent.len())
        .filter(|&i| independent[i] == Vec3::ONE)
        .collect();
    // The cube's pixels away from its silhouette: no background pixel in the 3x3 around.
    let (wi, hi) = (w as i64, h as i64);
    let object: Vec<usize> = (0..independent.len())
        .filter(|&i| {
            let (x, y) = (i as i64 % wi, i as i64 / wi);
            (-1..=1).all(|dy| {
                (-1..=1).all(|dx| {
                    let (u, v) = (x + dx, y + dy);
                    u >= 0
                        && v >= 0
                        && u < wi
                        && v < hi
                        && independent[(v * wi + u) as usize] != Vec3::ONE
                })
            })
        })
        .collect();
    assert!(
        background.len() > 400 && object.len() > 300,
        "{} background and {} object pixels of {}",
        background.len(),
        object.len(),
        independent.len()
    );
    let mean =
        |px: &[Vec3], on: &[usize]| on.iter().map(|&i| px[i]).sum::<Vec3>() / on.len() as f32;
    let m = mean(&independent, &object);
    eprintln!("independent: object mean {m}");
    assert!((m - Vec3::splat(albedo)).abs().max_element() < 0.005, "{m}");
    for method in [Method::MisExact, Method::MisCv, Method::Havran, Method::Mis] {
        let opts = RenderOptions {
            method,
            window: 5,
            spp: 2,
            seed: 3,
            frames: Some(1..=5),
            resolution: Some((w, h)),
            progress: false,
            ..RenderOptions::default()
        };
        let frames = pool.install(|| render_in_memory(&integ, &opts).0);
        let px = frames[&target].pixels();
        let m = mean(&px, &object);
        let b = mean(&px, &background);
        eprintln!("{method:?}: object mean {m}, background mean {b}");
        assert!(
            (m - Vec3::splat(albedo)).abs().max_element() < 0.01,
            "{method:?}: {m}"
        );
        assert!(
            (b - Vec3::ONE).abs().max_element() < 0.01,
            "{method:?}: background {b}"
        );
    }
}

/// A lat-long sky: a gradient, a dark ground and a small bright sun.
fn sky(path: &std::path::Path) {
    let (w, h) = (64u32, 32u32);
    let mut img = Image::new(w, h, &["R", "G", "B"]);
    for y in 0..h {
        for x in 0..w {
            let v = (y as f32 + 0.5) / h as f32;
            let c = if (x, y) == (19, 8) {
                Vec3::new(300.0, 280.0, 240.0)
            } else if v < 0.5 {
                Vec3::new(0.3, 0.5, 1.0) * (1.2 - v)
            } else {
                Vec3::new(0.2, 0.15, 0.1)
            };
            let i = 3 * (y * w + x) as usize;
            img.data[i..i + 3].copy_from_slice(&c.to_array());
        }
    }
    let opts = WriteOptions { exr_float: true };
    write_image(path, &img, &Metadata::default(), &opts).unwrap();
}

/// A glossy box on a diffuse floor under `sky` (written into `d`), rotated 20 degrees, with the
/// 9-frame camera: background pixels, a sun texel and a Phong lobe. Returns the scene's path.
fn glossy_box_under_the_sky(d: &std::path::Path) -> String {
    sky(&d.join("sky.exr"));
    write_scene(
        d,
        &format!(
            "{CUBE}v -3 -0.5 -3\nv 3 -0.5 -3\nv 3 -0.5 3\nv -3 -0.5 3\nusemtl floor\nf 9 12 11 10\n"
        ),
        "newmtl box\nKd 0.5 0.3 0.2\nKs 0.3 0.3 0.3\nNs 30\nnewmtl floor\nKd 0.5 0.5 0.5\n",
        &camera(9, "[environment]\nimage = \"sky.exr\"\nrotation = 20.0"),
    )
}

/// A floor and a glossy cube under the sky, seen against the horizon: background pixels, a sun
/// that casts a hard shadow, and a zoom. `mis-exact` and `mis-cv` (which reuse the escaped camera
/// samples as points at infinity carrying the sky's radiance) match an independent reference
/// block by block.
#[test]
fn reuse_is_unbiased_under_an_environment_with_background_pixels() {
    let dir = tempfile::tempdir().unwrap();
    let path = glossy_box_under_the_sky(dir.path());
    let device = Device::new().unwrap();
    let scene = Scene::load(&path, &device).unwrap();
    assert!(scene.inputs.iter().any(|p| p.ends_with("sky.exr")));
    let integ = Integrator::new(&scene, 8);
    let pool = thread_pool(0).unwrap();
    let (w, h, b, target) = (48usize, 36usize, 4, 4u32);
    let k = 96;
    let reference: Vec<Vec<Vec3>> = (0..k)
        .map(|s| {
            pool.install(|| {
                let cam = scene.camera(target, w as u32, h as u32);
                render_frame_independent(&integ, &cam, target, 16, 5000 + s, false, &|_| {}).pixels
            })
        })
        .collect();
    let reference = block_moments(&reference, w, h, b);
    for method in [Method::MisCv, Method::MisExact] {
        let res = (w as u32, h as u32);
        let frames = (0..=8, target);
        let renders = reuse_renders(&integ, &pool, (method, 5), frames, res, (k, 6000));
        let z = z_test(&block_moments(&renders, w, h, b), &reference);
        assert_unbiased(&format!("{method:?} under the environment"), &z);
    }
}

/// A card (one diffuse quad, no thickness) under a uniform sky, and a camera that crosses its
/// plane: the group's eyes see both of its sides. Each eye's light samples behind the surface
/// serve the eyes on the other side, and the MIS denominators count them there, so they must be
/// kept and traced: dropped (as the native eye alone would drop them), both sides came out 23%
/// too dark with `mis-exact` and `mis-cv`. Frames 0 and 8 (one side each) of one group of 9,
/// block by block against the independent tracer.
#[test]
fn reuse_is_unbiased_where_the_camera_crosses_a_card() {
    let dir = tempfile::tempdir().unwrap();
    let card =
        "mtllib s.mtl\nv 0 0 0.6\nv 0 0 -0.6\nv 0 1.2 -0.6\nv 0 1.2 0.6\nusemtl card\nf 1 2 3 4\n";
    let toml = "obj = \"s.obj\"\nframes = 9\nresolution = [48, 36]\n\
        [environment]\nradiance = [1.0, 1.0, 1.0]\n\
        [[keyframe]]\nframe = 0\nposition = [-1.0, 0.6, 3.0]\nlook_at = [0.0, 0.6, 0.0]\nup = [0.0, 1.0, 0.0]\nfov = 45.0\n\
        [[keyframe]]\nframe = 8\nposition = [1.0, 0.6, 3.0]\nlook_at = [0.0, 0.6, 0.0]\nup = [0.0, 1.0, 0.0]\nfov = 45.0\n";
    let path = write_scene(dir.path(), card, "newmtl card\nKd 0.5 0.5 0.5\n", toml);
    let device = Device::new().unwrap();
    let scene = Scene::load(&path, &device).unwrap();
    let integ = Integrator::new(&scene, 8);
    let pool = thread_pool(0).unwrap();
    let (w, h, b) = (48usize, 36usize, 4);
    let k = 64;
    for target in [0u32, 8] {
        let reference: Vec<Vec<Vec3>> = (0..k)
            .map(|s| {
                pool.install(|| {
                    let cam = scene.camera(target, w as u32, h as u32);
                    render_frame_independent(&integ, &cam, target, 8, 7000 + s, false, &|_| {})
                        .pixels
                })
            })
            .collect();
        let reference = block_moments(&reference, w, h, b);
        for method in [Method::MisExact, Method::MisCv] {
            let res = (w as u32, h as u32);
            let renders =
                reuse_renders(&integ, &pool, (method, 9), (0..=8, target), res, (k, 8000));
            let z = z_test(&block_moments(&renders, w, h, b), &reference);
            assert_unbiased(
                &format!("{method:?}, frame {target}, both sides of a card"),
                &z,
            );
        }
    }
}

/// The power heuristic after the first hit (`PathMis::Power`) gives the same image in
/// expectation as the default balance heuristic: per 4x4 block, z-tested against the balance
/// renders, on the glossy box under the sky and sun (environment against BSDF sampling) and on
/// `cornell` (an area light against a glossy block and diffuse walls, several bounces).
#[test]
fn power_heuristic_after_the_first_hit_is_unbiased() {
    use reframe::integrator::PathMis;
    let dir = tempfile::tempdir().unwrap();
    let path = glossy_box_under_the_sky(dir.path());
    let device = Device::new().unwrap();
    let pool = thread_pool(0).unwrap();
    for scene in [
        Scene::load(&path, &device).unwrap(),
        Scene::load("cornell", &device).unwrap(),
    ] {
        let (w, h, b, target, k) = (48usize, 36usize, 4, 4u32, 64);
        let cam = scene.camera(target, w as u32, h as u32);
        let renders = |mis: PathMis, seed: u64| -> Vec<Vec<Vec3>> {
            let mut integ = Integrator::new(&scene, 8);
            integ.path_mis = mis;
            (0..k)
                .map(|s| {
                    pool.install(|| {
                        render_frame_independent(&integ, &cam, target, 16, seed + s, false, &|_| {})
                            .pixels
                    })
                })
                .collect()
        };
        let balance = block_moments(&renders(PathMis::Balance, 7000), w, h, b);
        let power = block_moments(&renders(PathMis::Power, 8000), w, h, b);
        let z = z_test(&power, &balance);
        assert_unbiased(&format!("power heuristic on {}", scene.name), &z);
    }
}

/// An environment's rotation is an angle modulo a turn: 20 degrees, 20 plus a thousand turns and
/// -340 are the same scene (and so render the same: the hash covers the rotation's sine and
/// cosine), which 21 degrees is not. 360020 rounded to f32 before it was reduced turned the sky
/// by a hair.
#[test]
fn an_environment_rotation_is_taken_modulo_a_turn() {
    let device = Device::new().unwrap();
    let hash = |rotation: &str| {
        let d = tempfile::tempdir().unwrap();
        sky(&d.path().join("sky.exr"));
        let p = write_scene(
            d.path(),
            CUBE,
            "newmtl box\nKd 0.5 0.5 0.5\n",
            &camera(
                3,
                &format!("[environment]\nimage = \"sky.exr\"\nrotation = {rotation}"),
            ),
        );
        scene_and_build_hashes(&Scene::load(&p, &device).unwrap())
            .unwrap()
            .0
    };
    let base = hash("20.0");
    assert_eq!(base, hash("360020.0"));
    assert_eq!(base, hash("-340.0"));
    assert_ne!(base, hash("21.0"));
}

/// The numbers of `list` (separated by `sep`) times `s`, separated alike.
fn times(list: &str, sep: &str, s: f32) -> String {
    let scaled: Vec<String> = list
        .split(sep)
        .map(|x| (x.parse::<f32>().unwrap() * s).to_string())
        .collect();
    scaled.join(sep)
}

/// A scene and its camera path scaled by 2^16 render the frames of the unscaled scene, with the
/// reuse methods too, where pixels see the environment: an escaped sample was projected into the
/// other eyes as the point `eye + d`, which f32 rounds by the eye's distance from the origin (2^-6
/// at 2.6e5), so the background landed in the wrong pixels along the film's border and frame
/// means moved by up to 5%. Now a direction is projected as a direction.
#[test]
fn a_scene_scaled_up_renders_its_background_as_the_unscaled_one() {
    let device = Device::new().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let pool = thread_pool(2).unwrap();
    let env = "[environment]\nradiance = [0.3, 0.4, 0.5]";
    let scaled = |s: f32| {
        let d = dir.path().join(format!("s{s}"));
        std::fs::create_dir(&d).unwrap();
        let obj: String = CUBE
            .lines()
            .map(|l| match l.strip_prefix("v ") {
                Some(p) => format!("v {}\n", times(p, " ", s)),
                None => format!("{l}\n"),
            })
            .collect();
        let toml: String = camera(3, env)
            .lines()
            .map(|l| {
                let key = ["position = [", "look_at = ["]
                    .into_iter()
                    .find(|k| l.starts_with(k));
                match key {
                    Some(k) => format!("{k}{}]\n", times(&l[k.len()..l.len() - 1], ", ", s)),
                    None => format!("{l}\n"),
                }
            })
            .collect();
        let path = write_scene(&d, &obj, "newmtl box\nKd 0.5 0.5 0.5\n", &toml);
        Scene::load(&path, &device).unwrap()
    };
    let (a, b) = (scaled(1.0), scaled(65536.0));
    for method in [Method::MisExact, Method::MisCv] {
        let frames = |scene: &Scene| {
            let integ = Integrator::new(scene, 4);
            let opts = RenderOptions {
                method,
                window: 3,
                spp: 2,
                seed: 5,
                frames: Some(0..=2),
                progress: false,
                ..RenderOptions::default()
            };
            pool.install(|| render_in_memory(&integ, &opts).0)
        };
        let (fa, fb) = (frames(&a), frames(&b));
        for f in 0..=2 {
            let (pa, pb) = (fa[&f].pixels(), fb[&f].pixels());
            let mean = pa.iter().map(|p| p.element_sum() as f64).sum::<f64>() / pa.len() as f64;
            let off = pa
                .iter()
                .zip(&pb)
                .map(|(p, q)| (*p - *q).abs().element_sum() as f64)
                .sum::<f64>()
                / pa.len() as f64;
            assert!(
                off < 1e-3 * mean,
                "{method:?} frame {f}: the scaled scene's pixels are {off} from the unscaled one's \
                 (mean {mean})"
            );
        }
    }
}
