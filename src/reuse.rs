//! Frame reuse (Méndez-Feliu, Sbert, Szirmay-Kalos 2006; the estimators in ESTIMATOR.md).
//!
//! Schedule (the paper's Sec. 4.1): a group is `n_f = --window` consecutive frames; every frame of
//! the group shoots `n_r = --spp` native samples per pixel, and every native primary hit is
//! reused in every other frame of the group after one visibility test towards that frame's eye.
//! Groups slide one frame at a time; a frame's estimate is the mean of the estimates of the
//! groups it belongs to. A frame leaves memory, written, as soon as no later group contains it.
//!
//! Methods, for a native sample `s = (x, w)` of eye `m` landing in pixel `i` of frame `j`:
//! - `havran`: the own-eye estimate (7) with the native densities, averaged by count per pixel;
//! - `mis`: eq. 15, `f_j cos L / (n_r sum_{visible m'} p(w | x, x->o_m'))` (approximation (10)
//!   makes every visible eye's area density `n_r`, so only pdfs remain), averaged by count per
//!   pixel as the paper does ("for every pixel we keep the final color and the number of samples
//!   ... and average every result", Sec. 4.2). With `n_v` eyes seeing `x`, `n_r n_v` samples
//!   are expected per pixel, so the value splatted per sample is `n_r n_v` times eq. 15, the
//!   balance-heuristic estimate `f_j cos L / mean_{visible m'} p`, and the pixel divides by the
//!   count that landed. On diffuse surfaces this is Havran's average (eq. 14);
//! - `mis-exact`: `(J_j / A_pix,j) f_j cos L / sum_{m'} D_m'(x) p(w | x, x->o_m')` with
//!   `D_m' = n_r J_m'(x) vis inside / A_pix,m'` (ESTIMATOR.md), which is unbiased.
//!
//! The light sample and the emitter reached along `w` use `p + p_l` in the denominators and the
//! self-emission of `x` divides by `sum D_m'` (ESTIMATOR.md, `Q_dir`).
//!
//! Streaming and determinism: contributions are splatted as they are made into per-frame
//! accumulators in 32-bit fixed point with stochastic rounding (`FixedSums`): integer addition is
//! associative, so the frames are bitwise identical for any thread count, and memory grows with
//! width x height x n_f: 12 bytes per pixel per frame in flight (16 for the methods that average
//! by count, 24 with `--aov`).
//! Visibility tests for a tile of hits towards one eye all converge on that eye and go through
//! `rtcOccluded16` packets (`--visibility packet`, the default) or single rays.
use crate::camera::Camera;
use crate::checkpoint::{Checkpointer, FrameRecord, Progress, RecordData, Run};
use crate::embree::{Packet16, Ray};
use crate::integrator::{facing, FirstHit, Integrator, RayCounts, Tally};
use crate::render::{place_tile, progress_bar, tiles, FrameReuse, Method, RenderOptions};
use crate::sampling::{mix64, Sampler};
use anyhow::{bail, Result};
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use std::collections::HashMap;
use std::collections::VecDeque;
use std::ops::RangeInclusive;
use std::sync::atomic::{AtomicI32, AtomicU32, AtomicU64, Ordering::Relaxed};
use std::sync::Mutex;
use std::time::Instant;

/// Fixed-point scale of the accumulators: 2^20 steps per unit of (pre-scaled) radiance.
const FIXED: f64 = (1u64 << 20) as f64;

/// Per-pixel RGB sums in 32-bit fixed point, the most compact form whose additions are
/// associative (so the frames are bitwise identical for any thread count).
///
/// A value is quantised by stochastic rounding, `floor(v 2^20 + u)` with a hashed `u` in [0, 1):
/// its expectation is exactly `v 2^20`, so splats far below one step (high sample counts, dark
/// pixels) are not rounded away and the estimator stays unbiased. The 32-bit cells wrap; every
/// wrap is recorded as a carry of 2^32 in a side table, so the true sum is `cell + carry` exactly
/// and independent of the order of additions. Carries need a pixel's pre-scaled sum past 2048,
/// which the per-method pre-scaling (`FrameAccum::unit`) keeps rare.
struct FixedSums {
    cells: Vec<AtomicI32>,
    carry: Mutex<HashMap<usize, i64>>,
}

impl FixedSums {
    fn new(n: usize) -> FixedSums {
        FixedSums {
            cells: (0..n).map(|_| AtomicI32::new(0)).collect(),
            carry: Mutex::new(HashMap::new()),
        }
    }

