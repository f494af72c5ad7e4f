//! The `reframe` command line.
//!
//! ```text
//! reframe render [SCENE] --method independent --spp 8 --frames 0-47 --res 320x240 \
//!     --out out/vase_####.exr --seed 0 --threads 0 --stats stats.json
//! reframe render vase --method mis-exact --window 7 --chunk 2/3 --out out/vase_####.exr
//! reframe merge --chunks 3 --out out/vase_####.exr
//! reframe bench [SCENE] --json bench.json
//! reframe reference [SCENE] --frames 15-31 --reference-spp 256
//! reframe compare [SCENE] --out out/compare
//! ```
use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use reframe::checkpoint::{default_checkpoint_dir, Chunk};
use reframe::compare;
use reframe::embree::Device;
use reframe::render::{self, Method, RenderOptions};
use reframe::scene::Scene;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

#[derive(Parser)]
#[command(
    name = "reframe",
    version,
    about = "Render camera animations, reusing frames (Méndez-Feliu et al. 2006)"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
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

#[derive(clap::Args)]
struct ReferenceArgs {
    /// Scene TOML file or shipped scene (default: vase).
    scene: Option<String>,
    /// Frames, "A-B" (default: 17 around the middle of the animation).
    #[arg(long, value_parser = parse_frames)]
    frames: Option<(u32, u32)>,
    /// Resolution "WxH" (default: the scene's).
    #[arg(long, value_parser = parse_res)]
    res: Option<(u32, u32)>,
    /// Samples per pixel of the reference (a multiple of 8: it is 8 passes, for its variance).
    #[arg(long, default_value_t = 256)]
    reference_spp: u32,
    /// Folder of cached references.
    #[arg(long, default_value = "out/reference-cache")]
    cache: PathBuf,
    #[arg(long, default_value_t = 0)]
    threads: usize,
}

#[derive(clap::Args)]
struct MergeArgs {
    /// The partial files of chunks 1..N (`<out folder>/<name>.chunk-K-of-N.partial`).
    #[arg(required_unless_present = "chunks", conflicts_with = "chunks")]
    partials: Vec<PathBuf>,
    /// Instead of naming the partial files: merge the N chunks of the render that was given
    /// this --out (their files are found beside it).
    #[arg(long, requires = "out")]
    chunks: Option<u32>,
    /// Output pattern of the frames (default: the one the chunks were rendered with).
    #[arg(long)]
    out: Option<String>,
}

#[derive(clap::Args)]
struct CompareArgs {
    #[command(flatten)]
    reference: ReferenceArgs,
    /// Folder for compare.json, compare.csv and the charts (PNG and SVG).
    #[arg(long, default_value = "out/compare")]
    out: PathBuf,
    /// Methods to compare, comma-separated.
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = [Method::Independent, Method::Havran, Method::Mis, Method::MisExact])]
    methods: Vec<Method>,
    /// Samples per pixel of the independent runs, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = [1, 2, 4, 8, 16])]
    budgets: Vec<u32>,
    /// Native samples per pixel of the reuse runs, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = [1, 2])]
    reuse_budgets: Vec<u32>,
    /// Frames per group n_f of the reuse runs, comma-separated (odd; longer than the frames:
    /// skipped).
    #[arg(long, value_delimiter = ',', default_values_t = [3, 7, 17])]
    windows: Vec<u32>,
    /// Crop of the equal-time strip, "X,Y,W,H" in pixels (default: a centred square of half
    /// the height).
    #[arg(long, value_parser = parse_crop)]
    crop: Option<[u32; 4]>,
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

fn parse_crop(s: &str) -> Result<[u32; 4], String> {
    let v: Vec<u32> = s
        .split(',')
        .map(|p| p.trim().parse())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("'{s}': expected X,Y,W,H in pixels"))?;
    <[u32; 4]>::try_from(v).map_err(|_| format!("'{s}': expected X,Y,W,H in pixels"))
}

