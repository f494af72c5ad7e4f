//! `reframe compare`: every method at a ladder of budgets against a cached high-sample reference
//! (`reference`), error against time and flicker (`errors`), and the charts (`chart`).
use super::bench::{measure_costs, predicted_speedup, Costs, SHORT_RUN_SECONDS};
use super::chart::{bar_chart, image_strip, write_svg_png, LineChart, Series, COLOURS};
use super::errors::{
    bias_estimate, errors, loglog_fit, time_for, FrameError, FLICKER_FORMULA, RELMSE_FORMULA,
    RMSE_FORMULA,
};
use super::reference::{reference, Reference, PASSES};
use crate::driver::denoise::{denoise_frame, Layers};
use crate::driver::guard::{check_outputs, OutputLock};
use crate::driver::options::{
    check_max_depth, check_resolution, check_reuse_film, check_spp, check_threads,
};
use crate::driver::{check_frames, progress_bar, render_frames, thread_pool, RenderOptions};
use crate::film::Developed;
use crate::image::oidn::Denoiser;
use crate::image::{write_image, Image, Metadata, WriteOptions};
use crate::integrator::Integrator;
use crate::reuse::Method;
use crate::scene::Scene;
use crate::state::checkpoint::Counters;
use crate::util::fs::{check_writable_dir, write_atomic, write_json, CreatedDirs};
use anyhow::{bail, Context, Result};
use glam::Vec3;
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::ops::RangeInclusive;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// A method as `compare` runs it: a rendering method, optionally followed by Open Image Denoise
/// on every measured frame (`independent+oidn`, `mis-cv+oidn`). Spelled and serialised as
/// `name()`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Candidate {
    pub method: Method,
    pub denoise: bool,
}

impl Candidate {
    pub const fn plain(method: Method) -> Candidate {
        Candidate {
            method,
            denoise: false,
        }
    }

    pub const fn denoised(method: Method) -> Candidate {
        Candidate {
            method,
            denoise: true,
        }
    }

    pub fn name(&self) -> String {
        if self.denoise {
            format!("{}+oidn", self.method.name())
        } else {
            self.method.name().to_string()
        }
    }

    /// Its chart colour: the method's, or for a denoised line one of its own.
    fn colour(&self) -> &'static str {
        COLOURS[(self.method as usize + 5 * self.denoise as usize) % COLOURS.len()]
    }
}

impl std::fmt::Display for Candidate {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.name())
    }
}

impl std::str::FromStr for Candidate {
    type Err = String;
    fn from_str(s: &str) -> Result<Candidate, String> {
        if s.trim().is_empty() {
            let why = "an empty method name in the list (a comma at its end, or two together?)";
            return Err(why.to_string());
        }
        let (base, denoise) = match s.strip_suffix("+oidn") {
            Some(b) => (b, true),
            None => (s, false),
        };
        match Method::from_name(base) {
            Some(method) => Ok(Candidate { method, denoise }),
            None => {
                let names: Vec<&str> = Method::ALL.iter().map(|m| m.name()).collect();
                Err(format!(
                    "'{s}': not a method; expected one of {}, each optionally followed by \
                     '+oidn' (denoised)",
                    names.join(", ")
                ))
            }
        }
    }
}

impl Serialize for Candidate {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.name())
    }
}

/// Which frames of a reuse run are measured, and what they are charged.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Regime {
    /// The steady state of a long animation: each reuse run renders `n_f - 1` frames more on
    /// either side of the measured ones, so that every measured frame is in all `n_f` of its
    /// groups, and the measured frames are charged their share of the run's time (one group's
    /// time per output frame, what a user pays per frame of a long animation).
    Steady,
    /// Only the measured frames are rendered, and the whole run's time is charged: the ends of a
    /// range (the first and last `n_f - 1` frames, in fewer groups) weigh in; their error is
    /// reported apart (`ends_relmse`).
    Range,
}

/// Most seeds of the denoised methods' bias estimate (`--bias-seeds`), as `bench::MAX_REPEATS`
/// bounds its repeats: beyond it a typo would be hours of renders.
pub const MAX_BIAS_SEEDS: u32 = 64;

/// What to compare.
#[derive(Clone, Debug)]
pub struct CompareOptions {
    pub regime: Regime,
    /// Frames; `None`: 17 frames around the middle of the animation (all of a shorter one).
    pub frames: Option<RangeInclusive<u32>>,
    pub res: Option<(u32, u32)>,
    /// Methods, each optionally denoised (`Candidate`).
    pub methods: Vec<Candidate>,
    /// Samples per pixel of the independent runs.
    pub budgets: Vec<u32>,
    /// Native samples per pixel of the reuse runs.
    pub reuse_budgets: Vec<u32>,
    /// Group sizes of the reuse runs (longer than the frames: skipped).
    pub windows: Vec<u32>,
    pub reference_spp: u32,
    /// Longest path, in bounces, of every run and of the reference.
    pub max_depth: u32,
    pub cache: PathBuf,
    pub out: PathBuf,
    pub threads: usize,
    pub seed: u64,
    /// Crop of the strip (x, y, width, height); `None`: a centred square of half the height.
    pub crop: Option<[u32; 4]>,
    /// Seeds of the bias images of the denoised methods (0: none; otherwise at least 2).
    pub bias_seeds: u32,
    pub progress: bool,
}

impl Default for CompareOptions {
    fn default() -> Self {
        CompareOptions {
            regime: Regime::Steady,
            frames: None,
            res: None,
            methods: Method::ALL.into_iter().map(Candidate::plain).collect(),
            budgets: vec![1, 2, 4, 8, 16],
            reuse_budgets: vec![1, 2],
            windows: vec![3, 7, 17, 33],
            reference_spp: 256,
            max_depth: crate::driver::options::DEFAULT_MAX_DEPTH,
            cache: PathBuf::from("out/reference-cache"),
            out: PathBuf::from("out/compare"),
            threads: 0,
            seed: 0,
            crop: None,
            bias_seeds: 4,
            progress: true,
        }
    }
}

/// One run of `compare`.
#[derive(Clone, Debug, Serialize)]
pub struct Run {
    /// The method's name, `+oidn` when denoised.
    pub method: Candidate,
    pub window: u32,
    pub spp: u32,
    /// The time charged to the measured frames (see `Regime`), their denoising included; the
    /// fits use it.
    pub seconds: f64,
    /// Of `seconds`, the time spent denoising the measured frames (guides included).
    pub denoise_seconds: f64,
    /// The whole run's time, and the frames it rendered.
    pub run_seconds: f64,
    pub rendered_frames: [u32; 2],
    pub rmse: f64,
    pub relmse: f64,
    pub flicker: f64,
    pub mean_effective_spp: f64,
    /// `Regime::Range`, reuse runs: the mean relMSE of the first and last `n_f - 1` frames
    /// (fewer groups) and of the frames between them, if any.
    pub ends_relmse: Option<f64>,
    pub middle_relmse: Option<f64>,
    pub per_frame: Vec<FrameError>,
}

