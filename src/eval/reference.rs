//! `reframe reference`: the high-sample reference frames that `compare` measures against.
//!
//! The independent tracer at `--reference-spp`, as `PASSES` passes with their own seeds: the
//! mean is the reference `R` and the spread of the passes gives the variance of that mean per
//! pixel and channel, `V = sum_k (p_k - R)^2 / (K (K - 1))`. The frames are cached as EXR
//! (channels R, G, B, var.R, var.G, var.B) in a folder whose name carries a key: a hash of the
//! loaded scene (geometry, materials, camera path), the resolution, the frames, the sample count,
//! the path depth and the reframe executable itself, so that any change to the scene, the
//! settings or the code renders it anew. A folder is used only once its `reference.json`
//! (written last) is there.
use crate::camera::Camera;
use crate::driver::options::{check_max_depth, check_spp};
use crate::driver::{progress_bar, render_frame_independent};
use crate::image::{read_image, write_image, Image, Metadata, WriteOptions};
use crate::integrator::{Integrator, RayCounts};
use crate::scene::Scene;
use crate::state::key::scene_and_build_hashes;
use crate::util::fs::{check_writable_dir, write_json};
use crate::util::hash::Fnv;
use crate::util::input::{open_input_or_missing, InputError};
use anyhow::{bail, Context, Result};
use glam::Vec3;
use serde::{Deserialize, Serialize};
use std::ops::RangeInclusive;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Passes the reference is split into, for its per-pixel variance.
pub const PASSES: u32 = 8;
/// Seed of the reference's first pass; compare's runs use `--seed` (small numbers).
const REFERENCE_SEED: u64 = 0x7265_6672_616d_6500;
/// One reference frame: the mean and the variance of the mean, per pixel.
pub struct RefFrame {
    pub mean: Vec<Vec3>,
    pub var: Vec<Vec3>,
}

pub struct Reference {
    pub first: u32,
    pub frames: Vec<RefFrame>,
    pub dir: PathBuf,
    pub spp: u32,
    /// Found in the cache (nothing rendered).
    pub cached: bool,
    /// Render time when it was made.
    pub seconds: f64,
}

/// What marks a cached reference as complete and what it was made from.
#[derive(Serialize, Deserialize)]
struct ReferenceInfo {
    scene: String,
    width: u32,
    height: u32,
    first_frame: u32,
    last_frame: u32,
    spp: u32,
    passes: u32,
    #[serde(default)]
    max_depth: u32,
    key: String,
    seconds: f64,
    /// Each frame's content hash (`frame_digest`), in order: a frame changed or damaged since
    /// (a file replaced by another frame's, a value edited) is found and made again.
    #[serde(default)]
    digests: Vec<String>,
}

/// The hash of a reference frame's values (mean and variance, as f32 bits) under the entry's
/// key, so that a frame of another entry (another scene's, copied in with its description)
/// does not pass for this one's.
fn frame_digest(key: &str, f: &RefFrame) -> String {
    let mut h = Fnv::default();
    h.bytes(key.as_bytes());
    h.f32s(f.mean.iter().chain(&f.var).flat_map(|v| v.to_array()));
    h.hex()
}

/// The cached frames of a reference if its description is the one asked for (`want`: every
/// field but the time and the digests) and every frame reads back as it was made; why not,
/// else. An entry copied or renamed from another reference (another scene's, another sample
/// count's) was read as this one, and `compare` measured against it.
fn read_cached(
    info: &ReferenceInfo,
    want: &ReferenceInfo,
    range: &RangeInclusive<u32>,
    frame_path: impl Fn(u32) -> PathBuf,
) -> Result<Vec<RefFrame>> {
    let fields = [
        ("scene", info.scene.clone(), want.scene.clone()),
        ("key", info.key.clone(), want.key.clone()),
        ("width", info.width.to_string(), want.width.to_string()),
        ("height", info.height.to_string(), want.height.to_string()),
        (
            "first_frame",
            info.first_frame.to_string(),
            want.first_frame.to_string(),
        ),
        (
            "last_frame",
            info.last_frame.to_string(),
            want.last_frame.to_string(),
        ),
        ("spp", info.spp.to_string(), want.spp.to_string()),
        ("passes", info.passes.to_string(), want.passes.to_string()),
        (
            "max_depth",
            info.max_depth.to_string(),
            want.max_depth.to_string(),
        ),
    ];
    if let Some((name, got, wanted)) = fields.iter().find(|(_, a, b)| a != b) {
        bail!("its description's {name} is {got}, not {wanted}: it is another reference's");
    }
    if !(info.seconds.is_finite() && info.seconds >= 0.0) {
        bail!("its description's seconds, {}, is no time", info.seconds);
    }
    let (w, h) = (want.width, want.height);
    let mut frames = Vec::new();
    for (k, f) in range.clone().enumerate() {
        let path = frame_path(f);
        let frame = read_reference_frame(&path, w, h)?;
        if info.digests.get(k) != Some(&frame_digest(&want.key, &frame)) {
            bail!("frame {f} is not the one that was made");
        }
        // What the file says it is (a frame swapped with another together with their digests).
        let md = crate::image::read_metadata(&path).unwrap_or_default();
        let said = |k: &str| md.iter().find(|(n, _)| n == k).map(|(_, v)| v.as_str());
        if said("reframe:frame") != Some(&f.to_string()) {
            bail!(
                "{} says it is frame {}, not {f}",
                path.display(),
                said("reframe:frame").unwrap_or("none")
            );
        }
        frames.push(frame);
    }
    Ok(frames)
}

