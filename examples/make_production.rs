//! Generates `scenes/production/`: a courtyard that looks like a production asset, lit by a sky
//! with a sun, paved with a stone texture, with wooden crates and plastered columns each placed
//! several times (instanced), and a camera move read from a camera file.
//!
//! ```text
//! cargo run --release --example make_production -- scenes/production
//! ```
//!
//! Writes `courtyard.toml`, `camera.json`, `sky.exr` (a lat-long HDR sky, 256 x 128), the
//! textures `tiles.png`, `wood.png`, `plaster.png` (8-bit sRGB, through reframe's own image
//! writer) and `ground.obj`, `crate.obj`, `column.obj` with their MTLs (`map_Kd`). Everything is
//! computed from closed forms and an integer hash, so the output is the same on every run (the
//! EXR's `DateTime` aside: pixels, PNGs and text files are byte for byte the same). It
//! then loads the scene through reframe's loader and checks it: no warnings, the crates and
//! columns instanced, the sun above the horizon on the side the shadows need, the textures read.
//!
//! Conventions: right-handed, y up, metres; faces wind counter-clockwise seen from outside.
use glam::{Vec2, Vec3};
use reframe::embree::Device;
use reframe::image::{write_image, Image, Metadata, WriteOptions};
use reframe::scene::Scene;
use std::f32::consts::PI;
use std::fmt::Write as _;
use std::path::Path;

/// An integer hash to [0, 1): per-tile and per-plank variation.
fn hash(a: u32, b: u32, c: u32) -> f32 {
    let mut h = a
        .wrapping_mul(0x9E37_79B1)
        .wrapping_add(b.wrapping_mul(0x85EB_CA77))
        .wrapping_add(c.wrapping_mul(0xC2B2_AE3D));
    h ^= h >> 15;
    h = h.wrapping_mul(0x2C1B_3C6D);
    h ^= h >> 12;
    h = h.wrapping_mul(0x297A_2D39);
    h ^= h >> 15;
    (h >> 8) as f32 / (1u32 << 24) as f32
}

fn image(w: u32, h: u32, f: impl Fn(u32, u32) -> Vec3) -> Image {
    let mut img = Image::new(w, h, &["R", "G", "B"]);
    for y in 0..h {
        for x in 0..w {
            let i = 3 * (y * w + x) as usize;
            img.data[i..i + 3].copy_from_slice(&f(x, y).to_array());
        }
    }
    img
}

/// The sun's direction (towards it): 35 degrees up, from the camera's left and behind it, so
/// that shadows fall to the back right.
fn sun() -> Vec3 {
    let elevation = 35f32.to_radians();
    let azimuth = 230f32.to_radians(); // about +Y, from -Z towards +X
    Vec3::new(
        elevation.cos() * azimuth.sin(),
        elevation.sin(),
        -elevation.cos() * azimuth.cos(),
    )
}

/// The lat-long sky, in the renderer's convention (docs/environment.md): texel centre (u, v)
/// looks along theta = v pi from +Y and phi = 2 pi u from -Z towards +X.
fn sky() -> Image {
    let (w, h) = (256u32, 128u32);
    let s = sun();
    image(w, h, |x, y| {
        let (u, v) = ((x as f32 + 0.5) / w as f32, (y as f32 + 0.5) / h as f32);
        let (theta, phi) = (v * PI, u * 2.0 * PI);
        let d = Vec3::new(
            theta.sin() * phi.sin(),
            theta.cos(),
            -theta.sin() * phi.cos(),
        );
        if d.dot(s) > 2.5f32.to_radians().cos() {
            return Vec3::new(900.0, 820.0, 700.0);
        }
        if d.y < 0.0 {
            // Below the horizon: the warm ground of the world beyond the courtyard.
            return Vec3::new(0.22, 0.19, 0.15);
        }
        let zenith = Vec3::new(0.12, 0.25, 0.62);
        let horizon = Vec3::new(0.62, 0.7, 0.82);
        let t = d.y.powf(0.45);
        // A glow around the sun.
        let glow = (d.dot(s).max(0.0)).powf(16.0) * 1.5;
        horizon.lerp(zenith, t) + Vec3::new(1.0, 0.85, 0.6) * glow
    })
}

