//! Several objects placed by transforms: an OBJ placed more than once is one Embree prototype
//! with an instance per placement, and renders like the same geometry flattened into one mesh;
//! an emitting OBJ placed twice is copied (two lights); the refusals of `[[object]]`.
mod common;

use glam::{DMat3, DMat4, DVec3, Vec2, Vec3};
use reframe::driver::{render_frame_independent, thread_pool};
use reframe::embree::{Device, Ray};
use reframe::integrator::Integrator;
use reframe::scene::Scene;
use reframe::state::key::scene_and_build_hashes;
use std::fmt::Write as _;
use std::path::Path;

/// A unit cube centred at the origin, wound outwards, with texture coordinates per face.
fn cube() -> (Vec<Vec3>, Vec<[usize; 4]>) {
    let v = (0..8)
        .map(|i| {
            Vec3::new(
                if i & 1 == 0 { -0.5 } else { 0.5 },
                if i & 2 == 0 { -0.5 } else { 0.5 },
                if i & 4 == 0 { -0.5 } else { 0.5 },
            )
        })
        .collect();
    let faces = vec![
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
        [2, 6, 7, 3],
        [0, 1, 5, 4],
    ];
    (v, faces)
}

/// An OBJ of `copies` of the cube, each through its transform (none: as it is), in material
/// `box`, then (if `ground`) a floor quad in material `floor`.
fn obj(copies: &[Option<DMat4>], ground: bool) -> String {
    let (v, faces) = cube();
    let mut s = String::from("mtllib s.mtl\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl box\n");
    for (k, m) in copies.iter().enumerate() {
        for p in &v {
            let q = match m {
                Some(m) => m.transform_point3(p.as_dvec3()).as_vec3(),
                None => *p,
            };
            writeln!(s, "v {} {} {}", q.x, q.y, q.z).unwrap();
        }
        // A mirrored copy's faces turn inwards, here and in the instance alike (a geometric
        // normal follows the placed corners' winding).
        for f in &faces {
            let ids: Vec<String> = f
                .iter()
                .enumerate()
                .map(|(c, i)| format!("{}/{}", 8 * k + i + 1, c + 1))
                .collect();
            writeln!(s, "f {}", ids.join(" ")).unwrap();
        }
    }
    if ground {
        let base = 8 * copies.len();
        s.push_str("v -4 -0.5 -4\nv 4 -0.5 -4\nv 4 -0.5 4\nv -4 -0.5 4\nusemtl floor\n");
        writeln!(s, "f {} {} {} {}", base + 1, base + 4, base + 3, base + 2).unwrap();
    }
    s
}

const MTL: &str =
    "newmtl box\nKd 0.6 0.4 0.3\nKs 0.2 0.2 0.2\nNs 40\nnewmtl floor\nKd 0.5 0.5 0.5\n";

/// The scene file: `geometry` (`obj = ...` at the top, or `[[object]]` tables at the end).
fn toml(geometry: &str) -> String {
    let (top, tables) = if geometry.starts_with("[[") {
        ("", geometry)
    } else {
        (geometry, "")
    };
    format!(
        "{top}\nframes = 1\nresolution = [64, 48]\n\
         [environment]\nradiance = [0.6, 0.7, 0.9]\n\
         [[keyframe]]\nframe = 0\nposition = [2.5, 2.0, 4.0]\nlook_at = [0.3, 0.0, 0.0]\n\
         up = [0.0, 1.0, 0.0]\nfov = 50.0\n{tables}\n"
    )
}

