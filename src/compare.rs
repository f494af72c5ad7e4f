//! `reframe reference` and `reframe compare`: every method against a cached high-sample reference,
//! error against time, flicker, and the charts.
//!
//! **Reference.** The independent tracer at `--reference-spp`, as `PASSES` passes with their own
//! seeds: the mean is the reference `R` and the spread of the passes gives the variance of that
//! mean per pixel and channel, `V = sum_k (p_k - R)^2 / (K (K - 1))`. The frames are cached as EXR
//! (channels R, G, B, var.R, var.G, var.B) in a folder whose name carries a key: a hash of the
//! loaded scene (geometry, materials, camera path), the resolution, the frames, the sample count
//! and the reframe executable itself, so that any change to the scene or the code renders it anew.
//! A folder is used only once its `reference.json` (written last) is there.
//!
//! **Errors**, per frame over pixels `p` and channels `c`, with `I` the image under test and `V`
//! subtracted so that the reference's own noise does not count (it is independent of `I`):
//! - `rmse = sqrt(max(0, mean((I - R)^2 - V)))`;
//! - `relmse = mean(((I - R)^2 - V) / (R^2 + 0.01))`;
//! - `flicker_t = sqrt(max(0, mean((E_t - E_(t-1))^2 - V_t - V_(t-1))))` with `E_t = I_t - R_t`:
//!   the RMS change of the error image from one frame to the next; lower is steadier.
//!
//! Overall: `rmse` over all frames' pixels, `relmse` the mean over frames, `flicker` the mean of
//! `flicker_t` over consecutive pairs.
//!
//! **Equal-error speed-up**: `log relmse = a + b log t` is fitted by least squares to each
//! method's runs (one line per method and window; a single run assumes `b = -1`, the Monte Carlo
//! rate). At the geometric mean of the method's own errors, the time the independent line needs
//! over the time the method's line needs is the speed-up.
use crate::bench::{measure_costs, predicted_speedup, Costs};
use crate::camera::Camera;
use crate::chart::{bar_chart, image_strip, write_svg_png, LineChart, Series, COLOURS};
use crate::checkpoint::{hash_exe, hash_scene, Fnv};
use crate::image::{check_writable_dir, read_image, write_image, Image, Metadata, WriteOptions};
use crate::integrator::{Integrator, RayCounts};
use crate::render::{
    check_frames, progress_bar, render_frame_independent, thread_pool, to_image, write_atomic,
    write_json, Method, RenderOptions,
};
use crate::reuse::render_reuse;
use crate::scene::Scene;
use anyhow::{bail, Context, Result};
use glam::Vec3;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::ops::RangeInclusive;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Passes the reference is split into, for its per-pixel variance.
pub const PASSES: u32 = 8;
/// Seed of the reference's first pass; compare's runs use `--seed` (small numbers).
const REFERENCE_SEED: u64 = 0x7265_6672_616d_6500;
/// The `relmse` denominator offset.
const REL_EPS: f64 = 0.01;

pub const RELMSE_FORMULA: &str = "relmse = mean over pixels and RGB channels of ((I - R)^2 - V) / (R^2 + 0.01), V = variance of the reference's mean";
pub const RMSE_FORMULA: &str =
    "rmse = sqrt(max(0, mean over pixels and RGB channels of (I - R)^2 - V))";
pub const FLICKER_FORMULA: &str = "flicker = mean over t of sqrt(max(0, mean over pixels and RGB channels of (E_t - E_(t-1))^2 - V_t - V_(t-1))), E_t = I_t - R_t";

/// One reference frame: the mean and the variance of the mean, per pixel.
pub struct RefFrame {
    pub mean: Vec<Vec3>,
    pub var: Vec<Vec3>,
}

pub struct Reference {
    pub first: u32,
    pub frames: Vec<RefFrame>,
    pub dir: PathBuf,
    pub spp: u32,
    /// Found in the cache (nothing rendered).
    pub cached: bool,
    /// Render time when it was made.
    pub seconds: f64,
}

/// What marks a cached reference as complete and what it was made from.
#[derive(Serialize, Deserialize)]
struct ReferenceInfo {
    scene: String,
    width: u32,
    height: u32,
    first_frame: u32,
    last_frame: u32,
    spp: u32,
    passes: u32,
    key: String,
    seconds: f64,
}

/// The cache key of a reference (see the module note).
pub fn reference_key(
    scene: &Scene,
    range: &RangeInclusive<u32>,
    (w, h): (u32, u32),
    spp: u32,
) -> Result<String> {
    let mut f = Fnv::default();
    hash_scene(&mut f, scene);
    for v in [*range.start(), *range.end(), w, h, spp, PASSES] {
        f.bytes(&v.to_le_bytes());
    }
    hash_exe(&mut f)?;
    Ok(format!("{:016x}", f.0))
}

