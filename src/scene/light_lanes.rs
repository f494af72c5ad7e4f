//! Light samples for a batch of shading points at once (the wavefront's rounds): each lane gets
//! `Scene::sample_light`'s answer to the bit.
//!
//! A light sample is a short chain of dependent divisions and square roots (the stretch of the
//! number, the point on the triangle, the distance, the direction), which one path at a time
//! waits on. Here the picks and the memory reads are made path by path, and the arithmetic
//! (`area_sample`, the same function `sample_light` calls) runs over 16 paths at a time in SIMD
//! lanes. The environment's samples are taken path by path, as `sample_light` takes them.
use super::{area_sample, AreaInputs, AreaPick, AreaSample, LightPick, LightSample, Scene};
use glam::{Vec2, Vec3};

const LANES: usize = 16;

/// One chunk of area-light samples, a column per number: what `area_sample` reads and gives,
/// lane by lane.
#[derive(Default)]
struct Chunk {
    ux: [f32; LANES],
    uy: [f32; LANES],
    lo: [f32; LANES],
    width: [f32; LANES],
    /// The corners' coordinates: `c[3 * corner + axis]`.
    c: [[f32; LANES]; 9],
    n: [[f32; LANES]; 3],
    pdf_area: [f32; LANES],
    x: [[f32; LANES]; 3],
    b1: [f32; LANES],
    b2: [f32; LANES],
    p: [[f32; LANES]; 3],
    wi: [[f32; LANES]; 3],
    dist: [f32; LANES],
    cos_l: [f32; LANES],
    pdf: [f32; LANES],
}

impl Chunk {
    #[inline(always)]
    fn set(&mut self, l: usize, a: &AreaInputs) {
        (self.ux[l], self.uy[l], self.lo[l], self.width[l]) = (a.u.x, a.u.y, a.lo, a.width);
        for (k, corner) in a.corners.iter().enumerate() {
            for (axis, v) in corner.to_array().into_iter().enumerate() {
                self.c[3 * k + axis][l] = v;
            }
        }
        for axis in 0..3 {
            self.n[axis][l] = a.n[axis];
            self.x[axis][l] = a.x[axis];
        }
        self.pdf_area[l] = a.pdf_area;
    }

    #[inline(always)]
    fn get(&self, l: usize) -> AreaSample {
        let v = |c: &[[f32; LANES]; 3]| Vec3::new(c[0][l], c[1][l], c[2][l]);
        AreaSample {
            b1: self.b1[l],
            b2: self.b2[l],
            p: v(&self.p),
            wi: v(&self.wi),
            dist: self.dist[l],
            cos_l: self.cos_l[l],
            pdf: self.pdf[l],
        }
    }
}

/// `area_sample` in every lane of a chunk, compiled for AVX-512 and AVX2 besides the portable
/// build and chosen at run time (IEEE arithmetic with nothing fused: the same bits in all).
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512cd+avx512dq+avx512vl",
    "x86_64+avx2",
))]
fn run(c: &mut Chunk) {
    for l in 0..LANES {
        let col = |v: &[[f32; LANES]], i: usize| Vec3::new(v[i][l], v[i + 1][l], v[i + 2][l]);
        let at = area_sample(&AreaInputs {
            u: Vec2::new(c.ux[l], c.uy[l]),
            lo: c.lo[l],
            width: c.width[l],
            corners: [col(&c.c, 0), col(&c.c, 3), col(&c.c, 6)],
            n: col(&c.n, 0),
            pdf_area: c.pdf_area[l],
            x: col(&c.x, 0),
        });
        (c.b1[l], c.b2[l]) = (at.b1, at.b2);
        for axis in 0..3 {
            c.p[axis][l] = at.p[axis];
            c.wi[axis][l] = at.wi[axis];
        }
        (c.dist[l], c.cos_l[l], c.pdf[l]) = (at.dist, at.cos_l, at.pdf);
    }
}

/// The room of `Scene::sample_lights`, kept from one batch to the next.
#[derive(Default)]
pub struct LightLanes {
    out: Vec<Option<LightSample>>,
    chunk: Box<Chunk>,
    /// The query and pick of each lane of the chunk being filled.
    lanes: Vec<(usize, AreaPick)>,
}

impl LightLanes {
    /// The light samples of the last `Scene::sample_lights`, one per query, in order.
    pub fn samples(&self) -> &[Option<LightSample>] {
        &self.out
    }

    /// Bytes held per query (for memory estimates).
    pub const BYTES_PER_QUERY: usize = std::mem::size_of::<Option<LightSample>>();
}

