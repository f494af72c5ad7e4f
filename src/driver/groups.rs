//! The reuse methods' frame loop: groups of `n_f` frames sliding one frame at a time.
//!
//! Group `g` is frames `g..g + n_f`. Its frames' accumulators stay in memory while any group
//! still to render contains them; a frame that no later group touches is developed and handed
//! to the sink as soon as its last group is done (or, for a chunk, its share is appended to the
//! chunk's log). Memory therefore grows with width x height x n_f: 12 bytes per pixel per frame
//! in flight (16 for the methods that average by count, 24 with `--aov`).
use super::progress_bar;
use super::run::{Graceful, Run};
use crate::film::tiles::{tiles, tiles_in};
use crate::film::{develop, FrameAccum, Layout, Sink, View};
use crate::integrator::{Integrator, RayCounts, Tally};
use crate::reuse::adaptive::adaptive_counts;
use crate::reuse::shade::{block_side, shade_block, Target};
use crate::reuse::Params;
use crate::state::Record;
use anyhow::{bail, Result};
use rayon::prelude::*;
use std::collections::VecDeque;
use std::ops::RangeInclusive;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};

/// What the group loop needs besides the estimator's parameters.
pub struct GroupSettings {
    pub params: Params,
    pub window: u32,
    pub aov: bool,
    /// `--adaptive` target share of `n_f n_r`.
    pub adaptive: Option<f32>,
    pub width: u32,
    pub height: u32,
    pub progress: bool,
    /// Every group of the run, of which `run.units` may be a chunk's share: whether a frame is
    /// reached by one group only depends on the whole run (`Method::sample_folds`).
    pub all_groups: RangeInclusive<u32>,
    /// What one unit of the films' sums is worth in radiance (`reuse::radiance_unit`).
    pub radiance_unit: f32,
}

/// How many groups of `all` (first frames, `n_f` frames each) contain frame `f`.
fn coverage(all: &RangeInclusive<u32>, n_f: u32, f: u32) -> u32 {
    let first = (f + 1).saturating_sub(n_f).max(*all.start());
    let last = f.min(*all.end());
    (last + 1).saturating_sub(first)
}

