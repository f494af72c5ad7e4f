//! The render driver: owns the frame loop, the rayon tiles, the progress bar, the statistics and
//! every file that is written. Integrators only estimate (Mitsuba's `SamplingIntegrator::render`
//! against the CLI's `film->write`).
//!
//! Determinism: pixels are independent (their random numbers are keyed by seed, frame, pixel and
//! sample), each tile's pixels are summed in sample order, and tiles are placed into the frame by
//! index, so the frames are bitwise identical for any thread count.
//!
//! ```no_run
//! use reframe::render::{render, Method, RenderOptions};
//! use reframe::{embree::Device, scene::Scene};
//! let device = Device::new()?;
//! let scene = Scene::load("furnace", &device)?;
//! let opts = RenderOptions { out: "out/furnace_####.exr".into(), ..RenderOptions::default() };
//! let stats = render(&scene, &opts)?;
//! println!("{} rays", stats.rays_total());
//! # anyhow::Ok(())
//! ```
use crate::camera::Camera;
use crate::checkpoint::{
    hash_exe, hash_scene, remove_stale_tmp, tmp_name, Checkpointer, Chunk, Fnv, FrameRecord,
    Progress, RecordData, Run, RunKey, Trailer,
};
use crate::image::{parent_dir, write_image, Image, Metadata, OutputPattern, WriteOptions};
use crate::integrator::{Integrator, RayCounts, Tally};
use crate::sampling::Sampler;
use crate::scene::Scene;
use anyhow::{bail, Context, Result};
use glam::{Vec2, Vec3};
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use serde::Serialize;
use std::ops::RangeInclusive;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Rendering methods, registered in one place: a new method is one file and one line here.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// Independent path tracing of every frame (the baseline).
    Independent,
    /// Havran et al. 2003: reused samples averaged unweighted (biased on glossy surfaces).
    Havran,
    /// The paper's MIS reuse (eq. 13-15 with approximation (10)).
    Mis,
    /// Balance heuristic over the group's eyes with exact area densities (ESTIMATOR.md).
    MisExact,
}

impl Method {
    pub fn name(&self) -> &'static str {
        match self {
            Method::Independent => "independent",
            Method::Havran => "havran",
            Method::Mis => "mis",
            Method::MisExact => "mis-exact",
        }
    }

    pub fn reuses(&self) -> bool {
        *self != Method::Independent
    }
}

#[derive(Clone, Debug)]
pub struct RenderOptions {
    pub method: Method,
    pub spp: u32,
    /// Frames per reuse group (n_f = 2n+1); 1 for the independent tracer.
    pub window: u32,
    /// Visibility tests of reuse in 16-wide packets (else single rays).
    pub packets: bool,
    /// Write extra EXR channels: effective sample count and share of lost reuses per pixel.
    pub aov: bool,
    /// Inclusive frame range; `None` renders all of the scene's frames.
    pub frames: Option<RangeInclusive<u32>>,
    /// Resolution override; `None` keeps the scene's.
    pub resolution: Option<(u32, u32)>,
    pub out: String,
    pub seed: u64,
    /// Worker threads; 0 = one per core.
    pub threads: usize,
    pub max_depth: u32,
    pub exr_float: bool,
    pub stats: Option<PathBuf>,
    /// Draw a progress bar (only ever on a terminal).
    pub progress: bool,
    /// Checkpoint folder (`None`: no checkpoints); see `checkpoint`.
    pub checkpoint: Option<PathBuf>,
    /// Seconds between checkpoints (0: after every group, or frame).
    pub checkpoint_every: f64,
    /// Continue from the checkpoint in `checkpoint`, if there is one.
    pub resume: bool,
    /// `mis-exact` only: top every pixel's expected sample count up to this share of `n_f n_r`
    /// with extra native samples (`reuse::adaptive_counts`); `None`: `n_r` everywhere.
    pub adaptive: Option<f32>,
    /// Render only chunk K of N of the groups and write its partial file (`reframe merge`).
    pub chunk: Option<Chunk>,
    /// Set (by a signal handler) to stop at the next group or frame, after a checkpoint.
    pub interrupt: Option<Arc<AtomicBool>>,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            method: Method::Independent,
            spp: 8,
            window: 1,
            packets: true,
            aov: false,
            frames: None,
            resolution: None,
            out: "out/frame_####.exr".into(),
            seed: 0,
            threads: 0,
            max_depth: 16,
            exr_float: false,
            stats: None,
            progress: true,
            checkpoint: None,
            checkpoint_every: 60.0,
            resume: false,
            adaptive: None,
            chunk: None,
            interrupt: None,
        }
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct RayStats {
    pub primary: u64,
    pub path: u64,
    pub shadow: u64,
    /// Reuse visibility tests (hit to another eye).
    pub visibility: u64,
}

