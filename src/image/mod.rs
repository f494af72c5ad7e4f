//! Image files: reframe's rendered frames go out through OpenImageIO, and reference images come
//! back in through it. Output names come from a frame-number pattern that is checked before any
//! rendering starts, files are written atomically (a crash never leaves a half-written frame
//! under the real name), EXR keeps every channel plus the render's metadata, and 8-bit formats get
//! sRGB-encoded, deterministically dithered RGB.
//!
//! ```no_run
//! use reframe::image::{write_image, Image, Metadata, OutputPattern, WriteOptions};
//!
//! let pattern = OutputPattern::parse("out/vase_####.exr")?;
//! pattern.validate()?; // fail now, not after an hour of rendering
//! let img = Image::new(640, 360, &["R", "G", "B"]);
//! let meta = Metadata { method: "reuse".into(), spp: 64, ..Metadata::default() };
//! write_image(&pattern.path(7), &img, &meta, &WriteOptions::default())?; // out/vase_0007.exr
//! # Ok::<(), anyhow::Error>(())
//! ```

mod bridge;
pub mod oidn;
mod texture;
pub use texture::{TextureId, Textures, MAX_TEXELS};

use std::fmt;
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Result};
use rayon::prelude::*;

use crate::util::fs::{check_writable_dir, parent_dir, unique, CreatedDirs};
use bridge::ffi;

/// A float image, interleaved channels, row-major, top row first.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub channels: Vec<String>,
    pub data: Vec<f32>,
}

impl Image {
    /// A black image with the given channel names.
    pub fn new(width: u32, height: u32, channels: &[&str]) -> Self {
        let n = width as usize * height as usize * channels.len();
        Image {
            width,
            height,
            channels: channels.iter().map(|c| c.to_string()).collect(),
            data: vec![0.0; n],
        }
    }

    pub fn channel_index(&self, name: &str) -> Option<usize> {
        self.channels.iter().position(|c| c == name)
    }

    /// The `channels.len()` values of pixel (x, y); panics outside the image.
    pub fn pixel(&self, x: u32, y: u32) -> &[f32] {
        let nch = self.channels.len();
        let i = (y as usize * self.width as usize + x as usize) * nch;
        &self.data[i..i + nch]
    }

    fn check(&self) -> Result<()> {
        if self.width == 0 || self.height == 0 || self.channels.is_empty() {
            bail!(
                "image is empty ({}x{}, {} channels)",
                self.width,
                self.height,
                self.channels.len()
            );
        }
        let expected = self.width as usize * self.height as usize * self.channels.len();
        if self.data.len() != expected {
            bail!(
                "image data holds {} values, but {}x{} with {} channels needs {expected}",
                self.data.len(),
                self.width,
                self.height,
                self.channels.len()
            );
        }
        Ok(())
    }
}

/// What a frame file records about how it was made.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Metadata {
    pub method: String,
    pub spp: u32,
    pub window: u32,
    pub seed: u64,
    pub render_seconds: f64,
    /// Imath/EXR layout (row-vector convention), written as EXR `worldToCamera`.
    pub world_to_camera: [f32; 16],
    /// Written as the standard EXR `worldToNDC`.
    pub world_to_ndc: [f32; 16],
    /// More string attributes, written as `"reframe:<key>"`.
    pub extra: Vec<(String, String)>,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WriteOptions {
    /// EXR pixels are half by default (plenty for final frames, at half the disk space);
    /// float when true.
    pub exr_float: bool,
}

/// Spec attribute names that OIIO's EXR writer translates into the standard EXR header
/// attributes `worldToCamera` / `worldToNDC` (m44f). Not "worldtoscreen": that one becomes EXR
/// `worldToScreen`. The TIFF writer stores `worldtocamera` (as a Pixar tag) and drops the other.
const OIIO_WORLD_TO_CAMERA: &str = "worldtocamera";
const OIIO_WORLD_TO_NDC: &str = "worldtoNDC";
/// The names as they appear in the EXR header; OIIO's EXR reader reports these, and so does
/// `read_metadata` whatever the format.
pub const EXR_WORLD_TO_CAMERA: &str = "worldToCamera";
const EXR_WORLD_TO_NDC: &str = "worldToNDC";

const PREFIX: &str = "reframe:";
const BUILTIN_KEYS: [&str; 5] = ["method", "spp", "window", "seed", "render_seconds"];

/// Largest finite half; larger values would become infinity in a half EXR.
const HALF_MAX: f32 = 65504.0;
/// Half float's smallest normal number, 2^-14: below it a value keeps fewer digits.
const HALF_MIN_NORMAL: f32 = 6.103_515_6e-5;

/// Whether the clamp to `HALF_MAX` has been said (once a process).
static HALF_CLAMP_SAID: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
/// The frames written so far whose values were clamped to half's largest (`half_clamped`).
static HALF_CLAMPED: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

/// How many frames this process wrote with values clamped to 65504 (the first is named when it
/// is written; the command's summary says how many in all).
pub fn half_clamped() -> u64 {
    HALF_CLAMPED.load(std::sync::atomic::Ordering::Relaxed)
}
/// Whether the warning of values below half's normal range was given (once a process).
static HALF_SMALL_SAID: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// How a file extension is written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum FileKind {
    /// All channels, half or float, with all metadata.
    Exr,
    /// Float formats that only hold RGB (Radiance HDR, PFM).
    FloatRgb,
    /// Radiance HDR (RGBE): RGB with a shared exponent, rounded before the writer truncates.
    Rgbe,
    /// Everything else: 8-bit sRGB RGB.
    Ldr,
}

impl FileKind {
    fn of(path: &Path) -> Result<Self> {
        let ext = path.extension().and_then(|e| e.to_str()).ok_or_else(|| {
            anyhow!(
                "{} has no file extension to pick a format by",
                path.display()
            )
        })?;
        Ok(match ext.to_ascii_lowercase().as_str() {
            "exr" | "sxr" | "mxr" => FileKind::Exr,
            "hdr" | "rgbe" => FileKind::Rgbe,
            "pfm" => FileKind::FloatRgb,
            _ => FileKind::Ldr,
        })
    }
}

/// Output path pattern, e.g. "out/vase_####.exr": a run of '#' in the file name is the
/// zero-padded frame number, and the extension picks the format.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OutputPattern {
    original: String,
    prefix: String,
    digits: usize,
    suffix: String,
}

impl OutputPattern {
    pub fn parse(s: &str) -> Result<Self> {
        if s.trim().is_empty() {
            bail!("output path is empty");
        }
        if s.ends_with('/') || s.ends_with(std::path::MAIN_SEPARATOR) {
            bail!("output path {s:?} names a folder; add a file name such as frame_####.exr");
        }
        let name_start = s
            .rfind(['/', std::path::MAIN_SEPARATOR])
            .map_or(0, |i| i + 1);
        let runs: Vec<(usize, usize)> = hash_runs(s);
        if runs.len() > 1 {
            bail!("output path {s:?} has more than one run of '#'; use one for the frame number");
        }
        if let Some(&(start, _)) = runs.first() {
            if start < name_start {
                bail!(
                    "output path {s:?} has '#' in a folder name; the frame number belongs in \
                     the file name"
                );
            }
        }
        let ext = Path::new(s)
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("");
        if ext.is_empty() {
            bail!(
                "output path {s:?} has no file extension; the extension picks the format \
                 (e.g. .exr, .png)"
            );
        }
        if ext.contains('#') {
            bail!("output path {s:?}: the frame number must come before the extension");
        }
        let (prefix, digits, suffix) = match runs.first() {
            Some(&(start, end)) => (&s[..start], end - start, &s[end..]),
            None => (s, 0, ""),
        };
        Ok(OutputPattern {
            original: s.to_string(),
            prefix: prefix.to_string(),
            digits,
            suffix: suffix.to_string(),
        })
    }

    /// Whether the pattern has a '#' run. Without one every frame gets the same name, which only
    /// makes sense for a single-frame render; the caller knows whether that is the case.
    pub fn has_frame_field(&self) -> bool {
        self.digits > 0
    }

    /// The file name for `frame`: "####" with frame 7 gives "0007"; numbers wider than the run
    /// keep all their digits.
    pub fn path(&self, frame: u32) -> PathBuf {
        if self.digits == 0 {
            return PathBuf::from(&self.original);
        }
        let width = self.digits;
        PathBuf::from(format!("{}{frame:0width$}{}", self.prefix, self.suffix))
    }

    /// The frame whose file is named `name` (a file name, without its folder) under this
    /// pattern: the inverse of `path` on file names. `None` for a name it never writes, and
    /// for a pattern without a '#' run (every frame has its one name).
    pub fn frame_named(&self, name: &str) -> Option<u32> {
        if self.digits == 0 {
            return None;
        }
        let own = self
            .prefix
            .rfind(['/', std::path::MAIN_SEPARATOR])
            .map_or(&self.prefix[..], |i| &self.prefix[i + 1..]);
        let number = name.strip_prefix(own)?.strip_suffix(&self.suffix[..])?;
        if number.len() < self.digits || !number.bytes().all(|b| b.is_ascii_digit()) {
            return None;
        }
        // Wider than the run only without padding: "####" writes 12345, never 012345.
        if number.len() > self.digits && number.starts_with('0') {
            return None;
        }
        number.parse().ok()
    }

    /// Checks everything that could make a write fail later, so that it fails before any
    /// rendering: OIIO can write the format, the folder exists (it is created if need be) and a
    /// file can be created in it. The folders it created go again unless the caller keeps them.
    pub fn validate(&self) -> Result<CreatedDirs> {
        let target = self.path(0);
        ffi::check_output_format(path_bytes(&target))
            .map_err(|e| anyhow!("cannot write {}: {}", self.original, e.what()))?;
        // Netpbm's grey and bitmap names: OpenImageIO writes a colour frame into them as a
        // colour file (P6), which a reader that goes by the name takes for something else.
        let ext = target
            .extension()
            .map_or(String::new(), |e| e.to_string_lossy().to_ascii_lowercase());
        if matches!(ext.as_str(), "pgm" | "pbm") {
            bail!(
                "cannot write {}: a .{ext} file holds {} only, and frames are in colour (write \
                 .ppm, or .png)",
                self.original,
                if ext == "pgm" {
                    "grey"
                } else {
                    "black and white"
                }
            );
        }
        // A frame is written as `.NAME.tmp-PID-N.EXT` first (`write_image`), which must fit
        // the 255 bytes a file name may have on Linux's file systems, or the first frame fails
        // after its rendering (with an empty checkpoint folder left behind).
        let name = target.file_name().map_or(0, |n| n.len());
        let ext = target.extension().map_or(0, |e| e.len());
        let longest = name + ext + 40;
        if longest > 255 {
            bail!(
                "--out {}: a frame's file name of {name} bytes is too long: written first under a \
                 temporary name about {} bytes longer, it would pass the 255 bytes a file name \
                 may have",
                self.original,
                longest - name
            );
        }
        let dir = parent_dir(&target);
        let created = CreatedDirs::create(&dir)
            .map_err(|e| anyhow!("cannot create output folder {}: {e}", dir.display()))?;
        check_writable_dir(&dir)?;
        Ok(created)
    }

    /// Refuse, before rendering, frames of `width` x `height` that this format's writer would
    /// refuse at the first frame's write (`probe_output`): opened on a temporary file in the
    /// output folder (which `validate` has made), then removed. EXR holds any frame and is
    /// not probed.
    pub fn probe(&self, width: u32, height: u32) -> Result<()> {
        let target = self.path(0);
        let kind = FileKind::of(&target)?;
        if kind == FileKind::Exr {
            return Ok(());
        }
        let name = target
            .file_name()
            .map_or("frame".into(), |n| n.to_string_lossy());
        let ext = target
            .extension()
            .map_or("".into(), |e| e.to_string_lossy());
        // Formats whose size fields are narrower than a frame can be: libjpeg ends the process
        // on its own past 65500 (no error line, lock files left), and the TGA writer accepted
        // the probe and failed after the first frame had rendered. libheif reads no HEIF or
        // AVIF image past 32768 a side (its security limit): the probe said the disk may be
        // full.
        let lower = ext.to_ascii_lowercase();
        let most = match lower.as_str() {
            "jpg" | "jpeg" | "jpe" | "jfif" => Some(65_500),
            "tga" | "tpic" | "gif" => Some(65_535),
            "webp" => Some(16_383),
            "heic" | "heif" | "avif" | "avifs" | "hif" => Some(32_768),
            _ => None,
        };
        if let Some(m) = most.filter(|&m| width.max(height) > m) {
            bail!(
                "cannot write {}: a .{ext} file holds at most {m} pixels a side, and the frames \
                 are {width}x{height} (write EXR, PNG or TIFF)",
                self.original
            );
        }
        let probe = parent_dir(&target).join(format!(
            ".{name}.probe-{}-{}.{ext}",
            std::process::id(),
            unique()
        ));
        // Made empty here, where a stop by signal cannot miss it, and removed after (declared
        // later, dropped first): the writer that opens it may not (the formats frames are
        // written in are not probed).
        let _live = crate::util::fs::create_temporary(&probe)
            .map_err(|e| anyhow!("cannot write {}: {e}", self.original))?;
        let probe = TempFile {
            path: probe,
            keep: false,
        };
        let store_as = match kind {
            FileKind::Ldr => ffi::PixelType::U8,
            _ => ffi::PixelType::Float,
        };
        let desc = ffi::ImageDesc {
            width,
            height,
            channels: vec!["R".into(), "G".into(), "B".into()],
            store_as,
        };
        ffi::probe_output(path_bytes(&target), path_bytes(&probe.path), &desc)
            .map_err(|e| anyhow!("cannot write {}: {}", self.original, e.what()))
    }

    /// Whether frames are written as EXR (every channel, half or float).
    pub fn is_exr(&self) -> bool {
        matches!(FileKind::of(&self.path(0)), Ok(FileKind::Exr))
    }

    /// Whether frames are written as 8-bit sRGB (PNG, JPEG, TIFF, ...) rather than float.
    pub fn is_ldr(&self) -> bool {
        matches!(FileKind::of(&self.path(0)), Ok(FileKind::Ldr))
    }
}

impl fmt::Display for OutputPattern {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.original)
    }
}

/// Byte ranges of the runs of '#'.
fn hash_runs(s: &str) -> Vec<(usize, usize)> {
    let mut runs = Vec::new();
    let mut start = None;
    for (i, b) in s.bytes().enumerate() {
        match (b == b'#', start) {
            (true, None) => start = Some(i),
            (false, Some(st)) => {
                runs.push((st, i));
                start = None;
            }
            _ => {}
        }
    }
    if let Some(st) = start {
        runs.push((st, s.len()));
    }
    runs
}

