//! Adaptive native samples (`--adaptive F`, the paper's future work; docs/estimators.md,
//! "adaptive counts"): for every pixel of every frame of a group, how many native samples it
//! shoots in this group, decided from the geometry before any sample is drawn, so that the exact
//! densities can use them and the estimator stays unbiased.
//!
//! One pilot ray per 2x2 block of pixels, through the block's centre, finds the point x it sees.
//! Eye k shoots `n_r` samples per pixel, so the count of its samples expected in a pixel of frame
//! m around x is `n_r (J_k(x) / A_pix,k) / (J_m(x) / A_pix,m)` where it sees x (one visibility
//! test) and 0 where it does not. A pixel that every eye of the group sees expects about
//! `n_f n_r`; one at a border, a disocclusion or a cut expects fewer. The block's pixels top
//! their expectation up to `target n_f n_r` in whole samples:
//! `n_r + clamp(floor(target n_f n_r - expected), 0, (n_f - 1) n_r)`. The pilot rays are
//! deterministic (block centres), so the counts are independent of every sample.
use super::shade::Target;
use crate::embree::Ray;
use crate::film::tiles::{place_tile, Tile};
use crate::integrator::{Integrator, RayCounts};
use glam::Vec2;
use rayon::prelude::*;

/// Side of the pixel blocks that share one pilot ray.
const PILOT_BLOCK: u32 = 2;

/// The native counts of every pixel of every frame of `group` (frame-major), for the `work`
/// items (frame, tile index into `tile_list`); and the pilot and visibility rays traced.
pub fn adaptive_counts(
    integrator: &Integrator,
    group: &[Target],
    spp: u32,
    target: f32,
    work: &[(usize, usize)],
    tile_list: &[Tile],
) -> (Vec<Vec<u16>>, RayCounts) {
    let scene = integrator.scene;
    let n_f = group.len() as u32;
    let full = target * (n_f * spp) as f32;
    let cap = ((n_f - 1) * spp) as f32;
    let per_tile: Vec<(Vec<u16>, RayCounts)> = work
        .par_iter()
        .map(|&(m, t)| {
            let (x0, y0, x1, y1) = tile_list[t];
            let cam_m = group[m].cam;
            let mut rays = RayCounts::default();
            // `RenderOptions::validate` keeps `spp` within a u16.
            let base = u16::try_from(spp).expect("adaptive spp fits 16 bits");
            let mut out = vec![base; ((x1 - x0) * (y1 - y0)) as usize];
            for by in (y0..y1).step_by(PILOT_BLOCK as usize) {
                for bx in (x0..x1).step_by(PILOT_BLOCK as usize) {
                    let (ex, ey) = ((bx + PILOT_BLOCK).min(x1), (by + PILOT_BLOCK).min(y1));
                    let r = Vec2::new((bx + ex) as f32, (by + ey) as f32) * 0.5;
                    rays.primary += 1;
                    let Some(sp) = scene
                        .geometry
                        .intersect1(&Ray::new(cam_m.eye, cam_m.direction(r)))
                        .map(|hit| scene.surface(&hit))
                    else {
                        continue; // nothing there to reuse into: no top-up
                    };
                    let own = cam_m.jacobian(sp.p, sp.ng) / cam_m.pixel_area();
                    if own <= 0.0 {
                        continue;
                    }
                    let mut expected = spp as f32;
                    for (k, t) in group.iter().enumerate() {
                        if k == m || t.cam.pixel_of(sp.p).is_none() {
                            continue;
                        }
                        rays.visibility += 1;
                        let ray = Ray::from_eye(t.cam.eye, sp.p, sp.ng, scene.offset_floor);
                        if !scene.geometry.occluded1(&ray) {
                            let ja = t.cam.jacobian(sp.p, sp.ng) / t.cam.pixel_area();
                            expected += spp as f32 * ja / own;
                        }
                    }
                    let n = spp + (full - expected).floor().clamp(0.0, cap) as u32;
                    // Capped: a count is 16 bits, and the densities read the counts stored.
                    let n = n.min(u16::MAX as u32) as u16;
                    for y in by..ey {
                        for x in bx..ex {
                            out[((y - y0) * (x1 - x0) + x - x0) as usize] = n;
                        }
                    }
                }
            }
            (out, rays)
        })
        .collect();
    let (w, h) = (group[0].cam.width, group[0].cam.height);
    let mut counts = vec![vec![0u16; (w * h) as usize]; group.len()];
    let mut rays = RayCounts::default();
    for (&(m, t), (c, r)) in work.iter().zip(per_tile) {
        place_tile(&mut counts[m], w, tile_list[t], &c);
        rays.add(&r);
    }
    (counts, rays)
}
