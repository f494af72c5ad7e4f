//! Random numbers and the warps that turn them into directions and points.
//!
//! Every random number is a hash of (seed, frame, pixel, sample index, dimension), as pbrt-v4's
//! `StartPixelSample` and Embree's `RandomSampler_init` do: nothing depends on which thread
//! draws it or in which order, so the same command gives bitwise identical frames with any
//! thread count, and the frame is part of the key so that noise does not 'swim' with the camera.
//!
//! ```
//! use reframe::sampling::Sampler;
//! let mut a = Sampler::new(1, 2, 3, 4);
//! let mut b = Sampler::new(1, 2, 3, 4);
//! assert_eq!(a.next_1d(), b.next_1d());
//! ```
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

/// The 64-bit finaliser of SplitMix64 (Steele, Lea, Flood 2014): a bijective avalanche mix.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A counter-based sampler: the key names the sample, the dimension counter the number in it.
#[derive(Clone, Debug)]
pub struct Sampler {
    key: u64,
    dim: u64,
}

impl Sampler {
    pub fn new(seed: u64, frame: u32, pixel: u32, sample: u32) -> Sampler {
        let mut h = mix64(seed ^ 0x5851_f42d_4c95_7f2d);
        h = mix64(h ^ frame as u64);
        h = mix64(h ^ pixel as u64);
        h = mix64(h ^ sample as u64);
        Sampler { key: h, dim: 0 }
    }

