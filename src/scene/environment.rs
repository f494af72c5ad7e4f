//! The environment light: radiance arriving from infinitely far away, a lat-long (equirectangular)
//! image or one uniform colour, seen by every ray that leaves the scene and sampled for next-event
//! estimation by luminance times solid angle (docs/environment.md).
//!
//! Directions map to the image as Mitsuba 3's `envmap` and most lat-long tools do, with +Y up: in
//! the environment's own frame, `u = atan2(d.x, -d.z) / 2π` (wrapped into [0, 1)) runs along a
//! row from the -Z direction through +X, and `v = acos(d.y) / π` down the rows from +Y (top row)
//! to -Y (bottom row). `rotation` turns the environment about +Y (right-handed, degrees).
//!
//! The radiance is interpolated bilinearly as Mitsuba 3's `envmap` interpolates it: along a row
//! between texel centres (`x = u W - 1/2`, wrapping around), and down the rows between rows
//! placed from the top pole to the bottom one (`y = v (H - 1)`: row 0 is exactly +Y and row
//! `H - 1` exactly -Y). Sampling divides the sphere into cells, one per texel (`u` in
//! `[c, c + 1] / W`, `v` in `[r, r + 1] / H`), picks a cell with probability proportional to the
//! largest luminance among the texels that the interpolation can reach in it (its texel and
//! the eight around it, so no direction of positive radiance has zero density) times its solid
//! angle, then a direction uniformly in solid angle inside the cell: the density is constant
//! over each cell, `pdf(d) = P(cell) / Ω(cell)`, with no singularity at the poles, and a
//! uniform environment is sampled uniformly over the sphere.
//!
//! ```
//! use reframe::scene::environment::Environment;
//! use glam::{Vec2, Vec3};
//! let env = Environment::uniform(Vec3::splat(2.0));
//! let s = env.sample(Vec2::new(0.3, 0.7)).unwrap();
//! assert_eq!(env.radiance(s.wi), Vec3::splat(2.0));
//! assert!((s.pdf - 1.0 / (4.0 * std::f32::consts::PI)).abs() < 1e-6);
//! ```
use crate::bsdf::luminance;
use glam::{Vec2, Vec3};
use std::f64::consts::PI;

/// An environment light, ready to evaluate and sample.
pub struct Environment {
    width: u32,
    height: u32,
    /// Radiance per texel, row-major, top row (+Y) first, intensity applied.
    texels: Vec<Vec3>,
    /// `cos` and `sin` of the rotation about +Y.
    rot: (f32, f32),
    /// Cumulative probability of the rows (marginal), and within each row of its texels
    /// (conditional), in f64 so that rows of tiny weight keep their share.
    row_cdf: Vec<f64>,
    col_cdf: Vec<f64>,
    /// Solid-angle density of sampling in each texel, `P(texel) / Ω(texel)`.
    density: Vec<f32>,
    /// Whether any texel has power: an all-black environment is never sampled.
    power: f64,
    /// The largest radiance of a texel in a channel (`brightest`).
    brightest: f32,
}

/// A direction sampled towards the environment.
#[derive(Clone, Copy, Debug)]
pub struct EnvSample {
    /// Unit world direction towards the environment.
    pub wi: Vec3,
    /// Radiance arriving from direction `wi` (`radiance(wi)`).
    pub le: Vec3,
    /// Solid-angle density of the sample.
    pub pdf: f32,
}

impl Environment {
    /// One colour from every direction.
    pub fn uniform(radiance: Vec3) -> Environment {
        Environment::from_texels(1, 1, vec![radiance], 0.0)
    }

