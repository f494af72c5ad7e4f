//! Errors against a reference, and the fits that turn runs into equal-error speed-ups.
//!
//! Per frame over pixels `p` and channels `c`, with `I` the image under test and `V` the
//! variance of the reference's mean subtracted so that the reference's own noise does not count
//! (it is independent of `I`):
//! - `rmse = sqrt(max(0, mean((I - R)^2 - V)))`;
//! - `relmse = mean(((I - R)^2 - V) / (R^2 + 0.01))`;
//! - `flicker_t = sqrt(max(0, mean((E_t - E_(t-1))^2 - V_t - V_(t-1))))` with `E_t = I_t - R_t`:
//!   the RMS change of the error image from one frame to the next; lower is steadier.
//!
//! Overall: `rmse` over all frames' pixels, `relmse` the mean over frames, `flicker` the mean of
//! `flicker_t` over consecutive pairs.
//!
//! **Equal-error speed-up**: `log relmse = a + b log t` is fitted by least squares to each
//! method's runs (`loglog_fit`; a single run assumes `b = -1`, the Monte Carlo rate of a mean
//! squared error, and `b = -0.5` for flicker, an RMS figure). At a common
//! error, the time the independent line needs over the time the method's line needs is the
//! speed-up (`time_for`).
use super::reference::{RefFrame, Reference};
use glam::Vec3;
use serde::Serialize;

/// The `relmse` denominator offset.
const REL_EPS: f64 = 0.01;

pub const RELMSE_FORMULA: &str = "relmse = mean over pixels and RGB channels of ((I - R)^2 - V) / (R^2 + 0.01), V = variance of the reference's mean";
pub const RMSE_FORMULA: &str =
    "rmse = sqrt(max(0, mean over pixels and RGB channels of (I - R)^2 - V))";
pub const FLICKER_FORMULA: &str = "flicker = mean over t of sqrt(max(0, mean over pixels and RGB channels of (E_t - E_(t-1))^2 - V_t - V_(t-1))), E_t = I_t - R_t";

/// Errors of one frame against the reference.
#[derive(Clone, Debug, Serialize)]
pub struct FrameError {
    pub frame: u32,
    pub rmse: f64,
    pub relmse: f64,
    /// Against the previous frame; absent for the first.
    pub flicker: Option<f64>,
}

/// The errors of a run's frames: per frame, and overall (rmse, relmse, flicker).
pub fn errors(frames: &[Vec<Vec3>], r: &Reference) -> (Vec<FrameError>, f64, f64, f64) {
    let mut per = Vec::new();
    let mut sq_total = 0.0;
    for (t, img) in frames.iter().enumerate() {
        let rf = &r.frames[t];
        let (mut sq, mut rel) = (0.0f64, 0.0f64);
        for ((i, m), v) in img.iter().zip(&rf.mean).zip(&rf.var) {
            for c in 0..3 {
                let d = (i[c] - m[c]) as f64;
                let e = d * d - v[c] as f64;
                sq += e;
                rel += e / ((m[c] as f64).powi(2) + REL_EPS);
            }
        }
        let n = (img.len() * 3) as f64;
        let flicker = (t > 0).then(|| {
            let (prev, rp) = (&frames[t - 1], &r.frames[t - 1]);
            let mut s = 0.0f64;
            for p in 0..img.len() {
                for c in 0..3 {
                    let e1 = (img[p][c] - rf.mean[p][c]) as f64;
                    let e0 = (prev[p][c] - rp.mean[p][c]) as f64;
                    s += (e1 - e0).powi(2) - rf.var[p][c] as f64 - rp.var[p][c] as f64;
                }
            }
            (s / n).max(0.0).sqrt()
        });
        sq_total += sq;
        per.push(FrameError {
            frame: r.first + t as u32,
            rmse: (sq / n).max(0.0).sqrt(),
            relmse: rel / n,
            flicker,
        });
    }
    let n_all = frames.iter().map(|f| f.len() * 3).sum::<usize>() as f64;
    let rmse = (sq_total / n_all).max(0.0).sqrt();
    let relmse = per.iter().map(|e| e.relmse).sum::<f64>() / per.len() as f64;
    let fl: Vec<f64> = per.iter().filter_map(|e| e.flicker).collect();
    // Flicker is a change between consecutive frames: of one frame there is none, NaN here
    // (`null` in the JSON, empty in the CSV: a 0 read as perfectly steady).
    let flicker = if fl.is_empty() {
        f64::NAN
    } else {
        fl.iter().sum::<f64>() / fl.len() as f64
    };
    (per, rmse, relmse, flicker)
}

