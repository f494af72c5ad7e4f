//! Where a tile's native hits land in the eyes of their group: the projection onto each eye's
//! film, one visibility test per hit from the eye towards it, and the per-eye terms of the
//! weights (the direction to the eye and the film density `J_k / A_pix,k`).
//!
//! The pass goes eye by eye over a tile's hits, eight hits at a time in structure-of-arrays
//! form (`HitLanes`), so that the compiler computes the projections, square roots and divisions
//! of eight hits in SIMD lanes; each lane takes the operations of `Camera::project`,
//! `Camera::view_terms` and `Ray::from_eye` in the same order, so the same bits. The visibility
//! rays of a tile converge on the eye, so they are coherent and go through `rtcOccluded16`
//! packets (or single rays, `--visibility single`).
use crate::camera::Camera;
use crate::embree::{Packet16, Ray, SPAWN_EPS};
use crate::integrator::{FirstHit, Integrator, Tally};
use glam::Vec3;

/// Per hit and target eye: the pixel it lands in (if on the target's film and visible).
pub type Landing = Option<u32>;

/// A native sample that hit something: (pixel, sample index, first-hit record).
pub type NativeHit = (u32, u32, FirstHit);

/// Hits per chunk of the pass: two SSE vectors, or one AVX vector.
const LANES: usize = 8;

/// How a hit is seen from one eye of its group: the weights' `EyeTerms` before the sample
/// counts.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EyeView {
    /// Unit direction from the hit to the eye (`Camera::view_terms`).
    pub wo: Vec3,
    /// `J_k / A_pix,k`: the eye's film density at the hit, in pixels per unit area, whether or
    /// not the eye sees it (the landing says that).
    pub j_over_a: f32,
}

/// The points and geometric normals of a tile's hits in structure-of-arrays form, padded with
/// zeros to a whole number of chunks.
#[derive(Default)]
pub struct HitLanes {
    p: [Vec<f32>; 3],
    n: [Vec<f32>; 3],
    len: usize,
}

impl HitLanes {
    /// Lay out the points and geometric normals of `hits`.
    pub fn fill(&mut self, hits: &[NativeHit]) {
        self.fill_points(hits.iter().map(|h| (h.2.sp.p, h.2.sp.ng)));
    }

