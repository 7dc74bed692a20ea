"""Renders per hour on 1 and 2 external Dask workers (``dask worker`` processes as a lab starts
them, two threads each), side by side in one run, on this machine.

Two real ``dask scheduler`` processes on loopback, one with one ``dask worker``, one with two
(each ``--nthreads 2``, as ``dask worker`` starts on a 2-core machine). Every worker renders one
image first (import, Mitsuba smoke test, kernel compile) before the clock starts. Then
``--rounds`` rounds are timed, each rendering the same stimuli (pass 1 of ``render_set``: EXRs)
once on each set-up, the order alternating from round to round (interleaved, so load from other
jobs hits both). Printed: images per hour of each and their ratio.

Both set-ups share the same cores (each worker's Dr.Jit threads use all of them); the ratio says
what a second worker on the *same* machine gains. Measured on the shared 2-core development
machine (load average 8-12 from other jobs): 1.24x (64 px, 16 spp, 2 rounds), 1.63x (64 px, 4
rounds), 1.74x (128 px, 2 rounds). Two causes are not told apart there: a worker renders one
group at a time and its single-threaded parts (tracing the render, building the scene, writing
and hashing the EXR) leave cores idle that a second worker fills; and under load, two processes
with twice the threads take a larger share of the CPU from the other jobs. Re-run it on an idle
machine before starting two workers per machine; more machines, one worker each, is what the plan
``stimuli render`` prints assumes. Absolute figures are only indicative on a shared machine.

Usage: ``.venv/bin/python bench/stimuli_external_workers.py [--size 64] [--spp 16] [--rounds 2]``
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
from tests.dask_processes import dask_processes


def _warm(job, row, folder):
    render_group(job, [row], folder)
    return os.getpid()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--depth-levels", type=int, default=4,
                    help="arrays rendered per round (9 gloss levels each; one Dask task each)")
    args = ap.parse_args()
    from distributed import Client

    variant = setup_mitsuba()
    design = load_design()
    cal = default_calibration(design)
    depths = [str(d) for d in design.depth.rendered_levels[:args.depth_levels]]
    table = apply_filters(stimulus_set(design, "experiment"),
                          {"illumination": [design.illuminations[0].name], "depth_level": depths})
    job = RenderJob(camera=camera_geometry(design, cal), size_px=args.size, spp=args.spp,
                    variant=variant, design_path=str(design.source),
                    llvm_path=os.environ.get("DRJIT_LIBLLVM_PATH", ""))
    names = ["1 worker", "2 workers"]
    elapsed = dict.fromkeys(names, 0.0)
    with tempfile.TemporaryDirectory() as tmp, \
            dask_processes(Path(tmp) / "one") as one, dask_processes(Path(tmp) / "two") as two:
        for procs, n in ((one, 1), (two, 2)):
            for _ in range(n):
                procs.start_worker(nthreads=2)
            procs.wait_workers(n)
        clients = {"1 worker": Client(one.address), "2 workers": Client(two.address)}
        try:
            row = dict(table.iloc[0]) | {"rho_d": 0.3, "rho_s": 0.05, "alpha": 0.1,
                                         "exr_path": "exr/warm.exr"}
            for client in clients.values():
                client.run(_warm, job, row, tmp)
            for rnd in range(args.rounds):
                for name in (names if rnd % 2 == 0 else names[::-1]):
                    summary = render_set(table, Path(tmp) / f"r{rnd}_{name[0]}", job=job,
                                         gloss_table=default_gloss_table(), calibration=cal,
                                         tonemap_spec=design.tonemap, client=clients[name],
                                         progress=False, workers={"plan": False})
                    elapsed[name] += summary["render_s"]
                print(f"round {rnd}: " + ", ".join(f"{n} {elapsed[n]:.1f} s" for n in names)
                      + f" (cumulative), load average {os.getloadavg()[0]:.1f}", flush=True)
        finally:
            for client in clients.values():
                client.close()
    n_images = len(table) * args.rounds
    per_hour = {name: 3600 * n_images / t for name, t in elapsed.items()}
    print(f"variant {variant}, {len(table)} images ({len(depths)} arrays x 9 gloss levels) x "
          f"{args.rounds} rounds per set-up, {args.size} px, {args.spp} spp, "
          f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}")
    for name in names:
        print(f"{name:>10} (dask worker --nthreads 2 each): {elapsed[name]:7.2f} s, "
              f"{per_hour[name]:7.0f} images/hour")
    ratio = per_hour["2 workers"] / per_hour["1 worker"]
    print(f"2 workers / 1 worker on this machine: {ratio:.2f}x (same cores; on a machine other "
          "jobs share, two processes also take a larger share of its CPU from them)")


if __name__ == "__main__":
    main()
