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
use super::obj::{Corner, Face, Obj, FREE_FORM, POINTS, POLYLINES, SHORT_FACE, UNKNOWN};
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
/// `DEGENERATE` for a triangle whose material emits: its own kind, so that a scene left without
/// a light says why.
pub const DEGENERATE_LIGHT: Kind = Kind {
    one: "emitting triangle of zero area (or of an area below single precision's range, 1.2e-38) \
          skipped: it emits nothing",
    many: "emitting triangles of zero area (or of areas below single precision's range, 1.2e-38) \
           skipped: they emit nothing",
};
const FANNED: Kind = Kind {
    one: "polygon that winds over itself (or that ear clipping could not triangulate) split as \
          a fan",
    many: "polygons that wind over themselves (or that ear clipping could not triangulate) \
           split as fans",
};

/// A polygon's triangles on the same three points as another of its triangles, left out
/// (`without_repeats`).
const REPEATED_TRIANGLES: Kind = Kind {
    one: "polygon that goes round its outline more than once (its triangles repeat) read once: \
          on a lamp each round added the lamp's light again",
    many: "polygons that go round their outlines more than once (their triangles repeat) read \
           once: on a lamp each round added the lamp's light again",
};

/// Triangle soup with per-triangle materials, as loaded from OBJ/MTL and checked (`default`:
/// empty, to build or `append` meshes into).
#[derive(Default)]
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

/// Wind each emitting triangle of `mesh` whose three corners have vertex normals so that it
/// faces where they point together (their sum), turning it over where they point against its
/// winding: a light emits to its front (`tri_normal`), and pbrt-v4 and Mitsuba 3 both emit to
/// the side of the shading normal, so that a lamp exported with outward normals but faces
/// wound inward lit the other side than in them (and a mirrored placement of a lamp with
/// normals shines as the mirror image of it, as in them). Without vertex normals the winding
/// decides. Other triangles keep their winding (their shading follows it). Returns those
/// turned over (their indices, in order).
pub fn orient_emitters(mesh: &mut Mesh) -> Vec<usize> {
    let mut turned = Vec::new();
    if mesh.normals.is_empty() {
        return turned;
    }
    for (t, tri) in mesh.triangles.iter_mut().enumerate() {
        if !mesh.materials[mesh.tri_material[t] as usize].is_emissive() {
            continue;
        }
        let n = tri.map(|i| mesh.normals[i as usize]);
        if n.contains(&Vec3::ZERO) {
            continue;
        }
        if (n[0] + n[1] + n[2]).dot(mesh.tri_normal[t]) < 0.0 {
            tri.swap(1, 2);
            mesh.tri_normal[t] = -mesh.tri_normal[t];
            turned.push(t);
        }
    }
    turned
}