fn placements() -> Vec<(String, DMat4)> {
    let rot = |x: f64, y: f64, z: f64| {
        DMat4::from_mat3(
            DMat3::from_rotation_z(z.to_radians())
                * DMat3::from_rotation_y(y.to_radians())
                * DMat3::from_rotation_x(x.to_radians()),
        )
    };
    vec![
        (
            "translate = [-0.8, 0.0, 0.3]\nrotate = [10.0, 35.0, 5.0]\nscale = 0.9".into(),
            DMat4::from_translation(DVec3::new(-0.8, 0.0, 0.3))
                * rot(10.0, 35.0, 5.0)
                * DMat4::from_scale(DVec3::splat(0.9)),
        ),
        (
            "matrix = [-1.2, 0, 0, 1.0,  0, 0.7, 0, -0.15,  0, 0, 1.0, -0.5,  0, 0, 0, 1]".into(),
            DMat4::from_cols_array(&[
                -1.2, 0.0, 0.0, 0.0, 0.0, 0.7, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, -0.15, -0.5, 1.0,
            ]),
        ),
        (
            "translate = [0.4, 0.9, -1.6]\nrotate = [0.0, -20.0, 0.0]\nscale = [0.5, 1.5, 0.5]"
                .into(),
            DMat4::from_translation(DVec3::new(0.4, 0.9, -1.6))
                * rot(0.0, -20.0, 0.0)
                * DMat4::from_scale(DVec3::new(0.5, 1.5, 0.5)),
        ),
    ]
}

fn write(d: &Path, files: &[(&str, &str)]) -> String {
    for (name, text) in files {
        std::fs::write(d.join(name), text).unwrap();
    }
    d.join("s.toml").to_str().unwrap().to_string()
}

#[test]
fn one_obj_under_several_names_is_read_once_and_instanced() {
    // The cube as `cube.obj`, `./cube.obj`, `sub/../cube.obj`, a symbolic link and a hard
    // link: one file, so one prototype with five instances (each name was an OBJ of its own,
    // read again and copied into the scene's mesh).
    let d = tempfile::tempdir().unwrap();
    std::fs::create_dir(d.path().join("sub")).unwrap();
    let mut objects = String::new();
    for name in [
        "cube.obj",
        "./cube.obj",
        "sub/../cube.obj",
        "link.obj",
        "hard.obj",
    ] {
        write!(objects, "[[object]]\nobj = \"{name}\"\n").unwrap();
    }
    let s = write(
        d.path(),
        &[
            ("cube.obj", &obj(&[None], false)),
            ("s.mtl", MTL),
            ("s.toml", &toml(&objects)),
        ],
    );
    std::os::unix::fs::symlink("cube.obj", d.path().join("link.obj")).unwrap();
    std::fs::hard_link(d.path().join("cube.obj"), d.path().join("hard.obj")).unwrap();
    let scene = Scene::load(&s, &Device::new().unwrap()).unwrap();
    assert_eq!((scene.prototypes.len(), scene.instances.len()), (1, 5));
    assert!(scene.triangles.is_empty());
    // A copy of the file is another OBJ: the two are placed once each, in the scene's mesh.
    std::fs::copy(d.path().join("cube.obj"), d.path().join("copy.obj")).unwrap();
    let two = "[[object]]\nobj = \"cube.obj\"\n[[object]]\nobj = \"copy.obj\"\n";
    let s = write(d.path(), &[("s.toml", &toml(two))]);
    let scene = Scene::load(&s, &Device::new().unwrap()).unwrap();
    assert_eq!((scene.prototypes.len(), scene.triangles.len()), (0, 24));
}

#[test]
fn names_in_another_unicode_composition_find_their_files() {
    // Folders and files named in decomposed form (`u` and a combining diaeresis, as a macOS
    // archive stores them), named in the scene file composed (`ü`), and the other way round:
    // one name, which was "no such file".
    let d = tempfile::tempdir().unwrap();
    let (composed, decomposed) = ("gr\u{fc}n", "gru\u{308}n");
    let cube = obj(&[None], false);
    for folder in [decomposed, "bl\u{fc}n"] {
        std::fs::create_dir(d.path().join(folder)).unwrap();
        std::fs::write(d.path().join(folder).join("cube.obj"), &cube).unwrap();
        std::fs::write(d.path().join(folder).join("s.mtl"), MTL).unwrap();
    }
    let camera = "{\"frames\": [{\"frame\": 0, \"fov\": 50, \"position\": [2.5, 2, 4], \
                  \"look_at\": [0, 0, 0], \"up\": [0, 1, 0]}]}";
    std::fs::write(d.path().join("ka\u{308}mera.json"), camera).unwrap();
    let scene = format!(
        "camera = \"k\u{e4}mera.json\"\nframes = 1\nresolution = [64, 48]\n\
         [environment]\nradiance = [0.6, 0.7, 0.9]\n\
         [[object]]\nobj = \"{composed}/cube.obj\"\n[[object]]\nobj = \"blu\u{308}n/cube.obj\"\n\
         translate = [2, 0, 0]\n"
    );
    let s = write(d.path(), &[("s.toml", &scene)]);
    let scene = Scene::load(&s, &Device::new().unwrap()).unwrap();
    assert_eq!(scene.triangles.len(), 24, "both cubes");
    let s = write(
        d.path(),
        &[("s.toml", &toml(&format!("obj = \"{composed}/cube.obj\"")))],
    );
    assert_eq!(
        Scene::load(&s, &Device::new().unwrap())
            .unwrap()
            .triangles
            .len(),
        12
    );
}

