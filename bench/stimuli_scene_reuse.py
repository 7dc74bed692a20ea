"""Claim: building the scene once per (array, probe) and updating the Ward parameters in place
(``mi.traverse``) is faster than re-loading the scene for every image.

Side by side, the 9 gloss levels of one experiment array under the indoor probe: (a) reuse: one
``load`` then 9 renders with parameter updates; (b) reload: for each image a fresh renderer
(mesh + scene + probe upload) and one render; (c) reuse with the render frozen
(``dr.freeze``: Dr.Jit replays the recorded kernels instead of tracing the Python Ward BSDF
again). Same size, spp, variant; (a) and (c) interleaved image by image. Printed: total seconds
of each and the ratios reload / reuse and reuse / frozen.

Usage: ``.venv/bin/python bench/stimuli_scene_reuse.py [--size 128] [--spp 16]``
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

    import drjit as dr
    import mitsuba as mi

    r = StimulusRenderer(cam, size_px=args.size, spp=args.spp)
    r.load(geometry, probe)

    @dr.freeze
    def frozen(scene, seed):
        return mi.render(scene, spp=r.spp, seed=seed)

    def set_material(m):
        for name, v in zip(("rho_d", "rho_s", "alpha"), m, strict=True):
            r.params[r._keys[name]] = mi.Float(float(v))
        r.params.update()

    for i, m in enumerate(materials[:3]):  # record, and compile both paths
        set_material(m)
        frozen(r.scene, mi.UInt32(i))
        r.render(*m, seed=i)
    t_plain = t_frozen = 0.0
    same = True
    for i, m in enumerate(materials):
        seed = zlib.crc32(str(i).encode()) & 0x7FFFFFFF
        t = time.perf_counter()
        plain = r.render(*m, seed=seed)
        t_plain += time.perf_counter() - t
        t = time.perf_counter()
        set_material(m)
        img = np.asarray(frozen(r.scene, mi.UInt32(seed)))
        t_frozen += time.perf_counter() - t
        same &= bool(np.allclose(img.reshape(plain.shape), plain, rtol=1e-5, atol=1e-6))
    print(f"reuse, traced per image: {t_plain:.2f} s; reuse, frozen: {t_frozen:.2f} s "
          f"(images {'identical' if same else 'DIFFERENT'})")
    print(f"ratio reuse / frozen: {t_plain / t_frozen:.2f}")


if __name__ == "__main__":
    main()
