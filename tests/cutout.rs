//! Cut-outs (`map_d`): a masked quad renders as the geometry its mask keeps, placed once (the
//! scene's own mesh) and instanced; the reuse methods stay unbiased when the eyes of a group see
//! through its holes; packets and single rays see the same surface; masks are read from an
//! alpha channel, a grey channel or the first, as the file holds them; and what reframe does not
//! render (`d` below 1, a mask on a light) is said, or refused with `--strict`.
mod common;
mod stats;

use common::{render_in_memory, reuse_renders};
use glam::{Vec2, Vec3};
use reframe::driver::{render_frame_independent, thread_pool, RenderOptions};
use reframe::embree::Device;
use reframe::image::{write_image, Image, Metadata, Textures, WriteOptions};
use reframe::integrator::{Integrator, Rays};
use reframe::reuse::Method;
use reframe::scene::{LoadOptions, Scene};
use reframe::state::key::scene_and_build_hashes;
use stats::{assert_unbiased, block_moments, z_test};
use std::path::Path;

/// An uncompressed TGA (the format of many production assets' masks): 8-bit grey when
/// `channels` is 1, BGRA when 4; `texel(x, y)` gives each pixel's values (grey, or RGBA), row 0
/// at the top.
fn write_tga(path: &Path, size: u16, channels: u8, texel: impl Fn(u16, u16) -> [u8; 4]) {
    let (kind, bits, descriptor) = if channels == 1 {
        (3u8, 8u8, 0x20u8)
    } else {
        (2, 32, 0x28)
    };
    let mut b = vec![0u8, 0, kind, 0, 0, 0, 0, 0, 0, 0, 0, 0];
    b.extend_from_slice(&size.to_le_bytes());
    b.extend_from_slice(&size.to_le_bytes());
    b.extend_from_slice(&[bits, descriptor]);
    for y in 0..size {
        for x in 0..size {
            let [r, g, bl, a] = texel(x, y);
            if channels == 1 {
                b.push(r);
            } else {
                b.extend_from_slice(&[bl, g, r, a]);
            }
        }
    }
    std::fs::write(path, b).unwrap();
}

/// The mask of the tests: 8 x 8 texels, the top-left and bottom-right quarters kept (255), the
/// other two cut out (0).
fn checker(x: u16, y: u16) -> u8 {
    if (x < 4) == (y < 4) {
        255
    } else {
        0
    }
}

/// A quad z = 0 over x, y in [-1, 1] facing +z, texture coordinates (0, 0) at its bottom-left.
const QUAD: &str = "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\n\
    vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl leaf\nf 1/1 2/2 3/3 4/4\n";

/// What the mask keeps of `QUAD`, as geometry: the top-left and bottom-right quarters.
const SQUARES: &str = "v -1 0 0\nv 0 0 0\nv 0 1 0\nv -1 1 0\n\
    v 0 -1 0\nv 1 -1 0\nv 1 0 0\nv 0 0 0\nusemtl leaf\nf 1 2 3 4\nf 5 6 7 8\n";

/// A light behind the quad (6 x 6 at z = -2, facing +z) and a floor below it (relative
/// indices: it follows the quad in one file).
const ROOM: &str = "v -3 -3 -2\nv 3 -3 -2\nv 3 3 -2\nv -3 3 -2\nusemtl light\nf -4 -3 -2 -1\n\
    v -4 -1.5 -4\nv 4 -1.5 -4\nv 4 -1.5 4\nv -4 -1.5 4\nusemtl floor\nf -1 -2 -3 -4\n";

const MTL: &str = "newmtl leaf\nKd 0.8 0.3 0.2\nmap_d mask.tga\n\
    newmtl light\nKd 0 0 0\nKe 2 2 2\nnewmtl floor\nKd 0.5 0.5 0.5\n";

