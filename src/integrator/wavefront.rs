//! The path tracer in wavefront form: a batch of camera samples (a tile's samples of one index,
//! or the native samples a reuse worker has queued) advances bounce by bounce. Each round takes
//! one step of every live path (`Integrator::first_samples`, then `walk_vertex`), which queues at
//! most one shadow ray and one continuation ray per path; the queues are traced as 16-wide Embree
//! packets with finished paths left out, so the packets stay full while paths end at different
//! depths (or one ray at a time: `Integrator::paths`), and the answers are handed back to the
//! paths in the order they were queued.
//!
//! The estimator and its random numbers are the scalar walk's (`Integrator::first_hit_at`, kept
//! as the test oracle): a path draws its numbers from its own sampler at fixed dimensions, and
//! its radiance is summed in the same order, so traced one ray at a time the wavefront gives
//! the scalar walk's records bit for bit; in packets the hits may differ in their last bits.
use super::lanes::BsdfLanes;
use super::{facing, FirstHit, Integrator, LightSides, Rays, Tally, Walk};
use crate::bsdf::Material;
use crate::embree::{Hit, Packet16, Ray, TriangleScene};
use crate::sampling::{Sampler, StepBatch, StepLanes};
use crate::scene::{LightLanes, Scene, SurfacePoint};
use glam::{Vec2, Vec3};

/// Rays queued by the paths of a round, written straight into the lanes of 16-wide packets in
/// the order they are queued (so that the packets of live paths are full), with the path that
/// asked for each; traced as packets, or one at a time (`Rays::Single`, the answers kept
/// beside the packets).
#[derive(Default)]
struct RayQueue {
    packets: Vec<Packet16>,
    paths: Vec<u32>,
    /// The answers of a queue traced one ray at a time (empty where it was traced as packets,
    /// whose answers stay in their lanes).
    blocked: Vec<bool>,
    hits: Vec<Option<Hit>>,
}

impl RayQueue {
    fn clear(&mut self) {
        self.paths.clear();
    }

    fn len(&self) -> usize {
        self.paths.len()
    }

    #[inline]
    fn push(&mut self, path: usize, ray: &Ray) {
        let (p, lane) = (self.paths.len() / 16, self.paths.len() % 16);
        if p == self.packets.len() {
            self.packets.push(Packet16::new());
        }
        if lane == 0 {
            self.packets[p].clear();
        }
        self.packets[p].set(lane, ray);
        self.paths.push(path as u32);
    }

    /// Trace the queue for occlusion (shadow rays).
    fn occlude(&mut self, geometry: &TriangleScene, rays: Rays, t: &mut Tally) {
        let n = self.len();
        let out = &mut self.blocked;
        trace(
            &mut self.packets,
            n,
            rays,
            true,
            t,
            out,
            |p| geometry.occluded16_incoherent(p),
            |r| geometry.occluded1(r),
        );
    }

    /// Trace the queue for closest hits (continuation rays).
    fn intersect(&mut self, geometry: &TriangleScene, rays: Rays, t: &mut Tally) {
        let n = self.len();
        let out = &mut self.hits;
        trace(
            &mut self.packets,
            n,
            rays,
            false,
            t,
            out,
            |p| geometry.intersect16_incoherent(p),
            |r| geometry.intersect1(r),
        );
    }

    /// Whether ray `k` of the queue was blocked, after `occlude`.
    #[inline]
    fn blocked(&self, k: usize) -> bool {
        if self.blocked.is_empty() {
            self.packets[k / 16].occluded(k % 16)
        } else {
            self.blocked[k]
        }
    }

    /// The hit of ray `k` of the queue, after `intersect`.
    #[inline]
    fn hit(&self, k: usize) -> Option<Hit> {
        if self.hits.is_empty() {
            self.packets[k / 16].hit(k % 16)
        } else {
            self.hits[k]
        }
    }
}

