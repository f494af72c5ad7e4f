#!/usr/bin/env python3
"""reframe's independent tracer against Mitsuba 3's path tracer on one all-diffuse scene.

Run by scripts/peer/run.sh, which makes the Python environment (Mitsuba is not a dependency of
reframe). The scene is shipped `cornell` with its glossy block made diffuse, one frame, 256x256:
written here as a reframe scene (the shipped OBJ with another MTL) and as a Mitsuba scene (the
OBJ split per material, since Mitsuba's OBJ loader takes one material per shape). Both render at
equal resolution, samples per pixel and path length (reframe's --max-depth N bounces is
Mitsuba's max_depth N + 1, which counts the camera vertex), with a box pixel filter. Runs are
interleaved (reframe, scalar_rgb, llvm_ad_rgb, reframe, ...) so that load hits all alike. Each
renderer's own render time is taken (reframe's --stats `seconds`; Mitsuba's render call until its
image is evaluated), after one untimed warm-up render per Mitsuba variant (llvm_ad_rgb compiles
its kernel then). relMSE is against one reference, reframe at --ref-spp, and Mitsuba's converged
image is checked against it too. Efficiency is 1 / (relMSE x seconds).
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
EPS = 0.01  # relMSE's denominator offset, as `reframe compare` uses


def make_scene(work: Path, res: int):
    """The peer scene in both formats; returns (reframe toml, Mitsuba shapes, camera)."""
    src = (ROOT / "scenes" / "cornell.obj").read_text().splitlines()
    mtl = parse_mtl((ROOT / "scenes" / "cornell.mtl").read_text())
    # All diffuse: the glossy block gets a white Lambertian.
    mtl["glossy"] = {"Kd": [0.6, 0.6, 0.6], "Ke": [0.0, 0.0, 0.0]}
    with open(work / "peer.mtl", "w") as f:
        for name, m in mtl.items():
            f.write(f"newmtl {name}\nKd {' '.join(map(str, m['Kd']))}\nKs 0 0 0\nNs 1\n"
                    f"Ke {' '.join(map(str, m['Ke']))}\n\n")
    lines = ["mtllib peer.mtl" if l.startswith("mtllib") else l for l in src]
    (work / "peer.obj").write_text("\n".join(lines) + "\n")
    # The frame-12 camera of cornell (its orbit's middle), held still.
    cam = {"position": [0.0118, 1.0, 3.9], "look_at": [0.0, 1.0, 0.0], "up": [0.0, 1.0, 0.0],
           "fov": 40.0}
    (work / "peer.toml").write_text(
        'obj = "peer.obj"\nframes = 1\n'
        f"resolution = [{res}, {res}]\n\n[[keyframe]]\nframe = 0\n"
        f"position = {cam['position']}\nlook_at = {cam['look_at']}\nup = {cam['up']}\n"
        f"fov = {cam['fov']}\n")
    # Per material: its faces, with their own vertex list (OBJ indices are global, 1-based).
    verts, by_mtl, cur = [], {}, None
    for l in src:
        p = l.split()
        if not p:
            continue
        if p[0] == "v":
            verts.append(p[1:4])
        elif p[0] == "usemtl":
            cur = p[1]
        elif p[0] == "f":
            by_mtl.setdefault(cur, []).append([int(t.split("/")[0]) for t in p[1:]])
    shapes = {}
    for name, faces in by_mtl.items():
        used = sorted({i for f in faces for i in f})
        remap = {i: k + 1 for k, i in enumerate(used)}
        body = [f"v {' '.join(verts[i - 1])}" for i in used]
        body += ["f " + " ".join(str(remap[i]) for i in f) for f in faces]
        path = work / f"mi_{name}.obj"
        path.write_text("\n".join(body) + "\n")
        shapes[name] = (path, mtl[name])
    return work / "peer.toml", shapes, cam


def parse_mtl(text):
    out, cur = {}, None
    for l in text.splitlines():
        p = l.split()
        if not p or p[0].startswith("#"):
            continue
        if p[0] == "newmtl":
            cur = p[1]
            out[cur] = {"Kd": [0.0] * 3, "Ke": [0.0] * 3}
        elif p[0] in ("Kd", "Ke"):
            out[cur][p[0]] = [float(x) for x in p[1:4]]
    return out


def mitsuba_scene(mi, shapes, cam, res, spp, max_depth, sampler, rr_depth=None):
    """The peer scene for Mitsuba; `rr_depth` sets its path integrator's roulette start
    (Mitsuba's default, 5, when None)."""
    integrator = {"type": "path", "max_depth": max_depth + 1}
    if rr_depth is not None:
        integrator["rr_depth"] = rr_depth
    scene = {
        "type": "scene",
        "integrator": integrator,
        "sensor": {
            "type": "perspective",
            "fov": cam["fov"],
            "fov_axis": "y",
            "to_world": mi.ScalarTransform4f().look_at(
                origin=cam["position"], target=cam["look_at"], up=cam["up"]),
            "film": {"type": "hdrfilm", "width": res, "height": res, "pixel_format": "rgb",
                     "rfilter": {"type": "box"}},
            "sampler": {"type": sampler, "sample_count": spp},
        },
    }
    for name, (path, m) in shapes.items():
        s = {"type": "obj", "filename": str(path), "face_normals": True,
             "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": m["Kd"]}}}
        if any(m["Ke"]):
            s["emitter"] = {"type": "area", "radiance": {"type": "rgb", "value": m["Ke"]}}
        scene[f"shape_{name}"] = s
    return mi.load_dict(scene)


