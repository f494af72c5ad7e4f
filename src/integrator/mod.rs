//! The independent path tracer, split at the first hit so that frame reuse can consume it.
//!
//! `trace_first_hit` follows one camera sample to its primary hit `x` and gathers, once, all that
//! the paper reuses across eyes (docs/estimators.md, "Notation"): the BSDF-sampled direction `w`
//! with the radiance arriving along it, split into the emitter reached directly (`le_w`) and the
//! rest of the random walk (`li_w`), and one light sample at `x`. `FirstHit::radiance` then
//! shades that record for any eye: for the eye that generated it this is the ordinary path-traced
//! estimate; the reuse methods evaluate it (or their own weights) for the other eyes.
//!
//! Direct light at every vertex combines next-event estimation and BSDF sampling by multiple
//! importance sampling (docs/environment.md, "Next-event estimation and MIS"). At the first hit
//! it is the balance heuristic (Veach 1997, eq. 9.13): a light sample contributes
//! `f cos Le / (p_l + p_b)`, an emitter hit by the BSDF direction `f cos Le / (p_b + p_l)`, which
//! is the form whose denominator the reuse estimator extends over the eyes of a group
//! (docs/estimators.md, "Direct light and self-emission"). From the second vertex on, where
//! nothing is reused, the heuristic is free (`PathMis`): the balance heuristic by default, the
//! power heuristic (Veach eq. 9.15) as the measured alternative.
//! Rays that leave the scene see the environment light (`scene::environment`), which is an
//! emitter like any other for MIS: its light samples are weighted against BSDF sampling and the
//! BSDF directions that escape against its light sampling.
//! Paths end by Russian roulette from bounce `RR_DEPTH` on, or at `max_depth`
//! (`examples/rr_efficiency.rs` measures where roulette should start).
pub mod lanes;
pub mod wavefront;

use crate::bsdf::{BsdfSample, Material};
use crate::embree::{Hit, Packet16, Ray};
use crate::sampling::{Sampler, StepDims};
use crate::scene::{LightSample, Scene, SurfacePoint};
use glam::{Vec2, Vec3};

/// The first bounce after which Russian roulette may end a path (chosen by efficiency,
/// README "The tracer").
pub const RR_DEPTH: u32 = 3;

/// How light sampling and BSDF sampling are weighted at the vertices after the first hit
/// (docs/environment.md, "Next-event estimation and MIS"): each technique's weight is
/// `p_this^b / (p_this^b + p_other^b)`, with `b = 1` (balance) or `b = 2` (power).
/// Balance is the default: the power heuristic measured no better on the shipped scenes
/// (README, "The tracer").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum PathMis {
    #[default]
    Balance,
    Power,
}

impl PathMis {
    /// The weight of the technique that sampled with density `p_this > 0` against the one with
    /// `p_other`. The power heuristic is written `1 / (1 + r²)` with `r = p_other / p_this`, so
    /// that no density is squared (no overflow) and an infinite `p_other` gives 0.
    #[inline]
    pub fn weight(self, p_this: f32, p_other: f32) -> f32 {
        match self {
            PathMis::Balance => p_this / (p_this + p_other),
            PathMis::Power => {
                let r = p_other / p_this;
                1.0 / (1.0 + r * r)
            }
        }
    }
}
/// Sampler dimensions: 0-1 pixel position, 2-3 light sample at x (4 unused), 5-7 BSDF sample at
/// x, then `DIMS_PER_BOUNCE` per further vertex. Fixed offsets keep the first hit's numbers the
/// same whatever the rest of the path used.
const DIM_LIGHT: u64 = 2;
const DIM_BSDF: u64 = 5;
const DIM_PATH: u64 = 8;
const DIMS_PER_BOUNCE: u64 = 8;

/// Ray counts by kind, for statistics and the rays-per-second figures.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct RayCounts {
    pub primary: u64,
    /// Continuation rays of the random walk (BSDF-sampled), including the one from the first hit.
    pub path: u64,
    /// Next-event estimation shadow rays.
    pub shadow: u64,
    /// Reuse visibility tests (hit to another eye).
    pub visibility: u64,
}

