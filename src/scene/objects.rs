//! Several objects in one scene: the `[[object]]` tables of a scene TOML, each an OBJ placed by
//! a transform, and what they become for tracing: one mesh of the scene's own (every object
//! placed once, and every copy of an emitting one, transformed into world space) and prototypes
//! placed by Embree instances (an OBJ placed more than once is built once).
//!
//! ```toml
//! [[object]]
//! obj = "crate.obj"
//! translate = [1.0, 0.0, -2.0]
//! rotate = [0.0, 30.0, 0.0]   # degrees about X, then Y, then Z (R = Rz Ry Rx)
//! scale = 0.8                 # one number, or [sx, sy, sz]
//! [[object]]
//! obj = "crate.obj"
//! matrix = [1, 0, 0, 3,  0, 1, 0, 0,  0, 0, 1, -4,  0, 0, 0, 1]   # instead of the three above
//! ```
//!
//! The transform is `T R S` (scale, then rotate, then translate), or `matrix`, row-major with
//! the translation in the last column (object to world). Emitting objects are copied, not
//! instanced, because light sampling picks points of the lights in world space.
use super::maps::Maps;
use super::mesh::Mesh;
use super::text::{past_max_coord, quote_name, Lines, MAX_COORD, MAX_DEGREES};
use anyhow::{bail, Result};
use glam::{DMat3, DMat4, DVec3, Mat3, Mat4, Vec2, Vec3};
use serde::Deserialize;
use toml::Spanned;

/// `[[object]]`: an OBJ and its placement.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectFile {
    pub obj: Spanned<String>,
    translate: Option<Spanned<[f64; 3]>>,
    rotate: Option<Spanned<[f64; 3]>>,
    scale: Option<Spanned<Scale>>,
    matrix: Option<Spanned<Matrix>>,
}

/// `matrix`: 16 numbers, row by row, or 4 rows of 4 (as a camera file's JSON may give it).
#[derive(Deserialize)]
#[serde(
    untagged,
    expecting = "expected matrix as 16 numbers, row by row, or as 4 rows of 4 numbers"
)]
enum Matrix {
    Flat(Vec<f64>),
    Rows(Vec<Vec<f64>>),
}

#[derive(Deserialize)]
#[serde(
    untagged,
    expecting = "expected scale as one number (uniform) or three ([sx, sy, sz])"
)]
enum Scale {
    Uniform(f64),
    Axes([f64; 3]),
}

