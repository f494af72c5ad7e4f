//! The Slurm job-array path end to end: a one-node cluster (`tests/slurm/cluster.sh`: munged,
//! slurmctld and slurmd from Debian's packages, as root, config in a temporary folder) runs
//! `scripts/slurm/submit.sh` for N = 3 chunks and the merge job; the merged frames must equal a
//! one-process render bit for bit. Then a chunk is lost and resubmitted alone. Every daemon the
//! test started is stopped, whatever happens.
//!
//! Needs root and the packages `./setup.sh --tests` installs; `REFRAME_SKIP_SLURM=1` skips it
//! (loudly) on a machine without them.
mod common;

use common::{assert_identical, reframe, reframe_ok};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// The cluster, stopped on drop.
struct Cluster {
    dir: PathBuf,
    conf: String,
}

impl Cluster {
    fn start(dir: &Path) -> Cluster {
        let o = Command::new(format!("{ROOT}/tests/slurm/cluster.sh"))
            .arg("start")
            .arg(dir)
            .output()
            .unwrap();
        assert!(
            o.status.success(),
            "starting the cluster: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        Cluster {
            dir: dir.to_path_buf(),
            conf: String::from_utf8_lossy(&o.stdout).trim().to_string(),
        }
    }

    fn cmd(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        c.env("SLURM_CONF", &self.conf);
        c
    }

    /// A job's state from `scontrol` (COMPLETED, FAILED, PENDING, ...).
    fn job_states(&self, job: &str) -> Vec<String> {
        let o = self
            .cmd("scontrol")
            .args(["show", "job", "-o", job])
            .output()
            .unwrap();
        String::from_utf8_lossy(&o.stdout)
            .lines()
            .filter_map(|l| {
                l.split_whitespace()
                    .find_map(|f| f.strip_prefix("JobState=").map(str::to_string))
            })
            .collect()
    }

    /// Wait until every job (array tasks included) of `jobs` has ended; their final states.
    fn wait(&self, jobs: &[&str], timeout: Duration) -> Vec<String> {
        let start = Instant::now();
        loop {
            let states: Vec<String> = jobs.iter().flat_map(|j| self.job_states(j)).collect();
            let running = states
                .iter()
                .any(|s| ["PENDING", "RUNNING", "CONFIGURING", "COMPLETING"].contains(&s.as_str()));
            if !states.is_empty() && !running {
                return states;
            }
            assert!(
                start.elapsed() < timeout,
                "jobs {jobs:?} still not done after {timeout:?}: {states:?}"
            );
            std::thread::sleep(Duration::from_millis(200));
        }
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let _ = Command::new(format!("{ROOT}/tests/slurm/cluster.sh"))
            .arg("stop")
            .arg(&self.dir)
            .status();
    }
}

/// Submit 3 chunks of `render` and their merge with the binary `exe`; the two job ids.
fn submit(
    c: &Cluster,
    exe: &Path,
    logs: &Path,
    more: &[&str],
    render: &[String],
) -> (String, String) {
    let o = c
        .cmd(&format!("{ROOT}/scripts/slurm/submit.sh"))
        .args(["-n", "3", "--reframe"])
        .arg(exe)
        .arg("--logs")
        .arg(logs)
        .args(more)
        .arg("--")
        .args(render)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "submit.sh: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let ids = std::fs::read_to_string(logs.join("last-submission")).unwrap();
    let mut it = ids.split_whitespace().map(str::to_string);
    (it.next().unwrap(), it.next().unwrap())
}