/// A path as OpenImageIO is handed it: the file name's bytes, which on Unix need not be UTF-8
/// (a texture named in Latin-1 by an old asset).
pub(crate) fn path_bytes(path: &Path) -> &[u8] {
    use std::os::unix::ffi::OsStrExt;
    path.as_os_str().as_bytes()
}

/// Deletes the temporary file on every way out of `write_image` except success.
struct TempFile {
    path: PathBuf,
    keep: bool,
}

impl Drop for TempFile {
    fn drop(&mut self) {
        if !self.keep {
            // It may never have been created; there is nothing useful to do on failure.
            let _ = fs::remove_file(&self.path);
        }
    }
}

/// Writes `img` to `path` atomically: into a temporary file in the same folder, then renamed
/// over the target. On any error no file is left behind (and an existing target is untouched).
///
/// EXR gets all channels (half, or float with `opts.exr_float`) and all of `meta`. 8-bit
/// formats get the first three channels as R,G,B: clamped to \[0, 1\], sRGB-encoded and dithered
/// (see [`encode_srgb8`]). Radiance HDR and PFM get the first three channels as float.
/// Formats keep what metadata they can: PNG keeps the scalar values as text, TIFF keeps
/// `worldtocamera`, JPEG keeps none. PNG and JPEG bytes depend only on the inputs; TIFF and EXR
/// also carry the time of writing (OIIO adds `DateTime` / `capDate`).
pub fn write_image(path: &Path, img: &Image, meta: &Metadata, opts: &WriteOptions) -> Result<()> {
    write_image_hashed(path, img, meta, opts).map(|_| ())
}

/// `write_image`, returning the FNV-1a hash of the bytes written (`bytes_digest`): of the
/// encoded bytes in memory, or of the file where the writer wrote it itself, so that a caller
/// that keeps the hash (a checkpoint's `frame_digests`) does not read the file back.
pub fn write_image_hashed(
    path: &Path,
    img: &Image,
    meta: &Metadata,
    opts: &WriteOptions,
) -> Result<u64> {
    write_image_placing(path, img, meta, opts, &mut || {})
}

/// `write_image_hashed`, running `placed` as the file is renamed into place, both while a stop
/// by signal cannot come between them (`util::fs::holding_registry`): what `placed` records
/// (the stop note's count of frames written) is true of the files on disk whenever a stop
/// reads it.
pub fn write_image_placing(
    path: &Path,
    img: &Image,
    meta: &Metadata,
    opts: &WriteOptions,
    placed: &mut dyn FnMut(),
) -> Result<u64> {
    write_image_inner(path, img, meta, opts, placed)
        .map_err(|e| anyhow!("cannot write {}: {e}", path.display()))
}

/// The FNV-1a hash of `bytes`: a frame file's identity in a checkpoint (`frame_digests`).
pub fn bytes_digest(bytes: &[u8]) -> u64 {
    let mut h = crate::util::hash::Fnv::default();
    h.bytes(bytes);
    h.0
}

fn write_image_inner(
    path: &Path,
    img: &Image,
    meta: &Metadata,
    opts: &WriteOptions,
    placed: &mut dyn FnMut(),
) -> Result<u64> {
    img.check()?;
    crate::util::fs::check_replaceable(path)?;
    let kind = FileKind::of(path)?;
    let name = path
        .file_name()
        .and_then(|n| n.to_str())
        .ok_or_else(|| anyhow!("not a file name"))?;
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
    // Same folder, so that the rename cannot cross file systems; extension kept, because OIIO
    // picks the writer by it; leading dot, so that file browsers and globs skip it.
    let tmp_path = parent_dir(path).join(format!(
        ".{name}.tmp-{}-{}.{ext}",
        std::process::id(),
        unique()
    ));
    // Made empty here, where a stop by signal cannot miss it; the writer fills it. Registered
    // until after `tmp` (declared later, dropped first) has removed it on a failure.
    let (_live, made) = crate::util::fs::create_temporary(&tmp_path).map_err(|e| anyhow!("{e}"))?;
    let mut tmp = TempFile {
        path: tmp_path,
        keep: false,
    };
    let tmp_str = path_bytes(&tmp.path);
    let mut attrs = attributes(meta, kind)?;
    if kind == FileKind::Ldr {
        // Lets PNG record the encoding (sRGB chunk), so viewers need not guess.
        attrs.push(text_attr("oiio:ColorSpace", "sRGB"));
    }

    let encoded = match kind {
        FileKind::Exr => {
            let store_as = if opts.exr_float {
                ffi::PixelType::Float
            } else {
                ffi::PixelType::Half
            };
            let desc = ffi::ImageDesc {
                width: img.width,
                height: img.height,
                channels: img.channels.clone(),
                store_as,
            };
            let needs_clamp = !opts.exr_float && img.data.iter().any(|v| v.abs() > HALF_MAX);
            if needs_clamp {
                HALF_CLAMPED.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            }
            if needs_clamp && !HALF_CLAMP_SAID.swap(true, std::sync::atomic::Ordering::Relaxed) {
                // Once a process (the command's summary counts the frames): a light seen
                // directly at 1e5 came out at 65504, 35% dark.
                errln!(
                    "warning: {}: values beyond ±65504, half float's largest, are clamped to it \
                     (--exr-float keeps them)",
                    crate::util::text::printable(&path.display().to_string())
                );
            }
            if !opts.exr_float && !HALF_SMALL_SAID.load(std::sync::atomic::Ordering::Relaxed) {
                // Below half's smallest normal number a value keeps fewer digits, and below
                // 3e-8 none (a scene lit at 1e-5 lost a tenth of half its pixels, and its
                // darkest became 0, without a word).
                // Pixels, by their largest colour channel: a red pixel's green of 1e-5 loses
                // nothing one sees (it warned of normally lit frames).
                let nch = img.channels.len().max(1);
                let (small, nonzero) = img
                    .data
                    .par_chunks(nch)
                    .map(|px| {
                        let v = px[..nch.min(3)].iter().fold(0.0f32, |m, v| m.max(v.abs()));
                        (v < HALF_MIN_NORMAL && v != 0.0, v != 0.0)
                    })
                    .fold(
                        || (0u64, 0u64),
                        |(s, n), (a, b)| (s + a as u64, n + b as u64),
                    )
                    .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
                if small * 100 >= nonzero
                    && small > 0
                    && !HALF_SMALL_SAID.swap(true, std::sync::atomic::Ordering::Relaxed)
                {
                    errln!(
                        "warning: {}: {:.0}% of the pixels that are not black are below \
                         6.1e-5, where half floats keep fewer digits (and none below 3e-8): \
                         --exr-float keeps them",
                        crate::util::text::printable(&path.display().to_string()),
                        (100 * small) as f64 / nonzero as f64
                    );
                }
            }
            if needs_clamp {
                let clamped: Vec<f32> = img
                    .data
                    .par_iter()
                    .map(|v| v.clamp(-HALF_MAX, HALF_MAX))
                    .collect();
                ffi::write_f32(tmp_str, &desc, &clamped, &attrs)
            } else {
                ffi::write_f32(tmp_str, &desc, &img.data, &attrs)
            }
        }
        FileKind::FloatRgb | FileKind::Rgbe => {
            let mut rgb = first_three(img)?;
            if kind == FileKind::Rgbe {
                round_for_rgbe(&mut rgb);
            }
            let desc = rgb_desc(img, ffi::PixelType::Float);
            ffi::write_f32(tmp_str, &desc, &rgb, &attrs)
        }
        FileKind::Ldr => {
            let bytes = encode_srgb8(img)?;
            let desc = rgb_desc(img, ffi::PixelType::U8);
            ffi::write_u8(tmp_str, &desc, &bytes, &attrs)
        }
    }
    .map_err(|e| anyhow!("{}", e.what()))?;
    // The bytes are written here, where a failed write (a full disk, a quota) is an error, and
    // synced before the rename, so that a frame in place is whole.
    let encoded = encoded.as_slice();
    let digest = if encoded.is_empty() {
        bytes_digest(&fs::read(&tmp.path).map_err(|e| anyhow!("{e}"))?)
    } else {
        bytes_digest(encoded)
    };
    let file = if encoded.is_empty() {
        // Written by the writer, and read back whole by the bridge.
        fs::File::open(&tmp.path)
    } else {
        let mut f = made;
        f.write_all(encoded).map(|()| f)
    };
    file.and_then(|f| f.sync_all())
        .map_err(|e| anyhow!("{e}"))?;

    crate::util::fs::holding_registry(|| fs::rename(&tmp.path, path).map(|()| placed()))
        .map_err(|e| anyhow!("cannot move the finished file into place: {e}"))?;
    tmp.keep = true;
    Ok(digest)
}

fn rgb_desc(img: &Image, store_as: ffi::PixelType) -> ffi::ImageDesc {
    ffi::ImageDesc {
        width: img.width,
        height: img.height,
        channels: vec!["R".into(), "G".into(), "B".into()],
        store_as,
    }
}

fn require_rgb(img: &Image) -> Result<()> {
    if img.channels.len() < 3 {
        bail!(
            "this format holds R,G,B, but the image has only {} channel(s) {:?}",
            img.channels.len(),
            img.channels
        );
    }
    Ok(())
}

/// Prepare RGB for an RGBE file (Radiance HDR), whose writer (OpenImageIO's) truncates each
/// channel to 8 bits of mantissa under the pixel's shared exponent: half a step of that exponent
/// is added, so that the truncation rounds to nearest (a frame read back was 0.4% dark on
/// average, up to 1.9% in a channel). The step is `2^(e - 8)` for the largest channel's exponent
/// `e` (`m = f 2^e`, `f` in [0.5, 1)).
fn round_for_rgbe(rgb: &mut [f32]) {
    for px in rgb.chunks_exact_mut(3) {
        let m = px[0].max(px[1]).max(px[2]);
        if !(m.is_finite() && m > 1e-32) {
            continue;
        }
        let e = m.log2().floor() as i32 + 1;
        let mut half_step = 2f32.powi(e - 9);
        // Where the largest channel rounds up to the next power of two, the exponent is one
        // more, and so is the step of every channel.
        if m + half_step >= 2f32.powi(e) {
            half_step *= 2.0;
        }
        for v in px.iter_mut() {
            if *v > 0.0 {
                *v += half_step;
            }
        }
    }
}

fn first_three(img: &Image) -> Result<Vec<f32>> {
    require_rgb(img)?;
    let nch = img.channels.len();
    Ok(img
        .data
        .chunks_exact(nch)
        .flat_map(|px| [px[0], px[1], px[2]])
        .collect())
}

/// The first three channels of `img` as 8-bit sRGB, interleaved RGB: linear values clamped to
/// \[0, 1\], encoded with the exact piecewise sRGB curve, then quantised with a triangular dither
/// of +-1 LSB. The dither hides banding in dark gradients; it comes from a hash of (x, y,
/// channel) rather than a random generator, so the same image always gives the same bytes
/// (frames can be compared and cached) and the pattern does not crawl between frames.
/// Values that clamp to exactly black or white are not dithered: there is no gradient there to
/// protect, and speckling flat black backgrounds would only cost file size.
pub fn encode_srgb8(img: &Image) -> Result<Vec<u8>> {
    img.check()?;
    require_rgb(img)?;
    let nch = img.channels.len();
    let width = img.width as usize;
    let mut out = vec![0u8; width * img.height as usize * 3];
    out.par_chunks_mut(width * 3)
        .zip(img.data.par_chunks(width * nch))
        .enumerate()
        .for_each(|(y, (out_row, in_row))| {
            for (x, (o, px)) in out_row
                .chunks_exact_mut(3)
                .zip(in_row.chunks_exact(nch))
                .enumerate()
            {
                for c in 0..3 {
                    o[c] = quantize_srgb8(px[c], x as u32, y as u32, c as u32);
                }
            }
        });
    Ok(out)
}

fn quantize_srgb8(linear: f32, x: u32, y: u32, c: u32) -> u8 {
    if linear.is_nan() || linear <= 0.0 {
        return 0;
    }
    if linear >= 1.0 {
        return 255;
    }
    let encoded = srgb_oetf(linear as f64);
    let q = (encoded * 255.0 + triangular_dither(x, y, c)).round();
    q.clamp(0.0, 255.0) as u8
}

/// The sRGB (IEC 61966-2-1) encoding curve, for linear values in \[0, 1\].
fn srgb_oetf(v: f64) -> f64 {
    if v <= 0.0031308 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// The linear value of each 8-bit sRGB code (`srgb_eotf(k / 255)`).
fn srgb8() -> &'static [f32; 256] {
    static TABLE: std::sync::OnceLock<[f32; 256]> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| std::array::from_fn(|k| srgb_eotf(k as f64 / 255.0) as f32))
}

/// The linear value of an sRGB-encoded value `v` in \[0, 1\] as OIIO gives it: an 8-bit code
/// over 255 is found in a table (a file of 8192 x 8192 texels spent 4 s in `pow` decoding
/// every value), any other value is decoded.
#[inline]
pub(crate) fn decode_srgb(v: f32) -> f32 {
    let k = v * 255.0;
    let r = (k + 0.5) as i32;
    if (0..256).contains(&r) && (k - r as f32).abs() < 1e-3 {
        srgb8()[r as usize]
    } else {
        srgb_eotf(v as f64) as f32
    }
}

/// The inverse of `srgb_oetf`: an sRGB-encoded value in \[0, 1\] back to linear.
fn srgb_eotf(e: f64) -> f64 {
    if e <= 0.04045 {
        e / 12.92
    } else {
        ((e + 0.055) / 1.055).powf(2.4)
    }
}

/// Triangular noise in (-1, 1): the difference of two uniforms taken from one hash.
fn triangular_dither(x: u32, y: u32, c: u32) -> f64 {
    let h = splitmix64(splitmix64(((y as u64) << 32) | x as u64) ^ c as u64);
    let u1 = (h >> 40) as f64 / (1u64 << 24) as f64;
    let u2 = ((h >> 16) & 0xff_ffff) as f64 / (1u64 << 24) as f64;
    u1 - u2
}

fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

fn attr(name: &str, kind: ffi::AttrKind) -> ffi::Attribute {
    ffi::Attribute {
        name: name.to_string(),
        kind,
        int_value: 0,
        float_value: 0.0,
        text: String::new(),
        matrix: [0.0; 16],
    }
}

fn text_attr(name: &str, value: &str) -> ffi::Attribute {
    ffi::Attribute {
        text: value.to_string(),
        ..attr(name, ffi::AttrKind::Text)
    }
}

