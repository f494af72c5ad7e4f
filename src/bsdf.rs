//! Materials and their BSDF: a Lambertian lobe (`Kd`) plus an energy-conserving modified Phong
//! lobe (`Ks`, `Ns`; Lafortune and Willems 1994, the paper's glossy vase), and emission (`Ke`).
//!
//! `f(wo, wi) = Kd / pi + Ks (n + 2) / (2 pi) cos^n(alpha)`, alpha the angle between `wi` and the
//! mirror direction of `wo`. With `Kd + Ks <= 1` per channel the albedo never exceeds one: at
//! normal incidence the Phong term integrates (times cos) to exactly `Ks`, and less elsewhere.
//! Sampling picks a lobe with probability proportional to its luminance and samples it exactly;
//! `pdf` is the resulting mixture density, so MIS and frame reuse can re-evaluate it for any
//! outgoing direction (the reuse methods evaluate `p(w | x, x->o_m)` for every eye).
//!
//! ```
//! use reframe::bsdf::Material;
//! use glam::Vec3;
//! let m = Material { kd: Vec3::splat(0.5), ..Material::default() };
//! let f = m.eval(Vec3::Z, Vec3::Z, Vec3::Z);
//! assert!((f.x - 0.5 / std::f32::consts::PI).abs() < 1e-6);
//! ```
use crate::sampling::{cosine_hemisphere, phong_lobe, phong_lobe_pdf, to_world};
use glam::{Vec2, Vec3};
use std::f32::consts::{FRAC_1_PI, PI};

/// Largest Phong exponent. `phong_lobe` draws `cos = u^(1 / (Ns + 1))`: above about 1.6e7 the
/// exponent rounds that to 1 in f32 for most `u`, so the sampled lobe is no longer the lobe that
/// `eval` and `pdf` describe; 1e6 keeps a factor 16 from there (a lobe about 0.1 degree wide,
/// a mirror for any image). Before `eval` clamped its cosine to 1, `Ns` 1e10 and above gave NaN
/// pixels on the corpus' base floor (1e8 did not): `cos^Ns` of a cosine rounded above 1
/// overflowed, `1.0000001^Ns` does from `Ns` about 7.5e8.
pub const MAX_NS: f32 = 1e6;

#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Material {
    pub kd: Vec3,
    pub ks: Vec3,
    /// Phong exponent `Ns`.
    pub ns: f32,
    /// Emitted radiance `Ke`, to the front side of the triangle only.
    pub ke: Vec3,
}