    /// Add the already quantised `q` to cell `i`.
    #[inline]
    fn add(&self, i: usize, q: i64) {
        // |q| beyond 2^31 (a single splat over 2048) goes to the carry table whole.
        let Ok(q32) = i32::try_from(q) else {
            *self.carry.lock().unwrap().entry(i).or_default() += q;
            return;
        };
        let old = self.cells[i].fetch_add(q32, Relaxed);
        if old.overflowing_add(q32).1 {
            let wrap = if q32 > 0 { 1i64 << 32 } else { -(1i64 << 32) };
            *self.carry.lock().unwrap().entry(i).or_default() += wrap;
        }
    }

    /// The exact sum of cell `i`, back in units.
    #[cfg(test)]
    fn get(&self, i: usize, carry: &HashMap<usize, i64>) -> f64 {
        let c = carry.get(&i).copied().unwrap_or(0);
        (self.cells[i].load(Relaxed) as i64 + c) as f64 / FIXED
    }
}

/// The running sums of one frame over all the groups that contain it.
struct FrameAccum {
    frame: u32,
    cam: Camera,
    /// RGB per pixel, in units of `unit` radiance.
    sum: FixedSums,
    /// What one unit of `sum` is worth: 1 for `mis-exact` (its contributions are already divided
    /// by the expected sample count), `n_r n_f` for the methods that average by count, whose
    /// contributions are whole radiance estimates divided by the count only at the end.
    unit: f32,
    /// Samples that landed per pixel (native and reused); kept only where a pixel needs it
    /// (averages by count, or the `--aov` channel): 4 bytes a pixel the statistics do not need.
    landed: Option<Vec<AtomicU32>>,
    /// Attempted and lost reuses into this frame per pixel, kept only for `--aov`.
    per_pixel_loss: Option<(Vec<AtomicU32>, Vec<AtomicU32>)>,
    /// Samples that landed in the whole frame, attempted reuses, and those lost (occluded, or off
    /// the film).
    landed_total: AtomicU64,
    tried: AtomicU64,
    lost: AtomicU64,
    groups: u32,
    started: Instant,
    /// Seconds spent on this frame by the process a checkpoint was resumed from.
    earlier_seconds: f64,
}

impl FrameAccum {
    fn new(frame: u32, cam: Camera, opts: &RenderOptions) -> FrameAccum {
        let p = (cam.width * cam.height) as usize;
        let zeros32 = |n| (0..n).map(|_| AtomicU32::new(0)).collect::<Vec<_>>();
        let by_count = by_count(opts.method);
        FrameAccum {
            frame,
            sum: FixedSums::new(3 * p),
            unit: if by_count {
                (opts.spp * opts.window) as f32
            } else {
                1.0
            },
            landed: (by_count || opts.aov).then(|| zeros32(p)),
            per_pixel_loss: opts.aov.then(|| (zeros32(p), zeros32(p))),
            cam,
            landed_total: AtomicU64::new(0),
            tried: AtomicU64::new(0),
            lost: AtomicU64::new(0),
            groups: 0,
            started: Instant::now(),
            earlier_seconds: 0.0,
        }
    }

    /// The accumulator as a state-file record (a copy: the frame keeps rendering).
    fn to_record(&self) -> FrameRecord {
        let mut carry: Vec<(u64, i64)> = self
            .sum
            .carry
            .lock()
            .unwrap()
            .iter()
            .map(|(&i, &c)| (i as u64, c))
            .collect();
        carry.sort_unstable();
        let load = |v: &[AtomicU32]| v.iter().map(|c| c.load(Relaxed)).collect::<Vec<u32>>();
        FrameRecord {
            frame: self.frame,
            width: self.cam.width,
            height: self.cam.height,
            groups: self.groups,
            unit: self.unit,
            data: RecordData::Sums {
                cells: self.sum.cells.iter().map(|c| c.load(Relaxed)).collect(),
                carry,
            },
            landed: self.landed.as_deref().map(load),
            loss: self
                .per_pixel_loss
                .as_ref()
                .map(|(t, l)| (load(t), load(l))),
            landed_total: self.landed_total.load(Relaxed),
            tried: self.tried.load(Relaxed),
            lost: self.lost.load(Relaxed),
            seconds: self.started.elapsed().as_secs_f64() + self.earlier_seconds,
            world_to_camera: self.cam.world_to_camera().to_cols_array(),
            world_to_ndc: self.cam.world_to_ndc().to_cols_array(),
        }
    }

