//! Scenes: a small TOML file naming an OBJ (geometry, MTL materials) and the camera path.
//!
//! ```toml
//! obj = "vase.obj"            # relative to the TOML file
//! frames = 48
//! resolution = [320, 240]     # width, height
//! [[keyframe]]                # one or more; frames 0-based, strictly increasing
//! frame = 0
//! position = [0.0, 1.2, 4.0]
//! look_at = [0.0, 0.9, 0.0]
//! up = [0.0, 1.0, 0.0]
//! fov = 50.0                  # vertical, degrees, in (0, 180)
//! ```
//!
//! Materials: `Kd` Lambertian, `Ks`/`Ns` modified Phong (`Kd + Ks <= 1` per channel), `Ke`
//! emission (one-sided, to the side of the counter-clockwise face normal). Every triangle with
//! `Ke > 0` is an area light. Loading checks everything a render could trip over later and
//! fails with a one-line error naming the file and the line (and the key or statement) at
//! fault; the OBJ and MTL rules are in `scene/text.rs`. Limits: at most `MAX_FRAMES` frames and
//! `MAX_PIXELS` pixels, coordinates (vertices, camera) at most 1e18 in magnitude, and every
//! `usemtl` must name a material of an `mtllib` above it.
//! The shipped scenes (`vase`, `cornell`, `furnace`) are embedded in the binary.
//!
//! ```no_run
//! use reframe::{embree::Device, scene::Scene};
//! let device = Device::new()?;
//! let scene = Scene::load("vase", &device)?;
//! assert_eq!(scene.frames, 48);
//! # anyhow::Ok(())
//! ```
use crate::bsdf::{luminance, Material};
use crate::camera::{Camera, CameraPath, Keyframe};
use crate::embree::{Device, Hit, TriangleScene};
use crate::sampling::uniform_triangle;
use anyhow::{anyhow, bail, Context, Result};
use glam::{Vec2, Vec3};
use serde::Deserialize;
use std::cell::RefCell;
use std::collections::HashMap;
use std::ops::Range;
use std::path::{Path, PathBuf};
use toml::Spanned;

mod text;
use text::{as_text, line_at, quote, MAX_COORD};

/// Most frames a scene may have: every frame of the camera path is checked when it loads.
pub const MAX_FRAMES: u32 = 1_000_000;
/// Most pixels of a scene's resolution (16384 x 16384).
pub const MAX_PIXELS: u64 = 1 << 28;

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

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    obj: Spanned<String>,
    frames: Spanned<u32>,
    resolution: Spanned<[u32; 2]>,
    keyframe: Vec<KeyframeFile>,
}

/// Every value keeps its place in the file, so that an error can name its line.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct KeyframeFile {
    frame: Spanned<u32>,
    position: Spanned<[f32; 3]>,
    look_at: Spanned<[f32; 3]>,
    up: Spanned<[f32; 3]>,
    fov: Spanned<f32>,
}

/// Emitting triangles, sampled in proportion to their power (area times luminance of `Ke`).
pub struct Lights {
    /// Triangle index of each light.
    pub tris: Vec<u32>,
    cdf: Vec<f32>,
    /// Per triangle of the scene: probability of choosing it divided by its area (0 if not a
    /// light), i.e. the area density of light sampling on it.
    pdf_area: Vec<f32>,
}

/// A point sampled on a light, seen from a shading point.
#[derive(Clone, Copy, Debug)]
pub struct LightSample {
    pub p: Vec3,
    pub n: Vec3,
    pub wi: Vec3,
    pub dist: f32,
    /// Emitted radiance towards the shading point (zero from the back of the light).
    pub le: Vec3,
    /// Solid-angle density at the shading point.
    pub pdf: f32,
}

