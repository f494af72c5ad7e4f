//! The driver: owns the frame loops, the worker pool, the progress bar, the statistics and every
//! file a render writes. The estimators only estimate (Mitsuba's `SamplingIntegrator::render`
//! against the CLI's `film->write`); arrows point down only: the driver calls `reuse`, `film`,
//! `state` and the integrator, none of which calls back.
//!
//! The rooms: `options` (what a render is asked to do, and its one validation), `run` (a
//! resumable run and its interruption), `independent` and `groups` (the two frame loops),
//! `sink` (frame files), `stats` (what `--stats` writes) and `merge` (`reframe merge`).
//!
//! ```no_run
//! use reframe::driver::{render, RenderOptions};
//! use reframe::{embree::Device, scene::Scene};
//! let device = Device::new()?;
//! let scene = Scene::load("furnace", &device)?;
//! let opts = RenderOptions { out: "out/furnace_####.exr".into(), ..RenderOptions::default() };
//! let stats = render(&scene, &opts)?;
//! println!("{} rays", stats.rays_total());
//! # anyhow::Ok(())
//! ```
pub mod denoise;
pub mod groups;
pub mod guard;
pub mod independent;
pub mod merge;
pub mod options;
pub mod run;
pub mod sink;
pub mod stats;

pub use independent::{render_frame_independent, FrameResult};
pub use options::{check_frames, Plan, RenderOptions};
pub use run::Interrupted;
pub use stats::RenderStats;

use crate::film::{FrameAccum, Sink};
use crate::image::OutputPattern;
use crate::integrator::Integrator;
use crate::reuse::Params;
use crate::scene::Scene;
use crate::state::checkpoint::{Checkpointer, Counters};
use crate::state::key::{
    checkpoint_named, default_checkpoint_dir, output_stem, partial_path, scene_and_build_hashes,
    Chunk, RunKey,
};
use crate::state::Trailer;
use crate::util::fs::{parent_dir, remove_stale_tmp, write_json, CreatedDirs};
use anyhow::{bail, Context, Result};
use groups::{run_groups, GroupSettings};
use indicatif::{ProgressBar, ProgressStyle};
use run::Run;
use sink::{FileSink, FrameMeta};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// The lock file of a render writing `pattern` (or of its chunk), beside its frames.
pub fn lock_path(pattern: &str, chunk: Option<Chunk>) -> PathBuf {
    let (dir, stem) = output_stem(pattern);
    match chunk {
        Some(c) => dir.join(format!(".{stem}.chunk-{}-of-{}.lock", c.k, c.n)),
        None => dir.join(format!(".{stem}.lock")),
    }
}

/// Remove the temporary frame files (`.NAME.tmp-PID-N.ext`) that a process killed while
/// writing frames `frames` of `out` left: called with the pattern's lock held, so no other
/// process is writing them.
pub(crate) fn remove_stale_frames(out: &OutputPattern, frames: std::ops::RangeInclusive<u32>) {
    // The frames' names, made only if the folder holds a temporary file at all.
    let names = std::cell::OnceCell::<std::collections::HashSet<String>>::new();
    let dir = parent_dir(&out.path(*frames.start()));
    remove_stale_tmp(&dir, |n| {
        names
            .get_or_init(|| {
                frames
                    .clone()
                    .filter_map(|f| Some(out.path(f).file_name()?.to_string_lossy().into_owned()))
                    .collect()
            })
            .contains(n)
    });
}

