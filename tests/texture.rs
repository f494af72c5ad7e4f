//! Textures end to end: a checkerboard seen head-on against the analytic pattern (orientation,
//! the `map_Ke` path and 8-bit files), a textured reflectance under a uniform environment
//! (`map_Kd` times `Kd`, and the furnace's exact answer), the reuse methods unbiased on a
//! textured, environment-lit scene with background pixels (the z-test of tests/reuse.rs), and
//! damaged textures refused with one line before anything is written.
mod common;
mod stats;

use common::{files_under, reuse_renders};
use glam::{Vec2, Vec3};
use reframe::driver::{render_frame_independent, thread_pool};
use reframe::embree::Device;
use reframe::image::{write_image, Image, Metadata, Textures, WriteOptions};
use reframe::integrator::Integrator;
use reframe::reuse::Method;
use reframe::scene::Scene;
use reframe::state::key::scene_and_build_hashes;
use stats::{assert_unbiased, block_moments, z_test};
use std::path::Path;

/// The quad z = 0, x and y in [-1, 1], facing +z, with texture coordinates (0, 0) at its
/// bottom-left corner and (1, 1) at its top-right, in material `q`.
const QUAD: &str = "mtllib s.mtl\n\
    v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\n\
    vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
    usemtl q\nf 1/1 2/2 3/3 4/4\n";

/// 4 x 4 squares of 8 x 8 texels; the square in image row `r` (from the top) and column `c`:
/// red in the top-left corner square, else white where `r + c` is even, black where odd.
fn square(r: u32, c: u32) -> Vec3 {
    if (r, c) == (0, 0) {
        Vec3::new(1.0, 0.0, 0.0)
    } else if (r + c).is_multiple_of(2) {
        Vec3::ONE
    } else {
        Vec3::ZERO
    }
}

fn write_texture(path: &Path, size: u32, texel: impl Fn(u32, u32) -> Vec3, exr_float: bool) {
    let mut img = Image::new(size, size, &["R", "G", "B"]);
    for y in 0..size {
        for x in 0..size {
            let i = 3 * (y * size + x) as usize;
            img.data[i..i + 3].copy_from_slice(&texel(x, y).to_array());
        }
    }
    write_image(
        path,
        &img,
        &Metadata::default(),
        &WriteOptions { exr_float },
    )
    .unwrap();
}

fn write_scene(d: &Path, obj: &str, mtl: &str, toml: &str) -> String {
    std::fs::write(d.join("s.obj"), obj).unwrap();
    std::fs::write(d.join("s.mtl"), mtl).unwrap();
    let p = d.join("s.toml");
    std::fs::write(&p, toml).unwrap();
    p.to_str().unwrap().to_string()
}

/// `checker.png` in `dir`: `square`'s 32 x 32 texels, 8-bit sRGB.
fn write_checker(dir: &Path) {
    write_texture(
        &dir.join("checker.png"),
        32,
        |x, y| square(y / 8, x / 8),
        false,
    );
}

/// A folder holding `checker.png` (`write_checker`), a device and a pool of one thread.
fn checker_setup() -> (tempfile::TempDir, Device, rayon::ThreadPool) {
    let dir = tempfile::tempdir().unwrap();
    write_checker(dir.path());
    (dir, Device::new().unwrap(), thread_pool(1).unwrap())
}

/// `QUAD` with the materials `mtl` under a white sky, seen from (0, 0, 2) at 16 x 16 and 4 spp
/// (written into `dir`, loaded, rendered on `pool`): its pixels and the scene's warnings.
fn quad_under_sky(
    dir: &Path,
    mtl: &str,
    device: &Device,
    pool: &rayon::ThreadPool,
) -> (Vec<Vec3>, Vec<String>) {
    let sky = "[environment]\nradiance = [1, 1, 1]";
    let path = write_scene(dir, QUAD, mtl, &toml(16, 16, [0.0, 0.0, 2.0], 40.0, sky));
    let scene = Scene::load(&path, device).unwrap();
    let integ = Integrator::new(&scene, 2);
    let cam = scene.camera(0, 16, 16);
    let px = pool
        .install(|| render_frame_independent(&integ, &cam, 0, 4, 1, false, &|_| {}))
        .pixels;
    (px, scene.warnings)
}

/// A camera at `position` looking at the origin, `frames` frames, `w` x `h`, and `extra` TOML.
fn toml(w: u32, h: u32, position: [f32; 3], fov: f32, extra: &str) -> String {
    format!(
        "obj = \"s.obj\"\nframes = 1\nresolution = [{w}, {h}]\n{extra}\n\
         [[keyframe]]\nframe = 0\nposition = {position:?}\nlook_at = [0.0, 0.0, 0.0]\n\
         up = [0.0, 1.0, 0.0]\nfov = {fov}\n"
    )
}

/// An 8-bit colour file is sRGB-encoded unless it says otherwise, whatever its format: OIIO
/// names the encoding of PNG and JPEG but not of TGA or BMP, which were read as linear codes
/// (a mid-grey 1.7-2x too bright against other renderers). The same ramp written as PNG, TGA,
/// BMP and 8-bit TIFF must read back as the same linear values, as an environment or colour
/// map (`read_linear_rgb`) and through the texture system, and within the 8-bit step of the
/// float EXR they were written from.
#[test]
fn eight_bit_colour_files_are_srgb_whatever_their_format() {
    let dir = tempfile::tempdir().unwrap();
    let ramp = |x: u32, y: u32| Vec3::new(x as f32 / 15.0, y as f32 / 15.0, 0.25);
    let exr = dir.path().join("ramp.exr");
    write_texture(&exr, 16, ramp, true);
    let want = reframe::image::read_linear_rgb(&exr, 1 << 20, 0).unwrap();
    let mut textures = Textures::new().unwrap();
    let mut first: Option<(Vec<f32>, Vec<Vec3>)> = None;
    for ext in ["png", "tga", "bmp", "tif"] {
        let path = dir.path().join(format!("ramp.{ext}"));
        write_texture(&path, 16, ramp, false);
        let img = reframe::image::read_linear_rgb(&path, 1 << 20, 0).unwrap();
        for (k, (&a, &b)) in img.data.iter().zip(&want.data).enumerate() {
            // The writer's dither of +-1 code and its rounding: 1.5 codes of the sRGB curve
            // where it is steepest in linear terms (0.009 per code near 1). Read as linear
            // codes, a ramp value of 0.5 came back near 0.73.
            assert!(
                (a - b).abs() < 0.014,
                "{ext}: value {k} is {a}, the EXR's {b}"
            );
        }
        let id = textures.open(&path).unwrap();
        let looked_up: Vec<Vec3> = (0..16)
            .flat_map(|y| (0..16).map(move |x| (x, y)))
            .map(|(x, y)| {
                let uv = Vec2::new((x as f32 + 0.5) / 16.0, 1.0 - (y as f32 + 0.5) / 16.0);
                textures.rgb(id, uv)
            })
            .collect();
        match &first {
            None => first = Some((img.data, looked_up)),
            Some((data, lookups)) => {
                assert_eq!(&img.data, data, "{ext} read differently from the PNG");
                assert_eq!(
                    &looked_up, lookups,
                    "{ext} looked up differently from the PNG"
                );
            }
        }
    }
}

