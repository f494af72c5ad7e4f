//! A worker's private share of one frame's sums, over a window of pixels around the block of
//! tiles it works on, added into the frame's shared accumulator once at the end (`flush`).
//!
//! Why: a reuse splats into the film of another frame, which other workers splat into too, so a
//! direct splat is three or four atomic read-modify-writes on cells that are often not in cache
//! (`perf` put them at 18% of a `mis-cv` render at n_f = 17). The samples a worker reuses into
//! one frame land close together, around the worker's block (the frames of a group see the scene
//! from nearby eyes), and a window pixel receives several of them: summed here, the frame sees one
//! atomic add per touched cell instead of one per splat.
//!
//! The window sums in `f32`, with plain float adds, and rounds each cell to the frame's fixed
//! point once, stochastically, when it is flushed (the frame's rounding, `FrameAccum::splat`,
//! with a dither that names the frame, the pixel and the window, `LocalFilm::new`'s `key`): a
//! splat costs one float add per channel instead of a dither hash and a stochastic rounding per
//! channel, and the flush's rounding keeps the expectation exact, as the frame's own does. The
//! float sums round each add to 24 bits (a relative error of 2^-24 of the cell's sum per add,
//! far below the noise of any sample count), but they depend on the order of the adds: frames
//! stay bitwise identical for any thread count because the order is fixed by the block alone
//! (`reuse::shade::block_side` takes the resolution, not the thread count; a block's splats are
//! made in one order, and its window grows the same way). A splat outside the window, or one
//! whose sum would leave the f32 range, goes to the frame directly, rounded on its own.
use super::tiles::Tile;
use super::FrameAccum;
use crate::sampling::mix64;
use glam::Vec3;
use std::sync::atomic::{AtomicU32, Ordering::Relaxed};

/// Pixels of margin around the block that a window starts with, and that it grows by beyond a
/// splat that falls outside it: the reprojected samples of a group's frames land near their
/// native pixel, farther the farther apart the frames are and the faster the camera moves.
pub const MARGIN: u32 = 8;

/// The most pixels a window grows to (128 x 128); splats beyond go to the frame directly. A
/// worker holds one window per frame of the group: at most `n_f` x 16384 x 32 bytes (`mis-cv`
/// where a frame's splats go to both folds; 16 where they go to one, as in most frames; 12 for
/// `mis-exact`), 17 MB at n_f = 33; on `vase` they grow to about 4400 pixels.
pub const MAX_PIXELS: usize = 1 << 14;

/// A window of one frame's sums, private to one worker.
pub struct LocalFilm<'a> {
    film: &'a FrameAccum,
    /// The window: its top-left pixel and size, inside the frame.
    x0: u32,
    y0: u32,
    w: u32,
    h: u32,
    /// The folds the window holds: `folds` of them from `fold0` (all the frame's, or the one
    /// a group's splats go to); a splat into another goes to the frame directly.
    fold0: usize,
    folds: usize,
    /// Cells per window pixel: the RGB sums of each fold held, then one weight sum per fold
    /// held (the control variate's), in the frame's order; in the splats' units (the frame
    /// divides by its layout's unit when it rounds them).
    rgb: usize,
    cells_px: usize,
    cells: Vec<f32>,
    /// What the flush's rounding dither is hashed from, with the pixel (`new`).
    key: u64,
    /// `1 / width` of the frame (`column_row`).
    inv_width: f64,
    /// Per window pixel: samples landed (where the layout keeps them), reuses tried and lost
    /// (where it keeps those).
    counts_px: usize,
    counts: Vec<u32>,
    /// Landed, tried and lost over the whole frame.
    totals: [u64; 3],
}

