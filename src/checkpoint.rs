//! State files: resume checkpoints and the partial accumulators of a chunk (`--chunk K/N`), in
//! one format, so that a resumed render and a merge of chunks both finish exactly the integer
//! sums an uninterrupted single process would have.
//!
//! A state file is a sequence of frame records followed by a JSON trailer:
//!
//! ```text
//! record*  trailer-json  u64 trailer length (LE)  b"RFSTATE1"
//! ```
//!
//! The trailer says what the file is (`checkpoint` or `partial`), the settings it was made with
//! (`RunKey`: a resume or merge with other settings is refused, naming the key that differs), how
//! far the run got, and where each record starts. A record is one frame's accumulator: the
//! fixed-point RGB sums of the reuse methods (`reuse::FixedSums`, 32-bit cells and their exact
//! carries) with the per-pixel counts, or the finished pixels of the independent tracer. The
//! magic at the very end is written last: a file without it is incomplete and is refused.
//!
//! Atomicity: a checkpoint is written to a temporary name, flushed to disk and renamed over the
//! previous one, so a kill at any moment (even SIGKILL) leaves either the old or the new
//! checkpoint. A chunk's finished records go to an append-only log beside its partial file; the
//! checkpoint remembers the log's length, a resume truncates the log to it, and the finished
//! chunk appends the trailer and renames the log to the partial file.
//!
//! Where they live, for `--out DIR/NAME_####.ext`: the checkpoint in `DIR/NAME.checkpoint/state`
//! (`DIR/NAME.chunk-K-of-N.checkpoint/` for a chunk), a chunk's partial in
//! `DIR/NAME.chunk-K-of-N.partial`. A render that finishes removes its checkpoint.
use crate::integrator::RayCounts;
use crate::render::FrameReuse;
use crate::scene::Scene;
use anyhow::{anyhow, bail, Context, Result};
use serde::{Deserialize, Serialize};
use std::fs::{File, OpenOptions};
use std::io::{BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::ops::RangeInclusive;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::{Duration, Instant};

const MAGIC: &[u8; 8] = b"RFSTATE1";
const RECORD_MAGIC: u32 = 0x4341_4652; // "RFAC"
const VERSION: u32 = 1;

/// FNV-1a, 64 bits: a stable content hash for cache and settings keys (not for security).
pub struct Fnv(pub u64);

impl Default for Fnv {
    fn default() -> Self {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv {
    pub fn bytes(&mut self, b: &[u8]) {
        for &x in b {
            self.0 = (self.0 ^ x as u64).wrapping_mul(0x100_0000_01b3);
        }
    }
    pub fn f32s(&mut self, v: impl IntoIterator<Item = f32>) {
        for x in v {
            self.bytes(&x.to_bits().to_le_bytes());
        }
    }
}

/// Everything about a scene that changes a rendered pixel: geometry, materials, camera path.
pub fn hash_scene(f: &mut Fnv, scene: &Scene) {
    f.f32s(scene.positions.iter().flat_map(|p| p.to_array()));
    f.f32s(scene.normals.iter().flat_map(|p| p.to_array()));
    for t in &scene.triangles {
        f.bytes(&t.map(u32::to_le_bytes).concat());
    }
    for m in &scene.tri_material {
        f.bytes(&m.to_le_bytes());
    }
    f.bytes(format!("{:?}{:?}", scene.materials, scene.path).as_bytes());
    f.bytes(&scene.frames.to_le_bytes());
}

/// A hash of the running executable: a different build may round differently, so neither a
/// resume nor a merge mixes builds.
pub fn hash_exe(f: &mut Fnv) -> Result<()> {
    let exe = std::env::current_exe().context("finding the reframe executable")?;
    // Streamed: the binary is ~50 MB, which would otherwise show in the peak memory.
    let mut r = File::open(&exe).with_context(|| format!("reading {}", exe.display()))?;
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = r
            .read(&mut buf)
            .with_context(|| format!("reading {}", exe.display()))?;
        if n == 0 {
            return Ok(());
        }
        f.bytes(&buf[..n]);
    }
}

/// The settings a state file was made with; resuming or merging needs them all equal.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RunKey {
    pub scene: String,
    pub scene_hash: String,
    pub build_hash: String,
    pub method: String,
    pub spp: u32,
    pub window: u32,
    pub first_frame: u32,
    pub last_frame: u32,
    pub width: u32,
    pub height: u32,
    pub seed: u64,
    pub max_depth: u32,
    pub visibility: String,
    pub aov: bool,
    /// `--adaptive` target, 0 when off.
    #[serde(default)]
    pub adaptive: f32,
}

impl RunKey {
    /// The first setting that differs from `o`, as "key: ours vs theirs".
    pub fn difference(&self, o: &RunKey) -> Option<String> {
        let (a, b) = (
            serde_json::to_value(self).ok()?,
            serde_json::to_value(o).ok()?,
        );
        let (a, b) = (a.as_object()?, b.as_object()?);
        a.iter().find_map(|(k, v)| {
            let w = &b[k];
            (v != w).then(|| format!("{k}: {v} vs {w}"))
        })
    }
}

/// `K/N` of `--chunk`, 1-based.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Chunk {
    pub k: u32,
    pub n: u32,
}

