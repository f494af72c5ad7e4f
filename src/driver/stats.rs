//! What `--stats` writes: the run's counters (`state::checkpoint::Counters`, carried across a
//! resume) with the render's settings, time and memory. Keys are a contract with users'
//! scripts: add, never rename.
use super::options::{Plan, RenderOptions};
use crate::integrator::RayCounts;
use crate::reuse::Method;
use crate::state::checkpoint::Counters;
use serde::Serialize;

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
    /// `primary`, `path` (BSDF-sampled continuations), `shadow` (next-event) and `visibility`
    /// (reuse tests).
    pub rays: RayCounts,
    pub rays_per_second: f64,
    pub peak_rss_bytes: u64,
    /// Resident memory when the render began: the shared libraries (Debian's OpenImageIO and its
    /// dependencies alone are about 120 MB) and the scene. `peak_rss_bytes` minus this is what
    /// the render itself needed.
    pub startup_rss_bytes: u64,
    /// Pixels written with a NaN or infinite channel (for a chunk: its finished pixels; `merge`
    /// reports the rest).
    pub nonfinite_pixels: u64,
    /// Frames written black in every pixel, in order (a chunk writes no frames: `merge`
    /// reports them).
    pub black_frames: Vec<u32>,
    /// Reuse contributions that came out NaN/Inf and were dropped (should be 0).
    pub nonfinite_samples: u64,
    /// Native plus reused samples that landed, per pixel, averaged over frames.
    pub mean_effective_spp: f64,
    /// Share of attempted reuses lost to occlusion or to falling off the target film.
    pub lost_reuse_fraction: f64,
    /// Per frame retired (for a chunk, its share of each frame it touched).
    pub per_frame: Vec<crate::film::FrameReuse>,
    /// The frame files written, or a chunk's partial file.
    pub outputs: Vec<String>,
    /// `K/N` of `--chunk`, if a chunk.
    pub chunk: Option<String>,
    /// The groups (reuse) or frames (independent) this render covered, inclusive.
    pub units: [u32; 2],
    /// Checkpoints written by this process, and the seconds spent writing them.
    pub checkpoints_written: u32,
    pub checkpoint_seconds: f64,
    /// Seconds this process spent denoising frames (`--denoise`: the guide pass and Open Image
    /// Denoise), part of `seconds` and of each frame's time; 0 without `--denoise`.
    pub denoise_seconds: f64,
}

impl RenderStats {
    /// The statistics of a finished run.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        scene: &str,
        opts: &RenderOptions,
        plan: &Plan,
        counters: &Counters,
        seconds: f64,
        threads: usize,
        startup_rss_bytes: u64,
        outputs: Vec<String>,
        checkpoints: (u32, f64),
    ) -> RenderStats {
        let counts = counters.counts;
        let reuses = opts.method.reuses();
        RenderStats {
            method: opts.method,
            scene: scene.to_string(),
            width: plan.width,
            height: plan.height,
            frames: plan.frame_count(),
            first_frame: *plan.frames.start(),
            last_frame: *plan.frames.end(),
            spp: opts.spp,
            window: opts.window,
            seed: opts.seed,
            threads,
            seconds,
            rays: counts,
            rays_per_second: counts.total() as f64 / seconds.max(1e-9),
            peak_rss_bytes: crate::util::mem::peak_rss_bytes(),
            startup_rss_bytes,
            nonfinite_pixels: counters.nonfinite_pixels,
            black_frames: {
                let mut b = counters.black_frames.clone();
                b.sort_unstable();
                b
            },
            nonfinite_samples: counters.nonfinite_samples,
            mean_effective_spp: if reuses {
                counters.mean_effective_spp(plan.frame_count())
            } else {
                opts.spp as f64
            },
            lost_reuse_fraction: counters.lost_reuse_fraction(),
            per_frame: if reuses {
                counters.per_frame.clone()
            } else {
                vec![]
            },
            outputs,
            chunk: opts.chunk.map(|c| c.to_string()),
            units: [*plan.units.start(), *plan.units.end()],
            checkpoints_written: checkpoints.0,
            checkpoint_seconds: checkpoints.1,
            denoise_seconds: 0.0,
        }
    }

    pub fn rays_total(&self) -> u64 {
        self.rays.total()
    }
}