    /// The accumulator a checkpoint's record holds, for a render with `opts`.
    fn from_record(r: &FrameRecord, cam: Camera, opts: &RenderOptions) -> Result<FrameAccum> {
        let mut a = FrameAccum::new(r.frame, cam, opts);
        let RecordData::Sums { cells, carry } = &r.data else {
            bail!(
                "frame {}: the checkpoint holds finished pixels, not sums",
                r.frame
            );
        };
        if cells.len() != a.sum.cells.len()
            || r.unit.to_bits() != a.unit.to_bits()
            || r.landed.is_some() != a.landed.is_some()
            || r.loss.is_some() != a.per_pixel_loss.is_some()
        {
            bail!(
                "frame {}: the checkpoint's accumulator does not fit these settings",
                r.frame
            );
        }
        for (c, &v) in a.sum.cells.iter().zip(cells) {
            c.store(v, Relaxed);
        }
        *a.sum.carry.lock().unwrap() = carry.iter().map(|&(i, c)| (i as usize, c)).collect();
        let store = |dst: &[AtomicU32], src: &[u32]| {
            dst.iter().zip(src).for_each(|(d, &s)| d.store(s, Relaxed))
        };
        if let (Some(d), Some(s)) = (&a.landed, &r.landed) {
            store(d, s);
        }
        if let (Some((dt, dl)), Some((st, sl))) = (&a.per_pixel_loss, &r.loss) {
            store(dt, st);
            store(dl, sl);
        }
        a.landed_total = AtomicU64::new(r.landed_total);
        a.tried = AtomicU64::new(r.tried);
        a.lost = AtomicU64::new(r.lost);
        a.groups = r.groups;
        a.earlier_seconds = r.seconds;
        Ok(a)
    }

    /// Add `v` to pixel `i`, rounding stochastically with the bits of `dither`; false (and
    /// nothing added) if `v` is not finite.
    #[inline]
    fn splat(&self, i: usize, v: Vec3, dither: u64) -> bool {
        if !v.is_finite() {
            return false;
        }
        let v = v / self.unit;
        for c in 0..3 {
            // 21 bits of the hash per channel: u in [0, 1).
            let u = ((dither >> (21 * c)) & 0x1f_ffff) as f64 / (1u64 << 21) as f64;
            self.sum
                .add(3 * i + c, (v[c] as f64 * FIXED + u).floor() as i64);
        }
        true
    }

    /// Count `n` samples landing in pixel `i`.
    #[inline]
    fn land(&self, i: usize, n: u32) {
        if let Some(landed) = &self.landed {
            landed[i].fetch_add(n, Relaxed);
        }
    }
}

/// Per hit and target eye: the pixel it lands in (if on the target's film and visible).
pub type Landing = Option<u32>;

/// A native sample that hit something: (pixel, sample index, first-hit record).
pub type NativeHit = (u32, u32, FirstHit);

/// The per-eye quantities of one native hit that every method's weights are built from.
pub struct EyeTerms {
    /// Unit direction from x to the eye.
    pub wo: Vec3,
    /// `J_k / A_pix,k` (film density in pixels per unit area at x), or 0 where eye k cannot see x.
    pub j_over_a: f32,
    /// `n_k(pi_k(x))`: native samples eye k shot in the pixel x projects to (`--spp`, or the
    /// adaptive count of that pixel; ESTIMATOR.md, adaptive sampling).
    pub n: f32,
}

/// MIS denominators of one native sample over the eyes of its group (ESTIMATOR.md, `Q`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Denominators {
    /// `sum_k D_k p_k(w)`: indirect radiance along w.
    pub ind: f32,
    /// `sum_k D_k (p_k(w) + p_l(w))`: the emitter reached along w.
    pub dir_w: f32,
    /// `sum_k D_k (p_k(w_l) + p_l(w_l))`: the light sample.
    pub dir_l: f32,
    /// `sum_k D_k`: self-emission.
    pub emit: f32,
}

/// `D_k(x)` for each eye (0 where it cannot see x), for the exact (`exact`:
/// `D_k = n_k(pi_k(x)) J_k / A_pix,k`, ESTIMATOR.md) or the paper's (approximation (10): every
/// visible eye's density equal to `n_r`) weights.
fn densities(eyes: &[EyeTerms], spp: u32, exact: bool) -> impl Iterator<Item = f32> + '_ {
    eyes.iter().map(move |e| {
        if e.j_over_a <= 0.0 {
            0.0
        } else if exact {
            e.n * e.j_over_a
        } else {
            spp as f32
        }
    })
}