/// The attributes for `meta`. Outside EXR, numbers go as text: PNG keeps only text chunks, and
/// the other 8-bit formats drop unknown attributes whatever their type.
fn attributes(meta: &Metadata, kind: FileKind) -> Result<Vec<ffi::Attribute>> {
    let typed = kind == FileKind::Exr;
    let int = |key: &str, v: u32| -> Result<ffi::Attribute> {
        let name = format!("{PREFIX}{key}");
        if !typed {
            return Ok(text_attr(&name, &v.to_string()));
        }
        let int_value = i32::try_from(v)
            .map_err(|_| anyhow!("{key} = {v} does not fit the file's int attribute"))?;
        Ok(ffi::Attribute {
            int_value,
            ..attr(&name, ffi::AttrKind::Int)
        })
    };
    let seconds_name = format!("{PREFIX}render_seconds");
    let seconds = if typed {
        ffi::Attribute {
            float_value: meta.render_seconds as f32,
            ..attr(&seconds_name, ffi::AttrKind::Float)
        }
    } else {
        text_attr(&seconds_name, &meta.render_seconds.to_string())
    };
    let mut attrs = vec![
        text_attr(&format!("{PREFIX}method"), &meta.method),
        int("spp", meta.spp)?,
        int("window", meta.window)?,
        // A u64 does not fit any integer attribute type EXR has.
        text_attr(&format!("{PREFIX}seed"), &meta.seed.to_string()),
        seconds,
        ffi::Attribute {
            matrix: meta.world_to_camera,
            ..attr(OIIO_WORLD_TO_CAMERA, ffi::AttrKind::Matrix)
        },
        ffi::Attribute {
            matrix: meta.world_to_ndc,
            ..attr(OIIO_WORLD_TO_NDC, ffi::AttrKind::Matrix)
        },
    ];
    for (i, (key, value)) in meta.extra.iter().enumerate() {
        if key.is_empty() {
            bail!("metadata key is empty");
        }
        if BUILTIN_KEYS.contains(&key.as_str()) || meta.extra[..i].iter().any(|(k, _)| k == key) {
            bail!("metadata key {key:?} is given twice");
        }
        attrs.push(text_attr(&format!("{PREFIX}{key}"), value));
    }
    Ok(attrs)
}

/// Reads any file OIIO can read into float, all channels of its first subimage. 8-bit files
/// come back as their code values / 255, not linearised. Channels come in the order OIIO
/// reports them, which for EXR is R, G, B, A first and then the others alphabetically (EXR
/// itself stores channels sorted by name), so look channels up by name.
pub fn read_image(path: &Path) -> Result<Image> {
    let read = || -> Result<Image> {
        let (mut reader, info) = open_checked(path, u64::MAX)?;
        // A header that claims more pixels than memory holds (a damaged EXR's display window
        // of 10^6 x 10^6) is refused in one line: its allocation aborted the process.
        let channels = info.channels.len();
        let need = 4 * info.width as u64 * info.height as u64 * channels as u64;
        check_room(&info, channels, need)?;
        let data = read_all(&mut reader, &info)?;
        Ok(Image {
            width: info.width,
            height: info.height,
            channels: info.channels,
            data,
        })
    };
    let _reading = crate::sys::reading(crash_line(path));
    read().map_err(|e| read_error(path, e))
}

/// The error of a file that could not be read (every reader's: `read_image`, `read_colour`,
/// `read_mask`), with what a Radiance file's bytes say of why where OpenImageIO's words mislead
/// (`radiance_hint`).
fn read_error(path: &Path, e: anyhow::Error) -> anyhow::Error {
    // OpenImageIO 2.4 opens no EXR with subsampled channels: OpenEXR's luminance and chroma
    // (Y at full resolution, RY and BY at half), which OpenEXR's own RGBA reader turns into
    // RGB. Its words named the sampling of each channel, not what to do.
    if e.to_string()
        .contains("Subsampled channels are not supported")
    {
        return anyhow!(
            "cannot read {}: it stores luminance and chroma (Y, RY, BY) with the chroma at \
             reduced resolution, which this OpenImageIO does not read: save it as RGB first (in \
             a compositor or an image editor)",
            path.display()
        );
    }
    match radiance_hint(path) {
        Some(hint) => anyhow!("cannot read {}: {e} ({hint})", path.display()),
        None => anyhow!("cannot read {}: {e}", path.display()),
    }
}

/// Why OpenImageIO 2.4 cannot read a valid Radiance file, from its first bytes: its header's
/// lines end in CR LF (written in text mode on Windows: "no FORMAT specifier found" of a header
/// that has the line), its pixels are not RGBE (an XYZE file, or a header without the FORMAT
/// line: "no FORMAT specifier found" too), or they are in the old run-length encoding of before
/// 1991 ("Read error reading pixels on scanline 2", as if it were cut short). `None` for
/// anything else.
fn radiance_hint(path: &Path) -> Option<&'static str> {
    use std::io::Read;
    // Never blocking on a FIFO, and never reading a device.
    let mut f = crate::util::fs::open_regular(path).ok()?;
    let len = f.metadata().ok()?.len();
    let mut head = vec![0u8; 65536];
    let n = f.read(&mut head).ok()?;
    let head = &head[..n];
    if !head.starts_with(b"#?") {
        return None;
    }
    let blank = head.windows(2).position(|w| w == b"\n\n");
    let crlf = head.windows(4).position(|w| w == b"\r\n\r\n");
    if crlf.is_some_and(|c| blank.is_none_or(|b| c < b)) {
        return Some(
            "its header's lines end in CR LF, as a file written in text mode on Windows has \
             them, which OpenImageIO does not read: remove the CRs, or convert it to OpenEXR",
        );
    }
    let header = &head[..blank.unwrap_or(head.len())];
    if !header
        .windows(22)
        .any(|w| w.eq_ignore_ascii_case(b"FORMAT=32-bit_rle_rgbe"))
    {
        return Some(
            "OpenImageIO reads Radiance HDR files of RGBE pixels with a FORMAT line; an XYZE \
             file, or one without that line, must be converted to RGBE or OpenEXR",
        );
    }
    // The resolution line after the header, `-Y H +X W`, then the pixels.
    let start = blank? + 2;
    let end = start + head[start..].iter().position(|&b| b == b'\n')?;
    let words: Vec<&str> = std::str::from_utf8(&head[start..end])
        .ok()?
        .split_whitespace()
        .collect();
    let [_, h, _, w] = words[..] else { return None };
    let (w, h): (u64, u64) = (w.parse().ok()?, h.parse().ok()?);
    let data = head.get(end + 1..end + 3)?;
    let flat = w * h * 4;
    (data != [2, 2] && len - (end as u64 + 1) < flat).then_some(
        "its pixels are not in the run-length encoding OpenImageIO reads, and fewer than a flat \
         file holds: Radiance's old run-length encoding (before 1991), which OpenImageIO does \
         not read, or a file cut short; convert it to the new encoding (Radiance's ra_rgbe) or \
         to OpenEXR",
    )
}

/// OpenImageIO's reader of the image at `path`, which must be a regular file (through any
/// links): a named pipe blocked the reader until something wrote into it, and a device such as
/// `/dev/zero` was read without end (a cached reference frame replaced by either hung
/// `reference` and `compare`). Every read of an image file starts here.
fn open_reader(path: &Path) -> Result<cxx::UniquePtr<ffi::ImageReader>> {
    // A name that picks OpenImageIO's "null" reader (`.null`, or `.null?RES=...`) is read as
    // an image made from the name alone, the file's bytes never looked at: a PNG renamed so
    // rendered black, and `x.null?RES=8000x8000` made a 0.9 GB image of nothing.
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    if name.ends_with(".null") || name.contains(".null?") {
        bail!(
            "a name ending in .null picks the image library's null reader, which makes an \
             image from the name and reads nothing of the file: name it for its format \
             (.png, .exr, ...)"
        );
    }
    // (Opened here to be looked at; a missing or unreadable file is left for OpenImageIO to
    // say.)
    if let Err(e) = crate::util::fs::open_regular(path) {
        if crate::util::fs::not_regular(&e) {
            bail!("it {e}");
        }
    }
    // What OpenImageIO's words leave out of a Radiance file is added by `read_error`.
    ffi::open_reader(path_bytes(path)).map_err(|e| anyhow!("{}", e.what()))
}

/// The largest value (maxval) a Netpbm file's header declares (P2, P3, P5, P6: its fourth
/// field; P7, PAM: its `MAXVAL` line), where it has one that reads as a number; `None` for the
/// bitmaps (P1, P4), which have none, and for a header that cannot be read (left to OpenImageIO).
fn pnm_maxval(path: &Path) -> Option<u64> {
    let head = file_head(path, 4096)?;
    let text = String::from_utf8_lossy(&head);
    // Fields are separated by white space; `#` starts a comment to the end of its line.
    let mut fields = text
        .lines()
        .map(|l| l.split('#').next().unwrap_or(""))
        .flat_map(str::split_whitespace);
    match fields.next()? {
        "P2" | "P3" | "P5" | "P6" => fields.nth(2)?.parse().ok(),
        "P7" => {
            let mut fields = fields.skip_while(|f| *f != "MAXVAL");
            fields.nth(1)?.parse().ok()
        }
        _ => None,
    }
}

/// The first `n` bytes of the regular file `path` (fewer where it is shorter), for a header
/// that OpenImageIO does not report.
fn file_head(path: &Path, n: u64) -> Option<Vec<u8>> {
    use std::io::Read;
    let mut head = Vec::with_capacity(n as usize);
    crate::util::fs::open_regular(path)
        .ok()?
        .take(n)
        .read_to_end(&mut head)
        .ok()?;
    Some(head)
}

/// The scale a PFM file's header gives (its third field, after the width and height: its
/// magnitude scales the values, as pbrt-v4 reads it, and its sign gives the byte order), as
/// written; `None` where the header cannot be read.
fn pfm_scale(path: &Path) -> Option<String> {
    let head = file_head(path, 256)?;
    let text = String::from_utf8_lossy(&head);
    let mut fields = text.split_whitespace();
    match fields.next()? {
        "PF" | "Pf" => fields.nth(2).map(str::to_string),
        _ => None,
    }
}

/// `path` opened for reading, with its description; more than `max_pixels` pixels are refused
/// before any is read.
fn open_checked(
    path: &Path,
    max_pixels: u64,
) -> Result<(cxx::UniquePtr<ffi::ImageReader>, ffi::ImageInfo)> {
    let reader = open_reader(path)?;
    let info = reader.info();
    let attrs = reader.attributes();
    // A LogLuv TIFF (SGI's log-encoded HDR) comes out of this OpenImageIO as 8-bit codes of
    // another meaning, which would light a scene with the wrong values without a word.
    let logluv = attrs.iter().any(|a| {
        (a.name == "compression" && a.text.to_ascii_lowercase().starts_with("sgilog"))
            || (a.name == "tiff:PhotometricInterpretation" && matches!(a.int_value, 32844 | 32845))
    });
    // A "white is zero" greyscale TIFF (photometric 0) of more than 8 bits: OpenImageIO 2.4
    // turns 1- and 8-bit ones the right way up and hands the others over as stored, a
    // negative (as a colour map, and as a cut-out its other half).
    let attr = |name: &str| attrs.iter().find(|a| a.name == name);
    let white_is_zero = attr("tiff:PhotometricInterpretation").is_some_and(|a| a.int_value == 0);
    let bits = attr("oiio:BitsPerSample").map_or(8, |a| a.int_value);
    if white_is_zero && bits > 8 {
        bail!(
            "a {bits}-bit 'white is zero' greyscale TIFF, which OpenImageIO {} reads as its \
             negative: convert it (to a 'black is zero' TIFF, PNG or EXR; oiiotool reads it \
             the same wrong way)",
            ffi::oiio_version()
        );
    }
    if logluv {
        bail!(
            "a LogLuv (SGILog) TIFF, which OpenImageIO {} does not decode as HDR: convert it \
             to OpenEXR or Radiance HDR first",
            ffi::oiio_version()
        );
    }
    if info.format_name == "pnm" {
        if let Some(v) = pnm_maxval(path).filter(|v| !(1..=65535).contains(v)) {
            bail!(
                "a Netpbm image whose largest value (maxval) is {v}: the format allows 1 to \
                 65535, the scale its codes are read on (with a maxval of 0, black codes \
                 were read as white)"
            );
        }
    }
    if matches!(info.format_name.as_str(), "pnm" | "pfm") {
        if let Some(scale) = pfm_scale(path) {
            let ok = scale
                .parse::<f64>()
                .is_ok_and(|v| v.is_finite() && v != 0.0);
            if !ok {
                bail!(
                    "a PFM file whose scale (its header's third number) is '{}': it must be a \
                     finite number other than 0, its sign the byte order (a scale of 0 read \
                     every pixel as black, one of nan as a NaN texel)",
                    crate::util::text::printable(&scale)
                );
            }
        }
    }
    if info.stored_outside {
        bail!(
            "it stores {}x{} pixels (its data window), none of them inside its {}x{} image (its \
             display window), which would read as black: give it a display window that holds \
             its data (e.g. with oiiotool's --fullpixels)",
            info.stored_width,
            info.stored_height,
            info.width,
            info.height,
        );
    }
    let stored = (info.stored_width, info.stored_height);
    if stored != (info.width, info.height) && stored.0 as u64 * stored.1 as u64 > max_pixels {
        bail!(
            "it stores {}x{} pixels (its data window; the image is {}x{}), more than the \
             {max_pixels} reframe reads",
            info.stored_width,
            info.stored_height,
            info.width,
            info.height
        );
    }
    if info.width as u64 * info.height as u64 > max_pixels && stored != (info.width, info.height) {
        bail!(
            "its image (the display window) is {}x{} pixels, more than the {max_pixels} reframe \
             reads, though the file stores {}x{} (its data window): give it a display window \
             the size of its data",
            info.width,
            info.height,
            stored.0,
            stored.1
        );
    }
    if info.width as u64 * info.height as u64 > max_pixels {
        // Halved until it fits, in the file's own format: a copy in another one may be read
        // otherwise (an 8-bit JPEG resized into an EXR keeps its sRGB codes, which an EXR's
        // reader takes for linear values).
        let (mut w, mut h) = (info.width as u64, info.height as u64);
        while w * h > max_pixels {
            (w, h) = (w.div_ceil(2), h.div_ceil(2));
        }
        let ext = path
            .extension()
            .map_or("exr".into(), |e| e.to_string_lossy().to_lowercase());
        bail!(
            "{}x{} pixels, more than the {max_pixels} reframe reads (make a smaller copy in the \
             same format, e.g. 'oiiotool {} --resize {w}x{h} -o smaller.{ext}')",
            info.width,
            info.height,
            path.display()
        );
    }
    Ok((reader, info))
}

/// Refuses, in one line, to read the image `info` describes when reading it needs `need` bytes
/// and less memory than that is available (an allocation that fails aborts the process).
fn check_room(info: &ffi::ImageInfo, channels: usize, need: u64) -> Result<()> {
    if let Some(a) = crate::util::mem::available_bytes().filter(|&a| need > a) {
        bail!(
            "reading its {}x{} pixels of {} channels needs about {}, but {} of memory \
             is available",
            info.width,
            info.height,
            channels,
            crate::util::mem::size(need),
            crate::util::mem::size(a)
        );
    }
    Ok(())
}

