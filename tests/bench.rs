//! `reframe bench`, `reframe reference` and `reframe compare` end to end, at small sizes.
use serde_json::Value;
use std::path::Path;
use std::process::Command;

fn reframe(args: &[&str]) -> std::process::Output {
    let o = Command::new(env!("CARGO_BIN_EXE_reframe"))
        .args(args)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "reframe {args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    o
}

fn json(p: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

#[test]
fn bench_writes_the_cost_model_figures() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bench.json");
    reframe(&[
        "bench",
        "cornell",
        "--res",
        "48x48",
        "--spp",
        "2",
        "--windows",
        "3,7",
        "--json",
        out.to_str().unwrap(),
    ]);
    let b = json(&out);
    for key in ["c_e", "c_l", "c_v_single", "c_v_packet", "ratio"] {
        let v = b[key].as_f64().unwrap_or_else(|| panic!("{key} missing"));
        assert!(v.is_finite() && v > 0.0, "{key} = {v}");
    }
    for n_f in ["3", "7"] {
        let p = b["predicted_speedup"][n_f].as_f64().unwrap();
        let m = b["measured_speedup"][n_f].as_f64().unwrap();
        // Eq. 16 lies between 1 and n_f for any positive costs.
        let n: f64 = n_f.parse().unwrap();
        assert!(p > 1.0 && p < n, "predicted {p} for n_f {n_f}");
        assert!(m.is_finite() && m > 0.0, "measured {m}");
    }
    assert!(b["predicted_speedup"].get("17").is_none());
}
