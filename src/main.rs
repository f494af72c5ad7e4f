//! The `reframe` command line: parses (`cli.rs`), dispatches to the library, prints one-line
//! summaries, and turns errors into one line on stderr with a non-zero exit.
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
mod cli;

use anyhow::{bail, Context, Result};
use cli::{Cli, Command, Visibility};
use reframe::driver::{self, RenderOptions};
use reframe::embree::Device;
use reframe::eval::{compare, reference};
use reframe::scene::{LoadOptions, Scene};
use reframe::state::key::{chunk_partials, default_checkpoint_dir, partial_path, Chunk};
use reframe::util::fs::{check_file_target, exit_removing_temporaries, exit_with, write_json};
use reframe::util::text::{message, printable};
use reframe::{errln, outln};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

fn main() {
    reframe::sys::keep_stderr();
    reframe::sys::say_aborts();
    reframe::sys::ignore_file_size_signal();
    // A panic's message goes to standard error as the process started with it, like every
    // other line: the default hook writes to descriptor 2, which a reader may have pointed at
    // /dev/null for a moment (`QuietStderr`), and the message was lost.
    std::panic::set_hook(Box::new(|info| {
        let thread = std::thread::current();
        let backtrace = std::backtrace::Backtrace::capture();
        let trace = match backtrace.status() {
            std::backtrace::BacktraceStatus::Captured => format!("\n{backtrace}"),
            _ => "\nnote: run with `RUST_BACKTRACE=1` environment variable to display a \
                  backtrace"
                .to_string(),
        };
        // `info` reads "panicked at FILE:LINE:COL:\nMESSAGE", as the default hook writes it.
        errln!(
            "thread '{}' {info}{trace}",
            thread.name().unwrap_or("<unnamed>")
        );
    }));
    if reframe::util::mem::address_space_limited() {
        reframe::sys::limit_malloc_arenas(2);
    }
    // clap refuses an argument that is not UTF-8 without saying which: say it, and what to do
    // (paths travel as text through the output patterns and the state files' keys).
    if let Some((k, arg)) = std::env::args_os()
        .enumerate()
        .skip(1)
        .find(|(_, a)| a.to_str().is_none())
    {
        errln!(
            "error: argument {k} ('{}', its bytes that are not UTF-8 shown as \u{fffd}) is not UTF-8 \
             text: reframe takes file names and patterns in UTF-8; rename the file (for example \
             `convmv -f latin1 -t utf8 FILE`) or link it under a UTF-8 name",
            printable(&arg.to_string_lossy())
        );
        std::process::exit(2);
    }
    // (Every argument is UTF-8, checked above.)
    let args: Vec<String> = std::env::args_os()
        .map(|a| a.to_string_lossy().into_owned())
        .collect();
    let parsed = negative_numbers(<Cli as clap::CommandFactory>::command())
        .try_get_matches_from(negative_values_joined(args))
        .and_then(|m| <Cli as clap::FromArgMatches>::from_arg_matches(&m));
    let cli = match parsed {
        Ok(cli) => cli,
        // --help, --version: on standard output, whose failure (a full disk) is said as any
        // command's is (clap's own exit said nothing, with status 0).
        // --version names the build too: a resume or a merge refuses another build by its
        // hash (`state::key::build_hash`, which `merge` quotes).
        Err(e) if e.kind() == clap::error::ErrorKind::DisplayVersion => {
            let build = reframe::state::key::build_hash().unwrap_or_else(|_| "unknown".into());
            outln!("reframe {} (build {build})", env!("CARGO_PKG_VERSION"));
            exit_done();
        }
        Err(e) if !e.use_stderr() => {
            let written = e
                .print()
                .and_then(|_| std::io::Write::flush(&mut std::io::stdout()));
            if let Err(w) = written {
                reframe::util::stdout_failed(w);
            }
            exit_done();
        }
        Err(e) => {
            // Keep usage errors to one line too; `--help` has the rest. The line is clap's first
            // paragraph, joined: a list of missing arguments follows its heading, indented.
            let text = e.render().to_string();
            let first: Vec<&str> = text
                .lines()
                .map(str::trim)
                .take_while(|l| !l.is_empty())
                .collect();
            let line = match first.join(" ") {
                l if l.is_empty() => "invalid arguments".to_string(),
                // `merge` with neither its partial files nor `--chunks`: clap names the files
                // alone.
                l if l.contains("<PARTIALS>") => format!(
                    "{l}: name the chunks' partial files, or give --chunks N and the --out \
                     they were rendered with"
                ),
                l => l,
            };
            let line = reframe::util::text::plain_parse_errors(&line);
            errln!("{} (see --help)", message(&line));
            std::process::exit(2);
        }
    };
    if let Err(e) = run(cli) {
        if reframe::util::fs::stopping() {
            exit_with(130); // the signal handler's exit, and its line
        }
        if let Some(c) = e.downcast_ref::<reframe::state::checkpoint::ChunkComplete>() {
            outln!("{}", printable(&c.to_string()));
            exit_with(0);
        }
        if let Some(i) = e.downcast_ref::<driver::Interrupted>() {
            errln!("{}", printable(&i.to_string()));
            if i.checkpoint.is_some() {
                errln!("resume with: {}", resume_command());
            }
            exit_with(130);
        }
        // One line: the chain of contexts, outermost first.
        errln!("error: {}", message(&format!("{e:#}")));
        reframe::util::fs::remove_empty_made_folders();
        exit_with(1);
    }
    exit_done();
}