/// The reference of `range` at `w` x `h`: from the cache when there, else rendered and cached.
#[allow(clippy::too_many_arguments)]
pub fn reference(
    scene: &Scene,
    range: RangeInclusive<u32>,
    (w, h): (u32, u32),
    spp: u32,
    cache: &Path,
    pool: &rayon::ThreadPool,
    progress: bool,
) -> Result<Reference> {
    if spp < PASSES || !spp.is_multiple_of(PASSES) {
        bail!("--reference-spp {spp}: must be a multiple of {PASSES} (the reference is {PASSES} passes, for its variance)");
    }
    let key = reference_key(scene, &range, (w, h), spp)?;
    let (first, last) = (*range.start(), *range.end());
    let dir = cache.join(format!(
        "{}_{w}x{h}_f{first}-{last}_{spp}spp_{key}",
        scene.name
    ));
    let info_path = dir.join("reference.json");
    let frame_path = |f: u32| dir.join(format!("ref_{f:04}.exr"));
    if let Ok(text) = std::fs::read_to_string(&info_path) {
        let info: ReferenceInfo = serde_json::from_str(&text)
            .with_context(|| format!("{}: not a reference description", info_path.display()))?;
        let mut frames = Vec::new();
        for f in range.clone() {
            frames.push(read_reference_frame(&frame_path(f), w, h)?);
        }
        return Ok(Reference {
            first,
            frames,
            dir,
            spp,
            cached: true,
            seconds: info.seconds,
        });
    }
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    check_writable_dir(&dir)?;
    let integrator = Integrator::new(scene, 16);
    let n = (last - first + 1) as u64;
    let pb = progress_bar(progress, n * PASSES as u64, "reference passes");
    let start = Instant::now();
    let mut frames = Vec::new();
    for f in range.clone() {
        let cam = scene.camera(f, w, h);
        let none = |_: &RayCounts| {};
        let passes: Vec<Vec<Vec3>> = (0..PASSES as u64)
            .map(|k| {
                let px = pool.install(|| {
                    render_frame_independent(
                        &integrator,
                        &cam,
                        f,
                        spp / PASSES,
                        REFERENCE_SEED + k,
                        false,
                        &none,
                    )
                    .pixels
                });
                pb.inc(1);
                px
            })
            .collect();
        let k = PASSES as f32;
        let mean: Vec<Vec3> = (0..passes[0].len())
            .map(|i| passes.iter().map(|p| p[i]).sum::<Vec3>() / k)
            .collect();
        let var: Vec<Vec3> = (0..mean.len())
            .map(|i| {
                passes
                    .iter()
                    .map(|p| (p[i] - mean[i]) * (p[i] - mean[i]))
                    .sum::<Vec3>()
                    / (k * (k - 1.0))
            })
            .collect();
        write_reference_frame(&frame_path(f), scene, &cam, f, spp, &mean, &var)?;
        frames.push(RefFrame { mean, var });
    }
    pb.finish_and_clear();
    let seconds = start.elapsed().as_secs_f64();
    write_json(
        &info_path,
        &ReferenceInfo {
            scene: scene.name.clone(),
            width: w,
            height: h,
            first_frame: first,
            last_frame: last,
            spp,
            passes: PASSES,
            key,
            seconds,
        },
    )?;
    Ok(Reference {
        first,
        frames,
        dir,
        spp,
        cached: false,
        seconds,
    })
}

fn write_reference_frame(
    path: &Path,
    scene: &Scene,
    cam: &Camera,
    frame: u32,
    spp: u32,
    mean: &[Vec3],
    var: &[Vec3],
) -> Result<()> {
    let mut img = Image::new(
        cam.width,
        cam.height,
        &["R", "G", "B", "var.R", "var.G", "var.B"],
    );
    img.data = mean
        .iter()
        .zip(var)
        .flat_map(|(m, v)| m.to_array().into_iter().chain(v.to_array()))
        .collect();
    let meta = Metadata {
        method: "reference".into(),
        spp,
        window: 1,
        seed: REFERENCE_SEED,
        render_seconds: 0.0,
        world_to_camera: cam.world_to_camera().to_cols_array(),
        world_to_ndc: cam.world_to_ndc().to_cols_array(),
        extra: vec![
            ("scene".into(), scene.name.clone()),
            ("frame".into(), frame.to_string()),
        ],
    };
    write_image(path, &img, &meta, &WriteOptions { exr_float: true })
}

fn read_reference_frame(path: &Path, w: u32, h: u32) -> Result<RefFrame> {
    let img = read_image(path).with_context(|| "the cached reference is incomplete")?;
    if (img.width, img.height) != (w, h) {
        bail!(
            "{}: {}x{}, expected {w}x{h}",
            path.display(),
            img.width,
            img.height
        );
    }
    let ch = |name: &str| {
        img.channel_index(name)
            .with_context(|| format!("{}: no channel {name}", path.display()))
    };
    let idx = [
        ch("R")?,
        ch("G")?,
        ch("B")?,
        ch("var.R")?,
        ch("var.G")?,
        ch("var.B")?,
    ];
    let nc = img.channels.len();
    let at = |i: usize, c: usize| img.data[i * nc + idx[c]];
    let n = (w * h) as usize;
    Ok(RefFrame {
        mean: (0..n)
            .map(|i| Vec3::new(at(i, 0), at(i, 1), at(i, 2)))
            .collect(),
        var: (0..n)
            .map(|i| Vec3::new(at(i, 3), at(i, 4), at(i, 5)))
            .collect(),
    })
}