/// Stone paving: 4 x 4 tiles per texture, grout lines, a colour per tile.
fn tiles() -> Image {
    image(256, 256, |x, y| {
        let (tx, ty) = (x / 64, y / 64);
        let (fx, fy) = (x % 64, y % 64);
        if fx < 3 || fy < 3 {
            return Vec3::new(0.18, 0.17, 0.16);
        }
        let k = hash(tx, ty, 1);
        let base = Vec3::new(0.55, 0.5, 0.43).lerp(Vec3::new(0.42, 0.4, 0.38), k);
        base * (0.9 + 0.15 * hash(x, y, 2))
    })
}

/// Planks across the texture, each with its own tone and a grain of stripes.
fn wood() -> Image {
    image(256, 256, |x, y| {
        let plank = y / 32;
        if y % 32 < 2 {
            return Vec3::new(0.1, 0.06, 0.03);
        }
        let tone = hash(plank, 7, 3);
        let grain = ((x as f32 * 0.09 + hash(plank, 1, 4) * 20.0).sin()
            + 0.5 * (x as f32 * 0.31 + y as f32 * 0.05).sin())
            * 0.5;
        let base = Vec3::new(0.5, 0.32, 0.17).lerp(Vec3::new(0.36, 0.22, 0.11), tone);
        base * (0.85 + 0.15 * grain)
    })
}

/// Plaster: an off-white with a faint mottle and a darker band near the foot.
fn plaster() -> Image {
    image(128, 128, |x, y| {
        let mottle = 0.9 + 0.1 * hash(x / 4, y / 4, 5);
        let c = if y > 112 {
            Vec3::new(0.45, 0.42, 0.38)
        } else {
            Vec3::new(0.78, 0.74, 0.66)
        };
        c * mottle
    })
}

/// An OBJ writer: vertices, texture coordinates, normals, faces of `v/vt[/vn]` corners.
#[derive(Default)]
struct Obj {
    text: String,
    v: usize,
    vt: usize,
    vn: usize,
}

impl Obj {
    fn new(mtl: &str, material: &str) -> Obj {
        Obj {
            text: format!("mtllib {mtl}\nusemtl {material}\n"),
            ..Obj::default()
        }
    }
    fn v(&mut self, p: Vec3) -> usize {
        writeln!(self.text, "v {:.6} {:.6} {:.6}", p.x, p.y, p.z).unwrap();
        self.v += 1;
        self.v
    }
    fn vt(&mut self, t: Vec2) -> usize {
        writeln!(self.text, "vt {:.6} {:.6}", t.x, t.y).unwrap();
        self.vt += 1;
        self.vt
    }
    fn vn(&mut self, n: Vec3) -> usize {
        let n = n.normalize();
        writeln!(self.text, "vn {:.6} {:.6} {:.6}", n.x, n.y, n.z).unwrap();
        self.vn += 1;
        self.vn
    }
    /// A face of corners (v, vt, vn or 0).
    fn f(&mut self, corners: &[(usize, usize, usize)]) {
        self.text.push('f');
        for &(v, t, n) in corners {
            if n == 0 {
                write!(self.text, " {v}/{t}").unwrap();
            } else {
                write!(self.text, " {v}/{t}/{n}").unwrap();
            }
        }
        self.text.push('\n');
    }
    /// A flat quad, corners counter-clockwise seen from its front, texture coordinates at them.
    fn quad(&mut self, p: [Vec3; 4], t: [Vec2; 4]) {
        let c: Vec<(usize, usize, usize)> =
            (0..4).map(|i| (self.v(p[i]), self.vt(t[i]), 0)).collect();
        self.f(&c);
    }
}

const UV: [Vec2; 4] = [
    Vec2::new(0.0, 0.0),
    Vec2::new(1.0, 0.0),
    Vec2::new(1.0, 1.0),
    Vec2::new(0.0, 1.0),
];

/// A 30 x 30 m paved ground at y = 0, the tile texture repeated 15 times each way (2 m a repeat,
/// 0.5 m a tile).
fn ground() -> String {
    let mut o = Obj::new("ground.mtl", "paving");
    let h = 15.0;
    o.quad(
        [
            Vec3::new(-h, 0.0, h),
            Vec3::new(h, 0.0, h),
            Vec3::new(h, 0.0, -h),
            Vec3::new(-h, 0.0, -h),
        ],
        UV.map(|t| t * 15.0),
    );
    o.text
}