impl Chunk {
    /// This chunk's share of `units` (groups, or frames for the independent tracer): contiguous
    /// and as even as integer division makes them.
    pub fn share(
        &self,
        units: std::ops::RangeInclusive<u32>,
    ) -> Result<std::ops::RangeInclusive<u32>> {
        let (a, count) = (*units.start(), units.end() - units.start() + 1);
        if self.n > count {
            bail!(
                "--chunk {}/{}: only {count} {} to split; use at most {count} chunks",
                self.k,
                self.n,
                if count == 1 { "unit" } else { "units" }
            );
        }
        let lo = (self.k - 1) as u64 * count as u64 / self.n as u64;
        let hi = self.k as u64 * count as u64 / self.n as u64;
        Ok(a + lo as u32..=a + hi as u32 - 1)
    }
}

impl std::fmt::Display for Chunk {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.k, self.n)
    }
}

/// The counters a render carries across a resume (what `--stats` reports).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Progress {
    pub counts: RayCounts,
    pub nonfinite_samples: u64,
    pub nonfinite_pixels: u64,
    pub tried: u64,
    pub lost: u64,
    pub per_frame: Vec<FrameReuse>,
    /// Seconds of rendering before this process started.
    pub seconds: f64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Kind {
    Checkpoint,
    Partial,
}

/// What a state file says about itself.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Trailer {
    pub format: String,
    pub version: u32,
    pub kind: Kind,
    pub key: RunKey,
    pub chunk: Option<Chunk>,
    /// The units (groups, or frames) this run covers, inclusive.
    pub units: [u32; 2],
    /// The first unit still to render (a checkpoint); one past the last (a partial).
    pub next_unit: u32,
    /// A chunk's checkpoint: how many bytes of its partial log are valid.
    pub log_len: u64,
    /// A chunk's checkpoint: the frames finished in the log and where their records start.
    pub log_records: Vec<(u32, u64)>,
    /// Where this file's own records start (a checkpoint: the frames in flight; a partial: every
    /// frame the chunk touched).
    pub records: Vec<(u32, u64)>,
    pub progress: Progress,
    /// The output pattern and EXR precision the frames are (to be) written with.
    pub out: String,
    pub exr_float: bool,
}

impl Trailer {
    /// A run's trailer before it has rendered anything: `key`'s settings, the units it covers,
    /// the output it writes.
    pub fn new(
        key: RunKey,
        chunk: Option<Chunk>,
        units: &RangeInclusive<u32>,
        out: String,
        exr_float: bool,
    ) -> Trailer {
        Trailer {
            format: "reframe-state".into(),
            version: VERSION,
            kind: Kind::Checkpoint,
            key,
            chunk,
            units: [*units.start(), *units.end()],
            next_unit: *units.start(),
            log_len: 0,
            log_records: vec![],
            records: vec![],
            progress: Progress::default(),
            out,
            exr_float,
        }
    }
}

/// One frame's accumulator.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameRecord {
    pub frame: u32,
    pub width: u32,
    pub height: u32,
    /// Groups that contributed (reuse), 1 for finished pixels.
    pub groups: u32,
    /// What one unit of the sums is worth (`reuse::FrameAccum::unit`).
    pub unit: f32,
    pub data: RecordData,
    pub landed: Option<Vec<u32>>,
    /// Per pixel: attempted and lost reuses (`--aov`).
    pub loss: Option<(Vec<u32>, Vec<u32>)>,
    pub landed_total: u64,
    pub tried: u64,
    pub lost: u64,
    pub seconds: f64,
    pub world_to_camera: [f32; 16],
    pub world_to_ndc: [f32; 16],
}

#[derive(Clone, Debug, PartialEq)]
pub enum RecordData {
    /// Fixed-point RGB cells and their carries (pixel channel index, value in steps).
    Sums {
        cells: Vec<i32>,
        carry: Vec<(u64, i64)>,
    },
    /// Finished RGB pixels (the independent tracer).
    Pixels(Vec<f32>),
}

