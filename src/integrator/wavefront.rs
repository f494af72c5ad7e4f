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
use super::{FirstHit, Integrator, Rays, Shadow, Tally, Walk};
use crate::embree::{Hit, Packet16, Ray};
use crate::sampling::Sampler;
use glam::Vec3;

/// A wavefront's room, kept from one batch to the next so that a worker allocates it once.
#[derive(Default)]
pub struct Wavefront {
    /// The records being built, one per path, in the batch's order.
    recs: Vec<FirstHit>,
    /// Each path's walk from its second vertex on, once its continuation ray hit something.
    walks: Vec<Option<Walk>>,
    /// This round's rays: the first vertex's shadow rays (path, ray), the walk's shadow rays
    /// (path, ray with its contribution), the continuation rays (path, ray).
    first_shadows: Vec<(u32, Ray)>,
    shadows: Vec<(u32, Shadow)>,
    continuations: Vec<(u32, Ray)>,
    /// The continuation rays of the round being queued, while this round's are answered.
    next_continuations: Vec<(u32, Ray)>,
    /// The answers, in the order of the queue traced.
    blocked: Vec<bool>,
    hits: Vec<Option<Hit>>,
    packet: Packet16,
}

impl Wavefront {
    pub fn new() -> Wavefront {
        Wavefront::default()
    }
}

/// Queue the rays that path `i`'s step asked for.
#[inline]
fn queue(
    i: usize,
    shadow: Option<Shadow>,
    next: Option<Ray>,
    shadows: &mut Vec<(u32, Shadow)>,
    continuations: &mut Vec<(u32, Ray)>,
) {
    if let Some(sh) = shadow {
        shadows.push((i as u32, sh));
    }
    if let Some(ray) = next {
        continuations.push((i as u32, ray));
    }
}

impl Integrator<'_> {
    /// The first-hit records of a batch of camera samples from `eye`: sample `i` hit `hits[i]`
    /// and draws its numbers from `samplers[i]`. Record `i` of the result is what
    /// `first_hit_at(&hits[i], eye, &mut samplers[i], ..)` returns.
    pub fn first_hits<'w>(
        &self,
        eye: Vec3,
        hits: &[Hit],
        samplers: &mut [Sampler],
        wf: &'w mut Wavefront,
        t: &mut Tally,
    ) -> &'w [FirstHit] {
        assert_eq!(hits.len(), samplers.len(), "one sampler per path");
        wf.recs.clear();
        wf.walks.clear();
        wf.first_shadows.clear();
        wf.continuations.clear();
        for (i, (hit, s)) in hits.iter().zip(samplers.iter_mut()).enumerate() {
            wf.recs.push(self.first_record(hit, eye));
            let rec = wf.recs.last_mut().expect("just pushed");
            let (shadow, next) = self.first_samples(rec, s);
            wf.walks.push(None);
            if let Some(ray) = shadow {
                wf.first_shadows.push((i as u32, ray));
            }
            if let Some(ray) = next {
                wf.continuations.push((i as u32, ray));
            }
        }
        let (blocked, first_shadows) = (&mut wf.blocked, &wf.first_shadows);
        self.occluded_all(first_shadows, |e| &e.1, blocked, &mut wf.packet, t);
        for (&(i, _), &b) in wf.first_shadows.iter().zip(wf.blocked.iter()) {
            self.light_blocked(&mut wf.recs[i as usize], b);
        }
        self.intersect_all(&wf.continuations, &mut wf.hits, &mut wf.packet, t);
        // Each round hands every path its continuation's hit and, where the walk goes on, takes
        // its next step at once (the path's state is touched once per round); the walk's shadow
        // rays of a round are answered before the hits, as the scalar walk adds them first.
        wf.shadows.clear();
        wf.next_continuations.clear();
        for (&(i, _), &hit) in wf.continuations.iter().zip(wf.hits.iter()) {
            let (i, s) = (i as usize, &mut samplers[i as usize]);
            let walk = &mut wf.walks[i];
            *walk = self.first_continue(&mut wf.recs[i], hit);
            if let Some(walk) = walk {
                let (shadow, next) = self.walk_vertex(walk, s);
                queue(i, shadow, next, &mut wf.shadows, &mut wf.next_continuations);
            }
        }
        while !wf.next_continuations.is_empty() || !wf.shadows.is_empty() {
            let (blocked, shadows) = (&mut wf.blocked, &wf.shadows);
            self.occluded_all(shadows, |e| &e.1.ray, blocked, &mut wf.packet, t);
            for ((i, sh), &b) in wf.shadows.iter().zip(wf.blocked.iter()) {
                let walk = wf.walks[*i as usize]
                    .as_mut()
                    .expect("a shadow ray's path walks");
                walk.shadow_resolved(sh, b);
            }
            std::mem::swap(&mut wf.continuations, &mut wf.next_continuations);
            self.intersect_all(&wf.continuations, &mut wf.hits, &mut wf.packet, t);
            wf.shadows.clear();
            wf.next_continuations.clear();
            for (&(i, _), &hit) in wf.continuations.iter().zip(wf.hits.iter()) {
                let (i, s) = (i as usize, &mut samplers[i as usize]);
                let walk = wf.walks[i].as_mut().expect("a continuation's path walks");
                if self.walk_continue(walk, hit, s) {
                    let (shadow, next) = self.walk_vertex(walk, s);
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

    /// Whether each ray of `queue` is blocked, into `blocked` (in the queue's order).
    fn occluded_all<E>(
        &self,
        queue: &[E],
        ray: impl Fn(&E) -> &Ray,
        blocked: &mut Vec<bool>,
        packet: &mut Packet16,
        t: &mut Tally,
    ) {
        let geometry = &self.scene.geometry;
        blocked.clear();
        match self.paths {
            Rays::Packet => {
                for chunk in queue.chunks(16) {
                    packet.clear();
                    for (lane, e) in chunk.iter().enumerate() {
                        t.shadow(ray(e));
                        packet.set(lane, ray(e));
                    }
                    geometry.occluded16_incoherent(packet);
                    blocked.extend((0..chunk.len()).map(|lane| packet.occluded(lane)));
                }
            }
            Rays::Single => blocked.extend(queue.iter().map(|e| {
                t.shadow(ray(e));
                geometry.occluded1(ray(e))
            })),
        }
    }

    /// The closest hit of each continuation ray of `queue`, into `hits` (in the queue's order).
    fn intersect_all(
        &self,
        queue: &[(u32, Ray)],
        hits: &mut Vec<Option<Hit>>,
        packet: &mut Packet16,
        t: &mut Tally,
    ) {
        let geometry = &self.scene.geometry;
        hits.clear();
        match self.paths {
            Rays::Packet => {
                for chunk in queue.chunks(16) {
                    packet.clear();
                    for (lane, (_, ray)) in chunk.iter().enumerate() {
                        t.path(ray);
                        packet.set(lane, ray);
                    }
                    geometry.intersect16_incoherent(packet);
                    hits.extend((0..chunk.len()).map(|lane| packet.hit(lane)));
                }
            }
            Rays::Single => hits.extend(queue.iter().map(|(_, ray)| {
                t.path(ray);
                geometry.intersect1(ray)
            })),
        }
    }
}
