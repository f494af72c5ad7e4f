//! What a render is asked to do, and the one validation of it: the library's `render` and the
//! command line both go through `RenderOptions::validate`, before the first ray and before the
//! first file is written.
use crate::image::OutputPattern;
use crate::reuse::Method;
use crate::scene::{Scene, MAX_PIXELS};
use crate::state::key::{run_units, Chunk};
use crate::util::fs::{check_file_target, CreatedDirs};
use anyhow::{bail, Context, Result};
use std::ops::RangeInclusive;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

#[derive(Clone, Debug)]
pub struct RenderOptions {
    pub method: Method,
    pub spp: u32,
    /// Frames per reuse group, n_f (odd: the frames around each); 1 for the independent tracer.
    pub window: u32,
    /// Visibility tests of reuse in 16-wide packets (else single rays).
    pub packets: bool,
    /// Primary rays (the independent tracer's, the reuse methods' native samples') in 16-wide
    /// packets (else single rays). `render` sets its integrator's `primary` from it;
    /// `render_frames` takes the integrator it is given as it is.
    pub primary: crate::integrator::Rays,
    /// The rays after the primary hit (continuation and shadow rays of the wavefront) in 16-wide
    /// packets (else single rays). Set like `primary`.
    pub paths: crate::integrator::Rays,
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
    /// Checkpoint folder (`None`: no checkpoints); see `state::checkpoint`.
    pub checkpoint: Option<PathBuf>,
    /// Seconds between checkpoints (0: after every group, or frame).
    pub checkpoint_every: f64,
    /// Continue from the checkpoint in `checkpoint`, if there is one.
    pub resume: bool,
    /// `mis-exact` only: top every pixel's expected sample count up to this share of `n_f n_r`
    /// with extra native samples (`reuse::adaptive`); `None`: `n_r` everywhere.
    pub adaptive: Option<f32>,
    /// Render only chunk K of N of the groups and write its partial file (`reframe merge`).
    pub chunk: Option<Chunk>,
    /// Set (by a signal handler) to stop at the next group or frame, after a checkpoint.
    pub interrupt: Option<Arc<AtomicBool>>,
    /// Denoise every frame with Open Image Denoise before it is written (`driver::denoise`),
    /// with these extra layers; `None`: frames as rendered.
    pub denoise: Option<super::denoise::Layers>,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            method: Method::Independent,
            spp: 8,
            window: 1,
            packets: true,
            primary: crate::integrator::Rays::Packet,
            paths: crate::integrator::Rays::Packet,
            aov: false,
            frames: None,
            resolution: None,
            out: "out/frame_####.exr".into(),
            seed: 0,
            threads: 0,
            max_depth: DEFAULT_MAX_DEPTH,
            exr_float: false,
            stats: None,
            progress: true,
            checkpoint: None,
            checkpoint_every: 60.0,
            resume: false,
            adaptive: None,
            chunk: None,
            interrupt: None,
            denoise: None,
        }
    }
}

/// A validated render: what it covers.
#[derive(Clone, Debug)]
pub struct Plan {
    pub frames: RangeInclusive<u32>,
    pub width: u32,
    pub height: u32,
    /// The units of work this process renders: groups of `window` frames sliding by one (group
    /// `g` is frames `g..g + window`), or single frames; a chunk's share of them.
    pub units: RangeInclusive<u32>,
    /// Every unit of the run (`units` for a render that is not a chunk).
    pub all_units: RangeInclusive<u32>,
    /// What one unit of a reuse film's sums is worth (`reuse::radiance_unit`; 1 for the
    /// independent tracer).
    pub radiance_unit: f32,
}

impl Plan {
    pub fn frame_count(&self) -> u32 {
        self.frames.end() - self.frames.start() + 1
    }
}

/// The widest film the reuse methods take (`Camera::film_extent`: its corner, in focal
/// lengths from its centre; about 179.98 degrees of vertical fov at 4:3, 11.4 degrees at
/// 100000:1).
/// Their weights multiply film densities of up to its cube, and sum them over a group's
/// counts: at 1e4 every such product stays far inside single precision, where a film of 5e6
/// (179.99998 degrees at 4:3, or 179.99 at 1000:1) overflowed it into frames of -9e12.
pub const MAX_REUSE_FILM_EXTENT: f32 = 1e4;

