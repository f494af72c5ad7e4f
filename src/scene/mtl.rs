//! The MTL reader: the values reframe's BSDF uses (`Kd`, `Ks`, `Ns`, `Ke`) of each `newmtl`,
//! each with its line, turned into `Material`s clamped to where the BSDF is stable, the
//! texture maps that scale them (`map_Kd`, `map_Ks`, `map_Ke`), and the cut-out mask `map_d`
//! (`scene::cutout`).
//!
//! A map multiplies its colour, as the MTL format defines it (`Kd` times the texture at the
//! hit); a map whose colour line is missing takes the colour 1 (the texture as it is). Of a
//! map's options, `-o u [v]` (offset) and `-s u [v]` (scale) of the texture coordinates are
//! applied (`uv * s + o`), and `map_d`'s `-imfchan` (the mask's channel); the others
//! (`-blendu`, `-blendv`, `-bm`, `-boost`, `-cc`, `-clamp`, `-imfchan` of a colour map, `-mm`,
//! `-t`, `-texres`, `-type`) are read and ignored with one warning. The file
//! name is the rest of the line (names with spaces are common), relative to the MTL's folder.
//!
//! Read as production loaders read them: any whitespace between words, lines that are not UTF-8
//! (Latin-1), a colour of one number (grey, as the MTL format allows). Statements reframe does
//! not use (`Ka`, `Ni`, `illum`, `Tr`, `map_Ka`, ...) are skipped without a look; what would
//! change the look and is not rendered says so, once per kind and file (a repair: `--strict`
//! refuses it): `d` (dissolve) below 1, where the surface stays opaque, and the other texture
//! maps (`bump`, `map_Bump`, `norm`, `disp`, `refl`, `map_Ns`, `map_Pr`, ...). Refused,
//! naming the line, because the material would be ambiguous or meaningless: a used value that
//! is not a number, negative or not finite, a colour of two numbers, a value before any
//! `newmtl`, and a material defined twice in one file.
//!
//! Repaired with one warning per kind (`Repairs`): `Kd + Ks` above 1 in a channel (both scaled
//! down by one factor until no channel is above 1, so the Phong model conserves energy and both
//! lobes keep their colour), `Ns` above `MAX_NS`, `Ke` above
//! `MAX_KE`.
use super::repairs::{Kind, Repairs};
use super::text::{canonical, did_you_mean, joined, lines, number, number_saturating, quote, rest};
use crate::bsdf::Material;
/// Largest Phong exponent: the BSDF's own bound (`bsdf::MAX_NS`).
pub use crate::bsdf::MAX_NS;
use anyhow::{anyhow, Result};
use glam::{Vec2, Vec3};
use std::collections::HashMap;

/// Largest emitted radiance per channel. Pixel values are f32 sums over samples and eyes of
/// `Ke` times path weights: with `Ke` 1e36 the vase scene's sums overflow to infinity (and NaN).
/// 1e9 leaves a factor 1e27 of head-room for sample counts and geometric gains.
pub const MAX_KE: f32 = 1e9;

const ENERGY: Kind = Kind {
    one: "Kd + Ks above 1 scaled down to 1 (energy conservation)",
    many: "materials with Kd + Ks above 1 scaled down to 1 (energy conservation)",
};
const WIDE_KS: Kind = Kind {
    one: "a Phong lobe (Ks) of Ns 1 or less beside a map_Kd is a second, untextured diffuse \
          lobe: the texture shows faded towards Ks (drop Ks, or give Ns its highlight's size)",
    many: "Phong lobes (Ks) of Ns 1 or less beside a map_Kd are second, untextured diffuse \
           lobes: the textures show faded towards Ks (drop Ks, or give Ns the highlights' size)",
};
const NS: Kind = Kind {
    one: "Ns capped (the Phong lobe is unstable above it)",
    many: "materials with Ns capped (the Phong lobe is unstable above it)",
};
const MAP_OPTION: Kind = Kind {
    one: "texture map option ignored (reframe applies -o and -s only)",
    many: "texture map options ignored (reframe applies -o and -s only)",
};
const UNKNOWN_MAP_OPTION: Kind = Kind {
    one: "unknown texture map option ignored, with the numbers or the one word after it",
    many: "unknown texture map options ignored, with the numbers or the one word after each",
};
const DISSOLVE: Kind = Kind {
    one: "dissolve (d) not rendered: the surface is opaque (map_d cut-outs are rendered)",
    many: "materials with dissolve (d) rendered opaque (map_d cut-outs are rendered)",
};
const DEFINED_AGAIN: Kind = Kind {
    one: "a material defined twice in one MTL, differently: the first definition is used",
    many: "materials defined twice in one MTL, differently: the first definitions are used",
};
const STATED_AGAIN: Kind = Kind {
    one: "a colour (Kd, Ks or Ke) given twice in one material, differently: the last is used",
    many: "colours (Kd, Ks or Ke) given twice in one material, differently: the last ones are used",
};
const TRANSPARENCY: Kind = Kind {
    one: "transparency (Tr) not rendered: the surface is opaque (map_d cut-outs are rendered)",
    many: "materials with transparency (Tr) rendered opaque (map_d cut-outs are rendered)",
};
const GLASS: Kind = Kind {
    one: "glass (illum 4, 6, 7 or 9 with an Ni other than 1: refraction) not rendered: the \
          surface is its Kd diffuse and Ks Phong lobes",
    many: "materials of glass (illum 4, 6, 7 or 9 with an Ni other than 1: refraction) rendered \
           as their Kd diffuse and Ks Phong lobes",
};
const METALLIC: Kind = Kind {
    one: "metallic (Pm) not rendered: the surface is its Kd diffuse and Ks Phong lobes",
    many: "materials with metallic (Pm) rendered as their Kd diffuse and Ks Phong lobes",
};
const KD_ZERO_MAP: Kind = Kind {
    one: "Kd 0 beside a map_Kd read as Kd 1, the texture as it is (as Maya writes it)",
    many:
        "materials with Kd 0 beside a map_Kd read as Kd 1, the texture as it is (as Maya writes it)",
};
const KS_ZERO_MAP: Kind = Kind {
    one: "map_Ks has no effect: the map is multiplied by Ks, which is 0 (write Ks 1 for the \
          map as it is)",
    many: "maps (map_Ks) with no effect: each is multiplied by its Ks, which is 0 (write Ks 1 \
           for the map as it is)",
};
pub(crate) const KE_ZERO_MAP: Kind = Kind {
    one: "map_Ke has no effect: the map is multiplied by Ke, which is 0, so the surface emits \
          nothing (write Ke 1 for the map as it is)",
    many: "maps (map_Ke) with no effect: each is multiplied by its Ke, which is 0, so the \
           surfaces emit nothing (write Ke 1 for the map as it is)",
};
const EXTRA_NUMBERS: Kind = Kind {
    one: "numbers past a statement's own ignored",
    many: "statements with numbers past their own ignored",
};
/// A statement that is no MTL statement: a misspelt `Kd` or `Ke` (the material kept its
/// default, and a scene could lose its light without a word), another format's line.
pub(crate) const UNKNOWN: Kind = Kind {
    one: "statement the MTL format does not have: ignored",
    many: "statements the MTL format does not have: ignored",
};