/// Whether the closed 2D polygon `flat` (x, y pairs) winds over itself: a directed edge
/// repeated (a loop walked twice: `f 1 2 3 1 2 3 ...`) or two edges that cross (each
/// passes strictly through the other's line; a vertex shared by a polygon with a hole bridged
/// to its outline, or an edge walked back, is not a crossing). Edges are bucketed in a grid of
/// about one cell per edge, and pairs are tested within cells, up to a budget proportional to
/// the corners: past it (many long edges through the same cells) the answer is `false`, and
/// ear clipping takes the polygon as it would have.
fn winds_over_itself(flat: &[f64]) -> bool {
    let n = flat.len() / 2;
    let pt = |i: usize| (flat[2 * (i % n)], flat[2 * (i % n) + 1]);
    let mut directed = std::collections::HashSet::with_capacity(n);
    for i in 0..n {
        let ((ax, ay), (bx, by)) = (pt(i), pt(i + 1));
        if (ax, ay) != (bx, by) && !directed.insert([ax, ay, bx, by].map(f64::to_bits)) {
            return true;
        }
    }
    let (mut lo, mut hi) = ((f64::MAX, f64::MAX), (f64::MIN, f64::MIN));
    for i in 0..n {
        let (x, y) = pt(i);
        lo = (lo.0.min(x), lo.1.min(y));
        hi = (hi.0.max(x), hi.1.max(y));
    }
    let g = (n as f64).sqrt().ceil().max(1.0) as usize;
    let (w, h) = ((hi.0 - lo.0) / g as f64, (hi.1 - lo.1) / g as f64);
    if !(w > 0.0 && h > 0.0 && w.is_finite() && h.is_finite()) {
        return false; // on a line: nothing crosses properly
    }
    let cell = |v: f64, lo: f64, size: f64| (((v - lo) / size) as usize).min(g - 1);
    // Each edge in the cells of the columns it spans, rows from its extent within each column.
    let mut cells: Vec<Vec<u32>> = vec![Vec::new(); g * g];
    for i in 0..n {
        let ((ax, ay), (bx, by)) = (pt(i), pt(i + 1));
        let (c0, c1) = (cell(ax.min(bx), lo.0, w), cell(ax.max(bx), lo.0, w));
        for c in c0..=c1 {
            let (x0, x1) = (lo.0 + c as f64 * w, lo.0 + (c + 1) as f64 * w);
            let y_at = |x: f64| {
                if bx == ax {
                    (ay, by)
                } else {
                    let t = ((x - ax) / (bx - ax)).clamp(0.0, 1.0);
                    let y = ay + t * (by - ay);
                    (y, y)
                }
            };
            let ((p, q), (r, s)) = (y_at(x0.max(ax.min(bx))), y_at(x1.min(ax.max(bx))));
            let (ylo, yhi) = (p.min(q).min(r).min(s), p.max(q).max(r).max(s));
            for r in cell(ylo, lo.1, h)..=cell(yhi, lo.1, h) {
                cells[r * g + c].push(i as u32);
            }
        }
    }
    // The side of line a-b that c is on: 1, -1, or 0 on it (`signum` would give 1 for 0).
    let orient = |a: (f64, f64), b: (f64, f64), c: (f64, f64)| {
        let v = (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0);
        (v > 0.0) as i32 - (v < 0.0) as i32
    };
    let mut budget = 64 * n + 4096;
    for list in &cells {
        for (k, &i) in list.iter().enumerate() {
            for &j in &list[k + 1..] {
                let (i, j) = (i as usize, j as usize);
                if (i + 1) % n == j || (j + 1) % n == i {
                    continue; // neighbours share a corner
                }
                if budget == 0 {
                    return false;
                }
                budget -= 1;
                let (a, b, c, d) = (pt(i), pt(i + 1), pt(j), pt(j + 1));
                if orient(a, b, c) * orient(a, b, d) < 0 && orient(c, d, a) * orient(c, d, b) < 0 {
                    return true;
                }
            }
        }
    }
    false
}

/// Whether the polygon of 2D corners `flat` (x, y pairs, in order) is strictly convex and
/// simple: every corner turns the same way, by more than nothing, and the turns add up to one
/// full turn (a star turns the same way at every corner too, but twice round).
fn is_convex(flat: &[f64]) -> bool {
    let n = flat.len() / 2;
    let pt = |i: usize| (flat[2 * (i % n)], flat[2 * (i % n) + 1]);
    let (mut sign, mut turned) = (0.0f64, 0.0f64);
    for i in 0..n {
        let (a, b, c) = (pt(i), pt(i + 1), pt(i + 2));
        let (e, f) = ((b.0 - a.0, b.1 - a.1), (c.0 - b.0, c.1 - b.1));
        let cross = e.0 * f.1 - e.1 * f.0;
        if cross == 0.0 || (sign != 0.0 && cross.signum() != sign) {
            return false;
        }
        sign = cross.signum();
        turned += cross.atan2(e.0 * f.0 + e.1 * f.1);
    }
    (turned.abs() - std::f64::consts::TAU).abs() < 1e-6
}

/// The most corners of a face that ear clipping splits; a larger face that is not convex is split
/// by a constrained Delaunay triangulation (`constrained_delaunay`). Ear clipping finds few ears
/// on a thin spiral strip and scans the whole outline for each: earcut's time grew about as
/// n^2.6 (a simple spiral face of 65,000 corners took 47 s to load, four of them passed a
/// minute), where the triangulation takes about n log n.
const EARCUT_MOST: usize = 1024;

/// What `constrained_delaunay` made of a polygon.
enum Cdt {
    /// Its triangles, as corner indices, three by three.
    Triangles(Vec<usize>),
    /// Edges that meet other than at their ends (overlapping on one line, or crossing where
    /// `winds_over_itself` gave up), or coordinates the triangulation does not take: left to
    /// ear clipping, as every polygon was.
    Unsuited,
}

