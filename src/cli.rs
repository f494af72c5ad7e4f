//! The command line's shape: clap's structs for every subcommand and the parsers of its values.
//! `main.rs` dispatches them; the checks of what the values mean belong to the library
//! (`driver::RenderOptions::validate` and the like), so that library and command line agree.
use clap::{Parser, Subcommand};
use reframe::eval::compare::{Candidate, Regime};
use reframe::reuse::Method;
use reframe::state::key::Chunk;
use std::path::PathBuf;

#[derive(Parser)]
#[command(
    name = "reframe",
    version,
    about = "Render camera animations, reusing frames (Méndez-Feliu et al. 2006)"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand)]
pub enum Command {
    /// Render frames of an animation.
    Render(RenderArgs),
    /// Measure the cost model's c_e, c_l, c_v, the speed-up eq. 16 predicts against the one
    /// measured, and the tracer's rays per second against bare Embree calls on the same rays.
    Bench(BenchArgs),
    /// Render (or find in the cache) the high-sample reference frames that compare measures against.
    Reference(ReferenceArgs),
    /// Combine the partial files of a render split with `render --chunk K/N` into its frames,
    /// bitwise identical to a one-process render.
    Merge(MergeArgs),
    /// Render every method at a ladder of budgets, measure error, time and flicker against the
    /// reference, and chart them.
    Compare(CompareArgs),
}

impl Command {
    /// The command's `--threads`.
    pub fn threads(&self) -> usize {
        match self {
            Command::Render(a) => a.threads,
            Command::Bench(a) => a.threads,
            Command::Reference(a) => a.threads,
            Command::Merge(a) => a.threads,
            Command::Compare(a) => a.reference.threads,
        }
    }
}

#[derive(clap::Args)]
pub struct ReferenceArgs {
    /// Scene TOML file or shipped scene (default: vase-long, the vase's zoom with 36 frames of
    /// camera move either side, long enough for the steady state of n_f = 33).
    pub scene: Option<String>,
    /// Frames, "A-B" (default: 17 around the middle of the animation).
    #[arg(long, value_parser = parse_frames, allow_negative_numbers = true)]
    pub frames: Option<(u32, u32)>,
    /// Resolution "WxH" (default: the scene's).
    #[arg(long, value_parser = parse_res)]
    pub res: Option<(u32, u32)>,
    /// Samples per pixel of the reference (a multiple of 8: it is 8 passes, for its variance).
    #[arg(long, default_value_t = 256)]
    pub reference_spp: u32,
    /// Longest path, in bounces, of the reference (and, for compare, of every run).
    #[arg(long, default_value_t = crate::driver::options::DEFAULT_MAX_DEPTH)]
    pub max_depth: u32,
    /// Folder of cached references.
    #[arg(long, default_value = "out/reference-cache")]
    pub cache: PathBuf,
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Refuse what loading would repair with a warning in a real model (degenerate faces, zero
    /// normals, unknown materials, clamped values, ...), naming the file and line.
    #[arg(long)]
    pub strict: bool,
}

#[derive(clap::Args)]
pub struct MergeArgs {
    /// The partial files of chunks 1..N (`<out folder>/<name>.chunk-K-of-N.partial`).
    #[arg(required_unless_present = "chunks", conflicts_with = "chunks")]
    pub partials: Vec<PathBuf>,
    /// Instead of naming the partial files: merge the N chunks of the render that was given
    /// this --out (their files are found beside it).
    #[arg(long, requires = "out")]
    pub chunks: Option<u32>,
    /// Output pattern of the frames (default: the one the chunks were rendered with).
    #[arg(long)]
    pub out: Option<String>,
    /// The scene the chunks rendered: needed when they were rendered with --denoise (the merge
    /// denoises each frame and traces the denoiser's guides in it); checked against their hash.
    #[arg(long)]
    pub scene: Option<String>,
    /// Worker threads of the denoising (0: one per core).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
}

#[derive(clap::Args)]
pub struct CompareArgs {
    #[command(flatten)]
    pub reference: ReferenceArgs,
    /// Folder for compare.json, compare.csv and the charts (PNG and SVG).
    #[arg(long, default_value = "out/compare")]
    pub out: PathBuf,
    /// Methods to compare, comma-separated: independent, havran, mis, mis-exact, mis-cv, each
    /// optionally with "+oidn" (every measured frame denoised by Open Image Denoise, its time
    /// charged), e.g. independent,independent+oidn,mis-cv,mis-cv+oidn.
    #[arg(long, value_delimiter = ',', default_values_t = Method::ALL.map(Candidate::plain))]
    pub methods: Vec<Candidate>,
    /// Samples per pixel of the independent runs, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = [1, 2, 4, 8, 16])]
    pub budgets: Vec<u32>,
    /// Native samples per pixel of the reuse runs, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = [1, 2])]
    pub reuse_budgets: Vec<u32>,
    /// Frames per group n_f of the reuse runs, comma-separated (odd; longer than the frames:
    /// skipped).
    #[arg(long, value_delimiter = ',', default_values_t = [3, 7, 17, 33])]
    pub windows: Vec<u32>,
    /// What a reuse run measures: `steady` (every measured frame in all n_f of its groups,
    /// charged one group's time: a long animation) or `range` (only the measured frames
    /// rendered, their ends in fewer groups).
    #[arg(long, value_enum, default_value_t = Regime::Steady)]
    pub regime: Regime,
    /// Crop of the equal-time strip, "X,Y,W,H" in pixels (default: a centred square of half
    /// the shorter side).
    #[arg(long, value_parser = parse_crop)]
    pub crop: Option<[u32; 4]>,
    /// Seeds of the bias images of the "+oidn" methods: the crop frame of each one's strip run
    /// rendered this many times, its mean minus the reference (bias_<method>.exr, bias.png;
    /// 0: none).
    #[arg(long, default_value_t = 4)]
    pub bias_seeds: u32,
    #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
    pub seed: u64,
}

pub fn parse_crop(s: &str) -> Result<[u32; 4], String> {
    let v: Vec<u32> = s
        .split(',')
        .map(|p| p.trim().parse())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("'{s}': expected X,Y,W,H in pixels"))?;
    <[u32; 4]>::try_from(v).map_err(|_| format!("'{s}': expected X,Y,W,H in pixels"))
}

