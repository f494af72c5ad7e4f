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
//! fails with a one-line error naming the file and the offending key, face or vertex.
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
use std::path::{Path, PathBuf};

/// The scenes shipped in `scenes/`, compiled into the binary: (name, toml, obj, mtl).
const BUILTIN: &[(&str, &str, &str, &str)] = &[
    (
        "vase",
        include_str!("../scenes/vase.toml"),
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
    obj: String,
    frames: u32,
    resolution: [u32; 2],
    keyframe: Vec<KeyframeFile>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct KeyframeFile {
    frame: u32,
    position: [f32; 3],
    look_at: [f32; 3],
    up: [f32; 3],
    fov: f32,
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
        let (label, toml_text) = match &source {
            Source::Files { toml } => (
                toml.display().to_string(),
                std::fs::read_to_string(toml)
                    .with_context(|| format!("{}: cannot read", toml.display()))?,
            ),
            Source::Builtin(i) => (
                format!("{} (built in)", BUILTIN[*i].0),
                BUILTIN[*i].1.to_string(),
            ),
        };
        let file: SceneFile = toml::from_str(&toml_text).map_err(|e| {
            // toml's message spans several lines (a snippet of the file); keep it to one line.
            let msg = e.message().to_string();
            match e.span() {
                Some(span) => {
                    let line = toml_text[..span.start].matches('\n').count() + 1;
                    anyhow!("{label}: line {line}: {msg}")
                }
                None => anyhow!("{label}: {msg}"),
            }
        })?;
        let name = match &source {
            Source::Files { toml } => toml
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default(),
            Source::Builtin(i) => BUILTIN[*i].0.to_string(),
        };
        let (width, height, path) = check_camera(&label, &file)?;
        let (obj_label, obj_text, mtl_dir) = match &source {
            Source::Files { toml } => {
                let dir = toml.parent().unwrap_or(Path::new(".")).to_path_buf();
                let obj = dir.join(&file.obj);
                let text = std::fs::read(&obj)
                    .with_context(|| format!("{label}: obj '{}': cannot read", obj.display()))?;
                (
                    obj.display().to_string(),
                    text,
                    Some(obj.parent().unwrap_or(&dir).to_path_buf()),
                )
            }
            Source::Builtin(i) => (
                format!("{} (built in)", file.obj),
                BUILTIN[*i].2.as_bytes().to_vec(),
                None,
            ),
        };
        let builtin_mtl = match &source {
            Source::Builtin(i) => Some(BUILTIN[*i].3),
            Source::Files { .. } => None,
        };
        let mesh = load_obj(&obj_label, &obj_text, mtl_dir.as_deref(), builtin_mtl)?;
        let geometry = TriangleScene::new(device, &mesh.positions, &mesh.triangles)
            .with_context(|| format!("{obj_label}: building the Embree scene"))?;
        let lights = Lights::new(&mesh)?.ok_or_else(|| {
            anyhow!("{obj_label}: the scene has no lights (no material with a positive Ke)")
        })?;
        Ok(Scene {
            name,
            frames: file.frames,
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

fn check_camera(label: &str, f: &SceneFile) -> Result<(u32, u32, CameraPath)> {
    let [w, h] = f.resolution;
    if w == 0 || h == 0 {
        bail!("{label}: resolution {w}x{h}: width and height must be positive");
    }
    if f.frames == 0 {
        bail!("{label}: frames = 0: a scene needs at least one frame");
    }
    if f.keyframe.is_empty() {
        bail!("{label}: no [[keyframe]]: the camera path needs at least one");
    }
    if f.keyframe[0].frame != 0 {
        bail!(
            "{label}: keyframe 1: the first keyframe must be at frame 0, not {}",
            f.keyframe[0].frame
        );
    }
    let mut keys = Vec::new();
    for (i, k) in f.keyframe.iter().enumerate() {
        let at = format!("{label}: keyframe {} (frame {})", i + 1, k.frame);
        if i > 0 && k.frame <= f.keyframe[i - 1].frame {
            bail!("{at}: keyframe frames must increase strictly");
        }
        if k.frame >= f.frames {
            bail!("{at}: frame is past the last frame ({})", f.frames - 1);
        }
        for (key, v) in [
            ("position", k.position),
            ("look_at", k.look_at),
            ("up", k.up),
        ] {
            if !v.iter().all(|c| c.is_finite()) {
                bail!("{at}: {key} {v:?} is not finite");
            }
        }
        if !(k.fov > 0.0 && k.fov < 180.0) {
            bail!("{at}: fov {} must be in (0, 180) degrees", k.fov);
        }
        keys.push(Keyframe {
            frame: k.frame,
            position: Vec3::from(k.position),
            look_at: Vec3::from(k.look_at),
            up: Vec3::from(k.up),
            fov: k.fov,
        });
    }
    let path = CameraPath { keyframes: keys };
    // Interpolation can make a valid pair of keyframes degenerate in between: check every frame.
    for frame in 0..f.frames {
        let k = path.at(frame);
        let view = k.look_at - k.position;
        if view.length() <= 1e-6 {
            bail!("{label}: frame {frame}: look_at coincides with position");
        }
        if view.normalize().cross(k.up).length() <= 1e-4 {
            bail!(
                "{label}: frame {frame}: up {} is parallel to the view direction",
                k.up
            );
        }
    }
    Ok((w, h, path))
}

/// The MTL statements reframe reads must carry numbers: colours three, exponents one.
fn check_mtl(text: &str) -> Result<()> {
    for (i, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        let Some(key) = words.next() else { continue };
        let want = match key {
            "Ka" | "Kd" | "Ks" | "Ke" => 3,
            "Ns" => 1,
            _ => continue,
        };
        let nums: Vec<&str> = words.collect();
        if nums.len() < want || nums[..want].iter().any(|w| w.parse::<f32>().is_err()) {
            let shape = if want == 3 {
                format!("'{key} r g b'")
            } else {
                format!("'{key} value'")
            };
            bail!("line {}: '{}': expected {shape}", i + 1, line.trim());
        }
    }
    Ok(())
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

fn load_obj(
    label: &str,
    text: &[u8],
    mtl_dir: Option<&Path>,
    builtin_mtl: Option<&str>,
) -> Result<Mesh> {
    let opts = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ignore_points: true,
        ignore_lines: true,
    };
    let mtl_error: std::cell::RefCell<Option<String>> = Default::default();
    let mut reader = std::io::BufReader::new(text);
    let (models, materials) = tobj::load_obj_buf(&mut reader, &opts, |p| {
        let (name, text) = match (builtin_mtl, mtl_dir) {
            (Some(m), _) => (p.display().to_string(), m.to_string()),
            (None, Some(dir)) => {
                let path = dir.join(p);
                match std::fs::read_to_string(&path) {
                    Ok(t) => (path.display().to_string(), t),
                    Err(e) => {
                        *mtl_error.borrow_mut() = Some(format!("mtl '{}': {e}", path.display()));
                        return Err(tobj::LoadError::OpenFileFailed);
                    }
                }
            }
            (None, None) => unreachable!("a scene has either files or built-in text"),
        };
        // tobj 4.0.5 panics on a colour with fewer than three numbers: check first.
        if let Err(e) = check_mtl(&text) {
            *mtl_error.borrow_mut() = Some(format!("mtl '{name}': {e}"));
            return Err(tobj::LoadError::MaterialParseError);
        }
        let result = tobj::load_mtl_buf(&mut std::io::BufReader::new(text.as_bytes()));
        if let Err(e) = &result {
            *mtl_error.borrow_mut() = Some(format!("mtl '{name}': {e}"));
        }
        result
    })
    .map_err(|e| anyhow!("{label}: {e}"))?;
    if let Some(e) = mtl_error.into_inner() {
        bail!("{label}: {e}");
    }
    let tmats = materials.map_err(|e| anyhow!("{label}: materials: {e}"))?;

    let mut mats = Vec::new();
    let mut names = Vec::new();
    for m in &tmats {
        let kd = Vec3::from(m.diffuse.unwrap_or([0.0; 3]));
        let ks = Vec3::from(m.specular.unwrap_or([0.0; 3]));
        let ke = Vec3::from(m.emissive.unwrap_or([0.0; 3]));
        let ns = m.shininess.unwrap_or(0.0);
        let at = format!("{label}: material '{}'", m.name);
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
    let all_have_normals = models.iter().all(|m| !m.mesh.normals.is_empty());
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
        if all_have_normals {
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
            if let Some(&bad) = t.iter().find(|&&i| i as usize >= nv) {
                bail!(
                    "{label}: face {face}: vertex index {} out of range (1..{nv})",
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
            if len.is_nan() || len <= 1e-7 * scale {
                bail!(
                    "{label}: face {face} (object '{}'): zero-area triangle",
                    model.name
                );
            }
            mesh.triangles.push(tri);
            mesh.tri_material.push(mat);
            mesh.tri_normal.push(cr / len);
            mesh.tri_area.push(0.5 * len);
        }
    }
    if mesh.triangles.is_empty() {
        bail!("{label}: no triangles");
    }
    if need_default {
        eprintln!("warning: {label}: faces without a material get a grey diffuse one (Kd 0.5)");
        mats.push(Material {
            kd: Vec3::splat(0.5),
            ..Default::default()
        });
        names.push("default".into());
    }
    mesh.materials = mats;
    mesh.material_names = names;
    Ok(mesh)
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
