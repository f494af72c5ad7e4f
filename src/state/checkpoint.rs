//! Checkpoints and a chunk's log of finished frames, and the counters a run carries across a
//! resume.
//!
//! Atomicity: a checkpoint is written to a temporary name, flushed to disk and renamed over the
//! previous one, so a kill at any moment (even SIGKILL) leaves either the old or the new
//! checkpoint. A chunk's finished records go to an append-only log beside its partial file; the
//! checkpoint remembers the log's length, a resume truncates the log to it, and the finished
//! chunk appends the trailer and renames the log to the partial file.
//!
//! Where they live, for `--out DIR/NAME_####.ext`: the checkpoint in `DIR/NAME.checkpoint/state`
//! (`DIR/NAME.chunk-K-of-N.checkpoint/` for a chunk), a chunk's partial in
//! `DIR/NAME.chunk-K-of-N.partial` (`key`). A render that finishes removes its checkpoint.
use super::key::{checkpoint_named, partial_path, RunKey};
use super::{
    accum_bytes, pixels_bytes, read_record, write_accum, write_pixels, write_state, write_trailer,
    Kind, Record, StateFile, Trailer,
};
use crate::film::{FrameAccum, FrameReuse, Norm};
use crate::integrator::RayCounts;
use crate::util::fs::{check_writable_dir, open_own_file, remove_stale_tmp, MadeFolder};
use anyhow::{anyhow, bail, Context, Result};
use serde::{Deserialize, Serialize};
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The counters a render carries across a resume (what `--stats` reports). Each is counted once:
/// the run's reuse figures are the sums of `per_frame`.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Counters {
    pub counts: RayCounts,
    pub nonfinite_samples: u64,
    pub nonfinite_pixels: u64,
    /// Frames written black in every pixel (absent in older files: none).
    #[serde(default)]
    pub black_frames: Vec<u32>,
    /// Reuse figures of every frame retired so far (for a chunk, its share of each frame).
    pub per_frame: Vec<FrameReuse>,
    /// Seconds of rendering before this process started.
    pub seconds: f64,
}

impl Counters {
    /// Reuses tried and lost over the frames retired so far.
    pub fn tried_lost(&self) -> (u64, u64) {
        self.per_frame
            .iter()
            .fold((0, 0), |(t, l), f| (t + f.tried, l + f.lost))
    }

    pub fn lost_reuse_fraction(&self) -> f64 {
        match self.tried_lost() {
            (0, _) => 0.0,
            (t, l) => l as f64 / t as f64,
        }
    }

    /// Landed samples per pixel, averaged over `frames` frames.
    pub fn mean_effective_spp(&self, frames: u32) -> f64 {
        self.per_frame
            .iter()
            .map(|f| f.mean_effective_spp)
            .sum::<f64>()
            / frames as f64
    }
}

/// What a resumed render starts from.
pub struct Resumed {
    pub trailer: Trailer,
    /// The frames in flight at the checkpoint.
    pub active: Vec<FrameAccum>,
}

/// A chunk's append-only log of finished records: (file, path, valid length, (frame, offset) of
/// each record, each record's CRC-32).
type ChunkLog = (File, PathBuf, u64, Vec<(u32, u64)>, Vec<u32>);

/// The CRC-32 a record of `f` ends in (the record ends at byte `end`).
fn record_crc(f: &File, end: u64) -> std::io::Result<u32> {
    use std::os::unix::fs::FileExt;
    let mut b = [0u8; 4];
    f.read_exact_at(&mut b, end.saturating_sub(4))?;
    Ok(u32::from_le_bytes(b))
}

/// Checkpoints and the chunk log of one render.
pub struct Checkpointer {
    /// The checkpoint folder; `None`: no checkpoints.
    dir: Option<PathBuf>,
    every: Duration,
    last: Instant,
    template: Trailer,
    /// A chunk's append-only log of finished records.
    log: Option<ChunkLog>,
    partial: Option<PathBuf>,
    /// Time spent writing checkpoints, for the statistics.
    pub spent: Duration,
    pub written: u32,
    /// The checkpoint folder, registered while this process may leave it empty (it created it).
    _made: Option<MadeFolder>,
    /// Whether the checkpoint folder is this render's to remove when it completes: this process
    /// made it, or an earlier run did (it held a checkpoint, or the temporary of one). A folder
    /// that was there before without either (one you made for it) is kept, empty or not.
    own_dir: bool,
    /// Whether a checkpoint counts the chunk log (one was resumed or written): a log that none
    /// counts is of no use to a later run, which starts it over, and is removed if the run
    /// fails (a full disk at the first checkpoint left an empty log beside the outputs).
    log_counted: bool,
}

