//! The reuse kernel: trace the native samples of one block of tiles of each frame of a group,
//! find where each hit lands in every eye of the group, and splat its weighted value into each
//! of those frames' films.
//!
//! The unit of parallel work is one block of every frame of the group: the samples that the
//! group's eyes reuse into a frame around that block are summed in a window private to the
//! worker (`film::local::LocalFilm`) and added into the frame once, at the end, instead of with
//! atomic adds splat by splat. The block is traced tile by tile (a tile's samples are one
//! wavefront batch), and its splats are made frame by frame, so that consecutive splats fall on
//! neighbouring pixels of one window.
//!
//! Streaming and determinism: a window sums its splats in `f32`, in the block's order, and rounds
//! each pixel's sums once into the frame's fixed point with a hashed dither when it is flushed;
//! the frame's sums are integers, whose addition is associative. The blocks depend on the
//! resolution alone (`block_side`), so the frames are bitwise identical for any thread count.
use super::visibility::{landings, EyeView, HitLanes, Landing, NativeHit};
use super::weights::{EyeTerms, LambertWeighing, Weighing, SIDE_UNKNOWN};
use super::{Params, Weights};
use crate::camera::Camera;
use crate::embree::{Hit, Packet16, Ray};
use crate::film::local::LocalFilm;
use crate::film::tiles::{tiles_in, Tile, TILE};
use crate::film::FrameAccum;
use crate::integrator::wavefront::Wavefront;
use crate::integrator::{Integrator, LightSides, Tally};
use crate::sampling::{mix64, Sampler};
use glam::{Vec2, Vec3};

/// One frame of a group: its eye and its film.
#[derive(Clone, Copy)]
pub struct Target<'a> {
    pub cam: &'a Camera,
    pub film: &'a FrameAccum,
    /// `mis-cv`: this group is the only one that reaches the frame, so its splats are folded by
    /// the parity of the sample index within the pixel, not the group's
    /// (`Method::sample_folds`).
    pub split: bool,
}

impl Target<'_> {
    /// The one fold that every splat of the group starting at frame `g0` into this frame goes
    /// to, where the film has two and the group is not split by sample index (`fold`).
    #[inline]
    fn only_fold(&self, g0: u32) -> Option<usize> {
        (self.film.layout.norm.folds() >= 2 && !self.split).then_some((g0 % 2) as usize)
    }

    /// The control variate's fold of the splats of sample `s` (its index within its pixel) of
    /// the group starting at frame `g0` into this frame (0 where the film has one fold).
    #[inline]
    fn fold(&self, g0: u32, s: u32) -> usize {
        self.folding(g0).of(s)
    }

    /// `fold` for every sample of the group starting at `g0`, its rule found once.
    #[inline]
    fn folding(&self, g0: u32) -> Folding {
        if self.film.layout.norm.folds() < 2 {
            Folding { base: 0, mask: 0 }
        } else if self.split {
            Folding { base: 0, mask: 1 }
        } else {
            Folding {
                base: (g0 % 2) as usize,
                mask: 0,
            }
        }
    }
}

/// A frame's rule for the fold of a sample's splats (`Target::folding`): `base + (s & mask)`.
#[derive(Clone, Copy)]
struct Folding {
    base: usize,
    mask: u32,
}

impl Folding {
    #[inline]
    fn of(self, s: u32) -> usize {
        self.base + (s & self.mask) as usize
    }
}

/// The side of the reuse kernel's blocks (`shade_block`) for a `w` x `h` frame: the largest of
/// 64, 32 and 16 pixels that makes 16 blocks or more.
///
/// Why large: a window gathers what the group's eyes reuse into its frame around the block,
/// which the group's other eyes see shifted (on `vase` at n_f = 17, a 16-pixel tile's window
/// grows to about 66 x 66 pixels), so with small blocks a window pixel receives about one splat
/// and adding the window into the frame costs as many atomic adds as direct splats would. A
/// 64-pixel block's windows receive several splats per pixel. Why not larger: a group ends when
/// its last block does, so workers with few blocks each wait longer for the slowest; eight per
/// worker rather than 16 (64-pixel blocks on a 320x240 frame at 2 threads, not 32) rendered
/// `mis-cv` at n_f = 17 3.3% faster (6 interleaved runs of 34 frames, 20.53 s against 19.86 s).
/// Why not from the thread count: a window sums its splats in floating point, in the block's
/// order (`film::local`), so the blocks must not depend on the threads for the frames to be
/// the same to the bit for any number of them; 16 blocks keep 8 per worker at 2 threads, and a
/// production frame (1920x1080: 510 blocks of 64) has many per worker at any thread count.
pub fn block_side(w: u32, h: u32) -> u32 {
    for side in [4 * TILE, 2 * TILE] {
        if w.div_ceil(side) * h.div_ceil(side) >= 16 {
            return side;
        }
    }
    TILE
}