/// Reuse figures of one frame.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct FrameReuse {
    pub frame: u32,
    pub mean_effective_spp: f64,
    pub lost_reuse_fraction: f64,
}

/// What `--stats` writes (keys are a contract with users' scripts: add, never rename).
#[derive(Clone, Debug, Serialize)]
pub struct RenderStats {
    pub method: Method,
    pub scene: String,
    pub width: u32,
    pub height: u32,
    pub frames: u32,
    pub first_frame: u32,
    pub last_frame: u32,
    pub spp: u32,
    pub window: u32,
    pub seed: u64,
    pub threads: usize,
    pub seconds: f64,
    pub rays: RayStats,
    pub rays_per_second: f64,
    pub peak_rss_bytes: u64,
    /// Resident memory when the render began: the shared libraries (Debian's OpenImageIO and its
    /// dependencies alone are about 120 MB) and the scene. `peak_rss_bytes` minus this is what
    /// the render itself needed.
    pub startup_rss_bytes: u64,
    pub nonfinite_pixels: u64,
    /// Reuse contributions that came out NaN/Inf and were dropped (should be 0).
    pub nonfinite_samples: u64,
    /// Native plus reused samples that landed, per pixel, averaged over frames.
    pub mean_effective_spp: f64,
    /// Share of attempted reuses lost to occlusion or to falling off the target film.
    pub lost_reuse_fraction: f64,
    pub per_frame: Vec<FrameReuse>,
    /// The frame files written, or a chunk's partial file.
    pub outputs: Vec<String>,
    /// `K/N` of `--chunk`, if a chunk.
    pub chunk: Option<String>,
    /// The groups (reuse) or frames (independent) this render covered, inclusive.
    pub units: [u32; 2],
    /// Checkpoints written by this process, and the seconds spent writing them.
    pub checkpoints_written: u32,
    pub checkpoint_seconds: f64,
    #[serde(skip)]
    pub ray_counts: RayCounts,
}

impl RenderStats {
    pub fn rays_total(&self) -> u64 {
        self.ray_counts.total()
    }
}

/// Peak resident set size of this process (Linux `VmHWM`), 0 where unavailable.
pub fn peak_rss_bytes() -> u64 {
    proc_status_bytes("VmHWM:")
}

/// Resident set size of this process now (Linux `VmRSS`), 0 where unavailable.
pub fn rss_bytes() -> u64 {
    proc_status_bytes("VmRSS:")
}

fn proc_status_bytes(key: &str) -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with(key))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<u64>().ok())
        })
        .map_or(0, |kb| kb * 1024)
}

/// A rayon pool whose workers set FTZ/DAZ, as Embree asks of every tracing thread.
pub fn thread_pool(threads: usize) -> Result<rayon::ThreadPool> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .start_handler(|_| crate::embree::set_flush_denormals())
        .build()
        .context("creating the worker threads")
}

pub const TILE: u32 = 16;

