//! Statistical and structural tests of frame reuse (docs/estimators.md): window 1 is the independent
//! tracer, the MIS weights of a sample's eyes sum to one, `mis-exact` is unbiased on a glossy
//! scene with occlusion and a zooming camera while Havran's reuse is caught biased, and on a
//! diffuse scene without occlusion all reuse methods agree.
mod common;
mod stats;

use common::render_in_memory;
use glam::Vec3;
use reframe::camera::Camera;
use reframe::driver::{render_frame_independent, thread_pool, RenderOptions};
use reframe::embree::Device;
use reframe::film::Developed;
use reframe::integrator::{Integrator, Rays};
use reframe::reuse::weights::{indirect_weights, EyeTerms};
use reframe::reuse::Method;
use reframe::sampling::Sampler;
use reframe::scene::Scene;
use stats::{assert_unbiased, block_moments, z_pass_fraction, z_test};
use std::collections::BTreeMap;

/// Render frames `a..=b` at `w` x `h` with a reuse method in memory: frame -> pixels.
#[allow(clippy::too_many_arguments)]
fn reuse_frames(
    integ: &Integrator,
    method: Method,
    window: u32,
    spp: u32,
    seed: u64,
    a: u32,
    b: u32,
    w: u32,
    h: u32,
) -> BTreeMap<u32, Vec<Vec3>> {
    let opts = RenderOptions {
        method,
        window,
        spp,
        seed,
        progress: false,
        ..RenderOptions::default()
    };
    reuse_render(integ, &opts, a, b, w, h)
        .into_iter()
        .map(|(f, d)| (f, d.pixels()))
        .collect()
}

/// Render frames `a..=b` at `w` x `h` with `opts` in memory: frame -> developed frame.
fn reuse_render(
    integ: &Integrator,
    opts: &RenderOptions,
    a: u32,
    b: u32,
    w: u32,
    h: u32,
) -> BTreeMap<u32, Developed> {
    let opts = RenderOptions {
        frames: Some(a..=b),
        resolution: Some((w, h)),
        ..opts.clone()
    };
    render_in_memory(integ, &opts).0
}

/// A scene written into `d` as `NAME.obj`, `NAME.mtl`, `NAME.toml` (in that order in `files`),
/// and loaded.
fn scene_in(d: &std::path::Path, name: &str, files: [&str; 3], device: &Device) -> Scene {
    for (ext, text) in ["obj", "mtl", "toml"].iter().zip(files) {
        std::fs::write(d.join(format!("{name}.{ext}")), text).unwrap();
    }
    Scene::load(d.join(format!("{name}.toml")).to_str().unwrap(), device).unwrap()
}

#[test]
fn window_one_is_the_independent_tracer() {
    let device = Device::new().unwrap();
    let scene = Scene::load("vase", &device).unwrap();
    // Single primary rays for both (packets give the same frames up to Embree's rounding:
    // tests/render.rs and `native_packets_give_the_single_ray_frames`).
    let mut integ = Integrator::new(&scene, 16);
    integ.primary = Rays::Single;
    let pool = thread_pool(0).unwrap();
    let (w, h) = (48, 36);
    for method in [Method::MisExact, Method::MisCv, Method::Mis, Method::Havran] {
        let reuse = pool.install(|| reuse_frames(&integ, method, 1, 3, 5, 30, 31, w, h));
        for f in 30..=31 {
            let ind = pool.install(|| {
                render_frame_independent(&integ, &scene.camera(f, w, h), f, 3, 5, false, &|_| {})
            });
            for (a, b) in reuse[&f].iter().zip(&ind.pixels) {
                let tol = 1e-5 + 1e-5 * b.abs().max_element();
                assert!(
                    (*a - *b).abs().max_element() <= tol,
                    "{method:?} frame {f}: {a} vs {b}"
                );
            }
        }
    }
}

/// The native samples' rays in packets (primary rays 16 consecutive camera samples of a tile
/// row to a packet, the wavefront's shadow and continuation rays 16 live paths) give the frames
/// of single rays, up to the rounding of Embree's two kernels: every method, a
/// textured and environment-lit scene (escapes kept) and an odd size whose rows end in partial
/// packets.
#[test]
fn native_packets_give_the_single_ray_frames() {
    let device = Device::new().unwrap();
    let root = env!("CARGO_MANIFEST_DIR");
    for name in [
        "vase".to_string(),
        format!("{root}/scenes/production/courtyard.toml"),
    ] {
        let scene = Scene::load(&name, &device).unwrap();
        let pool = thread_pool(2).unwrap();
        let (w, h) = (45, 31);
        let f0 = scene.frames / 2;
        for method in [Method::MisCv, Method::MisExact, Method::Mis, Method::Havran] {
            let frames = |rays| {
                let mut integ = Integrator::new(&scene, 16);
                integ.primary = rays;
                integ.paths = rays;
                pool.install(|| reuse_frames(&integ, method, 3, 2, 9, f0, f0 + 3, w, h))
            };
            let (single, packet) = (frames(Rays::Single), frames(Rays::Packet));
            let (mut n, mut bitwise) = (0, 0);
            for (f, px) in &single {
                for (a, b) in px.iter().zip(&packet[f]) {
                    let tol = 1e-3 * a.abs().max_element().max(1.0);
                    assert!(
                        (*a - *b).abs().max_element() <= tol,
                        "{name} {method:?} {f}: {a} vs {b}"
                    );
                    n += 1;
                    bitwise +=
                        (a.to_array().map(f32::to_bits) == b.to_array().map(f32::to_bits)) as usize;
                }
            }
            assert!(
                bitwise * 100 >= n * 99,
                "{name} {method:?}: {bitwise} of {n} bitwise"
            );
        }
    }
}