impl FrameRecord {
    fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// The exact fixed-point sums, cells plus carries, one per pixel channel.
    pub fn totals(&self) -> Vec<i64> {
        match &self.data {
            RecordData::Sums { cells, carry } => {
                let mut t: Vec<i64> = cells.iter().map(|&c| c as i64).collect();
                for &(i, c) in carry {
                    t[i as usize] += c;
                }
                t
            }
            RecordData::Pixels(_) => Vec::new(),
        }
    }

    pub fn write(&self, w: &mut impl Write) -> std::io::Result<()> {
        let u32s = |w: &mut dyn Write, v: &[u32]| -> std::io::Result<()> {
            for x in v {
                w.write_all(&x.to_le_bytes())?;
            }
            Ok(())
        };
        let kind = match &self.data {
            RecordData::Sums { .. } => 0u8,
            RecordData::Pixels(_) => 1u8,
        };
        for v in [
            RECORD_MAGIC,
            self.frame,
            self.width,
            self.height,
            self.groups,
        ] {
            w.write_all(&v.to_le_bytes())?;
        }
        w.write_all(&[
            kind,
            self.landed.is_some() as u8,
            self.loss.is_some() as u8,
            0,
        ])?;
        w.write_all(&self.unit.to_le_bytes())?;
        for v in [self.landed_total, self.tried, self.lost] {
            w.write_all(&v.to_le_bytes())?;
        }
        w.write_all(&self.seconds.to_le_bytes())?;
        for m in self.world_to_camera.iter().chain(&self.world_to_ndc) {
            w.write_all(&m.to_le_bytes())?;
        }
        match &self.data {
            RecordData::Sums { cells, carry } => {
                for c in cells {
                    w.write_all(&c.to_le_bytes())?;
                }
                w.write_all(&(carry.len() as u64).to_le_bytes())?;
                for &(i, c) in carry {
                    w.write_all(&i.to_le_bytes())?;
                    w.write_all(&c.to_le_bytes())?;
                }
            }
            RecordData::Pixels(px) => {
                for p in px {
                    w.write_all(&p.to_le_bytes())?;
                }
            }
        }
        if let Some(l) = &self.landed {
            u32s(w, l)?;
        }
        if let Some((t, l)) = &self.loss {
            u32s(w, t)?;
            u32s(w, l)?;
        }
        Ok(())
    }

    pub fn read(r: &mut impl Read) -> std::io::Result<FrameRecord> {
        let bad =
            |what: &str| std::io::Error::new(std::io::ErrorKind::InvalidData, what.to_string());
        let mut b4 = [0u8; 4];
        let mut u32_ = |r: &mut dyn Read| -> std::io::Result<u32> {
            r.read_exact(&mut b4)?;
            Ok(u32::from_le_bytes(b4))
        };
        if u32_(r)? != RECORD_MAGIC {
            return Err(bad("not a frame record"));
        }
        let (frame, width, height, groups) = (u32_(r)?, u32_(r)?, u32_(r)?, u32_(r)?);
        let mut flags = [0u8; 4];
        r.read_exact(&mut flags)?;
        let unit = f32::from_bits(u32_(r)?);
        let mut b8 = [0u8; 8];
        let mut u64_ = |r: &mut dyn Read| -> std::io::Result<u64> {
            r.read_exact(&mut b8)?;
            Ok(u64::from_le_bytes(b8))
        };
        let (landed_total, tried, lost) = (u64_(r)?, u64_(r)?, u64_(r)?);
        let seconds = f64::from_bits(u64_(r)?);
        let mut mats = [0f32; 32];
        for m in &mut mats {
            *m = f32::from_bits(u32_(r)?);
        }
        let p = width as usize * height as usize;
        if p == 0 || p > 1 << 28 {
            return Err(bad("implausible frame size"));
        }
        let words = |r: &mut dyn Read, n: usize| -> std::io::Result<Vec<u32>> {
            let mut bytes = vec![0u8; 4 * n];
            r.read_exact(&mut bytes)?;
            Ok(bytes
                .chunks_exact(4)
                .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
                .collect())
        };
        let data = match flags[0] {
            0 => {
                let cells = words(r, 3 * p)?.into_iter().map(|c| c as i32).collect();
                let n = u64_(r)? as usize;
                if n > 3 * p {
                    return Err(bad("implausible carry table"));
                }
                let mut carry = Vec::with_capacity(n);
                for _ in 0..n {
                    let i = u64_(r)?;
                    let c = u64_(r)? as i64;
                    if i as usize >= 3 * p {
                        return Err(bad("carry outside the frame"));
                    }
                    carry.push((i, c));
                }
                RecordData::Sums { cells, carry }
            }
            1 => RecordData::Pixels(words(r, 3 * p)?.into_iter().map(f32::from_bits).collect()),
            _ => return Err(bad("unknown record kind")),
        };
        let landed = if flags[1] != 0 {
            Some(words(r, p)?)
        } else {
            None
        };
        let loss = if flags[2] != 0 {
            Some((words(r, p)?, words(r, p)?))
        } else {
            None
        };
        Ok(FrameRecord {
            frame,
            width,
            height,
            groups,
            unit,
            data,
            landed,
            loss,
            landed_total,
            tried,
            lost,
            seconds,
            world_to_camera: mats[..16].try_into().unwrap(),
            world_to_ndc: mats[16..].try_into().unwrap(),
        })
    }

