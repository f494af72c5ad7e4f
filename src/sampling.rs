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
///
/// Two kinds, both pure functions of their key (no state shared between samples):
/// - `Sampler::new`: independent uniform numbers, a hash of (seed, frame, pixel, sample,
///   dimension).
/// - `Sampler::stratified`: sample `index` of a stream of samples of one pixel (docs/sampler.md):
///   every pair of dimensions read by `next_2d` is a 2D Sobol point and every `next_1d` a van der
///   Corput point, each Owen-scrambled with its own hashed seed and with the sample index shuffled
///   per dimension (Burley 2020's padded, hash-based Owen scrambling). The first `2^k` samples of
///   a stream are stratified in every pair of dimensions, any prefix is well spread, and every
///   sample is still uniform on its own, so every estimator keeps its expectation. Streams with
///   different keys are independent of each other.
#[derive(Clone, Debug)]
pub struct Sampler {
    key: u64,
    dim: u64,
    /// The sample's index in its stream, bit-reversed (as the scrambles read it); `None` for
    /// independent numbers.
    index_reversed: Option<u32>,
}

/// A bijection of 32-bit words in which each output bit depends only on the input bits at and
/// below it (multiplication by an even number, addition, multiplication by an odd number, and
/// xor-shifts towards the high bits all carry information upwards only): applied to reversed
/// bits, it is a hash-based nested uniform (Owen) scramble of a number in [0, 1)
/// (Laine and Karras 2011; these steps after Vegdahl 2021's search for better mixing).
#[inline]
fn lk_permutation(mut x: u32, seed: u32) -> u32 {
    x ^= x.wrapping_mul(0x3d20_adea);
    x = x.wrapping_add(seed);
    x = x.wrapping_mul((seed >> 16) | 1);
    x ^= x.wrapping_mul(0x0552_6c56);
    x ^= x.wrapping_mul(0x53a2_2864);
    x
}

/// Owen scrambling of the binary fraction `x / 2^32`: every subinterval's halves swapped or not
/// by a hash of the bits above them (the seed chooses the permutation).
#[inline]
pub fn owen_scramble(x: u32, seed: u32) -> u32 {
    lk_permutation(x.reverse_bits(), seed).reverse_bits()
}

/// The first two dimensions of the Sobol sequence at index `i`, as 32-bit binary fractions:
/// the van der Corput sequence and the dimension of primitive polynomial `x + 1`, whose direction
/// numbers are `v_{k+1} = v_k ^ (v_k >> 1)` from `v_1 = 1/2`.
#[inline]
pub fn sobol_2d(i: u32) -> (u32, u32) {
    (i.reverse_bits(), sobol_y_reversed(i).reverse_bits())
}

/// Sobol's second dimension at index `i`, bit-reversed: the sum (xor) of the reversed direction
/// numbers of `i`'s set bits, one table per byte of the index (the sequence is linear over GF(2)).
#[inline]
fn sobol_y_reversed(i: u32) -> u32 {
    let t = &SOBOL_Y_REVERSED;
    t[0][(i & 255) as usize]
        ^ t[1][((i >> 8) & 255) as usize]
        ^ t[2][((i >> 16) & 255) as usize]
        ^ t[3][(i >> 24) as usize]
}

static SOBOL_Y_REVERSED: [[u32; 256]; 4] = sobol_y_tables();

const fn sobol_y_tables() -> [[u32; 256]; 4] {
    let mut dir = [0u32; 32];
    let mut v = 1u32 << 31;
    let mut k = 0;
    while k < 32 {
        dir[k] = v.reverse_bits();
        v ^= v >> 1;
        k += 1;
    }
    let mut t = [[0u32; 256]; 4];
    let mut byte = 0;
    while byte < 4 {
        let mut e = 0;
        while e < 256 {
            let mut y = 0;
            let mut j = 0;
            while j < 8 {
                if e & (1 << j) != 0 {
                    y ^= dir[8 * byte + j];
                }
                j += 1;
            }
            t[byte][e] = y;
            e += 1;
        }
        byte += 1;
    }
    t
}