#[derive(clap::Args)]
pub struct RenderArgs {
    /// Scene TOML file, or a shipped scene: vase (default), vase-long, cornell, furnace.
    pub scene: Option<String>,
    #[arg(long, value_enum, default_value_t = Method::Independent)]
    pub method: Method,
    /// Samples per pixel (for reuse methods: native samples per pixel per group pass).
    #[arg(long, default_value_t = 8)]
    pub spp: u32,
    /// Frames per reuse group, n_f: odd, each frame reused in the n_f frames around it (reuse
    /// methods only; at 1 they reuse nothing).
    #[arg(long, default_value_t = 1)]
    pub window: u32,
    /// How primary rays are traced (the independent tracer's and the reuse methods' native
    /// samples'): 16-wide coherent packets, or single rays (the same estimator; hits may differ
    /// in their last bits).
    #[arg(long, value_enum, default_value_t = Visibility::Packet)]
    pub primary: Visibility,
    /// How the rays after the primary hit are traced (continuation and shadow rays, the
    /// tile's paths advancing together bounce by bounce): 16-wide packets of live paths, or
    /// single rays (the same estimator; hits may differ in their last bits).
    #[arg(long, value_enum, default_value_t = Visibility::Packet)]
    pub paths: Visibility,
    /// How reuse visibility tests are traced: 16-wide coherent packets or single rays.
    #[arg(long, value_enum, default_value_t = Visibility::Packet)]
    pub visibility: Visibility,
    /// Write extra EXR channels per frame: `spp_eff` (samples that landed per pixel) and
    /// `lost_reuse` (share of attempted reuses lost).
    #[arg(long)]
    pub aov: bool,
    /// Frames to render, 0-based and inclusive: "A-B" or "A" (default: all).
    #[arg(long, value_parser = parse_frames, allow_negative_numbers = true)]
    pub frames: Option<(u32, u32)>,
    /// Resolution "WxH" (default: the scene's).
    #[arg(long, value_parser = parse_res)]
    pub res: Option<(u32, u32)>,
    /// Output pattern; '####' is the zero-padded frame number, the extension picks the format
    /// (exr: linear half float; png, jpg, tif: 8-bit sRGB). Default: out/<scene>_####.exr
    #[arg(long)]
    pub out: Option<String>,
    /// Write EXR pixels as 32-bit float instead of half.
    #[arg(long)]
    pub exr_float: bool,
    /// Denoise every frame with Intel Open Image Denoise (its RT filter, HDR, guided by albedo
    /// and normal images of the first hits) before writing it; any method
    #[arg(long)]
    pub denoise: bool,
    /// With --denoise, also keep the undenoised radiance and the guides as EXR layers
    /// (raw.R/G/B, albedo.R/G/B, normal.X/Y/Z)
    #[arg(long, requires = "denoise")]
    pub denoise_layers: bool,
    #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
    pub seed: u64,
    /// Worker threads (0: one per core).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Longest path, in bounces (a bound paths do not reach: roulette ends them first).
    #[arg(long, default_value_t = crate::driver::options::DEFAULT_MAX_DEPTH)]
    pub max_depth: u32,
    /// Write render statistics as JSON.
    #[arg(long)]
    pub stats: Option<PathBuf>,
    /// Continue an interrupted render from its checkpoint (same command line otherwise).
    #[arg(long)]
    pub resume: bool,
    /// Checkpoint folder (default: `<out folder>/<name>.checkpoint`, or
    /// `<name>.chunk-K-of-N.checkpoint` for a chunk).
    #[arg(long)]
    pub checkpoint: Option<PathBuf>,
    /// Seconds between checkpoints (0: after every group of frames, or every frame).
    #[arg(long, default_value_t = 60.0, allow_negative_numbers = true)]
    pub checkpoint_every: f64,
    /// mis-exact and mis-cv: extra native samples where a pixel expects fewer reused samples
    /// than others (borders, disocclusions, cuts), topping each pixel up to F n_f n_r (F in
    /// (0, 1]; `--adaptive` alone is 0.75; off without the flag).
    #[arg(
        long,
        num_args = 0..=1,
        default_missing_value = "0.75",
        value_name = "F",
        allow_negative_numbers = true,
        value_parser = parse_share
    )]
    pub adaptive: Option<f32>,
    /// Render chunk K of N (1-based) of the groups and write its partial file
    /// `<out folder>/<name>.chunk-K-of-N.partial` for `reframe merge`.
    #[arg(long, value_parser = parse_chunk)]
    pub chunk: Option<Chunk>,
    /// Refuse what loading would repair with a warning in a real model (degenerate faces, zero
    /// normals, unknown materials, clamped values, ...), naming the file and line.
    #[arg(long)]
    pub strict: bool,
}

