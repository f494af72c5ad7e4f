//! Property: a damaged state file is never accepted. Real partial files (chunks of a `mis-cv`
//! render with `--aov`, so that every array of a record is there, and of an independent render,
//! whose records are finished pixels) and a real checkpoint (a render killed mid-way) are
//! damaged at random (a flipped byte, a truncation, a length field or an offset overwritten, bytes
//! inserted) from a fixed seed; `reframe merge` and `reframe render --resume` must refuse each
//! with one line, no panic and no hang, and `merge` must write no frame. The undamaged files
//! merge and resume (so the refusals are the damage's).
mod common;

use common::{par_map, reframe_ok, refusal, run_reframe};
use proptest::prelude::*;
use proptest::strategy::ValueTree;
use proptest::test_runner::{Config, RngAlgorithm, TestRng, TestRunner};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

const SEED: [u8; 32] = *b"reframe: damaged state refused.!";
/// Damaged partial files tried, and damaged checkpoints (a resume loads the scene: slower).
const PARTIAL_CASES: usize = 80;
const CHECKPOINT_CASES: usize = 24;

#[derive(Clone, Debug)]
enum Damage {
    Flip {
        at: f64,
        mask: u8,
    },
    Truncate {
        at: f64,
    },
    /// Overwrite 8 bytes (a length, an offset, a count) with a value.
    Word {
        at: f64,
        value: u64,
    },
    Insert {
        at: f64,
        bytes: Vec<u8>,
    },
}

fn damage() -> impl Strategy<Value = Damage> {
    let at = 0.0..1.0f64;
    prop_oneof![
        (at.clone(), 1u8..=255).prop_map(|(at, mask)| Damage::Flip { at, mask }),
        at.clone().prop_map(|at| Damage::Truncate { at }),
        (
            at.clone(),
            prop_oneof![Just(0u64), Just(u64::MAX), Just(1 << 40), 0u64..4096]
        )
            .prop_map(|(at, value)| Damage::Word { at, value }),
        (at, proptest::collection::vec(any::<u8>(), 1..16))
            .prop_map(|(at, bytes)| Damage::Insert { at, bytes }),
    ]
}

fn apply(d: &Damage, b: &mut Vec<u8>) {
    let pos = |at: f64, n: usize| ((at * n as f64) as usize).min(n.saturating_sub(1));
    match d {
        Damage::Flip { at, mask } => {
            let i = pos(*at, b.len());
            b[i] ^= mask;
        }
        Damage::Truncate { at } => b.truncate(pos(*at, b.len())),
        Damage::Word { at, value } => {
            let i = pos(*at, b.len().saturating_sub(8));
            let old = &b[i..i + 8];
            let new = value.to_le_bytes();
            // A word that already holds the value damages nothing: change one more bit.
            let new = if old == new {
                (value ^ 1).to_le_bytes()
            } else {
                new
            };
            b[i..i + 8].copy_from_slice(&new);
        }
        Damage::Insert { at, bytes } => {
            let i = pos(*at, b.len());
            b.splice(i..i, bytes.iter().copied());
        }
    }
}

fn cases(n: usize) -> Vec<Damage> {
    let mut runner = TestRunner::new_with_rng(
        Config::default(),
        TestRng::from_seed(RngAlgorithm::ChaCha, &SEED),
    );
    (0..n)
        .map(|_| damage().new_tree(&mut runner).unwrap().current())
        .collect()
}

/// Where a state file's trailer starts (its JSON, the JSON's CRC-32, its length and the magic
/// end the file).
fn trailer_start(b: &[u8]) -> usize {
    let n = b.len();
    n - 20 - u64::from_le_bytes(b[n - 16..n - 8].try_into().unwrap()) as usize
}

/// `reframe merge` of the partial files `first` and `second` into `case/o/f_####.exr`.
fn merge_two(case: &Path, first: &Path, second: &Path) -> common::Outcome {
    let out = case.join("o").join("f_####.exr").display().to_string();
    run_reframe(
        &strings(&[
            "merge",
            "--out",
            &out,
            &first.display().to_string(),
            &second.display().to_string(),
        ]),
        Duration::from_secs(20),
    )
}

fn strings(v: &[&str]) -> Vec<String> {
    v.iter().map(|s| s.to_string()).collect()
}