impl ObjectFile {
    /// The object-to-world transform, checked: finite, within `MAX_COORD`, invertible (a
    /// volume of its unit-scaled axes above 1e-9: a flattened object has no inside to shade).
    /// `label` and `lines` are the scene file's, for the line in errors.
    pub fn transform(&self, label: &str, lines: &Lines) -> Result<DMat4> {
        let line = |start: usize| lines.at(start);
        let at = format!(
            "{label}: line {}: object '{}'",
            line(self.obj.span().start),
            quote_name(self.obj.get_ref())
        );
        let m = if let Some(m) = &self.matrix {
            if self.translate.is_some() || self.rotate.is_some() || self.scale.is_some() {
                bail!("{at}: give either matrix or translate/rotate/scale, not both");
            }
            let v: Vec<f64> = match m.get_ref() {
                Matrix::Flat(v) => v.clone(),
                Matrix::Rows(rows) if rows.len() == 4 && rows.iter().all(|r| r.len() == 4) => {
                    rows.concat()
                }
                Matrix::Rows(rows) => {
                    let sizes: Vec<String> = rows.iter().map(|r| r.len().to_string()).collect();
                    bail!(
                        "{at}: matrix has {} rows of {} numbers, not 4 rows of 4",
                        rows.len(),
                        sizes.join(", ")
                    );
                }
            };
            if v.len() != 16 {
                bail!("{at}: matrix has {} numbers, not 16", v.len());
            }
            if !v.iter().all(|x| x.is_finite()) {
                bail!("{at}: matrix has a number that is not finite");
            }
            if v[12..] != [0.0, 0.0, 0.0, 1.0] {
                bail!("{at}: matrix's bottom row is not 0 0 0 1 (no projective transforms)");
            }
            DMat4::from_cols_array(&[
                v[0], v[4], v[8], v[12], v[1], v[5], v[9], v[13], v[2], v[6], v[10], v[14], v[3],
                v[7], v[11], v[15],
            ])
        } else {
            let t = self.translate.as_ref().map_or([0.0; 3], |t| *t.get_ref());
            let r = self.rotate.as_ref().map_or([0.0; 3], |r| *r.get_ref());
            let s = match self.scale.as_ref().map(|s| s.get_ref()) {
                None => [1.0; 3],
                Some(Scale::Uniform(s)) => [*s; 3],
                Some(Scale::Axes(s)) => *s,
            };
            if !t.iter().chain(&r).chain(&s).all(|x| x.is_finite()) {
                bail!("{at}: translate, rotate and scale must be finite");
            }
            // As the environment's rotation: past a million degrees an angle's sine and cosine
            // keep few correct digits.
            if let Some(a) = r.iter().find(|a| a.abs() > MAX_DEGREES) {
                bail!("{at}: rotate {a:e}: at most {MAX_DEGREES:e} degrees in magnitude");
            }
            if s.contains(&0.0) {
                bail!("{at}: scale has a zero (the object would be flat)");
            }
            let [rx, ry, rz] = r.map(f64::to_radians);
            let rot = DMat3::from_rotation_z(rz)
                * DMat3::from_rotation_y(ry)
                * DMat3::from_rotation_x(rx);
            DMat4::from_translation(DVec3::from(t))
                * DMat4::from_mat3(rot)
                * DMat4::from_scale(DVec3::from(s))
        };
        if m.to_cols_array().into_iter().any(past_max_coord) {
            bail!("{at}: a transform entry is over {MAX_COORD:e}");
        }
        let a = DMat3::from_mat4(m);
        for axis in [a.x_axis, a.y_axis, a.z_axis] {
            // Scaled to its largest entry first: the squares of 1e-300 underflow, and its
            // length was said as 0e0, not as the value written.
            let big = axis.abs().max_element();
            let l = if big > 0.0 {
                big * (axis / big).length()
            } else {
                0.0
            };
            if !(1e-6..=1e6).contains(&l) {
                bail!(
                    "{at}: the transform scales an axis by {l:e} (at most 1e6 and at least 1e-6)"
                );
            }
        }
        let unit = |c: DVec3| c.normalize_or_zero();
        let volume = unit(a.x_axis)
            .cross(unit(a.y_axis))
            .dot(unit(a.z_axis))
            .abs();
        if volume.is_nan() || volume <= 1e-9 {
            bail!("{at}: the transform is singular (it flattens the object)");
        }
        Ok(m)
    }
}

/// A mesh as Embree's instances place it: in its object space, its materials indexed into the
/// scene's.
pub struct Prototype {
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    pub uvs: Vec<Vec2>,
    pub triangles: Vec<[u32; 3]>,
    pub tri_material: Vec<u32>,
    pub tri_normal: Vec<Vec3>,
}

/// One placement of a prototype.
#[derive(Clone, Copy, Debug)]
pub struct Instance {
    pub proto: u32,
    /// Object to world, as Embree applies it.
    pub to_world: Mat4,
    /// Normals to world: the inverse transpose of the linear part, times the sign of its
    /// determinant (a mirrored placement turns the counter-clockwise side over).
    pub normal: Mat3,
}

impl Instance {
    pub fn new(proto: u32, m: &DMat4) -> Instance {
        let a = DMat3::from_mat4(*m);
        let n = a.inverse().transpose() * a.determinant().signum();
        Instance {
            proto,
            to_world: m.as_mat4(),
            normal: n.as_mat3(),
        }
    }

    /// The transform as `TriangleScene::build` takes it: 3x4, row-major.
    pub fn rows(&self) -> [f32; 12] {
        let c = self.to_world.to_cols_array_2d();
        std::array::from_fn(|k| c[k % 4][k / 4])
    }
}

