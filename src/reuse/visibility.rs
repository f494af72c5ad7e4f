//! Where a tile's native hits land in another eye: projection onto its film and one visibility
//! test per hit, from the eye towards the hit. The rays of a tile converge on the eye, so they
//! are coherent and go through `rtcOccluded16` packets (or single rays, `--visibility single`).
use crate::camera::Camera;
use crate::embree::{Packet16, Ray};
use crate::integrator::{FirstHit, Integrator, Tally};

/// Per hit and target eye: the pixel it lands in (if on the target's film and visible).
pub type Landing = Option<u32>;

/// A native sample that hit something: (pixel, sample index, first-hit record).
pub type NativeHit = (u32, u32, FirstHit);

/// Fill `land[hi * n_f + k]` for eye `k` (camera `cam`): project every hit, test visibility
/// from the eye.
#[allow(clippy::too_many_arguments)]
pub fn visibility(
    integrator: &Integrator,
    cam: &Camera,
    hits: &[NativeHit],
    k: usize,
    n_f: usize,
    packets: bool,
    land: &mut [Landing],
    tally: &mut Tally,
) {
    let geometry = &integrator.scene.geometry;
    let mut packet = Packet16::new();
    let mut lanes: [usize; 16] = [0; 16];
    let mut n = 0;
    let flush = |packet: &mut Packet16, lanes: &[usize], n: usize, land: &mut [Landing]| {
        geometry.occluded16(packet);
        for (lane, &hi) in lanes.iter().enumerate().take(n) {
            if packet.occluded(lane) {
                land[hi * n_f + k] = None;
            }
        }
        packet.clear();
    };
    for (hi, (_, _, fh)) in hits.iter().enumerate() {
        let Some(i) = cam.pixel_of(fh.sp.p) else {
            continue;
        };
        land[hi * n_f + k] = Some(i);
        let ray = Ray::from_eye(cam.eye, fh.sp.p, fh.sp.ng);
        tally.counts.visibility += 1;
        if packets {
            packet.set(n, &ray);
            lanes[n] = hi;
            n += 1;
            if n == 16 {
                flush(&mut packet, &lanes, n, land);
                n = 0;
            }
        } else if geometry.occluded1(&ray) {
            land[hi * n_f + k] = None;
        }
    }
    if packets && n > 0 {
        flush(&mut packet, &lanes, n, land);
    }
}
