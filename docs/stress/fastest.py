#!/usr/bin/env python3
"""Merge repeated `reframe compare` runs of the stress scenes: keep each run's fastest time.

The errors of a run are the same in every repeat (every random number is a hash of the seed),
only the times differ, and on a shared machine a time can only be inflated by other processes,
so the fastest of the repeats is the best estimate of the run's cost. The fits are compare's
(src/compare.rs): `ln relmse = a + b ln t` per method and window; the equal-error speed-up is
independent's time over the method's at the geometric mean of the method's own errors; flicker
at equal time is read off each method's widest window at the geometric mean of the independent
times.

    fastest.py OUT.csv STATS_DIR RUN_DIR [RUN_DIR ...]

Each RUN_DIR holds one folder per scene with its compare.csv; STATS_DIR holds the
`reframe render --stats` files `stats_<scene>_w<n_f>.json` (the lost reuse fraction).
Writes OUT.csv and prints the README table.
"""
import csv
import json
import math
import os
import sys


def fit(points):
    p = [(math.log(x), math.log(y)) for x, y in points if x > 0 and y > 0]
    if len(p) == 1:
        return p[0][1] + p[0][0], -1.0
    n = len(p)
    mx = sum(q[0] for q in p) / n
    my = sum(q[1] for q in p) / n
    sxx = sum((q[0] - mx) ** 2 for q in p)
    sxy = sum((q[0] - mx) * (q[1] - my) for q in p)
    if sxx < 1e-12:
        return my + mx, -1.0
    b = sxy / sxx
    return my - b * mx, b


def time_for(f, e):
    return math.exp((math.log(e) - f[0]) / f[1]) if f[1] < -1e-3 else None


def main():
    out, stats_dir, run_dirs = sys.argv[1], sys.argv[2], sys.argv[3:]
    scenes = sorted(os.listdir(run_dirs[0]), key=lambda s: SCENES.index(s) if s in SCENES else 99)
    rows = []
    table = []
    for scene in scenes:
        runs = {}
        for d in run_dirs:
            with open(os.path.join(d, scene, "compare.csv")) as f:
                for r in csv.DictReader(f):
                    key = (r["method"], int(r["window"]), int(r["spp"]))
                    err = (r["rmse"], r["relmse"], r["flicker"])
                    if key in runs:
                        assert runs[key]["err"] == err, f"{scene} {key}: errors differ between repeats"
                        runs[key]["seconds"] = min(runs[key]["seconds"], float(r["seconds"]))
                    else:
                        runs[key] = {"err": err, "seconds": float(r["seconds"]),
                                     "eff": r["mean_effective_spp"]}
        lost = {}
        for n_f in (3, 7):
            with open(os.path.join(stats_dir, f"stats_{scene}_w{n_f}.json")) as f:
                lost[n_f] = json.load(f)["lost_reuse_fraction"]
        for (m, w, s), r in runs.items():
            rows.append([scene, m, w, s, f"{r['seconds']:.3f}", *r["err"], r["eff"],
                         f"{lost[w]:.4f}" if w in lost else ""])
        line = lambda m, w: [(r["seconds"], float(r["err"][1])) for (mm, ww, _), r in runs.items()
                             if (mm, ww) == (m, w)]
        fl_line = lambda m, w: [(r["seconds"], float(r["err"][2])) for (mm, ww, _), r in runs.items()
                                if (mm, ww) == (m, w)]
        fi = fit(line("independent", 1))
        ind_times = [t for t, _ in line("independent", 1)]
        t_eq = math.exp(sum(math.log(t) for t in ind_times) / len(ind_times))
        for m in ("independent", "havran", "mis", "mis-exact"):
            if m == "independent":
                speed = ["1", "1"]
                a, b = fit(fl_line(m, 1))
            else:
                speed = []
                for w in (3, 7):
                    pts = line(m, w)
                    e = math.exp(sum(math.log(y) for _, y in pts) / len(pts))
                    ti, tm = time_for(fi, e), time_for(fit(pts), e)
                    speed.append(f"{ti / tm:.2f}" if ti and tm else "-")
                a, b = fit(fl_line(m, 7))
            flick = math.exp(a + b * math.log(t_eq))
            lost_s = "-" if m == "independent" else f"{lost[3]:.2f} / {lost[7]:.2f}"
            table.append(f"| `{scene}` | `{m}` | {speed[0]} / {speed[1]} | {flick:.3f} ({t_eq:.1f} s) | {lost_s} |")
    with open(out, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["scene", "method", "window", "spp", "seconds", "rmse", "relmse", "flicker",
                    "mean_effective_spp", "lost_reuse_fraction"])
        w.writerows(rows)
    print("| scene | method | equal-error speed-up, n_f = 3 / 7 | flicker at equal time | lost reuse, n_f = 3 / 7 |")
    print("| --- | --- | --- | --- | --- |")
    print("\n".join(table))


SCENES = ["occluders", "fast-pan", "cut", "mirror-like", "vase-border"]

if __name__ == "__main__":
    main()
