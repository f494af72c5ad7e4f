//! Finished frames written as image files: atomically, with the metadata every frame file
//! carries (method, samples, window, seed, time, scene, frame and the camera's matrices).
use crate::film::{Developed, Sink};
use crate::image::{
    bytes_digest, write_image_hashed, Image, Metadata, OutputPattern, WriteOptions,
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
        let digest = write_image_hashed(
            &path,
            &img,
            &meta,
            &WriteOptions {
                exr_float: self.meta.exr_float,
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
/// waits on the render's thread. A write that fails is said at the next `put` or `sync`, and
/// the frames behind it are not written.
pub struct Writer {
    jobs: std::sync::mpsc::SyncSender<Job>,
    replies: std::sync::mpsc::Receiver<Result<Vec<(u32, u64)>>>,
}

impl Writer {
    /// Start the writer's thread in `scope`, writing to `inner` (which it borrows until the
    /// scope ends: the frames are all written by then).
    pub fn spawn<'scope, S: Sink + Send>(
        scope: &'scope std::thread::Scope<'scope, '_>,
        inner: &'scope mut S,
    ) -> Writer {
        let (jobs, queue) = std::sync::mpsc::sync_channel::<Job>(1);
        let (answer, replies) = std::sync::mpsc::channel();
        scope.spawn(move || {
            let serve = || {
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
            // The image code's parallel loops (the half-float range checks, the sRGB
            // encoding) run on this thread alone, not on a pool of their own beside the
            // render's workers.
            match rayon::ThreadPoolBuilder::new()
                .num_threads(1)
                .use_current_thread()
                .build()
            {
                Ok(pool) => pool.install(serve),
                Err(_) => serve(),
            }
        });
        Writer { jobs, replies }
    }

    /// The writer's thread has stopped: the failure it said.
    fn failure(&mut self) -> anyhow::Error {
        match self.replies.recv() {
            Ok(Err(e)) => e,
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
            Ok(reply) => reply,
            Err(_) => Err(anyhow::anyhow!("the frame writer stopped")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::film::View;
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
        let (first, second) = std::thread::scope(|s| {
            let mut w = Writer::spawn(s, &mut rec);
            pool.install(|| {
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
        let me = std::thread::current().id();
        for (f, thread, threads) in &rec.got {
            assert_ne!(*thread, me, "frame {f} written on the caller's thread");
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
                let mut w = Writer::spawn(s, &mut rec);
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

    /// A sink that holds each write until the test lets it go.
    struct Held(mpsc::Receiver<()>, Vec<u32>);

    impl Sink for Held {
        fn put(&mut self, d: Developed) -> Result<()> {
            self.0
                .recv_timeout(Duration::from_secs(60))
                .map_err(|_| anyhow::anyhow!("frame {}: never let go", d.view.frame))?;
            self.1.push(d.view.frame);
            Ok(())
        }
    }

    #[test]
    fn the_render_goes_on_while_a_frame_is_written() {
        let (go, held) = mpsc::channel();
        let mut sink = Held(held, vec![]);
        std::thread::scope(|s| {
            let mut w = Writer::spawn(s, &mut sink);
            // One frame being written and one waiting: both puts return with neither written
            // (a writer on the caller's thread would wait for `go` here, which comes after).
            w.put(frame(0)).unwrap();
            w.put(frame(1)).unwrap();
            go.send(()).unwrap();
            go.send(()).unwrap();
            w.sync().unwrap();
        });
        assert_eq!(sink.1, [0, 1]);
    }
}
