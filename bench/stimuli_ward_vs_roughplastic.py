"""Claim: our Python Ward BSDF renders the stimulus scene within 1.25x the time of Mitsuba's C++
``roughplastic`` (same scene, camera, probe, spp, variant, thread count).

Both scenes: the deepest experiment array under the indoor probe, the camera of the experiment.
Ward: rho_d 0.3, rho_s 0.09, alpha 0.026 (the default table at 90 %); roughplastic: Beckmann
alpha 0.026, diffuse 0.3 (a different but comparable material: we compare render cost only).
Each scene is loaded and rendered once to compile its kernel; then renders alternate between the
two, and the median time per render of each is printed with the ratio.

Usage: ``.venv/bin/python bench/stimuli_ward_vs_roughplastic.py [--size 256] [--spp 32] [--n 7]``
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")

from calibration import default_calibration
from stimuli import (
    StimulusRenderer,
    camera_geometry,
    draw_array,
    load_light_probe,
    setup_mitsuba,
    stimulus_seed,
)
from studydesign import load_design


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--n", type=int, default=7)
    args = ap.parse_args()
    variant = setup_mitsuba()
    design = load_design()
    cam = camera_geometry(design, default_calibration(design))
    level = design.depth.rendered_levels[-1]
    geometry = draw_array(design, design.depth.cm(level), stimulus_seed(level))
    probe = load_light_probe(design.illuminations[0].envmap)
    ward = StimulusRenderer(cam, size_px=args.size, spp=args.spp)
    rough = StimulusRenderer(cam, size_px=args.size, spp=args.spp, bsdf={
        "type": "roughplastic", "distribution": "beckmann", "alpha": 0.026,
        "diffuse_reflectance": {"type": "rgb", "value": 0.3}})
    for r in (ward, rough):
        r.load(geometry, probe)
    ward.render(0.3, 0.09, 0.026)
    rough.render(None, None, None)
    times = {"ward": [], "roughplastic": []}
    for i in range(args.n):
        t = time.perf_counter()
        ward.render(0.3, 0.09, 0.026, seed=i)
        times["ward"].append(time.perf_counter() - t)
        t = time.perf_counter()
        rough.render(None, None, None, seed=i)
        times["roughplastic"].append(time.perf_counter() - t)
    w, r = np.median(times["ward"]), np.median(times["roughplastic"])
    print(f"variant {variant}, {args.size}x{args.size} px, {args.spp} spp, {args.n} renders each")
    print(f"ward (Python plugin)      median {w:.3f} s/render")
    print(f"roughplastic (C++)        median {r:.3f} s/render")
    print(f"ratio ward / roughplastic {w / r:.3f}  (target <= 1.25)")


if __name__ == "__main__":
    main()
