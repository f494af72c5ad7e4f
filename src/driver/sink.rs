//! Finished frames written as image files: atomically, with the metadata every frame file
//! carries (method, samples, window, seed, time, scene, frame and the camera's matrices).
use crate::film::{Developed, Sink};
use crate::image::{
    bytes_digest, write_image_placing, Image, Metadata, OutputPattern, WriteOptions,
};
use anyhow::{Context, Result};

/// What every frame file of a render records about how it was made.
#[derive(Clone, Debug)]
pub struct FrameMeta {
    pub scene: String,
    pub method: String,
    pub spp: u32,
    pub window: u32,
    pub seed: u64,
    pub exr_float: bool,
}

/// Writes finished frames to `out`, and remembers which.
pub struct FileSink {
    pub meta: FrameMeta,
    pub out: OutputPattern,
    pub written: Vec<std::path::PathBuf>,
    /// The frames written since `sync` last took them, and their files' hashes.
    digests: Vec<(u32, u64)>,
}

impl FileSink {
    pub fn new(meta: FrameMeta, out: OutputPattern) -> FileSink {
        FileSink {
            meta,
            out,
            written: Vec::new(),
            digests: Vec::new(),
        }
    }
}

impl Sink for FileSink {
    fn put(&mut self, d: Developed) -> Result<()> {
        let frame = d.view.frame;
        let path = self.out.path(frame);
        let meta = Metadata {
            method: self.meta.method.clone(),
            spp: self.meta.spp,
            window: self.meta.window,
            seed: self.meta.seed,
            render_seconds: d.seconds,
            world_to_camera: d.view.world_to_camera,
            world_to_ndc: d.view.world_to_ndc,
            extra: vec![
                ("scene".into(), self.meta.scene.clone()),
                ("frame".into(), frame.to_string()),
            ],
        };
        let img = Image {
            width: d.view.width,
            height: d.view.height,
            channels: d.channels.iter().map(|c| c.to_string()).collect(),
            data: d.data,
        };
        // What a stop by signal from the rename on says was written (a merge's frames are not
        // in a checkpoint: its message had said nothing of them), set as the frame is renamed
        // into place: set after, a stop between the two counted one frame less than was there.
        let note = format!(
            "{} frame file(s) written whole before it, the last {}",
            self.written.len() + 1,
            crate::util::text::printable(&path.display().to_string())
        );
        let mut note = Some(note);
        let digest = write_image_placing(
            &path,
            &img,
            &meta,
            &WriteOptions {
                exr_float: self.meta.exr_float,
            },
            &mut || {
                if let Some(n) = note.take() {
                    crate::util::fs::set_stop_note(n);
                }
            },
        )
        .with_context(|| format!("writing frame {frame}"))?;
        self.digests.push((frame, digest));
        self.written.push(path);
        Ok(())
    }

    fn sync(&mut self) -> Result<Vec<(u32, u64)>> {
        Ok(std::mem::take(&mut self.digests))
    }
}

/// The hash of the bytes of the file at `path`, as `write_image_hashed` gave it when it wrote
/// the file (`Trailer::frame_digests`).
pub fn file_digest(path: &std::path::Path) -> Result<u64> {
    let bytes = std::fs::read(path).with_context(|| format!("reading back {}", path.display()))?;
    Ok(bytes_digest(&bytes))
}

/// What the render's thread asks of the writer's.
enum Job {
    Frame(Box<Developed>),
    Sync,
}

/// A sink that hands each frame to `inner` on a thread of its own, so that the workers go on
/// to the next frame (or group) while the last one is encoded and written. Without it the
/// workers waited for every write: 20-35 ms for a 640x480 EXR, a sixth of a 1 spp frame's time
/// at 2 threads and more at 16. At most one frame waits while one is being written (the
/// render's memory estimate counts both); a frame that arrives while both places are taken
/// waits on the render's thread. A write that fails is said by a later `put` (the one after
/// the next, where the next was handed over before the failure) or by the next `sync`; the
/// frames behind it are not written.
pub struct Writer {
    jobs: std::sync::mpsc::SyncSender<Job>,
    replies: std::sync::mpsc::Receiver<Result<Vec<(u32, u64)>>>,
    /// The writer's thread stopped, and its failure has been said.
    told: bool,
}