/// A camera that moves over `frames` frames, seeing the quad (and through it, the light)
/// slightly from the side, under a dim sky that lights its front: the top-level keys, and the
/// tables (which come after the scene's objects).
fn camera(frames: u32, w: u32, h: u32) -> (String, String) {
    let key = |frame: u32, position: &str| {
        format!(
            "[[keyframe]]\nframe = {frame}\nposition = {position}\nlook_at = [0.0, 0.0, 0.0]\n\
             up = [0.0, 1.0, 0.0]\nfov = 45.0\n"
        )
    };
    let mut tables =
        "[environment]\nradiance = [0.3, 0.35, 0.4]\n".to_string() + &key(0, "[0.6, 0.4, 4.0]");
    if frames > 1 {
        tables += &key(frames - 1, "[-0.3, 0.2, 3.6]");
    }
    (
        format!("frames = {frames}\nresolution = [{w}, {h}]\n"),
        tables,
    )
}

/// Write the scene of `objects` TOML (`obj = ...` or `[[object]]`s) with `files` (name and
/// text) beside the mask, and give its path.
fn write_scene(
    d: &Path,
    objects: &str,
    cam: &(String, String),
    files: &[(&str, String)],
) -> String {
    write_tga(&d.join("mask.tga"), 8, 1, |x, y| [checker(x, y); 4]);
    std::fs::write(d.join("s.mtl"), MTL).unwrap();
    for (name, text) in files {
        std::fs::write(d.join(name), text).unwrap();
    }
    let p = d.join("s.toml");
    std::fs::write(&p, format!("{}{objects}\n{}", cam.0, cam.1)).unwrap();
    p.to_str().unwrap().to_string()
}

/// `k` independent renders of frame `frame` of `scene` at `w` x `h`, 16 spp, seeds from `seed`.
fn renders(scene: &Scene, frame: u32, (w, h): (u32, u32), k: u64, seed: u64) -> Vec<Vec<Vec3>> {
    let integ = Integrator::new(scene, 8);
    let pool = thread_pool(0).unwrap();
    (0..k)
        .map(|s| {
            pool.install(|| {
                let cam = scene.camera(frame, w, h);
                render_frame_independent(&integ, &cam, frame, 16, seed + s, false, &|_| {}).pixels
            })
        })
        .collect()
}

/// The masked quad against the squares it keeps, modelled: the same picture block by block, for
/// the scene's own mesh and for an OBJ placed twice (Embree instances of one prototype). A mask
/// read upside down, or mirrored, or not at all, puts the light where the other has the quad.
#[test]
fn a_cut_out_quad_renders_as_the_geometry_its_mask_keeps() {
    let (w, h, b) = (40u32, 40u32, 4usize);
    let cam = camera(2, w, h);
    let placed = |obj: &str| {
        format!(
            "[[object]]\nobj = \"room.obj\"\n\
             [[object]]\nobj = \"{obj}\"\ntranslate = [-0.6, 0.0, 0.2]\nscale = 0.55\n\
             [[object]]\nobj = \"{obj}\"\ntranslate = [0.6, 0.0, -0.2]\nscale = 0.55\n"
        )
    };
    let mtllib = "mtllib s.mtl\n";
    let files = [
        ("cut.obj", format!("{mtllib}{QUAD}{ROOM}")),
        ("kept.obj", format!("{mtllib}{SQUARES}{ROOM}")),
        ("room.obj", format!("{mtllib}{ROOM}")),
        ("quad.obj", format!("{mtllib}{QUAD}")),
        ("squares.obj", format!("{mtllib}{SQUARES}")),
    ];
    let device = Device::new().unwrap();
    for (what, cut, kept) in [
        (
            "own mesh",
            "obj = \"cut.obj\"".to_string(),
            "obj = \"kept.obj\"".to_string(),
        ),
        ("instanced", placed("quad.obj"), placed("squares.obj")),
    ] {
        let d = tempfile::tempdir().unwrap();
        let cut = Scene::load(&write_scene(d.path(), &cut, &cam, &files), &device).unwrap();
        let kept = Scene::load(&write_scene(d.path(), &kept, &cam, &files), &device).unwrap();
        assert!(cut.warnings.is_empty(), "{:?}", cut.warnings);
        if what == "instanced" {
            assert_eq!(cut.instances.len(), 2, "the masked quad is instanced");
        }
        let test = block_moments(
            &renders(&cut, 0, (w, h), 32, 100),
            w as usize,
            h as usize,
            b,
        );
        let reference = block_moments(
            &renders(&kept, 0, (w, h), 32, 900),
            w as usize,
            h as usize,
            b,
        );
        assert_unbiased(
            &format!("the cut-out quad ({what})"),
            &z_test(&test, &reference),
        );
        assert_eq!(cut.textures.as_ref().unwrap().failures(), 0);
    }
}

