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
use super::reference::Reference;
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
    let flicker = if fl.is_empty() {
        0.0
    } else {
        fl.iter().sum::<f64>() / fl.len() as f64
    };
    (per, rmse, relmse, flicker)
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
        let (_, rmse, _, _) = errors(&[vec![Vec3::splat(1.0); 4]], &noisy);
        assert_eq!(rmse, 0.0);
    }
}