/// What a worker counts while tracing: ray counts and, for the benchmark only, a log of the
/// rays themselves (`true` = occlusion query) to replay against bare Embree calls.
#[derive(Default)]
pub struct Tally {
    pub counts: RayCounts,
    pub log: Option<Vec<(Ray, bool)>>,
}

impl Tally {
    pub fn logging() -> Tally {
        Tally {
            counts: RayCounts::default(),
            log: Some(Vec::new()),
        }
    }

    #[inline]
    pub fn primary(&mut self, r: &Ray) {
        self.counts.primary += 1;
        if let Some(l) = &mut self.log {
            l.push((*r, false));
        }
    }

    #[inline]
    pub fn path(&mut self, r: &Ray) {
        self.batch(false, 1, std::iter::once(*r));
    }

    #[inline]
    pub fn shadow(&mut self, r: &Ray) {
        self.batch(true, 1, std::iter::once(*r));
    }

    /// `n` rays traced together: shadow rays (`occlusion`) or path rays (`shadow` and `path`
    /// are this for one ray). The rays are read only where there is a log.
    #[inline]
    pub fn batch<I: Iterator<Item = Ray>>(&mut self, occlusion: bool, n: usize, rays: I) {
        *if occlusion {
            &mut self.counts.shadow
        } else {
            &mut self.counts.path
        } += n as u64;
        if let Some(l) = &mut self.log {
            l.extend(rays.map(|r| (r, occlusion)));
        }
    }
}

impl RayCounts {
    pub fn total(&self) -> u64 {
        self.primary + self.path + self.shadow + self.visibility
    }

    pub fn add(&mut self, o: &RayCounts) {
        self.primary += o.primary;
        self.path += o.path;
        self.shadow += o.shadow;
        self.visibility += o.visibility;
    }
}

/// One light sample at the first hit.
#[derive(Clone, Copy, Debug)]
pub struct FirstLight {
    pub wi: Vec3,
    /// Emitted radiance arriving along `wi`, zero if the light point is occluded.
    pub le: Vec3,
    /// Solid-angle density of light sampling, `p_l(wi | x)` (independent of the eye).
    pub pdf: f32,
}

/// The primary hit of a camera sample and everything gathered there that does not depend on
/// the eye (docs/estimators.md's native sample), plus the generating eye's BSDF density.
#[derive(Clone, Copy, Debug, Default)]
pub struct FirstHit {
    pub sp: SurfacePoint,
    /// The material at `x`, its textures looked up once here (not once per eye).
    pub m: Material,
    /// Unit direction from `x` to the native eye.
    pub wo: Vec3,
    /// BSDF-sampled direction at `x`, drawn for the native eye; `None` if sampling failed.
    pub w: Option<Vec3>,
    /// `p(w | x, x->o_native)` and the BSDF value for the native eye, `f(x->o_native, w)`.
    pub pdf_w: f32,
    pub f_w: Vec3,
    /// Emission of the surface hit directly along `w` (unweighted), and `p_l(w | x)`.
    pub le_w: Vec3,
    pub pdf_light_w: f32,
    /// Radiance reflected towards `x` by the surface hit along `w` (the rest of the walk).
    pub li_w: Vec3,
    pub light: Option<FirstLight>,
}

/// Shading normal on the side of `toward` (reflection is two-sided); `None` when `toward` sees
/// the back of the geometric surface relative to `ns` in a way shading cannot resolve.
#[inline]
pub fn facing(sp: &SurfacePoint, toward: Vec3) -> (Vec3, Vec3) {
    if sp.ng.dot(toward) >= 0.0 {
        (sp.ng, sp.ns)
    } else {
        (-sp.ng, -sp.ns)
    }
}

