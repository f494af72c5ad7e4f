//! Scenes: a small TOML file naming an OBJ (geometry, MTL materials) and the camera path.
//!
//! ```toml
//! obj = "vase.obj"            # relative to the TOML file
//! frames = 48
//! resolution = [320, 240]     # width, height
//! interpolation = "linear"    # optional: "linear" (the default) or "catmull-rom"
//! [[keyframe]]                # one or more; frames 0-based, strictly increasing
//! frame = 0
//! position = [0.0, 1.2, 4.0]
//! look_at = [0.0, 0.9, 0.0]
//! up = [0.0, 1.0, 0.0]
//! fov = 50.0                  # vertical, degrees, in (0, 180)
//! ```
//!
//! Instead of `obj`, `[[object]]` tables place several OBJs by transforms (`scene/objects.rs`:
//! an OBJ placed more than once becomes one Embree prototype with an instance per placement).
//!
//! Instead of `[[keyframe]]` tables (exactly one of the two), `camera = "shot.json"` (or `.csv`,
//! relative to the TOML) names a camera file with one camera per frame, as animation packages
//! export it: a camera-to-world matrix or position/look-at/up, and the vertical fov, for every
//! frame in order, nothing interpolated (`scene/camera_file.rs`; formats and the Catmull-Rom
//! spline in docs/camera.md). Every frame's camera is checked either way.
//!
//! Materials: `Kd` Lambertian, `Ks`/`Ns` modified Phong, `Ke` emission (one-sided, to the
//! side its vertex normals point to, else to the side of the counter-clockwise face normal:
//! `mesh::orient_emitters`). Every triangle with `Ke > 0` is an area light.
//! `map_Kd`, `map_Ks` and `map_Ke` multiply their colour by a texture at the OBJ's `vt`
//! coordinates (`scene/maps.rs`, looked up through `image::Textures`); `Scene::material` gives
//! the material at a point with its textures applied. `map_d` cuts a surface out where its mask
//! is below one half (`scene/cutout.rs`, a filter inside Embree's traversal).
//! `[environment]` (an `image` or a `radiance`, `intensity`, `rotation`) adds the environment
//! light of `scene/environment.rs`. A scene needs an area light or an environment that emits.
//!
//! Loading is strict where the input is unsafe or ambiguous and lenient, but loud, where a
//! production loader would load a real model: what it refuses fails with a one-line error
//! naming the file and the line (and the key or statement) at fault; what it repairs (a
//! missing MTL, an unknown material, `Kd + Ks` above 1, a huge `Ns` or `Ke`, a zero normal, a
//! degenerate triangle, polylines ...) becomes one warning per kind with a count, in
//! `Scene::warnings`, or an error under `LoadOptions { strict: true }`. Every file (TOML,
//! camera file, OBJ, MTL) is opened through `read_input` (regular files only, size capped) and
//! listed in `Scene::inputs`. The OBJ and MTL rules are in
//! `scene/obj.rs` and `scene/mtl.rs`, the triangulation in `scene/mesh.rs`. Limits: at most
//! `MAX_FRAMES` frames and `MAX_PIXELS` pixels, coordinates (vertices, camera) at most 1e18
//! in magnitude, files of at most `MAX_INPUT_BYTES`.
//! The shipped scenes (`vase`, `vase-long`, `cornell`, `furnace`) are embedded in the binary.
//!
//! ```no_run
//! use reframe::{embree::Device, scene::Scene};
//! let device = Device::new()?;
//! let scene = Scene::load("vase", &device)?;
//! assert_eq!(scene.frames, 48);
//! let strict = Scene::load_with("vase", &device, &reframe::scene::LoadOptions { strict: true })?;
//! assert!(strict.warnings.is_empty());
//! # anyhow::Ok(())
//! ```
use crate::bsdf::Material;
use crate::camera::{Camera, CameraPath, Cameras, Interpolation, Keyframe, Pose};
use crate::embree::{Cutout, Cutouts, Device, Hit, MeshRef, Placement, TriangleScene};
use crate::image::Textures;
use crate::util::text::plain_types;
use anyhow::{anyhow, bail, Context, Result};
use cutout::MeshCutout;
use environment::Environment;
use glam::{DVec3, Vec2, Vec3};
pub use light_lanes::LightLanes;
pub use maps::{Map, Maps};
pub use objects::{Instance, Prototype};
use serde::{de, Deserialize, Deserializer};
use std::collections::{HashMap, HashSet};
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use toml::Spanned;

mod camera_file;
mod coplanar;
mod cutout;
mod files;
pub(crate) use files::{locate_named_file, missing_file_message};
use files::{mtl_paths, scene_named, Listings};
pub mod environment;
mod light_lanes;
mod lights;
use lights::{area_sample, stretch, AreaInputs, AreaPick, AreaSample, LightPick};
pub use lights::{LightSample, Lights};
mod maps;
mod mesh;
mod mtl;
mod obj;
mod objects;
mod precision;
mod repairs;
mod text;
mod view;
pub use crate::util::input::{read_input, read_input_or_missing, InputError, MAX_INPUT_BYTES};
use mesh::Mesh;
pub use mtl::{MAX_KE, MAX_NS};
use repairs::{Kind, Repairs};
use text::{as_text, fov_fault, line_at, quote, quote_name, Lines, MAX_COORD, MAX_DEGREES};

/// Most frames a scene may have: every frame of the camera path is checked when it loads.
pub const MAX_FRAMES: u32 = 1_000_000;
/// Most pixels of a scene's resolution (16384 x 16384).
pub const MAX_PIXELS: u64 = 1 << 28;
/// The least radiance the brightest light of a scene may emit (`Scene::brightest_emission`): a
/// path multiplies it by its throughput (albedos, cosines; 1e-6 after a few dark bounces) and a
/// reuse film by its unit, and below single precision's smallest normal number (1.2e-38) the
/// tracer's threads flush values to zero (FTZ/DAZ, as Embree asks). 1e-30 leaves those products
/// a factor 1e8; an environment at intensity 1e-40 rendered every frame black without a word.
pub const MIN_LIGHT: f32 = 1e-30;

/// The scenes shipped in `scenes/`, compiled into the binary: (name, toml, obj, mtl).
const BUILTIN: &[(&str, &str, &str, &str)] = &[
    (
        "vase",
        include_str!("../scenes/vase.toml"),
        include_str!("../scenes/vase.obj"),
        include_str!("../scenes/vase.mtl"),
    ),
    (
        "vase-long",
        include_str!("../scenes/vase-long.toml"),
        include_str!("../scenes/vase.obj"),
        include_str!("../scenes/vase.mtl"),
    ),
    (
        "cornell",
        include_str!("../scenes/cornell.toml"),
        include_str!("../scenes/cornell.obj"),
        include_str!("../scenes/cornell.mtl"),
    ),
    (
        "furnace",
        include_str!("../scenes/furnace.toml"),
        include_str!("../scenes/furnace.obj"),
        include_str!("../scenes/furnace.mtl"),
    ),
];

pub fn builtin_names() -> Vec<&'static str> {
    BUILTIN.iter().map(|b| b.0).collect()
}

/// How to load a scene.
#[derive(Clone, Copy, Debug, Default)]
pub struct LoadOptions {
    /// Refuse what the loader would otherwise repair with a warning (each warning becomes an
    /// error naming the file and line).
    pub strict: bool,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    /// One OBJ as it is, or else `[[object]]` tables (objects placed by transforms).
    obj: Option<Spanned<String>>,
    object: Option<Tables<objects::ObjectFile>>,
    frames: Spanned<Whole>,
    resolution: Spanned<Exactly<Whole, 2>>,
    /// `[[keyframe]]` tables, or else `camera`: a camera file.
    keyframe: Option<Tables<KeyframeFile>>,
    camera: Option<Spanned<String>>,
    /// How the keyframes are interpolated (linear if not given).
    interpolation: Option<Spanned<Interpolation>>,
    /// Not `Spanned`: the toml crate cannot give the span of a table written with dotted keys
    /// (`environment.radiance = [1, 1, 1]`), and refused it (`EnvironmentFile::line`).
    environment: Option<Table<EnvironmentFile>>,
}

/// What a table of the scene file is, in a message about what was written in its place.
trait TableName {
    const WHAT: &'static str;
}

impl TableName for EnvironmentFile {
    const WHAT: &'static str =
        "the [environment] table (image = \"sky.exr\" or radiance = [r, g, b], with intensity \
         and rotation)";
}

impl TableName for KeyframeFile {
    const WHAT: &'static str = "[[keyframe]] tables, one per keyframe";
}

impl TableName for objects::ObjectFile {
    const WHAT: &'static str = "[[object]] tables, one per object";
}

/// A table written as one (`[environment]`). serde's derived structs also take an array, their
/// fields in order: `[[environment]]` was refused as "invalid type: map, expected a string"
/// (of its first field), and a string in its place as "expected struct EnvironmentFile".
struct Table<T>(T);

impl<'de, T: Deserialize<'de> + TableName> Deserialize<'de> for Table<T> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V<T>(std::marker::PhantomData<T>);
        impl<'de, T: Deserialize<'de> + TableName> de::Visitor<'de> for V<T> {
            type Value = Table<T>;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str(T::WHAT)
            }
            fn visit_map<A: de::MapAccess<'de>>(self, m: A) -> Result<Table<T>, A::Error> {
                T::deserialize(de::value::MapAccessDeserializer::new(m)).map(Table)
            }
        }
        d.deserialize_map(V(std::marker::PhantomData))
    }
}

impl<T> std::ops::Deref for Table<T> {
    type Target = T;
    fn deref(&self) -> &T {
        &self.0
    }
}

impl<T> std::ops::Deref for Tables<T> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        &self.0
    }
}

/// Tables written as an array of tables (`[[keyframe]]`): `[keyframe]` was refused as
/// "invalid type: map, expected a sequence".
struct Tables<T>(Vec<T>);

impl<'de, T: Deserialize<'de> + TableName> Deserialize<'de> for Tables<T> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V<T>(std::marker::PhantomData<T>);
        impl<'de, T: Deserialize<'de> + TableName> de::Visitor<'de> for V<T> {
            type Value = Tables<T>;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str(T::WHAT)
            }
            fn visit_seq<A: de::SeqAccess<'de>>(self, mut seq: A) -> Result<Tables<T>, A::Error> {
                let mut v = Vec::new();
                while let Some(t) = seq.next_element::<Table<T>>()? {
                    v.push(t.0);
                }
                Ok(Tables(v))
            }
        }
        d.deserialize_seq(V(std::marker::PhantomData))
    }
}

/// `[environment]`: a lat-long image or one colour, scaled and turned about +Y.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct EnvironmentFile {
    image: Option<Spanned<String>>,
    /// Read in double precision (as the file's numbers are), so that a refusal names the value
    /// given: `intensity = 1e39` was named as `inf`.
    radiance: Option<Spanned<Exactly<f64, 3>>>,
    intensity: Option<Spanned<f64>>,
    rotation: Option<Spanned<f64>>,
}

impl EnvironmentFile {
    /// The line of the table in `text`, for messages: its header's (`[environment]`), else its
    /// first key's (dotted keys, an inline table), else the line that names it
    /// (`environment = {}`).
    fn line(&self, text: &str) -> usize {
        let header = text.lines().position(|l| {
            let l = l.split('#').next().unwrap_or("").replace([' ', '\t'], "");
            l == "[environment]"
        });
        if let Some(i) = header {
            return i + 1;
        }
        let spans = [
            self.image.as_ref().map(Spanned::span),
            self.radiance.as_ref().map(Spanned::span),
            self.intensity.as_ref().map(Spanned::span),
            self.rotation.as_ref().map(Spanned::span),
        ];
        match spans.into_iter().flatten().map(|s| s.start).min() {
            Some(at) => line_at(text.as_bytes(), at),
            None => text
                .lines()
                .position(|l| {
                    let l = l.trim_start().trim_start_matches('[').trim_start();
                    l.strip_prefix("environment")
                        .is_some_and(|r| r.trim_start().starts_with([']', '=', '.']))
                })
                .map_or(1, |i| i + 1),
        }
    }
}

/// An array of exactly `N` values: serde's `[T; N]` takes the first `N` of a longer TOML array
/// and ignores the rest, so `resolution = [16, 12, 3]` would load as 16x12.
struct Exactly<T, const N: usize>([T; N]);

impl<'de, T: Deserialize<'de>, const N: usize> Deserialize<'de> for Exactly<T, N> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V<T, const N: usize>(std::marker::PhantomData<T>);
        impl<'de, T: Deserialize<'de>, const N: usize> de::Visitor<'de> for V<T, N> {
            type Value = Exactly<T, N>;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                write!(f, "an array of length {N}")
            }
            fn visit_seq<A: de::SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
                let mut v = Vec::with_capacity(N);
                while let Some(x) = seq.next_element::<T>()? {
                    if v.len() == N {
                        // Count the rest without keeping it, for the message.
                        let mut n = N + 1;
                        while seq.next_element::<de::IgnoredAny>()?.is_some() {
                            n += 1;
                        }
                        return Err(de::Error::invalid_length(n, &self));
                    }
                    v.push(x);
                }
                let n = v.len();
                v.try_into()
                    .map(Exactly)
                    .map_err(|_| de::Error::invalid_length(n, &self))
            }
        }
        d.deserialize_seq(V::<T, N>(std::marker::PhantomData))
    }
}

/// A keyframe's frame: a whole number from 0, written as an integer or as a float (`frame =
/// 12.0`, as a script that computes its frames writes them), as a camera file's frame may be.
struct FrameNumber(u32);

impl<'de> Deserialize<'de> for FrameNumber {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        whole(d, "a frame number (a whole number, 0 or more)").map(FrameNumber)
    }
}

/// A count or size (`frames`, `resolution`): a whole number from 0 to 2^32 - 1, written as an
/// integer or as a float whose value is whole (`frames = 48.0`, as a script that computes it
/// writes it; it was refused as "invalid type: floating point `48.0`, expected u32", though a
/// keyframe's `frame = 12.0` was read).
#[derive(Clone, Copy)]
struct Whole(u32);

