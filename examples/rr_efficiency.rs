//! Where Russian roulette should start, and which MIS heuristic the path after the first hit
//! uses: the independent tracer's efficiency, `1 / (relMSE x seconds)`, for each first bounce of
//! roulette and each heuristic, on the shipped scenes.
//!
//! ```sh
//! cargo run --release --example rr_efficiency [-- --spp 16 --seeds 4 --ref-spp 1024 --scenes a,b \
//!     --rr 2,3,4,5,6,8,never --mis power,balance]
//! ```
//!
//! Per scene: its middle frame at its own resolution, a reference of `--ref-spp` samples with the
//! roulette of today's default, then every setting at `--spp` with `--seeds` seeds, the settings
//! interleaved within each seed so that load on the machine hits them alike. relMSE is
//! `mean((I - R)^2 / (R^2 + 0.01))` over pixels and channels (compare's, without the reference's
//! variance: the same for every setting). Roulette keeps the estimator unbiased at every setting,
//! so only the variance and the time change. Prints a table per scene, efficiency relative to the
//! default's.
use anyhow::{Context, Result};
use glam::Vec3;
use reframe::driver::{render_frame_independent, thread_pool};
use reframe::embree::Device;
use reframe::integrator::{Integrator, PathMis, RR_DEPTH};
use reframe::scene::{LoadOptions, Scene};
use std::time::Instant;

fn arg(name: &str, default: u32) -> Result<u32> {
    let args: Vec<String> = std::env::args().collect();
    match args.iter().position(|a| a == name) {
        Some(i) => args
            .get(i + 1)
            .with_context(|| format!("{name} needs a value"))?
            .parse()
            .with_context(|| format!("{name}: not a count")),
        None => Ok(default),
    }
}

/// The comma-separated values of `name`, or `default`.
fn list(name: &str, default: &str) -> Result<Vec<String>> {
    let args: Vec<String> = std::env::args().collect();
    let v = match args.iter().position(|a| a == name) {
        Some(i) => args
            .get(i + 1)
            .with_context(|| format!("{name} needs a value"))?,
        None => default,
    };
    Ok(v.split(',').map(str::to_string).collect())
}

fn relmse(img: &[Vec3], reference: &[Vec3]) -> f64 {
    let mut s = 0.0;
    for (i, r) in img.iter().zip(reference) {
        for c in 0..3 {
            let d = (i[c] - r[c]) as f64;
            s += d * d / ((r[c] as f64).powi(2) + 0.01);
        }
    }
    s / (3 * img.len()) as f64
}

fn main() -> Result<()> {
    let spp = arg("--spp", 16)?;
    let seeds = arg("--seeds", 4)?;
    let ref_spp = arg("--ref-spp", 1024)?;
    let max_depth = 16;
    // Roulette decides at the end of bounce `rr` (the walk from the second vertex on; the first
    // hit's own continuation is always traced), from the second bounce up to never.
    let rrs = list("--rr", "2,3,4,5,6,8,never")?
        .iter()
        .map(|r| match r.as_str() {
            "never" => Ok(max_depth + 1),
            r => r
                .parse()
                .with_context(|| format!("--rr: {r} is not a bounce")),
        })
        .collect::<Result<Vec<u32>>>()?;
    let mises = list("--mis", "balance")?
        .iter()
        .map(|m| match m.as_str() {
            "power" => Ok(PathMis::Power),
            "balance" => Ok(PathMis::Balance),
            m => anyhow::bail!("--mis: {m} is not power or balance"),
        })
        .collect::<Result<Vec<PathMis>>>()?;
    let settings: Vec<(u32, PathMis)> = rrs
        .iter()
        .flat_map(|&r| mises.iter().map(move |&m| (r, m)))
        .collect();
    let default = settings
        .iter()
        .position(|&s| s == (RR_DEPTH, PathMis::default()))
        .context("the settings must include the default (roulette from RR_DEPTH, balance)")?;
    let device = Device::new()?;
    let pool = thread_pool(0)?;
    let root = env!("CARGO_MANIFEST_DIR");
    let all = [
        "cornell".to_string(),
        "vase".to_string(),
        format!("{root}/scenes/occluders.toml"),
        format!("{root}/scenes/production/courtyard.toml"),
    ];
    // `--scenes a,b`: a shipped scene's name or a scene file (default: the four above).
    let args: Vec<String> = std::env::args().collect();
    let names: Vec<String> = match args.iter().position(|a| a == "--scenes") {
        Some(i) => args
            .get(i + 1)
            .context("--scenes needs a value")?
            .split(',')
            .map(str::to_string)
            .collect(),
        None => all.to_vec(),
    };
    for name in names {
        let scene = Scene::load_with(&name, &device, &LoadOptions { strict: false })?;
        let frame = scene.frames / 2;
        let cam = scene.camera(frame, scene.width, scene.height);
        let mut integrator = Integrator::new(&scene, max_depth);
        let render = |integrator: &Integrator, spp: u32, seed: u64| {
            pool.install(|| {
                let start = Instant::now();
                let r =
                    render_frame_independent(integrator, &cam, frame, spp, seed, false, &|_| {});
                (r.pixels, start.elapsed().as_secs_f64())
            })
        };
        let (reference, t_ref) = render(&integrator, ref_spp, 1 << 40);
        eprintln!("{}: reference {ref_spp} spp in {t_ref:.1} s", scene.name);
        // Per setting: (seconds, relMSE) summed over seeds.
        let mut sums = vec![(0.0f64, 0.0f64); settings.len()];
        for seed in 0..seeds as u64 {
            for (k, &(rr, mis)) in settings.iter().enumerate() {
                integrator.rr_depth = rr;
                integrator.path_mis = mis;
                let (img, t) = render(&integrator, spp, seed);
                sums[k].0 += t;
                sums[k].1 += relmse(&img, &reference);
            }
        }
        let eff = |k: usize| (seeds as f64).powi(2) / (sums[k].0 * sums[k].1);
        let base = eff(default);
        println!(
            "\n{} (frame {frame}, {}x{}, {spp} spp, {seeds} seeds, reference {ref_spp} spp)",
            scene.name, scene.width, scene.height
        );
        println!(
            "| roulette from bounce | MIS after the first hit | seconds per frame | relMSE | efficiency / default's |"
        );
        println!("| --- | --- | --- | --- | --- |");
        for (k, &(rr, mis)) in settings.iter().enumerate() {
            let label = if rr > max_depth {
                "never".to_string()
            } else {
                rr.to_string()
            };
            println!(
                "| {label} | {mis:?} | {:.3} | {:.5} | {:.3} |",
                sums[k].0 / seeds as f64,
                sums[k].1 / seeds as f64,
                eff(k) / base
            );
        }
    }
    Ok(())
}