    /// Lay out points and their unit geometric normals.
    pub fn fill_points(&mut self, points: impl Iterator<Item = (Vec3, Vec3)> + Clone) {
        for c in 0..3 {
            self.p[c].clear();
            self.n[c].clear();
            self.p[c].extend(points.clone().map(|(p, _)| p[c]));
            self.n[c].extend(points.clone().map(|(_, n)| n[c]));
        }
        self.len = self.p[0].len();
        let padded = self.len.div_ceil(LANES) * LANES;
        for c in 0..3 {
            self.p[c].resize(padded, 0.0);
            self.n[c].resize(padded, 0.0);
        }
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Bytes per hit (for `RenderOptions::memory_estimate`).
    pub const fn bytes_per_hit() -> usize {
        6 * std::mem::size_of::<f32>()
    }
}

/// What one eye makes of a chunk of hits, lane by lane.
#[derive(Default)]
struct Chunk {
    /// Raster position, where the hit is in front of the eye and on its film (`on`).
    on: [bool; LANES],
    rx: [f32; LANES],
    ry: [f32; LANES],
    wo: [[f32; LANES]; 3],
    j_over_a: [f32; LANES],
    /// The visibility ray's direction (`Ray::from_eye`: the eye to the hit's offset point).
    dir: [[f32; LANES]; 3],
}

/// Eye `cam` (film area of a pixel `pixel_area`) on hits `at..at + LANES` of `h`: each lane's
/// arithmetic is `Camera::project`, `Camera::view_terms` (divided by the pixel area; only with
/// `VIEWS`) and `Ray::from_eye` written out, operation for operation (`tests` checks the bits).
#[inline(always)]
fn chunk<const VIEWS: bool>(
    (cam, pixel_area): (&Camera, f32),
    h: &HitLanes,
    at: usize,
    floor: f32,
    out: &mut Chunk,
) {
    let (e, f, r, u) = (cam.eye, cam.forward, cam.right, cam.up);
    let (w, ht) = (cam.width as f32, cam.height as f32);
    let (tan, aspect) = (cam.tan_half_fov, cam.aspect);
    let lanes = |v: &[f32]| -> [f32; LANES] { v[at..at + LANES].try_into().expect("padded") };
    let p: [[f32; LANES]; 3] = std::array::from_fn(|c| lanes(&h.p[c]));
    let n: [[f32; LANES]; 3] = std::array::from_fn(|c| lanes(&h.n[c]));
    for l in 0..LANES {
        let (px, py, pz) = (p[0][l], p[1][l], p[2][l]);
        let (nx, ny, nz) = (n[0][l], n[1][l], n[2][l]);
        // c = x - eye
        let (cx, cy, cz) = (px - e.x, py - e.y, pz - e.z);
        // project
        let z = cx * f.x + cy * f.y + cz * f.z;
        let sx = (cx * r.x + cy * r.y + cz * r.z) / (z * tan * aspect);
        let sy = (cx * u.x + cy * u.y + cz * u.z) / (z * tan);
        let rx = (sx + 1.0) * 0.5 * w;
        let ry = (1.0 - sy) * 0.5 * ht;
        out.on[l] = z > 0.0 && rx >= 0.0 && ry >= 0.0 && rx < w && ry < ht;
        out.rx[l] = rx;
        out.ry[l] = ry;
        if VIEWS {
            // view_terms
            let d2 = cx * cx + cy * cy + cz * cz;
            let d = d2.sqrt();
            let rcp = 1.0 / d;
            out.wo[0][l] = (e.x - px) * rcp;
            out.wo[1][l] = (e.y - py) * rcp;
            out.wo[2][l] = (e.z - pz) * rcp;
            let cos_t = z / d;
            let cos_x = (nx * -cx + ny * -cy + nz * -cz).abs() / d;
            out.j_over_a[l] = cos_x / (cos_t * cos_t * cos_t * d2) / pixel_area;
        }
        // from_eye: the hit's point offset off its surface towards the eye
        let scale = SPAWN_EPS * (floor + px.abs().max(py.abs().max(pz.abs())));
        let (tx, ty, tz) = (e.x - px, e.y - py, e.z - pz);
        let s = if nx * tx + ny * ty + nz * tz >= 0.0 {
            scale
        } else {
            -scale
        };
        // `p + n * scale` with `n` the normal on the eye's side: `-ng * scale` is
        // `ng * -scale` to the bit (negation is exact).
        out.dir[0][l] = (px + nx * s) - e.x;
        out.dir[1][l] = (py + ny * s) - e.y;
        out.dir[2][l] = (pz + nz * s) - e.z;
    }
}

/// Fill `land[hi * n_f + k]` for eye `k` (camera `cam`, film area of a pixel `pixel_area`) of
/// the tile's hits `h`: project every hit and test its visibility from the eye; with `views`,
/// also `views[hi * n_f + k]`, how the eye sees each hit. For the hits' own eye (`native`),
/// which sees each hit in the pixel it was shot through (the caller's landing), the view terms
/// alone.
///
/// Compiled for AVX-512 and AVX2 besides the portable build and chosen at run time, so that a
/// chunk's eight lanes are one vector (IEEE arithmetic with nothing fused: the same bits in all).
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512cd+avx512dq+avx512vl",
    "x86_64+avx2",
))]
#[allow(clippy::too_many_arguments)]
pub fn landings(
    integrator: &Integrator,
    (cam, pixel_area): (&Camera, f32),
    h: &HitLanes,
    (k, n_f): (usize, usize),
    native: bool,
    packets: bool,
    land: &mut [Landing],
    mut views: Option<&mut [EyeView]>,
    tally: &mut Tally,
) {
    let geometry = &integrator.scene.geometry;
    let mut packet = Packet16::new();
    let mut lanes: [usize; 16] = [0; 16];
    let mut queued = 0;
    let flush = |packet: &mut Packet16, lanes: &[usize], n: usize, land: &mut [Landing]| {
        geometry.occluded16(packet);
        for (lane, &hi) in lanes.iter().enumerate().take(n) {
            if packet.occluded(lane) {
                land[hi * n_f + k] = None;
            }
        }
        packet.clear();
    };
    let mut c = Chunk::default();
    let floor = integrator.scene.offset_floor;
    for at in (0..h.len()).step_by(LANES) {
        // Without `views` (`bench`'s visibility costs), the projection and the ray alone.
        if views.is_some() {
            chunk::<true>((cam, pixel_area), h, at, floor, &mut c);
        } else {
            chunk::<false>((cam, pixel_area), h, at, floor, &mut c);
        }
        for l in 0..LANES.min(h.len() - at) {
            let hi = at + l;
            if let Some(v) = views.as_deref_mut() {
                v[hi * n_f + k] = EyeView {
                    wo: Vec3::new(c.wo[0][l], c.wo[1][l], c.wo[2][l]),
                    j_over_a: c.j_over_a[l],
                };
            }
            if native || !c.on[l] {
                continue;
            }
            land[hi * n_f + k] = Some(c.ry[l] as u32 * cam.width + c.rx[l] as u32);
            let ray = Ray::from_eye_dir(cam.eye, Vec3::new(c.dir[0][l], c.dir[1][l], c.dir[2][l]));
            tally.counts.visibility += 1;
            if packets {
                packet.set(queued, &ray);
                lanes[queued] = hi;
                queued += 1;
                if queued == 16 {
                    flush(&mut packet, &lanes, queued, land);
                    queued = 0;
                }
            } else if geometry.occluded1(&ray) {
                land[hi * n_f + k] = None;
            }
        }
    }
    if packets && queued > 0 {
        flush(&mut packet, &lanes, queued, land);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Pose;
    use crate::sampling::mix64;

    fn unit(h: u64) -> f32 {
        (h >> 40) as f32 / (1u64 << 24) as f32
    }

    #[test]
    fn the_lanes_give_the_scalar_functions_bits() {
        // Points all around two eyes (in front, behind, off the film, on it, near the eye and
        // far) with normals facing either way: every lane's projection, pixel, view terms and
        // visibility ray are those of `Camera::project`, `Camera::view_terms` and
        // `Ray::from_eye`, to the bit.
        let cams = [
            Camera::from_pose(
                &Pose {
                    eye: Vec3::new(0.3, 1.2, 4.0),
                    view: Vec3::new(-0.1, -0.05, -1.0),
                    up: Vec3::Y,
                    fov: 40.0,
                },
                320,
                240,
            ),
            Camera::from_pose(
                &Pose {
                    eye: Vec3::new(-2.0, 0.5, 1.0),
                    view: Vec3::new(1.0, 0.2, -0.3),
                    up: Vec3::Y,
                    fov: 65.0,
                },
                97,
                61,
            ),
        ];
        let points: Vec<(Vec3, Vec3)> = (0..1003u64)
            .map(|i| {
                let h = |j: u64| unit(mix64(i * 8 + j));
                let p = Vec3::new(h(0) * 8.0 - 4.0, h(1) * 4.0 - 1.0, h(2) * 8.0 - 4.0);
                let n = Vec3::new(h(4) - 0.5, h(5) - 0.5, h(6) - 0.5).normalize();
                (p * (1.0 + h(3)), n)
            })
            .collect();
        let mut lanes = HitLanes::default();
        lanes.fill_points(points.iter().copied());
        assert_eq!(lanes.len(), points.len());
        let mut on_film = 0;
        // Both offset floors: a scene of ordinary size, and one modelled tiny.
        for (cam, floor) in cams.iter().flat_map(|c| [(c, 1.0), (c, 1e-4)]) {
            let area = cam.pixel_area();
            let mut c = Chunk::default();
            for at in (0..points.len()).step_by(LANES) {
                chunk::<true>((cam, area), &lanes, at, floor, &mut c);
                for l in 0..LANES.min(points.len() - at) {
                    let (p, ng) = points[at + l];
                    // The view terms and the ray for every lane (the native eye's terms are
                    // used wherever its hits are, on the film or not).
                    let ray = Ray::from_eye(cam.eye, p, ng, floor);
                    let dir = Vec3::new(c.dir[0][l], c.dir[1][l], c.dir[2][l]);
                    let lane_ray = Ray::from_eye_dir(cam.eye, dir);
                    // Debug prints the shortest decimal that reads back as the same float.
                    assert_eq!(format!("{ray:?}"), format!("{lane_ray:?}"));
                    let (wo, j) = cam.view_terms(p, ng);
                    let wo_l = Vec3::new(c.wo[0][l], c.wo[1][l], c.wo[2][l]);
                    assert_eq!(
                        wo.to_array().map(f32::to_bits),
                        wo_l.to_array().map(f32::to_bits)
                    );
                    assert_eq!((j / area).to_bits(), c.j_over_a[l].to_bits());
                    // The projection where the point is on the film.
                    let r = cam.project(p);
                    assert_eq!(r.is_some(), c.on[l]);
                    if let Some(r) = r {
                        on_film += 1;
                        assert_eq!(r.x.to_bits(), c.rx[l].to_bits());
                        assert_eq!(r.y.to_bits(), c.ry[l].to_bits());
                        assert_eq!(
                            cam.pixel_of(p),
                            Some(c.ry[l] as u32 * cam.width + c.rx[l] as u32)
                        );
                    }
                }
            }
        }
        // 650 of the 2006 (point, eye) pairs are on a film.
        assert!(on_film > 500, "{on_film} points on the films");
    }
}