/// A resumed render's outputs must be where its checkpoint left them: the same `--out`, and
/// every frame it finished (the first `next_unit - first unit` frames of the plan; a chunk's are
/// in its log) still there and readable. A frame deleted or damaged since would otherwise be
/// reported as written.
fn check_resumed_outputs(
    t: &Trailer,
    opts: &RenderOptions,
    plan: &Plan,
    (out, meta): (&OutputPattern, &FrameMeta),
    scene: &crate::scene::Scene,
) -> Result<()> {
    // The same pattern, written alike or not (`o/f_####.exr`, `./o/f_####.exr`, absolute).
    let same = |a: &str, b: &str| {
        a == b
            || guard::resolved(Path::new(a))
                .is_some_and(|r| guard::resolved(Path::new(b)) == Some(r))
    };
    if !same(&t.out, &opts.out) {
        bail!(
            "--resume: the checkpoint is of --out {}, not {}; resume with the same --out",
            t.out,
            opts.out
        );
    }
    if opts.chunk.is_some() {
        return Ok(());
    }
    let done = t.next_unit.saturating_sub(*plan.units.start()) as usize;
    for f in plan.frames.clone().take(done) {
        let p = out.path(f);
        // Every pixel read (a file cut short or damaged in its compressed data fails here,
        // where reading its header alone passed), its size this render's, and what its
        // metadata names (frame, seed, scene, method, samples, window) this render's where the
        // format keeps them: another file in its place, or another run's frame, is refused.
        // A file that cannot be opened (another user's, a directory or a link to nothing in
        // its place) is said to be so, and how to mend it: OpenImageIO's words for it ("not
        // an OpenEXR file") hid the reason, and a chmod mends what a new render would redo.
        use crate::util::input::{open_input_or_missing, InputError};
        match open_input_or_missing(&p, "frame", u64::MAX) {
            Ok(_) => {}
            Err(InputError::NotFound(_)) => bail!(
                "--resume: frame {f} was finished before the stop, but {} is gone; delete \
                 the checkpoint folder to render every frame again",
                p.display()
            ),
            Err(InputError::Refused(why)) => bail!(
                "--resume: frame {f} was finished before the stop, but {why}; make it a \
                 readable file again, or delete the checkpoint folder to render every frame \
                 again"
            ),
        }
        let why = match crate::image::read_image(&p) {
            Err(e) => Some(format!("it cannot be read ({e:#})")),
            Ok(img) if (img.width, img.height) != (plan.width, plan.height) => Some(format!(
                "it is {}x{} pixels, not this render's {}x{}",
                img.width, img.height, plan.width, plan.height
            )),
            Ok(_) => {
                let md = crate::image::read_metadata(&p).unwrap_or_default();
                let get = |k: &str| md.iter().find(|(n, _)| n == k).map(|(_, v)| v.clone());
                let want = [
                    ("frame", f.to_string()),
                    ("seed", meta.seed.to_string()),
                    ("scene", meta.scene.clone()),
                    ("method", meta.method.clone()),
                    ("spp", meta.spp.to_string()),
                    ("window", meta.window.to_string()),
                ];
                let named = want
                    .iter()
                    .find_map(|(k, v)| match get(&format!("reframe:{k}")) {
                        Some(got) if got != *v => Some(format!(
                            "it is not this render's (its {k} is {got}, not {v})"
                        )),
                        None if out.is_exr() => Some(format!(
                            "it is not a frame of this render (it has no reframe:{k})"
                        )),
                        _ => None,
                    });
                // The camera, where the format keeps it and not the rest (TIFF): two frames
                // swapped there were taken as finished.
                let camera = || {
                    let theirs: Vec<f32> = get(crate::image::EXR_WORLD_TO_CAMERA)?
                        .split_whitespace()
                        .map(|v| v.parse().unwrap_or(f32::NAN))
                        .collect();
                    let cam = scene.camera(f, plan.width, plan.height);
                    let ours = crate::film::View::of(f, &cam).world_to_camera;
                    let same = theirs.len() == 16
                        && theirs
                            .iter()
                            .zip(ours)
                            .all(|(a, b)| (a - b).abs() <= 1e-6 * b.abs().max(1.0));
                    (!same).then(|| {
                        format!(
                            "it is not this render's (its camera, worldToCamera, is not frame \
                             {f}'s)"
                        )
                    })
                };
                // Last, the file's bytes against what this render wrote: another file in its
                // place in a format that keeps none of the above (JPEG, HDR, TGA: two frames
                // swapped were taken as finished), or an edit.
                let bytes = || {
                    let (_, wrote) = t.frame_digests.iter().find(|(g, _)| *g == f)?;
                    match sink::file_digest(&p) {
                        Ok(d) if d == *wrote => None,
                        Ok(_) => Some(
                            "it is not the file this render wrote there (its bytes have changed \
                             since: another file in its place, or an edit)"
                                .to_string(),
                        ),
                        Err(e) => Some(format!("{e:#}")),
                    }
                };
                named.or_else(camera).or_else(bytes)
            }
        };
        if let Some(why) = why {
            bail!(
                "--resume: frame {f} was finished before the stop, but {}: {why}; delete the \
                 checkpoint folder to render every frame again",
                p.display()
            );
        }
    }
    Ok(())
}