    /// Add `o` (the same frame from another chunk) into `self`: the integer sums and counts add
    /// exactly, so the order of the chunks does not matter.
    pub fn absorb(&mut self, o: &FrameRecord, totals: &mut [i64]) -> Result<()> {
        if (o.width, o.height, o.unit.to_bits()) != (self.width, self.height, self.unit.to_bits()) {
            bail!("frame {}: records of different sizes or scales", self.frame);
        }
        let RecordData::Sums { .. } = &o.data else {
            bail!("frame {}: finished pixels in two partials", self.frame);
        };
        for (t, v) in totals.iter_mut().zip(o.totals()) {
            *t += v;
        }
        self.groups += o.groups;
        let add = |a: &mut Vec<u32>, b: &Vec<u32>| a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
        match (&mut self.landed, &o.landed) {
            (Some(a), Some(b)) => add(a, b),
            (None, None) => {}
            _ => bail!("frame {}: records with and without counts", self.frame),
        }
        match (&mut self.loss, &o.loss) {
            (Some((a, b)), Some((c, d))) => {
                add(a, c);
                add(b, d);
            }
            (None, None) => {}
            _ => bail!(
                "frame {}: records with and without loss channels",
                self.frame
            ),
        }
        self.landed_total += o.landed_total;
        self.tried += o.tried;
        self.lost += o.lost;
        self.seconds += o.seconds;
        Ok(())
    }

    /// Size in bytes on disk.
    pub fn bytes(&self) -> u64 {
        let p = self.pixels() as u64;
        let data = match &self.data {
            RecordData::Sums { carry, .. } => 12 * p + 8 + 16 * carry.len() as u64,
            RecordData::Pixels(_) => 12 * p,
        };
        4 * 5
            + 4
            + 4
            + 24
            + 8
            + 128
            + data
            + self.landed.as_ref().map_or(0, |_| 4 * p)
            + self.loss.as_ref().map_or(0, |_| 8 * p)
    }
}

/// A state file opened for reading: its trailer, and its records on demand.
pub struct StateFile {
    pub path: PathBuf,
    pub trailer: Trailer,
    file: BufReader<File>,
}

impl StateFile {
    pub fn open(path: &Path) -> Result<StateFile> {
        let label = path.display();
        let mut f = File::open(path).with_context(|| format!("{label}: cannot open"))?;
        let len = f.metadata()?.len();
        let incomplete = || {
            anyhow!(
                "{label}: not a complete reframe state file (truncated, or still being written)"
            )
        };
        if len < 16 {
            return Err(incomplete());
        }
        f.seek(SeekFrom::Start(len - 16))?;
        let mut tail = [0u8; 16];
        f.read_exact(&mut tail)?;
        if &tail[8..] != MAGIC {
            return Err(incomplete());
        }
        let tlen = u64::from_le_bytes(tail[..8].try_into().unwrap());
        if tlen > len - 16 {
            return Err(incomplete());
        }
        f.seek(SeekFrom::Start(len - 16 - tlen))?;
        let mut json = vec![0u8; tlen as usize];
        f.read_exact(&mut json)?;
        let trailer: Trailer = serde_json::from_slice(&json)
            .map_err(|e| anyhow!("{label}: unreadable trailer ({e})"))?;
        if trailer.format != "reframe-state" || trailer.version != VERSION {
            bail!(
                "{label}: state format {} version {}, this build reads reframe-state version {VERSION}",
                trailer.format,
                trailer.version
            );
        }
        Ok(StateFile {
            path: path.to_path_buf(),
            trailer,
            file: BufReader::new(f),
        })
    }