/// `mesh` placed by `m`: positions through `m`, normals through its inverse transpose (zero
/// stays zero), each triangle's normal and area again from its placed corners.
pub fn transformed(mesh: &Mesh, m: &DMat4) -> Mesh {
    let a = DMat3::from_mat4(*m);
    let n = a.inverse().transpose();
    let positions: Vec<Vec3> = mesh
        .positions
        .iter()
        .map(|p| m.transform_point3(p.as_dvec3()).as_vec3())
        .collect();
    let normals = mesh
        .normals
        .iter()
        .map(|v| (n * v.as_dvec3()).normalize_or_zero().as_vec3())
        .collect();
    let (tri_normal, tri_area) = mesh
        .triangles
        .iter()
        .map(|t| {
            let [p0, p1, p2] = t.map(|i| positions[i as usize]);
            // As the OBJ reader measures them, in f64 where f32 overflows (a placed floor 1e10
            // wide had lost its normal and its area: black, or its light gone).
            let (n, len, _) = super::mesh::measure(p0, p1, p2);
            (n, 0.5 * len)
        })
        .unzip();
    Mesh {
        positions,
        normals,
        uvs: mesh.uvs.clone(),
        triangles: mesh.triangles.clone(),
        tri_material: mesh.tri_material.clone(),
        tri_normal,
        tri_area,
        materials: mesh.materials.clone(),
        maps: mesh.maps.clone(),
        material_names: mesh.material_names.clone(),
    }
}

/// Add `materials` of a mesh (with their maps and names) to `into`'s; the index of the first.
pub fn add_materials(into: &mut Mesh, from: &Mesh) -> u32 {
    let base = into.materials.len() as u32;
    if !from.maps.is_empty() || !into.maps.is_empty() {
        into.maps.resize(into.materials.len(), Maps::default());
        if from.maps.is_empty() {
            into.maps
                .extend(std::iter::repeat_n(Maps::default(), from.materials.len()));
        } else {
            into.maps.extend_from_slice(&from.maps);
        }
    }
    into.materials.extend_from_slice(&from.materials);
    into.material_names.extend_from_slice(&from.material_names);
    base
}

/// Append `mesh` to `into`: its vertices, triangles and materials after `into`'s.
pub fn append(into: &mut Mesh, mesh: Mesh) {
    let base_v = into.positions.len() as u32;
    let base_m = add_materials(into, &mesh);
    let nv = mesh.positions.len();
    // Normals and texture coordinates: one per vertex where any mesh has them (zero elsewhere).
    extend_per_vertex(&mut into.normals, &mesh.normals, base_v as usize, nv);
    extend_per_vertex(&mut into.uvs, &mesh.uvs, base_v as usize, nv);
    into.positions.extend(mesh.positions);
    into.triangles
        .extend(mesh.triangles.iter().map(|t| t.map(|i| i + base_v)));
    into.tri_material
        .extend(mesh.tri_material.iter().map(|m| m + base_m));
    into.tri_normal.extend(mesh.tri_normal);
    into.tri_area.extend(mesh.tri_area);
}

/// Per-vertex values `own` of `n` vertices after `had` vertices' `all`: either may be empty
/// (none given), the other's vertices are then zero.
fn extend_per_vertex<T: Copy + Default>(all: &mut Vec<T>, own: &[T], had: usize, n: usize) {
    if own.is_empty() && all.is_empty() {
        return;
    }
    all.resize(had, T::default());
    if own.is_empty() {
        all.resize(had + n, T::default());
    } else {
        all.extend_from_slice(own);
    }
}