impl Drop for Checkpointer {
    fn drop(&mut self) {
        // `finish` takes the log; one still here belongs to a run that did not complete.
        if let Some((f, lp, ..)) = &self.log {
            if !self.log_counted && same_file(f, lp) {
                let _ = std::fs::remove_file(lp);
            }
        }
    }
}

/// Read back every record of a chunk's log that a checkpoint counts (`recs`: frame and offset,
/// in file order; the last ends at `len`): each must end in the CRC the checkpoint has for it
/// (`crcs`, where it has them: another run's log), pass its checksum and be of its frame.
/// Returns each record's CRC (an older checkpoint's are taken from the log, which read back
/// whole).
fn check_log(
    lp: &Path,
    recs: &[(u32, u64)],
    crcs: &[u32],
    len: u64,
    norm: Norm,
) -> Result<Vec<u32>> {
    if !crcs.is_empty() && crcs.len() != recs.len() {
        bail!(
            "{}: its checkpoint counts {} records but has the checksums of {}: the checkpoint is \
             damaged; delete the checkpoint and the log to start the chunk over",
            lp.display(),
            recs.len(),
            crcs.len()
        );
    }
    if recs.is_empty() {
        return Ok(Vec::new());
    }
    let mut r = BufReader::new(
        crate::util::fs::open_regular(lp).with_context(|| format!("opening {}", lp.display()))?,
    );
    let mut read = Vec::with_capacity(recs.len());
    for (k, &(frame, off)) in recs.iter().enumerate() {
        let end = recs.get(k + 1).map_or(len, |n| n.1);
        let crc = record_crc(r.get_ref(), end)?;
        if crcs.get(k).is_some_and(|&want| want != crc) {
            bail!(
                "{}: the record of frame {frame} at byte {off} is not the one its checkpoint \
                 counted (the log of another run?); delete the checkpoint and the log to start \
                 the chunk over",
                lp.display()
            );
        }
        let damaged = |why: String| {
            anyhow!(
                "{}: the record of frame {frame} at byte {off} is damaged ({why}); delete the \
                 checkpoint and the log to start the chunk over",
                lp.display()
            )
        };
        r.seek(SeekFrom::Start(off))?;
        let rec = read_record(&mut (&mut r).take(end.saturating_sub(off)), norm, end - off)
            .map_err(|e| damaged(e.to_string()))?;
        if rec.frame() != frame {
            return Err(damaged(format!("it holds frame {}", rec.frame())));
        }
        read.push(crc);
    }
    Ok(read)
}

impl Checkpointer {
    /// No checkpoints and no chunk: a plain in-memory render.
    pub fn none() -> Checkpointer {
        Checkpointer {
            dir: None,
            every: Duration::MAX,
            last: Instant::now(),
            template: Trailer::new(RunKey::default(), None, &(0..=0), String::new(), false),
            log: None,
            partial: None,
            spent: Duration::ZERO,
            written: 0,
            _made: None,
            own_dir: false,
            log_counted: false,
        }
    }

    /// Whether finished frames go to a chunk's partial log rather than to frame files.
    pub fn chunked(&self) -> bool {
        self.log.is_some()
    }

    pub fn dir(&self) -> Option<&Path> {
        self.dir.as_deref()
    }

