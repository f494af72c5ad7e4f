//! Textured materials: the maps of a material (`map_Kd`, `map_Ks`, `map_Ke` of its MTL) and the
//! material they make at a point of a surface, and its cut-out mask (`map_d`, which
//! `scene::cutout` hands to Embree). The textures themselves are looked up through
//! `image::Textures` (OpenImageIO's texture system).
use super::mtl::{MapSpec, MtlMaterial, Slot, MAX_KE};
use super::repairs::{Kind, Repairs};
use super::text::{self, quote};
use crate::bsdf::Material;
use crate::image::{TextureId, Textures};
use crate::util::input::{open_input_or_missing, InputError};
use anyhow::{anyhow, Result};
use glam::{Vec2, Vec3};
use std::path::{Path, PathBuf};

/// One texture map: the texture and the transform of the texture coordinates, `uv * scale +
/// offset` (the MTL's `-s` and `-o`).
#[derive(Clone, Copy, Debug)]
pub struct Map {
    pub tex: TextureId,
    pub scale: Vec2,
    pub offset: Vec2,
}

impl Map {
    /// The map's colour at the surface's texture coordinates `uv` (transformed by `-s`, `-o`).
    #[inline]
    pub fn rgb(&self, textures: &Textures, uv: Vec2) -> Vec3 {
        textures.rgb(self.tex, uv * self.scale + self.offset)
    }

    /// Whether a mask (`map_d`) keeps the surface at texture coordinates `uv`: its value there
    /// is at least `CUTOFF`.
    #[inline]
    pub fn keeps(&self, textures: &Textures, uv: Vec2) -> bool {
        textures.value(self.tex, uv * self.scale + self.offset) >= CUTOFF
    }
}

/// The maps of one material; each multiplies the colour it names, except `cutout` (`map_d`),
/// the mask that cuts the surface out where it is below `CUTOFF`.
#[derive(Clone, Copy, Debug, Default)]
pub struct Maps {
    pub kd: Option<Map>,
    pub ks: Option<Map>,
    pub ke: Option<Map>,
    pub cutout: Option<Map>,
}

/// A `map_d` mask cuts its surface out where its value (bilinear between texels, as the
/// colours) is below this: glTF's default `alphaCutoff`, Blender's alpha clip.
pub const CUTOFF: f32 = 0.5;

const COLOUR_AS_MASK: Kind = Kind {
    one: "map_d names the colour texture (map_Kd), which has no alpha: no cut-out",
    many: "map_d names the colour texture (map_Kd), which has no alpha: no cut-outs",
};

/// A texture with values below zero (a photograph's small negatives from debayering, a change
/// of colour space or lossy EXR compression): read as zero.
const NEGATIVE_TEXELS: Kind = Kind {
    one: "texture with values below 0 (read as 0)",
    many: "textures with values below 0 (read as 0)",
};

/// A colour texture black in every texel on a material that has no other light (no `Ks`, no
/// emission): rendered as it says (a black surface), but said: a PNG whose header its writer
/// got wrong (its colour type) is decoded to zeros without an error, and so is a map meant for
/// another slot.
const KD_MAP_BLACK: Kind = Kind {
    one: "colour texture (map_Kd) black in every texel: the surface reflects no diffuse light \
          (a damaged file, or a map meant for another slot?)",
    many: "colour textures (map_Kd) black in every texel: their surfaces reflect no diffuse \
           light (damaged files, or maps meant for other slots?)",
};

/// A mask that is zero everywhere: the surface is cut away entirely.
const MASK_CUTS_ALL: Kind = Kind {
    one: "mask that is zero everywhere: the surface is cut away entirely (an alpha its writer \
          left at zero? add -imfchan to read another channel, or drop map_d)",
    many: "masks that are zero everywhere: their surfaces are cut away entirely (alphas their \
           writers left at zero? add -imfchan to read another channel, or drop map_d)",
};

/// A mask file whose alpha is opaque everywhere, with the mask in its colour (`map_d` of a
/// DDS or TGA saved with a filled alpha).
const MASK_IN_COLOUR: Kind = Kind {
    one: "mask whose alpha is opaque everywhere read from its grey or first colour channel (add -imfchan to choose)",
    many: "masks whose alpha is opaque everywhere read from their grey or first colour channel (add -imfchan to choose)",
};