def render_mitsuba(variant, shapes, cam, res, spp, max_depth, seed, warm, sampler):
    """One render with a Mitsuba variant: (seconds, image). The scene is loaded before the clock
    starts; a variant's first use renders once untimed (`warm`: the variants already used)."""
    import mitsuba as mi
    import drjit as dr
    mi.set_variant(variant)
    scene = mitsuba_scene(mi, shapes, cam, res, spp, max_depth, sampler)
    if variant not in warm:
        img = mi.render(scene, spp=spp, seed=seed + 100000)
        dr.eval(img)
        dr.sync_thread()
        warm.add(variant)
    t = time.perf_counter()
    img = mi.render(scene, spp=spp, seed=seed)
    dr.eval(img)
    dr.sync_thread()
    return time.perf_counter() - t, np.array(img)[..., :3]


def render_reframe(exe, toml, work, spp, max_depth, threads, seed):
    out = work / f"rf_{spp}_{seed}_####.exr"
    stats = work / f"rf_{spp}_{seed}.json"
    cmd = [str(exe), "render", str(toml), "--spp", str(spp), "--max-depth", str(max_depth),
           "--threads", str(threads), "--seed", str(seed), "--exr-float", "--out", str(out),
           "--stats", str(stats)]
    o = subprocess.run(cmd, capture_output=True, text=True)
    if o.returncode != 0:
        sys.exit(f"reframe failed: {' '.join(cmd)}\n{o.stderr}")
    import drjit as dr
    import mitsuba as mi
    # Mitsuba's EXR reader hangs with a one-thread pool: read with two, then restore.
    threads = dr.thread_count()
    dr.set_thread_count(max(threads, 2))
    img = np.array(mi.Bitmap(str(work / f"rf_{spp}_{seed}_0000.exr")))[..., :3]
    dr.set_thread_count(threads)
    return json.loads(stats.read_text())["seconds"], img


def relmse(img, ref):
    return float(np.mean((img - ref) ** 2 / (ref ** 2 + EPS)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reframe", default=str(ROOT / "target" / "release" / "reframe"))
    ap.add_argument("--work", default=str(ROOT / "out" / "peer"))
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--ref-spp", type=int, default=4096)
    ap.add_argument("--max-depth", type=int, default=16, help="reframe's bounces")
    ap.add_argument("--threads", type=int, default=os.cpu_count())
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--variants", default="scalar_rgb,llvm_ad_rgb")
    ap.add_argument("--mi-sampler", default="independent",
                    help="Mitsuba's sampler: independent (its default), stratified, multijitter, "
                         "ldsampler, ...")
    a = ap.parse_args()
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    toml, shapes, cam = make_scene(work, a.res)
    import mitsuba as mi
    import drjit as dr
    print(f"Mitsuba {mi.__version__}, Dr.Jit {dr.__version__}; reframe {a.reframe}; "
          f"{a.res}x{a.res}, {a.spp} spp, {a.max_depth} bounces, {a.threads} threads, "
          f"Mitsuba's sampler {a.mi_sampler}", flush=True)
    # Mitsuba's render threads (both variants) are Dr.Jit's pool: as many as reframe's.
    dr.set_thread_count(a.threads)
    ref_path = work / f"reference_{a.res}_{a.ref_spp}_{a.max_depth}.npy"
    if ref_path.exists():
        ref = np.load(ref_path)
    else:
        t, ref = render_reframe(a.reframe, toml, work, a.ref_spp, a.max_depth, a.threads, 999)
        np.save(ref_path, ref)
        print(f"reference: reframe {a.ref_spp} spp in {t:.1f} s", flush=True)
    variants = [v for v in a.variants.split(",") if v]
    runs = {k: [] for k in ["reframe"] + variants}
    warm = set()
    for rep in range(a.repeats):
        t, img = render_reframe(a.reframe, toml, work, a.spp, a.max_depth, a.threads, rep)
        runs["reframe"].append((t, relmse(img, ref), float(img.mean())))
        for v in variants:
            t, img = render_mitsuba(v, shapes, cam, a.res, a.spp, a.max_depth, rep, warm,
                                    a.mi_sampler)
            runs[v].append((t, relmse(img, ref), float(img.mean())))
        print(f"repeat {rep + 1}: " + ", ".join(
            f"{k} {r[-1][0]:.2f} s relMSE {r[-1][1]:.5f}" for k, r in runs.items()), flush=True)
    n = a.res * a.res * a.spp
    rows = {}
    for k, r in runs.items():
        t = statistics.median(x[0] for x in r)
        e = statistics.mean(x[1] for x in r)
        rows[k] = {"seconds": t, "seconds_all": [x[0] for x in r],
                   "samples_per_second": n / t, "relmse": e, "efficiency": 1 / (e * t),
                   "mean": float(statistics.mean(x[2] for x in r))}
    base = rows["reframe"]["efficiency"]
    print(f"\n| renderer | seconds (median of {a.repeats}) | samples/s | relMSE | efficiency "
          "1/(relMSE s) | reframe's efficiency / its |")
    print("| --- | --- | --- | --- | --- | --- |")
    for k, r in rows.items():
        print(f"| {k} | {r['seconds']:.2f} | {r['samples_per_second'] / 1e6:.2f} M | "
              f"{r['relmse']:.5f} | {r['efficiency']:.1f} | {base / r['efficiency']:.2f} |")
    means = {k: r["mean"] for k, r in rows.items()}
    print(f"image means: {means} (reference {ref.mean():.5f})")
    (work / "peer.json").write_text(json.dumps(
        {"res": a.res, "spp": a.spp, "max_depth": a.max_depth, "threads": a.threads,
         "reference_spp": a.ref_spp, "mitsuba": mi.__version__, "mitsuba_sampler": a.mi_sampler,
         "runs": rows}, indent=1))


if __name__ == "__main__":
    main()
