//! Triangles too large for single precision beside how near the camera comes to them.
//!
//! Embree intersects a ray with a triangle in single precision, from the triangle's vertices
//! taken relative to the ray's origin, so the distance to a hit is found to a precision that
//! falls as `R / d` grows, `R` being how far the vertices lie from the origin and `d` the
//! distance of the hit. A ground quad 5x10^6 units across seen from 1.5 units above it
//! (`R / d` about 5x10^6) lost 8% of `mis-exact`'s reuses to visibility tests that met the quad
//! short of the hit (its floor 10% dark, without a word); at 2x10^6 across, 2.6%; at 5x10^5,
//! 0.7%; at 5x10^4, none measurable. Such a scene is warned of at load.
use super::Scene;
use glam::{DVec3, Vec3};

/// `R / d` above which a triangle is warned of: about where a reuse's visibility tests start
/// to fail measurably (half a percent of them, by the figures above).
pub const MAX_REACH: f32 = 3.0e5;

/// At most this many frames' eyes are tried, spread over the animation.
const EYES: u32 = 8;

/// The worst triangle of a set: `R / d`, `R`, `d`.
#[derive(Clone, Copy, Default)]
struct Worst {
    count: usize,
    ratio: f32,
    reach: f32,
    near: f32,
}

impl Worst {
    fn merge(a: Worst, b: Worst) -> Worst {
        let w = if b.ratio > a.ratio { b } else { a };
        Worst {
            count: a.count + b.count,
            ..w
        }
    }
}

/// What of a triangle does not depend on the eye: its corners, its box and the box's diagonal.
struct Tri {
    v: [Vec3; 3],
    lo: Vec3,
    hi: Vec3,
    diagonal: f32,
}

impl Tri {
    fn new(v: [Vec3; 3]) -> Tri {
        let (lo, hi) = (v[0].min(v[1]).min(v[2]), v[0].max(v[1]).max(v[2]));
        Tri {
            v,
            lo,
            hi,
            diagonal: (hi - lo).length(),
        }
    }

    /// `R / d` seen from `eye`, `d` its distance to the triangle; `None` where it cannot
    /// exceed `MAX_REACH` (found cheaply by the box, which is nearer than the triangle).
    fn reach(&self, eye: Vec3) -> Option<(f32, f32, f32)> {
        let to_box = distance_to_box(eye, self.lo, self.hi);
        // R <= to_box + diagonal, and d >= to_box.
        if to_box + self.diagonal <= MAX_REACH * to_box {
            return None;
        }
        let near = distance_to_triangle(eye, self.v);
        let far = self.v.iter().map(|p| p.distance(eye)).fold(0.0, f32::max);
        (far > MAX_REACH * near).then(|| (far / near.max(f32::MIN_POSITIVE), far, near))
    }
}