/// A share in (0, 1], read in f64 so that a refusal names the value as typed (`1e-300` became
/// the f32 0 and was refused as `--adaptive 0`).
pub fn parse_share(s: &str) -> Result<f32, String> {
    let x: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("'{s}' is not a number"))?;
    if !(x > 0.0 && x <= 1.0) {
        return Err("the target share of n_f n_r must be in (0, 1]".to_string());
    }
    if x < f32::MIN_POSITIVE as f64 {
        return Err(format!(
            "too small a share to hold (at least {:e})",
            f32::MIN_POSITIVE
        ));
    }
    Ok(x as f32)
}

pub fn parse_chunk(s: &str) -> Result<Chunk, String> {
    let err = || format!("'{s}': expected K/N with 1 <= K <= N, e.g. 2/3");
    let (k, n) = s.split_once('/').ok_or_else(err)?;
    // A count past u32 is a count too large, not a form misread (it said "expected K/N").
    let number = |t: &str| {
        t.trim().parse::<u32>().map_err(|e| match e.kind() {
            std::num::IntErrorKind::PosOverflow => format!(
                "'{s}': {} is too large (a render has at most {} frames, and a chunk at least one)",
                t.trim(),
                reframe::scene::MAX_FRAMES
            ),
            _ => err(),
        })
    };
    let (k, n) = (number(k)?, number(n)?);
    if k == 0 || k > n {
        return Err(err());
    }
    Ok(Chunk { k, n })
}

#[derive(Clone, Copy, clap::ValueEnum)]
pub enum Visibility {
    Packet,
    Single,
}

impl Visibility {
    /// The library's name for the choice (`--primary`, `--paths`).
    pub fn rays(self) -> reframe::integrator::Rays {
        match self {
            Visibility::Packet => reframe::integrator::Rays::Packet,
            Visibility::Single => reframe::integrator::Rays::Single,
        }
    }
}