impl Writer {
    /// Start the writer's thread in `scope`, writing to `inner` (which it borrows until the
    /// scope ends, when the frames handed over are written or the first failure is kept).
    /// Refused where the thread cannot be started (its stack does not fit under `ulimit -v`).
    pub fn spawn<'scope, S: Sink + Send>(
        scope: &'scope std::thread::Scope<'scope, '_>,
        inner: &'scope mut S,
    ) -> anyhow::Result<Writer> {
        let (jobs, queue) = std::sync::mpsc::sync_channel::<Job>(1);
        let (answer, replies) = std::sync::mpsc::channel();
        let serve = move || {
            // As the workers that wrote frames before did.
            crate::embree::set_flush_denormals();
            for job in queue {
                let reply = match job {
                    Job::Frame(d) => match inner.put(*d) {
                        Ok(()) => continue,
                        Err(e) => Err(e),
                    },
                    Job::Sync => inner.sync(),
                };
                let failed = reply.is_err();
                if answer.send(reply).is_err() || failed {
                    // Dropping the queue refuses the frames behind a failed one.
                    return;
                }
            }
        };
        std::thread::Builder::new()
            // Named for a panic's message, which the process ends with, as a worker's does.
            .name("frame writer".into())
            .spawn_scoped(scope, move || {
                // The image code's parallel loops (the half-float range checks, the sRGB
                // encoding) run on this thread alone, as the one worker of a pool of one, not
                // on rayon's global pool beside the render's workers (where the pool cannot be
                // made, they do).
                match rayon::ThreadPoolBuilder::new()
                    .num_threads(1)
                    .use_current_thread()
                    .build()
                {
                    Ok(pool) => pool.install(serve),
                    Err(_) => serve(),
                }
            })
            .map_err(|e| {
                anyhow::anyhow!(
                    "starting the frame writer's thread: {e}{}",
                    crate::util::mem::address_space_note()
                )
            })?;
        Ok(Writer {
            jobs,
            replies,
            told: false,
        })
    }

    /// Whether a failure of the writer's thread has been said by `put` or `sync`.
    pub fn told(&self) -> bool {
        self.told
    }

    /// The writer's thread has stopped: the failure it said.
    fn failure(&mut self) -> anyhow::Error {
        let told = std::mem::replace(&mut self.told, true);
        match self.replies.recv() {
            Ok(Err(e)) if !told => e,
            _ => anyhow::anyhow!("the frame writer stopped"),
        }
    }
}

impl Sink for Writer {
    fn put(&mut self, d: Developed) -> Result<()> {
        match self.jobs.send(Job::Frame(Box::new(d))) {
            Ok(()) => Ok(()),
            Err(_) => Err(self.failure()),
        }
    }