/// The cache key of a reference (see the module note).
pub fn reference_key(
    scene: &Scene,
    range: &RangeInclusive<u32>,
    (w, h): (u32, u32),
    spp: u32,
    max_depth: u32,
) -> Result<String> {
    let (scene_hash, build_hash) = scene_and_build_hashes(scene)?;
    let mut f = Fnv::default();
    f.bytes(scene_hash.as_bytes());
    f.bytes(build_hash.as_bytes());
    for v in [*range.start(), *range.end(), w, h, spp, PASSES, max_depth] {
        f.bytes(&v.to_le_bytes());
    }
    Ok(f.hex())
}

/// The lock of the cache entry `dir` (`cache/.NAME.lock`), held until dropped: taken at once,
/// or after waiting (with a note) for the process that holds it. The lock file stays (a process
/// waiting on it must find the same file when its holder is done). `None` where the cache
/// folder cannot be made or the lock cannot be opened (a cache shared read-only: its finished
/// entries are read unlocked, and a missing one fails where it cannot be written). A folder, a
/// link or a FIFO planted at the lock's path is refused, as at an output's lock: the run had
/// gone on unlocked, and two processes could render one entry at once.
fn lock_entry(cache: &Path, dir: &Path) -> Result<Option<std::fs::File>> {
    use std::os::unix::fs::OpenOptionsExt;
    if std::fs::create_dir_all(cache).is_err() {
        return Ok(None);
    }
    let name = dir.file_name().unwrap_or_default().to_string_lossy();
    let path = cache.join(format!(".{name}.lock"));
    let opened = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK)
        .open(&path);
    // Planted in the lock's place, a link, a folder or a FIFO is refused (as an output's lock
    // is); any other failure to open it (a read-only cache, a full disk) reads unlocked. A hard
    // link is harmless here (nothing is written in the lock): a cache copied with `cp -al`.
    let planted = matches!(
        opened.as_ref().map_err(|e| e.raw_os_error()),
        Err(Some(libc::ELOOP | libc::EISDIR))
    ) || opened
        .as_ref()
        .is_ok_and(|f| !f.metadata().is_ok_and(|m| m.is_file()));
    if planted {
        crate::util::fs::open_own_file(&path, "the reference cache's lock file")?;
    }
    let Ok(f) = opened else {
        return Ok(None);
    };
    if f.try_lock().is_err() {
        errln!(
            "note: another reframe is rendering this reference (its lock is {}); waiting for it",
            crate::util::text::printable(&path.display().to_string())
        );
        f.lock()
            .with_context(|| format!("waiting for the lock {}", path.display()))?;
    }
    Ok(Some(f))
}