    /// Open the checkpoint folder `dir` (if any) for a run with `template`'s settings. With
    /// `resume`, read the checkpoint there and check it was made with the same settings; without,
    /// refuse to overwrite one. A chunk also opens its log, truncated to the checkpoint's length.
    pub fn open(
        dir: Option<PathBuf>,
        every: Duration,
        resume: bool,
        mut template: Trailer,
        norm: Norm,
    ) -> Result<(Checkpointer, Option<Resumed>)> {
        let mut resumed = None;
        let mut made = None;
        // Whether the checkpoint folder was there with a reframe run's checkpoint or the
        // temporary of one in it: an earlier run of the render made it (`own_dir`).
        let mut left_by_a_run = false;
        // A chunk's log is truncated and written: refused before anything is made if something
        // other than a regular file of one name is in its place (a link planted there to the
        // scene's OBJ had the OBJ overwritten; a FIFO blocked the open).
        if let Some(c) = template.chunk {
            check_partial_is_ours(&partial_path(&template.out, c), &template)?;
            let lp = log_path(&partial_path(&template.out, c));
            let hard_link = || {
                use std::os::unix::fs::MetadataExt;
                let m = std::fs::symlink_metadata(&lp).ok()?;
                (m.nlink() != 1).then_some("a file with other names (a hard link)")
            };
            if let Some(what) = crate::util::fs::in_the_way(&lp).or_else(hard_link) {
                bail!(
                    "the chunk log {} is {what}; remove it (reframe makes its own) and run again",
                    lp.display()
                );
            }
        }
        if let Some(d) = &dir {
            let named = checkpoint_named(d, &template.out, template.chunk);
            // What sits at the folder's path, named as what it is.
            if let Ok(m) = std::fs::symlink_metadata(d) {
                let t = m.file_type();
                if t.is_symlink() && !d.exists() {
                    bail!(
                        "{named}: that is a symbolic link to nothing; remove it or name \
                         another folder"
                    );
                }
                if !d.is_dir() {
                    let what =
                        crate::util::input::kind(std::fs::metadata(d).map_or(t, |m| m.file_type()));
                    bail!("{named}: that is {what}, not a folder (the checkpoint is a folder)");
                }
            }
            let state = d.join("state");
            // A folder that cannot be searched (mode 000) reads as one without a checkpoint:
            // said as what it is (it said "no checkpoint", then could not create files).
            if let Err(e) = state.try_exists() {
                bail!(
                    "{named}: cannot look into the folder ({e}); make it readable, or name \
                     another folder"
                );
            }
            if !state.exists() {
                // A temporary of the first checkpoint, which a process killed while writing it
                // left: no later run removed it, and the folder outlived the render. Or the
                // default folder, empty: a run killed (SIGKILL, no handler) before its first
                // checkpoint left it (a folder of that name made by hand and left empty is
                // nothing to keep).
                let default = super::key::default_checkpoint_dir(&template.out, template.chunk);
                let empty = std::fs::read_dir(d).is_ok_and(|mut e| e.next().is_none());
                left_by_a_run = remove_stale_tmp(d, |n| n == "state") > 0
                    || (empty && d.as_path() == default.as_path());
            } else {
                left_by_a_run = super::is_state_file(&state);
            }
            // (`left_by_a_run` is whether a 'state' there is a reframe checkpoint.)
            if state.exists() && !resume && !left_by_a_run {
                bail!(
                    "{named}: the folder holds a file named 'state' that is not a complete \
                     reframe checkpoint (another program's file, or one cut short); name \
                     another folder, or remove the file"
                );
            }
            if state.exists() {
                if !resume {
                    // Named by its `--out` where that is not this render's: a render of
                    // another `--out` of the same stem (`f_####.png` beside `f_####.exr`)
                    // shares the default folder, and `--resume` would refuse it too.
                    let other = StateFile::open(&state)
                        .ok()
                        .map(|sf| sf.trailer.out)
                        .filter(|o| *o != template.out);
                    if let Some(o) = other {
                        bail!(
                            "{} holds the checkpoint of an interrupted render to --out {o}: \
                             resume that render (the same command with --resume), give this \
                             one a folder of its own with --checkpoint DIR, or delete the \
                             folder to start over",
                            d.display()
                        );
                    }
                    bail!(
                        "{} holds the checkpoint of an interrupted render: add --resume to \
                         continue it, or delete the folder to start over",
                        d.display()
                    );
                }
                let mut sf = StateFile::open(&state)?;
                crate::util::fs::set_checkpoint_in_place(true);
                let t = sf.trailer.clone();
                if t.kind != Kind::Checkpoint {
                    bail!("{}: not a checkpoint", state.display());
                }
                if let Some(diff) = t.key.difference(&template.key) {
                    bail!(
                        "--resume: the checkpoint in {} was made with other settings ({diff}); \
                         resume with the same command line and build, or delete the folder",
                        d.display()
                    );
                }
                if t.chunk != template.chunk {
                    bail!(
                        "--resume: the checkpoint in {} is of another chunk",
                        d.display()
                    );
                }
                // The same settings (the key holds the frames and the window) give the same
                // units: other units are a damaged or edited trailer.
                if t.units != template.units {
                    bail!(
                        "--resume: the checkpoint in {} counts units {:?}, where this render's \
                         are {:?}: it is damaged; delete the folder to start over",
                        d.display(),
                        t.units,
                        template.units
                    );
                }
                // Only this checkpoint's own temporary (`state.tmp-PID`), which a process
                // killed while writing it left: the folder may be one the user named and keeps
                // other files in (every `*.tmp-*` was removed, a user's file and another node's
                // temporary frame with it).
                remove_stale_tmp(d, |n| n == "state");
                let mut active = Vec::new();
                for &(_, off) in &t.records {
                    match sf.record(off, norm)? {
                        Record::Sums(a) => active.push(*a),
                        Record::Pixels(_) => bail!(
                            "{}: the checkpoint holds finished pixels, not sums",
                            state.display()
                        ),
                    }
                }
                resumed = Some(Resumed { trailer: t, active });
            } else if resume {
                // A chunk that finished has no checkpoint, but its partial file: with --resume
                // (which the Slurm scripts always pass) it is not rendered again.
                if let Some(c) = template.chunk {
                    let partial = partial_path(&template.out, c);
                    // Complete only if this run's, and every record reads back whole, as
                    // `merge` reads them: a damaged one was called complete, and the merge that
                    // refused it could never be mended by running the chunk again. One cut
                    // short, or with its trailer damaged, is no complete result either.
                    let complete = || -> Result<bool> {
                        let mut sf = StateFile::open(&partial)?;
                        let t = sf.trailer.clone();
                        if t.kind != Kind::Partial
                            || t.key.difference(&template.key).is_some()
                            || t.chunk != template.chunk
                            || t.units != template.units
                            || t.next_unit != template.units[1] + 1
                        {
                            return Ok(false);
                        }
                        for &(_, off) in &t.records {
                            sf.record(off, norm)?;
                        }
                        Ok(true)
                    };
                    match crate::util::fs::open_regular(&partial) {
                        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                        // One that cannot be opened (another user's, in a shared folder) is not
                        // damaged: rendered again, the chunk failed only at its end, on the
                        // rename.
                        Err(e) => bail!(
                            "{}: cannot read the chunk's partial file ({e}); make it readable, \
                             or remove it to render the chunk again",
                            partial.display()
                        ),
                        Ok(_) => match complete() {
                            Ok(true) => {
                                return Err(ChunkComplete {
                                    chunk: c.to_string(),
                                    partial,
                                }
                                .into())
                            }
                            Ok(false) => {}
                            Err(e) => errln!(
                                "note: {}: chunk {c} is rendered again (its partial file is \
                                 replaced when it is done)",
                                crate::util::text::message(&format!("{e:#}"))
                            ),
                        },
                    }
                }
                errln!(
                    "note: no checkpoint in {}: starting from the beginning",
                    crate::util::text::printable(&d.display().to_string())
                );
            }
            if !d.exists() {
                // A stop before the first checkpoint leaves no empty folder behind.
                made =
                    Some(MadeFolder::create(d).with_context(|| {
                        format!("creating the checkpoint folder {}", d.display())
                    })?);
            }
            crate::util::fs::create_dir_all(d)
                .with_context(|| format!("creating the checkpoint folder {}", d.display()))?;
            check_writable_dir(d)?;
        }
        let partial = template.chunk.map(|c| partial_path(&template.out, c));
        let log = match &partial {
            None => None,
            Some(p) => {
                let lp = log_path(p);
                let log_len = resumed.as_ref().map_or(0, |r| r.trailer.log_len);
                if log_len > 0 && std::fs::symlink_metadata(&lp).is_err() {
                    bail!(
                        "{}: the chunk log is missing, but its checkpoint says it holds {} \
                         finished frame(s); put it back, or delete the checkpoint to start the \
                         chunk over",
                        lp.display(),
                        resumed.as_ref().map_or(0, |r| r.trailer.log_records.len())
                    );
                }
                // As the lock file is opened (a link planted there to the scene's OBJ had the
                // OBJ overwritten; a FIFO blocked the open).
                let f = open_own_file(&lp, "the chunk log")?;
                let (len, recs, crcs) = match &resumed {
                    Some(r) => (
                        r.trailer.log_len,
                        r.trailer.log_records.clone(),
                        r.trailer.log_crcs.clone(),
                    ),
                    None => (0, Vec::new(), Vec::new()),
                };
                if f.metadata()?.len() < len {
                    bail!("{}: shorter than its checkpoint says; delete the checkpoint and the log to start the chunk over", lp.display());
                }
                // The frames the log holds are not rendered again: each must read back whole
                // (its checksum), or the chunk would finish on a damaged record that only
                // `merge` would find.
                let crcs = check_log(&lp, &recs, &crcs, len, norm)?;
                f.set_len(len)?;
                let mut f = f;
                f.seek(SeekFrom::Start(len))?;
                Some((f, lp, len, recs, crcs))
            }
        };
        // Whether the folder is this render's to remove when it completes: made now, or by
        // the run resumed (its trailer says; older checkpoints do not, and count as made), or
        // by a run killed while writing its first checkpoint (its temporary was there).
        let made_by_a_run = match &resumed {
            Some(r) => r.trailer.dir_made.unwrap_or(true),
            None => left_by_a_run,
        };
        let own_dir = made.is_some() || made_by_a_run;
        if dir.is_some() {
            template.dir_made = Some(own_dir);
        }
        Ok((
            Checkpointer {
                dir,
                every,
                last: Instant::now(),
                template,
                log,
                partial,
                spent: Duration::ZERO,
                written: 0,
                own_dir,
                _made: made,
                log_counted: resumed.is_some(),
            },
            resumed,
        ))
    }