pub fn luminance(c: Vec3) -> f32 {
    c.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

/// Mirror `wo` about `n` (both unit, pointing away from the surface).
#[inline]
pub fn reflect(wo: Vec3, n: Vec3) -> Vec3 {
    2.0 * wo.dot(n) * n - wo
}

/// A sampled direction: `wi`, the BSDF value, and the mixture pdf (solid angle).
#[derive(Clone, Copy, Debug)]
pub struct BsdfSample {
    pub wi: Vec3,
    pub f: Vec3,
    pub pdf: f32,
}

impl Material {
    pub fn is_emissive(&self) -> bool {
        self.ke.max_element() > 0.0
    }

    pub fn reflects(&self) -> bool {
        self.kd.max_element() > 0.0 || self.ks.max_element() > 0.0
    }

    /// Probability of choosing the diffuse lobe when sampling.
    #[inline]
    fn diffuse_weight(&self) -> f32 {
        let d = luminance(self.kd);
        let s = luminance(self.ks);
        // `d / (d + 0)` is exactly 1: a Lambertian surface skips the division (same bits).
        if d + s <= 0.0 || s == 0.0 {
            1.0
        } else {
            d / (d + s)
        }
    }

    /// BSDF value; `n` is the shading normal on the side of `wo`. Zero below the surface.
    #[inline]
    pub fn eval(&self, n: Vec3, wo: Vec3, wi: Vec3) -> Vec3 {
        if n.dot(wi) <= 0.0 || n.dot(wo) <= 0.0 {
            return Vec3::ZERO;
        }
        let mut f = self.kd * FRAC_1_PI;
        if self.ks.max_element() > 0.0 {
            // Rounding can put the cosine of unit vectors above 1, and 1.0000001^Ns overflows
            // for Ns near 1e9: clamp (see `scene::MAX_NS`).
            let cos_a = reflect(wo, n).dot(wi).min(1.0);
            if cos_a > 0.0 {
                f += self.ks * ((self.ns + 2.0) / (2.0 * PI) * cos_a.powf(self.ns));
            }
        }
        f
    }

    /// `eval` and `pdf` together, sharing the lobe's `cos^n` (one `powf` instead of two).
    #[inline]
    pub fn eval_pdf(&self, n: Vec3, wo: Vec3, wi: Vec3) -> (Vec3, f32) {
        let cos_i = n.dot(wi);
        if cos_i <= 0.0 || n.dot(wo) <= 0.0 {
            return (Vec3::ZERO, 0.0);
        }
        let q = self.diffuse_weight();
        let mut f = self.kd * FRAC_1_PI;
        let mut p = q * cos_i * FRAC_1_PI;
        if self.ks.max_element() > 0.0 {
            let cos_a = reflect(wo, n).dot(wi).min(1.0);
            if cos_a > 0.0 {
                let c = cos_a.powf(self.ns) / (2.0 * PI);
                f += self.ks * ((self.ns + 2.0) * c);
                p += (1.0 - q) * (self.ns + 1.0) * c;
            }
        }
        (f, p)
    }

    /// `(self.eval(n, wo, wi), self.pdf(n, wo, wi))` to the bit, with one `powf` for the two
    /// (the reuse weights evaluate both for every eye of a group; `eval_pdf` shares more of the
    /// arithmetic and so rounds differently). Always inlined: called with vectors the caller has
    /// just computed, passing them through memory stalls on store forwarding.
    #[inline(always)]
    pub fn eval_and_pdf(&self, n: Vec3, wo: Vec3, wi: Vec3) -> (Vec3, f32) {
        let cos_i = n.dot(wi);
        if cos_i <= 0.0 || n.dot(wo) <= 0.0 {
            return (Vec3::ZERO, 0.0);
        }
        let q = self.diffuse_weight();
        let glossy = self.ks.max_element() > 0.0;
        let cos_a = reflect(wo, n).dot(wi).min(1.0);
        // As `eval`, the lobe where cos_a > 0; as `phong_lobe_pdf`, wherever !(cos_a <= 0).
        #[allow(clippy::neg_cmp_op_on_partial_ord)]
        let lobe = !(cos_a <= 0.0);
        let pw = if (glossy || q < 1.0) && lobe {
            cos_a.powf(self.ns)
        } else {
            0.0
        };
        let mut f = self.kd * FRAC_1_PI;
        if glossy && cos_a > 0.0 {
            f += self.ks * ((self.ns + 2.0) / (2.0 * PI) * pw);
        }
        let mut p = q * cos_i * FRAC_1_PI;
        if q < 1.0 {
            p += (1.0 - q)
                * if lobe {
                    (self.ns + 1.0) / (2.0 * PI) * pw
                } else {
                    0.0
                };
        }
        (f, p)
    }

    /// Density of `sample` (solid angle) of returning `wi`, for outgoing `wo`.
    #[inline]
    pub fn pdf(&self, n: Vec3, wo: Vec3, wi: Vec3) -> f32 {
        let cos_i = n.dot(wi);
        if cos_i <= 0.0 || n.dot(wo) <= 0.0 {
            return 0.0;
        }
        let q = self.diffuse_weight();
        let mut p = q * cos_i * FRAC_1_PI;
        if q < 1.0 {
            p += (1.0 - q) * phong_lobe_pdf(reflect(wo, n).dot(wi).min(1.0), self.ns);
        }
        p
    }

    /// Whether `sample` takes `lambert_sample`'s path for lobe number `u_lobe`: no Phong lobe
    /// (then `diffuse_weight` is exactly 1 and every number below 1 picks the diffuse lobe).
    #[inline(always)]
    pub fn samples_lambert(&self, u_lobe: f32) -> bool {
        self.ks == Vec3::ZERO && u_lobe < 1.0
    }

    /// Sample `wi` for `wo` (`u_lobe` picks the lobe, `u` the direction). `None` when the
    /// direction falls below the surface (possible for the Phong lobe near grazing angles).
    #[inline]
    pub fn sample(&self, n: Vec3, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        if self.samples_lambert(u_lobe) {
            let (wi, f, pdf) = lambert_sample(self.kd, n, wo, u);
            return (pdf > 0.0).then_some(BsdfSample { wi, f, pdf });
        }
        let wi = self.sample_direction(n, wo, u_lobe, u);
        if n.dot(wi) <= 0.0 {
            return None;
        }
        let (f, pdf) = self.eval_pdf(n, wo, wi);
        (pdf > 0.0).then_some(BsdfSample { wi, f, pdf })
    }

    /// The raw direction drawn by `sample`, possibly below the surface (for the chi-square test).
    pub fn sample_direction(&self, n: Vec3, wo: Vec3, u_lobe: f32, u: Vec2) -> Vec3 {
        if u_lobe < self.diffuse_weight() {
            to_world(n, cosine_hemisphere(u))
        } else {
            to_world(reflect(wo, n), phong_lobe(u, self.ns))
        }
    }
}

/// `Material::sample` of a material with no Phong lobe (`samples_lambert`), written without a
/// branch so that a loop of them runs in SIMD lanes (`integrator::lanes`): the direction, the
/// BSDF value and the density, which is 0 where `sample` gives `None` (the direction below the
/// surface, `wo` below it, or a density that rounds to 0). The same operations in the same order
/// as `sample_direction` and `eval_pdf` take for such a material (its diffuse weight is exactly
/// 1, so `q cos_i / pi` is `cos_i / pi`), so the same bits.
#[inline(always)]
pub fn lambert_sample(kd: Vec3, n: Vec3, wo: Vec3, u: Vec2) -> (Vec3, Vec3, f32) {
    let wi = to_world(n, cosine_hemisphere(u));
    let cos_i = n.dot(wi);
    #[allow(clippy::neg_cmp_op_on_partial_ord)]
    let faces = cos_i > 0.0 && !(n.dot(wo) <= 0.0);
    let pdf = if faces { cos_i * FRAC_1_PI } else { 0.0 };
    (wi, kd * FRAC_1_PI, pdf)
}

/// Materials from Lambertian to nearly a mirror, lobes without a specular part or without a
/// diffuse one, and black (for the tests here and of the BSDF lanes).
#[cfg(test)]
pub(crate) fn test_materials() -> [Material; 5] {
    [
        Material {
            kd: Vec3::splat(0.5),
            ..Material::default()
        },
        Material {
            kd: Vec3::new(0.2, 0.3, 0.1),
            ks: Vec3::splat(0.6),
            ns: 30.0,
            ..Material::default()
        },
        Material {
            ks: Vec3::new(0.9, 0.0, 0.5),
            ns: 1e6,
            ..Material::default()
        },
        Material {
            kd: Vec3::new(0.0, 0.4, 0.0),
            ks: Vec3::new(0.0, 0.5, 0.0),
            ns: 0.5,
            ..Material::default()
        },
        Material::default(),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::{chi_square, phong_lobe, Sampler};

    #[test]
    fn eval_and_pdf_are_eval_and_pdf_to_the_bit() {
        // Random directions (unit, some not quite, some zero) and materials from Lambertian to
        // nearly a mirror, and lobes without a specular part or without a diffuse one.
        let mut s = Sampler::new(7, 0, 0, 0);
        let mats = test_materials();
        let mut dir = || {
            let u = s.next_2d();
            let v = s.next_1d();
            let (z, phi) = (1.0 - 2.0 * u.x, 2.0 * PI * u.y);
            let r = (1.0 - z * z).max(0.0).sqrt();
            let d = Vec3::new(r * phi.cos(), r * phi.sin(), z) * (1.0 + (v - 0.5) * 1e-6);
            if v < 0.01 {
                Vec3::ZERO
            } else {
                d
            }
        };
        for m in &mats {
            for _ in 0..20_000 {
                let (n, wo, wi) = (dir(), dir(), dir());
                let (f, p) = m.eval_and_pdf(n, wo, wi);
                let (f0, p0) = (m.eval(n, wo, wi), m.pdf(n, wo, wi));
                assert_eq!(
                    f.to_array().map(f32::to_bits),
                    f0.to_array().map(f32::to_bits)
                );
                assert_eq!(p.to_bits(), p0.to_bits(), "{m:?} {n} {wo} {wi}");
            }
        }
    }

    #[test]
    fn a_lambertian_sample_is_the_general_path_to_the_bit() {
        // `sample` takes `lambert_sample` for materials without a Phong lobe; the general path
        // (`sample_direction`, then `eval_pdf`) must give the same bits, and `None` in the same
        // places: directions below the surface, `wo` below it, NaN normals.
        let mut s = Sampler::new(3, 0, 0, 0);
        let mats = [
            Vec3::splat(0.5),
            Vec3::new(0.9, 0.0, 0.2),
            Vec3::new(1.0, 1e-30, 3.0),
        ];
        let (mut some, mut none) = (0, 0);
        for i in 0..60_000 {
            let kd = mats[i % 3];
            let m = Material {
                kd,
                ..Material::default()
            };
            let mut unit = || {
                let v = Vec3::new(s.next_1d(), s.next_1d(), s.next_1d()) * 2.0 - 1.0;
                v.normalize_or(Vec3::Z)
            };
            let n = if i % 1000 == 7 { Vec3::NAN } else { unit() };
            let wo = unit();
            let (u_lobe, u) = (s.next_1d(), s.next_2d());
            assert!(m.samples_lambert(u_lobe));
            let general = {
                let wi = m.sample_direction(n, wo, u_lobe, u);
                let (f, pdf) = m.eval_pdf(n, wo, wi);
                (n.dot(wi) > 0.0 && pdf > 0.0).then_some((wi, f, pdf))
            };
            let got = m.sample(n, wo, u_lobe, u).map(|b| (b.wi, b.f, b.pdf));
            let bits = |x: Option<(Vec3, Vec3, f32)>| {
                x.map(|(a, b, c)| {
                    (
                        a.to_array().map(f32::to_bits),
                        b.to_array().map(f32::to_bits),
                        c.to_bits(),
                    )
                })
            };
            assert_eq!(bits(got), bits(general), "{kd} {n} {wo} {u}");
            if got.is_some() {
                some += 1;
            } else {
                none += 1;
            }
        }
        assert!(some > 20_000 && none > 20_000, "{some} {none}");
        // A Phong lobe, however small, takes the general path.
        let glossy = Material {
            kd: Vec3::splat(0.5),
            ks: Vec3::new(0.0, 1e-20, 0.0),
            ns: 10.0,
            ..Material::default()
        };
        assert!(!glossy.samples_lambert(0.5));
    }

    /// The density of `sample_direction` over the whole sphere (including the part of the Phong
    /// lobe below the surface, which `sample` discards).
    fn full_pdf(m: &Material, n: Vec3, wo: Vec3, wi: Vec3) -> f64 {
        let q = m.diffuse_weight() as f64;
        let mut p = q * (n.dot(wi).max(0.0) as f64) / std::f64::consts::PI;
        if q < 1.0 {
            p += (1.0 - q) * phong_lobe_pdf(reflect(wo, n).dot(wi), m.ns) as f64;
        }
        p
    }

    /// Chi-square goodness of fit of `sample_direction` against `full_pdf`, over a
    /// (cos theta, phi) grid of the sphere around `n` (pbrt-v4 bsdfs_test, Mitsuba chi2.py):
    /// 1e6 samples, expected counts from a fine midpoint quadrature of the pdf, cells with fewer
    /// than 5 expected pooled, alpha 0.01 Sidak-corrected over the `trials` of the caller.
    fn chi2_test(m: &Material, wo: Vec3, trials: u32, seed: u64) {
        const NT: usize = 40;
        const NP: usize = 80;
        const N: usize = 1_000_000;
        let n = Vec3::Z;
        let mut observed = vec![0f64; NT * NP];
        let mut s = Sampler::new(seed, 0, 0, 0);
        for _ in 0..N {
            let wi = m
                .sample_direction(n, wo, s.next_1d(), s.next_2d())
                .normalize();
            let ct = ((wi.z.clamp(-1.0, 1.0) + 1.0) * 0.5 * NT as f32) as usize;
            let phi = wi.y.atan2(wi.x).rem_euclid(2.0 * PI);
            let cp = (phi / (2.0 * PI) * NP as f32) as usize;
            observed[ct.min(NT - 1) * NP + cp.min(NP - 1)] += 1.0;
        }
        // Expected counts: integrate the pdf over each cell (d omega = d cos_theta d phi).
        const SUB: usize = 8;
        let mut expected = vec![0f64; NT * NP];
        for it in 0..NT {
            for ip in 0..NP {
                let mut acc = 0.0;
                for a in 0..SUB {
                    for b in 0..SUB {
                        let z =
                            -1.0 + 2.0 * (it as f64 + (a as f64 + 0.5) / SUB as f64) / NT as f64;
                        let phi = 2.0
                            * std::f64::consts::PI
                            * (ip as f64 + (b as f64 + 0.5) / SUB as f64)
                            / NP as f64;
                        let r = (1.0 - z * z).max(0.0).sqrt();
                        let wi =
                            Vec3::new((r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32);
                        acc += full_pdf(m, n, wo, wi);
                    }
                }
                let cell = (2.0 / NT as f64) * (2.0 * std::f64::consts::PI / NP as f64);
                expected[it * NP + ip] = acc / (SUB * SUB) as f64 * cell * N as f64;
            }
        }
        let total_expected: f64 = expected.iter().sum();
        assert!(
            (total_expected / N as f64 - 1.0).abs() < 0.01,
            "pdf integrates to {}",
            total_expected / N as f64
        );
        let (chi2, dof, p_value) = chi_square(&expected, &observed);
        let alpha = 1.0 - (1.0f64 - 0.01).powf(1.0 / trials as f64); // Sidak
        assert!(
            p_value > alpha,
            "chi2 {chi2:.1} dof {dof} p {p_value:.2e} < {alpha:.2e} for {m:?} wo {wo}"
        );
    }

    fn wo_at(theta_deg: f32) -> Vec3 {
        let t = theta_deg.to_radians();
        Vec3::new(t.sin(), 0.0, t.cos())
    }

    #[test]
    fn lambert_sampling_matches_pdf() {
        let m = Material {
            kd: Vec3::splat(0.8),
            ..Default::default()
        };
        chi2_test(&m, wo_at(30.0), 1, 1);
    }

    #[test]
    fn phong_sampling_matches_pdf() {
        let cases = [(10.0, 0.0), (30.0, 45.0), (200.0, 70.0)];
        for (i, &(ns, theta)) in cases.iter().enumerate() {
            let m = Material {
                ks: Vec3::splat(0.9),
                ns,
                ..Default::default()
            };
            chi2_test(&m, wo_at(theta), cases.len() as u32 + 1, 10 + i as u64);
        }
        let mix = Material {
            kd: Vec3::new(0.3, 0.2, 0.1),
            ks: Vec3::splat(0.5),
            ns: 20.0,
            ..Default::default()
        };
        chi2_test(&mix, wo_at(50.0), cases.len() as u32 + 1, 20);
    }

    /// Monte Carlo albedo E[f cos / pdf] over `sample`.
    fn albedo(m: &Material, wo: Vec3, n: usize) -> Vec3 {
        let mut s = Sampler::new(77, 0, 0, 0);
        let mut acc = glam::DVec3::ZERO;
        for _ in 0..n {
            if let Some(bs) = m.sample(Vec3::Z, wo, s.next_1d(), s.next_2d()) {
                let w = bs.f * bs.wi.z / bs.pdf;
                acc += w.as_dvec3();
            }
        }
        (acc / n as f64).as_vec3()
    }

    #[test]
    fn energy_checks() {
        // Lambert: f cos / pdf is exactly kd for every sample.
        let d = Material {
            kd: Vec3::new(0.2, 0.5, 0.7),
            ..Default::default()
        };
        assert!((albedo(&d, wo_at(40.0), 10_000) - d.kd).abs().max_element() < 1e-5);
        // Phong at normal incidence: albedo is exactly ks (the (n+2)/(2 pi) normalisation).
        for ns in [1.0, 10.0, 100.0, 1000.0] {
            let p = Material {
                ks: Vec3::splat(0.8),
                ns,
                ..Default::default()
            };
            let a = albedo(&p, Vec3::Z, 200_000);
            assert!((a.x - 0.8).abs() < 0.01, "ns {ns}: albedo {a}");
            // At oblique angles part of the lobe falls below the horizon: never more than ks.
            for theta in [30.0, 60.0, 85.0] {
                let a = albedo(&p, wo_at(theta), 100_000);
                assert!(a.x <= 0.8 + 0.01, "ns {ns} theta {theta}: albedo {a}");
            }
        }
        // A mixture with kd + ks = 1 conserves energy.
        let m = Material {
            kd: Vec3::splat(0.4),
            ks: Vec3::splat(0.6),
            ns: 30.0,
            ..Default::default()
        };
        let a = albedo(&m, wo_at(20.0), 200_000);
        assert!(a.max_element() <= 1.0 + 0.01, "{a}");
    }

    #[test]
    fn pdf_and_eval_agree_with_sample() {
        let m = Material {
            kd: Vec3::splat(0.3),
            ks: Vec3::splat(0.6),
            ns: 50.0,
            ..Default::default()
        };
        let mut s = Sampler::new(4, 0, 0, 0);
        let wo = wo_at(35.0);
        for _ in 0..10_000 {
            if let Some(bs) = m.sample(Vec3::Z, wo, s.next_1d(), s.next_2d()) {
                assert!((bs.pdf - m.pdf(Vec3::Z, wo, bs.wi)).abs() <= 1e-5 * bs.pdf.max(1.0));
                assert!(
                    (bs.f - m.eval(Vec3::Z, wo, bs.wi)).abs().max_element()
                        <= 1e-5 * bs.f.max_element().max(1.0)
                );
                assert!(bs.f.is_finite() && bs.pdf.is_finite() && bs.pdf > 0.0);
            }
        }
    }

    #[test]
    fn phong_is_finite_and_faithful_up_to_the_cap() {
        // Sampling stays the lobe that eval and pdf describe up to the cap: for cos = u^(1/(n+1))
        // the mean of 1 - cos is 1 / (n + 2), which f32 resolves at MAX_NS (it rounds cos to 1
        // about 16 times further out, where the lobe degenerates to the mirror direction).
        for (ns, faithful) in [(MAX_NS, true), (MAX_NS * 100.0, false)] {
            let mut s = Sampler::new(9, 0, 0, 0);
            let n = 200_000;
            let mean: f64 = (0..n)
                .map(|_| 1.0 - phong_lobe(s.next_2d(), ns).z as f64)
                .sum::<f64>()
                / n as f64;
            let want = 1.0 / (ns as f64 + 2.0);
            assert_eq!(
                (mean / want - 1.0).abs() < 0.05,
                faithful,
                "ns {ns:e}: {mean:e} vs {want:e}"
            );
        }
        // Beyond the cap the values stay finite (cosines rounded above 1 are clamped), so a cap
        // is about fidelity, not overflow: f cos / pdf stays finite even at 1e37.
        for ns in [MAX_NS, 1e9, 1e20, 1e37] {
            let m = Material {
                kd: Vec3::splat(0.1),
                ks: Vec3::splat(0.9),
                ns,
                ..Default::default()
            };
            let mut s = Sampler::new(5, 0, 0, 0);
            for k in 0..20_000 {
                let wo = wo_at((k % 90) as f32);
                if let Some(bs) = m.sample(Vec3::Z, wo, s.next_1d(), s.next_2d()) {
                    let w = bs.f * bs.wi.z / bs.pdf;
                    assert!(w.is_finite() && bs.pdf.is_finite(), "ns {ns:e}: {bs:?}");
                }
            }
        }
    }
}