    /// The record that starts at `offset`.
    pub fn record(&mut self, offset: u64) -> Result<FrameRecord> {
        self.file.seek(SeekFrom::Start(offset))?;
        FrameRecord::read(&mut self.file)
            .with_context(|| format!("{}: damaged record at byte {offset}", self.path.display()))
    }
}

/// Write a state file atomically: records, trailer (with the records' offsets filled in), flush
/// to disk, rename. The records are taken one at a time, so that a checkpoint holds one frame's
/// copy in memory, not all of them.
pub fn write_state(
    path: &Path,
    trailer: &mut Trailer,
    records: impl IntoIterator<Item = FrameRecord>,
) -> Result<()> {
    let tmp = tmp_name(path);
    let result = (|| -> Result<()> {
        let mut w = BufWriter::new(File::create(&tmp)?);
        let mut offset = 0u64;
        trailer.records.clear();
        for r in records {
            trailer.records.push((r.frame, offset));
            r.write(&mut w)?;
            offset += r.bytes();
        }
        write_trailer(&mut w, trailer)?;
        let f = w.into_inner().map_err(|e| e.into_error())?;
        f.sync_all()?;
        Ok(())
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(e.context(format!("writing {}", tmp.display())));
    }
    std::fs::rename(&tmp, path)
        .with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))
}

fn write_trailer(w: &mut impl Write, t: &Trailer) -> std::io::Result<()> {
    let json = serde_json::to_vec(t).map_err(std::io::Error::other)?;
    w.write_all(&json)?;
    w.write_all(&(json.len() as u64).to_le_bytes())?;
    w.write_all(MAGIC)
}

/// The temporary name `p` is written under before it is renamed into place (the `.tmp-PID`
/// suffix that `remove_stale_tmp` recognises).
pub fn tmp_name(p: &Path) -> PathBuf {
    let mut name = p.file_name().unwrap_or_default().to_os_string();
    name.push(format!(".tmp-{}", std::process::id()));
    p.with_file_name(name)
}