impl<'a> LocalFilm<'a> {
    /// An empty window of `film` around `tile` (a block of tiles, grown by `MARGIN`, clipped
    /// to the frame), holding every fold of the frame's sums, or only `fold` (`Some`): a group
    /// whose splats into the frame all go to one of the control variate's folds needs no room
    /// for the other, and a window half the size stays in cache. `key` names the window among
    /// all those of the render (its group and block): the flush rounds pixel `i`'s sums with a
    /// dither hashed from `key`, the frame and `i`, so that no two windows round alike.
    pub fn new(
        film: &'a FrameAccum,
        (tx0, ty0, tx1, ty1): Tile,
        fold: Option<usize>,
        key: u64,
    ) -> LocalFilm<'a> {
        let (fw, fh) = (film.view.width, film.view.height);
        let x0 = tx0.saturating_sub(MARGIN);
        let y0 = ty0.saturating_sub(MARGIN);
        let w = (tx1 + MARGIN).min(fw).saturating_sub(x0);
        let h = (ty1 + MARGIN).min(fh).saturating_sub(y0);
        let all = film.layout.norm.folds();
        let (fold0, folds) = match fold {
            Some(f) if f < all => (f, 1),
            _ => (0, all),
        };
        let rgb = 3 * folds;
        let cells_px = rgb
            + if film.layout.weight_cells() > 0 {
                folds
            } else {
                0
            };
        let counts_px = film.layout.count_cells();
        let px = (w * h) as usize;
        LocalFilm {
            film,
            x0,
            y0,
            w,
            h,
            fold0,
            folds,
            rgb,
            cells_px,
            cells: vec![0.0; px * cells_px],
            key: mix64(key ^ film.frame() as u64),
            inv_width: 1.0 / fw as f64,
            counts_px,
            counts: vec![0; px * counts_px],
            totals: [0; 3],
        }
    }

    pub fn film(&self) -> &'a FrameAccum {
        self.film
    }

    /// The window pixel of frame pixel `i`: the window grows to hold it (by at least `MARGIN`
    /// more on that side) unless it would pass `MAX_PIXELS`; then `None`.
    #[inline]
    fn local(&mut self, i: usize) -> Option<usize> {
        let (x, y) = self.column_row(i as u32);
        if let Some(l) = self.inside(x, y) {
            return Some(l);
        }
        self.grow(x, y)?;
        self.inside(x, y)
    }

    /// The column and row of frame pixel `i`, `(i mod width, i / width)`, by a multiplication
    /// with the width's reciprocal, exact for every frame (`check_resolution`: at most 2^28
    /// pixels): `(i + 1/2) / width` lies at least `1 / (2 width)` from an integer, and the
    /// product's rounding error is at most about `(i / width) 2^-52`, below that margin by a
    /// factor of `2^-23` or less for `i < 2^28`. A 32-bit division here was a tenth of a
    /// reuse's own instructions, and its latency in every splat's path.
    #[inline]
    fn column_row(&self, i: u32) -> (u32, u32) {
        column_row(i, self.film.view.width, self.inv_width)
    }

    /// The window pixel of frame pixel (x, y), if the window holds it.
    #[inline]
    fn inside(&self, x: u32, y: u32) -> Option<usize> {
        let (dx, dy) = (x.wrapping_sub(self.x0), y.wrapping_sub(self.y0));
        (dx < self.w && dy < self.h).then_some((dy * self.w + dx) as usize)
    }

    /// Grow the window to hold pixel (x, y) and `MARGIN` beyond it, keeping what it holds;
    /// `None` (and no change) if it would cover more than `MAX_PIXELS`.
    #[cold]
    fn grow(&mut self, x: u32, y: u32) -> Option<()> {
        let (fw, fh) = (self.film.view.width, self.film.view.height);
        let x0 = self.x0.min(x.saturating_sub(MARGIN));
        let y0 = self.y0.min(y.saturating_sub(MARGIN));
        let x1 = (self.x0 + self.w).max((x + 1 + MARGIN).min(fw));
        let y1 = (self.y0 + self.h).max((y + 1 + MARGIN).min(fh));
        let (w, h) = (x1 - x0, y1 - y0);
        if (w * h) as usize > MAX_PIXELS {
            return None;
        }
        let mut cells = vec![0.0; (w * h) as usize * self.cells_px];
        let mut counts = vec![0; (w * h) as usize * self.counts_px];
        for row in 0..self.h {
            let from = (row * self.w) as usize;
            let to = ((self.y0 + row - y0) * w + self.x0 - x0) as usize;
            let n = self.w as usize;
            cells[to * self.cells_px..(to + n) * self.cells_px]
                .copy_from_slice(&self.cells[from * self.cells_px..(from + n) * self.cells_px]);
            counts[to * self.counts_px..(to + n) * self.counts_px]
                .copy_from_slice(&self.counts[from * self.counts_px..(from + n) * self.counts_px]);
        }
        (self.x0, self.y0, self.w, self.h) = (x0, y0, w, h);
        (self.cells, self.counts) = (cells, counts);
        Some(())
    }

    /// Where a splat into pixel `i` of fold `fold` goes in the window: its window pixel and the
    /// fold's place among those the window holds; `None` where the window does not hold the
    /// fold, or cannot grow to the pixel (the splat goes to the frame directly).
    #[inline]
    fn place(&mut self, i: usize, fold: usize) -> Option<(usize, usize)> {
        let f = fold.wrapping_sub(self.fold0);
        if f >= self.folds {
            return None;
        }
        Some((self.local(i)?, f))
    }

    /// As `FrameAccum::splat`: add `v` to pixel `i` of fold `fold`; false (nothing added) if
    /// `v` is not finite. `key`: where the splat is rounded on its own (outside the window),
    /// its dither is `mix64(key)`.
    #[inline]
    pub fn splat(&mut self, i: usize, fold: usize, v: Vec3, key: u64) -> bool {
        match self.place(i, fold) {
            Some((l, f)) => self.splat_at(l, i, (fold, f), v, key),
            None => self.film.splat(i, fold, v, mix64(key)),
        }
    }

    /// One reuse into pixel `i`, which is found in the window once: `splat(i, fold, v, key)`,
    /// `splat_weight(i, fold, w, mix64(key))` unless `w` is NaN (no weight), and with `count`,
    /// `land(i, 1)` and `try_reuse(i, false)`. Returns what `splat` returns.
    #[inline]
    pub fn reuse(&mut self, i: usize, fold: usize, v: Vec3, w: f32, key: u64, count: bool) -> bool {
        let Some((l, f)) = self.place(i, fold) else {
            if count {
                self.film.land(i, 1);
                self.film.try_reuse(i, false);
            }
            let dither = mix64(key);
            if !w.is_nan() {
                self.film.splat_weight(i, fold, w, mix64(dither));
            }
            return self.film.splat(i, fold, v, dither);
        };
        if count {
            self.land_at(l, 1);
            self.try_reuse_at(l, false);
        }
        if !w.is_nan() {
            self.weight_at(l, i, (fold, f), w, mix64(key));
        }
        self.splat_at(l, i, (fold, f), v, key)
    }

    /// As `FrameAccum::splat_weight`; `key` as in `splat`.
    #[inline]
    pub fn splat_weight(&mut self, i: usize, fold: usize, w: f32, key: u64) {
        if self.film.weights.is_none() {
            return;
        }
        match self.place(i, fold) {
            Some((l, f)) => self.weight_at(l, i, (fold, f), w, key),
            None => self.film.splat_weight(i, fold, w, mix64(key)),
        }
    }

    /// As `FrameAccum::land`.
    #[inline]
    pub fn land(&mut self, i: usize, n: u32) {
        if self.film.landed.is_none() {
            return;
        }
        match self.local(i) {
            Some(l) => self.land_at(l, n),
            None => self.film.land(i, n),
        }
    }

    /// As `FrameAccum::try_reuse`.
    #[inline]
    pub fn try_reuse(&mut self, i: usize, lost: bool) {
        if self.film.loss.is_none() {
            return;
        }
        match self.local(i) {
            Some(l) => self.try_reuse_at(l, lost),
            None => self.film.try_reuse(i, lost),
        }
    }

    /// `splat` into window pixel `l`, which is frame pixel `i`, of fold `fold`, the window's
    /// `f`th.
    #[inline(always)]
    fn splat_at(
        &mut self,
        l: usize,
        i: usize,
        (fold, f): (usize, usize),
        v: Vec3,
        key: u64,
    ) -> bool {
        let cell = l * self.cells_px + 3 * f;
        let cells = &mut self.cells[cell..cell + 3];
        let s = [cells[0] + v.x, cells[1] + v.y, cells[2] + v.z];
        // Finite where every channel is: an infinity or a NaN in any makes the total one.
        if (s[0] + s[1] + s[2]).is_finite() {
            cells.copy_from_slice(&s);
            return true;
        }
        // `v` is not finite (the frame refuses it), or the sums would leave the f32 range (or
        // their total would): `v` to the frame, rounded on its own.
        self.film.splat(i, fold, v, mix64(key))
    }

    /// `splat_weight` into window pixel `l`, which is frame pixel `i`, of fold `fold`, the
    /// window's `f`th (nothing where the film keeps no weights).
    #[inline]
    fn weight_at(&mut self, l: usize, i: usize, (fold, f): (usize, usize), w: f32, key: u64) {
        if self.film.weights.is_some() {
            let cell = &mut self.cells[l * self.cells_px + self.rgb + f];
            let s = *cell + w;
            if s.is_finite() {
                *cell = s;
            } else {
                self.film.splat_weight(i, fold, w, mix64(key));
            }
        }
    }

    /// `land` in window pixel `l` (nothing where the film keeps no counts).
    #[inline]
    fn land_at(&mut self, l: usize, n: u32) {
        if self.film.landed.is_some() {
            let c = &mut self.counts[l * self.counts_px];
            *c = c.wrapping_add(n);
        }
    }

    /// `try_reuse` in window pixel `l` (nothing where the film keeps no losses).
    #[inline]
    fn try_reuse_at(&mut self, l: usize, lost: bool) {
        if self.film.loss.is_some() {
            let at = l * self.counts_px + usize::from(self.film.landed.is_some());
            self.counts[at] = self.counts[at].wrapping_add(1);
            self.counts[at + 1] = self.counts[at + 1].wrapping_add(u32::from(lost));
        }
    }

    /// As `FrameAccum::add_counts`.
    pub fn add_counts(&mut self, landed: u64, tried: u64, lost: u64) {
        self.totals[0] += landed;
        self.totals[1] += tried;
        self.totals[2] += lost;
    }

    /// Add everything the window holds into the frame.
    pub fn flush(self) {
        let film = self.film;
        let fw = film.view.width as usize;
        let add_count = |v: &[AtomicU32], i: usize, n: u32| {
            if n != 0 {
                v[i].fetch_add(n, Relaxed);
            }
        };
        for l in 0..(self.w * self.h) as usize {
            let cells = &self.cells[l * self.cells_px..(l + 1) * self.cells_px];
            let counts = &self.counts[l * self.counts_px..(l + 1) * self.counts_px];
            let (dx, dy) = (l % self.w as usize, l / self.w as usize);
            let i = (self.y0 as usize + dy) * fw + self.x0 as usize + dx;
            // Each sum rounded to the frame's fixed point as a splat is, with a dither of this
            // window, pixel and fold (and its hash for the weight); a zero sum rounds to zero
            // whatever the dither.
            let dither = |f: usize| mix64(self.key ^ i as u64 ^ ((f as u64) << 48));
            // The folds held are consecutive in the frame's cells too.
            let fold_base = film.rgb_cell(i, self.fold0);
            for (f, rgb) in cells[..self.rgb].chunks_exact(3).enumerate() {
                let v = Vec3::from_slice(rgb);
                if v == Vec3::ZERO {
                    continue;
                }
                // The window's sums are finite (`splat_at`).
                let q = film.quantize_rgb(v, dither(f)).unwrap_or_default();
                for (c, q) in q.into_iter().enumerate() {
                    if q != 0 {
                        film.sum.add(fold_base + 3 * f + c, q);
                    }
                }
            }
            // (Weight cells exist only where the frame keeps weights.)
            for (f, &w) in cells[self.rgb..].iter().enumerate() {
                if w != 0.0 {
                    film.splat_weight(i, self.fold0 + f, w, mix64(dither(f)));
                }
            }
            let mut counts = counts.iter().copied();
            if let Some(landed) = &film.landed {
                add_count(landed, i, counts.next().unwrap_or(0));
            }
            if let Some((tried, lost)) = &film.loss {
                add_count(tried, i, counts.next().unwrap_or(0));
                add_count(lost, i, counts.next().unwrap_or(0));
            }
        }
        let [landed, tried, lost] = self.totals;
        film.add_counts(landed, tried, lost);
    }
}

