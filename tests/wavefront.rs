//! The wavefront tracer (`integrator::wavefront`) against the scalar walk it replaces
//! (`Integrator::first_hit_at`, which traces each ray as soon as it is drawn): per path, the
//! same record, whatever the batch (a single path, fewer paths than a packet, a packet and one,
//! a whole tile), with paths ending at many different depths within a batch.
use reframe::embree::{Device, Hit, Ray};
use reframe::integrator::wavefront::Wavefront;
use reframe::integrator::{FirstHit, Integrator, LightSides, Rays, Tally};
use reframe::sampling::Sampler;
use reframe::scene::Scene;

/// A record's every field, each float printed to round-trip (equal strings: equal bits).
fn bits(rec: &FirstHit) -> String {
    format!("{rec:?}")
}

/// Camera samples of a frame: their primary hits and samplers (after the pixel position).
fn camera_samples(scene: &Scene, w: u32, h: u32, spp: u32) -> (glam::Vec3, Vec<(Hit, Sampler)>) {
    let frame = scene.frames / 2;
    let cam = scene.camera(frame, w, h);
    let mut out = Vec::new();
    for y in 0..h {
        for x in 0..w {
            for s in 0..spp {
                let mut sampler = Sampler::stratified(11, frame, y * w + x, 0, s);
                let r = glam::Vec2::new(x as f32, y as f32) + sampler.next_2d();
                let ray = Ray::new(cam.eye, cam.direction(r));
                if let Some(hit) = scene.geometry.intersect1(&ray) {
                    out.push((hit, sampler));
                }
            }
        }
    }
    (cam.eye, out)
}

/// Traced one ray at a time, the wavefront gives the scalar walk's records bit for bit, and its
/// rays are the walk's (the same counts); in packets, the same records up to the rounding of
/// Embree's packet kernels, with the same rays. Batches of 1, 3 (a packet mostly empty), 16,
/// 17 (a full packet and one lane) and 300 paths; in each scene the paths of a batch end at
/// several different depths (checked, or the test would not show that finished lanes drop out).
#[test]
fn wavefront_records_are_the_scalar_walks() {
    let device = Device::new().unwrap();
    let root = env!("CARGO_MANIFEST_DIR");
    let scenes = [
        "cornell".to_string(),
        "vase".to_string(),
        format!("{root}/scenes/occluders.toml"),
        format!("{root}/scenes/mirror-like.toml"),
        format!("{root}/scenes/production/courtyard.toml"),
    ];
    for name in &scenes {
        let scene = Scene::load(name, &device).unwrap();
        let (eye, samples) = camera_samples(&scene, 24, 18, 2);
        assert!(samples.len() > 300, "{name}: {} hits", samples.len());
        let mut integ = Integrator::new(&scene, 12);
        // Light samples for the native eye alone, and for a group with an eye far on the other
        // side of most surfaces (lights behind a surface kept, their shadow rays traced).
        let group = [eye, -3.0 * eye + glam::Vec3::new(0.5, 7.0, 0.25)];
        let mut native_shadows = 0;
        for sides in [LightSides::Native, LightSides::Group(&group)] {
            // The oracle: each path on its own, with its own count of rays.
            let mut oracle = Vec::new();
            let mut oracle_counts = Tally::default();
            let mut depths = std::collections::BTreeSet::new();
            for (hit, sampler) in &samples {
                let mut t = Tally::default();
                let rec = integ.first_hit_at(hit, eye, &mut sampler.clone(), &mut t, sides);
                depths.insert(t.counts.path);
                oracle_counts.counts.add(&t.counts);
                oracle.push(rec);
            }
            assert!(
                depths.len() >= 4,
                "{name}: paths end at {} depths only",
                depths.len()
            );
            let mut wf = Wavefront::new();
            for paths in [Rays::Single, Rays::Packet] {
                integ.paths = paths;
                for batch in [1, 3, 16, 17, 300] {
                    let mut counts = Tally::default();
                    let mut bitwise = 0;
                    for (chunk, expected) in samples.chunks(batch).zip(oracle.chunks(batch)) {
                        let hits: Vec<Hit> = chunk.iter().map(|c| c.0).collect();
                        let samplers: Vec<Sampler> = chunk.iter().map(|c| c.1.clone()).collect();
                        let recs =
                            integ.first_hits(eye, &hits, &samplers, &mut wf, &mut counts, sides);
                        assert_eq!(recs.len(), chunk.len());
                        for (rec, want) in recs.iter().zip(expected) {
                            if bits(rec) == bits(want) {
                                bitwise += 1;
                                continue;
                            }
                            assert_eq!(
                                paths,
                                Rays::Packet,
                                "{name}: batch {batch}: {rec:?} vs {want:?}"
                            );
                            let (a, b) = (rec.radiance(eye), want.radiance(eye));
                            let close = (a - b).abs().max_element()
                                <= 1e-3 * b.abs().max_element().max(1.0);
                            assert!(close, "{name}: batch {batch}: {a} wavefront, {b} scalar");
                        }
                    }
                    assert_eq!(
                        counts.counts, oracle_counts.counts,
                        "{name}: batch {batch}: rays"
                    );
                    // Rounding may move a hit now and then; nearly every record must agree bit for bit.
                    let n = samples.len();
                    assert!(
                        bitwise * 100 >= n * 99,
                        "{name}: {paths:?}, batch {batch}: {bitwise} of {n} records bitwise equal"
                    );
                }
            }
            // The group's far eye keeps light samples the native eye alone drops.
            if let LightSides::Group(_) = sides {
                assert!(
                    oracle_counts.counts.shadow > native_shadows,
                    "{name}: no light kept behind"
                );
            } else {
                native_shadows = oracle_counts.counts.shadow;
            }
        }
    }
}