/// The triangles of the simple 2D polygon `flat` (x, y pairs): the constrained Delaunay
/// triangulation of its corners with its edges as constraints covers their convex hull, and
/// its triangles inside the polygon are those reached from the outside across an odd number of
/// the polygon's edges. Corners on one point are one vertex (a hole bridged to the outline
/// walks two corners twice), and an edge walked there and back (the bridge) is crossed twice.
fn constrained_delaunay(flat: &[f64]) -> Cdt {
    use spade::{ConstrainedDelaunayTriangulation, Point2, Triangulation};
    let n = flat.len() / 2;
    // Each corner's vertex, and each vertex's first corner (the triangulation keeps the first
    // of the points given twice, in order).
    let mut first = std::collections::HashMap::with_capacity(n);
    let mut corners = Vec::with_capacity(n);
    let vertex: Vec<usize> = flat
        .chunks_exact(2)
        .enumerate()
        .map(|(i, q)| {
            *first
                .entry([q[0].to_bits(), q[1].to_bits()])
                .or_insert_with(|| {
                    corners.push(i);
                    corners.len() - 1
                })
        })
        .collect();
    let points: Vec<Point2<f64>> = corners
        .iter()
        .map(|&i| Point2::new(flat[2 * i], flat[2 * i + 1]))
        .collect();
    // The polygon's edges between vertices, and how often each is walked either way.
    let mut walked: std::collections::HashMap<[usize; 2], u32> = Default::default();
    let mut edges = Vec::with_capacity(n);
    for i in 0..n {
        let (a, b) = (vertex[i], vertex[(i + 1) % n]);
        if a == b {
            continue;
        }
        let key = [a.min(b), a.max(b)];
        let count = walked.entry(key).or_insert(0);
        if *count == 0 {
            edges.push(key);
        }
        *count += 1;
    }
    let mut crossed = false;
    let Ok(cdt) =
        ConstrainedDelaunayTriangulation::<Point2<f64>>::try_bulk_load_cdt(points, edges, |_| {
            crossed = true
        })
    else {
        return Cdt::Unsuited;
    };
    if crossed || cdt.num_vertices() != corners.len() {
        return Cdt::Unsuited;
    }
    // The faces on either side of each edge, and whether crossing it goes in or out: one of
    // the polygon's edges walked an odd number of times.
    let faces = cdt.num_all_faces();
    let mut next: Vec<Vec<(usize, bool)>> = vec![Vec::new(); faces];
    for e in cdt.undirected_edges() {
        let d = e.as_directed();
        let (a, b) = (d.face().fix().index(), d.rev().face().fix().index());
        let [u, v] = e.vertices().map(|v| v.fix().index());
        let wall = e.is_constraint_edge()
            && walked
                .get(&[u.min(v), u.max(v)])
                .is_some_and(|c| c % 2 == 1);
        next[a].push((b, wall));
        next[b].push((a, wall));
    }
    let mut inside: Vec<Option<bool>> = vec![None; faces];
    let outer = cdt.outer_face().fix().index();
    inside[outer] = Some(false);
    let mut todo = vec![outer];
    while let Some(f) = todo.pop() {
        let here = inside[f].expect("set before it was queued");
        for &(g, wall) in &next[f] {
            if inside[g].is_none() {
                inside[g] = Some(here != wall);
                todo.push(g);
            }
        }
    }
    Cdt::Triangles(
        cdt.inner_faces()
            .filter(|f| inside[f.fix().index()] == Some(true))
            .flat_map(|f| f.vertices().map(|v| corners[v.fix().index()]))
            .collect(),
    )
}

/// `tris` (indices into the polygon's corners `p`) without those on the same three points as
/// an earlier one, in either winding: a face that goes round its outline twice, `f 5 6 7 8 5 6
/// 7 8`, is split (as a fan) into each triangle twice, which on a lamp emitted twice.
pub fn without_repeats(p: &[Vec3], tris: Vec<[usize; 3]>) -> Vec<[usize; 3]> {
    let key = |t: &[usize; 3]| {
        let mut k = t.map(|i| p[i].to_array().map(f32::to_bits));
        k.sort_unstable();
        k
    };
    let mut seen = std::collections::HashSet::with_capacity(tris.len());
    tris.into_iter().filter(|t| seen.insert(key(t))).collect()
}