/// The balance weights the estimator gives a sample's eyes (as the generating technique of its
/// BSDF direction) sum to one, for the exact densities and for approximation (10), whenever some
/// eye of the group sees the hit.
#[test]
fn mis_weights_sum_to_one() {
    let device = Device::new().unwrap();
    let scene = Scene::load("vase", &device).unwrap();
    let integ = Integrator::new(&scene, 16);
    let (w, h) = (64, 48);
    let eyes: Vec<Camera> = (20..27).map(|f| scene.camera(f, w, h)).collect();
    let spp = 2;
    let mut tested = 0;
    let mut t = reframe::integrator::Tally::default();
    for i in 0..4000u32 {
        let mut s = Sampler::new(1, 23, i, 0);
        let cam = &eyes[3];
        let r = glam::Vec2::new(s.next_1d() * w as f32, s.next_1d() * h as f32);
        let Some(fh) = integ.trace_first_hit(cam.eye, cam.direction(r), &mut s, &mut t) else {
            continue;
        };
        if fh.w.is_none() {
            continue;
        }
        // Pretend every eye that has x on its film sees it (visibility is a 0/1 factor of D),
        // with uneven native counts, as adaptive sampling makes them.
        let terms: Vec<EyeTerms> = eyes
            .iter()
            .enumerate()
            .map(|(k, e)| {
                EyeTerms::new(
                    (e.eye - fh.sp.p).normalize(),
                    if e.project(fh.sp.p).is_some() {
                        e.jacobian(fh.sp.p, fh.sp.ng) / e.pixel_area()
                    } else {
                        0.0
                    },
                    (spp + k as u32 % 3) as f32,
                )
            })
            .collect();
        for method in [Method::MisExact, Method::Mis] {
            let weights = indirect_weights(&fh, &terms, spp, method.weights());
            assert!(weights.iter().all(|w| (0.0..=1.0 + 1e-6).contains(w)));
            let sum: f64 = weights.iter().map(|&w| w as f64).sum();
            assert!((sum - 1.0).abs() < 1e-5, "{method:?}: weights sum to {sum}");
            // An eye that cannot see x never takes weight.
            for (wk, e) in weights.iter().zip(&terms) {
                assert!(e.j_over_a > 0.0 || *wk == 0.0);
            }
        }
        tested += 1;
    }
    assert!(tested > 1000, "only {tested} samples tested");
}

