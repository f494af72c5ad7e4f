//! A worker's private share of one frame's sums, over a window of pixels around the tile it
//! works on, added into the frame's shared accumulator once at the end (`flush`).
//!
//! Why: a reuse splats into the film of another frame, which other workers splat into too, so a
//! direct splat is three or four atomic read-modify-writes on cells that are often not in cache
//! (`perf` put them at 18% of a `mis-cv` render at n_f = 17). The samples a worker reuses into
//! one frame land close together, around the worker's tile (the frames of a group see the scene
//! from nearby eyes), and a window pixel receives several of them: summed here with plain
//! integer adds, the frame sees one atomic add per touched cell instead of one per splat.
//!
//! Bitwise: every splat is quantised exactly as `FrameAccum::splat` quantises it (the same
//! dither, the same rounding), and integer addition is associative, so the frame's totals (and
//! with them every developed pixel) are the same to the bit as with direct splats, for any
//! window and any order. A splat outside the window goes to the frame directly; a window cell
//! that would leave the i32 range hands its sum to the frame first.
use super::fixed::FixedSums;
use super::tiles::Tile;
use super::FrameAccum;
use glam::Vec3;
use std::sync::atomic::{AtomicU32, Ordering::Relaxed};

/// Pixels of margin around the tile that a window covers: reprojected samples of a group's
/// frames mostly land within a few pixels of where their native pixel is.
pub const MARGIN: u32 = 8;

/// A window of one frame's sums, private to one worker.
pub struct LocalFilm<'a> {
    film: &'a FrameAccum,
    /// The window: its top-left pixel and size, inside the frame.
    x0: u32,
    y0: u32,
    w: u32,
    h: u32,
    /// Cells per window pixel: the RGB cells of every fold, then one weight cell per fold (the
    /// control variate's), in the frame's order.
    rgb: usize,
    cells_px: usize,
    cells: Vec<i32>,
    /// Per window pixel: samples landed (where the layout keeps them), reuses tried and lost
    /// (where it keeps those).
    counts_px: usize,
    counts: Vec<u32>,
    /// Landed, tried and lost over the whole frame.
    totals: [u64; 3],
}

impl<'a> LocalFilm<'a> {
    /// An empty window of `film` around `tile` (grown by `MARGIN`, clipped to the frame).
    pub fn new(film: &'a FrameAccum, (tx0, ty0, tx1, ty1): Tile) -> LocalFilm<'a> {
        let (fw, fh) = (film.view.width, film.view.height);
        let x0 = tx0.saturating_sub(MARGIN);
        let y0 = ty0.saturating_sub(MARGIN);
        let w = (tx1 + MARGIN).min(fw).saturating_sub(x0);
        let h = (ty1 + MARGIN).min(fh).saturating_sub(y0);
        let folds = film.layout.norm.folds();
        let rgb = 3 * folds;
        let cells_px = rgb + if film.weights.is_some() { folds } else { 0 };
        let counts_px =
            usize::from(film.landed.is_some()) + if film.loss.is_some() { 2 } else { 0 };
        let px = (w * h) as usize;
        LocalFilm {
            film,
            x0,
            y0,
            w,
            h,
            rgb,
            cells_px,
            cells: vec![0; px * cells_px],
            counts_px,
            counts: vec![0; px * counts_px],
            totals: [0; 3],
        }
    }

    pub fn film(&self) -> &'a FrameAccum {
        self.film
    }

    /// The window pixel of frame pixel `i`, if the window holds it.
    #[inline]
    fn local(&self, i: usize) -> Option<usize> {
        let fw = self.film.view.width as usize;
        let (x, y) = ((i % fw) as u32, (i / fw) as u32);
        let (dx, dy) = (x.wrapping_sub(self.x0), y.wrapping_sub(self.y0));
        (dx < self.w && dy < self.h).then(|| (dy * self.w + dx) as usize)
    }

    /// Add the quantised `q` to window cell `cell`, whose cell in `sums` is `global`.
    #[inline]
    fn add(cells: &mut [i32], cell: usize, sums: &FixedSums, global: usize, q: i64) {
        let c = &mut cells[cell];
        match i32::try_from(q).ok().and_then(|q| c.checked_add(q)) {
            Some(s) => *c = s,
            None => {
                sums.add(global, *c as i64 + q);
                *c = 0;
            }
        }
    }

    /// As `FrameAccum::splat`: add `v` to pixel `i` of fold `fold`; false (nothing added) if
    /// `v` is not finite.
    #[inline]
    pub fn splat(&mut self, i: usize, fold: usize, v: Vec3, dither: u64) -> bool {
        let Some(l) = self.local(i) else {
            return self.film.splat(i, fold, v, dither);
        };
        let Some(q) = self.film.quantize_rgb(v, dither) else {
            return false;
        };
        let base = self.film.rgb_cell(i, fold);
        let cell = l * self.cells_px + 3 * fold;
        for (c, q) in q.into_iter().enumerate() {
            Self::add(&mut self.cells, cell + c, &self.film.sum, base + c, q);
        }
        true
    }

    /// As `FrameAccum::splat_weight`.
    #[inline]
    pub fn splat_weight(&mut self, i: usize, fold: usize, w: f32, dither: u64) {
        let Some(ws) = &self.film.weights else {
            return;
        };
        let Some(l) = self.local(i) else {
            return self.film.splat_weight(i, fold, w, dither);
        };
        let q = FrameAccum::quantize_weight(w, dither);
        let cell = l * self.cells_px + self.rgb + fold;
        Self::add(&mut self.cells, cell, ws, 2 * i + fold, q);
    }

    /// As `FrameAccum::land`.
    #[inline]
    pub fn land(&mut self, i: usize, n: u32) {
        if self.film.landed.is_none() {
            return;
        }
        match self.local(i) {
            Some(l) => {
                let c = &mut self.counts[l * self.counts_px];
                *c = c.wrapping_add(n);
            }
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
            Some(l) => {
                let at = l * self.counts_px + usize::from(self.film.landed.is_some());
                self.counts[at] = self.counts[at].wrapping_add(1);
                self.counts[at + 1] = self.counts[at + 1].wrapping_add(u32::from(lost));
            }
            None => self.film.try_reuse(i, lost),
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
            let fold_base = film.rgb_cell(i, 0);
            for (c, &q) in cells[..self.rgb].iter().enumerate() {
                if q != 0 {
                    film.sum.add(fold_base + c, q as i64);
                }
            }
            if let Some(ws) = &film.weights {
                for (f, &q) in cells[self.rgb..].iter().enumerate() {
                    if q != 0 {
                        ws.add(2 * i + f, q as i64);
                    }
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