/// Refuse a reuse render whose camera's film, in some frame of `range` at `(w, h)`, is wider
/// than `MAX_REUSE_FILM_EXTENT` (the independent tracer takes any fov below 180 degrees).
pub fn check_reuse_film(
    scene: &Scene,
    range: &RangeInclusive<u32>,
    (w, h): (u32, u32),
    method: &str,
) -> Result<()> {
    for f in range.clone() {
        let cam = scene.camera(f, w, h);
        let extent = cam.film_extent();
        if extent.is_nan() || extent > MAX_REUSE_FILM_EXTENT {
            bail!(
                "--method {method}: frame {f}'s field of view ({} degrees vertical at {w}x{h}) \
                 puts the film's corner {extent:.3e} focal lengths from its centre, wider than \
                 the reuse methods take (at most {MAX_REUSE_FILM_EXTENT:e}: their weights \
                 multiply the film densities, 1/cos^3 of the angle off the axis, which would \
                 overflow); narrow the fov or the aspect, or use --method independent",
                (2.0 * (cam.tan_half_fov as f64).atan()).to_degrees() as f32
            );
        }
    }
    Ok(())
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

/// What is wrong with a resolution, if anything: it must have pixels, and at most `MAX_PIXELS`
/// of them (2^28, 16384 x 16384, keeps every per-pixel index and buffer size inside 32 bits).
pub fn resolution_problem((w, h): (u32, u32)) -> Option<&'static str> {
    if w == 0 || h == 0 {
        Some("width and height must be positive")
    } else if w as u64 * h as u64 > MAX_PIXELS {
        Some("at most 2^28 pixels (e.g. 16384x16384)")
    } else {
        None
    }
}

/// A resolution must have pixels, and at most `MAX_PIXELS` of them.
pub fn check_resolution((w, h): (u32, u32)) -> Result<()> {
    match resolution_problem((w, h)) {
        Some(why) => bail!("--res {w}x{h}: {why}"),
        None => Ok(()),
    }
}

/// The most samples per pixel a run (or, for reuse, a group) takes: 2^20, far beyond any
/// render that ends, and inside every counter.
pub const MAX_SPP: u32 = 1 << 20;
/// The longest interval between checkpoints, in seconds: a year.
pub const MAX_CHECKPOINT_EVERY: f64 = 365.0 * 24.0 * 3600.0;

/// A sample count (`flag` names it) must be at least 1 and at most `MAX_SPP`.
pub fn check_spp(flag: &str, spp: u32) -> Result<()> {
    if spp == 0 {
        bail!("{flag} 0: at least one sample per pixel is needed");
    }
    if spp > MAX_SPP {
        bail!("{flag} {spp}: at most {MAX_SPP} samples per pixel");
    }
    Ok(())
}

/// The machine's cores (what `--threads 0` means), 1 where unknown.
pub fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Worker threads: 0 (one per core) or at most 8 per core; more only thrash.
pub fn check_threads(threads: usize) -> Result<()> {
    let cores = cores();
    if threads > 8 * cores {
        bail!(
            "--threads {threads}: at most 8 per core ({} on this machine with {cores} cores), \
             or 0 for one per core",
            8 * cores
        );
    }
    Ok(())
}

/// The longest path, in bounces, where no `--max-depth` is given: a bound that paths do not
/// reach, so that frames are not darkened by it. Russian roulette ends a path after bounce 3
/// with probability at least 5% a bounce (its survival is capped at 0.95), so a path passes
/// 1024 bounces with probability below 1e-22, and typical scenes end their paths long before:
/// `cornell` at 64 spp has the same mean to 1e-5, in the same time, at 16 bounces and at 1024.
/// A cap of 16 (the default before) left a closed room of albedo 0.9 12% dark (17% in red)
/// against Mitsuba 3's path tracer at its default, unbounded depth.
pub const DEFAULT_MAX_DEPTH: u32 = 1024;

/// Paths need at least one bounce.
pub fn check_max_depth(max_depth: u32) -> Result<()> {
    if max_depth == 0 {
        bail!("--max-depth 0: paths need at least one bounce");
    }
    Ok(())
}

impl RenderOptions {
    /// `--adaptive` as the render takes it: ignored at `--window 1` (a group of one frame lands
    /// nothing from other frames: every pixel gets `--spp`), where it traced its pilot rays
    /// for nothing.
    pub fn effective_adaptive(&self) -> Option<f32> {
        self.adaptive.filter(|_| self.window > 1)
    }

