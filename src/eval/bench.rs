//! `reframe bench`: the costs of the paper's model (eq. 16), measured on a scene, the speed-up it
//! predicts against the one measured, and the renderer's ray rate against bare Embree calls.
//!
//! Every cost is CPU time of one core per item: the wall time of a pass over a whole frame on the
//! worker pool, times the number of workers, over the number of items.
//! - `c_e`: one eye ray: the camera sample, `rtcIntersect1`, the surface record at the hit.
//! - `c_l`: the illumination at the hit, the rest of a path-traced sample (light sample and shadow
//!   ray, BSDF sample, the walk from the second vertex on): the independent tracer's time per
//!   sample minus `c_e`.
//! - `c_v_single`, `c_v_packet`: one reuse visibility test (projection into the eye, the ray from
//!   the eye to the hit), through `rtcOccluded1` or 16-wide coherent `rtcOccluded16` packets, on
//!   the middle frame's primary hits towards the eyes of the frames up to 4 away.
//! - `c_e` and the two `c_v` are each the median of 5 passes (single rays and packets
//!   alternating): one pass takes tens of milliseconds and alone moved by up to 2x between runs.
//!   The independent render behind `c_l` and the ray rate, the bare replay and each speed-up
//!   run (reuse and independent alternating) are the median of `--repeats` runs (3): single
//!   runs of one build moved by 10-50% on a shared machine.
//!
//! The speed-up (eq. 16, `n_f (c_e + c_l) / ((c_e + c_l) + (n_f - 1) c_v)`) is measured the way
//! the paper derives it: one group of `n_f` frames around the middle of the animation rendered
//! with a reuse method (`mis-exact` unless `--method` says otherwise) at `n_r` native samples, against the independent tracer on the same frames at
//! `n_f n_r` samples per pixel (the same number of samples per pixel, were no reuse lost). The
//! measured time of a reuse run also pays for what the model leaves out (projecting into every
//! eye, the Jacobians and BRDFs of the weights, the splats), reported per reuse as `c_reuse`.
//!
//! The ray rate: the frame is rendered twice with the same seed, once timed and once logging every
//! ray it traces; the log is replayed through `rtcIntersect1`/`rtcOccluded1` alone on the same
//! tiles and threads, so the bare rate is measured on exactly the rays the renderer traced.
//!
//! ```no_run
//! use reframe::{embree::Device, eval::bench, scene::Scene};
//! let device = Device::new()?;
//! let opts = bench::BenchOptions { windows: vec![3, 7], ..Default::default() };
//! let report = bench::run(&Scene::load("vase", &device)?, &opts)?;
//! println!("{}", report.table());
//! # anyhow::Ok(())
//! ```
use crate::camera::Camera;
use crate::driver::options::{check_max_depth, check_resolution, check_reuse_film, check_spp};
use crate::driver::{
    render_frame_independent, render_frames, thread_pool, FrameResult, RenderOptions,
};
use crate::embree::Ray;
use crate::film::tiles::tiles;
use crate::integrator::{Integrator, RayCounts, Rays, Tally};
use crate::reuse::visibility::{landings, HitLanes, Landing, NativeHit};
use crate::reuse::Method;
use crate::sampling::Sampler;
use crate::scene::Scene;
use anyhow::{bail, Context, Result};
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::time::Instant;

/// What to measure.
#[derive(Clone, Debug)]
pub struct BenchOptions {
    /// Samples per pixel of the cost and ray-rate passes.
    pub spp: u32,
    /// Resolution override; `None` keeps the scene's.
    pub res: Option<(u32, u32)>,
    /// Frame of the cost and ray-rate passes; `None` = the middle one.
    pub frame: Option<u32>,
    /// Worker threads; 0 = one per core.
    pub threads: usize,
    /// Native samples per pixel `n_r` of the speed-up runs.
    pub speedup_spp: u32,
    /// The reuse method of the speed-up runs.
    pub speedup_method: Method,
    /// Group sizes `n_f` of the speed-up runs (odd, at most the scene's frames: others are refused).
    pub windows: Vec<u32>,
    pub seed: u64,
    /// Longest path, in bounces.
    pub max_depth: u32,
    /// Timed runs of each kind whose median is reported: the independent render of `c_l` and
    /// the ratio, the bare replay, and each speed-up run's reuse and independent renders
    /// (alternating).
    pub repeats: usize,
}