/// A frame's bias, estimated from `N >= 2` renders with different seeds (`BiasFigures`).
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct BiasFigures {
    /// `mean(b^2 / (R^2 + 0.01))`, with per pixel and channel the unbiased estimate of the
    /// squared bias `b^2 = (N ebar^2 - mean(e^2)) / (N - 1) - V` from the seeds' errors
    /// `e_i = I_i - R`: `E[ebar^2] = b^2 + s^2/N + V` and `E[mean(e^2)] = b^2 + s^2 + V`.
    pub bias_relmse: f64,
    /// The relMSE of one seed's frame, averaged over the seeds.
    pub relmse: f64,
    /// The relMSE of the seeds' mean frame.
    pub relmse_of_mean: f64,
}

/// The bias figures of one frame rendered with `seeds.len()` seeds, and the seeds' mean image.
pub fn bias_estimate(seeds: &[Vec<Vec3>], r: &RefFrame) -> (BiasFigures, Vec<Vec3>) {
    let n = seeds.len();
    assert!(n >= 2, "a bias estimate needs two seeds");
    let nf = n as f64;
    let (mut b2, mut e2, mut eb2) = (0.0f64, 0.0f64, 0.0f64);
    let mut mean = vec![Vec3::ZERO; r.mean.len()];
    for (p, m) in mean.iter_mut().enumerate() {
        for c in 0..3 {
            let rv = r.mean[p][c] as f64;
            let errs = seeds.iter().map(|s| s[p][c] as f64 - rv);
            let ebar = errs.clone().sum::<f64>() / nf;
            let esq = errs.map(|e| e * e).sum::<f64>() / nf;
            let v = r.var[p][c] as f64;
            let w = 1.0 / (rv * rv + REL_EPS);
            b2 += ((nf * ebar * ebar - esq) / (nf - 1.0) - v) * w;
            e2 += (esq - v) * w;
            eb2 += (ebar * ebar - v) * w;
            m[c] = (rv + ebar) as f32;
        }
    }
    let k = (r.mean.len() * 3) as f64;
    (
        BiasFigures {
            bias_relmse: b2 / k,
            relmse: e2 / k,
            relmse_of_mean: eb2 / k,
        },
        mean,
    )
}

/// Least-squares line through `(ln x, ln y)`: `(a, b)` with `ln y = a + b ln x`. A single point
/// (or points at one x) gets the Monte Carlo slope `single`: -1 for a mean squared error, -0.5
/// for an RMS figure such as flicker. `None` without a usable point.
pub fn loglog_fit(points: &[(f64, f64)], single: f64) -> Option<(f64, f64)> {
    let p: Vec<(f64, f64)> = points
        .iter()
        .filter(|(x, y)| *x > 0.0 && *y > 0.0 && x.is_finite() && y.is_finite())
        .map(|(x, y)| (x.ln(), y.ln()))
        .collect();
    match p.len() {
        0 => None,
        1 => Some((p[0].1 - single * p[0].0, single)),
        n => {
            let n = n as f64;
            let (mx, my) = (
                p.iter().map(|q| q.0).sum::<f64>() / n,
                p.iter().map(|q| q.1).sum::<f64>() / n,
            );
            let sxx: f64 = p.iter().map(|q| (q.0 - mx).powi(2)).sum();
            let sxy: f64 = p.iter().map(|q| (q.0 - mx) * (q.1 - my)).sum();
            if sxx < 1e-12 {
                return Some((my - single * mx, single));
            }
            let b = sxy / sxx;
            Some((my - b * mx, b))
        }
    }
}