/// What `compare.json` holds (keys are a contract with users' scripts: add, never rename).
#[derive(Debug, Serialize)]
pub struct CompareReport {
    pub regime: Regime,
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
    /// Per denoised method, per window: `independent+oidn`'s time over the method's time at
    /// equal relMSE (when `independent+oidn` ran).
    pub equal_error_speedup_over_denoised: BTreeMap<String, BTreeMap<String, f64>>,
    pub costs: Costs,
    /// `mis-exact` per window: eq. 16 with the measured costs, and the same-sample speed-up
    /// measured from the runs' times.
    pub predicted_speedup: BTreeMap<String, f64>,
    pub measured_speedup: BTreeMap<String, f64>,
    /// The time of equal-time comparisons and each method's flicker there (fitted).
    pub equal_time_seconds: f64,
    pub equal_time_flicker: BTreeMap<String, f64>,
    /// Each method's relMSE at that time (fitted), at its widest window. Both maps hold the
    /// undenoised methods only: a denoised frame costs more than the cheapest runs.
    pub equal_time_relmse: BTreeMap<String, f64>,
    /// With denoised methods: their equal time (the geometric mean of `independent+oidn`'s
    /// times, else of all denoised runs'), and every method's flicker and relMSE there (fitted,
    /// widest window).
    pub denoised_equal_time_seconds: Option<f64>,
    pub denoised_equal_time_flicker: BTreeMap<String, f64>,
    pub denoised_equal_time_relmse: BTreeMap<String, f64>,
    /// The bias images of the denoised methods (and of `independent`, for scale).
    pub bias: Vec<Bias>,
    pub crop: [u32; 4],
    pub crop_frame: u32,
    /// Runs left out, and why (a window whose steady state needs frames the scene lacks).
    pub skipped: Vec<String>,
    pub outputs: Vec<String>,
}

/// What a method's frame averages to: the crop frame of its strip run rendered with
/// `seeds` seeds, their mean against the reference. The squared bias is estimated per pixel and
/// channel from the seeds' errors `e_i = I_i - R`, `b^2 = (N mean(e)^2 - mean(e^2)) / (N - 1) - V`,
/// unbiased for the method's `(E[I] - R)^2` (docs/compare.md).
#[derive(Clone, Debug, Serialize)]
pub struct Bias {
    pub method: Candidate,
    pub window: u32,
    pub spp: u32,
    pub seeds: u32,
    pub frame: u32,
    /// The squared bias in relMSE's units: mean of `b^2 / (R^2 + 0.01)`.
    pub bias_relmse: f64,
    /// The relMSE of one seed's frame (the mean over seeds), of which `bias_relmse` is part.
    pub relmse: f64,
    /// The relMSE of the mean over seeds.
    pub relmse_of_mean: f64,
    /// `mean - reference`, RGB, float EXR.
    pub image: String,
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
    let s = Setting::check(scene, opts)?;
    // The denoiser is loaded before anything is rendered: a missing library is one line now.
    let mut denoiser = match opts.methods.iter().find(|c| c.denoise) {
        Some(c) => Some(Denoiser::load(
            opts.threads,
            &format!("--methods {}", c.name()),
        )?),
        None => None,
    };
    // The runs, planned and checked before anything is made or rendered: a plan with nothing
    // to compare, or a run its render would refuse, is refused before the reference (minutes
    // of work on the default scene) is rendered.
    let (plan, skipped) = s.plan();
    let say_skipped = || {
        for s in &skipped {
            errln!("compare: skipped {s}");
        }
    };
    if plan.is_empty() {
        say_skipped();
        bail!("nothing to compare: no method with a budget and a window that fits the frames");
    }
    for p in &plan {
        s.spec(p, opts.seed)
            .options()
            .check(scene)
            .with_context(|| {
                if p.c.method.reuses() {
                    format!(
                        "--methods {} at --reuse-budgets {} and --windows {}",
                        p.c, p.spp, p.window
                    )
                } else {
                    format!("--methods {} at --budgets {}", p.c, p.spp)
                }
            })?;
    }
    let (created, _lock) = s.claim_out()?;
    let pool = thread_pool(opts.threads)?;
    let threads = pool.current_num_threads();
    crate::embree::set_flush_denormals();

    let reference = reference(
        scene,
        s.range.clone(),
        (s.w, s.h),
        opts.reference_spp,
        opts.max_depth,
        &opts.cache,
        &pool,
        opts.progress,
    )?;
    // The reference is in hand: the output folder stays (a refusal until here removes it).
    created.keep();
    say_skipped();
    errln!(
        "reference: {} spp, {} ({})",
        reference.spp,
        crate::util::text::printable(&reference.dir.display().to_string()),
        if reference.cached {
            "cached".to_string()
        } else {
            format!("rendered in {:.1} s", reference.seconds)
        }
    );
    if let Some(d) = denoiser.as_mut() {
        d.prepare(s.w as usize, s.h as usize)?;
    }
    let integrator = Integrator::new(scene, opts.max_depth);
    let mut runner = Runner {
        s: &s,
        integrator: &integrator,
        pool: &pool,
        denoiser: &mut denoiser,
    };
    let mut runs: Vec<Run> = Vec::new();
    let mut crops: Vec<Vec<Vec3>> = Vec::new();
    let pb = progress_bar(opts.progress, plan.len() as u64, "runs");
    for p in plan {
        let (run, crop) = runner.measure(&p, &reference)?;
        // Flicker is measured between consecutive frames: none for one frame.
        let shown = if run.per_frame.len() < 2 {
            "-".to_string()
        } else {
            format!("{:.5}", run.flicker)
        };
        pb.suspend(|| {
            errln!(
                "{:>16} window {:>2} spp {:>3}: {:>7.2} s  rmse {:.5}  relMSE {:.5}  flicker {shown}",
                run.method.name(),
                run.window,
                run.spp,
                run.seconds,
                run.rmse,
                run.relmse
            )
        });
        pb.inc(1);
        crops.push(crop);
        runs.push(run);
    }
    pb.finish_and_clear();

    // Cost model: measured on the middle frame, as `reframe bench` does.
    let cam = scene.camera(s.crop_frame(), s.w, s.h);
    let (costs, _, _) = measure_costs(&integrator, &pool, &cam, s.crop_frame(), 2, opts.seed, 1);
    let figures = figures(&runs, &opts.methods, &costs, s.n_frames());

    // Files. A chart that cannot be drawn fails the command, but only after the measurements
    // are written (`compare.csv`, `compare.json`): they are hours of rendering at production
    // sizes.
    let mut charts = Charts {
        out: &opts.out,
        outputs: Vec::new(),
        error: None,
    };
    let strip = s.charts(&runs, &crops, &figures, &reference, threads, &mut charts)?;
    let bias = runner.bias(&runs, &crops, &strip, &reference, &mut charts)?;
    let mut outputs = charts.outputs;
    outputs.extend(bias.iter().map(|b| b.image.clone()));
    let csv_path = opts.out.join("compare.csv");
    write_atomic(&csv_path, csv(&runs).as_bytes())?;
    outputs.push(csv_path.display().to_string());
    let json_path = opts.out.join("compare.json");
    outputs.push(json_path.display().to_string());
    let Figures {
        equal_error_speedup,
        equal_error_speedup_over_denoised,
        predicted,
        measured,
        equal_time,
        denoised_equal_time,
        equal_time_flicker,
        equal_time_relmse,
        denoised_equal_time_flicker,
        denoised_equal_time_relmse,
        ..
    } = figures;
    let report = CompareReport {
        regime: opts.regime,
        scene: scene.name.clone(),
        width: s.w,
        height: s.h,
        first_frame: s.first,
        last_frame: s.last,
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
        equal_error_speedup_over_denoised,
        costs,
        predicted_speedup: predicted,
        measured_speedup: measured,
        equal_time_seconds: equal_time,
        equal_time_flicker,
        equal_time_relmse,
        denoised_equal_time_seconds: denoised_equal_time,
        denoised_equal_time_flicker,
        denoised_equal_time_relmse,
        bias,
        crop: s.crop,
        crop_frame: s.crop_frame(),
        skipped,
        outputs,
    };
    write_json(&json_path, &report)?;
    if let Some(e) = charts.error {
        return Err(e.context(format!(
            "the measurements are in {} and {}, but a chart could not be drawn",
            csv_path.display(),
            json_path.display()
        )));
    }
    Ok(report)
}