/// MTL statements that reframe passes over without a word, besides the maps and their
/// relatives (`unrendered_map`): ambient colour, transmission, refraction index, the
/// illumination model, transparency as `Tr` (exporters disagree on which way it runs), and
/// the PBR extension's sheen, clearcoat and anisotropy; `Kt` and `Km` as some exporters write
/// them; `map_aat` (texture antialiasing).
const PASSED_OVER: [&str; 14] = [
    "Ka",
    "Tf",
    "Ni",
    "illum",
    "Tr",
    "sharpness",
    "Ps",
    "Pc",
    "Pcr",
    "aniso",
    "anisor",
    "Kt",
    "Km",
    "map_aat",
];

/// An `xyz` colour (`Kd xyz x y z`) outside the gamut of Rec.709's primaries.
const OUT_OF_GAMUT: Kind = Kind {
    one: "XYZ colour outside the Rec.709 gamut: its negative channels read as 0",
    many: "XYZ colours outside the Rec.709 gamut: their negative channels read as 0",
};

/// A CIE XYZ colour as linear Rec.709 RGB (the primaries of sRGB, white D65), derived from the
/// primaries' and the white's chromaticities (docs/colour.md, eq. 1-3): the RGB-to-XYZ matrix
/// has as columns each primary's XYZ at luminance 1, `(x/y, 1, (1-x-y)/y)`, scaled so that RGB
/// (1, 1, 1) is the white at luminance 1; this is its inverse. Computed in f64, rounded once.
fn xyz_to_rec709(c: Vec3) -> Vec3 {
    use glam::{DMat3, DVec3};
    let at_y1 = |x: f64, y: f64| DVec3::new(x / y, 1.0, (1.0 - x - y) / y);
    let primaries = DMat3::from_cols(at_y1(0.64, 0.33), at_y1(0.30, 0.60), at_y1(0.15, 0.06));
    let white = at_y1(0.3127, 0.3290);
    let scale = primaries.inverse() * white;
    let rgb_to_xyz = primaries * DMat3::from_diagonal(scale);
    (rgb_to_xyz.inverse() * c.as_dvec3()).as_vec3()
}

/// The statements reframe reads or says it does not render, in their usual case (a misspelt
/// statement is compared with these and `PASSED_OVER` for a hint, `did_you_mean`).
const STATEMENTS: [&str; 20] = [
    "newmtl", "Kd", "Ks", "Ke", "Ns", "d", "map_Kd", "map_Ks", "map_Ke", "map_d", "Pr", "Pm",
    "map_Bump", "bump", "disp", "norm", "refl", "decal", "map_Ka", "map_Ns",
];

const UNRENDERED_MAP: Kind = Kind {
    one: "texture map not rendered (reframe renders map_Kd, map_Ks, map_Ke and map_d)",
    many: "texture maps not rendered (reframe renders map_Kd, map_Ks, map_Ke and map_d)",
};

/// The statements reframe reads, read in any case (`kd`, `KD` and `map_kd` are `Kd` and
/// `map_Kd`: exporters differ; `text::canonical`).
const KEYS: [&str; 10] = [
    "newmtl", "Kd", "Ks", "Ke", "Ns", "d", "map_Kd", "map_Ks", "map_Ke", "map_d",
];

/// Whether `key` is a map statement that reframe does not render (any case): `Some(true)` where
/// it would change the look and is said (bump, normal and displacement maps, maps of the
/// exponent, reflection and the PBR extension's values), `Some(false)` for `map_Ka`, passed over
/// without a word (a path tracer has no ambient term; exporters write it as a copy of
/// `map_Kd`); `None` for any other statement (`map_aat` is an option, not a map).
fn unrendered_map(key: &str) -> Option<bool> {
    let k = key.to_ascii_lowercase();
    if matches!(key, "map_Kd" | "map_Ks" | "map_Ke" | "map_d") || k == "map_aat" {
        return None;
    }
    if k == "map_ka" {
        return Some(false);
    }
    (k.starts_with("map_") || matches!(k.as_str(), "bump" | "disp" | "decal" | "refl" | "norm"))
        .then_some(true)
}

const KE: Kind = Kind {
    one: "Ke capped (radiance sums would overflow above it)",
    many: "materials with Ke capped (radiance sums would overflow above it)",
};

/// One `newmtl` and the lines of the values it sets.
#[derive(Clone, Debug, Default)]
pub struct MtlMaterial {
    pub name: String,
    pub line: usize,
    kd: Option<(Vec3, usize)>,
    ks: Option<(Vec3, usize)>,
    ke: Option<(Vec3, usize)>,
    ns: Option<(f32, usize)>,
    /// `Pr`: the PBR roughness, which gives `Ns` where the MTL has none (Blender's export with
    /// PBR extensions writes it instead).
    pr: Option<(f32, usize)>,
    /// `map_Kd`, `map_Ks`, `map_Ke`, `map_d`, in that order.
    pub maps: [Option<MapSpec>; 4],
    /// The statements after `newmtl`: line, key (as `canonical` gives it) and words, to tell a
    /// repeated definition from another one (`drop_repeats`) and to see the whole material
    /// before saying what of it is not rendered (`note_transparency`).
    body: Vec<(usize, String, Vec<String>)>,
}

/// Which colour a texture map scales.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Slot {
    Kd = 0,
    Ks = 1,
    Ke = 2,
    /// `map_d`: the cut-out mask, not a colour.
    D = 3,
}

/// A `map_K?` statement: the file (relative to the MTL's folder), the texture-coordinate
/// transform `uv * scale + offset`, and its line (with the statement, for messages).
#[derive(Clone, Debug)]
pub struct MapSpec {
    pub file: String,
    pub scale: Vec2,
    pub offset: Vec2,
    pub line: usize,
    pub statement: String,
    /// `-imfchan r|g|b|m|l|z`: the channel a scalar map reads (`map_d` honours it).
    pub channel: Option<char>,
    /// Whether its line was read as Latin-1 (not UTF-8): `file` is then the line's bytes.
    pub latin1: bool,
}

/// The materials of one MTL file, in order, and where each name is.
#[derive(Debug, Default)]
pub struct Mtl {
    pub materials: Vec<MtlMaterial>,
    pub index: HashMap<String, usize>,
    /// The files named by map statements reframe does not render (`map_Bump`, `map_Ka`, ...):
    /// never read, but a command must not write over them either.
    pub other_files: Vec<String>,
}

/// Read an MTL file; `label` names it in errors ("label: line N: 'statement': why") and repairs.
#[cfg(test)]
pub fn parse(label: &str, bytes: &[u8], repairs: &mut Repairs) -> Result<Mtl> {
    parse_for(label, bytes, repairs, &|_| true)
}