impl<'de> Deserialize<'de> for Whole {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        whole(d, "a positive whole number").map(Whole)
    }
}

/// A whole number from 0 to 2^32 - 1, as an integer or a float whose value is whole; `what`:
/// what a refusal says was expected.
fn whole<'de, D: Deserializer<'de>>(d: D, what: &'static str) -> Result<u32, D::Error> {
    struct V(&'static str);
    impl de::Visitor<'_> for V {
        type Value = u32;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str(self.0)
        }
        // Past the range of any count or frame: said so (it read "from 0 to 4294967295",
        // where frames and frame numbers stop at `MAX_FRAMES` and a film at `MAX_PIXELS`,
        // which the checks after reading say).
        fn visit_i64<E: de::Error>(self, v: i64) -> Result<u32, E> {
            if v > u32::MAX as i64 {
                return Err(E::custom(format!("{v} is too large")));
            }
            u32::try_from(v).map_err(|_| E::invalid_value(de::Unexpected::Signed(v), &self))
        }
        fn visit_u64<E: de::Error>(self, v: u64) -> Result<u32, E> {
            u32::try_from(v).map_err(|_| E::custom(format!("{v} is too large")))
        }
        fn visit_f64<E: de::Error>(self, v: f64) -> Result<u32, E> {
            if v.fract() == 0.0 && (0.0..=u32::MAX as f64).contains(&v) {
                Ok(v as u32)
            } else if v.fract() == 0.0 && v > u32::MAX as f64 {
                Err(E::custom(format!("{v} is too large")))
            } else {
                Err(E::invalid_value(de::Unexpected::Float(v), &self))
            }
        }
    }
    d.deserialize_any(V(what))
}

/// Every value keeps its place in the file, so that an error can name its line.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct KeyframeFile {
    frame: Spanned<FrameNumber>,
    /// Read in double precision for a scene moved to its origin (`check_camera`); checked and
    /// used as f32 otherwise.
    position: Spanned<Exactly<f64, 3>>,
    look_at: Spanned<Exactly<f64, 3>>,
    up: Spanned<Exactly<f32, 3>>,
    /// Read in double precision so that a refusal names the value given (`text::fov_fault`).
    fov: Spanned<f64>,
}

/// The geometry at a hit, built from Embree's minimal hit only when it is shaded.
#[derive(Clone, Copy, Debug, Default)]
pub struct SurfacePoint {
    pub p: Vec3,
    /// Unit geometric normal, as wound (front side = emitting side).
    pub ng: Vec3,
    /// Unit shading normal (interpolated vertex normals, or `ng`), on the same side as `ng`.
    pub ns: Vec3,
    pub prim: u32,
    pub material: u32,
    /// Texture coordinates (zero where the mesh has none).
    pub uv: Vec2,
}

pub struct Scene {
    pub name: String,
    pub frames: u32,
    pub width: u32,
    pub height: u32,
    /// The camera of every frame: keyframes interpolated, or a camera file's.
    pub cameras: Cameras,
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    /// Texture coordinates per vertex; empty when the OBJ has none.
    pub uvs: Vec<Vec2>,
    pub triangles: Vec<[u32; 3]>,
    pub tri_material: Vec<u32>,
    pub tri_normal: Vec<Vec3>,
    pub tri_area: Vec<f32>,
    /// Each material as the MTL gives it; `Scene::material` applies its texture maps.
    pub materials: Vec<Material>,
    /// The texture maps of each material (`map_Kd`, `map_Ks`, `map_Ke`); empty when none has one.
    maps: Vec<Maps>,
    /// The textures the maps look up, if any material has one (shared with the geometry's
    /// cut-outs, `scene::cutout`).
    pub textures: Option<Arc<Textures>>,
    /// Meshes placed more than once, by Embree instances (`instances`), in object space.
    pub prototypes: Vec<Prototype>,
    pub instances: Vec<Instance>,
    pub material_names: Vec<String>,
    pub lights: Lights,
    /// The environment light, if the scene has one (`[environment]`).
    pub environment: Option<Environment>,
    /// Probability that light sampling picks the environment rather than an area light: 1/2
    /// when both emit, 1 or 0 when only one does.
    env_select: f32,
    pub geometry: TriangleScene,
    /// The least offset of a ray's origin off its surface, in units of `SPAWN_EPS`
    /// (`embree::offset_origin`): 1, or the size of the scene's geometry (the largest side of
    /// its bounding box) where that is smaller, so that a scene modelled tiny keeps its contact
    /// shadows.
    pub offset_floor: f32,
    /// The point of the scene file's space that is the render's origin: zero, or the centre of
    /// the geometry's bounding box where that lies far from the origin (`render_origin`). Every
    /// position the render uses (vertices, placements, the cameras' eyes) has it subtracted;
    /// what a render writes out (the frames' camera matrices) is in the file's coordinates.
    pub origin: DVec3,
    /// What loading found odd but not wrong (e.g. faces without a material). The command line
    /// prints them once the command has succeeded, so that a failure stays one line.
    pub warnings: Vec<String>,
    /// The files the scene was read from (TOML, camera file, OBJ, MTLs; none for a shipped
    /// scene): a command never writes over them.
    pub inputs: Vec<PathBuf>,
}

/// Where a scene's files come from: the file system or the binary.
enum Source {
    Files { toml: PathBuf },
    Builtin(usize),
}

impl Scene {
    /// Bytes the texture cache will hold while rendering (0 without textures): memory the
    /// render's frames cannot have (`RenderOptions::check_memory`).
    pub fn texture_cache_bytes(&self) -> u64 {
        self.textures.as_ref().map_or(0, |t| t.cache_use_bytes())
    }

    /// Load a scene by file path, or by the name of a shipped scene (`vase`, `cornell`,
    /// `furnace`) when no such file exists; repairs are warnings (`LoadOptions::default()`).
    pub fn load(name_or_path: &str, device: &Device) -> Result<Scene> {
        Scene::load_with(name_or_path, device, &LoadOptions::default())
    }

    /// `load`, with options (`strict`: refuse what would be repaired).
    pub fn load_with(name_or_path: &str, device: &Device, opts: &LoadOptions) -> Result<Scene> {
        let _listings = Listings::hold();
        let p = Path::new(name_or_path);
        // Anything at the path (a FIFO, a dangling link) is the user's file, for `read_input`
        // to refuse with its reason; a shipped scene's name is the fallback, also over a
        // folder of that name (an output folder called `vase`, say).
        let builtin = BUILTIN.iter().position(|b| b.0 == name_or_path);
        let exists = std::fs::symlink_metadata(p).is_ok() && !(builtin.is_some() && p.is_dir());
        let source = if exists {
            Source::Files {
                toml: p.to_path_buf(),
            }
        } else if let Some(i) = builtin {
            Source::Builtin(i)
        } else {
            bail!(
                "scene '{name_or_path}': no such file{}, and not a shipped scene ({})",
                crate::util::input::other_case(p),
                builtin_names().join(", ")
            );
        };
        // A file here with a shipped scene's name (`cornell`, no extension) is the one read:
        // said in every message about it, and in a note, since the name alone reads as the
        // shipped scene's.
        let shadowed = matches!(source, Source::Files { .. }) && builtin.is_some();
        let shadow_note = shadowed.then(|| {
            format!(
                "'{name_or_path}' is the file {} here, not the shipped scene {name_or_path}: \
                 rename the file to use the shipped scene from this folder",
                p.display()
            )
        });
        let mut repairs = Repairs::new(opts.strict);
        let (label, toml_bytes) = match &source {
            Source::Files { toml } => (
                if shadowed {
                    format!("{} (a file here, not the shipped scene)", toml.display())
                } else {
                    toml.display().to_string()
                },
                text::from_wide(read_input(toml, "scene file", MAX_INPUT_BYTES)?),
            ),
            Source::Builtin(i) => (
                format!("{} (built in)", BUILTIN[*i].0),
                BUILTIN[*i].1.as_bytes().to_vec(),
            ),
        };
        let toml_text = as_text(&toml_bytes).map_err(|e| anyhow!("{label}: {e}"))?;
        let file = parse_scene_file(&label, toml_text)?;
        let name = match &source {
            Source::Files { toml } => toml
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default(),
            Source::Builtin(i) => BUILTIN[*i].0.to_string(),
        };
        let dir = match &source {
            Source::Files { toml } => Some(toml.parent().unwrap_or(Path::new(".")).to_path_buf()),
            Source::Builtin(_) => None,
        };
        let camera_path = |name: &str| dir.as_ref().map(|d| scene_named(d, name));
        // The poses of a camera file, its eyes given from `origin` (`Scene::origin`).
        let read_camera = |name: &Spanned<String>,
                           frames: u32,
                           origin: DVec3,
                           repairs: &mut Repairs|
         -> Result<Vec<Pose>> {
            let at = format!(
                "{label}: line {}: camera '{}'",
                line_at(toml_text.as_bytes(), name.span().start),
                quote_name(name.get_ref())
            );
            let Some(format) = camera_file::Format::of(name.get_ref()) else {
                bail!("{at}: a camera file's name ends in .json or .csv");
            };
            let Some(path) = camera_path(name.get_ref()) else {
                bail!("{at}: a shipped scene has no camera file");
            };
            let bytes = read_input(&path, "camera file", MAX_INPUT_BYTES)
                .map(text::from_wide)
                .map_err(|e| anyhow!("{at}: {e}"))?;
            let label = path.display().to_string();
            camera_file::parse_from(&label, &bytes, format, frames, repairs, origin)
        };
        // Kept, not yet returned: a scene far out is checked again from its origin, where f32
        // can tell its cameras' points apart (a look-at 10 units from its position 10^9 units
        // out is the same f32 point, refused as 'coincides').
        let first_cameras = check_camera(
            &label,
            toml_text,
            &file,
            |n, frames| read_camera(n, frames, DVec3::ZERO, &mut repairs),
            DVec3::ZERO,
        );
        if let (Ok(_), Some(keys)) = (&first_cameras, &file.keyframe) {
            let fovs = keys.iter().map(|k| *k.fov.get_ref());
            if let Some(largest) = camera_file::fovs_look_like_radians(fovs) {
                let line = line_at(toml_text.as_bytes(), keys[0].fov.span().start);
                repairs.note(&label, line, camera_file::FOV_RADIANS, || {
                    format!("the largest of its keyframes' fovs is {largest}")
                })?;
            }
        }
        let (environment, env_input) = match &file.environment {
            None => (None, None),
            Some(e) => {
                let (env, input) =
                    load_environment(&label, toml_text, e, dir.as_deref(), &mut repairs)?;
                (Some(env), input)
            }
        };
        let mut textures = None;
        let loaded = match (&file.obj, &file.object) {
            (Some(obj), None) => {
                let obj_at = format!(
                    "{label}: line {}: obj '{}'",
                    line_at(toml_text.as_bytes(), obj.span().start),
                    quote_name(obj.get_ref())
                );
                let (obj_label, obj_bytes, files) = match &source {
                    Source::Files { toml } => {
                        let dir = toml.parent().unwrap_or(Path::new(".")).to_path_buf();
                        let obj = scene_named(&dir, obj.get_ref());
                        refuse_scene_as_obj(&obj, toml, &obj_at)?;
                        let bytes = read_input(&obj, "OBJ", MAX_INPUT_BYTES)
                            .map(text::from_wide)
                            .map_err(|e| anyhow!("{obj_at}: {e}"))?;
                        let mtl_dir = obj.parent().unwrap_or(&dir).to_path_buf();
                        (obj.display().to_string(), bytes, MtlSource::Dir(mtl_dir))
                    }
                    Source::Builtin(i) => (
                        format!("{} (built in)", obj.get_ref()),
                        BUILTIN[*i].2.as_bytes().to_vec(),
                        MtlSource::Builtin(BUILTIN[*i].3),
                    ),
                };
                let (mesh, mtls, anchor) =
                    load_obj_files(&obj_label, &obj_bytes, &files, &mut textures, &mut repairs)?;
                let objs = match &source {
                    Source::Files { toml } => {
                        vec![toml.parent().unwrap_or(Path::new(".")).join(obj.get_ref())]
                    }
                    Source::Builtin(_) => Vec::new(),
                };
                Objects {
                    parts: vec![(0, obj_label.clone())],
                    label: obj_label,
                    mesh,
                    prototypes: Vec::new(),
                    instances: Vec::new(),
                    inputs: objs.into_iter().chain(mtls).collect(),
                    // Its positions are given from its anchor: that is the scene's origin.
                    origin: anchor,
                    notes: Vec::new(),
                }
            }
            (None, Some(list)) if !list.is_empty() => {
                let Some(dir) = &dir else {
                    bail!("{label}: a shipped scene has no [[object]] files");
                };
                load_objects(&label, toml_text, dir, list, &mut textures, &mut repairs)?
            }
            (Some(obj), Some(_)) => {
                let line = line_at(toml_text.as_bytes(), obj.span().start);
                bail!("{label}: line {line}: give either obj or [[object]] tables, not both")
            }
            (None, _) => bail!("{label}: no obj and no [[object]]: the scene has no geometry"),
        };
        // A scene far from the origin was moved near it as it loaded (rays leave surfaces by an
        // offset that grows with the coordinates); its cameras follow.
        let Objects {
            label: obj_label,
            mut mesh,
            prototypes,
            instances,
            inputs: object_inputs,
            origin,
            notes: object_notes,
            parts,
        } = loaded;
        // Every light is in the scene's own mesh, placed: each emits to its normals' side.
        let turned = mesh::orient_emitters(&mut mesh);
        // How many were turned over in each object (copies of one counted together).
        let mut turned_in: Vec<(&str, usize)> = Vec::new();
        for (k, (start, name)) in parts.iter().enumerate() {
            let end = parts.get(k + 1).map_or(mesh.triangles.len(), |p| p.0);
            let n = turned.partition_point(|&t| t < end) - turned.partition_point(|&t| t < *start);
            match turned_in.iter_mut().find(|(o, _)| *o == name) {
                Some((_, count)) => *count += n,
                None => turned_in.push((name, n)),
            }
        }
        let (width, height, cameras) = if origin == DVec3::ZERO {
            first_cameras?
        } else {
            // The cameras again, given from the origin in f64 (no warning twice where the first
            // reading noted them).
            let mut again = Repairs::new(false);
            let notes = if first_cameras.is_ok() {
                &mut again
            } else {
                &mut repairs
            };
            check_camera(
                &label,
                toml_text,
                &file,
                |n, frames| read_camera(n, frames, origin, notes),
                origin,
            )?
        };
        let (lo, hi) = world_bounds(&mesh.positions, &prototypes, &instances);
        let inputs = match &source {
            Source::Files { toml } => [toml.clone()]
                .into_iter()
                .chain(file.camera.as_ref().and_then(|c| camera_path(c.get_ref())))
                .chain(object_inputs)
                .chain(env_input)
                .collect(),
            Source::Builtin(_) => Vec::new(),
        };
        let proto_meshes: Vec<MeshRef> = prototypes
            .iter()
            .map(|p| (p.positions.as_slice(), p.triangles.as_slice()))
            .collect();
        let placements: Vec<Placement> = instances.iter().map(|i| (i.proto, i.rows())).collect();
        let own = (!mesh.triangles.is_empty())
            .then_some((mesh.positions.as_slice(), mesh.triangles.as_slice()));
        let cache_note = textures
            .as_mut()
            .and_then(|t| t.size_cache(crate::util::mem::available_bytes()));
        let textures = textures.map(Arc::new);
        let cut = |tris: &[[u32; 3]], uvs: &[Vec2], tri_material: &[u32]| {
            MeshCutout::new(textures.as_ref(), &mesh.maps, tris, uvs, tri_material)
                .map(|c| Arc::new(c) as Arc<dyn Cutout>)
        };
        let cutouts = Cutouts {
            own: cut(&mesh.triangles, &mesh.uvs, &mesh.tri_material),
            prototypes: prototypes
                .iter()
                .map(|p| cut(&p.triangles, &p.uvs, &p.tri_material))
                .collect(),
        };
        let geometry = TriangleScene::build(device, own, &proto_meshes, &placements, cutouts)
            .with_context(|| format!("{obj_label}: building the Embree scene"))?;
        // A light's area is summed and sampled in f32: past its range (an emitter 1e19 wide, or
        // placed at a scale that takes it there) its density is zero, and it lit nothing.
        let huge = (0..mesh.triangles.len())
            .filter(|&t| {
                !mesh.tri_area[t].is_finite()
                    && mesh.materials[mesh.tri_material[t] as usize].is_emissive()
            })
            .count();
        if huge > 0 {
            bail!(
                "{obj_label}: {huge} emitting triangle(s) (its own or its [[object]]s') have an \
                 area past the range of single-precision numbers (3.4e38), which no light can \
                 be sampled on: model the scene in larger units (or place the object at a \
                 smaller scale)"
            );
        }
        let lights = Lights::new(&obj_label, &mesh, textures.as_deref())?;
        let env_emits = environment.as_ref().is_some_and(Environment::emits);
        if lights.tris.is_empty() && !env_emits {
            // A light lost with its material is the likely cause: say so on the same line.
            let degenerate = repairs.first_of(&[mesh::DEGENERATE_LIGHT]);
            let lost = degenerate
                .as_ref()
                .map(|w| format!(" ({w})"))
                .or_else(|| {
                    repairs
                        .first_of(&[MTL_MISSING, NO_MTLLIB, UNKNOWN_MATERIAL, NO_USEMTL])
                        .map(|w| format!(" (materials fell back to the default: {w})"))
                })
                .or_else(|| {
                    // A misspelt `usemtl` (its faces kept the material before it), or `Ke`.
                    repairs
                        .first_of(&[obj::UNKNOWN, mtl::UNKNOWN])
                        .map(|w| format!(" (a line was ignored: {w})"))
                })
                .or_else(|| {
                    // An emission map beside `Ke 0`, which it is multiplied by.
                    repairs
                        .first_of(&[mtl::KE_ZERO_MAP])
                        .map(|w| format!(" ({w})"))
                })
                .unwrap_or_default();
            let env = if environment.is_some() {
                "its [environment] is black"
            } else {
                "it has no [environment]"
            };
            let none = if lights.black_maps > 0 {
                "the emission maps (map_Ke) of its emitting materials are black in every texel"
            } else if degenerate.is_some() {
                "every triangle of its emitting materials has zero area, or an area below single \
                 precision's range"
            } else {
                "no material has a positive Ke"
            };
            // A black [environment] is the scene file's: named there, the OBJ beside it.
            if environment.is_some() && obj_label != label {
                bail!("{label}: the scene has no light: {none} in {obj_label}, and {env}{lost}");
            }
            bail!("{obj_label}: the scene has no light: {none}, and {env}{lost}");
        }
        let env_select = match (env_emits, lights.tris.is_empty()) {
            (false, _) => 0.0,
            (true, true) => 1.0,
            (true, false) => 0.5,
        };
        let offset_floor = offset_floor(lo, hi);
        let mut warnings = repairs.into_warnings();
        warnings.extend(shadow_note);
        warnings.extend(object_notes);
        warnings.extend(cache_note);
        warnings.extend(coplanar::warnings(
            &obj_label,
            &mesh,
            &prototypes,
            &instances,
        ));
        for (object, n) in turned_in.into_iter().filter(|&(_, n)| n > 0) {
            warnings.push(format!(
                "{object}: {n} emitting triangle(s) wound against their vertex normals \
                 emit to the side the normals point to, as pbrt-v4 and Mitsuba 3 take them"
            ));
        }
        if lights.black_maps > 0 && !lights.tris.is_empty() {
            warnings.push(format!(
                "{obj_label}: {} triangle(s) of materials with a positive Ke have an emission \
                 map (map_Ke) black in every texel: they emit nothing",
                lights.black_maps
            ));
        }
        warnings.extend(spread_warning(
            &obj_label,
            lo,
            hi,
            offset_floor,
            &mesh.tri_area,
        ));
        let mut scene = Scene {
            inputs,
            warnings,
            name,
            frames: file.frames.get_ref().0,
            width,
            height,
            cameras,
            positions: mesh.positions,
            normals: mesh.normals,
            uvs: mesh.uvs,
            triangles: mesh.triangles,
            tri_material: mesh.tri_material,
            tri_normal: mesh.tri_normal,
            tri_area: mesh.tri_area,
            materials: mesh.materials,
            maps: mesh.maps,
            textures,
            prototypes,
            instances,
            material_names: mesh.material_names,
            lights,
            environment,
            env_select,
            geometry,
            offset_floor,
            origin,
        };
        scene
            .warnings
            .extend(precision::near_huge_triangles(&scene, &obj_label));
        // Lights so dim that the render's arithmetic loses them: every frame black, no word.
        let (brightest, emitters) = (scene.brightest_emission(), scene.brightest_emitter());
        if brightest > 0.0 && brightest < MIN_LIGHT {
            // Named where that light is written: the environment in the scene file, an
            // emitting material in its OBJ.
            let whose = match &file.environment {
                Some(e) if brightest > emitters => {
                    format!("{label}: line {}: [environment]", e.line(toml_text))
                }
                _ => obj_label,
            };
            bail!(
                "{whose}: the scene's brightest light emits {brightest:e}, below {MIN_LIGHT:e}: \
                 a path's products of it fall below single precision's smallest normal number \
                 (1.2e-38, under which the ray tracer's threads flush values to zero), and every \
                 frame would be black; scale the lights (Ke, the environment's intensity) up"
            );
        }
        Ok(scene)
    }