/// The reuse methods on the masked scene while the camera moves: a first hit seen through a
/// hole by one eye is hidden by the quad from another, and every eye's visibility test and
/// the weights must agree with it. `mis-exact` and `mis-cv` against an independent reference,
/// block by block; and the tracer's packets against single rays, which must see the same
/// surface.
#[test]
fn reuse_and_packets_agree_on_a_cut_out_scene() {
    let (w, h, b, target) = (36usize, 36usize, 4, 3u32);
    let d = tempfile::tempdir().unwrap();
    let files = [("cut.obj", format!("mtllib s.mtl\n{QUAD}{ROOM}"))];
    let path = write_scene(d.path(), "obj = \"cut.obj\"", &camera(7, 36, 36), &files);
    let device = Device::new().unwrap();
    let scene = Scene::load(&path, &device).unwrap();
    let reference = block_moments(&renders(&scene, target, (36, 36), 64, 5000), w, h, b);
    let integ = Integrator::new(&scene, 8);
    let pool = thread_pool(0).unwrap();
    for method in [Method::MisCv, Method::MisExact] {
        let res = (w as u32, h as u32);
        let frames = (0..=6, target);
        let renders = reuse_renders(&integ, &pool, (method, 5), frames, res, (64, 6000));
        let z = z_test(&block_moments(&renders, w, h, b), &reference);
        assert_unbiased(&format!("{method:?} on the cut-out scene"), &z);
    }
    // Packets and single rays: the same frames, up to the last bits of a hit.
    let frame = |rays: Rays, method: Method| {
        let opts = RenderOptions {
            method,
            window: if method == Method::Independent { 1 } else { 3 },
            spp: 4,
            frames: Some(2..=4),
            resolution: Some((w as u32, h as u32)),
            primary: rays,
            paths: rays,
            progress: false,
            ..RenderOptions::default()
        };
        pool.install(|| {
            render_in_memory(&integ, &opts)
                .0
                .remove(&3)
                .unwrap()
                .pixels()
        })
    };
    for method in [Method::Independent, Method::MisCv] {
        let (single, packet) = (frame(Rays::Single, method), frame(Rays::Packet, method));
        let worst = single
            .iter()
            .zip(&packet)
            .map(|(a, b)| (*a - *b).abs().max_element())
            .fold(0.0f32, f32::max);
        assert!(
            worst < 1e-3,
            "{method:?}: packets and single rays differ by {worst}"
        );
    }
}