/// The vase moves in and zooms (fov 55 -> 30 over the animation), the ball occludes part of
/// the vase from some eyes, and the vase is glossy: every source of bias of the approximate
/// methods is present. K independent mis-exact renders must match a high-sample independent
/// reference block by block; Havran's reuse must not.
#[test]
fn mis_exact_is_unbiased_and_havran_is_not() {
    let device = Device::new().unwrap();
    let scene = Scene::load("vase", &device).unwrap();
    let integ = Integrator::new(&scene, 8);
    let pool = thread_pool(0).unwrap();
    let (w, h, b) = (64, 48, 4);
    let (a, z, target) = (32, 40, 36); // window 9 around frame 36: eyes far apart, strong zoom
    let k = 128;
    let reference: Vec<Vec<Vec3>> = (0..k)
        .map(|s| {
            pool.install(|| {
                render_frame_independent(
                    &integ,
                    &scene.camera(target, w, h),
                    target,
                    16,
                    1000 + s,
                    false,
                    &|_| {},
                )
                .pixels
            })
        })
        .collect();
    let reference = block_moments(&reference, w as usize, h as usize, b);
    let run = |method: Method| {
        let renders: Vec<Vec<Vec3>> = (0..k)
            .map(|s| {
                pool.install(|| {
                    reuse_frames(&integ, method, 9, 2, s, a, z, w, h)
                        .remove(&target)
                        .unwrap()
                })
            })
            .collect();
        block_moments(&renders, w as usize, h as usize, b)
    };
    let (exact_pass, exact_worst) = z_pass_fraction(&run(Method::MisExact), &reference);
    // mis-cv, with groups of both parities over the target (window 5 over the same frames puts
    // frame 36 in 5 groups, first frames 32-36), with and without adaptive counts; in the
    // one group of window 9 with 2 native samples, where it folds by sample index; and as the
    // last frame of frames 32-36 at window 3, folded by sample index in its one group, whose
    // other eyes' frames are reached by other groups too (their samples were one stratified
    // stream there, its consecutive samples dependent, and split across the two folds they
    // made the control variate biased: up to 3% dark on glossy surfaces at 2 spp).
    for (window, spp, adaptive, (a, z)) in [
        (5, 1, None, (a, z)),
        (5, 1, Some(0.75), (a, z)),
        (9, 2, None, (a, z)),
        (3, 2, None, (a, target)),
    ] {
        let renders: Vec<Vec<Vec3>> = (0..k)
            .map(|s| {
                let opts = RenderOptions {
                    method: Method::MisCv,
                    window,
                    spp,
                    seed: 500 + s,
                    adaptive,
                    progress: false,
                    ..RenderOptions::default()
                };
                pool.install(|| {
                    reuse_render(&integ, &opts, a, z, w, h)
                        .remove(&target)
                        .unwrap()
                        .pixels()
                })
            })
            .collect();
        let z = z_test(
            &block_moments(&renders, w as usize, h as usize, b),
            &reference,
        );
        assert_unbiased(
            &format!("mis-cv (window {window}, spp {spp}, adaptive {adaptive:?})"),
            &z,
        );
    }
    // Adaptive native counts (decided by pilot rays before the samples) enter the densities:
    // still unbiased. With the zoom, the later eyes see less than the earlier ones, so the
    // borders get extra samples.
    let adaptive: Vec<Vec<Vec3>> = (0..k)
        .map(|s| {
            let opts = RenderOptions {
                method: Method::MisExact,
                window: 9,
                spp: 1,
                seed: s,
                adaptive: Some(0.75),
                progress: false,
                ..RenderOptions::default()
            };
            pool.install(|| {
                reuse_render(&integ, &opts, a, z, w, h)
                    .remove(&target)
                    .unwrap()
                    .pixels()
            })
        })
        .collect();
    let (adaptive_pass, adaptive_worst) = z_pass_fraction(
        &block_moments(&adaptive, w as usize, h as usize, b),
        &reference,
    );
    eprintln!(
        "mis-exact --adaptive: {:.1}% of blocks pass (worst z {adaptive_worst:.1})",
        100.0 * adaptive_pass
    );
    assert!(
        adaptive_pass >= 0.99,
        "adaptive mis-exact fails the z-test on {:.1}% of blocks",
        100.0 * (1.0 - adaptive_pass)
    );
    let (havran_pass, havran_worst) = z_pass_fraction(&run(Method::Havran), &reference);
    let (mis_pass, mis_worst) = z_pass_fraction(&run(Method::Mis), &reference);
    eprintln!(
        "mis (approximation (10)): {:.1}% of blocks pass (worst z {mis_worst:.1})",
        100.0 * mis_pass
    );
    eprintln!("mis-exact: {:.1}% of blocks pass (worst z {exact_worst:.1}); havran: {:.1}% (worst z {havran_worst:.1})", 100.0 * exact_pass, 100.0 * havran_pass);
    assert!(
        exact_pass >= 0.99,
        "mis-exact fails the z-test on {:.1}% of blocks",
        100.0 * (1.0 - exact_pass)
    );
    assert!(
        havran_pass < 0.99,
        "the z-test did not detect Havran's bias: it has no power"
    );
}

/// A diffuse box without occluders, camera drifting a little: all reuse methods estimate the
/// same image within their noise.
#[test]
fn reuse_methods_agree_on_diffuse_scene_without_occlusion() {
    let device = Device::new().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = scene_in(
        d,
        "box",
        [
        "mtllib box.mtl\nv -1 0 -1\nv 1 0 -1\nv 1 2 -1\nv -1 2 -1\nv -1 0 1\nv 1 0 1\nv 1 2 1\nv -1 2 1\n\
         v -0.3 1.99 -0.3\nv 0.3 1.99 -0.3\nv 0.3 1.99 0.3\nv -0.3 1.99 0.3\n\
         usemtl white\nf 1 2 6 5\nf 4 8 7 3\nf 1 4 3 2\nusemtl red\nf 1 5 8 4\nusemtl green\nf 2 3 7 6\n\
         usemtl light\nf 9 10 11 12\n",
        "newmtl white\nKd 0.7 0.7 0.7\nnewmtl red\nKd 0.6 0.1 0.1\nnewmtl green\nKd 0.1 0.5 0.1\nnewmtl light\nKd 0 0 0\nKe 10 10 10\n",
        "obj = \"box.obj\"\nframes = 9\nresolution = [32, 32]\n\
         [[keyframe]]\nframe = 0\nposition = [-0.15, 1.0, 3.0]\nlook_at = [0.0, 1.0, 0.0]\nup = [0.0, 1.0, 0.0]\nfov = 40.0\n\
         [[keyframe]]\nframe = 8\nposition = [0.15, 1.0, 3.0]\nlook_at = [0.0, 1.0, 0.0]\nup = [0.0, 1.0, 0.0]\nfov = 40.0\n",
        ],
        &device,
    );
    let integ = Integrator::new(&scene, 8);
    let pool = thread_pool(0).unwrap();
    let k = 32;
    let run = |method: Method| {
        let renders: Vec<Vec<Vec3>> = (0..k)
            .map(|s| {
                pool.install(|| {
                    reuse_frames(&integ, method, 5, 2, 7 + s, 2, 6, 32, 32)
                        .remove(&4)
                        .unwrap()
                })
            })
            .collect();
        block_moments(&renders, 32, 32, 4)
    };
    let exact = run(Method::MisExact);
    for method in [Method::Mis, Method::Havran] {
        let (pass, worst) = z_pass_fraction(&run(method), &exact);
        assert!(
            pass >= 0.99,
            "{method:?} disagrees with mis-exact on {:.1}% of blocks (worst z {worst:.1})",
            100.0 * (1.0 - pass)
        );
    }
}

