//! State files: resume checkpoints and the partial accumulators of a chunk (`--chunk K/N`), in
//! one format, so that a resumed render and a merge of chunks both finish exactly the integer
//! sums an uninterrupted single process would have (the format is written out in
//! `docs/state-format.md`).
//!
//! ```text
//! record*  trailer-json  u64 trailer length (LE)  b"RFSTATE1"
//! ```
//!
//! The trailer says what the file is (`checkpoint` or `partial`), the settings it was made with
//! (`RunKey`: a resume or merge with other settings is refused, naming the key that differs), how
//! far the run got, and where each record starts. A record is one frame's accumulator
//! (`film::FrameAccum`: the fixed-point RGB sums, their exact carries and the per-pixel counts),
//! or the finished pixels of the independent tracer. The magic at the very end is written last:
//! a file without it is incomplete and is refused.
//!
//! The rooms: the format (here), the run key, chunks and file names (`key`), and the
//! checkpointer with the counters a run carries across a resume (`checkpoint`).
pub mod checkpoint;
pub mod key;

use crate::film::fixed::FixedSums;
use crate::film::{AccumParts, Developed, FrameAccum, Layout, Norm, RawSums, View};
use crate::util::fs::{create_registered, tmp_name};
use anyhow::{anyhow, bail, Context, Result};
use checkpoint::Counters;
use key::{Chunk, RunKey};
use serde::{Deserialize, Serialize};
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::ops::RangeInclusive;
use std::path::{Path, PathBuf};

const MAGIC: &[u8; 8] = b"RFSTATE1";
const RECORD_MAGIC: u32 = 0x4341_4652; // "RFAC"
/// Version 2: the trailer's counters keep reuse figures per frame only (version 1 also kept run
/// totals). Version 3: the trailer lists its records' CRC-32s (`Trailer::record_crcs`). Older
/// files are refused with a line that says so.
const VERSION: u32 = 3;

/// Whether `p` is a complete state file (a checkpoint or a chunk's partial, of any run): it
/// ends in the magic. Outputs that are not state files must not replace one (`--stats` naming
/// another chunk's finished partial would destroy it).
pub fn is_state_file(p: &Path) -> bool {
    let read = || -> std::io::Result<bool> {
        let Ok(mut f) = crate::util::fs::open_regular(p) else {
            return Ok(false);
        };
        let m = f.metadata()?;
        if m.len() < MAGIC.len() as u64 {
            return Ok(false);
        }
        f.seek(SeekFrom::End(-(MAGIC.len() as i64)))?;
        let mut tail = [0u8; 8];
        f.read_exact(&mut tail)?;
        Ok(&tail == MAGIC)
    };
    read().unwrap_or(false)
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
    /// A chunk's checkpoint: each of those records' CRC-32 (its last four bytes), which ties
    /// the log to this run: another run's log of the same frames and sizes read back whole
    /// and was merged (absent in older files: not checked).
    #[serde(default)]
    pub log_crcs: Vec<u32>,
    /// Where this file's own records start (a checkpoint: the frames in flight; a partial: every
    /// frame the chunk touched).
    pub records: Vec<(u32, u64)>,
    /// Each of those records' CRC-32 (its last four bytes), in `records`' order: ties the
    /// records to this trailer (another run's records of the same frames and sizes, each whole,
    /// spliced under a trailer, were merged).
    pub record_crcs: Vec<u32>,
    pub progress: Counters,
    /// The output pattern and EXR precision the frames are (to be) written with.
    pub out: String,
    pub exr_float: bool,
    /// The scene's files (canonical paths, those in UTF-8): a merge, which has no scene to ask,
    /// must not write a frame over one (absent in older files: nothing to check).
    #[serde(default)]
    pub inputs: Vec<String>,
    /// A checkpoint of a render that writes frames: each finished frame and the FNV-1a hash of
    /// its file's bytes as written (`Sink::sync`), so that a resume finds another file
    /// in its place in any format, one that keeps no metadata too (absent in older files: not
    /// checked).
    #[serde(default)]
    pub frame_digests: Vec<(u32, u64)>,
    /// A checkpoint: whether a run of this render made its folder, so that the run that
    /// completes it removes the folder, and a folder you made for it is kept, also when a
    /// resume completes the render (absent in older files and in partials: taken as made by
    /// a run, as before).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dir_made: Option<bool>,
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
            log_crcs: vec![],
            frame_digests: vec![],
            records: vec![],
            record_crcs: vec![],
            progress: Counters::default(),
            out,
            exr_float,
            inputs: vec![],
            dir_made: None,
        }
    }
}

/// One frame's record: an accumulator in flight or a chunk's share of one, or finished pixels.
pub enum Record {
    Sums(Box<FrameAccum>),
    Pixels(Developed),
}

impl Record {
    pub fn frame(&self) -> u32 {
        match self {
            Record::Sums(a) => a.frame(),
            Record::Pixels(d) => d.view.frame,
        }
    }
}

/// The fixed part of a record, before its per-pixel arrays.
struct Header {
    view: View,
    /// Groups that contributed, by the parity of their first frame.
    groups: [u32; 2],
    /// 0: sums, 1: finished pixels.
    kind: u8,
    landed: bool,
    loss: bool,
    /// The control variate's two folds and weight sums.
    folds: bool,
    unit: f32,
    /// Landed, tried and lost over the frame.
    counts: [u64; 3],
    seconds: f64,
}

/// Bytes of a record's fixed part, and of the CRC-32 that ends every record.
const HEADER_BYTES: u64 = 4 * 5 + 4 + 4 + 4 + 24 + 8 + 128;
const CRC_BYTES: u64 = 4;
/// The largest state file opened (1 TiB): state files are as large as the frames they hold, so
/// the cap only keeps what cannot be one out; each record is checked against its span anyway.
const MAX_STATE_BYTES: u64 = 1 << 40;

