//! Bad input through the real binary: every case must end with a clear one-line error and a
//! non-zero exit, never a panic, and leave no output file behind.
use std::path::Path;
use std::process::Command;

const OBJ: &str = "mtllib s.mtl
v -1 0 -1
v 1 0 -1
v 1 0 1
v -1 0 1
v -0.2 1.9 -0.2
v 0.2 1.9 -0.2
v 0.2 1.9 0.2
v -0.2 1.9 0.2
usemtl floor
f 1 4 3 2
usemtl light
f 5 6 7 8
";
const MTL: &str = "newmtl floor
Kd 0.5 0.5 0.5
newmtl light
Kd 0 0 0
Ke 5 5 5
";
const TOML: &str = "obj = \"s.obj\"
frames = 2
resolution = [16, 12]
[[keyframe]]
frame = 0
position = [0.0, 1.0, 3.0]
look_at = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
fov = 45.0
";

struct Case {
    name: &'static str,
    toml: String,
    obj: String,
    mtl: String,
    args: Vec<String>,
    expect: &'static str,
}

fn case(name: &'static str, expect: &'static str) -> Case {
    Case {
        name,
        toml: TOML.into(),
        obj: OBJ.into(),
        mtl: MTL.into(),
        args: vec![],
        expect,
    }
}

fn run(c: &Case) {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("s.toml"), &c.toml).unwrap();
    if !c.obj.is_empty() {
        std::fs::write(d.join("s.obj"), &c.obj).unwrap();
    }
    std::fs::write(d.join("s.mtl"), &c.mtl).unwrap();
    let out_dir = d.join("out");
    let mut args: Vec<String> = vec!["render".into(), d.join("s.toml").display().to_string()];
    if !c.args.iter().any(|a| a == "--spp") {
        args.extend(["--spp".to_string(), "1".to_string()]);
    }
    if !c.args.iter().any(|a| a == "--out") {
        args.push("--out".into());
        args.push(out_dir.join("f_####.exr").display().to_string());
    }
    args.extend(c.args.iter().cloned());
    let o = Command::new(env!("CARGO_BIN_EXE_reframe"))
        .args(&args)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{}: exited 0", c.name);
    assert!(
        !err.contains("panicked") && !err.contains("RUST_BACKTRACE"),
        "{}: panic: {err}",
        c.name
    );
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert!(
        lines.len() == 1 || err.contains("Usage:"),
        "{}: not one line: {err}",
        c.name
    );
    assert!(
        err.to_lowercase().contains(&c.expect.to_lowercase()),
        "{}: '{}' not in: {err}",
        c.name,
        c.expect
    );
    let left = files_under(d)
        .into_iter()
        .filter(|p| !p.ends_with("s.toml") && !p.ends_with("s.obj") && !p.ends_with("s.mtl"));
    let left: Vec<_> = left.collect();
    assert!(left.is_empty(), "{}: left files behind: {left:?}", c.name);
}

fn files_under(d: &Path) -> Vec<String> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(d).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            v.extend(files_under(&p));
        } else {
            v.push(p.display().to_string());
        }
    }
    v
}