    /// The largest radiance any light of the scene emits in a channel: an emitting material's
    /// `Ke` times the largest texel of its emission map (at most `MAX_KE`, as a lookup is
    /// capped), and the environment's brightest texel. 0 for a scene that emits nothing.
    pub fn brightest_emission(&self) -> f32 {
        let env = self
            .environment
            .as_ref()
            .map_or(0.0, Environment::brightest);
        env.max(self.brightest_emitter())
    }

    /// `brightest_emission` of the emitting materials alone (0 where none emits).
    fn brightest_emitter(&self) -> f32 {
        let materials = self
            .lights
            .tris
            .iter()
            .map(|&t| self.tri_material[t as usize] as usize);
        let mut brightest = 0.0f32;
        for m in materials {
            let ke = self.materials[m].ke.max_element();
            let map = self.maps.get(m).and_then(|maps| maps.ke.as_ref());
            let texel = match (map, &self.textures) {
                (Some(map), Some(t)) => t.max_rgb(map.tex).into_iter().fold(0.0, f32::max),
                _ => 1.0,
            };
            brightest = brightest.max((ke * texel).min(MAX_KE));
        }
        brightest
    }

    /// The camera of frame `frame`, at `width` x `height`: its eye where the render has it
    /// (`cameras` are given from `origin`), its matrices in the scene file's coordinates.
    pub fn camera(&self, frame: u32, width: u32, height: u32) -> Camera {
        let mut cam = Camera::from_pose(&self.cameras.pose(frame), width, height);
        if self.origin != DVec3::ZERO {
            cam.world_eye = (cam.eye.as_dvec3() + self.origin).as_vec3();
        }
        cam
    }

    /// Shading data for Embree's hit.
    #[inline]
    pub fn surface(&self, hit: &Hit) -> SurfacePoint {
        if hit.inst != Hit::NO_INSTANCE {
            return self.instance_surface(hit);
        }
        let prim = hit.prim_id;
        let [i0, i1, i2] = self.triangles[prim as usize];
        let (b1, b2) = (hit.u, hit.v);
        let b0 = 1.0 - b1 - b2;
        let p = self.positions[i0 as usize] * b0
            + self.positions[i1 as usize] * b1
            + self.positions[i2 as usize] * b2;
        let ng = self.tri_normal[prim as usize];
        let ns = if self.normals.is_empty() {
            ng
        } else {
            let n = self.normals[i0 as usize] * b0
                + self.normals[i1 as usize] * b1
                + self.normals[i2 as usize] * b2;
            let n = n.normalize_or_zero();
            if n == Vec3::ZERO {
                ng
            } else if n.dot(ng) < 0.0 {
                -n
            } else {
                n
            }
        };
        let uv = if self.uvs.is_empty() {
            Vec2::ZERO
        } else {
            self.uvs[i0 as usize] * b0 + self.uvs[i1 as usize] * b1 + self.uvs[i2 as usize] * b2
        };
        SurfacePoint {
            p,
            ng,
            ns,
            prim,
            material: self.tri_material[prim as usize],
            uv,
        }
    }

    /// `surface` for a hit on an instance: the prototype's point, normals through the
    /// instance's transforms. Instances never emit (emitting objects are copied), so the point
    /// has no light triangle (`prim` is `u32::MAX`).
    fn instance_surface(&self, hit: &Hit) -> SurfacePoint {
        let inst = &self.instances[hit.inst as usize];
        let proto = &self.prototypes[inst.proto as usize];
        let prim = hit.prim_id as usize;
        let [i0, i1, i2] = proto.triangles[prim].map(|i| i as usize);
        let (b1, b2) = (hit.u, hit.v);
        let b0 = 1.0 - b1 - b2;
        let p_obj = proto.positions[i0] * b0 + proto.positions[i1] * b1 + proto.positions[i2] * b2;
        let p = inst.to_world.transform_point3(p_obj);
        let ng = (inst.normal * proto.tri_normal[prim]).normalize();
        let ns = if proto.normals.is_empty() {
            ng
        } else {
            // Each corner's normal into world space and made unit before they are interpolated,
            // as a placed copy's are (`objects::transformed`): under a non-uniform scale the
            // transformed normals differ in length, and interpolating them in object space
            // weighted the corners otherwise (a glossy ellipsoid's highlight moved; 0.9% against
            // Mitsuba 3 and its own flattened copy).
            let world = |i: usize| (inst.normal * proto.normals[i]).normalize_or_zero();
            let n = world(i0) * b0 + world(i1) * b1 + world(i2) * b2;
            let n = n.normalize_or_zero();
            if n == Vec3::ZERO {
                ng
            } else if n.dot(ng) < 0.0 {
                -n
            } else {
                n
            }
        };
        let uv = if proto.uvs.is_empty() {
            Vec2::ZERO
        } else {
            proto.uvs[i0] * b0 + proto.uvs[i1] * b1 + proto.uvs[i2] * b2
        };
        SurfacePoint {
            p,
            ng,
            ns,
            prim: u32::MAX,
            material: proto.tri_material[prim],
            uv,
        }
    }

    /// The material at `sp`, its texture maps looked up there. Look it up once per point: a
    /// textured material costs a texture lookup per map.
    #[inline]
    pub fn material(&self, sp: &SurfacePoint) -> Material {
        let m = &self.materials[sp.material as usize];
        match (self.maps.get(sp.material as usize), &self.textures) {
            (Some(maps), Some(t)) if !maps.is_empty() => maps.apply(m, t, sp.uv),
            _ => *m,
        }
    }

    /// Each material's texture maps (empty when no material has one).
    pub fn texture_maps(&self) -> &[Maps] {
        &self.maps
    }

    /// The emission of material `material` at texture coordinates `uv`.
    #[inline]
    fn ke(&self, material: u32, uv: Vec2) -> Vec3 {
        let ke = self.materials[material as usize].ke;
        match (self.maps.get(material as usize), &self.textures) {
            (Some(maps), Some(t)) if ke != Vec3::ZERO => maps.ke(ke, t, uv),
            _ => ke,
        }
    }

