//! A resumable run in progress: the units it covers, how far it got, its counters and clock,
//! its checkpoints, and how a signal stops it.
use crate::film::{Clock, FrameAccum, Sink};
use crate::state::checkpoint::{Checkpointer, Counters};
use anyhow::Result;
use std::ops::RangeInclusive;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;

/// Runs in this process that are inside their unit loop and watch their interrupt flag.
static GRACEFUL: AtomicUsize = AtomicUsize::new(0);

/// Whether a first signal can stop this process gracefully (a render inside its loop of groups
/// or frames, which stops at the next boundary after a checkpoint). Elsewhere (loading, merge,
/// bench, reference, compare, writing statistics) a signal stops the process at once
/// (`util::fs::exit_removing_temporaries`).
pub fn stops_gracefully() -> bool {
    GRACEFUL.load(Ordering::SeqCst) > 0
}

/// Held by a frame loop for as long as it watches its run's interrupt flag.
pub struct Graceful(bool);

impl Graceful {
    pub fn begin(run: &Run) -> Graceful {
        let watched = run.interrupt.is_some();
        if watched {
            GRACEFUL.fetch_add(1, Ordering::SeqCst);
        }
        Graceful(watched)
    }
}

impl Drop for Graceful {
    fn drop(&mut self) {
        if self.0 {
            GRACEFUL.fetch_sub(1, Ordering::SeqCst);
        }
    }
}

pub struct Run {
    pub ckpt: Checkpointer,
    pub units: RangeInclusive<u32>,
    /// The first unit not yet rendered.
    pub next: u32,
    pub counters: Counters,
    /// Set by a signal handler: stop at the next unit boundary, after a checkpoint.
    pub interrupt: Option<Arc<AtomicBool>>,
    /// Each frame written so far, this process and the ones it resumed, and its file's hash
    /// (`Trailer::frame_digests`).
    pub frame_digests: Vec<(u32, u64)>,
    clock: Clock,
}

impl Run {
    /// A run of `units` from `next` on, with the counters of the processes before it.
    pub fn new(
        ckpt: Checkpointer,
        units: RangeInclusive<u32>,
        next: u32,
        counters: Counters,
    ) -> Run {
        Run {
            ckpt,
            next,
            units,
            clock: Clock::start(counters.seconds),
            counters,
            interrupt: None,
            frame_digests: Vec::new(),
        }
    }

    /// A run in memory: no checkpoints, no chunk, nothing before it.
    pub fn in_memory(units: RangeInclusive<u32>) -> Run {
        let next = *units.start();
        Run::new(Checkpointer::none(), units, next, Counters::default())
    }

    pub fn interrupted(&self) -> bool {
        self.interrupt
            .as_ref()
            .is_some_and(|f| f.load(std::sync::atomic::Ordering::Relaxed))
    }

    /// Seconds of rendering, this process and the ones it resumed.
    pub fn seconds(&self) -> f64 {
        self.clock.seconds()
    }

    /// Checkpoint at `next` (the first unit still to render), with the frames in flight
    /// `active`, once every frame handed to `sink` is written: a checkpoint never counts a
    /// frame whose file is not whole.
    pub fn save<'a>(
        &mut self,
        sink: &mut dyn Sink,
        active: impl IntoIterator<Item = &'a FrameAccum>,
    ) -> Result<()> {
        self.frame_digests.extend(sink.sync()?);
        self.counters.seconds = self.seconds();
        let digests = &self.frame_digests;
        self.ckpt.save(self.next, &self.counters, active, digests)
    }

    /// The run is complete: the chunk's partial file, if any (the checkpoint is removed).
    pub fn finish(&mut self) -> Result<Option<PathBuf>> {
        self.counters.seconds = self.seconds();
        self.ckpt.finish(self.next, &self.counters)
    }

    /// Frames finished so far, this process and the ones it resumed: every unit retires its
    /// first frame (the last unit retires the rest, but a run stopped early never did it).
    pub fn frames_retired(&self) -> u32 {
        self.next - self.units.start()
    }
}

/// A render stopped by a signal (`RenderOptions::interrupt`) after a checkpoint; `--resume`
/// continues it.
#[derive(Debug)]
pub struct Interrupted {
    /// The checkpoint folder, if checkpoints were on.
    pub checkpoint: Option<PathBuf>,
    /// Frames finished and written (or, for a chunk, retired to its log) so far.
    pub frames_done: u32,
}

impl std::fmt::Display for Interrupted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.checkpoint {
            Some(d) => write!(
                f,
                "interrupted after {} finished frame(s); the checkpoint is in {}",
                self.frames_done,
                d.display()
            ),
            None => write!(
                f,
                "interrupted after {} finished frame(s), without a checkpoint",
                self.frames_done
            ),
        }
    }
}

impl std::error::Error for Interrupted {}