/// Exit once the work is done: 0, or 1 where standard output could not be written (what was
/// printed is lost; a closed pipe is no failure: `util::stdout_failed`).
fn exit_done() -> ! {
    if let Some(e) = reframe::util::stdout_error() {
        errln!("error: writing standard output: {}", printable(&e));
        exit_with(1);
    }
    exit_with(0)
}

/// A scene by name or path; `strict` refuses what loading would repair.
fn load(name: &str, device: &Device, strict: bool) -> Result<Scene> {
    Scene::load_with(name, device, &LoadOptions { strict })
}

/// The scene's load warnings, once a command has succeeded (a failure stays one line).
fn print_warnings(scene: &Scene) {
    for w in &scene.warnings {
        errln!("warning: {}", message(w));
    }
}

/// The command line with each value that starts with a minus and a digit joined to the option
/// before it (`--res -5x3` as `--res=-5x3`), so that the option's parser refuses it naming the
/// option: clap takes a value that starts with `-` for a flag unless all of it is a number
/// (`negative_numbers`), so `--res -5x3`, `--crop -1,0,4,4` and `--budgets -1,2` said
/// "unexpected argument '-5'", naming none. Nothing after a bare `--` is touched.
fn negative_values_joined(args: Vec<String>) -> Vec<String> {
    let mut out = Vec::with_capacity(args.len());
    let mut it = args.into_iter().peekable();
    while let Some(a) = it.next() {
        if a == "--" {
            out.push(a);
            out.extend(it);
            break;
        }
        let option = a.len() > 2 && a.starts_with("--") && !a.contains('=');
        let negative = |v: &String| {
            let mut c = v.chars();
            c.next() == Some('-') && c.next().is_some_and(|d| d.is_ascii_digit() || d == '.')
        };
        match it.next_if(|v| option && negative(v)) {
            Some(v) => out.push(format!("{a}={v}")),
            None => out.push(a),
        }
    }
    out
}