/// Frame files in `d`.
fn frames_in(d: &Path) -> Vec<PathBuf> {
    std::fs::read_dir(d)
        .map(|e| {
            e.flatten()
                .map(|e| e.path())
                .filter(|p| p.extension().is_some_and(|x| x == "exr"))
                .collect()
        })
        .unwrap_or_default()
}

#[test]
fn damaged_partials_are_never_merged() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let renders: [(&str, &[&str]); 2] = [
        ("cv", &["--method", "mis-cv", "--window", "3", "--aov"]),
        ("ind", &["--method", "independent"]),
    ];
    let mut sets = Vec::new();
    for (name, extra) in renders {
        let out = d.join(name).join("f_####.exr").display().to_string();
        for k in 1..=2 {
            let mut a = strings(&[
                "render", "vase", "--frames", "10-15", "--res", "24x18", "--spp", "1", "--out",
                &out,
            ]);
            a.extend(strings(extra));
            a.extend(strings(&["--chunk", &format!("{k}/2")]));
            reframe_ok(&a);
        }
        let partials: Vec<PathBuf> = (1..=2)
            .map(|k| d.join(name).join(format!("f.chunk-{k}-of-2.partial")))
            .collect();
        // Undamaged, they merge.
        let check = d.join(format!("{name}-check"));
        let out = check.join("f_####.exr").display().to_string();
        let mut a = strings(&["merge", "--out", &out]);
        a.extend(partials.iter().map(|p| p.display().to_string()));
        reframe_ok(&a);
        assert_eq!(frames_in(&check).len(), 6);
        sets.push(partials);
    }
    let all: Vec<(usize, Damage)> = cases(PARTIAL_CASES).into_iter().enumerate().collect();
    let outcomes = par_map(&all, |(i, dmg)| {
        let i = *i;
        let partials = &sets[i % sets.len()];
        let k = (i / sets.len()) % 2;
        let case = d.join(format!("case{i}"));
        std::fs::create_dir_all(&case).unwrap();
        let mut files = Vec::new();
        for (j, p) in partials.iter().enumerate() {
            let mut b = std::fs::read(p).unwrap();
            if j == k {
                apply(dmg, &mut b);
            }
            let q = case.join(p.file_name().unwrap());
            std::fs::write(&q, &b).unwrap();
            files.push(q.display().to_string());
        }
        let out = case.join("f_####.exr").display().to_string();
        let mut a = strings(&["merge", "--out", &out]);
        a.extend(files);
        let o = run_reframe(&a, Duration::from_secs(20));
        let verdict = refusal(&o).map_err(|e| format!("case {i} {dmg:?}: {e}"));
        if verdict.is_ok() && !frames_in(&case).is_empty() {
            return Err(format!("case {i} {dmg:?}: frames written"));
        }
        verdict
    });
    for o in outcomes {
        o.unwrap();
    }
}

