//! Property: whatever is done to a valid scene, `reframe render` either renders it or refuses it
//! cleanly (exit 1 or 2, one non-empty line on stderr, no panic, no file written), and never
//! hangs.
//!
//! proptest draws `MUTANTS` mutants (200; `REFRAME_MUTANTS=n` for more) from a fixed ChaCha
//! seed, so every run tries the same ones. Each takes a scene (vase, cornell, furnace, or the
//! corpus' small `base` scene), one of its three files (TOML, OBJ, MTL), and applies one to
//! three edits: delete, duplicate, swap or insert lines, drop a key, replace a number with
//! `nan`, `inf`, `-1`, `1e39`, a word …, truncate at a byte, flip the bits of a byte. Each
//! mutant renders frame 0 at 8x6 with 1 spp; runs are killed after 20 s. The mutants run on a
//! few threads, so there is no shrinking: a failing mutant's files are kept under
//! `target/tmp/mutants-failed/` and its edits printed. A refusal must also name a file by its
//! path; `REFRAME_MUTANTS_SHOW=1` prints every refusal.
mod common;

use common::{files_under, par_map, refusal, run_reframe};
use proptest::prelude::*;
use proptest::sample::{select, Index};
use proptest::strategy::ValueTree;
use proptest::test_runner::{Config, RngAlgorithm, TestRng, TestRunner};
use std::path::{Path, PathBuf};
use std::time::Duration;

const MUTANTS: usize = 200;
const SEED: [u8; 32] = *b"reframe: bad input, nothing lost";

/// Numbers put in place of a number.
const NUMBERS: &[&str] = &[
    "nan",
    "NaN",
    "inf",
    "-inf",
    "-1",
    "0",
    "-0",
    "1e-45",
    "1e30",
    "1e39",
    "4294967296",
    "99999999999999999999",
    "-2147483648",
    "0.5",
    "2",
    "x",
    "",
    "1.5.2",
    "1,",
    "[",
    "\"",
];

/// Lines put anywhere: TOML keys, OBJ and MTL statements, junk.
const LINES: &[&str] = &[
    "exposure = 2",
    "frames = 3",
    "frames = 0",
    "[[keyframe]]",
    "frame = 1",
    "fov = 90.0",
    "up = [0.0, 0.0, 1.0]",
    "resolution = [4, 4]",
    "obj = \"missing.obj\"",
    "keyframe = 1",
    "[camera]",
    "f 1 2",
    "f 1 2 3",
    "f -1 -2 -3",
    "f 1 1 2",
    "f 1/1/1 2/2/2 3/3/3",
    "f 99999 1 2",
    "v nan 0 0",
    "v 1e30 0 0",
    "v 0 0 0 1 1 1",
    "vn 0 0 0",
    "vt 0",
    "l 1 2 3",
    "p 1 2",
    "f 1 2 3 4 5 6 7",
    "f\t1\t2  3",
    "vn nan 0 0",
    "o thing",
    "usemtl nope",
    "usemtl",
    "mtllib nope.mtl",
    "newmtl extra",
    "newmtl",
    "Kd 1",
    "Ke 1 1 1",
    "Ks 0.9 0.9 0.9",
    "Ns -1",
    "Ns 1e30",
    "Ke 1e38 1e38 1e38",
    "Kd 0.9",
    "Kd spectral a.rfl",
    "# caf\u{e9}",
    "illum x",
    "map_Kd",
    "",
    "#",
    "garbage",
    "\u{0}",
    "\u{feff}",
    "resolution = [8, 6, 2]",
    "position = [0.0, 1.0, 3.0, 4.0]",
    "= = =",
    "[",
    "\"",
];