/// What `compare` measures, its options checked: the frames, the resolution and the crop.
struct Setting<'a> {
    scene: &'a Scene,
    opts: &'a CompareOptions,
    /// The measured frames.
    range: RangeInclusive<u32>,
    first: u32,
    last: u32,
    w: u32,
    h: u32,
    /// The crop of the strips (x, y, width, height), inside the frame.
    crop: [u32; 4],
}

/// One run of the plan: `c` at `window` and `spp`, rendering the frames `rendered`.
struct Planned {
    c: Candidate,
    window: u32,
    spp: u32,
    rendered: RangeInclusive<u32>,
}

impl<'a> Setting<'a> {
    /// `opts` checked against `scene`, every refusal that needs no render.
    fn check(scene: &'a Scene, opts: &'a CompareOptions) -> Result<Setting<'a>> {
        let range = opts.frames.clone().unwrap_or_else(|| default_frames(scene));
        check_frames(scene, &range)?;
        let (first, last) = (*range.start(), *range.end());
        let (w, h) = opts.res.unwrap_or((scene.width, scene.height));
        check_resolution((w, h))?;
        if let Some(c) = opts.methods.iter().find(|c| c.denoise) {
            crate::image::oidn::check_size(&format!("--methods {}", c.name()), (w, h))?;
        }
        check_max_depth(opts.max_depth)?;
        if let Some(c) = opts.methods.iter().find(|c| c.method.reuses()) {
            check_reuse_film(scene, &range, (w, h), c.method.name())?;
        }
        for &b in &opts.budgets {
            check_spp("--budgets", b)?;
        }
        for &b in &opts.reuse_budgets {
            check_spp("--reuse-budgets", b)?;
        }
        check_threads(opts.threads)?;
        if let Some(&n) = opts.windows.iter().find(|&&n| n % 2 == 0) {
            bail!(
                "--windows {n}: a group is a frame and as many on each side (n_f odd: 3, 5, 7, \
                 ...), so windows must be odd"
            );
        }
        // One given twice would run its renders twice and put two points at one place.
        if let Some(c) = super::first_repeat(&opts.methods) {
            bail!("--methods: {} is given twice", c.name());
        }
        for (flag, list) in [
            ("--budgets", &opts.budgets),
            ("--reuse-budgets", &opts.reuse_budgets),
            ("--windows", &opts.windows),
        ] {
            if let Some(b) = super::first_repeat(list) {
                bail!("{flag}: {b} is given twice");
            }
        }
        if opts.methods.iter().any(|c| !c.method.reuses()) && opts.budgets.is_empty() {
            bail!("--budgets: the independent tracer needs at least one budget");
        }
        if opts.bias_seeds == 1 {
            bail!("--bias-seeds 1: a bias estimate needs at least 2 seeds (0: no bias images)");
        }
        if opts.bias_seeds > MAX_BIAS_SEEDS {
            bail!(
                "--bias-seeds {}: at most {MAX_BIAS_SEEDS} (each seed renders every denoised \
                 method's strip again)",
                opts.bias_seeds
            );
        }
        // The default crop: a centred square of half the shorter side.
        let side = (w.min(h) / 2).max(1);
        let crop = opts
            .crop
            .unwrap_or([(w - side) / 2, (h - side) / 2, side, side]);
        let [x, y, cw, ch] = crop;
        if cw == 0 || ch == 0 {
            bail!("--crop {x},{y},{cw},{ch}: empty (X,Y,W,H: its width and height must be at least 1)");
        }
        let inside = |x: u32, cw: u32, limit: u32| x.checked_add(cw).is_some_and(|e| e <= limit);
        if !inside(x, cw, w) || !inside(y, ch, h) {
            bail!("--crop {x},{y},{cw},{ch}: not inside the {w}x{h} frame");
        }
        Ok(Setting {
            scene,
            opts,
            range,
            first,
            last,
            w,
            h,
            crop,
        })
    }

    fn n_frames(&self) -> u32 {
        self.last - self.first + 1
    }

    /// The frame of the strips: the middle of the measured ones.
    fn crop_frame(&self) -> u32 {
        self.first + self.n_frames() / 2
    }

    /// Every run, and the runs left out with why (a window longer than the frames, or whose
    /// steady state needs frames the scene lacks).
    fn plan(&self) -> (Vec<Planned>, Vec<String>) {
        let (opts, first, last, n_frames) = (self.opts, self.first, self.last, self.n_frames());
        let frames = self.scene.frames;
        let mut plan = Vec::new();
        let mut skipped = Vec::new();
        for &c in &opts.methods {
            let mut add = |window: u32, spp: &[u32], rendered: RangeInclusive<u32>| {
                plan.extend(spp.iter().map(|&spp| Planned {
                    c,
                    window,
                    spp,
                    rendered: rendered.clone(),
                }))
            };
            if !c.method.reuses() {
                add(1, &opts.budgets, self.range.clone());
                continue;
            }
            for &n_f in &opts.windows {
                match opts.regime {
                    Regime::Range if n_f <= n_frames => {
                        add(n_f, &opts.reuse_budgets, self.range.clone())
                    }
                    Regime::Steady if first >= n_f - 1 && last + n_f - 1 < frames => {
                        add(n_f, &opts.reuse_budgets, first + 1 - n_f..=last + n_f - 1)
                    }
                    Regime::Range => {
                        skipped.push(format!("{c} n_f {n_f}: longer than the {n_frames} frames"))
                    }
                    Regime::Steady => skipped.push(format!(
                        "{c} n_f {n_f}: its steady state needs frames {} to {}, the scene has 0 \
                         to {}",
                        first as i64 + 1 - n_f as i64,
                        last + n_f - 1,
                        frames - 1
                    )),
                }
            }
        }
        (plan, skipped)
    }

    /// The render of planned run `p` with `seed`.
    fn spec(&self, p: &Planned, seed: u64) -> RunSpec {
        RunSpec {
            c: p.c,
            window: p.window,
            spp: p.spp,
            seed,
            rendered: p.rendered.clone(),
            res: (self.w, self.h),
            max_depth: self.opts.max_depth,
            threads: self.opts.threads,
        }
    }

    /// The output folder made (removed again by the guard unless kept), checked writable,
    /// nothing in it that is an input of the scene, and locked against another `compare`.
    fn claim_out(&self) -> Result<(CreatedDirs, OutputLock)> {
        let out = &self.opts.out;
        let created = CreatedDirs::create(out)
            .with_context(|| format!("--out {}: cannot create the folder", out.display()))?;
        check_writable_dir(out).with_context(|| format!("--out {}", out.display()))?;
        let written = [
            "compare.json",
            "compare.csv",
            "error_vs_time.png",
            "error_vs_time.svg",
            "speedup_vs_nf.png",
            "speedup_vs_nf.svg",
            "flicker.png",
            "flicker.svg",
            "flicker_denoised.png",
            "flicker_denoised.svg",
            "crops.png",
            "crops.svg",
            "bias.png",
            "bias.svg",
            ".compare.lock",
        ];
        let bias_files: Vec<String> = self
            .opts
            .methods
            .iter()
            .map(|c| format!("bias_{}.exr", c.name()))
            .collect();
        check_outputs(
            written
                .iter()
                .copied()
                .chain(bias_files.iter().map(String::as_str))
                .map(|n| ("--out", out.join(n))),
            &self.scene.inputs,
        )?;
        let lock =
            OutputLock::acquire(&out.join(".compare.lock"), &out.display().to_string(), None)?;
        Ok((created, lock))
    }

    /// The charts of the runs and their `figures` (error against time, speed-up against
    /// `n_f`, flicker at equal time, the crop strip), through `charts`. Gives back the strip:
    /// its reference tile, each widest line's run in it, and its zoom (the bias strip's too).
    fn charts(
        &self,
        runs: &[Run],
        crops: &[Vec<Vec3>],
        figures: &Figures,
        reference: &Reference,
        threads: usize,
        charts: &mut Charts,
    ) -> Result<Strip> {
        let (scene, w, h, first, last) = (self.scene, self.w, self.h, self.first, self.last);
        let (crop, crop_frame) = (self.crop, self.crop_frame());
        let Figures {
            lines,
            widest,
            equal_error_speedup,
            predicted,
            measured,
            equal_time,
            denoised_equal_time,
            equal_time_flicker,
            denoised_equal_time_flicker,
            ..
        } = figures;
        let key = |r: &Run| (r.method, r.window);
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
            // Every method at its widest window, solid; the unbiased methods' narrower windows
            // dashed.
            series: lines
                .iter()
                .filter(|l| !l.0.method.reuses() || l.1 == max_window)
                .map(|&l| (l, false))
                .chain(
                    lines
                        .iter()
                        .filter(|l| {
                            matches!(l.0.method, Method::MisExact | Method::MisCv)
                                && l.1 != max_window
                        })
                        .map(|&l| (l, true)),
                )
                .map(|((c, n_f), dashed)| Series {
                    name: line_label(c, n_f),
                    colour: c.colour(),
                    dashed,
                    points: runs
                        .iter()
                        .filter(|r| key(r) == (c, n_f))
                        .map(|r| (r.seconds, r.relmse))
                        .collect(),
                })
                .collect(),
        };
        charts.write(chart1.svg(), "error_vs_time");
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
                    points: num_points(predicted),
                },
                Series {
                    name: "measured, same spp".into(),
                    colour: COLOURS[3],
                    dashed: false,
                    points: num_points(measured),
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
        charts.write(chart2.svg(), "speedup_vs_nf");
        // Each widest line's fitted flicker in `at` as a bar.
        let flicker_bars = |at: &BTreeMap<String, f64>| -> Vec<(String, f64, &str)> {
            widest
                .iter()
                .filter_map(|&(c, n_f)| {
                    at.get(&c.name())
                        .map(|&v| (line_label(c, n_f), v, c.colour()))
                })
                .collect()
        };
        const FLICKER_AXIS: &str = "flicker (RMS frame-to-frame change of the error)";
        charts.write(
            bar_chart(
                &format!("{}: flicker at equal time ({equal_time:.1} s)", scene.name),
                FLICKER_AXIS,
                &flicker_bars(equal_time_flicker),
            ),
            "flicker",
        );
        if let Some(t) = denoised_equal_time {
            charts.write(
                bar_chart(
                    &format!(
                        "{}: flicker at the denoised equal time ({t:.1} s)",
                        scene.name
                    ),
                    FLICKER_AXIS,
                    &flicker_bars(denoised_equal_time_flicker),
                ),
                "flicker_denoised",
            );
        }
        // The crop strip: each method's run closest in time to a reference time, the cheapest
        // widest run of mis-exact (else of the first reuse method compared; else equal time).
        let strip_time = [Candidate::plain(Method::MisExact)]
            .into_iter()
            .chain(
                self.opts
                    .methods
                    .iter()
                    .copied()
                    .filter(|c| c.method.reuses()),
            )
            .map(|c| {
                runs.iter()
                    .filter(|r| r.method == c && r.window == max_window)
                    .map(|r| r.seconds)
                    .fold(f64::INFINITY, f64::min)
            })
            .find(|t| t.is_finite())
            .unwrap_or(*equal_time);
        let ref_crop = &reference.frames[(crop_frame - first) as usize];
        let reference_tile = (
            format!("reference\n{} spp", reference.spp),
            crop_png(&ref_crop.mean, w, crop)?,
            crop[2],
            crop[3],
        );
        let mut tiles = vec![reference_tile.clone()];
        let mut strip_runs: Vec<(Candidate, usize)> = Vec::new();
        for &(c, n_f) in widest {
            let best = runs
                .iter()
                .enumerate()
                .filter(|(_, r)| key(r) == (c, n_f))
                .min_by(|a, b| {
                    let d = |r: &Run| (r.seconds / strip_time).ln().abs();
                    d(a.1).total_cmp(&d(b.1))
                });
            if let Some((i, r)) = best {
                strip_runs.push((c, i));
                tiles.push((
                    format!("{c}\n{}, {:.2} s", run_label(r), r.seconds),
                    crop_png(&crops[i], w, crop)?,
                    crop[2],
                    crop[3],
                ));
            }
        }
        let zoom = (240 / crop[2].max(crop[3])).clamp(1, 8);
        charts.write(
            image_strip(
                &format!(
                    "{}: frame {crop_frame}, crop {}x{} at ({}, {}), about {strip_time:.2} s each",
                    scene.name, crop[2], crop[3], crop[0], crop[1]
                ),
                &tiles,
                zoom,
            ),
            "crops",
        );
        Ok(Strip {
            reference_tile,
            runs: strip_runs,
            zoom,
        })
    }
}