/// The group sizes `bench` measures when `--windows` is not given.
pub const DEFAULT_WINDOWS: [u32; 4] = [3, 7, 17, 33];

impl Default for BenchOptions {
    fn default() -> Self {
        BenchOptions {
            spp: 4,
            res: None,
            frame: None,
            threads: 0,
            speedup_spp: 1,
            speedup_method: Method::MisExact,
            windows: DEFAULT_WINDOWS.to_vec(),
            seed: 1,
            max_depth: crate::driver::options::DEFAULT_MAX_DEPTH,
            repeats: 3,
        }
    }
}

/// One speed-up measurement: a group of `window` frames.
#[derive(Clone, Debug, Serialize)]
pub struct SpeedupRun {
    pub window: u32,
    pub first_frame: u32,
    pub last_frame: u32,
    /// The independent tracer on the group's frames at `window * speedup_spp` samples per pixel
    /// (the median of `independent_seconds_all`).
    pub independent_seconds: f64,
    /// The reuse method over the group at `speedup_spp` native samples per pixel (the median of
    /// `reuse_seconds_all`).
    pub reuse_seconds: f64,
    /// Every timed run (`--repeats`), reuse and independent alternating.
    pub independent_seconds_all: Vec<f64>,
    pub reuse_seconds_all: Vec<f64>,
    pub visibility_tests: u64,
    pub lost_reuse_fraction: f64,
}

/// What `reframe bench --json` writes (keys are a contract with users' scripts: add, never
/// rename). Costs are nanoseconds of one core; speed-up maps are keyed by `n_f`.
#[derive(Debug, Serialize)]
pub struct BenchReport {
    pub scene: String,
    pub width: u32,
    pub height: u32,
    pub frame: u32,
    pub spp: u32,
    pub threads: usize,
    pub cost_unit: &'static str,
    pub c_e: f64,
    pub c_l: f64,
    pub c_v_single: f64,
    pub c_v_packet: f64,
    /// Eq. 16 with `c_v_packet` (the default visibility mode).
    pub predicted_speedup: BTreeMap<String, f64>,
    /// Independent time over reuse time at the same samples per pixel.
    pub measured_speedup: BTreeMap<String, f64>,
    /// Per reuse, everything a reuse costs (visibility test, weights, splat), from the measured
    /// reuse time: `(t_reuse / native samples - (c_e + c_l)) / (n_f - 1)`.
    pub c_reuse: BTreeMap<String, f64>,
    /// Share of the reuse run's time spent in visibility tests (`tests * c_v_packet / time`).
    pub visibility_share: BTreeMap<String, f64>,
    pub speedup_spp: u32,
    pub speedup_method: Method,
    pub speedup_runs: Vec<SpeedupRun>,
    /// The timed independent render of `c_l` and `ratio`: the median of `--repeats` runs.
    pub render_seconds: f64,
    pub rays: RayCounts,
    pub render_rays_per_second: f64,
    /// The replay through bare Embree calls: the median of `--repeats` runs.
    pub bare_seconds: f64,
    pub bare_rays_per_second: f64,
    /// Timed runs of each kind whose median is reported.
    pub repeats: usize,
    /// Renderer rate over bare Embree rate.
    pub ratio: f64,
    /// The independent tracer on the same frame with its primary rays in 16-wide packets and one
    /// at a time (`integrator::Rays`): the median of 3 alternating runs each, seconds. Both with
    /// the wavefront's rays in packets.
    pub primary_packet_seconds: f64,
    pub primary_single_seconds: f64,
    /// The same with the wavefront's shadow and continuation rays one at a time (`--paths
    /// single`; primary rays in packets), alternating with the two above; the packet figure is
    /// `primary_packet_seconds`.
    pub paths_single_seconds: f64,
}

/// Eq. 16: the speed-up of reusing `n_f` frames over independent rendering at the same number of
/// samples per pixel.
pub fn predicted_speedup(n_f: u32, c_e: f64, c_l: f64, c_v: f64) -> f64 {
    let n = n_f as f64;
    n * (c_e + c_l) / ((c_e + c_l) + (n - 1.0) * c_v)
}

