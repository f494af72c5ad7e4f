//! Emitters laid into another surface: a lamp quad flush with the ceiling it hangs from, an
//! emissive decal on a wall. Where the two overlap, a camera ray meets both at the same
//! distance, and which of them it sees is settled by the order in which Embree happens to test
//! them (in practice the order of the faces in the file), not by the scene: writing the lamp
//! before the ceiling in the OBJ took a lamp seen whole (50 pixels) to one pixel, and other
//! renderers settle it otherwise (Mitsuba 3 showed half of the same lamp). The light the lamp
//! casts is the same either way; only the lamp seen directly, or in a mirror, changes. Found
//! when the scene loads and warned of, with the materials named.
//!
//! How: the emitters' triangles go into a grid over the box around them, cells about an
//! emitter's size; each other triangle whose box meets that box looks at the emitters of the
//! cells its box covers. A pair is coplanar when their normals are parallel (within 1e-3
//! radians) and the emitter's corners lie on the other's plane (`PLANE_TOLERANCE`), and it
//! overlaps when no edge of either separates the two in that plane by more than a sliver
//! (triangles that only share an edge or a corner, as a lamp fitted into a hole cut in the
//! ceiling does, do not overlap).
use super::mesh::Mesh;
use super::objects::{Instance, Prototype};
use glam::{Vec2, Vec3};
use std::collections::BTreeMap;

/// An emitter's corners closer to another plane than this times the largest of `|n_i q_i|`
/// over its corners `q` (what single precision rounds the distance to its plane with, some 200
/// steps of it), or times its size where that is larger, lie on that plane.
pub const PLANE_TOLERANCE: f32 = 1e-5;

/// Cells, pairs of triangles and placed triangles visited at most: past it the check stops,
/// with what it found so far (a few seconds at most).
const MAX_VISITS: u64 = 50_000_000;

/// Entries of the emitters' grid at most (an emitter is in every cell its box covers): past it
/// the check is not made.
const MAX_ENTRIES: usize = 1 << 22;

/// Cells of the emitters' grid at most.
const MAX_CELLS: usize = 1 << 18;

/// Emitting triangles looked into at most (`warnings`).
const MAX_EMITTERS: usize = 1 << 18;

/// A triangle in world space with its plane: unit normal `n` (its largest component positive)
/// and `d = n . p` for the points `p` of the plane.
#[derive(Clone, Copy)]
struct Planar {
    p: [Vec3; 3],
    n: Vec3,
    d: f32,
    material: u32,
    /// How far a point may be from its plane and lie on it (`PLANE_TOLERANCE`).
    tol: f32,
}

impl Planar {
    fn new(p: [Vec3; 3], material: u32) -> Option<Planar> {
        let n = (p[1] - p[0]).cross(p[2] - p[0]).normalize_or_zero();
        if n == Vec3::ZERO || !n.is_finite() {
            return None;
        }
        let a = n.abs();
        let big = if a.x >= a.y && a.x >= a.z {
            n.x
        } else if a.y >= a.z {
            n.y
        } else {
            n.z
        };
        let n = if big < 0.0 { -n } else { n };
        let along = p.map(|q| (n * q).abs().element_sum());
        let size = (p[1] - p[0])
            .length()
            .max((p[2] - p[1]).length())
            .max((p[0] - p[2]).length());
        Some(Planar {
            p,
            n,
            d: n.dot(p[0]),
            material,
            tol: PLANE_TOLERANCE * along[0].max(along[1]).max(along[2]).max(size),
        })
    }

    /// Whether every corner of `other` lies within `tol` of this triangle's plane.
    fn holds(&self, other: &Planar, tol: f32) -> bool {
        other
            .p
            .iter()
            .all(|&q| (self.n.dot(q) - self.d).abs() <= tol)
    }
}

/// The triangles' corners in the plane of normal `n`: the axis `n` is largest along dropped.
fn flatten(n: Vec3, p: &[Vec3; 3]) -> [Vec2; 3] {
    let a = n.abs();
    p.map(|q| {
        if a.x >= a.y && a.x >= a.z {
            Vec2::new(q.y, q.z)
        } else if a.y >= a.z {
            Vec2::new(q.z, q.x)
        } else {
            Vec2::new(q.x, q.y)
        }
    })
}

