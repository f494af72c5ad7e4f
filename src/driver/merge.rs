//! `reframe merge`: the frames of a render split into chunks (`render --chunk K/N`), from the
//! chunks' partial files.
//!
//! Chunks split the render by group, not by frame: a frame near a chunk's edge belongs to groups
//! of two chunks, and each chunk leaves its share of that frame's accumulator in its partial file.
//! Merging adds the shares' integer fixed-point sums and counts (exact and order-free) and
//! develops the frame with the same function a single process uses (`film::develop`),
//! so the merged frames are bitwise identical to a one-process render with the same seed, for
//! any N. Nothing is written unless every chunk 1..N is there, made with the same settings and
//! build.
//!
//! ```text
//! reframe render vase --method mis-exact --window 7 --chunk 2/3 --out out/vase_####.exr
//! reframe merge out/vase.chunk-*-of-3.partial --out out/vase_####.exr
//! ```
//!
//! Chunks rendered with `--denoise` leave raw shares; the merge denoises each merged frame as a
//! one-process render does (same guides, same filter), given the scene to trace the guides in
//! (`Denoising`), which must hash as the chunks' scene did.
use super::denoise::{DenoiseSink, Layers};
use super::groups::groups_holding;
use super::options::check_output;
use super::sink::{FileSink, FrameMeta};
use crate::film::{develop, Developed, FrameAccum, Sink};
use crate::image::oidn::Denoiser;
use crate::integrator::Integrator;
use crate::reuse::Method;
use crate::scene::Scene;
use crate::state::key::{partial_path, run_units, Chunk, RunKey};
use crate::state::{Kind, Record, StateFile};
use anyhow::{anyhow, bail, Context, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

pub struct MergeReport {
    pub frames: Vec<PathBuf>,
    pub seconds: f64,
    /// Bytes of the partial files, and of the frames written.
    pub partial_bytes: u64,
    pub frame_bytes: u64,
    /// Pixels written with a NaN or infinite channel.
    pub nonfinite_pixels: u64,
    /// Frames written black in every pixel, in order.
    pub black_frames: Vec<u32>,
    /// What the chunks' settings asked for that these frames do not hold, in words (as
    /// `RenderOptions::flag_warnings` says it for a render).
    pub warnings: Vec<String>,
}

/// What a merge of chunks rendered with `--denoise` needs: the scene, for the guides.
pub struct Denoising<'a> {
    pub scene: &'a Scene,
    /// Threads of the guide pass and of the denoiser (0: one per core).
    pub threads: usize,
}

