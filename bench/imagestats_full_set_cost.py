"""What the full image-statistics set (58,564 images) costs, measured on a stratified slice.

Renders the ``imagestats_slice`` set (stimuli/sets.py: 2 images per light field, 44 in all,
covering all 22 light fields and, within each kind, every physical gloss and depth level twice;
the slice's mean spp equals the full set's where the spp depend on the gloss level only, since both
hold every gloss level equally often; with spp per light field, the slice's 2 images per light field
sample each light field's counts) at the image-statistics size (the design's ``spp_planned_at_px``,
256 px) with the design's spp per (light field, gloss level), in this process (one Dr.Jit worker on every core), and reports:

- images per core-hour, from the CPU time this process used (user + system, all its threads:
  what the images cost, whatever else the machine runs) and, beside it, from wall time x cores
  (what they cost here, where other jobs share the cores);
- the projected wall time of all 58,564 images on 2 cores and on 64 cores of a cluster (CPU
  pace; perfect scaling assumed, which bench/stimuli_dask_scaling.py measures separately). No
  GPU is measured here.

Then the per-image statistics of the slice (``python -m analysis imagestats``) and their
relation to gloss and depth within and across light fields (``imagestats relate``).

    DRJIT_LIBLLVM_PATH=... PYTHONPATH=. nice .venv/bin/python bench/imagestats_full_set_cost.py \\
        --out out/imagestats-slice
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import time
from pathlib import Path

import numpy as np


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _hours(seconds: float) -> str:
    return f"{seconds / 3600:.1f} h ({seconds / 86400:.2f} days)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("out/imagestats-slice"))
    ap.add_argument("--size", type=int, help="px (default: the design's spp_planned_at_px)")
    ap.add_argument("--skip-stats", action="store_true")
    args = ap.parse_args()

    from calibration import default_calibration
    from stimuli import camera_geometry, setup_mitsuba, stimulus_set
    from stimuli.glosstable import default_gloss_table
    from stimuli.noise import spp_table
    from stimuli.pipeline import RenderJob, render_set
    from studydesign import load_design

    design = load_design()
    size = args.size or design.render.spp_planned_at_px
    variant = setup_mitsuba(design.render.variant)
    cal = default_calibration(design)
    table = stimulus_set(design, "imagestats_slice")
    by_level, by_light_field = spp_table(design, table["light_field"])
    cores = len(os.sched_getaffinity(0))
    job = RenderJob(camera=camera_geometry(design, cal), size_px=size,
                    spp=max(max(v) for _, v in by_light_field),
                    variant=variant, design_path=str(design.source), threads=cores,
                    spp_by_gloss_level=by_level, spp_by_light_field=by_light_field,
                    llvm_path=os.environ.get("DRJIT_LIBLLVM_PATH", ""))
    cpu0, t0 = _cpu_s(), time.perf_counter()
    summary = render_set(table, args.out, job=job, gloss_table=default_gloss_table(),
                         calibration=cal, tonemap_spec=design.tonemap, progress=False)
    wall, cpu = time.perf_counter() - t0, _cpu_s() - cpu0
    n = summary["rendered"]
    full = design.n_imagestats_images
    load = os.getloadavg()
    result = {"variant": variant, "size_px": size, "images": n,
              "light_fields": int(table["light_field"].nunique()),
              "mean_spp": round(sum(job.spp_for(g, lf) for g, lf in zip(
                  table["gloss_level"], table["light_field"], strict=True)) / len(table), 1),
              "wall_s": round(wall, 1), "cpu_s": round(cpu, 1), "cores": cores,
              "loadavg_1_5_15_after": [round(v, 1) for v in load]}
    whole = stimulus_set(design, "imagestats")
    full_spp = float(np.mean([job.spp_for(g, lf) for g, lf in zip(
        whole["gloss_level"], whole["light_field"], strict=True)]))
    result["full_set_mean_spp"] = round(full_spp, 1)
    if n:
        # the full set's images hold full_spp samples on average, the slice's mean_spp: scaled
        # by samples (the render's cost is nearly proportional to them)
        per_core_h_cpu = 3600 * n / cpu * result["mean_spp"] / full_spp
        per_core_h_wall = 3600 * n / (wall * cores) * result["mean_spp"] / full_spp
        result.update({"images_per_core_hour_cpu": round(per_core_h_cpu, 1),
                       "images_per_core_hour_wall": round(per_core_h_wall, 1),
                       "core_s_per_image_cpu": round(cpu / n, 2)})
        print(json.dumps(result))
        print(f"measured: {n} images ({result['light_fields']} light fields, mean "
              f"{result['mean_spp']} spp, {size} px, {variant}) in {wall:.0f} s wall, {cpu:.0f} "
              f"s CPU on {cores} cores (load average {load[0]:.1f} after)")
        print(f"full-set images (mean {full_spp:.1f} spp) per core-hour: {per_core_h_cpu:.0f} "
              f"from CPU time ({cpu / n:.2f} core-s per slice image); {per_core_h_wall:.0f} from "
              f"wall x cores here; all {full:,}: {full / per_core_h_cpu:.0f} core-hours")
        for c in (2, 64):
            print(f"all {full:,} images on {c} cores: {_hours(full / (per_core_h_cpu * c) * 3600)}"
                  f" at the CPU-time pace; {_hours(full / (per_core_h_wall * c) * 3600)} at "
                  "this machine's wall pace")
        print("one GPU: not measured (no GPU on this machine)")
    else:
        print(json.dumps(result), "(nothing rendered: the folder was complete; use a new --out)")
    if args.skip_stats:
        return
    from analysis.imagestats.__main__ import main as imagestats

    stats = args.out.with_name(args.out.name + "-stats.parquet")
    t1 = time.perf_counter()
    imagestats([str(args.out), "--out", str(stats), "--workers", str(cores), "--batch-size",
                "4", "--quiet"])
    print(f"image statistics of {len(table)} images: {time.perf_counter() - t1:.0f} s wall")
    report = args.out.with_name(args.out.name + "-relate")
    imagestats(["relate", str(stats), "--out", str(report), "--n-boot", "200"])


if __name__ == "__main__":
    main()