#[derive(Clone, Debug)]
enum Op {
    DeleteLine(Index),
    DuplicateLine(Index),
    SwapLines(Index, Index),
    InsertLine(Index, &'static str),
    /// Delete the i-th line that holds a key (TOML) or a statement (OBJ, MTL).
    DropKey(Index),
    /// Replace the i-th number.
    Number(Index, &'static str),
    Truncate(Index),
    /// XOR the i-th byte with a non-zero mask.
    FlipByte(Index, u8),
}

#[derive(Clone, Debug)]
struct Mutant {
    scene: usize,
    /// 0: TOML, 1: OBJ, 2: MTL.
    file: usize,
    ops: Vec<Op>,
}

fn op() -> impl Strategy<Value = Op> {
    prop_oneof![
        2 => any::<Index>().prop_map(Op::DeleteLine),
        1 => any::<Index>().prop_map(Op::DuplicateLine),
        1 => (any::<Index>(), any::<Index>()).prop_map(|(a, b)| Op::SwapLines(a, b)),
        2 => (any::<Index>(), select(LINES)).prop_map(|(i, l)| Op::InsertLine(i, l)),
        2 => any::<Index>().prop_map(Op::DropKey),
        4 => (any::<Index>(), select(NUMBERS)).prop_map(|(i, n)| Op::Number(i, n)),
        1 => any::<Index>().prop_map(Op::Truncate),
        1 => (any::<Index>(), 1..=255u8).prop_map(|(i, m)| Op::FlipByte(i, m)),
    ]
}

fn mutant(scenes: usize) -> impl Strategy<Value = Mutant> {
    (0..scenes, 0..3usize, prop::collection::vec(op(), 1..=3))
        .prop_map(|(scene, file, ops)| Mutant { scene, file, ops })
}

/// A valid scene: its name (the stem of its files) and the folder they are in.
fn scenes() -> Vec<(&'static str, PathBuf)> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    vec![
        ("vase", root.join("scenes")),
        ("cornell", root.join("scenes")),
        ("furnace", root.join("scenes")),
        ("s", root.join("tests/corpus/base")),
    ]
}

fn lines(b: &[u8]) -> Vec<Vec<u8>> {
    b.split(|&c| c == b'\n').map(<[u8]>::to_vec).collect()
}

/// Byte ranges of the numbers in `b` (words between spaces, commas, brackets, '=' and '/').
fn numbers(b: &[u8]) -> Vec<(usize, usize)> {
    let sep = |c: u8| c.is_ascii_whitespace() || b",[]=/".contains(&c);
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        if sep(b[i]) {
            i += 1;
            continue;
        }
        let start = i;
        while i < b.len() && !sep(b[i]) {
            i += 1;
        }
        let word = std::str::from_utf8(&b[start..i]).unwrap_or("");
        if word.parse::<f64>().is_ok() {
            out.push((start, i));
        }
    }
    out
}

fn apply(op: &Op, b: &mut Vec<u8>) {
    let mut ls = lines(b);
    let n = ls.len();
    match op {
        Op::DeleteLine(i) => {
            ls.remove(i.index(n));
        }
        Op::DuplicateLine(i) => {
            let k = i.index(n);
            ls.insert(k, ls[k].clone());
        }
        Op::SwapLines(i, j) => ls.swap(i.index(n), j.index(n)),
        Op::InsertLine(i, l) => ls.insert(i.index(n + 1), l.as_bytes().to_vec()),
        Op::DropKey(i) => {
            let keyed: Vec<usize> = (0..n)
                .filter(|&k| {
                    let t = String::from_utf8_lossy(&ls[k]);
                    let t = t.trim();
                    !t.is_empty() && !t.starts_with('#')
                })
                .collect();
            if !keyed.is_empty() {
                ls.remove(keyed[i.index(keyed.len())]);
            }
        }
        Op::Number(i, to) => {
            let nums = numbers(b);
            if !nums.is_empty() {
                let (s, e) = nums[i.index(nums.len())];
                b.splice(s..e, to.bytes());
            }
            return;
        }
        Op::Truncate(i) => {
            if !b.is_empty() {
                b.truncate(i.index(b.len()));
            }
            return;
        }
        Op::FlipByte(i, mask) => {
            if !b.is_empty() {
                let k = i.index(b.len());
                b[k] ^= mask;
            }
            return;
        }
    }
    *b = ls.join(&b'\n');
}

