#!/usr/bin/env python3
"""Sampler vs Russian-roulette split of the reframe / Mitsuba relMSE gap on the peer scene.

Error only (no timing). Every render uses one CPU thread. The Mitsuba scene and relMSE are
scripts/peer/peer.py's (`mitsuba_scene` with its `rr_depth`, `relmse`), on the files its
`make_scene` wrote into out/peer (run scripts/peer/run.sh first). Reference: out/peer/reference_<res>_4096_16.npy (reframe
4096 spp, 16 bounces); at 128x128 it is the 2x2 box average of the 256x256 reference (with a box
pixel filter a 128 pixel is exactly the union of four 256 pixels).

  .deps/peer-venv/bin/python scripts/peer/isolate/sampler_rr.py [--res 256] [--seeds 4]
      [--configs reframe,independent:3,...]
"""
import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
PEER = ROOT / "out" / "peer"
# The scene, the MTL reader and relMSE are peer.py's.
sys.path.insert(0, str(ROOT / "scripts" / "peer"))
from peer import mitsuba_scene, parse_mtl, relmse  # noqa: E402


def shapes_and_cam():
    """The Mitsuba shapes peer.py's make_scene wrote into out/peer (not rewritten here)."""
    mtl = parse_mtl((ROOT / "scenes" / "cornell.mtl").read_text())
    mtl["glossy"] = {"Kd": [0.6, 0.6, 0.6], "Ke": [0.0, 0.0, 0.0]}  # as peer.py: all diffuse
    shapes = {}
    for name in mtl:
        path = PEER / f"mi_{name}.obj"
        if path.exists():
            shapes[name] = (path, mtl[name])
    cam = {"position": [0.0118, 1.0, 3.9], "look_at": [0.0, 1.0, 0.0], "up": [0.0, 1.0, 0.0],
           "fov": 40.0}
    return shapes, cam


def render_reframe(exe, toml, work, res, spp, max_depth, seed):
    out = work / f"rf_{res}_{spp}_{seed}_####.exr"
    cmd = [str(exe), "render", str(toml), "--res", f"{res}x{res}", "--spp", str(spp),
           "--max-depth", str(max_depth), "--threads", "1", "--seed", str(seed), "--exr-float",
           "--out", str(out)]
    o = subprocess.run(cmd, capture_output=True, text=True)
    if o.returncode != 0:
        sys.exit(f"reframe failed: {' '.join(cmd)}\n{o.stderr}")
    import drjit as dr
    import mitsuba as mi
    # Mitsuba's EXR reader hangs with a one-thread pool: read with two, then back to one.
    dr.set_thread_count(2)
    img = np.array(mi.Bitmap(str(work / f"rf_{res}_{spp}_{seed}_0000.exr")))[..., :3]
    dr.set_thread_count(1)
    return img


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--reframe", default=str(ROOT / "target" / "release" / "reframe"))
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--max-depth", type=int, default=16)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--variant", default="scalar_rgb")
    ap.add_argument("--configs", default="reframe,independent:3,stratified:3,multijitter:3,"
                    "ldsampler:3,ldsampler:5,independent:5")
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    import mitsuba as mi
    import drjit as dr
    dr.set_thread_count(1)
    mi.set_variant(a.variant)
    ref256 = np.load(PEER / f"reference_256_4096_{a.max_depth}.npy")
    if a.res == 256:
        ref = ref256
    elif a.res == 128:
        ref = ref256.reshape(128, 2, 128, 2, 3).mean(axis=(1, 3))
    else:
        sys.exit("res 256 or 128")
    shapes, cam = shapes_and_cam()
    toml = PEER / "peer.toml"
    print(f"Mitsuba {mi.__version__} {a.variant}; {a.res}x{a.res} {a.spp} spp, "
          f"{a.max_depth} bounces, seeds 0..{a.seeds - 1}; reference mean {ref.mean():.5f}",
          flush=True)
    rows = {}
    for cfg in a.configs.split(","):
        errs, means = [], []
        t0 = time.process_time()
        w0 = time.perf_counter()
        for seed in range(a.seeds):
            if cfg == "reframe":
                img = render_reframe(a.reframe, toml, PEER, a.res, a.spp, a.max_depth, seed)
            else:
                sampler, rr = cfg.split(":")
                scene = mitsuba_scene(mi, shapes, cam, a.res, a.spp, a.max_depth, sampler,
                                      int(rr))
                img = np.array(mi.render(scene, spp=a.spp, seed=seed))[..., :3]
            errs.append(relmse(img, ref))
            means.append(float(img.mean()))
        rows[cfg] = {"relmse": errs, "mean": means}
        print(f"{cfg:16s} relMSE {np.mean(errs):.5f} [{min(errs):.5f}-{max(errs):.5f}] "
              f"image mean {np.mean(means):.5f} ({np.mean(means) / ref.mean() - 1:+.2%}) "
              f"wall {time.perf_counter() - w0:.0f} s", flush=True)
    if "reframe" in rows:
        base = np.mean(rows["reframe"]["relmse"])
        print(f"\n| config | relMSE mean | min-max | / reframe | image mean (ref {ref.mean():.5f}) |")
        print("| --- | --- | --- | --- | --- |")
        for k, r in rows.items():
            e = r["relmse"]
            print(f"| {k} | {np.mean(e):.5f} | {min(e):.5f}-{max(e):.5f} | "
                  f"{np.mean(e) / base:.3f} | {np.mean(r['mean']):.5f} |")
    if a.json:
        Path(a.json).write_text(json.dumps({"res": a.res, "spp": a.spp, "ref_mean": float(ref.mean()),
                                            "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