/// A line's name in the charts: the method, with its window where it reuses.
fn line_label(c: Candidate, n_f: u32) -> String {
    if c.method.reuses() {
        format!("{c} n_f={n_f}")
    } else {
        c.name()
    }
}

/// The crop strip as `Setting::charts` drew it.
struct Strip {
    /// The reference's tile (the bias strip starts with it too).
    reference_tile: (String, Vec<u8>, u32, u32),
    /// (candidate, index of its run) per widest line.
    runs: Vec<(Candidate, usize)>,
    zoom: u32,
}

/// Where `compare`'s charts go: the files written, and the first chart that could not be drawn
/// (reported after the measurements are written).
struct Charts<'a> {
    out: &'a Path,
    outputs: Vec<String>,
    error: Option<anyhow::Error>,
}

impl Charts<'_> {
    /// `svg` as `<stem>.svg` and `<stem>.png`.
    fn write(&mut self, svg: String, stem: &str) {
        let p = self.out.join(stem);
        match write_svg_png(&svg, &p) {
            Ok(()) => {
                self.outputs
                    .push(p.with_extension("png").display().to_string());
                self.outputs
                    .push(p.with_extension("svg").display().to_string());
            }
            Err(e) => {
                self.error.get_or_insert(e);
            }
        }
    }
}

/// What the runs share: the setting, the tracer, the worker pool and the denoiser.
struct Runner<'a, 'b> {
    s: &'b Setting<'a>,
    integrator: &'b Integrator<'a>,
    pool: &'b rayon::ThreadPool,
    denoiser: &'b mut Option<Denoiser>,
}

