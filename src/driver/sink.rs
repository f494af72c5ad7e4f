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
    /// The frames written since `take_digests` last took them, and their files' hashes.
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

    fn take_digests(&mut self) -> Vec<(u32, u64)> {
        std::mem::take(&mut self.digests)
    }
}

/// The hash of the bytes of the file at `path`, as `write_image_hashed` gave it when it wrote
/// the file (`Trailer::frame_digests`).
pub fn file_digest(path: &std::path::Path) -> Result<u64> {
    let bytes = std::fs::read(path).with_context(|| format!("reading back {}", path.display()))?;
    Ok(bytes_digest(&bytes))
}
