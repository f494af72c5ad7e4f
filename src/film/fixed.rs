//! Per-pixel sums in 32-bit fixed point, the most compact form whose additions are associative,
//! so that frames are bitwise identical for any thread count (pbrt-v4's issue #85 is what
//! floating-point splats from many threads do).
//!
//! A value is quantised by stochastic rounding, `floor(v 2^20 + u)` with a hashed `u` in [0, 1):
//! its expectation is exactly `v 2^20`, so splats far below one step (high sample counts, dark
//! pixels) are not rounded away and the estimator stays unbiased. The 32-bit cells wrap; every
//! wrap is recorded as a carry of 2^32 in a side table, so the true sum is `cell + carry` exactly
//! and independent of the order of additions. Carries need a pixel's pre-scaled sum past 2048,
//! which the per-method pre-scaling (`Layout::unit`) keeps rare.
use std::collections::HashMap;
use std::sync::atomic::{AtomicI32, Ordering::Relaxed};
use std::sync::Mutex;

/// Fixed-point scale of the accumulators: 2^20 steps per unit of (pre-scaled) radiance.
pub const FIXED: f64 = (1u64 << 20) as f64;

/// `1.5 2^52`: a float between 2^52 and 2^53 whose unit in the last place is 1 (`floor_small`).
const ROUND: f64 = 6755399441055744.0;
/// Values below 2^51 in size round through `ROUND` (`floor_small`).
const LIMIT: f64 = 2251799813685248.0;

/// `floor(x)` for `|x| < 2^51` in plain float arithmetic: `x + 1.5 2^52` rounds `x` to the
/// nearest integer `n` and holds it in its low bits (the sum lies between 2^52 and 2^53, where
/// the float's unit in the last place is 1), so `n` is the difference of the two bit patterns,
/// and `n - 1` where `n > x` is the floor. No float-to-integer conversion, which x86-64 has only
/// one value at a time and which `as` follows with saturation checks.
#[inline]
fn floor_small(x: f64) -> i64 {
    let y = x + ROUND;
    let n = y.to_bits() as i64 - ROUND.to_bits() as i64;
    n - ((y - ROUND) > x) as i64
}

/// `floor(v 2^20 + u)`, saturating at the ends of i64 (as `f64::floor` followed by `as i64`,
/// to the bit): stochastic rounding of `v` with the dither `u` in [0, 1). Written out because
/// `f64::floor` is a call into libm on x86-64 without SSE4.1, and every splat rounds; all but
/// absurd splats take `floor_small`.
#[inline]
pub fn quantize(v: f32, u: f64) -> i64 {
    let x = v as f64 * FIXED + u;
    if x.abs() < LIMIT {
        return floor_small(x);
    }
    let t = x as i64; // rounds towards zero, saturates, NaN to 0
    t.saturating_sub(((t as f64) > x) as i64)
}

/// `quantize` of three values at once, to the bit: where every `x = v 2^20 + u` is below 2^51
/// in size, the three `floor_small`s (and a fourth lane of padding) in plain float arithmetic
/// that the compiler vectorises, two channels per instruction; elsewhere each value goes
/// through `quantize`.
#[inline]
pub fn quantize3(v: [f32; 3], u: [f64; 3]) -> [i64; 3] {
    let x = [
        v[0] as f64 * FIXED + u[0],
        v[1] as f64 * FIXED + u[1],
        v[2] as f64 * FIXED + u[2],
        0.0,
    ];
    // Without short-circuits: one packed comparison instead of a branch per channel.
    if (x[0].abs() < LIMIT) & (x[1].abs() < LIMIT) & (x[2].abs() < LIMIT) {
        let mut q = [0i64; 4];
        for c in 0..4 {
            q[c] = floor_small(x[c]);
        }
        return [q[0], q[1], q[2]];
    }
    [
        quantize(v[0], u[0]),
        quantize(v[1], u[1]),
        quantize(v[2], u[2]),
    ]
}

/// `v` within i64, at its ends where past them.
fn clamp(v: i128) -> i64 {
    v.clamp(i64::MIN as i128, i64::MAX as i128) as i64
}

pub struct FixedSums {
    cells: Vec<AtomicI32>,
    /// Wider than a total, so that carries add exactly in any order even past i64 (only absurd
    /// splats get there); a total is clamped to i64 once, when read.
    carry: Mutex<HashMap<usize, i128>>,
}