/// An image file of several images (a multi-part EXR's parts, a multi-page TIFF's pages, an
/// animated GIF's frames): the first is read.
pub const MULTI_PART: Kind = Kind {
    one: "only the first of the file's images (a multi-part EXR's parts, a multi-page TIFF's pages, an animated GIF's frames) is read",
    many: "only the first of each file's images (a multi-part EXR's parts, a multi-page TIFF's pages, an animated GIF's frames) is read",
};

pub const MULTI_LAYER: Kind = Kind {
    one: "a multi-layer EXR: one layer is read (Combined, else one named beauty, rgba, rgb, color or colour, else the first)",
    many: "multi-layer EXRs: one layer of each is read (Combined, else one named beauty, rgba, rgb, color or colour, else the first)",
};

/// What a multi-layer file's note says: its layers of colour and the one read (the first of
/// `layers`, as `image::colour_layers` orders them).
pub fn layers_read(layers: &[String]) -> String {
    let mut all = layers.to_vec();
    all.sort();
    format!(
        "the file holds {} layers of colour ({}): '{}' is read",
        layers.len(),
        quote(&all.join(", ")),
        quote(&layers[0])
    )
}

/// A file that says its image is stored rotated or mirrored (EXIF, a Radiance `+Y` line).
const ORIENTED: Kind = Kind {
    one: "image file that says it is stored turned or mirrored read as stored (as Mitsuba 3, pbrt-v4 and Blender read textures; turn the file itself if it is meant so)",
    many: "image files that say they are stored turned or mirrored read as stored (as Mitsuba 3, pbrt-v4 and Blender read textures; turn the files themselves if they are meant so)",
};

/// An EXR whose primaries are not Rec.709's (XYZ, ACES, a wide gamut).
const PRIMARIES: Kind = Kind {
    one: "image with other primaries than Rec.709 read as Rec.709 (convert it, e.g. with oiiotool --colorconvert)",
    many: "images with other primaries than Rec.709 read as Rec.709 (convert them, e.g. with oiiotool --colorconvert)",
};

/// A file in a log encoding (a film scan's DPX or Cineon, an ACEScct grade, a camera's log).
const LOG_ENCODED: Kind = Kind {
    one: "image in a log encoding read as its values, not decoded (convert it to linear or sRGB, e.g. with oiiotool --colorconvert)",
    many: "images in a log encoding read as their values, not decoded (convert them to linear or sRGB, e.g. with oiiotool --colorconvert)",
};

/// An OpenEXR file whose data window holds under 1% of its display window: read as its
/// display window, black wherever nothing is stored.
const SPARSE: Kind = Kind {
    one: "image that stores under 1% of its pixels (an OpenEXR data window far smaller than its display window): the rest reads as black",
    many: "images that store under 1% of their pixels (OpenEXR data windows far smaller than their display windows): the rest reads as black",
};

/// Note what the image file `what` (at `file`'s `line`) says of its pixels that reframe does
/// not apply (`image::Meaning`): an orientation, other primaries, a log encoding; and where it
/// stores almost none of its pixels.
pub fn note_meaning(
    repairs: &mut Repairs,
    (file, line): (&str, usize),
    what: &str,
    meaning: &crate::image::Meaning,
) -> Result<()> {
    if let Some(o) = meaning.orientation {
        repairs.note(file, line, ORIENTED, || {
            format!(
                "{what}: the file says it is stored {} (orientation {o})",
                crate::image::orientation_in_words(o)
            )
        })?;
    }
    if let Some(c) = &meaning.chromaticities {
        repairs.note(file, line, PRIMARIES, || {
            format!("{what}: its chromaticities are {}", quote(c))
        })?;
    }
    if let Some(e) = &meaning.encoding {
        repairs.note(file, line, LOG_ENCODED, || {
            format!("{what}: the file says its encoding is {}", quote(e))
        })?;
    }
    if let Some((stored, w, h)) = meaning.sparse {
        repairs.note(file, line, SPARSE, || {
            format!("{what}: the file stores {stored} of its {w}x{h} pixels")
        })?;
    }
    Ok(())
}