/// Adaptive native samples even out the noise: on the vase zooming in, the pixels that the other
/// eyes of a group barely see (the image borders, which the later, narrower eyes miss, and
/// disocclusions behind the vase and ball) have far more variance than the rest without them.
/// With them, the variance of those starved pixels relative to the rest drops, at about equal
/// time (the figures are printed; the test asserts the ratio and the unbiased mean).
#[test]
fn adaptive_samples_even_out_the_noise() {
    let occluders = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/occluders.toml");
    // The vase's borders (zooming in), and the bands beside the pillars of `occluders`.
    adaptive_evens_out(occluders, (2, 14, 8));
    adaptive_evens_out("vase", (30, 42, 36));
}

fn adaptive_evens_out(scene: &str, (a, z, target): (u32, u32, u32)) {
    let device = Device::new().unwrap();
    let name = scene;
    let scene = Scene::load(scene, &device).unwrap();
    let integ = Integrator::new(&scene, 8);
    let pool = thread_pool(0).unwrap();
    let (w, h) = (64, 48);
    let k = 48;
    let run = |adaptive: Option<f32>| {
        let start = std::time::Instant::now();
        let renders: Vec<Developed> = (0..k)
            .map(|s| {
                let opts = RenderOptions {
                    method: Method::MisExact,
                    window: 7,
                    spp: 1,
                    seed: 50 + s,
                    aov: true,
                    adaptive,
                    progress: false,
                    ..RenderOptions::default()
                };
                pool.install(|| {
                    reuse_render(&integ, &opts, a, z, w, h)
                        .remove(&target)
                        .unwrap()
                })
            })
            .collect();
        (renders, start.elapsed().as_secs_f64() / k as f64)
    };
    let (plain, t_plain) = run(None);
    let (adapt, t_adapt) = run(Some(0.75));
    let n = (w * h) as usize;
    let lum = |p: Vec3| (0.2126 * p.x + 0.7152 * p.y + 0.0722 * p.z) as f64;
    // Relative variance per pixel, var / (mean^2 + 0.01): the noise as seen, whatever the
    // pixel's brightness (the relMSE of `compare`).
    let variance = |r: &[Developed]| -> Vec<f64> {
        (0..n)
            .map(|i| {
                let v: Vec<f64> = r.iter().map(|d| lum(d.rgb(i))).collect();
                let m = v.iter().sum::<f64>() / v.len() as f64;
                let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (v.len() - 1) as f64;
                var / (m * m + 0.01)
            })
            .collect()
    };
    let spp_eff = |r: &[Developed]| -> Vec<f32> {
        let mut sum = vec![0.0f32; n];
        for d in r {
            let e = d.channel("spp_eff").expect("an spp_eff channel");
            sum.iter_mut()
                .zip(e)
                .for_each(|(s, v)| *s += v / r.len() as f32);
        }
        sum
    };
    // Starved pixels: fewer than 3/4 of the median samples landed (mean over the renders)
    // without adaptive counts.
    let eff = spp_eff(&plain);
    let mut sorted = eff.clone();
    sorted.sort_by(f32::total_cmp);
    let median = sorted[n / 2];
    let starved: Vec<bool> = eff.iter().map(|&e| e < 0.75 * median).collect();
    let n_starved = starved.iter().filter(|&&s| s).count();
    assert!(
        n_starved > n / 50,
        "only {n_starved} starved pixels: the test has no subject"
    );
    let mean_over = |v: &[f64], want: bool| {
        let sel: Vec<f64> = v
            .iter()
            .zip(&starved)
            .filter(|(_, &s)| s == want)
            .map(|(x, _)| *x)
            .collect();
        sel.iter().sum::<f64>() / sel.len() as f64
    };
    let (vp, va) = (variance(&plain), variance(&adapt));
    let ratio_plain = mean_over(&vp, true) / mean_over(&vp, false);
    let ratio_adapt = mean_over(&va, true) / mean_over(&va, false);
    assert!(
        ratio_plain > 1.2,
        "starved pixels are not noisier ({ratio_plain:.2}): no subject"
    );
    let eff_a = spp_eff(&adapt);
    let min_share = |e: &[f32]| {
        let mut s = e.to_vec();
        s.sort_by(f32::total_cmp);
        s[n / 100] / s[n / 2]
    };
    eprintln!(
        "{name}: starved pixels {n_starved}/{n}; relative variance starved/rest: {ratio_plain:.2} plain, \
         {ratio_adapt:.2} adaptive; 1st-percentile/median spp_eff: {:.2} plain, {:.2} adaptive; \
         seconds per render {t_plain:.3} plain, {t_adapt:.3} adaptive; variance x time, all \
         pixels: {:.3e} plain, {:.3e} adaptive; starved pixels: {:.3e} plain, {:.3e} adaptive",
        min_share(&eff),
        min_share(&eff_a),
        (mean_over(&vp, true) * n_starved as f64 + mean_over(&vp, false) * (n - n_starved) as f64)
            / n as f64
            * t_plain,
        (mean_over(&va, true) * n_starved as f64 + mean_over(&va, false) * (n - n_starved) as f64)
            / n as f64
            * t_adapt,
        mean_over(&vp, true) * t_plain,
        mean_over(&va, true) * t_adapt,
    );
    assert!(
        min_share(&eff_a) > 1.3 * min_share(&eff),
        "spp_eff not evened out"
    );
    // More uniform: the starved/rest ratio nearer 1, on a log scale.
    assert!(
        ratio_adapt.ln().abs() < 0.75 * ratio_plain.ln().abs(),
        "starved pixels' relative variance ratio {ratio_adapt:.2} (adaptive) vs {ratio_plain:.2}"
    );
}

