"""Claim: at equal displayed error, the stimulus renderer makes >= 3x the images per hour of the
source study's way of rendering (spectral, one spp for every image) on the same 2 cores, and the
image-statistics set (58,564 images) is planned in hours and machines from measured throughput.

Compared side by side in this process, both with Dr.Jit's threads on all cores, interleaved image
by image (each round renders every gloss level, alternating the two configurations; the first
round compiles the kernels and is not timed):

* before: ``llvm_ad_spectral``, plain environment sampling, one spp for every gloss level
  (``--baseline-spp``, 144: the former default for 256 px renders);
* after: the design's variant (``auto``: ``llvm_ad_mono``, exact for the grey stimuli), MIS
  compensation on the environment, the design's spp per gloss level
  (``design.render.spp_by_gloss_level``, from ``python -m stimuli plan-spp``).

Stimuli: every physical gloss level (1..11) of the deepest rendered array under the indoor probe
(the hardest case for noise; the image-statistics set has every level equally often). Displayed
error (``stimuli.noise``, eq. 1, ``--repeats`` independent seeds): before, on its hardest
stimulus (100 % gloss) under each probe; after, on every gloss level under each probe. The ratio
is "at equal displayed error" when the after-renders' largest error is no larger than the
before-renders' (then the ratio is a lower bound: after is at most as noisy everywhere).

Then, for the after configuration, throughput (images / hour, and per core) of: the in-process
renderer (Dr.Jit threads = cores), one Dask worker with 1 thread, one Dask worker per core with 1
thread each (today's default), and one Dask worker with all cores as Dr.Jit threads (the new
default); those are interleaved too (all clusters stay up; each round gives each configuration
the same 22 images: gloss levels 1..11 of two arrays; the first round is not timed). From the
one-worker-per-machine figure: hours for the 58,564-image set on machines like this one, and
machines for a 24-hour and an 8-hour run.

All figures are ratios measured side by side on a machine that other jobs share (the load average
is printed); absolute seconds are only indicative.

Usage: ``.venv/bin/python bench/stimuli_throughput.py [--size PX] [--baseline-spp 144]
[--repeats 3] [--rounds 2] [--no-workers]``
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")

from _workers import clients, worker_configs

from calibration import default_calibration
from stimuli import (
    RenderJob,
    StimulusRenderer,
    camera_geometry,
    default_gloss_table,
    draw_array,
    load_light_probe,
    setup_mitsuba,
    stimulus_seed,
    tone_curve,
    ward_params_for_gloss,
)
from stimuli.noise import displayed_error
from stimuli.render import multijitter_spp
from stimuli.tonemap import luminance_range
from studydesign import load_design


class _PlainSampling:
    """A light probe whose emitter has MIS compensation off (the renderer before)."""

    def __init__(self, probe):
        self._probe = probe
        self.sha256 = probe.sha256 + "-plain"
        self.rotation_deg, self.scale = probe.rotation_deg, probe.scale

    def emitter(self):
        return self._probe.emitter() | {"mis_compensation": False}


def _worker_render(job, rows, folder):
    from stimuli.pipeline import render_group

    t = time.perf_counter()
    render_group(job, rows, folder)
    return time.perf_counter() - t


def main() -> None:
    design = load_design()
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=design.render.spp_planned_at_px,
                    help="image width = height, px (default: the size the design's spp were "
                         "planned at)")
    ap.add_argument("--baseline-spp", type=int, default=144)
    ap.add_argument("--repeats", type=int, default=3, help="seeds per displayed-error estimate")
    ap.add_argument("--rounds", type=int, default=2, help="rounds (the first is not timed)")
    ap.add_argument("--no-workers", action="store_true", help="skip the Dask worker comparison")
    args = ap.parse_args()
    cores = os.cpu_count() or 1
    after_variant = setup_mitsuba(design.render.variant)
    before_variant = "llvm_ad_spectral" if after_variant.startswith("llvm") else "cuda_ad_spectral"
    cal = default_calibration(design)
    cam = camera_geometry(design, cal)
    depth = design.depth.rendered_levels[-1]
    geometry = draw_array(design, float(design.depth.cm(depth)), stimulus_seed(depth))
    levels = list(design.gloss.labels)
    materials = list(zip(*ward_params_for_gloss(default_gloss_table(),
                                                design.gloss.pct(np.asarray(levels))),
                         strict=True))
    after_spp = [multijitter_spp(design.render.spp(g)) for g in levels]
    before_spp = multijitter_spp(args.baseline_spp)
    probes = [load_light_probe(il.envmap) for il in design.illuminations]
    print(f"{args.size} x {args.size} px, {cores} cores, before: {before_variant}, "
          f"{before_spp} spp for every level, plain envmap sampling; after: {after_variant}, "
          f"MIS compensation, spp per gloss level {after_spp} (planned at "
          f"{design.render.spp_planned_at_px} px for {design.render.displayed_error_pct:g} %)")

    def renderers(variant, wrap):
        setup_mitsuba(variant, smoke_test=False)
        out = []
        for probe in probes:
            r = StimulusRenderer(cam, size_px=args.size, spp=before_spp)
            r.load(geometry, wrap(probe))
            out.append(r)
        return out

    before = renderers(before_variant, _PlainSampling)
    after = renderers(after_variant, lambda p: p)

    # -- displayed error ------------------------------------------------------------------------
    seed = iter(range(1, 1 << 30))
    err_before, err_after = [], np.zeros((len(probes), len(levels)))
    for p, probe in enumerate(probes):
        setup_mitsuba(before_variant, smoke_test=False)
        stack = np.stack([before[p].render(*materials[-1], seed=next(seed))
                          for _ in range(args.repeats)])
        curve = tone_curve(design.tonemap, luminance_range([stack.mean(axis=0)]))
        err_before.append(displayed_error(stack, curve))
        setup_mitsuba(after_variant, smoke_test=False)
        stacks = [np.stack([after[p].render(*m, seed=next(seed), spp=n)
                            for _ in range(args.repeats)])
                  for m, n in zip(materials, after_spp, strict=True)]
        curve = tone_curve(design.tonemap, luminance_range([s.mean(axis=0) for s in stacks]))
        err_after[p] = [displayed_error(s, curve) for s in stacks]
        print(f"displayed error, {probe.name}: before {100 * err_before[-1]:.3f} % (gloss level "
              f"{levels[-1]}, {before_spp} spp); after, per gloss level: "
              + ", ".join(f"{100 * e:.2f}" for e in err_after[p]) + " %")
    worst_before, worst_after = max(err_before), float(err_after.max())
    equal = worst_after <= worst_before
    print(f"largest displayed error: before {100 * worst_before:.3f} %, after "
          f"{100 * worst_after:.3f} % -> "
          + ("after is at most as noisy: the ratio below is at equal (or lower) displayed error"
             if equal else "after is NOISIER than before: the ratio below is NOT at equal error"))

    # -- render cost, side by side, in process ----------------------------------------------------
    t_before = t_after = 0.0
    for rnd in range(args.rounds):
        tb = ta = 0.0
        for g, m in enumerate(materials):  # alternate image by image: load changes hit both
            setup_mitsuba(before_variant, smoke_test=False)
            t = time.perf_counter()
            before[0].render(*m, seed=10_000 * rnd + g)
            tb += time.perf_counter() - t
            setup_mitsuba(after_variant, smoke_test=False)
            t = time.perf_counter()
            after[0].render(*m, seed=10_000 * rnd + g, spp=after_spp[g])
            ta += time.perf_counter() - t
        timed = rnd > 0 or args.rounds == 1
        print(f"round {rnd}{'' if timed else ' (compiles kernels, not timed)'}: before "
              f"{tb:.1f} s, after {ta:.1f} s for {len(levels)} images each, load average "
              f"{os.getloadavg()[0]:.1f}")
        if timed:
            t_before, t_after = t_before + tb, t_after + ta
    n_timed = len(levels) * max(1, args.rounds - 1)
    ratio_render = t_before / t_after
    before_per_hour = 3600 * n_timed / t_before
    after_per_hour = 3600 * n_timed / t_after
    print(f"in process, Dr.Jit threads = {cores} cores: before {before_per_hour:.0f} images/hour "
          f"({before_per_hour / cores:.0f} per core), after {after_per_hour:.0f} images/hour "
          f"({after_per_hour / cores:.0f} per core); ratio {ratio_render:.2f}")

    # -- workers ----------------------------------------------------------------------------------
    per_hour = {"in-process": after_per_hour}
    if not args.no_workers:
        per_hour = _workers(args, design, cam, after_variant, levels, after_spp, cores, per_hour)
    # the recommended set-up: one worker per machine, Dr.Jit threads on all its cores
    chosen = f"1 worker x {cores} threads" if f"1 worker x {cores} threads" in per_hour \
        else "in-process"
    n_set = design.n_imagestats_images
    hours_one = n_set / per_hour[chosen]
    print(f"plan: {n_set} images at {args.size} px, one worker per machine ({chosen}, "
          f"{per_hour[chosen]:.0f} images/hour = {per_hour[chosen] / cores:.0f} per core here): "
          f"{hours_one:.1f} h on one {cores}-core machine like this one, "
          f"{int(np.ceil(hours_one / 24))} such machines for 24 h, "
          f"{int(np.ceil(hours_one / 8))} for 8 h; {n_set / (per_hour[chosen] / cores * 16):.1f} h "
          "on one 16-core machine if Dr.Jit's threads scale with cores (measured here on a "
          f"machine with load average {os.getloadavg()[0]:.1f}: on an idle one these are upper "
          "bounds)")
    today = f"{cores} workers x 1 thread"
    if today in per_hour and chosen in per_hour and chosen != "in-process":
        ratio_workers = per_hour[chosen] / per_hour[today]
        print(f"one worker with {cores} Dr.Jit threads vs today's default ({today}), same cores: "
              f"{ratio_workers:.2f}x; with the render ratio: {ratio_render * ratio_workers:.1f}x "
              "(the product of two side-by-side ratios, an estimate)")
    print(f"speed-up vs spectral at equal displayed error: {ratio_render:.1f}x"
          + ("" if equal else " (NOT at equal displayed error, see above)"))


def _workers(args, design, cam, variant, levels, spp, cores, per_hour):
    table = default_gloss_table()
    rho = ward_params_for_gloss(table, design.gloss.pct(np.asarray(levels)))
    groups = []
    for depth in (design.depth.rendered_levels[-1], design.depth.rendered_levels[-2]):
        s = stimulus_seed(depth)
        groups.append([{"stimulus_id": f"d{depth}_g{g:02d}", "gloss_level": g,
                        "true_depth_cm": float(design.depth.cm(depth)), "seed": s,
                        "envmap": design.illuminations[0].envmap, "rotation_deg": 0.0,
                        "rho_d": float(rho[0][i]), "rho_s": float(rho[1][i]),
                        "alpha": float(rho[2][i]), "exr_path": f"exr/d{depth}_g{g:02d}.exr"}
                       for i, g in enumerate(levels)])
    from stimuli.pipeline import render_group

    configs = worker_configs(cores)
    elapsed = dict.fromkeys(configs, 0.0)
    elapsed["in-process"] = 0.0  # the in-process renderer once more, beside the workers
    with tempfile.TemporaryDirectory() as tmp, clients(configs) as client:
        for rnd in range(args.rounds):
            for name in [*configs, "in-process"]:
                threads = configs.get(name, (0, cores))[1]
                job = RenderJob(camera=cam, size_px=args.size, spp=max(spp),
                                variant=variant, design_path=str(design.source),
                                threads=threads, spp_by_gloss_level=tuple(spp))
                t = time.perf_counter()
                if name == "in-process":
                    for rows in groups:
                        render_group(job, rows, tmp)
                else:
                    futures = [client[name].submit(_worker_render, job, rows, tmp, pure=False)
                               for rows in groups]
                    client[name].gather(futures)
                if rnd > 0 or args.rounds == 1:
                    elapsed[name] += time.perf_counter() - t
    n_images = sum(len(g) for g in groups) * max(1, args.rounds - 1)
    used = {name: n * threads for name, (n, threads) in configs.items()} | {"in-process": cores}
    out = dict(per_hour)
    for name, t in elapsed.items():
        out[name] = 3600 * n_images / t
        n_cores = min(used[name], cores)
        print(f"after, {name:>22}: {out[name]:7.0f} images/hour on {n_cores} core(s) = "
              f"{out[name] / n_cores:6.0f} images/hour/core")
    print(f"(load average {os.getloadavg()[0]:.1f}: other jobs share these {cores} cores, so a "
          "1-thread worker's per-core figure is inflated relative to the all-core ones)")
    return out


if __name__ == "__main__":
    main()