    /// Radiance emitted by the triangle of `sp` towards `toward` (one-sided).
    #[inline]
    pub fn emitted(&self, sp: &SurfacePoint, toward: Vec3) -> Vec3 {
        if self.materials[sp.material as usize].is_emissive() && sp.ng.dot(toward - sp.p) > 0.0 {
            self.ke(sp.material, sp.uv)
        } else {
            Vec3::ZERO
        }
    }

    /// `emitted` for a point whose material `m` (textures applied) is already at hand.
    #[inline]
    pub fn emitted_by(m: &Material, sp: &SurfacePoint, toward: Vec3) -> Vec3 {
        if m.is_emissive() && sp.ng.dot(toward - sp.p) > 0.0 {
            m.ke
        } else {
            Vec3::ZERO
        }
    }

    /// Sample a point on a light (or a direction towards the environment) as seen from `x`: the
    /// environment with probability `env_select`, else an area light (by power, and evenly
    /// between lights: `Lights`).
    ///
    /// One 2D number does both: its first coordinate picks the light and is then stretched back
    /// to [0, 1) over the chosen light's share (`(u.x - F_lo) / p`), so that the points the
    /// picks leave on each light keep the stratification of the sampler's 2D points instead of
    /// being a random subset of them (Mitsuba's and pbrt's sample reuse).
    pub fn sample_light(&self, x: Vec3, u: Vec2) -> Option<LightSample> {
        match self.pick_light(u)? {
            LightPick::Environment(u) => self.environment_sample(x, u),
            LightPick::Area(pick) => {
                let at = area_sample(&self.area_inputs(&pick, x));
                self.finish_area(&pick, &at)
            }
        }
    }

    /// The light that `sample_light` picks with `u`, and the rest of `u` for the point on it.
    #[inline(always)]
    fn pick_light(&self, u: Vec2) -> Option<LightPick> {
        let mut u = u;
        let p_env = self.env_select;
        if p_env > 0.0 {
            if u.x < p_env {
                return Some(LightPick::Environment(Vec2::new(
                    stretch(u.x, 0.0, p_env),
                    u.y,
                )));
            }
            // The rest of [0, 1) picks among the area lights.
            u.x = stretch(u.x, p_env, 1.0 - p_env);
        }
        let l = &self.lights;
        if l.tris.is_empty() {
            return None;
        }
        let i = l.cdf.partition_point(|&c| c <= u.x).min(l.table.len() - 1);
        // The stretch of `u.x` over the light's share of the CDF is `area_sample`'s.
        Some(LightPick::Area(AreaPick { light: i as u32, u }))
    }

    /// A direction towards the environment, picked with the stretched `u`.
    #[inline]
    fn environment_sample(&self, x: Vec3, u: Vec2) -> Option<LightSample> {
        let es = self.environment.as_ref()?.sample(u)?;
        Some(LightSample {
            p: x + es.wi,
            n: -es.wi,
            wi: es.wi,
            dist: f32::INFINITY,
            le: es.le,
            pdf: self.env_select * es.pdf,
        })
    }

    /// What `area_sample` reads for the point `pick` asks for, seen from `x`.
    #[inline(always)]
    fn area_inputs(&self, pick: &AreaPick, x: Vec3) -> AreaInputs {
        let t = &self.lights.table[pick.light as usize];
        AreaInputs {
            u: pick.u,
            lo: t.lo,
            width: t.width,
            corners: t.corners,
            n: t.n,
            pdf_area: t.pdf_area * (1.0 - self.env_select),
            x,
        }
    }

    /// The light sample from `area_sample`'s arithmetic: `None` where the point coincides with
    /// `x` or the light is seen edge-on; no emission from the light's back.
    #[inline(always)]
    fn finish_area(&self, pick: &AreaPick, at: &AreaSample) -> Option<LightSample> {
        if at.dist <= 0.0 || at.cos_l.abs() <= 1e-7 {
            return None;
        }
        let light = &self.lights.table[pick.light as usize];
        let tri = light.tri as usize;
        let le = if at.cos_l > 0.0 {
            let [i0, i1, i2] = self.triangles[tri];
            // A part's barycentrics, in the whole triangle's.
            let (b1, b2) = match light.part_of {
                None => (at.b1, at.b2),
                Some([a, b, c]) => {
                    let w = a * (1.0 - at.b1 - at.b2) + b * at.b1 + c * at.b2;
                    (w.x, w.y)
                }
            };
            let uv = if self.uvs.is_empty() {
                Vec2::ZERO
            } else {
                self.uvs[i0 as usize] * (1.0 - b1 - b2)
                    + self.uvs[i1 as usize] * b1
                    + self.uvs[i2 as usize] * b2
            };
            self.ke(self.tri_material[tri], uv)
        } else {
            Vec3::ZERO
        };
        Some(LightSample {
            p: at.p,
            n: light.n,
            wi: at.wi,
            dist: at.dist,
            le,
            pdf: at.pdf,
        })
    }

    /// Solid-angle density with which `sample_light` from `x` picks the point `y` on triangle
    /// `prim` (0 if that triangle is not a light).
    #[inline]
    pub fn light_pdf(&self, x: Vec3, y: Vec3, prim: u32) -> f32 {
        // A point on an instance (`prim` u32::MAX) is on no light.
        let mut pa = self
            .lights
            .pdf_area
            .get(prim as usize)
            .copied()
            .unwrap_or(0.0);
        if pa == 0.0 {
            return 0.0;
        }
        if pa < 0.0 {
            pa = self.lights.grids[(-pa) as usize - 1].pdf_at(y);
        }
        let d = y - x;
        let dist2 = d.length_squared();
        let cos_l = self.tri_normal[prim as usize].dot(d).abs() / dist2.sqrt();
        if cos_l <= 1e-7 {
            return 0.0;
        }
        pa * (1.0 - self.env_select) * dist2 / cos_l
    }

    /// Radiance arriving from the environment along unit direction `d` (zero without one): what
    /// a ray that leaves the scene sees.
    #[inline]
    pub fn env_radiance(&self, d: Vec3) -> Vec3 {
        self.environment
            .as_ref()
            .map_or(Vec3::ZERO, |e| e.radiance(d))
    }

    /// Solid-angle density with which `sample_light` picks direction `d` towards the
    /// environment (0 without one).
    #[inline]
    pub fn env_pdf(&self, d: Vec3) -> f32 {
        match &self.environment {
            Some(e) if self.env_select > 0.0 => self.env_select * e.pdf(d),
            _ => 0.0,
        }
    }
}

/// Refused: an OBJ name that is the scene file itself (`obj = "s.toml"`), which was read as an
/// OBJ of no faces ("s.toml: no faces"). `at`: the key, for the message.
fn refuse_scene_as_obj(obj: &Path, scene: &Path, at: &str) -> Result<()> {
    let same = match (std::fs::canonicalize(obj), std::fs::canonicalize(scene)) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    };
    if same {
        bail!("{at}: that is this scene file; obj names the OBJ model to render (obj = \"model.obj\")");
    }
    Ok(())
}

/// Every required key missing from the table a "missing key" error is about (serde names the
/// first alone, so a new scene file was refused once per key it lacked): the top level
/// (`span_start` 0) or the `[[keyframe]]` table whose header starts at `span_start`, and then
/// the top level's too. `None` where there is no more to say than serde's message.
fn missing_keys(text: &str, span_start: usize) -> Option<String> {
    let doc: toml::Table = text.parse().ok()?;
    let lacks = |table: &toml::Table, required: &[&str]| -> Vec<String> {
        required
            .iter()
            .filter(|k| !table.contains_key(**k))
            .map(|k| format!("'{k}'"))
            .collect()
    };
    let list = |keys: &[String]| match keys {
        [one] => one.clone(),
        [rest @ .., last] => format!("{} and {last}", rest.join(", ")),
        [] => String::new(),
    };
    let top = lacks(&doc, &["frames", "resolution"]);
    if span_start == 0 {
        return (top.len() > 1).then(|| format!("missing keys {}", list(&top)));
    }
    // The keyframe tables in order; which one is the header's at `span_start`.
    let header =
        |l: &str| l.split('#').next().unwrap_or("").replace([' ', '\t'], "") == "[[keyframe]]";
    let k = text
        .get(..span_start)?
        .lines()
        .filter(|l| header(l))
        .count();
    let table = doc.get("keyframe")?.as_array()?.get(k)?.as_table()?;
    let own = lacks(table, &["frame", "position", "look_at", "up", "fov"]);
    let what = if own.len() > 1 { "keys" } else { "key" };
    match (own.is_empty(), top.is_empty()) {
        (true, _) => None,
        (false, true) if own.len() == 1 => None,
        (false, true) => Some(format!("missing keys {}", list(&own))),
        (false, false) => Some(format!(
            "missing {what} {} (and at the top level {})",
            list(&own),
            list(&top)
        )),
    }
}

/// The scene TOML, with errors on one line that name the line and quote it.
fn parse_scene_file(label: &str, text: &str) -> Result<SceneFile> {
    if text.trim().is_empty() {
        bail!("{label}: the file is empty");
    }
    // Lines that end in a bare CR throughout (a classic Mac editor's, as the OBJ, MTL and camera
    // readers take them): read as lines, where TOML saw one line of the whole file and refused
    // it, quoting it all.
    let unix;
    let text = if text::bare_cr_lines(text.as_bytes()) {
        unix = text.replace('\r', "\n");
        unix.as_str()
    } else {
        text
    };
    toml::from_str(text).map_err(|e| {
        // An OBJ or MTL given as the scene (a first try with a model): said so, not a TOML
        // syntax error on its first statement.
        let first = text
            .trim_start_matches('\u{feff}')
            .lines()
            .map(str::trim)
            .find(|l| !l.is_empty() && !l.starts_with('#'))
            .unwrap_or("");
        let word = first.split_whitespace().next().unwrap_or("");
        if matches!(
            word,
            "v" | "vt" | "vn" | "f" | "o" | "g" | "mtllib" | "usemtl"
        ) {
            return anyhow!(
                "{label}: this is an OBJ file, not a scene: a scene is a TOML file that names it \
                 (obj = \"{}\"), with its frames, resolution and camera (see the README's Scenes)",
                Path::new(label)
                    .file_name()
                    .map_or("model.obj".into(), |n| n.to_string_lossy())
            );
        }
        if matches!(word, "newmtl") {
            return anyhow!(
                "{label}: this is an MTL file (materials), not a scene: a scene is a TOML file \
                 that names an OBJ (obj = \"model.obj\"), whose mtllib names this file"
            );
        }
        // toml's own message spans several lines (a snippet of the file); keep it to one.
        let mut msg = short_floats(&e.message().trim().replace('\n', " "));
        msg = plain_types(&msg, "a table");
        let Some(span) = e.span() else {
            return anyhow!("{label}: {msg}");
        };
        // serde reads a TOML date or time as a map (its private form of one), which
        // `plain_types` called a table: say what it is.
        let value = text.get(span.clone()).unwrap_or("").trim();
        if value.parse::<toml::value::Datetime>().is_ok() {
            msg = msg.replacen(
                "invalid type: a table",
                &format!("invalid type: a date or time ({value})"),
                1,
            );
        }
        let line = line_at(text.as_bytes(), span.start);
        let quoted = quote(text.lines().nth(line - 1).unwrap_or(""));
        // toml gives no words for a file that ends where a value should be (`frames =` as
        // its last line): the error ended in a colon.
        if msg.is_empty() {
            msg = if quoted.ends_with('=') {
                "the value after '=' is missing".into()
            } else {
                "not TOML here (the file may be cut short)".into()
            };
        }
        // Every key the table lacks, not the first alone.
        if msg.starts_with("missing key") {
            if let Some(all) = missing_keys(text, span.start) {
                msg = all;
            }
        }
        // A key missing from the top level is reported against the whole top-level table.
        if span.start == 0 && !quoted.starts_with('[') && msg.starts_with("missing key") {
            anyhow!("{label}: {msg} at the top level")
        } else if quoted.is_empty() {
            anyhow!("{label}: line {line}: {msg}")
        } else {
            anyhow!("{label}: line {line} ('{quoted}'): {msg}")
        }
    })
}

/// `msg` with every float that serde quotes (`` floating point `x` ``) in exponent form where its
/// decimal form is long: `frame = 1e-320` was refused with a number of 330 digits.
fn short_floats(msg: &str) -> String {
    const QUOTE: &str = "floating point `";
    let mut out = String::with_capacity(msg.len());
    let mut rest = msg;
    while let Some(at) = rest.find(QUOTE) {
        let (head, tail) = rest.split_at(at + QUOTE.len());
        out.push_str(head);
        let end = tail.find('`').unwrap_or(tail.len());
        let (number, after) = tail.split_at(end);
        match number.parse::<f64>() {
            Ok(v) if number.len() > 24 => out.push_str(&format!("{v:e}")),
            _ => out.push_str(number),
        }
        rest = after;
    }
    out.push_str(rest);
    out
}