/// An input image (a texture, a mask, an environment) opened for reading as `open_checked`
/// opens it, with its pixel count; one without pixels or channels is refused.
fn open_input_image(
    path: &Path,
    max_pixels: u64,
) -> Result<(cxx::UniquePtr<ffi::ImageReader>, ffi::ImageInfo, u64)> {
    let (reader, mut info) = open_checked(path, max_pixels)?;
    // Blanks around a channel's name are no part of it (`color.R `, as a converted file may
    // hold): unmatched, the colour fell back to the channels' order in the file, B, G, R in an
    // EXR, and red and blue swapped unsaid.
    for name in &mut info.channels {
        if name.trim().len() != name.len() {
            *name = name.trim().to_string();
        }
    }
    let pixels = info.width as u64 * info.height as u64;
    if pixels == 0 || info.channels.is_empty() {
        bail!("the image has no pixels");
    }
    // The reader holds a tile whole: a 1 KB EXR of 8 x 8 pixels that claimed tiles of 8192 x
    // 8192 took 780 MB to read (or failed with a bare `std::bad_alloc` under `ulimit -v`).
    // Tiles up to 1024 x 1024 are always taken (a small texture saved with large tiles).
    let tile = info.tile_width as u64 * info.tile_height as u64;
    if tile > (4 * pixels).max(1 << 20) {
        bail!(
            "its tiles of {}x{} pixels are far larger than its {}x{} pixels (a damaged or \
             hostile file): re-save it untiled or with tiles of 64 x 64",
            info.tile_width,
            info.tile_height,
            info.width,
            info.height
        );
    }
    Ok((reader, info, pixels))
}

/// Every channel of the first subimage of an open file as f32.
fn read_all(
    reader: &mut cxx::UniquePtr<ffi::ImageReader>,
    info: &ffi::ImageInfo,
) -> Result<Vec<f32>> {
    read_channels(reader, info, 0..info.channels.len())
}

/// Channels `range` of every pixel, as f32, pixel by pixel: only the channels read are held (a
/// compositor's EXR of 203 channels, read whole for its RGB, took 3.7 GB at 2048 x 2048).
fn read_channels(
    reader: &mut cxx::UniquePtr<ffi::ImageReader>,
    info: &ffi::ImageInfo,
    range: std::ops::Range<usize>,
) -> Result<Vec<f32>> {
    // Taken fallibly, so that an image past what the process can map is an error, not an
    // abort, for every reader (`check_room` goes by the memory available, which a limit on
    // the address space does not lower).
    let n = (info.width as u64 * info.height as u64).saturating_mul(range.len() as u64);
    let mut data: Vec<f32> = Vec::new();
    if usize::try_from(n).map_or(true, |n| data.try_reserve_exact(n).is_err()) {
        bail!(
            "reading its {}x{} pixels of {} channels needs {}, more memory than this process \
             can take",
            info.width,
            info.height,
            range.len(),
            crate::util::mem::size(4 * n)
        );
    }
    data.resize(n as usize, 0.0);
    reader
        .pin_mut()
        .read_f32(range.start as u32, range.end as u32, &mut data)
        .map_err(|e| anyhow!("{}", e.what()))?;
    Ok(data)
}

/// The channels `picked` name (`None`: none), as the smallest range that holds them, and each
/// one's place in it.
fn span_of<const N: usize>(
    picked: [Option<usize>; N],
) -> (std::ops::Range<usize>, [Option<usize>; N]) {
    let used = picked.iter().flatten();
    let lo = used.clone().min().copied().unwrap_or(0);
    let hi = used.max().map_or(lo + 1, |&c| c + 1);
    (lo..hi, picked.map(|c| c.map(|c| c - lo)))
}

/// Where an image's colour is (`colour_channels`): the channels of red, green and blue (`None`:
/// zero), or one channel taken as grey.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Colour {
    Rgb([Option<usize>; 3]),
    Grey(usize),
}

impl Colour {
    /// The channel of red, green and blue in turn (a grey channel three times).
    pub fn indices(self) -> [Option<usize>; 3] {
        match self {
            Colour::Rgb(c) => c,
            Colour::Grey(c) => [Some(c); 3],
        }
    }
}

/// The colour of an image with channels `names` (as OIIO names them): the channels named R, G
/// and B, those missing zero (an EXR of R and G is red and green, not grey); else one named Y,
/// as grey (OIIO's name for the channel of a grey PNG or TIFF); else the first three channels,
/// or a single one as grey. An image whose only channels are alpha (or alpha and one more,
/// unnamed) has no colour and is refused.
pub fn colour_channels(names: &[String]) -> Result<Colour> {
    let find = |c: &str| names.iter().position(|n| n == c);
    // R, G and B as named, else in another case or spelled out (`R, g, b`: the G and B of a
    // file that named them so read as zero, and it rendered red), among the channels of no
    // layer.
    let rgb = ['R', 'G', 'B'].map(|c| {
        find(&c.to_string()).or_else(|| {
            names
                .iter()
                .position(|n| layer_of(n).is_none() && role(n) == Some(c))
        })
    });
    if rgb.iter().any(Option::is_some) {
        // Some of R, G and B named, the others not, beside channels of no layer whose names say
        // nothing (`red, grn, blu`: read as red alone, green and blue zero, without a word):
        // those are likely the missing colours under other names, which reframe cannot tell.
        let unknown: Vec<&str> = names
            .iter()
            .filter(|n| {
                layer_of(n).is_none() && role(n).is_none() && !matches!(n.as_str(), "Z" | "Y")
            })
            .map(String::as_str)
            .collect();
        if rgb.iter().any(Option::is_none) && !unknown.is_empty() {
            let said = |want: bool| {
                ["red", "green", "blue"]
                    .iter()
                    .zip(&rgb)
                    .filter(|(_, c)| c.is_some() == want)
                    .map(|(n, _)| *n)
                    .collect::<Vec<_>>()
                    .join(" and ")
            };
            bail!(
                "its channels ({}) name {} but not {}, beside channels whose colour cannot be \
                 told ({}): name its colour channels R, G and B",
                names.join(", "),
                said(true),
                said(false),
                unknown.join(", ")
            );
        }
        return Ok(Colour::Rgb(rgb));
    }
    // A multi-layer EXR (Blender's MultiLayer output, a compositor's AOVs): the channels of
    // the layer `colour_layers` picks, never the first three across layers (the AO pass read
    // for the Combined one, or a depth channel mixed with a colour's red and green).
    if let Some(layer) = colour_layers(names).first() {
        let find = |c: char| {
            names.iter().position(|n| {
                layer_of(n).is_some_and(|(l, k)| l == layer.as_str() && role(k) == Some(c))
            })
        };
        return Ok(Colour::Rgb(['R', 'G', 'B'].map(find)));
    }
    // Luminance and chroma (OpenEXR's Y, RY, BY, also in a layer): RY and BY are no colours of
    // their own, and the image read as its Y alone would be grey without a word (in a layer,
    // as RGB: Y as red).
    if names.iter().any(|n| own_name(n) == "RY") && names.iter().any(|n| own_name(n) == "BY") {
        bail!(
            "its channels ({}) are luminance and chroma (Y, RY, BY), not RGB: save it as RGB \
             first (in a compositor or an image editor)",
            names.join(", ")
        );
    }
    // Printers' inks (a CMYK TIFF as OpenImageIO hands it over: C, M, Y, K, or ink0..), whose
    // first three read as RGB would turn red into cyan, and whose Y is yellow, not grey.
    let cmyk = ["C", "M", "Y", "K"].iter().all(|c| find(c).is_some());
    if cmyk || names.iter().any(|n| n.starts_with("ink")) {
        bail!(
            "its channels ({}) are printing inks (CMYK), not light: convert it to RGB first \
             (in an image editor, or with ImageMagick: 'convert in.tif -colorspace sRGB out.png')",
            names.join(", ")
        );
    }
    if let Some(y) = find("Y") {
        return Ok(Colour::Grey(y));
    }
    // Layers, none with colour: the first layer's own channels, not three across layers.
    let first_layer: Vec<String>;
    let names = match names.first().and_then(|n| layer_of(n)) {
        Some((layer, _)) if names.len() > 1 => {
            first_layer = names
                .iter()
                .take_while(|n| layer_of(n).is_some_and(|(l, _)| l == layer))
                .cloned()
                .collect();
            &first_layer[..]
        }
        _ => names,
    };
    match names {
        [] => bail!("the image has no channels"),
        [a, ..] if role(a) == Some('A') && names.len() <= 2 => bail!(
            "its channels ({}) hold no colour: an alpha channel alone is not a colour",
            names.join(", ")
        ),
        [_] | [_, _] => Ok(Colour::Grey(0)),
        _ => Ok(Colour::Rgb([Some(0), Some(1), Some(2)])),
    }
}

/// A channel's own name, without its layer (`R` of `ViewLayer.Combined.R`).
fn own_name(name: &str) -> &str {
    layer_of(name).map_or(name, |(_, k)| k)
}

/// A layered channel name (`ViewLayer.Combined.R`, as OpenEXR names the channels of a
/// layer): its layer and its own name, split at the last dot; `None` for a name of no layer.
fn layer_of(name: &str) -> Option<(&str, &str)> {
    name.rsplit_once('.')
        .filter(|(l, c)| !l.is_empty() && !c.is_empty())
}

/// The layers of a file's channels (`names`) that hold colour (a channel named R, G or B in
/// the layer), the one a colour is read from first: a layer named Combined (Blender's beauty
/// pass, `ViewLayer.Combined`), else one named beauty, rgba, rgb, color or colour (another
/// program's), else the first in the file's order. Empty where no layer holds colour.
pub fn colour_layers(names: &[String]) -> Vec<String> {
    let mut layers: Vec<String> = Vec::new();
    for n in names {
        if let Some((layer, c)) = layer_of(n) {
            if matches!(role(c), Some('R' | 'G' | 'B')) && !layers.iter().any(|l| l == layer) {
                layers.push(layer.to_string());
            }
        }
    }
    // Stable: the file's order within a rank.
    layers.sort_by_key(|l| layer_rank(l));
    layers
}

/// How surely a layer named `l` is a file's colour: 0 for Blender's Combined, 1 for another
/// program's beauty pass (beauty, rgba, rgb, color, colour), 2 for any other.
fn layer_rank(l: &str) -> u8 {
    let last = l.rsplit('.').next().unwrap_or(l).to_ascii_lowercase();
    match last.as_str() {
        "combined" => 0,
        "beauty" | "rgba" | "rgb" | "color" | "colour" => 1,
        _ => 2,
    }
}

/// What a layer's channel named `c` holds, in any case and spelled out as Nuke spells it
/// (`diffuse.r`, `diffuse.red`): red, green, blue or alpha.
fn role(c: &str) -> Option<char> {
    match c.to_ascii_lowercase().as_str() {
        "r" | "red" => Some('R'),
        "g" | "green" => Some('G'),
        "b" | "blue" => Some('B'),
        "a" | "alpha" => Some('A'),
        _ => None,
    }
}

/// Whether a colour file's values are sRGB-encoded, from the colour space the file names
/// (`space`, OIIO's `oiio:ColorSpace`), whether it stores 8- or 16-bit unsigned codes, and its
/// format (OIIO's name):
/// - a file that names sRGB is sRGB, one that names a linear space (`linear`, `scene_linear`,
///   `lin_*`, ACEScg and ACES2065, `GammaCorrected1.0`) is linear;
/// - a file in a log encoding (`log_encoding`: Cineon's and DPX's `KodakLog`, `ACEScct`,
///   `LogC`, ...) is read as its values, not decoded (and warned of: `Meaning::encoding`);
/// - a file that names another gamma (`GammaCorrected2.2` or `Gamma2.2`: a PNG with a `gAMA`
///   chunk and no `sRGB` chunk; `g22_rec709`) is decoded as sRGB, the curve that gamma stands
///   for in practice; data that is no colour (`Non-Color`, `raw`) is not decoded;
/// - a file that names nothing is sRGB where it stores 8- or 16-bit unsigned codes (`codes`:
///   TGA, BMP, 8- and 16-bit TIFF and PNG: the encoding of such colour files unless they say
///   otherwise, as other renderers read them) and linear where it stores floats (EXR, HDR,
///   float TIFF), 32-bit or signed integers (data, not colour codes; they were decoded as sRGB
///   and read up to 20 times too dark) or is an EXR;
/// - a Radiance picture (`hdr`) is linear whatever it names: its pixels are radiance by the
///   format's definition, and a `GAMMA=` line in its header (no variable of the format), which
///   OIIO names `Gamma2.2`, put a sky of 4 through the sRGB curve to 25.3 (pbrt-v4 and Mitsuba 3
///   read such files as linear).
pub fn srgb_encoded(space: Option<&str>, codes: bool, format: &str) -> bool {
    if format.eq_ignore_ascii_case("hdr") {
        return false;
    }
    let s = space.unwrap_or("").trim().to_ascii_lowercase();
    if log_encoding(&s) {
        return false;
    }
    // A gamma by number: OIIO 2.4's `GammaCorrected2.2`, later versions' `Gamma2.2`.
    let gamma = s
        .strip_prefix("gammacorrected")
        .or_else(|| s.strip_prefix("gamma"));
    if let Some(g) = gamma.and_then(|g| g.parse::<f64>().ok()) {
        return (g - 1.0).abs() > 0.01;
    }
    // Linear spaces, and data that is no colour (OCIO's `Non-Color`, `raw`), which is not
    // decoded either; `g10_*` names a gamma of 1, `g22_*` and `g18_*` others.
    let linear = s.contains("linear")
        || s.starts_with("lin_")
        || s.starts_with("aces")
        || s.starts_with("g10")
        || s == "raw"
        || s == "data"
        || s.replace(['-', '_', ' '], "") == "noncolor";
    if linear {
        false
    } else if s.contains("srgb") {
        true
    } else {
        codes && !format.eq_ignore_ascii_case("openexr")
    }
}

/// Whether colour space `space` (OIIO's `oiio:ColorSpace`, any case) is a logarithmic encoding,
/// which reframe does not decode: film scans' `KodakLog` (Cineon, DPX), ACES's `ACEScc` and
/// `ACEScct` (the others of its spaces are linear), cameras' `LogC`, `S-Log3`, `Log3G10`, `V-Log`
/// and the like, and ADX film densities.
pub fn log_encoding(space: &str) -> bool {
    let s = space.to_ascii_lowercase().replace(['-', '_', ' ', '.'], "");
    s.contains("log") || s.starts_with("acescc") || s.contains("cineon") || s.starts_with("adx")
}

