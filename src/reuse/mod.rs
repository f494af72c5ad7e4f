//! Frame reuse (Méndez-Feliu, Sbert, Szirmay-Kalos 2006; the estimators derived in
//! `docs/estimators.md`).
//!
//! Schedule (the paper's Sec. 4.1): a group is `n_f = --window` consecutive frames; every frame of
//! the group shoots `n_r = --spp` native samples per pixel, and every native primary hit is
//! reused in every other frame of the group after one visibility test towards that frame's eye.
//! Groups slide one frame at a time; a frame's estimate is the mean of the estimates of the
//! groups it belongs to (the driver's group loop, `driver::groups`).
//!
//! The rooms: `Method` (here) is the one registry of methods and answers every per-method
//! question; `weights` holds each equation of the paper once, by number; `shade` traces a tile's
//! native samples and splats their reuses into the group's films; `visibility` tests hits against
//! an eye; `adaptive` decides per-pixel native counts before sampling. The estimator takes a
//! `Params` struct, never the command line's options, and writes no file.
pub mod adaptive;
pub mod shade;
pub mod visibility;
pub mod weights;

use crate::film::{Layout, Norm};
use serde::Serialize;

/// Rendering methods, registered in one place: a new method is one variant here and one arm in
/// each `match` on it (`name`, `weights`, `norm`, `adaptive`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, clap::ValueEnum, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// Independent path tracing of every frame (the baseline).
    Independent,
    /// Havran et al. 2003: reused samples averaged unweighted (biased on glossy surfaces).
    Havran,
    /// The paper's MIS reuse (eq. 13-15 with approximation (10)).
    Mis,
    /// Balance heuristic over the group's eyes with exact area densities (docs/estimators.md).
    MisExact,
    /// `mis-exact` with a cross-fitted control variate on the sum of the weights that land in a
    /// pixel: unbiased, without the count noise (docs/estimators.md, "Control variate").
    MisCv,
}

/// Which estimator a method splats with (`weights`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Weights {
    /// No reuse: the path tracer's own estimate in its own pixel.
    None,
    /// The native eye's estimate (7) re-evaluated for the target eye (Havran et al.).
    OwnEye,
    /// The balance heuristic of eq. 15, which approximation (10) reduces eq. 13 to.
    Paper,
    /// Eq. 13 with the exact area densities `D_k` (docs/estimators.md, "exact").
    Exact,
}

impl Method {
    pub const ALL: [Method; 5] = [
        Method::Independent,
        Method::Havran,
        Method::Mis,
        Method::MisExact,
        Method::MisCv,
    ];

    pub fn name(&self) -> &'static str {
        match self {
            Method::Independent => "independent",
            Method::Havran => "havran",
            Method::Mis => "mis",
            Method::MisExact => "mis-exact",
            Method::MisCv => "mis-cv",
        }
    }

    /// The method named `s` (as `name` spells it).
    pub fn from_name(s: &str) -> Option<Method> {
        Method::ALL.into_iter().find(|m| m.name() == s)
    }

    pub fn weights(&self) -> Weights {
        match self {
            Method::Independent => Weights::None,
            Method::Havran => Weights::OwnEye,
            Method::Mis => Weights::Paper,
            Method::MisExact | Method::MisCv => Weights::Exact,
        }
    }

    /// Whether it reuses samples across frames (and so takes a window).
    pub fn reuses(&self) -> bool {
        self.weights() != Weights::None
    }

    /// How a pixel's sums are normalised: by the count that landed (the ratio estimators of
    /// Havran et al. and of the paper: "for every pixel we keep the final color and the number
    /// of samples ... and average every result", Sec. 4.2), or by the groups (each group's
    /// splats are already a whole estimate, their weights dividing by the expected count).
    pub fn norm(&self) -> Norm {
        match self {
            Method::Havran | Method::Mis => Norm::Count,
            Method::Independent | Method::MisExact => Norm::Groups,
            Method::MisCv => Norm::ControlVariate,
        }
    }

    /// Whether adaptive native counts (`--adaptive`) keep it unbiased: only weights built from
    /// the exact densities take per-pixel counts into account.
    pub fn adaptive(&self) -> bool {
        self.weights() == Weights::Exact
    }

    /// `mis-cv`'s folds for a frame that only one group reaches (the first and last frames of a
    /// range, every frame of a range of one group): its splats are folded by the parity of the
    /// sample index within the pixel instead of the group's, and each fold is then a complete
    /// sampling with `ceil(n_r / 2)` or `floor(n_r / 2)` samples per pixel of every eye, whose
    /// weight sums expect those shares of one (docs/estimators.md, "Frames that one group
    /// reaches"). Returns the two expected shares, or `None` where that is not exact or not
    /// useful: other methods, one native sample, a window of one (nothing lands from other eyes:
    /// the weights sum to one exactly), adaptive counts (a pixel's count may be odd, and the
    /// shares would differ from pixel to pixel).
    pub fn sample_folds(&self, spp: u32, window: u32, adaptive: bool) -> Option<[f64; 2]> {
        if self.norm() != Norm::ControlVariate || spp < 2 || window < 2 || adaptive {
            return None;
        }
        let n = spp as f64;
        Some([spp.div_ceil(2) as f64 / n, (spp / 2) as f64 / n])
    }

    /// The accumulator layout of a frame for `n_r` native samples and `n_f` frames per group,
    /// in sums whose unit is worth `radiance` (`radiance_unit`, the scene's scale): the methods
    /// that average by count splat whole radiance estimates, so one unit of their sums is worth
    /// `n_r n_f` times that (the count expected without losses) to keep the sums small.
    pub fn layout(&self, spp: u32, window: u32, aov: bool, radiance: f32) -> Layout {
        let by_count = self.norm() == Norm::Count;
        Layout {
            unit: if by_count {
                (spp * window) as f32 * radiance
            } else {
                radiance
            },
            norm: self.norm(),
            landed: by_count || aov,
            loss: aov,
        }
    }
}