/// A mask is the channel its `-imfchan` names, or its file's alpha channel, else its grey one,
/// else its first, as the file holds it:
/// an 8-bit code of 128 is 0.502, not the 0.216 that decoding sRGB would make of it (coverage
/// is not a colour). Interpolated bilinearly between texel centres, as colours are.
#[test]
fn masks_read_alpha_grey_or_first_channel_as_stored() {
    let d = tempfile::tempdir().unwrap();
    // Left column 0, right column 128 (of 255) in the mask channel; the colour white.
    let value = |x: u16| if x == 0 { 0u8 } else { 128 };
    let rgba = d.path().join("rgba.tga");
    write_tga(&rgba, 2, 4, |x, _| [255, 255, 255, value(x)]);
    let grey = d.path().join("grey.tga");
    write_tga(&grey, 2, 1, |x, _| [value(x); 4]);
    let exr = d.path().join("rgb.exr");
    let mut img = Image::new(2, 2, &["R", "G", "B"]);
    for (i, px) in img.data.chunks_exact_mut(3).enumerate() {
        let r = if i % 2 == 0 { 0.0 } else { 128.0 / 255.0 };
        px.copy_from_slice(&[r, 1.0, 1.0]);
    }
    let exr_opts = WriteOptions { exr_float: true };
    write_image(&exr, &img, &Metadata::default(), &exr_opts).unwrap();
    let mut t = Textures::new().unwrap();
    for path in [&rgba, &grey, &exr] {
        let id = t.open_mask(path, None).unwrap();
        for (u, want) in [(0.25, 0.0), (0.75, 128.0 / 255.0), (0.5, 64.0 / 255.0)] {
            let got = t.value(id, Vec2::new(u, 0.5));
            assert!(
                (got - want).abs() < 1e-6,
                "{} at u {u}: {got}, want {want}",
                path.display()
            );
        }
    }
    // The RGBA file's colour is still its colour when a material also takes it as its map_Kd.
    let colour = t.open(&rgba).unwrap();
    assert_ne!(colour, t.open_mask(&rgba, None).unwrap());
    // ... and not multiplied by its alpha (OIIO's default for PNG and TGA), which would darken
    // it wherever it is partly transparent: white where alpha is 0, as stored.
    assert_eq!(t.rgb(colour, Vec2::new(0.25, 0.5)), glam::Vec3::ONE);
    // `-imfchan` picks the channel: r the (white) red, m the alpha; a grey file has no alpha.
    let red = t.open_mask(&rgba, Some('r')).unwrap();
    assert_eq!(t.value(red, Vec2::new(0.25, 0.5)), 1.0);
    let matte = t.open_mask(&rgba, Some('m')).unwrap();
    assert_eq!(t.value(matte, Vec2::new(0.25, 0.5)), 0.0);
    let e = t.open_mask(&grey, Some('m')).unwrap_err().to_string();
    assert!(
        e.contains("-imfchan m names a channel it does not have"),
        "{e}"
    );
    // `l` is the luminance: a grey file's grey, and of a colour file without one, its red,
    // green and blue weighted as BT.709 (not its red: pure red, 0.2126, is cut out; pure green,
    // 0.7152, kept), each below zero read as zero, as the lookups read them.
    let grey_l = t.open_mask(&grey, Some('l')).unwrap();
    assert_eq!(t.value(grey_l, Vec2::new(0.75, 0.5)), 128.0 / 255.0);
    let hues = d.path().join("hues.exr");
    let mut img = Image::new(2, 2, &["B", "G", "R"]);
    for (i, px) in img.data.chunks_exact_mut(3).enumerate() {
        // Left red (and blue below zero), right green; as B, G, R.
        let bgr = if i % 2 == 0 {
            [-4.0, 0.0, 1.0]
        } else {
            [0.0, 1.0, 0.0]
        };
        px.copy_from_slice(&bgr);
    }
    write_image(&hues, &img, &Metadata::default(), &exr_opts).unwrap();
    let lum = t.open_mask(&hues, Some('l')).unwrap();
    for (u, want) in [(0.25, 0.2126), (0.75, 0.7152), (0.5, 0.4639)] {
        let got = t.value(lum, Vec2::new(u, 0.5));
        assert!(
            (got - want).abs() < 1e-6,
            "luminance at u {u}: {got}, want {want}"
        );
    }
}