impl FirstHit {
    /// Radiance leaving `x` towards eye position `eye`, estimated from this record with the
    /// native eye's densities (estimator (7) of the paper): for the native eye it is the path
    /// tracer's estimate; for another eye it is what Havran et al. reuse, the BSDF re-evaluated
    /// for the new view but divided by the pdfs the native eye sampled with.
    pub fn radiance(&self, eye: Vec3) -> Vec3 {
        let sp = &self.sp;
        let wo = (eye - sp.p).normalize();
        let m = &self.m;
        let mut l = Scene::emitted_by(m, sp, eye);
        let (ng, ns) = facing(sp, wo);
        // Densities belong to the native eye's hemisphere and lobe.
        let (ng_n, ns_n) = facing(sp, self.wo);
        if let Some(ls) = &self.light {
            if ls.le != Vec3::ZERO && ng.dot(ls.wi) > 0.0 && ng_n.dot(ls.wi) > 0.0 {
                let f = m.eval(ns, wo, ls.wi);
                let pb = m.pdf(ns_n, self.wo, ls.wi);
                l += f * ns.dot(ls.wi).max(0.0) * ls.le / (ls.pdf + pb);
            }
        }
        if let Some(w) = self.w {
            if ng.dot(w) > 0.0 && self.pdf_w > 0.0 {
                let fc = m.eval(ns, wo, w) * ns.dot(w).max(0.0);
                l += fc * (self.le_w / (self.pdf_w + self.pdf_light_w) + self.li_w / self.pdf_w);
            }
        }
        l
    }
}

/// Which eyes a first hit's light sample serves, and so whether a light behind the surface (on
/// the other side from the native eye) is kept.
#[derive(Clone, Copy, Debug)]
pub enum LightSides<'e> {
    /// The native eye's only (the independent tracer, and reuse that shades with the native
    /// eye's densities): a light behind the surface cannot light what that eye sees, so the
    /// sample is dropped without a ray.
    Native,
    /// Every eye of a reuse group (their positions). Where one of them is on the other side of
    /// the surface from the native eye (the camera crosses the plane of a card, a leaf, a wall
    /// of no thickness), a light behind the surface is kept and its shadow ray traced: that
    /// eye sees what the light lights, and the MIS denominators count every eye's light
    /// sampling for every direction (docs/estimators.md, "Both sides of a surface"). Dropped,
    /// such samples darkened both sides of a card by 23%.
    Group(&'e [Vec3]),
}

impl LightSides<'_> {
    /// Whether the light sample in direction `wi` at `p` is kept, `ng` the geometric normal on
    /// the native eye's side.
    #[inline]
    fn keeps(self, p: Vec3, ng: Vec3, wi: Vec3) -> bool {
        let c = ng.dot(wi);
        c > 0.0
            || (c < 0.0
                && match self {
                    LightSides::Native => false,
                    LightSides::Group(eyes) => eyes.iter().any(|&e| ng.dot(e - p) < 0.0),
                })
    }
}

pub struct Integrator<'a> {
    pub scene: &'a Scene,
    pub max_depth: u32,
    /// Russian roulette may end a path after this bounce (`RR_DEPTH`; only the efficiency
    /// measurement changes it).
    pub rr_depth: u32,
    /// How primary rays are traced (the independent tracer and the native samples of reuse).
    pub primary: Rays,
    /// How the wavefront (`wavefront::Wavefront`) traces the rays after the primary hit: the
    /// continuation rays of the walks and the shadow rays of next-event estimation.
    pub paths: Rays,
    /// The MIS heuristic after the first hit (only the efficiency measurement changes it).
    pub path_mis: PathMis,
}

/// How a batch of rays is traced: as 16-wide Embree packets (`rtcIntersect16`/`rtcOccluded16`)
/// or one ray at a time. Both give the same estimator; hits may differ in the last bits of `t`,
/// `u` and `v` (Embree's packet and single-ray kernels round differently).
///
/// For primary rays a packet is coherent: the independent tracer's 4x4 pixel blocks per sample
/// index, or the reuse methods' 16 consecutive camera samples of a tile, row by row. For the rays
/// after the primary hit (`Integrator::paths`) it is 16 consecutive live paths of a wavefront.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Rays {
    #[default]
    Packet,
    Single,
}

impl Rays {
    /// The name the command line and the state file's key use.
    pub fn name(self) -> &'static str {
        match self {
            Rays::Packet => "packet",
            Rays::Single => "single",
        }
    }
}