/// What the reuse estimator needs to know of a render (a small part of the driver's options).
#[derive(Clone, Copy, Debug)]
pub struct Params {
    pub method: Method,
    /// Native samples per pixel per group, `n_r`.
    pub spp: u32,
    pub seed: u64,
    /// Visibility tests in 16-wide packets (else single rays).
    pub packets: bool,
}

/// Camera samples of the pilot that sets `radiance_unit`: a grid over the film of at most this
/// many columns and rows.
const PILOT_GRID: (u32, u32) = (32, 24);

/// What one unit of a reuse film's sums is worth in radiance: a power of two, from the
/// brightest of a fixed grid of independent samples of frame `frame` through `cam` (a pilot, the
/// same for every chunk and resume of a run: it depends only on the scene, the frame, the
/// resolution, the depth, the seed and the samples per group), and never so small that the
/// scene's brightest light would overflow a sum in a frame the pilot did not see
/// (`unit_floor`).
///
/// Why: the sums are fixed point with steps of 2^-20 units (`film::fixed`), so with a fixed unit
/// a dim scene (radiance of 1e-5, as a small lamp in a large room, or a scene in other units
/// gives) was summed in steps as large as its splats: unbiased, but most pixels came out black
/// or a single step. The unit follows the scene down, so that its brightest sample is between
/// one half and one unit, and up past 2^20 units, so that a pixel's total stays inside the 63
/// bits of a sum (docs/estimators.md, "Fixed-point accumulation"); in between it is 1 (the
/// shipped scenes). A power of two divides exactly, so a scene scaled by one renders frames
/// scaled by it, bit for bit.
pub fn radiance_unit(
    integrator: &crate::integrator::Integrator,
    cam: &crate::camera::Camera,
    frame: u32,
    seed: u64,
    samples_per_group: u32,
) -> f32 {
    use crate::integrator::Tally;
    use crate::sampling::Sampler;
    let (gx, gy) = (PILOT_GRID.0.min(cam.width), PILOT_GRID.1.min(cam.height));
    let mut t = Tally::default();
    let mut brightest = 0.0f32;
    for j in 0..gy {
        for i in 0..gx {
            // Cell centres, in raster coordinates of the film.
            let r = glam::Vec2::new(
                (i as f32 + 0.5) * cam.width as f32 / gx as f32,
                (j as f32 + 0.5) * cam.height as f32 / gy as f32,
            );
            let mut s = Sampler::new(seed ^ PILOT_SALT, frame, j * gx + i, 0);
            let v = integrator.sample_pixel(cam, r, &mut s, &mut t);
            if v.is_finite() {
                brightest = brightest.max(v.max_element());
            }
        }
    }
    unit_for(brightest).max(unit_floor(
        integrator.scene.brightest_emission(),
        samples_per_group,
    ))
}

/// The smallest unit at which a pixel of any frame, however bright, keeps its total inside the
/// 63 bits of a sum (2^43 units): a frame reached by `n_f` groups of `n_r` samples each sums
/// about `n_f n_r` samples' worth, and a sample sees at most a few thousand times the brightest
/// emission `l` (2^12: a light seen directly is `l`, one reflected near it can be more). The
/// pilot sees one frame: a first frame lit at 1e-5 set a unit that clipped a lamp of 1e9 seen
/// in a later frame to 1.3e8 (docs/estimators.md). A power of two, 0 where nothing emits.
fn unit_floor(l: f32, samples_per_group: u32) -> f32 {
    let most = l as f64 * samples_per_group as f64 * 4096.0 / 2f64.powi(43);
    if !(most > 0.0 && most.is_finite()) {
        return 0.0;
    }
    2f32.powi((most.log2().ceil() as i32).clamp(-120, 120))
}

/// Salt of the pilot's random numbers, so that they are not a frame's own samples.
const PILOT_SALT: u64 = 0x7069_6c6f_7475_6e69;

/// The unit for a brightest sample of `b`: `2^e` with `e = ceil(log2 b)` where that is below 0,
/// `e - 20` where it is above 20, else 1; 1 for a black or unreadable pilot.
fn unit_for(b: f32) -> f32 {
    if !(b > 0.0 && b.is_finite()) {
        return 1.0;
    }
    let e = b.log2().ceil() as i32;
    let e = (e.min(0) + (e - 20).max(0)).clamp(-120, 120);
    2f32.powi(e)
}