/// Errors of one frame against the reference.
#[derive(Clone, Debug, Serialize)]
pub struct FrameError {
    pub frame: u32,
    pub rmse: f64,
    pub relmse: f64,
    /// Against the previous frame; absent for the first.
    pub flicker: Option<f64>,
}

/// The errors of a run's frames: per frame, and overall (rmse, relmse, flicker).
pub fn errors(frames: &[Vec<Vec3>], r: &Reference) -> (Vec<FrameError>, f64, f64, f64) {
    let mut per = Vec::new();
    let mut sq_total = 0.0;
    for (t, img) in frames.iter().enumerate() {
        let rf = &r.frames[t];
        let (mut sq, mut rel) = (0.0f64, 0.0f64);
        for ((i, m), v) in img.iter().zip(&rf.mean).zip(&rf.var) {
            for c in 0..3 {
                let d = (i[c] - m[c]) as f64;
                let e = d * d - v[c] as f64;
                sq += e;
                rel += e / ((m[c] as f64).powi(2) + REL_EPS);
            }
        }
        let n = (img.len() * 3) as f64;
        let flicker = (t > 0).then(|| {
            let (prev, rp) = (&frames[t - 1], &r.frames[t - 1]);
            let mut s = 0.0f64;
            for p in 0..img.len() {
                for c in 0..3 {
                    let e1 = (img[p][c] - rf.mean[p][c]) as f64;
                    let e0 = (prev[p][c] - rp.mean[p][c]) as f64;
                    s += (e1 - e0).powi(2) - rf.var[p][c] as f64 - rp.var[p][c] as f64;
                }
            }
            (s / n).max(0.0).sqrt()
        });
        sq_total += sq;
        per.push(FrameError {
            frame: r.first + t as u32,
            rmse: (sq / n).max(0.0).sqrt(),
            relmse: rel / n,
            flicker,
        });
    }
    let n_all = frames.iter().map(|f| f.len() * 3).sum::<usize>() as f64;
    let rmse = (sq_total / n_all).max(0.0).sqrt();
    let relmse = per.iter().map(|e| e.relmse).sum::<f64>() / per.len() as f64;
    let fl: Vec<f64> = per.iter().filter_map(|e| e.flicker).collect();
    let flicker = if fl.is_empty() {
        0.0
    } else {
        fl.iter().sum::<f64>() / fl.len() as f64
    };
    (per, rmse, relmse, flicker)
}

/// Least-squares line through `(ln x, ln y)`: `(a, b)` with `ln y = a + b ln x`. A single point
/// gets the Monte Carlo slope `b = -1`. `None` without a usable point.
pub fn loglog_fit(points: &[(f64, f64)]) -> Option<(f64, f64)> {
    let p: Vec<(f64, f64)> = points
        .iter()
        .filter(|(x, y)| *x > 0.0 && *y > 0.0 && x.is_finite() && y.is_finite())
        .map(|(x, y)| (x.ln(), y.ln()))
        .collect();
    match p.len() {
        0 => None,
        1 => Some((p[0].1 + p[0].0, -1.0)),
        n => {
            let n = n as f64;
            let (mx, my) = (
                p.iter().map(|q| q.0).sum::<f64>() / n,
                p.iter().map(|q| q.1).sum::<f64>() / n,
            );
            let sxx: f64 = p.iter().map(|q| (q.0 - mx).powi(2)).sum();
            let sxy: f64 = p.iter().map(|q| (q.0 - mx) * (q.1 - my)).sum();
            if sxx < 1e-12 {
                return Some((my + mx, -1.0));
            }
            let b = sxy / sxx;
            Some((my - b * mx, b))
        }
    }
}

/// The time at which the fitted line `(a, b)` reaches error `e`; `None` if it never falls.
fn time_for(fit: (f64, f64), e: f64) -> Option<f64> {
    (fit.1 < -1e-3).then(|| ((e.ln() - fit.0) / fit.1).exp())
}