/// A random walk from the second vertex of a path on: the state that one bounce hands the next.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Walk {
    /// The unit direction back along the path from the current vertex (the surface point
    /// itself is handed to each step: `walk_vertex`).
    wo: Vec3,
    /// Path throughput from the second vertex (the first hit's BSDF term is the record's).
    beta: Vec3,
    /// Radiance gathered so far: the record's `li_w` when the walk ends.
    l: Vec3,
    /// Bounces: the first hit is bounce 1, the walk starts at bounce 2.
    depth: u32,
    /// The continuation drawn at `sp`, kept for the MIS weight at the vertex it reaches:
    /// the vertex it left, its direction and its BSDF density.
    from: Vec3,
    wi: Vec3,
    pdf_b: f32,
    /// The light sample of the shadow ray in flight: its contribution `d` (weighted by MIS,
    /// before the throughput) counts, times the throughput `beta` it was drawn with, if nothing
    /// blocks the ray.
    shadow_beta: Vec3,
    shadow_d: Vec3,
}

impl Walk {
    /// The answer of the shadow ray this walk asked for: its contribution counts unless blocked.
    #[inline]
    pub(crate) fn shadow_resolved(&mut self, blocked: bool) {
        self.l += self.shadow_beta * if blocked { Vec3::ZERO } else { self.shadow_d };
    }
}

impl<'a> Integrator<'a> {
    pub fn new(scene: &'a Scene, max_depth: u32) -> Self {
        Integrator {
            scene,
            max_depth,
            rr_depth: RR_DEPTH,
            primary: Rays::default(),
            paths: Rays::default(),
            path_mis: PathMis::default(),
        }
    }

    /// Where the numbers of vertex `depth` of a path are read (the first hit is vertex 1): its
    /// light sample, its lobe and its BSDF sample, and (`rr`) the roulette after vertex
    /// `depth - 1` that let the walk reach it, where roulette applies there. Vertex 1 reads
    /// dimensions 2-3 (light) and 5-7 (lobe, BSDF); vertex `d >= 2` reads the 8 from
    /// `DIM_PATH + 8 (d - 2)`: light +0, lobe +2, BSDF +3, and the roulette after it +5.
    #[inline]
    pub(crate) fn step_dims(&self, depth: u32) -> StepDims {
        if depth <= 1 {
            return StepDims {
                rr: None,
                light: DIM_LIGHT,
                lobe: DIM_BSDF,
                bsdf: DIM_BSDF + 1,
            };
        }
        let base = |d: u32| DIM_PATH + DIMS_PER_BOUNCE * (d - 2) as u64;
        let before = depth - 1;
        StepDims {
            rr: (before >= 2 && before >= self.rr_depth).then(|| base(before) + 5),
            light: base(depth),
            lobe: base(depth) + 2,
            bsdf: base(depth) + 3,
        }
    }

    /// Sample a light from `sp` (normal pair facing `wo`) at a path vertex after the first hit:
    /// the MIS-weighted direct contribution `w_l f cos Le / p_l` and the shadow ray that decides
    /// whether it counts (`None` with a zero contribution when no ray is needed).
    #[inline(always)]
    fn direct(
        &self,
        sp: &SurfacePoint,
        m: &Material,
        wo: Vec3,
        light: Option<LightSample>,
    ) -> (Vec3, Option<Ray>) {
        let (ng, ns) = facing(sp, wo);
        let Some(ls) = light else {
            return (Vec3::ZERO, None);
        };
        if ls.le == Vec3::ZERO || ng.dot(ls.wi) <= 0.0 || ls.pdf <= 0.0 {
            return (Vec3::ZERO, None);
        }
        let (f, pb) = m.eval_pdf(ns, wo, ls.wi);
        if f == Vec3::ZERO {
            return (Vec3::ZERO, None);
        }
        let fc_le = f * ns.dot(ls.wi) * ls.le;
        let d = match self.path_mis {
            // `w_l / p_l` with `w_l = p_l / (p_l + p_b)`.
            PathMis::Balance => fc_le / (ls.pdf + pb),
            PathMis::Power => fc_le * (self.path_mis.weight(ls.pdf, pb) / ls.pdf),
        };
        (d, Some(ls.shadow_ray(sp.p, sp.ng, self.scene.offset_floor)))
    }

