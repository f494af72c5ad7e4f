//! `reframe compare`: every method at a ladder of budgets against a cached high-sample reference
//! (`reference`), error against time and flicker (`errors`), and the charts (`chart`).
use super::bench::{measure_costs, predicted_speedup, Costs};
use super::chart::{bar_chart, image_strip, write_svg_png, LineChart, Series, COLOURS};
use super::errors::{
    errors, loglog_fit, time_for, FrameError, FLICKER_FORMULA, RELMSE_FORMULA, RMSE_FORMULA,
};
use super::reference::{reference, PASSES};
use crate::driver::guard::{check_not_inputs, OutputLock};
use crate::driver::options::{check_max_depth, check_resolution, check_spp, check_threads};
use crate::driver::{check_frames, progress_bar, render_frames, thread_pool, RenderOptions};
use crate::film::Developed;
use crate::image::Image;
use crate::integrator::Integrator;
use crate::reuse::Method;
use crate::scene::Scene;
use crate::util::fs::{check_writable_dir, write_atomic, write_json, CreatedDirs};
use anyhow::{bail, Context, Result};
use glam::Vec3;
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::ops::RangeInclusive;
use std::path::PathBuf;
use std::time::Instant;

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

/// What to compare.
#[derive(Clone, Debug)]
pub struct CompareOptions {
    pub regime: Regime,
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
    /// Longest path, in bounces, of every run and of the reference.
    pub max_depth: u32,
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
            regime: Regime::Steady,
            frames: None,
            res: None,
            methods: vec![
                Method::Independent,
                Method::Havran,
                Method::Mis,
                Method::MisExact,
                Method::MisCv,
            ],
            budgets: vec![1, 2, 4, 8, 16],
            reuse_budgets: vec![1, 2],
            windows: vec![3, 7, 17, 33],
            reference_spp: 256,
            max_depth: 16,
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
    /// The time charged to the measured frames (see `Regime`); the fits use it.
    pub seconds: f64,
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
    /// Runs left out, and why (a window whose steady state needs frames the scene lacks).
    pub skipped: Vec<String>,
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
    check_resolution((w, h))?;
    check_max_depth(opts.max_depth)?;
    let n_frames = last - first + 1;
    for &b in opts.budgets.iter().chain(&opts.reuse_budgets) {
        check_spp("--budgets", b)?;
    }
    check_threads(opts.threads)?;
    if opts.budgets.contains(&0) || opts.reuse_budgets.contains(&0) {
        bail!("a budget of 0 samples per pixel: every run needs at least one");
    }
    if let Some(&n) = opts.windows.iter().find(|&&n| n % 2 == 0) {
        bail!("--windows {n}: a group is n_f = 2n+1 frames, so windows must be odd");
    }
    if opts.methods.contains(&Method::Independent) && opts.budgets.is_empty() {
        bail!("--budgets: the independent tracer needs at least one budget");
    }
    // The default crop: a centred square of half the shorter side.
    let side = (w.min(h) / 2).max(1);
    let crop = opts
        .crop
        .unwrap_or([(w - side) / 2, (h - side) / 2, side, side]);
    let inside =
        |x: u32, cw: u32, limit: u32| cw > 0 && x.checked_add(cw).is_some_and(|e| e <= limit);
    if !inside(crop[0], crop[2], w) || !inside(crop[1], crop[3], h) {
        bail!(
            "--crop {},{},{},{}: not inside the {w}x{h} frame",
            crop[0],
            crop[1],
            crop[2],
            crop[3]
        );
    }
    let created = CreatedDirs::create(&opts.out)
        .with_context(|| format!("--out {}: cannot create the folder", opts.out.display()))?;
    check_writable_dir(&opts.out).with_context(|| format!("--out {}", opts.out.display()))?;
    let lock = opts.out.join(".compare.lock");
    let written = [
        "compare.json",
        "compare.csv",
        "error_vs_time.png",
        "error_vs_time.svg",
        "speedup_vs_nf.png",
        "speedup_vs_nf.svg",
        "flicker.png",
        "flicker.svg",
        "crops.png",
        "crops.svg",
        ".compare.lock",
    ];
    check_not_inputs(
        written.iter().map(|n| ("--out", opts.out.join(n))),
        &scene.inputs,
    )?;
    let _lock = OutputLock::acquire(&lock, &opts.out.display().to_string())?;
    created.keep();
    let pool = thread_pool(opts.threads)?;
    let threads = pool.current_num_threads();
    crate::embree::set_flush_denormals();