/// `mesh` as a prototype whose materials start at `base_material` of the scene's.
pub fn prototype(mesh: Mesh, base_material: u32) -> Prototype {
    Prototype {
        positions: mesh.positions,
        normals: mesh.normals,
        uvs: mesh.uvs,
        tri_material: mesh
            .tri_material
            .iter()
            .map(|m| m + base_material)
            .collect(),
        triangles: mesh.triangles,
        tri_normal: mesh.tri_normal,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn transforms_compose_scale_rotation_translation() {
        let parse = |s: &str| -> Result<DMat4> {
            let text = format!("obj = \"a.obj\"\n{s}\n");
            let o: ObjectFile = toml::from_str(&text).unwrap();
            o.transform("s.toml", &Lines::new(text.as_bytes()))
        };
        // Scale x by 2, turn 90 degrees about Y (x -> -z), move up 1.
        let m = parse("scale = [2.0, 1.0, 1.0]\nrotate = [0.0, 90.0, 0.0]\ntranslate = [0, 1, 0]")
            .unwrap();
        let p = m.transform_point3(DVec3::X);
        assert!((p - DVec3::new(0.0, 1.0, -2.0)).length() < 1e-12, "{p}");
        // Rotations apply about X first, then Y, then Z.
        let m = parse("rotate = [90.0, 0.0, 90.0]").unwrap();
        let p = m.transform_point3(DVec3::Y); // X: y -> z; Z leaves z.
        assert!((p - DVec3::Z).length() < 1e-12, "{p}");
        let m = parse("matrix = [1, 0, 0, 3,  0, 1, 0, 0,  0, 0, 1, -4,  0, 0, 0, 1]").unwrap();
        assert_eq!(m.transform_point3(DVec3::ZERO), DVec3::new(3.0, 0.0, -4.0));
        // Or 4 rows of 4, the same matrix (it was refused: "invalid type: sequence").
        let rows = parse("matrix = [[1, 0, 0, 3], [0, 1, 0, 0], [0, 0, 1, -4], [0, 0, 0, 1]]");
        assert_eq!(rows.unwrap(), m);
        for (bad, want) in [
            ("scale = 0.0", "scale has a zero"),
            ("matrix = [1, 0, 0, 0]", "matrix has 4 numbers, not 16"),
            (
                "matrix = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]",
                "matrix has 3 rows of 3, 3, 3 numbers, not 4 rows of 4",
            ),
            (
                "matrix = [1, 0, 0, 0,  0, 1, 0, 0,  0, 0, 1, 0,  0, 0, 1, 1]",
                "bottom row is not 0 0 0 1",
            ),
            (
                "matrix = [1, 1, 0, 0,  0, 0, 0, 0,  0, 0, 1, 0,  0, 0, 0, 1]",
                "the transform is singular",
            ),
            (
                "scale = 2.0\nmatrix = [1, 0, 0, 0,  0, 1, 0, 0,  0, 0, 1, 0,  0, 0, 0, 1]",
                "either matrix or translate/rotate/scale",
            ),
            ("translate = [nan, 0, 0]", "must be finite"),
            ("scale = 1e7", "scales an axis by 1e7"),
            ("scale = [1, 1, 1e-300]", "scales an axis by 1e-300"),
            ("translate = [1e19, 0, 0]", "over 1e18"),
            (
                "rotate = [1e300, 0, 0]",
                "rotate 1e300: at most 1e6 degrees",
            ),
        ] {
            let e = parse(bad).unwrap_err().to_string();
            assert!(
                e.starts_with("s.toml: line 1: object 'a.obj': ") && e.contains(want),
                "{bad}: {e}"
            );
        }
    }

    #[test]
    fn instance_normals_follow_the_placed_winding() {
        // A mirror (x -> -x) turns the counter-clockwise side over: the placed triangle's
        // normal from its corners is what the instance's normal matrix gives.
        for m in [
            DMat4::from_scale(DVec3::new(-1.0, 2.0, 0.5)),
            DMat4::from_rotation_y(0.7) * DMat4::from_scale(DVec3::new(3.0, 1.0, 1.0)),
        ] {
            let i = Instance::new(0, &m);
            let p = [Vec3::ZERO, Vec3::X, Vec3::new(0.3, 1.0, 0.2)];
            let n_obj = (p[1] - p[0]).cross(p[2] - p[0]).normalize();
            let w = p.map(|q| m.transform_point3(q.as_dvec3()).as_vec3());
            let n_world = (w[1] - w[0]).cross(w[2] - w[0]).normalize();
            let n = (i.normal * n_obj).normalize();
            assert!((n - n_world).length() < 1e-5, "{n} vs {n_world}");
            let rows = i.rows();
            let t = m.transform_point3(DVec3::new(1.0, 2.0, 3.0));
            let by_rows = [0, 1, 2].map(|r| {
                rows[4 * r] + 2.0 * rows[4 * r + 1] + 3.0 * rows[4 * r + 2] + rows[4 * r + 3]
            });
            assert!((DVec3::from(by_rows.map(f64::from)) - t).length() < 1e-5);
        }
    }

    #[test]
    fn placed_triangles_of_any_size_keep_their_normal_and_area() {
        // Edges of 2e10, where the f32 cross product overflows, and of 2: the same shape.
        for half in [1e10f32, 1.0] {
            let mesh = Mesh {
                positions: vec![
                    Vec3::new(-half, 5.0, -half),
                    Vec3::new(half, 5.0, -half),
                    Vec3::new(half, 5.0, half),
                ],
                triangles: vec![[0, 2, 1]],
                tri_material: vec![0],
                ..Mesh::default()
            };
            let placed = transformed(&mesh, &DMat4::IDENTITY);
            assert!((placed.tri_normal[0] - Vec3::Y).length() < 1e-6, "{half}");
            let area = 2.0 * half as f64 * half as f64;
            assert!(
                (placed.tri_area[0] as f64 / area - 1.0).abs() < 1e-6,
                "{half}"
            );
        }
    }
}