/// What to compare.
#[derive(Clone, Debug)]
pub struct CompareOptions {
    /// Frames; `None`: 17 frames around the middle of the animation (all of a shorter one).
    pub frames: Option<RangeInclusive<u32>>,
    pub res: Option<(u32, u32)>,
    pub methods: Vec<Method>,
    /// Samples per pixel of the independent runs.
    pub budgets: Vec<u32>,
    /// Native samples per pixel of the reuse runs.
    pub reuse_budgets: Vec<u32>,
    /// Group sizes of the reuse runs (longer than the frames: skipped).
    pub windows: Vec<u32>,
    pub reference_spp: u32,
    pub cache: PathBuf,
    pub out: PathBuf,
    pub threads: usize,
    pub seed: u64,
    /// Crop of the strip (x, y, width, height); `None`: a centred square of half the height.
    pub crop: Option<[u32; 4]>,
    pub progress: bool,
}

impl Default for CompareOptions {
    fn default() -> Self {
        CompareOptions {
            frames: None,
            res: None,
            methods: vec![
                Method::Independent,
                Method::Havran,
                Method::Mis,
                Method::MisExact,
            ],
            budgets: vec![1, 2, 4, 8, 16],
            reuse_budgets: vec![1, 2],
            windows: vec![3, 7, 17],
            reference_spp: 256,
            cache: PathBuf::from("out/reference-cache"),
            out: PathBuf::from("out/compare"),
            threads: 0,
            seed: 0,
            crop: None,
            progress: true,
        }
    }
}

/// One run of `compare`.
#[derive(Clone, Debug, Serialize)]
pub struct Run {
    pub method: Method,
    pub window: u32,
    pub spp: u32,
    pub seconds: f64,
    pub rmse: f64,
    pub relmse: f64,
    pub flicker: f64,
    pub mean_effective_spp: f64,
    pub per_frame: Vec<FrameError>,
}

/// What `compare.json` holds (keys are a contract with users' scripts: add, never rename).
#[derive(Debug, Serialize)]
pub struct CompareReport {
    pub scene: String,
    pub width: u32,
    pub height: u32,
    pub first_frame: u32,
    pub last_frame: u32,
    pub threads: usize,
    pub reference: ReferenceSummary,
    pub rmse_formula: &'static str,
    pub relmse_formula: &'static str,
    pub flicker_formula: &'static str,
    pub runs: Vec<Run>,
    /// Per method, per window: independent's time over the method's time at equal relMSE.
    pub equal_error_speedup: BTreeMap<String, BTreeMap<String, f64>>,
    pub costs: Costs,
    /// `mis-exact` per window: eq. 16 with the measured costs, and the same-sample speed-up
    /// measured from the runs' times.
    pub predicted_speedup: BTreeMap<String, f64>,
    pub measured_speedup: BTreeMap<String, f64>,
    /// The time of equal-time comparisons and each method's flicker there (fitted).
    pub equal_time_seconds: f64,
    pub equal_time_flicker: BTreeMap<String, f64>,
    pub crop: [u32; 4],
    pub crop_frame: u32,
    pub outputs: Vec<String>,
}

#[derive(Debug, Serialize)]
pub struct ReferenceSummary {
    pub spp: u32,
    pub passes: u32,
    pub cached: bool,
    pub seconds: f64,
    pub dir: String,
}

/// The frames `compare` and `reference` use by default: 17 around the middle.
pub fn default_frames(scene: &Scene) -> RangeInclusive<u32> {
    let n = scene.frames.min(17);
    let first = (scene.frames - n) / 2;
    first..=first + n - 1
}