    /// `validate`'s checks alone, nothing traced: the frames and the resolution the render
    /// would take. `compare` and `bench` check each of their runs with it before the first.
    pub fn check(&self, scene: &Scene) -> Result<(RangeInclusive<u32>, (u32, u32))> {
        let range = self.frames.clone().unwrap_or(0..=scene.frames - 1);
        check_frames(scene, &range)?;
        let (w, h) = self.resolution.unwrap_or((scene.width, scene.height));
        check_resolution((w, h))?;
        if self.denoise.is_some() {
            crate::image::oidn::check_size("--denoise", (w, h))?;
        }
        check_spp("--spp", self.spp)?;
        let n = range.end() - range.start() + 1;
        if self.window.is_multiple_of(2) {
            bail!(
                "--window {}: a group is a frame and as many on each side (n_f odd: 3, 5, 7, ...), \
                 so the window must be odd",
                self.window
            );
        }
        if self.window > n {
            bail!(
                "--window {}: larger than the {n} frames rendered",
                self.window
            );
        }
        if let Some(t) = self.adaptive {
            if !self.method.adaptive() {
                bail!(
                    "--adaptive: only mis-exact and mis-cv weigh samples by their exact \
                     densities, which adaptive counts need (method is {})",
                    self.method.name()
                );
            }
            if !(t > 0.0 && t <= 1.0) {
                bail!("--adaptive {t}: the target share of n_f n_r must be in (0, 1]");
            }
        }
        if self.method.reuses() {
            check_reuse_film(scene, &range, (w, h), self.method.name())?;
        }
        if !self.method.reuses() && self.window != 1 {
            bail!(
                "--window {}: only the reuse methods (havran, mis, mis-exact, mis-cv) take a window",
                self.window
            );
        }
        if !(0.0..=MAX_CHECKPOINT_EVERY).contains(&self.checkpoint_every) {
            bail!(
                "--checkpoint-every {:?}: seconds from 0 to {MAX_CHECKPOINT_EVERY} (a year)",
                self.checkpoint_every
            );
        }
        if self.spp as u64 * self.window as u64 > MAX_SPP as u64 {
            bail!(
                "--spp {} with --window {}: {} samples per pixel per group (--spp times \
                 --window), at most {MAX_SPP}",
                self.spp,
                self.window,
                self.spp as u64 * self.window as u64
            );
        }
        // A pixel's adaptive count is held in 16 bits (a count per pixel of every frame of a
        // group): `--spp 65536` wrapped to 0, and the pixels that see no surface rendered
        // black. A top-up past 65535 is capped (the densities read the same counts).
        if self.effective_adaptive().is_some() && self.spp > u16::MAX as u32 {
            bail!(
                "--adaptive with --spp {}: at most {} native samples per pixel per group with \
                 adaptive counts",
                self.spp,
                u16::MAX
            );
        }
        check_threads(self.threads)?;
        check_max_depth(self.max_depth)?;
        self.check_memory(
            (w, h),
            crate::util::mem::available_bytes(),
            scene.texture_cache_bytes(),
        )?;
        Ok((range, (w, h)))
    }

    /// Every setting checked against `scene`, before anything is traced or written: the frames,
    /// resolution, samples, window, method-specific flags, checkpoint interval and depth. The
    /// files (`--out`, `--stats`) are checked by `check_files`.
    pub fn validate(&self, scene: &Scene) -> Result<Plan> {
        let (range, (w, h)) = self.check(scene)?;
        let all_units = run_units(*range.start(), *range.end(), self.window);
        let units = match self.chunk {
            Some(c) => c.share(all_units.clone()).with_context(|| {
                if self.method.reuses() {
                    format!(
                        "the groups of {} frames over frames {}-{}",
                        self.window,
                        range.start(),
                        range.end()
                    )
                } else {
                    format!("frames {}-{}", range.start(), range.end())
                }
            })?,
            None => all_units.clone(),
        };
        // The reuse films' unit, from a pilot of the run's first frame (every chunk of the run
        // renders the same range, so every chunk finds the same unit).
        let radiance_unit = if self.method.reuses() {
            // Its samples are scalar walks (`Integrator::sample_pixel`): packets or not, the
            // same unit.
            let integrator = crate::integrator::Integrator::new(scene, self.max_depth);
            let f = *range.start();
            crate::reuse::radiance_unit(
                &integrator,
                &scene.camera(f, w, h),
                f,
                self.seed,
                self.spp.saturating_mul(self.window),
            )
        } else {
            1.0
        };
        Ok(Plan {
            frames: range,
            width: w,
            height: h,
            units,
            all_units,
            radiance_unit,
        })
    }

