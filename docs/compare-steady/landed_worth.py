"""What a landed sample is worth against a native one, with the stratified sampler: the README's
"What a landed sample is worth" table (`vase` frame 36, n_f = 9, 1 native spp).

Renders (16 seeds each; frame 36 is in all 9 groups of frames 28-44 at n_f = 9):

    for s in $(seq 0 15); do
      for m in mis-cv mis-exact mis; do
        reframe render vase --method $m --window 9 --spp 1 --frames 28-44 --seed $s --aov \
            --exr-float --out lw/$m$s/f_####.exr
      done
      for n in 1 64 256; do
        reframe render vase --frames 36 --spp $n --seed $s --exr-float --out lw/in$n-$s/f_####.exr
      done
    done
    reframe render vase --frames 36 --spp 1024 --exr-float --out lw/ref_####.exr
    python3 docs/compare-steady/landed_worth.py lw   # Debian: python3-numpy python3-openimageio

Per pixel: the relative variance of the estimate over the seeds, var / (R^2 + 1e-4) with R the
1024 spp reference's luminance, times the samples behind it (`spp_eff` for the reuse methods,
the spp for the independent tracer): the relative variance of one sample. An independent
sample's falls as the stratified stream grows (its samples are spread evenly), a landed
sample's does not. `worth` is the independent tracer's at 64 spp (about the count that lands)
over the method's: how many stratified native samples one landed sample is worth. Regions as in
residual_noise.py.
"""
import sys

import numpy as np

from frame36 import luminance, read, regions

root = sys.argv[1] if len(sys.argv) > 1 else "lw"
SEEDS = range(16)
ref = luminance(read(f"{root}/ref_0036.exr")[0])
regions = regions(ref)


def per_sample(tag, spp=None):
    lum, count = [], []
    for s in SEEDS:
        a, names = read(f"{root}/{tag}{s}/f_0036.exr")
        lum.append(luminance(a))
        count.append(a[..., names.index("spp_eff")] if spp is None else np.full(ref.shape, spp))
    rel = np.array(lum).var(0, ddof=1) / (ref**2 + 1e-4)
    count = np.array(count, float).mean(0)
    return {k: (float((rel * count)[m].mean()), float(count[m].mean())) for k, m in regions.items()}


ind = {n: per_sample(f"in{n}-", n) for n in (1, 64, 256)}
reuse = {m: per_sample(m) for m in ("mis-cv", "mis", "mis-exact")}
print("| region | independent, 1 / 64 / 256 spp | `mis-cv` | `mis` (ratio, biased) | `mis-exact` "
      "| landed | worth: `mis-cv` / `mis` |")
print("| --- | --- | --- | --- | --- | --- | --- |")
for k in regions:
    i = [ind[n][k][0] for n in (1, 64, 256)]
    cv, mis, mx = (reuse[m][k][0] for m in ("mis-cv", "mis", "mis-exact"))
    print(f"| {k} | {i[0]:.3f} / {i[1]:.3f} / {i[2]:.3f} | {cv:.3f} | {mis:.3f} | {mx:.3f} "
          f"| {reuse['mis-cv'][k][1]:.1f} | {i[1] / cv:.2f} / {i[1] / mis:.2f} |")