/// Run the comparison and write `compare.json`, `compare.csv` and the charts into `opts.out`.
pub fn compare(scene: &Scene, opts: &CompareOptions) -> Result<CompareReport> {
    let range = opts.frames.clone().unwrap_or_else(|| default_frames(scene));
    check_frames(scene, &range)?;
    let (first, last) = (*range.start(), *range.end());
    let (w, h) = opts.res.unwrap_or((scene.width, scene.height));
    if w == 0 || h == 0 {
        bail!("--res {w}x{h}: width and height must be positive");
    }
    let n_frames = last - first + 1;
    if opts.budgets.contains(&0) || opts.reuse_budgets.contains(&0) {
        bail!("a budget of 0 samples per pixel: every run needs at least one");
    }
    if let Some(&n) = opts.windows.iter().find(|&&n| n % 2 == 0) {
        bail!("--windows {n}: a group is n_f = 2n+1 frames, so windows must be odd");
    }
    if opts.methods.contains(&Method::Independent) && opts.budgets.is_empty() {
        bail!("--budgets: the independent tracer needs at least one budget");
    }
    let crop = opts.crop.unwrap_or([w / 2 - h / 4, h / 4, h / 2, h / 2]);
    if crop[2] == 0 || crop[3] == 0 || crop[0] + crop[2] > w || crop[1] + crop[3] > h {
        bail!(
            "--crop {},{},{},{}: not inside the {w}x{h} frame",
            crop[0],
            crop[1],
            crop[2],
            crop[3]
        );
    }
    std::fs::create_dir_all(&opts.out)
        .with_context(|| format!("--out {}: cannot create the folder", opts.out.display()))?;
    check_writable_dir(&opts.out).with_context(|| format!("--out {}", opts.out.display()))?;
    let pool = thread_pool(opts.threads)?;
    let threads = pool.current_num_threads();
    crate::embree::set_flush_denormals();

    let reference = reference(
        scene,
        range.clone(),
        (w, h),
        opts.reference_spp,
        &opts.cache,
        &pool,
        opts.progress,
    )?;
    eprintln!(
        "reference: {} spp, {} ({})",
        reference.spp,
        reference.dir.display(),
        if reference.cached {
            "cached".to_string()
        } else {
            format!("rendered in {:.1} s", reference.seconds)
        }
    );
    let integrator = Integrator::new(scene, 16);
    let crop_frame = first + n_frames / 2;
    let mut runs: Vec<Run> = Vec::new();
    let mut crops: Vec<Vec<Vec3>> = Vec::new();
    let mut plan: Vec<(Method, u32, u32)> = Vec::new();
    for &m in &opts.methods {
        if m == Method::Independent {
            plan.extend(opts.budgets.iter().map(|&s| (m, 1, s)));
        } else {
            for &n_f in opts.windows.iter().filter(|&&n| n <= n_frames) {
                plan.extend(opts.reuse_budgets.iter().map(|&s| (m, n_f, s)));
            }
        }
    }
    if plan.is_empty() {
        bail!("nothing to compare: no method with a budget and a window that fits the frames");
    }
    let pb = progress_bar(opts.progress, plan.len() as u64, "runs");
    for (method, window, spp) in plan {
        let start = Instant::now();
        let mut frames: Vec<Vec<Vec3>> = Vec::with_capacity(n_frames as usize);
        let mut eff = spp as f64;
        if method == Method::Independent {
            for f in range.clone() {
                let cam = scene.camera(f, w, h);
                let none = |_: &RayCounts| {};
                let px = pool.install(|| {
                    render_frame_independent(&integrator, &cam, f, spp, opts.seed, false, &none)
                });
                frames.push(px.pixels);
            }
        } else {
            let ropts = RenderOptions {
                method,
                spp,
                window,
                seed: opts.seed,
                progress: false,
                ..RenderOptions::default()
            };
            let stats = pool.install(|| {
                render_reuse(
                    &integrator,
                    &ropts,
                    range.clone(),
                    w,
                    h,
                    &mut |_, _, px, _, _| {
                        frames.push(px.to_vec());
                        Ok(())
                    },
                )
            })?;
            eff = stats.mean_effective_spp;
        }
        let seconds = start.elapsed().as_secs_f64();
        let (per_frame, rmse, relmse, flicker) = errors(&frames, &reference);
        pb.suspend(|| {
            eprintln!(
                "{:>11} window {window:>2} spp {spp:>3}: {seconds:>7.2} s  rmse {rmse:.5}  relMSE {relmse:.5}  flicker {flicker:.5}",
                method.name()
            )
        });
        pb.inc(1);
        crops.push(frames.swap_remove((crop_frame - first) as usize));
        runs.push(Run {
            method,
            window,
            spp,
            seconds,
            rmse,
            relmse,
            flicker,
            mean_effective_spp: eff,
            per_frame,
        });
    }
    pb.finish_and_clear();

    // Cost model: measured on the middle frame, as `reframe bench` does.
    let cam = scene.camera(crop_frame, w, h);
    let (costs, _, _) = measure_costs(scene, &integrator, &pool, &cam, crop_frame, 2, opts.seed);

    // Fits and derived figures.
    let key = |r: &Run| (r.method, r.window);
    let mut lines: Vec<(Method, u32)> = runs.iter().map(key).collect();
    lines.dedup();
    let fit_of = |m: Method, n_f: u32, y: fn(&Run) -> f64| {
        let pts: Vec<(f64, f64)> = runs
            .iter()
            .filter(|r| key(r) == (m, n_f))
            .map(|r| (r.seconds, y(r)))
            .collect();
        loglog_fit(&pts)
    };
    let indep_fit = fit_of(Method::Independent, 1, |r| r.relmse);
    let mut equal_error_speedup: BTreeMap<String, BTreeMap<String, f64>> = BTreeMap::new();
    for &(m, n_f) in lines.iter().filter(|l| l.0 != Method::Independent) {
        let own: Vec<f64> = runs
            .iter()
            .filter(|r| key(r) == (m, n_f) && r.relmse > 0.0)
            .map(|r| r.relmse.ln())
            .collect();
        let (Some(fi), Some(fm)) = (indep_fit, fit_of(m, n_f, |r| r.relmse)) else {
            continue;
        };
        if own.is_empty() {
            continue;
        }
        let e = (own.iter().sum::<f64>() / own.len() as f64).exp();
        if let (Some(ti), Some(tm)) = (time_for(fi, e), time_for(fm, e)) {
            equal_error_speedup
                .entry(m.name().to_string())
                .or_default()
                .insert(n_f.to_string(), ti / tm);
        }
    }
    // Same-sample speed-up of mis-exact: independent time per frame and sample, times the
    // samples per frame the groups would give without losses, over the reuse time.
    let mut per_sample: Vec<f64> = runs
        .iter()
        .filter(|r| r.method == Method::Independent)
        .map(|r| r.seconds / (n_frames * r.spp) as f64)
        .collect();
    per_sample.sort_by(f64::total_cmp);
    let t_sample = per_sample.get(per_sample.len() / 2).copied();
    let mut predicted = BTreeMap::new();
    let mut measured = BTreeMap::new();
    for &n_f in opts.windows.iter().filter(|&&n| n <= n_frames) {
        predicted.insert(
            n_f.to_string(),
            predicted_speedup(n_f, costs.c_e, costs.c_l, costs.c_v_packet),
        );
        let groups = (n_frames - n_f + 1) as f64;
        let ratios: Vec<f64> = runs
            .iter()
            .filter(|r| r.method == Method::MisExact && r.window == n_f)
            .filter_map(|r| {
                let ideal = groups * (n_f * n_f * r.spp) as f64;
                t_sample.map(|t| t * ideal / r.seconds)
            })
            .collect();
        if !ratios.is_empty() {
            measured.insert(
                n_f.to_string(),
                ratios.iter().sum::<f64>() / ratios.len() as f64,
            );
        }
    }
    // Equal time: the geometric mean of the independent runs' times (or of all runs').
    let times: Vec<f64> = {
        let ind: Vec<f64> = runs
            .iter()
            .filter(|r| r.method == Method::Independent)
            .map(|r| r.seconds)
            .collect();
        if ind.is_empty() {
            runs.iter().map(|r| r.seconds).collect()
        } else {
            ind
        }
    };
    let equal_time = (times.iter().map(|t| t.ln()).sum::<f64>() / times.len() as f64).exp();
    // Each method at its largest window.
    let widest: Vec<(Method, u32)> = opts
        .methods
        .iter()
        .filter_map(|&m| {
            lines
                .iter()
                .filter(|l| l.0 == m)
                .max_by_key(|l| l.1)
                .copied()
        })
        .collect();
    let mut equal_time_flicker = BTreeMap::new();
    for &(m, n_f) in &widest {
        if let Some((a, b)) = fit_of(m, n_f, |r| r.flicker) {
            equal_time_flicker.insert(m.name().to_string(), (a + b * equal_time.ln()).exp());
        }
    }

    // Files.
    let mut outputs = Vec::new();
    let colour = |m: Method| COLOURS[m as usize % COLOURS.len()];
    let label = |m: Method, n_f: u32| {
        if m == Method::Independent {
            m.name().to_string()
        } else {
            format!("{} n_f={n_f}", m.name())
        }
    };
    let max_window = lines.iter().map(|l| l.1).max().unwrap_or(1);
    let chart1 = LineChart {
        title: format!(
            "{}: relMSE against time ({w}x{h}, frames {first}-{last}, {threads} threads)",
            scene.name
        ),
        x_label: "render time, seconds".into(),
        y_label: "relMSE".into(),
        log_x: true,
        log_y: true,
        // Every method at its widest window, solid; mis-exact's narrower windows dashed.
        series: lines
            .iter()
            .filter(|l| l.0 == Method::Independent || l.1 == max_window)
            .map(|&l| (l, false))
            .chain(
                lines
                    .iter()
                    .filter(|l| l.0 == Method::MisExact && l.1 != max_window)
                    .map(|&l| (l, true)),
            )
            .map(|((m, n_f), dashed)| Series {
                name: label(m, n_f),
                colour: colour(m),
                dashed,
                points: runs
                    .iter()
                    .filter(|r| key(r) == (m, n_f))
                    .map(|r| (r.seconds, r.relmse))
                    .collect(),
            })
            .collect(),
    };
    let mut write_chart = |svg: String, stem: &str| -> Result<()> {
        let p = opts.out.join(stem);
        write_svg_png(&svg, &p)?;
        outputs.push(p.with_extension("png").display().to_string());
        outputs.push(p.with_extension("svg").display().to_string());
        Ok(())
    };
    write_chart(chart1.svg(), "error_vs_time")?;
    let chart2 = LineChart {
        title: format!("{}: mis-exact speed-up against n_f", scene.name),
        x_label: "frames per group n_f".into(),
        y_label: "speed-up over independent".into(),
        log_x: false,
        log_y: false,
        series: vec![
            Series {
                name: "eq. 16 predicted".into(),
                colour: COLOURS[0],
                dashed: true,
                points: num_points(&predicted),
            },
            Series {
                name: "measured, same spp".into(),
                colour: COLOURS[3],
                dashed: false,
                points: num_points(&measured),
            },
            Series {
                name: "measured, equal error".into(),
                colour: COLOURS[5],
                dashed: false,
                points: equal_error_speedup
                    .get(Method::MisExact.name())
                    .map(num_points)
                    .unwrap_or_default(),
            },
        ],
    };
    write_chart(chart2.svg(), "speedup_vs_nf")?;
    let bars: Vec<(String, f64, &str)> = widest
        .iter()
        .filter_map(|&(m, n_f)| {
            equal_time_flicker
                .get(m.name())
                .map(|&v| (label(m, n_f), v, colour(m)))
        })
        .collect();
    write_chart(
        bar_chart(
            &format!("{}: flicker at equal time ({equal_time:.1} s)", scene.name),
            "flicker (RMS frame-to-frame change of the error)",
            &bars,
        ),
        "flicker",
    )?;
    // The crop strip: each method's run closest in time to mis-exact's cheapest widest run.
    let strip_time = runs
        .iter()
        .filter(|r| r.method == Method::MisExact && r.window == max_window)
        .map(|r| r.seconds)
        .fold(f64::INFINITY, f64::min);
    let strip_time = if strip_time.is_finite() {
        strip_time
    } else {
        equal_time
    };
    let mut tiles = vec![(
        format!("reference\n{} spp", reference.spp),
        crop_png(
            &reference.frames[(crop_frame - first) as usize].mean,
            w,
            h,
            crop,
        )?,
        crop[2],
        crop[3],
    )];
    for &(m, n_f) in &widest {
        let best = runs
            .iter()
            .enumerate()
            .filter(|(_, r)| key(r) == (m, n_f))
            .min_by(|a, b| {
                let d = |r: &Run| (r.seconds / strip_time).ln().abs();
                d(a.1).total_cmp(&d(b.1))
            });
        if let Some((i, r)) = best {
            let what = if m == Method::Independent {
                format!("{} spp", r.spp)
            } else {
                format!("{} spp, n_f {}", r.spp, r.window)
            };
            tiles.push((
                format!("{}\n{what}, {:.2} s", m.name(), r.seconds),
                crop_png(&crops[i], w, h, crop)?,
                crop[2],
                crop[3],
            ));
        }
    }
    let zoom = (240 / crop[2].max(crop[3])).clamp(1, 8);
    write_chart(
        image_strip(
            &format!(
                "{}: frame {crop_frame}, crop {}x{} at ({}, {}), about {strip_time:.2} s each",
                scene.name, crop[2], crop[3], crop[0], crop[1]
            ),
            &tiles,
            zoom,
        ),
        "crops",
    )?;
    let csv_path = opts.out.join("compare.csv");
    let mut csv =
        String::from("method,window,spp,seconds,rmse,relmse,flicker,mean_effective_spp\n");
    for r in &runs {
        let _ = writeln!(
            csv,
            "{},{},{},{:.6},{:.8},{:.8},{:.8},{:.3}",
            r.method.name(),
            r.window,
            r.spp,
            r.seconds,
            r.rmse,
            r.relmse,
            r.flicker,
            r.mean_effective_spp
        );
    }
    write_atomic(&csv_path, csv.as_bytes())?;
    outputs.push(csv_path.display().to_string());
    let json_path = opts.out.join("compare.json");
    outputs.push(json_path.display().to_string());
    let report = CompareReport {
        scene: scene.name.clone(),
        width: w,
        height: h,
        first_frame: first,
        last_frame: last,
        threads,
        reference: ReferenceSummary {
            spp: reference.spp,
            passes: PASSES,
            cached: reference.cached,
            seconds: reference.seconds,
            dir: reference.dir.display().to_string(),
        },
        rmse_formula: RMSE_FORMULA,
        relmse_formula: RELMSE_FORMULA,
        flicker_formula: FLICKER_FORMULA,
        runs,
        equal_error_speedup,
        costs,
        predicted_speedup: predicted,
        measured_speedup: measured,
        equal_time_seconds: equal_time,
        equal_time_flicker,
        crop,
        crop_frame,
        outputs,
    };
    write_json(&json_path, &report)?;
    Ok(report)
}