/// Note that the image file `what` (at `file`'s `line`) holds several images (`parts`, of
/// which the first is read) or several layers of colour (`layers`, the one read first), where
/// it does: a texture's and an environment's alike.
pub fn note_images_read(
    repairs: &mut Repairs,
    (file, line): (&str, usize),
    what: &str,
    parts: u32,
    layers: &[String],
) -> Result<()> {
    if parts > 1 {
        repairs.note(file, line, MULTI_PART, || {
            format!(
                "{what}: the file holds {} images",
                crate::image::images_in_words(parts)
            )
        })?;
    }
    if !layers.is_empty() {
        repairs.note(file, line, MULTI_LAYER, || {
            format!("{what}: {}", layers_read(layers))
        })?;
    }
    Ok(())
}

/// A map's file name with a comment after it, read without the comment.
const COMMENT_AFTER_FILE: Kind = Kind {
    one: "a map's file name with a comment after it: the name before the '#' is used",
    many: "maps' file names with a comment after them: the names before the '#' are used",
};

/// A map's file name in double quotes, read without them.
const QUOTED_FILE: Kind = Kind {
    one: "a map's file name in quotes: the name within them is used",
    many: "maps' file names in quotes: the names within them are used",
};

/// A map's file name with its spaces escaped by backslashes, as `mtllib` names may be.
const ESCAPED_FILE: Kind = Kind {
    one: "a map's file name with backslash-escaped spaces: read as spaces",
    many: "maps' file names with backslash-escaped spaces: read as spaces",
};

/// What a map's file name `file` may mean where as written it names no file, in the order
/// tried: within double quotes (`"my tex.png"`), with its spaces escaped (`my\ tex.png`, as
/// tinyobjloader writes `mtllib` names), and before a comment after it (`wood.png # oak`, each
/// of those heads also within quotes).
fn other_spellings(file: &str) -> impl Iterator<Item = (String, Kind)> + '_ {
    let unquoted = |s: &str| {
        (s.len() >= 2 && s.starts_with('"') && s.ends_with('"'))
            .then(|| s[1..s.len() - 1].to_string())
    };
    let quoted = unquoted(file).map(|n| (n, QUOTED_FILE));
    let escaped = file
        .contains("\\ ")
        .then(|| (file.replace("\\ ", " "), ESCAPED_FILE));
    let heads = text::before_comments(file).flat_map(move |h| {
        [Some(h.to_string()), unquoted(h)]
            .into_iter()
            .flatten()
            .map(|n| (n, COMMENT_AFTER_FILE))
    });
    quoted.into_iter().chain(escaped).chain(heads)
}

const KE_MAP_CAPPED: Kind = Kind {
    one: "emission map capped at 1e9 (radiance sums would overflow above it)",
    many: "emission maps capped at 1e9 (radiance sums would overflow above it)",
};

const EMITTER_CUTOUT: Kind = Kind {
    one: "map_d on an emitting material ignored (lights are opaque)",
    many: "map_d on emitting materials ignored (lights are opaque)",
};