    /// A lat-long image of `width` x `height` texels (row-major, top row first), turned by
    /// `rotation_deg` about +Y. Texels must be finite and non-negative (the loader checks).
    pub fn from_texels(width: u32, height: u32, texels: Vec<Vec3>, rotation_deg: f32) -> Self {
        let (w, h) = (width as usize, height as usize);
        assert_eq!(texels.len(), w * h, "texel count");
        // A saturated colour can have zero luminance: its max keeps it samplable.
        let lum = |t: Vec3| luminance(t).max(t.max_element() * 1e-3) as f64;
        // Weights: the largest luminance the interpolation reaches in a cell (its texel's row and
        // column and their neighbours: `x` spans a column either side of the centre, and `y`
        // of a cell between rows `r - 1` and `r + 1`), times the cell's solid angle,
        // 2π/W (cos θ0 - cos θ1).
        let mut col_cdf = vec![0.0f64; w * h];
        let mut row_weight = vec![0.0f64; h];
        for r in 0..h {
            let omega = cell_solid_angle(r, w, h);
            let rows = r.saturating_sub(1)..=(r + 1).min(h - 1);
            let mut acc = 0.0;
            for c in 0..w {
                let mut reach = 0.0f64;
                for rr in rows.clone() {
                    for cc in [c + w - 1, c, c + 1] {
                        reach = reach.max(lum(texels[rr * w + cc % w]));
                    }
                }
                acc += reach * omega;
                col_cdf[r * w + c] = acc;
            }
            row_weight[r] = acc;
        }
        let power: f64 = row_weight.iter().sum();
        let mut row_cdf = vec![0.0f64; h];
        let mut density = vec![0.0f32; w * h];
        let mut acc = 0.0;
        for r in 0..h {
            acc += row_weight[r];
            row_cdf[r] = if power > 0.0 { acc / power } else { 0.0 };
            let omega = cell_solid_angle(r, w, h);
            let row = &mut col_cdf[r * w..(r + 1) * w];
            let mut before = 0.0;
            for (c, cdf) in row.iter_mut().enumerate() {
                let weight = *cdf - before;
                before = *cdf;
                if power > 0.0 {
                    density[r * w + c] = (weight / power / omega) as f32;
                }
                *cdf = if row_weight[r] > 0.0 {
                    *cdf / row_weight[r]
                } else {
                    0.0
                };
            }
        }
        if power > 0.0 {
            *row_cdf.last_mut().unwrap() = 1.0;
        }
        let a = rotation_deg.to_radians();
        let brightest = texels.iter().map(|t| t.max_element()).fold(0.0, f32::max);
        Environment {
            brightest,
            width,
            height,
            texels,
            rot: (a.cos(), a.sin()),
            row_cdf,
            col_cdf,
            density,
            power,
        }
    }

    /// The largest radiance of a texel in a channel (intensity applied), found once when it is
    /// made: every reuse render's plan asks for it (`Scene::brightest_emission`).
    pub fn brightest(&self) -> f32 {
        self.brightest
    }

    /// Whether it emits at all (an all-black environment is never sampled).
    pub fn emits(&self) -> bool {
        self.power > 0.0
    }

    /// What a rendered pixel depends on, for the scene's hash: the image's size, the rotation's
    /// cosine and sine, and the texels (intensity applied).
    pub fn identity(&self) -> (u32, u32, [f32; 2], &[Vec3]) {
        (
            self.width,
            self.height,
            [self.rot.0, self.rot.1],
            &self.texels,
        )
    }

    /// The image coordinates `(u, v)` in [0, 1) x [0, 1] of a world direction.
    #[inline]
    fn uv(&self, d: Vec3) -> (f64, f64) {
        let l = self.to_local(d);
        let u = (l.x as f64).atan2(-l.z as f64) / (2.0 * PI);
        let u = if u < 0.0 { u + 1.0 } else { u };
        let v = (l.y.clamp(-1.0, 1.0) as f64).acos() / PI;
        (u, v)
    }

    /// The sampling cell a world direction falls in (one per texel).
    #[inline]
    fn texel(&self, d: Vec3) -> usize {
        let (u, v) = self.uv(d);
        let c = ((u * self.width as f64) as usize).min(self.width as usize - 1);
        let r = ((v * self.height as f64) as usize).min(self.height as usize - 1);
        r * self.width as usize + c
    }