/// The triangles of a polygon, as indices into `p` (its corners in order): a fan from the
/// first corner where the polygon is convex, ear clipping where not (a constrained Delaunay
/// triangulation past `EARCUT_MOST` corners).
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
    // A convex polygon is a fan from its first corner, as other renderers and OBJ readers split
    // it: where a quad's two halves are not coplanar, or its vertex normals differ, the
    // diagonal decides the surface. Ear clipping picks a diagonal by the sign of the
    // projection, so a quad mirrored or turned over by a placement split the other way.
    if is_convex(&flat) {
        return Some((1..p.len() - 1).map(|i| [0, i, i + 1]).collect());
    }
    // A polygon that winds over itself has no inside to triangulate: ear clipping filled
    // some of it, as it happened to clip (a pentagram `f 1 3 5 2 4` lost two arms' notch,
    // unsaid), and met a large one with passes of cubic cost (a 2000-corner face took 37 s).
    // It is split as a fan (the caller's repair) instead.
    if winds_over_itself(&flat) {
        return None;
    }
    let idx = match (p.len() > EARCUT_MOST).then(|| constrained_delaunay(&flat)) {
        Some(Cdt::Triangles(t)) => t,
        Some(Cdt::Unsuited) | None => earcutr::earcut(&flat, &[], 2).ok()?,
    };
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
/// A triangle's unit normal (counter-clockwise), the length of its edges' cross product (twice
/// its area), and whether it is degenerate (zero area against its longest edge, or an area
/// below the range of f32's normal numbers). Corners may be up to the 1e18 the scene allows (and
/// further once placed), where the f32 cross product's length overflows (from edges of about
/// 4e9 on: a floor 1e10 wide would be "zero area"), and as small as the scene likes, where the
/// squares in its length underflow (a lamp of area 4e-22, in a scene modelled in units of
/// 1e-11, was "zero area"): such a triangle is measured in f64, and its normal fits f32; its
/// area may be past f32's range (what `Scene::load` refuses for a light). The OBJ reader and
/// placed objects (`objects::transformed`) measure triangles with it.
pub fn measure(a: Vec3, b: Vec3, c: Vec3) -> (Vec3, f32, bool) {
    let cr = (b - a).cross(c - a);
    let len = cr.length();
    let scale = (b - a).length_squared().max((c - a).length_squared());
    // Above 1e-18 the squares in `length` are normal f32 numbers, and exact to f32's precision.
    if len.is_finite() && scale.is_finite() && len > 1e-18 {
        (cr / len, len, len <= 1e-7 * scale)
    } else {
        let [a, b, c] = [a, b, c].map(|p| p.as_dvec3());
        let cr = (b - a).cross(c - a);
        let len = cr.length();
        let scale = (b - a).length_squared().max((c - a).length_squared());
        let ok = len.is_finite() && len > 1e-7 * scale && len as f32 >= f32::MIN_POSITIVE;
        ((cr / len).as_vec3(), len as f32, !ok)
    }
}

/// A face on the same points as an earlier one, left out (`repeated_faces`).
const REPEATED_FACE: Kind = Kind {
    one: "face on the same corners as an earlier one (a two-sided export, as SketchUp writes \
          each face again, reversed, with its back material) left out: the two would fight over \
          every point of the surface, a speckle of both materials; the earlier face's material \
          shows from both sides",
    many: "faces on the same corners as earlier ones (a two-sided export, as SketchUp writes \
           each face again, reversed, with its back material) left out: the two would fight \
           over every point of the surface, a speckle of both materials; the earlier faces' \
           materials show from both sides",
};

/// An emitting face on the same points as an earlier emitting one, left out (`repeated_faces`).
const REPEATED_LAMP: Kind = Kind {
    one: "emitting face on the same corners as an earlier emitting one (a lamp made two-sided \
          by a reversed copy of its faces, or written twice) left out: the two would fight \
          over every point, a speckle of light and dark, which the reuse methods also read \
          otherwise than the independent tracer; reframe's lights emit to one side, here the \
          earlier face's (for light on both sides, give the copy its own corners a little apart)",
    many: "emitting faces on the same corners as earlier emitting ones (a lamp made two-sided \
           by a reversed copy of its faces, or written twice) left out: the two would fight \
           over every point, a speckle of light and dark, which the reuse methods also read \
           otherwise than the independent tracer; reframe's lights emit to one side, here the \
           earlier faces' (for light on both sides, give the copies their own corners a little \
           apart)",
};

/// The earlier faces on the same points that a face is compared with (`repeated_faces`).
const MAX_COMPARED: usize = 8;