/// A 32-bit binary fraction as a float in [0, 1), keeping 24 bits.
#[inline]
fn unit(x: u32) -> f32 {
    (x >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
}

/// The key of a sampler: `salt` (which kind), seed, frame, pixel and `last` (the sample, or the
/// stream) hashed in turn.
fn key(salt: u64, seed: u64, frame: u32, pixel: u32, last: u32) -> u64 {
    let mut h = mix64(seed ^ salt);
    h = mix64(h ^ frame as u64);
    h = mix64(h ^ pixel as u64);
    mix64(h ^ last as u64)
}

/// The hash of dimension `d` of the sample with key `key`: its independent number, or the seeds
/// of its stratified number.
#[inline(always)]
fn dim_hash(key: u64, d: u64) -> u64 {
    mix64(key ^ d.wrapping_mul(0x9e37_79b9_7f4a_7c15))
}

/// The seeds of 1D dimension `d` of the sample with key `key`: the index shuffle and the
/// scramble.
#[inline(always)]
fn seeds_1d(key: u64, d: u64) -> (u32, u32) {
    let h = dim_hash(key, d);
    (h as u32, (h >> 32) as u32)
}

/// The seeds of 2D dimension `d`: those of `seeds_1d` and the second coordinate's scramble.
#[inline(always)]
fn seeds_2d(key: u64, d: u64) -> (u32, u32, u32) {
    let h = dim_hash(key, d);
    (h as u32, (h >> 32) as u32, mix64(h) as u32)
}

/// The stratified number at 1D dimension `d` of the sample with key `key` and bit-reversed
/// index `ir`: the scrambled van der Corput point of the shuffled index.
#[inline(always)]
fn stratified_1d(key: u64, ir: u32, d: u64) -> f32 {
    // The shuffled index is i' = O(i) = rev(lk(rev(i))), then O(vdC(i'), sx), where
    // vdC(i') = rev(i'), so O(rev(i'), sx) = rev(lk(i', sx)).
    let (shuffle, sx) = seeds_1d(key, d);
    let i = lk_permutation(ir, shuffle).reverse_bits();
    unit(lk_permutation(i, sx).reverse_bits())
}

/// The stratified 2D point at dimensions `d`, `d + 1` of the sample with key `key` and
/// bit-reversed index `ir`.
#[inline(always)]
fn stratified_2d(key: u64, ir: u32, d: u64) -> (f32, f32) {
    let (shuffle, sx, sy) = seeds_2d(key, d);
    // As `owen_scramble(sobol_2d(owen_scramble(i, shuffle)))` coordinate by coordinate, with
    // the reversals that cancel left out (the scramble works on reversed bits).
    let i = lk_permutation(ir, shuffle).reverse_bits();
    let x = lk_permutation(i, sx).reverse_bits();
    let y = lk_permutation(sobol_y_reversed(i), sy).reverse_bits();
    (unit(x), unit(y))
}

/// Where the numbers of one step of a path are read: the Russian roulette decision that ends the
/// step (if the step has one), then the vertex's light sample (2D), the choice of its BSDF
/// lobe (1D) and its BSDF sample (2D). The integrator fixes the dimensions (so that a stage
/// always reads the same numbers, whatever the stages before it used).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StepDims {
    pub rr: Option<u64>,
    pub light: u64,
    pub lobe: u64,
    pub bsdf: u64,
}

/// The numbers of one step of a path, read at its `StepDims` (`rr` is 0 where it has none).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepNumbers {
    pub rr: f32,
    pub light: Vec2,
    pub lobe: f32,
    pub bsdf: Vec2,
}

/// The samplers of a batch of paths in structure-of-arrays form, to draw a step's numbers for
/// many paths at once (`draw`): the wavefront's paths all take the same step in a round, so
/// the hashing and scrambling of their numbers runs in SIMD lanes, one path per lane.
#[derive(Default)]
pub struct StepLanes {
    keys: Vec<u64>,
    index_reversed: Vec<u32>,
    /// Whether every sampler is stratified (else `draw` goes path by path).
    stratified: bool,
    samplers: Vec<Sampler>,
    /// The keys and indices of the paths of one `draw`, gathered.
    gather_keys: Vec<u64>,
    gather_index: Vec<u32>,
}

