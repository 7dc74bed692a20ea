"""Claim: rendering with 2 Dask workers is >= 1.7x faster than with 1 (target), on the same cores.

Same stimuli (experiment set, one illumination, four depth levels: 4 groups of 9 gloss levels),
size, spp and variant. Three LocalClusters: 1 worker process with 1 Dr.Jit thread, 2 worker
processes with 1 thread each (Dask's scaling at equal resources per worker: the target, and how a
cluster of single-core workers grows), and 1 worker process with Dr.Jit threads = all cores
(Dr.Jit's own threading on the same cores, for comparison). Each worker renders one image first (import,
smoke test, kernel compile) before the clock starts; then pass 1 of ``render_set`` (EXRs) is
timed. Printed: seconds of each and the speed-up. On a machine shared with other jobs the figure
is only indicative (the load average is printed).

Usage: ``.venv/bin/python bench/stimuli_dask_scaling.py [--size 128] [--spp 16]``
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")

from calibration import default_calibration
from stimuli import (
    RenderJob,
    apply_filters,
    camera_geometry,
    default_gloss_table,
    render_set,
    setup_mitsuba,
    stimulus_set,
)
from stimuli.pipeline import render_group
from studydesign import load_design


def _warm(job, row, folder):
    render_group(job, [row], folder)
    return os.getpid()


def run(n_workers: int, threads: int, table, job_kw, design, cal) -> float:
    from dask.distributed import Client, LocalCluster

    job = RenderJob(**job_kw, threads=threads)
    with LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                      dashboard_address=":0") as cluster, Client(cluster) as client, \
            tempfile.TemporaryDirectory() as tmp:
        row = dict(table.iloc[0]) | {"rho_d": 0.3, "rho_s": 0.05, "alpha": 0.1,
                                     "exr_path": "exr/warm.exr"}
        client.run(_warm, job, row, tmp)
        summary = render_set(table, Path(tmp) / "out", job=job, gloss_table=default_gloss_table(),
                             calibration=cal, tonemap_spec=design.tonemap, client=client,
                             progress=False)
    return summary["render_s"]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--spp", type=int, default=16)
    args = ap.parse_args()
    variant = setup_mitsuba()
    design = load_design()
    cal = default_calibration(design)
    depths = ",".join(str(d) for d in design.depth.rendered_levels[:4])
    table = apply_filters(stimulus_set(design, "experiment"),
                          {"illumination": [design.illuminations[0].name],
                           "depth_level": depths.split(",")})
    job_kw = {"camera": camera_geometry(design, cal), "size_px": args.size, "spp": args.spp,
              "variant": variant, "design_path": str(design.source)}
    cores = os.cpu_count() or 1
    t1 = run(1, 1, table, job_kw, design, cal)
    t2 = run(2, 1, table, job_kw, design, cal)
    t1n = run(1, cores, table, job_kw, design, cal)
    print(f"variant {variant}, {len(table)} images, {args.size} px, {args.spp} spp, "
          f"{cores} cores, load average {os.getloadavg()[0]:.1f}")
    print(f"1 worker  x 1 thread : {t1:.2f} s ({3600 * len(table) / t1:.0f} images/hour)")
    print(f"2 workers x 1 thread : {t2:.2f} s ({3600 * len(table) / t2:.0f} images/hour)")
    print(f"1 worker  x {cores} threads: {t1n:.2f} s ({3600 * len(table) / t1n:.0f} images/hour)")
    print(f"speed-up 2 vs 1 workers (1 thread each): {t1 / t2:.2f}  (target >= 1.7)")
    print(f"2 workers x 1 thread vs 1 worker x {cores} threads: {t1n / t2:.2f}  "
          "(Dask processes vs Dr.Jit's threads on the same cores)")


if __name__ == "__main__":
    main()
