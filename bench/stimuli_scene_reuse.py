"""Claim: building the scene once per (array, probe) and updating the Ward parameters in place
(``mi.traverse``) is faster than re-loading the scene for every image; and freezing the render
(``dr.freeze``) would gain nothing worth its constraints, because re-tracing the Python Ward BSDF
per image costs little next to the render itself.

Side by side, the 9 rendered gloss levels of one experiment array under the indoor probe, three
ways, interleaved image by image (each image is rendered by all three before the next; the order
of the three rotates from image to image so that none always runs first after a load change):

* reuse: one ``load``, then per image a parameter update and a render (the renderer's way; Dr.Jit
  traces the Python Ward BSDF again for each render and finds the compiled kernel in its cache);
* reload: per image a fresh renderer (mesh + scene + probe upload) and one render;
* frozen: the reuse scene rendered through a ``dr.freeze``-d function (Dr.Jit replays the
  recorded kernel launches instead of tracing again).

Before the clock starts, every way renders three images (kernel compile, freeze recording). Then
``--rounds`` rounds over the 9 materials are timed. Also measured: the first render at a new
sample count (Dr.Jit compiles a kernel per count) against a later one at that count.
Printed: seconds of each way, the ratios reload / reuse and reuse / frozen, the per-image
difference reuse - frozen in ms (what tracing costs), and the load average (other jobs share the
machine: ratios, not seconds).

Usage: ``.venv/bin/python bench/stimuli_scene_reuse.py [--size 128] [--spp 16] [--rounds 2]``
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import zlib
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")

import numpy as np

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
    ap.add_argument("--rounds", type=int, default=2, help="timed rounds over the 9 materials")
    args = ap.parse_args()
    import drjit as dr
    import mitsuba as mi

    variant = setup_mitsuba()
    design = load_design()
    cam = camera_geometry(design, default_calibration(design))
    level = design.depth.rendered_levels[len(design.depth.rendered_levels) // 2]
    geometry = draw_array(design, design.depth.cm(level), stimulus_seed(level))
    probe = load_light_probe(design.illuminations[0].envmap)
    materials = list(zip(*ward_params_for_gloss(default_gloss_table(), design.gloss.rendered_pct),
                         strict=True))

    reused = StimulusRenderer(cam, size_px=args.size, spp=args.spp)
    reused.load(geometry, probe)
    spp = reused.spp
    frozen_scene = StimulusRenderer(cam, size_px=args.size, spp=args.spp)
    frozen_scene.load(geometry, probe)

    @dr.freeze
    def frozen(scene, seed):
        return mi.render(scene, spp=spp, seed=seed)

    def render_frozen(m, seed):
        for name, v in zip(("rho_d", "rho_s", "alpha"), m, strict=True):
            frozen_scene.params[frozen_scene._keys[name]] = mi.Float(float(v))
        frozen_scene.params.update()
        return np.asarray(frozen(frozen_scene.scene, mi.UInt32(seed)))

    def render_reload(m, seed):
        r = StimulusRenderer(cam, size_px=args.size, spp=args.spp)
        r.load(geometry, probe)
        return r.render(*m, seed=seed)

    ways = {"reuse": lambda m, s: reused.render(*m, seed=s), "reload": render_reload,
            "frozen": render_frozen}
    for i, m in enumerate(materials[:3]):  # compile, record the frozen function
        for f in ways.values():
            f(m, i)

    elapsed = dict.fromkeys(ways, 0.0)
    same = True
    for rnd in range(args.rounds):
        for i, m in enumerate(materials):
            seed = zlib.crc32(f"{rnd}:{i}".encode()) & 0x7FFFFFFF
            names = list(ways)
            k = (rnd * len(materials) + i) % len(names)
            images = {}
            for name in names[k:] + names[:k]:
                t = time.perf_counter()
                images[name] = ways[name](m, seed)
                elapsed[name] += time.perf_counter() - t
            same &= bool(np.allclose(np.reshape(images["frozen"], images["reuse"].shape),
                                     images["reuse"], rtol=1e-5, atol=1e-6))
        print(f"round {rnd}: load average {os.getloadavg()[0]:.1f}")

    # a new sample count compiles a kernel; the next render at that count reuses it
    new_spp = reused.spp_for(spp + 9)
    t = time.perf_counter()
    reused.render(*materials[0], seed=1, spp=new_spp)
    first = time.perf_counter() - t
    t = time.perf_counter()
    reused.render(*materials[1], seed=2, spp=new_spp)
    later = time.perf_counter() - t

    n = len(materials) * args.rounds
    reuse, reload, froz = elapsed["reuse"], elapsed["reload"], elapsed["frozen"]
    print(f"variant {variant}, {args.size}x{args.size} px, {spp} spp, {n} images per way, "
          f"interleaved image by image, load average {os.getloadavg()[0]:.1f}")
    print(f"reuse (1 load + traverse updates): {reuse:.2f} s  ({reuse / n:.3f} s/img)")
    print(f"reload (load per image):           {reload:.2f} s  ({reload / n:.3f} s/img)")
    print(f"reuse, frozen (dr.freeze):         {froz:.2f} s  ({froz / n:.3f} s/img; images "
          f"{'identical to reuse' if same else 'DIFFERENT from reuse'})")
    print(f"tracing the Python Ward BSDF per image (reuse - frozen): "
          f"{1000 * (reuse - froz) / n:+.1f} ms/img")
    print(f"first render at a new sample count ({new_spp} spp, compiles a kernel): {first:.2f} s; "
          f"the next at that count: {later:.2f} s")
    print(f"ratio reload / reuse: {reload / reuse:.2f}")
    print(f"ratio reuse / frozen: {reuse / froz:.2f}")


if __name__ == "__main__":
    main()