/// Trace the first `n` lanes of `packets`, as packets (`packet`; the answers stay in them) or
/// one ray at a time (`single`; the answers go to `out`), counted in `t` as shadow rays
/// (`occlusion`) or path rays.
#[allow(clippy::too_many_arguments)]
fn trace<A>(
    packets: &mut [Packet16],
    n: usize,
    rays: Rays,
    occlusion: bool,
    t: &mut Tally,
    out: &mut Vec<A>,
    packet: impl Fn(&mut Packet16),
    single: impl Fn(&Ray) -> A,
) {
    out.clear();
    for (p, packet16) in packets.iter_mut().take(n.div_ceil(16)).enumerate() {
        let lanes = (n - 16 * p).min(16);
        t.batch(occlusion, lanes, (0..lanes).map(|lane| packet16.ray(lane)));
        match rays {
            Rays::Packet => packet(packet16),
            Rays::Single => out.extend((0..lanes).map(|lane| single(&packet16.ray(lane)))),
        }
    }
}

/// A wavefront's room, kept from one batch to the next so that a worker allocates it once.
#[derive(Default)]
pub struct Wavefront {
    /// The records being built, one per path, in the batch's order.
    recs: Vec<FirstHit>,
    /// Each path's walk from its second vertex on, once its continuation ray hit something.
    walks: Vec<Option<Walk>>,
    /// This round's shadow rays and continuation rays, and the next round's continuation rays
    /// (queued while this round's are answered).
    shadows: RayQueue,
    continuations: RayQueue,
    next_continuations: RayQueue,
    /// The batch's samplers, and the numbers of the step the paths of a round take, drawn for
    /// all of them at once.
    lanes: StepLanes,
    numbers: StepBatch,
    /// `0..n`: the paths of the first round.
    all: Vec<u32>,
    /// The surfaces a round's rays hit, the points and light numbers of their light samples,
    /// and the room in which those are taken together.
    surfaces: Vec<SurfacePoint>,
    /// Whether each of the round's rays hit a surface (`surfaces[k]` is stale where not).
    hit: Vec<bool>,
    queries: Vec<(Vec3, Vec2)>,
    light_lanes: LightLanes,
    /// The material of each surface of the round (`Scene::material`), and its BSDF sample,
    /// drawn for all of them at once.
    materials: Vec<Material>,
    bsdf_lanes: BsdfLanes,
}

impl Wavefront {
    pub fn new() -> Wavefront {
        Wavefront::default()
    }

    /// Before the paths whose continuation rays were just answered take their step to vertex
    /// `depth`: their numbers, the surfaces their rays hit and the light samples there
    /// (`light_lanes.samples()`, one per surface, in order), and empty queues for the rays the
    /// step asks for.
    ///
    /// Then, within `max_depth`, the materials of the surfaces and their BSDF samples: the
    /// walks' outgoing directions are their continuation rays' reversed (`walk.wo` is set to
    /// `-walk.wi` as the walk goes on), `wi` of the walk's last step or, at the second vertex,
    /// the record's BSDF direction.
    fn prepare_round(&mut self, integrator: &Integrator, depth: u32) {
        let dims = integrator.step_dims(depth);
        self.lanes
            .draw(&self.continuations.paths, dims, &mut self.numbers);
        let n = self.continuations.len();
        let hits = (0..n).map(|k| self.continuations.hit(k));
        let scene = integrator.scene;
        let surfaces = (&mut self.surfaces, &mut self.hit);
        surfaces_and_lights(scene, n, hits, &self.numbers, surfaces, &mut self.queries);
        scene.sample_lights(&self.queries, &mut self.light_lanes);
        self.shadows.clear();
        self.next_continuations.clear();
        if depth > integrator.max_depth {
            // The walks end here: the step reads no material or sample, but their rows must
            // exist.
            if self.materials.len() < n {
                self.materials.resize(n, Material::default());
            }
            self.bsdf_lanes.start(n);
            return;
        }
        let (recs, walks) = (&self.recs, &self.walks);
        let wo = |k: usize| {
            let i = self.continuations.paths[k] as usize;
            match (depth, &walks[i]) {
                (2, _) => -recs[i].w.expect("a continuation ray has a direction"),
                (_, Some(walk)) => -walk.wi,
                (_, None) => unreachable!("a continuation past the second vertex walks"),
            }
        };
        sample_bsdfs(
            scene,
            n,
            &self.surfaces,
            &self.hit,
            wo,
            &self.numbers,
            (&mut self.materials, &mut self.bsdf_lanes),
        );
    }

