//! Textures for the materials' `map_Kd`, `map_Ks` and `map_Ke`, looked up through OpenImageIO's
//! `TextureSystem` (its image cache: tiled and MIP-mapped files are read a tile at a time, many
//! textures share a memory budget, any format OIIO reads).
//!
//! Each file is decoded once, whole, when the scene loads, so that a missing, unreadable or
//! damaged texture is refused before the first ray (the cache itself would only meet a damaged
//! tile during the render); the pixels are then dropped and the cache reads what lookups need.
//!
//! A lookup is bilinear on the finest level, repeating outside \[0, 1): a point lookup with no
//! footprint. The film's samples average the texture over each pixel, as they average
//! everything else; a footprint-driven MIP level would make a first hit's value depend on the
//! eye whose pixel it was traced for, which frame reuse cannot have (one hit is shaded for every
//! eye of a group), and it would blur the converged image away from the scene as modelled.
//!
//! The filtering is done here, in linear values: the cache gives the four texels around the
//! point (`get_texels`), each is decoded from sRGB where the file is 8-bit sRGB (OIIO's
//! `oiio:ColorSpace`), and then they are interpolated. OIIO 2.4's texture system has no colour
//! conversion, and its own bilinear lookup of an sRGB file interpolates the encoded values,
//! which darkens every edge between texels (down to half, between black and white) and a
//! texture's mean by a few percent against renderers that filter radiance.
//!
//! ```no_run
//! use reframe::image::Textures;
//! let mut t = Textures::new()?;
//! let id = t.open(std::path::Path::new("wood.png"))?;
//! let rgb = t.rgb(id, glam::Vec2::new(0.25, 0.5));
//! # anyhow::Ok(())
//! ```
use super::bridge::ffi;
use super::{decode_srgb, path_bytes, read_colour, read_mask, Colour, ColourLayout, MaskLayout};
use crate::util::hash::Fnv;
use anyhow::{anyhow, bail, Result};
use glam::{Vec2, Vec3};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Most texels of one texture (8192 x 8192): each is decoded once when the scene loads.
pub const MAX_TEXELS: u64 = 1 << 26;

/// The texture cache's need and its limit, in MB, for textures of `bytes` in memory and
/// `available` bytes of memory (`None`: unknown): all of them and a margin, within three
/// quarters of the memory available, and never below OpenImageIO's default of 1024.
fn cache_limit(bytes: u64, available: Option<u64>) -> (f64, f64) {
    const MB: f64 = 1e6;
    let need = bytes as f64 * 1.05 / MB + 64.0;
    let cap = available.map_or(f64::INFINITY, |a| 0.75 * a as f64 / MB);
    // Never below OpenImageIO's default of 1 GB, unless that passes the cap.
    (need, need.min(cap).max(1024f64.min(cap)))
}

/// A texture of a `Textures`, by index.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TextureId(u32);

/// The most channels a texture's colour may be spread over (`texels` fetches them all).
const MAX_SPREAD: usize = 16;

struct Info {
    width: u32,
    height: u32,
    /// Channels fetched per texel (from the first colour channel to the last), and where red,
    /// green and blue are among them (`None`: zero).
    fetched: usize,
    pick: [Option<usize>; 3],
    srgb: bool,
    /// FNV-1a of the decoded texels and the size: the texture's identity in a scene's hash.
    digest: u64,
    /// The largest linear value of each colour channel (red, green, blue), for the emission
    /// cap's check (`Maps::open`).
    max: [f32; 3],
    /// The file's layers of colour where it holds several, the one read first
    /// (`ColourLayout::layers`).
    layers: Vec<String>,
    /// The images its file holds (`ColourLayout::parts`, `MaskLayout::parts`).
    parts: u32,
    /// The file, and for a mask whether it reads the first channel of a colour image without
    /// alpha (`image::mask_source`) and whether it does so because the alpha is opaque
    /// everywhere (`MaskLayout::alpha_opaque`).
    path: PathBuf,
    colour_mask: bool,
    alpha_opaque: bool,
    /// Values below zero in the texels read (`check_texels`), which lookups read as zero.
    negatives: u64,
    /// Whether every texel read is zero or below (a mask that cuts away everything).
    zero: bool,
    /// Whether the mask is the luminance of the colour fetched (`image::LUMINANCE`), not its
    /// first channel.
    luminance: bool,
    /// What its file says of its pixels that is not applied (`image::Meaning`).
    meaning: super::Meaning,
}