/// Reads a colour input (an environment map, a texture) as linear RGB: refuses images of more
/// than `max_pixels` pixels before reading their pixels; takes its colour from the channels
/// `colour_channels` names; decodes sRGB where the file's values are sRGB-encoded
/// (`srgb_encoded`: 8-bit PNG and JPEG, and any file of 8- or 16-bit codes that does not name a
/// linear space), so that an 8-bit file gives the same linear values as the HDR it was made from.
///
/// `then_per_pixel`: the bytes per pixel the caller goes on to hold beside or after the image
/// (an environment's texels and sampling tables), counted in the memory check before the file
/// is read, so that a file that decodes but whose tables would not fit is refused in one line
/// (an allocation that fails aborts the process).
pub fn read_linear_rgb(path: &Path, max_pixels: u64, then_per_pixel: u64) -> Result<Image> {
    read_colour(path, max_pixels, then_per_pixel).map(|(img, _)| img)
}

/// The images a file holds, in words: its count, or "more than 64" where the count stopped
/// (`ImageInfo::images`).
pub fn images_in_words(n: u32) -> String {
    if n > 64 {
        "more than 64".into()
    } else {
        n.to_string()
    }
}

/// How a colour input's file holds its colour: in which channels (`colour_channels`), and
/// whether they are sRGB-encoded (OIIO's `oiio:ColorSpace`).
#[derive(Clone, Debug)]
pub struct ColourLayout {
    pub colour: Colour,
    pub srgb: bool,
    /// The images the file holds (a multi-part EXR's parts, OIIO's subimages); the first is
    /// the one read.
    pub parts: u32,
    /// The layers of colour the file holds where it holds more than one (a multi-layer EXR), the
    /// one read first (`colour_layers`); empty otherwise.
    pub layers: Vec<String>,
    /// Whether the file says it is a cube-face environment map (`textureformat` "CubeFace
    /// Environment": OpenEXR's `envmap` of cube faces, six faces stacked).
    pub cube_faces: bool,
    /// What the file says of its pixels that reframe does not apply (`Meaning`).
    pub meaning: Meaning,
}

/// What an image file says of its pixels beyond their values, which reframe does not apply:
/// pixels are read as stored and as Rec.709 primaries, as Mitsuba 3, pbrt-v4 and Blender read
/// textures (a model's texture coordinates were made against the stored image).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Meaning {
    /// The orientation it says its image is stored in (EXIF's 1-8, OpenImageIO's
    /// `Orientation`; a Radiance file's `+Y` or `-X` resolution line), where not the usual
    /// top-down, left-to-right (1).
    pub orientation: Option<i32>,
    /// Its EXR `chromaticities` (red, green, blue and white x, y), where not Rec.709's.
    pub chromaticities: Option<String>,
    /// The log encoding it names (`log_encoding`: its `oiio:ColorSpace`, or a DPX's
    /// `dpx:Transfer`), whose values are read as they are, not decoded.
    pub encoding: Option<String>,
    /// Where the file stores under 1% of its image (an OpenEXR data window far smaller than its
    /// display window, which reads as black outside it): the pixels it stores inside the image,
    /// and the image's width and height.
    pub sparse: Option<(u64, u32, u32)>,
}

/// EXIF's names of the orientations (`Meaning::orientation`).
pub fn orientation_in_words(o: i32) -> &'static str {
    match o {
        2 => "mirrored left to right",
        3 => "turned 180 degrees",
        4 => "upside down (rows bottom to top)",
        5 => "transposed",
        6 => "turned 90 degrees (to be shown turned clockwise)",
        7 => "transposed and turned",
        8 => "turned 90 degrees (to be shown turned anticlockwise)",
        _ => "in an unknown orientation",
    }
}

/// `Meaning` from a reader's attributes and what it says of the image.
fn meaning(attrs: &[ffi::Attribute], info: &ffi::ImageInfo) -> Meaning {
    let find = |name: &str| attrs.iter().find(|a| a.name.eq_ignore_ascii_case(name));
    // An int, or (a JPEG's EXIF) a uint16 the bridge gives as text; 0 is no orientation.
    let orientation = find("Orientation")
        .and_then(|a| match a.kind {
            ffi::AttrKind::Int => Some(a.int_value),
            _ => a.text.trim().parse().ok(),
        })
        .filter(|o| !matches!(o, 0 | 1));
    // Rec.709 (and sRGB): red (0.64, 0.33), green (0.3, 0.6), blue (0.15, 0.06), D65 white.
    const REC709: [f32; 8] = [0.64, 0.33, 0.3, 0.6, 0.15, 0.06, 0.3127, 0.329];
    let chromaticities = find("chromaticities").and_then(|a| {
        let v: Vec<f32> = a
            .text
            .split(|c: char| c == ',' || c.is_whitespace() || c == '(' || c == ')')
            .filter_map(|w| w.parse().ok())
            .collect();
        let rec709 = v.len() == 8 && v.iter().zip(REC709).all(|(a, b)| (a - b).abs() < 2e-3);
        (!rec709).then(|| a.text.clone())
    });
    // A DPX says its encoding in its transfer characteristic too (OIIO names the colour space
    // from it for some values only).
    let text = |name: &str| find(name).map(|a| a.text.trim().to_string());
    let encoding = text("oiio:ColorSpace")
        .filter(|s| log_encoding(s))
        .or_else(|| {
            text("dpx:Transfer")
                .filter(|t| matches!(t.as_str(), "Logarithmic" | "Printing density"))
                .map(|t| format!("dpx:Transfer {t}"))
        });
    // A 341-byte EXR of one stored pixel in a 16384 x 8192 display window read as a sky of that
    // size, black but for one texel, without a word.
    let pixels = info.width as u64 * info.height as u64;
    let sparse = (info.stored_inside < pixels.div_ceil(100)).then_some((
        info.stored_inside,
        info.width,
        info.height,
    ));
    Meaning {
        orientation,
        chromaticities,
        encoding,
        sparse,
    }
}

/// The layers of colour of channels `names` where there are several (`ColourLayout::layers`),
/// unless the file's unlayered R, G or B is its colour.
fn several_layers(names: &[String]) -> Vec<String> {
    let plain = names.iter().any(|n| matches!(n.as_str(), "R" | "G" | "B"));
    let layers = colour_layers(names);
    // A beauty pass by name (Blender's Combined, `rgba`, ...) is the colour without a doubt:
    // no warning, which `--strict` would turn into a refusal of every Blender MultiLayer file.
    if plain || layers.len() < 2 || layer_rank(&layers[0]) < 2 {
        Vec::new()
    } else {
        layers
    }
}

/// `read_linear_rgb`, and how the file held the colour (for a lookup that reads the file's own
/// texels later, `Textures`).
pub fn read_colour(
    path: &Path,
    max_pixels: u64,
    then_per_pixel: u64,
) -> Result<(Image, ColourLayout)> {
    let read = || -> Result<(Image, ColourLayout)> {
        let (mut reader, info, pixels) = open_input_image(path, max_pixels)?;
        let attrs = reader.attributes();
        let space = attrs
            .iter()
            .find(|a| a.name.eq_ignore_ascii_case("oiio:ColorSpace"))
            .map(|a| a.text.as_str());
        let srgb = srgb_encoded(space, info.codes, &info.format_name);
        let meaning = meaning(&attrs, &info);
        let cube_faces = attrs.iter().any(|a| {
            a.name.eq_ignore_ascii_case("textureformat")
                && a.text.to_ascii_lowercase().starts_with("cubeface")
        });
        let parts = parts_of(&reader, &info);
        let colour = colour_channels(&info.channels)?;
        // The colour's channels as f32 (those from its first to its last: the other passes of
        // a compositor's EXR are not read), then the RGB: refused in one line if that does not
        // fit (an allocation that fails aborts the process).
        let (range, pick) = span_of(colour.indices());
        let nch = range.len();
        let need = pixels * (4 * nch as u64 + 12).max(then_per_pixel);
        check_room(&info, nch, need)?;
        let mut data = read_channels(&mut reader, &info, range)?;
        let decode = |v: f32| if srgb { decode_srgb(v) } else { v };
        // In place where a pixel has three channels or more (pixel i's RGB is written at 3i,
        // at or before where its channels were read from), so that an 8192 x 8192 file is held
        // once, not twice; a grey file of one or two channels grows into a new buffer.
        let rgb = if nch >= 3 {
            for i in 0..pixels as usize {
                let px = pick.map(|c| c.map_or(0.0, |c| decode(data[i * nch + c])));
                data[3 * i..3 * i + 3].copy_from_slice(&px);
            }
            data.truncate(pixels as usize * 3);
            data.shrink_to_fit();
            data
        } else {
            let mut rgb = Vec::with_capacity(pixels as usize * 3);
            for px in data.chunks_exact(nch) {
                rgb.extend(pick.map(|c| c.map_or(0.0, |c| decode(px[c]))));
            }
            rgb
        };
        let img = Image {
            width: info.width,
            height: info.height,
            channels: vec!["R".into(), "G".into(), "B".into()],
            data: rgb,
        };
        Ok((
            img,
            ColourLayout {
                colour,
                srgb,
                parts,
                layers: several_layers(&info.channels),
                cube_faces,
                meaning,
            },
        ))
    };
    let _reading = crate::sys::reading(crash_line(path));
    read().map_err(|e| read_error(path, e))
}

/// The channel of an image (channels `names`, as OIIO names them) that a cut-out mask
/// (`map_d`) reads: the one its `-imfchan` names (`r`, `g`, `b` by name or else by place, `m`
/// the alpha, `l` the grey channel or else the first, `z` the first), or by default its alpha
/// (`A`), else a grey channel (`Y`), else the first; and whether that channel holds a coverage
/// (`true`: named by `-imfchan`, an alpha or a grey channel, or an image of one or two
/// channels) rather than the first channel of a colour image without alpha.
pub fn mask_source(names: &[String], imfchan: Option<char>) -> Result<(usize, bool)> {
    mask_pick(names, imfchan).map(|p| (p.channel, p.coverage))
}

/// Where a mask is read from (`mask_pick`).
struct MaskPick {
    channel: usize,
    coverage: bool,
    /// With no `-imfchan` and an alpha channel read: the channel (and whether it holds a
    /// coverage) to read instead if the alpha is opaque everywhere (a mask saved in the colour
    /// of an RGBA file whose alpha was filled), its grey channel or else its first other one.
    if_opaque: Option<(usize, bool)>,
    /// With `-imfchan l` and no grey channel: the red, green and blue channels whose luminance
    /// is the mask (`LUMINANCE`); `channel` is then the red one.
    luminance: Option<[usize; 3]>,
}

/// The weights of linear red, green and blue in luminance (ITU-R BT.709, as the rest of reframe
/// takes colours): what `-imfchan l` reads from a colour file that has no grey channel.
pub const LUMINANCE: [f32; 3] = [0.2126, 0.7152, 0.0722];

/// `mask_source`, and the channel to read instead where the alpha it picks is opaque.
fn mask_pick(names: &[String], imfchan: Option<char>) -> Result<MaskPick> {
    if names.is_empty() {
        bail!("the image has no channels");
    }
    // The channels a mask is taken from: all of them, or in a multi-layer EXR all of whose
    // channels are in layers those of the layer a colour is read from (`colour_layers`): Blender's
    // alpha is `ViewLayer.Combined.A`, and the file's first channel was its AO pass's red.
    let plain = names.iter().any(|n| layer_of(n).is_none());
    let scope: Vec<usize> = match colour_layers(names).first() {
        Some(layer) if !plain => (0..names.len())
            .filter(|&i| layer_of(&names[i]).is_some_and(|(l, _)| l == layer))
            .collect(),
        _ => (0..names.len()).collect(),
    };
    // A channel by its name, else by its role in any case (`a`, `Alpha`, `diffuse.a`), as the
    // colour's channels are found (a lower-case `r, g, b, a` file read its red as the mask).
    let own = |i: usize| own_name(&names[i]);
    let find = |c: &str| {
        let role_of = |i: usize| c.len() == 1 && role(own(i)) == c.chars().next();
        (scope.iter().copied().find(|&i| own(i) == c))
            .or_else(|| scope.iter().copied().find(|&i| role_of(i)))
    };
    let by_place = |i: usize| scope.get(i).copied();
    let first = Some(scope[0]);
    let (alpha, grey) = (find("A"), find("Y"));
    let picked = match imfchan {
        None => alpha.or(grey).or(first),
        Some('r') => find("R").or_else(|| by_place(0)),
        Some('g') => find("G").or_else(|| by_place(1)),
        Some('b') => find("B").or_else(|| by_place(2)),
        Some('m') => alpha,
        Some('l') => grey.or(first),
        Some(_) => first,
    };
    // The luminance of a colour file's red, green and blue (each found by name or role); an
    // image of fewer channels is grey already.
    let luminance = match (imfchan, grey) {
        (Some('l'), None) => match (find("R"), find("G"), find("B")) {
            (Some(r), Some(g), Some(b)) => Some([r, g, b]),
            _ => None,
        },
        _ => None,
    };
    let picked = luminance.map_or(picked, |[r, _, _]| Some(r));
    let channel = picked.ok_or_else(|| {
        anyhow!(
            "-imfchan {} names a channel it does not have (its channels: {})",
            imfchan.unwrap_or('?'),
            names.join(", ")
        )
    })?;
    let coverage = imfchan.is_some() || alpha.is_some() || grey.is_some() || scope.len() < 3;
    let if_opaque = match (imfchan, alpha) {
        (None, Some(a)) => grey
            .or_else(|| scope.iter().copied().find(|&i| i != a))
            .map(|c| (c, grey.is_some() || scope.len() < 3)),
        _ => None,
    };
    Ok(MaskPick {
        channel,
        coverage,
        if_opaque,
        luminance,
    })
}

/// Where a cut-out mask's file holds its coverage (`read_mask`).
#[derive(Clone, Debug)]
pub struct MaskLayout {
    /// The channel read (its index in the file), and whether it holds a coverage
    /// (`mask_source`).
    pub channel: usize,
    pub coverage: bool,
    /// The red, green and blue channels (their indices in the file) whose luminance is the
    /// mask (`-imfchan l` on a colour file without a grey channel), `channel` then the red.
    pub luminance: Option<[usize; 3]>,
    /// As `ColourLayout`'s: the images the file holds, and its layers of colour where several.
    pub parts: u32,
    pub layers: Vec<String>,
    /// Whether the alpha the mask would have been read from is opaque everywhere, so that
    /// `channel` is the grey or first other channel instead (`MaskPick::if_opaque`).
    pub alpha_opaque: bool,
    /// As `ColourLayout`'s.
    pub meaning: Meaning,
}

/// The images a file holds, from its reader's attributes (`oiio:subimages`, which OIIO sets for
/// some formats) and the count `open_input_image` took.
fn parts_of(reader: &ffi::ImageReader, info: &ffi::ImageInfo) -> u32 {
    reader
        .attributes()
        .iter()
        .find(|a| a.name == "oiio:subimages")
        .map_or(1, |a| a.int_value.max(1) as u32)
        .max(info.images)
}