/// `parse`, saying what is not rendered only of the materials `used` (by name): a material no
/// `usemtl` names shows nothing of it.
pub fn parse_for(
    label: &str,
    bytes: &[u8],
    repairs: &mut Repairs,
    used: &dyn Fn(&str) -> bool,
) -> Result<Mtl> {
    let mut out = Mtl::default();
    for line in joined(lines(bytes).map_err(|e| anyhow!("{label}: {e}"))?) {
        let (n, text) = (line.n, line.text.as_ref());
        let err = |msg: String| anyhow!("{label}: line {n}: '{}': {msg}", quote(text));
        let Some((key, args)) = line.statement(label, repairs)? else {
            continue;
        };
        let key = canonical(key, &KEYS);
        if let (false, Some(m)) = (key == "newmtl", out.materials.last_mut()) {
            let words = args.iter().map(|a| a.to_string()).collect();
            m.body.push((n, key.to_string(), words));
        }
        // What a statement of a material no face uses would say goes nowhere, and so does what
        // one of a second definition of a name says (that definition is dropped: `drop_repeats`).
        let mut unsaid = Repairs::new(false);
        let last = out.materials.len().wrapping_sub(1);
        let notes = match out.materials.last() {
            Some(m) if !used(&m.name) || out.index[&m.name] != last => &mut unsaid,
            _ => &mut *repairs,
        };
        if key == "newmtl" {
            // An empty name is a name (Blender 2.61 wrote one; `usemtl` with none uses it). A
            // name defined again is read as a material of its own and compared with the first
            // at the end (`drop_repeats`); the index keeps the first.
            let name = rest(text);
            out.index
                .entry(name.to_string())
                .or_insert(out.materials.len());
            out.materials.push(MtlMaterial {
                name: name.to_string(),
                line: n,
                ..Default::default()
            });
            continue;
        }
        let slot = match key {
            "map_Kd" => Some(Slot::Kd),
            "map_Ks" => Some(Slot::Ks),
            "map_Ke" => Some(Slot::Ke),
            "map_d" => Some(Slot::D),
            _ => None,
        };
        if let Some(slot) = slot {
            let Some(m) = out.materials.last_mut() else {
                return Err(err(format!("'{key}' before any newmtl")));
            };
            let (mut spec, ignored) = map_spec(n, text, &args, slot == Slot::D).map_err(err)?;
            spec.latin1 = line.latin1;
            if let Some(opt) = ignored.unknown {
                notes.note(label, n, UNKNOWN_MAP_OPTION, || {
                    format!("'{}': '{}'", quote(text), quote(opt))
                })?;
            } else if ignored.known {
                notes.note(label, n, MAP_OPTION, || format!("'{}'", quote(text)))?;
            }
            m.maps[slot as usize] = Some(spec);
            continue;
        }
        if let Some(said) = unrendered_map(key) {
            // The file as a map statement names it; where the options do not parse, the rest of
            // the line and its last word, either of which may be the file.
            match map_spec(n, text, &args, false) {
                Ok((spec, _)) => out.other_files.push(spec.file),
                Err(_) => out
                    .other_files
                    .extend([args.join(" "), args.last().unwrap_or(&"").to_string()]),
            }
            if let (true, Some(m)) = (said, out.materials.last()) {
                notes.note(label, n, UNRENDERED_MAP, || {
                    format!("'{}' in '{}'", quote(text), m.name)
                })?;
            }
            continue;
        }
        if key == "d" {
            // Dissolve (partial transparency) is not rendered: say so where it would show
            // (`d -halo 0.5` takes the last word).
            let d = args.last().and_then(|a| number(a));
            if let Some(m) = out.materials.last() {
                // Anything but a number of at least 1 (opaque): below 1, negative, not a
                // number, a decimal comma.
                if !d.is_some_and(|d| d >= 1.0) {
                    notes.note(label, n, DISSOLVE, || {
                        format!("'{}' in '{}'", quote(text), m.name)
                    })?;
                }
            }
            continue;
        }
        if key == "Pm" {
            // Metallic (PBR extensions): the surface stays Kd diffuse and Ks Phong; say so
            // where it would show.
            let pm = args.first().and_then(|a| number(a));
            if let (true, Some(m)) = (pm.is_some_and(|v| v > 0.0), out.materials.last()) {
                notes.note(label, n, METALLIC, || {
                    format!("'{}' in '{}'", quote(text), m.name)
                })?;
            }
            continue;
        }
        if !matches!(key, "Kd" | "Ks" | "Ke" | "Ns" | "Pr") {
            let known = || STATEMENTS.iter().chain(&PASSED_OVER).copied();
            if !known().any(|k| k.eq_ignore_ascii_case(key)) {
                notes.note(label, n, UNKNOWN, || {
                    format!("'{}'{}", quote(text), did_you_mean(key, known()))
                })?;
            }
            continue;
        }
        let Some(m) = out.materials.last_mut() else {
            return Err(err(format!("'{key}' before any newmtl")));
        };
        // The format's other two forms of a colour: `Kd xyz x [y z]`, CIE XYZ values, and
        // `Kd spectral file.rfl [factor]`, a spectral curve in a file of its own.
        let colour = matches!(key, "Kd" | "Ks" | "Ke");
        let form = args.first().map(|a| a.to_ascii_lowercase());
        if colour && form.as_deref() == Some("spectral") {
            return Err(err(format!(
                "spectral colours (a curve in an .rfl file) are not read: write '{key} r g b' \
                 (linear Rec.709 RGB)"
            )));
        }
        let xyz = colour && form.as_deref() == Some("xyz");
        let args = if xyz { &args[1..] } else { &args[..] };
        // A number written finite but past single precision (`Ke 1e39`) is the largest single
        // (then capped, clamped or scaled as any large value is), not the infinity it reads as:
        // `Ke 1e38` was capped at 1e9 with a warning and `Ke 1e39` refused as not finite.
        let parsed: Option<Vec<f32>> = args.iter().map(|a| number_saturating(a)).collect();
        // Numbers past the statement's (`Kd 0.2 0.3 0.4 0.9`, `Ns 10 20`): ignored, and said.
        let most = if matches!(key, "Ns" | "Pr") { 1 } else { 3 };
        if let Some(extra) = parsed.as_ref().filter(|p| p.len() > most) {
            let name = &m.name;
            notes.note(label, n, EXTRA_NUMBERS, || {
                format!(
                    "'{}' in '{name}': the {} after the {most} of {key}",
                    quote(text),
                    if extra.len() - most == 1 {
                        "number"
                    } else {
                        "numbers"
                    }
                )
            })?;
        }
        let bad = |v: f32| !v.is_finite() || v < 0.0;
        // `Ns value`, `Pr roughness`: one number.
        let one = |what: &str| {
            let [x] = parsed
                .as_deref()
                .and_then(|p| p.get(..1)?.try_into().ok())
                .ok_or_else(|| err(format!("expected '{key} {what}'")))?;
            Ok::<f32, anyhow::Error>(x)
        };
        if key == "Ns" {
            let x = one("value")?;
            if bad(x) {
                return Err(err("Ns must be finite and non-negative".into()));
            }
            m.ns = Some((x, n));
            continue;
        }
        if key == "Pr" {
            let x = one("roughness")?;
            if !x.is_finite() {
                return Err(err("Pr (roughness) must be finite".into()));
            }
            // An extension's value: outside 0..1 taken at the nearest end.
            m.pr = Some((x.clamp(0.0, 1.0), n));
            continue;
        }
        // `Kd r [g b]`: one number is a grey. Two are neither a grey nor a colour.
        let c = match parsed.as_deref() {
            Some(&[r]) => Vec3::splat(r),
            Some(&[r, g, b, ..]) => Vec3::new(r, g, b),
            _ if xyz => {
                return Err(err(format!(
                    "expected '{key} xyz x y z' (or '{key} xyz x')"
                )))
            }
            _ => return Err(err(format!("expected '{key} r g b' (or '{key} grey')"))),
        };
        if !c.is_finite() || c.min_element() < 0.0 {
            return Err(err(format!("{key} must be finite and non-negative")));
        }
        let c = if xyz {
            let rgb = xyz_to_rec709(c);
            // Values near the top of the float range (each finite) pass it in RGB.
            if !rgb.is_finite() {
                return Err(err(format!(
                    "{key} xyz: the colour is past the range of numbers in linear Rec.709 RGB"
                )));
            }
            // A colour outside the Rec.709 gamut has a negative channel, which no BSDF or
            // light can have: clamped to 0, and said.
            if rgb.min_element() < 0.0 {
                let name = &m.name;
                notes.note(label, n, OUT_OF_GAMUT, || {
                    format!(
                        "'{}' in '{name}': linear Rec.709 RGB ({}, {}, {})",
                        quote(text),
                        rgb.x,
                        rgb.y,
                        rgb.z
                    )
                })?;
            }
            rgb.max(Vec3::ZERO)
        } else {
            c
        };
        let slot = match key {
            "Kd" => &mut m.kd,
            "Ks" => &mut m.ks,
            _ => &mut m.ke,
        };
        // A colour given again in one material, otherwise: the last is used, as tinyobjloader
        // and Blender's importer use it, and said (a `Kd` written twice by a hand edit darkened
        // a floor to a third without a word).
        if let Some((was, line)) = *slot {
            if was != c {
                let name = &m.name;
                notes.note(label, n, STATED_AGAIN, || {
                    format!(
                        "'{}' in '{name}', after '{key}' at line {line}",
                        quote(text)
                    )
                })?;
            }
        }
        *slot = Some((c, n));
    }
    drop_repeats(label, &mut out, repairs, used)?;
    for m in out.materials.iter().filter(|m| used(&m.name)) {
        note_transparency(label, m, repairs)?;
    }
    Ok(out)
}