/// What reframe does not render is said: `d` below 1 (the surface stays opaque) and a mask on
/// a light (lights are opaque), each a warning naming the line, refused with `--strict`; `d 1`
/// says nothing. The mask is part of the scene's identity. A missing mask is refused naming the
/// MTL line.
#[test]
fn dissolve_and_masked_lights_are_said_masks_hashed_and_missing_masks_refused() {
    let device = Device::new().unwrap();
    let cam = camera(1, 8, 8);
    let obj = "obj = \"cut.obj\"";
    for (mtl, warning) in [
        (
            "newmtl leaf\nKd 0.5 0.5 0.5\nd 0.4\nnewmtl light\nKe 1 1 1\nnewmtl floor\nKd 1 1 1\n",
            Some("line 3: 'd 0.4' in 'leaf': dissolve (d) not rendered"),
        ),
        (
            "newmtl leaf\nKd 0.5 0.5 0.5\nd 1.0\nTr 0\nnewmtl light\nKe 1 1 1\nnewmtl floor\n",
            None,
        ),
        (
            "newmtl leaf\nKd 0.5 0.5 0.5\nnewmtl light\nKe 1 1 1\nmap_d mask.tga\nnewmtl floor\n",
            Some("line 5: 'map_d mask.tga' in 'light': map_d on an emitting material ignored"),
        ),
    ] {
        let d = tempfile::tempdir().unwrap();
        let files = [("cut.obj", format!("mtllib s.mtl\n{QUAD}{ROOM}"))];
        let path = write_scene(d.path(), obj, &cam, &files);
        std::fs::write(d.path().join("s.mtl"), mtl).unwrap();
        let scene = Scene::load(&path, &device).unwrap();
        match warning {
            Some(w) => {
                assert!(
                    scene.warnings.iter().any(|x| x.contains(w)),
                    "{:?} lacks {w}",
                    scene.warnings
                );
                let strict = LoadOptions { strict: true };
                let e = Scene::load_with(&path, &device, &strict).err().unwrap();
                assert!(
                    format!("{e:#}").contains("refused: strict loading"),
                    "{e:#}"
                );
            }
            None => assert!(scene.warnings.is_empty(), "{:?}", scene.warnings),
        }
    }
    // The light's mask is left out: it emits over its whole quad, as if it had none.
    let d = tempfile::tempdir().unwrap();
    let files = [("cut.obj", format!("mtllib s.mtl\n{QUAD}{ROOM}"))];
    let path = write_scene(d.path(), obj, &cam, &files);
    std::fs::write(
        d.path().join("s.mtl"),
        "newmtl light\nKe 1 1 1\nmap_d mask.tga\n",
    )
    .unwrap();
    let scene = Scene::load(&path, &device).unwrap();
    assert!(scene.texture_maps().iter().all(|m| m.cutout.is_none()));
    // A map_d that names the material's own colour texture, which has no alpha (an exporter's
    // habit where it means no mask), cuts nothing out, and says so; the same file with alpha,
    // or a grey mask, is a mask.
    let mut img = Image::new(4, 4, &["R", "G", "B"]);
    img.data.fill(0.2);
    write_image(
        &d.path().join("bark.png"),
        &img,
        &Metadata::default(),
        &WriteOptions::default(),
    )
    .unwrap();
    let mtl = "newmtl leaf\nKd 1 1 1\nmap_Kd bark.png\nmap_d bark.png\nnewmtl light\nKe 1 1 1\n";
    std::fs::write(d.path().join("s.mtl"), mtl).unwrap();
    let scene = Scene::load(&path, &device).unwrap();
    assert!(scene.texture_maps().iter().all(|m| m.cutout.is_none()));
    assert!(
        scene.warnings.iter().any(|w| w.contains(
            "line 4: 'map_d bark.png' in 'leaf': map_d names the colour texture (map_Kd), which \
             has no alpha: no cut-out"
        )),
        "{:?}",
        scene.warnings
    );
    let mtl = "newmtl leaf\nKd 1 1 1\nmap_Kd mask.tga\nmap_d mask.tga\nnewmtl light\nKe 1 1 1\n";
    std::fs::write(d.path().join("s.mtl"), mtl).unwrap();
    let scene = Scene::load(&path, &device).unwrap();
    assert!(scene.texture_maps().iter().any(|m| m.cutout.is_some()));
    // The mask's content is part of the scene's identity (checkpoints, chunk merges, cached
    // references): another mask is another scene.
    std::fs::write(d.path().join("s.mtl"), MTL).unwrap();
    let hash = || {
        scene_and_build_hashes(&Scene::load(&path, &device).unwrap())
            .unwrap()
            .0
    };
    let before = hash();
    assert_eq!(before, hash());
    write_tga(&d.path().join("mask.tga"), 8, 1, |x, y| {
        [255 - checker(x, y); 4]
    });
    assert_ne!(before, hash());
    // A missing mask.
    std::fs::write(
        d.path().join("s.mtl"),
        "newmtl leaf\nKd 1 1 1\nmap_d gone.tga\n",
    )
    .unwrap();
    let e = format!("{:#}", Scene::load(&path, &device).err().unwrap());
    assert!(
        e.contains("s.mtl: line 3: 'map_d gone.tga': no file"),
        "{e}"
    );
}