impl Header {
    fn write(&self, w: &mut impl Write) -> std::io::Result<()> {
        let v = &self.view;
        let total = self.groups[0] + self.groups[1];
        for x in [RECORD_MAGIC, v.frame, v.width, v.height, total] {
            w.write_all(&x.to_le_bytes())?;
        }
        let flags = [
            self.kind,
            self.landed as u8,
            self.loss as u8,
            self.folds as u8,
        ];
        w.write_all(&flags)?;
        w.write_all(&self.unit.to_le_bytes())?;
        w.write_all(&self.groups[1].to_le_bytes())?;
        for x in self.counts {
            w.write_all(&x.to_le_bytes())?;
        }
        w.write_all(&self.seconds.to_le_bytes())?;
        for m in v.world_to_camera.iter().chain(&v.world_to_ndc) {
            w.write_all(&m.to_le_bytes())?;
        }
        Ok(())
    }

    fn read(r: &mut impl Read) -> std::io::Result<Header> {
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
        let odd = u32_(r)?;
        if odd > groups {
            return Err(bad("more odd groups than groups"));
        }
        let mut b8 = [0u8; 8];
        let mut u64_ = |r: &mut dyn Read| -> std::io::Result<u64> {
            r.read_exact(&mut b8)?;
            Ok(u64::from_le_bytes(b8))
        };
        let counts = [u64_(r)?, u64_(r)?, u64_(r)?];
        let seconds = f64::from_bits(u64_(r)?);
        let mut mats = [0f32; 32];
        for m in &mut mats {
            *m = f32::from_bits(u32_(r)?);
        }
        let p = width as usize * height as usize;
        if p == 0 || p > 1 << 28 {
            return Err(bad("implausible frame size"));
        }
        // Written into the frame's metadata as they are: a header forged with its checksum
        // (seconds NaN, -5 or 1e300; a matrix of NaN) would have carried into the EXR.
        if !(seconds.is_finite() && (0.0..1e12).contains(&seconds)) {
            return Err(bad("implausible seconds of rendering"));
        }
        if !mats.iter().all(|m| m.is_finite()) {
            return Err(bad("a camera matrix that is not finite"));
        }
        if !camera_matrices_agree(&mats) {
            return Err(bad("camera matrices that no camera has"));
        }
        Ok(Header {
            view: View {
                frame,
                width,
                height,
                world_to_camera: mats[..16].try_into().unwrap(),
                world_to_ndc: mats[16..].try_into().unwrap(),
            },
            groups: [groups - odd, odd],
            kind: flags[0],
            landed: flags[1] != 0,
            loss: flags[2] != 0,
            folds: flags[3] != 0,
            unit,
            counts,
            seconds,
        })
    }
}

/// Whether a record's world-to-camera and world-to-NDC matrices (column-major, as
/// `Camera::world_to_camera` and `Camera::world_to_ndc` write them, one after the other) are a
/// camera's: the first a rotation (orthonormal rows) and a translation, the second the first's
/// rows under `Camera::world_to_ndc`'s projection, `x_ndc = k_x x_c + z_c / 2`,
/// `y_ndc = k_y y_c + z_c / 2` with `k_x > 0 > k_y`, and `z_c` twice. They go into the frame's
/// metadata as they are, and `merge` has no scene to compare them with: a matrix element forged
/// with its record's checksum was written out.
fn camera_matrices_agree(mats: &[f32; 32]) -> bool {
    // Row `r` of a column-major 4x4 matrix, in f64.
    let row = |m: &[f32], r: usize| -> [f64; 4] { std::array::from_fn(|c| m[4 * c + r] as f64) };
    let (c, n) = (&mats[..16], &mats[16..]);
    let rows: [[f64; 4]; 4] = std::array::from_fn(|r| row(c, r));
    if rows[3] != [0.0, 0.0, 0.0, 1.0] {
        return false;
    }
    let dot3 = |a: &[f64; 4], b: &[f64; 4]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    for i in 0..3 {
        for j in 0..3 {
            let want = if i == j { 1.0 } else { 0.0 };
            if (dot3(&rows[i], &rows[j]) - want).abs() > 1e-4 {
                return false;
            }
        }
    }
    // Within the rounding of f32 sums of products of the size `scale` (10^-5 of it: a few
    // hundred units in the last place).
    let close = |a: f64, b: f64, scale: f64| (a - b).abs() <= 1e-5 * (1.0 + scale);
    let z = rows[2];
    let size = z.iter().fold(0f64, |m, v| m.max(v.abs()));
    for r in [2, 3] {
        let nr = row(n, r);
        if !(0..4).all(|k| close(nr[k], z[k], size)) {
            return false;
        }
    }
    // Rows 0 and 1 less `z_c / 2`, over the camera's rows: one factor for all four columns.
    for (r, sign) in [(0, 1.0), (1, -1.0)] {
        let nr = row(n, r);
        let d: [f64; 4] = std::array::from_fn(|k| nr[k] - 0.5 * z[k]);
        let k = dot3(&d, &rows[r]);
        // Each element against the size of the terms it was summed from, and of the camera's
        // own element: `k`, found from the rounded rotation columns, is off by about 10^-8
        // whatever its size, which the translation multiplies (a fov of 170 degrees on a film
        // 4000 wide, `k` 2e-3, with the eye 4e4 along the camera's right: a real camera's
        // chunk was refused).
        let agrees = |i: usize| {
            let scale = nr[i]
                .abs()
                .max(0.5 * z[i].abs())
                .max((k * rows[r][i]).abs())
                .max(rows[r][i].abs());
            close(d[i], k * rows[r][i], scale)
        };
        if k * sign <= 0.0 || !(0..4).all(agrees) {
            return false;
        }
    }
    true
}

fn bad(what: &str) -> std::io::Error {
    std::io::Error::new(std::io::ErrorKind::InvalidData, what.to_string())
}

fn write_u32s(w: &mut impl Write, v: impl Iterator<Item = u32>) -> std::io::Result<()> {
    for x in v {
        w.write_all(&x.to_le_bytes())?;
    }
    Ok(())
}

fn read_u32s(r: &mut impl Read, n: usize) -> std::io::Result<Vec<u32>> {
    let mut bytes = vec![0u8; 4 * n];
    r.read_exact(&mut bytes)?;
    Ok(bytes
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
        .collect())
}