/// A step's numbers for a batch of paths, one column per number (`get` puts a path's together).
#[derive(Default)]
pub struct StepBatch {
    rr: Vec<f32>,
    light_x: Vec<f32>,
    light_y: Vec<f32>,
    lobe: Vec<f32>,
    bsdf_x: Vec<f32>,
    bsdf_y: Vec<f32>,
}

impl StepBatch {
    /// The numbers of the `k`-th path of the last `StepLanes::draw`.
    #[inline]
    pub fn get(&self, k: usize) -> StepNumbers {
        StepNumbers {
            rr: self.rr[k],
            light: self.light(k),
            lobe: self.lobe[k],
            bsdf: Vec2::new(self.bsdf_x[k], self.bsdf_y[k]),
        }
    }

    /// The lobe number of the `k`-th path.
    #[inline(always)]
    pub fn lobe(&self, k: usize) -> f32 {
        self.lobe[k]
    }

    /// The BSDF sample's numbers of the `k`-th path.
    #[inline(always)]
    pub fn bsdf(&self, k: usize) -> Vec2 {
        Vec2::new(self.bsdf_x[k], self.bsdf_y[k])
    }

    /// The BSDF sample's numbers of every path, as two columns.
    pub fn bsdf_columns(&self) -> (&[f32], &[f32]) {
        (&self.bsdf_x, &self.bsdf_y)
    }

    /// The light sample's numbers of the `k`-th path of the last `StepLanes::draw`.
    #[inline]
    pub fn light(&self, k: usize) -> Vec2 {
        Vec2::new(self.light_x[k], self.light_y[k])
    }

    /// Bytes held per path (for memory estimates).
    pub const BYTES_PER_PATH: usize = 6 * std::mem::size_of::<f32>();
}

impl StepLanes {
    /// Bytes held per path (for memory estimates).
    pub const BYTES_PER_PATH: usize = 2 * (8 + 4) + std::mem::size_of::<Sampler>();

    /// Take the samplers of a batch: path `i` draws from `samplers[i]`.
    pub fn fill(&mut self, samplers: &[Sampler]) {
        self.stratified = samplers.iter().all(|s| s.index_reversed.is_some());
        self.keys.clear();
        self.index_reversed.clear();
        self.samplers.clear();
        if self.stratified {
            self.keys.extend(samplers.iter().map(|s| s.key));
            self.index_reversed
                .extend(samplers.iter().map(|s| s.index_reversed.unwrap_or(0)));
        } else {
            self.samplers.extend_from_slice(samplers);
        }
    }

    /// The numbers at `dims` of paths `paths` (indices into the batch), into `out`: the `k`-th
    /// path's are `out.get(k)`, bitwise what `Sampler::step(dims)` gives.
    pub fn draw(&mut self, paths: &[u32], dims: StepDims, out: &mut StepBatch) {
        let n = paths.len();
        for col in [
            &mut out.rr,
            &mut out.light_x,
            &mut out.light_y,
            &mut out.lobe,
            &mut out.bsdf_x,
            &mut out.bsdf_y,
        ] {
            col.clear();
            col.resize(n, 0.0);
        }
        if !self.stratified {
            for (k, &i) in paths.iter().enumerate() {
                let s = self.samplers[i as usize].step(dims);
                (out.rr[k], out.lobe[k]) = (s.rr, s.lobe);
                (out.light_x[k], out.light_y[k]) = (s.light.x, s.light.y);
                (out.bsdf_x[k], out.bsdf_y[k]) = (s.bsdf.x, s.bsdf.y);
            }
            return;
        }
        self.gather_keys.clear();
        self.gather_index.clear();
        self.gather_keys
            .extend(paths.iter().map(|&i| self.keys[i as usize]));
        self.gather_index
            .extend(paths.iter().map(|&i| self.index_reversed[i as usize]));
        draw_stratified(&self.gather_keys, &self.gather_index, dims, out);
    }
}

