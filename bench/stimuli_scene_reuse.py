"""Claim: building the scene once per (array, probe) and updating the Ward parameters in place
(``mi.traverse``) is faster than re-loading the scene for every image.

Side by side, the 9 gloss levels of one experiment array under the indoor probe: (a) reuse: one
``load`` then 9 renders with parameter updates; (b) reload: for each image a fresh renderer
(mesh + scene + probe upload) and one render. Same size, spp, variant. Printed: total seconds of
each and the ratio reload / reuse.

Usage: ``.venv/bin/python bench/stimuli_scene_reuse.py [--size 128] [--spp 16]``
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")

from calibration import default_calibration
from stimuli import (
    StimulusRenderer,
    camera_geometry,
    default_gloss_table,
    draw_array,
    load_light_probe,
    setup_mitsuba,
    stimulus_seed,
    ward_params_for_gloss,
)
from studydesign import load_design


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--spp", type=int, default=16)
    args = ap.parse_args()
    variant = setup_mitsuba()
    design = load_design()
    cam = camera_geometry(design, default_calibration(design))
    level = design.depth.rendered_levels[len(design.depth.rendered_levels) // 2]
    geometry = draw_array(design, design.depth.cm(level), stimulus_seed(level))
    probe = load_light_probe(design.illuminations[0].envmap)
    materials = list(zip(*ward_params_for_gloss(default_gloss_table(), design.gloss.rendered_pct)))
    warm = StimulusRenderer(cam, size_px=args.size, spp=args.spp)
    warm.load(geometry, probe)
    warm.render(*materials[0])  # compile the kernel once, for both sides

    t = time.perf_counter()
    r = StimulusRenderer(cam, size_px=args.size, spp=args.spp)
    r.load(geometry, probe)
    for i, m in enumerate(materials):
        r.render(*m, seed=i)
    reuse = time.perf_counter() - t

    t = time.perf_counter()
    for i, m in enumerate(materials):
        r = StimulusRenderer(cam, size_px=args.size, spp=args.spp)
        r.load(geometry, probe)
        r.render(*m, seed=i)
    reload = time.perf_counter() - t
    print(f"variant {variant}, {args.size}x{args.size} px, {r.spp} spp, {len(materials)} images")
    print(f"reuse (1 load + traverse updates): {reuse:.2f} s  ({reuse / len(materials):.3f} s/img)")
    print(f"reload (load per image):           {reload:.2f} s  ({reload / len(materials):.3f} s/img)")
    print(f"ratio reload / reuse: {reload / reuse:.2f}")


if __name__ == "__main__":
    main()