/// The time at which the fitted line `(a, b)` reaches error `e`; `None` if it never falls.
pub fn time_for(fit: (f64, f64), e: f64) -> Option<f64> {
    (fit.1 < -1e-3).then(|| ((e.ln() - fit.0) / fit.1).exp())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::reference::RefFrame;
    use std::path::PathBuf;

    #[test]
    fn loglog_fit_recovers_a_power_law() {
        let pts: Vec<(f64, f64)> = [1.0, 2.0, 4.0, 8.0].iter().map(|&t| (t, 0.3 / t)).collect();
        let (a, b) = loglog_fit(&pts, -1.0).unwrap();
        assert!((b + 1.0).abs() < 1e-12 && (a - 0.3f64.ln()).abs() < 1e-12);
        assert!((time_for((a, b), 0.03).unwrap() - 10.0).abs() < 1e-9);
        // One point: the Monte Carlo slope through it.
        let (a1, b1) = loglog_fit(&[(2.0, 0.5)], -1.0).unwrap();
        assert_eq!(b1, -1.0);
        assert!((time_for((a1, b1), 0.25).unwrap() - 4.0).abs() < 1e-9);
        // An error that does not fall with time has no time for a lower error.
        assert!(time_for((0.0, 0.0), 0.1).is_none());
        assert!(loglog_fit(&[(1.0, 0.0)], -1.0).is_none());
        // An RMS figure falls with the root of the time: 0.2 at 4 s is 0.1 at 16 s.
        let (a2, b2) = loglog_fit(&[(4.0, 0.2)], -0.5).unwrap();
        assert!(((a2 + b2 * 16f64.ln()).exp() - 0.1).abs() < 1e-12);
    }

    #[test]
    fn bias_estimate_finds_a_known_bias_under_noise_and_none_without_one() {
        // Pixels with reference 1 and reference variance 0.0004; seeds' frames are the
        // reference plus a bias `b` plus uniform noise of variance 1/12 (far above b^2).
        let npix = 20_000;
        let r = RefFrame {
            mean: vec![Vec3::ONE; npix],
            var: vec![Vec3::splat(0.0004); npix],
        };
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut uniform = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 40) as f32 / (1u64 << 24) as f32 - 0.5
        };
        for (b, seeds) in [(0.1f32, 4usize), (0.0, 4), (0.05, 2)] {
            // The reference mean here is exact, so every figure is short by the variance `V` it
            // subtracts.
            let frames: Vec<Vec<Vec3>> = (0..seeds)
                .map(|_| {
                    (0..npix)
                        .map(|_| Vec3::new(uniform(), uniform(), uniform()) + Vec3::splat(1.0 + b))
                        .collect()
                })
                .collect();
            let (fig, mean) = bias_estimate(&frames, &r);
            let v = 0.0004 / 1.01;
            let want = (b * b) as f64 / 1.01 - v;
            // Standard error of the estimate: about sqrt(2/(N-1)) (1/12) / sqrt(3 npix).
            let se = (2.0 / (seeds as f64 - 1.0)).sqrt() / 12.0 / (3.0 * npix as f64).sqrt();
            assert!(
                (fig.bias_relmse - want).abs() < 5.0 * se,
                "b {b}, {seeds} seeds: {} against {want}",
                fig.bias_relmse
            );
            // One seed's relMSE holds the noise; the mean of the seeds a 1/N of it.
            let noise = 1.0 / 12.0 / 1.01;
            assert!((fig.relmse - want - noise).abs() < 0.03 * noise, "{fig:?}");
            assert!(
                (fig.relmse_of_mean - want - noise / seeds as f64).abs() < 0.05 * noise,
                "{fig:?}"
            );
            let m: f32 = mean.iter().map(|v| v.x).sum::<f32>() / npix as f32;
            assert!((m - 1.0 - b).abs() < 0.01, "mean {m}");
            // Without a correction for the noise, the squared mean error alone would be off.
            if b == 0.0 {
                assert!(fig.relmse_of_mean > 30.0 * se, "{fig:?}");
            }
        }
    }

    fn reference_of(mean: Vec<Vec<Vec3>>, var: f32) -> Reference {
        Reference {
            first: 0,
            frames: mean
                .into_iter()
                .map(|m| RefFrame {
                    var: vec![Vec3::splat(var); m.len()],
                    mean: m,
                })
                .collect(),
            dir: PathBuf::new(),
            spp: 8,
            cached: false,
            seconds: 0.0,
        }
    }

    #[test]
    fn errors_follow_their_formulas() {
        let r = reference_of(
            vec![vec![Vec3::splat(1.0); 4], vec![Vec3::splat(2.0); 4]],
            0.0,
        );
        // Frame 0 off by +0.1 everywhere, frame 1 off by -0.1: rmse 0.1, flicker 0.2.
        let frames = vec![vec![Vec3::splat(1.1); 4], vec![Vec3::splat(1.9); 4]];
        let (per, rmse, relmse, flicker) = errors(&frames, &r);
        assert!((rmse - 0.1).abs() < 1e-6, "{rmse}");
        assert!((per[0].relmse - 0.01 / 1.01).abs() < 1e-6);
        assert!((per[1].relmse - 0.01 / 4.01).abs() < 1e-6);
        assert!((relmse - (per[0].relmse + per[1].relmse) / 2.0).abs() < 1e-12);
        assert!(per[0].flicker.is_none());
        assert!((flicker - 0.2).abs() < 1e-6, "{flicker}");
        // The reference's variance is taken off: an exact image scores 0, not -V.
        let noisy = reference_of(vec![vec![Vec3::splat(1.0); 4]], 0.0025);
        let (_, rmse, _, _) = errors(&[vec![Vec3::splat(1.1); 4]], &noisy);
        assert!((rmse - 0.0075f64.sqrt()).abs() < 1e-6, "{rmse}");
        let (_, rmse, _, flicker) = errors(&[vec![Vec3::splat(1.0); 4]], &noisy);
        assert_eq!(rmse, 0.0);
        // One frame has no flicker: `null` in compare.json, not a 0 that reads as steady.
        assert!(flicker.is_nan());
        assert_eq!(serde_json::to_string(&flicker).unwrap(), "null");
    }
}