/// Whether two triangles of one plane overlap by more than a sliver: no edge of either
/// separates them, by the separating-axis test, with an overlap of more than `rel` times the
/// smaller triangle's size required along every edge's normal (so that triangles sharing an
/// edge or a corner do not overlap; the larger's would pass over a small lamp on a large
/// floor).
fn overlap_2d(a: &[Vec2; 3], b: &[Vec2; 3], rel: f32) -> bool {
    let size = |t: &[Vec2; 3]| {
        (t[1] - t[0])
            .length()
            .max((t[2] - t[1]).length())
            .max((t[0] - t[2]).length())
    };
    let eps = rel * size(a).min(size(b));
    for t in [a, b] {
        for k in 0..3 {
            let e = t[(k + 1) % 3] - t[k];
            let axis = Vec2::new(-e.y, e.x).normalize_or_zero();
            if axis == Vec2::ZERO {
                continue;
            }
            let span = |s: &[Vec2; 3]| {
                let v = s.map(|q| q.dot(axis));
                (v[0].min(v[1]).min(v[2]), v[0].max(v[1]).max(v[2]))
            };
            let ((a0, a1), (b0, b1)) = (span(a), span(b));
            if a1.min(b1) - a0.max(b0) <= eps {
                return false;
            }
        }
    }
    true
}