    /// Bytes a batch holds per path, at most: its record, walk, sampler and hit, and a lane in
    /// each of the three ray queues (for `RenderOptions::memory_estimate`).
    pub fn bytes_per_path() -> usize {
        use std::mem::size_of;
        size_of::<FirstHit>()
            + size_of::<Option<Walk>>()
            + size_of::<Sampler>()
            + size_of::<Hit>()
            + 3 * (Packet16::bytes() / 16 + size_of::<u32>())
            + StepLanes::BYTES_PER_PATH
            + StepBatch::BYTES_PER_PATH
            + size_of::<u32>()
            + size_of::<SurfacePoint>()
            + size_of::<bool>()
            + size_of::<(Vec3, Vec2)>()
            + LightLanes::BYTES_PER_QUERY
            + size_of::<Material>()
            + BsdfLanes::BYTES_PER_SAMPLE
    }
}

impl Integrator<'_> {
    /// The first-hit records of a batch of camera samples from `eye`: sample `i` hit `hits[i]`
    /// and draws its numbers from `samplers[i]`; `sides` are the eyes its light samples serve.
    /// Record `i` of the result is what `first_hit_at(&hits[i], eye, &mut samplers[i], ..,
    /// sides)` returns.
    pub fn first_hits<'w>(
        &self,
        eye: Vec3,
        hits: &[Hit],
        samplers: &[Sampler],
        wf: &'w mut Wavefront,
        t: &mut Tally,
        sides: LightSides,
    ) -> &'w [FirstHit] {
        first_hits(self, eye, hits, samplers, wf, t, sides)
    }
}