    /// Whether a checkpoint is due (there is a folder and `every` has passed since the last).
    pub fn due(&self) -> bool {
        self.dir.is_some() && self.last.elapsed() >= self.every
    }

    pub fn enabled(&self) -> bool {
        self.dir.is_some()
    }

    /// Write the checkpoint: the next unit to render, the counters, the frames in flight.
    pub fn save<'a>(
        &mut self,
        next_unit: u32,
        progress: &Counters,
        active: impl IntoIterator<Item = &'a FrameAccum>,
        frame_digests: &[(u32, u64)],
    ) -> Result<()> {
        let Some(dir) = &self.dir else {
            return Ok(());
        };
        let t0 = Instant::now();
        let mut t = self.template.clone();
        t.kind = Kind::Checkpoint;
        t.next_unit = next_unit;
        t.progress = progress.clone();
        t.frame_digests = frame_digests.to_vec();
        if let Some((f, lp, len, recs, crcs)) = &mut self.log {
            // The log's records must be on disk before a checkpoint counts them.
            f.sync_data()
                .with_context(|| format!("writing {}", lp.display()))?;
            t.log_len = *len;
            t.log_records = recs.clone();
            t.log_crcs = crcs.clone();
        }
        let state = dir.join("state");
        if let Err(e) = write_state(&state, &mut t, active) {
            // What is on disk and what a resume does (a disk full or a file-size limit named
            // the temporary file alone, and said neither).
            let kept = if state.is_file() {
                "the checkpoint before it is kept: --resume continues from there"
            } else {
                "no checkpoint of this render is on disk: --resume would start from its beginning"
            };
            return Err(e.context(format!("checkpoint not written ({kept})")));
        }
        crate::util::fs::set_checkpoint_in_place(true);
        self.log_counted = true;
        self.spent += t0.elapsed();
        self.written += 1;
        self.last = Instant::now();
        Ok(())
    }

    /// A chunk's frame that no later group of the chunk touches: append it to the log.
    pub fn retire(&mut self, r: &Record) -> Result<()> {
        let (f, lp, len, recs, crcs) = self.log.as_mut().expect("retire is only called for chunks");
        let mut w = BufWriter::new(&mut *f);
        match r {
            Record::Sums(a) => write_accum(a, &mut w),
            Record::Pixels(d) => write_pixels(d, &mut w),
        }
        .and_then(|_| std::io::Write::flush(&mut w))
        .with_context(|| format!("writing {}", lp.display()))?;
        drop(w);
        recs.push((r.frame(), *len));
        *len += match r {
            Record::Sums(a) => accum_bytes(a),
            Record::Pixels(d) => pixels_bytes(d),
        };
        crcs.push(record_crc(f, *len).with_context(|| format!("reading {}", lp.display()))?);
        Ok(())
    }

    /// The run is complete: a chunk turns its log into the partial file; the checkpoint goes.
    /// Returns the partial file of a chunk.
    pub fn finish(&mut self, next_unit: u32, progress: &Counters) -> Result<Option<PathBuf>> {
        let mut out = None;
        if let (Some((f, lp, _, recs, crcs)), Some(partial)) = (self.log.take(), &self.partial) {
            let mut t = self.template.clone();
            t.kind = Kind::Partial;
            t.next_unit = next_unit;
            t.progress = progress.clone();
            t.records = recs;
            t.record_crcs = crcs;
            let mut w = BufWriter::new(f);
            write_trailer(&mut w, &t).with_context(|| format!("writing {}", lp.display()))?;
            let f = w
                .into_inner()
                .map_err(|e| e.into_error())
                .and_then(|f| f.sync_all().map(|()| f))
                .with_context(|| format!("writing {}", lp.display()))?;
            // The log is renamed by its name: whatever sits there now must be the file this run
            // wrote (another program's file renamed over it made the partial file that file,
            // and the chunk reported success).
            if !same_file(&f, &lp) {
                bail!(
                    "{} was replaced by another file while the chunk rendered; its partial file \
                     was not written: render the chunk again",
                    lp.display()
                );
            }
            std::fs::rename(&lp, partial)
                .with_context(|| format!("renaming {} to {}", lp.display(), partial.display()))?;
            out = Some(partial.clone());
        }
        if let Some(d) = &self.dir {
            crate::util::fs::set_checkpoint_in_place(false);
            let _ = std::fs::remove_file(d.join("state"));
            if self.own_dir {
                let _ = std::fs::remove_dir(d);
            }
        }
        Ok(out)
    }
}

