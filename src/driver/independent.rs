//! The independent tracer's frame loop: every frame path-traced on its own, tile by tile.
//!
//! Determinism: pixels are independent (their random numbers are keyed by seed, frame, pixel and
//! sample), each tile's pixels are summed in sample order, and tiles are placed into the frame by
//! index, so the frames are bitwise identical for any thread count.
use super::progress_bar;
use super::run::{Graceful, Run};
use crate::camera::Camera;
use crate::embree::{Hit, Packet16};
use crate::film::tiles::Tile;
use crate::film::tiles::{place_tile, tiles};
use crate::film::{Developed, Sink, View};
use crate::integrator::wavefront::Wavefront;
use crate::integrator::{Integrator, LightSides, RayCounts, Tally};
use crate::sampling::Sampler;
use crate::state::Record;
use anyhow::Result;
use glam::{DVec3, Vec2, Vec3};
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::time::Instant;

/// A rendered frame: linear RGB pixels, ray counts, samples dropped as NaN or infinite, and
/// (benchmark only) each tile's rays.
pub struct FrameResult {
    pub pixels: Vec<Vec3>,
    pub counts: RayCounts,
    pub nonfinite_samples: u64,
    pub ray_logs: Vec<Vec<(crate::embree::Ray, bool)>>,
}

/// A tile's pixel means (row by row) and its samples dropped as NaN or infinite. Per sample
/// index, the primary rays of each 4x4 block of pixels are traced together (one coherent packet,
/// or one ray at a time: `Integrator::primary_hits`), and the tile's paths then advance together
/// (`Integrator::first_hits`). Each pixel keeps its own sampler and sums its samples in index
/// order, so its value depends only on its own hits.
fn render_tile(
    integrator: &Integrator,
    cam: &Camera,
    frame: u32,
    spp: u32,
    seed: u64,
    (x0, y0, x1, y1): Tile,
    t: &mut Tally,
) -> (Vec<Vec3>, u64) {
    const BLOCK: u32 = 4;
    let (w, tw) = (cam.width, x1 - x0);
    let n = (tw * (y1 - y0)) as usize;
    // Summed in f64: an f32 sum of thousands of samples drifts (a pixel of constant radiance
    // 0.3 came out 0.2999004 at 32768 spp, adding in f32), and it drifts the same way every time.
    let mut sums = vec![DVec3::ZERO; n];
    // This sample index's value of each pixel.
    let mut values = vec![Vec3::ZERO; n];
    let mut bad = 0u64;
    let mut packet = Packet16::new();
    let mut wavefront = Wavefront::new();
    // A block's lanes: pixel (index in the tile), sampler and ray direction.
    let mut lanes: Vec<usize> = Vec::with_capacity(16);
    let mut samplers: Vec<Sampler> = Vec::with_capacity(16);
    let mut dirs: Vec<Vec3> = Vec::with_capacity(16);
    // The tile's paths that hit a surface: their pixels (index in the tile), hits and samplers.
    let mut slots: Vec<usize> = Vec::with_capacity(n);
    let mut hits: Vec<Hit> = Vec::with_capacity(n);
    let mut path_samplers: Vec<Sampler> = Vec::with_capacity(n);
    // Each pixel's stream, hashed once per tile (row by row in the tile).
    let streams: Vec<Sampler> = (y0..y1)
        .flat_map(|y| (x0..x1).map(move |x| Sampler::stratified(seed, frame, y * w + x, 0, 0)))
        .collect();
    for s in 0..spp {
        slots.clear();
        hits.clear();
        path_samplers.clear();
        for by in (y0..y1).step_by(BLOCK as usize) {
            for bx in (x0..x1).step_by(BLOCK as usize) {
                lanes.clear();
                samplers.clear();
                dirs.clear();
                for y in by..(by + BLOCK).min(y1) {
                    for x in bx..(bx + BLOCK).min(x1) {
                        let slot = ((y - y0) * tw + (x - x0)) as usize;
                        let mut sampler = streams[slot].at_index(s);
                        let r = Vec2::new(x as f32, y as f32) + sampler.next_2d();
                        lanes.push(slot);
                        dirs.push(cam.direction(r));
                        samplers.push(sampler);
                    }
                }
                let block_hits = integrator.primary_hits(cam.eye, &dirs, &mut packet, t);
                for (lane, (sampler, &slot)) in samplers.drain(..).zip(&lanes).enumerate() {
                    match block_hits[lane] {
                        Some(hit) => {
                            slots.push(slot);
                            hits.push(hit);
                            path_samplers.push(sampler);
                        }
                        None => values[slot] = integrator.scene.env_radiance(dirs[lane]),
                    }
                }
            }
        }
        let recs = integrator.first_hits(
            cam.eye,
            &hits,
            &path_samplers,
            &mut wavefront,
            t,
            LightSides::Native,
        );
        for (rec, &slot) in recs.iter().zip(&slots) {
            values[slot] = rec.radiance(cam.eye);
        }
        for (sum, v) in sums.iter_mut().zip(&values) {
            // A NaN or infinite sample is dropped and counted, never written.
            if v.is_finite() {
                *sum += v.as_dvec3();
            } else {
                bad += 1;
            }
        }
    }
    let px = sums
        .iter()
        .map(|&sum| (sum / spp as f64).as_vec3())
        .collect();
    (px, bad)
}