/// Merge `partials` into frames written with `out` (default: the pattern the chunks were given),
/// denoised when the chunks were rendered with `--denoise` (which needs `denoising`).
pub fn merge(
    partials: &[PathBuf],
    out: Option<&str>,
    denoising: Option<&Denoising>,
) -> Result<MergeReport> {
    let start = Instant::now();
    if partials.is_empty() {
        bail!("no partial files given");
    }
    let mut files = partials
        .iter()
        .map(|p| {
            // Not there at all: a link to nothing (or a loop of links) is left to `open`,
            // which says what it is.
            if p.symlink_metadata().is_err() {
                bail!(
                    "{}: no such partial file; render its chunk (--chunk K/N) and merge again; \
                     no frame was written",
                    p.display()
                );
            }
            StateFile::open(p)
        })
        .collect::<Result<Vec<_>>>()?;
    // One set: the same settings and build, chunks 1..N each once.
    let t0 = files[0].trailer.clone();
    let label = |f: &StateFile| f.path.display().to_string();
    let mut by_k: BTreeMap<u32, usize> = BTreeMap::new();
    let mut n = None;
    for (i, f) in files.iter().enumerate() {
        let t = &f.trailer;
        if t.kind != Kind::Partial {
            bail!("{}: a checkpoint, not a chunk's partial file", label(f));
        }
        let Some(c) = t.chunk else {
            bail!("{}: not a chunk's partial file", label(f));
        };
        if let Some(d) = t0.key.difference(&t.key) {
            bail!(
                "{} and {} are not chunks of the same render ({d})",
                label(&files[0]),
                label(f)
            );
        }
        // Chunks told to write other frames (another name or format) are of another render,
        // as a chunk's own partial file says (a merge took the first one's --out, unsaid; the
        // folder may differ, as where chunks ran on other machines).
        let name = |out: &str| Path::new(out).file_name().map(|n| n.to_owned());
        if name(&t.out) != name(&t0.out) {
            bail!(
                "{} and {} are not chunks of the same render (--out {} vs {})",
                label(&files[0]),
                label(f),
                t0.out,
                t.out
            );
        }
        if *n.get_or_insert(c.n) != c.n {
            bail!(
                "{} is chunk {c} but {} is of {} chunks",
                label(f),
                label(&files[0]),
                n.unwrap()
            );
        }
        if let Some(&j) = by_k.get(&c.k) {
            bail!(
                "chunk {c} given twice: {} and {}",
                label(&files[j]),
                label(f)
            );
        }
        let all = run_units(t.key.first_frame, t.key.last_frame, t.key.window);
        let share = c.share(all).map_err(|e| anyhow!("{}: {e}", label(f)))?;
        if t.units != [*share.start(), *share.end()] || t.next_unit != share.end() + 1 {
            bail!(
                "{}: damaged partial file (chunk {c} should cover units {}-{} and be complete)",
                label(f),
                share.start(),
                share.end()
            );
        }
        by_k.insert(c.k, i);
    }
    let n = n.unwrap();
    // The chunks' build, which a merge needs as a resume does (README, "The tracer",
    // "Building for the host CPU"): partials of another build merged without a word, and with
    // `--denoise` this build traced the guides of frames another one rendered.
    let own = crate::state::key::build_hash()?;
    if own != t0.key.build_hash {
        bail!(
            "{}: the chunks were rendered by another build of reframe (build {}, this one \
             {own}); merge them with the reframe that rendered them",
            label(&files[0]),
            t0.key.build_hash
        );
    }
    // The pattern the chunks were given. A relative one was relative to the folder the chunks
    // ran in, which holds their partial files (written beside the frames): it is resolved
    // against the partials' folder, not the merge's own, so that a merge run from elsewhere
    // writes (by default) and names missing chunks beside the partials.
    let chunks_out = match Path::new(&t0.out) {
        p if p.is_relative() => {
            let name = p.file_name().unwrap_or_default();
            let beside = match files[0].path.parent() {
                Some(dir) => dir.join(name),
                None => PathBuf::from(name),
            };
            beside
                .to_str()
                .ok_or_else(|| anyhow!("{}: the folder's name is not UTF-8", label(&files[0])))?
                .to_string()
        }
        _ => t0.out.clone(),
    };
    if let Some(k) = (1..=n).find(|k| !by_k.contains_key(k)) {
        let c = Chunk { k, n };
        bail!(
            "chunk {c} is missing (expected {}): render it with --chunk {c} and merge again; \
             no frame was written",
            partial_path(&chunks_out, c).display()
        );
    }
    let key = &t0.key;
    let method = Method::from_name(&key.method)
        .ok_or_else(|| anyhow!("{}: unknown method '{}'", label(&files[0]), key.method))?;
    let layers = match key.denoise.as_str() {
        "" | "off" => None,
        "rgb" => Some(Layers::None),
        "rgb+layers" => Some(Layers::RawAndGuides),
        d => bail!("{}: unknown denoise setting '{d}'", label(&files[0])),
    };
    // Denoised chunks: the scene is checked and the denoiser loaded before anything is written.
    // (A scene given for chunks rendered without --denoise is not needed, and not used: said.)
    let denoise = match (layers, denoising) {
        (None, Some(d)) => {
            errln!(
                "warning: --scene {}: the chunks were rendered without --denoise, so the merge \
                 does not use the scene",
                crate::util::text::message(&d.scene.name)
            );
            None
        }
        (None, None) => None,
        (Some(_), None) => bail!(
            "the chunks were rendered with --denoise: the merge traces the denoiser's guides in \
             the scene, so name it with --scene (the scene the chunks rendered, '{}')",
            key.scene
        ),
        (Some(layers), Some(d)) => {
            let (hash, _) = crate::state::key::scene_and_build_hashes(d.scene)?;
            if hash != key.scene_hash {
                bail!(
                    "--scene {}: not the scene the chunks rendered (its content hashes to {hash}, \
                     theirs to {}); no frame was written",
                    d.scene.name,
                    key.scene_hash
                );
            }
            let pool = super::thread_pool(d.threads)?;
            Some((
                Denoiser::load(d.threads, "the chunks' --denoise")?,
                layers,
                d.scene,
                pool,
            ))
        }
    };
    let range = key.first_frame..=key.last_frame;
    let pattern = out.unwrap_or(&chunks_out);
    let (out, created) = check_output(pattern, &range, (key.width, key.height))?;
    let mut warnings = Vec::new();
    if key.aov && method.reuses() && !out.is_exr() {
        warnings.push(format!(
            "--aov: the chunks kept the reuse channels, but {pattern} holds RGB only; they were \
             not written (use .exr)"
        ));
    }
    if key.denoise == "rgb+layers" && !out.is_exr() {
        warnings.push(format!(
            "--denoise-layers: {pattern} holds RGB only; the raw and guide layers were not \
             written (use .exr)"
        ));
    }
    let lock = super::lock_path(pattern, None);
    // The partials, every file of the scene the chunks recorded (its textures too), and with
    // --scene that scene's: none may be written over.
    let scene_inputs = denoising.map_or(&[][..], |d| &d.scene.inputs[..]);
    let inputs: Vec<PathBuf> = files
        .iter()
        .map(|f| f.path.clone())
        .chain(
            files
                .iter()
                .flat_map(|f| f.trailer.inputs.iter().map(PathBuf::from)),
        )
        .chain(scene_inputs.iter().cloned())
        .collect();
    let outputs = range
        .clone()
        .map(|f| ("--out", out.path(f)))
        .chain([("the lock of --out", lock.clone())]);
    super::guard::check_outputs(outputs, &inputs)?;
    let frames = super::guard::Frames {
        pattern: &out,
        frames: range.clone(),
    };
    let _lock = super::guard::OutputLock::acquire(&lock, pattern, Some(frames))?;
    // After the lock: a render of these frames that is running holds it, and is said as such.
    super::check_no_interrupted_render(pattern, &range, None)?;
    super::remove_stale_frames(&out, range.clone());
    // Where each frame's shares are: frame -> (file, offset).
    let mut shares: BTreeMap<u32, Vec<(usize, u64)>> = BTreeMap::new();
    for (i, f) in files.iter().enumerate() {
        for &(frame, off) in &f.trailer.records {
            shares.entry(frame).or_default().push((i, off));
        }
    }
    for f in range.clone() {
        if !shares.contains_key(&f) {
            bail!("frame {f}: in none of the partial files; no frame was written");
        }
    }
    let mut sink = FileSink::new(
        FrameMeta {
            scene: key.scene.clone(),
            method: key.method.clone(),
            spp: key.spp,
            window: key.window,
            seed: key.seed,
            exr_float: t0.exr_float,
        },
        out,
    );
    let partial_bytes = files
        .iter()
        .map(|f| std::fs::metadata(&f.path).map_or(0, |m| m.len()))
        .sum();
    let norm = method.norm();
    let sample_folds = method.sample_folds(key.spp, key.window, key.adaptive != 0.0);
    // A frame from its shares: read (each record checked), added, its groups counted.
    let mut combine = |frame: u32, list: &[(usize, u64)]| -> Result<Developed> {
        let mut shares = list.iter().map(|&(i, off)| -> Result<(Record, String)> {
            let label = label(&files[i]);
            let r = files[i].record(off, norm)?;
            check_record(&r, frame, key, method).with_context(|| label.clone())?;
            Ok((r, label))
        });
        let (first, _) = shares.next().expect("a frame has at least one share")?;
        Ok(match first {
            Record::Pixels(d) => {
                if let Some(r) = shares.next() {
                    bail!("frame {frame}: finished pixels in two partials ({})", r?.1);
                }
                d
            }
            Record::Sums(mut acc) => {
                for r in shares {
                    let (r, label) = r?;
                    absorb(&mut acc, r).with_context(|| format!("merging {label}"))?;
                }
                check_groups(&acc, key.first_frame, key.last_frame, key.window, method)?;
                develop(&acc, sample_folds)
            }
        })
    };
    // Every record of every partial is read and checked before the first frame is written: a
    // damaged record in the last partial must not leave the first frames written.
    for (frame, list) in &shares {
        combine(*frame, list)?;
    }
    // Every check has passed: the output folder stays.
    created.keep();
    let mut nonfinite_pixels = 0;
    let mut black_frames = Vec::new();
    let mut write_frames = |out: &mut dyn Sink| -> Result<()> {
        for (frame, list) in &shares {
            let d = combine(*frame, list)?;
            nonfinite_pixels += d.nonfinite;
            if d.is_black() {
                black_frames.push(*frame);
            }
            out.put(d)?;
        }
        Ok(())
    };
    match denoise {
        None => write_frames(&mut sink)?,
        Some((denoiser, layers, scene, pool)) => {
            let integrator = Integrator::new(scene, key.max_depth);
            let mut dsink = DenoiseSink {
                inner: &mut sink,
                denoiser,
                integrator: &integrator,
                seed: key.seed,
                layers,
                seconds: 0.0,
                warned: false,
            };
            pool.install(|| write_frames(&mut dsink))?;
        }
    }
    let frame_bytes = sink
        .written
        .iter()
        .map(|p| std::fs::metadata(p).map_or(0, |m| m.len()))
        .sum();
    Ok(MergeReport {
        warnings,
        frames: sink.written,
        seconds: start.elapsed().as_secs_f64(),
        partial_bytes,
        frame_bytes,
        nonfinite_pixels,
        black_frames,
    })
}