/// Fixed-point cells, then the count of carries and the carries (cell, value in steps).
fn write_sums(s: &FixedSums, w: &mut impl Write) -> std::io::Result<()> {
    for c in s.cells() {
        w.write_all(&c.to_le_bytes())?;
    }
    let carry = s.carries();
    w.write_all(&(carry.len() as u64).to_le_bytes())?;
    for (i, c) in carry {
        w.write_all(&i.to_le_bytes())?;
        w.write_all(&c.to_le_bytes())?;
    }
    Ok(())
}

/// `n` fixed-point cells and their carries, as `write_sums` wrote them.
fn read_sums(r: &mut impl Read, n: usize) -> std::io::Result<RawSums> {
    let cells: Vec<i32> = read_u32s(r, n)?.into_iter().map(|c| c as i32).collect();
    let mut b8 = [0u8; 8];
    let mut u64_ = |r: &mut dyn Read| -> std::io::Result<u64> {
        r.read_exact(&mut b8)?;
        Ok(u64::from_le_bytes(b8))
    };
    let k = u64_(r)? as usize;
    if k > n {
        return Err(bad("implausible carry table"));
    }
    let mut carry = Vec::with_capacity(k);
    for _ in 0..k {
        let i = u64_(r)?;
        let c = u64_(r)? as i64;
        if i as usize >= n {
            return Err(bad("carry outside the frame"));
        }
        // The writer lists each carried cell once, in order (`FixedSums::carries`).
        if carry.last().is_some_and(|&(j, _)| i <= j) {
            return Err(bad("carry table out of order or with a cell twice"));
        }
        carry.push((i, c));
    }
    // Every splat is at least zero (radiance, MIS weights), and rounds to at least zero
    // (`film::fixed::quantize` of v >= 0), so every exact sum a render writes is too: a
    // negative one is damage or forgery, which would develop into a pixel of -65504.
    let mut carried = carry.iter().peekable();
    for (i, &c) in cells.iter().enumerate() {
        let lift = carried
            .next_if(|&&(j, _)| j as usize == i)
            .map_or(0, |&(_, k)| k as i128);
        if c as i128 + lift < 0 {
            return Err(bad("a negative sum, which no render writes"));
        }
    }
    Ok((cells, carry))
}

/// A writer that checksums what passes through it (CRC-32, `crc32fast`).
struct CrcWriter<'w, W: Write> {
    inner: &'w mut W,
    crc: crc32fast::Hasher,
}

impl<W: Write> Write for CrcWriter<'_, W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.crc.update(&buf[..n]);
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// A reader that checksums what passes through it, and counts it.
struct CrcReader<'r, R: Read> {
    inner: &'r mut R,
    crc: crc32fast::Hasher,
    read: u64,
}

impl<R: Read> Read for CrcReader<'_, R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.crc.update(&buf[..n]);
        self.read += n as u64;
        Ok(n)
    }
}

/// Write a record's body with `body`, then its CRC-32.
fn checksummed<W: Write>(
    w: &mut W,
    body: impl FnOnce(&mut CrcWriter<W>) -> std::io::Result<()>,
) -> std::io::Result<u32> {
    let mut cw = CrcWriter {
        inner: w,
        crc: crc32fast::Hasher::new(),
    };
    body(&mut cw)?;
    let crc = cw.crc.finalize();
    w.write_all(&crc.to_le_bytes())?;
    Ok(crc)
}

/// Write an accumulator as a record, streamed from its cells (no copy of the frame); returns
/// its CRC-32.
pub fn write_accum(a: &FrameAccum, w: &mut impl Write) -> std::io::Result<u32> {
    checksummed(w, |w| write_accum_body(a, w))
}

fn write_accum_body(a: &FrameAccum, w: &mut impl Write) -> std::io::Result<()> {
    Header {
        view: a.view,
        groups: a.groups,
        kind: 0,
        landed: a.layout.landed,
        loss: a.layout.loss,
        folds: a.weight_sums().is_some(),
        unit: a.layout.unit,
        counts: a.counts(),
        seconds: a.clock.seconds(),
    }
    .write(w)?;
    write_sums(a.sums(), w)?;
    if let Some(ws) = a.weight_sums() {
        write_sums(ws, w)?;
    }
    if let Some(l) = a.landed_counts() {
        write_u32s(w, l)?;
    }
    if let Some((t, l)) = a.loss_counts() {
        write_u32s(w, t)?;
        write_u32s(w, l)?;
    }
    Ok(())
}

/// Write a finished frame (RGB only) as a record; returns its CRC-32.
pub fn write_pixels(d: &Developed, w: &mut impl Write) -> std::io::Result<u32> {
    checksummed(w, |w| write_pixels_body(d, w))
}

fn write_pixels_body(d: &Developed, w: &mut impl Write) -> std::io::Result<()> {
    Header {
        view: d.view,
        groups: [1, 0],
        kind: 1,
        landed: false,
        loss: false,
        folds: false,
        unit: 1.0,
        counts: [0; 3],
        seconds: d.seconds,
    }
    .write(w)?;
    let rgb = (0..d.view.pixels()).flat_map(|i| d.rgb(i).to_array());
    write_u32s(w, rgb.map(f32::to_bits))
}

/// Bytes of an accumulator's record.
pub fn accum_bytes(a: &FrameAccum) -> u64 {
    let p = a.view.pixels() as u64;
    let sums = |s: &FixedSums| 4 * s.len() as u64 + 8 + 16 * s.carries().len() as u64;
    HEADER_BYTES
        + CRC_BYTES
        + sums(a.sums())
        + a.weight_sums().map_or(0, sums)
        + if a.layout.landed { 4 * p } else { 0 }
        + if a.layout.loss { 8 * p } else { 0 }
}

/// Bytes of a finished frame's record.
pub fn pixels_bytes(d: &Developed) -> u64 {
    HEADER_BYTES + CRC_BYTES + 12 * d.view.pixels() as u64
}