/// Refuses a texture with a texel that is not finite; the texels below zero, which lookups read
/// as zero (a photograph's: debayering, a change of colour space and lossy EXR compression leave
/// small negative values, and such files were refused whole).
fn check_texels(path: &Path, data: &[f32]) -> Result<u64> {
    if let Some(v) = data.iter().find(|v| !v.is_finite()) {
        bail!(
            "cannot use {}: it has a texel of {v} (textures must be finite)",
            path.display()
        );
    }
    Ok(data.iter().filter(|v| **v < 0.0).count() as u64)
}

/// The file a texture key names, as `Textures::by_file` keys it: its device and inode (after
/// symbolic links) and the key's mask channel; `None` where it cannot be read.
fn file_key(key: &(PathBuf, Option<Option<char>>)) -> Option<(u64, u64, Option<Option<char>>)> {
    let (dev, ino) = crate::util::fs::file_id(&key.0)?;
    Some((dev, ino, key.1))
}

/// The textures of a scene and the texture system they are looked up through.
pub struct Textures {
    set: cxx::UniquePtr<ffi::TextureSet>,
    info: Vec<Info>,
    /// The textures open, by path and, for a mask (`open_mask`), its `-imfchan`.
    by_path: HashMap<(PathBuf, Option<Option<char>>), TextureId>,
    /// The same by the file itself (its device and inode): one file under other names (hard
    /// links, symbolic links, `./a.png` and `sub/../a.png`) is decoded and cached once. Two
    /// hundred hard links to one 2048 x 2048 PNG, each the map of a material, took over a
    /// minute to load, every name decoded again.
    by_file: HashMap<(u64, u64, Option<Option<char>>), TextureId>,
    /// Lookups the texture system failed (a file changed or vanished during the render); they
    /// return black.
    failures: AtomicU64,
    /// Bytes the cache holds once every texture is read, within its limit (`size_cache`).
    cache_use: u64,
}

impl Textures {
    pub fn new() -> Result<Textures> {
        let set = ffi::new_texture_set().map_err(|e| anyhow!("{}", e.what()))?;
        Ok(Textures {
            set,
            info: Vec::new(),
            by_path: HashMap::new(),
            by_file: HashMap::new(),
            failures: AtomicU64::new(0),
            cache_use: 0,
        })
    }

    /// How many textures are open.
    pub fn len(&self) -> usize {
        self.info.len()
    }

    pub fn is_empty(&self) -> bool {
        self.info.is_empty()
    }

    /// Open the texture at `path` (once: the same path gives the same id). Refused: a file that
    /// is missing or no image, damaged anywhere in its pixels, larger than `MAX_TEXELS`, with a
    /// texel that is negative or not finite.
    pub fn open(&mut self, path: &Path) -> Result<TextureId> {
        let key = (path.to_path_buf(), None);
        if let Some(id) = self.known(&key) {
            return Ok(id);
        }
        // Decoded whole once, for the checks; the cache reads it again on demand.
        let (
            img,
            ColourLayout {
                colour,
                srgb,
                parts,
                layers,
                meaning,
                ..
            },
        ) = read_colour(path, MAX_TEXELS, 0)?;
        let negatives = check_texels(path, &img.data)?;
        let used = colour.indices().into_iter().flatten();
        let (first, last) = (used.clone().min().unwrap_or(0), used.max().unwrap_or(0));
        if last - first >= MAX_SPREAD {
            bail!(
                "cannot use {}: its colour channels are {} channels apart (at most {MAX_SPREAD})",
                path.display(),
                last - first
            );
        }
        let id = self
            .set
            .pin_mut()
            .add(path_bytes(path), first as u32, last as u32 + 1)
            .map_err(|e| anyhow!("cannot open {} as a texture: {}", path.display(), e.what()))?;
        let pick = match colour {
            Colour::Grey(c) => [Some(c - first); 3],
            Colour::Rgb(c) => c.map(|c| c.map(|c| c - first)),
        };
        Ok(self.add(
            key,
            id,
            &img,
            (last - first + 1, pick, srgb, parts, layers),
            (false, false),
            (negatives, meaning),
        ))
    }