/// The faces of `obj` that repeat an earlier one, each with that face (indices, in order;
/// `None` where the memory to find them is not left): the same corner points
/// (positions to the bit), in the same cyclic order or the reverse, where both faces emit or
/// neither does (`emits(face)`; a lamp's face and a wall's on the same corners are both kept).
/// Two such faces are one surface twice, and which a ray hits is a matter of rounding (a lamp
/// made two-sided by a reversed copy of its faces rendered as a speckle, seen from either side,
/// and the reuse methods, whose visibility rays settle the tie otherwise than primary rays,
/// were biased against the independent tracer on it). Faces are grouped by a hash of their
/// corners that does not depend on their order, then compared.
fn repeated_faces(obj: &Obj, emits: &dyn Fn(&Face) -> bool) -> Option<Vec<(u32, u32)>> {
    let corners = |f: &Face| obj.corners[f.corners.clone()].iter();
    let point = |c: &Corner| obj.positions[c.v as usize].to_array().map(f32::to_bits);
    // A corner's hash (its point's), its high bits folded down: the face's is their sum.
    let mix = |c: &Corner| {
        let mut f = crate::util::hash::Fnv::default();
        f.f32s(obj.positions[c.v as usize].to_array());
        f.0 ^ (f.0 >> 29)
    };
    // Taken fallibly, as the mesh's lists are (`util::mem::grow`): 16 bytes a face.
    let mut keys: Vec<(u64, u32)> = Vec::new();
    keys.try_reserve_exact(obj.faces.len()).ok()?;
    keys.extend(
        obj.faces
            .iter()
            .enumerate()
            .filter(|(_, f)| f.corners.len() >= 3)
            .map(|(i, f)| {
                let h = corners(f).fold(0u64, |h, c| h.wrapping_add(mix(c)));
                (h ^ f.corners.len() as u64, i as u32)
            }),
    );
    keys.sort_unstable();
    let same = |a: &Face, b: &Face| {
        let (p, q): (Vec<_>, Vec<_>) = (
            corners(a).map(point).collect(),
            corners(b).map(point).collect(),
        );
        let n = p.len();
        q.len() == n
            && (0..n).any(|r| {
                (0..n).all(|k| q[k] == p[(r + k) % n]) || (0..n).all(|k| q[k] == p[(r + n - k) % n])
            })
    };
    // (face, the earlier face it repeats), few in any model.
    let mut repeats = Vec::new();
    for run in keys.chunk_by(|a, b| a.0 == b.0).filter(|r| r.len() > 1) {
        // Within a run (sorted by face after the hash: in the order of the file), each face
        // against the first few earlier ones kept: the faces on one set of points in other
        // orders are few in any model, but a file of thousands of orders of ten points would
        // take a time in the square of their count.
        // (Emitting faces against emitting ones, the others against the others.)
        let mut kept: [Vec<u32>; 2] = Default::default();
        for &(_, j) in run {
            let fj = &obj.faces[j as usize];
            let kept = &mut kept[usize::from(emits(fj))];
            match kept.iter().find(|&&i| same(&obj.faces[i as usize], fj)) {
                Some(&i) => {
                    if !crate::util::mem::grow(&mut repeats) {
                        return None;
                    }
                    repeats.push((j, i));
                }
                None if kept.len() < MAX_COMPARED => kept.push(j),
                None => {}
            }
        }
    }
    repeats.sort_unstable();
    Some(repeats)
}