/// Render one frame with the independent path tracer; `on_tile` sees each finished tile's rays.
pub fn render_frame_independent(
    integrator: &Integrator,
    cam: &Camera,
    frame: u32,
    spp: u32,
    seed: u64,
    log_rays: bool,
    on_tile: &(dyn Fn(&RayCounts) + Sync),
) -> FrameResult {
    let (w, h) = (cam.width, cam.height);
    let tiles = tiles(w, h);
    let results: Vec<(Vec<Vec3>, Tally, u64)> = tiles
        .par_iter()
        .map(|&(x0, y0, x1, y1)| {
            let mut t = if log_rays {
                Tally::logging()
            } else {
                Tally::default()
            };
            let tile = (x0, y0, x1, y1);
            let (px, bad) = render_tile(integrator, cam, frame, spp, seed, tile, &mut t);
            on_tile(&t.counts);
            (px, t, bad)
        })
        .collect();
    let mut pixels = vec![Vec3::ZERO; (w * h) as usize];
    let mut counts = RayCounts::default();
    let mut ray_logs = Vec::new();
    let mut nonfinite_samples = 0;
    for (&tile, (px, t, bad)) in tiles.iter().zip(results) {
        place_tile(&mut pixels, w, tile, &px);
        counts.add(&t.counts);
        ray_logs.extend(t.log);
        nonfinite_samples += bad;
    }
    FrameResult {
        pixels,
        counts,
        nonfinite_samples,
        ray_logs,
    }
}

/// The frames `run.units` with the independent tracer, from `run.next` on; each finished frame
/// goes to `sink` (or, for a chunk, to its partial log). Returns false if interrupted (after a
/// checkpoint).
pub fn run_independent(
    integrator: &Integrator,
    (spp, seed): (u32, u64),
    (w, h): (u32, u32),
    progress: bool,
    run: &mut Run,
    active: Vec<crate::film::FrameAccum>,
    sink: &mut dyn Sink,
) -> Result<bool> {
    if !active.is_empty() {
        anyhow::bail!(
            "the checkpoint holds frames in flight, which the independent tracer never leaves: \
             it is damaged, or of another render; delete it to start over"
        );
    }
    let scene = integrator.scene;
    let (a, b) = (*run.units.start(), *run.units.end());
    let tiles_per_frame = tiles(w, h).len() as u64;
    let pb = progress_bar(progress, (b + 1 - a) as u64 * tiles_per_frame, "tiles");
    pb.set_position((run.next - a) as u64 * tiles_per_frame);
    let start = Instant::now();
    let total_rays = AtomicU64::new(0);
    let _graceful = Graceful::begin(run);
    for frame in run.next..=b {
        if run.interrupted() {
            run.save(sink, [])?;
            pb.abandon();
            return Ok(false);
        }
        let cam = scene.camera(frame, w, h);
        let frame_start = Instant::now();
        let on_tile = |c: &RayCounts| {
            let total = total_rays.fetch_add(c.total(), Relaxed) + c.total();
            let secs = start.elapsed().as_secs_f64().max(1e-9);
            pb.set_message(format!(
                "| frame {}/{} | {:.2} Mrays/s",
                frame - a + 1,
                b - a + 1,
                total as f64 / secs / 1e6
            ));
            pb.inc(1);
        };
        let f = render_frame_independent(integrator, &cam, frame, spp, seed, false, &on_tile);
        run.counters.counts.add(&f.counts);
        run.counters.nonfinite_samples += f.nonfinite_samples;
        let d = Developed::from_pixels(
            View::of(frame, &cam),
            &f.pixels,
            frame_start.elapsed().as_secs_f64(),
        );
        run.counters.nonfinite_pixels += d.nonfinite;
        if run.ckpt.chunked() {
            run.ckpt.retire(&Record::Pixels(d))?;
        } else {
            if d.is_black() {
                run.counters.black_frames.push(frame);
            }
            sink.put(d)?;
        }
        run.next = frame + 1;
        if frame < b && run.ckpt.due() {
            run.save(sink, [])?;
        }
    }
    // Every frame on disk before the loop (and its graceful stop) ends.
    run.frame_digests.extend(sink.sync()?);
    pb.finish_and_clear();
    Ok(true)
}