    /// Open the texture at `path` as a cut-out mask (once: a second time gives the same id):
    /// the channel `imfchan` names, or by default its alpha channel, else its grey one, else its
    /// first (`image::mask_source`), as the file holds it (never decoded from sRGB: coverage is
    /// not a colour). `value` looks it up. Refused as `open` refuses.
    pub fn open_mask(&mut self, path: &Path, imfchan: Option<char>) -> Result<TextureId> {
        let key = (path.to_path_buf(), Some(imfchan));
        if let Some(id) = self.known(&key) {
            return Ok(id);
        }
        let (
            img,
            MaskLayout {
                channel,
                coverage,
                parts,
                layers,
                alpha_opaque,
                meaning,
                luminance,
            },
        ) = read_mask(path, MAX_TEXELS, imfchan)?;
        let negatives = check_texels(path, &img.data)?;
        // The channels fetched: the mask's one, or the span of the three whose luminance it is.
        let (first, last, pick) = match luminance {
            Some(c) => {
                let (lo, hi) = (c.iter().min().unwrap(), c.iter().max().unwrap());
                (*lo, *hi, c.map(|c| Some(c - lo)))
            }
            None => (channel, channel, [Some(0), None, None]),
        };
        let id = self
            .set
            .pin_mut()
            .add(path_bytes(path), first as u32, last as u32 + 1)
            .map_err(|e| anyhow!("cannot open {} as a texture: {}", path.display(), e.what()))?;
        let id = self.add(
            key,
            id,
            &img,
            (last - first + 1, pick, false, parts, layers),
            (!coverage, alpha_opaque),
            (negatives, meaning),
        );
        self.info[id.0 as usize].luminance = luminance.is_some();
        Ok(id)
    }

    /// The texture already open as `key`, under its path or another name of its file (which
    /// is then remembered under this path too).
    fn known(&mut self, key: &(PathBuf, Option<Option<char>>)) -> Option<TextureId> {
        if let Some(&id) = self.by_path.get(key) {
            return Some(id);
        }
        let id = *self.by_file.get(&file_key(key)?)?;
        self.by_path.insert(key.clone(), id);
        Some(id)
    }

    /// Record texture `id` of the texture set, opened as `key` and read as `img` (what its
    /// identity hashes), fetched as `(channels, pick, srgb)`, with its file's images and layers
    /// of colour (`Info`); `colour_mask`: a mask that reads a colour image's first channel,
    /// `alpha_opaque`: in place of its opaque alpha; what the file holds below zero and says of
    /// its pixels (`check_texels`, `image::Meaning`).
    fn add(
        &mut self,
        key: (PathBuf, Option<Option<char>>),
        id: u32,
        img: &super::Image,
        (fetched, pick, srgb, parts, layers): (usize, [Option<usize>; 3], bool, u32, Vec<String>),
        (colour_mask, alpha_opaque): (bool, bool),
        (negatives, meaning): (u64, super::Meaning),
    ) -> TextureId {
        let mut f = Fnv::default();
        f.bytes(&[img.width.to_le_bytes(), img.height.to_le_bytes()].concat());
        f.f32s(img.data.iter().copied());
        self.info.push(Info {
            width: img.width,
            height: img.height,
            fetched,
            pick,
            srgb,
            digest: f.0,
            parts,
            max: img.data.chunks_exact(3).fold([0.0f32; 3], |m, c| {
                [m[0].max(c[0]), m[1].max(c[1]), m[2].max(c[2])]
            }),
            path: key.0.clone(),
            colour_mask,
            alpha_opaque,
            negatives,
            zero: img.data.iter().all(|&v| v <= 0.0),
            luminance: false,
            layers,
            meaning,
        });
        let id = TextureId(id);
        if let Some(file) = file_key(&key) {
            self.by_file.insert(file, id);
        }
        self.by_path.insert(key, id);
        id
    }