/// A little-endian, uncompressed RGB TIFF of `size` x `size` texels, each channel one
/// `bits`-bit integer (`signed`: two's complement, TIFF's `SampleFormat` 2) with code `code`.
fn write_integer_tiff(path: &Path, size: u32, bits: u16, signed: bool, code: i64) {
    let bytes_per = (bits / 8) as usize;
    let mut pixels = Vec::new();
    for _ in 0..size * size * 3 {
        pixels.extend_from_slice(&code.to_le_bytes()[..bytes_per]);
    }
    // Header, then the pixels, then the directory (12 entries) and the three-value arrays.
    let ifd = 8 + pixels.len() as u32;
    let arrays = ifd + 2 + 12 * 12 + 4;
    let entry = |tag: u16, kind: u16, count: u32, value: u32| {
        let mut e = Vec::new();
        e.extend_from_slice(&tag.to_le_bytes());
        e.extend_from_slice(&kind.to_le_bytes());
        e.extend_from_slice(&count.to_le_bytes());
        e.extend_from_slice(&value.to_le_bytes());
        e
    };
    const SHORT: u16 = 3;
    const LONG: u16 = 4;
    let entries = [
        entry(256, LONG, 1, size),                // ImageWidth
        entry(257, LONG, 1, size),                // ImageLength
        entry(258, SHORT, 3, arrays),             // BitsPerSample
        entry(259, SHORT, 1, 1),                  // Compression: none
        entry(262, SHORT, 1, 2),                  // Photometric: RGB
        entry(273, LONG, 1, 8),                   // StripOffsets
        entry(277, SHORT, 1, 3),                  // SamplesPerPixel
        entry(278, LONG, 1, size),                // RowsPerStrip
        entry(279, LONG, 1, pixels.len() as u32), // StripByteCounts
        entry(284, SHORT, 1, 1),                  // PlanarConfiguration: chunky
        entry(339, SHORT, 3, arrays + 6),         // SampleFormat
        entry(296, SHORT, 1, 1),                  // ResolutionUnit: none
    ];
    let mut f = b"II*\0".to_vec();
    f.extend_from_slice(&ifd.to_le_bytes());
    f.extend_from_slice(&pixels);
    f.extend_from_slice(&(entries.len() as u16).to_le_bytes());
    // Entries in ascending tag order, as TIFF asks.
    let mut sorted = entries.to_vec();
    sorted.sort_by_key(|e| u16::from_le_bytes([e[0], e[1]]));
    for e in sorted {
        f.extend_from_slice(&e);
    }
    f.extend_from_slice(&0u32.to_le_bytes());
    let format: u16 = if signed { 2 } else { 1 };
    for v in [bits, bits, bits, format, format, format] {
        f.extend_from_slice(&v.to_le_bytes());
    }
    std::fs::write(path, f).unwrap();
}

/// TIFFs of 32-bit or signed integers hold data (depths, masks, measurements), not colour
/// codes: they are linear, read as their normalised values. They were decoded as sRGB, as 8-
/// and 16-bit files are, and a half read as 0.21. An unsigned 16-bit TIFF stays sRGB.
#[test]
fn thirty_two_bit_and_signed_integer_tiffs_are_linear() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        (32, false, (u32::MAX / 2) as i64, 0.5),
        (16, true, (i16::MAX / 2) as i64, 0.5),
        // sRGB: code 0.5 is 0.214 linear.
        (16, false, (u16::MAX / 2) as i64, 0.214),
    ];
    let mut textures = Textures::new().unwrap();
    for (bits, signed, code, want) in cases {
        let path = dir.path().join(format!("t{bits}{signed}.tif"));
        write_integer_tiff(&path, 4, bits, signed, code);
        let img = reframe::image::read_linear_rgb(&path, 1 << 20, 0).unwrap();
        assert!(
            img.data.iter().all(|v| (v - want).abs() < 0.002),
            "{bits}-bit, signed {signed}: {:?}, want {want}",
            &img.data[..3]
        );
        let id = textures.open(&path).unwrap();
        let v = textures.rgb(id, Vec2::new(0.5, 0.5));
        assert!(
            (v.x - want).abs() < 0.002,
            "{bits}-bit through the cache: {v}"
        );
    }
}

#[test]
fn one_file_under_several_names_is_one_texture() {
    // A PNG as itself, `./`, `sub/../`, a symbolic link and a hard link: one texture, decoded
    // once (each name was decoded and cached again: 200 hard links to one 2048 x 2048 PNG took
    // over a minute to load). A copy of the file is another texture; the file as a mask is
    // another texture of it.
    let d = tempfile::tempdir().unwrap();
    let path = d.path().join("t.png");
    write_texture(&path, 4, |x, _| Vec3::splat(x as f32 / 3.0), false);
    std::fs::create_dir(d.path().join("sub")).unwrap();
    std::os::unix::fs::symlink("t.png", d.path().join("link.png")).unwrap();
    std::fs::hard_link(&path, d.path().join("hard.png")).unwrap();
    std::fs::copy(&path, d.path().join("copy.png")).unwrap();
    let mut t = Textures::new().unwrap();
    let id = t.open(&path).unwrap();
    for name in ["./t.png", "sub/../t.png", "link.png", "hard.png"] {
        assert_eq!(t.open(&d.path().join(name)).unwrap(), id, "{name}");
    }
    assert_eq!(t.len(), 1);
    assert_ne!(t.open(&d.path().join("copy.png")).unwrap(), id);
    let mask = t.open_mask(&d.path().join("hard.png"), None).unwrap();
    assert_ne!(mask, id);
    assert_eq!(t.open_mask(&path, None).unwrap(), mask);
    assert_eq!(t.len(), 3);
}

#[test]
fn textures_are_filtered_in_linear_values() {
    // A black and a white column of texels, as an 8-bit sRGB PNG and as a float EXR. Half way
    // between the two texel centres a lookup is their linear mean, 0.5, in both, as renderers
    // that filter radiance give it (OIIO's own bilinear lookup of the PNG mixes the encoded
    // values: 0.5 encoded is 0.214); at a centre it is the texel, a quarter of the way 0.25,
    // and across the right and left edges the texture repeats.
    let tmp = tempfile::tempdir().unwrap();
    for (name, exr_float) in [("t.png", false), ("t.exr", true)] {
        let path = tmp.path().join(name);
        write_texture(&path, 2, |x, _| Vec3::splat(x as f32), exr_float);
        let mut t = Textures::new().unwrap();
        let id = t.open(&path).unwrap();
        for (u, want) in [
            (0.5, 0.5),
            (0.25, 0.0),
            (0.75, 1.0),
            (0.375, 0.25),
            (1.0, 0.5),
            (0.0, 0.5),
            (-0.875, 0.25),
        ] {
            let got = t.rgb(id, Vec2::new(u, 0.3));
            assert!(
                (got - Vec3::splat(want)).abs().max_element() < 1e-6,
                "{name} u {u}: {got}, want {want}"
            );
        }
    }
    // An EXR of channels R and G is red and green (it was read as grey); one of alpha alone is
    // refused.
    let mut rg = Image::new(2, 2, &["R", "G"]);
    rg.data
        .chunks_exact_mut(2)
        .for_each(|px| px.copy_from_slice(&[0.8, 0.1]));
    let path = tmp.path().join("rg.exr");
    write_image(
        &path,
        &rg,
        &Metadata::default(),
        &WriteOptions { exr_float: true },
    )
    .unwrap();
    let mut t = Textures::new().unwrap();
    let id = t.open(&path).unwrap();
    let got = t.rgb(id, Vec2::new(0.3, 0.6));
    assert!(
        (got - Vec3::new(0.8, 0.1, 0.0)).abs().max_element() < 1e-6,
        "{got}"
    );
    let path = tmp.path().join("a.exr");
    let alpha = Image::new(2, 2, &["A"]);
    write_image(
        &path,
        &alpha,
        &Metadata::default(),
        &WriteOptions { exr_float: true },
    )
    .unwrap();
    let e = t.open(&path).map(|_| ()).unwrap_err().to_string();
    assert!(e.contains("its channels (A) hold no colour"), "{e}");
}

#[test]
fn checkerboard_seen_head_on_matches_the_pattern() {
    // The quad fills a square frame exactly (tan(fov / 2) = 1 / 2 at distance 2), one pixel per
    // texel; it emits Ke times the texture and reflects nothing, so a pixel is the texture
    // averaged over the pixel. Pixels whose texels and bilinear neighbours all lie in one
    // square are that square's colour; an image flipped or turned would put red elsewhere.
    for file in ["checker.png", "checker.exr"] {
        let dir = tempfile::tempdir().unwrap();
        write_texture(
            &dir.path().join(file),
            32,
            |x, y| square(y / 8, x / 8),
            true,
        );
        let fov = 2.0 * 0.5f32.atan().to_degrees();
        let path = write_scene(
            dir.path(),
            QUAD,
            &format!("newmtl q\nKd 0\nKe 1 1 1\nmap_Ke {file}\n"),
            &toml(32, 32, [0.0, 0.0, 2.0], fov, ""),
        );
        let device = Device::new().unwrap();
        let scene = Scene::load(&path, &device).unwrap();
        assert!(scene.warnings.is_empty(), "{:?}", scene.warnings);
        assert!(scene.inputs.iter().any(|p| p.ends_with(file)), "{file}");
        let integ = Integrator::new(&scene, 4);
        let pool = thread_pool(0).unwrap();
        let px = pool
            .install(|| {
                render_frame_independent(&integ, &scene.camera(0, 32, 32), 0, 8, 1, false, &|_| {})
            })
            .pixels;
        let mut checked = 0;
        for y in 0..32 {
            for x in 0..32 {
                if !(1..7).contains(&(x % 8)) || !(1..7).contains(&(y % 8)) {
                    continue;
                }
                let want = square(y / 8, x / 8);
                let got = px[(y * 32 + x) as usize];
                assert!(
                    (got - want).abs().max_element() < 1e-5,
                    "{file}: pixel ({x}, {y}) is {got}, the pattern says {want}"
                );
                checked += 1;
            }
        }
        assert_eq!(checked, 16 * 36);
        // Across a square's edge the pixel mixes the two colours.
        let edge = px[(12 * 32 + 8) as usize];
        assert!(edge.x > 0.05 && edge.x < 0.95, "{file}: edge pixel {edge}");
    }
}