/// The files of maps reframe does not render (`map_Bump`, `map_Ka`, `norm`) are still the
/// scene's inputs: a frame or a report named like one is refused and the file kept.
#[test]
fn maps_that_are_not_rendered_are_never_written_over() {
    let d = tempfile::tempdir().unwrap();
    let files = [("cut.obj", format!("mtllib s.mtl\n{QUAD}{ROOM}"))];
    let path = write_scene(d.path(), "obj = \"cut.obj\"", &camera(1, 8, 8), &files);
    let mtl = "newmtl leaf\nKd 0.5 0.5 0.5\nmap_Bump -bm 1 m_0000.png\nmap_Ka k.png\n\
               norm n.json\nnewmtl light\nKe 1 1 1\nnewmtl floor\nKd 1 1 1\n";
    std::fs::write(d.path().join("s.mtl"), mtl).unwrap();
    for f in ["m_0000.png", "k.png", "n.json"] {
        std::fs::write(d.path().join(f), "precious").unwrap();
    }
    let at = |f: &str| d.path().join(f).display().to_string();
    for args in [
        vec!["--out".to_string(), at("m_####.png")],
        vec!["--out".to_string(), at("k.png")],
        vec![
            "--out".to_string(),
            at("o_####.png"),
            "--stats".into(),
            at("n.json"),
        ],
    ] {
        let o = common::reframe(
            &[
                vec!["render".into(), path.clone(), "--spp".into(), "1".into()],
                args,
            ]
            .concat(),
        )
        .output()
        .unwrap();
        common::assert_refused(&o, "that is an input of this command");
    }
    for f in ["m_0000.png", "k.png", "n.json"] {
        assert_eq!(
            std::fs::read_to_string(d.path().join(f)).unwrap(),
            "precious"
        );
    }
}