/// A 1 m crate standing on y = 0, centred on x = z = 0, each face showing the whole wood texture.
fn crate_() -> String {
    let mut o = Obj::new("crate.mtl", "wood");
    let c = |x: f32, y: f32, z: f32| Vec3::new(x - 0.5, y, z - 0.5);
    let faces = [
        [c(0., 0., 1.), c(1., 0., 1.), c(1., 1., 1.), c(0., 1., 1.)], // +z
        [c(1., 0., 0.), c(0., 0., 0.), c(0., 1., 0.), c(1., 1., 0.)], // -z
        [c(1., 0., 1.), c(1., 0., 0.), c(1., 1., 0.), c(1., 1., 1.)], // +x
        [c(0., 0., 0.), c(0., 0., 1.), c(0., 1., 1.), c(0., 1., 0.)], // -x
        [c(0., 1., 1.), c(1., 1., 1.), c(1., 1., 0.), c(0., 1., 0.)], // +y
        [c(0., 0., 0.), c(1., 0., 0.), c(1., 0., 1.), c(0., 0., 1.)], // -y
    ];
    for f in faces {
        o.quad(f, UV);
    }
    o.text
}

/// A column of radius 0.35 m and height 3 m on y = 0: 32 smooth sides (the plaster texture
/// once around, twice up) and flat caps.
fn column() -> String {
    let mut o = Obj::new("column.mtl", "plaster");
    let (n, r, h) = (32usize, 0.35f32, 3.0f32);
    let ring = |k: usize| {
        let a = k as f32 / n as f32 * 2.0 * PI;
        Vec3::new(a.sin(), 0.0, a.cos())
    };
    for k in 0..n {
        let (d0, d1) = (ring(k), ring(k + 1));
        let (u0, u1) = (k as f32 / n as f32, (k + 1) as f32 / n as f32);
        let c = [
            (o.v(d0 * r), o.vt(Vec2::new(u0, 0.0)), o.vn(d0)),
            (o.v(d1 * r), o.vt(Vec2::new(u1, 0.0)), o.vn(d1)),
            (
                o.v(d1 * r + Vec3::Y * h),
                o.vt(Vec2::new(u1, 2.0)),
                o.vn(d1),
            ),
            (
                o.v(d0 * r + Vec3::Y * h),
                o.vt(Vec2::new(u0, 2.0)),
                o.vn(d0),
            ),
        ];
        o.f(&c);
    }
    // Caps: a fan polygon each (reframe ear-clips it), flat-shaded.
    for (y, up) in [(h, true), (0.0, false)] {
        let mut c: Vec<(usize, usize, usize)> = (0..n)
            .map(|k| {
                let d = ring(k);
                (
                    o.v(d * r + Vec3::Y * y),
                    o.vt(Vec2::new(0.5 + 0.5 * d.x, 0.5 + 0.5 * d.z)),
                    0,
                )
            })
            .collect();
        // The ring runs counter-clockwise seen from above (+z towards +x): reverse it for the
        // bottom.
        if !up {
            c.reverse();
        }
        o.f(&c);
    }
    o.text
}

/// 48 frames: the camera walks an arc across the courtyard, eye 1.6 m up, and turns to keep the
/// arrangement in view, easing in and out.
fn camera() -> String {
    let mut s = String::from("{\"frames\": [\n");
    for f in 0..48 {
        let t = f as f32 / 47.0;
        let e = t * t * (3.0 - 2.0 * t);
        let a = (-28.0 + 40.0 * e).to_radians();
        let radius = 8.2 - 1.2 * e;
        let eye = Vec3::new(radius * a.sin(), 1.6 + 0.15 * e, radius * a.cos());
        let look = Vec3::new(0.3 * e, 1.0, -0.5);
        let sep = if f < 47 { "," } else { "" };
        writeln!(
            s,
            "{{\"frame\": {f}, \"fov\": 48.0, \"position\": [{:.5}, {:.5}, {:.5}], \"look_at\": [{:.5}, {:.5}, {:.5}], \"up\": [0, 1, 0]}}{sep}",
            eye.x, eye.y, eye.z, look.x, look.y, look.z
        )
        .unwrap();
    }
    s.push_str("]}\n");
    s
}