/// Transparency that is not rendered, said of a whole material (its statements may come in any
/// order), where `d` (said as it is read) does not already say it:
/// - `Tr` strictly between 0 and 1: partial transparency whichever way an exporter writes it
///   (some write `1 - d`, others `d`); `Tr 0` and `Tr 1` (MeshLab's opaque default) say nothing.
/// - the illumination models of glass (`illum 4`, `6`, `7`, `9`) with an index of refraction
///   `Ni` other than 1: a refracting surface, rendered as its `Kd` and `Ks` lobes. Maya writes
///   `illum 4` with `Ni 1` (and `Tf 1 1 1`) for every material, opaque ones too: nothing said.
fn note_transparency(label: &str, m: &MtlMaterial, repairs: &mut Repairs) -> Result<()> {
    let value = |key: &str| {
        m.body
            .iter()
            .find(|(_, k, _)| k.eq_ignore_ascii_case(key))
            .map(|(n, _, words)| (*n, words.first().and_then(|w| number(w)), words.join(" ")))
    };
    if value("d").is_some() {
        return Ok(());
    }
    let statement = |key: &str, words: &str| {
        format!(
            "'{}' in '{}'",
            quote(format!("{key} {words}").trim()),
            m.name
        )
    };
    if let Some((line, Some(t), words)) = value("Tr") {
        if t > 0.0 && t < 1.0 {
            return repairs.note(label, line, TRANSPARENCY, || statement("Tr", &words));
        }
    }
    let refracts = value("Ni").is_some_and(|(_, ni, _)| ni.is_some_and(|ni| ni != 1.0));
    if let (Some((line, _, words)), true) = (value("illum"), refracts) {
        if matches!(words.as_str(), "4" | "6" | "7" | "9") {
            return repairs.note(label, line, GLASS, || statement("illum", &words));
        }
    }
    Ok(())
}

/// A name defined twice in one file: the later definition is dropped. Where it repeats the
/// first statement for statement (Cinema 4D writes each material once per object that uses it),
/// nothing is said; where it differs, the first is used, as between files (`DEFINED_AGAIN`;
/// `--strict` refuses it). Both were refused ("already defined").
fn drop_repeats(
    label: &str,
    out: &mut Mtl,
    repairs: &mut Repairs,
    used: &dyn Fn(&str) -> bool,
) -> Result<()> {
    if out.index.len() == out.materials.len() {
        return Ok(());
    }
    let mut kept: Vec<MtlMaterial> = Vec::with_capacity(out.index.len());
    // Each kept definition's place among the kept, by its place in the file.
    let mut kept_at = HashMap::new();
    for (i, m) in std::mem::take(&mut out.materials).into_iter().enumerate() {
        let first = out.index[&m.name];
        if first == i {
            kept_at.insert(i, kept.len());
            kept.push(m);
            continue;
        }
        let earlier = &kept[kept_at[&first]];
        // The same statements in the same order, wherever their lines are.
        let same =
            (earlier.body.iter().map(|(_, k, w)| (k, w))).eq(m.body.iter().map(|(_, k, w)| (k, w)));
        if !same && used(&m.name) {
            let first_line = earlier.line;
            repairs.note(label, m.line, DEFINED_AGAIN, || {
                format!("material '{}' (first at line {first_line})", m.name)
            })?;
        }
    }
    out.index = kept
        .iter()
        .enumerate()
        .map(|(i, m)| (m.name.clone(), i))
        .collect();
    out.materials = kept;
    Ok(())
}