/// Trace the native samples of block `block` (`block_side`) of every frame of a group (the
/// group starts at frame `g0`), a tile at a time, and splat every reuse of them into the
/// group's films. `counts`: per frame of the group, the adaptive native count of each pixel
/// (`None`: `n_r` everywhere). Returns the number of non-finite contributions dropped.
pub fn shade_block(
    integrator: &Integrator,
    p: &Params,
    group: &[Target],
    block: Tile,
    g0: u32,
    counts: Option<&[Vec<u16>]>,
    tally: &mut Tally,
) -> u64 {
    // The windows' flush rounding, named by the group and the block (each window mixes in its
    // frame, `LocalFilm::new`).
    let key = mix64(mix64(p.seed ^ g0 as u64) ^ ((block.0 as u64) << 32 | block.1 as u64));
    let mut films: Vec<LocalFilm> = group
        .iter()
        .map(|t| LocalFilm::new(t.film, block, t.only_fold(g0), key))
        .collect();
    let mut scratch = Scratch {
        pixel_areas: group.iter().map(|t| t.cam.pixel_area()).collect(),
        group_eyes: group.iter().map(|t| t.cam.eye).collect(),
        ..Scratch::default()
    };
    let mut bad = 0;
    for tile in tiles_in(block, TILE) {
        for m in 0..group.len() {
            bad += shade_eye(
                integrator,
                p,
                group,
                m,
                tile,
                g0,
                counts,
                &mut films,
                &mut scratch,
                tally,
            );
        }
    }
    for f in films {
        f.flush();
    }
    bad
}

/// What `shade_eye` needs room for, kept from one eye to the next.
#[derive(Default)]
struct Scratch {
    hits: Vec<NativeHit>,
    /// Camera samples that left the scene: (pixel, sample index, direction); kept for the
    /// control variate only, whose weights must cover every direction a pixel sees.
    escapes: Vec<(u32, u32, Vec3)>,
    land: Vec<Landing>,
    /// How each eye of the group sees each hit (`land`'s order), and the hits' points and
    /// normals in lanes.
    views: Vec<EyeView>,
    lanes: HitLanes,
    eyes: Vec<EyeTerms>,
    /// `A_pix,k` of each eye of the group.
    pixel_areas: Vec<f32>,
    /// Each eye of the group's position (`LightSides::Group`).
    group_eyes: Vec<Vec3>,
    /// The tile's camera samples before their primary rays: (pixel, sample index, sampler, ray
    /// direction), row by row.
    pending: Vec<(u32, u32, Sampler, Vec3)>,
    natives: Natives,
    /// What each hit adds where it lands in each eye, eye by eye (`[k * hits + hi]`): RGB and
    /// the control variate's weight.
    splats: Vec<[f32; 4]>,
    /// Each hit's rounding dither, before the target frame is hashed in.
    dithers: Vec<Dither>,
    /// The side of a Lambertian hit's surface each eye of the group sees (`LambertWeighing`).
    eye_sides: Vec<u8>,
}