/// How a mutant ended: rendered (true) or refused (false), or what is wrong.
fn check(m: &Mutant, scenes: &[(&str, PathBuf)], k: usize) -> Result<bool, String> {
    let (name, from) = &scenes[m.scene];
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    for ext in ["toml", "obj", "mtl"] {
        let f = format!("{name}.{ext}");
        std::fs::copy(from.join(&f), dir.join(&f)).unwrap();
    }
    let target = dir.join(format!("{name}.{}", ["toml", "obj", "mtl"][m.file]));
    let mut bytes = std::fs::read(&target).unwrap();
    for op in &m.ops {
        apply(op, &mut bytes);
    }
    std::fs::write(&target, &bytes).unwrap();
    let inputs = files_under(dir);
    let d = dir.display();
    let args: Vec<String> = [
        "render",
        &format!("{d}/{name}.toml"),
        "--spp",
        "1",
        "--res",
        "8x6",
        "--frames",
        "0",
        "--threads",
        "1",
        "--out",
        &format!("{d}/out/f_####.png"),
    ]
    .map(String::from)
    .to_vec();
    let o = run_reframe(&args, Duration::from_secs(20));
    let written: Vec<PathBuf> = files_under(dir)
        .into_iter()
        .filter(|p| !inputs.contains(p))
        .collect();
    let verdict = if o.code == Some(0) && !o.stderr.contains("panicked") {
        if written == [dir.join("out/f_0000.png")] {
            Ok(true)
        } else {
            Err(format!("exit 0, but wrote {written:?}"))
        }
    } else {
        match refusal(&o) {
            Ok(_) if !written.is_empty() => Err(format!("refused, but wrote {written:?}")),
            // Every file is named by its path.
            Ok(line) if !line.contains(&format!("{d}/")) => {
                Err(format!("the error names no file: {line}"))
            }
            Ok(line) => {
                if std::env::var_os("REFRAME_MUTANTS_SHOW").is_some() {
                    eprintln!("mutant {k}: {line}");
                }
                Ok(false)
            }
            Err(e) => Err(e),
        }
    };
    verdict.map_err(|e| {
        // Keep the mutant to reproduce it.
        let keep = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("mutants-failed/{k}"));
        let _ = std::fs::create_dir_all(&keep);
        for f in &inputs {
            let _ = std::fs::copy(f, keep.join(f.file_name().unwrap()));
        }
        format!(
            "mutant {k} ({name}, {m:?}), kept in {}: {e}",
            keep.display()
        )
    })
}

#[test]
fn mutated_scenes_render_or_fail_cleanly() {
    let count = std::env::var("REFRAME_MUTANTS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(MUTANTS);
    let scenes = scenes();
    let mut runner = TestRunner::new_with_rng(
        Config::default(),
        TestRng::from_seed(RngAlgorithm::ChaCha, &SEED),
    );
    let strategy = mutant(scenes.len());
    let mutants: Vec<Mutant> = (0..count)
        .map(|_| strategy.new_tree(&mut runner).unwrap().current())
        .collect();
    let start = std::time::Instant::now();
    let indexed: Vec<(usize, &Mutant)> = mutants.iter().enumerate().collect();
    let results = par_map(&indexed, |(k, m)| check(m, &scenes, *k));
    let mut split = [[0usize; 2]; 3];
    for (m, r) in mutants.iter().zip(&results) {
        if let Ok(rendered) = r {
            split[m.file][usize::from(*rendered)] += 1;
        }
    }
    let failures: Vec<&String> = results.iter().filter_map(|r| r.as_ref().err()).collect();
    let rendered: usize = split.iter().map(|s| s[1]).sum();
    let refused: usize = split.iter().map(|s| s[0]).sum();
    eprintln!(
        "mutants: {count} tried in {:.0} s: {rendered} rendered, {refused} refused with a one-line \
         error, {} failed (refused/rendered: TOML {}/{}, OBJ {}/{}, MTL {}/{})",
        start.elapsed().as_secs_f64(),
        failures.len(),
        split[0][0],
        split[0][1],
        split[1][0],
        split[1][1],
        split[2][0],
        split[2][1],
    );
    assert!(
        failures.is_empty(),
        "\n{}",
        failures
            .iter()
            .map(|f| f.as_str())
            .collect::<Vec<_>>()
            .join("\n")
    );
}