impl MtlMaterial {
    /// The material as the BSDF uses it: missing values are zero (`Kd` too: a material that
    /// gives none does not reflect diffusely), clamped values noted in `repairs`.
    pub fn material(&self, label: &str, repairs: &mut Repairs) -> Result<Material> {
        // A map without its colour line is the texture as it is (colour 1).
        let get = |v: Option<(Vec3, usize)>, slot: Slot| {
            v.map_or(
                if self.maps[slot as usize].is_some() {
                    Vec3::ONE
                } else {
                    Vec3::ZERO
                },
                |v| v.0,
            )
        };
        let (mut kd, mut ks, mut ke) = (
            get(self.kd, Slot::Kd),
            get(self.ks, Slot::Ks),
            get(self.ke, Slot::Ke),
        );
        let name = &self.name;
        // `Kd 0` beside a `map_Kd`: Maya writes it for a colour connected to a file texture (its
        // own value unused), and Blender and Maya show the texture. As the format reads it (the
        // texture times Kd) the surface was black, without a word.
        if kd == Vec3::ZERO && self.maps[Slot::Kd as usize].is_some() {
            kd = Vec3::ONE;
            let line = self.kd.map_or(self.line, |v| v.1);
            repairs.note(label, line, KD_ZERO_MAP, || format!("material '{name}'"))?;
        }
        // `Ks 0` or `Ke 0` beside its map: the map does nothing, said so (it was dropped without
        // a word, and a lamp textured so was refused as no light). Not read as 1: an exporter
        // writes `Ke` as the emission's colour times its strength, and a strength of 0 with an
        // image on the colour means no light, which reading it as 1 would add.
        for (value, given, slot, kind) in [
            (ks, self.ks, Slot::Ks, KS_ZERO_MAP),
            (ke, self.ke, Slot::Ke, KE_ZERO_MAP),
        ] {
            if value == Vec3::ZERO && self.maps[slot as usize].is_some() {
                let line = given.map_or(self.line, |v| v.1);
                repairs.note(label, line, kind, || format!("material '{name}'"))?;
            }
        }
        // Without `Ns`, Blender's exponent for a roughness `Pr` (what it writes as `Ns` without
        // its PBR extensions, and reads `Ns` back as): 1000 (1 - Pr)^2.
        let mut ns = match (self.ns, self.pr) {
            (Some((ns, _)), _) => ns,
            (None, Some((pr, _))) => 1000.0 * (1.0 - pr) * (1.0 - pr),
            (None, None) => 0.0,
        };
        // In f64: Kd + Ks of two values near f32::MAX is not finite in f32.
        let sum = kd.as_dvec3() + ks.as_dvec3();
        // A lobe with a map is the constant times the texel, and the pair is scaled where that
        // passes 1, point by point (`Maps::apply`): scaled here too, a textured material was
        // darkened as if every texel were white (Blender's `Kd 0.8` + `Ks 0.5` + `map_Kd`, a
        // fifth dark in both lobes where the texture is dark, against Mitsuba 3).
        let textured =
            self.maps[Slot::Kd as usize].is_some() || self.maps[Slot::Ks as usize].is_some();
        if !textured && sum.max_element() > 1.0 + 1e-6 {
            // Scale both lobes by one factor, so that the largest channel's sum is 1: the
            // colours of both lobes are kept (per channel, a red diffuse under a white Ks 0.5,
            // as Blender exports it, got a cyan highlight).
            let scale = glam::DVec3::splat(sum.max_element().recip());
            let (kd0, ks0) = (kd, ks);
            kd = (kd.as_dvec3() * scale).as_vec3();
            ks = (ks.as_dvec3() * scale).as_vec3();
            repairs.note(label, self.line, ENERGY, || {
                format!(
                    "material '{name}': Kd {} + Ks {} became Kd {} + Ks {}",
                    rgb(kd0),
                    rgb(ks0),
                    rgb(kd),
                    rgb(ks)
                )
            })?;
        }
        // A Phong lobe of `Ns` 1 or less is about as wide as the diffuse one: beside a `map_Kd`
        // it is a second, untextured diffuse lobe that takes the texture's share of the energy
        // (`Kd + Ks` at most 1 per texel), so the texture shows faded to the `Ks` colour.
        // MeshLab writes `Ks 1 1 1` and `Ns 0` for every material: its textured scans came out
        // near white without a word.
        // Said where `Ks` takes half the range or more (a weak `Ks 0.1` without `Ns` is common
        // and shows little).
        if self.maps[Slot::Kd as usize].is_some() && ks.max_element() >= 0.5 && ns <= 1.0 {
            let line = self.ks.map_or(self.line, |v| v.1);
            repairs.note(label, line, WIDE_KS, || {
                format!("material '{name}': Ks {} with Ns {}", rgb(ks), num(ns))
            })?;
        }
        if ns > MAX_NS {
            let line = self.ns.map_or(self.line, |v| v.1);
            repairs.note(label, line, NS, || {
                format!("material '{name}': Ns {} capped at {MAX_NS:e}", num(ns))
            })?;
            ns = MAX_NS;
        }
        if ke.max_element() > MAX_KE {
            let line = self.ke.map_or(self.line, |v| v.1);
            let ke0 = ke;
            ke = ke.min(Vec3::splat(MAX_KE));
            repairs.note(label, line, KE, || {
                format!("material '{name}': Ke {} capped at {MAX_KE:e}", rgb(ke0))
            })?;
        }
        Ok(Material { kd, ks, ns, ke })
    }
}

/// The largest `-s` or `-o` a map takes (`map_spec`).
const MAX_MAP_UV: f32 = 1e5;

/// The options of a map statement that reframe does not apply.
#[derive(Default)]
struct Ignored<'a> {
    /// An option of the format reframe does not apply (`-bm`, `-clamp`, ...).
    known: bool,
    /// The first option the format does not have (an exporter's own, such as `-colorspace`).
    unknown: Option<&'a str>,
}

/// The options and file name of a `map_K?` line (`args`: its words after the key), and which
/// options reframe ignores.
///
/// An option the format does not have is skipped with what follows it, as far as that can be
/// told without knowing the option: the numbers after it, or else one word where two or more
/// words follow (a value and the file name), or else nothing (the word after it is the file).
fn map_spec<'a>(
    n: usize,
    text: &str,
    args: &[&'a str],
    scalar: bool,
) -> std::result::Result<(MapSpec, Ignored<'a>), String> {
    let mut ignored = Ignored::default();
    let mut spec = MapSpec {
        file: String::new(),
        scale: Vec2::ONE,
        offset: Vec2::ZERO,
        line: n,
        statement: text.trim().to_string(),
        channel: None,
        latin1: false,
    };
    let mut i = 0;
    // Up to `most` numbers after an option (fewer if a word is not a number).
    let numbers_after = |i: usize, most: usize| -> Vec<f32> {
        args[i + 1..]
            .iter()
            .take(most)
            .map_while(|w| number(w))
            .collect()
    };
    while i < args.len() && args[i].starts_with('-') && args[i].len() > 1 {
        let opt = args[i];
        let taken = match opt {
            "-o" | "-s" => {
                let v = numbers_after(i, 3);
                if v.is_empty() || !v.iter().all(|x| x.is_finite()) {
                    return Err(format!("'{opt}' expects 1 to 3 finite numbers"));
                }
                // A fourth number with words after it: the file name is not '4 c.png'.
                let next = args.get(i + 1 + v.len()).filter(|w| number(w).is_some());
                if let (Some(w), true) = (next, i + 2 + v.len() < args.len()) {
                    return Err(format!(
                        "'{opt}' takes at most 3 numbers, and '{w}' follows them"
                    ));
                }
                // Texture coordinates are single floats: scaled or moved past 1e5, a repeat
                // of the map is a few texels wide (it collapsed to one texel at 1e30); a scale
                // of 0 maps the whole surface to one texel. The third number (w, for 3D
                // textures) is not used, and not checked.
                let mut uv = v.iter().take(2);
                let (what, bad) = if opt == "-s" {
                    ("a scale", uv.find(|x| **x == 0.0 || x.abs() > MAX_MAP_UV))
                } else {
                    ("an offset", uv.find(|x| x.abs() > MAX_MAP_UV))
                };
                if let Some(x) = bad {
                    return Err(format!(
                        "'{opt}': {what} of {} leaves no detail of the map (at most {MAX_MAP_UV:e} \
                         in size{})",
                        num(*x),
                        if opt == "-s" { ", and not 0" } else { "" }
                    ));
                }
                let uv = Vec2::new(
                    v[0],
                    v.get(1)
                        .copied()
                        .unwrap_or(if opt == "-s" { 1.0 } else { 0.0 }),
                );
                if opt == "-s" {
                    spec.scale = uv;
                } else {
                    spec.offset = uv;
                }
                v.len()
            }
            "-t" => numbers_after(i, 3).len().max(1),
            "-mm" => 2,
            "-blendu" | "-blendv" | "-cc" | "-clamp" | "-bm" | "-boost" | "-texres"
            | "-imfchan" | "-type" => 1,
            _ => {
                ignored.unknown.get_or_insert(opt);
                let numbers = numbers_after(i, usize::MAX).len();
                if numbers > 0 {
                    numbers
                } else if args.len() - i >= 3 && !args[i + 1].starts_with('-') {
                    1
                } else {
                    0
                }
            }
        };
        if i + taken >= args.len() {
            return Err(format!(
                "'{opt}' needs its value(s) and a file name after it"
            ));
        }
        if opt == "-imfchan" && scalar {
            let c = args[i + 1];
            if !matches!(c, "r" | "g" | "b" | "m" | "l" | "z") {
                return Err(format!("'-imfchan {c}': expected r, g, b, m, l or z"));
            }
            spec.channel = c.chars().next();
        }
        let applied = matches!(opt, "-o" | "-s") || (scalar && opt == "-imfchan");
        ignored.known |= !applied;
        i += 1 + taken;
    }
    if i >= args.len() {
        return Err("expected a file name".into());
    }
    // The name as written, from its first word to the end of the line: a run of spaces or a tab
    // in it is kept (`my  tex.png`; joined from its words it named 'my tex.png', another file).
    spec.file = rest_from(text, args[i]).map_or_else(|| args[i..].join(" "), str::to_string);
    Ok((spec, ignored))
}