/// `--resume` of a chunk whose partial file is already there, complete and of the same run:
/// nothing to do (not an error; the command says so and succeeds).
#[derive(Debug)]
pub struct ChunkComplete {
    pub chunk: String,
    pub partial: PathBuf,
}

impl std::fmt::Display for ChunkComplete {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "chunk {} is already complete ({}): nothing to do",
            self.chunk,
            self.partial.display()
        )
    }
}

impl std::error::Error for ChunkComplete {}

/// Whether `path` (not followed, if a link) is the open file `f`.
fn same_file(f: &File, path: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (f.metadata(), std::fs::symlink_metadata(path)) {
        (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
        _ => false,
    }
}

/// A chunk's partial file left by a render of another `--out` is refused, with or without
/// `--resume`: outputs of one stem share partial names (`f_####.exr` and `f_####.png`), and a
/// chunk of one replaced the other's finished result without a word (its merge then wrote the
/// other sequence's frames, or was refused). One of this `--out` but of other frames or another
/// scene is refused too (below). One of this `--out` and these frames is this render's: an
/// earlier run's, of other settings (a scene fixed, a new build) is rendered again, as a
/// resubmitted Slurm array expects. Anything that is not a reframe partial file is left to the
/// checks that follow.
fn check_partial_is_ours(partial: &Path, template: &Trailer) -> Result<()> {
    let Ok(theirs) = StateFile::open(partial).map(|f| f.trailer) else {
        return Ok(());
    };
    if theirs.kind != Kind::Partial {
        return Ok(());
    }
    if theirs.out != template.out {
        bail!(
            "{} is the partial file of another render, of --out {}, {}: remove it to render this \
             chunk, or give this render an --out of another name",
            partial.display(),
            theirs.out,
            crate::state::key::shared_names(&theirs.out, &template.out)
        );
    }
    // Of this --out, but of other frames or another scene: a chunk file's name says only which
    // chunk it is, so two job arrays over different ranges of one shot given one --out replaced
    // each other's finished chunks, unsaid. A partial of the same frames is replaced, whatever
    // its other settings (a job run again, or an array resubmitted after a change of samples or
    // seed, whose old chunks the merge could not use).
    let (t, k) = (&theirs.key, &template.key);
    if (t.first_frame, t.last_frame, &t.scene) == (k.first_frame, k.last_frame, &k.scene) {
        return Ok(());
    }
    let name = crate::util::text::printable;
    bail!(
        "{}: holds chunk {} of frames {}-{} of '{}', finished, and this render is of frames {}-{} \
         of '{}': a chunk file's name says only which chunk it is, so this render would replace \
         that work; give it another --out, or delete that file to render the chunk again",
        partial.display(),
        template.chunk.map_or_else(String::new, |c| c.to_string()),
        t.first_frame,
        t.last_frame,
        name(&t.scene),
        k.first_frame,
        k.last_frame,
        name(&k.scene)
    )
}

/// The append-only log of a chunk whose partial file is `partial`: `NAME.partial.log`.
fn log_path(partial: &Path) -> PathBuf {
    let mut name = partial.file_name().unwrap_or_default().to_os_string();
    name.push(".log");
    partial.with_file_name(name)
}
