"""Claim: our power simulation runs >= 20x more simulated studies per second than the loop
simr's powerSim runs in R (lme4 ``simulate`` on the planned layout, ``refit``,
``car::Anova(type = 2)``), at equal work, with the same power.

Both simulate from the same fitted model: the source study's gloss model fitted to the demo's
pilot (4 humanlike observers, seed 2), with the gloss x depth interaction at a quarter of its
fitted size, planned studies of ``--n`` new participants x 162 trials; each simulated study is
simulated, refitted and its three terms tested (R: ``analysis/r/power_sim.R``; its time covers
simulate, the refits and the tests, not R's start-up or the pilot's fit). One process each
(R's loop is serial, and so is ours without --workers). The power of the interaction is
printed beside each, with its Monte-Carlo SE.

Usage: ``.venv/bin/python bench/analysis_power_vs_simr.py [--n 12] [--sims 2000] [--sims-r 100]``
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from analysis.lmm import fit
from analysis.models import SOURCE_STUDY_RHS
from analysis.montecarlo import decision_rates
from analysis.power import Effect, ModelDraws, layout_frame, scaled_fixef
from studydesign import load_design
from tests.analysis.powerdata import pilot_frame

TERMS = ["gloss", "depth", "gloss:depth"]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=12, help="participants of the planned study")
    ap.add_argument("--sims", type=int, default=2000, help="our simulated studies")
    ap.add_argument("--sims-r", type=int, default=100, help="R's simulated studies")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    design = load_design()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        frame = pilot_frame(tmp / "pilot", design)
        gfit = fit(f"gloss_match_pct ~ {SOURCE_STUDY_RHS}", frame)
        beta = scaled_fixef(gfit, [Effect("gloss:depth", scale=0.25)], design)
        lay = layout_frame(design, args.n)
        frame[["participant", "gloss", "depth", "gloss_match_pct"]].to_csv(
            tmp / "pilot.csv", index=False, float_format="%.17g")
        lay[["participant", "gloss", "depth"]].to_csv(tmp / "layout.csv", index=False,
                                                      float_format="%.17g")
        np.savetxt(tmp / "beta.csv", beta, fmt="%.17g")
        t0 = time.perf_counter()
        ours = decision_rates(ModelDraws(gfit, lay, beta, TERMS), args.sims, columns=3,
                              seed=args.seed)
        our_s = time.perf_counter() - t0
        subprocess.run(
            ["Rscript", str(ROOT / "analysis/r/power_sim.R"), f"data={tmp / 'pilot.csv'}",
             f"formula={gfit.formula}", f"beta={tmp / 'beta.csv'}",
             f"layouts={tmp / 'layout.csv'}", f"terms={','.join(TERMS)}",
             f"nsim={args.sims_r}", f"seed={args.seed}", "alpha=0.05",
             f"out={tmp / 'r.csv'}"], check=True, capture_output=True, text=True)
        r = pd.read_csv(tmp / "r.csv")
    r_s = float(r["seconds"].iloc[0])
    ours_rate, r_rate = args.sims / our_s, args.sims_r / r_s
    print(f"planned study: {args.n} participants x {len(lay) // args.n} trials; gloss model, "
          "interaction at 0.25x the pilot's; 1 process each")
    print(f"{'':28}{'ours':>12}{'R (simr loop)':>16}")
    print(f"{'simulated studies':28}{args.sims:>12d}{args.sims_r:>16d}")
    print(f"{'seconds':28}{our_s:>12.1f}{r_s:>16.1f}")
    print(f"{'studies per second':28}{ours_rate:>12.1f}{r_rate:>16.2f}")
    for k, term in enumerate(TERMS):
        p_r = r["hits"].iloc[k] / args.sims_r
        se = np.sqrt(p_r * (1 - p_r) / args.sims_r)
        print(f"{'power ' + term:28}{ours[k].rate:>12.3f}{p_r:>10.3f} ± {se:.3f}")
    print(f"ratio (ours / R, studies per second): {ours_rate / r_rate:.1f}x (target >= 20x)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