/// `text` from the word `word` (a slice of it, as `Line::statement` gives its words) to its end,
/// less trailing white space; `None` if `word` is not a slice of `text`.
fn rest_from<'t>(text: &'t str, word: &str) -> Option<&'t str> {
    let start = (word.as_ptr() as usize).checked_sub(text.as_ptr() as usize)?;
    (start + word.len() <= text.len())
        .then(|| text.get(start..))
        .flatten()
        .map(str::trim_end)
}

/// A number as a message shows it: short, in exponent form when large.
fn num(x: f32) -> String {
    // A number written past single precision is read as its largest (`number_saturating`).
    if x.abs() == f32::MAX {
        let sign = if x < 0.0 { "-" } else { "" };
        format!("{sign}(past 3.4e38)")
    } else if x.abs() >= 1e6 {
        format!("{x:e}")
    } else {
        format!("{}", (x * 1e4).round() / 1e4)
    }
}

fn rgb(c: Vec3) -> String {
    format!("{} {} {}", num(c.x), num(c.y), num(c.z))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn xyz_colours_are_read_as_linear_rec709() {
        // The published XYZ-to-linear-sRGB matrix (IEC 61966-2-1, to its 4 decimals, which it
        // derived from rounded values: within 5e-4 of the exact one), column by column, and the
        // D65 white (x 0.3127, y 0.3290) to white.
        let columns = [
            (Vec3::X, Vec3::new(3.2406, -0.9689, 0.0557)),
            (Vec3::Y, Vec3::new(-1.5372, 1.8758, -0.2040)),
            (Vec3::Z, Vec3::new(-0.4986, 0.0415, 1.0570)),
            (Vec3::new(0.950456, 1.0, 1.089058), Vec3::ONE),
        ];
        for (xyz, rgb) in columns {
            let got = xyz_to_rec709(xyz);
            assert!(got.abs_diff_eq(rgb, 5e-4), "{xyz} -> {got}, not {rgb}");
        }
        // In a file: the D65 white, one number for all three, and a colour outside the gamut
        // (pure Y), whose negative channels are 0 with a warning.
        let text = "newmtl a\nKd xyz 0.950456 1 1.089058\nnewmtl b\nKs XYZ 0.5\nnewmtl c\n\
                    Ke xyz 0 1 0\n";
        let mut r = Repairs::new(false);
        let m = parse("a.mtl", text.as_bytes(), &mut r).unwrap();
        assert!(m.materials[0].kd.unwrap().0.abs_diff_eq(Vec3::ONE, 1e-4));
        let ks = m.materials[1].ks.unwrap().0;
        assert!(
            ks.abs_diff_eq(xyz_to_rec709(Vec3::splat(0.5)), 1e-6),
            "{ks}"
        );
        let ke = m.materials[2].ke.unwrap().0;
        assert!(
            ke.x == 0.0 && ke.z == 0.0 && (ke.y - 1.8758).abs() < 5e-4,
            "{ke}"
        );
        let w = r.into_warnings();
        assert!(
            w.len() == 1
                && w[0].contains("line 6: 'Ke xyz 0 1 0' in 'c'")
                && w[0].contains("gamut"),
            "{w:?}"
        );
    }

    #[test]
    fn statements_and_refusals() {
        let ok = "# c\nnewmtl a\nKd 0.5 0.5 0.5\nillum 2\nnewmtl b\nKe 1 1 1\nKa x\n";
        let m = parse("a.mtl", ok.as_bytes(), &mut Repairs::new(false)).unwrap();
        assert_eq!(m.index["b"], 1);
        assert_eq!(m.materials[1].line, 5);
        for (bad, want) in [
            (
                "Kd 0.5 0.5",
                "line 8: 'Kd 0.5 0.5': expected 'Kd r g b' (or 'Kd grey')",
            ),
            ("Ks 1 x 1", "expected 'Ks r g b'"),
            ("Ke -1 0 0", "Ke must be finite and non-negative"),
            ("Kd nan 0 0", "Kd must be finite"),
            ("Ns", "expected 'Ns value'"),
            ("Kd xyz", "expected 'Kd xyz x y z' (or 'Kd xyz x')"),
            ("Ke xyz 1 1", "expected 'Ke xyz x y z'"),
            ("Kd xyz -1 0 0", "Kd must be finite and non-negative"),
            (
                "Kd spectral grey.rfl 0.8",
                "spectral colours (a curve in an .rfl file) are not read: write 'Kd r g b'",
            ),
            ("Ns -5", "Ns must be finite and non-negative"),
        ] {
            let e = parse(
                "a.mtl",
                format!("{ok}{bad}\n").as_bytes(),
                &mut Repairs::new(false),
            )
            .unwrap_err()
            .to_string();
            assert!(e.contains(want), "{bad}: {e}");
        }
        let e = parse("a.mtl", b"Kd 1 1 1\nnewmtl a\n", &mut Repairs::new(false))
            .unwrap_err()
            .to_string();
        assert!(e.contains("before any newmtl"), "{e}");
    }

    #[test]
    fn a_material_defined_twice_in_one_file() {
        // Repeated statement for statement (Cinema 4D's export; spacing and comments aside):
        // one material, and what it has that is not rendered said of the first only.
        let repeated = "newmtl a\nKd 0.5 0.5 0.5\nPm 0.5\nnewmtl b\nKe 1 1 1\nnewmtl a\n  Kd 0.5 \
                        0.5  0.5 # grey\nPm 0.5\n";
        let mut r = Repairs::new(false);
        let m = parse("a.mtl", repeated.as_bytes(), &mut r).unwrap();
        assert_eq!((m.materials.len(), m.index["a"], m.index["b"]), (2, 0, 1));
        let said = r.into_warnings();
        assert_eq!(said.len(), 1, "{said:?}");
        assert!(
            said[0].starts_with("a.mtl: line 3: 'Pm 0.5' in 'a'"),
            "{said:?}"
        );
        // Defined otherwise: the first definition is used, said once; refused when strict; an
        // empty name too.
        for (text, name, kd, line) in [
            (
                "newmtl a\nKd 0.5 0.5 0.5\nnewmtl b\nnewmtl a\nKd 0.1 0.1 0.1\n",
                "a",
                0.5,
                4,
            ),
            ("newmtl \nKd 1 1 1\nnewmtl\n", "", 1.0, 3),
        ] {
            let mut r = Repairs::new(false);
            let m = parse("a.mtl", text.as_bytes(), &mut r).unwrap();
            let first = &m.materials[m.index[name]];
            assert_eq!(
                (first.line, first.kd.map(|k| k.0)),
                (1, Some(Vec3::splat(kd)))
            );
            assert_eq!(m.materials.iter().filter(|m| m.name == name).count(), 1);
            let said = r.into_warnings();
            assert_eq!(said.len(), 1, "{said:?}");
            let want = format!("a.mtl: line {line}: material '{name}' (first at line 1)");
            assert!(
                said[0].starts_with(&want) && said[0].contains("defined twice"),
                "{said:?}"
            );
            let e = parse("a.mtl", text.as_bytes(), &mut Repairs::new(true)).unwrap_err();
            assert!(format!("{e:#}").contains("defined twice"), "{e:#}");
        }
        // A material no face uses says nothing of its second definition.
        let mut r = Repairs::new(false);
        let text = "newmtl a\nKd 0.5 0.5 0.5\nnewmtl a\nKd 0.1 0.1 0.1\n";
        parse_for("a.mtl", text.as_bytes(), &mut r, &|n| n != "a").unwrap();
        assert!(r.into_warnings().is_empty());
    }

    #[test]
    fn keys_in_any_case_and_comments_after_numbers() {
        let text = "NEWMTL a\nkd 0.5 0.25 0.125 # brown\nKE 1 2 3\nmap_kd t.png\n";
        let mut r = Repairs::new(false);
        let mtl = parse("a.mtl", text.as_bytes(), &mut r).unwrap();
        let m = mtl.materials[0].material("a.mtl", &mut r).unwrap();
        assert_eq!(m.kd, Vec3::new(0.5, 0.25, 0.125));
        assert_eq!(m.ke, Vec3::new(1.0, 2.0, 3.0));
        assert_eq!(
            mtl.materials[0].maps[Slot::Kd as usize]
                .as_ref()
                .unwrap()
                .file,
            "t.png"
        );
        assert!(r.into_warnings().is_empty());
    }

    #[test]
    fn maps_that_are_not_rendered_are_said_once() {
        // Blender's, 3ds Max's and the PBR extension's maps, any case; map_Ka and d 1 say
        // nothing; d below 1 (or no number) says it is not rendered.
        let text =
            "map_Bump before.png\nnewmtl a\nmap_Bump -bm 1 n.png\nbump b.png\nmap_Ka a.png\n\
                    d 1.0\nd -halo 1\nnewmtl b\nNORM n.png\nmap_Pr r.png\nd 0.25\n";
        let mut r = Repairs::new(false);
        parse("a.mtl", text.as_bytes(), &mut r).unwrap();
        assert_eq!(
            r.into_warnings(),
            [
                "a.mtl: 4 texture maps not rendered (reframe renders map_Kd, map_Ks, map_Ke and \
                 map_d) (first at line 3: 'map_Bump -bm 1 n.png' in 'a')",
                "a.mtl: line 11: 'd 0.25' in 'b': dissolve (d) not rendered: the surface is \
                 opaque (map_d cut-outs are rendered)"
            ]
        );
        let e = parse("a.mtl", text.as_bytes(), &mut Repairs::new(true)).unwrap_err();
        assert!(e.to_string().contains("line 3"), "{e}");
    }

    /// What is not rendered is said only of materials in use: a library MTL's unused
    /// materials say nothing (their `d`, `Pm`, `bump` reached the warnings and `--strict`).
    #[test]
    fn only_materials_in_use_say_what_is_not_rendered() {
        let text = "newmtl used\nd 0.5\nPm 1\nnewmtl spare\nd 0.5\nPm 1\nbump b.png\n\
                    map_Kd -bm 2 k.png\n";
        let mut r = Repairs::new(false);
        let mtl = parse_for("a.mtl", text.as_bytes(), &mut r, &|n| n == "used").unwrap();
        assert_eq!(mtl.materials.len(), 2);
        let w = r.into_warnings();
        assert_eq!(w.len(), 2, "{w:?}");
        assert!(w.iter().all(|w| w.contains("in 'used'")), "{w:?}");
        // Under strict loading the unused material refuses nothing.
        let strict = parse_for(
            "a.mtl",
            b"newmtl used\nnewmtl spare\nd 0.5\n",
            &mut Repairs::new(true),
            &|n| n == "used",
        );
        assert!(strict.is_ok());
    }

    /// Blender's MTL export with PBR extensions writes the roughness as `Pr` and no `Ns`: the
    /// exponent is Blender's for that roughness, 1000 (1 - Pr)^2 (it was 0, a lobe with no
    /// highlight); an `Ns` wins over it; a metallic `Pm` is said not to be rendered.
    #[test]
    fn pbr_roughness_gives_the_exponent_and_metallic_is_said() {
        let text = "newmtl a\nKd 0.5 0.2 0.1\nKs 0.25 0.25 0.25\nPr 0.4\nPm 0.9\nPs 0.06\n\
                    newmtl b\nKs 0.5\nPr 0.4\nNs 50\nPm 0\nnewmtl c\nKs 0.5\n";
        let mut r = Repairs::new(false);
        let mtl = parse("a.mtl", text.as_bytes(), &mut r).unwrap();
        let ns: Vec<f32> = mtl
            .materials
            .iter()
            .map(|m| m.material("a.mtl", &mut r).unwrap().ns)
            .collect();
        assert!((ns[0] - 360.0).abs() < 1e-3, "{ns:?}");
        assert_eq!(ns[1..], [50.0, 0.0]);
        assert_eq!(
            r.into_warnings(),
            ["a.mtl: line 5: 'Pm 0.9' in 'a': metallic (Pm) not rendered: the surface is its Kd \
              diffuse and Ks Phong lobes"]
        );
        for bad in ["Pr inf", "Pr x"] {
            let text = format!("newmtl a\n{bad}\n");
            assert!(
                parse("a.mtl", text.as_bytes(), &mut Repairs::new(false)).is_err(),
                "{bad}"
            );
        }
    }

    #[test]
    fn clamps_warn_once_per_kind() {
        let text = "newmtl a\nKd 0.8\t0.2 0.2\nKs  0.5 0.5 0.5\nNs 1e30\nKe 1e38 1 1\n\
                    newmtl b\nKd 1 1 1\nKs 1 1 1\nnewmtl c\nKd 3e38 0 0\nKs 3e38 0 0\n";
        let mut r = Repairs::new(false);
        let mtl = parse("a.mtl", text.as_bytes(), &mut r).unwrap();
        let a = mtl.materials[0].material("a.mtl", &mut r).unwrap();
        let b = mtl.materials[1].material("a.mtl", &mut r).unwrap();
        let c = mtl.materials[2].material("a.mtl", &mut r).unwrap();
        assert_eq!((c.kd.x, c.ks.x), (0.5, 0.5));
        assert!(((a.kd + a.ks).x - 1.0).abs() < 1e-6 && (a.kd.x / a.ks.x - 1.6).abs() < 1e-5);
        // One factor for every channel: the highlight stays white, the diffuse as red.
        assert!(a.ks.y == a.ks.x && a.ks.z == a.ks.x, "{:?}", a.ks);
        assert!(
            (a.kd.y / a.kd.x - 0.25).abs() < 1e-6 && a.kd.z == a.kd.y,
            "{:?}",
            a.kd
        );
        assert_eq!(a.ns, MAX_NS);
        assert_eq!(a.ke, Vec3::new(MAX_KE, 1.0, 1.0));
        assert_eq!(b.kd + b.ks, Vec3::ONE);
        let w = r.into_warnings();
        assert_eq!(w.len(), 3, "{w:?}");
        assert!(w[0].starts_with("a.mtl: 3 materials with Kd + Ks above 1 scaled down to 1"));
        assert_eq!(
            w[1],
            "a.mtl: line 4: material 'a': Ns 1e30 capped at 1e6: Ns capped (the Phong lobe is \
             unstable above it)"
        );
        assert!(
            w[2].starts_with("a.mtl: line 5: material 'a': Ke 1e38 1 1 capped at 1e9"),
            "{}",
            w[2]
        );
        let mut strict = Repairs::new(true);
        let e = mtl.materials[1].material("a.mtl", &mut strict).unwrap_err();
        assert!(
            e.to_string().starts_with("a.mtl: line 6: material 'b'"),
            "{e}"
        );
    }

    #[test]
    fn texture_maps_and_their_options() {
        let text = "newmtl a\nmap_Kd -s 2 3 -o 0.5 wood grain.png\nKs 0\n\
                    map_Ks -blendu off -mm 0 1 -t 0.1 0.1 shine.exr\n\
                    newmtl b\nKd 0.5\nmap_Ke -o 0.25 0.5 0 glow.png\n";
        let mut r = Repairs::new(false);
        let mtl = parse("a.mtl", text.as_bytes(), &mut r).unwrap();
        let [kd, ks, ke, _] = &mtl.materials[0].maps;
        let kd = kd.as_ref().unwrap();
        assert_eq!(kd.file, "wood grain.png");
        assert_eq!(
            (kd.scale, kd.offset),
            (Vec2::new(2.0, 3.0), Vec2::new(0.5, 0.0))
        );
        assert_eq!(kd.line, 2);
        assert_eq!(ks.as_ref().unwrap().file, "shine.exr");
        assert!(ke.is_none());
        let glow = mtl.materials[1].maps[Slot::Ke as usize].as_ref().unwrap();
        assert_eq!((glow.scale, glow.offset), (Vec2::ONE, Vec2::new(0.25, 0.5)));
        // A map without its colour line is the texture as it is; with one, their product; a
        // Ks of 0 beside its map makes the map useless, with a warning.
        let a = mtl.materials[0].material("a.mtl", &mut r).unwrap();
        let b = mtl.materials[1].material("a.mtl", &mut r).unwrap();
        assert_eq!((a.kd, a.ks), (Vec3::ONE, Vec3::ZERO));
        assert_eq!((b.kd, b.ke), (Vec3::splat(0.5), Vec3::ONE));
        let w = r.into_warnings();
        assert_eq!(w.len(), 2, "{w:?}");
        assert!(
            w[1].starts_with("a.mtl: line 3: material 'a': map_Ks has no effect"),
            "{}",
            w[1]
        );
        assert!(
            w[0].starts_with("a.mtl: line 4: 'map_Ks -blendu off"),
            "{}",
            w[0]
        );
        assert!(w[0].contains("texture map option ignored"), "{}", w[0]);
        // Options the format does not have: skipped with their numbers, or one word where a
        // file name follows it, or nothing where the next word is the file.
        for (line, file, skipped) in [
            ("map_Kd -foo 1 2 a b.png", "a b.png", "-foo"),
            ("map_Kd -colorspace sRGB a.png", "a.png", "-colorspace"),
            ("map_Kd -flip a.png", "a.png", "-flip"),
            ("map_Kd -s 2 -x -y 3 a.png", "a.png", "-x"),
        ] {
            let mut r = Repairs::new(false);
            let m = parse("a.mtl", format!("newmtl a\n{line}\n").as_bytes(), &mut r).unwrap();
            let spec = m.materials[0].maps[Slot::Kd as usize].as_ref().unwrap();
            assert_eq!(spec.file, file, "{line}");
            let w = r.into_warnings();
            assert_eq!(
                w,
                [format!(
                    "a.mtl: line 2: '{line}': '{skipped}': unknown texture map option ignored, \
                     with the numbers or the one word after it"
                )]
            );
            let e = parse(
                "a.mtl",
                format!("newmtl a\n{line}\n").as_bytes(),
                &mut Repairs::new(true),
            );
            assert!(e
                .unwrap_err()
                .to_string()
                .contains("(refused: strict loading)"));
        }
        for (bad, want) in [
            ("map_Kd -s 2 2", "expected a file name"),
            (
                "map_Kd -clamp",
                "'-clamp' needs its value(s) and a file name after it",
            ),
            ("map_Kd -o x a.png", "'-o' expects 1 to 3 finite numbers"),
            ("map_Ke", "expected a file name"),
        ] {
            let e = parse(
                "a.mtl",
                format!("newmtl a\n{bad}\n").as_bytes(),
                &mut Repairs::new(false),
            )
            .unwrap_err()
            .to_string();
            assert!(
                e.contains(&format!("line 2: '{bad}': {want}")),
                "{bad}: {e}"
            );
        }
        let e = parse("a.mtl", b"map_Kd a.png\n", &mut Repairs::new(false)).unwrap_err();
        assert!(e.to_string().contains("'map_Kd' before any newmtl"), "{e}");
    }
}
