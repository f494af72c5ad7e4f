//! The BSDF samples of a wavefront round in SIMD lanes: every path of a round samples its
//! continuation at once, so the samples are drawn together, each lane getting
//! `Material::sample`'s answer to the bit.
//!
//! A Lambertian sample is a chain of dependent arithmetic (a square root, a sine and cosine, the
//! shading frame's division, the change of frame, the density) that one path at a time waits
//! on. Every surface of a round goes through `bsdf::lambert_sample` in lanes, a column per number
//! (the numbers are the round's own columns, `StepBatch`); the samples of materials with a
//! Phong lobe (a `powf` per lane; `Material::samples_lambert` says which) are then drawn path by
//! path over them.
use crate::bsdf::{lambert_sample, BsdfSample};
use glam::{Vec2, Vec3};

/// The BSDF samples of a round, a column per number, one row per surface: `start`, `set` each
/// row's inputs, `run`, then `put` the samples of rows that are not Lambertian, and read them
/// with `get`. Kept from one round to the next.
#[derive(Default)]
pub struct BsdfLanes {
    kd: [Vec<f32>; 3],
    n: [Vec<f32>; 3],
    wo: [Vec<f32>; 3],
    wi: [Vec<f32>; 3],
    f: [Vec<f32>; 3],
    /// 0 where the sample is `None`.
    pdf: Vec<f32>,
}

impl BsdfLanes {
    /// Bytes held per row (for memory estimates).
    pub const BYTES_PER_SAMPLE: usize = 16 * std::mem::size_of::<f32>();

    /// Room for rows `0..n`. A row that is neither `set` nor `put` holds numbers of no
    /// meaning, which `run` computes on and nothing reads.
    pub fn start(&mut self, n: usize) {
        let columns = [
            &mut self.kd,
            &mut self.n,
            &mut self.wo,
            &mut self.wi,
            &mut self.f,
        ];
        for col in columns.into_iter().flatten().chain([&mut self.pdf]) {
            if col.len() < n {
                col.resize(n, 0.0);
            }
        }
    }

    /// The inputs of Lambertian row `k` (`Material::samples_lambert`): the material's `kd`,
    /// the shading normal `n` and the outgoing direction `wo`.
    #[inline(always)]
    pub fn set(&mut self, k: usize, kd: Vec3, n: Vec3, wo: Vec3) {
        for axis in 0..3 {
            self.kd[axis][k] = kd[axis];
            self.n[axis][k] = n[axis];
            self.wo[axis][k] = wo[axis];
        }
    }

    /// `lambert_sample` of every row `0..n`, with the numbers `(ux[k], uy[k])`.
    pub fn run(&mut self, n: usize, ux: &[f32], uy: &[f32]) {
        run(n, self, ux, uy);
    }

    /// The sample of row `k`, drawn otherwise (after `run`).
    #[inline(always)]
    pub fn put(&mut self, k: usize, sample: Option<BsdfSample>) {
        let b = sample.unwrap_or(BsdfSample {
            wi: Vec3::ZERO,
            f: Vec3::ZERO,
            pdf: 0.0,
        });
        for axis in 0..3 {
            self.wi[axis][k] = b.wi[axis];
            self.f[axis][k] = b.f[axis];
        }
        self.pdf[k] = b.pdf;
    }

    /// The sample of row `k`.
    #[inline(always)]
    pub fn get(&self, k: usize) -> Option<BsdfSample> {
        let v = |c: &[Vec<f32>; 3]| Vec3::new(c[0][k], c[1][k], c[2][k]);
        let pdf = self.pdf[k];
        (pdf > 0.0).then(|| BsdfSample {
            wi: v(&self.wi),
            f: v(&self.f),
            pdf,
        })
    }
}

