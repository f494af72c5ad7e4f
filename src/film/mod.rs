//! The film: what a frame accumulates while the groups that contain it are rendered, and how it
//! becomes pixels. A leaf under the estimators: it knows no method, no option and no file.
//!
//! - `FixedSums` (`fixed.rs`): per-pixel RGB sums in 32-bit fixed point with exact carries.
//! - `FrameAccum`: one frame's sums plus the counts some methods and `--aov` need (samples that
//!   landed, reuses tried and lost), the number of groups that contributed and the time spent.
//!   Its `Layout` says what one unit of the sums is worth and how a pixel is normalised; the
//!   reuse methods choose it (`reuse::Method::layout`).
//! - `develop`: the one function that turns an accumulator into pixels, for a frame of a single
//!   process, of a resumed one and of a merge of chunks alike, so that they agree to the bit.
//!   It writes the interleaved channels an image file takes, straight from the sums.
//! - `Developed` and `Sink`: a finished frame and where it goes (the driver writes files; the
//!   comparisons and tests keep frames in memory).
pub mod fixed;
pub mod local;
pub mod tiles;

use crate::camera::Camera;
use fixed::{FixedSums, FIXED};
use glam::Vec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering::Relaxed};
use std::time::Instant;

/// How a pixel's sums become its value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Norm {
    /// Divided by the groups that contributed: each group's contributions are already a whole
    /// estimate of the pixel (`mis-exact`, whose weights divide by the expected sample count).
    Groups,
    /// Divided by the samples that landed in the pixel (the ratio estimators of Havran et al.
    /// and of the paper, which average whatever lands).
    Count,
    /// The cross-fitted control variate on the weight sums (`mis-cv`, docs/estimators.md,
    /// "Control variate"): the groups are split into two folds by the parity of their first
    /// frame; each fold keeps its sums `A_F` and its weight sums `W_F` (whose expectation is one
    /// per group), and the pixel is
    /// `(A_E - beta_O (W_E - G_E) + A_O - beta_E (W_O - G_O)) / (G_E + G_O)`,
    /// `beta_F = A_F / W_F`.
    ControlVariate,
}

impl Norm {
    /// Folds of sums a pixel keeps: two for the control variate, else one.
    pub fn folds(&self) -> usize {
        match self {
            Norm::ControlVariate => 2,
            Norm::Groups | Norm::Count => 1,
        }
    }
}

/// What a frame's accumulator holds and how it is developed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Layout {
    /// What one unit of the sums is worth: contributions are divided by it before they are
    /// quantised, so that the sums stay in the range of the 32-bit cells.
    pub unit: f32,
    pub norm: Norm,
    /// Per-pixel landed counts (needed by `Norm::Count`, and for the `spp_eff` channel).
    pub landed: bool,
    /// Per-pixel tried and lost reuses (the `lost_reuse` channel).
    pub loss: bool,
}

impl Layout {
    /// 32-bit sum cells per pixel: RGB for each fold.
    pub fn sum_cells(&self) -> usize {
        3 * self.norm.folds()
    }

    /// 32-bit weight cells per pixel: one per fold for the control variate, else none.
    pub fn weight_cells(&self) -> usize {
        match self.norm {
            Norm::ControlVariate => self.norm.folds(),
            Norm::Groups | Norm::Count => 0,
        }
    }

    /// 32-bit count cells per pixel: samples landed, reuses tried and lost, where kept.
    pub fn count_cells(&self) -> usize {
        usize::from(self.landed) + if self.loss { 2 } else { 0 }
    }

    /// Bytes per pixel of a frame's accumulator.
    pub fn bytes_per_pixel(&self) -> usize {
        4 * (self.sum_cells() + self.weight_cells() + self.count_cells())
    }
}

/// Elapsed seconds that survive a resume: those of earlier processes plus this one's.
#[derive(Clone, Copy, Debug)]
pub struct Clock {
    pub earlier: f64,
    since: Instant,
}

impl Clock {
    pub fn start(earlier: f64) -> Clock {
        Clock {
            earlier,
            since: Instant::now(),
        }
    }

    pub fn seconds(&self) -> f64 {
        self.earlier + self.since.elapsed().as_secs_f64()
    }
}

/// Which frame an accumulator is, at what size, seen from which camera (the matrices every
/// frame file records).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    pub frame: u32,
    pub width: u32,
    pub height: u32,
    pub world_to_camera: [f32; 16],
    pub world_to_ndc: [f32; 16],
}