/// The control variate removes the count noise: on the flat, evenly lit back wall of `vase`
/// (the top rows of frame 36), where nearly all of `mis-exact`'s variance comes from how many
/// reused samples happen to land in a pixel, `mis-cv`'s per-pixel variance is at least 4x lower
/// at the same settings (n_f = 9, 1 native spp, frame 36 in all 9 of its groups). A frame that
/// one group reaches (a range of one group, 2 native spp) is folded by sample index instead, and
/// loses the count noise too: also at least 4x lower.
#[test]
fn control_variate_removes_the_count_noise() {
    let device = Device::new().unwrap();
    let scene = Scene::load("vase", &device).unwrap();
    let integ = Integrator::new(&scene, 8);
    let pool = thread_pool(0).unwrap();
    let (w, h, target) = (64, 48, 36);
    let k = 24;
    let renders = |method: Method, spp: u32, (a, b): (u32, u32)| -> Vec<Vec<Vec3>> {
        (0..k)
            .map(|s| {
                let opts = RenderOptions {
                    method,
                    window: 9,
                    spp,
                    seed: 900 + s,
                    progress: false,
                    ..RenderOptions::default()
                };
                pool.install(|| {
                    reuse_render(&integ, &opts, a, b, w, h)
                        .remove(&target)
                        .unwrap()
                        .pixels()
                })
            })
            .collect()
    };
    // The wall: rows 2-9, away from the borders' columns.
    let wall: Vec<usize> = (2..10)
        .flat_map(|y| (4..w as usize - 4).map(move |x| y * w as usize + x))
        .collect();
    let variance = |r: &[Vec<Vec3>]| -> f64 {
        let lum = |p: Vec3| (0.2126 * p.x + 0.7152 * p.y + 0.0722 * p.z) as f64;
        wall.iter()
            .map(|&i| {
                let v: Vec<f64> = r.iter().map(|px| lum(px[i])).collect();
                let m = v.iter().sum::<f64>() / v.len() as f64;
                v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (v.len() - 1) as f64
            })
            .sum::<f64>()
            / wall.len() as f64
    };
    // Frame 36 in all 9 groups of frames 28-44 (group folds), and in the one group of frames
    // 32-40 (sample folds).
    for (spp, range, what, ratio) in [
        // 3.3x measured: mis-exact's native samples of a frame are stratified across its groups
        // (5.5x when they were a stream per group, which stratified nothing at 1 spp).
        (1, (target - 8, target + 8), "9 groups", 2.5),
        // Here mis-exact's two samples of a pixel are one stratified stream, while mis-cv's two
        // folds must be independent samplings (a stream each): 3.7x measured (5.2x when every
        // sample was independent).
        (2, (target - 4, target + 4), "one group", 3.0),
    ] {
        let exact = variance(&renders(Method::MisExact, spp, range));
        let cv = variance(&renders(Method::MisCv, spp, range));
        eprintln!(
            "back wall, frame {target} in {what}: per-pixel variance mis-exact {exact:.3e}, \
             mis-cv {cv:.3e}, ratio {:.2}",
            exact / cv
        );
        assert!(
            exact > ratio * cv,
            "{what}: mis-cv's variance {cv:.3e} is not {ratio}x below mis-exact's {exact:.3e}"
        );
    }
}