/// The denominators for `fh` given each eye's terms.
pub fn denominators(
    integrator: &Integrator,
    fh: &FirstHit,
    eyes: &[EyeTerms],
    spp: u32,
    exact: bool,
) -> Denominators {
    let m = integrator.scene.material(&fh.sp);
    let mut q = Denominators::default();
    for (e, d) in eyes.iter().zip(densities(eyes, spp, exact)) {
        if d == 0.0 {
            continue;
        }
        let (ng, ns) = facing(&fh.sp, e.wo);
        // The density eye k samples w with: its lobe, on its side of the surface.
        let pdf_k = |w: Vec3| {
            if ng.dot(w) > 0.0 {
                m.pdf(ns, e.wo, w)
            } else {
                0.0
            }
        };
        q.emit += d;
        if let Some(w) = fh.w {
            let p = pdf_k(w);
            q.ind += d * p;
            q.dir_w += d * (p + fh.pdf_light_w);
        }
        if let Some(l) = &fh.light {
            q.dir_l += d * (pdf_k(l.wi) + l.pdf);
        }
    }
    q
}

/// Contribution of native sample `fh` to the pixel it lands in of the eye at `eye` (unit
/// direction `wo`), with pixel-density factor `scale` (`J_j / A_pix,j`, or 1 for the paper's).
fn mis_contribution(
    integrator: &Integrator,
    fh: &FirstHit,
    eye: Vec3,
    wo: Vec3,
    scale: f32,
    q: &Denominators,
) -> Vec3 {
    let scene = integrator.scene;
    let sp = &fh.sp;
    let m = scene.material(sp);
    let (ng, ns) = facing(sp, wo);
    let mut l = Vec3::ZERO;
    if q.emit > 0.0 {
        l += scene.emitted(sp, eye) / q.emit;
    }
    if let Some(ls) = &fh.light {
        if ls.le != Vec3::ZERO && ng.dot(ls.wi) > 0.0 && q.dir_l > 0.0 {
            l += m.eval(ns, wo, ls.wi) * ns.dot(ls.wi) * ls.le / q.dir_l;
        }
    }
    if let Some(w) = fh.w {
        if ng.dot(w) > 0.0 {
            let fc = m.eval(ns, wo, w) * ns.dot(w);
            if q.dir_w > 0.0 {
                l += fc * fh.le_w / q.dir_w;
            }
            if q.ind > 0.0 {
                l += fc * fh.li_w / q.ind;
            }
        }
    }
    l * scale
}

/// A finished frame as `render_reuse` hands it out: (frame, camera, pixels, extra channels, seconds).
pub type Emit<'e> = dyn FnMut(u32, &Camera, &[Vec3], &[(&str, Vec<f32>)], f64) -> Result<()> + 'e;

/// What `render_reuse` reports besides the frames.
pub struct ReuseStats {
    pub counts: RayCounts,
    pub nonfinite_samples: u64,
    pub mean_effective_spp: f64,
    pub lost_reuse_fraction: f64,
    pub per_frame: Vec<FrameReuse>,
}

impl ReuseStats {
    pub fn of(p: &Progress, frames: u32) -> ReuseStats {
        ReuseStats {
            counts: p.counts,
            nonfinite_samples: p.nonfinite_samples,
            mean_effective_spp: p
                .per_frame
                .iter()
                .map(|f| f.mean_effective_spp)
                .sum::<f64>()
                / frames as f64,
            lost_reuse_fraction: if p.tried > 0 {
                p.lost as f64 / p.tried as f64
            } else {
                0.0
            },
            per_frame: p.per_frame.clone(),
        }
    }
}

/// Render `range` with a reuse method, handing each frame to `emit` as soon as it is final.
/// (No checkpoints, one process: `render::render` adds those.)
pub fn render_reuse(
    integrator: &Integrator,
    opts: &RenderOptions,
    range: RangeInclusive<u32>,
    w: u32,
    h: u32,
    emit: &mut Emit,
) -> Result<ReuseStats> {
    let groups = *range.start()..=range.end() + 1 - opts.window;
    let mut run = Run::new(Checkpointer::none(), groups, Progress::default());
    render_reuse_run(integrator, opts, w, h, &mut run, vec![], emit)?;
    Ok(ReuseStats::of(
        &run.progress,
        range.end() - range.start() + 1,
    ))
}