/// `lambert_sample` in every row `0..n`, compiled for AVX-512 and AVX2 besides the portable
/// build and chosen at run time (IEEE arithmetic with nothing fused: the same bits in all).
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512cd+avx512dq+avx512vl",
    "x86_64+avx2",
))]
fn run(n: usize, c: &mut BsdfLanes, ux: &[f32], uy: &[f32]) {
    // Every column cut to `n` rows, so that the loop needs no bounds checks.
    fn cut(v: &[Vec<f32>; 3], n: usize) -> [&[f32]; 3] {
        [&v[0][..n], &v[1][..n], &v[2][..n]]
    }
    let (kd, nrm, wo) = (cut(&c.kd, n), cut(&c.n, n), cut(&c.wo, n));
    let (ux, uy) = (&ux[..n], &uy[..n]);
    let [wx, wy, wz] = &mut c.wi;
    let (wx, wy, wz) = (&mut wx[..n], &mut wy[..n], &mut wz[..n]);
    let [fx, fy, fz] = &mut c.f;
    let (fx, fy, fz) = (&mut fx[..n], &mut fy[..n], &mut fz[..n]);
    let pdf = &mut c.pdf[..n];
    for k in 0..n {
        let col = |v: &[&[f32]; 3]| Vec3::new(v[0][k], v[1][k], v[2][k]);
        let u = Vec2::new(ux[k], uy[k]);
        let (wi, f, p) = lambert_sample(col(&kd), col(&nrm), col(&wo), u);
        (wx[k], wy[k], wz[k]) = (wi.x, wi.y, wi.z);
        (fx[k], fy[k], fz[k]) = (f.x, f.y, f.z);
        pdf[k] = p;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Sampler;

    #[test]
    fn lanes_give_sample_to_the_bit() {
        // Lambertian materials (one black) among Phong ones, whose samples are put over the
        // lanes' rows; normals and outgoing directions of every
        // orientation, some below the surface, some not quite unit; numbers on the ends of
        // [0, 1). Rounds of 0 to 3000 rows, the room kept from one round to the next.
        let mats = crate::bsdf::test_materials();
        let mut s = Sampler::new(11, 0, 0, 0);
        let dir = |s: &mut Sampler| {
            let u = s.next_2d();
            let (z, phi) = (1.0 - 2.0 * u.x, 2.0 * std::f32::consts::PI * u.y);
            let r = (1.0 - z * z).max(0.0).sqrt();
            Vec3::new(r * phi.cos(), r * phi.sin(), z) * (1.0 + (s.next_1d() - 0.5) * 1e-6)
        };
        let mut queries = Vec::new();
        for k in 0..3000 {
            let m = mats[(k * 7 / 5) % mats.len()];
            let (n, wo) = (dir(&mut s), dir(&mut s));
            let u = match k % 11 {
                0 => Vec2::ZERO,
                1 => Vec2::splat(1.0 - f32::EPSILON / 2.0),
                2 => Vec2::new(0.25, 0.75),
                _ => s.next_2d(),
            };
            queries.push((m, n, wo, s.next_1d(), u));
        }
        let bits = |b: &Option<BsdfSample>| {
            b.map(|b| {
                (
                    [b.wi, b.f].map(|v| v.to_array().map(f32::to_bits)),
                    b.pdf.to_bits(),
                )
            })
        };
        let mut lanes = BsdfLanes::default();
        let (mut some, mut none) = (0, 0);
        for n in [0, 1, 15, 16, 17, 40, queries.len()] {
            lanes.start(n);
            let (ux, uy): (Vec<f32>, Vec<f32>) =
                queries[..n].iter().map(|q| (q.4.x, q.4.y)).unzip();
            for (k, &(m, nrm, wo, lobe, _)) in queries[..n].iter().enumerate() {
                if m.samples_lambert(lobe) {
                    lanes.set(k, m.kd, nrm, wo);
                }
            }
            lanes.run(n, &ux, &uy);
            for (k, &(m, nrm, wo, lobe, u)) in queries[..n].iter().enumerate() {
                if !m.samples_lambert(lobe) {
                    lanes.put(k, m.sample(nrm, wo, lobe, u));
                }
            }
            for (k, &(m, nrm, wo, lobe, u)) in queries[..n].iter().enumerate() {
                let want = m.sample(nrm, wo, lobe, u);
                assert_eq!(
                    bits(&lanes.get(k)),
                    bits(&want),
                    "{k} of {n}: {m:?} {nrm} {wo}"
                );
                if n == queries.len() && m.samples_lambert(lobe) {
                    if want.is_some() {
                        some += 1
                    } else {
                        none += 1
                    }
                }
            }
        }
        // Both outcomes occurred in lanes (half the outgoing directions are below the surface).
        assert!(some > 500 && none > 500, "{some} samples, {none} none");
    }
}
