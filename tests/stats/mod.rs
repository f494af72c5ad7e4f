//! Statistics shared by the statistical tests (`tests/reuse.rs`, `tests/stress.rs`): per-block
//! luminance moments over independent renders, and the per-block z-test of one estimator against
//! another, Šidák-corrected (Mitsuba's `test_renders.py` shape).
#![allow(dead_code)]
use glam::Vec3;

pub struct Moments {
    pub mean: Vec<f64>,
    pub var_of_mean: Vec<f64>,
}

/// Per-block luminance over `k` independent renders: block mean and the variance of that mean.
pub fn block_moments(renders: &[Vec<Vec3>], w: usize, h: usize, b: usize) -> Moments {
    let (bw, bh) = (w / b, h / b);
    let k = renders.len() as f64;
    let mut sums = vec![0.0f64; bw * bh];
    let mut sq = vec![0.0f64; bw * bh];
    for r in renders {
        let mut blk = vec![0.0f64; bw * bh];
        for y in 0..bh * b {
            for x in 0..bw * b {
                let p = r[y * w + x];
                blk[(y / b) * bw + x / b] +=
                    (0.2126 * p.x + 0.7152 * p.y + 0.0722 * p.z) as f64 / (b * b) as f64;
            }
        }
        for i in 0..blk.len() {
            sums[i] += blk[i];
            sq[i] += blk[i] * blk[i];
        }
    }
    let mean: Vec<f64> = sums.iter().map(|s| s / k).collect();
    let var_of_mean = sq
        .iter()
        .zip(&mean)
        .map(|(q, m)| ((q / k - m * m) * k / (k - 1.0)).max(0.0) / k)
        .collect();
    Moments { mean, var_of_mean }
}

/// The outcome of a per-block z-test.
pub struct ZTest {
    /// Share of blocks whose |z| is at most `z_crit`.
    pub pass: f64,
    pub worst: f64,
    /// Two-sided critical value at alpha 0.01, Šidák-corrected for the number of blocks.
    pub z_crit: f64,
    /// z of the whole image's mean (signed): the blocks' differences summed over the root of
    /// their summed variances.
    pub mean_z: f64,
}

/// Block-by-block z-scores of `test` against `reference` (both with the variance of their means).
pub fn z_test(test: &Moments, reference: &Moments) -> ZTest {
    let n = test.mean.len() as f64;
    let alpha = 1.0 - (1.0f64 - 0.01).powf(1.0 / n);
    // Two-sided normal quantile for alpha by bisection on erfc.
    let z_crit = {
        let (mut lo, mut hi) = (0.0f64, 10.0f64);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if statrs::function::erf::erfc(mid / std::f64::consts::SQRT_2) > alpha {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        lo
    };
    let (mut pass, mut worst) = (0, 0.0f64);
    let (mut diff, mut var_sum) = (0.0f64, 0.0f64);
    for i in 0..test.mean.len() {
        // A floor of one part in a million of the block's value: the estimators compute in f32,
        // so a block that both get almost exactly (an evenly lit background, where the control
        // variate's variance is ~1e-8) differs by rounding, not bias.
        let floor = (1e-6 * reference.mean[i].abs()).powi(2);
        let var = test.var_of_mean[i] + reference.var_of_mean[i] + floor;
        let d = test.mean[i] - reference.mean[i];
        diff += d;
        var_sum += var;
        let z = if var > 0.0 { d.abs() / var.sqrt() } else { 0.0 };
        worst = worst.max(z);
        if z <= z_crit {
            pass += 1;
        }
    }
    ZTest {
        pass: pass as f64 / n,
        worst,
        z_crit,
        mean_z: if var_sum > 0.0 {
            diff / var_sum.sqrt()
        } else {
            0.0
        },
    }
}

/// Fraction of blocks whose z-score against the reference passes at alpha 0.01, Šidák-corrected,
/// and the worst |z|.
pub fn z_pass_fraction(test: &Moments, reference: &Moments) -> (f64, f64) {
    let z = z_test(test, reference);
    (z.pass, z.worst)
}

/// Print `z` for `what` and assert the reuse tests' criterion of unbiasedness: at least 99% of
/// blocks pass and the whole image's mean within 4 sigma.
pub fn assert_unbiased(what: &str, z: &ZTest) {
    eprintln!(
        "{what}: {:.1}% of blocks pass (worst z {:.1}), image mean z {:.2}",
        100.0 * z.pass,
        z.worst,
        z.mean_z
    );
    assert!(
        z.pass >= 0.99 && z.mean_z.abs() < 4.0,
        "{what} fails the z-test: {:.1}% of blocks fail, image mean z {:.2}",
        100.0 * (1.0 - z.pass),
        z.mean_z
    );
}