/// Warnings for the emitting triangles of `mesh` (world space; the scene's own and its
/// emitting objects') that overlap a non-emitting triangle of `mesh` or of an instance in
/// their plane: one per pair of materials, with the number of emitting triangles.
pub fn warnings(
    label: &str,
    mesh: &Mesh,
    prototypes: &[Prototype],
    instances: &[Instance],
) -> Vec<String> {
    let emits = |m: u32| mesh.materials[m as usize].is_emissive();
    let corners = |t: &[u32; 3]| t.map(|i| mesh.positions[i as usize]);
    // A lamp laid into a ceiling is a few triangles; a scene of more emitting ones than
    // `MAX_EMITTERS` (an emitting model placed hundreds of times) is not looked into, and
    // neither is one whose tables would not fit in the memory left (the load's own refusal of
    // such a scene must stay one line, not an allocation that aborts).
    let n = mesh.tri_material.iter().filter(|&&m| emits(m)).count();
    let mut emitters: Vec<Planar> = Vec::new();
    let mut tested: Vec<u32> = Vec::new();
    if n == 0
        || n > MAX_EMITTERS
        || emitters.try_reserve_exact(n).is_err()
        || tested.try_reserve_exact(n).is_err()
    {
        return Vec::new();
    }
    emitters.extend(
        mesh.triangles
            .iter()
            .zip(&mesh.tri_material)
            .filter(|&(_, &m)| emits(m))
            .filter_map(|(t, &m)| Planar::new(corners(t), m)),
    );
    if emitters.is_empty() {
        return Vec::new();
    }
    let tol = emitters.iter().map(|t| t.tol).fold(0.0, f32::max);
    let Some(grid) = Grid::new(&emitters, tol) else {
        return Vec::new();
    };
    // Per (emitter's material, other's material): the emitters found overlapping.
    let mut found: BTreeMap<(u32, u32), Vec<u32>> = BTreeMap::new();
    let mut visits = 0u64;
    // The last other triangle each emitter was tested against (one that spans several of its
    // cells is tested once).
    tested.resize(emitters.len(), u32::MAX);
    let mut others = 0u32;
    let mut check = |o: Planar| -> bool {
        // Every triangle looked at counts, every cell and every entry of a cell.
        visits += 1;
        let Some(cells) = grid.cells(&o.p, tol) else {
            return visits < MAX_VISITS;
        };
        others += 1;
        for cell in cells {
            visits += 1;
            for &e in &grid.cells[cell] {
                visits += 1;
                if std::mem::replace(&mut tested[e as usize], others) == others {
                    continue;
                }
                let t = &emitters[e as usize];
                if t.n.dot(o.n).abs() < 1.0 - 1e-6 || !o.holds(t, t.tol) {
                    continue;
                }
                if overlap_2d(&flatten(t.n, &t.p), &flatten(t.n, &o.p), 1e-4) {
                    found.entry((t.material, o.material)).or_default().push(e);
                }
            }
        }
        visits < MAX_VISITS
    };
    'all: {
        for (t, &m) in mesh.triangles.iter().zip(&mesh.tri_material) {
            if emits(m) {
                continue;
            }
            if let Some(o) = Planar::new(corners(t), m) {
                if !check(o) {
                    break 'all;
                }
            }
        }
        // A placement whose box misses the emitters' is not looked into (a forest of placed
        // trees around one lamp).
        let bounds = |ps: &mut dyn Iterator<Item = Vec3>| {
            ps.fold(
                (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
                |(lo, hi), p| (lo.min(p), hi.max(p)),
            )
        };
        let proto_bounds: Vec<(Vec3, Vec3)> = prototypes
            .iter()
            .map(|p| bounds(&mut p.positions.iter().copied()))
            .collect();
        for inst in instances {
            let proto = &prototypes[inst.proto as usize];
            let (lo, hi) = proto_bounds[inst.proto as usize];
            let corners = (0..8).map(|k| {
                let pick = |bit: usize, a: f32, b: f32| if k & bit == 0 { a } else { b };
                let c = Vec3::new(
                    pick(1, lo.x, hi.x),
                    pick(2, lo.y, hi.y),
                    pick(4, lo.z, hi.z),
                );
                inst.to_world.transform_point3(c)
            });
            let (wlo, whi) = bounds(&mut corners.into_iter());
            if !grid.meets(wlo - tol, whi + tol) {
                continue;
            }
            for (t, &m) in proto.triangles.iter().zip(&proto.tri_material) {
                let p = t.map(|i| inst.to_world.transform_point3(proto.positions[i as usize]));
                if let Some(o) = Planar::new(p, m) {
                    if !check(o) {
                        break 'all;
                    }
                }
            }
        }
    }
    let name = |m: u32| {
        mesh.material_names
            .get(m as usize)
            .map_or_else(|| "(unnamed)".to_string(), |n| format!("'{n}'"))
    };
    found
        .into_iter()
        .map(|((e, o), tris)| {
            let mut ids: Vec<u32> = tris;
            ids.sort_unstable();
            ids.dedup();
            format!(
                "{label}: {} emitting triangle(s) of material {} lie in the plane of faces of \
                 material {} and overlap them (a lamp flush with the surface it is on?): where \
                 both are, which one a camera sees is decided by the order of the faces, not by \
                 the scene, and other renderers decide otherwise; move the emitter off the \
                 surface (by a thousandth of its size) or cut the surface away behind it",
                ids.len(),
                name(e),
                name(o)
            )
        })
        .collect()
}

/// The emitters' triangles by the cells of a grid over the box around them that their boxes
/// cover.
struct Grid {
    lo: Vec3,
    hi: Vec3,
    inv_cell: f32,
    dims: [usize; 3],
    cells: Vec<Vec<u32>>,
}