/// Read one record of at most `max_len` bytes (what the file holds for it); its sums are
/// normalised as `norm` says (the method's, which the record does not carry). Its CRC-32 must
/// match, and nothing is allocated that the record's length does not hold.
pub fn read_record(r: &mut impl Read, norm: Norm, max_len: u64) -> std::io::Result<Record> {
    read_record_and_crc(r, norm, max_len).map(|(record, _)| record)
}

/// `read_record`, with the record's CRC-32.
fn read_record_and_crc(
    r: &mut impl Read,
    norm: Norm,
    max_len: u64,
) -> std::io::Result<(Record, u32)> {
    let mut cr = CrcReader {
        inner: r,
        crc: crc32fast::Hasher::new(),
        read: 0,
    };
    let record = read_record_body(&mut cr, norm, max_len)?;
    let crc = cr.crc.finalize();
    let mut b4 = [0u8; 4];
    cr.inner.read_exact(&mut b4)?;
    if u32::from_le_bytes(b4) != crc {
        return Err(bad("checksum mismatch (the record is damaged)"));
    }
    Ok((record, crc))
}

fn read_record_body(r: &mut impl Read, norm: Norm, max_len: u64) -> std::io::Result<Record> {
    let h = Header::read(r)?;
    let p = h.view.pixels();
    // The smallest record this header describes must fit in the bytes the file has for it.
    let per_pixel = match h.kind {
        0 => {
            let folds = if h.folds { 2 } else { 1 };
            12 * folds
                + if h.folds { 4 * folds } else { 0 }
                + if h.landed { 4 } else { 0 }
                + if h.loss { 8 } else { 0 }
        }
        _ => 12,
    };
    if HEADER_BYTES + CRC_BYTES + per_pixel * p as u64 > max_len {
        return Err(bad("longer than the file holds for it"));
    }
    // The reuse counters a resume or merge carries into `--stats` (a record forged with its
    // checksum reported a loss of 10^16 percent): as the trailer's (`check_trailer`).
    let [landed, tried, lost] = h.counts;
    if !possible_reuse_counts(landed, tried, lost) {
        return Err(bad("impossible reuse counters"));
    }
    match h.kind {
        0 => {
            let folds = if h.folds { 2 } else { 1 };
            let (cells, carry) = read_sums(r, 3 * folds * p)?;
            let weights = if h.folds {
                Some(read_sums(r, folds * p)?)
            } else {
                None
            };
            let landed = if h.landed {
                Some(read_u32s(r, p)?)
            } else {
                None
            };
            let loss = if h.loss {
                Some((read_u32s(r, p)?, read_u32s(r, p)?))
            } else {
                None
            };
            let layout = Layout {
                unit: h.unit,
                norm,
                landed: h.landed,
                loss: h.loss,
            };
            let parts = AccumParts {
                cells,
                carry,
                weights,
                landed,
                loss,
                totals: h.counts,
                groups: h.groups,
                seconds: h.seconds,
            };
            FrameAccum::from_parts(h.view, layout, parts)
                .map(|a| Record::Sums(Box::new(a)))
                .ok_or_else(|| bad("inconsistent accumulator"))
        }
        1 => {
            let rgb: Vec<f32> = read_u32s(r, 3 * p)?
                .into_iter()
                .map(f32::from_bits)
                .collect();
            // The independent tracer's pixels, means of finite samples of at least zero
            // (texels below zero are read as zero): a forged -1000 or NaN was merged as given.
            if rgb.iter().any(|v| !(*v >= 0.0 && v.is_finite())) {
                return Err(bad(
                    "a pixel below zero or not finite, which no render writes",
                ));
            }
            let px: Vec<glam::Vec3> = rgb
                .chunks_exact(3)
                .map(|c| glam::Vec3::new(c[0], c[1], c[2]))
                .collect();
            Ok(Record::Pixels(Developed::from_pixels(
                h.view, &px, h.seconds,
            )))
        }
        _ => Err(bad("unknown record kind")),
    }
}

/// A state file opened for reading: its trailer, and its records on demand.
pub struct StateFile {
    pub path: PathBuf,
    pub trailer: Trailer,
    file: BufReader<File>,
    /// Each record's frame, first byte and end, in file order: they tile the file up to the
    /// trailer, without gaps or overlaps.
    spans: Vec<(u32, u64, u64)>,
}

impl StateFile {
    /// Open a state file: the trailer must be whole (magic, length, CRC-32), of this version,
    /// and consistent with itself (units inside the run, the next unit inside the units,
    /// records of frames inside the run, each frame once, tiling the file). The records are
    /// checked as they are read (`record`).
    pub fn open(path: &Path) -> Result<StateFile> {
        let label = path.display();
        let mut f = crate::util::input::open_input(path, "state file", MAX_STATE_BYTES)?;
        let len = f.metadata()?.len();
        let incomplete = || {
            anyhow!(
                "{label}: not a complete reframe state file (truncated, or still being written)"
            )
        };
        if len < TAIL_BYTES {
            return Err(incomplete());
        }
        f.seek(SeekFrom::Start(len - TAIL_BYTES))?;
        let mut tail = [0u8; TAIL_BYTES as usize];
        f.read_exact(&mut tail)?;
        if &tail[12..] != MAGIC {
            return Err(incomplete());
        }
        let crc = u32::from_le_bytes(tail[..4].try_into().unwrap());
        let tlen = u64::from_le_bytes(tail[4..12].try_into().unwrap());
        if tlen > len - TAIL_BYTES {
            return Err(incomplete());
        }
        let trailer_start = len - TAIL_BYTES - tlen;
        f.seek(SeekFrom::Start(trailer_start))?;
        let mut json = vec![0u8; tlen as usize];
        f.read_exact(&mut json)?;
        if crc32fast::hash(&json) != crc {
            bail!("{label}: damaged state file (the trailer's checksum does not match)");
        }
        // The version first, so that an older file is refused as such, not as unreadable.
        #[derive(Deserialize)]
        struct Version {
            format: String,
            version: u32,
        }
        let v: Version = serde_json::from_slice(&json)
            .map_err(|e| anyhow!("{label}: unreadable trailer ({e})"))?;
        if v.format != "reframe-state" || v.version != VERSION {
            bail!(
                "{label}: state format {} version {}, but this build reads reframe-state version \
                 {VERSION}; finish it with the reframe that made it, or delete it and start over",
                v.format,
                v.version
            );
        }
        let trailer: Trailer = serde_json::from_slice(&json)
            .map_err(|e| anyhow!("{label}: unreadable trailer ({e})"))?;
        let spans = check_trailer(&trailer, trailer_start)
            .map_err(|why| anyhow!("{label}: damaged state file ({why})"))?;
        Ok(StateFile {
            path: path.to_path_buf(),
            trailer,
            file: BufReader::new(f),
            spans,
        })
    }