#[test]
fn slurm_array_and_merge_match_one_process() {
    if std::env::var_os("REFRAME_SKIP_SLURM").is_some() {
        eprintln!("SKIPPED: REFRAME_SKIP_SLURM is set; the Slurm path is untested here");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let render: Vec<String> = [
        "vase",
        "--method",
        "mis-exact",
        "--window",
        "3",
        "--spp",
        "1",
        "--frames",
        "20-28",
        "--res",
        "40x30",
        "--exr-float",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let one = d.join("one");
    let mut one_args = vec!["render".to_string()];
    one_args.extend(render.iter().cloned());
    one_args.extend(["--out".into(), one.join("f_####.exr").display().to_string()]);
    reframe_ok(&one_args);

    let cluster = Cluster::start(&d.join("cluster"));
    let out = d.join("array");
    let logs = d.join("logs");
    let mut args = render.clone();
    args.extend(["--out".into(), out.join("f_####.exr").display().to_string()]);
    // The binary in a folder whose name has a comma and a space: sbatch's `--export` splits
    // its list at commas, and the path was passed in it (every task failed on half a path).
    let bin = d.join("reframe build, v2");
    std::fs::create_dir(&bin).unwrap();
    let exe = bin.join("reframe");
    std::fs::copy(env!("CARGO_BIN_EXE_reframe"), &exe).unwrap();
    let (chunks, merge) = submit(&cluster, &exe, &logs, &[], &args);
    let states = cluster.wait(&[&chunks, &merge], Duration::from_secs(180));
    let log = |name: &str| std::fs::read_to_string(logs.join(name)).unwrap_or_default();
    assert!(
        states.iter().all(|s| s == "COMPLETED"),
        "{states:?}\nmerge log: {}",
        log(&format!("merge-{merge}.log"))
    );
    assert_eq!(states.len(), 4, "3 array tasks and the merge: {states:?}");
    for k in 1..=3 {
        let l = log(&format!("chunk-{chunks}_{k}.log"));
        assert!(l.contains(&format!("chunk {k}/3")), "chunk {k} log: {l}");
    }
    assert_identical(&one, &out, (20..=28).map(|f| format!("f_{f:04}.exr")));

    // A lost chunk: the merge refuses, naming it; resubmitted alone, it merges again.
    let lost = out.join("f.chunk-2-of-3.partial");
    std::fs::remove_file(&lost).unwrap();
    for f in 20..=28 {
        std::fs::remove_file(out.join(format!("f_{f:04}.exr"))).unwrap();
    }
    let o = reframe(&["merge", "--chunks", "3", "--out"])
        .arg(out.join("f_####.exr"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("chunk 2/3 is missing"),
        "{err}"
    );
    assert!(!out.join("f_0020.exr").exists());
    let (chunks, merge) = submit(&cluster, &exe, &logs, &["--only", "2"], &args);
    let states = cluster.wait(&[&chunks, &merge], Duration::from_secs(180));
    assert_eq!(states, ["COMPLETED", "COMPLETED"], "resubmission");
    assert!(lost.exists());
    assert_identical(&one, &out, (20..=28).map(|f| format!("f_{f:04}.exr")));
    drop(cluster);
    // Every daemon is gone.
    for pid in ["munged", "slurmctld", "slurmd"] {
        assert!(
            !d.join(format!("cluster/run/{pid}.pid")).exists(),
            "{pid} not stopped"
        );
    }
}

/// The array task's script takes `--resume` among the render flags (a retry script passes it
/// always; the task appended its own and clap refused it as given twice: every task failed),
/// and `submit.sh` refuses `--checkpoint` (one folder for every chunk: chunks running side by
/// side refused each other's lock), before anything is submitted.
#[test]
fn the_scripts_take_resume_and_refuse_a_shared_checkpoint() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("f_####.exr").display().to_string();
    let o = Command::new("bash")
        .arg(format!("{ROOT}/scripts/slurm/chunk.sbatch"))
        .args([
            "vase", "--res", "16x12", "--spp", "1", "--frames", "0-3", "--out", &out,
        ])
        .arg("--resume")
        .env("REFRAME", env!("CARGO_BIN_EXE_reframe"))
        .env("SLURM_ARRAY_TASK_ID", "1")
        .env("REFRAME_CHUNKS", "2")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(dir.path().join("f.chunk-1-of-2.partial").is_file());
    // `--stats FILE`: each task's report its own file (one file kept only the last task's).
    let other = dir.path().join("g_####.exr").display().to_string();
    for (k, stats) in [("1", "--stats"), ("2", "--stats=")] {
        let report = dir.path().join("st.json").display().to_string();
        let flag: Vec<String> = if stats == "--stats" {
            vec![stats.into(), report]
        } else {
            vec![format!("{stats}{report}")]
        };
        let o = Command::new("bash")
            .arg(format!("{ROOT}/scripts/slurm/chunk.sbatch"))
            .args([
                "vase", "--res", "16x12", "--spp", "1", "--frames", "0-3", "--out", &other,
            ])
            .args(&flag)
            .env("REFRAME", env!("CARGO_BIN_EXE_reframe"))
            .env("SLURM_ARRAY_TASK_ID", k)
            .env("REFRAME_CHUNKS", "2")
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    for k in ["1", "2"] {
        let report = dir.path().join(format!("st.chunk-{k}-of-2.json"));
        let text = std::fs::read_to_string(&report).unwrap_or_default();
        assert!(
            text.contains(&format!("{k}/2")),
            "{}: {text}",
            report.display()
        );
    }
    assert!(!dir.path().join("st.json").exists());
    let o = Command::new("bash")
        .arg(format!("{ROOT}/scripts/slurm/submit.sh"))
        .args(["-n", "2", "--", "vase", "--out", &out, "--checkpoint", "ck"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("--checkpoint: each chunk keeps its own"),
        "{err}"
    );
}

/// Merging chunks rendered with `--aov` into frames that hold RGB only says that the reuse
/// channels were not written, as `render` says it (the merge dropped them in silence).
#[test]
fn a_merge_into_rgb_frames_says_it_drops_the_aov_channels() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("f_####.exr").display().to_string();
    for k in 1..=2 {
        reframe_ok(&[
            "render",
            "vase",
            "--method",
            "mis-cv",
            "--window",
            "3",
            "--aov",
            "--res",
            "16x12",
            "--spp",
            "1",
            "--frames",
            "0-5",
            "--out",
            &out,
            "--chunk",
            &format!("{k}/2"),
        ]);
    }
    let partials: Vec<String> = (1..=2)
        .map(|k| {
            dir.path()
                .join(format!("f.chunk-{k}-of-2.partial"))
                .display()
                .to_string()
        })
        .collect();
    let png = dir.path().join("p/g_####.png").display().to_string();
    let o = reframe_ok(&["merge", &partials[0], &partials[1], "--out", &png]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains(&format!(
            "warning: --aov: the chunks kept the reuse channels, but {png} holds RGB only"
        )),
        "{err}"
    );
}

/// Chunks told to write other frames (`v_####.exr` and `w_####.exr`) are of other renders: a
/// merge of them is refused, naming both (it wrote the first chunk's frames, exit 0). Chunks of
/// one name rendered in other folders (as on other machines) merge.
#[test]
fn chunks_of_other_outputs_are_not_merged() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let chunk = |out: &str, k: u32| {
        let out = d.join(out).display().to_string();
        let args = [
            "render", "cornell", "--res", "8x6", "--spp", "1", "--frames", "0-3",
        ];
        reframe_ok(&[&args[..], &["--out", &out, "--chunk", &format!("{k}/2")]].concat());
    };
    chunk("a/v_####.exr", 1);
    chunk("b/w_####.exr", 2);
    chunk("c/v_####.exr", 2);
    let p = |s: &str| d.join(s).display().to_string();
    let a1 = p("a/v.chunk-1-of-2.partial");
    let o = reframe(&["merge", &a1, &p("b/w.chunk-2-of-2.partial")])
        .output()
        .unwrap();
    common::assert_refused(&o, "are not chunks of the same render (--out");
    assert!(!d.join("a/v_0000.exr").exists());
    reframe_ok(&["merge", &a1, &p("c/v.chunk-2-of-2.partial")]);
    assert!(d.join("a/v_0003.exr").exists());
}

/// A merge has no scene to ask (without `--scene`, as every merge of undenoised chunks runs),
/// so the chunks record the scene's files: an `--out` that names one of them (the environment
/// image, a texture) is refused and the file left as it was, as `render` refuses it. The merge
/// wrote a frame over the scene's sky, exit 0.
#[test]
fn a_merge_never_writes_over_a_file_of_the_scene_the_chunks_rendered() {
    let d = tempfile::tempdir().unwrap();
    let (scene, env) = common::base_scene_with_sky(d.path());
    let before = std::fs::read(&env).unwrap();
    let at = |name: &str| d.path().join(name).to_str().unwrap().to_string();
    // The scene's frame 0 as chunk 1 of 1, to `--out` `out`.
    let chunk = |out: &str| {
        common::reframe(&[
            "render",
            &scene,
            "--spp",
            "1",
            "--frames",
            "0",
            "--chunk",
            "1/1",
            "--threads",
            "1",
            "--out",
            out,
        ])
        .output()
        .unwrap()
    };
    let o = chunk(&at("o/f_####.exr"));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let partial = at("o/f.chunk-1-of-1.partial");
    // From another folder, by a relative path through a link: the same file.
    std::os::unix::fs::symlink(d.path(), d.path().join("link")).unwrap();
    for out in [at("e_####.exr"), at("link/e_####.exr")] {
        let o = common::reframe(&["merge", &partial, "--out", &out])
            .current_dir("/")
            .output()
            .unwrap();
        common::assert_refused(&o, "that is an input of this command");
    }
    assert_eq!(
        std::fs::read(&env).unwrap(),
        before,
        "the sky was written over"
    );
    common::reframe_ok(&["merge", &partial]);
    assert!(d.path().join("o/f_0000.exr").exists());
    // A link to nothing in a partial's place: the merge says so (it said "no such partial
    // file; render its chunk"), and a chunk's render names the path as its partial file (it
    // named it as the user's --out, which was o/g_####.exr).
    let dangling = at("o/g.chunk-1-of-1.partial");
    std::os::unix::fs::symlink(at("nowhere"), &dangling).unwrap();
    let o = common::reframe(&["merge", &dangling]).output().unwrap();
    common::assert_refused(&o, "a symbolic link to nothing");
    common::assert_refused(&chunk(&at("o/g_####.exr")), "the chunk's partial file ");
}