/// The tiles of a `w` x `h` image as (x0, y0, x1, y1), row by row.
pub fn tiles(w: u32, h: u32) -> Vec<(u32, u32, u32, u32)> {
    let mut v = Vec::new();
    for y0 in (0..h).step_by(TILE as usize) {
        for x0 in (0..w).step_by(TILE as usize) {
            v.push((x0, y0, (x0 + TILE).min(w), (y0 + TILE).min(h)));
        }
    }
    v
}

/// Copy a tile's values (row by row, as `tiles` gives them) into their place in a `w`-wide frame.
pub fn place_tile<T: Copy>(
    frame: &mut [T],
    w: u32,
    (x0, y0, x1, _): (u32, u32, u32, u32),
    values: &[T],
) {
    let tw = (x1 - x0) as usize;
    for (row, v) in values.chunks(tw).enumerate() {
        let start = ((y0 + row as u32) * w + x0) as usize;
        frame[start..start + tw].copy_from_slice(v);
    }
}

/// A frame range must be non-empty and inside the scene's animation.
pub fn check_frames(scene: &Scene, range: &RangeInclusive<u32>) -> Result<()> {
    let last = scene.frames - 1;
    if range.start() > range.end() || *range.end() > last {
        bail!(
            "--frames {}-{}: the scene '{}' has frames 0-{last}",
            range.start(),
            range.end(),
            scene.name
        );
    }
    Ok(())
}

/// Validated frame range and resolution for a scene and options.
pub fn frame_plan(scene: &Scene, opts: &RenderOptions) -> Result<(RangeInclusive<u32>, u32, u32)> {
    let range = opts.frames.clone().unwrap_or(0..=scene.frames - 1);
    check_frames(scene, &range)?;
    let (w, h) = opts.resolution.unwrap_or((scene.width, scene.height));
    if w == 0 || h == 0 {
        bail!("--res {w}x{h}: width and height must be positive");
    }
    if opts.spp == 0 {
        bail!("--spp 0: at least one sample per pixel is needed");
    }
    let n = range.end() - range.start() + 1;
    if opts.window.is_multiple_of(2) {
        bail!(
            "--window {}: a group is n_f = 2n+1 frames, so the window must be odd",
            opts.window
        );
    }
    if opts.window > n {
        bail!(
            "--window {}: larger than the {n} frames rendered",
            opts.window
        );
    }
    if let Some(t) = opts.adaptive {
        if opts.method != Method::MisExact {
            bail!(
                "--adaptive: only mis-exact weighs samples by their exact densities, which \
                 adaptive counts need (method is {})",
                opts.method.name()
            );
        }
        if !(t > 0.0 && t <= 1.0) {
            bail!("--adaptive {t}: the target share of n_f n_r must be in (0, 1]");
        }
    }
    if opts.method == Method::Independent && opts.window != 1 {
        bail!(
            "--window {}: only the reuse methods (havran, mis, mis-exact) take a window",
            opts.window
        );
    }
    Ok((range, w, h))
}

/// Check the output pattern before anything is traced: a long render must not fail at its end.
pub fn check_output(pattern: &str, frames: &RangeInclusive<u32>) -> Result<OutputPattern> {
    let out = OutputPattern::parse(pattern)?;
    if frames.start() != frames.end() && !out.has_frame_field() {
        bail!(
            "--out {pattern}: several frames need a frame number field such as '####' in the name"
        );
    }
    out.validate()?;
    Ok(out)
}

pub fn progress_bar(enabled: bool, len: u64, what: &str) -> ProgressBar {
    if !enabled {
        return ProgressBar::hidden();
    }
    // indicatif draws only when stderr is a terminal, so scripts and logs stay quiet.
    let pb = ProgressBar::new(len);
    pb.set_style(
        ProgressStyle::with_template(&format!(
            "{{spinner}} [{{elapsed_precise}}] {{bar:30}} {{pos}}/{{len}} {what} {{msg}} ETA {{eta}}"
        ))
        .expect("valid template"),
    );
    pb
}

