"""Claim (issue 29, verdicts of issue 43): a clean display is not a gap (``no_gap_that_matters`` or
``inconclusive``) in >= 95 % of seeds.

Four clean set-ups of the display layer, ``--n`` seeds each (issue 29's "hidden clean display"):

- ``none``, ``refit_clean``, ``floor_zeros``: the harder display benchmark's clean cases on the
  independent GOG display (:mod:`analysis.gapbench.bench_display`; calibration seeds
  ``--start + s``, s < n);
- ``blind none``: the default benchmark's simulated CRT (``calibration.SimulatedCRT`` via
  :mod:`analysis.gapbench.inject`), its calibration fitted from noisy repeats, checked
  against a separate run (seeds ``--start + 1000 + s``, diagnosis seed s).

Printed: per set-up the count of ``no_gap_that_matters`` / ``inconclusive`` verdicts (not a gap) and the verdicts met, then the
total and the rate. Usage::

    python bench/display_clean_rate.py --n 25 --start 1000
"""

from __future__ import annotations

import argparse
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from analysis.gap import NOT_A_GAP, diagnose
from analysis.gapbench import bench_display, inject

_NO_GAP = NOT_A_GAP


def _blind(seed: int, diag_seed: int, n_boot: int) -> str:
    with tempfile.TemporaryDirectory() as tmp:
        tmp, rng = Path(tmp), np.random.default_rng(seed)
        inject.write_calibration(rng, tmp / "sim")
        inject.write_readings(inject.simulate_readings(rng), tmp / "real")
        return diagnose("display", tmp / "real", tmp / "sim", None, seed=diag_seed,
                        n_boot=n_boot)[0].verdict


def _verdict(run, seed: int) -> str:
    """The verdict, or the error a diagnosis raised (counted as a miss)."""
    try:
        return run(seed)
    except Exception as exc:  # noqa: BLE001 - a crash is a miss, reported by its type
        return f"error {type(exc).__name__}: {exc}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    ap.add_argument("--n", type=int, default=20, help="seeds per set-up")
    ap.add_argument("--start", type=int, default=1000, help="first seed")
    ap.add_argument("--n-boot", type=int, default=300)
    ap.add_argument("--skip", nargs="*", default=[], help="set-ups to leave out, by name")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    t0, total, hits = time.perf_counter(), 0, 0
    setups = {case: (lambda s, c=case: bench_display._run_case(
        c, np.random.default_rng(s), args.n_boot, 1)["verdict"])
        for case in ("none", "refit_clean", "floor_zeros")}
    setups["blind none (SimulatedCRT)"] = lambda s: _blind(1000 + s, s - args.start,
                                                             args.n_boot)
    for name, run in ((k, f) for k, f in setups.items() if k not in args.skip):
        seeds = range(args.start, args.start + args.n)
        v = [_verdict(run, s) for s in seeds]
        ok = sum(x in _NO_GAP for x in v)
        misses = {s: x for s, x in zip(seeds, v) if x not in _NO_GAP}
        print(f"{name}: {ok} / {args.n}; misses {misses}", flush=True)
        total, hits = total + args.n, hits + ok
    print(f"clean display -> not a gap (no_gap_that_matters or inconclusive): {hits} / {total} = {100 * hits / total:.1f} % "
          f"(seeds {args.start}-{args.start + args.n - 1}; {time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