/// Reads a cut-out mask: the channel `mask_source` picks, as the file holds it (coverage is
/// not a colour: an 8-bit file's codes / 255, never decoded from sRGB), as a one-channel image
/// named `A`, and where the file held it (`MaskLayout`). Refused as `read_colour` refuses.
pub fn read_mask(
    path: &Path,
    max_pixels: u64,
    imfchan: Option<char>,
) -> Result<(Image, MaskLayout)> {
    let read = || -> Result<(Image, MaskLayout)> {
        let (mut reader, info, pixels) = open_input_image(path, max_pixels)?;
        let parts = parts_of(&reader, &info);
        let meaning = meaning(&reader.attributes(), &info);
        let pick = mask_pick(&info.channels, imfchan)?;
        // Only the channels the mask may be in are read (`read_channels`): `at` and
        // `instead_at` are the picked channel's and the one that stands in for an opaque
        // alpha's places among them.
        let lum = |k: usize| pick.luminance.map(|c| c[k]);
        let (range, [at, instead_at, r, g, b]) = span_of([
            Some(pick.channel),
            pick.if_opaque.map(|(c, _)| c),
            lum(0),
            lum(1),
            lum(2),
        ]);
        let nch = range.len();
        let need = pixels * (4 * nch as u64 + 4);
        check_room(&info, nch, need)?;
        let data = read_channels(&mut reader, &info, range)?;
        // An alpha that is opaque everywhere holds no mask: where another channel would cut
        // something out (below one half somewhere), the mask is in it (a DDS or TGA mask of
        // grey in RGB, saved with a filled alpha; the chains of Crytek's Sponza were solid).
        let texels = |c: usize| data.chunks_exact(nch).map(move |px| px[c]);
        let at = at.unwrap_or(0);
        let (channel, coverage, alpha_opaque, local) = match (pick.if_opaque, instead_at) {
            (Some((c, cov)), Some(i))
                if texels(at).all(|a| a >= 1.0) && texels(i).any(|v| v < 0.5) =>
            {
                (c, cov, true, i)
            }
            _ => (pick.channel, pick.coverage, false, at),
        };
        // Below zero a channel reads as zero, in the luminance as in the lookups
        // (`Textures::rgb`); one that is not finite makes the luminance so, to be refused.
        let clamp = |v: f32| if v.is_finite() { v.max(0.0) } else { v };
        let value = |px: &[f32]| match (r, g, b) {
            (Some(r), Some(g), Some(b)) => [r, g, b]
                .iter()
                .zip(LUMINANCE)
                .map(|(&c, w)| w * clamp(px[c]))
                .sum(),
            _ => px[local],
        };
        let img = Image {
            width: info.width,
            height: info.height,
            channels: vec!["A".into()],
            data: data.chunks_exact(nch).map(value).collect(),
        };
        let layout = MaskLayout {
            channel,
            coverage,
            luminance: pick.luminance,
            parts,
            layers: several_layers(&info.channels),
            alpha_opaque,
            meaning,
        };
        Ok((img, layout))
    };
    let _reading = crate::sys::reading(crash_line(path));
    read().map_err(|e| read_error(path, e))
}

/// reframe's metadata as found in the file, as (name, value) pairs: the "reframe:*" attributes
/// with their full names, and the camera matrices under their EXR names ("worldToCamera",
/// "worldToNDC") as 16 space-separated numbers in file order. Numbers are formatted so that they
/// parse back to the same value.
pub fn read_metadata(path: &Path) -> Result<Vec<(String, String)>> {
    let read = || -> Result<Vec<(String, String)>> {
        let reader = open_reader(path)?;
        Ok(reader
            .attributes()
            .into_iter()
            .filter_map(metadata_pair)
            .collect())
    };
    read().map_err(|e| anyhow!("cannot read metadata of {}: {e}", path.display()))
}

fn metadata_pair(a: ffi::Attribute) -> Option<(String, String)> {
    let name = if a.name.starts_with(PREFIX) {
        a.name.clone()
    } else if a.name.eq_ignore_ascii_case(OIIO_WORLD_TO_CAMERA) {
        EXR_WORLD_TO_CAMERA.to_string()
    } else if a.name.eq_ignore_ascii_case(OIIO_WORLD_TO_NDC) {
        EXR_WORLD_TO_NDC.to_string()
    } else {
        return None;
    };
    let value = match a.kind {
        ffi::AttrKind::Int => a.int_value.to_string(),
        ffi::AttrKind::Float => a.float_value.to_string(),
        ffi::AttrKind::Matrix => a
            .matrix
            .iter()
            .map(|v| v.to_string())
            .collect::<Vec<_>>()
            .join(" "),
        _ => a.text,
    };
    Some((name, value))
}

/// Let the image libraries' own parallel work (an EXR frame's compression) use `threads`
/// threads, as the render does, rather than one per core of the machine. Once, before any
/// image is read or written (the command line does it first thing): OpenEXR's pool resized
/// while other threads wrote EXR files left them waiting on it for ever.
/// The line an abort inside the image library prints while `path` is read (`sys::reading`).
pub fn crash_line(path: &Path) -> String {
    format!(
        "error: reading {} crashed the image library (OpenImageIO): the file is damaged, or of a \
         kind it cannot read; convert it (to PNG or EXR, say) and run again\n",
        crate::util::text::printable(&path.display().to_string())
    )
}

/// `Err` where a thread cannot be started (under a tight `ulimit -v`, a thread's stack may not
/// fit): OpenEXR starts its pool at once, and the C++ exception that says so ended the process
/// in `terminate` (exit 134) before a word was said.
pub fn set_threads(threads: usize) -> Result<()> {
    ffi::set_threads(threads.min(i32::MAX as usize) as i32)
        .map_err(|e| anyhow!("cannot start the image library's threads: {}", e.what()))
}