/// Check the resolution, the frames and the cameras of every frame: the keyframes, interpolated
/// as the scene says, or the camera file `camera` names (read by `read_camera`).
fn check_camera(
    label: &str,
    text: &str,
    f: &SceneFile,
    read_camera: impl FnOnce(&Spanned<String>, u32) -> Result<Vec<Pose>>,
    origin: DVec3,
) -> Result<(u32, u32, Cameras)> {
    let lines = Lines::new(text.as_bytes());
    let line = |span: Range<usize>| lines.at(span.start);
    let [Whole(w), Whole(h)] = f.resolution.get_ref().0;
    let at = format!("{label}: line {}: resolution", line(f.resolution.span()));
    if w == 0 || h == 0 {
        bail!("{at} {w}x{h}: width and height must be positive");
    }
    if w as u64 * h as u64 > MAX_PIXELS {
        bail!("{at} {w}x{h}: more than {MAX_PIXELS} pixels");
    }
    let frames = f.frames.get_ref().0;
    let at = format!("{label}: line {}: frames = {frames}", line(f.frames.span()));
    if frames == 0 {
        bail!("{at}: a scene needs at least one frame");
    }
    if frames > MAX_FRAMES {
        bail!("{at}: at most {MAX_FRAMES}");
    }
    let keyframes = match (&f.camera, &f.keyframe) {
        (Some(c), Some(_)) => bail!(
            "{label}: line {}: camera = '{}' and [[keyframe]] tables: give one or the other",
            line(c.span()),
            quote_name(c.get_ref())
        ),
        (Some(c), None) => {
            if let Some(i) = &f.interpolation {
                bail!(
                    "{label}: line {}: interpolation with a camera file: a camera file gives \
                     every frame, there is nothing to interpolate",
                    line(i.span())
                );
            }
            let poses = read_camera(c, frames)?;
            return Ok((w, h, Cameras::PerFrame(poses)));
        }
        (None, None) => bail!(
            "{label}: no camera: give [[keyframe]] tables or camera = \"file.json\" (or .csv)"
        ),
        (None, Some(k)) => k,
    };
    if keyframes.is_empty() {
        bail!("{label}: no [[keyframe]]: the camera path needs at least one");
    }
    let mut keys = Vec::new();
    let mut key_line = Vec::new();
    for (i, k) in keyframes.iter().enumerate() {
        let frame = k.frame.get_ref().0;
        let at = |span: Range<usize>| format!("{label}: line {}: keyframe {}", line(span), i + 1);
        if i == 0 && frame != 0 {
            bail!(
                "{}: the first keyframe must be at frame 0, not {frame}",
                at(k.frame.span())
            );
        }
        if i > 0 && frame <= keyframes[i - 1].frame.get_ref().0 {
            bail!(
                "{}: frame {frame}: keyframe frames must increase strictly (the one before is at {})",
                at(k.frame.span()),
                keyframes[i - 1].frame.get_ref().0
            );
        }
        if frame >= frames {
            bail!(
                "{}: frame {frame} is past the last frame ({})",
                at(k.frame.span()),
                frames - 1
            );
        }
        let as_f32 = |v: &Spanned<Exactly<f64, 3>>| v.get_ref().0.map(|c| c as f32);
        for (key, c, span) in [
            ("position", as_f32(&k.position), k.position.span()),
            ("look_at", as_f32(&k.look_at), k.look_at.span()),
            ("up", k.up.get_ref().0, k.up.span()),
        ] {
            if !c.iter().all(|c| c.is_finite()) {
                let why = text::beyond_f32(c.iter().copied());
                bail!("{}: {key} {c:?} is not finite{why}", at(span));
            }
            if c.iter().any(|c| c.abs() > MAX_COORD) {
                bail!(
                    "{}: {key} {c:?} is too large (at most {MAX_COORD:e})",
                    at(span)
                );
            }
        }
        if let Some(why) = fov_fault(*k.fov.get_ref()) {
            bail!("{}: {why}", at(k.fov.span()));
        }
        let fov = *k.fov.get_ref() as f32;
        // Given from `origin` in f64 (a camera 5x10^6 units out keeps its fraction of a unit).
        let from_origin = |v: &Spanned<Exactly<f64, 3>>| {
            let p = DVec3::from(v.get_ref().0);
            if origin == DVec3::ZERO {
                p.as_vec3()
            } else {
                (p - origin).as_vec3()
            }
        };
        keys.push(Keyframe {
            frame,
            position: from_origin(&k.position),
            look_at: from_origin(&k.look_at),
            up: Vec3::from(k.up.get_ref().0),
            fov,
        });
        key_line.push(line(k.position.span()));
    }
    let interpolation = f
        .interpolation
        .as_ref()
        .map_or(Interpolation::default(), |i| *i.get_ref());
    let path = CameraPath {
        keyframes: keys,
        interpolation,
    };
    // Interpolation can make a valid pair of keyframes degenerate in between: check every frame.
    // A spline can also overshoot: past the keyframes' fov range or coordinates.
    for frame in 0..frames {
        let k = path.at(frame);
        let coords = [k.position, k.look_at, k.up];
        let fails = if let Some(why) = k.pose().fault() {
            why
        } else if !(k.fov > 0.0 && k.fov < 180.0) {
            format!(
                "the spline overshoots to fov {} (outside (0, 180) degrees): add a keyframe or \
                 use interpolation = \"linear\"",
                k.fov
            )
        } else if let Some(why) = fov_fault(k.fov as f64) {
            format!("the spline goes to {why}: add a keyframe or use interpolation = \"linear\"")
        } else if coords
            .iter()
            .any(|c| !c.is_finite() || c.abs().max_element() > MAX_COORD)
        {
            format!("the spline overshoots past {MAX_COORD:e}")
        } else {
            continue;
        };
        let keys = &path.keyframes;
        let i = keys.partition_point(|k| k.frame <= frame) - 1;
        let at = if keys[i].frame == frame || i + 1 == keys.len() {
            format!("keyframe {} at line {}", i + 1, key_line[i])
        } else {
            format!(
                "between the keyframes at lines {} and {}",
                key_line[i],
                key_line[i + 1]
            )
        };
        bail!("{label}: frame {frame} ({at}): {fails}");
    }
    Ok((w, h, Cameras::Path(path)))
}

/// An environment texel (times `intensity`) brighter than `MAX_KE`, clamped to it (as the
/// `radiance` key and `Ke` refuse or clamp it).
const ENV_CLAMPED: Kind = Kind {
    one: "environment texel above 1e9 clamped to 1e9",
    many: "environment texels above 1e9 clamped to 1e9",
};

/// A one-colour environment brighter than `MAX_KE` (its `radiance` times its `intensity`),
/// clamped to it as an image's texels are.
const ENV_RADIANCE_CLAMPED: Kind = Kind {
    one: "environment radiance times intensity above 1e9 clamped to 1e9",
    many: "environment radiances times intensity above 1e9 clamped to 1e9",
};

/// An environment pixel below zero (a photograph's debayering, a change of colour space, lossy
/// compression), read as zero.
const ENV_NEGATIVE: Kind = Kind {
    one: "environment pixel with a value below 0 read as 0",
    many: "environment pixels with values below 0 read as 0",
};

/// An environment image that is not twice as wide as it is high: read as a lat-long map all
/// the same, but a mirror ball, an angular map or a cube cross (square or 4:3 images) lights
/// the scene wrongly that way.
const ENV_NOT_LATLONG: Kind = Kind {
    one: "not twice as wide as high: read as a lat-long (equirectangular) map all the same (a \
          mirror-ball, angular or cube-cross image lights the scene wrongly)",
    many: "environment images not twice as wide as high: read as lat-long (equirectangular) \
           maps all the same",
};

/// Most texels of an environment image (16384 x 8192, a common size of downloaded skies): 24
/// bytes each once loaded; such a sky peaks at 3.3 GB while it loads (15 s), and the memory
/// available is checked before it is read.
pub const MAX_ENV_TEXELS: u64 = 1 << 27;

/// The world bounding box of a scene's own triangles' `positions` and its placed `prototypes`
/// (inverted, `lo` above `hi`, where there are none).
fn world_bounds(
    positions: &[Vec3],
    prototypes: &[Prototype],
    instances: &[Instance],
) -> (Vec3, Vec3) {
    // The corners of the box around `points` (inverted where there are none).
    let bounds = |points: &[Vec3]| {
        points.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        )
    };
    let (mut lo, mut hi) = bounds(positions);
    for i in instances {
        let proto = &prototypes[i.proto as usize];
        let (plo, phi) = bounds(&proto.positions);
        if plo.x > phi.x {
            continue;
        }
        for corner in box_corners(plo.as_dvec3(), phi.as_dvec3()) {
            // f32 corners, exactly: placed as Embree places them.
            let w = i.to_world.transform_point3(corner.as_vec3());
            (lo, hi) = (lo.min(w), hi.max(w));
        }
    }
    (lo, hi)
}

/// The eight corners of the box from `lo` to `hi`.
fn box_corners(lo: DVec3, hi: DVec3) -> impl Iterator<Item = DVec3> {
    (0..8).map(move |k| DVec3::select(glam::BVec3::new(k & 1 != 0, k & 2 != 0, k & 4 != 0), hi, lo))
}

/// A warning where rays leave surfaces farther off them than a twentieth of the size of the
/// scene's median triangle (`sqrt` of its area): a scene that spans far more than its details
/// (a room 3x10^5 units from a marker at the origin, which keeps it from being moved there)
/// lets light through its gaps and thins its shadows; such a room rendered black.
fn spread_warning(label: &str, lo: Vec3, hi: Vec3, floor: f32, areas: &[f32]) -> Option<String> {
    let far = lo.abs().max(hi.abs()).max_element();
    if areas.is_empty() || !far.is_finite() {
        return None;
    }
    let offset = crate::embree::SPAWN_EPS * (floor + far);
    let mut sizes: Vec<f32> = areas.iter().map(|a| a.sqrt()).collect();
    let mid = sizes.len() / 2;
    let median = *sizes.select_nth_unstable_by(mid, f32::total_cmp).1;
    (offset > 0.05 * median).then(|| {
        format!(
            "{label}: the scene spans {:e} units and lies up to {far:e} from the origin: rays \
             leave surfaces {offset:.2e} units off them, more than a twentieth of its median \
             triangle ({median:.2e} units a side), so light may pass through its gaps and \
             shadows thin (model its parts nearer to one another, or render them apart)",
            (hi - lo).max_element()
        )
    })
}

/// `Scene::offset_floor` of a scene's bounding box: its largest side, capped at 1.
fn offset_floor(lo: Vec3, hi: Vec3) -> f32 {
    let size = (hi - lo).max_element();
    if size.is_finite() && size > 0.0 {
        size.min(1.0)
    } else {
        1.0
    }
}

/// `Scene::origin` of a scene's bounding box: its centre where the box lies farther from the
/// origin than `FAR_FROM_ORIGIN` times its largest side, else zero.
///
/// A ray leaves a surface `SPAWN_EPS (floor + max |p|)` off it (`embree::offset_origin`), so a
/// room of a few units modelled 10^4 units away (a building at its map position) started its
/// rays a tenth of a unit off its surfaces and lit its contact shadows (0.6% brighter overall
/// at 10^4, 1-2% in the shadows). Centred, its coordinates and offsets are those of the same
/// room at the origin. Its geometry keeps the precision its f32 vertices had; an `[[object]]`'s
/// placement moves it in f64 before its positions are rounded to f32 (a 2-unit room placed at
/// 3x10^5 lost 6% of its light to vertices rounded to 1/32 unit). A scene whose box reaches
/// near the origin keeps its coordinates (and its frames bit for bit).
fn render_origin(lo: DVec3, hi: DVec3) -> DVec3 {
    let size = (hi - lo).max_element();
    let far = lo.abs().max(hi.abs()).max_element();
    let tiny = f32::MIN_POSITIVE as f64;
    if !(size.is_finite() && far.is_finite() && far > FAR_FROM_ORIGIN * size.max(tiny)) {
        return DVec3::ZERO;
    }
    (lo + hi) * 0.5
}

/// How many of its own sizes a scene's bounding box may lie from the origin before the render
/// centres it (`render_origin`): its offsets then shrink by at least about this factor.
const FAR_FROM_ORIGIN: f64 = 4.0;