impl View {
    pub fn of(frame: u32, cam: &Camera) -> View {
        View {
            frame,
            width: cam.width,
            height: cam.height,
            world_to_camera: cam.world_to_camera().to_cols_array(),
            world_to_ndc: cam.world_to_ndc().to_cols_array(),
        }
    }

    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

/// Reuse figures of one frame (what `--stats` reports per frame; the run's figures are their
/// sums).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct FrameReuse {
    pub frame: u32,
    pub mean_effective_spp: f64,
    pub lost_reuse_fraction: f64,
    /// Samples that landed in the frame (native and reused), reuses tried into it, and those
    /// lost (occluded, or off its film).
    pub landed: u64,
    pub tried: u64,
    pub lost: u64,
}

/// The running sums of one frame over all the groups that contain it.
pub struct FrameAccum {
    pub view: View,
    pub layout: Layout,
    /// RGB per pixel and fold, pixel-major: cell `3 folds i + 3 f + c`.
    sum: FixedSums,
    /// The control variate's weight sums per pixel and fold (cell `2 i + f`).
    weights: Option<FixedSums>,
    landed: Option<Vec<AtomicU32>>,
    loss: Option<(Vec<AtomicU32>, Vec<AtomicU32>)>,
    landed_total: AtomicU64,
    tried: AtomicU64,
    lost: AtomicU64,
    /// Groups that contributed, by the parity of their first frame (the control variate's
    /// folds; the other methods use only the total).
    pub groups: [u32; 2],
    pub clock: Clock,
}

fn zeros(n: usize) -> Vec<AtomicU32> {
    (0..n).map(|_| AtomicU32::new(0)).collect()
}

/// Fixed-point cells and their carries (cell index, value in steps), as a state file holds them.
pub type RawSums = (Vec<i32>, Vec<(u64, i64)>);

/// The counters of an accumulator as a state file stores them.
pub struct AccumParts {
    pub cells: Vec<i32>,
    pub carry: Vec<(u64, i64)>,
    /// The control variate's weight cells and carries.
    pub weights: Option<RawSums>,
    pub landed: Option<Vec<u32>>,
    pub loss: Option<(Vec<u32>, Vec<u32>)>,
    /// Landed, tried and lost over the whole frame.
    pub totals: [u64; 3],
    pub groups: [u32; 2],
    pub seconds: f64,
}

impl FrameAccum {
    pub fn new(view: View, layout: Layout) -> FrameAccum {
        let p = view.pixels();
        FrameAccum {
            view,
            layout,
            sum: FixedSums::new(layout.sum_cells() * p),
            weights: (layout.weight_cells() > 0).then(|| FixedSums::new(layout.weight_cells() * p)),
            landed: layout.landed.then(|| zeros(p)),
            loss: layout.loss.then(|| (zeros(p), zeros(p))),
            landed_total: AtomicU64::new(0),
            tried: AtomicU64::new(0),
            lost: AtomicU64::new(0),
            groups: [0; 2],
            clock: Clock::start(0.0),
        }
    }

    /// An accumulator from the parts a state file holds; `None` if they do not fit `view` and
    /// `layout`.
    pub fn from_parts(view: View, layout: Layout, parts: AccumParts) -> Option<FrameAccum> {
        let p = view.pixels();
        let folds = layout.norm.folds();
        let fits = |v: &Vec<u32>| v.len() == p;
        let cells_fit = |cells: &Vec<i32>, carry: &Vec<(u64, i64)>, n: usize| {
            cells.len() == n && carry.iter().all(|&(i, _)| (i as usize) < n)
        };
        if !cells_fit(&parts.cells, &parts.carry, 3 * folds * p)
            || parts.weights.is_some() != (layout.norm == Norm::ControlVariate)
            || !parts
                .weights
                .as_ref()
                .is_none_or(|(c, k)| cells_fit(c, k, folds * p))
            || parts.landed.is_some() != layout.landed
            || parts.loss.is_some() != layout.loss
            || !parts.landed.as_ref().is_none_or(fits)
            || !parts.loss.as_ref().is_none_or(|(t, l)| fits(t) && fits(l))
        {
            return None;
        }
        let atomics = |v: Vec<u32>| v.into_iter().map(AtomicU32::new).collect::<Vec<_>>();
        let [landed_total, tried, lost] = parts.totals;
        Some(FrameAccum {
            view,
            layout,
            sum: FixedSums::from_parts(parts.cells, &parts.carry),
            weights: parts.weights.map(|(c, k)| FixedSums::from_parts(c, &k)),
            landed: parts.landed.map(atomics),
            loss: parts.loss.map(|(t, l)| (atomics(t), atomics(l))),
            landed_total: AtomicU64::new(landed_total),
            tried: AtomicU64::new(tried),
            lost: AtomicU64::new(lost),
            groups: parts.groups,
            clock: Clock::start(parts.seconds),
        })
    }