#[derive(clap::Args)]
struct RenderArgs {
    /// Scene TOML file, or a shipped scene: vase (default), cornell, furnace.
    scene: Option<String>,
    #[arg(long, value_enum, default_value_t = Method::Independent)]
    method: Method,
    /// Samples per pixel (for reuse methods: native samples per pixel per group pass).
    #[arg(long, default_value_t = 8)]
    spp: u32,
    /// Frames per reuse group, n_f = 2n+1 (reuse methods only).
    #[arg(long, default_value_t = 1)]
    window: u32,
    /// How reuse visibility tests are traced: 16-wide coherent packets or single rays.
    #[arg(long, value_enum, default_value_t = Visibility::Packet)]
    visibility: Visibility,
    /// Write extra EXR channels per frame: `spp_eff` (samples that landed per pixel) and
    /// `lost_reuse` (share of attempted reuses lost).
    #[arg(long)]
    aov: bool,
    /// Frames to render, 0-based and inclusive: "A-B" or "A" (default: all).
    #[arg(long, value_parser = parse_frames)]
    frames: Option<(u32, u32)>,
    /// Resolution "WxH" (default: the scene's).
    #[arg(long, value_parser = parse_res)]
    res: Option<(u32, u32)>,
    /// Output pattern; '####' is the zero-padded frame number, the extension picks the format
    /// (exr: linear half float; png, jpg, tif: 8-bit sRGB). Default: out/<scene>_####.exr
    #[arg(long)]
    out: Option<String>,
    /// Write EXR pixels as 32-bit float instead of half.
    #[arg(long)]
    exr_float: bool,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Worker threads (0: one per core).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Maximum path length in bounces.
    #[arg(long, default_value_t = 16)]
    max_depth: u32,
    /// Write render statistics as JSON.
    #[arg(long)]
    stats: Option<PathBuf>,
    /// Continue an interrupted render from its checkpoint (same command line otherwise).
    #[arg(long)]
    resume: bool,
    /// Checkpoint folder (default: `<out folder>/<name>.checkpoint`, or
    /// `<name>.chunk-K-of-N.checkpoint` for a chunk).
    #[arg(long)]
    checkpoint: Option<PathBuf>,
    /// Seconds between checkpoints (0: after every group of frames, or every frame).
    #[arg(long, default_value_t = 60.0)]
    checkpoint_every: f64,
    /// mis-exact: extra native samples where a pixel expects fewer reused samples than others
    /// (borders, disocclusions, cuts), topping each pixel up to F n_f n_r (F = 0.75 if not
    /// given).
    #[arg(long, num_args = 0..=1, default_missing_value = "0.75", value_name = "F")]
    adaptive: Option<f32>,
    /// Render chunk K of N (1-based) of the groups and write its partial file
    /// `<out folder>/<name>.chunk-K-of-N.partial` for `reframe merge`.
    #[arg(long, value_parser = parse_chunk)]
    chunk: Option<Chunk>,
}

fn parse_chunk(s: &str) -> Result<Chunk, String> {
    let err = || format!("'{s}': expected K/N with 1 <= K <= N, e.g. 2/3");
    let (k, n) = s.split_once('/').ok_or_else(err)?;
    let (k, n): (u32, u32) = (
        k.trim().parse().map_err(|_| err())?,
        n.trim().parse().map_err(|_| err())?,
    );
    if k == 0 || k > n {
        return Err(err());
    }
    Ok(Chunk { k, n })
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum Visibility {
    Packet,
    Single,
}

#[derive(clap::Args)]
struct BenchArgs {
    /// Scene TOML file or shipped scene (default: vase).
    scene: Option<String>,
    /// Samples per pixel of the cost and ray-rate passes.
    #[arg(long, default_value_t = 4)]
    spp: u32,
    /// Native samples per pixel n_r of the speed-up runs.
    #[arg(long, default_value_t = 1)]
    speedup_spp: u32,
    /// Group sizes n_f of the speed-up runs, comma-separated (longer than the animation: skipped).
    #[arg(long, value_delimiter = ',', default_values_t = [3, 7, 17, 33])]
    windows: Vec<u32>,
    /// Resolution "WxH" (default: the scene's).
    #[arg(long, value_parser = parse_res)]
    res: Option<(u32, u32)>,
    /// Frame to measure (default: the middle one).
    #[arg(long)]
    frame: Option<u32>,
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Write the figures as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
}

fn parse_frames(s: &str) -> Result<(u32, u32), String> {
    let err = || format!("'{s}': expected A-B or A (0-based frame numbers)");
    let (a, b) = match s.split_once('-') {
        Some((a, b)) => (
            a.trim().parse().map_err(|_| err())?,
            b.trim().parse().map_err(|_| err())?,
        ),
        None => {
            let a = s.trim().parse().map_err(|_| err())?;
            (a, a)
        }
    };
    if a > b {
        return Err(format!("'{s}': the first frame is after the last"));
    }
    Ok((a, b))
}

fn parse_res(s: &str) -> Result<(u32, u32), String> {
    let err = || format!("'{s}': expected WxH, e.g. 320x240");
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(err)?;
    let (w, h): (u32, u32) = (
        w.trim().parse().map_err(|_| err())?,
        h.trim().parse().map_err(|_| err())?,
    );
    if w == 0 || h == 0 {
        return Err(format!("'{s}': width and height must be positive"));
    }
    // The scene files' limit too: 2^28 pixels (16384 x 16384) keeps every per-pixel index and
    // buffer size far inside 32 bits.
    if w as u64 * h as u64 > 1 << 28 {
        return Err(format!("'{s}': at most 2^28 pixels (e.g. 16384x16384)"));
    }
    Ok((w, h))
}

fn main() {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) if !e.use_stderr() => e.exit(), // --help, --version
        Err(e) => {
            // Keep usage errors to one line too; `--help` has the rest.
            let text = e.render().to_string();
            eprintln!(
                "{} (see --help)",
                text.lines().next().unwrap_or("invalid arguments")
            );
            std::process::exit(2);
        }
    };
    if let Err(e) = run(cli) {
        if let Some(i) = e.downcast_ref::<render::Interrupted>() {
            eprintln!("{i}");
            if i.checkpoint.is_some() {
                eprintln!("resume with: {}", resume_command());
            }
            std::process::exit(130);
        }
        // One line: the chain of contexts, outermost first.
        let msg = format!("{e:#}").replace('\n', " ");
        eprintln!("error: {msg}");
        std::process::exit(1);
    }
}

