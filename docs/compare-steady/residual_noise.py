"""Residual noise per landed sample, region by region, of mis-cv against mis-exact and the
independent tracer on `vase` frame 36 (the README's "Residual noise" table).

Renders (16 seeds each; frame 36 is in all 9 groups of frames 28-44 at n_f = 9):

    for s in $(seq 0 15); do
      reframe render vase --method mis-cv --window 9 --spp 1 --frames 28-44 --seed $s --aov \
          --exr-float --out rn/cv$s/f_####.exr
      reframe render vase --method mis-exact --window 9 --spp 1 --frames 28-44 --seed $s --aov \
          --exr-float --out rn/mx$s/f_####.exr
      reframe render vase --frames 36 --spp 1 --seed $s --exr-float --out rn/in$s/f_####.exr
    done
    reframe render vase --frames 36 --spp 256 --exr-float --out rn/ref_####.exr
    python3 docs/compare-steady/residual_noise.py rn     # Debian: python3-numpy python3-openimageio

Per pixel: the relative variance of the estimate over the seeds, var / (R^2 + 1e-4) with R the
256 spp reference's luminance, times the samples that landed in it (`spp_eff`, summed over its
groups; 1 for the independent tracer): what one landed sample is worth, as a relative variance
per sample. Regions are boxes of the 320x240 frame with the edge pixels (the 7% of highest
relative gradient of the reference) taken out, and the edge pixels themselves.
"""
import sys

import numpy as np

from frame36 import luminance, read, regions

root = sys.argv[1] if len(sys.argv) > 1 else "rn"
SEEDS = range(16)
ref = luminance(read(f"{root}/ref_0036.exr")[0])
regions = regions(ref)


def per_landed_sample(tag):
    lum, landed = [], []
    for s in SEEDS:
        a, names = read(f"{root}/{tag}{s}/f_0036.exr")
        lum.append(luminance(a))
        landed.append(a[..., names.index("spp_eff")] if "spp_eff" in names else np.ones(ref.shape))
    rel = np.array(lum).var(0, ddof=1) / (ref**2 + 1e-4)
    landed = np.array(landed).mean(0)
    return {k: (float((rel * landed)[m].mean()), float(rel[m].mean()), float(landed[m].mean()))
            for k, m in regions.items()}


ind, exact, cv = (per_landed_sample(t) for t in ("in", "mx", "cv"))
print("| region | independent, per sample | mis-exact, per landed sample | mis-cv, per landed sample "
      "| samples landed | mis-cv variance / mis-exact variance |")
print("| --- | --- | --- | --- | --- | --- |")
for k in regions:
    print(f"| {k} | {ind[k][0]:.3f} | {exact[k][0]:.3f} | {cv[k][0]:.3f} | {cv[k][2]:.1f} "
          f"| {cv[k][1] / exact[k][1]:.2f} |")