/// `(i mod width, i / width)` with `inv_width = 1 / width` (`LocalFilm::column_row`), for
/// `i` and `width` below 2^28.
#[inline]
fn column_row(i: u32, width: u32, inv_width: f64) -> (u32, u32) {
    let y = ((i as f64 + 0.5) * inv_width) as u32;
    (i - y * width, y)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::film::{Layout, Norm, View};
    use crate::sampling::mix64;

    fn film(norm: Norm, aov: bool) -> FrameAccum {
        let view = View {
            frame: 3,
            width: 300,
            height: 250,
            world_to_camera: [0.0; 16],
            world_to_ndc: [0.0; 16],
        };
        let layout = Layout {
            unit: 1.0,
            norm,
            landed: aov || norm == Norm::Count,
            loss: aov,
        };
        FrameAccum::new(view, layout)
    }

    #[test]
    fn column_and_row_by_the_reciprocal_are_exact() {
        // Every pixel index of a frame of 2^28 pixels for two widths, and the indices around
        // every multiple of the width for others up to a row of 2^28 pixels.
        let check = |i: u32, w: u32| {
            assert_eq!(
                column_row(i, w, 1.0 / w as f64),
                (i % w, i / w),
                "{i} / {w}"
            );
        };
        for w in [3, 1920] {
            for i in 0..(1u32 << 28) {
                check(i, w);
            }
        }
        for w in [
            1,
            2,
            7,
            320,
            4096,
            65535,
            65537,
            1 << 20,
            (1 << 28) - 1,
            1 << 28,
        ] {
            let mut m = 0u64;
            while m < 1 << 28 {
                for i in [m.saturating_sub(1), m, m + 1] {
                    if i < 1 << 28 {
                        check(i as u32, w);
                    }
                }
                m += w as u64 * (1 + m / (w as u64 * 4096));
            }
        }
    }

    /// Per cell of a frame's sums: the exact total of what was splatted into it (in steps),
    /// the splats, and the sum of their sizes (in steps).
    #[derive(Clone, Copy, Default)]
    struct Exact {
        total: f64,
        n: f64,
        size: f64,
    }

    impl Exact {
        fn add(&mut self, v: f32) {
            let v = v as f64 * crate::film::fixed::FIXED;
            self.total += v;
            self.n += 1.0;
            self.size += v.abs();
        }

        /// How far two roundings of the same splats may lie apart: a step per splat rounded
        /// on its own (at most all of them) and one per window flush, and the float sums'
        /// rounding, 2^-24 of the sum's size per add (twice over).
        fn tolerance(&self) -> f64 {
            2.0 * self.n + 2.0 + 2.0 * self.n * self.size / (1u64 << 24) as f64
        }
    }

    #[test]
    fn a_window_sums_what_direct_splats_sum() {
        // Splats inside the window of a tile, outside it (it grows) and beyond the largest
        // window (a frame of 75000 pixels), some as large as 1e9: the totals of every cell agree
        // with splats made directly into the frame within their roundings (a splat lost, added
        // twice or to another pixel, fold or channel is thousands of steps off), the counts
        // exactly, and so do non-finite splats, which neither adds.
        // A window of the control variate's frame holds both folds, or one (the other's splats
        // go to the frame directly).
        for (norm, aov, held) in [
            (Norm::Groups, false, None),
            (Norm::Count, true, None),
            (Norm::ControlVariate, true, None),
            (Norm::ControlVariate, true, Some(0)),
            (Norm::ControlVariate, false, Some(1)),
        ] {
            let (direct, windowed) = (film(norm, aov), film(norm, aov));
            let mut local = LocalFilm::new(&windowed, (16, 8, 32, 24), held, 7);
            let folds = norm.folds();
            let mut exact = vec![Exact::default(); direct.sum.len()];
            let mut exact_w =
                vec![Exact::default(); direct.weights.as_ref().map_or(0, |w| w.len())];
            for k in 0..200_000u64 {
                let h = mix64(k);
                // First inside the window it starts with (the tile and its margin), then around
                // it (it grows, on every side, with data in it), later now and then anywhere.
                let (x, y) = if k < 2000 {
                    (8 + h % 32, (h >> 8) % 32)
                } else if k % 8 == 0 && k > 5000 {
                    (h % 300, (h >> 16) % 250)
                } else {
                    (h % 60, (h >> 8) % 70)
                };
                let i = (y * 300 + x) as usize;
                let fold = (h >> 20) as usize % folds;
                let scale = match k % 100 {
                    1..=9 => 1500.0,
                    10 => 1e9,
                    _ => 1.0,
                };
                let v = Vec3::new(
                    (h >> 32) as f32 / u32::MAX as f32,
                    (h >> 40) as f32 / 1e7,
                    0.25,
                ) * scale;
                let d = mix64(h);
                let cell = 3 * (folds * i + fold);
                for c in 0..3 {
                    exact[cell + c].add(v[c]);
                }
                if k % 4 == 1 {
                    // One reuse at once, with and without its count and weight.
                    let (count, w) = (k % 8 == 1, if k % 12 == 1 { f32::NAN } else { v.y });
                    let ok = direct.splat(i, fold, v, d);
                    if !w.is_nan() {
                        direct.splat_weight(i, fold, w, mix64(d));
                        if !exact_w.is_empty() {
                            exact_w[2 * i + fold].add(w);
                        }
                    }
                    if count {
                        direct.land(i, 1);
                        direct.try_reuse(i, false);
                    }
                    assert_eq!(ok, local.reuse(i, fold, v, w, d, count));
                    continue;
                }
                assert_eq!(direct.splat(i, fold, v, d), local.splat(i, fold, v, d));
                direct.splat_weight(i, fold, v.x, d);
                local.splat_weight(i, fold, v.x, d);
                if !exact_w.is_empty() {
                    exact_w[2 * i + fold].add(v.x);
                }
                direct.land(i, 2);
                local.land(i, 2);
                direct.try_reuse(i, k % 3 == 0);
                local.try_reuse(i, k % 3 == 0);
            }
            let nan = Vec3::new(f32::NAN, 0.0, 0.0);
            assert!(!local.splat(20 * 300 + 20, 0, nan, 1));
            direct.splat_weight(20 * 300 + 21, 0, 0.5, mix64(1));
            if !exact_w.is_empty() {
                exact_w[2 * (20 * 300 + 21)].add(0.5);
            }
            assert!(!local.reuse(20 * 300 + 21, 0, nan, 0.5, 1, false));
            assert!(local.w * local.h > 32 * 32, "the window never grew");
            assert!((local.w * local.h) as usize <= MAX_PIXELS);
            direct.add_counts(5, 6, 7);
            local.add_counts(5, 6, 7);
            local.flush();
            let agree = |a: Vec<i64>, b: Vec<i64>, exact: &[Exact]| {
                assert_eq!(a.len(), b.len());
                for (c, ((a, b), e)) in a.into_iter().zip(b).zip(exact).enumerate() {
                    let off = (a - b).abs() as f64;
                    assert!(off <= e.tolerance(), "cell {c}: {a} against {b}");
                    assert!((b as f64 - e.total).abs() <= e.tolerance(), "cell {c}");
                }
            };
            agree(direct.sum.totals(), windowed.sum.totals(), &exact);
            assert_eq!(direct.weights.is_some(), windowed.weights.is_some());
            if let (Some(a), Some(b)) = (&direct.weights, &windowed.weights) {
                agree(a.totals(), b.totals(), &exact_w);
            }
            assert_eq!(direct.counts(), windowed.counts());
            assert_eq!(
                direct.landed_counts().map(|c| c.collect::<Vec<_>>()),
                windowed.landed_counts().map(|c| c.collect::<Vec<_>>())
            );
        }
    }

    /// The flush rounds a window's sums stochastically, with a dither of its own key: many
    /// windows that each hold a tenth of a step (and a third of one in a weight) in one pixel
    /// add up to what they hold, not to nothing (every window rounding down) nor to a step
    /// each (all rounding alike).
    #[test]
    fn a_flush_rounds_sums_below_one_step_without_bias() {
        let frame = film(Norm::ControlVariate, false);
        let step = 1.0 / crate::film::fixed::FIXED as f32;
        let windows = 20_000u64;
        for key in 0..windows {
            let mut local = LocalFilm::new(&frame, (0, 0, 16, 16), None, key);
            local.splat(5, 1, Vec3::new(0.1, 0.5, 0.9) * step, 0);
            local.splat_weight(5, 1, step / 3.0, 0);
            local.flush();
        }
        let rgb = &frame.sum.totals()[3 * (2 * 5 + 1)..][..3];
        let w = frame.weights.as_ref().unwrap().totals()[2 * 5 + 1];
        for (got, p) in rgb.iter().chain([&w]).zip([0.1, 0.5, 0.9, 1.0 / 3.0]) {
            // Binomial: `windows` roundings up with probability p; 5 standard deviations.
            let n = windows as f64;
            let sd = (n * p * (1.0 - p)).sqrt();
            assert!(
                (*got as f64 - n * p).abs() < 5.0 * sd,
                "{got} steps, expected {}",
                n * p
            );
        }
    }
}