/// `StepLanes::draw` for stratified samplers whose keys and indices are gathered, one path per
/// SIMD lane.
fn draw_stratified(keys: &[u64], index_reversed: &[u32], dims: StepDims, out: &mut StepBatch) {
    let (light, bsdf) = (
        (&mut out.light_x[..], &mut out.light_y[..]),
        (&mut out.bsdf_x[..], &mut out.bsdf_y[..]),
    );
    draw_2d(keys, index_reversed, dims.light, light.0, light.1);
    draw_1d(keys, index_reversed, dims.lobe, &mut out.lobe);
    draw_2d(keys, index_reversed, dims.bsdf, bsdf.0, bsdf.1);
    if let Some(d) = dims.rr {
        draw_1d(keys, index_reversed, d, &mut out.rr);
    }
}

// The two kernels are compiled for AVX-512 and AVX2 besides the portable build, and the best
// the CPU runs is chosen at run time. They are integer hashing and an exact conversion, so every
// version gives the same bits. Each writes slices that are its own arguments, so that the
// compiler knows they do not overlap (it vectorises only then).

/// `stratified_1d` at dimension `d` for each lane (`keys[k]`, `index_reversed[k]`) into `out[k]`.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512cd+avx512dq+avx512vl",
    "x86_64+avx2",
))]
fn draw_1d(keys: &[u64], index_reversed: &[u32], d: u64, out: &mut [f32]) {
    for ((&key, &ir), v) in keys.iter().zip(index_reversed).zip(out) {
        *v = stratified_1d(key, ir, d);
    }
}

/// `stratified_2d` at dimension `d` for each lane into `x[k]`, `y[k]`.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512cd+avx512dq+avx512vl",
    "x86_64+avx2",
))]
fn draw_2d(keys: &[u64], index_reversed: &[u32], d: u64, x: &mut [f32], y: &mut [f32]) {
    let lanes = keys.iter().zip(index_reversed);
    for ((&key, &ir), (x, y)) in lanes.zip(x.iter_mut().zip(y)) {
        (*x, *y) = stratified_2d(key, ir, d);
    }
}

impl Sampler {
    /// Independent numbers for sample `sample` of `pixel` of `frame`.
    pub fn new(seed: u64, frame: u32, pixel: u32, sample: u32) -> Sampler {
        Sampler {
            key: key(0x5851_f42d_4c95_7f2d, seed, frame, pixel, sample),
            dim: 0,
            index_reversed: None,
        }
    }

    /// Sample `index` of stream `stream` of `pixel` of `frame`: stratified with the other
    /// samples of its stream, independent of every other stream.
    pub fn stratified(seed: u64, frame: u32, pixel: u32, stream: u32, index: u32) -> Sampler {
        Sampler {
            key: key(0x2545_f491_4f6c_dd1d, seed, frame, pixel, stream),
            dim: 0,
            index_reversed: Some(index.reverse_bits()),
        }
    }

    /// Sample `index` of the same stream as this stratified sampler (bitwise
    /// `Sampler::stratified` with this one's key and `index`): a tile keeps its pixels' streams
    /// and takes each sample index from them, instead of hashing the key again.
    #[inline]
    pub fn at_index(&self, index: u32) -> Sampler {
        debug_assert!(self.index_reversed.is_some(), "a stratified sampler");
        Sampler {
            key: self.key,
            dim: 0,
            index_reversed: Some(index.reverse_bits()),
        }
    }

    /// The hash of dimension `d` of this sample: its independent number, or its seeds.
    #[inline]
    fn dim_hash(&self, d: u64) -> u64 {
        dim_hash(self.key, d)
    }

    /// A uniform number in [0, 1), with 24 bits (every float of that spacing is representable).
    #[inline]
    pub fn next_1d(&mut self) -> f32 {
        let d = self.dim;
        self.dim += 1;
        self.get_1d(d)
    }

    /// Two uniform numbers in [0, 1): independent, or one 2D point of the stream.
    #[inline]
    pub fn next_2d(&mut self) -> Vec2 {
        let d = self.dim;
        self.dim += 2;
        self.get_2d(d)
    }

    /// The number `next_1d` reads at dimension `d`, the counter left as it is.
    #[inline]
    pub fn get_1d(&self, d: u64) -> f32 {
        match self.index_reversed {
            None => (self.dim_hash(d) >> 40) as f32 * (1.0 / (1u64 << 24) as f32),
            Some(ir) => stratified_1d(self.key, ir, d),
        }
    }