/// The groups `run.units` (group `g` is frames `g..g + n_f`): from `run.next` on, starting from
/// the frames in flight `active` (a resumed checkpoint's), writing checkpoints as they fall due.
/// Frames that no later group of the run touches go to `emit`, or, for a chunk, to its partial
/// log. Returns false if `run.interrupt` stopped it (after a checkpoint at the last finished
/// group).
pub fn render_reuse_run(
    integrator: &Integrator,
    opts: &RenderOptions,
    w: u32,
    h: u32,
    run: &mut Run,
    active: Vec<FrameRecord>,
    emit: &mut Emit,
) -> Result<bool> {
    let scene = integrator.scene;
    let n_f = opts.window;
    let last_group = *run.units.end();
    let chunked = run.ckpt.chunked();
    let pb = progress_bar(
        opts.progress,
        (last_group + 1 - run.units.start()) as u64,
        "groups",
    );
    pb.set_position((run.next - run.units.start()) as u64);
    let mut active: VecDeque<FrameAccum> = active
        .iter()
        .map(|r| FrameAccum::from_record(r, scene.camera(r.frame, w, h), opts))
        .collect::<Result<_>>()?;
    let nonfinite = AtomicU64::new(0);
    let tile_list = tiles(w, h);
    let mut written = 0;
    for g0 in run.next..=last_group {
        if run.interrupted() {
            run.save(active.iter().map(FrameAccum::to_record))?;
            pb.abandon();
            return Ok(false);
        }
        // The group's frames: keep those still active, add the new ones.
        while active.back().is_none_or(|a| a.frame < g0 + n_f - 1) {
            let f = active.back().map_or(g0, |a| a.frame + 1);
            active.push_back(FrameAccum::new(f, scene.camera(f, w, h), opts));
        }
        let group: Vec<&FrameAccum> = active
            .iter()
            .filter(|a| a.frame >= g0 && a.frame < g0 + n_f)
            .collect();
        debug_assert_eq!(group.len(), n_f as usize);
        let work: Vec<(usize, usize)> = (0..group.len())
            .flat_map(|m| (0..tile_list.len()).map(move |t| (m, t)))
            .collect();
        let (native_counts, pilot_rays) = match opts.adaptive {
            Some(target) => {
                let (c, r) =
                    adaptive_counts(integrator, &group, opts.spp, target, &work, &tile_list);
                (Some(c), r)
            }
            None => (None, RayCounts::default()),
        };
        run.progress.counts.add(&pilot_rays);
        let group_counts: RayCounts = work
            .par_iter()
            .map(|&(m, t)| {
                let mut tally = Tally::default();
                let bad = shade_tile(
                    integrator,
                    opts,
                    &group,
                    m,
                    tile_list[t],
                    g0,
                    native_counts.as_deref(),
                    &mut tally,
                );
                nonfinite.fetch_add(bad, Relaxed);
                tally.counts
            })
            .reduce(RayCounts::default, |mut a, b| {
                a.add(&b);
                a
            });
        run.progress.counts.add(&group_counts);
        run.progress.nonfinite_samples += nonfinite.swap(0, Relaxed);
        for a in active
            .iter_mut()
            .filter(|a| a.frame >= g0 && a.frame < g0 + n_f)
        {
            a.groups += 1;
        }
        // Frames no later group contains: g0 itself, or every remaining one after the last group.
        while active
            .front()
            .is_some_and(|a| a.frame == g0 || g0 == last_group)
        {
            let a = active.pop_front().unwrap();
            let rec = a.to_record();
            run.progress.tried += rec.tried;
            run.progress.lost += rec.lost;
            if chunked {
                run.ckpt.retire(&rec)?;
            } else {
                let fr = finish_record(&rec, &rec.totals(), opts.method);
                run.progress.per_frame.push(FrameReuse {
                    frame: a.frame,
                    mean_effective_spp: rec.landed_total as f64 / (w * h) as f64,
                    lost_reuse_fraction: if rec.tried > 0 {
                        rec.lost as f64 / rec.tried as f64
                    } else {
                        0.0
                    },
                });
                run.progress.nonfinite_pixels +=
                    fr.pixels.iter().filter(|p| !p.is_finite()).count() as u64;
                emit(
                    a.frame,
                    &a.cam,
                    &fr.pixels,
                    &fr.channels(),
                    a.started.elapsed().as_secs_f64() + a.earlier_seconds,
                )?;
            }
            written += 1;
        }
        run.next = g0 + 1;
        if g0 < last_group && run.ckpt.due() {
            run.save(active.iter().map(FrameAccum::to_record))?;
        }
        pb.set_message(format!(
            "| {written} frames {}",
            if chunked { "retired" } else { "written" }
        ));
        pb.inc(1);
    }
    pb.finish_and_clear();
    Ok(true)
}

/// A frame's final pixels and, with `--aov`, its extra channels.
pub struct Finished {
    pub pixels: Vec<Vec3>,
    pub spp_eff: Option<Vec<f32>>,
    pub lost_share: Option<Vec<f32>>,
}