    /// The record that starts at `offset` (one of the trailer's), its sums normalised as `norm`
    /// says; refused unless it is whole, its checksum matches, it fills its span exactly, and
    /// it is the frame the trailer says at the run's resolution.
    pub fn record(&mut self, offset: u64, norm: Norm) -> Result<Record> {
        let label = self.path.display().to_string();
        let damaged = |why: String| anyhow!("{label}: damaged record at byte {offset} ({why})");
        let &(frame, start, end) = self
            .spans
            .iter()
            .find(|s| s.1 == offset)
            .ok_or_else(|| damaged("not a record the trailer lists".into()))?;
        self.file.seek(SeekFrom::Start(start))?;
        let mut counted = CrcReader {
            inner: &mut self.file,
            crc: crc32fast::Hasher::new(),
            read: 0,
        };
        let (r, crc) = read_record_and_crc(&mut counted, norm, end - start)
            .map_err(|e| damaged(e.to_string()))?;
        // (`check_trailer` has made sure there is one per record.)
        let listed = self.trailer.records.iter().position(|r| r.1 == offset);
        if listed.map(|k| self.trailer.record_crcs[k]) != Some(crc) {
            return Err(damaged(
                "its checksum is not the one the trailer lists: a record of another run".into(),
            ));
        }
        if counted.read != end - start {
            return Err(damaged(format!(
                "{} bytes where the trailer has {}",
                counted.read,
                end - start
            )));
        }
        let key = &self.trailer.key;
        let view = match &r {
            Record::Sums(a) => a.view,
            Record::Pixels(d) => d.view,
        };
        if view.frame != frame || (view.width, view.height) != (key.width, key.height) {
            return Err(damaged(format!(
                "frame {} at {}x{}, where the trailer has frame {frame} at {}x{}",
                view.frame, view.width, view.height, key.width, key.height
            )));
        }
        Ok(r)
    }
}

/// Reuse counters a render can have written: no more reuses lost than tried, and none past
/// 2^56 (a century of reuses at a billion a second).
fn possible_reuse_counts(landed: u64, tried: u64, lost: u64) -> bool {
    lost <= tried && landed.max(tried) < 1 << 56
}

/// The trailer's own consistency; the records' spans, in file order.
fn check_trailer(t: &Trailer, trailer_start: u64) -> Result<Vec<(u32, u64, u64)>, String> {
    let k = &t.key;
    if k.first_frame > k.last_frame || k.window == 0 || k.window > k.last_frame - k.first_frame + 1
    {
        return Err(format!(
            "frames {}-{} with window {}",
            k.first_frame, k.last_frame, k.window
        ));
    }
    let last_unit = k.last_frame + 1 - k.window;
    let [u0, u1] = t.units;
    if u0 > u1 || u0 < k.first_frame || u1 > last_unit {
        return Err(format!(
            "units {u0}-{u1} outside {}-{last_unit}",
            k.first_frame
        ));
    }
    if t.next_unit < u0 || t.next_unit > u1 + 1 {
        return Err(format!("next unit {} outside {u0}-{}", t.next_unit, u1 + 1));
    }
    if t.kind == Kind::Partial && t.records.is_empty() {
        return Err("a partial file without records".into());
    }
    // The counters a resume or a merge carries into its statistics: a trailer whose checksum
    // was recomputed over nonsense must not report negative seconds or wrap a sum.
    let p = &t.progress;
    if !(p.seconds.is_finite() && p.seconds >= 0.0) {
        return Err(format!("{} seconds of rendering", p.seconds));
    }
    // 2^56 rays would take a century at a billion rays a second.
    let c = &p.counts;
    if [
        c.primary,
        c.path,
        c.shadow,
        c.visibility,
        p.nonfinite_samples,
        p.nonfinite_pixels,
    ]
    .iter()
    .any(|&n| n >= 1 << 56)
    {
        return Err("a counter past 2^56".into());
    }
    let mut seen: Vec<u32> = Vec::with_capacity(p.per_frame.len());
    for f in &p.per_frame {
        if f.frame < k.first_frame || f.frame > k.last_frame {
            return Err(format!(
                "reuse figures of frame {}, outside the run",
                f.frame
            ));
        }
        let sane = f.mean_effective_spp.is_finite()
            && f.mean_effective_spp >= 0.0
            && (0.0..=1.0).contains(&f.lost_reuse_fraction)
            && possible_reuse_counts(f.landed, f.tried, f.lost);
        if !sane {
            return Err(format!("impossible reuse figures of frame {}", f.frame));
        }
        seen.push(f.frame);
    }
    seen.sort_unstable();
    if seen.windows(2).any(|w| w[0] == w[1]) {
        return Err("reuse figures of a frame given twice".into());
    }
    if t.record_crcs.len() != t.records.len() {
        return Err(format!(
            "{} record checksums for {} records",
            t.record_crcs.len(),
            t.records.len()
        ));
    }
    let mut spans: Vec<(u32, u64)> = t.records.clone();
    spans.sort_by_key(|s| s.1);
    let mut frames: Vec<u32> = spans.iter().map(|s| s.0).collect();
    frames.sort_unstable();
    if frames.windows(2).any(|w| w[0] == w[1]) {
        return Err("a frame recorded twice".into());
    }
    if let Some(f) = frames
        .iter()
        .find(|&&f| f < k.first_frame || f > k.last_frame)
    {
        return Err(format!("a record of frame {f}, outside the run"));
    }
    // Records tile the file from byte 0 to the trailer.
    let mut expected = 0;
    let mut out = Vec::with_capacity(spans.len());
    for (i, &(frame, start)) in spans.iter().enumerate() {
        if start != expected {
            return Err(format!(
                "record offsets leave a gap or overlap at byte {start}"
            ));
        }
        let end = spans.get(i + 1).map_or(trailer_start, |s| s.1);
        if end <= start {
            return Err(format!("record offsets overlap at byte {start}"));
        }
        out.push((frame, start, end));
        expected = end;
    }
    if expected != trailer_start {
        return Err("bytes between the records and the trailer".into());
    }
    Ok(out)
}