impl BenchReport {
    pub fn table(&self) -> String {
        let mut t = String::new();
        let total = self.rays.primary + self.rays.path + self.rays.shadow;
        let _ = writeln!(
            t,
            "scene {} {}x{} frame {} spp {} threads {}",
            crate::util::text::printable(&self.scene),
            self.width,
            self.height,
            self.frame,
            self.spp,
            self.threads
        );
        let _ = writeln!(t, "costs, ns of one core:");
        let _ = writeln!(t, "  c_e  eye ray                 {:>9.1}", self.c_e);
        let _ = writeln!(t, "  c_l  illumination at the hit {:>9.1}", self.c_l);
        let _ = writeln!(t, "  c_v  visibility, single ray  {:>9.1}", self.c_v_single);
        let _ = writeln!(t, "  c_v  visibility, packet      {:>9.1}", self.c_v_packet);
        let _ = writeln!(
            t,
            "speed-up at equal samples per pixel ({} native spp, {}):",
            self.speedup_spp,
            self.speedup_method.name()
        );
        let _ = writeln!(
            t,
            "  {:>4} {:>10} {:>10} {:>8} {:>10} {:>10} {:>7}",
            "n_f", "predicted", "measured", "c_reuse", "indep. s", "reuse s", "vis."
        );
        for r in &self.speedup_runs {
            let k = r.window.to_string();
            let _ = writeln!(
                t,
                "  {:>4} {:>10.2} {:>10.2} {:>8.1} {:>10.2} {:>10.2} {:>6.1}%",
                r.window,
                self.predicted_speedup[&k],
                self.measured_speedup[&k],
                self.c_reuse[&k],
                r.independent_seconds,
                r.reuse_seconds,
                100.0 * self.visibility_share[&k]
            );
        }
        let _ = writeln!(
            t,
            "rays: {} primary, {} path, {} shadow ({} total)",
            self.rays.primary, self.rays.path, self.rays.shadow, total
        );
        let _ = writeln!(
            t,
            "  {:<28}{:>10.3} s {:>10.2} Mrays/s",
            "independent path tracer",
            self.render_seconds,
            self.render_rays_per_second / 1e6
        );
        let _ = writeln!(
            t,
            "  {:<28}{:>10.3} s {:>10.2} Mrays/s",
            "bare rtcIntersect1/Occluded1",
            self.bare_seconds,
            self.bare_rays_per_second / 1e6
        );
        let _ = writeln!(t, "renderer / bare Embree: {:.1}%", self.ratio * 100.0);
        let _ = writeln!(
            t,
            "primary rays in packets / single: {:.3} s / {:.3} s ({:.2}x)",
            self.primary_packet_seconds,
            self.primary_single_seconds,
            self.primary_single_seconds / self.primary_packet_seconds
        );
        let _ = write!(
            t,
            "path rays in packets / single:    {:.3} s / {:.3} s ({:.2}x)",
            self.primary_packet_seconds,
            self.paths_single_seconds,
            self.paths_single_seconds / self.primary_packet_seconds
        );
        // Runs this short are mostly the fixed costs of a render (threads, films), and the
        // ratios above read them, not the tracer.
        let shortest = self
            .speedup_runs
            .iter()
            .flat_map(|r| [r.independent_seconds, r.reuse_seconds])
            .chain([self.render_seconds, self.bare_seconds])
            .fold(f64::INFINITY, f64::min);
        if shortest < SHORT_RUN_SECONDS {
            let _ = write!(
                t,
                "\nnote: a timed run took {shortest:.3} s, under {SHORT_RUN_SECONDS} s: too short \
                 for these figures to mean much; give a larger --res or --spp"
            );
        }
        t
    }
}

/// A timed run shorter than this is said to be (`BenchReport::table`).
pub(super) const SHORT_RUN_SECONDS: f64 = 0.05;

/// The cost model's terms, nanoseconds of one core per item.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Costs {
    pub c_e: f64,
    pub c_l: f64,
    pub c_v_single: f64,
    pub c_v_packet: f64,
}