const TOML: &str = r#"# A courtyard, generated by examples/make_production.rs: paving, wooden crates and plastered
# columns (each OBJ placed several times: instanced), lit by a sky with a sun, seen along a
# camera move from a camera file.
frames = 48
resolution = [320, 240]
camera = "camera.json"

[environment]
image = "sky.exr"
intensity = 1.0
rotation = 0.0

[[object]]
obj = "ground.obj"

[[object]]
obj = "crate.obj"
translate = [-1.4, 0.0, 0.6]
rotate = [0.0, 20.0, 0.0]

[[object]]
obj = "crate.obj"
translate = [-0.3, 0.0, 1.1]
rotate = [0.0, -12.0, 0.0]
scale = 0.8

[[object]]
obj = "crate.obj"
translate = [-1.0, 1.0, 0.7]
rotate = [0.0, 55.0, 0.0]
scale = 0.7

[[object]]
obj = "crate.obj"
# 1.2 m wide and deep, 0.6 m high: a matrix (row-major, object to world), turned 30 degrees about +Y.
matrix = [1.039230, 0.0, 0.6, 1.6,  0.0, 0.6, 0.0, 0.0,  -0.6, 0.0, 1.039230, 0.9,  0.0, 0.0, 0.0, 1.0]

[[object]]
obj = "column.obj"
translate = [-3.0, 0.0, -2.5]

[[object]]
obj = "column.obj"
translate = [-1.0, 0.0, -2.5]

[[object]]
obj = "column.obj"
translate = [1.0, 0.0, -2.5]

[[object]]
obj = "column.obj"
translate = [3.0, 0.0, -2.5]
"#;

fn main() -> anyhow::Result<()> {
    let dir = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "scenes/production".into());
    let dir = Path::new(&dir);
    std::fs::create_dir_all(dir)?;
    let hdr = WriteOptions { exr_float: true };
    let meta = Metadata::default();
    write_image(&dir.join("sky.exr"), &sky(), &meta, &hdr)?;
    for (name, img) in [
        ("tiles.png", tiles()),
        ("wood.png", wood()),
        ("plaster.png", plaster()),
    ] {
        write_image(&dir.join(name), &img, &meta, &WriteOptions::default())?;
    }
    let files = [
        ("ground.obj", ground()),
        (
            "ground.mtl",
            "newmtl paving\nKd 1 1 1\nmap_Kd tiles.png\n".into(),
        ),
        ("crate.obj", crate_()),
        (
            "crate.mtl",
            "newmtl wood\nKd 0.95 0.95 0.95\nKs 0.04 0.04 0.04\nNs 20\nmap_Kd wood.png\n".into(),
        ),
        ("column.obj", column()),
        (
            "column.mtl",
            "newmtl plaster\nKd 1 1 1\nmap_Kd plaster.png\n".into(),
        ),
        ("camera.json", camera()),
        ("courtyard.toml", TOML.into()),
    ];
    for (name, text) in files {
        std::fs::write(dir.join(name), text)?;
    }
    // Read back through the renderer's own loader.
    let device = Device::new()?;
    let toml = dir.join("courtyard.toml");
    let scene = Scene::load(toml.to_str().unwrap(), &device)?;
    anyhow::ensure!(scene.warnings.is_empty(), "warnings: {:?}", scene.warnings);
    anyhow::ensure!(
        scene.prototypes.len() == 2 && scene.instances.len() == 8,
        "expected 2 prototypes and 8 instances, got {} and {}",
        scene.prototypes.len(),
        scene.instances.len()
    );
    anyhow::ensure!(scene.textures.as_ref().is_some_and(|t| t.len() == 3));
    anyhow::ensure!(scene.lights.tris.is_empty() && scene.environment.is_some());
    let s = sun();
    anyhow::ensure!(s.y > 0.5 && s.x < 0.0 && s.z > 0.0, "sun {s}");
    println!("wrote {} (sun towards {s})", dir.display());
    Ok(())
}