/// The geometry at a hit, built from Embree's minimal hit only when it is shaded.
#[derive(Clone, Copy, Debug)]
pub struct SurfacePoint {
    pub p: Vec3,
    /// Unit geometric normal, as wound (front side = emitting side).
    pub ng: Vec3,
    /// Unit shading normal (interpolated vertex normals, or `ng`), on the same side as `ng`.
    pub ns: Vec3,
    pub prim: u32,
    pub material: u32,
}

pub struct Scene {
    pub name: String,
    pub frames: u32,
    pub width: u32,
    pub height: u32,
    pub path: CameraPath,
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
    pub tri_material: Vec<u32>,
    pub tri_normal: Vec<Vec3>,
    pub tri_area: Vec<f32>,
    pub materials: Vec<Material>,
    pub material_names: Vec<String>,
    pub lights: Lights,
    pub geometry: TriangleScene,
    /// What loading found odd but not wrong (e.g. faces without a material). The command line
    /// prints them once the command has succeeded, so that a failure stays one line.
    pub warnings: Vec<String>,
}

/// Where a scene's files come from: the file system or the binary.
enum Source {
    Files { toml: PathBuf },
    Builtin(usize),
}

impl Scene {
    /// Load a scene by file path, or by the name of a shipped scene (`vase`, `cornell`,
    /// `furnace`) when no such file exists.
    pub fn load(name_or_path: &str, device: &Device) -> Result<Scene> {
        let p = Path::new(name_or_path);
        let source = if p.is_file() {
            Source::Files {
                toml: p.to_path_buf(),
            }
        } else if let Some(i) = BUILTIN.iter().position(|b| b.0 == name_or_path) {
            Source::Builtin(i)
        } else {
            bail!(
                "scene '{name_or_path}': no such file, and not a shipped scene ({})",
                builtin_names().join(", ")
            );
        };
        let (label, toml_bytes) = match &source {
            Source::Files { toml } => (
                toml.display().to_string(),
                std::fs::read(toml).map_err(|e| anyhow!("{}: cannot read: {e}", toml.display()))?,
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
        let (width, height, path) = check_camera(&label, toml_text, &file)?;
        let obj_at = format!(
            "{label}: line {}: obj '{}'",
            line_at(toml_text.as_bytes(), file.obj.span().start),
            file.obj.get_ref()
        );
        let (obj_label, obj_bytes, mtl_dir) = match &source {
            Source::Files { toml } => {
                let dir = toml.parent().unwrap_or(Path::new(".")).to_path_buf();
                let obj = dir.join(file.obj.get_ref());
                let bytes = std::fs::read(&obj)
                    .map_err(|e| anyhow!("{obj_at}: cannot read '{}': {e}", obj.display()))?;
                (
                    obj.display().to_string(),
                    bytes,
                    Some(obj.parent().unwrap_or(&dir).to_path_buf()),
                )
            }
            Source::Builtin(i) => (
                format!("{} (built in)", file.obj.get_ref()),
                BUILTIN[*i].2.as_bytes().to_vec(),
                None,
            ),
        };
        let builtin_mtl = match &source {
            Source::Builtin(i) => Some(BUILTIN[*i].3),
            Source::Files { .. } => None,
        };
        let (mesh, warning) = load_obj(&obj_label, &obj_bytes, mtl_dir.as_deref(), builtin_mtl)?;
        let geometry = TriangleScene::new(device, &mesh.positions, &mesh.triangles)
            .with_context(|| format!("{obj_label}: building the Embree scene"))?;
        let lights = Lights::new(&mesh)?.ok_or_else(|| {
            anyhow!("{obj_label}: the scene has no lights (no material with a positive Ke)")
        })?;
        Ok(Scene {
            warnings: warning.into_iter().collect(),
            name,
            frames: *file.frames.get_ref(),
            width,
            height,
            path,
            positions: mesh.positions,
            normals: mesh.normals,
            triangles: mesh.triangles,
            tri_material: mesh.tri_material,
            tri_normal: mesh.tri_normal,
            tri_area: mesh.tri_area,
            materials: mesh.materials,
            material_names: mesh.material_names,
            lights,
            geometry,
        })
    }

    /// The camera of frame `frame`, at `width` x `height`.
    pub fn camera(&self, frame: u32, width: u32, height: u32) -> Camera {
        Camera::new(&self.path.at(frame), width, height)
    }

    /// Shading data for Embree's hit.
    #[inline]
    pub fn surface(&self, hit: &Hit) -> SurfacePoint {
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
        SurfacePoint {
            p,
            ng,
            ns,
            prim,
            material: self.tri_material[prim as usize],
        }
    }

    pub fn material(&self, sp: &SurfacePoint) -> &Material {
        &self.materials[sp.material as usize]
    }

    /// Radiance emitted by the triangle of `sp` towards `toward` (one-sided).
    #[inline]
    pub fn emitted(&self, sp: &SurfacePoint, toward: Vec3) -> Vec3 {
        let m = self.material(sp);
        if m.is_emissive() && sp.ng.dot(toward - sp.p) > 0.0 {
            m.ke
        } else {
            Vec3::ZERO
        }
    }

    /// Sample a point on a light as seen from `x`.
    pub fn sample_light(&self, x: Vec3, u_sel: f32, u: Vec2) -> Option<LightSample> {
        let l = &self.lights;
        let i = l.cdf.partition_point(|&c| c <= u_sel).min(l.tris.len() - 1);
        let tri = l.tris[i] as usize;
        let [i0, i1, i2] = self.triangles[tri];
        let (b1, b2) = uniform_triangle(u);
        let p = self.positions[i0 as usize] * (1.0 - b1 - b2)
            + self.positions[i1 as usize] * b1
            + self.positions[i2 as usize] * b2;
        let n = self.tri_normal[tri];
        let d = p - x;
        let dist2 = d.length_squared();
        let dist = dist2.sqrt();
        if dist <= 0.0 {
            return None;
        }
        let wi = d / dist;
        let cos_l = n.dot(-wi);
        if cos_l.abs() <= 1e-7 {
            return None;
        }
        let le = if cos_l > 0.0 {
            self.materials[self.tri_material[tri] as usize].ke
        } else {
            Vec3::ZERO
        };
        let pdf = l.pdf_area[tri] * dist2 / cos_l.abs();
        Some(LightSample {
            p,
            n,
            wi,
            dist,
            le,
            pdf,
        })
    }

    /// Solid-angle density with which `sample_light` from `x` picks the point `y` on triangle
    /// `prim` (0 if that triangle is not a light).
    #[inline]
    pub fn light_pdf(&self, x: Vec3, y: Vec3, prim: u32) -> f32 {
        let pa = self.lights.pdf_area[prim as usize];
        if pa == 0.0 {
            return 0.0;
        }
        let d = y - x;
        let dist2 = d.length_squared();
        let cos_l = self.tri_normal[prim as usize].dot(d).abs() / dist2.sqrt();
        if cos_l <= 1e-7 {
            return 0.0;
        }
        pa * dist2 / cos_l
    }
}

impl Lights {
    fn new(mesh: &Mesh) -> Result<Option<Lights>> {
        let mut tris = Vec::new();
        let mut power = Vec::new();
        for (t, &m) in mesh.tri_material.iter().enumerate() {
            let ke = mesh.materials[m as usize].ke;
            if ke.max_element() > 0.0 {
                tris.push(t as u32);
                // Luminance can be zero for a saturated colour; the max keeps it samplable.
                power.push(mesh.tri_area[t] * luminance(ke).max(ke.max_element() * 1e-3));
            }
        }
        if tris.is_empty() {
            return Ok(None);
        }
        let total: f64 = power.iter().map(|&p| p as f64).sum();
        let mut acc = 0.0f64;
        let mut cdf = Vec::with_capacity(power.len());
        let mut pdf_area = vec![0.0f32; mesh.triangles.len()];
        for (k, &p) in power.iter().enumerate() {
            acc += p as f64;
            cdf.push((acc / total) as f32);
            let t = tris[k] as usize;
            pdf_area[t] = ((p as f64 / total) / mesh.tri_area[t] as f64) as f32;
        }
        *cdf.last_mut().unwrap() = 1.0;
        Ok(Some(Lights {
            tris,
            cdf,
            pdf_area,
        }))
    }
}

/// The scene TOML, with errors on one line that name the line and quote it.
fn parse_scene_file(label: &str, text: &str) -> Result<SceneFile> {
    if text.trim().is_empty() {
        bail!("{label}: the file is empty");
    }
    toml::from_str(text).map_err(|e| {
        // toml's own message spans several lines (a snippet of the file); keep it to one.
        let msg = e.message().trim().replace('\n', " ");
        let Some(span) = e.span() else {
            return anyhow!("{label}: {msg}");
        };
        let line = line_at(text.as_bytes(), span.start);
        let quoted = quote(text.lines().nth(line - 1).unwrap_or(""));
        // A key missing from the top level is reported against the whole top-level table.
        if span.start == 0 && !quoted.starts_with('[') && msg.starts_with("missing field") {
            anyhow!("{label}: {msg} at the top level")
        } else if quoted.is_empty() {
            anyhow!("{label}: line {line}: {msg}")
        } else {
            anyhow!("{label}: line {line} ('{quoted}'): {msg}")
        }
    })
}

fn check_camera(label: &str, text: &str, f: &SceneFile) -> Result<(u32, u32, CameraPath)> {
    let line = |span: Range<usize>| line_at(text.as_bytes(), span.start);
    let [w, h] = *f.resolution.get_ref();
    let at = format!("{label}: line {}: resolution", line(f.resolution.span()));
    if w == 0 || h == 0 {
        bail!("{at} {w}x{h}: width and height must be positive");
    }
    if w as u64 * h as u64 > MAX_PIXELS {
        bail!("{at} {w}x{h}: more than {MAX_PIXELS} pixels");
    }
    let frames = *f.frames.get_ref();
    let at = format!("{label}: line {}: frames = {frames}", line(f.frames.span()));
    if frames == 0 {
        bail!("{at}: a scene needs at least one frame");
    }
    if frames > MAX_FRAMES {
        bail!("{at}: at most {MAX_FRAMES}");
    }
    if f.keyframe.is_empty() {
        bail!("{label}: no [[keyframe]]: the camera path needs at least one");
    }
    let mut keys = Vec::new();
    let mut key_line = Vec::new();
    for (i, k) in f.keyframe.iter().enumerate() {
        let frame = *k.frame.get_ref();
        let at = |span: Range<usize>| format!("{label}: line {}: keyframe {}", line(span), i + 1);
        if i == 0 && frame != 0 {
            bail!(
                "{}: the first keyframe must be at frame 0, not {frame}",
                at(k.frame.span())
            );
        }
        if i > 0 && frame <= *f.keyframe[i - 1].frame.get_ref() {
            bail!(
                "{}: frame {frame}: keyframe frames must increase strictly (the one before is at {})",
                at(k.frame.span()),
                f.keyframe[i - 1].frame.get_ref()
            );
        }
        if frame >= frames {
            bail!(
                "{}: frame {frame} is past the last frame ({})",
                at(k.frame.span()),
                frames - 1
            );
        }
        for (key, v) in [
            ("position", &k.position),
            ("look_at", &k.look_at),
            ("up", &k.up),
        ] {
            let c = v.get_ref();
            if !c.iter().all(|c| c.is_finite()) {
                bail!("{}: {key} {c:?} is not finite", at(v.span()));
            }
            if c.iter().any(|c| c.abs() > MAX_COORD) {
                bail!(
                    "{}: {key} {c:?} is too large (at most {MAX_COORD:e})",
                    at(v.span())
                );
            }
        }
        let fov = *k.fov.get_ref();
        if !(fov > 0.0 && fov < 180.0) {
            bail!(
                "{}: fov {fov} must be in (0, 180) degrees",
                at(k.fov.span())
            );
        }
        keys.push(Keyframe {
            frame,
            position: Vec3::from(*k.position.get_ref()),
            look_at: Vec3::from(*k.look_at.get_ref()),
            up: Vec3::from(*k.up.get_ref()),
            fov,
        });
        key_line.push(line(k.position.span()));
    }
    let path = CameraPath { keyframes: keys };
    // Interpolation can make a valid pair of keyframes degenerate in between: check every frame.
    for frame in 0..frames {
        let k = path.at(frame);
        let view = k.look_at - k.position;
        let fails = if view.length() <= 1e-6 {
            "look_at coincides with position".to_string()
        } else if k.up.normalize_or_zero() == Vec3::ZERO {
            "up has zero length".to_string()
        } else if view.normalize().cross(k.up.normalize()).length() <= 1e-4 {
            format!("up {} is parallel to the view direction", k.up)
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
    Ok((w, h, path))
}

/// Triangle soup with per-triangle materials, as loaded from OBJ/MTL and checked.
struct Mesh {
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
    triangles: Vec<[u32; 3]>,
    tri_material: Vec<u32>,
    tri_normal: Vec<Vec3>,
    tri_area: Vec<f32>,
    materials: Vec<Material>,
    material_names: Vec<String>,
}

/// Where triangle `k` (1-based, in tobj's order) is: its OBJ line, quoted.
fn triangle_at(text: &str, lines: &text::ObjLines, k: usize) -> String {
    match lines.tri_line.get(k - 1) {
        Some(&l) => format!(
            "line {l}: '{}'",
            quote(text.lines().nth(l - 1).unwrap_or(""))
        ),
        None => format!("triangle {k}"),
    }
}

/// One MTL file as the material loader read it: its name in messages, the line of each material.
struct MtlFile {
    label: String,
    newmtl: HashMap<String, usize>,
}

/// Read and check the MTL file `p` that the OBJ line `at` names; its text, for tobj.
fn read_mtl(
    p: &Path,
    dir: Option<&Path>,
    builtin: Option<&str>,
    at: &str,
) -> Result<(MtlFile, String)> {
    let (label, bytes) = match (builtin, dir) {
        (Some(m), _) => (format!("{} (built in)", p.display()), m.as_bytes().to_vec()),
        (None, Some(dir)) => {
            let path = dir.join(p);
            let bytes = std::fs::read(&path)
                .map_err(|e| anyhow!("{at}: cannot read '{}': {e}", path.display()))?;
            (path.display().to_string(), bytes)
        }
        (None, None) => unreachable!("a scene has either files or built-in text"),
    };
    let text = as_text(&bytes).map_err(|e| anyhow!("{label}: {e}"))?;
    // tobj 4.0.5 panics on a colour with fewer than three numbers: check first.
    let newmtl = text::check_mtl(text).map_err(|e| anyhow!("{label}: {e}"))?;
    Ok((MtlFile { label, newmtl }, text.to_string()))
}

/// Load and check the OBJ and the MTL files it names. Also returns a warning, to be printed
/// once the whole scene has loaded.
fn load_obj(
    label: &str,
    bytes: &[u8],
    mtl_dir: Option<&Path>,
    builtin_mtl: Option<&str>,
) -> Result<(Mesh, Option<String>)> {
    let text = as_text(bytes).map_err(|e| anyhow!("{label}: {e}"))?;
    let lines = text::check_obj(text).map_err(|e| anyhow!("{label}: {e}"))?;
    let opts = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ignore_points: true,
        ignore_lines: true,
    };
    // tobj keeps only an error kind from the material loader: keep the message here.
    let mtl_files: RefCell<Vec<MtlFile>> = Default::default();
    let mtl_error: RefCell<Option<anyhow::Error>> = Default::default();
    let loaded = tobj::load_obj_buf(&mut text.as_bytes(), &opts, |p| {
        let call = mtl_files.borrow().len();
        let at = format!(
            "{label}: line {}: mtllib '{}'",
            lines.mtllib.get(call).copied().unwrap_or(0),
            p.display()
        );
        let read = read_mtl(p, mtl_dir, builtin_mtl, &at).and_then(|(file, text)| {
            let mats = tobj::load_mtl_buf(&mut text.as_bytes())
                .map_err(|e| anyhow!("{}: {e}", file.label))?;
            Ok((file, mats))
        });
        match read {
            Ok((file, mats)) => {
                mtl_files.borrow_mut().push(file);
                Ok(mats)
            }
            Err(e) => {
                mtl_error.borrow_mut().get_or_insert(e);
                Err(tobj::LoadError::MaterialParseError)
            }
        }
    });
    if let Some(e) = mtl_error.into_inner() {
        return Err(e);
    }
    // The checks above accept only what tobj reads: an error here is a gap in them.
    let (models, materials) = loaded.map_err(|e| anyhow!("{label}: {e}"))?;
    let tmats = materials.map_err(|e| anyhow!("{label}: materials: {e}"))?;
    let files = mtl_files.into_inner();

    // tobj gives faces after an unknown `usemtl` no material; say which line names it.
    for (n, name) in &lines.usemtl {
        let above: Vec<&MtlFile> = files
            .iter()
            .zip(&lines.mtllib)
            .filter(|(_, &l)| l < *n)
            .map(|(f, _)| f)
            .collect();
        if !above.iter().any(|f| f.newmtl.contains_key(name)) {
            let why = if above.is_empty() {
                "no mtllib above this line".to_string()
            } else {
                let names: Vec<&str> = above.iter().map(|f| f.label.as_str()).collect();
                format!("no such material in {}", names.join(", "))
            };
            bail!("{label}: line {n}: 'usemtl {}': {why}", quote(name));
        }
    }

    let mut mats = Vec::new();
    let mut names = Vec::new();
    for m in &tmats {
        let kd = Vec3::from(m.diffuse.unwrap_or([0.0; 3]));
        let ks = Vec3::from(m.specular.unwrap_or([0.0; 3]));
        let ke = Vec3::from(m.emissive.unwrap_or([0.0; 3]));
        let ns = m.shininess.unwrap_or(0.0);
        let defined = files
            .iter()
            .rev()
            .find_map(|f| {
                f.newmtl
                    .get(&m.name)
                    .map(|l| format!("{}: line {l}", f.label))
            })
            .unwrap_or_else(|| label.to_string());
        let at = format!("{defined}: material '{}'", m.name);
        for (key, v) in [("Kd", kd), ("Ks", ks), ("Ke", ke)] {
            if !v.is_finite() || v.min_element() < 0.0 {
                bail!("{at}: {key} {v} must be finite and non-negative");
            }
        }
        if !ns.is_finite() || ns < 0.0 {
            bail!("{at}: Ns {ns} must be finite and non-negative");
        }
        if (kd + ks).max_element() > 1.0 + 1e-6 {
            bail!(
                "{at}: Kd + Ks = {} exceeds 1 (the Phong model must conserve energy)",
                kd + ks
            );
        }
        mats.push(Material { kd, ks, ns, ke });
        names.push(m.name.clone());
    }
    let default_material = mats.len() as u32;
    let mut need_default = false;

    let mut mesh = Mesh {
        positions: Vec::new(),
        normals: Vec::new(),
        triangles: Vec::new(),
        tri_material: Vec::new(),
        tri_normal: Vec::new(),
        tri_area: Vec::new(),
        materials: Vec::new(),
        material_names: Vec::new(),
    };
    // Smooth shading, object by object: an object with a normal at every vertex is shaded with
    // them; one without (tobj leaves out the normals of face vertices given without one, so a
    // partial set cannot be aligned with the vertices) gets zero normals, which `surface` reads
    // as "use the face normal". Scenes without any normals keep the array empty.
    let smooth = |m: &tobj::Mesh| !m.normals.is_empty() && m.normals.len() == m.positions.len();
    let any_smooth = models.iter().any(|m| smooth(&m.mesh));
    let mut face = 0usize;
    for model in &models {
        let m = &model.mesh;
        let base = mesh.positions.len() as u32;
        let nv = m.positions.len() / 3;
        for (i, c) in m.positions.chunks_exact(3).enumerate() {
            let v = Vec3::new(c[0], c[1], c[2]);
            if !v.is_finite() {
                bail!(
                    "{label}: object '{}': vertex {} is not finite ({v})",
                    model.name,
                    i + 1
                );
            }
            mesh.positions.push(v);
        }
        if any_smooth && !smooth(m) {
            mesh.normals.extend(std::iter::repeat_n(Vec3::ZERO, nv));
        } else if any_smooth {
            for (i, c) in m.normals.chunks_exact(3).enumerate() {
                let n = Vec3::new(c[0], c[1], c[2]);
                if !n.is_finite() || n.length() < 1e-12 {
                    bail!(
                        "{label}: object '{}': normal {} is zero or not finite ({n})",
                        model.name,
                        i + 1
                    );
                }
                mesh.normals.push(n.normalize());
            }
        }
        let mat = match m.material_id {
            Some(id) if id < mats.len() => id as u32,
            Some(id) => bail!(
                "{label}: object '{}': material index {id} out of range",
                model.name
            ),
            None => {
                need_default = true;
                default_material
            }
        };
        for t in m.indices.chunks_exact(3) {
            face += 1;
            // Only on error: the OBJ line of this triangle, quoted.
            let at = || triangle_at(text, &lines, face);
            if let Some(&bad) = t.iter().find(|&&i| i as usize >= nv) {
                bail!(
                    "{label}: {}: vertex index {} out of range (1..{nv})",
                    at(),
                    bad as usize + 1
                );
            }
            let tri = [base + t[0], base + t[1], base + t[2]];
            let (a, b, c) = (
                mesh.positions[tri[0] as usize],
                mesh.positions[tri[1] as usize],
                mesh.positions[tri[2] as usize],
            );
            let cr = (b - a).cross(c - a);
            let len = cr.length();
            let scale = (b - a).length_squared().max((c - a).length_squared());
            if !len.is_finite() || len <= 1e-7 * scale {
                bail!("{label}: {}: zero-area triangle", at());
            }
            mesh.triangles.push(tri);
            mesh.tri_material.push(mat);
            mesh.tri_normal.push(cr / len);
            mesh.tri_area.push(0.5 * len);
        }
    }
    if mesh.triangles.is_empty() {
        bail!("{label}: no faces");
    }
    let mut warning = None;
    if need_default {
        warning = Some(format!(
            "{label}: faces without a material (before any usemtl) get a grey diffuse one (Kd 0.5)"
        ));
        mats.push(Material {
            kd: Vec3::splat(0.5),
            ..Default::default()
        });
        names.push("default".into());
    }
    mesh.materials = mats;
    mesh.material_names = names;
    Ok((mesh, warning))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_scenes_load() {
        let d = Device::new().unwrap();
        for name in builtin_names() {
            let s = Scene::load(name, &d).unwrap_or_else(|e| panic!("{name}: {e:#}"));
            assert!(s.frames >= 1 && !s.lights.tris.is_empty(), "{name}");
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
            let ls = s.sample_light(x, sm.next_1d(), sm.next_2d()).unwrap();
            let hit = s.geometry.intersect1(&crate::embree::Ray::new(x, ls.wi));
            let Some(h) = hit else { continue };
            if (h.t - ls.dist).abs() < 1e-3 {
                let pdf = s.light_pdf(x, ls.p, h.prim_id);
                assert!((pdf / ls.pdf - 1.0).abs() < 1e-3, "{pdf} vs {}", ls.pdf);
            }
        }
    }
}