impl Runner<'_, '_> {
    /// Planned run `p` rendered and measured against `reference`, and its crop frame.
    fn measure(&mut self, p: &Planned, reference: &Reference) -> Result<(Run, Vec<Vec3>)> {
        let s = self.s;
        let (opts, range, first, last) = (s.opts, &s.range, s.first, s.last);
        let (method, window, spp) = (p.c, p.window, p.spp);
        let reuses = method.method.reuses();
        let mut out = render_run(
            self.integrator,
            self.pool,
            self.denoiser,
            &s.spec(p, opts.seed),
            range,
        )?;
        let mut frames = std::mem::take(&mut out.frames);
        let eff = if reuses {
            let measured: Vec<f64> = out
                .counters
                .per_frame
                .iter()
                .filter(|f| range.contains(&f.frame))
                .map(|f| f.mean_effective_spp)
                .collect();
            measured.iter().sum::<f64>() / measured.len() as f64
        } else {
            spp as f64
        };
        let run_seconds = out.run_seconds;
        // The steady state charges the measured frames one group's time each (denoising is per
        // measured frame already).
        let groups = p.rendered.end() + 2 - p.rendered.start() - window;
        let render_seconds = run_seconds - out.denoise_seconds;
        let seconds = out.denoise_seconds
            + if opts.regime == Regime::Steady && reuses {
                render_seconds * s.n_frames() as f64 / groups as f64
            } else {
                render_seconds
            };
        let (per_frame, rmse, relmse, flicker) = errors(&frames, reference);
        let (ends_relmse, middle_relmse) = if opts.regime == Regime::Range && reuses {
            let mean =
                |v: Vec<f64>| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
            let at_end = |f: u32| f < first + window - 1 || f + window - 1 > last;
            let (ends, middle): (Vec<&FrameError>, Vec<&FrameError>) =
                per_frame.iter().partition(|e| at_end(e.frame));
            (
                mean(ends.iter().map(|e| e.relmse).collect()),
                mean(middle.iter().map(|e| e.relmse).collect()),
            )
        } else {
            (None, None)
        };
        let crop = frames.swap_remove((s.crop_frame() - first) as usize);
        let run = Run {
            method,
            window,
            spp,
            seconds,
            denoise_seconds: out.denoise_seconds,
            run_seconds,
            rendered_frames: [*p.rendered.start(), *p.rendered.end()],
            ends_relmse,
            middle_relmse,
            rmse,
            relmse,
            flicker,
            mean_effective_spp: eff,
            per_frame,
        };
        Ok((run, crop))
    }

    /// The bias images: the denoised methods' strip runs (and independent's, whose bias is
    /// zero: the scale of what the seeds leave of the noise), rendered again with more seeds,
    /// each written as an EXR of its mean less the reference, and their strip.
    fn bias(
        &mut self,
        runs: &[Run],
        crops: &[Vec<Vec3>],
        strip: &Strip,
        reference: &Reference,
        charts: &mut Charts,
    ) -> Result<Vec<Bias>> {
        let s = self.s;
        let (opts, scene, w, crop, crop_frame) = (s.opts, s.scene, s.w, s.crop, s.crop_frame());
        if opts.bias_seeds < 2 {
            return Ok(Vec::new());
        }
        let any_denoised = strip.runs.iter().any(|(c, _)| c.denoise);
        let bias_runs = strip
            .runs
            .iter()
            .copied()
            .filter(|(c, _)| c.denoise || (any_denoised && *c == INDEPENDENT));
        let ref_crop = &reference.frames[(crop_frame - s.first) as usize];
        let mut bias = Vec::new();
        let mut bias_images: Vec<(Candidate, String, Vec<Vec3>)> = Vec::new();
        for (c, i) in bias_runs {
            let r = &runs[i];
            // The crop frame in all of its groups, as in the measured run.
            let span = match opts.regime {
                Regime::Steady if c.method.reuses() => {
                    crop_frame + 1 - r.window..=crop_frame + r.window - 1
                }
                Regime::Range if c.method.reuses() => r.rendered_frames[0]..=r.rendered_frames[1],
                _ => crop_frame..=crop_frame,
            };
            let planned = Planned {
                c,
                window: r.window,
                spp: r.spp,
                rendered: span,
            };
            let mut seeds = vec![crops[i].clone()];
            let start = Instant::now();
            for k in 1..opts.bias_seeds {
                let out = render_run(
                    self.integrator,
                    self.pool,
                    self.denoiser,
                    &s.spec(&planned, opts.seed.wrapping_add(k as u64)),
                    &(crop_frame..=crop_frame),
                )?;
                seeds.extend(out.frames);
            }
            let (b, mean) = bias_estimate(&seeds, ref_crop);
            let path = opts.out.join(format!("bias_{}.exr", c.name()));
            let diff: Vec<Vec3> = mean
                .iter()
                .zip(&ref_crop.mean)
                .map(|(m, r)| *m - *r)
                .collect();
            write_bias_exr(
                &path,
                &diff,
                &scene.camera(crop_frame, w, s.h),
                &c,
                r,
                opts.seed,
                opts.bias_seeds,
            )?;
            errln!(
                "{:>16} bias over {} seeds ({:.1} s): bias {:.5} of relMSE {:.5}",
                c.name(),
                opts.bias_seeds,
                start.elapsed().as_secs_f64(),
                b.bias_relmse,
                b.relmse
            );
            bias_images.push((c, run_label(r), mean));
            bias.push(Bias {
                method: c,
                window: r.window,
                spp: r.spp,
                seeds: opts.bias_seeds,
                frame: crop_frame,
                bias_relmse: b.bias_relmse,
                relmse: b.relmse,
                relmse_of_mean: b.relmse_of_mean,
                image: path.display().to_string(),
            });
        }
        if bias_images.is_empty() {
            return Ok(bias);
        }
        // One scale for every tile: the 99th percentile of |mean - reference| in the crops.
        let diffs: Vec<Vec<f32>> = bias_images
            .iter()
            .map(|(_, _, m)| crop_diff(m, &ref_crop.mean, w, crop))
            .collect();
        let scale = percentile_abs(diffs.iter().flatten().copied(), 0.99).max(1e-6);
        let mut tiles = vec![strip.reference_tile.clone()];
        for ((c, what, _), d) in bias_images.iter().zip(&diffs) {
            tiles.push((
                format!("{c} mean - ref\n{what}, {} seeds", opts.bias_seeds),
                diverging_png(d, crop[2], crop[3], scale)?,
                crop[2],
                crop[3],
            ));
        }
        charts.write(
            image_strip(
                &format!(
                    "{}: frame {crop_frame}, mean over {} seeds minus the reference (luminance; \
                     red +, blue -, full colour at {scale:.3})",
                    scene.name, opts.bias_seeds
                ),
                &tiles,
                strip.zoom,
            ),
            "bias",
        );
        Ok(bias)
    }
}

/// `compare.csv`: one line per run.
fn csv(runs: &[Run]) -> String {
    let mut csv = String::from(
        "method,window,spp,seconds,rmse,relmse,flicker,mean_effective_spp,denoise_seconds\n",
    );
    for r in runs {
        let _ = writeln!(
            csv,
            "{},{},{},{:.6},{:.8},{:.8},{},{:.3},{:.6}",
            r.method.name(),
            r.window,
            r.spp,
            r.seconds,
            r.rmse,
            r.relmse,
            if r.flicker.is_nan() {
                String::new()
            } else {
                format!("{:.8}", r.flicker)
            },
            r.mean_effective_spp,
            r.denoise_seconds
        );
    }
    csv
}

