"""Claim: ``experiment.fit_observer_params`` recovers the humanlike population it was given
(means and between-observer SDs of every parameter) within its own standard errors, for the
study's 11 observers x 162 trials and more precisely for 40 observers.

Data come from ``experiment.simulate_dataset`` with the shipped ``experiment/observers.toml``
humanlike table as the truth (fixed numbers there have a between-observer SD of 0). For each
number of observers the script prints, for one replicate, true vs fitted vs error and the error in
units of the fit's own SE, and the mean and SD of the parameters the simulated observers actually
drew ("drawn": the population seen through n observers, which the fit cannot see past); then, over ``--reps`` replicates (different seeds), the bias, the RMSE,
the mean reported SE and the coverage of the interval +- t(n-1, 0.975) SE (about 0.95 if the SEs
are right; with 20 replicates a coverage is known to about +-0.05).

Usage::

    .venv/bin/python bench/experiment_observer_recovery.py [--reps 10] [--observers 11 40]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy import stats

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from experiment import (
    fit_observer_params,
    load_observer_params,
    make_observer,
    simulate_dataset,
)
from experiment.observer_fit import HUMANLIKE_PARAMS
from studydesign import load_design


def _truth(table) -> dict:
    return {k: (dict(v) if isinstance(v, dict) else {"mean": float(v), "sd": 0.0})
            for k, v in table.items()}


def _one(design, table, n: int, seed: int):
    rng = np.random.default_rng(seed)
    obs = [make_observer("humanlike", f"R{k:02d}", rng, table, design=design) for k in range(n)]
    frame = simulate_dataset(design, obs, rng)
    t0 = time.perf_counter()
    params = fit_observer_params(frame, design)
    drawn = {k: np.array([o.params[k] for o in obs]) for k in HUMANLIKE_PARAMS}
    return params, time.perf_counter() - t0, len(frame), drawn


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reps", type=int, default=10, help="replicates per size (default 10)")
    ap.add_argument("--observers", type=int, nargs="+", default=[11, 40])
    ap.add_argument("--seed", type=int, default=2026)
    args = ap.parse_args(argv)
    design = load_design()
    table = load_observer_params()["humanlike"]
    truth = _truth(table)
    for n in args.observers:
        fits, secs = [], []
        for r in range(args.reps):
            params, sec, n_trials, drawn = _one(design, table, n, seed=args.seed + 1000 * n + r)
            if r == 0:
                first_drawn = drawn
            fits.append(params)
            secs.append(sec)
        print(f"\n== {n} observers x {n_trials // n} trials: one replicate (seed "
              f"{args.seed + 1000 * n}); fit took {secs[0]:.2f} s ==")
        print(f"{'parameter':34s} {'true':>9s} {'fitted':>9s} {'error':>9s} {'SE':>8s} "
              f"{'err/SE':>7s} {'drawn':>9s}")
        first = fits[0]
        se = first["fit"]["standard_errors"]["humanlike"]
        for name in HUMANLIKE_PARAMS:
            for part in ("mean", "sd"):
                t, f, s = truth[name][part], first["humanlike"][name][part], se[name][part]
                v = first_drawn[name]
                sample = np.mean(v) if part == "mean" else np.std(v, ddof=1)
                print(f"{name + '.' + part:34s} {t:9.4g} {f:9.4g} {f - t:9.3g} {s:8.3g} "
                      f"{(f - t) / s:7.2f} {sample:9.4g}")
        print(f"\n-- {n} observers, over {args.reps} replicates (fit median "
              f"{np.median(secs):.2f} s) --")
        t_crit = stats.t.ppf(0.975, n - 1)
        print(f"{'parameter':34s} {'true':>9s} {'bias':>9s} {'RMSE':>9s} {'mean SE':>9s} "
              f"{'cover t SE':>10s}   (t = {t_crit:.2f})")
        for name in HUMANLIKE_PARAMS:
            for part in ("mean", "sd"):
                t = truth[name][part]
                est = np.array([p["humanlike"][name][part] for p in fits])
                ses = np.array([p["fit"]["standard_errors"]["humanlike"][name][part]
                                for p in fits])
                cover = np.mean(np.abs(est - t) <= t_crit * ses)
                print(f"{name + '.' + part:34s} {t:9.4g} {np.mean(est) - t:9.3g} "
                      f"{np.sqrt(np.mean((est - t) ** 2)):9.3g} {np.mean(ses):9.3g} "
                      f"{cover:10.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