/// The table `reframe compare` prints: one line per run, then the speed-ups.
pub fn summary(r: &CompareReport) -> String {
    let mut s = format!(
        "{:<12} {:>6} {:>4} {:>9} {:>10} {:>10} {:>10}\n",
        "method", "window", "spp", "seconds", "rmse", "relMSE", "flicker"
    );
    for run in &r.runs {
        let _ = writeln!(
            s,
            "{:<12} {:>6} {:>4} {:>9.2} {:>10.5} {:>10.5} {:>10.5}",
            run.method.name(),
            run.window,
            run.spp,
            run.seconds,
            run.rmse,
            run.relmse,
            run.flicker
        );
    }
    for (m, by_window) in &r.equal_error_speedup {
        let v: Vec<String> = num_points(by_window)
            .iter()
            .map(|(n, x)| format!("n_f {n}: {x:.2}x"))
            .collect();
        let _ = writeln!(
            s,
            "equal-error speed-up of {m} over independent: {}",
            v.join(", ")
        );
    }
    let p: Vec<String> = num_points(&r.predicted_speedup)
        .iter()
        .map(|(n, x)| {
            let m = r
                .measured_speedup
                .get(&n.to_string())
                .copied()
                .unwrap_or(f64::NAN);
            format!("n_f {n}: {x:.2}x / {m:.2}x")
        })
        .collect();
    let _ = write!(s, "same-spp speed-up, eq. 16 / measured: {}", p.join(", "));
    s
}