impl Finished {
    /// The extra channels as written: `spp_eff` and `lost_reuse` with `--aov`, else none.
    pub fn channels(&self) -> Vec<(&'static str, Vec<f32>)> {
        match (&self.spp_eff, &self.lost_share) {
            (Some(s), Some(l)) => vec![("spp_eff", s.clone()), ("lost_reuse", l.clone())],
            _ => vec![],
        }
    }
}

/// Whether `method` divides each pixel by the count of samples that landed in it (Havran's and
/// the paper's), rather than by the expected count built into its weights (`mis-exact`).
fn by_count(method: Method) -> bool {
    matches!(method, Method::Havran | Method::Mis)
}

/// The frame's final pixels from its record and exact fixed-point `totals` (cells plus carries,
/// summed over every chunk): the mean over its groups (`mis-exact`), or over everything that
/// landed (the methods that average by count). One function for a single process, a resumed
/// one and a merge of chunks, so that they agree to the bit.
pub fn finish_record(r: &FrameRecord, totals: &[i64], method: Method) -> Finished {
    let n = (r.width * r.height) as usize;
    if let RecordData::Pixels(px) = &r.data {
        return Finished {
            pixels: px
                .chunks_exact(3)
                .map(|c| Vec3::new(c[0], c[1], c[2]))
                .collect(),
            spp_eff: None,
            lost_share: None,
        };
    }
    let landed = |i: usize| r.landed.as_ref().map_or(0, |l| l[i]);
    let unit = |i: usize| (totals[i] as f64 / FIXED) as f32;
    let pixels = (0..n)
        .map(|i| {
            let s = Vec3::new(unit(3 * i), unit(3 * i + 1), unit(3 * i + 2)) * r.unit;
            if !by_count(method) {
                s / r.groups as f32
            } else if landed(i) > 0 {
                s / landed(i) as f32
            } else {
                Vec3::ZERO
            }
        })
        .collect();
    let spp_eff = r
        .landed
        .as_ref()
        .map(|l| l.iter().map(|&c| c as f32).collect());
    let lost_share = r.loss.as_ref().map(|(tried, lost)| {
        tried
            .iter()
            .zip(lost)
            .map(|(&t, &l)| if t > 0 { l as f32 / t as f32 } else { 0.0 })
            .collect()
    });
    Finished {
        pixels,
        spp_eff,
        lost_share,
    }
}

/// Side of the pixel blocks that share one pilot ray in `adaptive_counts`.
const PILOT_BLOCK: u32 = 2;