/// A rayon pool whose workers set FTZ/DAZ, as Embree asks of every tracing thread.
pub fn thread_pool(threads: usize) -> Result<rayon::ThreadPool> {
    options::check_threads(threads)?;
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .start_handler(|_| crate::embree::set_flush_denormals())
        .build()
        .map_err(|e| {
            anyhow::anyhow!(
                "creating the worker threads: {e}{}",
                crate::util::mem::address_space_note()
            )
        })
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

/// Refuse a render whose `--checkpoint` is the folder `d`, which holds no checkpoint, where the
/// default folder of this `--out` holds the checkpoint of an interrupted render to this very
/// `--out` (the state names it: outputs of one stem, `f_####.png` and `f_####.exr`, share the
/// default folder): the render would overwrite its frames, counted finished, so that it could
/// no longer be resumed, or (with `--resume`) start again from the beginning without a word.
/// `--resume` with that folder continues it; deleting it starts over.
fn check_no_checkpoint_elsewhere(d: &Path, opts: &RenderOptions) -> Result<()> {
    let default = default_checkpoint_dir(&opts.out, opts.chunk);
    let same = d == default
        || matches!((d.canonicalize(), default.canonicalize()), (Ok(a), Ok(b)) if a == b);
    let state = default.join("state");
    if same || d.join("state").exists() || !crate::state::is_state_file(&state) {
        return Ok(());
    }
    // A state that cannot be read is no render's to protect here (the resume that names it
    // says what is wrong with it).
    let ours = crate::state::StateFile::open(&state).is_ok_and(|sf| sf.trailer.out == opts.out);
    if !ours {
        return Ok(());
    }
    bail!(
        "{} holds the checkpoint of an interrupted render to --out {}, and --checkpoint {} holds \
         none: continue that render with --resume and --checkpoint {} (or no --checkpoint), or \
         delete {} to start over",
        default.display(),
        opts.out,
        d.display(),
        default.display(),
        default.display()
    )
}

/// Refuse a merge or render into `frames` of `pattern` where a checkpoint folder in the
/// output's folder (a render's default checkpoint, `<name>.checkpoint`; `own`, the render's own
/// checkpoint, is left to its resume) holds the checkpoint of an interrupted render to frames
/// of the same file names: the merge or render would write over frames that checkpoint counts
/// finished, and its resume was then refused. Frames are compared by file name, whatever
/// pattern names them (`v_####.exr` and `v_0###.exr` name the same files; only the same
/// pattern was caught). `render` refuses its own checkpoint the same way (`Checkpointer::open`:
/// a checkpoint needs `--resume`).
pub(super) fn check_no_interrupted_render(
    pattern: &str,
    frames: &std::ops::RangeInclusive<u32>,
    own: Option<&Path>,
) -> Result<()> {
    let Ok(ours) = crate::image::OutputPattern::parse(pattern) else {
        return Ok(());
    };
    let name = |p: PathBuf| p.file_name().map(|n| n.to_owned());
    let (dir, _) = crate::state::key::output_stem(pattern);
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return Ok(());
    };
    let own = own.and_then(|d| d.canonicalize().ok());
    let mut names: Option<std::collections::HashSet<_>> = None;
    for e in entries.flatten() {
        let folder = e.path();
        let is_checkpoint = folder.extension().is_some_and(|x| x == "checkpoint");
        if !is_checkpoint || folder.canonicalize().ok().is_some_and(|f| Some(f) == own) {
            continue;
        }
        let state = folder.join("state");
        if !crate::state::is_state_file(&state) {
            continue;
        }
        // A state that cannot be read is no render's to protect here (its resume says what is
        // wrong); a chunk's checkpoint counts frames of its partial file, not of the output.
        let Ok(t) = crate::state::StateFile::open(&state).map(|sf| sf.trailer) else {
            continue;
        };
        if t.kind != crate::state::Kind::Checkpoint || t.chunk.is_some() {
            continue;
        }
        let Ok(theirs) = crate::image::OutputPattern::parse(&t.out) else {
            continue;
        };
        let ours = names
            .get_or_insert_with(|| frames.clone().filter_map(|f| name(ours.path(f))).collect());
        let (first, last) = (t.key.first_frame, t.key.last_frame);
        if (first..=last).any(|f| name(theirs.path(f)).is_some_and(|n| ours.contains(&n))) {
            bail!(
                "{} holds the checkpoint of an interrupted render to --out {} (frames \
                 {first}-{last}), which writes frames of the same names: this would write over \
                 frames it counts finished or is still to write, and it could no longer be \
                 resumed; finish it with --resume, or delete {} first",
                folder.display(),
                t.out,
                folder.display()
            );
        }
    }
    Ok(())
}