    /// The closest hits of up to 16 primary rays from `eye` along `dirs` (lane `i` of the result
    /// for `dirs[i]`), as one coherent packet or one ray at a time, as `self.primary` says: the
    /// same hits up to Embree's rounding. `packet` is the caller's scratch.
    pub fn primary_hits(
        &self,
        eye: Vec3,
        dirs: &[Vec3],
        packet: &mut Packet16,
        t: &mut Tally,
    ) -> [Option<Hit>; 16] {
        assert!(dirs.len() <= 16, "a packet holds 16 rays");
        let geometry = &self.scene.geometry;
        let mut hits = [None; 16];
        match self.primary {
            Rays::Packet => {
                packet.clear();
                for (lane, &dir) in dirs.iter().enumerate() {
                    let ray = Ray::new(eye, dir);
                    t.primary(&ray);
                    packet.set(lane, &ray);
                }
                geometry.intersect16(packet);
                for (lane, hit) in hits.iter_mut().enumerate().take(dirs.len()) {
                    *hit = packet.hit(lane);
                }
            }
            Rays::Single => {
                for (hit, &dir) in hits.iter_mut().zip(dirs) {
                    let ray = Ray::new(eye, dir);
                    t.primary(&ray);
                    *hit = geometry.intersect1(&ray);
                }
            }
        }
        hits
    }

    /// The camera sample through raster position `r` of eye `eye` along unit `dir`, up to and
    /// including the first-hit record, traced as one scalar walk. `None` if the ray leaves the
    /// scene.
    pub fn trace_first_hit(
        &self,
        eye: Vec3,
        dir: Vec3,
        s: &mut Sampler,
        t: &mut Tally,
    ) -> Option<FirstHit> {
        let ray = Ray::new(eye, dir);
        t.primary(&ray);
        let hit = self.scene.geometry.intersect1(&ray)?;
        Some(self.first_hit_at(&hit, eye, s, t, LightSides::Native))
    }

    /// Build the first-hit record for a primary hit already found (e.g. by a packet), as one
    /// scalar walk that traces each ray as soon as it is drawn: the test oracle of the
    /// wavefront (`wavefront::Wavefront`), which takes the same steps over a batch of paths.
    pub fn first_hit_at(
        &self,
        hit: &Hit,
        eye: Vec3,
        s: &mut Sampler,
        t: &mut Tally,
        sides: LightSides,
    ) -> FirstHit {
        let geometry = &self.scene.geometry;
        let scene = self.scene;
        let mut rec = FirstHit::default();
        let sp = scene.surface(hit);
        let (m, wo) = (scene.material(&sp), (eye - sp.p).normalize());
        self.fill_first_record(&mut rec, &sp, m, wo);
        let step = s.step(self.step_dims(1));
        let light = scene.sample_light(rec.sp.p, step.light);
        let bs = m.sample(facing(&sp, wo).1, wo, step.lobe, step.bsdf);
        let (shadow, next) = self.first_samples(&mut rec, light, bs, sides);
        if let Some(ray) = shadow {
            t.shadow(&ray);
            self.light_blocked(&mut rec, geometry.occluded1(&ray));
        }
        let Some(ray) = next else {
            return rec;
        };
        t.path(&ray);
        let mut hit = geometry.intersect1(&ray).map(|h| scene.surface(&h));
        let Some(mut walk) = self.first_continue(&mut rec, hit.as_ref()) else {
            return rec;
        };
        let mut step = s.step(self.step_dims(2));
        // The surface the walk is at.
        while let Some(sp) = hit {
            let light = scene.sample_light(sp.p, step.light);
            let m = scene.material(&sp);
            let bs = (walk.depth <= self.max_depth)
                .then(|| m.sample(facing(&sp, walk.wo).1, walk.wo, step.lobe, step.bsdf))
                .flatten();
            let (shadow, next) = self.walk_vertex(&mut walk, &sp, &m, bs, light);
            if let Some(ray) = shadow {
                t.shadow(&ray);
                walk.shadow_resolved(geometry.occluded1(&ray));
            }
            let Some(ray) = next else {
                break;
            };
            t.path(&ray);
            step = s.step(self.step_dims(walk.depth + 1));
            hit = geometry.intersect1(&ray).map(|h| scene.surface(&h));
            if !self.walk_continue(&mut walk, hit.as_ref(), step.rr) {
                break;
            }
        }
        rec.li_w = walk.l;
        rec
    }

