//! `reframe bench`: the independent tracer's rays per second against bare Embree calls on the
//! same rays.
//!
//! The frame is rendered twice with the same seed: once timed, once logging every ray it traces
//! (origin, direction, interval, and whether it is an occlusion query). The log is then replayed
//! through `rtcIntersect1`/`rtcOccluded1` alone on the same tiles and threads, so the bare rate is
//! measured on exactly the rays the renderer traced. Their ratio is the share of the machine's
//! ray-tracing throughput that survives shading, sampling and bookkeeping.
//!
//! ```no_run
//! use reframe::{bench, embree::Device, scene::Scene};
//! let device = Device::new()?;
//! let report = bench::run(&Scene::load("vase", &device)?, 4, None, None, 0)?;
//! println!("{}", report.table());
//! # anyhow::Ok(())
//! ```
use crate::integrator::{Integrator, RayCounts};
use crate::render::{render_frame_independent, thread_pool, RayStats};
use crate::scene::Scene;
use anyhow::{bail, Result};
use rayon::prelude::*;
use serde::Serialize;
use std::time::Instant;

#[derive(Debug, Serialize)]
pub struct BenchReport {
    pub scene: String,
    pub width: u32,
    pub height: u32,
    pub frame: u32,
    pub spp: u32,
    pub threads: usize,
    pub render_seconds: f64,
    pub rays: RayStats,
    pub render_rays_per_second: f64,
    pub bare_seconds: f64,
    pub bare_rays_per_second: f64,
    /// Renderer rate over bare Embree rate.
    pub ratio: f64,
}

impl BenchReport {
    pub fn table(&self) -> String {
        let total = self.rays.primary + self.rays.path + self.rays.shadow;
        format!(
            "scene {} {}x{} frame {} spp {} threads {}\n\
             rays: {} primary, {} path, {} shadow ({} total)\n\
             {:<28}{:>10.3} s {:>10.2} Mrays/s\n\
             {:<28}{:>10.3} s {:>10.2} Mrays/s\n\
             renderer / bare Embree: {:.1}%",
            self.scene,
            self.width,
            self.height,
            self.frame,
            self.spp,
            self.threads,
            self.rays.primary,
            self.rays.path,
            self.rays.shadow,
            total,
            "independent path tracer",
            self.render_seconds,
            self.render_rays_per_second / 1e6,
            "bare rtcIntersect1/Occluded1",
            self.bare_seconds,
            self.bare_rays_per_second / 1e6,
            self.ratio * 100.0
        )
    }
}

pub fn run(
    scene: &Scene,
    spp: u32,
    res: Option<(u32, u32)>,
    frame: Option<u32>,
    threads: usize,
) -> Result<BenchReport> {
    let (w, h) = res.unwrap_or((scene.width, scene.height));
    let frame = frame.unwrap_or(scene.frames / 2);
    if frame >= scene.frames {
        bail!(
            "--frame {frame}: the scene has frames 0-{}",
            scene.frames - 1
        );
    }
    if spp == 0 {
        bail!("--spp 0: at least one sample per pixel is needed");
    }
    let pool = thread_pool(threads)?;
    let integrator = Integrator::new(scene, 16);
    let cam = scene.camera(frame, w, h);
    let seed = 1;
    let none = |_: &RayCounts| {};
    // Warm caches and the allocator, then time.
    pool.install(|| render_frame_independent(&integrator, &cam, frame, 1, seed, false, &none));
    let t0 = Instant::now();
    let timed = pool
        .install(|| render_frame_independent(&integrator, &cam, frame, spp, seed, false, &none));
    let render_seconds = t0.elapsed().as_secs_f64();
    let logged =
        pool.install(|| render_frame_independent(&integrator, &cam, frame, spp, seed, true, &none));
    debug_assert_eq!(logged.counts, timed.counts);
    let geometry = &scene.geometry;
    let t1 = Instant::now();
    let hits: u64 = pool.install(|| {
        logged
            .ray_logs
            .par_iter()
            .map(|log| {
                let mut hits = 0u64;
                for (ray, occlusion) in log {
                    let hit = if *occlusion {
                        geometry.occluded1(ray)
                    } else {
                        geometry.intersect1(ray).is_some()
                    };
                    hits += hit as u64;
                }
                hits
            })
            .sum()
    });
    let bare_seconds = t1.elapsed().as_secs_f64();
    std::hint::black_box(hits);
    let c = timed.counts;
    let render_rate = c.total() as f64 / render_seconds;
    let bare_rate = logged.ray_logs.iter().map(|l| l.len()).sum::<usize>() as f64 / bare_seconds;
    Ok(BenchReport {
        scene: scene.name.clone(),
        width: w,
        height: h,
        frame,
        spp,
        threads: pool.current_num_threads(),
        render_seconds,
        rays: RayStats {
            primary: c.primary,
            path: c.path,
            shadow: c.shadow,
            visibility: 0,
        },
        render_rays_per_second: render_rate,
        bare_seconds,
        bare_rays_per_second: bare_rate,
        ratio: render_rate / bare_rate,
    })
}
