//! The independent tracer's frame loop: every frame path-traced on its own, tile by tile.
//!
//! Determinism: pixels are independent (their random numbers are keyed by seed, frame, pixel and
//! sample), each tile's pixels are summed in sample order, and tiles are placed into the frame by
//! index, so the frames are bitwise identical for any thread count.
use super::progress_bar;
use super::run::{Graceful, Run};
use crate::camera::Camera;
use crate::embree::Packet16;
use crate::film::tiles::Tile;
use crate::film::tiles::{place_tile, tiles};
use crate::film::{Developed, Sink, View};
use crate::integrator::{Integrator, RayCounts, Tally};
use crate::sampling::Sampler;
use crate::state::Record;
use anyhow::Result;
use glam::{Vec2, Vec3};
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

/// A tile's pixel means (row by row) and its samples dropped as NaN or infinite. The primary
/// rays of each 4x4 block of pixels are traced together per sample index (one coherent packet,
/// or one ray at a time: `Integrator::primary_hits`); each lane keeps its own sampler and sums
/// its samples in index order, so a pixel's value depends only on its own hits.
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
    let mut px = vec![Vec3::ZERO; (tw * (y1 - y0)) as usize];
    let mut bad = 0u64;
    let mut packet = Packet16::new();
    // Per lane: its pixel (x, y), and its sampler and ray direction of the current sample.
    let mut lanes: Vec<(u32, u32)> = Vec::with_capacity(16);
    let mut samplers: Vec<Sampler> = Vec::with_capacity(16);
    let mut dirs: Vec<Vec3> = Vec::with_capacity(16);
    for by in (y0..y1).step_by(BLOCK as usize) {
        for bx in (x0..x1).step_by(BLOCK as usize) {
            lanes.clear();
            for y in by..(by + BLOCK).min(y1) {
                for x in bx..(bx + BLOCK).min(x1) {
                    lanes.push((x, y));
                }
            }
            let mut sums = [Vec3::ZERO; 16];
            for s in 0..spp {
                samplers.clear();
                dirs.clear();
                for &(x, y) in &lanes {
                    let mut sampler = Sampler::stratified(seed, frame, y * w + x, 0, s);
                    let r = Vec2::new(x as f32, y as f32) + sampler.next_2d();
                    dirs.push(cam.direction(r));
                    samplers.push(sampler);
                }
                let hits = integrator.primary_hits(cam.eye, &dirs, &mut packet, t);
                for (lane, sampler) in samplers.iter_mut().enumerate() {
                    let v = match &hits[lane] {
                        Some(hit) => integrator
                            .first_hit_at(hit, cam.eye, sampler, t)
                            .radiance(cam.eye),
                        None => integrator.scene.env_radiance(dirs[lane]),
                    };
                    // A NaN or infinite sample is dropped and counted, never written.
                    if v.is_finite() {
                        sums[lane] += v;
                    } else {
                        bad += 1;
                    }
                }
            }
            for (lane, &(x, y)) in lanes.iter().enumerate() {
                px[((y - y0) * tw + (x - x0)) as usize] = sums[lane] / spp as f32;
            }
        }
    }
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
            run.save([])?;
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
            sink.put(d)?;
        }
        run.next = frame + 1;
        if frame < b && run.ckpt.due() {
            run.save([])?;
        }
    }
    pb.finish_and_clear();
    Ok(true)
}