/// The mesh of `obj`: `usemtl_material[k]` is the material of the faces after the k-th
/// `usemtl`, `default_material` that of faces before any; `emissive(m)`: whether material `m`
/// emits. A face on the same corners as an earlier one, both emitting or neither, is left out
/// (`repeated_faces`). `bytes` is the OBJ text, for quoting.
pub fn build(
    label: &str,
    bytes: &[u8],
    obj: &Obj,
    (usemtl_material, default_material): (&[u32], u32),
    emissive: &dyn Fn(u32) -> bool,
    repairs: &mut Repairs,
) -> Result<Mesh> {
    let mut mesh = Mesh::default();
    let any_smooth = obj.corners.iter().any(|c| c.vn.is_some());
    let any_uv = obj.corners.iter().any(|c| c.vt.is_some());
    // One vertex per distinct (position, normal, texture coordinate) of the faces; `u32::MAX`:
    // none.
    let mut vertex: HashMap<(u32, u32, u32), u32> = HashMap::new();
    let mut skipped = 0usize;
    let mut first_skipped = 0usize;
    let mut pts = Vec::new();
    let mut ids: Vec<u32> = Vec::new();
    use crate::util::mem::grow;
    // The mesh's lists grow fallibly (`util::mem::grow`): an allocation that fails aborts the process (a
    // 26 MB OBJ of triangles under a tight `ulimit -v`: a backtrace, exit 134).
    let no_room = |line: usize, made: usize, what: &str| {
        anyhow::anyhow!(
            "{label}: line {line}: building the mesh needs more memory than is left ({made} \
             {what} so far){}",
            crate::util::mem::address_space_note()
        )
    };
    let material_of = |f: &Face| {
        f.usemtl
            .map_or(default_material, |k| usemtl_material[k as usize])
    };
    let repeats = repeated_faces(obj, &|f| emissive(material_of(f))).ok_or_else(|| {
        anyhow::anyhow!(
            "{label}: finding the faces that repeat others among its {} faces needs more memory \
             than is left{}",
            obj.faces.len(),
            crate::util::mem::address_space_note()
        )
    })?;
    let mut repeats = repeats.into_iter().peekable();
    for (k, f) in obj.faces.iter().enumerate() {
        let repeat = repeats
            .next_if(|&(j, _)| j as usize == k)
            .map(|(_, i)| i as usize);
        if let Some(earlier) = repeat {
            let kind = if emissive(material_of(f)) {
                REPEATED_LAMP
            } else {
                REPEATED_FACE
            };
            repairs.note(label, f.line, kind, || {
                format!(
                    "{} (the face of line {})",
                    quote_line(bytes, f.line),
                    obj.faces[earlier].line
                )
            })?;
            continue;
        }
        let corners = &obj.corners[f.corners.clone()];
        // Smooth only if every corner has a usable normal: interpolating a normal with the face
        // normal of a neighbour would shade a seam.
        let smooth = corners.iter().all(|c| c.vn.is_some());
        ids.clear();
        for &Corner { v, vt, vn } in corners {
            let n = if smooth { vn.unwrap() } else { u32::MAX };
            let key = (v, n, vt.unwrap_or(u32::MAX));
            if let Some(&id) = vertex.get(&key) {
                ids.push(id);
                continue;
            }
            let fits = vertex.try_reserve(1).is_ok()
                && grow(&mut mesh.positions)
                && (!any_smooth || grow(&mut mesh.normals))
                && (!any_uv || grow(&mut mesh.uvs));
            if !fits {
                return Err(no_room(f.line, mesh.positions.len(), "vertices"));
            }
            mesh.positions.push(obj.positions[v as usize]);
            if any_smooth {
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
            let id = mesh.positions.len() as u32 - 1;
            vertex.insert(key, id);
            ids.push(id);
        }
        pts.clear();
        pts.extend(ids.iter().map(|&i| mesh.positions[i as usize]));
        let mut tris = match triangulate(&pts) {
            Some(t) => t,
            None => {
                repairs.note(label, f.line, FANNED, || quote_line(bytes, f.line))?;
                (1..pts.len() - 1).map(|k| [0, k, k + 1]).collect()
            }
        };
        if pts.len() > 4 {
            let n = tris.len();
            tris = without_repeats(&pts, tris);
            if tris.len() < n {
                repairs.note(label, f.line, REPEATED_TRIANGLES, || {
                    quote_line(bytes, f.line)
                })?;
            }
        }
        let mat = material_of(f);
        for t in tris {
            let tri = t.map(|k| ids[k]);
            let [a, b, c] = t.map(|k| pts[k]);
            let (n, len, degenerate) = measure(a, b, c);
            if degenerate {
                skipped += 1;
                if first_skipped == 0 {
                    first_skipped = f.line;
                }
                let kind = if emissive(mat) {
                    DEGENERATE_LIGHT
                } else {
                    DEGENERATE
                };
                repairs.note(label, f.line, kind, || quote_line(bytes, f.line))?;
                continue;
            }
            let fits = grow(&mut mesh.triangles)
                && grow(&mut mesh.tri_material)
                && grow(&mut mesh.tri_normal)
                && grow(&mut mesh.tri_area);
            if !fits {
                return Err(no_room(f.line, mesh.triangles.len(), "triangles"));
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
        // An empty file, or a web page saved in the model's place (a download that fetched
        // the page around the file), said as what it is.
        let text = bytes.strip_prefix(b"\xef\xbb\xbf").unwrap_or(bytes);
        let first = text.iter().find(|b| !b.is_ascii_whitespace());
        if first.is_none() {
            bail!("{label}: the file is empty (no faces)");
        }
        if first == Some(&b'<') {
            bail!(
                "{label}: an HTML or XML page, not an OBJ (a web page saved in the model's \
                 place: download the raw file)"
            );
        }
        // What the file held instead (polylines, points, faces of one or two vertices, curves,
        // statements OBJ does not have), which was said as a warning only where something else
        // rendered.
        let instead = [SHORT_FACE, POLYLINES, POINTS, FREE_FORM, UNKNOWN];
        match repairs.first_in(Some(label), &instead) {
            Some(first) => bail!("{label}: no faces (what it has is left out: {first})"),
            None => bail!("{label}: no faces"),
        }
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

    #[test]
    fn convex_polygons_are_fans_from_their_first_corner_however_they_face() {
        // A quad whose halves are not coplanar (its last corner lifted), in each of the six
        // axis-facing orientations and both windings: always the diagonal from corner 0, so
        // the surface does not depend on which way a placement turned it.
        let quad = [
            (0.0, 0.0, 0.0),
            (1.0, 0.0, 0.0),
            (1.0, 1.0, 0.0),
            (0.0, 1.0, 0.3),
        ];
        for axes in [[0, 1, 2], [1, 2, 0], [2, 0, 1]] {
            for flip in [1.0f32, -1.0] {
                for reverse in [false, true] {
                    let mut p: Vec<Vec3> = quad
                        .iter()
                        .map(|&(x, y, z)| {
                            let mut v = [0.0f32; 3];
                            (v[axes[0]], v[axes[1]], v[axes[2]]) = (x, y, flip * z + 0.1);
                            Vec3::from(v) * Vec3::new(flip, 1.0, 1.0)
                        })
                        .collect();
                    if reverse {
                        p[1..].reverse();
                    }
                    assert_eq!(triangulate(&p).unwrap(), vec![[0, 1, 2], [0, 2, 3]]);
                }
            }
        }
        // A regular hexagon; and a star of five points, whose corners all turn one way but
        // which winds round twice, is not convex (ear clipping keeps its area).
        let hexagon: Vec<Vec3> = (0..6)
            .map(|k| {
                let a = k as f32 * std::f32::consts::TAU / 6.0;
                Vec3::new(a.cos(), a.sin(), 0.0)
            })
            .collect();
        assert_eq!(
            triangulate(&hexagon).unwrap(),
            vec![[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5]]
        );
        let pentagram: Vec<Vec3> = (0..5)
            .map(|k| {
                let a = (2 * k) as f32 * std::f32::consts::TAU / 5.0;
                Vec3::new(a.cos(), a.sin(), 0.0)
            })
            .collect();
        let flat: Vec<f64> = pentagram
            .iter()
            .flat_map(|q| [q.x as f64, q.y as f64])
            .collect();
        assert!(!is_convex(&flat));
        // A quad with three corners on a line is not strictly convex: ear clipping.
        let flat = [0.0, 0.0, 1.0, 0.0, 2.0, 0.0, 1.0, 1.0];
        assert!(!is_convex(&flat));
    }

    #[test]
    fn small_polygons_that_cross_themselves_are_left_to_the_fan() {
        // A pentagram walked as `f 1 3 5 2 4` over a regular pentagon's corners, and a bow
        // tie: ear clipping filled some of each, as it happened to clip, unsaid. A concave L is
        // no crossing (a hole bridged to its outline neither: the test below).
        let pentagon: Vec<Vec3> = (0..5)
            .map(|k| {
                let a = k as f32 * std::f32::consts::TAU / 5.0;
                Vec3::new(a.cos(), a.sin(), 0.0)
            })
            .collect();
        let star: Vec<Vec3> = [0, 2, 4, 1, 3].iter().map(|&k| pentagon[k]).collect();
        let bow = [Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::new(1.0, 1.0, 0.0)];
        assert!(triangulate(&star).is_none());
        assert!(triangulate(&bow).is_none());
        let l = [(0., 0.), (2., 0.), (2., 1.), (1., 1.), (1., 2.), (0., 2.)]
            .map(|(x, y)| Vec3::new(x, y, 0.0));
        assert!((area(&l, &triangulate(&l).unwrap()) - 3.0).abs() < 1e-6);
    }

    /// An `n`-gon of radius 20 with an `m`-gon hole of radius 10, wound the other way, bridged
    /// to it at their first corners (two corners on one point each, the bridge walked there and
    /// back), in the plane y = 0; and the ring's area.
    fn bridged_ring(n: usize, m: usize) -> (Vec<Vec3>, f32) {
        let circle = |n: usize, r: f32, turn: f32| -> Vec<Vec3> {
            (0..n)
                .map(|k| {
                    let a = turn * k as f32 * std::f32::consts::TAU / n as f32;
                    Vec3::new(r * a.cos(), 0.0, r * a.sin())
                })
                .collect()
        };
        let (outer, hole) = (circle(n, 20.0, 1.0), circle(m, 10.0, -1.0));
        let fan = |p: &[Vec3]| {
            area(
                p,
                &(1..p.len() - 1).map(|i| [0, i, i + 1]).collect::<Vec<_>>(),
            )
        };
        let ring = fan(&outer) - fan(&hole);
        let bridged = outer
            .iter()
            .chain(&outer[..1])
            .chain(&hole)
            .chain(&hole[..1])
            .copied()
            .collect();
        (bridged, ring)
    }

    #[test]
    fn a_large_simple_spiral_is_split_whole_and_at_once() {
        // A thin strip wound as a spiral, out along one edge and back along the other: simple,
        // and nearly without ears, where ear clipping took 47 s at 65,000 corners. 20,000
        // corners: n - 2 triangles, the polygon's area, each wound like the polygon.
        let m = 10_000;
        let arm = |dr: f32| -> Vec<Vec3> {
            (0..m)
                .map(|i| {
                    let a = i as f32 * 0.05;
                    let r = 0.01 + a * 0.002 + dr;
                    Vec3::new(r * a.cos(), 0.0, r * a.sin())
                })
                .collect()
        };
        let p: Vec<Vec3> = arm(0.0)
            .into_iter()
            .chain(arm(8e-4).into_iter().rev())
            .collect();
        let start = std::time::Instant::now();
        let t = triangulate(&p).unwrap();
        assert!(start.elapsed().as_secs_f32() < 30.0, "a hang guard");
        assert_eq!(t.len(), p.len() - 2);
        let d: Vec<glam::DVec3> = p.iter().map(|v| v.as_dvec3()).collect();
        let shoelace: f64 = (0..d.len())
            .map(|k| {
                let (a, b) = (d[k], d[(k + 1) % d.len()]);
                0.5 * (a.z * b.x - b.z * a.x)
            })
            .sum();
        // Wound so that the normal is +y (or -y): every triangle alike, their areas adding up.
        let signed: Vec<f64> = t
            .iter()
            .map(|t| 0.5 * (d[t[1]] - d[t[0]]).cross(d[t[2]] - d[t[0]]).y)
            .collect();
        assert!(signed.iter().all(|&a| a * shoelace >= 0.0));
        let total: f64 = signed.iter().sum();
        assert!(
            (total - shoelace).abs() < 1e-6 * shoelace.abs(),
            "{total} against {shoelace}"
        );
        // A 1500-gon with a 600-gon hole bridged to it at their first corners (two corners on
        // one point each, the bridge walked there and back): the ring's area, the hole left.
        let (bridged, ring) = bridged_ring(1500, 600);
        let t = triangulate(&bridged).unwrap();
        // (Split by the triangulation, not left to ear clipping.)
        let flat: Vec<f64> = bridged
            .iter()
            .flat_map(|q| [q.z as f64, q.x as f64])
            .collect();
        assert!(matches!(constrained_delaunay(&flat), Cdt::Triangles(_)));
        let got = area(&bridged, &t);
        assert!((got - ring).abs() < 1e-4 * ring, "{got} against {ring}");
    }

    #[test]
    fn polygons_that_wind_over_themselves_are_left_to_the_fan() {
        // One triangle walked 700 times (2100 corners) and a spiral of 2000 corners that
        // crosses itself took ear clipping 37 s and 10 s; both are found at once and left to
        // the caller's fan. A simple polygon as large (a comb of 2000 corners, concave) and a
        // square with a hole bridged to it (two corners walked twice, the bridge there and
        // back) still go to ear clipping, their area kept.
        let tri = [Vec3::ZERO, Vec3::X, Vec3::Z];
        let walked: Vec<Vec3> = (0..2100).map(|k| tri[k % 3]).collect();
        let spiral: Vec<Vec3> = (0..2000)
            .map(|k| tri[k % 3] + Vec3::splat(1e-4 * (k / 3) as f32))
            .collect();
        for p in [&walked, &spiral] {
            let start = std::time::Instant::now();
            assert!(triangulate(p).is_none());
            assert!(start.elapsed().as_secs_f32() < 30.0, "a hang guard");
        }
        let comb: Vec<Vec3> = (0..1000)
            .flat_map(|k| {
                let x = k as f32;
                [Vec3::new(x, 0.0, 10.0), Vec3::new(x + 0.5, 0.0, 1.0)]
            })
            .chain([Vec3::new(1000.0, 0.0, 0.0), Vec3::new(0.0, 0.0, 0.0)])
            .collect();
        let t = triangulate(&comb).unwrap();
        let shoelace = |p: &[Vec3]| {
            (0..p.len())
                .map(|k| {
                    let (a, b) = (p[k], p[(k + 1) % p.len()]);
                    0.5 * (a.x as f64 * b.z as f64 - b.x as f64 * a.z as f64)
                })
                .sum::<f64>()
                .abs() as f32
        };
        assert!((area(&comb, &t) - shoelace(&comb)).abs() < 1e-3 * shoelace(&comb));
        // A 40-gon with a 20-gon hole, bridged at their first corners.
        let (bridged, want) = bridged_ring(40, 20);
        let t = triangulate(&bridged).unwrap();
        assert!(
            (area(&bridged, &t) - want).abs() < 1e-4 * want,
            "{} {want}",
            area(&bridged, &t)
        );
    }
}