#[test]
fn instances_render_like_the_same_geometry_flattened() {
    let place = placements();
    // Instanced: the cube placed three times (one of them mirrored), the floor once.
    let inst_dir = tempfile::tempdir().unwrap();
    let mut objects = String::from("[[object]]\nobj = \"floor.obj\"\n");
    for (t, _) in &place {
        write!(objects, "[[object]]\nobj = \"cube.obj\"\n{t}\n").unwrap();
    }
    let floor = "mtllib s.mtl\nv -4 -0.5 -4\nv 4 -0.5 -4\nv 4 -0.5 4\nv -4 -0.5 4\n\
                 usemtl floor\nf 1 4 3 2\n";
    let inst = write(
        inst_dir.path(),
        &[
            ("cube.obj", &obj(&[None], false)),
            ("floor.obj", floor),
            ("s.mtl", MTL),
            ("s.toml", &toml(&objects)),
        ],
    );
    // Flattened: the same corners, transformed here, in one OBJ.
    let flat_dir = tempfile::tempdir().unwrap();
    let copies: Vec<Option<DMat4>> = place.iter().map(|p| Some(p.1)).collect();
    let flat = write(
        flat_dir.path(),
        &[
            ("s.obj", &obj(&copies, true)),
            ("s.mtl", MTL),
            ("s.toml", &toml("obj = \"s.obj\"")),
        ],
    );
    let device = Device::new().unwrap();
    let a = Scene::load(&inst, &device).unwrap();
    let b = Scene::load(&flat, &device).unwrap();
    assert!(a.warnings.is_empty(), "{:?}", a.warnings);
    assert_eq!((a.prototypes.len(), a.instances.len()), (1, 3));
    assert_eq!(
        a.triangles.len(),
        2,
        "only the floor is the scene's own mesh"
    );
    assert!(b.instances.is_empty());
    assert!(a.inputs.iter().any(|p| p.ends_with("cube.obj")));
    // Primary hits: the same points, normals, materials and texture coordinates.
    let cam = a.camera(0, 64, 48);
    let (mut hits, mut same) = (0, 0);
    for y in 0..48 {
        for x in 0..64 {
            let ray = Ray::new(
                cam.eye,
                cam.direction(Vec2::new(x as f32 + 0.5, y as f32 + 0.5)),
            );
            let (ha, hb) = (a.geometry.intersect1(&ray), b.geometry.intersect1(&ray));
            match (ha, hb) {
                (None, None) => same += 1,
                (Some(ha), Some(hb)) => {
                    hits += 1;
                    let (sa, sb) = (a.surface(&ha), b.surface(&hb));
                    let close = (sa.p - sb.p).length() < 1e-4
                        && (sa.ng - sb.ng).length() < 1e-4
                        && (sa.uv - sb.uv).length() < 1e-4
                        && a.material(&sa).kd == b.material(&sb).kd;
                    same += close as usize;
                }
                _ => {}
            }
        }
    }
    eprintln!("primary rays: {hits} hits, {same} of {} agree", 64 * 48);
    assert!(hits > 1500, "{hits} hits");
    assert!(same >= 64 * 48 - 4, "{same} of {} pixels agree", 64 * 48);
    // Rendered with the same numbers: paths part only where a ray's rounding differs.
    let pool = thread_pool(0).unwrap();
    let render = |s: &Scene| {
        let integ = Integrator::new(s, 8);
        pool.install(|| {
            render_frame_independent(&integ, &s.camera(0, 64, 48), 0, 8, 11, false, &|_| {})
        })
        .pixels
    };
    let (pa, pb) = (render(&a), render(&b));
    let close = pa
        .iter()
        .zip(&pb)
        .filter(|(x, y)| (**x - **y).abs().max_element() <= 1e-3 * y.max_element().max(1.0))
        .count();
    assert!(
        close as f64 >= 0.97 * pa.len() as f64,
        "{close} of {} pixels agree",
        pa.len()
    );
    let mean = |p: &[Vec3]| p.iter().sum::<Vec3>() / p.len() as f32;
    let (ma, mb) = (mean(&pa), mean(&pb));
    let exact = pa.iter().zip(&pb).filter(|(x, y)| x == y).count();
    eprintln!(
        "rendered: {exact} of {} pixels identical, {close} within 1e-3, means {ma} and {mb}",
        pa.len()
    );
    assert!(((ma - mb) / mb).abs().max_element() < 2e-3, "{ma} vs {mb}");
    // A placement is part of the scene's identity.
    let moved = inst_dir.path().join("s.toml");
    let hash = || {
        scene_and_build_hashes(&Scene::load(moved.to_str().unwrap(), &device).unwrap())
            .unwrap()
            .0
    };
    let before = hash();
    std::fs::write(&moved, toml(&objects.replace("0.9", "0.91"))).unwrap();
    assert_ne!(before, hash());
}