#[test]
fn textured_reflectance_under_a_uniform_environment() {
    // A diffuse quad under a uniform environment of radiance 1 and nothing else: the radiance
    // it reflects is exactly its albedo, here Kd times the texture (the MTL's product).
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (Vec3::new(0.4, 0.8, 1.0), Vec3::new(1.0, 0.5, 0.2));
    write_texture(
        &dir.path().join("t.exr"),
        32,
        |x, y| {
            if (x / 8 + y / 8).is_multiple_of(2) {
                a
            } else {
                b
            }
        },
        true,
    );
    let kd = Vec3::new(0.8, 0.6, 0.5);
    let path = write_scene(
        dir.path(),
        QUAD,
        &format!(
            "newmtl q\nKd {} {} {}\nmap_Kd -s 1 1 t.exr\n",
            kd.x, kd.y, kd.z
        ),
        &toml(
            32,
            32,
            [0.0, 0.0, 2.0],
            2.0 * 0.5f32.atan().to_degrees(),
            "[environment]\nradiance = [1.0, 1.0, 1.0]",
        ),
    );
    let device = Device::new().unwrap();
    let scene = Scene::load(&path, &device).unwrap();
    // The texture's content is part of the scene's identity (checkpoints, cached references).
    let hash = || {
        scene_and_build_hashes(&Scene::load(&path, &device).unwrap())
            .unwrap()
            .0
    };
    let before = hash();
    assert_eq!(before, hash());
    write_texture(
        &dir.path().join("t.exr"),
        32,
        |x, _| Vec3::splat(x as f32 / 32.0),
        true,
    );
    assert_ne!(before, hash());
    write_texture(
        &dir.path().join("t.exr"),
        32,
        |x, y| {
            if (x / 8 + y / 8).is_multiple_of(2) {
                a
            } else {
                b
            }
        },
        true,
    );
    assert_eq!(before, hash());
    let integ = Integrator::new(&scene, 8);
    let pool = thread_pool(0).unwrap();
    let px = pool
        .install(|| {
            render_frame_independent(&integ, &scene.camera(0, 32, 32), 0, 64, 3, false, &|_| {})
        })
        .pixels;
    let (mut sum, mut n) = ([Vec3::ZERO; 2], [0u32; 2]);
    for y in 0..32u32 {
        for x in 0..32u32 {
            if (1..7).contains(&(x % 8)) && (1..7).contains(&(y % 8)) {
                let k = ((x / 8 + y / 8) % 2) as usize;
                sum[k] += px[(y * 32 + x) as usize];
                n[k] += 1;
            }
        }
    }
    for (k, t) in [a, b].into_iter().enumerate() {
        let mean = sum[k] / n[k] as f32;
        let want = kd * t;
        eprintln!("squares {k}: mean {mean}, albedo {want}");
        assert!(
            ((mean - want) / want).abs().max_element() < 0.01,
            "squares {k}: {mean} against the albedo {want}"
        );
    }
}

/// A lat-long sky: a gradient above the horizon, dark ground below, a small bright sun.
fn sky(path: &Path) {
    let (w, h) = (64u32, 32u32);
    let mut img = Image::new(w, h, &["R", "G", "B"]);
    for y in 0..h {
        for x in 0..w {
            let v = (y as f32 + 0.5) / h as f32;
            let c = if (x, y) == (19, 8) {
                Vec3::new(300.0, 280.0, 240.0)
            } else if v < 0.5 {
                Vec3::new(0.3, 0.5, 1.0) * (1.2 - v)
            } else {
                Vec3::new(0.2, 0.15, 0.1)
            };
            let i = 3 * (y * w + x) as usize;
            img.data[i..i + 3].copy_from_slice(&c.to_array());
        }
    }
    write_image(
        path,
        &img,
        &Metadata::default(),
        &WriteOptions { exr_float: true },
    )
    .unwrap();
}

/// A textured floor (an 8-bit sRGB PNG, repeated four times across it) and a cube whose sides
/// carry a glossy texture, under a sky with a sun, seen against the horizon while the camera
/// zooms: `mis-exact` and `mis-cv`, which shade each first hit's texture once for every eye,
/// match an independent reference block by block.
#[test]
fn reuse_is_unbiased_on_a_textured_environment_lit_scene() {
    let dir = tempfile::tempdir().unwrap();
    sky(&dir.path().join("sky.exr"));
    write_texture(
        &dir.path().join("tiles.png"),
        16,
        |x, y| {
            if (x / 4 + y / 4).is_multiple_of(2) {
                Vec3::new(0.8, 0.7, 0.5)
            } else {
                Vec3::new(0.1, 0.2, 0.4)
            }
        },
        false,
    );
    write_texture(
        &dir.path().join("stripes.exr"),
        8,
        |x, _| Vec3::splat(if x < 4 { 1.0 } else { 0.3 }),
        true,
    );
    let obj = "mtllib s.mtl\n\
        v -0.5 -0.5 -0.5\nv 0.5 -0.5 -0.5\nv 0.5 0.5 -0.5\nv -0.5 0.5 -0.5\n\
        v -0.5 -0.5 0.5\nv 0.5 -0.5 0.5\nv 0.5 0.5 0.5\nv -0.5 0.5 0.5\n\
        vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
        usemtl box\n\
        f 1/1 4/2 3/3 2/4\nf 5/1 6/2 7/3 8/4\nf 1/1 5/2 8/3 4/4\n\
        f 2/1 3/2 7/3 6/4\nf 4/1 8/2 7/3 3/4\nf 1/1 2/2 6/3 5/4\n\
        v -3 -0.5 -3\nv 3 -0.5 -3\nv 3 -0.5 3\nv -3 -0.5 3\n\
        vt 0 0\nvt 4 0\nvt 4 4\nvt 0 4\n\
        usemtl floor\nf 9/5 12/8 11/7 10/6\n";
    let mtl = "newmtl box\nKd 0.5 0.3 0.2\nKs 0.3 0.3 0.3\nNs 30\nmap_Ks stripes.exr\n\
               newmtl floor\nKd 1 1 1\nmap_Kd tiles.png\n";
    let toml = "obj = \"s.obj\"\nframes = 9\nresolution = [48, 36]\n\
        [environment]\nimage = \"sky.exr\"\nrotation = 20.0\n\
        [[keyframe]]\nframe = 0\nposition = [1.6, 1.2, 2.4]\nlook_at = [0.0, 0.0, 0.0]\n\
        up = [0.0, 1.0, 0.0]\nfov = 45.0\n\
        [[keyframe]]\nframe = 8\nposition = [2.3, 1.0, 1.5]\nlook_at = [0.0, 0.1, 0.0]\n\
        up = [0.0, 1.0, 0.0]\nfov = 40.0\n";
    let path = write_scene(dir.path(), obj, mtl, toml);
    let device = Device::new().unwrap();
    let scene = Scene::load(&path, &device).unwrap();
    assert!(scene.textures.as_ref().is_some_and(|t| t.len() == 2));
    let integ = Integrator::new(&scene, 8);
    let pool = thread_pool(0).unwrap();
    let (w, h, b, target) = (48usize, 36usize, 4, 4u32);
    let k = 64;
    let reference: Vec<Vec<Vec3>> = (0..k)
        .map(|s| {
            pool.install(|| {
                let cam = scene.camera(target, w as u32, h as u32);
                render_frame_independent(&integ, &cam, target, 16, 5000 + s, false, &|_| {}).pixels
            })
        })
        .collect();
    let reference = block_moments(&reference, w, h, b);
    for method in [Method::MisCv, Method::MisExact] {
        let res = (w as u32, h as u32);
        let frames = (0..=8, target);
        let renders = reuse_renders(&integ, &pool, (method, 5), frames, res, (k, 6000));
        let z = z_test(&block_moments(&renders, w, h, b), &reference);
        assert_unbiased(&format!("{method:?} on the textured scene"), &z);
    }
    assert_eq!(scene.textures.as_ref().unwrap().failures(), 0);
}