    /// Radiance arriving from world direction `d` (unit): bilinear between texel centres along
    /// a row (wrapping) and between rows placed pole to pole down the image (see the module
    /// note).
    #[inline]
    pub fn radiance(&self, d: Vec3) -> Vec3 {
        let (w, h) = (self.width as usize, self.height as usize);
        if w * h == 1 {
            return self.texels[0];
        }
        let (u, v) = self.uv(d);
        let x = u * w as f64 - 0.5;
        let x0 = x.floor();
        let fx = (x - x0) as f32;
        let c0 = (x0 as i64).rem_euclid(w as i64) as usize;
        let c1 = (c0 + 1) % w;
        let (r0, r1, fy) = if h == 1 {
            (0, 0, 0.0)
        } else {
            let y = v * (h - 1) as f64;
            let r0 = (y as usize).min(h - 2);
            (r0, r0 + 1, (y - r0 as f64).clamp(0.0, 1.0) as f32)
        };
        let t = |r: usize, c: usize| self.texels[r * w + c];
        let top = t(r0, c0) * (1.0 - fx) + t(r0, c1) * fx;
        let bottom = t(r1, c0) * (1.0 - fx) + t(r1, c1) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// Solid-angle density with which `sample` picks world direction `d`.
    #[inline]
    pub fn pdf(&self, d: Vec3) -> f32 {
        self.density[self.texel(d)]
    }

    /// A direction with density `pdf`, from two uniform numbers; `None` if the environment is
    /// black.
    pub fn sample(&self, u: Vec2) -> Option<EnvSample> {
        if self.power <= 0.0 {
            return None;
        }
        let (w, h) = (self.width as usize, self.height as usize);
        let (r, fr) = pick(&self.row_cdf, u.x as f64);
        let (c, fc) = pick(&self.col_cdf[r * w..(r + 1) * w], u.y as f64);
        // Uniform in solid angle inside the cell: cos θ uniform between its rows, φ uniform.
        let (z0, z1) = (
            (PI * r as f64 / h as f64).cos(),
            (PI * (r + 1) as f64 / h as f64).cos(),
        );
        let cos_t = z0 + fr * (z1 - z0);
        let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
        let phi = 2.0 * PI * (c as f64 + fc) / w as f64;
        let local = Vec3::new(
            (sin_t * phi.sin()) as f32,
            cos_t as f32,
            (-sin_t * phi.cos()) as f32,
        );
        let wi = self.to_world(local).normalize();
        // The density of the texel it was drawn in (rounding can move `wi` across a cell edge;
        // the texel it evaluates in is the one whose density MIS must use).
        let i = self.texel(wi);
        let pdf = self.density[i];
        if pdf <= 0.0 {
            return None;
        }
        Some(EnvSample {
            wi,
            le: self.radiance(wi),
            pdf,
        })
    }

    /// World to the environment's frame: turn by `-rotation` about +Y.
    #[inline]
    fn to_local(&self, d: Vec3) -> Vec3 {
        let (c, s) = self.rot;
        Vec3::new(c * d.x - s * d.z, d.y, s * d.x + c * d.z)
    }

    #[inline]
    fn to_world(&self, d: Vec3) -> Vec3 {
        let (c, s) = self.rot;
        Vec3::new(c * d.x + s * d.z, d.y, -s * d.x + c * d.z)
    }
}

/// Solid angle of a texel of row `r` of a `w` x `h` lat-long image.
fn cell_solid_angle(r: usize, w: usize, h: usize) -> f64 {
    let z0 = (PI * r as f64 / h as f64).cos();
    let z1 = (PI * (r + 1) as f64 / h as f64).cos();
    2.0 * PI / w as f64 * (z0 - z1)
}

/// The entry of `cdf` (non-decreasing, ending at 1) that `u` in [0, 1) falls in, skipping
/// entries of zero probability, and where in it `u` fell, in [0, 1).
fn pick(cdf: &[f64], u: f64) -> (usize, f64) {
    let i = cdf.partition_point(|&c| c <= u).min(cdf.len() - 1);
    let lo = if i == 0 { 0.0 } else { cdf[i - 1] };
    let p = cdf[i] - lo;
    let f = if p > 0.0 {
        ((u - lo) / p).clamp(0.0, 1.0 - 1e-12)
    } else {
        0.5
    };
    (i, f)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::chi_square;
    use crate::sampling::Sampler;

    /// A small environment with structure: a bright spot, a dim gradient, black texels, and a
    /// saturated blue (zero red and green).
    fn test_env(rotation: f32) -> Environment {
        let (w, h) = (16u32, 8u32);
        let mut t = Vec::new();
        for r in 0..h {
            for c in 0..w {
                let v = if (r, c) == (2, 5) {
                    Vec3::new(40.0, 30.0, 20.0)
                } else if r == 6 && c < 4 {
                    Vec3::ZERO
                } else if r == 7 && c == 9 {
                    Vec3::new(0.0, 0.0, 3.0)
                } else {
                    Vec3::splat(0.1 + 0.05 * c as f32 + 0.2 * r as f32)
                };
                t.push(v);
            }
        }
        Environment::from_texels(w, h, t, rotation)
    }

    #[test]
    fn directions_map_to_the_texels_of_the_convention() {
        let (w, h) = (8u32, 4u32);
        let t: Vec<Vec3> = (0..w * h).map(|i| Vec3::splat(i as f32)).collect();
        let env = Environment::from_texels(w, h, t.clone(), 0.0);
        let at = |d: Vec3| env.radiance(d.normalize()).x;
        // Up is the top row, down the bottom row; -Z is the start of a row (u = 0), +X a quarter
        // along (u = 1/4), +Z the middle (u = 1/2), -X three quarters (u = 3/4). At a texel's
        // centre along the row, the radiance is the texel's.
        let dir = |u: f64, v: f64| {
            let (th, ph) = (PI * v, 2.0 * PI * u);
            Vec3::new(
                (th.sin() * ph.sin()) as f32,
                th.cos() as f32,
                (-th.sin() * ph.cos()) as f32,
            )
        };
        assert!((at(Vec3::Y) - 3.5).abs() < 1e-4, "{}", at(Vec3::Y)); // the top row, wrapped
        let row1 = 1.0 / 3.0; // rows at v = r / (h - 1)
        for (u, c) in [
            (0.5 / 8.0, 0.0),
            (2.5 / 8.0, 2.0),
            (4.5 / 8.0, 4.0),
            (6.5 / 8.0, 6.0),
        ] {
            let got = at(dir(u, row1));
            assert!((got - (w as f32 + c)).abs() < 1e-3, "u {u}: {got}");
        }
        // Turned by 90 degrees about +Y: what was seen towards -Z is now seen towards -X
        // (right-handed: -Z turns into -X).
        let turned = Environment::from_texels(w, h, t, 90.0);
        let d = Vec3::new(-1.0, 0.1, 0.01).normalize();
        let (a, b) = (
            turned.radiance(d),
            env.radiance(Vec3::new(-0.01, 0.1, -1.0).normalize()),
        );
        assert!((a - b).abs().max_element() < 1e-4, "{a} {b}");
    }

    #[test]
    fn radiance_is_interpolated_as_mitsuba_3_interpolates_it() {
        // Rows of 1, 10 and 100, and 1000 more red in column 1: the values Mitsuba 3.9.1's
        // `envmap` (scalar_rgb) returned for these directions, read from it.
        let (w, h) = (4u32, 3u32);
        let t: Vec<Vec3> = (0..w * h)
            .map(|i| {
                let v = [1.0, 10.0, 100.0][(i / w) as usize];
                Vec3::new(v + if i % w == 1 { 1000.0 } else { 0.0 }, v, v)
            })
            .collect();
        let env = Environment::from_texels(w, h, t, 0.0);
        let dir = |theta: f64, u: f64| {
            let ph = 2.0 * PI * u;
            Vec3::new(
                (theta.sin() * ph.sin()) as f32,
                theta.cos() as f32,
                (-theta.sin() * ph.cos()) as f32,
            )
        };
        let q = PI / 4.0;
        for (theta, want) in [
            (0.0, 1.0),
            (q / 2.0, 3.25),
            (q, 5.5),
            (PI / 3.0, 7.0),
            (2.0 * q, 10.0),
            (3.0 * q, 55.0),
            (PI, 100.0),
        ] {
            let got = env.radiance(dir(theta, 0.0)).y;
            assert!(
                (got - want).abs() < 1e-3 * want,
                "theta {theta}: {got}, Mitsuba {want}"
            );
        }
        for (u, want) in [(0.0, 10.0), (0.25, 510.0), (0.375, 1010.0), (0.5, 510.0)] {
            let got = env.radiance(dir(2.0 * q, u)).x;
            assert!(
                (got - want).abs() < 1e-3 * want,
                "u {u}: {got}, Mitsuba {want}"
            );
        }
    }

    /// A grid of world directions over the sphere, `nt` rows uniform in θ from +Y and `np`
    /// columns uniform in φ = atan2(x, -z): each cell's centre direction and solid angle. With
    /// `nt` a multiple of the test image's rows, `np` of its columns and a rotation by a
    /// multiple of `2π / np`, every cell lies inside one texel, where the density is constant:
    /// sums over the grid are then exact integrals, without quadrature error.
    fn grid(nt: usize, np: usize) -> Vec<(Vec3, f64)> {
        let mut cells = Vec::with_capacity(nt * np);
        for i in 0..nt {
            let (t0, t1) = (PI * i as f64 / nt as f64, PI * (i + 1) as f64 / nt as f64);
            let t = 0.5 * (t0 + t1);
            for j in 0..np {
                let phi = 2.0 * PI * (j as f64 + 0.5) / np as f64;
                let d = Vec3::new(
                    (t.sin() * phi.sin()) as f32,
                    t.cos() as f32,
                    (-t.sin() * phi.cos()) as f32,
                );
                cells.push((d, 2.0 * PI / np as f64 * (t0.cos() - t1.cos())));
            }
        }
        cells
    }

    #[test]
    fn density_integrates_to_one() {
        for rot in [0.0, 45.0, -90.0] {
            let env = test_env(rot);
            let total: f64 = grid(64, 128)
                .iter()
                .map(|&(d, omega)| env.pdf(d) as f64 * omega)
                .sum();
            assert!(
                (total - 1.0).abs() < 1e-5,
                "rotation {rot}: pdf integrates to {total}"
            );
        }
    }

    /// Chi-square goodness of fit of `sample` against `pdf` over the grid, 1e6 samples, cells
    /// expecting fewer than 5 pooled, alpha 0.01 Sidak-corrected over the trials (as the BSDFs').
    #[test]
    fn sampling_matches_the_density_chi_square() {
        const NT: usize = 32;
        const NP: usize = 64;
        const N: usize = 1_000_000;
        let rotations = [0.0f32, 45.0, off_texel_rotation()];
        for (trial, rot) in rotations.into_iter().enumerate() {
            let env = test_env(rot);
            let cells = grid(NT, NP);
            let expected: Vec<f64> = cells
                .iter()
                .map(|&(d, omega)| env.pdf(d) as f64 * omega * N as f64)
                .collect();
            let mut observed = vec![0f64; NT * NP];
            let mut s = Sampler::new(7 + trial as u64, 0, 0, 0);
            let mut none = 0;
            for _ in 0..N {
                // Rounding can put a direction drawn at a cell's edge into a black neighbour.
                let Some(es) = env.sample(s.next_2d()) else {
                    none += 1;
                    continue;
                };
                assert!(es.le != Vec3::ZERO, "a black texel sampled");
                assert!((es.wi.length() - 1.0).abs() < 1e-4);
                assert_eq!(es.pdf, env.pdf(es.wi));
                assert_eq!(es.le, env.radiance(es.wi));
                let d = es.wi;
                let t = (d.y.clamp(-1.0, 1.0) as f64).acos();
                let phi = (d.x as f64).atan2(-d.z as f64).rem_euclid(2.0 * PI);
                let ct = ((t / PI * NT as f64) as usize).min(NT - 1);
                let cp = ((phi / (2.0 * PI) * NP as f64) as usize).min(NP - 1);
                observed[ct * NP + cp] += 1.0;
            }
            assert!(none < 10, "{none} samples failed");
            let (chi2, dof, p) = chi_square(&expected, &observed);
            let alpha = 1.0 - (1.0f64 - 0.01).powf(1.0 / rotations.len() as f64);
            assert!(
                p > alpha,
                "rotation {rot}: chi2 {chi2:.1} dof {dof} p {p:.2e}"
            );
        }
    }

    /// A rotation by whole grid columns (5 of 64) that is not a whole texel (4 columns).
    fn off_texel_rotation() -> f32 {
        360.0 * 5.0 / 64.0
    }

    #[test]
    fn a_uniform_environment_is_sampled_uniformly() {
        let env = Environment::uniform(Vec3::new(1.0, 0.5, 0.25));
        let mut s = Sampler::new(3, 0, 0, 0);
        let mut mean = Vec3::ZERO;
        let n = 200_000;
        for _ in 0..n {
            let es = env.sample(s.next_2d()).unwrap();
            assert!((es.pdf as f64 - 1.0 / (4.0 * PI)).abs() < 1e-6);
            mean += es.wi;
        }
        // The mean direction of uniform samples is 0 (each component's sd is 1/sqrt(3n)).
        assert!((mean / n as f32).abs().max_element() < 5.0 / (3.0 * n as f32).sqrt());
        assert!(Environment::uniform(Vec3::ZERO)
            .sample(Vec2::splat(0.5))
            .is_none());
    }
}