#[test]
fn an_emitting_object_placed_twice_is_two_lights() {
    let d = tempfile::tempdir().unwrap();
    let lamp = "mtllib s.mtl\nv -0.2 0 -0.2\nv 0.2 0 -0.2\nv 0.2 0 0.2\nv -0.2 0 0.2\n\
                usemtl light\nf 1 2 3 4\n";
    let floor = "mtllib s.mtl\nv -4 -0.5 -4\nv 4 -0.5 -4\nv 4 -0.5 4\nv -4 -0.5 4\n\
                 usemtl floor\nf 1 4 3 2\n";
    let objects = "[[object]]\nobj = \"floor.obj\"\n\
                   [[object]]\nobj = \"lamp.obj\"\ntranslate = [-1, 2, 0]\n\
                   [[object]]\nobj = \"lamp.obj\"\ntranslate = [1, 2, 0]\n";
    let path = write(
        d.path(),
        &[
            ("lamp.obj", lamp),
            ("floor.obj", floor),
            (
                "s.mtl",
                "newmtl light\nKe 5 5 5\nnewmtl floor\nKd 0.5 0.5 0.5\n",
            ),
            (
                "s.toml",
                &toml(objects).replace("[environment]\nradiance = [0.6, 0.7, 0.9]\n", ""),
            ),
        ],
    );
    let device = Device::new().unwrap();
    let s = Scene::load(&path, &device).unwrap();
    assert!(s.instances.is_empty() && s.prototypes.is_empty());
    assert_eq!(s.lights.tris.len(), 4);
    // Both lamps face down (their quads wind clockwise seen from above): a point below sees
    // both.
    let below = Vec3::new(0.0, -0.5, 0.0);
    let mut lit = [false; 2];
    for k in 0..256 {
        let u = Vec2::new((k as f32 + 0.5) / 256.0, 0.3);
        if let Some(ls) = s.sample_light(below, u) {
            if ls.le != Vec3::ZERO {
                lit[(ls.p.x > 0.0) as usize] = true;
            }
        }
    }
    assert_eq!(lit, [true, true]);
}

