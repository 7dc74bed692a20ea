"""Claim to test: splitting a light probe's brightest small region off as a light of its own
(``stimuli.sunsplit``, ``StimulusRenderer(split_sun=True)``) lowers the displayed error at equal
spp without changing the expected image.

Side by side, per light field and gloss level: ``--repeats`` renders at ``--spp`` of the
deepest array with the probe unsplit (the renderer's default) and split, interleaved render by
render; printed: each one's displayed error (``stimuli.noise``, eq. 1; the tone curve from a
``--ref-spp`` reference of the unsplit map), their ratio (split / unsplit: < 1 is a gain), the
split's agreement with the reference (``compare_renders``, chi^2 per block, about 1 when
unbiased), the sun's share of the probe's power, and the seconds per image of each.

Usage: ``.venv/bin/python bench/stimuli_sun_split.py [--size 48] [--spp 16] [--repeats 6]
[--light-fields immenstadter_horn aerodynamics_workshop]``
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
    camera_geometry,
    default_gloss_table,
    draw_array,
    load_light_probe,
    setup_mitsuba,
    stimulus_seed,
    tone_curve,
    ward_params_for_gloss,
)
from stimuli.noise import compare_renders, displayed_error
from stimuli.render import StimulusRenderer
from stimuli.sunsplit import split_brightest_region
from stimuli.tonemap import luminance_range
from studydesign import load_design


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=48)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--ref-spp", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=6)
    ap.add_argument("--gloss-levels", type=int, nargs="+", default=[6, 11])
    ap.add_argument("--light-fields", nargs="+",
                    default=["immenstadter_horn", "aerodynamics_workshop"])
    args = ap.parse_args()
    design = load_design()
    variant = setup_mitsuba(design.render.variant)
    cam = camera_geometry(design, default_calibration(design))
    depth = design.depth.rendered_levels[-1]
    geometry = draw_array(design, float(design.depth.cm(depth)), stimulus_seed(depth))
    materials = list(zip(*ward_params_for_gloss(
        default_gloss_table(), design.gloss.pct(np.asarray(args.gloss_levels))), strict=True))
    print(f"{variant}, {args.size} px, {args.spp} spp x {args.repeats} seeds each way, "
          f"reference {args.ref_spp} spp; load average {os.getloadavg()[0]:.1f}")
    seed = iter(range(1, 1 << 30))
    for name in args.light_fields:
        lf = design.imagestats.light_field(name)
        probe = load_light_probe(lf.envmap, scale=lf.scale)
        share = split_brightest_region(probe.luminance).share
        plain = StimulusRenderer(cam, size_px=args.size, spp=args.spp)
        split = StimulusRenderer(cam, size_px=args.size, spp=args.spp, split_sun=True)
        plain.load(geometry, probe)
        split.load(geometry, probe)
        for level, m in zip(args.gloss_levels, materials, strict=True):
            ref = np.stack([plain.render(*m, seed=next(seed), spp=args.ref_spp)
                            for _ in range(args.repeats)])
            curve = tone_curve(design.tonemap, luminance_range([ref.mean(axis=0)]))
            a, b, ta, tb = [], [], 0.0, 0.0
            for _ in range(args.repeats):
                t = time.perf_counter()
                a.append(plain.render(*m, seed=next(seed)))
                ta += time.perf_counter() - t
                t = time.perf_counter()
                b.append(split.render(*m, seed=next(seed)))
                tb += time.perf_counter() - t
            ea, eb = displayed_error(a, curve), displayed_error(b, curve)
            agree = compare_renders(np.stack(b), ref, block_px=2)
            print(f"{name:24s} g{level:<2d} sun share {share:.2f}: displayed error unsplit "
                  f"{100 * ea:.2f} %, split {100 * eb:.2f} % (ratio {eb / ea:.2f}); split vs "
                  f"reference chi2/block {agree.chi2_per_df:.2f}, mean z {agree.mean_z:+.1f}; "
                  f"s/image {ta / args.repeats:.2f} vs {tb / args.repeats:.2f}", flush=True)


if __name__ == "__main__":
    main()