#[test]
fn valid_scene_renders() {
    // The corpus below is only meaningful if the unmutated scene is fine.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("s.toml"), TOML).unwrap();
    std::fs::write(d.join("s.obj"), OBJ).unwrap();
    std::fs::write(d.join("s.mtl"), MTL).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_reframe"))
        .args([
            "render",
            &d.join("s.toml").display().to_string(),
            "--spp",
            "1",
            "--out",
        ])
        .arg(d.join("o_####.png"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(d.join("o_0000.png").exists() && d.join("o_0001.png").exists());
}

#[test]
fn bad_inputs_fail_cleanly() {
    let mut cases = vec![];
    let mut c = case("missing obj", "cannot read");
    c.obj = String::new();
    cases.push(c);
    let mut c = case("malformed obj", "s.obj");
    c.obj = OBJ.replace("v 1 0 -1", "v 1 zero -1");
    cases.push(c);
    let mut c = case("short Kd", "line 2");
    c.mtl = MTL.replace("Kd 0.5 0.5 0.5", "Kd 0.5 0.5");
    cases.push(c);
    let mut c = case("nan vertex", "not finite");
    c.obj = OBJ.replace("v 1 0 -1", "v nan 0 -1");
    cases.push(c);
    let mut c = case("inf vertex", "not finite");
    c.obj = OBJ.replace("v 1 0 -1", "v inf 0 -1");
    cases.push(c);
    let mut c = case("repeated vertex", "appears twice");
    c.obj = OBJ.to_string() + "usemtl floor\nf 1 2 1\n";
    cases.push(c);
    let mut c = case("collinear triangle", "zero-area");
    c.obj = OBJ.to_string() + "v 2 0 -1\nusemtl floor\nf 1 2 9\n";
    cases.push(c);
    let mut c = case("out-of-range index", "s.obj");
    c.obj = OBJ.to_string() + "usemtl floor\nf 1 2 42\n";
    cases.push(c);
    let mut c = case("no lights", "no lights");
    c.mtl = MTL.replace("Ke 5 5 5", "");
    cases.push(c);
    let mut c = case("zero resolution in scene", "resolution");
    c.toml = TOML.replace("[16, 12]", "[0, 12]");
    cases.push(c);
    let mut c = case("zero resolution flag", "positive");
    c.args = vec!["--res".into(), "0x12".into()];
    cases.push(c);
    let mut c = case("zero samples", "--spp 0");
    c.args = vec!["--spp".into(), "0".into()];
    cases.push(c);
    for fov in ["0.0", "180.0", "-10.0", "nan"] {
        let mut c = case("fov out of range", "fov");
        c.toml = TOML.replace("fov = 45.0", &format!("fov = {fov}"));
        cases.push(c);
    }
    let mut c = case("up parallel to view", "parallel");
    c.toml = TOML.replace("position = [0.0, 1.0, 3.0]", "position = [0.0, 3.0, 0.0]");
    cases.push(c);
    let mut c = case("unknown key", "unknown field");
    c.toml = TOML.to_string() + "exposure = 2\n";
    cases.push(c);
    let mut c = case("wrong type", "line");
    c.toml = TOML.replace("frames = 2", "frames = \"two\"");
    cases.push(c);
    let mut c = case("frames out of range", "--frames");
    c.args = vec!["--frames".into(), "0-5".into()];
    cases.push(c);
    let mut c = case("even window", "odd");
    c.args = vec![
        "--method".into(),
        "mis-exact".into(),
        "--window".into(),
        "2".into(),
    ];
    cases.push(c);
    let mut c = case("window larger than the frames", "larger than");
    c.args = vec![
        "--method".into(),
        "mis".into(),
        "--window".into(),
        "5".into(),
    ];
    cases.push(c);
    let mut c = case("energy not conserved", "exceeds 1");
    c.mtl = MTL.replace("Kd 0.5 0.5 0.5", "Kd 0.8 0.8 0.8\nKs 0.5 0.5 0.5");
    cases.push(c);
    let mut c = case("unwritable output folder", "/dev/null/sub");
    c.args = vec!["--out".into(), "/dev/null/sub/f_####.exr".into()];
    cases.push(c);
    let mut c = case("unknown extension", "xyz");
    c.args = vec!["--out".into(), "f_####.xyz".into()];
    cases.push(c);
    let mut c = case("no frame field for several frames", "####");
    c.args = vec!["--out".into(), "f.exr".into()];
    cases.push(c);
    let mut c = case("unknown scene", "no such file");
    c.args = vec![];
    c.toml = TOML.into();
    cases.push(c);
    let n = cases.len();
    for c in &cases {
        if c.name == "unknown scene" {
            let o = Command::new(env!("CARGO_BIN_EXE_reframe"))
                .args(["render", "no-such-scene"])
                .output()
                .unwrap();
            let err = String::from_utf8_lossy(&o.stderr);
            assert!(
                !o.status.success() && err.contains("no such file") && err.lines().count() == 1,
                "{err}"
            );
            continue;
        }
        run(c);
    }
    eprintln!("{n} bad inputs rejected cleanly");
}