/// The `[environment]` table, checked, and the image file it read (none for a colour).
fn load_environment(
    label: &str,
    text: &str,
    f: &EnvironmentFile,
    dir: Option<&Path>,
    repairs: &mut Repairs,
) -> Result<(Environment, Option<PathBuf>)> {
    let line = |span: Range<usize>| line_at(text.as_bytes(), span.start);
    let at =
        |span: Range<usize>, key: &str| format!("{label}: line {}: environment {key}", line(span));
    let table_line = f.line(text);
    let intensity = match &f.intensity {
        Some(i) => {
            let v = *i.get_ref();
            // Below single precision's smallest it is 0, a black sky that was not given.
            if !((0.0..=MAX_KE as f64).contains(&v)) || (v > 0.0 && v as f32 == 0.0) {
                bail!(
                    "{} {}: must be 0 or a finite number from 1.4e-45 to {MAX_KE:e}",
                    at(i.span(), "intensity"),
                    text::shown(v)
                );
            }
            v as f32
        }
        None => 1.0,
    };
    let rotation = match &f.rotation {
        Some(r) => {
            let v = *r.get_ref();
            if !(v.is_finite() && v.abs() <= MAX_DEGREES) {
                bail!(
                    "{} {v:e}: must be finite degrees (at most {MAX_DEGREES:e} in magnitude)",
                    at(r.span(), "rotation")
                );
            }
            // Reduced in f64 before it is rounded: 360000 degrees is 0 (in f32 its sine and
            // cosine had lost digits, and the sky came out turned by a hair).
            v.rem_euclid(360.0) as f32
        }
        None => 0.0,
    };
    match (&f.image, &f.radiance) {
        (Some(_), Some(r)) => bail!(
            "{}: give either image or radiance, not both",
            at(r.span(), "radiance")
        ),
        (None, None) => bail!(
            "{label}: line {}: [environment] needs an image (a lat-long file) or a radiance \
             (one colour)",
            table_line
        ),
        (None, Some(r)) => {
            let c = r.get_ref().0;
            if !c.iter().all(|c| (0.0..=MAX_KE as f64).contains(c)) {
                bail!(
                    "{} [{}]: each must be a finite number in [0, {MAX_KE:e}]",
                    at(r.span(), "radiance"),
                    c.map(text::shown).join(", ")
                );
            }
            // Capped as an image's texels are (their product reached 1e18 unsaid).
            let l = Vec3::from(c.map(|c| c as f32)) * intensity;
            if l.max_element() > MAX_KE {
                repairs.note(label, table_line, ENV_RADIANCE_CLAMPED, || {
                    format!(
                        "environment radiance times intensity is ({:e}, {:e}, {:e})",
                        l.x, l.y, l.z
                    )
                })?;
            }
            Ok((Environment::uniform(l.min(Vec3::splat(MAX_KE))), None))
        }
        (Some(img), None) => {
            let Some(dir) = dir else {
                bail!(
                    "{}: a shipped scene cannot name an image",
                    at(img.span(), "image")
                );
            };
            let path = scene_named(dir, img.get_ref());
            let at = format!("{label}: line {}", line(img.span()));
            // Regular file, size-capped, before OIIO opens it (a FIFO must not block the load).
            crate::util::input::open_input(&path, "environment image", MAX_INPUT_BYTES)
                .map_err(|e| anyhow!("{at}: {e}"))?;
            // While it loads, an environment holds its RGB floats and its texels (12 bytes
            // each per pixel), then its texels and its sampling tables (12 more): 24 at most.
            let (image, layout) = crate::image::read_colour(&path, MAX_ENV_TEXELS, 24)
                .map_err(|e| anyhow!("{at}: environment image: {e}"))?;
            if layout.cube_faces {
                bail!(
                    "{at}: environment image {}: a cube-face environment map (its six faces \
                     stacked), but an environment is a lat-long (equirectangular) map: convert \
                     it to one",
                    path.display()
                );
            }
            let what = format!("environment image '{}'", quote_name(img.get_ref()));
            maps::note_images_read(
                repairs,
                (label, table_line),
                &what,
                layout.parts,
                &layout.layers,
            )?;
            maps::note_meaning(repairs, (label, table_line), &what, &layout.meaning)?;
            let at = format!("{at}: environment image {}", path.display());
            let (width, height) = (image.width, image.height);
            // 2:1 within a pixel or 1% (4000 x 2001 is a lat-long map rounded).
            let off = (width as f64 - 2.0 * height as f64).abs();
            if off > 2.0 && off > 0.02 * width as f64 {
                repairs.note(label, table_line, ENV_NOT_LATLONG, || {
                    format!(
                        "environment image '{}' is {width} x {height}",
                        quote_name(img.get_ref())
                    )
                })?;
            }
            let data = image.data;
            let mut texels = Vec::with_capacity(data.len() / 3);
            for (i, c) in data.chunks_exact(3).enumerate() {
                let mut t = Vec3::new(c[0], c[1], c[2]);
                let (x, y) = (i as u32 % width, i as u32 / width);
                if !t.is_finite() {
                    bail!("{at}: pixel ({x}, {y}) is {t}: environment radiance must be finite");
                }
                // A photograph's small negatives (debayering, a change of colour space, lossy
                // compression): read as zero; such files were refused whole.
                if t.min_element() < 0.0 {
                    repairs.note(label, table_line, ENV_NEGATIVE, || {
                        format!(
                            "environment image {}: pixel ({x}, {y}) is {t}",
                            path.display()
                        )
                    })?;
                    t = t.max(Vec3::ZERO);
                }
                let l = t * intensity;
                if l.max_element() > MAX_KE {
                    let (x, y) = (i as u32 % width, i as u32 / width);
                    repairs.note(label, table_line, ENV_CLAMPED, || {
                        format!(
                            "environment image {}: pixel ({x}, {y}) is ({:e}, {:e}, {:e})",
                            path.display(),
                            l.x,
                            l.y,
                            l.z
                        )
                    })?;
                }
                texels.push(l.min(Vec3::splat(MAX_KE)));
            }
            // Freed before the sampling tables are built: a 16384 x 8192 sky's floats are 1.6 GB,
            // and the peak of its loading fell from 4.9 to about 3.2 GB.
            drop(data);
            let env = Environment::from_texels(width, height, texels, rotation);
            Ok((env, Some(path)))
        }
    }
}

/// The geometry of a scene: its own mesh (world space), prototypes and their instances, what
/// errors call it, and the files it was read from (OBJs, MTLs, textures).
struct Objects {
    label: String,
    mesh: Mesh,
    prototypes: Vec<Prototype>,
    instances: Vec<Instance>,
    inputs: Vec<PathBuf>,
    /// `Scene::origin`: the geometry is given from it, moved in f64 before its positions were
    /// rounded to f32 (by the OBJ's anchor, or by the placements).
    origin: DVec3,
    /// Warnings of the placements (not repairs: `--strict` keeps them).
    notes: Vec<String>,
    /// Where each object's triangles start in `mesh`, in order, and the object as messages
    /// name it (the OBJ's file, or the `[[object]]` table's line and file).
    parts: Vec<(usize, String)>,
}

/// The `[[object]]` tables of scene file `label` (text `text`, in folder `dir`): each OBJ read
/// once; one placed once, or one that emits, transformed into the scene's own mesh (a copy per
/// placement); one placed more than once and not emitting, a prototype with an instance per
/// placement.
fn load_objects(
    label: &str,
    text: &str,
    dir: &Path,
    list: &[objects::ObjectFile],
    textures: &mut Option<Textures>,
    repairs: &mut Repairs,
) -> Result<Objects> {
    // The placements of each distinct OBJ, in order of first appearance (`first`: its group).
    let lines = Lines::new(text.as_bytes());
    let mut groups: Vec<(PathBuf, String, Vec<glam::DMat4>)> = Vec::new();
    // An OBJ is one by its file (device and inode) where it can be read, so that one file
    // under two names (`crate.obj` and `./crate.obj`, a link) is read once and instanced.
    let mut first: HashMap<(u64, u64, PathBuf), usize> = HashMap::new();
    let file = |path: &Path| match crate::util::fs::file_id(path) {
        Some((dev, ino)) => (dev, ino, PathBuf::new()),
        None => (0, 0, path.to_path_buf()),
    };
    for o in list {
        let m = o.transform(label, &lines)?;
        let path = scene_named(dir, o.obj.get_ref());
        match first.get(&file(&path)) {
            Some(&g) => groups[g].2.push(m),
            None => {
                let at = format!(
                    "{label}: line {}: object '{}'",
                    lines.at(o.obj.span().start),
                    quote_name(o.obj.get_ref())
                );
                first.insert(file(&path), groups.len());
                groups.push((path, at, vec![m]));
            }
        }
    }
    let mut meshes = Vec::with_capacity(groups.len());
    let mut inputs = Vec::new();
    for (path, at, _) in &groups {
        refuse_scene_as_obj(path, Path::new(label), at)?;
        let bytes = read_input(path, "OBJ", MAX_INPUT_BYTES)
            .map(text::from_wide)
            .map_err(|e| anyhow!("{at}: {e}"))?;
        let obj_label = path.display().to_string();
        let mtl_dir = path.parent().unwrap_or(dir).to_path_buf();
        let (mesh, read, anchor) = load_obj_files(
            &obj_label,
            &bytes,
            &MtlSource::Dir(mtl_dir),
            textures,
            repairs,
        )?;
        inputs.push(path.clone());
        for p in read {
            if !inputs.contains(&p) {
                inputs.push(p);
            }
        }
        meshes.push((mesh, anchor));
    }
    // The world box of every placement, in f64, and `Scene::origin` of it: the placements
    // move the geometry there before its positions are rounded to f32.
    let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    for ((_, _, placements), (mesh, anchor)) in groups.iter().zip(&meshes) {
        let (plo, phi) = mesh
            .positions
            .iter()
            .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p.as_dvec3()), hi.max(p.as_dvec3()))
            });
        if plo.x > phi.x {
            continue;
        }
        for m in placements {
            for corner in box_corners(plo, phi) {
                let w = m.transform_point3(corner + *anchor);
                (lo, hi) = (lo.min(w), hi.max(w));
            }
        }
    }
    let origin = render_origin(lo, hi);
    let to_origin = glam::DMat4::from_translation(-origin);
    let mut own = Mesh::default();
    let mut prototypes = Vec::new();
    let mut instances = Vec::new();
    let mut notes = Vec::new();
    let mut parts = Vec::new();
    for ((_, at, placements), (mesh, anchor)) in groups.iter().zip(meshes) {
        // From the OBJ's anchor to the file's space, placed, then to the render's origin (no
        // product where both are zero: the matrices as given, to the bit).
        let from_anchor = glam::DMat4::from_translation(anchor);
        let placements: Vec<glam::DMat4> = placements
            .iter()
            .map(|m| match (anchor == DVec3::ZERO, origin == DVec3::ZERO) {
                (true, true) => *m,
                (true, false) => to_origin * *m,
                (false, _) => to_origin * *m * from_anchor,
            })
            .collect();
        let emits = mesh
            .tri_material
            .iter()
            .any(|&m| mesh.materials[m as usize].is_emissive());
        // A mirror turns the counter-clockwise side over, and a light without vertex normals
        // emits from that side (as in Mitsuba 3, whose OBJ reader also takes the winding after
        // the transform): a lamp mirrored to make a symmetric copy shines the other way, which
        // is easy to miss. One with vertex normals emits where they point
        // (`mesh::orient_emitters`), which a mirror maps as it maps the lamp.
        let mirrored = placements.iter().filter(|m| m.determinant() < 0.0).count();
        let by_winding = mesh
            .triangles
            .iter()
            .zip(&mesh.tri_material)
            .any(|(t, &m)| {
                mesh.materials[m as usize].is_emissive()
                    && (mesh.normals.is_empty()
                        || t.iter().any(|&i| mesh.normals[i as usize] == Vec3::ZERO))
            });
        if by_winding && mirrored > 0 {
            notes.push(format!(
                "{at}: placed mirrored (a transform of negative determinant) {mirrored} time(s), and \
                 it emits: a mirror turns the emitting (counter-clockwise) side of its triangles \
                 over, so those lights shine the other way than a mirror image of the OBJ's; if \
                 a light goes dark, turn its faces around in the OBJ or place it unmirrored"
            ));
        }
        if placements.len() == 1 || emits {
            // Each copy is a mesh of its own in memory (its vertices, its triangles' records,
            // Embree's build, a light's table entries): refused in one line before the copies
            // are made where they would not fit (an allocation that fails aborts the process;
            // 1000 placements of an 80000-triangle lamp asked for about 16 GB).
            let tris = (own.triangles.len() + placements.len() * mesh.triangles.len()) as u64;
            let need = tris * BYTES_PER_PLACED_TRIANGLE;
            if let Some(a) = crate::util::mem::available_bytes().filter(|&a| need > a) {
                bail!(
                    "{at}: placed {} times, its {} triangles{} make {tris} triangles of the scene's \
                     own, about {}, but {} of memory is available (an OBJ that emits \
                     is copied for each placement, not instanced: place fewer, or a lighter light)",
                    placements.len(),
                    mesh.triangles.len(),
                    if emits { " (it emits)" } else { "" },
                    crate::util::mem::size(need),
                    crate::util::mem::size(a)
                );
            }
            for m in &placements {
                parts.push((own.triangles.len(), at.clone()));
                objects::append(&mut own, objects::transformed(&mesh, m));
            }
        } else {
            let base = objects::add_materials(&mut own, &mesh);
            let proto = prototypes.len() as u32;
            prototypes.push(objects::prototype(mesh, base));
            instances.extend(placements.iter().map(|m| Instance::new(proto, m)));
        }
    }
    Ok(Objects {
        label: label.to_string(),
        mesh: own,
        prototypes,
        instances,
        inputs,
        origin,
        notes,
        parts,
    })
}

/// The memory a triangle copied into the scene's own mesh costs, all told (its corners, normals
/// and texture coordinates, its records, Embree's build of it, a light's table entry): measured
/// at about 210 bytes on placements of an emitting 80000-triangle OBJ (1.7 GB for 100).
const BYTES_PER_PLACED_TRIANGLE: u64 = 256;

/// Where the MTL files an OBJ names come from.
enum MtlSource {
    /// The OBJ's folder.
    Dir(PathBuf),
    /// A shipped scene's one MTL, whatever the name.
    Builtin(&'static str),
}

const MTL_MISSING: Kind = Kind {
    one: "mtllib names a missing file: its materials get the grey default (Kd 0.5)",
    many: "missing files named by mtllib: their materials get the grey default (Kd 0.5)",
};
/// `usemtl floor # the ground`: names keep their `#` (3ds Max names materials `Material #25`),
/// but where the whole is no material and the name before the `#` is one, that one is meant.
const COMMENT_AFTER_NAME: Kind = Kind {
    one: "usemtl with a comment after the material's name: the name before the '#' is used",
    many: "usemtl lines with a comment after the material's name: the name before the '#' is used",
};
const NEWMTL_COMMENT: Kind = Kind {
    one: "usemtl names a material whose newmtl has a comment after the name: that material is \
          used",
    many: "usemtl lines name materials whose newmtl has a comment after the name: those \
           materials are used",
};
const NO_MTLLIB: Kind = Kind {
    one: "usemtl without any mtllib: grey default material (Kd 0.5)",
    many: "usemtl lines without any mtllib: grey default material (Kd 0.5)",
};
const UNKNOWN_MATERIAL: Kind = Kind {
    one: "usemtl names a material no MTL defines: grey default material (Kd 0.5)",
    many: "usemtl lines name materials no MTL defines: grey default material (Kd 0.5)",
};
const NO_USEMTL: Kind = Kind {
    one: "face before any usemtl: grey default material (Kd 0.5)",
    many: "faces before any usemtl: grey default material (Kd 0.5)",
};
const DEFINED_AGAIN: Kind = Kind {
    one: "material defined again in a later MTL: the first definition is used",
    many: "materials defined again in a later MTL: the first definitions are used",
};

/// A face of a material with texture maps, in an OBJ that has texture coordinates, with corners
/// that have none: read at (0, 0) there.
const FACE_NO_TEXCOORDS: Kind = Kind {
    one: "a face with texture maps has corners without texture coordinates: its maps are read \
          at (0, 0) there",
    many: "faces with texture maps have corners without texture coordinates: their maps are \
           read at (0, 0) there",
};

const NO_TEXCOORDS: Kind = Kind {
    one: "the OBJ has no texture coordinates (vt): its maps are read at (0, 0) everywhere",
    many: "the OBJ has no texture coordinates (vt): its maps are read at (0, 0) everywhere",
};

/// A file named by a path that is not there, found by `find_named_file`.
pub(crate) const FOUND_ELSEWHERE: Kind = Kind {
    one: "path not found as written (from another machine?): the file was found as shown",
    many: "paths not found as written (from another machine?): the files were found as shown",
};

/// How a `usemtl` name led to its material (`resolve_usemtl`).
#[derive(Clone, Copy, PartialEq, Debug)]
enum Via {
    /// The material's name.
    Name,
    /// The name before a comment after it (`usemtl floor # the floor`).
    UsemtlComment,
    /// The name of a material whose `newmtl` has a comment after it (`newmtl floor # wood`).
    NewmtlComment,
}

/// Each name before a comment in the names of `materials` (`text::before_comments`), and the
/// whole name it is the head of: the first material's where two share one.
fn names_by_comment_head<'m>(
    materials: impl Iterator<Item = &'m mtl::MtlMaterial>,
) -> HashMap<&'m str, &'m str> {
    let mut heads = HashMap::new();
    for m in materials {
        for head in text::before_comments(&m.name) {
            heads.entry(head).or_insert(m.name.as_str());
        }
    }
    heads
}