    /// Bytes a render at `(w, h)` holds at its peak, estimated before it starts: the
    /// accumulators of the frames in flight (`n_f` of them for the reuse methods, one for the
    /// independent tracer), the adaptive counts, three developed frames (one being developed,
    /// one waiting for the frame writer, one being written) and the writer's two copies, every
    /// worker's windows of the group's frames (`film::local`, at their largest),
    /// every worker's native samples of a tile (`reuse::shade::worker_bytes`) or wavefront batch
    /// (`integrator::wavefront`), with `--denoise` the denoiser's images and scratch
    /// (`image::oidn`), and 32 MB for the rest. The process as it starts (the scene,
    /// and mostly OpenImageIO's libraries) is not counted.
    pub fn memory_estimate(&self, (w, h): (u32, u32)) -> u64 {
        let pixels = w as u64 * h as u64;
        let per_pixel = self
            .method
            .layout(self.spp, self.window, self.aov, 1.0)
            .bytes_per_pixel() as u64;
        let n_f = self.window as u64;
        let threads = match self.threads {
            0 => cores(),
            t => t,
        } as u64;
        let frames = if self.method.reuses() {
            n_f * per_pixel * pixels
                + threads * n_f * per_pixel * (crate::film::local::MAX_PIXELS as u64).min(pixels)
        } else {
            12 * pixels // the frame's RGB
        };
        let adaptive = if self.effective_adaptive().is_some() {
            2 * n_f * pixels
        } else {
            0
        };
        // A frame smaller than a tile has one smaller tile, and only as many workers hold a
        // tile's samples as there are tiles.
        let tile = crate::film::tiles::TILE;
        let tile_pixels = (tile.min(w) * tile.min(h)) as u64;
        let tiles = (w.div_ceil(tile) as u64) * (h.div_ceil(tile) as u64);
        let threads = threads.min(tiles.max(1));
        let workers = if self.method.reuses() {
            let samples = self.spp
                * if self.effective_adaptive().is_some() {
                    self.window
                } else {
                    1
                };
            threads * crate::reuse::shade::worker_bytes(samples, self.window, tile_pixels)
        } else {
            threads * tile_pixels * crate::integrator::wavefront::Wavefront::bytes_per_path() as u64
        };
        // Developed frames (f32: RGB, `--aov`'s two channels, `--denoise-layers`' nine): one
        // on the render's thread, one waiting for the writer (`driver::sink::Writer`), and one
        // being written with the writer's two copies of it.
        let channels = 3
            + if self.aov { 2 } else { 0 }
            + self.denoise.map_or(0, |l| l.extra_channels().len()) as u64;
        let develop = 5 * 4 * channels * pixels;
        // The denoiser's images and its bounded scratch.
        let denoise = if self.denoise.is_some() {
            use crate::image::oidn;
            oidn::BYTES_PER_PIXEL * pixels + ((oidn::MAX_SCRATCH_MB as u64) << 20)
        } else {
            0
        };
        // Thread stacks, Embree's and the image library's working memory.
        let rest = 32 << 20;
        frames + adaptive + workers + develop + denoise + rest
    }

    /// Refuse a render whose `memory_estimate` and the scene's texture cache (`textures`
    /// bytes, filled while rendering) pass `available` (where known), naming the flags that
    /// change it.
    pub fn check_memory(
        &self,
        (w, h): (u32, u32),
        available: Option<u64>,
        textures: u64,
    ) -> Result<()> {
        let need = self.memory_estimate((w, h));
        let size = crate::util::mem::size;
        // Where the scene loaded holds more than the frames would, the scene is what to
        // lighten (an emitting OBJ placed a hundred times beside a frame of 8x6 pixels was
        // told to lower --res).
        // (Half a gigabyte at least: the libraries alone hold about 0.1 GB, and under a tight
        // `ulimit -v` a small scene's frames are what to lower.)
        let held = crate::util::mem::rss_bytes();
        let advice = if held >= 1 << 29 && held / 4 > need.saturating_add(textures) {
            format!(
                "the scene loaded holds about {}: render a lighter scene, or give the run more \
                 memory",
                size(held)
            )
        } else if self.method.reuses() {
            "lower --res or --window or --spp, or use fewer --threads".to_string()
        } else {
            "lower --res".to_string()
        };
        match available {
            Some(a) if need.saturating_add(textures) > a => bail!(
                "--res {w}x{h} with --method {}{}{}: the frames in flight need about {}{}, but \
                 {} of memory is available; {advice}",
                self.method.name(),
                // (The independent tracer takes no window.)
                if self.method.reuses() {
                    format!(" --window {}", self.window)
                } else {
                    String::new()
                },
                if self.denoise.is_some() {
                    " --denoise"
                } else {
                    ""
                },
                size(need),
                if textures > 0 {
                    format!(
                        " and the scene's textures about {} in their cache",
                        size(textures)
                    )
                } else {
                    String::new()
                },
                size(a),
            ),
            _ => Ok(()),
        }
    }

