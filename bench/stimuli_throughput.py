"""Claim: at equal displayed error, the stimulus renderer makes >= 3x the images per hour of the
source study's way of rendering (spectral, one spp for every image) on the same 2 cores, under
every light field of the image-statistics set, and the set (58,564 images) is planned in hours and
machines from measured throughput.

Compared side by side in this process, both with Dr.Jit's threads on all cores, light field by
light field (each light field renders its before-images, then its after-images):

* before: ``llvm_ad_spectral``, plain environment sampling, one spp for every gloss level
  (``--baseline-spp``, 144: the former default for 256 px renders);
* after: the design's variant (``auto``: ``llvm_ad_mono``, exact for the grey stimuli), MIS
  compensation on the environment, the spp of each (light field, gloss level)
  (``design.spp(level, light_field)``: ``[render.spp_by_light_field]`` from ``python -m stimuli
  plan-spp --light-fields all``, else ``spp_by_gloss_level``).

Stimuli: the deepest rendered array. Displayed error (``stimuli.noise``, eq. 1, ``--repeats``
independent seeds): before, on its hardest stimulus (100 % gloss) under each light field; after,
on every gloss level under each light field, each compared with the design's target
(``displayed_error_pct``). The ratio is "at equal displayed error" when every light field's
largest after-error is at or below the target (the before-renders' error is printed beside it).

Cost: the seconds of the same renders, the first of each stack left out (it compiles the kernel
of a new sample count): before, gloss level 11 (spectral at one spp costs about the same at every
level); after, every gloss level, each as often as in the image-statistics set. The ratio is the
mean seconds per image before over after, over all light fields measured.

Then (without ``--no-workers``), for the after configuration, throughput of the in-process
renderer and of Dask workers (1 thread; one per core; one with all cores), interleaved, on the
first light field, and the plan of the 58,564-image set from it.

All figures are ratios measured side by side on a machine that other jobs share (the load average
is printed); absolute seconds are only indicative.

Usage: ``.venv/bin/python bench/stimuli_throughput.py [--size PX] [--baseline-spp 144]
[--repeats 3] [--rounds 2] [--no-workers] [--light-fields NAME ...] [--design TOML]``
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


def _stack(renderer, material, seeds, spp=None):
    """Renders of one stimulus with these seeds, and the seconds of all but the first."""
    images, seconds = [], 0.0
    for i, seed in enumerate(seeds):
        t = time.perf_counter()
        images.append(renderer.render(*material, seed=seed, spp=spp))
        seconds += (time.perf_counter() - t) if i else 0.0
    return np.stack(images), seconds


def _light_field(ctx, lf, seed):
    """Before and after under one light field: errors (fractions) and timed seconds."""
    design, args = ctx["design"], ctx["args"]
    probe = load_light_probe(lf.envmap, scale=lf.scale)
    n_timed = args.repeats - 1
    setup_mitsuba(ctx["before_variant"], smoke_test=False)
    ctx["before"].load(ctx["geometry"], _PlainSampling(probe))
    stack, t_before = _stack(ctx["before"], ctx["materials"][-1],
                             [next(seed) for _ in range(args.repeats)])
    curve = tone_curve(design.tonemap, luminance_range([stack.mean(axis=0)]))
    err_before = displayed_error(stack, curve)
    setup_mitsuba(ctx["after_variant"], smoke_test=False)
    ctx["after"].load(ctx["geometry"], probe)
    spp = [multijitter_spp(design.spp(g, lf.name)) for g in ctx["levels"]]
    stacks, t_after = [], 0.0
    for m, n in zip(ctx["materials"], spp, strict=True):
        st, t = _stack(ctx["after"], m, [next(seed) for _ in range(args.repeats)], spp=n)
        stacks.append(st)
        t_after += t
    curve = tone_curve(design.tonemap, luminance_range([s.mean(axis=0) for s in stacks]))
    err_after = [displayed_error(s, curve) for s in stacks]
    return {"name": lf.name, "spp": spp, "err_before": err_before, "err_after": err_after,
            "s_before": t_before, "n_before": n_timed,
            "s_after": t_after, "n_after": n_timed * len(spp)}


def _print_light_field(r, target, before_spp) -> bool:
    worst = int(np.argmax(r["err_after"]))
    ok = r["err_after"][worst] <= target
    print(f"{r['name']:26s} before {100 * r['err_before']:.2f} % (g11, {before_spp} spp), "
          f"{r['s_before'] / r['n_before']:.2f} s/img | after largest "
          f"{100 * r['err_after'][worst]:.2f} % (g{worst + 1}) {'<=' if ok else 'ABOVE'} target "
          f"{100 * target:g} %, mean {np.mean(r['spp']):.1f} spp, "
          f"{r['s_after'] / r['n_after']:.2f} s/img | per level % "
          + " ".join(f"{100 * e:.2f}" for e in r["err_after"]), flush=True)
    return ok


def main() -> None:
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--design", help="design.toml (default: the shipped one)")
    design = load_design(pre.parse_known_args()[0].design)
    ap = argparse.ArgumentParser(parents=[pre])
    ap.add_argument("--size", type=int, default=design.render.spp_planned_at_px,
                    help="image width = height, px (default: the size the design's spp were "
                         "planned at)")
    ap.add_argument("--baseline-spp", type=int, default=144)
    ap.add_argument("--repeats", type=int, default=3, help="seeds per displayed-error estimate")
    ap.add_argument("--rounds", type=int, default=2, help="rounds (the first is not timed)")
    ap.add_argument("--no-workers", action="store_true", help="skip the Dask worker comparison")
    ap.add_argument("--light-fields", nargs="+", metavar="NAME",
                    help="these [imagestats] light fields (default: all)")
    args = ap.parse_args()
    if args.repeats < 2:
        ap.error("--repeats must be >= 2 (the displayed error needs two renders)")
    cores = os.cpu_count() or 1
    after_variant = setup_mitsuba(design.render.variant)
    before_variant = "llvm_ad_spectral" if after_variant.startswith("llvm") else "cuda_ad_spectral"
    cam = camera_geometry(design, default_calibration(design))
    depth = design.depth.rendered_levels[-1]
    levels = list(design.gloss.labels)
    fields = [design.imagestats.light_field(n) for n in args.light_fields] \
        if args.light_fields else list(design.imagestats.light_fields)
    target = design.render.displayed_error_pct / 100.0
    before_spp = multijitter_spp(args.baseline_spp)
    ctx = {"design": design, "args": args, "levels": levels, "before_variant": before_variant,
           "after_variant": after_variant,
           "geometry": draw_array(design, float(design.depth.cm(depth)), stimulus_seed(depth)),
           "materials": list(zip(*ward_params_for_gloss(default_gloss_table(),
                                                        design.gloss.pct(np.asarray(levels))),
                                 strict=True))}
    setup_mitsuba(before_variant, smoke_test=False)
    ctx["before"] = StimulusRenderer(cam, size_px=args.size, spp=before_spp)
    setup_mitsuba(after_variant, smoke_test=False)
    ctx["after"] = StimulusRenderer(cam, size_px=args.size, spp=before_spp)
    print(f"{args.size} x {args.size} px, {cores} cores, {len(fields)} light fields, before: "
          f"{before_variant}, {before_spp} spp for every level, plain envmap sampling; after: "
          f"{after_variant}, MIS compensation, spp per (light field, gloss level); target "
          f"{design.render.displayed_error_pct:g} % displayed error", flush=True)
    seed = iter(range(1, 1 << 30))
    results = []
    for lf in fields:
        results.append(_light_field(ctx, lf, seed))
        _print_light_field(results[-1], target, before_spp)
    all_ok = all(max(r["err_after"]) <= target for r in results)
    s_before = sum(r["s_before"] for r in results) / sum(r["n_before"] for r in results)
    s_after = sum(r["s_after"] for r in results) / sum(r["n_after"] for r in results)
    ratio_render = s_before / s_after
    after_per_hour = 3600 / s_after
    print(f"largest displayed error after: {100 * max(max(r['err_after']) for r in results):.3f}"
          f" % ({'every light field at or below' if all_ok else 'SOME light field ABOVE'} the "
          f"target {100 * target:g} %); before, largest: "
          f"{100 * max(r['err_before'] for r in results):.3f} %")
    print(f"in process, Dr.Jit threads = {cores} cores, mean over the light fields and levels: "
          f"before {s_before:.2f} s/image ({3600 / s_before:.0f} images/hour), after "
          f"{s_after:.2f} s/image ({after_per_hour:.0f} images/hour); ratio {ratio_render:.2f}; "
          f"load average {os.getloadavg()[0]:.1f}")
    per_hour = {"in-process": after_per_hour}
    if not args.no_workers:
        after_spp = [multijitter_spp(design.spp(g, fields[0].name)) for g in levels]
        per_hour = _workers(args, design, cam, after_variant, levels, after_spp, cores, per_hour)
    _print_plan(design, args, cores, per_hour, ratio_render)
    print(f"speed-up vs spectral at equal displayed error: {ratio_render:.1f}x"
          + ("" if all_ok else " (NOT at equal displayed error: a light field is above the "
                               "target, see above)"))


def _print_plan(design, args, cores, per_hour, ratio_render) -> None:
    # the recommended set-up: one worker per machine, Dr.Jit threads on all its cores
    chosen = f"1 worker x {cores} threads" if f"1 worker x {cores} threads" in per_hour \
        else "in-process"
    n_set = design.n_imagestats_images
    hours_one = n_set / per_hour[chosen]
    print(f"plan: {n_set} images at {args.size} px, one worker per machine ({chosen}, "
          f"{per_hour[chosen]:.0f} images/hour = {per_hour[chosen] / cores:.0f} per core here): "
          f"{hours_one:.1f} h on one {cores}-core machine like this one "
          f"({hours_one * cores:.1f} core-hours), {int(np.ceil(hours_one / 24))} such machines "
          f"for 24 h, {int(np.ceil(hours_one / 8))} for 8 h (measured here on a machine with "
          f"load average {os.getloadavg()[0]:.1f}: on an idle one these are upper bounds)")
    today = f"{cores} workers x 1 thread"
    if today in per_hour and chosen in per_hour and chosen != "in-process":
        ratio_workers = per_hour[chosen] / per_hour[today]
        print(f"one worker with {cores} Dr.Jit threads vs {today}, same cores: "
              f"{ratio_workers:.2f}x; with the render ratio: {ratio_render * ratio_workers:.1f}x "
              "(the product of two side-by-side ratios, an estimate)")


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
