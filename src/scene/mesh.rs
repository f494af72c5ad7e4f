//! From an OBJ's faces to the triangles Embree traces: polygons ear-clipped on their own plane
//! (concave ones too), vertices shared where a face corner repeats a position and normal,
//! zero-area triangles skipped, and per-triangle geometry (unit normal, area) that the lights
//! and shading use.
//!
//! A polygon is projected onto the coordinate plane most parallel to it (the largest component
//! of its Newell normal, which is robust for non-planar and self-touching polygons) and
//! triangulated there by `earcutr` (Mapbox's ear clipping), which also copes with repeated
//! vertices; each triangle is then wound like the polygon, so that its front (the emitting side
//! of a light) stays where the OBJ put it.
use super::obj::{Corner, Obj};
use super::repairs::{Kind, Repairs};
use super::text::quote_line;
use crate::bsdf::Material;
use anyhow::{bail, Result};
use glam::{DVec3, Vec2, Vec3};
use std::collections::HashMap;

pub const DEGENERATE: Kind = Kind {
    one: "degenerate (zero-area) triangle skipped",
    many: "degenerate (zero-area) triangles skipped",
};
const FANNED: Kind = Kind {
    one: "polygon that ear clipping could not triangulate split as a fan",
    many: "polygons that ear clipping could not triangulate split as fans",
};

/// Triangle soup with per-triangle materials, as loaded from OBJ/MTL and checked.
pub struct Mesh {
    pub positions: Vec<Vec3>,
    /// Unit normal per vertex, zero where the triangles use their face normal; empty when no
    /// vertex has one.
    pub normals: Vec<Vec3>,
    /// Texture coordinates per vertex, zero where a corner has no `vt`; empty when no corner
    /// has one.
    pub uvs: Vec<Vec2>,
    pub triangles: Vec<[u32; 3]>,
    pub tri_material: Vec<u32>,
    pub tri_normal: Vec<Vec3>,
    pub tri_area: Vec<f32>,
    pub materials: Vec<Material>,
    /// The texture maps of each material; empty when no material has one.
    pub maps: Vec<super::maps::Maps>,
    pub material_names: Vec<String>,
}

/// The triangles of a polygon, as indices into `p` (its corners in order).
pub fn triangulate(p: &[Vec3]) -> Option<Vec<[usize; 3]>> {
    if p.len() == 3 {
        return Some(vec![[0, 1, 2]]);
    }
    let d: Vec<DVec3> = p.iter().map(|v| v.as_dvec3()).collect();
    // Newell's normal: twice the polygon's vector area.
    let mut n = DVec3::ZERO;
    for (i, a) in d.iter().enumerate() {
        let b = d[(i + 1) % d.len()];
        n += DVec3::new(
            (a.y - b.y) * (a.z + b.z),
            (a.z - b.z) * (a.x + b.x),
            (a.x - b.x) * (a.y + b.y),
        );
    }
    let a = n.abs();
    let (u, v) = if a.x >= a.y && a.x >= a.z {
        (1, 2)
    } else if a.y >= a.z {
        (2, 0)
    } else {
        (0, 1)
    };
    let flat: Vec<f64> = d.iter().flat_map(|q| [q[u], q[v]]).collect();
    let idx = earcutr::earcut(&flat, &[], 2).ok()?;
    if idx.is_empty() {
        return None;
    }
    Some(
        idx.chunks_exact(3)
            .map(|t| {
                // Wound like the polygon (earcut's own winding depends on the projection).
                let c = (d[t[1]] - d[t[0]]).cross(d[t[2]] - d[t[0]]);
                if c.dot(n) < 0.0 {
                    [t[0], t[2], t[1]]
                } else {
                    [t[0], t[1], t[2]]
                }
            })
            .collect(),
    )
}