/// The native samples of tile `(x0, y0, x1, y1)` of frame `group[m]`, splatted into `films`
/// (the worker's windows of the group's films, in the group's order).
#[allow(clippy::too_many_arguments)]
fn shade_eye(
    integrator: &Integrator,
    p: &Params,
    group: &[Target],
    m: usize,
    (x0, y0, x1, y1): Tile,
    g0: u32,
    counts: Option<&[Vec<u16>]>,
    films: &mut [LocalFilm],
    scratch: &mut Scratch,
    tally: &mut Tally,
) -> u64 {
    let native = group[m];
    let cam_m = native.cam;
    let native_frame = native.film.frame();
    let w = cam_m.width;
    let spp = p.spp;
    let n_f = group.len();
    // Native samples of eye k in its pixel i: `--spp`, or the adaptive count.
    let n_at = |k: usize, i: u32| counts.map_or(spp, |c| c[k][i as usize] as u32);
    // Sample indices of a frame in a group: a stride that fits the most samples a pixel shoots.
    let stride = if counts.is_some() {
        spp * n_f as u32
    } else {
        spp
    };
    // Whether the film keeps the control variate's weights (and folds, `Target::fold`).
    let cv = native.film.weight_sums().is_some();
    // Camera samples that leave the scene are kept where they count: as points at infinity for
    // the control variate's weights, and for the environment's radiance where there is one.
    let keep_escapes = cv || integrator.scene.environment.is_some();
    // The sample index of the frame's first sample in a pixel (see `index` below).
    let first_index = (native_frame - g0) * stride;
    let mut landed_native = 0u64;
    let Scratch {
        hits,
        escapes,
        land,
        views,
        lanes,
        eyes,
        pixel_areas,
        group_eyes,
        pending,
        natives,
        splats,
        dithers,
        eye_sides,
    } = scratch;
    hits.clear();
    escapes.clear();
    // A group that reaches a frame folded by sample index (the first or the last of the run's
    // frames, `Target::split`) splats every eye's sample `s` into fold `s mod 2` there, so every
    // eye's samples of the group come in two independent streams, one per parity: a native
    // frame also reached by other groups drew its samples from its fold's stratified stream,
    // in which a pixel's consecutive samples are dependent, and the two folds' dependence made
    // the control variate biased there (a fifth of a percent to 3% dark at 2 spp). The streams
    // are apart from the fold streams (0, 1, 1000, 1001) and from those of the run's other end
    // group, which may share native frames with this one.
    let split_streams = group[m].film.layout.norm.folds() >= 2 && group.iter().any(|t| t.split);
    let split_base = if group[0].split { 2 } else { 4 };
    // A frame's native samples in all the groups of a fold are one stratified stream (the
    // groups of the other fold another), sample `s < spp` of the frame's position `q` in the
    // group at index `q * spp + s` (with the control variate's two folds, the positions of one
    // fold are every other one: `(q / 2) * spp + s`), so that the groups' samples of a pixel are
    // a gapless prefix of the stream.
    let position = native_frame - g0;
    // (the fold's stream, the frame's place among the fold's groups)
    let (fold_stream, slot) = if cv && n_f > 1 {
        (g0 % 2, position / 2)
    } else {
        (0, position)
    };
    for y in y0..y1 {
        for x in x0..x1 {
            let pixel = y * w + x;
            let n_p = n_at(m, pixel);
            films[m].land(pixel as usize, n_p);
            landed_native += n_p as u64;
            for s in 0..n_p {
                // Sample index within the group: the frame's position in the group, then `s`.
                let index = first_index + s;
                // The fold's stream (above), or, where the control variate folds by the sample
                // index, a stream per parity of `s`, so that its two folds are independent
                // samplings (docs/sampler.md).
                let mut sampler = if split_streams {
                    Sampler::stratified(p.seed, native_frame, pixel, split_base + s % 2, s / 2)
                } else if s < spp {
                    Sampler::stratified(p.seed, native_frame, pixel, fold_stream, slot * spp + s)
                } else {
                    // An adaptive extra sample: a stream of its own per fold, so that the
                    // `--spp` samples of every group stay one gapless stratified stream.
                    let extra = slot * (stride - spp) + (s - spp);
                    Sampler::stratified(p.seed, native_frame, pixel, fold_stream + 1000, extra)
                };
                let r = Vec2::new(x as f32, y as f32) + sampler.next_2d();
                pending.push((pixel, index, sampler, cam_m.direction(r)));
            }
        }
    }
    // The MIS weights count every eye's light sampling for every direction, so a light sample
    // behind the surface is kept where an eye of the group sees that side; the weights of the
    // native eye's densities (`havran`) serve that eye alone.
    let sides = match p.method.weights() {
        Weights::Paper | Weights::Exact => LightSides::Group(group_eyes),
        Weights::None | Weights::OwnEye => LightSides::Native,
    };
    natives.trace(
        integrator,
        cam_m,
        pending,
        (keep_escapes, sides),
        hits,
        escapes,
        tally,
    );
    // Where each hit lands in each eye of the group (None: occluded or off the film), and how
    // each eye sees it.
    land.clear();
    land.resize(hits.len() * n_f, None);
    // (`landings` writes every hit's view from every eye, so what an earlier tile left in
    // `views` needs no clearing.)
    if views.len() < hits.len() * n_f {
        views.resize(hits.len() * n_f, EyeView::default());
    }
    lanes.fill(hits);
    for (k, t) in group.iter().enumerate() {
        if k == m {
            for (hi, (pixel, _, _)) in hits.iter().enumerate() {
                land[hi * n_f + k] = Some(*pixel);
            }
        }
        landings(
            integrator,
            (t.cam, pixel_areas[k]),
            lanes,
            (k, n_f),
            k == m,
            p.packets,
            land,
            Some(views),
            tally,
        );
    }
    let weights = p.method.weights();
    let mut bad = 0u64;
    films[m].add_counts(landed_native, 0, 0);
    eyes.clear();
    eyes.resize(n_f, EyeTerms::new(Vec3::ZERO, 0.0, 0.0));
    // First what every hit is worth in every eye that sees it, hit by hit (the weights need
    // all the eyes of a hit at once), then the splats eye by eye: one frame's window at a time,
    // in the tile's pixel order, so that consecutive splats fall on neighbouring pixels of one
    // window, which stays in cache, where hit by hit they went to every window of the group in
    // turn. A window's splats come in the same order for any thread count (`block_side`).
    // (`splats` is written where a hit lands and read only there, so what an earlier tile left
    // in it needs no clearing.)
    let nh = hits.len();
    splats.resize(nh * n_f, [0.0; 4]);
    dithers.clear();
    eye_sides.resize(n_f, SIDE_UNKNOWN);
    for (hi, (pixel, index, fh)) in hits.iter().enumerate() {
        dithers.push(Dither::of(p.seed, native_frame, *pixel, *index));
        let (row, seen) = (&land[hi * n_f..][..n_f], &views[hi * n_f..][..n_f]);
        // A hit on a Lambertian surface (most of them): the weights straight from the views.
        let eye = |k: usize| row[k].map(|i| (seen[k].wo, seen[k].j_over_a, n_at(k, i) as f32));
        if let Some(weighing) = LambertWeighing::new(weights, fh, spp, n_f, eye, eye_sides) {
            let d = weighing.denominators().emit;
            for k in 0..n_f {
                if row[k].is_some() {
                    let j_over_a = seen[k].j_over_a;
                    let v = weighing.value(eye_sides[k], j_over_a);
                    let w = if cv && d > 0.0 {
                        j_over_a / d
                    } else {
                        f32::NAN
                    };
                    splats[k * nh + hi] = [v.x, v.y, v.z, w];
                }
            }
            continue;
        }
        // Each field written in place: a whole `EyeTerms` built aside and copied in is read
        // back wider than it was written, which stalls the store buffer (a third of this
        // loop's time in `perf`).
        for (k, e) in eyes.iter_mut().enumerate() {
            let v = &views[hi * n_f + k];
            e.wo = v.wo;
            e.f = None;
            match land[hi * n_f + k] {
                Some(i) => {
                    e.j_over_a = v.j_over_a;
                    e.n = n_at(k, i) as f32;
                }
                // The weights read nothing else of an eye that cannot see x.
                None => {
                    e.j_over_a = 0.0;
                    e.n = 0.0;
                }
            }
        }
        let weighing = Weighing::new(weights, fh, eyes, spp);
        // The sample's weight in eye k, `(J_k / A_pix,k) / sum_k' D_k'` (the control
        // variate's; NaN where there is none, which would quantise to nothing).
        let d = weighing.denominators().emit;
        for (k, t) in group.iter().enumerate() {
            if land[hi * n_f + k].is_some() {
                let v = weighing.value(t.cam.eye, &eyes[k]);
                let w = if cv && d > 0.0 {
                    eyes[k].j_over_a / d
                } else {
                    f32::NAN
                };
                splats[k * nh + hi] = [v.x, v.y, v.z, w];
            }
        }
    }
    for (k, (t, film)) in group.iter().zip(films.iter_mut()).enumerate() {
        let frame = t.film.frame();
        let folding = t.folding(g0);
        let splats = &splats[k * nh..(k + 1) * nh];
        for (hi, ((_, index, fh), &[x, y, z, w])) in hits.iter().zip(splats).enumerate() {
            let Some(i) = land[hi * n_f + k] else {
                if k != m {
                    film.add_counts(0, 1, 1);
                    // Only reuses lost to occlusion fall on a pixel of the target.
                    if t.film.layout.loss {
                        if let Some(i) = t.cam.pixel_of(fh.sp.p) {
                            film.try_reuse(i as usize, true);
                        }
                    }
                }
                continue;
            };
            if k != m {
                film.add_counts(1, 1, 0);
            }
            let key = dithers[hi].key(frame);
            let fold = folding.of(index - first_index);
            if !film.reuse(i as usize, fold, Vec3::new(x, y, z), w, key, k != m) {
                bad += 1;
            }
        }
    }
    for &(pixel, index, dir) in escapes.iter() {
        if weights == Weights::Exact {
            bad += splat_escape(
                integrator,
                p,
                group,
                m,
                (g0, first_index),
                (pixel, index, dir),
                &n_at,
                films,
                tally,
            );
            continue;
        }
        // The ratio estimators average what lands by count, and the sample is already counted
        // in its own pixel: it adds the environment's radiance there.
        let le = integrator.scene.env_radiance(dir);
        if le != Vec3::ZERO {
            let key = Dither::of(p.seed, native_frame, pixel, index).key(native_frame);
            if !films[m].splat(pixel as usize, 0, le, key) {
                bad += 1;
            }
        }
    }
    bad
}

