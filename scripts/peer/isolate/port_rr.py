#!/usr/bin/env python3
"""Mitsuba's samplers driving reframe's exact roulette and MIS (rfpath.py), llvm_ad_rgb, one
thread, error only. Configs: `builtin:SAMPLER:RR` (Mitsuba's C++ path) or
`port:SAMPLER:RR:RRMODE:MIS` (rfpath.py). Same scene / reference / relMSE as sampler_rr.py.

  DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM-19.so \
  .deps/peer-venv/bin/python scripts/peer/isolate/port_rr.py --configs ...
"""
import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from sampler_rr import PEER, mitsuba_scene, relmse, shapes_and_cam  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--max-depth", type=int, default=16)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--configs", required=True)
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    import drjit as dr
    import mitsuba as mi
    dr.set_thread_count(1)
    mi.set_variant("llvm_ad_rgb")
    import rfpath  # noqa: F401  registers 'rfpath'
    ref = np.load(PEER / f"reference_256_4096_{a.max_depth}.npy")
    if a.res == 128:
        ref = ref.reshape(128, 2, 128, 2, 3).mean(axis=(1, 3))
    shapes, cam = shapes_and_cam()
    print(f"Mitsuba {mi.__version__} llvm_ad_rgb; {a.res}x{a.res} {a.spp} spp, {a.max_depth} "
          f"bounces, seeds 0..{a.seeds - 1}; reference mean {ref.mean():.5f}", flush=True)
    rows = {}
    for cfg in a.configs.split(","):
        p = cfg.split(":")
        w0 = time.perf_counter()
        scene = mitsuba_scene(mi, shapes, cam, a.res, a.spp, a.max_depth, p[1], int(p[2]))
        if p[0] == "port":
            integ = mi.load_dict({"type": "rfpath", "max_depth": a.max_depth + 1,
                                  "rr_depth": int(p[2]), "rr_mode": p[3], "mis": p[4]})
        else:
            integ = scene.integrator()
        errs, means = [], []
        for seed in range(a.seeds):
            img = mi.render(scene, integrator=integ, spp=a.spp, seed=seed)
            img = np.array(img)[..., :3]
            errs.append(relmse(img, ref))
            means.append(float(img.mean()))
        rows[cfg] = {"relmse": errs, "mean": means}
        print(f"{cfg:32s} relMSE {np.mean(errs):.5f} [{min(errs):.5f}-{max(errs):.5f}] "
              f"image mean {np.mean(means):.5f} ({np.mean(means) / ref.mean() - 1:+.2%}) "
              f"wall {time.perf_counter() - w0:.0f} s", flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps({"res": a.res, "spp": a.spp,
                                            "ref_mean": float(ref.mean()), "rows": rows},
                                           indent=1))


if __name__ == "__main__":
    main()