/// Write a state file atomically: records, trailer (with the records' offsets filled in), flush
/// to disk, rename. The records are streamed from the accumulators, one at a time.
pub fn write_state<'a>(
    path: &Path,
    trailer: &mut Trailer,
    records: impl IntoIterator<Item = &'a FrameAccum>,
) -> Result<()> {
    let tmp = tmp_name(path);
    let mut _live = None;
    let result = (|| -> Result<()> {
        let (registered, f) = create_registered(&tmp, |p| File::create(p))?;
        _live = Some(registered);
        let mut w = BufWriter::new(f);
        let mut offset = 0u64;
        trailer.records.clear();
        trailer.record_crcs.clear();
        for a in records {
            trailer.records.push((a.frame(), offset));
            trailer.record_crcs.push(write_accum(a, &mut w)?);
            offset += accum_bytes(a);
        }
        write_trailer(&mut w, trailer)?;
        let f = w.into_inner().map_err(|e| e.into_error())?;
        f.sync_all()?;
        Ok(())
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(e.context(format!("writing {}", path.display())));
    }
    std::fs::rename(&tmp, path)
        .with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))
}

fn write_trailer(w: &mut impl Write, t: &Trailer) -> std::io::Result<()> {
    let json = serde_json::to_vec(t).map_err(std::io::Error::other)?;
    w.write_all(&json)?;
    w.write_all(&crc32fast::hash(&json).to_le_bytes())?;
    w.write_all(&(json.len() as u64).to_le_bytes())?;
    w.write_all(MAGIC)
}