impl Scene {
    /// `sample_light(x, u)` for every query `(x, u)`, in their order.
    pub fn sample_lights<'l>(
        &self,
        queries: &[(Vec3, Vec2)],
        room: &'l mut LightLanes,
    ) -> &'l [Option<LightSample>] {
        room.out.clear();
        room.out.resize(queries.len(), None);
        room.lanes.clear();
        for (q, &(x, u)) in queries.iter().enumerate() {
            match self.pick_light(u) {
                None => {}
                Some(LightPick::Environment(u)) => room.out[q] = self.environment_sample(x, u),
                Some(LightPick::Area(pick)) => {
                    room.chunk
                        .set(room.lanes.len(), &self.area_inputs(&pick, x));
                    room.lanes.push((q, pick));
                    if room.lanes.len() == LANES {
                        self.finish_chunk(room);
                    }
                }
            }
        }
        if !room.lanes.is_empty() {
            self.finish_chunk(room);
        }
        &room.out
    }

    /// Run the chunk's filled lanes (the others hold earlier inputs, computed and dropped).
    fn finish_chunk(&self, room: &mut LightLanes) {
        run(&mut room.chunk);
        for (l, (q, pick)) in room.lanes.drain(..).enumerate() {
            room.out[q] = self.finish_area(&pick, &room.chunk.get(l));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::embree::Device;
    use crate::sampling::Sampler;

    /// Three emitting triangles of different areas and powers, one lit through a texture, one
    /// facing away from most points, a floor, and (with `env`) a sky of one colour.
    fn lights_scene(dir: &std::path::Path, env: bool) -> Scene {
        let obj = "mtllib s.mtl\n\
            v -5 0 -5\nv 5 0 -5\nv 5 0 5\nv -5 0 5\n\
            v -1 3 -1\nv 1 3 -1\nv 0 3 1\n\
            v 2 1 2\nv 4 1 2\nv 3 4 2\n\
            v -3 2 0\nv -2 2 0\nv -3 2.5 0.5\n\
            vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvt 0.3 0.6\nvt 0.9 0.1\n\
            usemtl floor\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n\
            usemtl lamp\nf 5/1 7/3 6/2\n\
            usemtl sign\nf 8/5 9/6 10/3\n\
            usemtl tiny\nf 11/1 12/2 13/4\n";
        let mtl = "newmtl floor\nKd 0.5 0.5 0.5\n\
            newmtl lamp\nKd 0 0 0\nKe 10 9 8\n\
            newmtl sign\nKd 0 0 0\nKe 3 3 3\nmap_Ke tiles.png\n\
            newmtl tiny\nKd 0 0 0\nKe 50 20 5\n";
        std::fs::write(dir.join("s.obj"), obj).unwrap();
        std::fs::write(dir.join("s.mtl"), mtl).unwrap();
        let tiles = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/production/tiles.png");
        std::fs::copy(tiles, dir.join("tiles.png")).unwrap();
        let sky = if env {
            "[environment]\nradiance = [0.2, 0.3, 0.4]\n"
        } else {
            ""
        };
        let toml = format!(
            "obj = \"s.obj\"\nframes = 1\nresolution = [8, 8]\n{sky}[[keyframe]]\nframe = 0\n\
             position = [0, 1, 8]\nlook_at = [0, 1, 0]\nup = [0, 1, 0]\nfov = 50.0\n"
        );
        let path = dir.join(if env { "env.toml" } else { "s.toml" });
        std::fs::write(&path, toml).unwrap();
        Scene::load(path.to_str().unwrap(), &Device::new().unwrap()).unwrap()
    }

    #[test]
    fn lanes_give_sample_light_to_the_bit() {
        // Every query of a batch against `sample_light` on its own, field by field: batches
        // that fill no chunk, part of one and several; numbers on the picks' boundaries; points
        // on a light (distance 0) and in its plane (seen edge-on); with and without an
        // environment among the lights.
        let dir = tempfile::tempdir().unwrap();
        let scenes = [
            (
                "cornell",
                Scene::load("cornell", &Device::new().unwrap()).unwrap(),
            ),
            ("lights", lights_scene(dir.path(), false)),
            ("lights and sky", lights_scene(dir.path(), true)),
        ];
        let bits = |l: &Option<LightSample>| {
            l.map(|l| {
                let v = [l.p, l.n, l.wi, l.le].map(|v| v.to_array().map(f32::to_bits));
                (v, l.dist.to_bits(), l.pdf.to_bits())
            })
        };
        let mut room = LightLanes::default();
        let mut s = Sampler::new(5, 0, 0, 0);
        for (name, scene) in &scenes {
            let (lo, hi) = scene
                .positions
                .iter()
                .fold((Vec3::MAX, Vec3::MIN), |(lo, hi), &p| {
                    (lo.min(p), hi.max(p))
                });
            let mut queries = Vec::new();
            for k in 0..2000 {
                let x = lo + (hi - lo) * Vec3::new(s.next_1d(), s.next_1d(), s.next_1d());
                let u = match k % 7 {
                    0 => Vec2::new(scene.env_select, s.next_1d()),
                    1 => Vec2::new(*scene.lights.cdf.first().unwrap(), 1.0 - f32::EPSILON),
                    2 => Vec2::new(0.0, 0.0),
                    _ => s.next_2d(),
                };
                queries.push((x, u));
            }
            // A light's own corner, and a point in a light's plane.
            let [i0, i1, _] = scene.triangles[scene.lights.tris[0] as usize];
            let (c0, c1) = (scene.positions[i0 as usize], scene.positions[i1 as usize]);
            queries.push((c0, Vec2::ZERO));
            queries.push((c0 + (c1 - c0) * 3.0, Vec2::new(0.4, 0.4)));
            let (mut env, mut area, mut none, mut dark) = (0, 0, 0, 0);
            for n in [0, 1, 15, 16, 17, 40, queries.len()] {
                let got = scene.sample_lights(&queries[..n], &mut room).to_vec();
                assert_eq!(got.len(), n);
                for (q, (&(x, u), l)) in queries.iter().zip(&got).enumerate() {
                    let want = scene.sample_light(x, u);
                    assert_eq!(bits(l), bits(&want), "{name}: query {q} of {n}: {x} {u}");
                    if n == queries.len() {
                        match l {
                            None => none += 1,
                            Some(l) if l.dist.is_infinite() => env += 1,
                            Some(l) if l.le == Vec3::ZERO => dark += 1,
                            Some(_) => area += 1,
                        }
                    }
                }
            }
            // The cases the batch must get right all occurred (with a sky, the query on the
            // light's corner picks the sky).
            let sky = scene.environment.is_some();
            let counts = format!("{name}: area {area}, back {dark}, none {none}, sky {env}");
            assert!(area > 200 && dark >= 5 && (none >= 1 || sky), "{counts}");
            assert!((env > 100) == sky, "{counts}");
        }
    }
}