#[test]
fn damaged_textures_are_refused_before_anything_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let fov = 2.0 * 0.5f32.atan().to_degrees();
    let scene = write_scene(
        d,
        QUAD,
        "newmtl q\nKd 0\nKe 1 1 1\nmap_Ke t.exr\n",
        &toml(16, 16, [0.0, 0.0, 2.0], fov, ""),
    );
    let render = || {
        common::reframe(&[
            "render",
            &scene,
            "--spp",
            "1",
            "--out",
            d.join("out/f_####.exr").to_str().unwrap(),
        ])
        .output()
        .unwrap()
    };
    let mtl = format!("{}/s.mtl: line 4: 'map_Ke t.exr'", d.display());
    let nan = |x: u32, _| Vec3::splat(if x == 3 { f32::NAN } else { 0.5 });
    type Spoil<'a> = Box<dyn Fn() + 'a>;
    let cases: Vec<(&str, Spoil, String)> = vec![
        (
            "missing",
            Box::new(|| {
                let _ = std::fs::remove_file(d.join("t.exr"));
            }),
            format!("{mtl}: no file '{}/t.exr'", d.display()),
        ),
        (
            "not an image",
            Box::new(|| std::fs::write(d.join("t.exr"), "not an image").unwrap()),
            format!("{mtl}: cannot read {}/t.exr", d.display()),
        ),
        (
            "truncated",
            Box::new(|| {
                write_texture(
                    &d.join("t.exr"),
                    64,
                    |x, y| Vec3::splat((x ^ y) as f32),
                    true,
                );
                let bytes = std::fs::read(d.join("t.exr")).unwrap();
                std::fs::write(d.join("t.exr"), &bytes[..bytes.len() / 2]).unwrap();
            }),
            format!("{mtl}: cannot read {}/t.exr", d.display()),
        ),
        (
            "a NaN texel",
            Box::new(move || write_texture(&d.join("t.exr"), 8, nan, true)),
            format!(
                "{mtl}: cannot use {}/t.exr: it has a texel of NaN",
                d.display()
            ),
        ),
    ];
    for (what, spoil, want) in cases {
        spoil();
        let out = render();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{what}: {err}");
        assert_eq!(err.lines().count(), 1, "{what}: {err}");
        assert!(err.contains(&want), "{what}: {err}\nwant: {want}");
        assert!(files_under(&d.join("out")).is_empty(), "{what}");
    }
    // Made whole again, it renders.
    write_texture(&d.join("t.exr"), 8, |_, _| Vec3::splat(0.5), true);
    let out = render();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A photograph's small negative values (debayering, a change of colour space, lossy EXR
/// compression: OpenEXR's own `CandleGlass.exr` and `Desk.exr` hold them) read as zero, with
/// one warning per kind that counts them, in a texture and in an environment; such files were
/// refused whole. `--strict` refuses them, as every repair.
#[test]
fn negative_texels_read_as_zero_with_a_warning() {
    let d = tempfile::tempdir().unwrap();
    // Texel x = 1 of each row is below zero; the rest 0.5.
    let texel = |x: u32, _| Vec3::splat(if x == 1 { -0.01 } else { 0.5 });
    write_texture(&d.path().join("t.exr"), 4, texel, true);
    let mut t = Textures::new().unwrap();
    let id = t.open(&d.path().join("t.exr")).unwrap();
    assert_eq!(t.negative_texels(id), 4 * 3);
    // At the negative texel's centre, zero; between it and a 0.5 texel, half of 0.5 (it is
    // zero before the two are interpolated).
    assert_eq!(t.rgb(id, Vec2::new(1.5 / 4.0, 0.5)), Vec3::ZERO);
    let between = t.rgb(id, Vec2::new(1.0 / 4.0, 0.5 / 4.0));
    assert!((between.x - 0.25).abs() < 1e-6, "{between}");
    let scene = write_scene(
        d.path(),
        QUAD,
        "newmtl q\nKd 1 1 1\nmap_Kd t.exr\n",
        &toml(
            8,
            8,
            [0.0, 0.0, 3.0],
            60.0,
            "[environment]\nimage = \"t.exr\"",
        ),
    );
    let device = Device::new().unwrap();
    let s = Scene::load(&scene, &device).unwrap();
    let dir = d.path().display();
    for want in [
        format!("{dir}/s.toml: 4 environment pixels with values below 0 read as 0 (first at line"),
        format!("{dir}/s.mtl: line 3: 'map_Kd t.exr': 12 value(s) below 0: texture with values below 0 (read as 0)"),
    ] {
        assert!(s.warnings.iter().any(|w| w.contains(&want)), "{want}: {:?}", s.warnings);
    }
    let strict = reframe::scene::LoadOptions { strict: true };
    assert!(Scene::load_with(&scene, &device, &strict).is_err());
}

/// The texture files of a material that no `usemtl` names are not opened, but they are still
/// the scene's inputs: a render's `--out` that names one is refused, as for a material in use
/// (it was written over).
#[test]
fn an_unused_materials_texture_is_never_written_over() {
    let d = tempfile::tempdir().unwrap();
    write_texture(
        &d.path().join("wood_0000.png"),
        4,
        |_, _| Vec3::splat(0.5),
        false,
    );
    let before = std::fs::read(d.path().join("wood_0000.png")).unwrap();
    let scene = write_scene(
        d.path(),
        QUAD,
        "newmtl q\nKd 1 1 1\nnewmtl spare\nKd 1 1 1\nmap_Kd wood_0000.png\n",
        &toml(
            8,
            8,
            [0.0, 0.0, 3.0],
            60.0,
            "[environment]\nradiance = [1, 1, 1]",
        ),
    );
    let out = d.path().join("wood_####.png");
    let o = common::reframe(&[
        "render",
        &scene,
        "--spp",
        "1",
        "--out",
        out.to_str().unwrap(),
    ])
    .output()
    .unwrap();
    common::assert_refused(&o, "that is an input of this command");
    assert_eq!(
        std::fs::read(d.path().join("wood_0000.png")).unwrap(),
        before
    );
}

#[test]
fn a_texture_larger_than_the_memory_left_is_one_line() {
    // An 8192 x 8192 texture is within MAX_TEXELS but needs about 1.6 GB to decode: under a
    // 1.5 GB address-space limit the render aborted with a backtrace when the allocation
    // failed; it is refused in one line, naming the MTL's line, before anything is written.
    let dir = tempfile::tempdir().unwrap();
    let mut img = Image::new(8192, 8192, &["R", "G", "B"]);
    img.data.fill(0.5);
    write_image(
        &dir.path().join("big.exr"),
        &img,
        &Metadata::default(),
        &WriteOptions::default(),
    )
    .unwrap();
    drop(img);
    let mtl = "newmtl q\nKd 1 1 1\nmap_Kd big.exr\nnewmtl lamp\nKd 0 0 0\nKe 1 1 1\n";
    let obj = format!("{QUAD}v -1 -1 3\nv 1 -1 3\nv 0 1 3\nusemtl lamp\nf 5 7 6\n");
    let scene = write_scene(
        dir.path(),
        &obj,
        mtl,
        &toml(8, 6, [0.0, 0.0, 2.0], 60.0, ""),
    );
    let out = dir.path().join("o/f_####.exr");
    let limited = |scene: &str| {
        let cmd = format!(
            "ulimit -v 1500000 && exec '{}' render '{scene}' --spp 1 --threads 1 --out '{}'",
            env!("CARGO_BIN_EXE_reframe"),
            out.display()
        );
        std::process::Command::new("sh")
            .args(["-c", &cmd])
            .output()
            .unwrap()
    };
    // The limit leaves room for the process itself only where its libraries and threads take
    // less address space than that (a machine of many cores reserves more): the same scene
    // with a small texture must render under it, else there is nothing to test here.
    let small = dir.path().join("small");
    std::fs::create_dir(&small).unwrap();
    write_texture(&small.join("big.exr"), 4, |_, _| Vec3::splat(0.5), false);
    let small_scene = write_scene(&small, &obj, mtl, &toml(8, 6, [0.0, 0.0, 2.0], 60.0, ""));
    if !limited(&small_scene).status.success() {
        eprintln!("skipped: reframe does not start under a 1.5 GB address-space limit here");
        return;
    }
    std::fs::remove_dir_all(dir.path().join("o")).unwrap();
    let o = limited(&scene);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("s.mtl: line 3: 'map_Kd big.exr': cannot read")
            && err.contains("needs about 1.6 GB")
            && err.trim().lines().count() == 1,
        "{err}"
    );
    assert!(!dir.path().join("o").exists());
}