    fn sync(&mut self) -> Result<Vec<(u32, u64)>> {
        if self.jobs.send(Job::Sync).is_err() {
            return Err(self.failure());
        }
        match self.replies.recv() {
            Ok(Ok(digests)) => Ok(digests),
            Ok(Err(e)) => {
                self.told = true;
                Err(e)
            }
            Err(_) => Err(self.failure()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::film::View;
    use std::sync::atomic::{AtomicBool, Ordering::SeqCst};
    use std::sync::mpsc;
    use std::time::Duration;

    fn frame(f: u32) -> Developed {
        Developed {
            view: View {
                frame: f,
                width: 1,
                height: 1,
                world_to_camera: [0.0; 16],
                world_to_ndc: [0.0; 16],
            },
            channels: vec!["R", "G", "B"],
            data: vec![f as f32; 3],
            seconds: 0.0,
            nonfinite: 0,
        }
    }

    /// Records where and in what order it was handed frames; fails on `fail`.
    struct Recorder {
        got: Vec<(u32, std::thread::ThreadId, usize)>,
        fail: Option<u32>,
        unsynced: Vec<(u32, u64)>,
    }

    impl Sink for Recorder {
        fn put(&mut self, d: Developed) -> Result<()> {
            let f = d.view.frame;
            if self.fail == Some(f) {
                anyhow::bail!("cannot write frame {f}: disk full");
            }
            self.got
                .push((f, std::thread::current().id(), rayon::current_num_threads()));
            self.unsynced.push((f, 100 + f as u64));
            Ok(())
        }
        fn sync(&mut self) -> Result<Vec<(u32, u64)>> {
            Ok(std::mem::take(&mut self.unsynced))
        }
    }

    #[test]
    fn writes_every_frame_in_order_on_a_thread_of_its_own() {
        let mut rec = Recorder {
            got: vec![],
            fail: None,
            unsynced: vec![],
        };
        // Inside a pool of 3, as the render's loop is: the writer's parallel loops must not
        // run on it, nor on a global pool.
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap();
        let mut caller = None;
        let (first, second) = std::thread::scope(|s| {
            let mut w = Writer::spawn(s, &mut rec).unwrap();
            pool.install(|| {
                caller = Some(std::thread::current().id());
                for f in 0..5 {
                    w.put(frame(f)).unwrap();
                }
                let first = w.sync().unwrap();
                w.put(frame(5)).unwrap();
                (first, w.sync().unwrap())
            })
        });
        assert_eq!(
            first,
            (0..5).map(|f| (f, 100 + f as u64)).collect::<Vec<_>>()
        );
        assert_eq!(second, vec![(5, 105)]);
        let order: Vec<u32> = rec.got.iter().map(|g| g.0).collect();
        assert_eq!(order, [0, 1, 2, 3, 4, 5]);
        let caller = caller.unwrap();
        for (f, thread, threads) in &rec.got {
            assert_ne!(*thread, caller, "frame {f} written on the caller's thread");
            assert_eq!(
                *threads, 1,
                "frame {f}: the writer's rayon pool has {threads} threads"
            );
        }
    }

    #[test]
    fn a_failed_write_is_said_and_the_frames_behind_it_are_not_written() {
        for also_put in [false, true] {
            let mut rec = Recorder {
                got: vec![],
                fail: Some(1),
                unsynced: vec![],
            };
            let err = std::thread::scope(|s| {
                let mut w = Writer::spawn(s, &mut rec).unwrap();
                w.put(frame(0)).unwrap();
                // Handed over: the failure is said later, by a put or by sync.
                let _ = w.put(frame(1));
                let mut err = None;
                if also_put {
                    for f in 2..6 {
                        if let Err(e) = w.put(frame(f)) {
                            err = Some(e);
                            break;
                        }
                    }
                }
                err.unwrap_or_else(|| w.sync().unwrap_err()).to_string()
            });
            assert_eq!(
                err, "cannot write frame 1: disk full",
                "also_put {also_put}"
            );
            assert_eq!(rec.got.iter().map(|g| g.0).collect::<Vec<_>>(), [0]);
        }
    }

    /// A sink that holds each write until the test lets it go, and says which it holds.
    struct Held {
        go: mpsc::Receiver<()>,
        holding: mpsc::Sender<u32>,
        got: Vec<u32>,
    }

    impl Sink for Held {
        fn put(&mut self, d: Developed) -> Result<()> {
            let f = d.view.frame;
            self.holding.send(f).unwrap();
            self.go
                .recv_timeout(Duration::from_secs(60))
                .map_err(|_| anyhow::anyhow!("frame {f}: never let go"))?;
            self.got.push(f);
            Ok(())
        }
    }

    #[test]
    fn the_render_goes_on_while_a_frame_is_written_and_holds_two_at_most() {
        let (go, held) = mpsc::channel();
        let (holding, writing) = mpsc::channel();
        let mut sink = Held {
            go: held,
            holding,
            got: vec![],
        };
        let third_back = AtomicBool::new(false);
        std::thread::scope(|s| {
            let mut w = Writer::spawn(s, &mut sink).unwrap();
            // One frame being written and one waiting: both puts return with neither written
            // (a writer on the caller's thread would wait for `go` here, which comes after).
            w.put(frame(0)).unwrap();
            assert_eq!(writing.recv().unwrap(), 0);
            w.put(frame(1)).unwrap();
            let third_back = &third_back;
            let third = s.spawn(move || {
                w.put(frame(2)).unwrap();
                third_back.store(true, SeqCst);
                w.sync().unwrap();
            });
            // A third frame finds no place until frame 0 is written (an unbounded queue would
            // take it at once; a slow machine can only make this pass, never fail).
            std::thread::sleep(Duration::from_millis(300));
            assert!(
                !third_back.load(SeqCst),
                "a third frame was taken while two were in hand"
            );
            for _ in 0..3 {
                go.send(()).unwrap();
            }
            third.join().unwrap();
        });
        assert_eq!(sink.got, [0, 1, 2]);
    }

    /// A bug in a writer ends the process as a worker's panic does, and no caller waits
    /// forever for an answer.
    #[test]
    fn a_panicking_write_ends_the_render() {
        struct Bug;
        impl Sink for Bug {
            fn put(&mut self, _: Developed) -> Result<()> {
                panic!("an encoder's bug")
            }
        }
        let mut bug = Bug;
        let mut said = String::new();
        let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            std::thread::scope(|s| {
                let mut w = Writer::spawn(s, &mut bug).unwrap();
                w.put(frame(0)).unwrap();
                said = w.sync().unwrap_err().to_string();
            })
        }));
        assert!(outcome.is_err(), "the panic went unseen");
        assert_eq!(said, "the frame writer stopped");
    }
}