/// Adaptive native samples (the paper's future work, ESTIMATOR.md's `n_m(p)`): for every pixel of
/// every frame of the group, how many native samples it shoots in this group, decided from the
/// geometry before any sample is drawn, so that `mis-exact`'s densities can use them and stay
/// unbiased.
///
/// One pilot ray per 2x2 block of pixels, through the block's centre, finds the point x it sees.
/// Eye k shoots `n_r` samples per pixel, so the count of its samples expected in a pixel of frame
/// m around x is `n_r (J_k(x) / A_pix,k) / (J_m(x) / A_pix,m)` where it sees x (one visibility
/// test) and 0 where it does not. A pixel that every eye of the group sees expects about
/// `n_f n_r`; one at a border, a disocclusion or a cut expects fewer. The block's pixels top
/// their expectation up to `target n_f n_r` in whole samples:
/// `n_r + clamp(floor(target n_f n_r - expected), 0, (n_f - 1) n_r)`. The pilot rays are
/// deterministic (block centres), so the counts are independent of every sample.
fn adaptive_counts(
    integrator: &Integrator,
    group: &[&FrameAccum],
    spp: u32,
    target: f32,
    work: &[(usize, usize)],
    tile_list: &[(u32, u32, u32, u32)],
) -> (Vec<Vec<u16>>, RayCounts) {
    let scene = integrator.scene;
    let n_f = group.len() as u32;
    let full = target * (n_f * spp) as f32;
    let cap = ((n_f - 1) * spp) as f32;
    let per_tile: Vec<(Vec<u16>, RayCounts)> = work
        .par_iter()
        .map(|&(m, t)| {
            let (x0, y0, x1, y1) = tile_list[t];
            let cam_m = &group[m].cam;
            let mut rays = RayCounts::default();
            let mut out = vec![spp as u16; ((x1 - x0) * (y1 - y0)) as usize];
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
                    for (k, acc) in group.iter().enumerate() {
                        if k == m || acc.cam.pixel_of(sp.p).is_none() {
                            continue;
                        }
                        rays.visibility += 1;
                        let ray = Ray::between(acc.cam.eye, Vec3::ZERO, sp.p, sp.ng);
                        if !scene.geometry.occluded1(&ray) {
                            let ja = acc.cam.jacobian(sp.p, sp.ng) / acc.cam.pixel_area();
                            expected += spp as f32 * ja / own;
                        }
                    }
                    let n = spp + (full - expected).floor().clamp(0.0, cap) as u32;
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

/// Trace the native samples of one tile of frame `group[m]` and splat every reuse of them into
/// the group's frames. Returns the number of non-finite contributions dropped.
#[allow(clippy::too_many_arguments)]
fn shade_tile(
    integrator: &Integrator,
    opts: &RenderOptions,
    group: &[&FrameAccum],
    m: usize,
    (x0, y0, x1, y1): (u32, u32, u32, u32),
    g0: u32,
    counts: Option<&[Vec<u16>]>,
    tally: &mut Tally,
) -> u64 {
    let native = group[m];
    let cam_m = &native.cam;
    let w = cam_m.width;
    let spp = opts.spp;
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
    // (pixel, sample index, hit) of every native sample that hit something.
    let mut hits: Vec<NativeHit> = Vec::new();
    for y in y0..y1 {
        for x in x0..x1 {
            let pixel = y * w + x;
            let n_p = n_at(m, pixel);
            native.land(pixel as usize, n_p);
            landed_native += n_p as u64;
            for s in 0..n_p {
                // Sample index: the frame's position in the group keeps each group's samples of a
                // frame independent; with one frame per group this is the independent tracer's.
                let index = (native.frame - g0) * stride + s;
                let mut sampler = Sampler::new(opts.seed, native.frame, pixel, index);
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
    for (k, acc) in group.iter().enumerate() {
        if k == m {
            for (hi, (pixel, _, _)) in hits.iter().enumerate() {
                land[hi * n_f + k] = Some(*pixel);
            }
            continue;
        }
        visibility(
            integrator,
            &acc.cam,
            &hits,
            k,
            n_f,
            opts.packets,
            &mut land,
            tally,
        );
    }
    let exact = opts.method == Method::MisExact;
    let mut bad = 0u64;
    // Reuse bookkeeping summed locally and added once per tile: (tried, lost) per target eye.
    let mut loss = vec![(0u64, 0u64); n_f];
    let mut landed = vec![0u64; n_f];
    landed[m] = landed_native;
    let mut eyes: Vec<EyeTerms> = Vec::with_capacity(n_f);
    for (hi, (pixel, index, fh)) in hits.iter().enumerate() {
        let x = fh.sp.p;
        eyes.clear();
        for (k, acc) in group.iter().enumerate() {
            let wo = (acc.cam.eye - x).normalize();
            let (j_over_a, n) = match land[hi * n_f + k] {
                Some(i) => (
                    acc.cam.jacobian(x, fh.sp.ng) / acc.cam.pixel_area(),
                    n_at(k, i) as f32,
                ),
                None => (0.0, 0.0),
            };
            eyes.push(EyeTerms { wo, j_over_a, n });
        }
        let q = if opts.method == Method::Havran {
            Denominators::default()
        } else {
            denominators(integrator, fh, &eyes, spp, exact)
        };
        // The paper's count average: `n_r n_v` times eq. 15 (see the module note).
        let visible = eyes.iter().filter(|e| e.j_over_a > 0.0).count();
        let paper_scale = (spp as usize * visible) as f32;
        for (k, acc) in group.iter().enumerate() {
            let Some(i) = land[hi * n_f + k] else {
                if k != m {
                    loss[k].0 += 1;
                    loss[k].1 += 1;
                    // Only reuses lost to occlusion fall on a pixel of the target.
                    if let (Some((tried, lost)), Some(i)) =
                        (&acc.per_pixel_loss, acc.cam.pixel_of(x))
                    {
                        tried[i as usize].fetch_add(1, Relaxed);
                        lost[i as usize].fetch_add(1, Relaxed);
                    }
                }
                continue;
            };
            let i = i as usize;
            if k != m {
                loss[k].0 += 1;
                landed[k] += 1;
                acc.land(i, 1);
                if let Some((tried, _)) = &acc.per_pixel_loss {
                    tried[i].fetch_add(1, Relaxed);
                }
            }
            let e = &eyes[k];
            let v = match opts.method {
                Method::Havran => fh.radiance(integrator.scene, acc.cam.eye),
                _ => mis_contribution(
                    integrator,
                    fh,
                    acc.cam.eye,
                    e.wo,
                    if exact { e.j_over_a } else { paper_scale },
                    &q,
                ),
            };
            // The rounding dither: a hash of the native sample and the target frame.
            let dither = mix64(
                mix64(opts.seed ^ ((native.frame as u64) << 32 | *pixel as u64))
                    ^ ((*index as u64) << 32 | acc.frame as u64),
            );
            if !acc.splat(i, v, dither) {
                bad += 1;
            }
        }
    }
    for ((acc, (t, l)), n) in group.iter().zip(loss).zip(landed) {
        acc.landed_total.fetch_add(n, Relaxed);
        acc.tried.fetch_add(t, Relaxed);
        acc.lost.fetch_add(l, Relaxed);
    }
    bad
}

/// Fill `land[hi * n_f + k]` for eye `k`: project every hit, test visibility from the eye.
#[allow(clippy::too_many_arguments)]
pub fn visibility(
    integrator: &Integrator,
    cam: &Camera,
    hits: &[NativeHit],
    k: usize,
    n_f: usize,
    packets: bool,
    land: &mut [Landing],
    tally: &mut Tally,
) {
    let geometry = &integrator.scene.geometry;
    let mut packet = Packet16::new();
    let mut lanes: [usize; 16] = [0; 16];
    let mut n = 0;
    let flush = |packet: &mut Packet16, lanes: &[usize], n: usize, land: &mut [Landing]| {
        geometry.occluded16(packet);
        for (lane, &hi) in lanes.iter().enumerate().take(n) {
            if packet.occluded(lane) {
                land[hi * n_f + k] = None;
            }
        }
        packet.clear();
    };
    for (hi, (_, _, fh)) in hits.iter().enumerate() {
        let Some(i) = cam.pixel_of(fh.sp.p) else {
            continue;
        };
        land[hi * n_f + k] = Some(i);
        // From the eye towards the hit: the rays of a tile converge on the eye (coherent).
        let ray = Ray::between(cam.eye, Vec3::ZERO, fh.sp.p, fh.sp.ng);
        tally.counts.visibility += 1;
        if packets {
            packet.set(n, &ray);
            lanes[n] = hi;
            n += 1;
            if n == 16 {
                flush(&mut packet, &lanes, n, land);
                n = 0;
            }
        } else if geometry.occluded1(&ray) {
            land[hi * n_f + k] = None;
        }
    }
    if packets && n > 0 {
        flush(&mut packet, &lanes, n, land);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn total(s: &FixedSums, i: usize) -> f64 {
        s.get(i, &s.carry.lock().unwrap())
    }

    #[test]
    fn fixed_sums_carry_wraps_exactly_in_any_order() {
        // Splats that wrap the 32-bit cell many times, in two orders, and one single splat beyond
        // 2^31 steps: the totals are exact and equal.
        let values: Vec<i64> = (0..4000).map(|k| 900_000_000 + 7919 * k).collect();
        let exact: i64 = values.iter().sum::<i64>() + (3i64 << 40);
        let (a, b) = (FixedSums::new(1), FixedSums::new(1));
        for &q in &values {
            a.add(0, q);
        }
        a.add(0, 3i64 << 40);
        b.add(0, 3i64 << 40);
        for &q in values.iter().rev() {
            b.add(0, q);
        }
        assert_eq!(total(&a, 0), exact as f64 / FIXED);
        assert_eq!(total(&a, 0), total(&b, 0));
    }

    #[test]
    fn stochastic_rounding_keeps_splats_below_one_step() {
        // 10^6 splats of 0.3 steps each: rounding to nearest would give 0; the dithered sum
        // matches the exact sum within a few standard deviations (each splat's rounding error
        // has variance 0.3 * 0.7 steps^2).
        let key = crate::camera::Keyframe {
            frame: 0,
            position: Vec3::Z,
            look_at: Vec3::ZERO,
            up: Vec3::Y,
            fov: 40.0,
        };
        let cam = Camera::new(&key, 1, 1);
        let opts = RenderOptions {
            method: Method::MisExact,
            ..RenderOptions::default()
        };
        let acc = FrameAccum::new(0, cam, &opts);
        let v = 0.3 / FIXED as f32;
        let n = 1_000_000u64;
        for k in 0..n {
            assert!(acc.splat(0, Vec3::splat(v), mix64(k)));
        }
        let exact = n as f64 * v as f64;
        let sigma = (n as f64 * 0.21).sqrt() / FIXED;
        for c in 0..3 {
            let got = total(&acc.sum, c);
            assert!(
                (got - exact).abs() < 5.0 * sigma,
                "channel {c}: {got} vs {exact}"
            );
        }
        assert!(!acc.splat(0, Vec3::new(f32::NAN, 0.0, 0.0), 0));
    }
}