/// A texture cut short after the scene loaded (the cache reads it while rendering) makes its
/// lookups fail: each is counted (the render warns with the count) and comes back black.
#[test]
fn lookups_of_a_texture_damaged_after_loading_are_counted() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("gone.exr");
    write_texture(
        &path,
        1024,
        |x, _| Vec3::splat(x as f32 / 1024.0 + 0.1),
        true,
    );
    let mut t = Textures::new().unwrap();
    let id = t.open(&path).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() / 3]).unwrap();
    assert_eq!(t.rgb(id, Vec2::new(0.5, 0.5)), Vec3::ZERO);
    assert!(t.failures() > 0);
}

/// A float texture above 1 under `map_Kd`: the reflectance is `Kd` times the texel, clamped to
/// [0, 1] after the product (texel 1.6 under Kd 0.5 is 0.8, as other renderers take it; the
/// texel was clamped first, which made it 0.5), and where `Kd + Ks` then passes 1 in a channel
/// both are scaled by one factor, as the MTL's constants are.
#[test]
fn a_textured_reflectance_is_clamped_after_the_product() {
    let tmp = tempfile::tempdir().unwrap();
    write_texture(
        &tmp.path().join("t.exr"),
        4,
        |_, _| Vec3::new(1.6, 0.3, 1.2),
        true,
    );
    // And a dark texture under constants whose sum passes 1 (Blender's Kd 0.8 + Ks 0.5 with a
    // map_Kd): the texel is taken first and the pair is within 1, so nothing is scaled (the
    // constants were scaled at load as if the texel were white: a fifth dark, in both lobes).
    write_texture(
        &tmp.path().join("dark.exr"),
        4,
        |_, _| Vec3::new(0.25, 0.5, 0.1),
        true,
    );
    let device = Device::new().unwrap();
    let lamp = "v -1 -1 3\nv 1 -1 3\nv 0 1 3\nusemtl lamp\nf 5 7 6\n";
    for (kd, ks, map, want_kd, want_ks) in [
        (
            0.5,
            0.2,
            "map_Kd t.exr",
            Vec3::new(0.8, 0.15, 0.6),
            Vec3::splat(0.2),
        ),
        (
            0.7,
            0.2,
            "map_Kd t.exr",
            Vec3::new(1.0, 0.21, 0.84) / 1.2,
            Vec3::splat(0.2 / 1.2),
        ),
        (
            0.8,
            0.5,
            "map_Kd dark.exr",
            Vec3::new(0.2, 0.4, 0.08),
            Vec3::splat(0.5),
        ),
        (
            0.5,
            1.0,
            "map_Ks dark.exr",
            Vec3::splat(0.5),
            Vec3::new(0.25, 0.5, 0.1),
        ),
    ] {
        let mtl = format!(
            "newmtl q\nKd {kd} {kd} {kd}\nKs {ks} {ks} {ks}\nNs 20\n{map}\n\
             newmtl lamp\nKd 0 0 0\nKe 1 1 1\n"
        );
        let scene = write_scene(
            tmp.path(),
            &format!("{QUAD}{lamp}"),
            &mtl,
            &toml(8, 6, [0.0, 0.0, 2.0], 60.0, ""),
        );
        let s = Scene::load(&scene, &device).unwrap();
        let ray = reframe::embree::Ray::new(Vec3::new(0.1, 0.2, 2.0), -Vec3::Z);
        let sp = s.surface(&s.geometry.intersect1(&ray).unwrap());
        let m = s.material(&sp);
        assert!(
            (m.kd - want_kd).abs().max_element() < 1e-5
                && (m.ks - want_ks).abs().max_element() < 1e-5,
            "Kd {kd} Ks {ks} {map}: got Kd {} Ks {}, want {want_kd} {want_ks}",
            m.kd,
            m.ks
        );
    }
}

/// A PNG with an image offset (an `oFFs` chunk, which ImageMagick writes after a crop) is its
/// pixels, as other readers take it: the display-window rule is OpenEXR's alone (the offset
/// shifted the image and zeroed the rest: a sky's mean 0.527 fell to 0.027).
#[test]
fn a_png_offset_is_not_a_window() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/images");
    let (offset, plain) = (dir.join("offset.png"), dir.join("offset-none.png"));
    let read = |p: &std::path::Path| reframe::image::read_linear_rgb(p, 1 << 20, 0).unwrap();
    let (a, b) = (read(&offset), read(&plain));
    assert_eq!((a.width, a.height, &a.data), (b.width, b.height, &b.data));
    let mut t = Textures::new().unwrap();
    let (ia, ib) = (t.open(&offset).unwrap(), t.open(&plain).unwrap());
    for k in 0..64 {
        let uv = Vec2::new((k % 8) as f32 / 8.0 + 0.03, (k / 8) as f32 / 8.0 + 0.05);
        assert_eq!(t.rgb(ia, uv), t.rgb(ib, uv), "at {uv}");
    }
}

/// An EXR whose data window is larger than its display window (an overscan render: 12x12 stored
/// from (-2, -2) around an 8x8 image) is its display window, the margin dropped.
#[test]
fn an_overscan_exr_is_its_display_window() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/images/overscan.exr");
    let img = reframe::image::read_linear_rgb(&path, 1 << 20, 0).unwrap();
    assert_eq!((img.width, img.height), (8, 8));
    for p in img.data.chunks(3) {
        assert_eq!(p, [0.25, 0.5, 1.0]);
    }
    let mut t = Textures::new().unwrap();
    let id = t.open(&path).unwrap();
    for uv in [
        Vec2::new(0.01, 0.01),
        Vec2::new(0.5, 0.5),
        Vec2::new(0.99, 0.99),
    ] {
        assert!(
            (t.rgb(id, uv) - Vec3::new(0.25, 0.5, 1.0))
                .abs()
                .max_element()
                < 1e-6
        );
    }
}

/// An EXR whose data window is part of its display window (a file cropped to its non-empty
/// pixels by Nuke or oiiotool, an overscan render) is the image of its display window, zero
/// where nothing is stored: read whole (environments) and looked up as a texture alike.
/// `tests/images/cropped.exr` is 8x8 with (1, 0.5, 0.25) stored in x 2..6, y 4..8 only; it was
/// stretched over the whole image, lit sky where the file meant black.
#[test]
fn a_cropped_exr_is_its_display_window() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/images/cropped.exr");
    let want = |x: u32, y: u32| {
        if (2..6).contains(&x) && (4..8).contains(&y) {
            Vec3::new(1.0, 0.5, 0.25)
        } else {
            Vec3::ZERO
        }
    };
    let img = reframe::image::read_linear_rgb(&path, 1 << 20, 0).unwrap();
    assert_eq!((img.width, img.height), (8, 8));
    let mut t = Textures::new().unwrap();
    let id = t.open(&path).unwrap();
    for y in 0..8 {
        for x in 0..8 {
            let i = ((y * 8 + x) * 3) as usize;
            let read = Vec3::new(img.data[i], img.data[i + 1], img.data[i + 2]);
            assert_eq!(read, want(x, y), "read, pixel ({x}, {y})");
            // At a texel's centre the bilinear lookup is the texel (v runs up the image).
            let uv = Vec2::new((x as f32 + 0.5) / 8.0, 1.0 - (y as f32 + 0.5) / 8.0);
            let looked = t.rgb(id, uv);
            assert!(
                (looked - want(x, y)).abs().max_element() < 1e-6,
                "looked up, texel ({x}, {y}): {looked}"
            );
        }
    }
}

/// An EXR none of whose stored pixels lie in its image (`tests/images/disjoint.exr`: 8x4
/// pixels stored at (5000, 5000) of an 8x4 display window at the origin, as a compositor's
/// damaged metadata leaves it): refused, as a texture and as an environment, naming both
/// windows; it read as black without a word (a sky lit nothing).
#[test]
fn an_exr_that_stores_nothing_inside_its_image_is_refused() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/images/disjoint.exr");
    let e = reframe::image::read_linear_rgb(&path, 1 << 20, 0)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("it stores 8x4 pixels (its data window), none of them inside its 8x4 image"),
        "{e}"
    );
    let e = Textures::new()
        .unwrap()
        .open(&path)
        .unwrap_err()
        .to_string();
    assert!(e.contains("none of them inside its 8x4 image"), "{e}");
}