/// A scene that sees out into empty space (a floor and a low wall under an open sky, lit by one
/// area light): pixels along the wall's top edge are partly background, where the weights that
/// land sum to less than one unless escaped camera rays are weighed as points at infinity. The
/// camera trucks sideways, so every eye sees the edge elsewhere. `mis-cv` must match an
/// independent reference there block by block (and `mis-exact` too); fully background pixels
/// are exactly zero.
#[test]
fn control_variate_is_unbiased_where_pixels_see_the_background() {
    let device = Device::new().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scene = scene_in(
        d,
        "open",
        [
        "mtllib open.mtl\n\
         v -3 0 -4\nv 3 0 -4\nv 3 0 2\nv -3 0 2\n\
         v -3 0 -3\nv 3 0 -3\nv 3 1.2 -3\nv -3 1.2 -3\n\
         v -0.5 0 -1.5\nv 0.5 0 -1.5\nv 0.5 0.6 -1.5\nv -0.5 0.6 -1.5\n\
         v -0.4 2.5 -1.4\nv 0.4 2.5 -1.4\nv 0.4 2.5 -0.6\nv -0.4 2.5 -0.6\n\
         usemtl floor\nf 1 4 3 2\nusemtl wall\nf 5 6 7 8\nusemtl box\nf 9 10 11 12\n\
         usemtl light\nf 13 14 15 16\n",
        "newmtl floor\nKd 0.6 0.6 0.6\nnewmtl wall\nKd 0.7 0.5 0.3\n\
         newmtl box\nKd 0.2 0.3 0.6\nKs 0.3 0.3 0.3\nNs 40\n\
         newmtl light\nKd 0 0 0\nKe 12 12 12\n",
        "obj = \"open.obj\"\nframes = 9\nresolution = [48, 36]\n\
         [[keyframe]]\nframe = 0\nposition = [-0.6, 1.0, 2.5]\nlook_at = [-0.3, 0.9, -2.0]\nup = [0.0, 1.0, 0.0]\nfov = 50.0\n\
         [[keyframe]]\nframe = 8\nposition = [0.6, 1.1, 2.2]\nlook_at = [0.3, 0.9, -2.0]\nup = [0.0, 1.0, 0.0]\nfov = 44.0\n",
        ],
        &device,
    );
    let integ = Integrator::new(&scene, 8);
    let pool = thread_pool(0).unwrap();
    let (w, h, b, target) = (48usize, 36usize, 4, 4);
    let k = 96;
    let reference: Vec<Vec<Vec3>> = (0..k)
        .map(|s| {
            pool.install(|| {
                let cam = scene.camera(target, w as u32, h as u32);
                render_frame_independent(&integ, &cam, target, 16, 3000 + s, false, &|_| {}).pixels
            })
        })
        .collect();
    // The scene really has background and edge pixels: some are exactly black in every pass.
    let black = (0..w * h)
        .filter(|&i| reference.iter().all(|r| r[i] == Vec3::ZERO))
        .count();
    assert!(
        black > w * h / 10 && black < w * h / 2,
        "{black} background pixels of {}",
        w * h
    );
    let reference = block_moments(&reference, w, h, b);
    for method in [Method::MisCv, Method::MisExact] {
        let renders: Vec<Vec<Vec3>> = (0..k)
            .map(|s| {
                let opts = RenderOptions {
                    method,
                    window: 5,
                    spp: 1,
                    seed: 4000 + s,
                    progress: false,
                    ..RenderOptions::default()
                };
                pool.install(|| {
                    reuse_render(&integ, &opts, 0, 8, w as u32, h as u32)
                        .remove(&target)
                        .unwrap()
                        .pixels()
                })
            })
            .collect();
        let z = z_test(&block_moments(&renders, w, h, b), &reference);
        assert_unbiased(&format!("{method:?} where pixels see the background"), &z);
    }
}

/// Region means of luminance over a `g` x `g` grid (and the whole frame, last) of each render.
fn region_means(renders: &[Vec<Vec3>], w: usize, h: usize, g: usize) -> Vec<Vec<f64>> {
    renders
        .iter()
        .map(|r| {
            let mut sums = vec![0.0f64; g * g + 1];
            let mut counts = vec![0usize; g * g + 1];
            for y in 0..h {
                for x in 0..w {
                    let p = r[y * w + x];
                    let l = (0.2126 * p.x + 0.7152 * p.y + 0.0722 * p.z) as f64;
                    let k = (y * g / h) * g + x * g / w;
                    sums[k] += l;
                    counts[k] += 1;
                    sums[g * g] += l;
                    counts[g * g] += 1;
                }
            }
            sums.iter()
                .zip(&counts)
                .map(|(s, &c)| s / c as f64)
                .collect()
        })
        .collect()
}

/// Welch's z of the difference of two sets' means, region by region.
fn region_z(a: &[Vec<f64>], b: &[Vec<f64>]) -> Vec<(f64, f64)> {
    let moments = |v: &[Vec<f64>], i: usize| {
        let n = v.len() as f64;
        let m = v.iter().map(|r| r[i]).sum::<f64>() / n;
        let var = v.iter().map(|r| (r[i] - m).powi(2)).sum::<f64>() / (n - 1.0);
        (m, var / n)
    };
    (0..a[0].len())
        .map(|i| {
            let ((ma, va), (mb, vb)) = (moments(a, i), moments(b, i));
            (ma / mb, (ma - mb) / (va + vb).sqrt().max(1e-12))
        })
        .collect()
}