/// A rendered frame: linear RGB pixels, ray counts, and (benchmark only) each tile's rays.
pub struct FrameResult {
    pub pixels: Vec<Vec3>,
    pub counts: RayCounts,
    pub ray_logs: Vec<Vec<(crate::embree::Ray, bool)>>,
}

/// Render one frame with the independent path tracer.
pub fn render_frame_independent(
    integrator: &Integrator,
    cam: &Camera,
    frame: u32,
    spp: u32,
    seed: u64,
    log_rays: bool,
    on_tile: &(dyn Fn(&RayCounts) + Sync),
) -> FrameResult {
    let (w, h) = (cam.width, cam.height);
    let tiles = tiles(w, h);
    let results: Vec<(Vec<Vec3>, Tally)> = tiles
        .par_iter()
        .map(|&(x0, y0, x1, y1)| {
            let mut t = if log_rays {
                Tally::logging()
            } else {
                Tally::default()
            };
            let mut px = Vec::with_capacity(((x1 - x0) * (y1 - y0)) as usize);
            for y in y0..y1 {
                for x in x0..x1 {
                    let pixel = y * w + x;
                    let mut sum = Vec3::ZERO;
                    for s in 0..spp {
                        let mut sampler = Sampler::new(seed, frame, pixel, s);
                        let r = Vec2::new(x as f32, y as f32) + sampler.next_2d();
                        sum += integrator.sample_pixel(cam, r, &mut sampler, &mut t);
                    }
                    px.push(sum / spp as f32);
                }
            }
            on_tile(&t.counts);
            (px, t)
        })
        .collect();
    let mut pixels = vec![Vec3::ZERO; (w * h) as usize];
    let mut counts = RayCounts::default();
    let mut ray_logs = Vec::new();
    for (&tile, (px, t)) in tiles.iter().zip(results) {
        place_tile(&mut pixels, w, tile, &px);
        counts.add(&t.counts);
        ray_logs.extend(t.log);
    }
    FrameResult {
        pixels,
        counts,
        ray_logs,
    }
}

pub fn to_image(w: u32, h: u32, px: &[Vec3]) -> Image {
    Image {
        width: w,
        height: h,
        channels: vec!["R".into(), "G".into(), "B".into()],
        data: px.iter().flat_map(|p| p.to_array()).collect(),
    }
}

/// What every frame file of a render records about how it was made.
#[derive(Clone, Debug)]
pub struct FrameMeta {
    pub scene: String,
    pub method: String,
    pub spp: u32,
    pub window: u32,
    pub seed: u64,
    pub exr_float: bool,
}

/// Writes finished frames (atomically, with metadata).
pub struct FrameSink {
    pub meta: FrameMeta,
    pub out: OutputPattern,
}

impl FrameSink {
    /// Write frame `frame` seen by `cam`: RGB plus optional extra channels (name, one value per
    /// pixel).
    pub fn emit(
        &self,
        frame: u32,
        cam: &Camera,
        px: &[Vec3],
        extra: &[(&str, Vec<f32>)],
        seconds: f64,
    ) -> Result<PathBuf> {
        let matrices = (
            cam.world_to_camera().to_cols_array(),
            cam.world_to_ndc().to_cols_array(),
        );
        self.write(frame, (cam.width, cam.height), matrices, px, extra, seconds)
    }

