//! `--denoise`: every finished frame goes through Open Image Denoise before it is written.
//!
//! The denoiser is guided by two auxiliary images of the frame's camera, the first surface's
//! reflectance (albedo) and shading normal. They are traced here, in a pass of primary rays of
//! their own (`AUX_SPP` stratified rays per pixel, a fixed stream of the render's seed), rather
//! than gathered from the method's samples: every method gets the same guides for a frame, the
//! pass costs a few percent of one path-traced sample per pixel, and a resumed or merged frame
//! gets the guides a straight render would have.
use crate::film::{Developed, Sink};
use crate::image::oidn::{DenoiseInput, Denoiser};
use crate::integrator::Integrator;
use crate::sampling::Sampler;
use anyhow::{Context, Result};
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use std::time::Instant;

/// Primary rays per pixel of the guide pass.
pub const AUX_SPP: u32 = 8;
/// The sampler stream of the guide pass (the render's own samples use streams from 0 up).
const AUX_STREAM: u32 = u32::MAX;

/// What a denoised frame file holds beyond its (denoised) RGB.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Layers {
    /// RGB (and the `--aov` channels) only.
    None,
    /// Also the undenoised radiance and the two guides: `raw.R/G/B`, `albedo.R/G/B`,
    /// `normal.X/Y/Z`.
    RawAndGuides,
}

impl Layers {
    /// The channels a frame file holds beyond RGB and the `--aov` channels.
    pub fn extra_channels(self) -> &'static [&'static str] {
        match self {
            Layers::None => &[],
            Layers::RawAndGuides => &[
                "raw.R", "raw.G", "raw.B", "albedo.R", "albedo.G", "albedo.B", "normal.X",
                "normal.Y", "normal.Z",
            ],
        }
    }
}

/// The guides of frame `frame` at `w` x `h`: per pixel the mean over `AUX_SPP` primary rays of
/// the first surface's reflectance `Kd + Ks` (textures applied, clamped to 1; an escaped ray's
/// background radiance clamped to 1) and of its shading normal facing the camera (an escaped
/// ray's is 0). Row-major RGB triples.
pub fn guides(
    integrator: &Integrator,
    frame: u32,
    w: u32,
    h: u32,
    seed: u64,
) -> (Vec<f32>, Vec<f32>) {
    let scene = integrator.scene;
    let cam = scene.camera(frame, w, h);
    let len = 3 * (w * h) as usize;
    let (mut albedo, mut normal) = (vec![0.0f32; len], vec![0.0f32; len]);
    let row = 3 * w as usize;
    albedo
        .par_chunks_mut(row)
        .zip(normal.par_chunks_mut(row))
        .enumerate()
        .for_each(|(y, (albedo, normal))| {
            let y = y as u32;
            for x in 0..w {
                let pixel = y * w + x;
                let (mut a, mut n) = (Vec3::ZERO, Vec3::ZERO);
                for s in 0..AUX_SPP {
                    let mut sampler = Sampler::stratified(seed, frame, pixel, AUX_STREAM, s);
                    let r = Vec2::new(x as f32, y as f32) + sampler.next_2d();
                    let dir = cam.direction(r);
                    let ray = crate::embree::Ray::new(cam.eye, dir);
                    match scene.geometry.intersect1(&ray) {
                        Some(hit) => {
                            let sp = scene.surface(&hit);
                            let m = scene.material(&sp);
                            a += (m.kd + m.ks).min(Vec3::ONE);
                            n += if sp.ns.dot(dir) > 0.0 { -sp.ns } else { sp.ns };
                        }
                        None => a += scene.env_radiance(dir).clamp(Vec3::ZERO, Vec3::ONE),
                    }
                }
                let k = 1.0 / AUX_SPP as f32;
                let at = 3 * x as usize..3 * x as usize + 3;
                albedo[at.clone()].copy_from_slice(&(a * k).to_array());
                normal[at].copy_from_slice(&(n * k).to_array());
            }
        });
    (albedo, normal)
}

/// A denoised frame's mean, channel by channel, against the radiance it was given: the largest
/// relative change past which `DenoiseSink` warns. The denoiser keeps a frame's mean within a
/// few percent where its light is spread over the image (2% at 64x48 on `cornell`, 10% in a
/// channel at 8x6); where it comes from a few very bright points (emitters of 1e9 seen directly
/// beside ones of 1e-8 in a grey scene), it moved a channel's mean by 38% and tinted a grey
/// frame.
const MEAN_SHIFT_WARNING: f64 = 0.2;

/// What denoising a frame took and did.
pub struct Denoised {
    /// Seconds, the guides included.
    pub seconds: f64,
    /// Per channel (R, G, B), the denoised frame's mean over the mean of the radiance it was
    /// given, less 1 (0 where that was black).
    pub mean_shift: [f64; 3],
}