/// Camera samples traced together as one wavefront: a tile's pixels, as many as the independent
/// tracer's batches (more measured no faster, and a tile's samples at a high `--spp` would hold
/// tens of megabytes per worker).
const BATCH: usize = (TILE * TILE) as usize;

/// Bytes a worker holds for one tile of `tile_pixels` pixels (a full tile's, or fewer where the
/// frame is smaller) of one frame's native samples, at most `samples` per pixel (`--spp`, or
/// `n_f` times it with `--adaptive`) in a group of `n_f` frames: every camera
/// sample before its primary ray, every hit's record, its point and normal in lanes, and its
/// landing, view terms and splat in each eye, its dither, the escapes, and one wavefront batch (for
/// `RenderOptions::memory_estimate`).
pub fn worker_bytes(samples: u32, n_f: u32, tile_pixels: u64) -> u64 {
    use std::mem::size_of;
    let per_sample = size_of::<(u32, u32, Sampler, Vec3)>()
        + size_of::<NativeHit>()
        + n_f as usize * (size_of::<Landing>() + size_of::<EyeView>() + size_of::<[f32; 4]>())
        + size_of::<Dither>()
        + HitLanes::bytes_per_hit()
        + size_of::<(u32, u32, Vec3)>();
    let tile = tile_pixels.min((TILE * TILE) as u64) * samples as u64 * per_sample as u64;
    tile + (BATCH * (Wavefront::bytes_per_path() + size_of::<(u32, u32)>())) as u64
}