    /// Size the texture cache to hold every texture opened (OpenImageIO's default of 1 GB made
    /// a scene of eight 8K textures read them from disk again and again while rendering, ten
    /// times slower, and a texture file replaced during the render showed in the later
    /// frames), within three quarters of the memory `available` (bytes, `None`: unknown). A
    /// warning where they do not fit.
    pub fn size_cache(&mut self, available: Option<u64>) -> Option<String> {
        let (need, mb) = cache_limit(self.set.cache_bytes(), available);
        self.set.pin_mut().set_cache_mb(mb as f32);
        self.cache_use = (need.min(mb) * 1e6) as u64;
        (need > mb).then(|| {
            format!(
                "the scene's textures take about {} MB in the texture cache, more than the {} MB \
                 it may use (three quarters of the memory available): they are read from disk \
                 again while rendering, which is slower, and a texture file replaced during the \
                 render would show in the later frames",
                need.round(),
                mb.round()
            )
        })
    }

    /// Bytes the texture cache holds once the render has read every texture (within the limit
    /// `size_cache` set; 0 before it): memory a render's frames cannot have.
    pub fn cache_use_bytes(&self) -> u64 {
        self.cache_use
    }

    /// What the textures opened hold in the cache when all of it is in memory (bytes: their
    /// pixels in the files' own channel formats).
    pub fn cache_bytes(&self) -> u64 {
        self.set.cache_bytes()
    }

    /// The images the file of texture `id` holds: more than 1 for a multi-part EXR, of which
    /// the first part is read.
    pub fn parts(&self, id: TextureId) -> u32 {
        self.info[id.0 as usize].parts
    }

    /// The layers of colour of texture `id`'s file where it holds several (a multi-layer EXR),
    /// the one read first; empty otherwise.
    pub fn layers(&self, id: TextureId) -> &[String] {
        &self.info[id.0 as usize].layers
    }

    /// Texture `id`'s size in texels (width, height).
    pub fn size(&self, id: TextureId) -> (u32, u32) {
        let info = &self.info[id.0 as usize];
        (info.width, info.height)
    }

    /// The largest value of each colour channel of texture `id` (red, green, blue).
    pub fn max_rgb(&self, id: TextureId) -> [f32; 3] {
        self.info[id.0 as usize].max
    }

    /// Whether mask `id` reads the first channel of a colour image without alpha (no `-imfchan`,
    /// no alpha or grey channel), or a channel in place of an opaque alpha, from the file that
    /// texture `colour` was opened from: a `map_d` that names the material's own `map_Kd`
    /// without alpha (or with an opaque one), which exporters write where they mean no mask.
    pub fn is_colour_mask_of(&self, id: TextureId, colour: TextureId) -> bool {
        let (m, c) = (&self.info[id.0 as usize], &self.info[colour.0 as usize]);
        (m.colour_mask || m.alpha_opaque) && m.path == c.path
    }

    /// Whether every texel of texture `id` is zero or below: as a mask, it cuts away the whole
    /// surface.
    pub fn is_zero(&self, id: TextureId) -> bool {
        self.info[id.0 as usize].zero
    }

    /// Whether mask `id` is read from its file's grey or first colour channel because the
    /// file's alpha is opaque everywhere (`image::MaskLayout::alpha_opaque`).
    pub fn mask_alpha_opaque(&self, id: TextureId) -> bool {
        self.info[id.0 as usize].alpha_opaque
    }