/// The groups `run.units` from `run.next` on, starting from the frames in flight `active` (a
/// resumed checkpoint's), writing checkpoints as they fall due. Returns false if `run.interrupt`
/// stopped it (after a checkpoint at the last finished group).
pub fn run_groups(
    integrator: &Integrator,
    s: &GroupSettings,
    run: &mut Run,
    active: Vec<FrameAccum>,
    sink: &mut dyn Sink,
) -> Result<bool> {
    let scene = integrator.scene;
    let (w, h, n_f) = (s.width, s.height, s.window);
    let layout: Layout = s
        .params
        .method
        .layout(s.params.spp, n_f, s.aov, s.radiance_unit);
    let sample_folds = s
        .params
        .method
        .sample_folds(s.params.spp, n_f, s.adaptive.is_some());
    let last_group = *run.units.end();
    let chunked = run.ckpt.chunked();
    let pb = progress_bar(
        s.progress,
        (last_group + 1 - run.units.start()) as u64,
        "groups",
    );
    pb.set_position((run.next - run.units.start()) as u64);
    // A resumed checkpoint holds exactly the frames the groups before `run.next` left in
    // flight, each with the groups that contain it.
    let u0 = *run.units.start();
    let in_flight: Vec<u32> = if run.next > u0 {
        (run.next..run.next + n_f - 1).collect()
    } else {
        vec![]
    };
    let frames: Vec<u32> = active.iter().map(FrameAccum::frame).collect();
    if frames != in_flight {
        bail!(
            "the checkpoint holds frames {frames:?} in flight where the render needs {in_flight:?}; \
             it is damaged: delete it to start over"
        );
    }
    for a in &active {
        let f = a.frame();
        if a.layout != layout
            || (a.view.width, a.view.height) != (w, h)
            || a.groups != groups_holding(f, u0, run.next - 1, n_f)
        {
            bail!(
                "frame {f}: the checkpoint's accumulator does not fit these settings (it is \
                 damaged, or of another render): delete it to start over"
            );
        }
    }
    let mut active: VecDeque<(crate::camera::Camera, FrameAccum)> = active
        .into_iter()
        .map(|a| (scene.camera(a.frame(), w, h), a))
        .collect();
    let nonfinite = AtomicU64::new(0);
    let tile_list = tiles(w, h);
    // The reuse kernel's unit of parallel work (`shade_block`); the adaptive pilot's is a tile.
    let blocks = tiles_in((0, 0, w, h), block_side(w, h));
    let mut written = 0;
    let _graceful = Graceful::begin(run);
    for g0 in run.next..=last_group {
        if run.interrupted() {
            run.save(sink, active.iter().map(|(_, a)| a))?;
            pb.abandon();
            return Ok(false);
        }
        // The group's frames: keep those still active, add the new ones.
        while active.back().is_none_or(|(_, a)| a.frame() < g0 + n_f - 1) {
            let f = active.back().map_or(g0, |(_, a)| a.frame() + 1);
            let cam = scene.camera(f, w, h);
            let film = FrameAccum::new(View::of(f, &cam), layout);
            active.push_back((cam, film));
        }
        let group: Vec<Target> = active
            .iter()
            .filter(|(_, a)| a.frame() >= g0 && a.frame() < g0 + n_f)
            .map(|(cam, film)| Target {
                cam,
                film,
                split: sample_folds.is_some() && coverage(&s.all_groups, n_f, film.frame()) == 1,
            })
            .collect();
        debug_assert_eq!(group.len(), n_f as usize);
        let (native_counts, pilot_rays) = match s.adaptive {
            Some(target) => {
                // Pilot rays per (frame of the group, tile).
                let work: Vec<(usize, usize)> = (0..group.len())
                    .flat_map(|m| (0..tile_list.len()).map(move |t| (m, t)))
                    .collect();
                let (c, r) =
                    adaptive_counts(integrator, &group, s.params.spp, target, &work, &tile_list);
                (Some(c), r)
            }
            None => (None, RayCounts::default()),
        };
        run.counters.counts.add(&pilot_rays);
        let group_counts: RayCounts = blocks
            .par_iter()
            .map(|&block| {
                let mut tally = Tally::default();
                let bad = shade_block(
                    integrator,
                    &s.params,
                    &group,
                    block,
                    g0,
                    native_counts.as_deref(),
                    &mut tally,
                );
                nonfinite.fetch_add(bad, Relaxed);
                tally.counts
            })
            .reduce(RayCounts::default, |mut a, b| {
                a.add(&b);
                a
            });
        drop(group);
        run.counters.counts.add(&group_counts);
        run.counters.nonfinite_samples += nonfinite.swap(0, Relaxed);
        for (_, a) in active
            .iter_mut()
            .filter(|(_, a)| a.frame() >= g0 && a.frame() < g0 + n_f)
        {
            a.groups[(g0 % 2) as usize] += 1;
        }
        // Frames no later group contains: g0 itself, or every remaining one after the last group.
        while active
            .front()
            .is_some_and(|(_, a)| a.frame() == g0 || g0 == last_group)
        {
            let (_, a) = active.pop_front().unwrap();
            run.counters.per_frame.push(a.reuse());
            if chunked {
                run.ckpt.retire(&Record::Sums(Box::new(a)))?;
            } else {
                let d = develop(&a, sample_folds);
                drop(a);
                run.counters.nonfinite_pixels += d.nonfinite;
                if d.is_black() {
                    run.counters.black_frames.push(d.view.frame);
                }
                sink.put(d)?;
            }
            written += 1;
        }
        run.next = g0 + 1;
        if g0 < last_group && run.ckpt.due() {
            run.save(sink, active.iter().map(|(_, a)| a))?;
        }
        pb.set_message(format!(
            "| {written} frames {}",
            if chunked { "retired" } else { "written" }
        ));
        pb.inc(1);
    }
    // Every frame on disk before the loop (and its graceful stop) ends.
    run.frame_digests.extend(sink.sync()?);
    pb.finish_and_clear();
    Ok(true)
}

/// The groups of `n_f` frames, `first..=last_group` by their first frames, that hold frame `f`,
/// by the parity of their first frames (`FrameAccum::groups`, the control variate's folds): what
/// a finished frame of a merge, or a frame in flight in a checkpoint, must have counted.
pub(super) fn groups_holding(f: u32, first: u32, last_group: u32, n_f: u32) -> [u32; 2] {
    let lo = (f + 1).saturating_sub(n_f).max(first);
    let n = f.min(last_group) + 1 - lo;
    let odd = (lo + n) / 2 - lo / 2;
    [n - odd, odd]
}

#[cfg(test)]
mod tests {
    use super::coverage;

    #[test]
    fn coverage_counts_the_groups_that_contain_a_frame() {
        // Against enumerating the groups: ranges of one group, of a few, windows of one.
        for (all, n_f) in [(0..=8, 5), (3..=3, 7), (10..=30, 1), (2..=4, 9)] {
            for f in 0..all.end() + n_f + 2 {
                let brute = all.clone().filter(|g| (*g..*g + n_f).contains(&f)).count();
                assert_eq!(coverage(&all, n_f, f) as usize, brute, "{all:?} {n_f} {f}");
            }
        }
        assert_eq!(coverage(&(0..=8), 5, 0), 1);
        assert_eq!(coverage(&(0..=8), 5, 12), 1);
        assert_eq!(coverage(&(0..=8), 5, 6), 5);
    }
}