#[test]
fn a_mirrored_emitting_placement_turns_its_light_over_and_says_so() {
    // A mirror turns the counter-clockwise side over (as Mitsuba 3 takes an OBJ's winding after
    // its transform): a lamp facing down, mirrored in x, faces up, and loading says so once per
    // emitting OBJ placed mirrored; a mirrored object that does not emit is not warned of.
    let d = tempfile::tempdir().unwrap();
    let lamp = "mtllib s.mtl\nv -0.2 0 -0.2\nv 0.2 0 -0.2\nv 0.2 0 0.2\nv -0.2 0 0.2\n\
                usemtl light\nf 1 2 3 4\n";
    let floor = "mtllib s.mtl\nv -4 -0.5 -4\nv 4 -0.5 -4\nv 4 -0.5 4\nv -4 -0.5 4\n\
                 usemtl floor\nf 1 4 3 2\n";
    let mtl = "newmtl light\nKe 5 5 5\nnewmtl floor\nKd 0.5 0.5 0.5\n";
    let device = Device::new().unwrap();
    for (lamp_scale, floor_scale, warned, lit_below) in [
        ("[1, 1, 1]", "[-1, 1, 1]", false, true),
        ("[-1, 1, 1]", "[1, 1, 1]", true, false),
        // Two mirrors are a rotation (180 degrees about x): it faces up, as turned, unwarned.
        ("[1, -1, -1]", "[1, 1, 1]", false, false),
    ] {
        let objects = format!(
            "[[object]]\nobj = \"floor.obj\"\nscale = {floor_scale}\n\
             [[object]]\nobj = \"lamp.obj\"\ntranslate = [0, 2, 0]\nscale = {lamp_scale}\n"
        );
        let path = write(
            d.path(),
            &[
                ("lamp.obj", lamp),
                ("floor.obj", floor),
                ("s.mtl", mtl),
                (
                    "s.toml",
                    &toml(&objects).replace("[environment]\nradiance = [0.6, 0.7, 0.9]\n", ""),
                ),
            ],
        );
        let s = Scene::load(&path, &device).unwrap();
        let mirrored: Vec<&String> = s
            .warnings
            .iter()
            .filter(|w| w.contains("placed mirrored"))
            .collect();
        assert_eq!(
            mirrored.len(),
            warned as usize,
            "{lamp_scale}: {:?}",
            s.warnings
        );
        if warned {
            assert!(mirrored[0].contains("object 'lamp.obj'"), "{}", mirrored[0]);
        }
        // Which side the lamp lights: a point below it, and one above.
        let lit = |p: Vec3| {
            (0..64).any(|k| {
                let u = Vec2::new((k as f32 + 0.5) / 64.0, 0.3);
                s.sample_light(p, u).is_some_and(|ls| ls.le != Vec3::ZERO)
            })
        };
        assert_eq!(lit(Vec3::new(0.0, -0.5, 0.0)), lit_below, "{lamp_scale}");
        assert_eq!(lit(Vec3::new(0.0, 3.0, 0.0)), !lit_below, "{lamp_scale}");
    }
}