/// The same for tiled EXRs (a tiled overscan or cropped render, as renderers and Nuke write
/// them), which have no scanlines to read: they were refused with OpenImageIO's "called
/// OpenEXRInput::read_native_scanlines without an open file". `overscan-tiled.exr`: 12x10
/// stored from (-2, -1) in 4x4 tiles around an 8x8 image; `cropped-tiled.exr`: 3x4 stored at
/// (3, 2) in 2x2 tiles; each stored pixel is (its column and row in the stored data, 1).
#[test]
fn a_tiled_exr_is_its_display_window_too() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/images");
    let overscan = |x: u32, y: u32| Vec3::new(x as f32 + 2.0, y as f32 + 1.0, 1.0);
    let cropped = |x: u32, y: u32| {
        if (3..6).contains(&x) && (2..6).contains(&y) {
            Vec3::new(x as f32 - 3.0, y as f32 - 2.0, 1.0)
        } else {
            Vec3::ZERO
        }
    };
    let mut t = Textures::new().unwrap();
    for (name, want) in [
        ("overscan-tiled.exr", &overscan as &dyn Fn(u32, u32) -> Vec3),
        ("cropped-tiled.exr", &cropped),
    ] {
        let path = dir.join(name);
        let img = reframe::image::read_linear_rgb(&path, 1 << 20, 0).unwrap();
        assert_eq!((img.width, img.height), (8, 8), "{name}");
        let id = t.open(&path).unwrap();
        for y in 0..8 {
            for x in 0..8 {
                let i = ((y * 8 + x) * 3) as usize;
                let read = Vec3::new(img.data[i], img.data[i + 1], img.data[i + 2]);
                assert_eq!(read, want(x, y), "{name}: read, pixel ({x}, {y})");
                let uv = Vec2::new((x as f32 + 0.5) / 8.0, 1.0 - (y as f32 + 0.5) / 8.0);
                let looked = t.rgb(id, uv);
                assert!(
                    (looked - want(x, y)).abs().max_element() < 1e-5,
                    "{name}: looked up, texel ({x}, {y}): {looked}"
                );
            }
        }
    }
}

/// A textured emitter lights a white floor (direct light only): the floor's radiance against
/// the integral of the map over the emitter, by quadrature, region by region over seeds; and
/// the light samples go to the map's bright texels, so that the noise per sample stays far
/// below what sampling the emitter uniformly by area gave (its relative variance per sample
/// was about 30 on this floor, now about 0.5: the parts of a textured light are picked by
/// the map's radiance over them).
#[test]
fn a_textured_emitter_lights_in_proportion_to_its_map_and_is_sampled_by_it() {
    const N: u32 = 16;
    // A dim map with a block of hot texels: rows 2-4 from the top, columns 6-9 (symmetric
    // about the map's vertical centre line, so that the test needs no handedness).
    let texel = |x: u32, y: u32| -> f32 {
        if (6..=9).contains(&x) && (2..=4).contains(&y) {
            200.0
        } else {
            0.05
        }
    };
    let dir = tempfile::tempdir().unwrap();
    write_texture(
        &dir.path().join("t.exr"),
        N,
        |x, y| Vec3::splat(texel(x, y)),
        true,
    );
    // The emitter is QUAD (z = 0, facing +z); the floor is the plane z = 2 facing it, x and y
    // in [-3, 3]; the camera at z = 1 looks at the floor.
    let obj = "mtllib s.mtl\n\
        v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\n\
        vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
        usemtl q\nf 1/1 2/2 3/3 4/4\n\
        v -3 -3 2\nv 3 -3 2\nv 3 3 2\nv -3 3 2\n\
        usemtl floor\nf 8 7 6 5\n";
    let (w, h, fov) = (16u32, 16u32, 40.0f32);
    let toml = format!(
        "obj = \"s.obj\"\nframes = 1\nresolution = [{w}, {h}]\n\
         [[keyframe]]\nframe = 0\nposition = [0.0, 0.0, 1.0]\nlook_at = [0.0, 0.0, 2.0]\n\
         up = [0.0, 1.0, 0.0]\nfov = {fov}\n"
    );
    let path = write_scene(
        dir.path(),
        obj,
        "newmtl q\nKd 0\nKe 1 1 1\nmap_Ke t.exr\nnewmtl floor\nKd 1 1 1\n",
        &toml,
    );
    let device = Device::new().unwrap();
    let scene = Scene::load(&path, &device).unwrap();
    assert!(scene.warnings.is_empty(), "{:?}", scene.warnings);
    // The map, bilinear between texel centres and repeating (v up: row 0 is the top).
    let map = |u: f32, v: f32| -> f64 {
        let x = u * N as f32 - 0.5;
        let y = (1.0 - v) * N as f32 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = ((x - x0) as f64, (y - y0) as f64);
        let at = |i: f32, j: f32| {
            let wrap = |k: f32| (k as i64).rem_euclid(N as i64) as u32;
            texel(wrap(i), wrap(j)) as f64
        };
        let top = at(x0, y0) * (1.0 - fx) + at(x0 + 1.0, y0) * fx;
        let bottom = at(x0, y0 + 1.0) * (1.0 - fx) + at(x0 + 1.0, y0 + 1.0) * fx;
        top * (1.0 - fy) + bottom * fy
    };
    // The floor's radiance at (px, py, 2): (1 / pi) * integral of map * cos * cos / r^2 over
    // the emitter, by the midpoint rule on an M x M grid.
    const M: usize = 480;
    let cell = 2.0 / M as f64;
    let emitter: Vec<(f64, f64, f64)> = (0..M * M)
        .map(|k| {
            let (ex, ey) = (
                -1.0 + (k % M) as f64 * cell + 0.5 * cell,
                -1.0 + (k / M) as f64 * cell + 0.5 * cell,
            );
            let le = map(((ex + 1.0) / 2.0) as f32, ((ey + 1.0) / 2.0) as f32);
            (ex, ey, le * cell * cell)
        })
        .collect();
    let radiance = |px: f64, py: f64| -> f64 {
        emitter
            .iter()
            .map(|&(ex, ey, le_da)| {
                let r2 = (px - ex).powi(2) + (py - ey).powi(2) + 4.0;
                le_da * 4.0 / (r2 * r2)
            })
            .sum::<f64>()
            / std::f64::consts::PI
    };
    // Pixel (i, j)'s centre on the floor: the camera looks along +z with +y up, one unit from
    // the floor; the image's x runs along -x (right-handed), which the map's symmetry hides.
    let half = (fov.to_radians() / 2.0).tan() as f64;
    let want: Vec<f64> = (0..w * h)
        .map(|k| {
            let (i, j) = ((k % w) as f64, (k / w) as f64);
            let sx = ((i + 0.5) / w as f64 * 2.0 - 1.0) * half;
            let sy = (1.0 - (j + 0.5) / h as f64 * 2.0) * half;
            radiance(-sx, sy)
        })
        .collect();
    // A light sample's density is the one `light_pdf` gives its point (which weighs the hits
    // of BSDF samples against light samples): the part found again from the point.
    let checked = light_pdf_matches_samples(&scene, glam::Vec3::new(0.3, -0.2, 2.0 - 1e-3), 2000);
    assert!(checked > 1900, "{checked}");
    let integ = Integrator::new(&scene, 1);
    let pool = thread_pool(0).unwrap();
    let spp = 256;
    let renders: Vec<Vec<f64>> = (0..8u64)
        .map(|seed| {
            pool.install(|| {
                render_frame_independent(
                    &integ,
                    &scene.camera(0, w, h),
                    0,
                    spp,
                    seed,
                    false,
                    &|_| {},
                )
            })
            .pixels
            .iter()
            .map(|p| p.x as f64)
            .collect()
        })
        .collect();
    // Region by region (4 x 4 blocks of 4 x 4 pixels): the seeds' region means against the
    // quadrature's.
    let seeds = renders.len() as f64;
    for by in 0..4 {
        for bx in 0..4 {
            let pixels: Vec<usize> = (0..16)
                .map(|k| ((by * 4 + k / 4) * w + bx * 4 + k % 4) as usize)
                .collect();
            let mean_of = |img: &Vec<f64>| pixels.iter().map(|&p| img[p]).sum::<f64>() / 16.0;
            let got: Vec<f64> = renders.iter().map(mean_of).collect();
            let m = got.iter().sum::<f64>() / seeds;
            let var = got.iter().map(|g| (g - m).powi(2)).sum::<f64>() / (seeds - 1.0);
            let se = (var / seeds).sqrt();
            let expect = mean_of(&want);
            let z = (m - expect) / se;
            assert!(
                z.abs() < 4.5 && (m / expect - 1.0).abs() < 0.01,
                "region ({bx}, {by}): {m} against the quadrature's {expect} (z {z:.2})"
            );
        }
    }
    // The noise: relative variance of a pixel per sample, over seeds, averaged over the frame.
    let per_sample = (0..(w * h) as usize)
        .map(|p| {
            let m = renders.iter().map(|r| r[p]).sum::<f64>() / seeds;
            let var = renders.iter().map(|r| (r[p] - m).powi(2)).sum::<f64>() / (seeds - 1.0);
            var * spp as f64 / (want[p] * want[p])
        })
        .sum::<f64>()
        / (w * h) as f64;
    assert!(
        per_sample < 0.25,
        "relative variance per sample {per_sample}: the light samples miss the bright texels"
    );
}