    let reference = reference(
        scene,
        range.clone(),
        (w, h),
        opts.reference_spp,
        opts.max_depth,
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
    let integrator = Integrator::new(scene, opts.max_depth);
    let crop_frame = first + n_frames / 2;
    let mut runs: Vec<Run> = Vec::new();
    let mut crops: Vec<Vec<Vec3>> = Vec::new();
    // (method, window, spp, frames rendered) of every run.
    let mut plan: Vec<(Method, u32, u32, RangeInclusive<u32>)> = Vec::new();
    let mut skipped = Vec::new();
    for &m in &opts.methods {
        if !m.reuses() {
            plan.extend(opts.budgets.iter().map(|&s| (m, 1, s, range.clone())));
            continue;
        }
        for &n_f in &opts.windows {
            let rendered = match opts.regime {
                Regime::Range if n_f <= n_frames => range.clone(),
                Regime::Steady if first >= n_f - 1 && last + n_f - 1 < scene.frames => {
                    first + 1 - n_f..=last + n_f - 1
                }
                _ => {
                    skipped.push(format!(
                        "{} n_f {n_f}: {}",
                        m.name(),
                        match opts.regime {
                            Regime::Range => format!("longer than the {n_frames} frames"),
                            Regime::Steady => format!(
                                "its steady state needs frames {}-{}, the scene has 0-{}",
                                first as i64 + 1 - n_f as i64,
                                last + n_f - 1,
                                scene.frames - 1
                            ),
                        }
                    ));
                    continue;
                }
            };
            plan.extend(
                opts.reuse_budgets
                    .iter()
                    .map(|&s| (m, n_f, s, rendered.clone())),
            );
        }
    }
    for s in &skipped {
        eprintln!("compare: skipped {s}");
    }
    if plan.is_empty() {
        bail!("nothing to compare: no method with a budget and a window that fits the frames");
    }
    let pb = progress_bar(opts.progress, plan.len() as u64, "runs");
    for (method, window, spp, rendered) in plan {
        let start = Instant::now();
        let mut frames: Vec<Vec<Vec3>> = Vec::with_capacity(n_frames as usize);
        let ropts = RenderOptions {
            method,
            spp,
            window,
            seed: opts.seed,
            frames: Some(rendered.clone()),
            resolution: Some((w, h)),
            max_depth: opts.max_depth,
            progress: false,
            ..RenderOptions::default()
        };
        let mut keep = |d: Developed| {
            if range.contains(&d.view.frame) {
                frames.push(d.pixels());
            }
            Ok(())
        };
        let counters = pool.install(|| render_frames(&integrator, &ropts, &mut keep))?;
        let eff = if method.reuses() {
            let measured: Vec<f64> = counters
                .per_frame
                .iter()
                .filter(|f| range.contains(&f.frame))
                .map(|f| f.mean_effective_spp)
                .collect();
            measured.iter().sum::<f64>() / measured.len() as f64
        } else {
            spp as f64
        };
        let run_seconds = start.elapsed().as_secs_f64();
        // The steady state charges the measured frames one group's time each.
        let groups = rendered.end() + 2 - rendered.start() - window;
        let seconds = if opts.regime == Regime::Steady && method.reuses() {
            run_seconds * n_frames as f64 / groups as f64
        } else {
            run_seconds
        };
        let (per_frame, rmse, relmse, flicker) = errors(&frames, &reference);
        let (ends_relmse, middle_relmse) = if opts.regime == Regime::Range && method.reuses() {
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
            run_seconds,
            rendered_frames: [*rendered.start(), *rendered.end()],
            ends_relmse,
            middle_relmse,
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
    let (costs, _, _) = measure_costs(&integrator, &pool, &cam, crop_frame, 2, opts.seed);

    // Fits and derived figures.
    let key = |r: &Run| (r.method, r.window);
    let mut lines: Vec<(Method, u32)> = runs.iter().map(key).collect();
    lines.dedup();
    let fit_of = |m: Method, n_f: u32, y: fn(&Run) -> f64, single: f64| {
        let pts: Vec<(f64, f64)> = runs
            .iter()
            .filter(|r| key(r) == (m, n_f))
            .map(|r| (r.seconds, y(r)))
            .collect();
        loglog_fit(&pts, single)
    };
    let indep_fit = fit_of(Method::Independent, 1, |r| r.relmse, -1.0);
    let mut equal_error_speedup: BTreeMap<String, BTreeMap<String, f64>> = BTreeMap::new();
    for &(m, n_f) in lines.iter().filter(|l| l.0 != Method::Independent) {
        let own: Vec<f64> = runs
            .iter()
            .filter(|r| key(r) == (m, n_f) && r.relmse > 0.0)
            .map(|r| r.relmse.ln())
            .collect();
        let (Some(fi), Some(fm)) = (indep_fit, fit_of(m, n_f, |r| r.relmse, -1.0)) else {
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
    let mut windows: Vec<u32> = runs
        .iter()
        .filter(|r| r.method.reuses())
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
            .filter(|r| r.method == Method::MisExact && r.window == n_f)
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
        if let Some((a, b)) = fit_of(m, n_f, |r| r.flicker, -0.5) {
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
        // Every method at its widest window, solid; the unbiased methods' narrower windows dashed.
        series: lines
            .iter()
            .filter(|l| l.0 == Method::Independent || l.1 == max_window)
            .map(|&l| (l, false))
            .chain(
                lines
                    .iter()
                    .filter(|l| {
                        matches!(l.0, Method::MisExact | Method::MisCv) && l.1 != max_window
                    })
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
                crop_png(&crops[i], w, crop)?,
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
        regime: opts.regime,
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
        skipped,
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
fn crop_png(px: &[Vec3], w: u32, [x0, y0, cw, ch]: [u32; 4]) -> Result<Vec<u8>> {
    let mut img = Image::new(cw, ch, &["R", "G", "B"]);
    img.data = (y0..y0 + ch)
        .flat_map(|y| (x0..x0 + cw).map(move |x| (x, y)))
        .flat_map(|(x, y)| px[(y * w + x) as usize].to_array())
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