/// `Integrator::first_hits`, compiled for AVX-512 and AVX2 besides the portable build and
/// chosen at run time: what it inlines (each path's step) then uses the CPU's vectors, and IEEE
/// arithmetic with nothing fused gives the same bits in every version.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512cd+avx512dq+avx512vl",
    "x86_64+avx2",
))]
fn first_hits<'w>(
    this: &Integrator,
    eye: Vec3,
    hits: &[Hit],
    samplers: &[Sampler],
    wf: &'w mut Wavefront,
    t: &mut Tally,
    sides: LightSides,
) -> &'w [FirstHit] {
    assert_eq!(hits.len(), samplers.len(), "one sampler per path");
    let geometry = &this.scene.geometry;
    // Every record and walk is written in place below: a record pushed would be built aside
    // and copied in, and the copy's wide loads of what narrow stores had just written
    // cannot be forwarded from the store buffer.
    let n = hits.len();
    let scene = this.scene;
    wf.recs.resize(n, FirstHit::default());
    wf.walks.clear();
    wf.walks.resize(n, None);
    wf.shadows.clear();
    wf.continuations.clear();
    // A round's paths are all at the same vertex. For each round, the numbers of their
    // step are drawn together (`StepLanes`), then the surfaces their rays hit are found and
    // the light samples there taken together (`Scene::sample_lights`), both in SIMD lanes,
    // and then each path takes its step.
    wf.lanes.fill(samplers);
    wf.all.clear();
    wf.all.extend(0..n as u32);
    wf.lanes.draw(&wf.all, this.step_dims(1), &mut wf.numbers);
    let primary = hits.iter().map(|h| Some(*h));
    let surfaces = (&mut wf.surfaces, &mut wf.hit);
    surfaces_and_lights(scene, n, primary, &wf.numbers, surfaces, &mut wf.queries);
    let lights = scene.sample_lights(&wf.queries, &mut wf.light_lanes);
    // Each record's outgoing direction, towards the eye, which its BSDF sample needs before
    // the record is filled.
    for (rec, sp) in wf.recs.iter_mut().zip(&wf.surfaces[..n]) {
        rec.wo = (eye - sp.p).normalize();
    }
    let wo = |i: usize| wf.recs[i].wo;
    let room = (&mut wf.materials, &mut wf.bsdf_lanes);
    sample_bsdfs(scene, n, &wf.surfaces, &wf.hit, wo, &wf.numbers, room);
    for (i, (sp, light)) in wf.surfaces[..n].iter().zip(lights).enumerate() {
        let rec = &mut wf.recs[i];
        this.fill_first_record(rec, sp, wf.materials[i], rec.wo);
        let bs = wf.bsdf_lanes.get(i);
        let (shadow, next) = this.first_samples(rec, *light, bs, sides);
        if let Some(ray) = shadow {
            wf.shadows.push(i, &ray);
        }
        if let Some(ray) = next {
            wf.continuations.push(i, &ray);
        }
    }
    wf.shadows.occlude(geometry, this.paths, t);
    for k in 0..wf.shadows.len() {
        let i = wf.shadows.paths[k] as usize;
        this.light_blocked(&mut wf.recs[i], wf.shadows.blocked(k));
    }
    wf.continuations.intersect(geometry, this.paths, t);
    // Each round hands every path the surface its continuation hit and, where the walk goes
    // on, takes its next step at once (the path's state is touched once per round); the
    // walk's shadow rays of a round are answered before the hits, as the scalar walk adds
    // them first.
    let mut depth = 2;
    wf.prepare_round(this, depth);
    let mut lights = wf.light_lanes.samples().iter();
    for k in 0..wf.continuations.len() {
        let i = wf.continuations.paths[k] as usize;
        let sp = wf.hit[k].then(|| &wf.surfaces[k]);
        let walk = &mut wf.walks[i];
        *walk = this.first_continue(&mut wf.recs[i], sp);
        // Every surface has its light sample, in order.
        let light = sp.and_then(|_| *lights.next().expect("a light sample per surface"));
        if let (Some(walk), Some(sp)) = (walk, sp) {
            let (m, bs) = (&wf.materials[k], wf.bsdf_lanes.get(k));
            let (shadow, next) = this.walk_vertex(walk, sp, m, bs, light);
            queue(i, shadow, next, &mut wf.shadows, &mut wf.next_continuations);
        }
    }
    while wf.next_continuations.len() > 0 || wf.shadows.len() > 0 {
        wf.shadows.occlude(geometry, this.paths, t);
        for k in 0..wf.shadows.len() {
            let i = wf.shadows.paths[k] as usize;
            let walk = wf.walks[i].as_mut().expect("a shadow ray's path walks");
            walk.shadow_resolved(wf.shadows.blocked(k));
        }
        std::mem::swap(&mut wf.continuations, &mut wf.next_continuations);
        wf.continuations.intersect(geometry, this.paths, t);
        // The walks answered here are all at vertex `depth`: the step to the next one.
        depth += 1;
        wf.prepare_round(this, depth);
        let mut lights = wf.light_lanes.samples().iter();
        for k in 0..wf.continuations.len() {
            let i = wf.continuations.paths[k] as usize;
            let sp = wf.hit[k].then(|| &wf.surfaces[k]);
            let walk = wf.walks[i].as_mut().expect("a continuation's path walks");
            debug_assert_eq!(walk.depth + 1, depth, "a round's walks at one vertex");
            let light = sp.and_then(|_| *lights.next().expect("a light sample per surface"));
            let rr = wf.numbers.get(k).rr;
            if let (true, Some(sp)) = (this.walk_continue(walk, sp, rr), sp) {
                let (m, bs) = (&wf.materials[k], wf.bsdf_lanes.get(k));
                let (shadow, next) = this.walk_vertex(walk, sp, m, bs, light);
                queue(i, shadow, next, &mut wf.shadows, &mut wf.next_continuations);
            }
        }
    }
    for (rec, walk) in wf.recs.iter_mut().zip(&wf.walks) {
        if let Some(walk) = walk {
            rec.li_w = walk.l;
        }
    }
    &wf.recs
}