/// Measure `c_e`, `c_l` and `c_v` on frame `frame` seen by `cam` (see the module note). Also
/// returns the timed independent render and its wall time.
pub fn measure_costs(
    integrator: &Integrator,
    pool: &rayon::ThreadPool,
    cam: &Camera,
    frame: u32,
    spp: u32,
    seed: u64,
    repeats: usize,
) -> (Costs, FrameResult, f64) {
    let scene = integrator.scene;
    let threads = pool.current_num_threads();
    let (w, h) = (cam.width, cam.height);
    let none = |_: &RayCounts| {};
    let samples = (w * h * spp) as u64;
    // Warm caches and the allocator, then time the independent tracer: c_e + c_l, the median
    // of `repeats` runs.
    pool.install(|| render_frame_independent(integrator, cam, frame, 1, seed, false, &none));
    let mut timed = None;
    let render_seconds = median((0..repeats.max(1)).map(|_| {
        let t0 = Instant::now();
        let r = pool
            .install(|| render_frame_independent(integrator, cam, frame, spp, seed, false, &none));
        let seconds = t0.elapsed().as_secs_f64();
        timed.get_or_insert(r);
        seconds
    }));
    let timed = timed.expect("at least one timed run");
    let c_el = per_core_ns(render_seconds, threads, samples);

    // c_e: the same camera samples, the eye ray and its surface record only. This pass and the
    // visibility passes below take tens of milliseconds each, where one pass alone moved by up
    // to 2x between runs: each is the median of `REPEATS` passes.
    let c_e = median((0..REPEATS).map(|_| {
        let t0 = Instant::now();
        let found: u64 = pool.install(|| eye_rays(scene, cam, frame, spp, seed));
        std::hint::black_box(found);
        per_core_ns(t0.elapsed().as_secs_f64(), threads, samples)
    }));

    // c_v: the frame's primary hits (one per pixel) tested against the eyes up to 4 frames away.
    let hits: Vec<Vec<NativeHit>> = pool.install(|| first_hits(integrator, cam, frame, seed));
    let eyes: Vec<Camera> = (frame.saturating_sub(4)..=(frame + 4).min(scene.frames - 1))
        .filter(|&f| f != frame)
        .map(|f| scene.camera(f, w, h))
        .collect();
    // Single rays and packets alternate, so that load on the machine hits both alike.
    let mut c_v: [Vec<f64>; 2] = Default::default();
    for _ in 0..REPEATS {
        for (slot, packets) in [false, true].into_iter().enumerate() {
            let t0 = Instant::now();
            let tests: u64 = pool.install(|| visibility_pass(integrator, &hits, &eyes, packets));
            c_v[slot].push(per_core_ns(t0.elapsed().as_secs_f64(), threads, tests));
        }
    }
    let [c_v_single, c_v_packet] = c_v.map(|t| median(t.into_iter()));
    let costs = Costs {
        c_e,
        c_l: c_el - c_e,
        c_v_single,
        c_v_packet,
    };
    (costs, timed, render_seconds)
}

/// Passes of `c_e` and of each `c_v` whose median is reported.
const REPEATS: usize = 5;