    pub fn frame(&self) -> u32 {
        self.view.frame
    }

    /// Add `v` to pixel `i` of fold `fold` (0 unless the layout has two), rounding
    /// stochastically with the bits of `dither`; false (and nothing added) if `v` is not finite.
    #[inline]
    pub fn splat(&self, i: usize, fold: usize, v: Vec3, dither: u64) -> bool {
        let Some(q) = self.quantize_rgb(v, dither) else {
            return false;
        };
        let base = self.rgb_cell(i, fold);
        for (c, q) in q.into_iter().enumerate() {
            self.sum.add(base + c, q);
        }
        true
    }

    /// The first of the three RGB cells of pixel `i`, fold `fold`.
    #[inline]
    fn rgb_cell(&self, i: usize, fold: usize) -> usize {
        3 * (self.layout.norm.folds() * i + fold)
    }

    /// `v` in units of the layout, quantised per channel with 21 bits of `dither` each; `None`
    /// if `v` is not finite.
    #[inline]
    fn quantize_rgb(&self, v: Vec3, dither: u64) -> Option<[i64; 3]> {
        if !v.is_finite() {
            return None;
        }
        // The exact-weight layouts have unit 1, where the division (exact there) is left out.
        let unit = self.layout.unit;
        let v = if unit == 1.0 { v } else { v / unit };
        // 21 bits of the hash per channel: u in [0, 1).
        let u = |c: u32| ((dither >> (21 * c)) & 0x1f_ffff) as f64 / (1u64 << 21) as f64;
        Some(fixed::quantize3(v.to_array(), [u(0), u(1), u(2)]))
    }

    /// A control-variate weight quantised with the top 53 bits of `dither`.
    #[inline]
    fn quantize_weight(w: f32, dither: u64) -> i64 {
        fixed::quantize(w, (dither >> 11) as f64 / (1u64 << 53) as f64)
    }

    /// Add the weight `w` to the control variate's sum of pixel `i`, fold `fold` (nothing where
    /// the layout keeps none), rounding with `dither`.
    #[inline]
    pub fn splat_weight(&self, i: usize, fold: usize, w: f32, dither: u64) {
        if let Some(ws) = &self.weights {
            ws.add(2 * i + fold, Self::quantize_weight(w, dither));
        }
    }

    /// Groups that contributed, both folds.
    pub fn group_count(&self) -> u32 {
        self.groups[0] + self.groups[1]
    }

    /// Count `n` samples landing in pixel `i` (where the layout keeps counts).
    #[inline]
    pub fn land(&self, i: usize, n: u32) {
        if let Some(landed) = &self.landed {
            landed[i].fetch_add(n, Relaxed);
        }
    }

    /// A reuse into pixel `i` was tried, and lost (`lost`) or not (where the layout keeps the
    /// per-pixel loss).
    #[inline]
    pub fn try_reuse(&self, i: usize, lost: bool) {
        if let Some((tried, lost_px)) = &self.loss {
            tried[i].fetch_add(1, Relaxed);
            if lost {
                lost_px[i].fetch_add(1, Relaxed);
            }
        }
    }

    /// Add a tile's frame-wide counts: samples landed, reuses tried and lost.
    pub fn add_counts(&self, landed: u64, tried: u64, lost: u64) {
        self.landed_total.fetch_add(landed, Relaxed);
        self.tried.fetch_add(tried, Relaxed);
        self.lost.fetch_add(lost, Relaxed);
    }

    /// Landed, tried and lost over the whole frame.
    pub fn counts(&self) -> [u64; 3] {
        [
            self.landed_total.load(Relaxed),
            self.tried.load(Relaxed),
            self.lost.load(Relaxed),
        ]
    }

    pub fn sums(&self) -> &FixedSums {
        &self.sum
    }

    /// The control variate's weight sums, if the layout keeps them.
    pub fn weight_sums(&self) -> Option<&FixedSums> {
        self.weights.as_ref()
    }