/// The independent tracer as `compare` runs it, plain and denoised: the baselines of its
/// speed-ups.
const INDEPENDENT: Candidate = Candidate::plain(Method::Independent);
const INDEPENDENT_OIDN: Candidate = Candidate::denoised(Method::Independent);

/// What `compare` derives from its runs (`figures`), before its files are written.
struct Figures {
    /// Each (method, window) measured, in the runs' order, and each method at its widest.
    lines: Vec<(Candidate, u32)>,
    widest: Vec<(Candidate, u32)>,
    /// By method and window: the time of the independent tracer's fitted line (plain, or
    /// denoised) over the method's at the geometric mean of the method's errors.
    equal_error_speedup: BTreeMap<String, BTreeMap<String, f64>>,
    equal_error_speedup_over_denoised: BTreeMap<String, BTreeMap<String, f64>>,
    /// By window: eq. 16's speed-up with the measured costs, and `mis-exact`'s measured one.
    predicted: BTreeMap<String, f64>,
    measured: BTreeMap<String, f64>,
    /// The equal time of the plain lines and of the denoised ones, and the widest lines' fitted
    /// flicker and relMSE there.
    equal_time: f64,
    denoised_equal_time: Option<f64>,
    equal_time_flicker: BTreeMap<String, f64>,
    equal_time_relmse: BTreeMap<String, f64>,
    denoised_equal_time_flicker: BTreeMap<String, f64>,
    denoised_equal_time_relmse: BTreeMap<String, f64>,
}