/// Denoise `d`'s RGB in place (keeping its other channels), adding the raw radiance and the
/// guides as channels when `layers` asks. A frame black in every pixel stays black (the
/// denoiser made a pixel of 1e-6 out of nothing).
pub fn denoise_frame(
    denoiser: &mut Denoiser,
    integrator: &Integrator,
    seed: u64,
    layers: Layers,
    d: &mut Developed,
) -> Result<Denoised> {
    let start = Instant::now();
    let (w, h) = (d.view.width, d.view.height);
    let n = (w * h) as usize;
    let nch = d.channels.len();
    let (albedo, normal) = guides(integrator, d.view.frame, w, h, seed);
    // A non-finite pixel (counted in `nonfinite`) would poison its neighbourhood in the network:
    // it goes in as black and comes out as the denoiser makes it from its neighbours.
    let color: Vec<f32> = (0..n)
        .flat_map(|i| (0..3).map(move |c| (i, c)))
        .map(|(i, c)| {
            let v = d.data[i * nch + c];
            if v.is_finite() {
                v.max(0.0)
            } else {
                0.0
            }
        })
        .collect();
    let out = if color.iter().all(|&v| v == 0.0) {
        color.clone()
    } else {
        denoiser
            .denoise(&DenoiseInput {
                width: w as usize,
                height: h as usize,
                color: &color,
                albedo: &albedo,
                normal: &normal,
            })
            .with_context(|| format!("denoising frame {}", d.view.frame))?
    };
    let sums = |v: &[f32]| {
        v.chunks_exact(3).fold([0.0f64; 3], |mut s, p| {
            (0..3).for_each(|c| s[c] += p[c] as f64);
            s
        })
    };
    let (before, after) = (sums(&color), sums(&out));
    let mean_shift: [f64; 3] = std::array::from_fn(|c| {
        if before[c] > 0.0 {
            after[c] / before[c] - 1.0
        } else {
            0.0
        }
    });
    let extra = layers.extra_channels();
    let mut channels = d.channels.clone();
    channels.extend_from_slice(extra);
    let m = channels.len();
    let mut data = Vec::with_capacity(n * m);
    for i in 0..n {
        data.extend_from_slice(&out[3 * i..3 * i + 3]);
        data.extend_from_slice(&d.data[i * nch + 3..(i + 1) * nch]);
        if layers == Layers::RawAndGuides {
            data.extend_from_slice(&d.data[i * nch..i * nch + 3]);
            data.extend_from_slice(&albedo[3 * i..3 * i + 3]);
            data.extend_from_slice(&normal[3 * i..3 * i + 3]);
        }
    }
    d.channels = channels;
    d.data = data;
    let seconds = start.elapsed().as_secs_f64();
    d.seconds += seconds;
    Ok(Denoised {
        seconds,
        mean_shift,
    })
}

/// A sink that denoises each frame and hands it on to `inner`.
pub struct DenoiseSink<'a, S: Sink> {
    pub inner: &'a mut S,
    pub denoiser: Denoiser,
    pub integrator: &'a Integrator<'a>,
    pub seed: u64,
    pub layers: Layers,
    /// Seconds spent denoising (guides included), over the frames of this process.
    pub seconds: f64,
    /// Whether a frame's mean moved past `MEAN_SHIFT_WARNING` has been said (once a process).
    pub warned: bool,
}

impl<S: Sink> Sink for DenoiseSink<'_, S> {
    fn put(&mut self, mut d: Developed) -> Result<()> {
        let done = denoise_frame(
            &mut self.denoiser,
            self.integrator,
            self.seed,
            self.layers,
            &mut d,
        )?;
        self.seconds += done.seconds;
        let shift = done.mean_shift;
        if !self.warned && shift.iter().any(|s| s.abs() > MEAN_SHIFT_WARNING) {
            self.warned = true;
            let said: Vec<String> = ["red", "green", "blue"]
                .iter()
                .zip(shift)
                .map(|(c, s)| format!("{:+.0}% in {c}", 100.0 * s))
                .collect();
            errln!(
                "warning: denoising moved frame {}'s mean by {} (its light comes from a few very \
                 bright points, such as small emitters seen directly, or the frame is small): it \
                 does not show the frame's radiance there; --denoise-layers keeps the raw \
                 radiance beside it{}",
                d.view.frame,
                said.join(", "),
                if self.layers == Layers::RawAndGuides {
                    " (raw.R, raw.G, raw.B)"
                } else {
                    ""
                }
            );
        }
        self.inner.put(d)
    }

    fn sync(&mut self) -> Result<Vec<(u32, u64)>> {
        self.inner.sync()
    }
}