#[test]
fn damaged_checkpoints_are_never_resumed() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("k/f_####.exr").display().to_string();
    let args = strings(&[
        "render",
        "vase",
        "--method",
        "mis-cv",
        "--window",
        "5",
        "--spp",
        "1",
        "--frames",
        "10-40",
        "--res",
        "64x48",
        "--aov",
        "--checkpoint-every",
        "0",
        "--out",
        &out,
    ]);
    // A checkpoint with frames in flight: kill the render once one is there.
    let state = d.join("k/f.checkpoint/state");
    let mut child = common::reframe(&args).spawn().unwrap();
    let start = Instant::now();
    while !(state.exists() && d.join("k/f_0012.exr").exists()) {
        assert!(child.try_wait().unwrap().is_none(), "finished too soon");
        assert!(start.elapsed() < Duration::from_secs(60));
        std::thread::sleep(Duration::from_millis(5));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    let good = std::fs::read(&state).unwrap();
    // Each case resumes from its own copy of the output folder.
    let all: Vec<(usize, Damage)> = cases(CHECKPOINT_CASES).into_iter().enumerate().collect();
    let outcomes = par_map(&all, |(i, dmg)| {
        let case = d.join(format!("case{i}"));
        std::fs::create_dir_all(case.join("f.checkpoint")).unwrap();
        let mut b = good.clone();
        apply(dmg, &mut b);
        std::fs::write(case.join("f.checkpoint/state"), &b).unwrap();
        let out = case.join("f_####.exr").display().to_string();
        let mut a = args.clone();
        let n = a.len();
        a[n - 1] = out;
        a.push("--resume".into());
        let o = run_reframe(&a, Duration::from_secs(30));
        refusal(&o).map_err(|e| format!("case {i} {dmg:?}: {e}"))
    });
    for o in outcomes {
        o.unwrap();
    }
    // A frame in flight given another frame's camera (a camera's matrices, so plausible), its
    // record's checksum recomputed and listed in the trailer (whose checksum is recomputed
    // too): its file would have carried that camera. Refused as not the scene's.
    {
        let mut b = good.clone();
        let (n, trailer) = (b.len(), trailer_start(&b));
        let starts: Vec<usize> = (0..trailer - 4)
            .filter(|&p| &b[p..p + 4] == b"RFAC")
            .collect();
        assert!(starts.len() >= 2, "frames in flight: {}", starts.len());
        let (s0, e0) = (starts[0], starts[1]);
        let other = b[starts[1] + 64..starts[1] + 64 + 128].to_vec();
        b[s0 + 64..s0 + 64 + 128].copy_from_slice(&other);
        let crc = crc32fast::hash(&b[s0..e0 - 4]);
        b[e0 - 4..e0].copy_from_slice(&crc.to_le_bytes());
        let mut t: serde_json::Value = serde_json::from_slice(&b[trailer..n - 20]).unwrap();
        let k = t["records"]
            .as_array()
            .unwrap()
            .iter()
            .position(|r| r[1] == s0 as u64)
            .unwrap();
        t["record_crcs"][k] = crc.into();
        let json = serde_json::to_vec(&t).unwrap();
        b.truncate(trailer);
        b.extend_from_slice(&json);
        b.extend_from_slice(&crc32fast::hash(&json).to_le_bytes());
        b.extend_from_slice(&(json.len() as u64).to_le_bytes());
        b.extend_from_slice(b"RFSTATE1");
        // (In place: a resume checks the frames it finished against its --out.)
        std::fs::write(&state, &b).unwrap();
        let mut a = args.clone();
        a.push("--resume".into());
        let o = run_reframe(&a, Duration::from_secs(30));
        let why = refusal(&o).unwrap();
        assert!(why.contains("camera is not the scene's"), "{why}");
    }
    // Undamaged, it resumes.
    std::fs::write(&state, &good).unwrap();
    let mut a = args.clone();
    a.push("--resume".into());
    reframe_ok(&a);
    assert!(!state.exists());
}