/// The fits of `runs` (of `n_frames` measured frames, for `methods`, with the cost model's
/// `costs`) and the figures derived from them.
fn figures(runs: &[Run], methods: &[Candidate], costs: &Costs, n_frames: u32) -> Figures {
    let key = |r: &Run| (r.method, r.window);
    let mut lines: Vec<(Candidate, u32)> = runs.iter().map(key).collect();
    lines.dedup();
    let fit_of = |c: Candidate, n_f: u32, y: fn(&Run) -> f64, single: f64| {
        let pts: Vec<(f64, f64)> = runs
            .iter()
            .filter(|r| key(r) == (c, n_f))
            .map(|r| (r.seconds, y(r)))
            .collect();
        loglog_fit(&pts, single)
    };
    // Time of `base`'s line over the time of `(c, n_f)`'s line at the geometric mean of the
    // latter's errors.
    let speedup_over = |base: Candidate, c: Candidate, n_f: u32| -> Option<f64> {
        let own: Vec<f64> = runs
            .iter()
            .filter(|r| key(r) == (c, n_f) && r.relmse > 0.0)
            .map(|r| r.relmse.ln())
            .collect();
        let fi = fit_of(base, 1, |r| r.relmse, -1.0)?;
        let fm = fit_of(c, n_f, |r| r.relmse, -1.0)?;
        if own.is_empty() {
            return None;
        }
        let e = (own.iter().sum::<f64>() / own.len() as f64).exp();
        Some(time_for(fi, e)? / time_for(fm, e)?)
    };
    let mut equal_error_speedup: BTreeMap<String, BTreeMap<String, f64>> = BTreeMap::new();
    let mut equal_error_speedup_over_denoised: BTreeMap<String, BTreeMap<String, f64>> =
        BTreeMap::new();
    for &(c, n_f) in lines.iter().filter(|l| l.0 != INDEPENDENT) {
        if let Some(x) = speedup_over(INDEPENDENT, c, n_f) {
            equal_error_speedup
                .entry(c.name())
                .or_default()
                .insert(n_f.to_string(), x);
        }
        if c.denoise && c != INDEPENDENT_OIDN {
            if let Some(x) = speedup_over(INDEPENDENT_OIDN, c, n_f) {
                equal_error_speedup_over_denoised
                    .entry(c.name())
                    .or_default()
                    .insert(n_f.to_string(), x);
            }
        }
    }
    // Same-sample speed-up of mis-exact: independent time per frame and sample, times the
    // samples per frame the groups would give without losses, over the reuse time.
    let mut per_sample: Vec<f64> = runs
        .iter()
        .filter(|r| r.method == INDEPENDENT)
        .map(|r| r.seconds / (n_frames * r.spp) as f64)
        .collect();
    per_sample.sort_by(f64::total_cmp);
    let t_sample = per_sample.get(per_sample.len() / 2).copied();
    let mut predicted = BTreeMap::new();
    let mut measured = BTreeMap::new();
    let mut windows: Vec<u32> = runs
        .iter()
        .filter(|r| r.method.method.reuses())
        .map(|r| r.window)
        .collect();
    windows.sort_unstable();
    windows.dedup();
    for &n_f in &windows {
        predicted.insert(
            n_f.to_string(),
            predicted_speedup(n_f, costs.c_e, costs.c_l, costs.c_v_packet),
        );
        let ratios: Vec<f64> = runs
            .iter()
            .filter(|r| r.method == Candidate::plain(Method::MisExact) && r.window == n_f)
            .filter_map(|r| {
                // Groups of the run, each worth n_f^2 n_r samples per pixel without losses.
                let groups = (r.rendered_frames[1] + 2 - r.rendered_frames[0] - n_f) as f64;
                let ideal = groups * (n_f * n_f * r.spp) as f64;
                t_sample.map(|t| t * ideal / r.run_seconds)
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
            .filter(|r| r.method == INDEPENDENT)
            .map(|r| r.seconds)
            .collect();
        // Without independent runs, the plain runs' times (else all of them).
        let plain: Vec<f64> = runs
            .iter()
            .filter(|r| !r.method.denoise)
            .map(|r| r.seconds)
            .collect();
        match (ind.is_empty(), plain.is_empty()) {
            (false, _) => ind,
            (true, false) => plain,
            (true, true) => runs.iter().map(|r| r.seconds).collect(),
        }
    };
    let equal_time = geomean(&times);
    // Each method at its largest window.
    let widest: Vec<(Candidate, u32)> = methods
        .iter()
        .filter_map(|&c| {
            lines
                .iter()
                .filter(|l| l.0 == c)
                .max_by_key(|l| l.1)
                .copied()
        })
        .collect();
    // The denoised lines' equal time: the geometric mean of `independent+oidn`'s times (or of
    // all denoised runs'); denoising a frame costs a fixed time, so theirs is longer.
    let denoised_equal_time = {
        let pick = |f: &dyn Fn(&Run) -> bool| -> Vec<f64> {
            runs.iter().filter(|r| f(r)).map(|r| r.seconds).collect()
        };
        let mut t = pick(&|r| r.method == INDEPENDENT_OIDN);
        if t.is_empty() {
            t = pick(&|r| r.method.denoise);
        }
        (!t.is_empty()).then(|| geomean(&t))
    };
    // Fitted flicker and relMSE of the widest lines at time `t`.
    let at_time = |t: f64, keep: &dyn Fn(Candidate) -> bool| {
        let (mut flicker, mut relmse) = (BTreeMap::new(), BTreeMap::new());
        for &(c, n_f) in widest.iter().filter(|l| keep(l.0)) {
            if let Some((a, b)) = fit_of(c, n_f, |r| r.flicker, -0.5) {
                flicker.insert(c.name(), (a + b * t.ln()).exp());
            }
            if let Some((a, b)) = fit_of(c, n_f, |r| r.relmse, -1.0) {
                relmse.insert(c.name(), (a + b * t.ln()).exp());
            }
        }
        (flicker, relmse)
    };
    let (equal_time_flicker, equal_time_relmse) = at_time(equal_time, &|c| !c.denoise);
    let (denoised_equal_time_flicker, denoised_equal_time_relmse) = match denoised_equal_time {
        Some(t) => at_time(t, &|_| true),
        None => Default::default(),
    };
    Figures {
        lines,
        widest,
        equal_error_speedup,
        equal_error_speedup_over_denoised,
        predicted,
        measured,
        equal_time,
        denoised_equal_time,
        equal_time_flicker,
        equal_time_relmse,
        denoised_equal_time_flicker,
        denoised_equal_time_relmse,
    }
}

/// The table `reframe compare` prints: one line per run, then the speed-ups.
pub fn summary(r: &CompareReport) -> String {
    let mut s = format!(
        "{:<17} {:>6} {:>4} {:>9} {:>10} {:>10} {:>10}\n",
        "method", "window", "spp", "seconds", "rmse", "relMSE", "flicker"
    );
    for run in &r.runs {
        let _ = writeln!(
            s,
            "{:<17} {:>6} {:>4} {:>9.2} {:>10.5} {:>10.5} {:>10}",
            run.method.name(),
            run.window,
            run.spp,
            run.seconds,
            run.rmse,
            run.relmse,
            if run.per_frame.len() < 2 {
                "-".to_string()
            } else {
                format!("{:.5}", run.flicker)
            }
        );
    }
    let speedups = [
        ("independent", &r.equal_error_speedup),
        ("independent+oidn", &r.equal_error_speedup_over_denoised),
    ];
    for (base, map) in speedups {
        for (m, by_window) in map {
            let v: Vec<String> = num_points(by_window)
                .iter()
                .map(|(n, x)| format!("n_f {n}: {x:.2}x"))
                .collect();
            let _ = writeln!(
                s,
                "equal-error speed-up of {m} over {base}: {}",
                v.join(", ")
            );
        }
    }
    let times = [
        (
            Some(r.equal_time_seconds),
            &r.equal_time_flicker,
            &r.equal_time_relmse,
        ),
        (
            r.denoised_equal_time_seconds,
            &r.denoised_equal_time_flicker,
            &r.denoised_equal_time_relmse,
        ),
    ];
    for (t, flicker, relmse) in times {
        let Some(t) = t.filter(|_| !flicker.is_empty()) else {
            continue;
        };
        let v: Vec<String> = flicker
            .iter()
            .map(|(m, f)| {
                let e = relmse.get(m).copied().unwrap_or(f64::NAN);
                format!("{m} {f:.5} ({e:.5})")
            })
            .collect();
        let _ = writeln!(
            s,
            "at equal time ({t:.2} s), flicker (relMSE): {}",
            v.join(", ")
        );
    }
    let p: Vec<String> = num_points(&r.predicted_speedup)
        .iter()
        .map(|(n, x)| match r.measured_speedup.get(&n.to_string()) {
            Some(m) => format!("n_f {n}: {x:.2}x / {m:.2}x"),
            // The measured speed-up is a mis-exact run's time against the independent
            // runs' time per sample: say which of the two is missing.
            None if r.runs.iter().any(|run| {
                run.method == Candidate::plain(Method::MisExact) && run.window as f64 == *n
            }) =>
            {
                format!("n_f {n}: {x:.2}x / - (no independent run to measure it against)")
            }
            None => format!("n_f {n}: {x:.2}x / - (no mis-exact run)"),
        })
        .collect();
    if !p.is_empty() {
        let _ = write!(s, "same-spp speed-up, eq. 16 / measured: {}", p.join(", "));
    }
    if let Some(note) = short_run_note(&r.runs) {
        let _ = write!(s, "\n{note}");
    }
    s
}

/// A note where a run took under `SHORT_RUN_SECONDS` (its whole time, not the share charged
/// to the measured frames): such runs are mostly the fixed costs of a render (threads, films),
/// which the speed-ups then read (two runs of 8x6 frames gave 0.10x and 0.08x).
fn short_run_note(runs: &[Run]) -> Option<String> {
    let shortest = runs
        .iter()
        .map(|run| run.run_seconds)
        .fold(f64::INFINITY, f64::min);
    (shortest < SHORT_RUN_SECONDS).then(|| {
        format!(
            "note: a timed run took {shortest:.3} s, under {SHORT_RUN_SECONDS} s: too short for \
             the speed-ups and the equal-time figures to mean much; give a larger --res, \
             --budgets or --reuse-budgets"
        )
    })
}

/// The geometric mean of positive `v` (not empty).
fn geomean(v: &[f64]) -> f64 {
    (v.iter().map(|t| t.ln()).sum::<f64>() / v.len() as f64).exp()
}

/// What a run rendered, for a tile's label: samples per pixel, and the window of a reuse run.
fn run_label(r: &Run) -> String {
    if r.method.method.reuses() {
        format!("{} spp, n_f {}", r.spp, r.window)
    } else {
        format!("{} spp", r.spp)
    }
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
fn crop_png(px: &[Vec3], w: u32, [x0, y0, cw, ch]: [u32; 4]) -> Result<Vec<u8>> {
    let mut img = Image::new(cw, ch, &["R", "G", "B"]);
    img.data = (y0..y0 + ch)
        .flat_map(|y| (x0..x0 + cw).map(move |x| (x, y)))
        .flat_map(|(x, y)| px[(y * w + x) as usize].to_array())
        .collect();
    rgb8_png(&crate::image::encode_srgb8(&img)?, cw, ch)
}

/// 8-bit RGB triples as a PNG.
fn rgb8_png(rgb: &[u8], cw: u32, ch: u32) -> Result<Vec<u8>> {
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

/// One render of `compare`.
struct RunSpec {
    c: Candidate,
    window: u32,
    spp: u32,
    seed: u64,
    /// The frames rendered.
    rendered: RangeInclusive<u32>,
    res: (u32, u32),
    max_depth: u32,
    /// `--threads` (0: one per core), for the memory the run's check counts.
    threads: usize,
}

impl RunSpec {
    /// The render this run is.
    fn options(&self) -> RenderOptions {
        RenderOptions {
            method: self.c.method,
            spp: self.spp,
            window: self.window,
            seed: self.seed,
            frames: Some(self.rendered.clone()),
            resolution: Some(self.res),
            max_depth: self.max_depth,
            threads: self.threads,
            progress: false,
            ..RenderOptions::default()
        }
    }
}

/// What `render_run` gives back.
struct Rendered {
    /// The kept frames, in order.
    frames: Vec<Vec<Vec3>>,
    counters: Counters,
    /// The whole run, denoising included.
    run_seconds: f64,
    denoise_seconds: f64,
}

/// Render `spec`, keeping the frames in `keep`, each denoised (with the render's seed for its
/// guides) when the candidate asks; only kept frames are denoised, and timed.
fn render_run(
    integrator: &Integrator,
    pool: &rayon::ThreadPool,
    denoiser: &mut Option<Denoiser>,
    spec: &RunSpec,
    keep: &RangeInclusive<u32>,
) -> Result<Rendered> {
    let start = Instant::now();
    let ropts = spec.options();
    let mut frames = Vec::new();
    let mut denoise_seconds = 0.0;
    let mut sink = |mut d: Developed| {
        if keep.contains(&d.view.frame) {
            if spec.c.denoise {
                let dn = denoiser
                    .as_mut()
                    .context("a denoised method without a denoiser")?;
                denoise_seconds +=
                    denoise_frame(dn, integrator, spec.seed, Layers::None, &mut d)?.seconds;
            }
            frames.push(d.pixels());
        }
        Ok(())
    };
    let counters = pool.install(|| render_frames(integrator, &ropts, &mut sink))?;
    Ok(Rendered {
        frames,
        counters,
        run_seconds: start.elapsed().as_secs_f64(),
        denoise_seconds,
    })
}

/// The luminance of `mean - reference` over the crop, row by row.
fn crop_diff(mean: &[Vec3], reference: &[Vec3], w: u32, [x0, y0, cw, ch]: [u32; 4]) -> Vec<f32> {
    const LUMA: Vec3 = Vec3::new(0.2126, 0.7152, 0.0722);
    (y0..y0 + ch)
        .flat_map(|y| (x0..x0 + cw).map(move |x| (y * w + x) as usize))
        .map(|i| (mean[i] - reference[i]).dot(LUMA))
        .collect()
}

/// The `q` quantile of `|v|` (0 for no values; non-finite values skipped).
fn percentile_abs(v: impl Iterator<Item = f32>, q: f64) -> f32 {
    let mut a: Vec<f32> = v.filter(|x| x.is_finite()).map(f32::abs).collect();
    if a.is_empty() {
        return 0.0;
    }
    a.sort_by(f32::total_cmp);
    a[((a.len() - 1) as f64 * q).round() as usize]
}

/// Signed values as a PNG: white at 0, towards red for positive and blue for negative, full
/// colour at `scale` and beyond.
fn diverging_png(d: &[f32], cw: u32, ch: u32, scale: f32) -> Result<Vec<u8>> {
    let rgb: Vec<u8> = d
        .iter()
        .flat_map(|&v| {
            let t = if v.is_finite() {
                (v / scale).clamp(-1.0, 1.0)
            } else {
                0.0
            };
            let fade = (255.0 * (1.0 - t.abs())).round() as u8;
            if t >= 0.0 {
                [255, fade, fade]
            } else {
                [fade, fade, 255]
            }
        })
        .collect();
    rgb8_png(&rgb, cw, ch)
}

/// `mean - reference` of a bias estimate as a float EXR, with what made it in its metadata.
fn write_bias_exr(
    path: &std::path::Path,
    diff: &[Vec3],
    cam: &crate::camera::Camera,
    c: &Candidate,
    r: &Run,
    seed: u64,
    seeds: u32,
) -> Result<()> {
    let mut img = Image::new(cam.width, cam.height, &["R", "G", "B"]);
    img.data = diff.iter().flat_map(|v| v.to_array()).collect();
    let meta = Metadata {
        method: c.name(),
        spp: r.spp,
        window: r.window,
        seed,
        // The measured run's charged time (the other seeds' renders are not timed).
        render_seconds: r.seconds,
        world_to_camera: cam.world_to_camera().to_cols_array(),
        world_to_ndc: cam.world_to_ndc().to_cols_array(),
        extra: vec![
            (
                "content".into(),
                "mean over seeds minus the reference".into(),
            ),
            (
                "seeds".into(),
                format!("{seeds} ({seed}..={})", seed.wrapping_add(seeds as u64 - 1)),
            ),
        ],
    };
    write_image(path, &img, &meta, &WriteOptions { exr_float: true })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(method: Candidate, window: u32, seconds: f64, relmse: f64) -> Run {
        Run {
            method,
            window,
            spp: 1,
            seconds,
            denoise_seconds: 0.0,
            run_seconds: seconds,
            rendered_frames: [0, 9],
            rmse: relmse.sqrt(),
            relmse,
            flicker: relmse.sqrt(),
            mean_effective_spp: 1.0,
            ends_relmse: None,
            middle_relmse: None,
            per_frame: Vec::new(),
        }
    }

    #[test]
    fn runs_too_short_to_time_are_said_by_their_whole_time() {
        let ind = Candidate::plain(Method::Independent);
        let mut runs = vec![run(ind, 1, 0.2, 0.1), run(ind, 1, 0.4, 0.05)];
        assert_eq!(short_run_note(&runs), None);
        // A steady-state run charged 0.01 s of its 0.3 s is timed well enough.
        runs[0].seconds = 0.01;
        runs[0].run_seconds = 0.3;
        assert_eq!(short_run_note(&runs), None);
        runs[1].run_seconds = 0.004;
        let note = short_run_note(&runs).unwrap();
        assert!(
            note.starts_with("note: a timed run took 0.004 s, under 0.05 s"),
            "{note}"
        );
    }

    #[test]
    fn figures_read_equal_error_and_equal_time_off_the_fitted_lines() {
        // The independent tracer's error falls as 1/t; mis-cv's at window 5 is a quarter of it
        // at every time, and a denoised independent tracer's a half: to reach any error the
        // independent tracer takes 4 times mis-cv's time, and the denoised one twice it.
        let (ind, cv) = (
            Candidate::plain(Method::Independent),
            Candidate::plain(Method::MisCv),
        );
        let (ind_oidn, cv_oidn) = (
            Candidate::denoised(Method::Independent),
            Candidate::denoised(Method::MisCv),
        );
        let mut runs = Vec::new();
        for t in [1.0, 2.0, 4.0, 8.0] {
            runs.push(run(ind, 1, t, 1.0 / t));
            runs.push(run(cv, 5, 1.5 * t, 0.25 / (1.5 * t)));
            runs.push(run(ind_oidn, 1, 3.0 * t, 0.5 / (3.0 * t)));
            runs.push(run(cv_oidn, 5, 3.0 * t, 0.125 / (3.0 * t)));
        }
        let costs = Costs {
            c_e: 100.0,
            c_l: 900.0,
            c_v_single: 50.0,
            c_v_packet: 20.0,
        };
        let f = figures(&runs, &[ind, cv, ind_oidn, cv_oidn], &costs, 10);
        let near = |a: f64, b: f64| (a / b - 1.0).abs() < 1e-9;
        assert!(
            near(f.equal_error_speedup["mis-cv"]["5"], 4.0),
            "{:?}",
            f.equal_error_speedup
        );
        assert!(near(f.equal_error_speedup["independent+oidn"]["1"], 2.0));
        assert!(near(f.equal_error_speedup["mis-cv+oidn"]["5"], 8.0));
        // Over the denoised independent tracer: the denoised methods only.
        assert!(near(
            f.equal_error_speedup_over_denoised["mis-cv+oidn"]["5"],
            4.0
        ));
        assert!(!f.equal_error_speedup_over_denoised.contains_key("mis-cv"));
        // Equal time: the geometric mean of the independent runs' times (2^1.5), where the
        // fitted relMSE of each plain line is read; the denoised lines at theirs (3 x 2^1.5).
        let t = 2f64.powf(1.5);
        assert!(near(f.equal_time, t));
        assert!(near(f.equal_time_relmse["independent"], 1.0 / t));
        assert!(near(f.equal_time_relmse["mis-cv"], 0.25 / t));
        assert!(!f.equal_time_relmse.contains_key("mis-cv+oidn"));
        assert!(near(f.denoised_equal_time.unwrap(), 3.0 * t));
        assert!(near(
            f.denoised_equal_time_relmse["mis-cv+oidn"],
            0.125 / (3.0 * t)
        ));
        // Eq. 16 for window 5; no mis-exact run, so no measured same-sample speed-up.
        assert!(near(
            f.predicted["5"],
            predicted_speedup(5, 100.0, 900.0, 20.0)
        ));
        assert!(f.measured.is_empty());
        assert_eq!(
            f.widest,
            vec![(ind, 1), (cv, 5), (ind_oidn, 1), (cv_oidn, 5)]
        );
    }
}