/// Every option that takes a value takes one that looks like a negative number as its value,
/// which its parser then refuses for what it is (`--threads -1`: "invalid value '-1' for
/// '--threads <THREADS>'"); clap otherwise read `-1` as an unknown flag and named no option.
fn negative_numbers(cmd: clap::Command) -> clap::Command {
    cmd.mut_args(|a| {
        if a.get_action().takes_values() {
            a.allow_negative_numbers(true)
        } else {
            a
        }
    })
    .mut_subcommands(negative_numbers)
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

/// Ctrl-C, SIGTERM (Slurm's `scancel`, a scheduler's time limit) and SIGHUP, for every command
/// and in every phase. Inside a render's loop of groups or frames the first stops the render at
/// the next group or frame, after a checkpoint; anywhere else (loading, merge, bench, reference,
/// compare), and for a second signal, the process stops at once, after removing the temporary
/// files it was writing (every file is written under a temporary name and renamed, so what is
/// in place is whole, and the last checkpoint stays valid).
fn install_signal_handler() -> Result<Arc<AtomicBool>> {
    let flag = Arc::new(AtomicBool::new(false));
    let f = flag.clone();
    ctrlc::set_handler(move || {
        let again = f.swap(true, Ordering::SeqCst);
        if !again && driver::run::stops_gracefully() {
            errln!(
                "\ninterrupt: finishing the current group of frames and writing a checkpoint \
                 (interrupt again to stop at once)"
            );
            return;
        }
        exit_removing_temporaries(130, || {
            let note = reframe::util::fs::stop_note().map_or(String::new(), |n| format!(" ({n})"));
            if again && reframe::util::fs::checkpoint_in_place() {
                errln!("\nstopping now; a checkpoint already written is kept{note}");
            } else if again {
                errln!(
                    "\nstopping now, before the first checkpoint (a --resume starts from the \
                     beginning){note}"
                );
            } else {
                errln!("\ninterrupted: stopped at once; nothing is left half-written{note}");
            }
        });
    })
    .context("installing the signal handler")?;
    Ok(flag)
}

fn run(cli: Cli) -> Result<()> {
    let interrupt = install_signal_handler()
        .map_err(|e| anyhow::anyhow!("{e:#}{}", reframe::util::mem::address_space_note()))?;
    // The image libraries' compression threads follow the workers (by default OpenEXR starts
    // one per core of the machine: 64 for `--threads 2` on a shared 64-core node), set before
    // any image is read or written, and after `--threads` is checked (OpenEXR starts them at
    // once).
    let threads = cli.command.threads();
    reframe::driver::options::check_threads(threads)?;
    reframe::image::set_threads(match threads {
        0 => reframe::driver::options::cores(),
        t => t,
    })
    .map_err(|e| anyhow::anyhow!("{e:#}{}", reframe::util::mem::address_space_note()))?;
    match cli.command {
        Command::Render(a) => {
            let scene_name = a.scene.unwrap_or_else(|| "vase".into());
            let device = Device::new()?;
            let scene = load(&scene_name, &device, a.strict)?;
            let out = a.out.unwrap_or_else(|| default_out(&scene.name));
            let opts = RenderOptions {
                method: a.method,
                spp: a.spp,
                window: a.window,
                packets: matches!(a.visibility, Visibility::Packet),
                primary: a.primary.rays(),
                paths: a.paths.rays(),
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
                interrupt: Some(interrupt),
                denoise: match (a.denoise, a.denoise_layers) {
                    (false, _) => None,
                    (true, false) => Some(driver::denoise::Layers::None),
                    (true, true) => Some(driver::denoise::Layers::RawAndGuides),
                },
                out,
            };
            let stats = driver::render(&scene, &opts)?;
            print_warnings(&scene);
            // The frames and the resolution the render took (checked as it started).
            let (frames, size) = opts.check(&scene)?;
            // Black frames that the camera's check explains are not said again.
            let unseen = scene.missed_frames(frames.clone(), size);
            if let Some(w) = scene.unseen_frames(&unseen, frames.count()) {
                errln!("warning: {}", message(&w));
            }
            if let Ok(out) = reframe::image::OutputPattern::parse(&opts.out) {
                for w in opts.flag_warnings(&out, size) {
                    errln!("warning: {}", message(&w));
                }
            }
            errln!("{}", cli::render_summary(&stats));
            // A reuse method that reused next to nothing cost its time for no gain: said, as
            // `--window 1` is before the render.
            if stats.method.reuses() && stats.window > 1 && stats.lost_reuse_fraction >= 0.9 {
                errln!(
                    "warning: {:.1}% of the reuses were lost (hidden from the other frames' eyes, \
                     or off their films): --method {} reused almost nothing; the frames of a \
                     group see little of each other (a film {}x{}, a camera that jumps), and \
                     --method independent renders them faster",
                    100.0 * stats.lost_reuse_fraction,
                    stats.method.name(),
                    stats.width,
                    stats.height
                );
            }
            say_half_clamped();
            if stats.nonfinite_pixels > 0 {
                errln!(
                    "warning: {} pixels are NaN or infinite",
                    stats.nonfinite_pixels
                );
            }
            let black: Vec<u32> = (stats.black_frames.iter())
                .filter(|f| scene.environment.is_some() || unseen.binary_search(f).is_err())
                .copied()
                .collect();
            say_black(&black, stats.frames);
            if stats.nonfinite_samples > 0 {
                errln!(
                    "warning: {} samples came out NaN or infinite and were left out",
                    stats.nonfinite_samples
                );
            }
            // The texture cache reads files while rendering: one changed or removed since the
            // scene loaded answers with nothing (black, and a mask cuts its surface out).
            let failed = scene.textures.as_ref().map_or(0, |t| t.failures());
            if failed > 0 {
                errln!(
                    "warning: {failed} texture lookups failed (a texture or mask file changed or \
                     was removed during the render): those points were shaded black or cut out"
                );
            }
            outln!("{}", printable(&cli::wrote(&stats.outputs)));
            if let Some(p) = &a.stats {
                outln!("stats in {}", printable(&p.display().to_string()));
            }
            Ok(())
        }
        Command::Merge(a) => {
            reframe::driver::options::check_threads(a.threads)?;
            let partials = match a.chunks {
                Some(0) => bail!("--chunks 0: at least one chunk is needed"),
                Some(n) => {
                    // Those that exist, found in the folder (merge names a missing chunk
                    // itself): asking for each of n names made n paths first, and --chunks
                    // 4294967295 asked for 100 GB.
                    let out = a.out.as_deref().unwrap();
                    let first = partial_path(out, Chunk { k: 1, n });
                    let there = chunk_partials(out, n);
                    if there.is_empty() {
                        bail!(
                            "--chunks {n}: none of the partial files is there (expected {} ..)",
                            first.display()
                        );
                    }
                    there
                }
                None => a.partials.clone(),
            };
            // A scene is loaded only to denoise (merge checks that the chunks asked for it).
            let device;
            let scene = match &a.scene {
                Some(s) => {
                    device = Device::new()?;
                    Some(load(s, &device, false)?)
                }
                None => None,
            };
            let denoising = scene.as_ref().map(|scene| driver::merge::Denoising {
                scene,
                threads: a.threads,
            });
            let r = driver::merge::merge(&partials, a.out.as_deref(), denoising.as_ref())?;
            errln!(
                "merged {} partial file(s) ({:.1} MB) into {} frame(s) ({:.1} MB) in {:.2} s",
                partials.len(),
                r.partial_bytes as f64 / 1e6,
                r.frames.len(),
                r.frame_bytes as f64 / 1e6,
                r.seconds
            );
            say_black(&r.black_frames, r.frames.len() as u32);
            if r.nonfinite_pixels > 0 {
                errln!("warning: {} pixels are NaN or infinite", r.nonfinite_pixels);
            }
            for w in &r.warnings {
                errln!("warning: {}", message(w));
            }
            say_half_clamped();
            let frames: Vec<String> = r.frames.iter().map(|p| p.display().to_string()).collect();
            outln!("{}", printable(&cli::wrote(&frames)));
            Ok(())
        }
        Command::Bench(a) => {
            let scene_name = a.scene.unwrap_or_else(|| "vase".into());
            let device = Device::new()?;
            let scene = load(&scene_name, &device, a.strict)?;
            if let Some(p) = &a.json {
                check_file_target("--json", p)?;
                reframe::driver::guard::check_outputs([("--json", p.clone())], &scene.inputs)?;
            }
            let opts = reframe::eval::bench::BenchOptions {
                spp: a.spp,
                res: a.res,
                frame: a.frame,
                threads: a.threads,
                speedup_spp: a.speedup_spp,
                speedup_method: a.method,
                windows: a.windows,
                max_depth: a.max_depth,
                repeats: a.repeats,
                ..Default::default()
            };
            let report = reframe::eval::bench::run(&scene, &opts)?;
            print_warnings(&scene);
            outln!("{}", report.table());
            if let Some(p) = &a.json {
                write_json(p, &report)?;
                outln!("figures in {}", printable(&p.display().to_string()));
            }
            Ok(())
        }
        Command::Reference(a) => {
            let device = Device::new()?;
            let scene = load(a.scene.as_deref().unwrap_or("vase-long"), &device, a.strict)?;
            let range = match a.frames {
                Some((x, y)) => x..=y,
                None => compare::default_frames(&scene),
            };
            driver::check_frames(&scene, &range)?;
            let res = a.res.unwrap_or((scene.width, scene.height));
            let pool = driver::thread_pool(a.threads)?;
            reframe::embree::set_flush_denormals();
            let r = reference::reference(
                &scene,
                range,
                res,
                a.reference_spp,
                a.max_depth,
                &a.cache,
                &pool,
                true,
            )?;
            print_warnings(&scene);
            let how = if r.cached {
                "cached".to_string()
            } else {
                format!("rendered in {:.1} s", r.seconds)
            };
            outln!(
                "reference of '{}' ({}x{}, {} spp) in {} ({how})",
                printable(&scene.name),
                res.0,
                res.1,
                r.spp,
                printable(&r.dir.display().to_string())
            );
            Ok(())
        }
        Command::Compare(a) => {
            let device = Device::new()?;
            let r = a.reference;
            let scene = load(r.scene.as_deref().unwrap_or("vase-long"), &device, r.strict)?;
            let opts = compare::CompareOptions {
                regime: a.regime,
                frames: r.frames.map(|(x, y)| x..=y),
                res: r.res,
                methods: a.methods,
                budgets: a.budgets,
                reuse_budgets: a.reuse_budgets,
                windows: a.windows,
                reference_spp: r.reference_spp,
                max_depth: r.max_depth,
                cache: r.cache,
                out: a.out,
                threads: r.threads,
                seed: a.seed,
                crop: a.crop,
                bias_seeds: a.bias_seeds,
                progress: true,
            };
            let report = compare::compare(&scene, &opts)?;
            print_warnings(&scene);
            if let Some(c) = opts.methods.iter().find(|c| c.denoise) {
                let size = opts.res.unwrap_or((scene.width, scene.height));
                let what = format!("--methods {}", c.name());
                if let Some(w) = driver::options::small_denoise_warning(&what, size) {
                    errln!("warning: {}", message(&w));
                }
            }
            outln!("{}", compare::summary(&report));
            outln!("results in {}", printable(&opts.out.display().to_string()));
            Ok(())
        }
    }
}

/// Warn of frames written black in every pixel (`frames` of `total`): no light reached the
/// camera anywhere in them, which no scene one means to render looks like (a camera so far
/// from the scene that its pixels pass beside it, a field of view so wide that none looks
/// into it, lights that face away), and the camera's own check, which tests the scene's box
/// against the view, does not find.
fn say_black(frames: &[u32], total: u32) {
    if frames.is_empty() {
        return;
    }
    let which = if frames.len() as u32 == total {
        format!("every frame ({})", reframe::util::text::ranges(frames, 4))
    } else {
        format!(
            "{} of the {total} frames ({})",
            frames.len(),
            reframe::util::text::ranges(frames, 4)
        )
    };
    errln!(
        "warning: {which} came out black in every pixel: no light reached the camera there (its \
         pixels may all pass beside the scene, as from far away or with a field of view near \
         180 degrees, or see only unlit surfaces)"
    );
}

/// Where more than one frame was clamped to half float's largest, how many: the warning when the
/// first was written named that one only.
fn say_half_clamped() {
    let n = reframe::image::half_clamped();
    if n > 1 {
        errln!(
            "warning: {n} frames had values beyond ±65504 clamped to it (the first named above; \
             --exr-float keeps them)"
        );
    }
}

/// `--out`'s default for scene `name`: `out/<name>_####.exr`, with each `#` of the name made
/// `_` (a `#` is the frame number's field: `shot#2.toml` was refused for two runs of `#` in an
/// output path the user never gave).
fn default_out(name: &str) -> String {
    format!("out/{}_####.exr", name.replace('#', "_"))
}