/// A record must be the frame the trailer says, of the render's size, and of the kind and
/// layout its method and settings give (as `--resume` checks a checkpoint's): a header changed
/// and its checksum recomputed (a sums record's unit set to 100 made its frame 100 times too
/// bright; to NaN, all NaN) is refused.
fn check_record(r: &Record, frame: u32, key: &RunKey, method: Method) -> Result<()> {
    let view = match r {
        Record::Pixels(d) => d.view,
        Record::Sums(a) => a.view,
    };
    let why = if view.frame != frame {
        format!("the record is of frame {}", view.frame)
    } else if (view.width, view.height) != (key.width, key.height) {
        format!(
            "the record is {}x{}, the render {}x{}",
            view.width, view.height, key.width, key.height
        )
    } else {
        match r {
            Record::Pixels(_) if method.reuses() => {
                format!("finished pixels, where {} keeps sums", key.method)
            }
            Record::Sums(_) if !method.reuses() => {
                format!("sums, where {} keeps finished pixels", key.method)
            }
            Record::Sums(a)
                if a.layout != method.layout(key.spp, key.window, key.aov, key.radiance_unit) =>
            {
                format!(
                    "its sums' layout (unit {}, {:?}, landed counts {}, loss counts {}) is not \
                     the render's",
                    a.layout.unit, a.layout.norm, a.layout.landed, a.layout.loss
                )
            }
            _ => return Ok(()),
        }
    };
    bail!("frame {frame}: {why}: the file is damaged; render its chunk again; no frame was written")
}