/// The tracer of a tile's native samples, and its room.
#[derive(Default)]
struct Natives {
    packet: Packet16,
    wavefront: Wavefront,
    /// The samples whose primary rays hit a surface: (pixel, sample index), hit, sampler.
    found: Vec<(u32, u32)>,
    hits: Vec<Hit>,
    samplers: Vec<Sampler>,
}

impl Natives {
    /// Trace the camera samples `pending` (their primary rays 16 consecutive samples to a
    /// packet, `Integrator::primary_hits`; then their paths together, `BATCH` samples at a
    /// time, `Integrator::first_hits`) and record their first hits (and, with `keep_escapes`,
    /// the samples that left the scene) in the order they were queued, as `trace_first_hit`
    /// would.
    #[allow(clippy::too_many_arguments)]
    fn trace(
        &mut self,
        integrator: &Integrator,
        cam: &Camera,
        pending: &mut Vec<(u32, u32, Sampler, Vec3)>,
        (keep_escapes, sides): (bool, LightSides),
        hits: &mut Vec<NativeHit>,
        escapes: &mut Vec<(u32, u32, Vec3)>,
        tally: &mut Tally,
    ) {
        let mut dirs = [Vec3::ZERO; 16];
        for batch in pending.chunks(BATCH) {
            self.found.clear();
            self.hits.clear();
            self.samplers.clear();
            for chunk in batch.chunks(16) {
                for (d, p) in dirs.iter_mut().zip(chunk) {
                    *d = p.3;
                }
                let lanes =
                    integrator.primary_hits(cam.eye, &dirs[..chunk.len()], &mut self.packet, tally);
                for (&(pixel, index, ref sampler, dir), hit) in chunk.iter().zip(lanes) {
                    match hit {
                        Some(hit) => {
                            self.found.push((pixel, index));
                            self.hits.push(hit);
                            self.samplers.push(sampler.clone());
                        }
                        None if keep_escapes => escapes.push((pixel, index, dir)),
                        None => {}
                    }
                }
            }
            let recs = integrator.first_hits(
                cam.eye,
                &self.hits,
                &self.samplers,
                &mut self.wavefront,
                tally,
                sides,
            );
            hits.extend(
                self.found
                    .iter()
                    .zip(recs)
                    .map(|(&(pixel, index), fh)| (pixel, index, *fh)),
            );
        }
        pending.clear();
    }
}