/// The settings that make a render's pixels what they are (a resume or merge needs them equal).
fn run_key(scene: &Scene, opts: &RenderOptions, plan: &Plan) -> Result<RunKey> {
    let (scene_hash, build_hash) = scene_and_build_hashes(scene)?;
    Ok(RunKey {
        scene: scene.name.clone(),
        scene_hash,
        build_hash,
        method: opts.method.name().into(),
        spp: opts.spp,
        window: opts.window,
        first_frame: *plan.frames.start(),
        last_frame: *plan.frames.end(),
        width: plan.width,
        height: plan.height,
        seed: opts.seed,
        max_depth: opts.max_depth,
        visibility: if opts.packets { "packet" } else { "single" }.into(),
        primary: opts.primary.name().into(),
        paths: opts.paths.name().into(),
        // `--aov` changes nothing the independent tracer writes (it is ignored, with a
        // warning): it does not keep such a run from resuming.
        aov: opts.aov && opts.method.reuses(),
        adaptive: opts.effective_adaptive().unwrap_or(0.0),
        exr_float: opts.exr_float,
        radiance_unit: plan.radiance_unit,
        denoise: match opts.denoise {
            None => "off",
            Some(denoise::Layers::None) => "rgb",
            Some(denoise::Layers::RawAndGuides) => "rgb+layers",
        }
        .into(),
    })
}

/// Run `run` with the frame loop of `opts.method`, from the frames in flight `active`, handing
/// finished frames to `sink`. False if interrupted.
fn frame_loop(
    integrator: &Integrator,
    opts: &RenderOptions,
    plan: &Plan,
    run: &mut Run,
    active: Vec<FrameAccum>,
    sink: &mut dyn Sink,
) -> Result<bool> {
    let (w, h) = (plan.width, plan.height);
    if !opts.method.reuses() {
        return independent::run_independent(
            integrator,
            (opts.spp, opts.seed),
            (w, h),
            opts.progress,
            run,
            active,
            sink,
        );
    }
    let settings = GroupSettings {
        params: Params {
            method: opts.method,
            spp: opts.spp,
            seed: opts.seed,
            packets: opts.packets,
        },
        window: opts.window,
        aov: opts.aov,
        adaptive: opts.effective_adaptive(),
        width: w,
        height: h,
        progress: opts.progress,
        all_groups: plan.all_units.clone(),
        radiance_unit: plan.radiance_unit,
    };
    run_groups(integrator, &settings, run, active, sink)
}

/// Render the frames of `opts` in memory with `integrator`, handing each finished frame to
/// `sink` (no checkpoint, no chunk, no file): the comparisons', the benchmark's and the tests'
/// way in. Returns the run's counters.
pub fn render_frames(
    integrator: &Integrator,
    opts: &RenderOptions,
    sink: &mut dyn Sink,
) -> Result<Counters> {
    let plan = opts.validate(integrator.scene)?;
    let mut run = Run::in_memory(plan.units.clone());
    frame_loop(integrator, opts, &plan, &mut run, vec![], sink)?;
    run.counters.seconds = run.seconds();
    Ok(run.counters)
}