/// A light emits to the side its vertex normals point to, where its triangles have them, as in
/// pbrt-v4 and Mitsuba 3: a lamp quad wound to face down with normals pointing up lights what is
/// above it (it lit the floor below, and Mitsuba the ceiling); without normals the winding
/// decides. Mirrored, a lamp with normals shines as its mirror image would, unwarned.
#[test]
fn a_light_emits_to_the_side_of_its_vertex_normals() {
    let d = tempfile::tempdir().unwrap();
    // Wound clockwise seen from above (faces down); `vn 0 1 0`: normals up.
    let lamp = |vn: &str| {
        format!(
            "mtllib s.mtl\nv -0.2 0 -0.2\nv 0.2 0 -0.2\nv 0.2 0 0.2\nv -0.2 0 0.2\n{}\
             usemtl light\n{}\n",
            if vn.is_empty() {
                String::new()
            } else {
                format!("vn {vn}\n")
            },
            if vn.is_empty() {
                "f 1 2 3 4"
            } else {
                "f 1//1 2//1 3//1 4//1"
            }
        )
    };
    let floor = "mtllib s.mtl\nv -4 -0.5 -4\nv 4 -0.5 -4\nv 4 -0.5 4\nv -4 -0.5 4\n\
                 usemtl floor\nf 1 4 3 2\n";
    let mtl = "newmtl light\nKe 5 5 5\nnewmtl floor\nKd 0.5 0.5 0.5\n";
    let device = Device::new().unwrap();
    // (vn, scale, lit below, turned over: the placed winding and normals disagree)
    for (vn, scale, lit_below, turned) in [
        ("", "[1, 1, 1]", true, false),
        ("0 1 0", "[1, 1, 1]", false, true),
        ("0 -1 0", "[1, 1, 1]", true, false),
        // Mirrored in x: the winding turns up, the normals stay.
        ("0 1 0", "[-1, 1, 1]", false, false),
        ("0 -1 0", "[-1, 1, 1]", true, true),
        // Mirrored in y: the flat lamp's corners stay, the normals turn down.
        ("0 1 0", "[1, -1, 1]", true, false),
    ] {
        let objects = format!(
            "[[object]]\nobj = \"floor.obj\"\n\
             [[object]]\nobj = \"lamp.obj\"\ntranslate = [0, 2, 0]\nscale = {scale}\n"
        );
        let path = write(
            d.path(),
            &[
                ("lamp.obj", &lamp(vn)),
                ("floor.obj", floor),
                ("s.mtl", mtl),
                (
                    "s.toml",
                    &toml(&objects).replace("[environment]\nradiance = [0.6, 0.7, 0.9]\n", ""),
                ),
            ],
        );
        let s = Scene::load(&path, &device).unwrap();
        let lit = |p: Vec3| {
            (0..64).any(|k| {
                let u = Vec2::new((k as f32 + 0.5) / 64.0, 0.3);
                s.sample_light(p, u).is_some_and(|ls| ls.le != Vec3::ZERO)
            })
        };
        let case = format!("vn '{vn}', scale {scale}");
        // Said where the placed winding and the normals disagree, naming the object (the
        // warning named the scene file alone).
        let said = s.warnings.iter().any(|w| {
            w.contains(
                "object 'lamp.obj': 2 emitting triangle(s) wound against their vertex normals \
                 emit to the side",
            )
        });
        assert_eq!(said, turned, "{case}: {:?}", s.warnings);
        assert_eq!(lit(Vec3::new(0.0, -0.5, 0.0)), lit_below, "{case}");
        assert_eq!(lit(Vec3::new(0.0, 3.0, 0.0)), !lit_below, "{case}");
        if !vn.is_empty() {
            assert!(
                s.warnings.iter().all(|w| !w.contains("placed mirrored")),
                "{case}: {:?}",
                s.warnings
            );
        }
    }
}

#[test]
fn object_tables_are_checked() {
    let d = tempfile::tempdir().unwrap();
    let floor = "v -4 -0.5 -4\nv 4 -0.5 -4\nv 4 -0.5 4\nv -4 -0.5 4\nf 1 4 3 2\n";
    std::fs::write(d.path().join("floor.obj"), floor).unwrap();
    let device = Device::new().unwrap();
    let dir = d.path().display().to_string();
    let rest = "frames = 1\nresolution = [16, 12]\n[environment]\nradiance = [1.0, 1.0, 1.0]\n\
                [[keyframe]]\nframe = 0\nposition = [0.0, 1.0, 3.0]\nlook_at = [0.0, 0.0, 0.0]\n\
                up = [0.0, 1.0, 0.0]\nfov = 45.0\n";
    // (top-level keys, tables after the rest): the tables start at line 11.
    for (top, tables, want) in [
        (
            "obj = \"floor.obj\"\n",
            "[[object]]\nobj = \"floor.obj\"",
            "give either obj or [[object]] tables, not both".to_string(),
        ),
        (
            "",
            "",
            "no obj and no [[object]]: the scene has no geometry".to_string(),
        ),
        (
            "",
            "[[object]]\nobj = \"nope.obj\"",
            format!("line 12: object 'nope.obj': OBJ '{dir}/nope.obj': no such file"),
        ),
        (
            "",
            "[[object]]\nobj = \"floor.obj\"\nscale = [1, 0, 1]",
            "line 12: object 'floor.obj': scale has a zero".to_string(),
        ),
        (
            "",
            "[[object]]\nobj = \"floor.obj\"\nshear = 1.0",
            "unknown key 'shear'".to_string(),
        ),
    ] {
        let text = format!("{top}{rest}{tables}\n");
        let geometry = tables;
        let p = d.path().join("s.toml");
        std::fs::write(&p, &text).unwrap();
        let e = match Scene::load(p.to_str().unwrap(), &device) {
            Ok(_) => panic!("{geometry:?} loaded"),
            Err(e) => format!("{e:#}"),
        };
        assert!(e.contains(&want), "{geometry:?}: {e}\nwant: {want}\n{text}");
    }
}