impl FixedSums {
    pub fn new(n: usize) -> FixedSums {
        FixedSums {
            cells: (0..n).map(|_| AtomicI32::new(0)).collect(),
            carry: Mutex::new(HashMap::new()),
        }
    }

    /// Sums made of raw cells and carries (cell index, value in steps), as a state file holds
    /// them.
    pub fn from_parts(cells: Vec<i32>, carry: &[(u64, i64)]) -> FixedSums {
        FixedSums {
            cells: cells.into_iter().map(AtomicI32::new).collect(),
            carry: Mutex::new(
                carry
                    .iter()
                    .map(|&(i, c)| (i as usize, c as i128))
                    .collect(),
            ),
        }
    }

    pub fn len(&self) -> usize {
        self.cells.len()
    }

    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }

    /// Quantise `v` (in steps of 1/FIXED) with the dither `u` in [0, 1) and add it to cell `i`.
    #[inline]
    pub fn add_value(&self, i: usize, v: f32, u: f64) {
        self.add(i, quantize(v, u));
    }

    /// Add the already quantised `q` (any size) to cell `i`.
    #[inline]
    pub fn add(&self, i: usize, q: i64) {
        // |q| beyond 2^31 (a single splat over 2048) goes to the carry table whole.
        let carry = |c: i64| {
            *self.carry.lock().unwrap().entry(i).or_default() += c as i128;
        };
        let Ok(q32) = i32::try_from(q) else {
            carry(q);
            return;
        };
        let old = self.cells[i].fetch_add(q32, Relaxed);
        if old.overflowing_add(q32).1 {
            carry(if q32 > 0 { 1i64 << 32 } else { -(1i64 << 32) });
        }
    }

    /// The raw 32-bit cells, in order.
    pub fn cells(&self) -> impl ExactSizeIterator<Item = i32> + '_ {
        self.cells.iter().map(|c| c.load(Relaxed))
    }

    /// The carries (cell index, value in steps), sorted by index: past i64 (a sum past 2^63
    /// steps, 8.8e12 units: only ever absurd splats), at its end.
    pub fn carries(&self) -> Vec<(u64, i64)> {
        let mut v: Vec<(u64, i64)> = self
            .carry
            .lock()
            .unwrap()
            .iter()
            .map(|(&i, &c)| (i as u64, clamp(c)))
            .collect();
        v.sort_unstable();
        v
    }

    /// The exact sum of every cell, in steps (cell plus carry); a sum past i64 at the end of
    /// the range it ran over, never wrapped to the other sign.
    pub fn totals(&self) -> Vec<i64> {
        let mut t: Vec<i64> = self.cells().map(i64::from).collect();
        for (&i, &c) in self.carry.lock().unwrap().iter() {
            t[i] = clamp(t[i] as i128 + c);
        }
        t
    }

    /// Add every exact total of `o` into `self` (the same frame's share from another chunk).
    pub fn absorb(&self, o: &FixedSums) {
        for (i, q) in o.totals().into_iter().enumerate() {
            if q != 0 {
                self.add(i, q);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn carries_wrap_exactly_in_any_order() {
        // Splats that wrap the 32-bit cell many times, in two orders, and one single splat beyond
        // 2^31 steps: the totals are exact and equal.
        let values: Vec<i64> = (0..4000).map(|k| 900_000_000 + 7919 * k).collect();
        let exact: i64 = values.iter().sum::<i64>() + (3i64 << 40);
        let (a, b) = (FixedSums::new(1), FixedSums::new(1));
        for &q in &values {
            a.add(0, q);
        }
        a.add(0, 3i64 << 40);
        b.add(0, 3i64 << 40);
        for &q in values.iter().rev() {
            b.add(0, q);
        }
        assert_eq!(a.totals()[0], exact);
        assert_eq!(a.totals(), b.totals());
        // Absorbing one into a third in pieces keeps the sum exact too.
        let c = FixedSums::from_parts(vec![i32::MAX], &[(0, -(1 << 32))]);
        c.absorb(&a);
        assert_eq!(c.totals()[0], exact + i32::MAX as i64 - (1 << 32));
    }

    /// Sums past 2^63 steps (only absurd splats get there: a camera whose film densities
    /// overflowed wrote pixels of exactly -2^43 units) end at the end of the range they ran
    /// over instead of wrapping to the other sign, and partial sums past it add exactly, in any
    /// order.
    #[test]
    fn sums_past_the_range_clamp_instead_of_wrapping() {
        for order in [[i64::MAX, i64::MAX, 1], [1, i64::MAX, i64::MAX]] {
            let s = FixedSums::new(1);
            for q in order {
                s.add(0, q);
            }
            assert_eq!(s.totals()[0], i64::MAX);
        }
        let s = FixedSums::new(2);
        s.add(1, i64::MIN);
        s.add(1, -(1 << 40));
        assert_eq!(s.totals(), [0, i64::MIN]);
        // Past the top and back within it: exact, whatever the order of the additions (cells
        // that wrap among carries past i64 too).
        let values = [i64::MAX, i64::MAX, -i64::MAX, i32::MAX as i64, -i64::MAX, 7];
        let (a, b) = (FixedSums::new(1), FixedSums::new(1));
        for q in values {
            a.add(0, q);
        }
        for q in values.into_iter().rev() {
            b.add(0, q);
        }
        assert_eq!(a.totals(), [i32::MAX as i64 + 7]);
        assert_eq!(b.totals(), a.totals());
    }

    #[test]
    fn quantize_is_floor() {
        // Against `f64::floor` on values around every power of two in range, their neighbours,
        // both signs, and the ends: NaN, infinities, values past i64.
        let mut cases = vec![
            0.0f32,
            -0.0,
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MAX,
            f32::MIN,
        ];
        for e in -40..64 {
            let x = (2.0f32).powi(e) / FIXED as f32;
            for v in [
                x,
                -x,
                x * 1.5,
                -x * 1.5,
                f32::from_bits(x.to_bits() + 1),
                -f32::from_bits(x.to_bits() - 1),
            ] {
                cases.push(v);
            }
        }
        // Around `quantize3`'s limit: x = v 2^20 + u near +-2^51 (and x = +-2^31).
        for steps in [
            2f64.powi(51),
            2f64.powi(51) - 2f64.powi(28),
            2f64.powi(31) - 1.0,
        ] {
            for s in [1.0, -1.0] {
                let v = (s * steps / FIXED) as f32;
                cases.extend([
                    v,
                    f32::from_bits(v.to_bits() + 1),
                    f32::from_bits(v.to_bits() - 1),
                ]);
            }
        }
        let us = [0.0, 0.25, 0.5, 0.999_999_9, 1.0 - f64::EPSILON];
        for &v in &cases {
            for u in us {
                let want = (v as f64 * FIXED + u).floor() as i64;
                assert_eq!(quantize(v, u), want, "v {v:e} u {u}");
            }
        }
        // Three at a time: every value in every lane, beside small and huge neighbours.
        for (i, &v) in cases.iter().enumerate() {
            for (j, u) in us.into_iter().enumerate() {
                let w = cases[(i * 7 + j) % cases.len()];
                for lanes in [[v, 0.5, w], [w, v, 1e-3], [-1e-6, w, v]] {
                    let us3 = [u, us[(j + 1) % 5], us[(j + 3) % 5]];
                    let want = [0, 1, 2].map(|c| quantize(lanes[c], us3[c]));
                    assert_eq!(quantize3(lanes, us3), want, "{lanes:?} {us3:?}");
                }
            }
        }
    }

    #[test]
    fn stochastic_rounding_keeps_splats_below_one_step() {
        // 10^6 splats of 0.3 steps each: rounding to nearest would give 0; the dithered sum
        // matches the exact sum within a few standard deviations (each splat's rounding error
        // has variance 0.3 * 0.7 steps^2).
        let s = FixedSums::new(1);
        let v = 0.3 / FIXED as f32;
        let n = 1_000_000u64;
        for k in 0..n {
            let u = (crate::sampling::mix64(k) >> 11) as f64 / (1u64 << 53) as f64;
            s.add_value(0, v, u);
        }
        let exact = n as f64 * v as f64 * FIXED;
        let sigma = (n as f64 * 0.21).sqrt();
        let got = s.totals()[0] as f64;
        assert!((got - exact).abs() < 5.0 * sigma, "{got} vs {exact}");
    }
}
