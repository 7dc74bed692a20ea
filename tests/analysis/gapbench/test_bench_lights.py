"""The directional-light cases' scores (analysis.gapbench.bench_lights)."""

import math

import pandas as pd

from analysis.gapbench.bench_lights import score_light_cases


def test_scores_count_first_names_false_names_and_the_lobes_albedo():
    rows = pd.DataFrame([
        {"case": "lights_none", "named": "", "c": math.nan, "c_true": 0.0,
         "misfit_pct_before": 2.0, "misfit_pct_after": 2.0},
        {"case": "lights_none", "named": "clearcoat", "c": math.nan, "c_true": 0.0,
         "misfit_pct_before": 2.0, "misfit_pct_after": 1.9},
        {"case": "lights_broad", "named": "broad_lobe + vignetting", "c": 0.12, "c_true": 0.1,
         "misfit_pct_before": 4.0, "misfit_pct_after": 2.5},
        {"case": "lights_broad", "named": "clearcoat + broad_lobe", "c": 0.5, "c_true": 0.25,
         "misfit_pct_before": 5.0, "misfit_pct_after": 3.0}])
    s = score_light_cases(rows)
    assert (s["top1"], s["false_attribution"]) == (0.5, 0.5)
    assert math.isclose(s["c_error"], 0.2)  # only the case named first
    assert (s["n_broad"], s["n_none"]) == (2, 2)