/// The shipped production scene (generated by examples/make_production.rs): it loads without a
/// warning, its crates and columns are instanced, its textures are read, and every method
/// renders it with finite pixels, background pixels (sky) among them.
#[test]
fn the_shipped_production_scene_renders_with_every_method() {
    use reframe::driver::RenderOptions;
    use reframe::reuse::Method;
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/production/courtyard.toml");
    let device = Device::new().unwrap();
    let s = Scene::load(path.to_str().unwrap(), &device).unwrap();
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    assert_eq!((s.prototypes.len(), s.instances.len()), (2, 8));
    assert_eq!(s.textures.as_ref().map(|t| t.len()), Some(3));
    assert_eq!(s.frames, 48);
    let integ = Integrator::new(&s, 6);
    let pool = thread_pool(0).unwrap();
    for method in [
        Method::Independent,
        Method::Havran,
        Method::Mis,
        Method::MisExact,
        Method::MisCv,
    ] {
        let opts = RenderOptions {
            method,
            window: if method == Method::Independent { 1 } else { 3 },
            spp: 2,
            frames: Some(20..=25),
            resolution: Some((48, 36)),
            progress: false,
            ..RenderOptions::default()
        };
        let frames = pool.install(|| common::render_in_memory(&integ, &opts).0);
        assert_eq!(frames.len(), 6, "{method:?}");
        let px = frames[&22].pixels();
        let sky = px.iter().filter(|p| p.z > p.x && p.z > 0.3).count();
        assert!(sky > 100, "{method:?}: {sky} sky pixels");
    }
}

/// An emitting OBJ is copied for each placement: placements whose copies would not fit in the
/// memory left are refused in one line naming the `[[object]]`, before the copies are made
/// (under a 1.5 GB address-space limit, 400 copies of a 20000-triangle lamp, about 2 GB,
/// aborted or failed in Embree's build after seconds of copying). Placements that pass that
/// check render, or fail in one line: 120 to 150 copies, which the check let through, aborted
/// with a backtrace where the light tables were built (about 300 bytes a light triangle, grown
/// by doubling).
#[test]
fn emitting_placements_beyond_the_memory_left_are_one_line() {
    let d = tempfile::tempdir().unwrap();
    let n = 100;
    let mut lamp = String::from("mtllib s.mtl\nusemtl light\n");
    for j in 0..=n {
        for i in 0..=n {
            writeln!(lamp, "v {} 0 {}", i as f32 / n as f32, j as f32 / n as f32).unwrap();
        }
    }
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i + 1;
            writeln!(
                lamp,
                "f {a} {} {}\nf {a} {} {}",
                a + n + 1,
                a + n + 2,
                a + n + 2,
                a + 1
            )
            .unwrap();
        }
    }
    let placements = |k: usize| -> String {
        (0..k)
            .map(|i| format!("[[object]]\nobj = \"lamp.obj\"\ntranslate = [{i}, 2, 0]\n"))
            .collect()
    };
    let run = |k: usize| {
        let path = write(
            d.path(),
            &[
                ("lamp.obj", &lamp),
                ("s.mtl", "newmtl light\nKe 5 5 5\n"),
                ("s.toml", &toml(&placements(k))),
            ],
        );
        let cmd = format!(
            "ulimit -v 1500000 && exec '{}' render '{path}' --spp 1 --threads 1 --res 8x6 --out '{}'",
            env!("CARGO_BIN_EXE_reframe"),
            d.path().join("o/f_####.exr").display()
        );
        std::process::Command::new("sh")
            .args(["-c", &cmd])
            .output()
            .unwrap()
    };
    // As tests/texture.rs: only where reframe starts under the limit at all.
    if !run(2).status.success() {
        eprintln!("skipped: reframe does not start under a 1.5 GB address-space limit here");
        return;
    }
    for k in [120, 135, 150] {
        let o = run(k);
        let err = String::from_utf8_lossy(&o.stderr);
        let code = o.status.code();
        assert!(
            code == Some(0) || (code == Some(1) && err.trim().lines().count() == 1),
            "{k} placements: {code:?} {err}"
        );
        // An 8x6 frame left no room by the scene is not told to lower --res.
        assert!(
            !err.contains("frames in flight") || err.contains("the scene loaded holds about"),
            "{err}"
        );
    }
    let o = run(400);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("object 'lamp.obj': placed 400 times, its 20000 triangles (it emits)")
            && err.trim().lines().count() == 1,
        "{err}"
    );
}