    /// A uniform number in [0, 1), with 24 bits (every float of that spacing is representable).
    #[inline]
    pub fn next_1d(&mut self) -> f32 {
        let x = mix64(self.key ^ self.dim.wrapping_mul(0x9e37_79b9_7f4a_7c15));
        self.dim += 1;
        (x >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }

    #[inline]
    pub fn next_2d(&mut self) -> Vec2 {
        let a = self.next_1d();
        Vec2::new(a, self.next_1d())
    }

    /// Skip to a fixed dimension, so that a stage of the path always reads the same numbers
    /// whatever the stages before it consumed.
    pub fn set_dimension(&mut self, dim: u64) {
        self.dim = dim;
    }
}

/// An orthonormal basis around unit `n` (Duff et al. 2017, "Building an orthonormal basis,
/// revisited"), returned as (tangent, bitangent).
#[inline]
pub fn basis(n: Vec3) -> (Vec3, Vec3) {
    let sign = 1.0f32.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        Vec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// Express local direction `d` (z up) in the frame around unit `n`.
#[inline]
pub fn to_world(n: Vec3, d: Vec3) -> Vec3 {
    let (t, b) = basis(n);
    t * d.x + b * d.y + n * d.z
}

/// Cosine-weighted hemisphere around +z (Malley's method); pdf = cos(theta) / pi.
#[inline]
pub fn cosine_hemisphere(u: Vec2) -> Vec3 {
    let r = u.x.sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(r * phi.cos(), r * phi.sin(), (1.0 - u.x).max(0.0).sqrt())
}

/// Directions around +z with density (n+1)/(2 pi) cos^n(alpha) over the sphere (the Phong lobe):
/// cos(alpha) = u^(1/(n+1)).
#[inline]
pub fn phong_lobe(u: Vec2, exponent: f32) -> Vec3 {
    let cos_a = u.x.powf(1.0 / (exponent + 1.0));
    let sin_a = (1.0 - cos_a * cos_a).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(sin_a * phi.cos(), sin_a * phi.sin(), cos_a)
}

/// Density of `phong_lobe` at cos(alpha) (zero behind the lobe axis).
#[inline]
pub fn phong_lobe_pdf(cos_a: f32, exponent: f32) -> f32 {
    if cos_a <= 0.0 {
        0.0
    } else {
        (exponent + 1.0) / (2.0 * PI) * cos_a.powf(exponent)
    }
}

/// Uniform barycentrics (b1, b2) on a triangle (Heitz 2019 low-distortion map is not needed; the
/// square-root parameterisation is exact and cheap).
#[inline]
pub fn uniform_triangle(u: Vec2) -> (f32, f32) {
    let su = u.x.sqrt();
    (1.0 - su, u.y * su)
}

/// Pearson's chi-square of `observed` counts against `expected` ones (the sampling tests of the
/// BSDFs and the environment; pbrt-v4 bsdfs_test, Mitsuba chi2.py): cells expecting fewer than 5
/// are pooled, in order of expectation, until each pool expects 5. Returns the statistic, the
/// degrees of freedom and the p-value.
#[cfg(test)]
pub(crate) fn chi_square(expected: &[f64], observed: &[f64]) -> (f64, usize, f64) {
    use statrs::distribution::{ChiSquared, ContinuousCDF};
    let mut idx: Vec<usize> = (0..expected.len()).collect();
    idx.sort_by(|&a, &b| expected[a].partial_cmp(&expected[b]).unwrap());
    let (mut chi2, mut dof) = (0.0, 0usize);
    let (mut pe, mut po) = (0.0, 0.0);
    for &i in &idx {
        if expected[i] < 5.0 {
            pe += expected[i];
            po += observed[i];
            if pe >= 5.0 {
                chi2 += (po - pe) * (po - pe) / pe;
                dof += 1;
                pe = 0.0;
                po = 0.0;
            }
        } else {
            chi2 += (observed[i] - expected[i]).powi(2) / expected[i];
            dof += 1;
        }
    }
    if pe > 0.0 {
        chi2 += (po - pe) * (po - pe) / pe.max(1e-9);
        dof += 1;
    }
    let p = 1.0 - ChiSquared::new((dof - 1) as f64).unwrap().cdf(chi2);
    (chi2, dof, p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sampler_is_uniform_and_keyed() {
        let mut s = Sampler::new(1, 0, 0, 0);
        let n = 100_000;
        let mut bins = [0u32; 10];
        for _ in 0..n {
            let x = s.next_1d();
            assert!((0.0..1.0).contains(&x));
            bins[(x * 10.0) as usize] += 1;
        }
        for b in bins {
            assert!((b as f32 - 10_000.0).abs() < 500.0, "{bins:?}");
        }
        assert_ne!(
            Sampler::new(1, 0, 0, 0).next_1d(),
            Sampler::new(1, 1, 0, 0).next_1d()
        );
        assert_ne!(
            Sampler::new(1, 0, 0, 0).next_1d(),
            Sampler::new(1, 0, 1, 0).next_1d()
        );
        assert_ne!(
            Sampler::new(1, 0, 0, 0).next_1d(),
            Sampler::new(1, 0, 0, 1).next_1d()
        );
        assert_ne!(
            Sampler::new(1, 0, 0, 0).next_1d(),
            Sampler::new(2, 0, 0, 0).next_1d()
        );
    }

    #[test]
    fn basis_is_orthonormal() {
        let mut s = Sampler::new(5, 0, 0, 0);
        for _ in 0..1000 {
            let n = (Vec3::new(s.next_1d(), s.next_1d(), s.next_1d()) * 2.0 - 1.0).normalize();
            let (t, b) = basis(n);
            assert!((t.length() - 1.0).abs() < 1e-4 && (b.length() - 1.0).abs() < 1e-4);
            assert!(t.dot(n).abs() < 1e-4 && b.dot(n).abs() < 1e-4 && t.dot(b).abs() < 1e-4);
            assert!((t.cross(b) - n).length() < 1e-3, "right-handed");
        }
    }

    #[test]
    fn triangle_samples_are_inside() {
        let mut s = Sampler::new(9, 0, 0, 0);
        let mut mean = (0.0f64, 0.0f64);
        for _ in 0..100_000 {
            let (b1, b2) = uniform_triangle(s.next_2d());
            assert!(b1 >= 0.0 && b2 >= 0.0 && b1 + b2 <= 1.0 + 1e-6);
            mean.0 += b1 as f64;
            mean.1 += b2 as f64;
        }
        // The centroid has barycentrics (1/3, 1/3).
        assert!(
            (mean.0 / 1e5 - 1.0 / 3.0).abs() < 0.005 && (mean.1 / 1e5 - 1.0 / 3.0).abs() < 0.005
        );
    }
}