/// Add another chunk's share of a frame.
fn absorb(acc: &mut FrameAccum, r: Record) -> Result<()> {
    match r {
        Record::Sums(o) => acc
            .absorb(&o)
            .map_err(|e| anyhow!("frame {}: {e}", acc.frame())),
        Record::Pixels(_) => bail!("frame {}: finished pixels beside sums", acc.frame()),
    }
}

/// A merged frame must hold every group that contains it: with groups `g..g+n_f-1` for `g` in
/// `first..=last+1-n_f`, frame `f` is in `min(f, last_group) - max(f+1-n_f, first) + 1` of them.
fn check_groups(acc: &FrameAccum, first: u32, last: u32, n_f: u32, method: Method) -> Result<()> {
    if !method.reuses() {
        return Ok(());
    }
    let f = acc.frame();
    // By the parity of their first frames too (the control variate's two folds): a count moved
    // from one to the other changed the frame's pixels.
    let parity = groups_holding(f, first, last + 1 - n_f, n_f);
    let expected = parity[0] + parity[1];
    if acc.group_count() == expected && acc.groups != parity {
        bail!(
            "frame {f}: the partial files hold {} groups of even and {} of odd first frames, \
             where the render has {} and {}: a file is damaged; no frame was written",
            acc.groups[0],
            acc.groups[1],
            parity[0],
            parity[1]
        );
    }
    if acc.group_count() != expected {
        bail!(
            "frame {f}: the partial files hold {} of its {expected} groups; no frame was \
             written",
            acc.group_count()
        );
    }
    Ok(())
}

/// The groups that contain frame `f` of frames `first..=last` with `n_f` frames per group.
#[cfg(test)]
fn expected_groups(f: u32, first: u32, last: u32, n_f: u32) -> u32 {
    groups_holding(f, first, last + 1 - n_f, n_f).iter().sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn group_counts_per_frame() {
        // Frames 0-9, n_f 3: groups 0..=7; frame 0 in 1 group, 1 in 2, 2..=7 in 3, 8 in 2, 9 in 1,
        // counted here by listing the groups.
        for f in 0..10 {
            let g = (0..=7u32).filter(|g| f >= *g && f < g + 3).count() as u32;
            assert_eq!(expected_groups(f, 0, 9, 3), g, "frame {f}");
            // And by the parity of their first frames, frames 3-12 of a render from frame 3.
            let holding: Vec<u32> = (3..=10u32)
                .filter(|g| f + 3 >= *g && f + 3 < g + 3)
                .collect();
            let odd = holding.iter().filter(|g| *g % 2 == 1).count() as u32;
            let want = [holding.len() as u32 - odd, odd];
            assert_eq!(groups_holding(f + 3, 3, 10, 3), want, "frame {}", f + 3);
        }
        let counts: Vec<u32> = (0..10).map(|f| expected_groups(f, 0, 9, 3)).collect();
        assert_eq!(counts, [1, 2, 3, 3, 3, 3, 3, 3, 2, 1]);
    }
}