/// The median of `xs` (the upper one of an even count).
fn median(xs: impl Iterator<Item = f64>) -> f64 {
    let mut v: Vec<f64> = xs.collect();
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Nanoseconds of one core per item, from the wall time of a pass on `threads` workers.
fn per_core_ns(seconds: f64, threads: usize, items: u64) -> f64 {
    seconds * threads as f64 / items.max(1) as f64 * 1e9
}

/// The most timed runs of each kind `--repeats` may ask for (a median of 101 is already far
/// steadier than this machine's noise; more is a typo, and each run can take seconds).
pub const MAX_REPEATS: usize = 101;

/// The group of `n_f` frames a speed-up run renders: centred on `frame`, within the scene.
fn window_frames(scene: &Scene, frame: u32, n_f: u32) -> std::ops::RangeInclusive<u32> {
    let first = (frame.saturating_sub(n_f / 2)).min(scene.frames - n_f);
    first..=first + n_f - 1
}

/// The render of the speed-up run of `n_f` frames around `frame`.
fn speedup_options(
    scene: &Scene,
    opts: &BenchOptions,
    frame: u32,
    res: (u32, u32),
    n_f: u32,
) -> RenderOptions {
    RenderOptions {
        method: opts.speedup_method,
        spp: opts.speedup_spp,
        window: n_f,
        seed: opts.seed,
        frames: Some(window_frames(scene, frame, n_f)),
        resolution: Some(res),
        max_depth: opts.max_depth,
        threads: opts.threads,
        progress: false,
        ..RenderOptions::default()
    }
}

pub fn run(scene: &Scene, opts: &BenchOptions) -> Result<BenchReport> {
    let (w, h) = opts.res.unwrap_or((scene.width, scene.height));
    check_resolution((w, h))?;
    let frame = opts.frame.unwrap_or(scene.frames / 2);
    if frame >= scene.frames {
        bail!(
            "--frame {frame}: the scene has frames 0-{}",
            scene.frames - 1
        );
    }
    if !opts.speedup_method.reuses() {
        bail!("--method independent: the speed-up runs need a reuse method");
    }
    if opts.repeats == 0 {
        bail!("--repeats 0: at least one timed run of each kind is needed");
    }
    if opts.repeats > MAX_REPEATS {
        bail!(
            "--repeats {}: at most {MAX_REPEATS} timed runs of each kind",
            opts.repeats
        );
    }
    check_spp("--spp", opts.spp)?;
    check_spp("--speedup-spp", opts.speedup_spp)?;
    if let Some(&n) = opts.windows.iter().find(|&&n| n < 3 || n % 2 == 0) {
        bail!("--windows {n}: a reuse group is an odd number of frames, at least 3");
    }
    if let Some(n) = super::first_repeat(&opts.windows) {
        bail!("--windows {n}: given twice (each window is measured once; the JSON keys its figures by n_f)");
    }
    if let Some(&n) = opts.windows.iter().find(|&&n| n > scene.frames) {
        // The windows measured when none are given: said where they are those.
        let default = if opts.windows == DEFAULT_WINDOWS {
            let list: Vec<String> = DEFAULT_WINDOWS.iter().map(u32::to_string).collect();
            format!(
                " (--windows is {} when not given: give ones that fit)",
                list.join(",")
            )
        } else {
            String::new()
        };
        bail!(
            "--windows {n}: a group of {n} frames does not fit the scene's {} frames{default}",
            scene.frames
        );
    }
    check_max_depth(opts.max_depth)?;
    // The speed-up runs (`window_frames`), each checked as its render will check it (the
    // reuse film, samples per group, memory) before anything is timed: a run refused after the
    // cost passes had taken seconds, naming the render's `--spp` and `--window`.
    for &n_f in &opts.windows {
        check_reuse_film(
            scene,
            &window_frames(scene, frame, n_f),
            (w, h),
            opts.speedup_method.name(),
        )?;
        speedup_options(scene, opts, frame, (w, h), n_f)
            .check(scene)
            .with_context(|| {
                format!(
                    "--method {} at --speedup-spp {} and --windows {n_f}",
                    opts.speedup_method.name(),
                    opts.speedup_spp
                )
            })?;
    }
    let pool = thread_pool(opts.threads)?;
    let threads = pool.current_num_threads();
    let integrator = Integrator::new(scene, opts.max_depth);
    let cam = scene.camera(frame, w, h);
    let (spp, seed) = (opts.spp, opts.seed);
    let none = |_: &RayCounts| {};

    let (costs, timed, render_seconds) =
        measure_costs(&integrator, &pool, &cam, frame, spp, seed, opts.repeats);
    let Costs {
        c_e,
        c_l,
        c_v_single,
        c_v_packet,
    } = costs;
    let c_el = c_e + c_l;

    // The speed-up runs.
    let mut runs = Vec::new();
    let mut report_maps: [BTreeMap<String, f64>; 4] = Default::default();
    for &n_f in &opts.windows {
        let frames = window_frames(scene, frame, n_f);
        let (first, last) = (*frames.start(), *frames.end());
        let ropts = speedup_options(scene, opts, frame, (w, h), n_f);
        // The reuse run and the independent one alternate, so that load on the machine hits
        // both alike; the medians are reported.
        let (mut reuse_all, mut independent_all) = (Vec::new(), Vec::new());
        let mut stats = None;
        for _ in 0..opts.repeats {
            let t0 = Instant::now();
            let mut discard = |_: crate::film::Developed| Ok(());
            let s = pool.install(|| render_frames(&integrator, &ropts, &mut discard))?;
            reuse_all.push(t0.elapsed().as_secs_f64());
            stats.get_or_insert(s);
            let t0 = Instant::now();
            for f in first..=last {
                let cam = scene.camera(f, w, h);
                let spp = n_f * opts.speedup_spp;
                pool.install(|| {
                    render_frame_independent(&integrator, &cam, f, spp, seed, false, &none)
                });
            }
            independent_all.push(t0.elapsed().as_secs_f64());
        }
        let stats = stats.expect("at least one timed run");
        let reuse_seconds = median(reuse_all.iter().copied());
        let independent_seconds = median(independent_all.iter().copied());
        let native = (w * h * opts.speedup_spp * n_f) as u64;
        let per_native = per_core_ns(reuse_seconds, threads, native);
        let key = n_f.to_string();
        let [pred, meas, c_reuse, vis_share] = &mut report_maps;
        pred.insert(
            key.clone(),
            predicted_speedup(n_f, c_e, c_el - c_e, c_v_packet),
        );
        meas.insert(key.clone(), independent_seconds / reuse_seconds);
        c_reuse.insert(key.clone(), (per_native - c_el) / (n_f - 1) as f64);
        let vis_ns = stats.counts.visibility as f64 * c_v_packet;
        vis_share.insert(key, vis_ns / (reuse_seconds * threads as f64 * 1e9));
        runs.push(SpeedupRun {
            window: n_f,
            first_frame: first,
            last_frame: last,
            independent_seconds,
            reuse_seconds,
            independent_seconds_all: independent_all,
            reuse_seconds_all: reuse_all,
            visibility_tests: stats.counts.visibility,
            lost_reuse_fraction: stats.lost_reuse_fraction(),
        });
    }
    let [predicted_speedup, measured_speedup, c_reuse, visibility_share] = report_maps;

    // The ray rate against bare Embree on the same rays.
    let logged =
        pool.install(|| render_frame_independent(&integrator, &cam, frame, spp, seed, true, &none));
    debug_assert_eq!(logged.counts, timed.counts);
    let geometry = &scene.geometry;
    let bare_seconds = median((0..opts.repeats).map(|_| {
        let t1 = Instant::now();
        let hit_count: u64 = pool.install(|| {
            logged
                .ray_logs
                .par_iter()
                .map(|log| {
                    let mut hits = 0u64;
                    for (ray, occlusion) in log {
                        let hit = if *occlusion {
                            geometry.occluded1(ray)
                        } else {
                            geometry.intersect1(ray).is_some()
                        };
                        hits += hit as u64;
                    }
                    hits
                })
                .sum()
        });
        std::hint::black_box(hit_count);
        t1.elapsed().as_secs_f64()
    }));
    // Primary and path rays in packets against single rays, alternating so that load hits all
    // alike.
    let (mut packet_times, mut single_times, mut paths_single_times) =
        (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..3 {
        for (primary, paths, times) in [
            (Rays::Packet, Rays::Packet, &mut packet_times),
            (Rays::Single, Rays::Packet, &mut single_times),
            (Rays::Packet, Rays::Single, &mut paths_single_times),
        ] {
            let mut integ = Integrator::new(scene, opts.max_depth);
            integ.primary = primary;
            integ.paths = paths;
            let t0 = Instant::now();
            pool.install(|| render_frame_independent(&integ, &cam, frame, spp, seed, false, &none));
            times.push(t0.elapsed().as_secs_f64());
        }
    }
    let c = timed.counts;
    let render_rate = c.total() as f64 / render_seconds;
    let bare_rate = logged.ray_logs.iter().map(|l| l.len()).sum::<usize>() as f64 / bare_seconds;
    Ok(BenchReport {
        scene: scene.name.clone(),
        width: w,
        height: h,
        frame,
        spp,
        threads,
        cost_unit: "ns of one core per item",
        c_e,
        c_l,
        c_v_single,
        c_v_packet,
        predicted_speedup,
        measured_speedup,
        c_reuse,
        visibility_share,
        speedup_spp: opts.speedup_spp,
        speedup_method: opts.speedup_method,
        speedup_runs: runs,
        render_seconds,
        rays: c,
        render_rays_per_second: render_rate,
        bare_seconds,
        bare_rays_per_second: bare_rate,
        repeats: opts.repeats,
        ratio: render_rate / bare_rate,
        primary_packet_seconds: median(packet_times.into_iter()),
        primary_single_seconds: median(single_times.into_iter()),
        paths_single_seconds: median(paths_single_times.into_iter()),
    })
}

/// The eye rays of the independent tracer's samples, traced to their surface records only.
/// Returns how many hit (so that nothing is optimised away).
fn eye_rays(scene: &Scene, cam: &Camera, frame: u32, spp: u32, seed: u64) -> u64 {
    tiles(cam.width, cam.height)
        .par_iter()
        .map(|&(x0, y0, x1, y1)| {
            let mut found = 0u64;
            for y in y0..y1 {
                for x in x0..x1 {
                    let pixel = y * cam.width + x;
                    for s in 0..spp {
                        let mut sampler = Sampler::stratified(seed, frame, pixel, 0, s);
                        let r = Vec2::new(x as f32, y as f32) + sampler.next_2d();
                        let ray = Ray::new(cam.eye, cam.direction(r));
                        if let Some(hit) = scene.geometry.intersect1(&ray) {
                            let sp = scene.surface(&hit);
                            found += (sp.p != Vec3::ZERO) as u64;
                        }
                    }
                }
            }
            found
        })
        .sum()
}

/// One primary hit per pixel, per tile, as the reuse methods record them.
fn first_hits(integrator: &Integrator, cam: &Camera, frame: u32, seed: u64) -> Vec<Vec<NativeHit>> {
    tiles(cam.width, cam.height)
        .par_iter()
        .map(|&(x0, y0, x1, y1)| {
            let mut t = Tally::default();
            let mut hits = Vec::new();
            for y in y0..y1 {
                for x in x0..x1 {
                    let pixel = y * cam.width + x;
                    let mut sampler = Sampler::stratified(seed, frame, pixel, 0, 0);
                    let r = Vec2::new(x as f32, y as f32) + sampler.next_2d();
                    let dir = cam.direction(r);
                    if let Some(fh) = integrator.trace_first_hit(cam.eye, dir, &mut sampler, &mut t)
                    {
                        hits.push((pixel, 0, fh));
                    }
                }
            }
            hits
        })
        .collect()
}

/// Every tile's hits tested against every eye; returns the number of tests traced.
fn visibility_pass(
    integrator: &Integrator,
    hits: &[Vec<NativeHit>],
    eyes: &[Camera],
    packets: bool,
) -> u64 {
    hits.par_iter()
        .map(|tile| {
            let mut t = Tally::default();
            let mut land: Vec<Landing> = vec![None; tile.len()];
            let mut lanes = HitLanes::default();
            lanes.fill(tile);
            for eye in eyes {
                let view = (eye, eye.pixel_area());
                let k = (0, 1);
                landings(
                    integrator, view, &lanes, k, false, packets, &mut land, None, &mut t,
                );
            }
            std::hint::black_box(&land);
            t.counts.visibility
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eq16_limits() {
        // One frame: no reuse, no speed-up; free visibility: n_f; the limit (c_e + c_l) / c_v.
        assert_eq!(predicted_speedup(1, 10.0, 90.0, 5.0), 1.0);
        assert_eq!(predicted_speedup(7, 10.0, 90.0, 0.0), 7.0);
        let far = predicted_speedup(1_000_001, 10.0, 90.0, 5.0);
        assert!((far - 20.0).abs() < 1e-3, "{far}");
        // The paper's n_f = 3 with c_v = (c_e + c_l) / 10: 3 * 100 / (100 + 20) = 2.5.
        assert!((predicted_speedup(3, 10.0, 90.0, 10.0) - 2.5).abs() < 1e-12);
    }
}
