"""analysis.power against the loop simr's powerSim runs in R, on the same fitted model.

``analysis/r/power_sim.R`` (run now; lme4 1.1-31, car 3.1-1 from Debian) fits the source
study's gloss model to the demo's pilot (4 humanlike observers, seed 2), simulates planned
studies of 6 and of 12 new participants with lme4's ``simulate(newdata, allow.new.levels =
TRUE, use.u = FALSE)`` from the fitted model with the gloss x depth interaction at a quarter of
its fitted size, refits each (``refit``) and tests it with ``car::Anova(type = 2)``. Ours does
the same with 2,000 simulated studies per N, R with 200 (its time: about a minute on a loaded
2-core machine). With those counts the Monte-Carlo SE of the difference is at most
sqrt(0.25/200 + 0.25/2000) = 0.037: a difference of 0.1 is 2.7 SEs, and the test allows 2.6.
"""

from __future__ import annotations

import subprocess

import numpy as np
import pandas as pd
import pytest

from analysis.lmm import fit
from analysis.models import SOURCE_STUDY_RHS
from analysis.montecarlo import decision_rates
from analysis.power import Effect, ModelDraws, layout_frame, scaled_fixef

from .lmmref import ROOT, rscript
from .powerdata import pilot_frame

pytestmark = [pytest.mark.r, pytest.mark.slow]

N_OURS, N_R = 2000, 200


def test_power_agrees_with_lme4_simulate_refit_and_car_anova_at_two_n(tmp_path, design):
    frame = pilot_frame(tmp_path / "pilot", design)
    gfit = fit(f"gloss_match_pct ~ {SOURCE_STUDY_RHS}", frame)
    beta = scaled_fixef(gfit, [Effect("gloss:depth", scale=0.25)], design)
    frame[["participant", "gloss", "depth", "gloss_match_pct"]].to_csv(
        tmp_path / "pilot.csv", index=False, float_format="%.17g")
    np.savetxt(tmp_path / "beta.csv", beta, fmt="%.17g")
    ours, layouts = {}, []
    for n in (6, 12):
        lay = layout_frame(design, n)
        path = tmp_path / f"layout{n}.csv"
        lay[["participant", "gloss", "depth"]].to_csv(path, index=False, float_format="%.17g")
        layouts.append(str(path))
        (ours[f"layout{n}.csv"],) = decision_rates(
            ModelDraws(gfit, lay, beta, ["gloss:depth"]), N_OURS, columns=1, seed=n)
    proc = subprocess.run(
        [rscript(), str(ROOT / "analysis/r/power_sim.R"), f"data={tmp_path / 'pilot.csv'}",
         f"formula={gfit.formula}", f"beta={tmp_path / 'beta.csv'}",
         f"layouts={','.join(layouts)}", "terms=gloss:depth", f"nsim={N_R}", "seed=1",
         "alpha=0.05", f"out={tmp_path / 'r.csv'}"],
        capture_output=True, text=True, timeout=600, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    r = pd.read_csv(tmp_path / "r.csv")
    rates = []
    for row in r.itertuples():
        mine = ours[row.layout]
        theirs = row.hits / row.nsim
        se = np.sqrt(theirs * (1 - theirs) / row.nsim + mine.rate * (1 - mine.rate) / mine.n)
        rates.append((mine.rate, theirs))
        print(f"{row.layout}: ours {mine.rate:.3f} ({mine.n} studies), lme4+car {theirs:.3f} "
              f"({row.nsim}), difference {mine.rate - theirs:+.3f} = "
              f"{(mine.rate - theirs) / max(se, 0.01):+.2f} SE")  # shown with pytest -rP
        assert abs(mine.rate - theirs) < 2.6 * max(se, 0.01), (row.layout, mine, theirs)
    # an informative check: power between the ends at both N, and higher at 12 than at 6
    assert 0.1 < rates[0][0] < rates[1][0] < 0.95