    /// Write frame `frame` of `w` x `h` pixels with its camera's (world-to-camera,
    /// world-to-NDC) matrices.
    pub fn write(
        &self,
        frame: u32,
        (w, h): (u32, u32),
        (world_to_camera, world_to_ndc): ([f32; 16], [f32; 16]),
        px: &[Vec3],
        extra: &[(&str, Vec<f32>)],
        seconds: f64,
    ) -> Result<PathBuf> {
        let mut img = to_image(w, h, px);
        if !extra.is_empty() {
            let nc = 3 + extra.len();
            let mut data = Vec::with_capacity(px.len() * nc);
            for (i, p) in px.iter().enumerate() {
                data.extend(p.to_array());
                data.extend(extra.iter().map(|(_, v)| v[i]));
            }
            img.channels
                .extend(extra.iter().map(|(n, _)| n.to_string()));
            img.data = data;
        }
        let path = self.out.path(frame);
        let meta = Metadata {
            method: self.meta.method.clone(),
            spp: self.meta.spp,
            window: self.meta.window,
            seed: self.meta.seed,
            render_seconds: seconds,
            world_to_camera,
            world_to_ndc,
            extra: vec![
                ("scene".into(), self.meta.scene.clone()),
                ("frame".into(), frame.to_string()),
            ],
        };
        write_image(
            &path,
            &img,
            &meta,
            &WriteOptions {
                exr_float: self.meta.exr_float,
            },
        )
        .with_context(|| format!("writing frame {frame}"))?;
        Ok(path)
    }
}

/// A render stopped by a signal (`RenderOptions::interrupt`) after a checkpoint; `--resume`
/// continues it.
#[derive(Debug)]
pub struct Interrupted {
    /// The checkpoint folder, if checkpoints were on.
    pub checkpoint: Option<PathBuf>,
    /// Frames finished and written (or, for a chunk, retired to its log) so far.
    pub frames_done: u32,
}

impl std::fmt::Display for Interrupted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.checkpoint {
            Some(d) => write!(
                f,
                "interrupted after {} finished frame(s); the checkpoint is in {}",
                self.frames_done,
                d.display()
            ),
            None => write!(
                f,
                "interrupted after {} finished frame(s), without a checkpoint",
                self.frames_done
            ),
        }
    }
}

impl std::error::Error for Interrupted {}

/// The settings that make a render's pixels what they are (a resume or merge needs them equal).
fn run_key(
    scene: &Scene,
    opts: &RenderOptions,
    range: &RangeInclusive<u32>,
    (w, h): (u32, u32),
) -> Result<RunKey> {
    let mut f = Fnv::default();
    hash_scene(&mut f, scene);
    let scene_hash = format!("{:016x}", f.0);
    let mut f = Fnv::default();
    hash_exe(&mut f)?;
    Ok(RunKey {
        scene: scene.name.clone(),
        scene_hash,
        build_hash: format!("{:016x}", f.0),
        method: opts.method.name().into(),
        spp: opts.spp,
        window: opts.window,
        first_frame: *range.start(),
        last_frame: *range.end(),
        width: w,
        height: h,
        seed: opts.seed,
        max_depth: opts.max_depth,
        visibility: if opts.packets { "packet" } else { "single" }.into(),
        aov: opts.aov,
        adaptive: opts.adaptive.unwrap_or(0.0),
    })
}