/// Render the frames of `opts` and write them (or, for a chunk, its partial file); returns the
/// statistics (also written to `opts.stats` if set). A render stopped by `opts.interrupt` ends
/// in an `Interrupted` error after its checkpoint.
pub fn render(scene: &Scene, opts: &RenderOptions) -> Result<RenderStats> {
    let startup_rss_bytes = crate::util::mem::rss_bytes();
    let plan = opts.validate(scene)?;
    // The denoiser is loaded before anything is written or traced: a missing library is one
    // line at start, not an error after the first frame. A chunk writes no frames: `merge`
    // denoises them (the key records `--denoise`).
    let denoiser = opts
        .denoise
        .filter(|_| opts.chunk.is_none())
        .map(|layers| {
            crate::image::oidn::Denoiser::load(opts.threads, "--denoise").map(|d| (d, layers))
        })
        .transpose()?;
    let (out, created) = opts.check_files(&plan)?;
    // One render per output, and never over its own inputs.
    let lock = lock_path(&opts.out, opts.chunk);
    // A chunk writes its partial file, and its merge the frames: those are checked now too, as
    // the same render without `--chunk` checks them (a frame that is one of the scene's files,
    // a link or a FIFO at a frame's path), not after every chunk has rendered.
    let mut outputs: Vec<(&str, PathBuf)> = opts
        .chunk
        .map(|c| ("the chunk's partial file", partial_path(&opts.out, c)))
        .into_iter()
        .chain(plan.frames.clone().map(|f| ("--out", out.path(f))))
        .collect();
    outputs.extend(opts.stats.iter().map(|p| ("--stats", p.clone())));
    // Named as the flag where it was given, else as what it is (a render without
    // `--checkpoint` was told "--checkpoint o/f.checkpoint/state is a symbolic link").
    let given = opts.checkpoint.as_ref() != Some(&default_checkpoint_dir(&opts.out, opts.chunk));
    let (ck, ck_lock, ck_folder) = if given {
        ("--checkpoint", "the lock of --checkpoint", "--checkpoint")
    } else {
        (
            "the checkpoint",
            "the lock of the checkpoint folder",
            "the checkpoint folder",
        )
    };
    outputs.extend(opts.checkpoint.iter().map(|d| (ck, d.join("state"))));
    outputs.push(("the lock of --out", lock.clone()));
    outputs.extend(
        opts.checkpoint
            .iter()
            .map(|d| (ck_lock, guard::folder_lock_path(d))),
    );
    if let Some(d) = &opts.checkpoint {
        guard::check_folder_apart(ck_folder, d, &outputs)?;
    }
    guard::check_outputs(outputs, &scene.inputs)?;
    let frames = opts.chunk.is_none().then(|| guard::Frames {
        pattern: &out,
        frames: plan.frames.clone(),
    });
    let _lock = guard::OutputLock::acquire(&lock, &opts.out, frames)?;
    // One render per checkpoint folder too: two renders of other outputs given one
    // `--checkpoint` wrote over each other's state.
    // The folders above the checkpoint folder are made as an output's are (its lock lies
    // beside it: `--checkpoint a/b/c` under no `a` failed on opening `a/b/.c.lock`); those
    // made go again when the render ends and they are empty, the checkpoint folder gone.
    let _checkpoint_parents = match &opts.checkpoint {
        Some(d) => Some(CreatedDirs::create(&parent_dir(d)).with_context(|| {
            format!(
                "{}: cannot create its folder",
                checkpoint_named(d, &opts.out, opts.chunk)
            )
        })?),
        None => None,
    };
    let _checkpoint_lock = match &opts.checkpoint {
        Some(d) => Some(
            guard::OutputLock::acquire(
                &guard::folder_lock_path(d),
                &format!("the checkpoint folder {}", d.display()),
                None,
            )
            .with_context(|| checkpoint_named(d, &opts.out, opts.chunk))?,
        ),
        None => None,
    };
    // After the output's lock: a render of this `--out` that is running holds it (and is said
    // as such), so a checkpoint found now is one an interrupted render left.
    if let Some(d) = &opts.checkpoint {
        check_no_checkpoint_elsewhere(d, opts)?;
    }
    // Another interrupted render's frames of the same names (under another pattern); a chunk
    // writes a partial file, no frames.
    if opts.chunk.is_none() {
        check_no_interrupted_render(&opts.out, &plan.frames, opts.checkpoint.as_deref())?;
    }
    let (ckpt, resumed) = if opts.checkpoint.is_some() || opts.chunk.is_some() {
        let key = run_key(scene, opts, &plan)?;
        let mut template = Trailer::new(
            key,
            opts.chunk,
            &plan.units,
            opts.out.clone(),
            opts.exr_float,
        );
        template.inputs = scene
            .inputs
            .iter()
            .filter_map(|p| p.canonicalize().ok()?.to_str().map(String::from))
            .collect();
        let every = Duration::from_secs_f64(opts.checkpoint_every);
        Checkpointer::open(
            opts.checkpoint.clone(),
            every,
            opts.resume,
            template,
            opts.method.norm(),
        )?
    } else {
        (Checkpointer::none(), None)
    };
    // Every check has passed: the output folder stays.
    created.keep();
    if opts.chunk.is_none() {
        remove_stale_frames(&out, plan.frames.clone());
    }
    let meta = FrameMeta {
        scene: scene.name.clone(),
        method: opts.method.name().into(),
        spp: opts.spp,
        window: opts.window,
        seed: opts.seed,
        exr_float: opts.exr_float,
    };
    let (counters, next, active, digests) = match resumed {
        Some(r) => {
            check_resumed_outputs(&r.trailer, opts, &plan, (&out, &meta), scene)?;
            // A frame in flight carries its camera into its file's metadata as the checkpoint
            // has it: it must be the scene's, to the bit (the same scene and build, which the
            // key checks), where a matrix forged with the record's checksum was written out.
            for a in &r.active {
                let (w, h) = (a.view.width, a.view.height);
                if a.view != crate::film::View::of(a.frame(), &scene.camera(a.frame(), w, h)) {
                    bail!(
                        "--resume: the checkpoint in {} is damaged (frame {}'s camera is not the \
                         scene's); delete the folder to start over",
                        ckpt.dir().map_or("?".into(), |d| d.display().to_string()),
                        a.frame()
                    );
                }
            }
            let t = r.trailer;
            (t.progress, t.next_unit, r.active, t.frame_digests)
        }
        None => (Counters::default(), *plan.units.start(), vec![], vec![]),
    };
    let mut run = Run::new(ckpt, plan.units.clone(), next, counters);
    run.frame_digests = digests;
    run.interrupt = opts.interrupt.clone();
    let pool = thread_pool(opts.threads)?;
    crate::embree::set_flush_denormals();
    let mut integrator = Integrator::new(scene, opts.max_depth);
    integrator.primary = opts.primary;
    integrator.paths = opts.paths;
    let mut sink = FileSink::new(meta, out);
    let mut denoise_seconds = 0.0;
    let completed = std::thread::scope(|scope| -> Result<bool> {
        let mut writer = sink::Writer::spawn(scope, &mut sink)?;
        let done = match denoiser {
            Some((denoiser, layers)) => {
                let mut dsink = denoise::DenoiseSink {
                    inner: &mut writer,
                    denoiser,
                    integrator: &integrator,
                    seed: opts.seed,
                    layers,
                    seconds: 0.0,
                    warned: false,
                };
                let done = pool
                    .install(|| frame_loop(&integrator, opts, &plan, &mut run, active, &mut dsink));
                denoise_seconds = dsink.seconds;
                done
            }
            None => {
                pool.install(|| frame_loop(&integrator, opts, &plan, &mut run, active, &mut writer))
            }
        };
        // Every frame handed over is written (or its failure said) before the render ends; the
        // loops sync before they return, so this waits only where one stopped on an error.
        let told = writer.told();
        match (done, writer.sync()) {
            (Ok(done), Ok(digests)) => {
                run.frame_digests.extend(digests);
                Ok(done)
            }
            // A frame's write failed, unsaid, before the loop failed on a later one.
            (Err(e), Err(w)) if !told => Err(anyhow::anyhow!("{w:#}; then {e:#}")),
            (Err(e), _) | (Ok(_), Err(e)) => Err(e),
        }
    })?;
    if !completed {
        return Err(Interrupted {
            checkpoint: run.ckpt.dir().map(Path::to_path_buf),
            frames_done: run.frames_retired(),
        }
        .into());
    }
    if run.interrupted() {
        // The signal's line promised a checkpoint and a stop; the group in progress was the
        // last, so the render is whole and ends as one that was not stopped (status 0).
        errln!("note: the interrupt came during the last frames: the render is complete");
    }
    let partial = run.finish()?;
    let outputs = match &partial {
        Some(p) => vec![p.display().to_string()],
        None => plan
            .frames
            .clone()
            .map(|f| sink.out.path(f).display().to_string())
            .collect(),
    };
    let mut stats = RenderStats::new(
        &scene.name,
        opts,
        &plan,
        &run.counters,
        run.counters.seconds,
        pool.current_num_threads(),
        startup_rss_bytes,
        outputs,
        (run.ckpt.written, run.ckpt.spent.as_secs_f64()),
    );
    stats.denoise_seconds = denoise_seconds;
    if let Some(p) = &opts.stats {
        write_json(p, &stats)?;
    }
    Ok(stats)
}