    /// The point `next_2d` reads at dimensions `d` and `d + 1`, the counter left as it is.
    #[inline]
    pub fn get_2d(&self, d: u64) -> Vec2 {
        match self.index_reversed {
            None => Vec2::new(self.get_1d(d), self.get_1d(d + 1)),
            Some(ir) => {
                let (x, y) = stratified_2d(self.key, ir, d);
                Vec2::new(x, y)
            }
        }
    }

    /// The numbers of one step of a path, read at `dims`: what `StepLanes::draw` gives a batch
    /// of paths, to the bit.
    #[inline]
    pub fn step(&self, dims: StepDims) -> StepNumbers {
        StepNumbers {
            rr: dims.rr.map_or(0.0, |d| self.get_1d(d)),
            light: self.get_2d(dims.light),
            lobe: self.get_1d(dims.lobe),
            bsdf: self.get_2d(dims.bsdf),
        }
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

/// `(sin 2 pi t, cos 2 pi t)` for `t` in turns, without a call into the maths library, so that a
/// loop of them runs in SIMD lanes (`integrator::lanes`) and gives the same bits as one at a
/// time: nothing is fused and every step is an IEEE operation or a select.
///
/// The turn is reduced exactly to the nearest quarter `q / 4` and a remainder `r` in
/// `[-1/8, 1/8]` (for the sampler's numbers, multiples of `2^-24`, both steps are exact), the
/// remainder's angle `x = 2 pi r` lies in `[-pi/4, pi/4]`, where short odd and even polynomials
/// give `sin x` and `cos x` to about one unit in the last place (the Taylor series with its
/// last coefficients adjusted for the interval; docs/sampler.md, "Sine and cosine"), and the
/// quarter turns them: `sin(x + q pi/2)` is `sin x`, `cos x`, `-sin x` or `-cos x`.
#[inline(always)]
pub fn sin_cos_turns(t: f32) -> (f32, f32) {
    let q = (t * 4.0).round();
    let r = t - q * 0.25;
    let x = r * (2.0 * PI);
    let z = x * x;
    let s = x + x * z * (-1.666_665_5e-1 + z * (8.332_161e-3 + z * -1.951_529_6e-4));
    let c = 1.0 - 0.5 * z + z * z * (4.166_664_6e-2 + z * (-1.388_731_6e-3 + z * 2.443_315_7e-5));
    // The quarter modulo 4, in floats (every step exact for a whole `q`; a cast of `q` itself
    // saturates from 2^31 on), then cast (0 to 3).
    let quarter = (q - 4.0 * (q * 0.25).floor()) as i32;
    let (s, c) = if quarter & 1 == 0 { (s, c) } else { (c, -s) };
    if quarter & 2 == 0 {
        (s, c)
    } else {
        (-s, -c)
    }
}

/// Cosine-weighted hemisphere around +z (Malley's method); pdf = cos(theta) / pi.
#[inline(always)]
pub fn cosine_hemisphere(u: Vec2) -> Vec3 {
    let r = u.x.sqrt();
    let (sin_phi, cos_phi) = sin_cos_turns(u.y);
    Vec3::new(r * cos_phi, r * sin_phi, (1.0 - u.x).max(0.0).sqrt())
}

/// Directions around +z with density (n+1)/(2 pi) cos^n(alpha) over the sphere (the Phong lobe):
/// cos(alpha) = u^(1/(n+1)).
#[inline]
pub fn phong_lobe(u: Vec2, exponent: f32) -> Vec3 {
    let cos_a = u.x.powf(1.0 / (exponent + 1.0));
    let sin_a = (1.0 - cos_a * cos_a).max(0.0).sqrt();
    let (sin_phi, cos_phi) = sin_cos_turns(u.y);
    Vec3::new(sin_a * cos_phi, sin_a * sin_phi, cos_a)
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
    #[test]
    fn stratified_streams_are_stratified_uniform_and_independent() {
        // The first 16 samples of a stream: one in each of the 16 cells of every elementary
        // partition of the square (16 x 1, 8 x 2, 4 x 4, 2 x 8, 1 x 16), in every pair of
        // dimensions, and one per sixteenth in a 1D dimension.
        for stream in 0..50u32 {
            let pts: Vec<(Vec2, f32, Vec2)> = (0..16)
                .map(|i| {
                    let mut s = Sampler::stratified(3, 7, 1234, stream, i);
                    let a = s.next_2d();
                    let b = s.next_1d();
                    s.set_dimension(13);
                    (a, b, s.next_2d())
                })
                .collect();
            for (nx, ny) in [(16, 1), (8, 2), (4, 4), (2, 8), (1, 16)] {
                for pick in [|p: &(Vec2, f32, Vec2)| p.0, |p: &(Vec2, f32, Vec2)| p.2] {
                    let mut cells = vec![0; 16];
                    for p in &pts {
                        let q = pick(p);
                        cells[(q.x * nx as f32) as usize * ny + (q.y * ny as f32) as usize] += 1;
                    }
                    assert!(cells.iter().all(|&c| c == 1), "{nx}x{ny}: {cells:?}");
                }
            }
            let mut cells = [0; 16];
            for p in &pts {
                cells[(p.1 * 16.0) as usize] += 1;
            }
            assert_eq!(cells, [1; 16]);
        }
        // Any one sample, over many pixels, is uniform (chi-square over 8 x 8 cells), and two
        // streams of one pixel are uncorrelated.
        let n = 64_000u32;
        let mut cells = vec![0u32; 64];
        let (mut sxy, mut sx, mut sy) = (0.0f64, 0.0f64, 0.0f64);
        for pixel in 0..n {
            let q = Sampler::stratified(1, 2, pixel, 0, 5).next_2d();
            cells[(q.x * 8.0) as usize * 8 + (q.y * 8.0) as usize] += 1;
            let r = Sampler::stratified(1, 2, pixel, 1, 5).next_2d();
            sxy += (q.x as f64 - 0.5) * (r.x as f64 - 0.5);
            sx += (q.x as f64 - 0.5).powi(2);
            sy += (r.x as f64 - 0.5).powi(2);
        }
        let expect = vec![n as f64 / 64.0; 64];
        let observed: Vec<f64> = cells.iter().map(|&c| c as f64).collect();
        let (_, _, p) = chi_square(&expect, &observed);
        assert!(p > 1e-3, "chi-square p = {p}");
        let corr = sxy / (sx * sy).sqrt();
        assert!(corr.abs() < 0.02, "correlation {corr}");
        // Sobol's second dimension: 0, 1/2, 3/4, 1/4, 5/8, 1/8, 3/8, 7/8 for the first eight
        // indices, and its tables agree with the direction numbers' recurrence everywhere.
        let y: Vec<u32> = (0..8).map(|i| sobol_2d(i).1 >> 29).collect();
        assert_eq!(y, [0, 4, 6, 2, 5, 1, 3, 7]);
        for k in 0..2000u32 {
            let i = (mix64(k as u64) as u32) >> (k % 32);
            let (mut y, mut v, mut bits) = (0u32, 1u32 << 31, i);
            while bits != 0 {
                y ^= if bits & 1 != 0 { v } else { 0 };
                bits >>= 1;
                v ^= v >> 1;
            }
            assert_eq!(sobol_2d(i).1, y, "index {i}");
        }
        // The sampler's numbers are the scrambled, shuffled Sobol points as defined (its
        // shortcuts leave out reversals that cancel).
        for k in 0..500u32 {
            let mut s = Sampler::stratified(5, k, 3 * k, k % 7, k);
            let (shuffle, sx, sy) = seeds_2d(s.key, 0);
            let (x, y) = sobol_2d(owen_scramble(k, shuffle));
            let want = Vec2::new(unit(owen_scramble(x, sx)), unit(owen_scramble(y, sy)));
            assert_eq!(s.next_2d(), want);
            let (shuffle, sx) = seeds_1d(s.key, 2);
            let want = unit(owen_scramble(owen_scramble(k, shuffle).reverse_bits(), sx));
            assert_eq!(s.next_1d(), want);
        }
    }

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
    fn a_batch_draws_each_samplers_numbers_to_the_bit() {
        // `StepLanes::draw` (SIMD lanes, for a subset of a batch's paths in any order) against
        // `Sampler::step` path by path, and `step` against the sequential reads it replaces:
        // batches that fill no lane, part of one and several, stratified and independent
        // samplers, with and without the roulette's number.
        let dims = [
            StepDims {
                rr: None,
                light: 2,
                lobe: 5,
                bsdf: 6,
            },
            StepDims {
                rr: Some(21),
                light: 24,
                lobe: 26,
                bsdf: 27,
            },
            StepDims {
                rr: Some(1 << 40),
                light: 3,
                lobe: u64::MAX,
                bsdf: 0,
            },
        ];
        let (mut lanes, mut out) = (StepLanes::default(), StepBatch::default());
        for n in [0usize, 1, 7, 8, 9, 16, 17, 63, 300] {
            for stratified in [true, false] {
                let samplers: Vec<Sampler> = (0..n as u32)
                    .map(|i| match stratified {
                        true => Sampler::stratified(9, 3, i * 7919, i % 3, i.wrapping_mul(0x9e37)),
                        false => Sampler::new(9, 3, i, i),
                    })
                    .collect();
                lanes.fill(&samplers);
                // Every other path, backwards, then every path.
                let odd: Vec<u32> = (0..n as u32).rev().step_by(2).collect();
                let all: Vec<u32> = (0..n as u32).collect();
                for paths in [&odd, &all] {
                    for d in dims {
                        lanes.draw(paths, d, &mut out);
                        for (k, &i) in paths.iter().enumerate() {
                            let want = samplers[i as usize].step(d);
                            let got = out.get(k);
                            let bits = |s: StepNumbers| {
                                [s.rr, s.light.x, s.light.y, s.lobe, s.bsdf.x, s.bsdf.y]
                                    .map(f32::to_bits)
                            };
                            assert_eq!(bits(got), bits(want), "n {n}, path {i}, {d:?}");
                        }
                    }
                }
                for s in samplers.iter().take(20) {
                    let d = dims[1];
                    let mut seq = s.clone();
                    seq.set_dimension(d.rr.unwrap());
                    let rr = seq.next_1d();
                    seq.set_dimension(d.light);
                    let (light, lobe, bsdf) = (seq.next_2d(), seq.next_1d(), seq.next_2d());
                    let want = StepNumbers {
                        rr,
                        light,
                        lobe,
                        bsdf,
                    };
                    assert_eq!(s.step(d), want);
                    assert!([rr, light.x, light.y, lobe, bsdf.x, bsdf.y]
                        .iter()
                        .all(|v| (0.0..1.0).contains(v)));
                }
            }
        }
    }

    #[test]
    fn sin_cos_turns_is_accurate_and_exact_at_the_quarters() {
        // Every 97th multiple of 2^-24 in [0, 1) (the sampler's numbers), and others, against
        // f64: within 2 units in the last place of 1 (the values are at most 1 in magnitude).
        let mut worst = 0.0f64;
        let ts = (0..(1u32 << 24))
            .step_by(97)
            .map(|i| i as f32 / (1u32 << 24) as f32)
            .chain([-0.3, 0.999_999_9, 1.0, 1.37, -2.125]);
        for t in ts {
            let (s, c) = sin_cos_turns(t);
            let a = 2.0 * std::f64::consts::PI * t as f64;
            worst = worst.max((s as f64 - a.sin()).abs().max((c as f64 - a.cos()).abs()));
        }
        assert!(worst < 2.0 * f32::EPSILON as f64, "worst error {worst:e}");
        // Whole turns, however many, are exact: a saturating cast of the quarter gave (-1, 0)
        // from 2^29 on.
        for t in [5.37e8f32, 1e9, 2.5e9, 1e20, -1e20, -3.0] {
            let (s, c) = sin_cos_turns(t);
            assert_eq!((s.abs(), c), (0.0, 1.0), "t = {t}");
        }
        // The quarter turns are exact (the library's cos(pi / 2) in f32 is -4.4e-8).
        for (t, want) in [
            (0.0, (0.0, 1.0)),
            (0.25, (1.0, 0.0)),
            (0.5, (0.0, -1.0)),
            (0.75, (-1.0, 0.0)),
        ] {
            let (s, c) = sin_cos_turns(t);
            assert_eq!((s, c), want, "t = {t}");
        }
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