impl Maps {
    /// Open the textures `m`'s MTL (`mtl_label`, in folder `dir`) names, refusing a texture
    /// that cannot be used with one line naming the MTL file and line. `opened` gets each
    /// texture's path. A light's mask (the material emits `ke`) is left out, with a note in
    /// `repairs`: light sampling picks points on the whole triangle. An emission map whose
    /// texels times `ke` pass `MAX_KE` is capped there as it is looked up, with a note.
    pub fn open(
        mtl_label: &str,
        dir: Option<&Path>,
        (m, material): (&MtlMaterial, &Material),
        textures: &mut Option<Textures>,
        opened: &mut Vec<PathBuf>,
        repairs: &mut Repairs,
    ) -> Result<Maps> {
        let ke_colour = material.ke;
        let mut open = |spec: &Option<MapSpec>, mask: bool| -> Result<Option<Map>> {
            let Some(spec) = spec else {
                return Ok(None);
            };
            let at = format!(
                "{mtl_label}: line {}: '{}'",
                spec.line,
                quote(&spec.statement)
            );
            let Some(dir) = dir else {
                return Err(anyhow!("{at}: a shipped scene has no texture files"));
            };
            let (mut path, mut elsewhere) = super::locate_named_file(dir, &spec.file, spec.latin1);
            if !path.exists() {
                // The name as another tool wrote it, where as written it names no file.
                let found = other_spellings(&spec.file)
                    .map(|(name, kind)| (super::locate_named_file(dir, &name, spec.latin1), kind))
                    .find(|((p, _), _)| p.exists());
                if let Some((found, kind)) = found {
                    repairs.note(mtl_label, spec.line, kind, || {
                        format!("'{}'", quote(&spec.statement))
                    })?;
                    (path, elsewhere) = found;
                }
            }
            if elsewhere {
                repairs.note(mtl_label, spec.line, super::FOUND_ELSEWHERE, || {
                    format!("'{}': found '{}'", quote(&spec.statement), path.display())
                })?;
            }
            // Missing, or there but not a regular file (a folder, a FIFO, a device, a symlink
            // loop): said as such, as for every other input.
            match open_input_or_missing(&path, "texture", u64::MAX) {
                Ok(_) => {}
                Err(InputError::NotFound(_)) => {
                    // A tiled texture's name pattern (Mari, Blender, Substance, RenderMan):
                    // several images over UV tiles, which a lookup in [0, 1) cannot address.
                    let name = spec.file.to_ascii_uppercase();
                    let tiled = ["<UDIM>", "<UVTILE>", "%(UDIM)D", "_U<U>_V<V>"]
                        .iter()
                        .any(|t| name.contains(t));
                    if tiled {
                        return Err(anyhow!(
                            "{at}: a texture over UV tiles (UDIM: one image per tile, named by a \
                             pattern) is not supported: bake the tiles into one image, or give each \
                             tile's object its own material"
                        ));
                    }
                    let missing = super::missing_file_message(dir, &spec.file, &path);
                    return Err(anyhow!("{at}: {missing}"));
                }
                Err(e) => return Err(anyhow!("{at}: {e}")),
            }
            let t = match textures {
                Some(t) => t,
                None => textures.insert(Textures::new().map_err(|e| anyhow!("{at}: {e}"))?),
            };
            let tex = if mask {
                t.open_mask(&path, spec.channel)
            } else {
                t.open(&path)
            };
            let tex = tex.map_err(|e| anyhow!("{at}: {e}"))?;
            if !opened.contains(&path) {
                opened.push(path);
            }
            Ok(Some(Map {
                tex,
                scale: spec.scale,
                offset: spec.offset,
            }))
        };
        let kd = open(&m.maps[Slot::Kd as usize], false)?;
        let ks = open(&m.maps[Slot::Ks as usize], false)?;
        let emits = ke_colour.max_element() > 0.0;
        let ke = open(&m.maps[Slot::Ke as usize], false)?;
        let cutout = match &m.maps[Slot::D as usize] {
            Some(spec) if emits => {
                repairs.note(mtl_label, spec.line, EMITTER_CUTOUT, || {
                    format!("'{}' in '{}'", quote(&spec.statement), m.name)
                })?;
                None
            }
            spec => open(spec, true)?,
        };
        let cutout = match (cutout, &kd, textures.as_ref()) {
            (Some(c), Some(kd), Some(t)) if t.is_colour_mask_of(c.tex, kd.tex) => {
                // With an opaque alpha the file holds no mask either: as it always read.
                if !t.mask_alpha_opaque(c.tex) {
                    let spec = m.maps[Slot::D as usize]
                        .as_ref()
                        .expect("the mask's statement");
                    repairs.note(mtl_label, spec.line, COLOUR_AS_MASK, || {
                        format!("'{}' in '{}'", quote(&spec.statement), m.name)
                    })?;
                }
                None
            }
            (c, ..) => c,
        };
        if let (Some(c), Some(t), Some(spec)) =
            (&cutout, textures.as_ref(), &m.maps[Slot::D as usize])
        {
            // Rendered as it says (nothing of the surface), but said: an alpha left at zero by
            // its writer (32-bit TGAs whose header calls the alpha undefined) made a textured
            // surface vanish without a word.
            if t.is_zero(c.tex) {
                repairs.note(mtl_label, spec.line, MASK_CUTS_ALL, || {
                    format!("'{}' in '{}'", quote(&spec.statement), m.name)
                })?;
            }
            if t.mask_alpha_opaque(c.tex) {
                repairs.note(mtl_label, spec.line, MASK_IN_COLOUR, || {
                    format!("'{}' in '{}'", quote(&spec.statement), m.name)
                })?;
            }
        }
        // A multi-part file (an EXR of several layers as parts): its first part is read; a
        // multi-layer one (layers in one part): the layer `image::colour_layers` picks.
        for (map, slot) in [
            (&kd, Slot::Kd),
            (&ks, Slot::Ks),
            (&ke, Slot::Ke),
            (&cutout, Slot::D),
        ] {
            if let (Some(map), Some(t), Some(spec)) =
                (map, textures.as_ref(), &m.maps[slot as usize])
            {
                let what = format!("'{}'", quote(&spec.statement));
                note_images_read(
                    repairs,
                    (mtl_label, spec.line),
                    &what,
                    t.parts(map.tex),
                    t.layers(map.tex),
                )?;
                note_meaning(repairs, (mtl_label, spec.line), &what, t.meaning(map.tex))?;
                // (Not where the material reflects by its specular lobe or emits: a PBR
                // export's metal has a black diffuse map on purpose.)
                let other_light = material.ks.max_element() > 0.0 || material.is_emissive();
                if slot == Slot::Kd && t.is_zero(map.tex) && !other_light {
                    repairs.note(mtl_label, spec.line, KD_MAP_BLACK, || {
                        format!("{what} in '{}'", m.name)
                    })?;
                }
                let negatives = t.negative_texels(map.tex);
                if negatives > 0 {
                    repairs.note(mtl_label, spec.line, NEGATIVE_TEXELS, || {
                        format!("'{}': {negatives} value(s) below 0", quote(&spec.statement))
                    })?;
                }
            }
        }
        if let (Some(map), Some(t), Some(spec)) =
            (&ke, textures.as_ref(), &m.maps[Slot::Ke as usize])
        {
            let brightest = ke_colour * Vec3::from(t.max_rgb(map.tex));
            if brightest.max_element() > MAX_KE {
                repairs.note(mtl_label, spec.line, KE_MAP_CAPPED, || {
                    format!(
                        "'{}' in '{}': Ke times the texture reaches {:e}",
                        quote(&spec.statement),
                        m.name,
                        brightest.max_element()
                    )
                })?;
            }
        }
        Ok(Maps { kd, ks, ke, cutout })
    }