/// `mis-cv` at the first and last frames of a run, each reached by one group, which folds its
/// splats by the sample index: every eye's samples of that group must come in two independent
/// streams. The other eyes' native samples used to be one stratified stream (the frames are
/// in other groups too), whose consecutive samples are dependent (a stratified pair), so the
/// two folds were dependent and the cross-fitted coefficients biased: on glossy surfaces at
/// 2 spp, frames several percent dark. Region means (a 3 x 3 grid and the whole frame) of many
/// renders of the last and the first frame, against the independent tracer's.
#[test]
fn control_variate_is_unbiased_at_the_ends_of_a_run() {
    let device = Device::new().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let scene = scene_in(
        dir.path(),
        "gloss",
        [
            "mtllib gloss.mtl\n\
             v -3 0 -4\nv 3 0 -4\nv 3 0 2\nv -3 0 2\n\
             v -3 0 -3\nv 3 0 -3\nv 3 2.5 -3\nv -3 2.5 -3\n\
             v -0.6 0 -1.6\nv 0.6 0 -1.6\nv 0.6 0.9 -1.6\nv -0.6 0.9 -1.6\n\
             v -0.5 2.6 -1.5\nv 0.5 2.6 -1.5\nv 0.5 2.6 -0.5\nv -0.5 2.6 -0.5\n\
             usemtl floor\nf 1 4 3 2\nusemtl wall\nf 5 6 7 8\nusemtl box\nf 9 10 11 12\n\
             usemtl light\nf 13 14 15 16\n",
            "newmtl floor\nKd 0.2 0.2 0.2\nKs 0.6 0.6 0.6\nNs 300\n\
             newmtl wall\nKd 0.4 0.3 0.2\nKs 0.4 0.4 0.4\nNs 60\n\
             newmtl box\nKd 0.1 0.2 0.4\nKs 0.7 0.7 0.7\nNs 1000\n\
             newmtl light\nKd 0 0 0\nKe 10 10 10\n",
            "obj = \"gloss.obj\"\nframes = 5\nresolution = [48, 36]\n\
             [environment]\nradiance = [0.3, 0.35, 0.4]\n\
             [[keyframe]]\nframe = 0\nposition = [-1.2, 1.2, 2.2]\nlook_at = [-0.2, 0.6, -2.0]\nup = [0.0, 1.0, 0.0]\nfov = 55.0\n\
             [[keyframe]]\nframe = 4\nposition = [1.0, 0.9, 1.8]\nlook_at = [0.3, 0.5, -2.0]\nup = [0.0, 1.0, 0.0]\nfov = 40.0\n",
        ],
        &device,
    );
    let integ = Integrator::new(&scene, 6);
    let pool = thread_pool(0).unwrap();
    let (w, h, g) = (48usize, 36usize, 3);
    let k = 96;
    for target in [4, 0] {
        let reference: Vec<Vec<Vec3>> = (0..k)
            .map(|s| {
                pool.install(|| {
                    let cam = scene.camera(target, w as u32, h as u32);
                    render_frame_independent(&integ, &cam, target, 16, 7000 + s, false, &|_| {})
                        .pixels
                })
            })
            .collect();
        let renders: Vec<Vec<Vec3>> = (0..k)
            .map(|s| {
                let opts = RenderOptions {
                    method: Method::MisCv,
                    window: 3,
                    spp: 2,
                    seed: 8000 + s,
                    progress: false,
                    ..RenderOptions::default()
                };
                pool.install(|| {
                    reuse_render(&integ, &opts, 0, 4, w as u32, h as u32)
                        .remove(&target)
                        .unwrap()
                        .pixels()
                })
            })
            .collect();
        let z = region_z(
            &region_means(&renders, w, h, g),
            &region_means(&reference, w, h, g),
        );
        eprintln!("mis-cv frame {target} of 0-4, window 3, 2 spp: (ratio, z) by region, whole last: {z:.3?}");
        assert!(
            z.iter().all(|(_, z)| z.abs() < 4.5),
            "mis-cv is biased at frame {target}, the {} of the run: {z:.3?}",
            if target == 0 { "first" } else { "last" }
        );
    }
}