/// The reference of `range` at `w` x `h`: from the cache when there, else rendered and cached.
#[allow(clippy::too_many_arguments)]
pub fn reference(
    scene: &Scene,
    range: RangeInclusive<u32>,
    (w, h): (u32, u32),
    spp: u32,
    max_depth: u32,
    cache: &Path,
    pool: &rayon::ThreadPool,
    progress: bool,
) -> Result<Reference> {
    // (The passes first: 0 is refused as not a multiple of them, not as "at least one".)
    if spp < PASSES || !spp.is_multiple_of(PASSES) {
        bail!("--reference-spp {spp}: must be a multiple of {PASSES}, at least {PASSES} (the reference is {PASSES} passes, for its variance)");
    }
    check_spp("--reference-spp", spp)?;
    check_max_depth(max_depth)?;
    // The cache is a folder (made if missing); anything else at its path, or on the way to it,
    // is said as such before the reference is rendered.
    if let Some(p) = cache.ancestors().find(|p| p.exists()) {
        if !p.is_dir() {
            let what = std::fs::metadata(p)
                .map_or("not a folder", |m| crate::util::input::kind(m.file_type()));
            bail!(
                "--cache {}: {} is {what}, not a folder (the cache is a folder of references)",
                cache.display(),
                p.display()
            );
        }
    }
    let key = reference_key(scene, &range, (w, h), spp, max_depth)?;
    let (first, last) = (*range.start(), *range.end());
    let dir = cache.join(format!(
        "{}_{w}x{h}_f{first}-{last}_{spp}spp_d{max_depth}_{key}",
        scene.name
    ));
    // One process renders an entry at a time: another that wants it waits, then reads it from
    // the cache (two `compare` jobs sharing a cache both rendered the same reference).
    let _entry = lock_entry(cache, &dir)?;
    let info_path = dir.join("reference.json");
    let frame_path = |f: u32| dir.join(format!("ref_{f:04}.exr"));
    // Read as any input is (a FIFO or a device planted there is refused, not waited on); a
    // description cut short or damaged is a damaged cache, made again like a damaged frame.
    let text = match open_input_or_missing(&info_path, "cached reference description", 1 << 20) {
        Ok(mut f) => {
            use std::io::Read;
            let mut text = String::new();
            f.read_to_string(&mut text).map(|_| text).ok()
        }
        Err(InputError::NotFound(_)) => None,
        Err(InputError::Refused(why)) => bail!("{why}"),
    };
    // What this entry's description says, but for the time and the frames' hashes.
    let want = ReferenceInfo {
        scene: scene.name.clone(),
        width: w,
        height: h,
        first_frame: first,
        last_frame: last,
        spp,
        passes: PASSES,
        max_depth,
        key: key.clone(),
        seconds: 0.0,
        digests: vec![],
    };
    // Where the entry is to be written again, each of its files must be one a rename can
    // replace: a folder, a link, a FIFO or a device in a frame's place was found only after
    // the whole reference had been rendered again. Nor is an entry written through a link to
    // another folder: two entries linked to one folder (a cache shared by links) rendered over
    // each other in turn, each finding the other's reference in its place.
    let linked = || -> Result<()> {
        if dir
            .symlink_metadata()
            .is_ok_and(|m| m.file_type().is_symlink())
        {
            let to =
                std::fs::read_link(&dir).map_or_else(|_| "?".into(), |t| t.display().to_string());
            bail!(
                "{} is a symbolic link (to {to}), and an entry is written in a folder of its own, \
                 never through a link: remove the link (the reference is then made there)",
                dir.display()
            );
        }
        Ok(())
    };
    let replaceable = linked().and_then(|()| {
        range
            .clone()
            .map(frame_path)
            .chain([info_path.clone()])
            .try_for_each(|p| crate::util::fs::check_replaceable(&p))
    });
    if let Some(text) = text {
        let info = serde_json::from_str::<ReferenceInfo>(&text)
            .map_err(|e| {
                anyhow::anyhow!(crate::util::text::plain_types(&e.to_string(), "an object"))
            })
            .with_context(|| format!("{}: not a reference description", info_path.display()));
        let cached = info.and_then(|info| {
            read_cached(&info, &want, &range, frame_path).map(|frames| (info, frames))
        });
        match (cached, &replaceable) {
            (Ok((info, frames)), _) => {
                return Ok(Reference {
                    first,
                    frames,
                    dir,
                    spp,
                    cached: true,
                    seconds: info.seconds,
                })
            }
            (Err(e), Err(why)) => {
                bail!(
                    "the cached reference in {} is damaged ({e:#}), and cannot be made again \
                     in its place: {why:#}",
                    dir.display()
                );
            }
            // A cache is a copy of what can be made again: made again, said once.
            (Err(e), Ok(())) => errln!(
                "warning: {}",
                crate::util::text::message(&format!(
                    "the cached reference in {} is damaged ({e:#}); rendering it again",
                    dir.display()
                ))
            ),
        }
    }
    replaceable
        .with_context(|| format!("the cached reference in {} cannot be made", dir.display()))?;
    // Removed again if nothing is written in it (an error, a stop by signal).
    let _made = crate::util::fs::MadeFolder::create(&dir)
        .with_context(|| format!("creating {}", dir.display()))?;
    check_writable_dir(&dir)?;
    let integrator = Integrator::new(scene, max_depth);
    let n = (last - first + 1) as u64;
    let pb = progress_bar(progress, n * PASSES as u64, "reference passes");
    let start = Instant::now();
    let mut frames = Vec::new();
    for f in range.clone() {
        let cam = scene.camera(f, w, h);
        let none = |_: &RayCounts| {};
        let passes: Vec<Vec<Vec3>> = (0..PASSES as u64)
            .map(|k| {
                let px = pool.install(|| {
                    render_frame_independent(
                        &integrator,
                        &cam,
                        f,
                        spp / PASSES,
                        REFERENCE_SEED + k,
                        false,
                        &none,
                    )
                    .pixels
                });
                pb.inc(1);
                px
            })
            .collect();
        let k = PASSES as f32;
        let mean: Vec<Vec3> = (0..passes[0].len())
            .map(|i| passes.iter().map(|p| p[i]).sum::<Vec3>() / k)
            .collect();
        let var: Vec<Vec3> = (0..mean.len())
            .map(|i| {
                passes
                    .iter()
                    .map(|p| (p[i] - mean[i]) * (p[i] - mean[i]))
                    .sum::<Vec3>()
                    / (k * (k - 1.0))
            })
            .collect();
        write_reference_frame(&frame_path(f), scene, &cam, f, spp, &mean, &var)?;
        frames.push(RefFrame { mean, var });
    }
    pb.finish_and_clear();
    let seconds = start.elapsed().as_secs_f64();
    let digests = frames.iter().map(|f| frame_digest(&key, f)).collect();
    write_json(
        &info_path,
        &ReferenceInfo {
            seconds,
            digests,
            ..want
        },
    )?;
    Ok(Reference {
        first,
        frames,
        dir,
        spp,
        cached: false,
        seconds,
    })
}