/// `{"3": 2.1, "17": 6.0}` as points (3, 2.1), (17, 6.0), in numeric order.
fn num_points(m: &BTreeMap<String, f64>) -> Vec<(f64, f64)> {
    let mut p: Vec<(f64, f64)> = m
        .iter()
        .filter_map(|(k, v)| k.parse::<f64>().ok().map(|k| (k, *v)))
        .collect();
    p.sort_by(|a, b| a.0.total_cmp(&b.0));
    p
}

/// The crop of a frame as an 8-bit sRGB PNG.
fn crop_png(px: &[Vec3], w: u32, h: u32, [x0, y0, cw, ch]: [u32; 4]) -> Result<Vec<u8>> {
    let full = to_image(w, h, px);
    let mut img = Image::new(cw, ch, &["R", "G", "B"]);
    img.data = (y0..y0 + ch)
        .flat_map(|y| (x0..x0 + cw).map(move |x| (x, y)))
        .flat_map(|(x, y)| full.pixel(x, y).to_vec())
        .collect();
    let rgb = crate::image::encode_srgb8(&img)?;
    let mut pixmap = resvg::tiny_skia::Pixmap::new(cw, ch).context("empty crop")?;
    for (dst, src) in pixmap
        .data_mut()
        .chunks_exact_mut(4)
        .zip(rgb.chunks_exact(3))
    {
        dst[..3].copy_from_slice(src);
        dst[3] = 255;
    }
    pixmap.encode_png().context("encoding a crop")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn loglog_fit_recovers_a_power_law() {
        let pts: Vec<(f64, f64)> = [1.0, 2.0, 4.0, 8.0].iter().map(|&t| (t, 0.3 / t)).collect();
        let (a, b) = loglog_fit(&pts).unwrap();
        assert!((b + 1.0).abs() < 1e-12 && (a - 0.3f64.ln()).abs() < 1e-12);
        assert!((time_for((a, b), 0.03).unwrap() - 10.0).abs() < 1e-9);
        // One point: the Monte Carlo slope through it.
        let (a1, b1) = loglog_fit(&[(2.0, 0.5)]).unwrap();
        assert_eq!(b1, -1.0);
        assert!((time_for((a1, b1), 0.25).unwrap() - 4.0).abs() < 1e-9);
        // An error that does not fall with time has no time for a lower error.
        assert!(time_for((0.0, 0.0), 0.1).is_none());
        assert!(loglog_fit(&[(1.0, 0.0)]).is_none());
    }

    fn reference_of(mean: Vec<Vec<Vec3>>, var: f32) -> Reference {
        Reference {
            first: 0,
            frames: mean
                .into_iter()
                .map(|m| RefFrame {
                    var: vec![Vec3::splat(var); m.len()],
                    mean: m,
                })
                .collect(),
            dir: PathBuf::new(),
            spp: 8,
            cached: false,
            seconds: 0.0,
        }
    }

    #[test]
    fn errors_follow_their_formulas() {
        let r = reference_of(
            vec![vec![Vec3::splat(1.0); 4], vec![Vec3::splat(2.0); 4]],
            0.0,
        );
        // Frame 0 off by +0.1 everywhere, frame 1 off by -0.1: rmse 0.1, flicker 0.2.
        let frames = vec![vec![Vec3::splat(1.1); 4], vec![Vec3::splat(1.9); 4]];
        let (per, rmse, relmse, flicker) = errors(&frames, &r);
        assert!((rmse - 0.1).abs() < 1e-6, "{rmse}");
        assert!((per[0].relmse - 0.01 / 1.01).abs() < 1e-6);
        assert!((per[1].relmse - 0.01 / 4.01).abs() < 1e-6);
        assert!((relmse - (per[0].relmse + per[1].relmse) / 2.0).abs() < 1e-12);
        assert!(per[0].flicker.is_none());
        assert!((flicker - 0.2).abs() < 1e-6, "{flicker}");
        // The reference's variance is taken off: an exact image scores 0, not -V.
        let noisy = reference_of(vec![vec![Vec3::splat(1.0); 4]], 0.0025);
        let (_, rmse, _, _) = errors(&[vec![Vec3::splat(1.1); 4]], &noisy);
        assert!((rmse - 0.0075f64.sqrt()).abs() < 1e-6, "{rmse}");
        let (_, rmse, _, _) = errors(&[vec![Vec3::splat(1.0); 4]], &noisy);
        assert_eq!(rmse, 0.0);
    }
}