/// The material `usemtl name` names, among those `defined`: the one of that name; else the
/// longest name before a comment after it that one has (`usemtl Material #25 # x` is
/// `Material #25`, a name Blender gives); else the one whose `newmtl` has a comment after that
/// name (`heads`, from `names_by_comment_head`).
fn resolve_usemtl<'a>(
    name: &'a str,
    defined: &dyn Fn(&str) -> bool,
    heads: &HashMap<&'a str, &'a str>,
) -> Option<(&'a str, Via)> {
    if defined(name) {
        return Some((name, Via::Name));
    }
    if let Some(head) = text::before_comments(name).find(|h| defined(h)) {
        return Some((head, Via::UsemtlComment));
    }
    heads.get(name).map(|&full| (full, Via::NewmtlComment))
}

/// Load the OBJ and the MTL files it names into a checked mesh, noting repairs.
#[cfg(test)]
fn load_obj(label: &str, bytes: &[u8], files: &MtlSource, repairs: &mut Repairs) -> Result<Mesh> {
    load_obj_files(label, bytes, files, &mut None, repairs).map(|(mesh, _, _)| mesh)
}

/// `load_obj`, and the MTL and texture files it read from the file system, and the point its
/// positions are given from (`obj::Obj::anchor`); the textures the materials' maps name are
/// opened into `textures` (made when the first is).
fn load_obj_files(
    label: &str,
    bytes: &[u8],
    files: &MtlSource,
    textures: &mut Option<Textures>,
    repairs: &mut Repairs,
) -> Result<(Mesh, Vec<PathBuf>, DVec3)> {
    let parsed = obj::parse(label, bytes, repairs)?;
    let mut materials = Vec::new();
    let mut maps = Vec::new();
    let mut texture_files = Vec::new();
    // Sets beside the lists: an OBJ naming tens of thousands of MTL files (or an MTL as many
    // unrendered maps) took a time in the square of their count with a search of the list.
    let mut texture_seen: HashSet<PathBuf> = HashSet::new();
    let mut names = Vec::new();
    let mut by_name: HashMap<String, u32> = HashMap::new();
    let used: HashSet<&str> = parsed
        .usemtl
        .iter()
        .map(|(_, name)| name.as_str())
        .collect();
    // What an MTL's reader says of a material goes only to one some face may use: by its name,
    // or with a comment after the name in `usemtl` or in `newmtl` (`resolve_usemtl`).
    let used_heads: HashSet<&str> = used.iter().flat_map(|n| text::before_comments(n)).collect();
    let maybe_used = |name: &str| {
        used.contains(name)
            || used_heads.contains(name)
            || text::before_comments(name).any(|h| used.contains(h))
    };
    let mut mtls: Vec<(String, Option<PathBuf>, mtl::Mtl)> = Vec::new();
    let mut read: HashSet<PathBuf> = HashSet::new();
    for (line, rest) in &parsed.mtllib {
        let shown = String::from_utf8_lossy(rest);
        let at = format!("{label}: line {line}: mtllib '{}'", quote(&shown));
        let loaded: Vec<(String, Option<PathBuf>, Vec<u8>)> = match files {
            // A shipped scene has one MTL, whatever its OBJ calls it: read it once.
            MtlSource::Builtin(_) if !read.is_empty() => Vec::new(),
            MtlSource::Builtin(text) => {
                read.insert(PathBuf::from(shown.as_ref()));
                vec![(
                    format!("{shown} (built in)"),
                    None,
                    text.as_bytes().to_vec(),
                )]
            }
            MtlSource::Dir(dir) => {
                let mut v = Vec::new();
                for (path, elsewhere) in mtl_paths(dir, rest) {
                    if elsewhere {
                        repairs.note(label, *line, FOUND_ELSEWHERE, || {
                            format!("'mtllib {}': found '{}'", quote(&shown), path.display())
                        })?;
                    }
                    // An OBJ that names itself (an exporter's or a hand's slip) was read as
                    // its own MTL: every line an unknown statement, and its materials missing.
                    let canonical = |p: &Path| p.canonicalize().ok();
                    if canonical(&path).is_some() && canonical(&path) == canonical(Path::new(label))
                    {
                        bail!(
                            "{at}: that is this OBJ itself; mtllib names the MTL file that holds \
                             its materials (newmtl, Kd, ...)"
                        );
                    }
                    // The same file named twice is read once.
                    if !read.insert(path.clone()) {
                        continue;
                    }
                    match read_input_or_missing(&path, "MTL", MAX_INPUT_BYTES).map(text::from_wide)
                    {
                        Ok(b) => {
                            let dir = path.parent().map(Path::to_path_buf);
                            v.push((path.display().to_string(), dir, b))
                        }
                        Err(InputError::NotFound(_)) => {
                            repairs.note(label, *line, MTL_MISSING, || {
                                let name = path.strip_prefix(dir).unwrap_or(&path);
                                let missing =
                                    missing_file_message(dir, &name.to_string_lossy(), &path);
                                format!("'mtllib {}': {missing}", quote(&shown))
                            })?;
                        }
                        Err(e) => bail!("{at}: {e}"),
                    }
                }
                v
            }
        };
        for (mtl_label, mtl_dir, b) in loaded {
            let mtl = mtl::parse_for(&mtl_label, &b, repairs, &maybe_used)?;
            mtls.push((mtl_label, mtl_dir, mtl));
        }
    }
    // Each material's number, the first definition of a name's (a later one is said and
    // dropped below, in the same order); then which material each `usemtl` names, now that
    // every MTL's names are known: the materials in use are those whose maps are opened.
    for m in mtls.iter().flat_map(|(_, _, m)| &m.materials) {
        let next = by_name.len() as u32;
        by_name.entry(m.name.clone()).or_insert(next);
    }
    let names_by_head = names_by_comment_head(mtls.iter().flat_map(|(_, _, m)| &m.materials));
    let resolved: Vec<Option<(&str, Via)>> = parsed
        .usemtl
        .iter()
        .map(|(_, name)| resolve_usemtl(name, &|n| by_name.contains_key(n), &names_by_head))
        .collect();
    let in_use: HashSet<&str> = resolved.iter().flatten().map(|&(n, _)| n).collect();
    for (mtl_label, mtl_dir, mtl) in &mtls {
        let (mtl_label, mtl_dir) = (mtl_label.as_str(), mtl_dir.as_deref());
        // The maps reframe does not open are inputs too, never written over: those it does
        // not render, and those of the materials no `usemtl` names.
        if let Some(dir) = mtl_dir {
            let unused = mtl
                .materials
                .iter()
                .filter(|m| !in_use.contains(m.name.as_str()))
                .flat_map(|m| m.maps.iter().flatten().map(|spec| &spec.file));
            for f in mtl
                .other_files
                .iter()
                .chain(unused)
                .filter(|f| !f.is_empty())
            {
                let (path, _) = locate_named_file(dir, f, false);
                if texture_seen.insert(path.clone()) {
                    texture_files.push(path);
                }
            }
        }
        for m in &mtl.materials {
            if by_name[&m.name] as usize != materials.len() {
                repairs.note(mtl_label, m.line, DEFINED_AGAIN, || {
                    format!("material '{}'", m.name)
                })?;
                continue;
            }
            // A material no `usemtl` names colours nothing: its maps are not opened (a
            // library MTL naming textures that are not shipped refused the scene) and its
            // repairs are not said.
            let in_use = in_use.contains(m.name.as_str());
            let mut unsaid = Repairs::new(false);
            let notes = if in_use { &mut *repairs } else { &mut unsaid };
            let material = m.material(mtl_label, notes)?;
            materials.push(material);
            maps.push(if in_use {
                Maps::open(
                    mtl_label,
                    mtl_dir,
                    (m, &material),
                    textures,
                    &mut texture_files,
                    repairs,
                )?
            } else {
                Maps::default()
            });
            names.push(m.name.clone());
        }
    }
    // Faces with no material (or an unknown one) share one grey default, added if needed.
    let default = materials.len() as u32;
    let mut need_default = false;
    let mut usemtl_material = Vec::with_capacity(parsed.usemtl.len());
    for ((line, name), resolved) in parsed.usemtl.iter().zip(&resolved) {
        let id = match *resolved {
            Some((full, via)) => {
                match via {
                    Via::Name => {}
                    Via::UsemtlComment => repairs.note(label, *line, COMMENT_AFTER_NAME, || {
                        format!("'usemtl {}'", quote(name))
                    })?,
                    Via::NewmtlComment => repairs.note(label, *line, NEWMTL_COMMENT, || {
                        format!("'usemtl {}': 'newmtl {}'", quote(name), quote(full))
                    })?,
                }
                by_name[full]
            }
            None => {
                let kind = if parsed.mtllib.is_empty() {
                    NO_MTLLIB
                } else {
                    UNKNOWN_MATERIAL
                };
                repairs.note(label, *line, kind, || {
                    let hint = text::did_you_mean(name, names.iter().map(String::as_str));
                    format!("'usemtl {}'{hint}", quote(name))
                })?;
                need_default = true;
                default
            }
        };
        usemtl_material.push(id);
    }
    // An OBJ of geometry alone (no `mtllib`, no `usemtl`: a scanned model, a simulation's
    // output) is the grey default by design, not by a loss: no warning. Faces left without a
    // material in a file that has materials are warned of.
    let geometry_only = parsed.mtllib.is_empty() && parsed.usemtl.is_empty();
    for f in parsed.faces.iter().filter(|f| f.usemtl.is_none()) {
        if !geometry_only {
            repairs.note(label, f.line, NO_USEMTL, || text::quote_line(bytes, f.line))?;
        }
        need_default = true;
    }
    let emissive = |m: u32| materials.get(m as usize).is_some_and(Material::is_emissive);
    let material_of = (&usemtl_material[..], default);
    let mut mesh = mesh::build(label, bytes, &parsed, material_of, &emissive, repairs)?;
    if need_default {
        materials.push(Material {
            kd: Vec3::splat(0.5),
            ..Default::default()
        });
        names.push("default".into());
    }
    if maps.iter().any(|m| !m.is_empty()) {
        maps.resize(materials.len(), Maps::default());
        // A map on faces without texture coordinates reads one texel, (0, 0), everywhere.
        if parsed.uvs.is_empty() {
            if let Some(t) = mesh
                .tri_material
                .iter()
                .find(|&&m| !maps[m as usize].is_empty())
            {
                let name = &names[*t as usize];
                repairs.note(label, 1, NO_TEXCOORDS, || {
                    format!("material '{name}' has texture maps")
                })?;
            }
        } else {
            // An OBJ with texture coordinates whose mapped faces lack them, all or some corners
            // (one object of an export without a UV map, beside others with one).
            for f in &parsed.faces {
                let m = f.usemtl.map_or(default, |u| usemtl_material[u as usize]);
                let corners = &parsed.corners[f.corners.clone()];
                if maps[m as usize].is_empty() || corners.iter().all(|c| c.vt.is_some()) {
                    continue;
                }
                let none = corners.iter().all(|c| c.vt.is_none());
                repairs.note(label, f.line, FACE_NO_TEXCOORDS, || {
                    format!(
                        "{} (material '{}' has texture maps; {})",
                        text::quote_line(bytes, f.line),
                        names[m as usize],
                        if none {
                            "no corner has a vt"
                        } else {
                            "some corners have no vt"
                        }
                    )
                })?;
            }
        }
        mesh.maps = maps;
    }
    mesh.materials = materials;
    mesh.material_names = names;
    let read = match files {
        MtlSource::Dir(_) => read.into_iter().chain(texture_files).collect(),
        MtlSource::Builtin(_) => Vec::new(),
    };
    Ok((mesh, read, parsed.anchor))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An `mtllib` list: names split at white space, a backslash escaping a space or a tab
    /// (tinyobjloader's `mtl\ filename\ with\ whitespace\ issue46.mtl`, which was split into
    /// four missing names, and the MTL beside the OBJ never read), a trailing comment; the
    /// whole rest of the line where that is a file.
    #[test]
    fn mtllib_names_split_at_unescaped_white_space() {
        let d = tempfile::tempdir().unwrap();
        let dir = d.path();
        std::fs::write(dir.join("with spaces.mtl"), "").unwrap();
        std::fs::write(dir.join("a.mtl"), "").unwrap();
        let names = |line: &str| -> Vec<(String, bool)> {
            mtl_paths(dir, line.as_bytes())
                .into_iter()
                .map(|(p, found)| (p.strip_prefix(dir).unwrap().display().to_string(), found))
                .collect()
        };
        let plain = |n: &[&str]| -> Vec<(String, bool)> {
            n.iter().map(|n| (n.to_string(), false)).collect()
        };
        assert_eq!(
            names("missing.mtl with\\ spaces.mtl  a.mtl # comment"),
            plain(&["missing.mtl", "with spaces.mtl", "a.mtl"])
        );
        assert_eq!(names("with spaces.mtl"), plain(&["with spaces.mtl"]));
        assert_eq!(
            names("x\\\ty.mtl A.MTL"),
            [("x\ty.mtl".into(), false), ("a.mtl".into(), true)]
        );
        // A backslash before anything else is kept (a Windows path, found by its file name).
        assert_eq!(
            names("sub\\a.mtl b.mtl"),
            [("a.mtl".into(), true), ("b.mtl".into(), false)]
        );
    }

    #[test]
    fn shipped_scenes_load() {
        let d = Device::new().unwrap();
        for name in builtin_names() {
            let s = Scene::load(name, &d).unwrap_or_else(|e| panic!("{name}: {e:#}"));
            assert!(s.frames >= 1 && !s.lights.tris.is_empty(), "{name}");
            assert!(s.warnings.is_empty(), "{name}: {:?}", s.warnings);
        }
    }

    #[test]
    fn objects_with_normals_are_smooth_beside_flat_ones() {
        // The vase scene: the vase and ball carry `vn`, the room and table do not.
        let d = Device::new().unwrap();
        let s = Scene::load("vase", &d).unwrap();
        assert_eq!(s.normals.len(), s.positions.len());
        let zero = s.normals.iter().filter(|n| **n == Vec3::ZERO).count();
        assert!(zero > 0 && zero < s.normals.len(), "{zero} flat vertices");
        // A smooth triangle shades with an interpolated normal that differs from its face's.
        let t = (0..s.triangles.len())
            .find(|&t| {
                s.triangles[t]
                    .iter()
                    .all(|&i| s.normals[i as usize] != Vec3::ZERO)
            })
            .unwrap();
        let hit = Hit {
            t: 1.0,
            inst: Hit::NO_INSTANCE,
            prim_id: t as u32,
            u: 0.2,
            v: 0.3,
            ng: s.tri_normal[t],
        };
        let sp = s.surface(&hit);
        assert!(
            sp.ns.dot(sp.ng) > 0.0 && sp.ns.dot(sp.ng) < 0.99999,
            "{:?}",
            sp
        );
    }

    #[test]
    fn light_pdf_matches_sampling() {
        let d = Device::new().unwrap();
        let s = Scene::load("cornell", &d).unwrap();
        let x = Vec3::new(0.0, 0.5, 0.0)
            + s.positions.iter().copied().sum::<Vec3>() / s.positions.len() as f32;
        let mut sm = crate::sampling::Sampler::new(1, 0, 0, 0);
        for _ in 0..100 {
            let ls = s.sample_light(x, sm.next_2d()).unwrap();
            let hit = s.geometry.intersect1(&crate::embree::Ray::new(x, ls.wi));
            let Some(h) = hit else { continue };
            if (h.t - ls.dist).abs() < 1e-3 {
                let pdf = s.light_pdf(x, ls.p, h.prim_id);
                assert!((pdf / ls.pdf - 1.0).abs() < 1e-3, "{pdf} vs {}", ls.pdf);
            }
        }
    }

    /// A 400 x 400 dim panel overhead and a lamp of 0.04 x 0.04 units 10^4 times as bright
    /// per area beside a wall: by power alone the lamp got 10^-4 of the light samples
    /// (Mitsuba 3, which picks its four emitters evenly, lit the wall 2-9% brighter than
    /// reframe at 2048 spp: the lamp's light came in rare bright samples). It gets its even
    /// share now, and the density of every sample is what `light_pdf` says of its point.
    #[test]
    fn a_small_bright_light_beside_a_large_dim_one_gets_its_share_of_the_picks() {
        let dir = tempfile::tempdir().unwrap();
        let obj = "mtllib s.mtl\n\
            v -200 10 -200\nv 200 10 -200\nv 200 10 200\nv -200 10 200\n\
            v -0.02 0.5 0\nv 0.02 0.5 0\nv 0.02 0.54 0\nv -0.02 0.54 0\n\
            v -5 0 -5\nv 5 0 -5\nv 5 0 5\nv -5 0 5\n\
            usemtl panel\nf 1 4 3 2\nusemtl lamp\nf 5 6 7 8\nusemtl floor\nf 9 12 11 10\n";
        let mtl = "newmtl panel\nKd 0 0 0\nKe 0.05 0.05 0.05\n\
            newmtl lamp\nKd 0 0 0\nKe 500 500 500\nnewmtl floor\nKd 0.5 0.5 0.5\n";
        std::fs::write(dir.path().join("s.obj"), obj).unwrap();
        std::fs::write(dir.path().join("s.mtl"), mtl).unwrap();
        // And a speck whose area is 0 in single precision once placed: a light of no power,
        // which must get no share (its 0 / 0 made every pick NaN, and the frame black).
        std::fs::write(
            dir.path().join("speck.obj"),
            "mtllib speck.mtl\nv -1e-9 0 -1e-9\nv 1e-9 0 -1e-9\nv 1e-9 0 1e-9\nv -1e-9 0 1e-9\n\
             usemtl speck\nf 1 2 3 4\n",
        )
        .unwrap();
        std::fs::write(dir.path().join("speck.mtl"), "newmtl speck\nKe 1 1 1\n").unwrap();
        let toml = "frames = 1\nresolution = [8, 8]\n[[keyframe]]\nframe = 0\n\
                    position = [0, 1, 5]\nlook_at = [0, 0.5, 0]\nup = [0, 1, 0]\nfov = 50.0\n\
                    [[object]]\nobj = \"s.obj\"\n\
                    [[object]]\nobj = \"speck.obj\"\nscale = 1e-6\ntranslate = [3, 0.2, -1]\n";
        let path = dir.path().join("s.toml");
        std::fs::write(&path, toml).unwrap();
        let d = Device::new().unwrap();
        let s = Scene::load(path.to_str().unwrap(), &d).unwrap();
        // A point on the floor in front of the lamp, which faces +z.
        let x = Vec3::new(0.1, 0.0, 0.5);
        let mut sm = crate::sampling::Sampler::new(7, 0, 0, 0);
        let n = 40_000;
        let (mut on_lamp, mut checked) = (0, 0);
        for _ in 0..n {
            let ls = s.sample_light(x, sm.next_2d()).unwrap();
            if ls.p.y < 1.0 {
                on_lamp += 1;
            }
            let hit = s.geometry.intersect1(&crate::embree::Ray::new(x, ls.wi));
            if let Some(h) = hit.filter(|h| (h.t - ls.dist).abs() < 1e-3 * ls.dist) {
                let pdf = s.light_pdf(x, ls.p, h.prim_id);
                assert!((pdf / ls.pdf - 1.0).abs() < 1e-3, "{pdf} vs {}", ls.pdf);
                checked += 1;
            }
        }
        assert!(checked > n / 2, "{checked} samples checked");
        // Half of the even quarter of the picks (plus the lamp's tiny share by power): an
        // eighth, give or take the sampling.
        let share = on_lamp as f64 / n as f64;
        assert!(
            (0.115..0.135).contains(&share),
            "the lamp got {share} of the picks, not an eighth"
        );
    }

    #[test]
    fn materials_fall_back_to_the_default_with_one_warning_per_kind() {
        // No mtllib at all: every usemtl falls back (a scene file could not render this: it
        // has no light, so the loader is called directly).
        let obj =
            b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nusemtl a\nf 1 2 3\nusemtl b\nf 2 4 3\nf 3 4 1\n";
        let dir = tempfile::tempdir().unwrap();
        let files = MtlSource::Dir(dir.path().to_path_buf());
        let mut r = Repairs::new(false);
        let mesh = load_obj("a.obj", obj, &files, &mut r).unwrap();
        assert_eq!(mesh.material_names, ["default"]);
        assert_eq!(mesh.materials[0].kd, Vec3::splat(0.5));
        assert_eq!(mesh.tri_material, [0, 0, 0]);
        assert_eq!(
            r.into_warnings(),
            [
                "a.obj: 2 usemtl lines without any mtllib: grey default material (Kd 0.5) (first \
              at line 5: 'usemtl a')"
            ]
        );
        let e = load_obj("a.obj", obj, &files, &mut Repairs::new(true))
            .err()
            .unwrap();
        assert_eq!(
            e.to_string(),
            "a.obj: line 5: 'usemtl a': usemtl without any mtllib: grey default material (Kd \
             0.5) (refused: strict loading)"
        );
    }

    /// SketchUp's two-sided export writes each face again, reversed, with its back material:
    /// the later face of each such pair is left out with a warning (the two fought over every
    /// point, a speckle of both materials), whichever corner it starts from and however its
    /// vertices are numbered; a face repeated in the same order too. A lamp's reversed copy
    /// too, with a warning of its own (it rendered as a speckle of light and dark, and the reuse
    /// methods were biased on it); a lamp's face on a wall's corners is kept, and so are faces
    /// that share only some corners.
    #[test]
    fn a_face_on_the_corners_of_an_earlier_one_is_left_out() {
        let obj = b"mtllib m.mtl\nv -1 -1 0\nv 1 -1 0\nv -1 1 0\nv 1 1 0\nv 1 1 0\n\
                    usemtl Front\nf 1 2 4 3\nusemtl Back\nf 2 1 3 5\nf 4 3 1 2\nf 1 2 4\n\
                    usemtl Lamp\nf 1 2 3\nf 3 2 1\nusemtl Front\nf 2 3 1\n";
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("m.mtl"),
            "newmtl Front\nKd 0.8 0 0\nnewmtl Back\nKd 0 0 0.8\nnewmtl Lamp\nKe 1 1 1\n",
        )
        .unwrap();
        let files = MtlSource::Dir(dir.path().to_path_buf());
        let mut r = Repairs::new(false);
        let mesh = load_obj("a.obj", obj, &files, &mut r).unwrap();
        let names = |m: &u32| mesh.material_names[*m as usize].as_str();
        let kept: Vec<&str> = mesh.tri_material.iter().map(names).collect();
        // The quad (two triangles), the triangle on three of its corners, the lamp's first face,
        // and a wall's face on the lamp's corners.
        assert_eq!(kept, ["Front", "Front", "Back", "Lamp", "Front"]);
        let w = r.into_warnings();
        assert_eq!(w.len(), 2, "{w:?}");
        assert!(
            w[1].starts_with(
                "a.obj: line 15: 'f 3 2 1' (the face of line 14): emitting face on the same \
                 corners as an earlier emitting one (a lamp made two-sided by a reversed copy of its faces, or written \
                 twice) left out"
            ),
            "{w:?}"
        );
        assert!(
            w[0].starts_with(
                "a.obj: 2 faces on the same corners as earlier ones (a two-sided export, as \
                 SketchUp writes each face again, reversed, with its back material) left out"
            ) && w[0].ends_with("(first at line 10: 'f 2 1 3 5' (the face of line 8))"),
            "{w:?}"
        );
    }

    /// A lamp written as one face that goes round its outline twice or three times (`f 5 6 7
    /// 8 5 6 7 8`) was split as a fan into its triangles two or three times over, each
    /// emitting: the room was two or three times as bright. Its area is that of one round,
    /// with a warning; a pentagram (round twice about its centre, but no triangle repeated)
    /// is left to the fan as before.
    #[test]
    fn a_face_round_its_outline_twice_is_one_round() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("m.mtl"), "newmtl Lamp\nKe 1 1 1\n").unwrap();
        let files = MtlSource::Dir(dir.path().to_path_buf());
        let head = "mtllib m.mtl\nv 0 0 0\nv 2 0 0\nv 2 1 0\nv 0 1 0\nusemtl Lamp\n";
        let area = |faces: &str| {
            let mut r = Repairs::new(false);
            let obj = format!("{head}{faces}");
            let mesh = load_obj("a.obj", obj.as_bytes(), &files, &mut r).unwrap();
            (mesh.tri_area.iter().sum::<f32>(), r.into_warnings())
        };
        let (once, w) = area("f 1 2 3 4\n");
        assert_eq!((once, w.len()), (2.0, 0));
        for faces in [
            "f 1 2 3 4 1 2 3 4\n",
            "f 1 2 3 4 1 2 3 4 1 2 3 4\n",
            "f 2 3 4 1 2 3 4 1\n",
        ] {
            let (a, w) = area(faces);
            assert_eq!(a, once, "{faces}");
            assert!(
                w.iter()
                    .any(|w| w.contains("polygon that goes round its outline more than once")),
                "{w:?}"
            );
        }
        // Five points round a circle, joined every second one: a pentagram's fan.
        let star = "mtllib m.mtl\nv 0 1 0\nv 0.951 0.309 0\nv 0.588 -0.809 0\n\
                    v -0.588 -0.809 0\nv -0.951 0.309 0\nusemtl Lamp\nf 1 3 5 2 4\n";
        let mut r = Repairs::new(false);
        let mesh = load_obj("a.obj", star.as_bytes(), &files, &mut r).unwrap();
        assert_eq!(mesh.triangles.len(), 3);
        assert!(!r.into_warnings().iter().any(|w| w.contains("goes round")));
    }

    #[test]
    fn a_zero_normal_flattens_only_its_triangles() {
        let obj = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvn 0 0 1\nvn 0 0 0\n\
                    f 1//1 2//1 3//1\nf 2//1 4//2 3//1\n";
        let dir = tempfile::tempdir().unwrap();
        let files = MtlSource::Dir(dir.path().to_path_buf());
        let mut r = Repairs::new(false);
        let mesh = load_obj("a.obj", obj, &files, &mut r).unwrap();
        let normals = |t: usize| mesh.triangles[t].map(|i| mesh.normals[i as usize]);
        assert_eq!(normals(0), [Vec3::Z; 3]);
        assert_eq!(normals(1), [Vec3::ZERO; 3]);
        let w = r.into_warnings();
        // A file of geometry alone gets the grey default without a warning.
        assert_eq!(w.len(), 1, "the zero normal alone: {w:?}");
        assert!(w[0].contains("zero"), "{w:?}");
    }
}