    /// The record of a camera sample whose primary ray hit the surface at `sp` (`Scene::surface`
    /// of the hit), of material `m` (`Scene::material` there), seen along unit `wo` (towards the
    /// eye), before its samples (`first_samples` takes them), written field by field into
    /// `rec`: a record built aside and copied in is read with wide loads right after narrow
    /// stores, which the store buffer cannot forward (the wavefront fills its records in place).
    #[inline(always)]
    pub(crate) fn fill_first_record(
        &self,
        rec: &mut FirstHit,
        sp: &SurfacePoint,
        m: Material,
        wo: Vec3,
    ) {
        rec.sp = *sp;
        rec.m = m;
        rec.wo = wo;
        rec.w = None;
        rec.pdf_w = 0.0;
        rec.f_w = Vec3::ZERO;
        rec.le_w = Vec3::ZERO;
        rec.pdf_light_w = 0.0;
        rec.li_w = Vec3::ZERO;
        rec.light = None;
    }

    /// The samples of the first vertex: the shadow ray of its light sample (`light_blocked`
    /// takes the answer) and the continuation ray along the BSDF sample `w` (`first_continue`
    /// takes its hit). The light sample is stored unweighted: its weights depend on the eyes.
    /// With `n` the vertex's numbers (`step_dims(1)`), `light` is
    /// `scene.sample_light(rec.sp.p, n.light)` and `bs` is `rec.m.sample(ns, rec.wo, n.lobe,
    /// n.bsdf)` (`ns` the shading normal on `rec.wo`'s side), which the wavefront takes for
    /// many paths at once.
    #[inline(always)]
    pub(crate) fn first_samples(
        &self,
        rec: &mut FirstHit,
        light: Option<LightSample>,
        bs: Option<BsdfSample>,
        sides: LightSides,
    ) -> (Option<Ray>, Option<Ray>) {
        let (sp, m, wo) = (rec.sp, rec.m, rec.wo);
        if !m.reflects() {
            return (None, None);
        }
        let ng = facing(&sp, wo).0;
        let mut shadow = None;
        if let Some(ls) = light {
            let mut le = ls.le;
            // A light behind the surface cannot contribute for any eye on this side: no ray,
            // unless an eye of the group sees the other side (`LightSides`).
            if le != Vec3::ZERO && sides.keeps(sp.p, ng, ls.wi) {
                shadow = Some(ls.shadow_ray(sp.p, sp.ng, self.scene.offset_floor));
            } else {
                le = Vec3::ZERO;
            }
            rec.light = Some(FirstLight {
                wi: ls.wi,
                le,
                pdf: ls.pdf,
            });
        }
        let Some(bs) = bs else {
            return (shadow, None);
        };
        if ng.dot(bs.wi) <= 0.0 {
            return (shadow, None);
        }
        rec.w = Some(bs.wi);
        rec.pdf_w = bs.pdf;
        rec.f_w = bs.f;
        (
            shadow,
            Some(Ray::spawn(sp.p, sp.ng, bs.wi, self.scene.offset_floor)),
        )
    }

    /// The answer of the first vertex's shadow ray.
    #[inline(always)]
    pub(crate) fn light_blocked(&self, rec: &mut FirstHit, blocked: bool) {
        if let (true, Some(light)) = (blocked, &mut rec.light) {
            light.le = Vec3::ZERO;
        }
    }

    /// The surface the continuation ray along `w` hit (`Scene::surface` of its hit), or none:
    /// the emitter it reaches directly, and the walk from the second vertex, if it hit one.
    #[inline(always)]
    pub(crate) fn first_continue(
        &self,
        rec: &mut FirstHit,
        hit: Option<&SurfacePoint>,
    ) -> Option<Walk> {
        let scene = self.scene;
        let wi = rec.w.expect("a continuation ray has a direction");
        let Some(y) = hit else {
            // Out of the scene: the environment is the emitter reached along `w`.
            rec.le_w = scene.env_radiance(wi);
            if rec.le_w != Vec3::ZERO {
                rec.pdf_light_w = scene.env_pdf(wi);
            }
            return None;
        };
        rec.le_w = scene.emitted(y, rec.sp.p);
        if rec.le_w != Vec3::ZERO {
            rec.pdf_light_w = scene.light_pdf(rec.sp.p, y.p, y.prim);
        }
        Some(Walk {
            wo: -wi,
            beta: Vec3::ONE,
            l: Vec3::ZERO,
            depth: 2,
            from: Vec3::ZERO,
            wi: Vec3::ZERO,
            pdf_b: 0.0,
            shadow_beta: Vec3::ZERO,
            shadow_d: Vec3::ZERO,
        })
    }