    pub fn landed_counts(&self) -> Option<impl Iterator<Item = u32> + '_> {
        self.landed
            .as_ref()
            .map(|v| v.iter().map(|c| c.load(Relaxed)))
    }

    pub fn loss_counts(
        &self,
    ) -> Option<(
        impl Iterator<Item = u32> + '_,
        impl Iterator<Item = u32> + '_,
    )> {
        self.loss.as_ref().map(|(t, l)| {
            (
                t.iter().map(|c| c.load(Relaxed)),
                l.iter().map(|c| c.load(Relaxed)),
            )
        })
    }

    /// The frame's reuse figures.
    pub fn reuse(&self) -> FrameReuse {
        let [landed, tried, lost] = self.counts();
        FrameReuse {
            frame: self.view.frame,
            mean_effective_spp: landed as f64 / self.view.pixels() as f64,
            lost_reuse_fraction: if tried > 0 {
                lost as f64 / tried as f64
            } else {
                0.0
            },
            landed,
            tried,
            lost,
        }
    }

    /// Add `o`, the same frame's share from another chunk: the integer sums and counts add
    /// exactly, so the order of the chunks does not matter. `Err` if the two do not fit.
    pub fn absorb(&mut self, o: &FrameAccum) -> Result<(), String> {
        if (o.view.width, o.view.height) != (self.view.width, self.view.height)
            || o.layout != self.layout
        {
            return Err("records of different sizes or layouts".into());
        }
        self.sum.absorb(&o.sum);
        if let (Some(a), Some(b)) = (&self.weights, &o.weights) {
            a.absorb(b);
        }
        let add = |a: &mut [AtomicU32], b: &[AtomicU32]| {
            for (x, y) in a.iter_mut().zip(b) {
                *x.get_mut() += y.load(Relaxed);
            }
        };
        if let (Some(a), Some(b)) = (&mut self.landed, &o.landed) {
            add(a, b);
        }
        if let (Some((a, b)), Some((c, d))) = (&mut self.loss, &o.loss) {
            add(a, c);
            add(b, d);
        }
        let [l, t, x] = o.counts();
        self.add_counts(l, t, x);
        self.groups[0] += o.groups[0];
        self.groups[1] += o.groups[1];
        self.clock.earlier += o.clock.earlier;
        Ok(())
    }
}

/// A finished frame: its interleaved channels as an image file takes them.
pub struct Developed {
    pub view: View,
    /// `R`, `G`, `B`, then with `--aov` `spp_eff` and `lost_reuse`.
    pub channels: Vec<&'static str>,
    pub data: Vec<f32>,
    /// Seconds spent on the frame, by every process that rendered part of it.
    pub seconds: f64,
    /// Pixels with a NaN or infinite channel.
    pub nonfinite: u64,
}

impl Developed {
    /// Pixel `i`'s RGB.
    pub fn rgb(&self, i: usize) -> Vec3 {
        let k = i * self.channels.len();
        Vec3::new(self.data[k], self.data[k + 1], self.data[k + 2])
    }

    /// Whether every pixel's RGB is zero (no light reached the camera in the whole frame).
    pub fn is_black(&self) -> bool {
        let nc = self.channels.len().max(1);
        self.data
            .chunks_exact(nc)
            .all(|px| px[..nc.min(3)].iter().all(|&v| v == 0.0))
    }

    /// The RGB pixels, row by row.
    pub fn pixels(&self) -> Vec<Vec3> {
        (0..self.view.pixels()).map(|i| self.rgb(i)).collect()
    }

    /// A channel by name, one value per pixel.
    pub fn channel(&self, name: &str) -> Option<Vec<f32>> {
        let c = self.channels.iter().position(|n| *n == name)?;
        let nc = self.channels.len();
        Some(self.data.iter().skip(c).step_by(nc).copied().collect())
    }

    /// A frame of finished RGB pixels (the independent tracer's).
    pub fn from_pixels(view: View, px: &[Vec3], seconds: f64) -> Developed {
        let data: Vec<f32> = px.iter().flat_map(|p| p.to_array()).collect();
        Developed {
            view,
            channels: vec!["R", "G", "B"],
            nonfinite: count_nonfinite(&data, 3),
            data,
            seconds,
        }
    }
}

/// Pixels of `nc` interleaved channels with a NaN or infinite value among their first three.
pub fn count_nonfinite(data: &[f32], nc: usize) -> u64 {
    data.chunks_exact(nc)
        .filter(|p| !p[..3].iter().all(|v| v.is_finite()))
        .count() as u64
}