/// The surfaces that a round's `n` rays hit (`surfaces.0[k]`, where `surfaces.1[k]`: a ray
/// that left the scene hit none) and, for each surface in turn, the query of its light sample
/// (`queries`: the point and the path's light numbers). Each surface is written in its place
/// in a vector kept from round to round (a surface pushed is built aside and copied in, read
/// back wider than it was written).
fn surfaces_and_lights(
    scene: &Scene,
    n: usize,
    hits: impl Iterator<Item = Option<Hit>>,
    numbers: &StepBatch,
    (surfaces, hit_any): (&mut Vec<SurfacePoint>, &mut Vec<bool>),
    queries: &mut Vec<(Vec3, Vec2)>,
) {
    if surfaces.len() < n {
        surfaces.resize(n, SurfacePoint::default());
    }
    hit_any.clear();
    queries.clear();
    for (k, hit) in hits.enumerate() {
        hit_any.push(hit.is_some());
        if let Some(h) = hit {
            surfaces[k] = scene.surface(&h);
            queries.push((surfaces[k].p, numbers.light(k)));
        }
    }
}

/// The materials of a round's `n` surfaces (`room.0[k]`, where `hit[k]`) and their BSDF
/// samples (`room.1`, under `k`): `m.sample(ns, wo(k), lobe, bsdf)` with the numbers of path
/// `k` and `ns` the shading normal on the side of `wo(k)`, in SIMD lanes where they can be
/// (`lanes::BsdfLanes`). The samples of surfaces that reflect nothing are of no meaning (the
/// step reads none there).
fn sample_bsdfs(
    scene: &Scene,
    n: usize,
    surfaces: &[SurfacePoint],
    hit: &[bool],
    wo: impl Fn(usize) -> Vec3,
    numbers: &StepBatch,
    (materials, bsdfs): (&mut Vec<Material>, &mut BsdfLanes),
) {
    if materials.len() < n {
        materials.resize(n, Material::default());
    }
    bsdfs.start(n);
    for k in (0..n).filter(|&k| hit[k]) {
        let (sp, m) = (&surfaces[k], scene.material(&surfaces[k]));
        materials[k] = m;
        if m.samples_lambert(numbers.lobe(k)) {
            let wo = wo(k);
            bsdfs.set(k, m.kd, facing(sp, wo).1, wo);
        }
    }
    let (ux, uy) = numbers.bsdf_columns();
    bsdfs.run(n, ux, uy);
    for k in (0..n).filter(|&k| hit[k]) {
        let m = &materials[k];
        if m.reflects() && !m.samples_lambert(numbers.lobe(k)) {
            let wo = wo(k);
            let sample = m.sample(
                facing(&surfaces[k], wo).1,
                wo,
                numbers.lobe(k),
                numbers.bsdf(k),
            );
            bsdfs.put(k, sample);
        }
    }
}

/// Queue the rays that path `i`'s step asked for.
#[inline]
fn queue(
    i: usize,
    shadow: Option<Ray>,
    next: Option<Ray>,
    shadows: &mut RayQueue,
    continuations: &mut RayQueue,
) {
    if let Some(ray) = shadow {
        shadows.push(i, &ray);
    }
    if let Some(ray) = next {
        continuations.push(i, &ray);
    }
}