/// A smooth mesh (vertex normals) placed under a non-uniform scale: an instance's shading
/// normals are its flattened copy's, each corner's normal taken into world space and made unit
/// before they are interpolated (interpolated in object space, they were weighted otherwise:
/// up to 2% apart per pixel, a glossy ellipsoid's highlight moved).
#[test]
fn instanced_smooth_normals_follow_a_non_uniform_scale_as_a_copy_does() {
    let (nu, nv) = (12, 8);
    let mut sphere = String::from("mtllib s.mtl\nusemtl box\n");
    for j in 0..=nv {
        for i in 0..nu {
            let (th, ph) = (
                std::f32::consts::PI * j as f32 / nv as f32,
                std::f32::consts::TAU * i as f32 / nu as f32,
            );
            let p = Vec3::new(th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin());
            writeln!(
                sphere,
                "v {} {} {}\nvn {} {} {}",
                p.x, p.y, p.z, p.x, p.y, p.z
            )
            .unwrap();
        }
    }
    for j in 0..nv {
        for i in 0..nu {
            let k = |a: usize, b: usize| a * nu + b % nu + 1;
            let (a, b, c, d) = (k(j, i), k(j, i + 1), k(j + 1, i + 1), k(j + 1, i));
            writeln!(
                sphere,
                "f {a}//{a} {b}//{b} {c}//{c}\nf {a}//{a} {c}//{c} {d}//{d}"
            )
            .unwrap();
        }
    }
    let at = [
        "translate = [-0.9, 0.3, 0.0]\nscale = [1.6, 0.5, 0.8]\nrotate = [0, 30, 10]",
        "translate = [0.9, 0.3, -0.5]\nscale = [0.5, 1.2, 1.0]\nrotate = [20, 0, 0]",
    ];
    // Instanced: one OBJ placed twice. Flattened: two copies of it, each placed once.
    let (di, df) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let objects = |names: [&str; 2]| -> String {
        (0..2)
            .map(|k| format!("[[object]]\nobj = \"{}\"\n{}\n", names[k], at[k]))
            .collect()
    };
    let inst = write(
        di.path(),
        &[
            ("a.obj", &sphere),
            ("s.mtl", MTL),
            ("s.toml", &toml(&objects(["a.obj", "a.obj"]))),
        ],
    );
    let flat = write(
        df.path(),
        &[
            ("a.obj", &sphere),
            ("b.obj", &sphere),
            ("s.mtl", MTL),
            ("s.toml", &toml(&objects(["a.obj", "b.obj"]))),
        ],
    );
    let device = Device::new().unwrap();
    let (a, b) = (
        Scene::load(&inst, &device).unwrap(),
        Scene::load(&flat, &device).unwrap(),
    );
    assert_eq!((a.instances.len(), b.instances.len()), (2, 0));
    let cam = a.camera(0, 64, 48);
    let (mut hits, mut worst) = (0, 0.0f32);
    for y in 0..48 {
        for x in 0..64 {
            let ray = Ray::new(
                cam.eye,
                cam.direction(Vec2::new(x as f32 + 0.5, y as f32 + 0.5)),
            );
            if let (Some(ha), Some(hb)) = (a.geometry.intersect1(&ray), b.geometry.intersect1(&ray))
            {
                let (sa, sb) = (a.surface(&ha), b.surface(&hb));
                if (sa.p - sb.p).length() < 1e-4 {
                    hits += 1;
                    worst = worst.max((sa.ns - sb.ns).length());
                }
            }
        }
    }
    assert!(hits > 300, "{hits} hits");
    assert!(worst < 1e-4, "shading normals {worst} apart");
}