/// The frame's final pixels from its accumulator, and with `--aov` (`aov`, which the layout's
/// loss counts imply) its extra channels: RGB is the mean over the frame's groups (`Norm::Groups`)
/// or over everything that landed (`Norm::Count`); `spp_eff` is the landed count and
/// `lost_reuse` the share of tried reuses lost. `sample_folds`: the run's
/// `Method::sample_folds`, the folds' expected weight shares of a frame that one group reached
/// (the kernel folded its splats by sample index, `reuse::shade::Target::split`).
pub fn develop(a: &FrameAccum, sample_folds: Option<[f64; 2]>) -> Developed {
    let n = a.view.pixels();
    let totals = a.sum.totals();
    let weights = a.weights.as_ref().map(FixedSums::totals);
    // The per-pixel counts, read in place.
    let landed = a.landed.as_deref();
    let loss = a.loss.as_ref();
    let aov = loss.is_some();
    let mut channels = vec!["R", "G", "B"];
    if aov {
        channels.extend(["spp_eff", "lost_reuse"]);
    }
    let nc = channels.len();
    let unit = a.layout.unit;
    // The weights a fold expects: one per group, or a share of the one group.
    let g = match sample_folds {
        Some(shares) if a.group_count() == 1 => shares,
        _ => a.groups.map(f64::from),
    };
    // Pixel by pixel, each on its own: in parallel (in a render, on its workers, whose frame
    // loop waits for the frame here).
    let mut data = vec![0.0f32; n * nc];
    data.par_chunks_mut(nc).enumerate().for_each(|(i, px)| {
        let count = landed.map_or(0, |l| l[i].load(Relaxed));
        match (a.layout.norm, &weights) {
            (Norm::ControlVariate, Some(w)) => {
                let sum = |f: usize, c: usize| totals[6 * i + 3 * f + c] as f64 / FIXED;
                let w = [w[2 * i] as f64 / FIXED, w[2 * i + 1] as f64 / FIXED];
                for (c, v) in px[..3].iter_mut().enumerate() {
                    *v = control_variate([sum(0, c), sum(1, c)], w, g) as f32 * unit;
                }
            }
            (norm, _) => {
                let divisor = match norm {
                    Norm::Count => (count > 0).then_some(count as f32),
                    _ => Some(a.group_count() as f32),
                };
                for (c, v) in px[..3].iter_mut().enumerate() {
                    let s = (totals[3 * i + c] as f64 / FIXED) as f32 * unit;
                    *v = divisor.map_or(0.0, |d| s / d);
                }
            }
        }
        if let Some((tried, lost)) = loss {
            px[3] = count as f32;
            let (t, l) = (tried[i].load(Relaxed), lost[i].load(Relaxed));
            px[4] = if t > 0 { l as f32 / t as f32 } else { 0.0 };
        }
    });
    Developed {
        view: a.view,
        nonfinite: count_nonfinite(&data, nc),
        channels,
        data,
        seconds: a.clock.seconds(),
    }
}

/// The cross-fitted control-variate estimate of one pixel channel from its two folds' sums `s`,
/// weight sums `w` and the weight sums they expect `g` (one per group, or a share of one group;
/// docs/estimators.md, "Control variate"): each fold's self-normalised estimate `s_F / w_F` is
/// the other fold's coefficient, so the coefficient is independent of the samples it
/// multiplies. A fold without weight (no group, or nothing landed) gives coefficient 0.
pub fn control_variate(s: [f64; 2], w: [f64; 2], g: [f64; 2]) -> f64 {
    let groups = g[0] + g[1];
    if groups == 0.0 {
        return 0.0;
    }
    let beta = |f: usize| if w[f] > 0.0 { s[f] / w[f] } else { 0.0 };
    (s[0] - beta(1) * (w[0] - g[0]) + s[1] - beta(0) * (w[1] - g[1])) / groups
}

/// Where finished frames go: files (the driver), memory (comparisons, tests).
pub trait Sink {
    fn put(&mut self, frame: Developed) -> anyhow::Result<()>;

    /// Wait until every frame put so far is where the sink puts it (a sink may write on a
    /// thread of its own: `driver::sink::Writer`), and say the first failure if one failed.
    /// Returns the frames written to files since the last call, each with the FNV-1a hash of
    /// its file's bytes (a checkpoint keeps them: `state::Trailer::frame_digests`); none for a
    /// sink that writes no files.
    fn sync(&mut self) -> anyhow::Result<Vec<(u32, u64)>> {
        Ok(Vec::new())
    }
}

/// Frames kept in memory, by frame number.
#[derive(Default)]
pub struct MemorySink(pub std::collections::BTreeMap<u32, Developed>);

impl Sink for MemorySink {
    fn put(&mut self, frame: Developed) -> anyhow::Result<()> {
        self.0.insert(frame.view.frame, frame);
        Ok(())
    }
}

/// Frames handed to a closure.
impl<F: FnMut(Developed) -> anyhow::Result<()>> Sink for F {
    fn put(&mut self, frame: Developed) -> anyhow::Result<()> {
        self(frame)
    }
}
