//! `reframe merge`: the frames of a render split into chunks (`render --chunk K/N`), from the
//! chunks' partial files.
//!
//! Chunks split the render by group, not by frame: a frame near a chunk's edge belongs to groups
//! of two chunks, and each chunk leaves its share of that frame's accumulator in its partial file.
//! Merging adds the shares' integer fixed-point sums and counts (exact and order-free) and
//! finishes the frame with the same function a single process uses (`reuse::finish_record`),
//! so the merged frames are bitwise identical to a one-process render with the same seed, for
//! any N. Nothing is written unless every chunk 1..N is there, made with the same settings and
//! build.
//!
//! ```text
//! reframe render vase --method mis-exact --window 7 --chunk 2/3 --out out/vase_####.exr
//! reframe merge out/vase.chunk-*-of-3.partial --out out/vase_####.exr
//! ```
use crate::checkpoint::{partial_path, Chunk, FrameRecord, Kind, StateFile};
use crate::render::{check_output, FrameMeta, FrameSink, Method};
use crate::reuse::finish_record;
use anyhow::{anyhow, bail, Context, Result};
use clap::ValueEnum;
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

pub struct MergeReport {
    pub frames: Vec<PathBuf>,
    pub seconds: f64,
    /// Bytes of the partial files, and of the frames written.
    pub partial_bytes: u64,
    pub frame_bytes: u64,
}

/// Merge `partials` into frames written with `out` (default: the pattern the chunks were given).
pub fn merge(partials: &[PathBuf], out: Option<&str>) -> Result<MergeReport> {
    let start = Instant::now();
    if partials.is_empty() {
        bail!("no partial files given");
    }
    let mut files = partials
        .iter()
        .map(|p| {
            if !p.exists() {
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
        by_k.insert(c.k, i);
    }
    let n = n.unwrap();
    if let Some(k) = (1..=n).find(|k| !by_k.contains_key(k)) {
        let c = Chunk { k, n };
        bail!(
            "chunk {c} is missing (expected {}): render it with --chunk {c} and merge again; \
             no frame was written",
            partial_path(&t0.out, c).display()
        );
    }
    let key = &t0.key;
    let method = Method::from_str(&key.method, false)
        .map_err(|_| anyhow!("{}: unknown method '{}'", label(&files[0]), key.method))?;
    let range = key.first_frame..=key.last_frame;
    let pattern = out.unwrap_or(&t0.out);
    let out = check_output(pattern, &range)?;
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
    let sink = FrameSink {
        meta: FrameMeta {
            scene: key.scene.clone(),
            method: key.method.clone(),
            spp: key.spp,
            window: key.window,
            seed: key.seed,
            exr_float: t0.exr_float,
        },
        out,
    };
    let partial_bytes = files
        .iter()
        .map(|f| std::fs::metadata(&f.path).map_or(0, |m| m.len()))
        .sum();
    let mut frames = Vec::new();
    let mut frame_bytes = 0;
    for (frame, list) in &shares {
        let (i0, off0) = list[0];
        let mut rec: FrameRecord = files[i0].record(off0)?;
        let mut totals = rec.totals();
        for &(i, off) in &list[1..] {
            let other = files[i].record(off)?;
            rec.absorb(&other, &mut totals)
                .with_context(|| format!("merging {}", label(&files[i])))?;
        }
        check_groups(&rec, key.first_frame, key.last_frame, key.window, method)?;
        let fr = finish_record(&rec, &totals, method);
        let path = sink.write(
            *frame,
            (rec.width, rec.height),
            (rec.world_to_camera, rec.world_to_ndc),
            &fr.pixels,
            &fr.channels(),
            rec.seconds,
        )?;
        frame_bytes += std::fs::metadata(&path).map_or(0, |m| m.len());
        frames.push(path);
    }
    Ok(MergeReport {
        frames,
        seconds: start.elapsed().as_secs_f64(),
        partial_bytes,
        frame_bytes,
    })
}

/// A merged frame must hold every group that contains it: with groups `g..g+n_f-1` for `g` in
/// `first..=last+1-n_f`, frame `f` is in `min(f, last_group) - max(f+1-n_f, first) + 1` of them.
fn check_groups(rec: &FrameRecord, first: u32, last: u32, n_f: u32, method: Method) -> Result<()> {
    if !method.reuses() {
        return Ok(());
    }
    let f = rec.frame;
    let last_group = last + 1 - n_f;
    let expected = f.min(last_group) + 1 - (f + 1).saturating_sub(n_f).max(first);
    if rec.groups != expected {
        bail!(
            "frame {f}: the partial files hold {} of its {expected} groups; no further frame was \
             written",
            rec.groups
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn group_counts_per_frame() {
        // Frames 0-9, n_f 3: groups 0..=7; frame 0 in 1 group, 1 in 2, 2..=7 in 3, 8 in 2, 9 in 1.
        let counts: Vec<u32> = (0..10)
            .map(|f| {
                let g = (0..=7u32).filter(|g| f >= *g && f < g + 3).count() as u32;
                let rec = FrameRecord {
                    frame: f,
                    width: 1,
                    height: 1,
                    groups: g,
                    unit: 1.0,
                    data: crate::checkpoint::RecordData::Pixels(vec![0.0; 3]),
                    landed: None,
                    loss: None,
                    landed_total: 0,
                    tried: 0,
                    lost: 0,
                    seconds: 0.0,
                    world_to_camera: [0.0; 16],
                    world_to_ndc: [0.0; 16],
                };
                check_groups(&rec, 0, 9, 3, Method::MisExact).unwrap();
                g
            })
            .collect();
        assert_eq!(counts, [1, 2, 3, 3, 3, 3, 3, 3, 2, 1]);
    }
}