impl Grid {
    /// Cells about the size of an emitting triangle (fewer where they would pass
    /// `MAX_CELLS`), over the emitters' box grown by `tol`.
    /// `None` where its cells would not fit in the memory left.
    fn new(emitters: &[Planar], tol: f32) -> Option<Grid> {
        let bounds = |p: &[Vec3; 3]| (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]));
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        let mut sizes = 0.0f64;
        for t in emitters {
            let (a, b) = bounds(&t.p);
            (lo, hi) = (lo.min(a), hi.max(b));
            sizes += (b - a).max_element() as f64;
        }
        let (lo, hi) = (lo - tol, hi + tol);
        let extent = (hi - lo).max(Vec3::splat(tol));
        let mut cell = ((sizes / emitters.len() as f64) as f32).max(extent.max_element() / 256.0);
        let dims = loop {
            let dims = extent
                .to_array()
                .map(|e| ((e / cell).ceil() as usize).max(1));
            if dims.iter().product::<usize>() <= MAX_CELLS {
                break dims;
            }
            cell *= 1.25;
        };
        let mut cells = Vec::new();
        cells.try_reserve_exact(dims.iter().product()).ok()?;
        cells.resize(dims.iter().product(), Vec::new());
        let mut grid = Grid {
            lo,
            hi,
            inv_cell: 1.0 / cell,
            dims,
            cells,
        };
        let mut entries = 0;
        for (e, t) in emitters.iter().enumerate() {
            let (a, b) = bounds(&t.p);
            if let Some(cells) = grid.range(a - tol, b + tol) {
                for c in cells {
                    entries += 1;
                    if entries > MAX_ENTRIES {
                        return None;
                    }
                    grid.cells[c].try_reserve(1).ok()?;
                    grid.cells[c].push(e as u32);
                }
            }
        }
        Some(grid)
    }

    /// Whether a box from `a` to `b` meets the grid's box.
    fn meets(&self, a: Vec3, b: Vec3) -> bool {
        !(a.cmpgt(self.hi).any() || b.cmplt(self.lo).any())
    }

    /// The cells a box from `a` to `b` covers, or `None` where it misses the grid's box.
    fn range(&self, a: Vec3, b: Vec3) -> Option<impl Iterator<Item = usize>> {
        if !self.meets(a, b) {
            return None;
        }
        let at = |p: Vec3| {
            let q = (p - self.lo) * self.inv_cell;
            [q.x, q.y, q.z].map(|v| v.max(0.0) as usize)
        };
        let (i0, i1) = (at(a), at(b));
        let [nx, ny, nz] = self.dims;
        let (x1, y1, z1) = (i1[0].min(nx - 1), i1[1].min(ny - 1), i1[2].min(nz - 1));
        let (x0, y0, z0) = (i0[0].min(x1), i0[1].min(y1), i0[2].min(z1));
        Some((z0..=z1).flat_map(move |z| {
            (y0..=y1).flat_map(move |y| (x0..=x1).map(move |x| (z * ny + y) * nx + x))
        }))
    }

    /// The cells triangle `p`'s box (grown by `tol`) covers.
    fn cells(&self, p: &[Vec3; 3], tol: f32) -> Option<impl Iterator<Item = usize>> {
        self.range(
            p[0].min(p[1]).min(p[2]) - tol,
            p[0].max(p[1]).max(p[2]) + tol,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri(a: [f32; 2], b: [f32; 2], c: [f32; 2]) -> [Vec2; 3] {
        [a, b, c].map(Vec2::from)
    }

    #[test]
    fn triangles_overlap_only_by_more_than_a_sliver() {
        let a = tri([0.0, 0.0], [1.0, 0.0], [0.0, 1.0]);
        // Inside it, crossing it, and each way round.
        let inside = tri([0.1, 0.1], [0.3, 0.1], [0.1, 0.3]);
        let crossing = tri([0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]);
        for b in [inside, crossing] {
            assert!(overlap_2d(&a, &b, 1e-4) && overlap_2d(&b, &a, 1e-4));
            let flipped = [b[0], b[2], b[1]];
            assert!(overlap_2d(&a, &flipped, 1e-4));
        }
        // Sharing the long edge (the other half of a quad), a corner, or apart.
        let other_half = tri([1.0, 0.0], [1.0, 1.0], [0.0, 1.0]);
        let corner = tri([1.0, 0.0], [2.0, 0.0], [1.0, 1.0]);
        let apart = tri([2.0, 2.0], [3.0, 2.0], [2.0, 3.0]);
        for b in [other_half, corner, apart] {
            assert!(!overlap_2d(&a, &b, 1e-4) && !overlap_2d(&b, &a, 1e-4));
        }
    }

    #[test]
    fn a_plane_is_the_same_whichever_way_its_triangle_winds() {
        let p = [
            Vec3::new(0.0, 2.0, 0.0),
            Vec3::new(1.0, 2.0, 0.0),
            Vec3::new(0.0, 2.0, 1.0),
        ];
        let a = Planar::new(p, 0).unwrap();
        let b = Planar::new([p[0], p[2], p[1]], 0).unwrap();
        assert_eq!(a.n, Vec3::Y);
        assert_eq!((a.n, a.d), (b.n, b.d));
        assert!(Planar::new([p[0], p[0], p[1]], 0).is_none());
    }

    /// A ceiling quad at y = 2 (material 0) and a lamp quad (material 1, emitting) at height
    /// `lamp_y`, inside it.
    fn room(lamp_y: f32) -> Mesh {
        let quad =
            |y: f32, r: f32| [[-r, -r], [r, -r], [r, r], [-r, r]].map(|[x, z]| Vec3::new(x, y, z));
        let mut positions = quad(2.0, 1.0).to_vec();
        positions.extend(quad(lamp_y, 0.2));
        let lamp = crate::bsdf::Material {
            ke: Vec3::splat(5.0),
            ..Default::default()
        };
        Mesh {
            positions,
            triangles: vec![[0, 1, 2], [0, 2, 3], [4, 6, 5], [4, 7, 6]],
            tri_material: vec![0, 0, 1, 1],
            materials: vec![crate::bsdf::Material::default(), lamp],
            material_names: vec!["ceiling".into(), "lamp".into()],
            ..Default::default()
        }
    }

    #[test]
    fn a_lamp_in_the_plane_of_the_ceiling_is_warned_of_and_one_below_it_is_not() {
        let w = warnings("s.obj", &room(2.0), &[], &[]);
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(w[0].starts_with("s.obj: 2 emitting triangle(s) of material 'lamp' lie in the plane of faces of material 'ceiling'"), "{}", w[0]);
        // A millimetre below a ceiling 2 m high is off it; a micrometre is not.
        assert!(warnings("s.obj", &room(1.999), &[], &[]).is_empty());
        assert_eq!(warnings("s.obj", &room(2.0 - 1e-6), &[], &[]).len(), 1);
        // Nor far away along the plane: the same room moved 10^4 along x and z.
        let mut far = room(2.0);
        far.positions
            .iter_mut()
            .for_each(|p| *p += Vec3::new(1e4, 0.0, 1e4));
        assert_eq!(warnings("s.obj", &far, &[], &[]).len(), 1);
        let mut far = room(1.999);
        far.positions
            .iter_mut()
            .for_each(|p| *p += Vec3::new(1e4, 0.0, 1e4));
        assert!(warnings("s.obj", &far, &[], &[]).is_empty());
    }

    #[test]
    fn a_ceiling_placed_as_an_instance_is_looked_into_too() {
        // The ceiling as a prototype placed twice (at y = 1 and, moved up by 1, at y = 2),
        // the lamp alone in the scene's own mesh.
        let own = room(2.0);
        let proto = Prototype {
            positions: own.positions[..4].iter().map(|p| *p - Vec3::Y).collect(),
            normals: Vec::new(),
            uvs: Vec::new(),
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            tri_material: vec![0, 0],
            tri_normal: Vec::new(),
        };
        let mesh = Mesh {
            positions: own.positions.clone(),
            triangles: own.triangles[2..].to_vec(),
            tri_material: vec![1, 1],
            ..own
        };
        let at = |y: f64| Instance::new(0, &glam::DMat4::from_translation(glam::DVec3::Y * y));
        let protos = [proto];
        assert!(warnings("s.toml", &mesh, &protos, &[at(0.0)]).is_empty());
        let w = warnings("s.toml", &mesh, &protos, &[at(0.0), at(1.0)]);
        assert_eq!(w.len(), 1, "{w:?}");
    }

    #[test]
    fn a_small_lamp_on_a_large_ceiling_is_found() {
        // A 0.4 m lamp in the plane of a 2 km ceiling: the overlap was asked to exceed 1e-4 of
        // the larger triangle's size, 0.28 m, more than the lamp's halves on either side of the
        // ceiling's diagonal overlap each of its triangles by.
        let mut big = room(2.0);
        for p in &mut big.positions[..4] {
            *p = Vec3::new(p.x * 1000.0, p.y, p.z * 1000.0);
        }
        assert_eq!(warnings("s.obj", &big, &[], &[]).len(), 1);
    }
}