/// Render the frames of `opts` and write them (or, for a chunk, its partial file); returns the
/// statistics (also written to `opts.stats` if set). A render stopped by `opts.interrupt` ends
/// in an `Interrupted` error after its checkpoint.
pub fn render(scene: &Scene, opts: &RenderOptions) -> Result<RenderStats> {
    let startup_rss_bytes = rss_bytes();
    let (range, w, h) = frame_plan(scene, opts)?;
    let out = check_output(&opts.out, &range)?;
    if let Some(p) = &opts.stats {
        check_stats_path(p)?;
    }
    // The units of work: groups of n_f frames sliding by one, or single frames.
    let units = *range.start()..=range.end() + 1 - opts.window;
    let units = match opts.chunk {
        Some(c) => c.share(units).with_context(|| {
            format!(
                "{} of frames {}-{} with window {}",
                if opts.method.reuses() {
                    "groups"
                } else {
                    "frames"
                },
                range.start(),
                range.end(),
                opts.window
            )
        })?,
        None => units,
    };
    let (ckpt, resumed) = if opts.checkpoint.is_some() || opts.chunk.is_some() {
        let key = run_key(scene, opts, &range, (w, h))?;
        let template = Trailer::new(key, opts.chunk, &units, opts.out.clone(), opts.exr_float);
        let every = Duration::from_secs_f64(opts.checkpoint_every.max(0.0));
        Checkpointer::open(opts.checkpoint.clone(), every, opts.resume, template)?
    } else {
        (Checkpointer::none(), None)
    };
    let (progress, next, active) = match resumed {
        Some(r) => {
            // Frame files a killed process was writing when it died.
            let names: Vec<String> = range
                .clone()
                .filter_map(|f| Some(out.path(f).file_name()?.to_string_lossy().into_owned()))
                .collect();
            let dir = parent_dir(&out.path(*range.start()));
            remove_stale_tmp(&dir, |n| names.iter().any(|m| m == n));
            (r.trailer.progress, r.trailer.next_unit, r.active)
        }
        None => (Progress::default(), *units.start(), vec![]),
    };
    let mut run = Run::new(ckpt, units, progress);
    run.next = next;
    run.interrupt = opts.interrupt.clone();
    let pool = thread_pool(opts.threads)?;
    crate::embree::set_flush_denormals();
    let integrator = Integrator::new(scene, opts.max_depth);
    let n_frames = range.end() - range.start() + 1;
    let sink = FrameSink {
        meta: FrameMeta {
            scene: scene.name.clone(),
            method: opts.method.name().into(),
            spp: opts.spp,
            window: opts.window,
            seed: opts.seed,
            exr_float: opts.exr_float,
        },
        out,
    };
    let completed = match opts.method {
        Method::Independent => {
            pool.install(|| render_independent_run(&integrator, opts, (w, h), &mut run, &sink))?
        }
        Method::Havran | Method::Mis | Method::MisExact => {
            let mut emit =
                |f: u32, cam: &Camera, px: &[Vec3], extra: &[(&str, Vec<f32>)], secs: f64| {
                    sink.emit(f, cam, px, extra, secs).map(|_| ())
                };
            pool.install(|| {
                crate::reuse::render_reuse_run(&integrator, opts, w, h, &mut run, active, &mut emit)
            })?
        }
    };
    if !completed {
        return Err(Interrupted {
            checkpoint: run.ckpt.dir().map(Path::to_path_buf),
            frames_done: run.frames_retired(),
        }
        .into());
    }
    let partial = run.finish()?;
    let seconds = run.progress.seconds;
    let counts = run.progress.counts;
    let reuse_stats = opts
        .method
        .reuses()
        .then(|| crate::reuse::ReuseStats::of(&run.progress, n_frames));
    let outputs = match &partial {
        Some(p) => vec![p.display().to_string()],
        None => range
            .clone()
            .map(|f| sink.out.path(f).display().to_string())
            .collect(),
    };
    let stats = RenderStats {
        method: opts.method,
        scene: scene.name.clone(),
        width: w,
        height: h,
        frames: n_frames,
        first_frame: *range.start(),
        last_frame: *range.end(),
        spp: opts.spp,
        window: opts.window,
        seed: opts.seed,
        threads: pool.current_num_threads(),
        seconds,
        rays: RayStats {
            primary: counts.primary,
            path: counts.path,
            shadow: counts.shadow,
            visibility: counts.visibility,
        },
        rays_per_second: counts.total() as f64 / seconds.max(1e-9),
        peak_rss_bytes: peak_rss_bytes(),
        startup_rss_bytes,
        nonfinite_pixels: run.progress.nonfinite_pixels,
        nonfinite_samples: run.progress.nonfinite_samples,
        mean_effective_spp: reuse_stats
            .as_ref()
            .map_or(opts.spp as f64, |r| r.mean_effective_spp),
        lost_reuse_fraction: reuse_stats.as_ref().map_or(0.0, |r| r.lost_reuse_fraction),
        per_frame: reuse_stats.map(|r| r.per_frame).unwrap_or_default(),
        outputs,
        chunk: opts.chunk.map(|c| c.to_string()),
        units: [*run.units.start(), *run.units.end()],
        checkpoints_written: run.ckpt.written,
        checkpoint_seconds: run.ckpt.spent.as_secs_f64(),
        ray_counts: counts,
    };
    if let Some(p) = &opts.stats {
        write_json(p, &stats)?;
    }
    Ok(stats)
}