    /// The output pattern and the stats file, checked before anything is traced: a long render
    /// must not fail at its end.
    /// The folders it created go again unless the caller keeps them.
    pub fn check_files(&self, plan: &Plan) -> Result<(OutputPattern, CreatedDirs)> {
        let (out, created) = check_output(&self.out, &plan.frames, (plan.width, plan.height))?;
        if let Some(p) = &self.stats {
            check_file_target("--stats", p)?;
        }
        Ok((out, created))
    }
}

/// Frames smaller than this on a side are denoised with a warning (`flag_warnings`).
const MIN_DENOISE_SIDE: u32 = 32;

/// The warning for denoising (`what`: the flag that asks for it) frames of `width` x `height`
/// too small for the denoiser to work well, if they are.
pub fn small_denoise_warning(what: &str, (width, height): (u32, u32)) -> Option<String> {
    (width.min(height) < MIN_DENOISE_SIDE).then(|| {
        format!(
            "{what} on {width}x{height} frames: the denoiser needs more of an image to work from \
             than {MIN_DENOISE_SIDE} pixels a side (8x8 frames of 'cornell' came out 30% darker \
             than their radiance, 16x12 5%, 64x48 2%)"
        )
    })
}

impl RenderOptions {
    /// Flags given that change nothing for this render, or not what they should, in words (the
    /// command line warns); `(width, height)`: the frames'.
    pub fn flag_warnings(&self, out: &OutputPattern, (width, height): (u32, u32)) -> Vec<String> {
        let mut w = Vec::new();
        if self.denoise.is_some() {
            w.extend(small_denoise_warning("--denoise", (width, height)));
        }
        if self.aov && !self.method.reuses() {
            w.push("--aov: the independent tracer has no reuse channels; ignored".into());
        } else if self.aov && !out.is_exr() {
            w.push(format!(
                "--aov: {} holds RGB only; the extra channels were not written (use .exr)",
                self.out
            ));
        }
        if self.denoise == Some(super::denoise::Layers::RawAndGuides) && !out.is_exr() {
            w.push(format!(
                "--denoise-layers: {} holds RGB only; the raw and guide layers were not written \
                 (use .exr)",
                self.out
            ));
        }
        if self.exr_float && !out.is_exr() {
            w.push(format!("--exr-float: {} is not EXR; ignored", self.out));
        }
        if !self.packets && !self.method.reuses() {
            w.push("--visibility: the independent tracer tests no reuse; ignored".into());
        }
        if self.method.reuses() && self.window == 1 {
            w.push(format!(
                "--method {}: --window 1 (also the default) makes groups of one frame, which \
                 reuse nothing: this renders as the independent tracer would (give --window 3 or \
                 more)",
                self.method.name()
            ));
        }
        if self.adaptive.is_some() && self.window == 1 {
            w.push(
                "--adaptive with --window 1: a group of one frame lands nothing from other \
                 frames, so every pixel gets --spp; ignored"
                    .into(),
            );
        }
        w
    }
}

/// An output pattern that can take `frames`: parsed, with a frame field if it is more than one,
/// in a format OIIO writes, in a folder where files can be created.
pub fn check_output(
    pattern: &str,
    frames: &RangeInclusive<u32>,
    (width, height): (u32, u32),
) -> Result<(OutputPattern, CreatedDirs)> {
    let out = OutputPattern::parse(pattern)?;
    if frames.start() != frames.end() && !out.has_frame_field() {
        bail!(
            "--out {pattern}: several frames need a frame number field such as '####' in the name"
        );
    }
    let created = out.validate()?;
    out.probe(width, height)?;
    Ok((out, created))
}
