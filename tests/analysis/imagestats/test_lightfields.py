"""Statistics across light fields: recovery of planted slopes within light fields and per kind,
the indoor-outdoor difference, and the report's light-field section."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from analysis.imagestats import (
    light_field_effects,
    light_field_means,
    light_field_spread,
    load_stats,
)
from analysis.imagestats.__main__ import main
from analysis.imagestats.store import consolidate, start, write_part
from stimuli import stimulus_set

META = {"config": {"test": True}}


def _frame(design, rng, *, n_per_lf: int = 4) -> pd.DataFrame:
    """Images of the 22 light fields at random gloss and depth levels. ``a`` rises 0.5 per 10 %
    gloss and 2 per cm of depth within every light field, on top of a random level per light
    field; ``b`` has no gloss or depth slope but is 3 higher outdoors."""
    rows = []
    for lf in design.imagestats.light_fields:
        offset = rng.normal(0, 2.0)
        for _ in range(n_per_lf):
            g = 10.0 * rng.integers(0, 11)
            d = 0.4 * rng.integers(1, 12)
            rows.append({"light_field": lf.name, "illumination": lf.kind,
                         "true_gloss_pct": g, "true_depth_cm": d,
                         "a": offset + 0.05 * g + 2.0 * d + rng.normal(0, 0.05),
                         "b": 3.0 * (lf.kind == "outdoor") + rng.normal(0, 0.05)})
    return pd.DataFrame(rows)


def test_slopes_within_and_per_kind_recover_the_planted_ones(design, rng):
    frame = _frame(design, rng)
    effects = light_field_effects(frame, ["a", "b"]).set_index(["statistic", "scope"])
    sd_a = frame["a"].std(ddof=0)
    within = effects.loc[("a", "within light fields")]
    assert within["gloss_slope_sd_per_10pct"] == pytest.approx(0.5 / sd_a, rel=0.03)
    assert within["depth_slope_sd_per_cm"] == pytest.approx(2.0 / sd_a, rel=0.03)
    assert within["depth_ci_low"] < 2.0 / sd_a < within["depth_ci_high"]
    assert set(effects.loc["a"].index) == {"within light fields", "indoor", "outdoor"}
    b = effects.loc["b"]
    assert (b["gloss_ci_low"] < 0).all() and (b["gloss_ci_high"] > 0).all()
    spread = light_field_spread(frame, ["a", "b"]).set_index("statistic")
    sd_b = frame["b"].std(ddof=0)
    assert spread.loc["b", "indoor_minus_outdoor_sd"] == pytest.approx(-3.0 / sd_b, rel=0.02)
    assert spread.loc["b", "welch_p"] < 1e-6 and spread.loc["b", "between_light_field_r2"] > 0.99
    means = light_field_means(frame, ["a", "b"])
    assert len(means) == 22 and means["n_images"].eq(4).all()
    assert means.groupby("kind").size().to_dict() == {"indoor": 11, "outdoor": 11}


def test_one_light_field_is_refused(design, rng):
    from analysis.imagestats import ImageStatsError

    frame = _frame(design, rng)
    with pytest.raises(ImageStatsError, match=">= 2 light fields"):
        light_field_effects(frame[frame["light_field"] == frame["light_field"].iloc[0]], ["a"])


@pytest.mark.slow
def test_relate_reports_the_statistics_across_the_22_light_fields(tmp_path, design, rng, capsys):
    """A table keyed like the imagestats_slice set (44 images, 22 light fields)."""
    rows = []
    for r in stimulus_set(design, "imagestats_slice").itertuples(index=False):
        g, d = r.true_gloss_pct, r.true_depth_cm
        rows.append(r._asdict() | {
            "exr_sha256": "x", "mean_luminance": 1.0 + rng.normal(0, 0.1),
            "rms_contrast": 0.2 + 0.004 * g + 0.05 * d + rng.normal(0, 0.01),
            "skewness": 1.0 + 0.02 * g + rng.normal(0, 0.05),
            "kurtosis": 4.0 + 0.05 * g + 0.3 * d + rng.normal(0, 0.2),
            "highlight_coverage": 0.01 + 0.001 * g + rng.normal(0, 0.001)})
    path = tmp_path / "s.parquet"
    start(path, META)
    write_part(path, rows)
    consolidate(path, META, ["stimulus_id"])
    assert load_stats(path)["light_field"].nunique() == 22
    assert main(["relate", str(path), "--out", str(tmp_path / "r"), "--n-boot", "10"]) == 0
    out = capsys.readouterr().out
    assert "light fields: 22" in out and "rms_contrast" in out
    means = pd.read_csv(tmp_path / "r" / "light_field_means.csv")
    assert len(means) == 22 and (tmp_path / "r" / "light_fields.png").stat().st_size > 0
    results = json.loads((tmp_path / "r" / "results.json").read_text())
    within = next(e for e in results["light_fields"]["effects"]
              if e["statistic"] == "rms_contrast" and e["scope"] == "within light fields")
    assert within["depth_ci_low"] > 0 and np.isfinite(within["gloss_slope_sd_per_10pct"])
    assert "Across the light fields" in (tmp_path / "r" / "index.html").read_text()
