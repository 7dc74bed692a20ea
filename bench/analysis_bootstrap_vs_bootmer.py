"""Claim: our parametric bootstrap is >= 20x faster per refit than lme4's bootMer on the source
study's model and >= 10x on the crossed participant x stimulus model, with the same CIs.

Both bootstrap the same models, fitted by ML to the same simulated data (11 participants x 162
stimuli, the source study's design, with per-participant intercepts and slopes and
per-stimulus intercepts):

- source:  ``y ~ gloss * depth + (1 + gloss + depth | participant)``
- crossed: ``y ~ gloss * depth + (1 + gloss + depth | participant) + (1 | stimulus_id)``

on the same cores: ours with joblib, bootMer with ``parallel = "multicore"``. Each refit
computes the same things on both sides: fixed effects, random-effect SDs, sigma and the Type II
Wald chi-squares (``car::Anova`` in R); bootMer minimises with BOBYQA from the original theta,
ours the source model with SLSQP and the deviance's analytic gradient (the crossed model with
BOBYQA), reaching bootMer's optimum or a better one (`analysis.bootstrap.refit`;
tests/analysis/test_lmm.py). bootMer runs a subset of the runs; the time per refit is
compared (R's start-up and the original fit are not timed, nor is the start of our worker
processes). Percentile 95 % CIs of the fixed
effects are printed side by side with the Monte-Carlo standard error of a 2.5 % quantile from
R's smaller run.

Usage: ``.venv/bin/python bench/analysis_bootstrap_vs_bootmer.py [--n 10000] [--n-r 200]
[--model source crossed]``
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from analysis.bootstrap import BLOCK, parametric_bootstrap
from analysis.lmm import fit, standardise_predictors
from analysis.typeii import type2_wald
from studydesign import load_design

MODELS = {
    "source": ("y ~ gloss * depth + (1 + gloss + depth | participant)", 20.0),
    "crossed": ("y ~ gloss * depth + (1 + gloss + depth | participant) + (1 | stimulus_id)",
                10.0),
}


def simulate(design, rng: np.random.Generator, n_participants: int = 11) -> pd.DataFrame:
    """Gloss-like responses (%): correlated participant intercepts and slopes, stimulus
    intercepts (SD 3 %), residual SD 12 %."""
    stim = standardise_predictors(design.stimuli(), design)
    sds = np.array([5.0, 4.0, 2.0])
    cor = np.array([[1.0, 0.3, 0.0], [0.3, 1.0, 0.2], [0.0, 0.2, 1.0]])
    stim_effect = rng.normal(0.0, 3.0, len(stim))
    rows = []
    for k in range(n_participants):
        b = rng.multivariate_normal(np.zeros(3), cor * np.outer(sds, sds))
        g, d = stim["gloss"].to_numpy(), stim["depth"].to_numpy()
        y = (50 + b[0] + (25 + b[1]) * g + (6 + b[2]) * d + 3 * g * d + stim_effect
             + rng.normal(0, 12, g.size))
        rows.append(pd.DataFrame({"participant": f"P{k + 1:02d}",
                                  "stimulus_id": stim["stimulus_id"], "gloss": g, "depth": d,
                                  "y": y}))
    return pd.concat(rows, ignore_index=True)


def compare(name: str, frame: pd.DataFrame, args) -> None:
    formula, target = MODELS[name]
    result = fit(formula, frame)
    observed = {w.term: w.chi2 for w in type2_wald(result)}
    # Start the worker processes (Python, numpy, the analysis package: seconds on a loaded
    # machine) before timing, as R's start-up and package loading are not timed either; joblib
    # reuses the same workers for the timed run.
    parametric_bootstrap(frame, result, observed_chi2=observed, n_boot=BLOCK * args.cores,
                         seed=args.seed + 1, n_jobs=args.cores, progress=False)
    ours = parametric_bootstrap(frame, result, observed_chi2=observed, n_boot=args.n,
                                seed=args.seed, n_jobs=args.cores, progress=False)
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "data.csv"
        frame.to_csv(data, index=False, float_format="%.17g")
        proc = subprocess.run(
            ["Rscript", str(ROOT / "analysis/r/bootmer.R"), str(data), str(args.n_r),
             str(args.cores), str(args.seed), str(Path(tmp) / "boot.csv"), formula],
            capture_output=True, text=True, check=True,
        )
        r_samples = pd.read_csv(Path(tmp) / "boot.csv").to_numpy()
    r_per_refit = float(proc.stdout.split("seconds_per_refit")[1].split()[0])
    our_per_refit = ours.seconds / ours.n_boot
    print(f"\n== {name}: {formula}")
    print(f"ours:    {ours.n_boot} refits in {ours.seconds:.1f} s = "
          f"{1e3 * our_per_refit:.2f} ms per refit ({ours.n_ok} ok, "
          f"{100 * ours.singular_fraction:.1f} % singular)")
    print(f"bootMer: {args.n_r} refits, {1e3 * r_per_refit:.2f} ms per refit "
          f"(10,000 would take {r_per_refit * 1e4 / 60:.1f} min)")
    print(f"ratio (bootMer / ours, per refit): {r_per_refit / our_per_refit:.1f}x  "
          f"(target >= {target:g}x)")
    print("95 % percentile CIs of the fixed effects (z: difference of each limit in units of "
          "the Monte-Carlo s.e. of bootMer's smaller run; |z| < 2-3 = same up to MC error):")
    print(f"{'term':<12} {'ours (n=' + str(ours.n_boot) + ')':>24} "
          f"{'bootMer (n=' + str(args.n_r) + ')':>24} {'MC s.e.':>8} {'z lo':>6} {'z hi':>6}")
    for i, t in enumerate(result.fixef):
        lo, hi = ours.fixef_ci[t]
        rlo, rhi = np.percentile(r_samples[:, i], [2.5, 97.5])
        # Monte-Carlo s.e. of a 2.5 % quantile: sqrt(p (1 - p) / n) / density (normal approx.).
        sd = np.std(r_samples[:, i], ddof=1)
        density = np.exp(-0.5 * 1.96**2) / np.sqrt(2 * np.pi) / sd
        mc = np.sqrt(0.025 * 0.975 / args.n_r) / density
        print(f"{t:<12} [{lo:9.3f}, {hi:9.3f}] [{rlo:9.3f}, {rhi:9.3f}] {mc:8.3f} "
              f"{(rlo - lo) / mc:6.1f} {(rhi - hi) / mc:6.1f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10_000, help="our bootstrap runs")
    ap.add_argument("--n-r", type=int, default=200, help="bootMer runs (a subset)")
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--model", nargs="+", choices=list(MODELS), default=list(MODELS))
    args = ap.parse_args()
    if shutil.which("Rscript") is None:
        print("Rscript not found: install r-base-core r-cran-lme4 r-cran-car", file=sys.stderr)
        return 1
    design = load_design()
    frame = simulate(design, np.random.default_rng(args.seed))
    print(f"data: 11 participants x {design.n_stimuli} stimuli, seed {args.seed}, "
          f"{args.cores} cores")
    for name in args.model:
        compare(name, frame, args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