/// A mapped light cut into parts stays consistent where its numbers are extreme: far larger
/// than unit size (its barycentrics were found in f32, whose determinant overflowed from edges
/// of 4e9, and every point read as the first part: +69% on the floor at 1e10), and with texels
/// whose product with `Ke` passes the cap (the weights took the raw product, infinite, and every
/// light sample and MIS weight went NaN: a black frame). Every light sample's density must be
/// `light_pdf`'s, and the frame lit.
#[test]
fn a_mapped_light_is_sampled_consistently_at_any_size_and_brightness() {
    for (scale, texel) in [(1e10f32, 200.0f32), (1.0, 1e30)] {
        let dir = tempfile::tempdir().unwrap();
        write_texture(
            &dir.path().join("t.exr"),
            16,
            |x, y| Vec3::splat(if (x + y) % 5 == 0 { texel } else { 0.05 }),
            true,
        );
        let v = |x: f32, y: f32, z: f32| format!("v {} {} {}\n", x * scale, y * scale, z * scale);
        let obj = format!(
            "mtllib s.mtl\n{}{}{}{}vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl q\nf 1/1 2/2 3/3 4/4\n\
             {}{}{}{}usemtl floor\nf 8 7 6 5\n",
            v(-1.0, -1.0, 0.0),
            v(1.0, -1.0, 0.0),
            v(1.0, 1.0, 0.0),
            v(-1.0, 1.0, 0.0),
            v(-3.0, -3.0, 2.0),
            v(3.0, -3.0, 2.0),
            v(3.0, 3.0, 2.0),
            v(-3.0, 3.0, 2.0)
        );
        let toml = format!(
            "obj = \"s.obj\"\nframes = 1\nresolution = [16, 16]\n\
             [[keyframe]]\nframe = 0\nposition = [0.0, 0.0, {}]\nlook_at = [0.0, 0.0, {}]\n\
             up = [0.0, 1.0, 0.0]\nfov = 40.0\n",
            scale,
            2.0 * scale
        );
        let path = write_scene(
            dir.path(),
            &obj,
            "newmtl q\nKd 0\nKe 1 1 1\nmap_Ke t.exr\nnewmtl floor\nKd 1 1 1\n",
            &toml,
        );
        let device = Device::new().unwrap();
        let scene = Scene::load(&path, &device).unwrap();
        let x = glam::Vec3::new(0.3 * scale, -0.2 * scale, 2.0 * scale * (1.0 - 1e-4));
        let checked = light_pdf_matches_samples(&scene, x, 500);
        assert!(checked > 400, "scale {scale}, texel {texel}: {checked}");
        let integ = Integrator::new(&scene, 1);
        let pool = thread_pool(0).unwrap();
        let px = pool
            .install(|| {
                render_frame_independent(&integ, &scene.camera(0, 16, 16), 0, 16, 1, false, &|_| {})
            })
            .pixels;
        let mean = px.iter().map(|p| p.x as f64).sum::<f64>() / px.len() as f64;
        assert!(
            mean.is_finite() && mean > 0.0,
            "scale {scale}, texel {texel}: mean {mean}"
        );
    }
}

/// Take `n` light samples seen from `x` and check each one's density against what `light_pdf`
/// gives its point (found again by a ray: the light's triangle); the samples checked.
fn light_pdf_matches_samples(scene: &Scene, x: glam::Vec3, n: usize) -> usize {
    let mut sampler = reframe::sampling::Sampler::new(7, 0, 0, 0);
    let mut checked = 0;
    for _ in 0..n {
        let Some(ls) = scene.sample_light(x, sampler.next_2d()) else {
            continue;
        };
        let ray = reframe::embree::Ray::new(x, ls.wi);
        let Some(hit) = scene.geometry.intersect1(&ray) else {
            continue;
        };
        let pdf = scene.light_pdf(x, ls.p, hit.prim_id);
        assert!(
            (pdf / ls.pdf - 1.0).abs() < 1e-3,
            "{pdf} against the sample's {} at {}",
            ls.pdf,
            ls.p
        );
        checked += 1;
    }
    checked
}

/// The texture cache is sized from what the textures hold in it, in their files' own formats
/// (8-bit PNG: a byte a channel; half EXR: two; float EXR: four), so that every texture of a
/// scene is read once (at OpenImageIO's default of 1 GB, eight 8K textures were read from disk
/// again and again while rendering, and a file replaced during the render showed).
#[test]
fn the_texture_cache_counts_the_files_own_formats() {
    let tmp = tempfile::tempdir().unwrap();
    let grey = |_: u32, _: u32| Vec3::splat(0.5);
    write_texture(&tmp.path().join("a.png"), 64, grey, false);
    write_texture(&tmp.path().join("b.exr"), 32, grey, false);
    write_texture(&tmp.path().join("c.exr"), 16, grey, true);
    let mut t = Textures::new().unwrap();
    let mut want = 0;
    for (name, bytes) in [
        ("a.png", 64 * 64 * 3),
        ("b.exr", 32 * 32 * 3 * 2),
        ("c.exr", 16 * 16 * 3 * 4),
    ] {
        t.open(&tmp.path().join(name)).unwrap();
        want += bytes;
        assert_eq!(t.cache_bytes(), want, "{name}");
    }
    // A file opened again as a mask is in the cache once.
    t.open_mask(&tmp.path().join("a.png"), None).unwrap();
    assert_eq!(t.cache_bytes(), want);
    // Little: the default of 1 GB holds them; no warning.
    assert_eq!(t.size_cache(Some(1 << 30)), None);
    assert_eq!(t.size_cache(None), None);
}

/// The texture cache is memory the frames cannot have: a render that fits beside the scene's
/// textures runs, and one that would fit only without them is refused with a line that names
/// them (the cache, filled while rendering, was left out, and such a render ran out of memory
/// hours in).
#[test]
fn the_texture_cache_counts_against_the_memory_a_render_may_take() {
    use reframe::driver::RenderOptions;
    let d = tempfile::tempdir().unwrap();
    // 1024 x 1024 float RGB: 12.6 MB of texels.
    write_texture(
        &d.path().join("t.exr"),
        1024,
        |x, y| Vec3::splat(((x ^ y) & 1) as f32),
        true,
    );
    let p = write_scene(
        d.path(),
        QUAD,
        "newmtl q\nKd 1 1 1\nmap_Kd t.exr\n",
        &toml(
            8,
            8,
            [0.0, 0.0, 3.0],
            60.0,
            "[environment]\nradiance = [1, 1, 1]",
        ),
    );
    let device = Device::new().unwrap();
    let scene = Scene::load(&p, &device).unwrap();
    let cache = scene.texture_cache_bytes();
    assert!(cache >= 1024 * 1024 * 12, "{cache} bytes");
    let opts = RenderOptions::default();
    let frames = opts.memory_estimate((8, 8));
    opts.check_memory((8, 8), Some(frames + cache), cache)
        .unwrap();
    let err = opts
        .check_memory((8, 8), Some(frames + cache - 1), cache)
        .unwrap_err()
        .to_string();
    assert!(err.contains("the scene's textures about"), "{err}");
    // Without textures the same memory is enough.
    opts.check_memory((8, 8), Some(frames + cache - 1), 0)
        .unwrap();
    // An untextured scene holds no cache.
    let q = write_scene(
        d.path(),
        QUAD,
        "newmtl q\nKd 1 1 1\n",
        &toml(
            8,
            8,
            [0.0, 0.0, 3.0],
            60.0,
            "[environment]\nradiance = [1, 1, 1]",
        ),
    );
    assert_eq!(Scene::load(&q, &device).unwrap().texture_cache_bytes(), 0);
}

