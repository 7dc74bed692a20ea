"""Does a smaller light-field map raise the displayed error of the hardest stimulus past the target?

The shipped light fields (stimuli/probes/, protocol.md section 4) are Poly Haven's 1024 x 512
captures shrunk by an integer factor (solid-angle-weighted box filter,
``stimuli.illumination.downsample_latlong``) and stored as Radiance RGBE. A smaller map blurs
the sun and the lamps over larger pixels, which changes the highlights of the glossiest
stimuli. Measured here, per light field, on its hardest stimulus (gloss level 11 = 100 %, depth
level 11 = the deepest array, array 0, 256 px, the design's spp for gloss level 11), k renders
with independent seeds under the original map and under each smaller one (each scaled by the
design's rule, a matte white facing the viewer = 1), all tone-mapped with the original's curve
(L_max from the original's mean image):

- noise: the displayed error of one render (``stimuli.noise.displayed_error``, % of range);
- bias: the RMS over pixels of the difference between the expected displayed images under the
  smaller map and under the original (the noise of the two k-render means subtracted:
  E[(a - b)^2] = bias^2 + var_a / k + var_b / k per pixel);
- total = sqrt(noise_small^2 + bias^2): the RMS displayed difference between one render under the
  smaller map and the original's noise-free image, the figure compared with the design's target.

    DRJIT_LIBLLVM_PATH=... nice .venv/bin/python bench/lightfield_resolution.py \\
        --source ../shared/data/hdr/polyhaven --light-fields noon_grass rooitou_park --repeats 4
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from calibration import default_calibration
from stimuli import camera_geometry, setup_mitsuba
from stimuli.geometry import draw_array, stimulus_seed
from stimuli.glosstable import default_gloss_table, ward_params_for_gloss
from stimuli.illumination import LightProbe, diffuse_white_scale, downsample_latlong
from stimuli.noise import displayed_error
from stimuli.render import StimulusRenderer
from stimuli.rgbe import read_rgbe, write_rgbe
from stimuli.tonemap import luminance_range, tone_curve, tonemap
from studydesign import load_design


def _probe(rgb: np.ndarray, tag: str) -> LightProbe:
    scale = diffuse_white_scale(rgb)
    return LightProbe(name=tag, path="", sha256=tag, rgb=(rgb * np.float32(scale)).astype(
        np.float32), rotation_deg=0.0, scale=scale)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--source", type=Path, default=Path("../shared/data/hdr/polyhaven"))
    ap.add_argument("--light-fields", nargs="+", default=["noon_grass", "rooitou_park"])
    ap.add_argument("--factors", nargs="+", type=int, default=[2, 4],
                    help="shrink factors of the 1024 x 512 original (2: 512 x 256, 4: 256 x 128)")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=4)
    ap.add_argument("--tmp", type=Path, default=Path("/tmp/lightfield_resolution"))
    args = ap.parse_args()
    design = load_design()
    variant = setup_mitsuba(design.render.variant)
    cam = camera_geometry(design, default_calibration(design))
    gloss_level = design.gloss.labels[-1]
    depth_level = design.depth.labels[-1]
    spp = design.render.spp(gloss_level)
    material = [float(v[0]) for v in ward_params_for_gloss(
        default_gloss_table(), np.array([design.gloss.pct(gloss_level)]))]
    geometry = draw_array(design, float(design.depth.cm(depth_level)), stimulus_seed(depth_level))
    renderer = StimulusRenderer(cam, size_px=args.size, spp=spp)
    args.tmp.mkdir(parents=True, exist_ok=True)
    target = design.render.displayed_error_pct
    print(f"{variant}, {args.size} px, {renderer.spp_for(spp)} spp, gloss level {gloss_level}, "
          f"depth level {depth_level}, {args.repeats} seeds; target {target:g} % of range")
    seed = 1
    results = []
    for name in args.light_fields:
        original = read_rgbe(args.source / f"{name}_1k.hdr")
        maps = {"1024x512": original}
        for f in args.factors:
            small = downsample_latlong(original, f)
            path = args.tmp / f"{name}_{f}.hdr"
            write_rgbe(path, small)  # the shipped format's rounding included
            maps[f"{small.shape[1]}x{small.shape[0]}"] = read_rgbe(path)
        stacks = {}
        t0 = time.perf_counter()
        for tag, rgb in maps.items():
            renderer.load(geometry, _probe(rgb, f"{name}-{tag}"))
            stacks[tag] = np.stack([renderer.render(*material, seed=(seed := seed + 1))
                                    for _ in range(args.repeats)])
        curve = tone_curve(design.tonemap, luminance_range([stacks["1024x512"].mean(axis=0)]))
        shown = {t: np.stack([tonemap(im, curve) for im in s]) for t, s in stacks.items()}
        ref = shown["1024x512"]
        row = {"light_field": name, "render_s": round(time.perf_counter() - t0, 1),
               "noise_pct": {}, "bias_pct": {}, "total_pct": {}}
        for tag, s in shown.items():
            noise = 100 * displayed_error(stacks[tag], curve)
            row["noise_pct"][tag] = round(noise, 3)
            if tag == "1024x512":
                continue
            k = args.repeats
            d2 = (s.mean(0) - ref.mean(0)) ** 2 - (s.var(0, ddof=1) + ref.var(0, ddof=1)) / k
            bias = 100 * np.sqrt(max(float(d2.mean()), 0.0)) / curve.max_value
            row["bias_pct"][tag] = round(bias, 3)
            row["total_pct"][tag] = round(float(np.hypot(noise, bias)), 3)
        results.append(row)
        print(json.dumps(row), flush=True)
    print("summary: light field | noise at 1024x512 | total at " + ", ".join(
        t for t in results[0]["total_pct"]) + f" (% of range; target {target:g} %)")
    for r in results:
        print(f"  {r['light_field']:22s} {r['noise_pct']['1024x512']:6.3f} | " + ", ".join(
            f"{v:6.3f}" for v in r["total_pct"].values()))


if __name__ == "__main__":
    main()