/// The frames `run.units` with the independent tracer, from `run.next` on; each finished frame
/// is written (or retired to a chunk's log). Returns false if interrupted (after a checkpoint).
fn render_independent_run(
    integrator: &Integrator,
    opts: &RenderOptions,
    (w, h): (u32, u32),
    run: &mut Run,
    sink: &FrameSink,
) -> Result<bool> {
    let scene = integrator.scene;
    let (a, b) = (*run.units.start(), *run.units.end());
    let tiles_per_frame = tiles(w, h).len() as u64;
    let pb = progress_bar(opts.progress, (b + 1 - a) as u64 * tiles_per_frame, "tiles");
    pb.set_position((run.next - a) as u64 * tiles_per_frame);
    let start = Instant::now();
    let total_rays = AtomicU64::new(0);
    for frame in run.next..=b {
        if run.interrupted() {
            run.save([])?;
            pb.abandon();
            return Ok(false);
        }
        let cam = scene.camera(frame, w, h);
        let frame_start = Instant::now();
        let on_tile = |c: &RayCounts| {
            let total = total_rays.fetch_add(c.total(), Relaxed) + c.total();
            let secs = start.elapsed().as_secs_f64().max(1e-9);
            pb.set_message(format!(
                "| frame {}/{} | {:.2} Mrays/s",
                frame - a + 1,
                b - a + 1,
                total as f64 / secs / 1e6
            ));
            pb.inc(1);
        };
        let f = render_frame_independent(
            integrator, &cam, frame, opts.spp, opts.seed, false, &on_tile,
        );
        run.progress.counts.add(&f.counts);
        let seconds = frame_start.elapsed().as_secs_f64();
        if run.ckpt.chunked() {
            run.ckpt.retire(&FrameRecord {
                frame,
                width: w,
                height: h,
                groups: 1,
                unit: 1.0,
                data: RecordData::Pixels(f.pixels.iter().flat_map(|p| p.to_array()).collect()),
                landed: None,
                loss: None,
                landed_total: 0,
                tried: 0,
                lost: 0,
                seconds,
                world_to_camera: cam.world_to_camera().to_cols_array(),
                world_to_ndc: cam.world_to_ndc().to_cols_array(),
            })?;
        } else {
            run.progress.nonfinite_pixels +=
                f.pixels.iter().filter(|p| !p.is_finite()).count() as u64;
            sink.emit(frame, &cam, &f.pixels, &[], seconds)?;
        }
        run.next = frame + 1;
        if frame < b && run.ckpt.due() {
            run.save([])?;
        }
    }
    pb.finish_and_clear();
    Ok(true)
}

/// The stats file's folder must exist and be writable before the render starts.
pub fn check_stats_path(p: &std::path::Path) -> Result<()> {
    let dir = parent_dir(p);
    if !dir.is_dir() {
        bail!(
            "--stats {}: folder {} does not exist",
            p.display(),
            dir.display()
        );
    }
    crate::image::check_writable_dir(&dir).with_context(|| format!("--stats {}", p.display()))
}

/// Write JSON atomically (temporary name, then rename).
pub fn write_json<T: Serialize>(p: &std::path::Path, v: &T) -> Result<()> {
    let text = serde_json::to_string_pretty(v)?;
    write_atomic(p, (text + "\n").as_bytes())
}

/// Write a file atomically: a temporary name in the same folder, then a rename.
pub fn write_atomic(p: &std::path::Path, bytes: &[u8]) -> Result<()> {
    let tmp = tmp_name(p);
    std::fs::write(&tmp, bytes).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, p).with_context(|| {
        let _ = std::fs::remove_file(&tmp);
        format!("renaming {} to {}", tmp.display(), p.display())
    })
}