/// A record's header changed and its checksum recomputed (a forgery, or damage by a tool that
/// rewrites checksums) is refused where it contradicts the render: a sums record's unit (what
/// one step of its sums is worth) set to 100 or NaN, its frame number changed, its groups moved
/// from one fold to the other, its seconds NaN or negative, a camera matrix NaN. The merge took
/// them as written: a frame 100 times too bright, all NaN, or other pixels, and NaN metadata,
/// exit 0.
#[test]
fn partials_with_forged_record_headers_are_never_merged() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("r").join("f_####.exr").display().to_string();
    for k in 1..=2 {
        reframe_ok(&strings(&[
            "render",
            "vase",
            "--frames",
            "10-15",
            "--res",
            "24x18",
            "--spp",
            "1",
            "--method",
            "mis-cv",
            "--window",
            "3",
            "--out",
            &out,
            "--chunk",
            &format!("{k}/2"),
        ]));
    }
    let partials: Vec<PathBuf> = (1..=2)
        .map(|k| d.join("r").join(format!("f.chunk-{k}-of-2.partial")))
        .collect();
    // (byte offset in the record, new bytes): the unit, the frame number, the count of groups
    // of odd first frames (the control variate's second fold), the seconds, a camera matrix
    // (NaN; an element of world-to-NDC 3e38, which was written into the frame's metadata),
    // the reuse counters (more lost than tried: a loss of 10^16 percent in `--stats`).
    let forgeries: [(usize, Vec<u8>); 9] = [
        (24, 100f32.to_le_bytes().to_vec()),
        (24, f32::NAN.to_le_bytes().to_vec()),
        (4, 13u32.to_le_bytes().to_vec()),
        (28, 1u32.to_le_bytes().to_vec()),
        (56, f64::NAN.to_le_bytes().to_vec()),
        (56, (-5f64).to_le_bytes().to_vec()),
        (64, f32::NAN.to_le_bytes().to_vec()),
        (64 + 4 * 26, 3e38f32.to_le_bytes().to_vec()),
        (48, u64::MAX.to_le_bytes().to_vec()),
    ];
    for (i, (at, bytes)) in forgeries.iter().enumerate() {
        let case = d.join(format!("forged{i}"));
        std::fs::create_dir_all(&case).unwrap();
        let mut b = std::fs::read(&partials[0]).unwrap();
        // The trailer's start (its JSON, CRC, length and magic end the file), and the records
        // before it, each beginning with "RFAC" and ending in the CRC-32 of its bytes.
        let trailer = trailer_start(&b);
        let starts: Vec<usize> = (0..trailer - 4)
            .filter(|&p| &b[p..p + 4] == b"RFAC")
            .collect();
        let (start, end) = (starts[0], *starts.get(1).unwrap_or(&trailer));
        assert_eq!(
            crc32fast::hash(&b[start..end - 4]).to_le_bytes(),
            b[end - 4..end],
            "the first record's span"
        );
        b[start + at..start + at + bytes.len()].copy_from_slice(bytes);
        let crc = crc32fast::hash(&b[start..end - 4]);
        b[end - 4..end].copy_from_slice(&crc.to_le_bytes());
        let forged = case.join("f.chunk-1-of-2.partial");
        std::fs::write(&forged, &b).unwrap();
        let o = merge_two(&case, &forged, &partials[1]);
        let why = refusal(&o).unwrap_or_else(|e| panic!("forgery {i}: {e}"));
        // Named, or (a count only the merged frame can be checked by) said to be damaged.
        assert!(
            why.contains("f.chunk-1-of-2.partial") || why.contains("a file is damaged"),
            "forgery {i}: {why}"
        );
        assert!(
            frames_in(&case.join("o")).is_empty(),
            "forgery {i}: frames written"
        );
    }
    // Both partials of another build (their trailers' build hash rewritten, CRC and all): a
    // merge needs the build that rendered them, as a resume does. They merged without a word.
    let case = d.join("other-build");
    std::fs::create_dir_all(&case).unwrap();
    let mut forged = Vec::new();
    for p in &partials {
        let mut b = std::fs::read(p).unwrap();
        let (start, end) = (trailer_start(&b), b.len() - 20);
        let text = String::from_utf8(b[start..end].to_vec()).unwrap();
        let at = text.find("\"build_hash\":\"").unwrap() + "\"build_hash\":\"".len();
        let len = text[at..].find('"').unwrap();
        b[start + at..start + at + len].fill(b'0');
        let crc = crc32fast::hash(&b[start..end]);
        b[end..end + 4].copy_from_slice(&crc.to_le_bytes());
        let to = case.join(p.file_name().unwrap());
        std::fs::write(&to, &b).unwrap();
        forged.push(to.display().to_string());
    }
    let out = case.join("o").join("f_####.exr").display().to_string();
    let mut args = strings(&["merge", "--out", &out]);
    args.extend(forged);
    let o = run_reframe(&args, Duration::from_secs(20));
    let why = refusal(&o).unwrap();
    assert!(why.contains("another build of reframe"), "{why}");
    assert!(frames_in(&case.join("o")).is_empty(), "frames written");
    // Chunk 1's records of another seed (the same frames, sizes and layout, each whole, its
    // checksum right) under chunk 1's own trailer: merged as this run's (a fifth of the
    // pixels other, exit 0). The trailer lists its records' checksums.
    let other = d.join("seed1").join("f_####.exr").display().to_string();
    reframe_ok(&strings(&[
        "render", "vase", "--frames", "10-15", "--res", "24x18", "--spp", "1", "--method",
        "mis-cv", "--window", "3", "--out", &other, "--chunk", "1/2", "--seed", "1",
    ]));
    let ours = std::fs::read(&partials[0]).unwrap();
    let theirs = std::fs::read(d.join("seed1").join("f.chunk-1-of-2.partial")).unwrap();
    let (a, b) = (trailer_start(&ours), trailer_start(&theirs));
    assert_eq!(a, b, "records of the same sizes");
    let mut spliced = theirs[..b].to_vec();
    spliced.extend_from_slice(&ours[a..]);
    let case = d.join("spliced");
    std::fs::create_dir_all(&case).unwrap();
    let to = case.join("f.chunk-1-of-2.partial");
    std::fs::write(&to, &spliced).unwrap();
    let o = merge_two(&case, &to, &partials[1]);
    let why = refusal(&o).unwrap();
    assert!(why.contains("not the one the trailer lists"), "{why}");
    assert!(frames_in(&case.join("o")).is_empty(), "frames written");
}