    /// The value of mask `id` (`open_mask`) at texture coordinates `uv`: bilinear between the
    /// four texels around it, as `rgb`.
    #[inline]
    pub fn value(&self, id: TextureId, uv: Vec2) -> f32 {
        let c = self.rgb(id, uv);
        if self.info[id.0 as usize].luminance {
            c.dot(Vec3::from(super::LUMINANCE))
        } else {
            c.x
        }
    }

    /// The linear RGB of texture `id` at texture coordinates `uv` (`v` up, as in OBJ files:
    /// `(0, 0)` is the image's bottom-left corner), repeating outside \[0, 1): bilinear between
    /// the four texel centres around it, in linear values.
    #[inline]
    pub fn rgb(&self, id: TextureId, uv: Vec2) -> Vec3 {
        let info = &self.info[id.0 as usize];
        // Texel centres at half-integers; row 0 is the image's top.
        let x = uv.x * info.width as f32 - 0.5;
        let y = (1.0 - uv.y) * info.height as f32 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        // A coordinate too large for f32 to hold a fraction has none.
        let frac = |v: f32, v0: f32| {
            if (0.0..1.0).contains(&(v - v0)) {
                v - v0
            } else {
                0.0
            }
        };
        let (fx, fy) = (frac(x, x0), frac(y, y0));
        let mut out = [0.0f32; 4 * MAX_SPREAD];
        let n = info.fetched;
        if !self
            .set
            .texels(id.0, x0 as i64, y0 as i64, &mut out[..4 * n])
        {
            self.failures.fetch_add(1, Ordering::Relaxed);
        }
        // Texels below zero read as zero (`check_texels`), before they are interpolated.
        let texel = |k: usize| {
            let px = &out[k * n..(k + 1) * n];
            Vec3::from(
                info.pick
                    .map(|c| c.map_or(0.0, |c| if info.srgb { decode_srgb(px[c]) } else { px[c] })),
            )
            .max(Vec3::ZERO)
        };
        let top = texel(0) * (1.0 - fx) + texel(1) * fx;
        let bottom = texel(2) * (1.0 - fx) + texel(3) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// What texture `id`'s file says of its pixels that is not applied (`image::Meaning`).
    pub fn meaning(&self, id: TextureId) -> &super::Meaning {
        &self.info[id.0 as usize].meaning
    }

    /// How many values below zero texture `id`'s file holds in the channels read (they read as
    /// zero).
    pub fn negative_texels(&self, id: TextureId) -> u64 {
        self.info[id.0 as usize].negatives
    }

    /// Each texture's content hash (decoded texels and size), in id order: what a scene's hash
    /// takes of its textures, so that a checkpoint or a cached reference made with other
    /// texture files is not reused.
    pub fn digests(&self) -> Vec<u64> {
        self.info.iter().map(|i| i.digest).collect()
    }

    /// Lookups that failed so far (each returned black).
    pub fn failures(&self) -> u64 {
        self.failures.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::cache_limit;

    #[test]
    fn the_cache_holds_every_texture_within_the_memory_available() {
        let gb = 1_000_000_000u64;
        // Two GB of textures with eight available: all of them (and a margin).
        let (need, mb) = cache_limit(2 * gb, Some(8 * gb));
        assert!(mb >= 2000.0 && mb == need, "{need} {mb}");
        // With two available: three quarters of them, short of the need (a warning).
        let (need, mb) = cache_limit(2 * gb, Some(2 * gb));
        assert!(mb == 1500.0 && need > mb, "{need} {mb}");
        // Little texture: never below the default of 1 GB, unless that passes three quarters
        // of the memory available (the cache counts against what the frames may take, and a
        // floor of 1 GB above it refused every render with less than 1.37 GB available).
        assert_eq!(cache_limit(10_000_000, None).1, 1024.0);
        assert_eq!(cache_limit(10_000_000, Some(8 * gb)).1, 1024.0);
        assert_eq!(cache_limit(2 * gb, Some(gb / 2)).1, 375.0);
    }
}