/// The reuse films sum in fixed point, in a unit that follows the scene's brightness
/// (`reuse::radiance_unit`), so that a scene lit a billion times more dimly renders the same
/// frames, scaled: bit for bit between two dim scenes a power of two apart, and within the
/// rounding of the sums of the bright one. With a fixed unit (steps of 2^-20 of radiance) a dim
/// scene's splats were as small as a step: still unbiased, but 623 of 768 pixels of `cornell`
/// at Ke 1.6e-5 came out black, and its error was nine times the bright scene's. Chunks and
/// their merge find the same unit, so they give one process's frames.
#[test]
fn a_dim_scene_renders_as_a_bright_one_scaled() {
    let device = Device::new().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let src = |ext: &str| {
        std::fs::read_to_string(format!(
            "{}/scenes/cornell.{ext}",
            env!("CARGO_MANIFEST_DIR")
        ))
        .unwrap()
    };
    let (obj, mtl, toml) = (src("obj"), src("mtl"), src("toml"));
    // The light's Ke 16 times 2^-k: exact in decimal and in single precision.
    let scene = |k: i32| {
        let d = dir.path().join(format!("k{k}"));
        std::fs::create_dir(&d).unwrap();
        let ke = 16f64 * 2f64.powi(-k);
        let mtl = mtl.replace("Ke 16 16 16", &format!("Ke {ke:e} {ke:e} {ke:e}"));
        assert_ne!(mtl, src("mtl"));
        scene_in(&d, "cornell", [&obj, &mtl, &toml], &device)
    };
    let scenes = [scene(0), scene(30), scene(40)];
    let pool = thread_pool(2).unwrap();
    for method in [Method::MisExact, Method::MisCv, Method::Havran] {
        let [bright, dim, dimmer] = scenes.each_ref().map(|s| {
            let integ = Integrator::new(s, 16);
            pool.install(|| reuse_frames(&integ, method, 3, 4, 7, 0, 2, 48, 36))
        });
        for f in 0..=2 {
            let (a, b, c) = (&bright[&f], &dim[&f], &dimmer[&f]);
            // Bit for bit: the dimmer scene's frame is the dim one's times 2^-10.
            assert!(
                b.iter().zip(c).all(|(b, c)| *c * 1024.0 == *b),
                "{method:?} frame {f}: not the dim frame scaled"
            );
            let mean = a.iter().map(|v| v.element_sum() as f64).sum::<f64>() / a.len() as f64;
            let err = a
                .iter()
                .zip(b)
                .map(|(a, b)| (*a - *b * 2f32.powi(30)).abs().element_sum() as f64)
                .sum::<f64>()
                / a.len() as f64;
            assert!(
                mean > 0.1 && err < 1e-3 * mean,
                "{method:?} frame {f}: the dim frame (x 2^30) is {err} from the bright one, \
                 whose mean is {mean}"
            );
        }
    }
    // A night whose first frame (the pilot's) sees a sky of 1e-5, and whose later frames look
    // down at a lamp of 1e9: the unit is kept large enough for the lamp's pixels, which came
    // out 7.5 times too dark (their sums clipped at 2^43 units of 2^-16).
    let night = dir.path().join("night");
    std::fs::create_dir(&night).unwrap();
    let obj = "mtllib night.mtl\nusemtl ground\nv -50 0 -50\nv 50 0 -50\nv 50 0 50\nv -50 0 50\n\
               f 4 3 2 1\nusemtl lamp\nv -10.3 3 -10.3\nv -9.7 3 -10.3\nv -9.7 3 -9.7\n\
               v -10.3 3 -9.7\nf 8 7 6 5\n";
    let mtl = "newmtl ground\nKd 0.5 0.5 0.5\nnewmtl lamp\nKd 0 0 0\nKe 1e9 1e9 1e9\n";
    let key = |f: u32, p: &str, l: &str| {
        format!(
            "[[keyframe]]\nframe = {f}\nposition = {p}\nlook_at = {l}\nup = [0.0, 0.0, -1.0]\n\
             fov = 30.0\n"
        )
    };
    let toml = format!(
        "obj = \"night.obj\"\nframes = 5\nresolution = [24, 24]\n[environment]\n\
         radiance = [1e-5, 1e-5, 1e-5]\n{}{}{}",
        key(0, "[0.0, 3.0, 0.0]", "[0.0, 0.0, -0.5]"),
        key(1, "[-10.0, 13.0, -10.0]", "[-10.0, 3.0, -10.0]"),
        key(4, "[-10.0, 13.0, -10.0]", "[-10.0, 3.0, -10.0]")
    );
    let night = scene_in(&night, "night", [obj, mtl, &toml], &device);
    let integ = Integrator::new(&night, 4);
    let lamp = |px: &[Vec3]| {
        (10..14)
            .flat_map(|y| (10..14).map(move |x| px[y * 24 + x].x as f64))
            .sum::<f64>()
            / 16.0
    };
    let independent =
        pool.install(|| reuse_frames(&integ, Method::Independent, 1, 4, 3, 0, 4, 24, 24));
    for method in [Method::MisExact, Method::MisCv] {
        let reused = pool.install(|| reuse_frames(&integ, method, 3, 4, 3, 0, 4, 24, 24));
        for f in 1..=4 {
            let (a, b) = (lamp(&independent[&f]), lamp(&reused[&f]));
            assert!(
                a > 1e8 && (b / a - 1.0).abs() < 0.1,
                "{method:?} frame {f}: the lamp's pixels are {b}, the independent tracer's {a}"
            );
        }
    }
    // Two chunks and their merge: one process's frames, on the dim scene.
    let at = |s: &str| dir.path().join(s).to_str().unwrap().to_string();
    let args = |out: &str| {
        [
            "render",
            &at("k30/cornell.toml"),
            "--method",
            "mis-cv",
            "--window",
            "3",
            "--spp",
            "2",
            "--res",
            "32x24",
            "--frames",
            "0-4",
            "--exr-float",
            "--out",
            out,
        ]
        .map(str::to_string)
    };
    common::reframe_ok(&args(&at("one/f_####.exr")));
    for k in ["1/2", "2/2"] {
        let mut a = args(&at("two/f_####.exr")).to_vec();
        a.extend(["--chunk".into(), k.into()]);
        common::reframe_ok(&a);
    }
    common::reframe_ok(&["merge", "--chunks", "2", "--out", &at("two/f_####.exr")]);
    common::assert_identical(
        &dir.path().join("one"),
        &dir.path().join("two"),
        (0..=4).map(|f| format!("f_{f:04}.exr")),
    );
}