#[derive(clap::Args)]
pub struct BenchArgs {
    /// Scene TOML file or shipped scene (default: vase).
    pub scene: Option<String>,
    /// Samples per pixel of the cost and ray-rate passes.
    #[arg(long, default_value_t = 4)]
    pub spp: u32,
    /// Native samples per pixel n_r of the speed-up runs.
    #[arg(long, default_value_t = 1)]
    pub speedup_spp: u32,
    /// Reuse method of the speed-up runs.
    #[arg(long, value_enum, default_value_t = Method::MisExact)]
    pub method: Method,
    /// Group sizes n_f of the speed-up runs, comma-separated (odd, at most the scene's frames).
    #[arg(long, value_delimiter = ',', default_values_t = reframe::eval::bench::DEFAULT_WINDOWS)]
    pub windows: Vec<u32>,
    /// Resolution "WxH" (default: the scene's).
    #[arg(long, value_parser = parse_res)]
    pub res: Option<(u32, u32)>,
    /// Frame to measure (default: the middle one).
    #[arg(long)]
    pub frame: Option<u32>,
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Longest path, in bounces.
    #[arg(long, default_value_t = crate::driver::options::DEFAULT_MAX_DEPTH)]
    pub max_depth: u32,
    /// Timed runs of each kind (the independent render, the bare replay, each speed-up run's
    /// reuse and independent renders, alternating), whose medians are reported.
    #[arg(long, default_value_t = 3)]
    pub repeats: usize,
    /// Write the figures as JSON.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Refuse what loading would repair with a warning in a real model (degenerate faces, zero
    /// normals, unknown materials, clamped values, ...), naming the file and line.
    #[arg(long)]
    pub strict: bool,
}

/// `t` as a u32 of a flag's value `s`; an error that says `expected` where it is no number, and
/// that the `what` is too large where it is digits past u32 (it said only `expected`).
fn whole_number(s: &str, t: &str, what: &str, expected: &str) -> Result<u32, String> {
    let t = t.trim();
    t.parse().map_err(|_| {
        let digits = t.strip_prefix('+').unwrap_or(t);
        if !digits.is_empty() && digits.bytes().all(|b| b.is_ascii_digit()) {
            format!("'{s}': {what} {t} is past the largest, {}", u32::MAX)
        } else {
            format!("'{s}': {expected}")
        }
    })
}

pub fn parse_frames(s: &str) -> Result<(u32, u32), String> {
    let expected = "expected A-B or A (0-based frame numbers)";
    let frame = |t: &str| whole_number(s, t, "frame", expected);
    if s.trim_start().starts_with('-') {
        return Err(format!(
            "'{s}': frames are numbered from 0, never below (the first frame is 0)"
        ));
    }
    let (a, b) = match s.split_once('-') {
        Some((a, b)) => (frame(a)?, frame(b)?),
        None => {
            let a = frame(s)?;
            (a, a)
        }
    };
    if a > b {
        return Err(format!("'{s}': the first frame is after the last"));
    }
    Ok((a, b))
}

pub fn parse_res(s: &str) -> Result<(u32, u32), String> {
    let expected = "expected WxH, e.g. 320x240";
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("'{s}': {expected}"))?;
    let (w, h) = (
        whole_number(s, w, "width", expected)?,
        whole_number(s, h, "height", expected)?,
    );
    match reframe::driver::options::resolution_problem((w, h)) {
        Some(why) => Err(format!("'{s}': {why}")),
        None => Ok((w, h)),
    }
}

/// The line `render` prints when it is done: what was rendered, how, and how fast.
pub fn render_summary(stats: &reframe::driver::RenderStats) -> String {
    let reuses = stats.method.reuses();
    let how = if reuses && stats.chunk.is_none() {
        format!(
            "{}, window {}, {:.1} effective spp, {:.1}% reuses lost",
            stats.method.name(),
            stats.window,
            stats.mean_effective_spp,
            100.0 * stats.lost_reuse_fraction
        )
    } else if reuses {
        format!("{}, window {}", stats.method.name(), stats.window)
    } else {
        stats.method.name().to_string()
    };
    let what = match &stats.chunk {
        Some(c) => format!(
            "chunk {c} ({} {}-{}) of frames {}-{}",
            if reuses { "groups" } else { "frames" },
            stats.units[0],
            stats.units[1],
            stats.first_frame,
            stats.last_frame
        ),
        None => format!("{} frame(s)", stats.frames),
    };
    format!(
        "rendered {what} of '{}' ({}x{}, {} spp, {how}) in {:.1} s, {:.2} Mrays/s, peak memory {} MB",
        reframe::util::text::printable(&stats.scene),
        stats.width,
        stats.height,
        stats.spp,
        stats.seconds,
        stats.rays_per_second / 1e6,
        stats.peak_rss_bytes / 1_000_000
    )
}

/// `wrote FIRST .. LAST` (or `wrote FILE`) for the files a command wrote.
/// A line break in a file's name is shown as an escape (`\u{a}`), as the other control
/// characters are (`printable`, which turns a message's own line breaks into spaces): shown as a
/// space, the name read as another file's.
pub fn wrote(files: &[String]) -> String {
    let name = |f: &String| f.replace('\n', "\\u{a}");
    match files {
        [] => "wrote nothing".into(),
        [one] => format!("wrote {}", name(one)),
        [first, .., last] => format!("wrote {} .. {}", name(first), name(last)),
    }
}