/// The version of the OpenImageIO library in use, e.g. "2.4.7".
pub fn oiio_version() -> String {
    ffi::oiio_version()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colour_comes_from_light_channels_never_from_inks() {
        let names = |n: &[&str]| -> Vec<String> { n.iter().map(|c| c.to_string()).collect() };
        let ok = |n: &[&str]| colour_channels(&names(n)).unwrap();
        assert_eq!(
            ok(&["R", "G", "B", "A"]),
            Colour::Rgb([Some(0), Some(1), Some(2)])
        );
        assert_eq!(
            ok(&["B", "G", "R"]),
            Colour::Rgb([Some(2), Some(1), Some(0)])
        );
        assert_eq!(ok(&["Y", "A"]), Colour::Grey(0));
        assert_eq!(ok(&["X", "Y", "Z"]), Colour::Grey(1));
        // A CMYK TIFF as OpenImageIO hands it over: its Y is yellow, its first three no RGB.
        for inks in [&["C", "M", "Y", "K"][..], &["ink0", "ink1", "ink2", "ink3"]] {
            let e = colour_channels(&names(inks)).unwrap_err().to_string();
            assert!(e.contains("printing inks (CMYK)"), "{e}");
        }
        // R, G, B in mixed case and spelled out, in any order: G and B read as zero where
        // the case differed from R's.
        for rgb in [
            &["R", "g", "b"][..],
            &["r", "G", "B", "A"],
            &["Red", "green", "BLUE"],
        ] {
            assert_eq!(ok(rgb), Colour::Rgb([Some(0), Some(1), Some(2)]), "{rgb:?}");
        }
        assert_eq!(
            ok(&["a", "b", "g", "r"]),
            Colour::Rgb([Some(3), Some(2), Some(1)])
        );
        // Luminance and chroma read as grey Y, or in a layer as RGB.
        for yc in [&["BY", "RY", "Y"][..], &["l.BY", "l.RY", "l.Y"]] {
            let e = colour_channels(&names(yc)).unwrap_err().to_string();
            assert!(e.contains("luminance and chroma (Y, RY, BY)"), "{e}");
        }
        // A mask's alpha in lower case, as the colour's channels are found: it read the red.
        assert_eq!(
            mask_source(&names(&["r", "g", "b", "a"]), None).unwrap().0,
            3
        );
        assert_eq!(
            mask_source(&names(&["a", "b", "g", "r"]), Some('r'))
                .unwrap()
                .0,
            3
        );
        assert_eq!(
            mask_source(&names(&["r", "g", "b", "a"]), Some('m'))
                .unwrap()
                .0,
            3
        );
        // An alpha channel alone, in either case, is no colour.
        for alpha in ["A", "a", "alpha"] {
            assert!(colour_channels(&names(&[alpha])).is_err(), "{alpha}");
        }
        // Red named, green and blue under names that say nothing: read as red alone. Refused;
        // R and G alone (and beside depth or alpha) stay red and green.
        let e = colour_channels(&names(&["red", "grn", "blu"]))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("name red but not green and blue") && e.contains("(grn, blu)"),
            "{e}"
        );
        assert!(colour_channels(&names(&["R", "G", "chan2"])).is_err());
        assert_eq!(ok(&["R", "G"]), Colour::Rgb([Some(0), Some(1), None]));
        assert_eq!(
            ok(&["R", "G", "A", "Z"]),
            Colour::Rgb([Some(0), Some(1), None])
        );
    }

    #[test]
    fn a_multi_layer_file_gives_the_colour_and_the_mask_of_one_layer() {
        let names = |n: &[&str]| -> Vec<String> { n.iter().map(|c| c.to_string()).collect() };
        // Blender's MultiLayer output as OpenImageIO lists it (layers in alphabetical order):
        // the Combined layer, not the AO pass that comes first.
        let blender = names(&[
            "ViewLayer.AO.R",
            "ViewLayer.AO.G",
            "ViewLayer.AO.B",
            "ViewLayer.Combined.R",
            "ViewLayer.Combined.G",
            "ViewLayer.Combined.B",
            "ViewLayer.Combined.A",
            "ViewLayer.Depth.Z",
        ]);
        assert_eq!(
            colour_channels(&blender).unwrap(),
            Colour::Rgb([Some(3), Some(4), Some(5)])
        );
        assert_eq!(
            colour_layers(&blender),
            ["ViewLayer.Combined", "ViewLayer.AO"]
        );
        assert_eq!(mask_source(&blender, None).unwrap(), (6, true));
        assert_eq!(mask_source(&blender, Some('g')).unwrap(), (4, true));
        // Without the Combined layer's alpha: its first channel (a colour's, not a coverage),
        // never the file's first (the AO pass's red).
        let no_alpha: Vec<String> = blender
            .iter()
            .filter(|n| *n != "ViewLayer.Combined.A")
            .cloned()
            .collect();
        assert_eq!(mask_source(&no_alpha, None).unwrap(), (3, false));
        assert_eq!(mask_source(&no_alpha, Some('m')).map(|m| m.0).ok(), None);
        // One layer of colour beside one that is not: never a colour mixed across layers.
        let mixed = names(&["depth.Z", "diffuse.R", "diffuse.G", "diffuse.B"]);
        assert_eq!(
            colour_channels(&mixed).unwrap(),
            Colour::Rgb([Some(1), Some(2), Some(3)])
        );
        assert!(several_layers(&mixed).is_empty());
        // Blender's Combined is the colour without a doubt: nothing to warn of.
        assert!(several_layers(&blender).is_empty());
        // Lower case and spelled out (Nuke's `diffuse.red`), for colour and for a mask.
        let lower = names(&[
            "depth.Z",
            "diffuse.r",
            "diffuse.g",
            "diffuse.b",
            "diffuse.a",
        ]);
        assert_eq!(
            colour_channels(&lower).unwrap(),
            Colour::Rgb([Some(1), Some(2), Some(3)])
        );
        assert_eq!(mask_source(&lower, None).unwrap(), (4, true));
        let nuke = names(&[
            "aa.red",
            "aa.green",
            "aa.blue",
            "rgba.red",
            "rgba.green",
            "rgba.blue",
        ]);
        assert_eq!(
            colour_channels(&nuke).unwrap(),
            Colour::Rgb([Some(3), Some(4), Some(5)])
        );
        // Several layers of colour, none named as a beauty pass: the first in the file's order,
        // with a warning.
        let passes = names(&["spec.R", "spec.G", "spec.B", "diff.R", "diff.G", "diff.B"]);
        assert_eq!(
            colour_channels(&passes).unwrap(),
            Colour::Rgb([Some(0), Some(1), Some(2)])
        );
        assert_eq!(several_layers(&passes), ["spec", "diff"]);
        // Plain R, G, B beside layers are the colour, and nothing is said of the layers.
        let plain = names(&["R", "G", "B", "A", "N.R", "N.G", "N.B"]);
        assert_eq!(
            colour_channels(&plain).unwrap(),
            Colour::Rgb([Some(0), Some(1), Some(2)])
        );
        assert!(several_layers(&plain).is_empty());
        // Layers without colour: the first layer's own channels (here two: grey).
        let data = names(&["depth.Z", "depth.W", "motion.X", "motion.Y"]);
        assert_eq!(colour_channels(&data).unwrap(), Colour::Grey(0));
    }

    /// A deterministic spread of values, including negatives and values above 1.
    fn test_image(width: u32, height: u32, channels: &[&str]) -> Image {
        let mut img = Image::new(width, height, channels);
        for (i, v) in img.data.iter_mut().enumerate() {
            let h = splitmix64(i as u64);
            *v = (h >> 40) as f32 / (1u64 << 24) as f32 * 8.0 - 1.0;
        }
        img
    }

    /// Only the colour's channels are read (`read_channels`), each found at its place among
    /// them: the grey of an XYZ file is its Y, the second channel, among passes after it.
    #[test]
    fn only_the_colour_channels_are_read_at_their_places() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("xyz.exr");
        let mut img = Image::new(4, 2, &["X", "Y", "Z", "p0", "p1"]);
        for (i, px) in img.data.chunks_exact_mut(5).enumerate() {
            px.copy_from_slice(&[0.1, 0.25 + 0.0625 * i as f32, 0.9, 7.0, 8.0]);
        }
        write_image(
            &p,
            &img,
            &test_metadata(),
            &WriteOptions { exr_float: true },
        )
        .unwrap();
        let (rgb, layout) = read_colour(&p, u64::MAX, 0).unwrap();
        assert_eq!(layout.colour, Colour::Grey(1));
        for (i, px) in rgb.data.chunks_exact(3).enumerate() {
            let y = 0.25 + 0.0625 * i as f32;
            assert_eq!(px, [y, y, y], "pixel {i}");
        }
    }

    fn test_metadata() -> Metadata {
        let mut w2c = [0.0f32; 16];
        let mut w2n = [0.0f32; 16];
        for i in 0..16 {
            w2c[i] = i as f32 * 0.25 - 1.1;
            w2n[i] = 1.0 / (i as f32 + 3.0);
        }
        Metadata {
            method: "reuse".into(),
            spp: 256,
            window: 5,
            seed: u64::MAX - 12,
            render_seconds: 12.5,
            world_to_camera: w2c,
            world_to_ndc: w2n,
            extra: vec![
                ("scene".into(), "vase.toml".into()),
                ("frame".into(), "7".into()),
            ],
        }
    }

    fn files_in(dir: &Path) -> Vec<String> {
        let mut names: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }

    /// Each format a frame may be written in reads back whole, at its size, near the pixels
    /// written (a frame is encoded in memory where the writer can: OIIO 2.4's TIFF writer wrote
    /// a file without its height that way).
    #[test]
    fn frames_read_back_in_every_format() {
        let dir = tempfile::tempdir().unwrap();
        let mut img = Image::new(37, 23, &["R", "G", "B"]);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = 0.1 + 0.8 * ((i * 7) % 11) as f32 / 10.0;
        }
        let formats = [
            "exr", "png", "jpg", "tif", "hdr", "tga", "bmp", "ppm", "webp", "dpx", "sgi", "fits",
            "rla",
        ];
        for ext in formats {
            let path = dir.path().join(format!("f.{ext}"));
            write_image(&path, &img, &Metadata::default(), &WriteOptions::default())
                .unwrap_or_else(|e| panic!("{ext}: {e:#}"));
            let back = read_image(&path).unwrap_or_else(|e| panic!("{ext}: {e:#}"));
            assert_eq!((back.width, back.height), (37, 23), "{ext}");
            let n = back.channels.len();
            let mean_error: f64 = (0..37 * 23 * 3)
                .map(|k| {
                    let b = back.data[k / 3 * n + k % 3];
                    (b as f64 - img.data[k] as f64).abs()
                })
                .sum::<f64>()
                / (37.0 * 23.0 * 3.0);
            // 8-bit formats hold sRGB codes: read back as codes here, not linear; lossy
            // formats lose more. What matters is that the file is whole.
            assert!(mean_error < 0.35, "{ext}: mean error {mean_error}");
        }
        assert_eq!(files_in(dir.path()).len(), formats.len());
    }

    #[test]
    fn colour_inputs_read_as_linear_rgb() {
        let dir = tempfile::tempdir().unwrap();
        let mut img = Image::new(4, 2, &["R", "G", "B"]);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = 0.05 + 0.1 * (i % 9) as f32;
        }
        // An 8-bit PNG holds sRGB codes: read back linear, within a code's step.
        let png = dir.path().join("c.png");
        write_image(&png, &img, &Metadata::default(), &WriteOptions::default()).unwrap();
        let back = read_linear_rgb(&png, 1 << 20, 0).unwrap();
        assert_eq!((back.width, back.height, back.channels.len()), (4, 2, 3));
        for (a, b) in img.data.iter().zip(&back.data) {
            assert!((a - b).abs() < 0.01, "{a} read back as {b}");
        }
        // An EXR is linear already; its channels are found by name; a grey image is grey.
        let exr = dir.path().join("c.exr");
        let opts = WriteOptions { exr_float: true };
        write_image(&exr, &img, &Metadata::default(), &opts).unwrap();
        assert_eq!(read_linear_rgb(&exr, 1 << 20, 0).unwrap().data, img.data);
        let mut grey = Image::new(2, 1, &["Y"]);
        grey.data = vec![0.25, 3.0];
        let g = dir.path().join("g.exr");
        write_image(&g, &grey, &Metadata::default(), &opts).unwrap();
        assert_eq!(
            read_linear_rgb(&g, 1 << 20, 0).unwrap().data,
            [0.25, 0.25, 0.25, 3.0, 3.0, 3.0]
        );
        // Too many pixels: refused before reading them.
        let e = read_linear_rgb(&exr, 7, 0).unwrap_err().to_string();
        assert!(e.contains("4x2 pixels, more than the 7"), "{e}");
    }

    #[test]
    fn exr_half_round_trip_within_half_precision() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("half.exr");
        let mut img = test_image(13, 7, &["R", "G", "B", "A"]);
        img.data[0] = 1.0e6; // beyond half range: clamped, not infinity
        img.data[1] = -1.0e6;
        write_image(&path, &img, &Metadata::default(), &WriteOptions::default()).unwrap();
        let back = read_image(&path).unwrap();
        assert_eq!((back.width, back.height), (13, 7));
        assert_eq!(back.channels, img.channels);
        assert_eq!(back.data[0], HALF_MAX);
        assert_eq!(back.data[1], -HALF_MAX);
        for (a, b) in img.data.iter().zip(&back.data).skip(2) {
            // Half has an 11-bit significand: relative error at most 2^-11 after rounding,
            // plus the absolute spacing of its subnormals.
            assert!(
                (a - b).abs() <= a.abs() * 2f32.powi(-11) + 6.0e-8,
                "{a} -> {b}"
            );
        }
        assert!(
            img.data.iter().zip(&back.data).skip(2).any(|(a, b)| a != b),
            "was not stored as half"
        );
    }

    #[test]
    fn a_display_window_past_memory_is_refused_not_an_abort() {
        // An EXR whose header alone is damaged: its display window 10^6 x 10^6 pixels (its
        // data window and pixels whole). The reader's allocation of 24 TB aborted the process
        // (a cached reference, a resumed render's finished frame): now one error.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.exr");
        let img = test_image(9, 11, &["R", "G", "B"]);
        write_image(&path, &img, &Metadata::default(), &WriteOptions::default()).unwrap();
        let mut b = std::fs::read(&path).unwrap();
        let key = b"displayWindow\0box2i\0";
        let at = b.windows(key.len()).position(|w| w == key).unwrap() + key.len() + 4;
        for (k, v) in [0i32, 0, 999_999, 999_999].into_iter().enumerate() {
            b[at + 4 * k..at + 4 * k + 4].copy_from_slice(&v.to_le_bytes());
        }
        std::fs::write(&path, &b).unwrap();
        let e = format!("{:#}", read_image(&path).unwrap_err());
        assert!(
            e.contains("1000000x1000000 pixels of 3 channels needs"),
            "{e}"
        );
    }

    #[test]
    fn exr_float_round_trip_is_exact() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("float.exr");
        let img = test_image(9, 11, &["R", "G", "B"]);
        write_image(
            &path,
            &img,
            &Metadata::default(),
            &WriteOptions { exr_float: true },
        )
        .unwrap();
        assert_eq!(read_image(&path).unwrap(), img);
    }

    #[test]
    fn extra_channels_keep_their_names() {
        // Written in an order that EXR's name-sorted storage does not preserve.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("odd.exr");
        let img = test_image(2, 2, &["spp_eff", "B", "R", "G", "Z"]);
        write_image(
            &path,
            &img,
            &Metadata::default(),
            &WriteOptions { exr_float: true },
        )
        .unwrap();
        let back = read_image(&path).unwrap();
        let mut names = back.channels.clone();
        names.sort();
        assert_eq!(names, ["B", "G", "R", "Z", "spp_eff"]);
        for (c, name) in img.channels.iter().enumerate() {
            let bc = back.channel_index(name).unwrap();
            for y in 0..2 {
                for x in 0..2 {
                    assert_eq!(img.pixel(x, y)[c], back.pixel(x, y)[bc], "{name}");
                }
            }
        }

        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("aov.exr");
        let img = test_image(4, 3, &["R", "G", "B", "spp_eff"]);
        write_image(
            &path,
            &img,
            &Metadata::default(),
            &WriteOptions { exr_float: true },
        )
        .unwrap();
        let back = read_image(&path).unwrap();
        assert_eq!(back.channels, ["R", "G", "B", "spp_eff"]);
        assert_eq!(back, img);
    }

    #[test]
    fn exr_metadata_round_trips_with_types() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("meta.exr");
        let meta = test_metadata();
        write_image(
            &path,
            &test_image(2, 2, &["R", "G", "B"]),
            &meta,
            &WriteOptions::default(),
        )
        .unwrap();

        let got = read_metadata(&path).unwrap();
        let get = |k: &str| {
            got.iter()
                .find(|(n, _)| n == k)
                .unwrap_or_else(|| panic!("{k} missing from {got:?}"))
                .1
                .clone()
        };
        assert_eq!(get("reframe:method"), "reuse");
        assert_eq!(get("reframe:spp"), "256");
        assert_eq!(get("reframe:window"), "5");
        assert_eq!(get("reframe:seed"), (u64::MAX - 12).to_string());
        assert_eq!(get("reframe:render_seconds").parse::<f64>().unwrap(), 12.5);
        assert_eq!(get("reframe:scene"), "vase.toml");
        assert_eq!(get("reframe:frame"), "7");
        let matrix =
            |k: &str| -> Vec<f32> { get(k).split(' ').map(|v| v.parse().unwrap()).collect() };
        assert_eq!(matrix("worldToCamera"), meta.world_to_camera);
        assert_eq!(matrix("worldToNDC"), meta.world_to_ndc);

        // The types and names matter to other tools, not just to our reader.
        let attrs = ffi::open_reader(path_bytes(&path)).unwrap().attributes();
        let kind_of = |name: &str| attrs.iter().find(|a| a.name == name).map(|a| a.kind);
        assert_eq!(kind_of("worldToCamera"), Some(ffi::AttrKind::Matrix));
        assert_eq!(kind_of("worldToNDC"), Some(ffi::AttrKind::Matrix));
        assert_eq!(kind_of("reframe:spp"), Some(ffi::AttrKind::Int));
        assert_eq!(kind_of("reframe:window"), Some(ffi::AttrKind::Int));
        assert_eq!(
            kind_of("reframe:render_seconds"),
            Some(ffi::AttrKind::Float)
        );
        assert_eq!(kind_of("reframe:seed"), Some(ffi::AttrKind::Text));
        assert_eq!(kind_of("reframe:method"), Some(ffi::AttrKind::Text));
    }

    #[test]
    fn exr_header_has_standard_matrix_attributes() {
        // Read the raw header rather than trusting OIIO to read back what it wrote: the point is
        // that other EXR readers find `worldToCamera` / `worldToNDC` of type m44f.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("hdr.exr");
        let meta = test_metadata();
        write_image(
            &path,
            &test_image(2, 2, &["R", "G", "B"]),
            &meta,
            &WriteOptions::default(),
        )
        .unwrap();
        let bytes = fs::read(&path).unwrap();
        let find = |name: &str| -> Vec<f32> {
            let needle = [name.as_bytes(), b"\0m44f\0", &64i32.to_le_bytes()].concat();
            let at = bytes
                .windows(needle.len())
                .position(|w| w == needle.as_slice())
                .unwrap_or_else(|| panic!("no m44f attribute {name} in the EXR header"));
            bytes[at + needle.len()..at + needle.len() + 64]
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
                .collect()
        };
        assert_eq!(find("worldToCamera"), meta.world_to_camera);
        assert_eq!(find("worldToNDC"), meta.world_to_ndc);
    }

    #[test]
    fn colour_files_are_srgb_unless_they_say_they_are_linear_or_store_floats() {
        // (colour space named, integer codes, format, sRGB-encoded): what OIIO 2.4 names (8-bit
        // PNG and JPEG, a PNG with only a gAMA chunk, OpenEXR), then the spaces of newer OIIO
        // versions and OCIO configurations.
        let named = [
            ("sRGB", true, "png", true),
            ("GammaCorrected2.2", true, "png", true),
            ("GammaCorrected1.8", true, "png", true),
            ("GammaCorrected1.0", true, "png", false),
            ("GammaCorrected1", true, "tiff", false),
            ("Linear", false, "openexr", false),
            ("Gamma2.2", true, "png", true),
            ("Gamma1.0", true, "png", false),
            ("g22_rec709", true, "tiff", true),
            ("g10_rec709", true, "tiff", false),
            ("Non-Color", true, "png", false),
            ("Raw", true, "png", false),
            ("srgb_rec709_scene", true, "png", true),
            ("lin_srgb", true, "tiff", false),
            ("scene_linear", true, "tiff", false),
            ("ACEScg", false, "openexr", false),
            // Log encodings are read as their values (and warned of).
            ("ACEScct", true, "png", false),
            ("ACEScc", true, "tiff", false),
            ("KodakLog", true, "dpx", false),
            ("ARRI LogC3 (EI800)", true, "tiff", false),
            ("S-Log3", true, "tiff", false),
        ];
        for (space, integer, format, want) in named {
            assert_eq!(srgb_encoded(Some(space), integer, format), want, "{space}");
        }
        // Nothing named: integers are sRGB (TGA, BMP, TIFF), floats and EXR linear.
        for format in ["targa", "bmp", "tiff", "png"] {
            assert!(srgb_encoded(None, true, format), "{format}");
            assert!(srgb_encoded(Some(""), true, format), "{format}");
        }
        assert!(!srgb_encoded(None, false, "tiff"));
        assert!(!srgb_encoded(None, false, "hdr"));
        for space in [
            "Gamma2.2",
            "GammaCorrected2.2",
            "Gamma0.45",
            "Gamma0",
            "sRGB",
        ] {
            assert!(!srgb_encoded(Some(space), false, "hdr"), "{space}");
        }
        assert!(!srgb_encoded(None, true, "openexr"));
        // A sRGB float file (rare, but named) is decoded as it says.
        assert!(srgb_encoded(Some("sRGB"), false, "tiff"));
    }

    /// Blanks around a channel's name are no part of it: `color.B `, `color.G `, `color.R ` in
    /// an EXR (stored in that order) are blue, green and red, not red, green and blue by place.
    #[test]
    fn channel_names_are_read_without_blanks_around_them() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("spaced.exr");
        let mut img = Image::new(1, 1, &["color.B ", "color.G ", "color.R "]);
        img.data.copy_from_slice(&[0.25, 0.5, 1.0]);
        let opts = WriteOptions { exr_float: true };
        write_image(&path, &img, &test_metadata(), &opts).unwrap();
        let back = read_linear_rgb(&path, 1 << 20, 0).unwrap();
        assert_eq!(back.data, [1.0, 0.5, 0.25]);
    }

    /// An image past the limit is refused with a way to a smaller copy that fits, in its own
    /// format (a JPEG copied into an EXR kept its sRGB codes, read then as linear).
    #[test]
    fn an_image_too_large_names_a_copy_that_fits_in_its_own_format() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("atlas.PNG");
        let img = Image::new(10, 7, &["R", "G", "B"]);
        write_image(&path, &img, &test_metadata(), &WriteOptions::default()).unwrap();
        // 70 pixels against 17: halved twice, 3 x 2.
        let e = read_linear_rgb(&path, 17, 0).unwrap_err().to_string();
        assert!(
            e.ends_with(&format!(
                "10x7 pixels, more than the 17 reframe reads (make a smaller copy in the same \
                 format, e.g. 'oiiotool {} --resize 3x2 -o smaller.png')",
                path.display()
            )),
            "{e}"
        );
        assert!(read_linear_rgb(&path, 70, 0).is_ok());
    }

    #[test]
    fn a_radiance_picture_is_linear_whatever_gamma_its_header_names() {
        // 4 x 2 pixels of radiance 4 (RGBE 128 128 128 131: 0.5 * 2^3), flat (too narrow for
        // run-length rows), with and without a `GAMMA=` line.
        let d = tempfile::tempdir().unwrap();
        for (i, extra) in ["", "GAMMA=2.2\n", "GAMMA=0.4545\n", "GAMMA=0\n"]
            .iter()
            .enumerate()
        {
            let p = d.path().join(format!("s{i}.hdr"));
            let mut bytes =
                format!("#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n{extra}\n-Y 2 +X 4\n").into_bytes();
            for _ in 0..8 {
                bytes.extend([128u8, 128, 128, 131]);
            }
            std::fs::write(&p, bytes).unwrap();
            let (img, layout) = read_colour(&p, 1 << 20, 0).unwrap();
            assert!(!layout.srgb, "{extra:?}");
            assert!(
                img.data.iter().all(|&v| v == 4.0),
                "{extra:?}: {:?}",
                img.data
            );
        }
    }

    #[test]
    fn png_round_trip_of_srgb_values() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("grid.png");
        // Linear values whose sRGB encoding lies exactly on the 8-bit grid: the dither may move
        // them by at most one code.
        let mut img = Image::new(64, 4, &["R", "G", "B", "A"]);
        let mut expected = Vec::new();
        for y in 0..4u32 {
            for x in 0..64u32 {
                let i = ((y * 64 + x) * 4) as usize;
                for c in 0..3u32 {
                    let code = (x * 4 + c + y) % 256;
                    img.data[i + c as usize] = srgb_eotf(code as f64 / 255.0) as f32;
                    expected.push(code as f32 / 255.0);
                }
                img.data[i + 3] = 0.25; // alpha is not written to 8-bit files
            }
        }
        write_image(&path, &img, &test_metadata(), &WriteOptions::default()).unwrap();
        let back = read_image(&path).unwrap();
        assert_eq!(back.channels, ["R", "G", "B"]);
        for (e, b) in expected.iter().zip(&back.data) {
            assert!((e - b).abs() <= 1.0 / 255.0 + 1e-6, "{e} -> {b}");
        }
        assert!(
            expected.iter().zip(&back.data).any(|(e, b)| e != b),
            "no dither applied"
        );

        // Off-grid values: rounding plus +-1 LSB of dither stays within 1.5 codes.
        let img = test_image(32, 32, &["R", "G", "B"]);
        write_image(&path, &img, &Metadata::default(), &WriteOptions::default()).unwrap();
        let back = read_image(&path).unwrap();
        for (v, b) in img.data.iter().zip(&back.data) {
            let e = srgb_oetf(v.clamp(0.0, 1.0) as f64) as f32;
            assert!((e - b).abs() <= 1.5 / 255.0 + 1e-6, "{v} -> {b}");
        }
    }

    /// A Radiance HDR frame reads back within half a step of its 8-bit shared-exponent
    /// mantissa, on average unbiased (OpenImageIO's writer truncates: a frame was 0.4% dark).
    #[test]
    fn hdr_output_rounds_to_nearest() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("ramp.hdr");
        let (w, h) = (64, 32);
        let mut img = Image::new(w, h, &["R", "G", "B"]);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = 0.01 * 1.0007f32.powi((i / 3) as i32) * [1.0, 0.8, 0.55][i % 3];
        }
        write_image(&path, &img, &Metadata::default(), &WriteOptions::default()).unwrap();
        let back = read_image(&path).unwrap();
        let (mut sum, mut n) = (0.0f64, 0);
        for (px, got) in img.data.chunks_exact(3).zip(back.data.chunks_exact(3)) {
            // The step of the exponent stored (the largest channel may round up into the next).
            let m = px[0].max(got[0]);
            let step = 2f32.powi(m.log2().floor() as i32 + 1 - 8);
            for c in 0..3 {
                assert!(
                    (got[c] - px[c]).abs() <= 0.5 * step * 1.001,
                    "{} read back as {} (step {step})",
                    px[c],
                    got[c]
                );
            }
            sum += (got[0] / px[0]) as f64 - 1.0;
            n += 1;
        }
        let mean = sum / n as f64;
        assert!(mean.abs() < 5e-4, "mean relative error {mean}");
    }

    #[test]
    fn png_keeps_metadata_as_text() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("meta.png");
        write_image(
            &path,
            &test_image(2, 2, &["R", "G", "B"]),
            &test_metadata(),
            &WriteOptions::default(),
        )
        .unwrap();
        let got = read_metadata(&path).unwrap();
        assert!(
            got.contains(&("reframe:method".into(), "reuse".into())),
            "{got:?}"
        );
        assert!(
            got.contains(&("reframe:spp".into(), "256".into())),
            "{got:?}"
        );
        assert!(
            got.contains(&("reframe:scene".into(), "vase.toml".into())),
            "{got:?}"
        );
    }

    #[test]
    fn ldr_bytes_are_deterministic() {
        let dir = tempfile::tempdir().unwrap();
        let img = test_image(40, 30, &["R", "G", "B"]);
        let a = encode_srgb8(&img).unwrap();
        assert_eq!(a, encode_srgb8(&img).unwrap());
        for ext in ["png", "jpg", "tif"] {
            let p1 = dir.path().join(format!("a.{ext}"));
            let p2 = dir.path().join(format!("b.{ext}"));
            write_image(&p1, &img, &test_metadata(), &WriteOptions::default()).unwrap();
            write_image(&p2, &img, &test_metadata(), &WriteOptions::default()).unwrap();
            if ext == "tif" {
                // TIFF carries the time of writing, so only the pixels can be compared.
                assert_eq!(read_image(&p1).unwrap(), read_image(&p2).unwrap());
            } else {
                assert_eq!(
                    fs::read(&p1).unwrap(),
                    fs::read(&p2).unwrap(),
                    "{ext} bytes differ"
                );
            }
        }
        // The PNG holds exactly the encoded bytes.
        let back = read_image(&dir.path().join("a.png")).unwrap();
        let codes: Vec<u8> = back
            .data
            .iter()
            .map(|v| (v * 255.0).round() as u8)
            .collect();
        assert_eq!(codes, a);
    }

    #[test]
    fn ldr_clips_and_leaves_black_and_white_undithered() {
        let mut img = Image::new(16, 16, &["R", "G", "B"]);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = [0.0, -3.0, f32::NAN, 1.0, 7.0, f32::INFINITY][i % 6];
        }
        let bytes = encode_srgb8(&img).unwrap();
        for (v, b) in img.data.iter().zip(&bytes) {
            assert_eq!(*b, if *v >= 1.0 { 255 } else { 0 }, "{v}");
        }
    }

    #[test]
    fn ldr_needs_three_channels() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("gray.png");
        let err = write_image(
            &path,
            &Image::new(2, 2, &["Y"]),
            &Metadata::default(),
            &WriteOptions::default(),
        )
        .unwrap_err();
        assert!(err.to_string().contains("gray.png"), "{err}");
        assert!(files_in(dir.path()).is_empty());
    }

    #[test]
    fn write_to_uncreatable_folder_fails_and_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        // A regular file where a folder should be: fails even for root, unlike permissions.
        let blocker = dir.path().join("blocker");
        fs::write(&blocker, b"x").unwrap();
        for name in ["f.exr", "f.png"] {
            let path = blocker.join("sub").join(name);
            let err = write_image(
                &path,
                &test_image(2, 2, &["R", "G", "B"]),
                &test_metadata(),
                &WriteOptions::default(),
            )
            .unwrap_err();
            let msg = err.to_string();
            assert!(msg.contains(path.to_str().unwrap()), "{msg}");
            assert!(!msg.contains('\n'), "{msg}");
            assert!(!path.exists());
            let pattern = OutputPattern::parse(path.to_str().unwrap()).unwrap();
            let err = pattern.validate().unwrap_err().to_string();
            assert!(err.contains(blocker.to_str().unwrap()), "{err}");
        }
        assert_eq!(files_in(dir.path()), ["blocker"]);
    }

    #[test]
    fn failed_rename_removes_the_temporary_file() {
        let dir = tempfile::tempdir().unwrap();
        // The target exists as a non-empty folder, so the final rename fails after OIIO succeeded.
        let target = dir.path().join("taken.exr");
        fs::create_dir(&target).unwrap();
        fs::write(target.join("keep"), b"x").unwrap();
        let err = write_image(
            &target,
            &test_image(2, 2, &["R", "G", "B"]),
            &Metadata::default(),
            &WriteOptions::default(),
        )
        .unwrap_err();
        assert!(err.to_string().contains("taken.exr"), "{err}");
        assert_eq!(files_in(dir.path()), ["taken.exr"]);
        assert!(target.is_dir());
    }

    #[test]
    fn successful_write_leaves_only_the_target() {
        let dir = tempfile::tempdir().unwrap();
        let img = test_image(3, 3, &["R", "G", "B"]);
        for name in ["a.exr", "b.png", "c.jpg", "d.tiff", "e.hdr"] {
            write_image(
                &dir.path().join(name),
                &img,
                &test_metadata(),
                &WriteOptions::default(),
            )
            .unwrap();
        }
        // Overwriting an existing file goes through the same rename.
        write_image(
            &dir.path().join("a.exr"),
            &img,
            &test_metadata(),
            &WriteOptions::default(),
        )
        .unwrap();
        assert_eq!(
            files_in(dir.path()),
            ["a.exr", "b.png", "c.jpg", "d.tiff", "e.hdr"]
        );
        assert_eq!(
            read_image(&dir.path().join("e.hdr")).unwrap().channels,
            ["R", "G", "B"]
        );
    }

    #[test]
    fn validate_rejects_unknown_extension() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("frame_####.xyz");
        let pattern = OutputPattern::parse(p.to_str().unwrap()).unwrap();
        let err = pattern.validate().unwrap_err().to_string();
        assert!(err.contains("frame_####.xyz"), "{err}");
        assert!(!err.contains('\n'), "{err}");
    }

    #[test]
    fn validate_creates_the_folder_and_leaves_no_probe() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("new/deeper/vase_####.exr");
        let pattern = OutputPattern::parse(p.to_str().unwrap()).unwrap();
        // Not kept (a refusal after the check): both folders it created go again.
        drop(pattern.validate().unwrap());
        assert!(!dir.path().join("new").exists());
        // Kept (the render goes ahead): they stay, empty.
        pattern.validate().unwrap().keep();
        assert!(dir.path().join("new/deeper").is_dir());
        assert!(files_in(&dir.path().join("new/deeper")).is_empty());
        // A folder that was there already is never removed.
        drop(pattern.validate().unwrap());
        assert!(dir.path().join("new/deeper").is_dir());
    }

    #[test]
    fn pattern_padding_and_wide_numbers() {
        let p = OutputPattern::parse("out/vase_####.exr").unwrap();
        assert!(p.has_frame_field());
        assert_eq!(p.path(7), PathBuf::from("out/vase_0007.exr"));
        assert_eq!(p.path(0), PathBuf::from("out/vase_0000.exr"));
        assert_eq!(p.to_string(), "out/vase_####.exr");
        let p = OutputPattern::parse("f##.png").unwrap();
        assert_eq!(p.path(12345), PathBuf::from("f12345.png"));
        assert_eq!(p.path(3), PathBuf::from("f03.png"));
        let p = OutputPattern::parse("still.png").unwrap();
        assert!(!p.has_frame_field());
        assert_eq!(p.path(9), PathBuf::from("still.png"));
        assert_eq!(
            OutputPattern::parse("####.exr").unwrap().path(1),
            PathBuf::from("0001.exr")
        );
    }

    /// `frame_named` inverts `path` on file names, and names no frame for names the pattern
    /// never writes: padded wider than the run, another stem or extension, too few digits.
    #[test]
    fn a_file_name_gives_its_frame() {
        let p = OutputPattern::parse("out/v_####-L.exr").unwrap();
        for f in [0, 7, 9999, 10000, 123456, u32::MAX] {
            let name = p.path(f).file_name().unwrap().to_str().unwrap().to_string();
            assert_eq!(p.frame_named(&name), Some(f), "{name}");
        }
        for name in [
            "v_012-L.exr",
            "v_012345-L.exr",
            "v_0012-R.exr",
            "v_0012-L.png",
            "w_0012-L.exr",
            "out/v_0012-L.exr",
            "v_+012-L.exr",
            "v_99999999999-L.exr",
        ] {
            assert_eq!(p.frame_named(name), None, "{name}");
        }
        let p = OutputPattern::parse("####.exr").unwrap();
        assert_eq!(p.frame_named("0012.exr"), Some(12));
        assert_eq!(
            OutputPattern::parse("v_0012.exr")
                .unwrap()
                .frame_named("v_0012.exr"),
            None
        );
    }

    #[test]
    fn pattern_errors() {
        for bad in [
            "",
            "  ",
            "out/",
            "out/vase",
            "out/vase_####",
            "a_##_##.exr",
            "out_##/x.exr",
            "x.e##",
            "out/.exr",
        ] {
            let err = OutputPattern::parse(bad);
            assert!(err.is_err(), "{bad:?} was accepted");
            assert!(!err.unwrap_err().to_string().contains('\n'));
        }
    }

    #[test]
    fn ldr_and_hdr_extensions() {
        for (s, ldr) in [
            ("a.png", true),
            ("a.JPG", true),
            ("a.jpeg", true),
            ("a.tif", true),
            ("a.tiff", true),
            ("a.exr", false),
            ("a.EXR", false),
            ("a.hdr", false),
        ] {
            assert_eq!(OutputPattern::parse(s).unwrap().is_ldr(), ldr, "{s}");
        }
    }

    #[test]
    fn read_missing_file_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("missing.exr");
        let err = read_image(&path).unwrap_err().to_string();
        assert!(err.contains("missing.exr"), "{err}");
        assert!(read_metadata(&path).is_err());
    }

    #[test]
    fn metadata_keys_must_be_unique() {
        let dir = tempfile::tempdir().unwrap();
        let mut meta = test_metadata();
        meta.extra.push(("spp".into(), "1".into()));
        let path = dir.path().join("dup.exr");
        assert!(write_image(
            &path,
            &test_image(2, 2, &["R", "G", "B"]),
            &meta,
            &WriteOptions::default()
        )
        .is_err());
        assert!(files_in(dir.path()).is_empty());
    }

    #[test]
    fn version_is_reported() {
        let v = oiio_version();
        assert!(
            v.split('.').count() == 3 && v.chars().next().unwrap().is_ascii_digit(),
            "{v}"
        );
    }
}