    /// One vertex of the walk (radiance reflected at `sp`, the surface the walk is at, along
    /// `walk.wo`, excluding the vertex's own emission): the shadow ray of its light sample, if
    /// it needs one, and the continuation ray, `None` where the walk ends (depth, a black
    /// material, a failed or downward BSDF sample). With `n` the vertex's numbers, `m` is
    /// `scene.material(sp)`, `bs` is `m.sample(ns, walk.wo, n.lobe, n.bsdf)` (`ns` the shading
    /// normal on `walk.wo`'s side; only read within `max_depth`) and `light` is
    /// `scene.sample_light(sp.p, n.light)`.
    #[inline(always)]
    pub(crate) fn walk_vertex(
        &self,
        walk: &mut Walk,
        sp: &SurfacePoint,
        m: &Material,
        bs: Option<BsdfSample>,
        light: Option<LightSample>,
    ) -> (Option<Ray>, Option<Ray>) {
        if walk.depth > self.max_depth {
            return (None, None);
        }
        if !m.reflects() {
            return (None, None);
        }
        let shadow = match self.direct(sp, m, walk.wo, light) {
            (d, Some(ray)) => {
                walk.shadow_beta = walk.beta;
                walk.shadow_d = d;
                Some(ray)
            }
            (d, None) => {
                walk.l += walk.beta * d;
                None
            }
        };
        let (ng, ns) = facing(sp, walk.wo);
        let Some(bs) = bs else {
            return (shadow, None);
        };
        if ng.dot(bs.wi) <= 0.0 {
            return (shadow, None);
        }
        walk.beta *= bs.f * ns.dot(bs.wi) / bs.pdf;
        walk.from = sp.p;
        walk.wi = bs.wi;
        walk.pdf_b = bs.pdf;
        (
            shadow,
            Some(Ray::spawn(sp.p, sp.ng, bs.wi, self.scene.offset_floor)),
        )
    }

    /// The surface the walk's continuation ray hit (`Scene::surface` of its hit), or none: the
    /// emitter it reaches, weighted against light sampling, then Russian roulette with the
    /// number `rr`. Returns whether the walk goes on from the new vertex.
    #[inline(always)]
    pub(crate) fn walk_continue(
        &self,
        walk: &mut Walk,
        hit: Option<&SurfacePoint>,
        rr: f32,
    ) -> bool {
        let scene = self.scene;
        let Some(next) = hit else {
            // Out of the scene: the environment, weighted against its light sampling.
            let le = scene.env_radiance(walk.wi);
            if le != Vec3::ZERO {
                let pl = scene.env_pdf(walk.wi);
                walk.l += walk.beta * le * self.path_mis.weight(walk.pdf_b, pl);
            }
            return false;
        };
        let le = scene.emitted(next, walk.from);
        if le != Vec3::ZERO {
            // beta already holds f cos / p_b: the BSDF technique's weight is all it lacks.
            let pl = scene.light_pdf(walk.from, next.p, next.prim);
            walk.l += walk.beta * le * self.path_mis.weight(walk.pdf_b, pl);
        }
        if walk.depth >= self.rr_depth {
            let q = walk.beta.max_element().min(0.95);
            if rr >= q {
                return false;
            }
            walk.beta /= q;
        }
        walk.wo = -walk.wi;
        walk.depth += 1;
        true
    }

    /// One full path-traced sample through raster position `r` of camera `cam`.
    pub fn sample_pixel(
        &self,
        cam: &crate::camera::Camera,
        r: Vec2,
        s: &mut Sampler,
        t: &mut Tally,
    ) -> Vec3 {
        let dir = cam.direction(r);
        match self.trace_first_hit(cam.eye, dir, s, t) {
            Some(fh) => fh.radiance(cam.eye),
            None => self.scene.env_radiance(dir),
        }
    }
}