/// Remove the temporary files a killed process left in `dir` (`NAME.tmp-PID...` or
/// `.NAME.tmp-PID...`) whose `NAME` passes `ours`.
pub fn remove_stale_tmp(dir: &Path, ours: impl Fn(&str) -> bool) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if let Some((base, _)) = name.split_once(".tmp-") {
            if ours(base.strip_prefix('.').unwrap_or(base)) {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
}

/// The file name stem of an output pattern: `out/vase_####.exr` gives `out` and `vase`.
pub fn output_stem(pattern: &str) -> (PathBuf, String) {
    let p = Path::new(pattern);
    let dir = crate::image::parent_dir(p);
    let name = p
        .file_name()
        .map(|n| n.to_string_lossy())
        .unwrap_or_default();
    let stem = match name.find('#') {
        Some(i) => name[..i].trim_end_matches(['_', '.', '-']).to_string(),
        None => Path::new(&*name)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default(),
    };
    (
        dir,
        if stem.is_empty() {
            "frames".into()
        } else {
            stem
        },
    )
}

/// The default checkpoint folder of a render writing `pattern` (see the module note).
pub fn default_checkpoint_dir(pattern: &str, chunk: Option<Chunk>) -> PathBuf {
    let (dir, stem) = output_stem(pattern);
    match chunk {
        Some(c) => dir.join(format!("{stem}.chunk-{}-of-{}.checkpoint", c.k, c.n)),
        None => dir.join(format!("{stem}.checkpoint")),
    }
}

/// The partial file chunk `c` of a render writing `pattern` produces.
pub fn partial_path(pattern: &str, c: Chunk) -> PathBuf {
    let (dir, stem) = output_stem(pattern);
    dir.join(format!("{stem}.chunk-{}-of-{}.partial", c.k, c.n))
}

/// What a resumed render starts from.
pub struct Resumed {
    pub trailer: Trailer,
    /// The frames in flight at the checkpoint.
    pub active: Vec<FrameRecord>,
}

/// A chunk's append-only log of finished records: (file, path, valid length, (frame, offset) of
/// each record).
type ChunkLog = (File, PathBuf, u64, Vec<(u32, u64)>);

/// Checkpoints and the chunk log of one render.
pub struct Checkpointer {
    /// The checkpoint folder; `None`: no checkpoints.
    dir: Option<PathBuf>,
    every: Duration,
    last: Instant,
    template: Trailer,
    /// A chunk's append-only log of finished records.
    log: Option<ChunkLog>,
    partial: Option<PathBuf>,
    /// Time spent writing checkpoints, for the statistics.
    pub spent: Duration,
    pub written: u32,
}

impl Checkpointer {
    /// No checkpoints and no chunk: a plain in-memory render.
    pub fn none() -> Checkpointer {
        Checkpointer {
            dir: None,
            every: Duration::MAX,
            last: Instant::now(),
            template: Trailer::new(RunKey::default(), None, &(0..=0), String::new(), false),
            log: None,
            partial: None,
            spent: Duration::ZERO,
            written: 0,
        }
    }

    /// Whether finished frames go to a chunk's partial log rather than to frame files.
    pub fn chunked(&self) -> bool {
        self.log.is_some()
    }

    pub fn dir(&self) -> Option<&Path> {
        self.dir.as_deref()
    }

    /// Open the checkpoint folder `dir` (if any) for a run with `template`'s settings. With
    /// `resume`, read the checkpoint there and check it was made with the same settings; without,
    /// refuse to overwrite one. A chunk also opens its log, truncated to the checkpoint's length.
    pub fn open(
        dir: Option<PathBuf>,
        every: Duration,
        resume: bool,
        template: Trailer,
    ) -> Result<(Checkpointer, Option<Resumed>)> {
        let mut resumed = None;
        if let Some(d) = &dir {
            let state = d.join("state");
            if state.exists() {
                if !resume {
                    bail!(
                        "{} holds the checkpoint of an interrupted render: add --resume to \
                         continue it, or delete the folder to start over",
                        d.display()
                    );
                }
                let mut sf = StateFile::open(&state)?;
                let t = sf.trailer.clone();
                if t.kind != Kind::Checkpoint {
                    bail!("{}: not a checkpoint", state.display());
                }
                if let Some(diff) = t.key.difference(&template.key) {
                    bail!(
                        "--resume: the checkpoint in {} was made with other settings ({diff}); \
                         resume with the same command line and build, or delete the folder",
                        d.display()
                    );
                }
                if t.chunk != template.chunk || t.units != template.units {
                    bail!(
                        "--resume: the checkpoint in {} is of another chunk",
                        d.display()
                    );
                }
                remove_stale_tmp(d, |_| true);
                let active = t
                    .records
                    .iter()
                    .map(|&(_, off)| sf.record(off))
                    .collect::<Result<Vec<_>>>()?;
                resumed = Some(Resumed { trailer: t, active });
            } else if resume {
                eprintln!(
                    "note: no checkpoint in {}: starting from the beginning",
                    d.display()
                );
            }
            std::fs::create_dir_all(d)
                .with_context(|| format!("creating the checkpoint folder {}", d.display()))?;
            crate::image::check_writable_dir(d)?;
        }
        let partial = template.chunk.map(|c| partial_path(&template.out, c));
        let log = match &partial {
            None => None,
            Some(p) => {
                let mut name = p.file_name().unwrap_or_default().to_os_string();
                name.push(".log");
                let lp = p.with_file_name(name);
                let f = OpenOptions::new()
                    .create(true)
                    .truncate(false)
                    .write(true)
                    .open(&lp)
                    .with_context(|| format!("opening {}", lp.display()))?;
                let (len, recs) = match &resumed {
                    Some(r) => (r.trailer.log_len, r.trailer.log_records.clone()),
                    None => (0, Vec::new()),
                };
                if f.metadata()?.len() < len {
                    bail!("{}: shorter than its checkpoint says; delete the checkpoint and the log to start the chunk over", lp.display());
                }
                f.set_len(len)?;
                let mut f = f;
                f.seek(SeekFrom::Start(len))?;
                Some((f, lp, len, recs))
            }
        };
        Ok((
            Checkpointer {
                dir,
                every,
                last: Instant::now(),
                template,
                log,
                partial,
                spent: Duration::ZERO,
                written: 0,
            },
            resumed,
        ))
    }

    /// Whether a checkpoint is due (there is a folder and `every` has passed since the last).
    pub fn due(&self) -> bool {
        self.dir.is_some() && self.last.elapsed() >= self.every
    }

    pub fn enabled(&self) -> bool {
        self.dir.is_some()
    }

    /// Write the checkpoint: the next unit to render, the counters, the frames in flight.
    pub fn save(
        &mut self,
        next_unit: u32,
        progress: &Progress,
        active: impl IntoIterator<Item = FrameRecord>,
    ) -> Result<()> {
        let Some(dir) = &self.dir else {
            return Ok(());
        };
        let t0 = Instant::now();
        let mut t = self.template.clone();
        t.kind = Kind::Checkpoint;
        t.next_unit = next_unit;
        t.progress = progress.clone();
        if let Some((f, _, len, recs)) = &mut self.log {
            // The log's records must be on disk before a checkpoint counts them.
            f.sync_data()?;
            t.log_len = *len;
            t.log_records = recs.clone();
        }
        write_state(&dir.join("state"), &mut t, active)?;
        self.spent += t0.elapsed();
        self.written += 1;
        self.last = Instant::now();
        Ok(())
    }

    /// A chunk's frame that no later group of the chunk touches: append it to the log.
    pub fn retire(&mut self, r: &FrameRecord) -> Result<()> {
        let (f, lp, len, recs) = self.log.as_mut().expect("retire is only called for chunks");
        let mut w = BufWriter::new(&mut *f);
        r.write(&mut w)
            .and_then(|_| w.flush())
            .with_context(|| format!("writing {}", lp.display()))?;
        recs.push((r.frame, *len));
        *len += r.bytes();
        Ok(())
    }

    /// The run is complete: a chunk turns its log into the partial file; the checkpoint goes.
    /// Returns the partial file of a chunk.
    pub fn finish(&mut self, next_unit: u32, progress: &Progress) -> Result<Option<PathBuf>> {
        let mut out = None;
        if let (Some((f, lp, _, recs)), Some(partial)) = (self.log.take(), &self.partial) {
            let mut t = self.template.clone();
            t.kind = Kind::Partial;
            t.next_unit = next_unit;
            t.progress = progress.clone();
            t.records = recs;
            let mut w = BufWriter::new(f);
            write_trailer(&mut w, &t).with_context(|| format!("writing {}", lp.display()))?;
            let f = w.into_inner().map_err(|e| e.into_error())?;
            f.sync_all()?;
            std::fs::rename(&lp, partial)
                .with_context(|| format!("renaming {} to {}", lp.display(), partial.display()))?;
            out = Some(partial.clone());
        }
        if let Some(d) = &self.dir {
            let _ = std::fs::remove_file(d.join("state"));
            let _ = std::fs::remove_dir(d);
        }
        Ok(out)
    }
}

/// A resumable render in progress: its checkpoints, the units (groups, or frames) it covers,
/// how far it got, and its counters.
pub struct Run {
    pub ckpt: Checkpointer,
    pub units: RangeInclusive<u32>,
    /// The first unit not yet rendered.
    pub next: u32,
    pub progress: Progress,
    /// Set by a signal handler: stop at the next unit boundary, after a checkpoint.
    pub interrupt: Option<Arc<AtomicBool>>,
    started: Instant,
    earlier_seconds: f64,
}

impl Run {
    pub fn new(ckpt: Checkpointer, units: RangeInclusive<u32>, progress: Progress) -> Run {
        Run {
            ckpt,
            next: *units.start(),
            units,
            earlier_seconds: progress.seconds,
            progress,
            interrupt: None,
            started: Instant::now(),
        }
    }

    pub fn interrupted(&self) -> bool {
        self.interrupt
            .as_ref()
            .is_some_and(|f| f.load(std::sync::atomic::Ordering::Relaxed))
    }

    /// Seconds of rendering, this process and the ones it resumed.
    pub fn seconds(&self) -> f64 {
        self.earlier_seconds + self.started.elapsed().as_secs_f64()
    }

    /// Checkpoint at `next` (the first unit still to render), with the frames in flight
    /// `active`.
    pub fn save(&mut self, active: impl IntoIterator<Item = FrameRecord>) -> Result<()> {
        self.progress.seconds = self.seconds();
        self.ckpt.save(self.next, &self.progress, active)
    }

    /// The run is complete: the chunk's partial file, if any (the checkpoint is removed).
    pub fn finish(&mut self) -> Result<Option<PathBuf>> {
        self.progress.seconds = self.seconds();
        self.ckpt.finish(self.next, &self.progress)
    }

    /// Frames finished so far, this process and the ones it resumed: every unit retires its
    /// first frame (the last unit retires the rest, but a run stopped early never did it).
    pub fn frames_retired(&self) -> u32 {
        self.next - self.units.start()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(frame: u32, sums: bool) -> FrameRecord {
        let p = 6;
        FrameRecord {
            frame,
            width: 3,
            height: 2,
            groups: 2,
            unit: 7.0,
            data: if sums {
                RecordData::Sums {
                    cells: (0..3 * p as i32).map(|i| i * 1000 - 5).collect(),
                    carry: vec![(4, 1 << 32), (17, -(1 << 33))],
                }
            } else {
                RecordData::Pixels((0..3 * p).map(|i| i as f32 * 0.25).collect())
            },
            landed: sums.then(|| vec![3; p]),
            loss: sums.then(|| (vec![2; p], vec![1; p])),
            landed_total: 18,
            tried: 12,
            lost: 6,
            seconds: 1.5,
            world_to_camera: [0.5; 16],
            world_to_ndc: [-2.0; 16],
        }
    }

    #[test]
    fn records_round_trip_and_report_their_size() {
        for sums in [true, false] {
            let r = record(4, sums);
            let mut bytes = Vec::new();
            r.write(&mut bytes).unwrap();
            assert_eq!(bytes.len() as u64, r.bytes());
            assert_eq!(FrameRecord::read(&mut bytes.as_slice()).unwrap(), r);
            // Any truncation is an error, never a panic or a short record.
            for cut in [0, 3, 40, bytes.len() - 1] {
                assert!(FrameRecord::read(&mut &bytes[..cut]).is_err());
            }
        }
    }

    #[test]
    fn absorbing_adds_the_exact_sums() {
        let (mut a, b) = (record(1, true), record(1, true));
        let mut t = a.totals();
        a.absorb(&b, &mut t).unwrap();
        assert_eq!(t, b.totals().iter().map(|v| 2 * v).collect::<Vec<_>>());
        assert_eq!(t[4], 2 * (3995 + (1 << 32)));
        assert_eq!(a.groups, 4);
        assert_eq!(a.landed.as_ref().unwrap()[0], 6);
        assert!(a.absorb(&record(1, false), &mut t).is_err());
    }

    #[test]
    fn chunks_split_units_contiguously_and_evenly() {
        for count in 1..20u32 {
            for n in 1..=count {
                let shares: Vec<_> = (1..=n)
                    .map(|k| Chunk { k, n }.share(5..=4 + count).unwrap())
                    .collect();
                assert_eq!(*shares[0].start(), 5);
                assert_eq!(*shares.last().unwrap().end(), 4 + count);
                for w in shares.windows(2) {
                    assert_eq!(*w[0].end() + 1, *w[1].start());
                }
                let sizes: Vec<u32> = shares.iter().map(|s| s.end() + 1 - s.start()).collect();
                assert!(sizes.iter().max().unwrap() - sizes.iter().min().unwrap() <= 1);
            }
            assert!(Chunk { k: 1, n: count + 1 }.share(0..=count - 1).is_err());
        }
    }

    #[test]
    fn stems_and_paths() {
        assert_eq!(
            output_stem("out/vase_####.exr"),
            ("out".into(), "vase".into())
        );
        assert_eq!(output_stem("x.png"), (".".into(), "x".into()));
        assert_eq!(output_stem("a/####.exr"), ("a".into(), "frames".into()));
        assert_eq!(
            partial_path("r/f_####.exr", Chunk { k: 2, n: 3 }),
            PathBuf::from("r/f.chunk-2-of-3.partial")
        );
        assert_eq!(
            default_checkpoint_dir("r/f_####.exr", None),
            PathBuf::from("r/f.checkpoint")
        );
    }

    #[test]
    fn state_files_round_trip_and_incomplete_ones_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("state");
        let key = RunKey {
            scene: "s".into(),
            scene_hash: "0".into(),
            build_hash: "1".into(),
            method: "mis".into(),
            spp: 1,
            window: 3,
            first_frame: 0,
            last_frame: 9,
            width: 3,
            height: 2,
            seed: 0,
            max_depth: 16,
            visibility: "packet".into(),
            aov: false,
            adaptive: 0.0,
        };
        let mut t = Trailer::new(key.clone(), None, &(0..=7), "o_####.exr".into(), false);
        t.next_unit = 3;
        let recs = [record(3, true), record(4, true)];
        write_state(&p, &mut t, recs.clone()).unwrap();
        let mut sf = StateFile::open(&p).unwrap();
        assert_eq!(sf.trailer.next_unit, 3);
        let offs = sf.trailer.records.clone();
        assert_eq!(sf.record(offs[1].1).unwrap(), recs[1]);
        let bytes = std::fs::read(&p).unwrap();
        std::fs::write(&p, &bytes[..bytes.len() - 1]).unwrap();
        let err = StateFile::open(&p).err().unwrap().to_string();
        assert!(err.contains("not a complete"), "{err}");
        let mut other = key.clone();
        other.spp = 2;
        assert_eq!(key.difference(&other).unwrap(), "spp: 1 vs 2");
    }
}
