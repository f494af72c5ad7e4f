//! The reuse kernel: trace the native samples of one tile of one frame of a group, find where
//! each hit lands in every eye of the group, and splat its weighted value into each of those
//! frames' films.
//!
//! Streaming and determinism: contributions are splatted as they are made into per-frame
//! fixed-point accumulators (`film::FrameAccum`) with a hashed rounding dither: integer addition
//! is associative, so the frames are bitwise identical for any thread count.
use super::visibility::{visibility, Landing, NativeHit};
use super::weights::{EyeTerms, Weighing};
use super::Params;
use crate::camera::Camera;
use crate::film::tiles::Tile;
use crate::film::FrameAccum;
use crate::integrator::{Integrator, Tally};
use crate::sampling::{mix64, Sampler};
use glam::Vec2;

/// One frame of a group: its eye and its film.
#[derive(Clone, Copy)]
pub struct Target<'a> {
    pub cam: &'a Camera,
    pub film: &'a FrameAccum,
}

/// Trace the native samples of tile `tile` of frame `group[m]` (the group starts at frame `g0`)
/// and splat every reuse of them into the group's films. `counts`: per frame of the group, the
/// adaptive native count of each pixel (`None`: `n_r` everywhere). Returns the number of
/// non-finite contributions dropped.
#[allow(clippy::too_many_arguments)]
pub fn shade_tile(
    integrator: &Integrator,
    p: &Params,
    group: &[Target],
    m: usize,
    (x0, y0, x1, y1): Tile,
    g0: u32,
    counts: Option<&[Vec<u16>]>,
    tally: &mut Tally,
) -> u64 {
    let native = group[m];
    let cam_m = native.cam;
    let native_frame = native.film.frame();
    let w = cam_m.width;
    let spp = p.spp;
    let n_f = group.len();
    // Native samples of eye k in its pixel i: `--spp`, or the adaptive count.
    let n_at = |k: usize, i: u32| counts.map_or(spp, |c| c[k][i as usize] as u32);
    // Sample indices of a frame in a group: a stride that fits the most samples a pixel shoots.
    let stride = if counts.is_some() {
        spp * n_f as u32
    } else {
        spp
    };
    let mut landed_native = 0u64;
    let mut hits: Vec<NativeHit> = Vec::new();
    for y in y0..y1 {
        for x in x0..x1 {
            let pixel = y * w + x;
            let n_p = n_at(m, pixel);
            native.film.land(pixel as usize, n_p);
            landed_native += n_p as u64;
            for s in 0..n_p {
                // Sample index: the frame's position in the group keeps each group's samples of a
                // frame independent; with one frame per group this is the independent tracer's.
                let index = (native_frame - g0) * stride + s;
                let mut sampler = Sampler::new(p.seed, native_frame, pixel, index);
                let r = Vec2::new(x as f32, y as f32) + sampler.next_2d();
                if let Some(fh) =
                    integrator.trace_first_hit(cam_m.eye, cam_m.direction(r), &mut sampler, tally)
                {
                    hits.push((pixel, index, fh));
                }
            }
        }
    }
    // Where each hit lands in each eye of the group (None: occluded or off the film).
    let mut land: Vec<Landing> = vec![None; hits.len() * n_f];
    for (k, t) in group.iter().enumerate() {
        if k == m {
            for (hi, (pixel, _, _)) in hits.iter().enumerate() {
                land[hi * n_f + k] = Some(*pixel);
            }
            continue;
        }
        visibility(
            integrator, t.cam, &hits, k, n_f, p.packets, &mut land, tally,
        );
    }
    let weights = p.method.weights();
    let mut bad = 0u64;
    // Reuse bookkeeping summed locally and added once per tile: (tried, lost) per target eye.
    let mut loss = vec![(0u64, 0u64); n_f];
    let mut landed = vec![0u64; n_f];
    landed[m] = landed_native;
    let mut eyes: Vec<EyeTerms> = Vec::with_capacity(n_f);
    for (hi, (pixel, index, fh)) in hits.iter().enumerate() {
        let x = fh.sp.p;
        eyes.clear();
        for (k, t) in group.iter().enumerate() {
            let wo = (t.cam.eye - x).normalize();
            let (j_over_a, n) = match land[hi * n_f + k] {
                Some(i) => (
                    t.cam.jacobian(x, fh.sp.ng) / t.cam.pixel_area(),
                    n_at(k, i) as f32,
                ),
                None => (0.0, 0.0),
            };
            eyes.push(EyeTerms { wo, j_over_a, n });
        }
        let weighing = Weighing::new(weights, integrator, fh, &eyes, spp);
        for (k, t) in group.iter().enumerate() {
            let Some(i) = land[hi * n_f + k] else {
                if k != m {
                    loss[k].0 += 1;
                    loss[k].1 += 1;
                    // Only reuses lost to occlusion fall on a pixel of the target.
                    if t.film.layout.loss {
                        if let Some(i) = t.cam.pixel_of(x) {
                            t.film.try_reuse(i as usize, true);
                        }
                    }
                }
                continue;
            };
            let i = i as usize;
            if k != m {
                loss[k].0 += 1;
                landed[k] += 1;
                t.film.land(i, 1);
                t.film.try_reuse(i, false);
            }
            let v = weighing.value(t.cam.eye, &eyes[k]);
            // The rounding dither: a hash of the native sample and the target frame.
            let dither = mix64(
                mix64(p.seed ^ ((native_frame as u64) << 32 | *pixel as u64))
                    ^ ((*index as u64) << 32 | t.film.frame() as u64),
            );
            if !t.film.splat(i, v, dither) {
                bad += 1;
            }
        }
    }
    for ((t, (tried, lost)), n) in group.iter().zip(loss).zip(landed) {
        t.film.add_counts(n, tried, lost);
    }
    bad
}