/// The mesh of `obj`: `usemtl_material[k]` is the material of the faces after the k-th
/// `usemtl`, `default_material` that of faces before any. `bytes` is the OBJ text, for quoting.
pub fn build(
    label: &str,
    bytes: &[u8],
    obj: &Obj,
    usemtl_material: &[u32],
    default_material: u32,
    repairs: &mut Repairs,
) -> Result<Mesh> {
    let mut mesh = Mesh {
        positions: Vec::new(),
        normals: Vec::new(),
        uvs: Vec::new(),
        triangles: Vec::new(),
        tri_material: Vec::new(),
        tri_normal: Vec::new(),
        tri_area: Vec::new(),
        materials: Vec::new(),
        maps: Vec::new(),
        material_names: Vec::new(),
    };
    let any_smooth = obj.corners.iter().any(|c| c.vn.is_some());
    let any_uv = obj.corners.iter().any(|c| c.vt.is_some());
    // One vertex per distinct (position, normal, texture coordinate) of the faces; `u32::MAX`:
    // none.
    let mut vertex: HashMap<(u32, u32, u32), u32> = HashMap::new();
    let mut skipped = 0usize;
    let mut first_skipped = 0usize;
    let mut pts = Vec::new();
    for f in &obj.faces {
        let corners = &obj.corners[f.corners.clone()];
        // Smooth only if every corner has a usable normal: interpolating a normal with the face
        // normal of a neighbour would shade a seam.
        let smooth = corners.iter().all(|c| c.vn.is_some());
        let ids: Vec<u32> = corners
            .iter()
            .map(|&Corner { v, vt, vn }| {
                let n = if smooth { vn.unwrap() } else { u32::MAX };
                let key = (v, n, vt.unwrap_or(u32::MAX));
                *vertex.entry(key).or_insert_with(|| {
                    mesh.positions.push(obj.positions[v as usize]);
                    if any_smooth {
                        let n = key.1;
                        mesh.normals.push(if n == u32::MAX {
                            Vec3::ZERO
                        } else {
                            obj.normals[n as usize].unwrap()
                        });
                    }
                    if any_uv {
                        mesh.uvs
                            .push(vt.map_or(Vec2::ZERO, |t| obj.uvs[t as usize]));
                    }
                    mesh.positions.len() as u32 - 1
                })
            })
            .collect();
        pts.clear();
        pts.extend(ids.iter().map(|&i| mesh.positions[i as usize]));
        let tris = match triangulate(&pts) {
            Some(t) => t,
            None => {
                repairs.note(label, f.line, FANNED, || quote_line(bytes, f.line))?;
                (1..pts.len() - 1).map(|k| [0, k, k + 1]).collect()
            }
        };
        let mat = f
            .usemtl
            .map_or(default_material, |k| usemtl_material[k as usize]);
        for t in tris {
            let tri = t.map(|k| ids[k]);
            let [a, b, c] = t.map(|k| pts[k]);
            let cr = (b - a).cross(c - a);
            let len = cr.length();
            let scale = (b - a).length_squared().max((c - a).length_squared());
            // Corners may be up to the 1e18 the scene allows, where the f32 cross product's
            // length overflows (from edges of about 4e9 on: a floor 1e10 wide would be "zero
            // area"): such a triangle is measured in f64, whose normal and area fit f32.
            let (n, len, degenerate) = if len.is_finite() && scale.is_finite() {
                (cr / len, len, len <= 1e-7 * scale)
            } else {
                let [a, b, c] = [a, b, c].map(|p| p.as_dvec3());
                let cr = (b - a).cross(c - a);
                let len = cr.length();
                let scale = (b - a).length_squared().max((c - a).length_squared());
                let ok = len.is_finite() && len > 1e-7 * scale;
                ((cr / len).as_vec3(), len as f32, !ok)
            };
            if degenerate {
                skipped += 1;
                if first_skipped == 0 {
                    first_skipped = f.line;
                }
                repairs.note(label, f.line, DEGENERATE, || quote_line(bytes, f.line))?;
                continue;
            }
            mesh.triangles.push(tri);
            mesh.tri_material.push(mat);
            mesh.tri_normal.push(n);
            mesh.tri_area.push(0.5 * len);
        }
    }
    if mesh.triangles.is_empty() {
        if skipped > 0 {
            bail!(
                "{label}: no faces left: all {skipped} triangles are degenerate (zero-area; the \
                 first at line {first_skipped})"
            );
        }
        bail!("{label}: no faces");
    }
    Ok(mesh)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn area(p: &[Vec3], tris: &[[usize; 3]]) -> f32 {
        tris.iter()
            .map(|t| 0.5 * (p[t[1]] - p[t[0]]).cross(p[t[2]] - p[t[0]]).length())
            .sum()
    }

    #[test]
    fn concave_polygons_keep_their_area_and_winding() {
        // An L in the plane x = 1, wound so that its normal is +x.
        let l2 = [(0., 0.), (2., 0.), (2., 1.), (1., 1.), (1., 2.), (0., 2.)];
        let p: Vec<Vec3> = l2.iter().map(|&(y, z)| Vec3::new(1.0, y, z)).collect();
        let t = triangulate(&p).unwrap();
        assert_eq!(t.len(), 4);
        assert!((area(&p, &t) - 3.0).abs() < 1e-5);
        for t in &t {
            let n = (p[t[1]] - p[t[0]]).cross(p[t[2]] - p[t[0]]);
            assert!(n.x > 0.0, "{t:?}");
        }
        // Reversed, every triangle flips with it; a fan would have covered the notch.
        let r: Vec<Vec3> = p.iter().rev().copied().collect();
        for t in triangulate(&r).unwrap() {
            assert!((r[t[1]] - r[t[0]]).cross(r[t[2]] - r[t[0]]).x < 0.0);
        }
        // A star of 66 corners (33 points), one corner repeated: area of the star kept.
        let mut star: Vec<Vec3> = (0..66)
            .map(|k| {
                let a = k as f32 * std::f32::consts::TAU / 66.0;
                let r = if k % 2 == 0 { 1.0 } else { 0.5 };
                Vec3::new(r * a.cos(), 0.0, -r * a.sin())
            })
            .collect();
        // Its area: the fan from the centre (the star is star-shaped about it).
        let centre_area: f32 = (0..66)
            .map(|k| 0.5 * star[k].cross(star[(k + 1) % 66]).length())
            .sum();
        star.insert(10, star[10]);
        let t = triangulate(&star).unwrap();
        assert!((area(&star, &t) - centre_area).abs() < 1e-4 * centre_area);
    }
}