/// The distance from `p` to the triangle `v` (its nearest point, inside or on an edge or a
/// corner), in double precision: the triangles weighed here reach `MAX_REACH` times farther
/// than they pass, so single precision would lose the distance in their coordinates. An eye
/// in a triangle's plane and inside its box may lie far from it; bounding the distance by the
/// plane's and the box's had called that eye's distance 0 and warned of any triangle so seen.
fn distance_to_triangle(p: Vec3, v: [Vec3; 3]) -> f32 {
    let (p, a, b, c) = (
        p.as_dvec3(),
        v[0].as_dvec3(),
        v[1].as_dvec3(),
        v[2].as_dvec3(),
    );
    // The nearest point on each edge (or the point itself where it projects inside).
    let on_segment = |s: DVec3, e: DVec3| {
        let d = e - s;
        let len2 = d.length_squared();
        let t = if len2 > 0.0 {
            ((p - s).dot(d) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        p.distance(s + d * t)
    };
    // Inside the prism over the triangle: the distance to the plane; elsewhere (and for a
    // triangle without area) to the nearest edge.
    let n = (b - a).cross(c - a);
    let inside = n.length_squared() > 0.0
        && [(a, b), (b, c), (c, a)]
            .iter()
            .all(|&(s, e)| (e - s).cross(p - s).dot(n) >= 0.0);
    let d = if inside {
        (p - a).dot(n.normalize()).abs()
    } else {
        on_segment(a, b).min(on_segment(b, c)).min(on_segment(c, a))
    };
    d as f32
}

/// The distance from `p` to the box from `lo` to `hi` (0 inside it).
fn distance_to_box(p: Vec3, lo: Vec3, hi: Vec3) -> f32 {
    (lo - p).max(p - hi).max(Vec3::ZERO).length()
}

/// The triangles `tris` of `positions` that some eye of `eyes` (in the same space) sees with
/// `R / d` above `MAX_REACH`: their count and the worst, its distances times `scale` (world
/// units, where the triangles are a placed prototype's).
fn worst_of(positions: &[Vec3], tris: &[[u32; 3]], eyes: &[Vec3], scale: f32) -> Worst {
    // One thread: the scene loads before the render's pool exists, and rayon's global pool
    // would start a thread per core whatever `--threads` says (and panic where it cannot,
    // under `ulimit -v`).
    let worst = tris
        .iter()
        .filter_map(|t| {
            let tri = Tri::new(t.map(|i| positions[i as usize]));
            eyes.iter()
                .filter_map(|&e| tri.reach(e))
                .max_by(|a, b| a.0.total_cmp(&b.0))
        })
        .map(|(ratio, reach, near)| Worst {
            count: 1,
            ratio,
            reach,
            near,
        })
        .fold(Worst::default(), Worst::merge);
    Worst {
        reach: worst.reach * scale,
        near: worst.near * scale,
        ..worst
    }
}

/// A prototype's box and the largest box diagonal of its triangles: an instance whose every
/// eye (in the prototype's space) lies far enough from the box that no triangle can pass
/// `Tri::reach`'s first test is passed over whole (a forest of 1000 placed trees of 10^5
/// triangles took 8 s to load, each triangle tried from each eye).
struct Bound {
    lo: Vec3,
    hi: Vec3,
    diagonal: f32,
}

impl Bound {
    fn of(positions: &[Vec3], tris: &[[u32; 3]]) -> Bound {
        let mut b = Bound {
            lo: Vec3::INFINITY,
            hi: Vec3::NEG_INFINITY,
            diagonal: 0.0,
        };
        for t in tris {
            let t = Tri::new(t.map(|i| positions[i as usize]));
            (b.lo, b.hi) = (b.lo.min(t.lo), b.hi.max(t.hi));
            b.diagonal = b.diagonal.max(t.diagonal);
        }
        b
    }

    /// Whether no triangle within can exceed `MAX_REACH` from `eye`: each lies at least as far
    /// from `eye` as the box does, and its diagonal is at most `diagonal`, so its
    /// `(to_box + diagonal) / to_box` is at most `1 + diagonal / distance`. Two units of
    /// margin keep rounding from passing over one that `Tri::reach` would weigh.
    fn clear_of(&self, eye: Vec3) -> bool {
        let d = distance_to_box(eye, self.lo, self.hi);
        d > 0.0 && self.diagonal <= (MAX_REACH - 2.0) * d
    }
}

/// A warning naming the triangles of `scene` that reach more than `MAX_REACH` times farther
/// from some frame's eye than they pass by it.
pub fn near_huge_triangles(scene: &Scene, label: &str) -> Option<String> {
    let frames = scene.frames.max(1);
    let eyes: Vec<Vec3> = (0..EYES.min(frames))
        .map(|k| {
            let f = if frames <= EYES {
                k
            } else {
                (k as u64 * (frames - 1) as u64 / (EYES - 1) as u64) as u32
            };
            scene.camera(f, 2, 2).eye
        })
        .filter(|e| e.is_finite())
        .collect();
    let mut worst = worst_of(&scene.positions, &scene.triangles, &eyes, 1.0);
    let bounds: Vec<Bound> = scene
        .prototypes
        .iter()
        .map(|p| Bound::of(&p.positions, &p.triangles))
        .collect();
    for i in &scene.instances {
        let (p, b) = (
            &scene.prototypes[i.proto as usize],
            &bounds[i.proto as usize],
        );
        // In the prototype's own space, as Embree intersects an instance (`R / d` is unchanged
        // by a uniform scale and a rotation).
        let inv = i.to_world.inverse();
        let local: Vec<Vec3> = eyes.iter().map(|&e| inv.transform_point3(e)).collect();
        if local.iter().all(|&e| b.clear_of(e)) {
            continue;
        }
        // Distances said in world units: the placement's mean scale.
        let scale = glam::Mat3::from_mat4(i.to_world).determinant().abs().cbrt();
        worst = Worst::merge(worst, worst_of(&p.positions, &p.triangles, &local, scale));
    }
    (worst.count > 0).then(|| {
        format!(
            "{label}: {} triangle(s) reach up to {:.2e} units from the camera but pass within \
             {:.2e} of it ({:.0e} times nearer): single precision cannot place the hits on them \
             exactly enough, so their shadows and contacts may be off, and the reuse methods lose \
             visibility tests to them (split them into smaller triangles)",
            worst.count, worst.reach, worst.near, worst.ratio,
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The least distance from `p` to points spread densely over the triangle (barycentric
    /// grid), an upper bound within about a grid cell of the true distance.
    fn sampled(p: Vec3, v: [Vec3; 3]) -> f32 {
        const N: u32 = 400;
        let mut best = f32::INFINITY;
        for i in 0..=N {
            for j in 0..=N - i {
                let (a, b) = (i as f32 / N as f32, j as f32 / N as f32);
                let q = v[0] * (1.0 - a - b) + v[1] * a + v[2] * b;
                best = best.min(q.distance(p));
            }
        }
        best
    }

    #[test]
    fn the_distance_to_a_triangle_is_its_nearest_points() {
        let v = [
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(4.0, 0.0, 1.0),
            Vec3::new(1.0, 3.0, -1.0),
        ];
        // Above the inside, beyond each edge, beyond each corner, in the plane outside it.
        let points = [
            Vec3::new(1.5, 1.0, 2.0),
            Vec3::new(2.0, -2.0, 0.5),
            Vec3::new(4.0, 3.0, 0.0),
            Vec3::new(-2.0, 1.5, 0.0),
            Vec3::new(-1.0, -1.0, -1.0),
            Vec3::new(6.0, -1.0, 2.0),
            Vec3::new(1.0, 5.0, -2.0),
            Vec3::new(-3.0, 0.0, 0.0),
        ];
        for p in points {
            let (d, s) = (distance_to_triangle(p, v), sampled(p, v));
            assert!(d <= s + 1e-5 && s - d < 0.02, "{p}: {d} against {s}");
        }
        // A triangle without area is its segment.
        let flat = [Vec3::ZERO, Vec3::X * 2.0, Vec3::X];
        assert!((distance_to_triangle(Vec3::new(1.0, 3.0, 4.0), flat) - 5.0).abs() < 1e-6);
        assert!((distance_to_triangle(Vec3::new(-3.0, 4.0, 0.0), flat) - 5.0).abs() < 1e-6);
    }

    #[test]
    fn an_eye_in_a_huge_triangles_plane_but_far_from_it_is_not_near() {
        // The triangle x >= y of the square 0..10^6 in the plane z = 0; the eye in that plane,
        // inside the box but 3.5x10^5 from the triangle.
        let v = [
            Vec3::ZERO,
            Vec3::new(1.0e6, 0.0, 0.0),
            Vec3::new(1.0e6, 1.0e6, 0.0),
        ];
        let tri = Tri::new(v);
        assert!(tri.reach(Vec3::new(1.0, 5.0e5, 0.0)).is_none());
        assert!(tri.reach(Vec3::new(1.0, 5.0e5, 1.0e-3)).is_none());
        // Just above the triangle, it is.
        let (ratio, _, near) = tri.reach(Vec3::new(5.0e5, 1.0, 1.5)).expect("near");
        assert!((near - 1.5).abs() < 1e-3 && ratio > 4.0e5, "{ratio} {near}");
    }
}