/// What the rounding dither of a native sample's splat is hashed from, where the splat is
/// rounded on its own (outside a window, `LocalFilm::splat`): the dither is `mix64(key)`, with
/// the key `mix64(seed ^ (frame << 32 | pixel)) ^ (index << 32 | target)`, whose part that
/// names the sample is hashed once per sample.
#[derive(Clone, Copy)]
struct Dither(u64);

impl Dither {
    fn of(seed: u64, native_frame: u32, pixel: u32, index: u32) -> Dither {
        Dither(mix64(seed ^ ((native_frame as u64) << 32 | pixel as u64)) ^ ((index as u64) << 32))
    }

    /// The key of the splat into frame `target`.
    #[inline]
    fn key(self, target: u32) -> u64 {
        self.0 ^ target as u64
    }
}

/// A camera sample of eye `group[m]` that left the scene along `dir`, reused with the exact
/// weights (docs/estimators.md, "Background pixels"): a point at infinity, which eye k sees
/// where `dir` projects onto its film if the ray from its eye along `dir` escapes too, with the
/// film density of a direction `J_k = 1 / cos_t^3`. Its weight `(J_k / A_pix,k) / sum_k' D_k'` in
/// every eye that sees it goes into the control variate's weight sums (so that the weights
/// landing in a pixel sum to one in expectation also where the pixel sees the background), and
/// that weight times the environment's radiance along `dir` (the same for every eye) into the
/// sums. Returns the number of non-finite contributions dropped.
#[allow(clippy::too_many_arguments)]
fn splat_escape(
    integrator: &Integrator,
    p: &Params,
    group: &[Target],
    m: usize,
    (g0, first_index): (u32, u32),
    (pixel, index, dir): (u32, u32, Vec3),
    n_at: &dyn Fn(usize, u32) -> u32,
    films: &mut [LocalFilm],
    tally: &mut Tally,
) -> u64 {
    let geometry = &integrator.scene.geometry;
    // Per eye: the pixel `dir` lands in and `J_k / A_pix,k`, where the eye sees it.
    let seen: Vec<Option<(u32, f32)>> = group
        .iter()
        .enumerate()
        .map(|(k, t)| {
            let i = if k == m {
                pixel
            } else {
                let i = t.cam.pixel_of_dir(dir)?;
                tally.counts.visibility += 1;
                if geometry.occluded1(&Ray::new(t.cam.eye, dir)) {
                    return None;
                }
                i
            };
            Some((i, t.cam.jacobian_dir(dir) / t.cam.pixel_area()))
        })
        .collect();
    let total: f32 = seen
        .iter()
        .enumerate()
        .filter_map(|(k, s)| s.map(|(i, j)| n_at(k, i) as f32 * j))
        .sum();
    if total <= 0.0 {
        return 0;
    }
    let le = integrator.scene.env_radiance(dir);
    let sample = Dither::of(p.seed, group[m].film.frame(), pixel, index);
    let mut bad = 0;
    for ((f, s), t) in films.iter_mut().zip(&seen).zip(group) {
        if let Some((i, j)) = *s {
            let key = sample.key(f.film().frame());
            let fold = t.fold(g0, index - first_index);
            if le != Vec3::ZERO && !f.splat(i as usize, fold, le * (j / total), key) {
                bad += 1;
            }
            f.splat_weight(i as usize, fold, j / total, mix64(key));
        }
    }
    bad
}