/// `Kd 0` beside a `map_Kd` (Maya's export of a colour connected to a file texture, whose own
/// value is unused) is read as `Kd 1`, the texture as it is, with a warning: the surface rendered
/// black without a word, where Maya and Blender show the texture. The frame is the one of
/// `Kd 1`, bit for bit.
#[test]
fn kd_zero_beside_a_colour_map_is_the_texture() {
    let (dir, device, pool) = checker_setup();
    let frame = |kd: &str| {
        let mtl = format!("newmtl q\nKd {kd}\nmap_Kd checker.png\n");
        quad_under_sky(dir.path(), &mtl, &device, &pool)
    };
    let (zero, said) = frame("0.00 0.00 0.00");
    let (one, none) = frame("1 1 1");
    assert!(none.is_empty(), "{none:?}");
    assert!(
        said.len() == 1
            && said[0].contains("line 2: material 'q': Kd 0 beside a map_Kd read as Kd 1"),
        "{said:?}"
    );
    assert!(one.iter().map(|p| p.x).sum::<f32>() > 1.0);
    assert!(zero.iter().zip(&one).all(|(a, b)| a == b));
}

/// Threads that looked up a scene's texels and end after the scene is gone, or go on to another
/// scene (a glossy map under an environment here, where it showed; a test binary loads many
/// scenes on its threads, as a program that embeds the renderer would): the
/// texture system's per-thread state, kept in thread-local storage, held cache tiles that the
/// ending thread released into the destroyed cache, and OpenImageIO aborted the process
/// ("decr_tiles: Assertion 'm_mem_used >= 0' failed") as a second scene was loaded and
/// rendered on the same threads, or as the threads ended.
#[test]
fn threads_that_read_textures_end_after_their_scene_without_harm() {
    let dir = tempfile::tempdir().unwrap();
    write_checker(dir.path());
    let path = write_scene(
        dir.path(),
        QUAD,
        "newmtl q\nKd 0.2\nKs 1\nNs 20\nmap_Ks checker.png\n",
        &toml(
            16,
            16,
            [0.0, 0.0, 2.0],
            40.0,
            "[environment]\nradiance = [1, 1, 1]",
        ),
    );
    let pool = thread_pool(2).unwrap();
    let mut frames = Vec::new();
    for _ in 0..3 {
        let path = path.clone();
        let pool = &pool;
        let px = std::thread::scope(|s| {
            s.spawn(move || {
                // Two scenes one after the other on this thread: the second one's cache may be
                // made where the first one's was freed.
                let device = Device::new().unwrap();
                let mut px = Vec::new();
                for _ in 0..2 {
                    let scene = Scene::load(&path, &device).unwrap();
                    let integ = Integrator::new(&scene, 2);
                    let cam = scene.camera(0, 16, 16);
                    px = pool
                        .install(|| render_frame_independent(&integ, &cam, 0, 4, 1, false, &|_| {}))
                        .pixels;
                }
                px
            })
            .join()
            .unwrap()
        });
        frames.push(px);
    }
    assert!(frames[0].iter().map(|p| p.x).sum::<f32>() > 1.0);
    assert!(frames.iter().all(|f| f == &frames[0]));
}

/// OpenImageIO's statistics asked for by its environment variable: printed when the scene's
/// textures go, and the process exits cleanly (with the texture sets' own per-thread state, it
/// crashed at exit reading the slot that state left).
#[test]
fn texture_statistics_from_the_environment_end_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_reframe"))
        .env("OPENIMAGEIO_IMAGECACHE_OPTIONS", "statistics:level=1")
        .args([
            "render",
            "scenes/production/courtyard.toml",
            "--res",
            "16x12",
            "--spp",
            "1",
        ])
        .args(["--frames", "0", "--threads", "2", "--out"])
        .arg(dir.path().join("f_####.exr"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{:?}: {}",
        o.status,
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(out.contains("Peak cache memory"), "{out}");
}

/// `Ke 0` (and `Ks 0`) beside its map: the map does nothing (the format multiplies it by the
/// colour), and a warning says so; it was dropped without a word, and a lamp textured so was
/// refused as a scene without light with nothing said of its map. Not read as 1: a strength of
/// 0 on an image-driven emission exports the same way, and means no light.
#[test]
fn a_map_beside_a_zero_ks_or_ke_is_said_to_do_nothing() {
    let (dir, device, pool) = checker_setup();
    let frame = |mtl: &str| quad_under_sky(dir.path(), mtl, &device, &pool);
    for (with_map, without, said) in [
        (
            "newmtl q\nKd 0.5\nKe 0 0 0\nmap_Ke checker.png\n",
            "newmtl q\nKd 0.5\nKe 0 0 0\n",
            "line 3: material 'q': map_Ke has no effect: the map is multiplied by Ke, which is 0",
        ),
        (
            "newmtl q\nKd 0.2\nKs 0\nNs 20\nmap_Ks checker.png\n",
            "newmtl q\nKd 0.2\nKs 0\nNs 20\n",
            "line 3: material 'q': map_Ks has no effect: the map is multiplied by Ks, which is 0",
        ),
    ] {
        let (a, warned) = frame(with_map);
        let (b, none) = frame(without);
        assert!(none.is_empty(), "{none:?}");
        assert!(warned.len() == 1 && warned[0].contains(said), "{warned:?}");
        assert!(a.iter().map(|p| p.x).sum::<f32>() > 1.0);
        assert!(a.iter().zip(&b).all(|(a, b)| a == b));
    }
    // The lamp alone: the refusal of a scene without light names the map.
    let path = write_scene(
        dir.path(),
        QUAD,
        "newmtl q\nKd 0.5\nKe 0 0 0\nmap_Ke checker.png\n",
        &toml(16, 16, [0.0, 0.0, 2.0], 40.0, ""),
    );
    let e = Scene::load(&path, &device).err().unwrap().to_string();
    assert!(
        e.contains("the scene has no light") && e.contains("map_Ke has no effect"),
        "{e}"
    );
}

/// A damaged image that makes the image library's decoder fault (OpenImageIO 2.4's Softimage
/// PIC reader on a file cut short inside its pixels: a segmentation fault on every run) ends
/// the process as before, but says which file: it ended with status 139 and nothing said.
#[test]
fn a_decoder_that_faults_on_a_damaged_texture_names_the_file() {
    use std::os::unix::process::ExitStatusExt;
    let d = tempfile::tempdir().unwrap();
    // An 8x8 RLE PIC of four runs per row, cut inside its pixel data.
    let mut pic = Vec::new();
    pic.extend(0x5380_F634u32.to_be_bytes());
    pic.extend(3.71f32.to_be_bytes());
    let mut comment = [0u8; 80];
    comment[0] = b't';
    pic.extend(comment);
    pic.extend(b"PICT");
    pic.extend(8u16.to_be_bytes());
    pic.extend(8u16.to_be_bytes());
    pic.extend(1.0f32.to_be_bytes());
    pic.extend(3u16.to_be_bytes());
    pic.extend(0u16.to_be_bytes());
    pic.extend([0, 8, 2, 0xE0]);
    for y in 0..8 {
        let runs: [[u8; 3]; 2] = if y < 4 {
            [[255, 0, 0], [0, 255, 0]]
        } else {
            [[0, 0, 255], [255, 255, 255]]
        };
        for c in runs {
            pic.push(128 + 3);
            pic.extend(c);
        }
    }
    pic.truncate(119);
    std::fs::write(d.path().join("cut.pic"), &pic).unwrap();
    let mtl = "newmtl m\nKd 0.5 0.5 0.5\nmap_Kd cut.pic\n";
    let obj = "mtllib s.mtl\nv -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\n\
               vt 0 1\nusemtl m\nf 1/1 2/2 3/3 4/4\n";
    let sky = "[environment]\nradiance = [1, 1, 1]";
    let scene = write_scene(
        d.path(),
        obj,
        mtl,
        &toml(16, 16, [0.0, 0.0, 2.0], 40.0, sky),
    );
    let out = d.path().join("out/f_####.exr");
    let o = common::reframe(&[
        "render",
        &scene,
        "--spp",
        "1",
        "--threads",
        "1",
        "--out",
        out.to_str().unwrap(),
    ])
    // (Where the system writes a core file, it goes with the temporary folder.)
    .current_dir(d.path())
    .output()
    .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    // The decoder's fault may also surface as an abort (a heap it damaged); either way the
    // process ends by the signal, after the line.
    assert!(
        matches!(
            o.status.signal(),
            Some(libc::SIGSEGV | libc::SIGABRT | libc::SIGBUS)
        ),
        "{:?}: {err}",
        o.status
    );
    assert!(
        err.contains("cut.pic crashed the image library (OpenImageIO)"),
        "{err}"
    );
}