/// A mask saved in the colour of an RGBA file whose alpha was filled (opaque everywhere: the
/// DDS and TGA masks of Crytek's Sponza) is read from its colour, with a warning, and cuts out
/// exactly what the same mask in a grey file does; its alpha was read, and nothing was cut
/// out. An opaque alpha over a colour that would cut nothing, or `-imfchan m`, still reads the
/// alpha; and a `map_d` naming the material's own `map_Kd` with an opaque alpha still cuts
/// nothing out, without a word, as before.
#[test]
fn a_mask_in_the_colour_of_a_file_with_an_opaque_alpha_is_read_from_its_colour() {
    let device = Device::new().unwrap();
    let d = tempfile::tempdir().unwrap();
    let filled = d.path().join("filled.tga");
    write_tga(&filled, 8, 4, |x, y| {
        [checker(x, y), checker(x, y), checker(x, y), 255]
    });
    let white = d.path().join("white.tga");
    write_tga(&white, 8, 4, |_, _| [255, 255, 255, 255]);
    let mut t = Textures::new().unwrap();
    let m = t.open_mask(&filled, None).unwrap();
    assert!(t.mask_alpha_opaque(m));
    // Texel centres of the kept top-left quarter (v = 1 is row 0) and of a cut-out quarter.
    assert_eq!(t.value(m, Vec2::new(0.2, 0.8)), 1.0);
    assert_eq!(t.value(m, Vec2::new(0.8, 0.8)), 0.0);
    let a = t.open_mask(&filled, Some('m')).unwrap();
    assert!(!t.mask_alpha_opaque(a));
    assert_eq!(t.value(a, Vec2::new(0.8, 0.8)), 1.0);
    let w = t.open_mask(&white, None).unwrap();
    assert!(!t.mask_alpha_opaque(w));

    // The scene: the quad cut by the filled RGBA file renders the frames of the grey mask's.
    let cam = camera(1, 24, 24);
    let files = [("cut.obj", format!("mtllib s.mtl\n{QUAD}{ROOM}"))];
    let path = write_scene(d.path(), "obj = \"cut.obj\"", &cam, &files);
    let grey = Scene::load(&path, &device).unwrap();
    assert!(grey.warnings.is_empty(), "{:?}", grey.warnings);
    let want = renders(&grey, 0, (24, 24), 1, 7);
    std::fs::write(
        d.path().join("s.mtl"),
        MTL.replace("map_d mask.tga", "map_d filled.tga"),
    )
    .unwrap();
    let scene = Scene::load(&path, &device).unwrap();
    assert!(
        scene.warnings.iter().any(|x| x.contains(
            "line 3: 'map_d filled.tga' in 'leaf': mask whose alpha is opaque everywhere read \
             from its grey or first colour channel"
        )),
        "{:?}",
        scene.warnings
    );
    assert_eq!(renders(&scene, 0, (24, 24), 1, 7), want);
    // Refused with --strict, as every repair.
    let strict = LoadOptions { strict: true };
    assert!(Scene::load_with(&path, &device, &strict).is_err());
    // The material's own map_Kd as its map_d, with an opaque alpha: nothing cut out, no word.
    std::fs::write(
        d.path().join("s.mtl"),
        MTL.replace("map_d mask.tga", "map_Kd filled.tga\nmap_d filled.tga"),
    )
    .unwrap();
    let solid = Scene::load(&path, &device).unwrap();
    assert!(solid.warnings.is_empty(), "{:?}", solid.warnings);
    std::fs::write(
        d.path().join("s.mtl"),
        MTL.replace("map_d mask.tga", "map_Kd filled.tga"),
    )
    .unwrap();
    let unmasked = Scene::load(&path, &device).unwrap();
    assert_eq!(
        renders(&solid, 0, (24, 24), 1, 7),
        renders(&unmasked, 0, (24, 24), 1, 7)
    );
    // The same with a grey and alpha file (two channels): read from its grey as a mask, and as
    // its own map_Kd's map_d nothing cut out, without a word (it was cut by its grey).
    let mut ya = Image::new(8, 8, &["Y", "A"]);
    for (i, px) in ya.data.chunks_exact_mut(2).enumerate() {
        px.copy_from_slice(&[checker(i as u16 % 8, i as u16 / 8) as f32 / 255.0, 1.0]);
    }
    let grey_alpha = d.path().join("ya.exr");
    write_image(
        &grey_alpha,
        &ya,
        &Metadata::default(),
        &WriteOptions { exr_float: true },
    )
    .unwrap();
    let m = t.open_mask(&grey_alpha, None).unwrap();
    assert!(t.mask_alpha_opaque(m));
    assert_eq!(t.value(m, Vec2::new(0.8, 0.8)), 0.0);
    std::fs::write(
        d.path().join("s.mtl"),
        MTL.replace("map_d mask.tga", "map_Kd ya.exr\nmap_d ya.exr"),
    )
    .unwrap();
    let solid = Scene::load(&path, &device).unwrap();
    assert!(solid.warnings.is_empty(), "{:?}", solid.warnings);
    std::fs::write(
        d.path().join("s.mtl"),
        MTL.replace("map_d mask.tga", "map_Kd ya.exr"),
    )
    .unwrap();
    let unmasked = Scene::load(&path, &device).unwrap();
    assert_eq!(
        renders(&solid, 0, (24, 24), 1, 7),
        renders(&unmasked, 0, (24, 24), 1, 7)
    );
}