    pub fn is_empty(&self) -> bool {
        self.kd.is_none() && self.ks.is_none() && self.ke.is_none() && self.cutout.is_none()
    }

    /// `m` with its textured colours at texture coordinates `uv`: each reflectance is the
    /// constant times the texture, clamped to \[0, 1\] after the product (a float texel of 1.6
    /// under `Kd 0.5` is 0.8, as other renderers take it; clamping the texel first made it
    /// 0.5), and where `Kd + Ks` then passes 1 in a channel both are scaled by one factor, as
    /// the MTL's constants are at load (`MtlMaterial::material`). Emission stays below `MAX_KE`.
    #[inline]
    pub fn apply(&self, m: &Material, textures: &Textures, uv: Vec2) -> Material {
        let mut m = *m;
        let reflect = |c: Vec3, map: &Map| (c * map.rgb(textures, uv)).clamp(Vec3::ZERO, Vec3::ONE);
        if let Some(map) = &self.kd {
            m.kd = reflect(m.kd, map);
        }
        if let Some(map) = &self.ks {
            m.ks = reflect(m.ks, map);
        }
        if self.kd.is_some() || self.ks.is_some() {
            let sum = (m.kd + m.ks).max_element();
            if sum > 1.0 {
                m.kd /= sum;
                m.ks /= sum;
            }
        }
        if let Some(map) = &self.ke {
            m.ke = self.emission(m.ke, textures, uv, map);
        }
        m
    }

    /// Emission `ke` scaled by the `map_Ke` texture at `uv`, if there is one.
    #[inline]
    pub fn ke(&self, ke: Vec3, textures: &Textures, uv: Vec2) -> Vec3 {
        match &self.ke {
            Some(map) => self.emission(ke, textures, uv, map),
            None => ke,
        }
    }

    fn emission(&self, ke: Vec3, textures: &Textures, uv: Vec2, map: &Map) -> Vec3 {
        (ke * map.rgb(textures, uv)).min(Vec3::splat(MAX_KE))
    }
}