fn write_reference_frame(
    path: &Path,
    scene: &Scene,
    cam: &Camera,
    frame: u32,
    spp: u32,
    mean: &[Vec3],
    var: &[Vec3],
) -> Result<()> {
    let mut img = Image::new(
        cam.width,
        cam.height,
        &["R", "G", "B", "var.R", "var.G", "var.B"],
    );
    img.data = mean
        .iter()
        .zip(var)
        .flat_map(|(m, v)| m.to_array().into_iter().chain(v.to_array()))
        .collect();
    let meta = Metadata {
        method: "reference".into(),
        spp,
        window: 1,
        seed: REFERENCE_SEED,
        render_seconds: 0.0,
        world_to_camera: cam.world_to_camera().to_cols_array(),
        world_to_ndc: cam.world_to_ndc().to_cols_array(),
        extra: vec![
            ("scene".into(), scene.name.clone()),
            ("frame".into(), frame.to_string()),
        ],
    };
    write_image(path, &img, &meta, &WriteOptions { exr_float: true })
}

fn read_reference_frame(path: &Path, w: u32, h: u32) -> Result<RefFrame> {
    let img = read_image(path).with_context(|| "the cached reference is incomplete")?;
    if (img.width, img.height) != (w, h) {
        bail!(
            "{}: {}x{}, expected {w}x{h}",
            path.display(),
            img.width,
            img.height
        );
    }
    let ch = |name: &str| {
        img.channel_index(name)
            .with_context(|| format!("{}: no channel {name}", path.display()))
    };
    let idx = [
        ch("R")?,
        ch("G")?,
        ch("B")?,
        ch("var.R")?,
        ch("var.G")?,
        ch("var.B")?,
    ];
    let nc = img.channels.len();
    let at = |i: usize, c: usize| img.data[i * nc + idx[c]];
    let n = (w * h) as usize;
    Ok(RefFrame {
        mean: (0..n)
            .map(|i| Vec3::new(at(i, 0), at(i, 1), at(i, 2)))
            .collect(),
        var: (0..n)
            .map(|i| Vec3::new(at(i, 3), at(i, 4), at(i, 5)))
            .collect(),
    })
}