/// Bytes after the trailer's JSON: its CRC-32, its length, the magic.
const TAIL_BYTES: u64 = 4 + 8 + 8;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::film::fixed::FIXED;
    use glam::Vec3;

    fn view(frame: u32) -> View {
        View::of(frame, &camera(Vec3::new(0.3, 1.2, 4.0), 40.0, 3, 2))
    }

    fn camera(eye: Vec3, fov: f32, width: u32, height: u32) -> crate::camera::Camera {
        let pose = crate::camera::Pose {
            eye,
            view: Vec3::new(-0.1, -0.05, -1.0),
            up: Vec3::Y,
            fov,
        };
        crate::camera::Camera::from_pose(&pose, width, height)
    }

    #[test]
    fn every_cameras_matrices_agree_and_forged_ones_do_not() {
        use crate::sampling::mix64;
        let unit = |h: u64| (h >> 40) as f32 / (1u64 << 24) as f32;
        let agrees = |cam: &crate::camera::Camera| {
            let v = View::of(0, cam);
            let mut m = [0f32; 32];
            m[..16].copy_from_slice(&v.world_to_camera);
            m[16..].copy_from_slice(&v.world_to_ndc);
            camera_matrices_agree(&m)
        };
        // Wide fovs and films (a small `k_x`) with the eye far off along the camera's right,
        // where the projection's translation is least certain (a fov of 170 degrees, 4000 x 100
        // pixels, the eye 4e4 along the right: refused before).
        for i in 0..4000u64 {
            let h = |j: u64| unit(mix64(i * 16 + j + (1 << 40)));
            let view = Vec3::new(h(0) - 0.5, (h(1) - 0.5) * 0.4, h(2) - 0.5);
            let right = view.cross(Vec3::Y).normalize();
            let far = 10f32.powf(2.0 + h(3) * 6.0);
            let pose = crate::camera::Pose {
                eye: right * far + Vec3::new(h(4), h(5), h(6)) * far * 0.05,
                view,
                up: Vec3::Y,
                fov: [150.0, 170.0, 178.0, 179.9][i as usize % 4],
            };
            let films = [(4000, 100), (1920, 1080), (8192, 1024), (640, 480)];
            let (w, ht) = films[i as usize / 4 % 4];
            let cam = crate::camera::Camera::from_pose(&pose, w, ht);
            assert!(agrees(&cam), "{pose:?} {w}x{ht}");
        }
        for i in 0..20_000u64 {
            let h = |j: u64| unit(mix64(i * 16 + j));
            // Eyes near and very far from the origin, every direction, wide and narrow fovs,
            // films wide, tall and of one pixel.
            let far = 10f32.powf(h(0) * 12.0 - 4.0);
            let pose = crate::camera::Pose {
                eye: (Vec3::new(h(1), h(2), h(3)) - 0.5) * far,
                view: Vec3::new(h(4), h(5), h(6)) - 0.5,
                up: Vec3::new(h(7), h(8), h(9)) - 0.5,
                fov: 0.001 + h(10) * 179.99,
            };
            let (w, ht) = (1 + (h(11) * 4000.0) as u32, 1 + (h(12) * 4000.0) as u32);
            let cam = crate::camera::Camera::from_pose(&pose, w, ht);
            if !cam.forward.is_finite() || !cam.right.is_finite() {
                continue; // a pose the scene loader refuses
            }
            let v = View::of(0, &cam);
            let mut m = [0f32; 32];
            m[..16].copy_from_slice(&v.world_to_camera);
            m[16..].copy_from_slice(&v.world_to_ndc);
            assert!(camera_matrices_agree(&m), "{pose:?} {w}x{ht}");
            // Any one element set to 3e38; one of the rotation or projection changed by 1%, or
            // its sign flipped where it is not zero: no camera's. (Any translation is some
            // camera's: the projection's copy of it, scaled by `k_x`, which a wide film or a
            // fov near 180 degrees makes tiny, is all it is checked against.)
            let k = (mix64(i) % 32) as usize;
            let translation = matches!(k, 12..=14 | 28..=31);
            for new in [m[k] * 1.01 + 0.01, 3e38, -m[k]] {
                if translation && new != 3e38 {
                    continue;
                }
                if new == m[k] || m[k] == 0.0 && new == 0.0 {
                    continue;
                }
                let mut f = m;
                f[k] = new;
                // (A change within 10^-3 of the matrices' largest entries may pass: the
                // projection scales a translation by `k_x`, which a wide film makes small, and
                // the check allows for the rounding of the rest.)
                let size = m.iter().fold(1f32, |a, v| a.max(v.abs()));
                let tiny = (new - m[k]).abs() < 1e-3 * size;
                assert!(
                    tiny || !camera_matrices_agree(&f),
                    "{pose:?}: [{k}] = {new}"
                );
            }
        }
    }

    const LAYOUT: Layout = Layout {
        unit: 7.0,
        norm: Norm::Count,
        landed: true,
        loss: true,
    };

    fn accum(frame: u32) -> FrameAccum {
        let p = 6;
        FrameAccum::from_parts(
            view(frame),
            LAYOUT,
            AccumParts {
                // Cell 17 wrapped below zero, and its carry lifts it back.
                cells: (0..3 * p as i32)
                    .map(|i| if i == 17 { -5 } else { i * 1000 + 5 })
                    .collect(),
                carry: vec![(4, 1 << 32), (17, 1 << 33)],
                weights: None,
                landed: Some(vec![3; p]),
                loss: Some((vec![2; p], vec![1; p])),
                totals: [18, 12, 6],
                groups: [1, 1],
                seconds: 1.5,
            },
        )
        .unwrap()
    }

    fn pixels(frame: u32) -> Developed {
        let px: Vec<glam::Vec3> = (0..6).map(|i| glam::Vec3::splat(i as f32 * 0.25)).collect();
        Developed::from_pixels(view(frame), &px, 1.5)
    }

    fn bytes_of(r: &Record) -> Vec<u8> {
        let mut b = Vec::new();
        let crc = match r {
            Record::Sums(a) => write_accum(a, &mut b).unwrap(),
            Record::Pixels(d) => write_pixels(d, &mut b).unwrap(),
        };
        assert_eq!(
            crc.to_le_bytes(),
            b[b.len() - 4..],
            "the CRC-32 returned is the one written"
        );
        b
    }

    #[test]
    fn records_round_trip_and_report_their_size() {
        for r in [Record::Sums(Box::new(accum(4))), Record::Pixels(pixels(4))] {
            let bytes = bytes_of(&r);
            let size = match &r {
                Record::Sums(a) => accum_bytes(a),
                Record::Pixels(d) => pixels_bytes(d),
            };
            assert_eq!(bytes.len() as u64, size);
            let len = bytes.len() as u64;
            let back = read_record(&mut bytes.as_slice(), Norm::Count, len).unwrap();
            // Written again, the record read back gives the same bytes (the seconds aside,
            // which keep running).
            let again = bytes_of(&back);
            // (and the checksum, which covers them).
            let n = bytes.len();
            assert_eq!(again[..56], bytes[..56]);
            assert_eq!(again[64..n - 4], bytes[64..n - 4]);
            // Any truncation is an error, never a panic or a short record.
            for cut in [0, 3, 40, bytes.len() - 1] {
                assert!(read_record(&mut &bytes[..cut], Norm::Count, len).is_err());
            }
            // Any flipped bit is caught by the checksum (or the header's checks), and a record
            // longer than its span is refused before anything is allocated for it.
            for i in (0..bytes.len()).step_by(7) {
                let mut b = bytes.clone();
                b[i] ^= 0x10;
                assert!(
                    read_record(&mut b.as_slice(), Norm::Count, len).is_err(),
                    "byte {i}"
                );
            }
            assert!(read_record(&mut bytes.as_slice(), Norm::Count, len - 100).is_err());
        }
    }

    #[test]
    fn forged_sums_with_a_valid_checksum_are_refused() {
        let bytes = bytes_of(&Record::Sums(Box::new(accum(2))));
        let len = bytes.len() as u64;
        let cells = HEADER_BYTES as usize;
        let table = cells + 18 * 4 + 8;
        // Each forgery rewrites bytes and then the record's CRC-32, as a forger would.
        let forge = |edits: &[(usize, Vec<u8>)]| {
            let mut b = bytes.clone();
            for (at, new) in edits {
                b[*at..at + new.len()].copy_from_slice(new);
            }
            let n = b.len() - 4;
            let crc = crc32fast::hash(&b[..n]);
            b[n..].copy_from_slice(&crc.to_le_bytes());
            read_record(&mut b.as_slice(), Norm::Count, len)
        };
        assert!(forge(&[]).is_ok());
        type Edits = Vec<(usize, Vec<u8>)>;
        let cases: [(&str, Edits); 6] = [
            // The header's reuse counters (landed, tried, lost at bytes 32, 40, 48): more lost
            // than tried (a loss of 10^16 percent in `--stats`), and one past 2^56.
            (
                "impossible reuse counters",
                vec![(48, u64::MAX.to_le_bytes().to_vec())],
            ),
            (
                "impossible reuse counters",
                vec![(32, (1u64 << 60).to_le_bytes().to_vec())],
            ),
            // Cell 0 below zero, with no carry.
            (
                "negative sum",
                vec![(cells, (-5i32).to_le_bytes().to_vec())],
            ),
            // Cell 17's carry turned negative: -5 - 2^33.
            (
                "negative sum",
                vec![(table + 24, (-(1i64 << 33)).to_le_bytes().to_vec())],
            ),
            // Cell 4's carry listed twice (the second in place of cell 17's).
            ("twice", vec![(table + 16, 4u64.to_le_bytes().to_vec())]),
            // The two carries in the wrong order.
            (
                "out of order",
                vec![
                    (table, 17u64.to_le_bytes().to_vec()),
                    (table + 16, 4u64.to_le_bytes().to_vec()),
                ],
            ),
        ];
        for (want, edits) in cases {
            let Err(err) = forge(&edits) else {
                panic!("{want}: accepted");
            };
            let err = err.to_string();
            assert!(err.contains(want), "{want}: {err}");
        }
        // A finished frame's pixel below zero or not finite (merged as given before).
        let bytes = bytes_of(&Record::Pixels(pixels(2)));
        let at = HEADER_BYTES as usize + 4;
        for v in [-1000.0f32, f32::NAN, f32::INFINITY, -1e-30] {
            let mut b = bytes.clone();
            b[at..at + 4].copy_from_slice(&v.to_le_bytes());
            let n = b.len() - 4;
            let crc = crc32fast::hash(&b[..n]);
            b[n..].copy_from_slice(&crc.to_le_bytes());
            let err = read_record(&mut b.as_slice(), Norm::Count, b.len() as u64)
                .err()
                .unwrap_or_else(|| panic!("a pixel of {v} accepted"))
                .to_string();
            assert!(
                err.contains("a pixel below zero or not finite"),
                "{v}: {err}"
            );
        }
    }

    #[test]
    fn absorbing_adds_the_exact_sums() {
        let (mut a, b) = (accum(1), accum(1));
        a.absorb(&b).unwrap();
        let t = a.sums().totals();
        assert_eq!(
            t,
            b.sums().totals().iter().map(|v| 2 * v).collect::<Vec<_>>()
        );
        assert_eq!(t[4], 2 * (4005 + (1 << 32)));
        assert_eq!(t[17], 2 * ((1 << 33) - 5));
        assert_eq!(a.groups, [2, 2]);
        assert_eq!(a.landed_counts().unwrap().next(), Some(6));
        assert_eq!(a.counts(), [36, 24, 12]);
        // Developed by count: pixel 0's red is 2 * 5 steps, times the unit, over 6 landed.
        let d = crate::film::develop(&a, None);
        assert_eq!(d.data[0], (10.0 / FIXED) as f32 * 7.0 / 6.0);
        let other = FrameAccum::new(
            view(1),
            Layout {
                loss: false,
                ..LAYOUT
            },
        );
        assert!(a.absorb(&other).is_err());
    }

    #[test]
    fn forged_counters_are_refused() {
        use crate::film::FrameReuse;
        // A trailer whose checksum is right but whose counters cannot be: each refused by
        // `check_trailer` (what `StateFile::open` runs), the untouched one accepted.
        let key = RunKey {
            first_frame: 0,
            last_frame: 9,
            window: 3,
            ..RunKey::default()
        };
        let mut t = Trailer::new(key, None, &(0..=7), "o_####.exr".into(), false);
        t.next_unit = 3;
        t.progress.seconds = 12.5;
        t.progress.per_frame = (0..3)
            .map(|frame| FrameReuse {
                frame,
                mean_effective_spp: 3.0,
                lost_reuse_fraction: 0.25,
                landed: 30,
                tried: 8,
                lost: 2,
            })
            .collect();
        assert!(check_trailer(&t, 0).is_ok());
        type Forge = fn(&mut Trailer);
        let forged: [(&str, Forge); 8] = [
            ("seconds", |t| t.progress.seconds = -5.0),
            ("seconds", |t| t.progress.seconds = f64::NAN),
            ("2^56", |t| t.progress.counts.primary = u64::MAX),
            ("outside the run", |t| t.progress.per_frame[1].frame = 99),
            ("given twice", |t| t.progress.per_frame[2].frame = 0),
            ("impossible", |t| t.progress.per_frame[0].lost = 9),
            ("impossible", |t| {
                t.progress.per_frame[0].lost_reuse_fraction = 1.5
            }),
            ("impossible", |t| {
                t.progress.per_frame[0].mean_effective_spp = f64::INFINITY
            }),
        ];
        for (want, forge) in forged {
            let mut f = t.clone();
            forge(&mut f);
            let err = check_trailer(&f, 0).unwrap_err();
            assert!(err.contains(want), "{want}: {err}");
        }
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
            primary: "packet".into(),
            paths: "packet".into(),
            aov: false,
            adaptive: 0.0,
            exr_float: false,
            radiance_unit: 1.0,
            denoise: "off".into(),
        };
        let mut t = Trailer::new(key.clone(), None, &(0..=7), "o_####.exr".into(), false);
        t.next_unit = 3;
        let recs = [accum(3), accum(4)];
        write_state(&p, &mut t, &recs).unwrap();
        let mut sf = StateFile::open(&p).unwrap();
        assert_eq!(sf.trailer.next_unit, 3);
        let offs = sf.trailer.records.clone();
        let Record::Sums(back) = sf.record(offs[1].1, Norm::Count).unwrap() else {
            panic!("not sums")
        };
        assert_eq!(back.frame(), 4);
        assert_eq!(back.sums().totals(), recs[1].sums().totals());
        let bytes = std::fs::read(&p).unwrap();
        std::fs::write(&p, &bytes[..bytes.len() - 1]).unwrap();
        let err = StateFile::open(&p).err().unwrap().to_string();
        assert!(err.contains("not a complete"), "{err}");
        let mut other = key.clone();
        other.spp = 2;
        assert_eq!(key.difference(&other).unwrap(), "spp: 1 vs 2");
        // Text without JSON's quotes, and the scene's hash said for what it is.
        let other = RunKey {
            primary: "single".into(),
            ..key.clone()
        };
        assert_eq!(
            key.difference(&other).unwrap(),
            format!("primary: {} vs single", key.primary)
        );
        let other = RunKey {
            scene_hash: "5fb8".into(),
            ..key.clone()
        };
        assert!(key
            .difference(&other)
            .unwrap()
            .starts_with("the scene's files differ: content hash "));
    }
}