/// The scene's load warnings, once a command has succeeded (a failure stays one line).
fn print_warnings(scene: &Scene) {
    for w in &scene.warnings {
        eprintln!("warning: {w}");
    }
}

/// This process's command line with `--resume` added, quoted for a POSIX shell.
fn resume_command() -> String {
    let mut args: Vec<String> = std::env::args().collect();
    if !args.iter().any(|a| a == "--resume") {
        args.push("--resume".into());
    }
    args.iter()
        .map(|a| {
            if a.chars()
                .all(|c| c.is_ascii_alphanumeric() || "-_./=#:,".contains(c))
            {
                a.clone()
            } else {
                format!("'{}'", a.replace('\'', "'\\''"))
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
}

/// Ctrl-C, SIGTERM (Slurm's `scancel`, a scheduler's time limit) and SIGHUP: the first stops the
/// render at the next group or frame, after a checkpoint; the second stops at once (the last
/// checkpoint stays valid: every file is written under a temporary name and renamed).
fn install_signal_handler() -> Result<Arc<AtomicBool>> {
    let flag = Arc::new(AtomicBool::new(false));
    let f = flag.clone();
    ctrlc::set_handler(move || {
        if f.swap(true, Ordering::SeqCst) {
            eprintln!("\nstopping now; the last checkpoint is kept");
            std::process::exit(130);
        }
        eprintln!(
            "\ninterrupt: finishing the current group of frames and writing a checkpoint \
             (interrupt again to stop at once)"
        );
    })
    .context("installing the signal handler")?;
    Ok(flag)
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Render(a) => {
            let scene_name = a.scene.unwrap_or_else(|| "vase".into());
            let device = Device::new()?;
            let scene = Scene::load(&scene_name, &device)?;
            let out = a
                .out
                .unwrap_or_else(|| format!("out/{}_####.exr", scene.name));
            let opts = RenderOptions {
                method: a.method,
                spp: a.spp,
                window: a.window,
                packets: matches!(a.visibility, Visibility::Packet),
                aov: a.aov,
                frames: a.frames.map(|(x, y)| x..=y),
                resolution: a.res,
                seed: a.seed,
                threads: a.threads,
                max_depth: a.max_depth,
                exr_float: a.exr_float,
                stats: a.stats.clone(),
                progress: true,
                checkpoint: Some(
                    a.checkpoint
                        .clone()
                        .unwrap_or_else(|| default_checkpoint_dir(&out, a.chunk)),
                ),
                checkpoint_every: a.checkpoint_every,
                resume: a.resume,
                adaptive: a.adaptive,
                chunk: a.chunk,
                interrupt: Some(install_signal_handler()?),
                out,
            };
            if !opts.checkpoint_every.is_finite() || opts.checkpoint_every < 0.0 {
                bail!(
                    "--checkpoint-every {}: seconds must be 0 or more",
                    opts.checkpoint_every
                );
            }
            if opts.max_depth == 0 {
                bail!("--max-depth 0: paths need at least one bounce");
            }
            let stats = render::render(&scene, &opts)?;
            print_warnings(&scene);
            let first = stats.outputs.first().context("no frame written")?;
            let how = if stats.method.reuses() && stats.chunk.is_none() {
                format!(
                    "{}, window {}, {:.1} effective spp, {:.1}% reuses lost",
                    stats.method.name(),
                    stats.window,
                    stats.mean_effective_spp,
                    100.0 * stats.lost_reuse_fraction
                )
            } else if stats.method.reuses() {
                format!("{}, window {}", stats.method.name(), stats.window)
            } else {
                stats.method.name().to_string()
            };
            let what = match &stats.chunk {
                Some(c) => format!(
                    "chunk {c} ({} {}-{}) of frames {}-{}",
                    if stats.method.reuses() {
                        "groups"
                    } else {
                        "frames"
                    },
                    stats.units[0],
                    stats.units[1],
                    stats.first_frame,
                    stats.last_frame
                ),
                None => format!("{} frame(s)", stats.frames),
            };
            eprintln!(
                "rendered {what} of '{}' ({}x{}, {} spp, {how}) in {:.1} s, {:.2} Mrays/s, peak memory {} MB",
                scene.name,
                stats.width,
                stats.height,
                stats.spp,
                stats.seconds,
                stats.rays_per_second / 1e6,
                stats.peak_rss_bytes / 1_000_000
            );
            if stats.nonfinite_pixels > 0 {
                eprintln!(
                    "warning: {} pixels are NaN or infinite",
                    stats.nonfinite_pixels
                );
            }
            let last = stats.outputs.last().unwrap();
            if first == last {
                println!("wrote {first}");
            } else {
                println!("wrote {first} .. {last}");
            }
            if let Some(p) = &a.stats {
                println!("stats in {}", p.display());
            }
            Ok(())
        }
        Command::Merge(a) => {
            let partials = match a.chunks {
                Some(0) => bail!("--chunks 0: at least one chunk is needed"),
                Some(n) => {
                    // Those that exist: merge names a missing chunk itself.
                    let all: Vec<PathBuf> = (1..=n)
                        .map(|k| {
                            let out = a.out.as_deref().unwrap();
                            reframe::checkpoint::partial_path(out, Chunk { k, n })
                        })
                        .collect();
                    let there: Vec<PathBuf> = all.iter().filter(|p| p.exists()).cloned().collect();
                    if there.is_empty() {
                        bail!(
                            "--chunks {n}: none of the partial files is there (expected {} ..)",
                            all[0].display()
                        );
                    }
                    there
                }
                None => a.partials.clone(),
            };
            let r = reframe::merge::merge(&partials, a.out.as_deref())?;
            let (first, last) = (r.frames.first().unwrap(), r.frames.last().unwrap());
            eprintln!(
                "merged {} partial file(s) ({:.1} MB) into {} frame(s) ({:.1} MB) in {:.2} s",
                partials.len(),
                r.partial_bytes as f64 / 1e6,
                r.frames.len(),
                r.frame_bytes as f64 / 1e6,
                r.seconds
            );
            if first == last {
                println!("wrote {}", first.display());
            } else {
                println!("wrote {} .. {}", first.display(), last.display());
            }
            Ok(())
        }
        Command::Bench(a) => {
            let scene_name = a.scene.unwrap_or_else(|| "vase".into());
            let device = Device::new()?;
            let scene = Scene::load(&scene_name, &device)?;
            if let Some(p) = &a.json {
                render::check_stats_path(p)?;
            }
            let opts = reframe::bench::BenchOptions {
                spp: a.spp,
                res: a.res,
                frame: a.frame,
                threads: a.threads,
                speedup_spp: a.speedup_spp,
                windows: a.windows,
                ..Default::default()
            };
            let report = reframe::bench::run(&scene, &opts)?;
            print_warnings(&scene);
            println!("{}", report.table());
            if let Some(p) = &a.json {
                render::write_json(p, &report)?;
                println!("figures in {}", p.display());
            }
            Ok(())
        }
        Command::Reference(a) => {
            let device = Device::new()?;
            let scene = Scene::load(a.scene.as_deref().unwrap_or("vase"), &device)?;
            let range = match a.frames {
                Some((x, y)) => x..=y,
                None => compare::default_frames(&scene),
            };
            render::check_frames(&scene, &range)?;
            let res = a.res.unwrap_or((scene.width, scene.height));
            let pool = render::thread_pool(a.threads)?;
            reframe::embree::set_flush_denormals();
            let r = compare::reference(&scene, range, res, a.reference_spp, &a.cache, &pool, true)?;
            print_warnings(&scene);
            let how = if r.cached {
                "cached".to_string()
            } else {
                format!("rendered in {:.1} s", r.seconds)
            };
            println!(
                "reference of '{}' ({}x{}, {} spp) in {} ({how})",
                scene.name,
                res.0,
                res.1,
                r.spp,
                r.dir.display()
            );
            Ok(())
        }
        Command::Compare(a) => {
            let device = Device::new()?;
            let r = a.reference;
            let scene = Scene::load(r.scene.as_deref().unwrap_or("vase"), &device)?;
            let opts = compare::CompareOptions {
                frames: r.frames.map(|(x, y)| x..=y),
                res: r.res,
                methods: a.methods,
                budgets: a.budgets,
                reuse_budgets: a.reuse_budgets,
                windows: a.windows,
                reference_spp: r.reference_spp,
                cache: r.cache,
                out: a.out,
                threads: r.threads,
                seed: a.seed,
                crop: a.crop,
                progress: true,
            };
            let report = compare::compare(&scene, &opts)?;
            print_warnings(&scene);
            println!("{}", compare::summary(&report));
            println!("results in {}", opts.out.display());
            Ok(())
        }
    }
}
