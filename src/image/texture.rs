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
//! 8-bit sRGB files (OIIO's `oiio:ColorSpace`) are decoded to linear after the bilinear step.
//!
//! ```no_run
//! use reframe::image::Textures;
//! let mut t = Textures::new()?;
//! let id = t.open(std::path::Path::new("wood.png"))?;
//! let rgb = t.rgb(id, glam::Vec2::new(0.25, 0.5));
//! # anyhow::Ok(())
//! ```
use super::bridge::ffi;
use super::{path_str, read_linear_rgb, srgb_eotf};
use crate::util::hash::Fnv;
use anyhow::{anyhow, bail, Result};
use glam::{Vec2, Vec3};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Most texels of one texture (8192 x 8192): each is decoded once when the scene loads.
pub const MAX_TEXELS: u64 = 1 << 26;

/// A texture of a `Textures`, by index.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TextureId(u32);

struct Info {
    /// One channel looked up and taken as grey (grey and grey-alpha files), else three.
    grey: bool,
    srgb: bool,
    /// FNV-1a of the decoded texels and the size: the texture's identity in a scene's hash.
    digest: u64,
}

/// The textures of a scene and the texture system they are looked up through.
pub struct Textures {
    set: cxx::UniquePtr<ffi::TextureSet>,
    info: Vec<Info>,
    by_path: HashMap<PathBuf, TextureId>,
    /// Lookups the texture system failed (a file changed or vanished during the render); they
    /// return black.
    failures: AtomicU64,
}

impl Textures {
    pub fn new() -> Result<Textures> {
        let set = ffi::new_texture_set().map_err(|e| anyhow!("{}", e.what()))?;
        Ok(Textures {
            set,
            info: Vec::new(),
            by_path: HashMap::new(),
            failures: AtomicU64::new(0),
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
        if let Some(&id) = self.by_path.get(path) {
            return Ok(id);
        }
        // Decoded whole once, for the checks; the cache reads it again on demand.
        let img = read_linear_rgb(path, MAX_TEXELS)?;
        if let Some(v) = img.data.iter().find(|v| !v.is_finite() || **v < 0.0) {
            bail!(
                "cannot use {}: it has a texel of {v} (textures must be finite and non-negative)",
                path.display()
            );
        }
        let (grey, srgb) = {
            let reader = ffi::open_reader(path_str(path)?).map_err(|e| anyhow!("{}", e.what()))?;
            let srgb = reader.attributes().into_iter().any(|a| {
                a.name.eq_ignore_ascii_case("oiio:ColorSpace")
                    && a.text.to_ascii_lowercase().contains("srgb")
            });
            (reader.info().channels.len() < 3, srgb)
        };
        let id = self
            .set
            .pin_mut()
            .add(path_str(path)?, if grey { 1 } else { 3 })
            .map_err(|e| anyhow!("cannot open {} as a texture: {}", path.display(), e.what()))?;
        let id = TextureId(id);
        let mut f = Fnv::default();
        f.bytes(&[img.width.to_le_bytes(), img.height.to_le_bytes()].concat());
        f.f32s(img.data.iter().copied());
        self.info.push(Info {
            grey,
            srgb,
            digest: f.0,
        });
        self.by_path.insert(path.to_path_buf(), id);
        Ok(id)
    }

    /// The linear RGB of texture `id` at texture coordinates `uv` (`v` up, as in OBJ files:
    /// `(0, 0)` is the image's bottom-left corner), repeating outside \[0, 1).
    #[inline]
    pub fn rgb(&self, id: TextureId, uv: Vec2) -> Vec3 {
        let info = &self.info[id.0 as usize];
        let mut out = [0.0f32; 3];
        let n = if info.grey { 1 } else { 3 };
        if !self.set.lookup(id.0, uv.x, 1.0 - uv.y, &mut out[..n]) {
            self.failures.fetch_add(1, Ordering::Relaxed);
        }
        let mut c = if info.grey {
            Vec3::splat(out[0])
        } else {
            Vec3::from(out)
        };
        if info.srgb {
            c = c.map(|e| srgb_eotf(e as f64) as f32);
        }
        c
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
