"""Relating statistics to depth and perceived gloss: recovery of a planted depth cue, the
image-statistics observer, and the report (`python -m analysis imagestats relate`)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from analysis.imagestats import (
    ImageStatsObserver,
    depth_effects,
    gloss_regression,
    join_perception,
    load_stats,
    stat_table,
)
from analysis.imagestats.__main__ import main
from analysis.imagestats.store import consolidate, start, write_part
from analysis.load import load_sessions
from tests.analysis.sessions import write_sessions

META = {"config": {"test": True}}


def _write_table(path, design, rng, *, n_images_per_cell: int = 2):
    """A statistics table of the design's stimuli in which highlight coverage and RMS contrast
    rise with depth at fixed gloss and kurtosis does not depend on depth at all."""
    rows = []
    mid = float(np.mean(design.depth.rendered_cm))
    for stim in design.stimuli().itertuples(index=False):
        for k in range(n_images_per_cell):
            g, d = stim.true_gloss_pct, stim.true_depth_cm
            cue = g + 8.0 * (d - mid)  # what the humanlike observer reports
            row = stim._asdict() | {"stimulus_id": f"{stim.stimulus_id}_a{k}",
                                    "exr_sha256": "x"}
            row |= {
                "mean_luminance": 1.0 + 0.002 * g + rng.normal(0, 0.01),
                "rms_contrast": 0.3 + 0.05 * d + rng.normal(0, 0.01),
                "skewness": 0.5 + 0.01 * g + rng.normal(0, 0.05),
                "kurtosis": 3.0 + 0.02 * g + rng.normal(0, 0.1),
                "highlight_coverage": 0.002 * cue + 0.05 + rng.normal(0, 0.003),
            }
            row |= {f"ps_x_{j}": rng.normal() + (0.1 * d if j < 3 else 0.0) for j in range(12)}
            rows.append(row)
    start(path, META)
    write_part(path, rows)
    consolidate(path, META, ["stimulus_id"])
    return load_stats(path)


def test_depth_effects_find_the_planted_cues_only(tmp_path, design, rng):
    stats = _write_table(tmp_path / "s.parquet", design, rng)
    frame, names = stat_table(stats, n_ps_components=2)
    assert names[-2:] == ["ps_pc1", "ps_pc2"]
    effects, per_cell = depth_effects(frame, names)
    by = {e.statistic: e for e in effects}
    assert by["highlight_coverage"].ci_low > 0 and by["highlight_coverage"].p_holm < 1e-6
    assert by["rms_contrast"].slope_per_cm == pytest.approx(0.05, rel=0.1)
    assert by["highlight_coverage"].slope_per_cm == pytest.approx(0.016, rel=0.1)
    for flat in ("kurtosis", "skewness", "mean_luminance"):
        assert by[flat].ci_low < 0 < by[flat].ci_high or by[flat].p_holm > 0.05, flat
    assert set(per_cell["statistic"]) == set(names)
    assert len(per_cell) == len(names) * 2 * 9


def test_regression_and_observer_recover_a_cue_observer(tmp_path, design, rng):
    stats = _write_table(tmp_path / "s.parquet", design, rng)
    write_sessions(tmp_path / "data", design, rng, n_participants=4, kind="humanlike")
    trials = load_sessions(tmp_path / "data", design).frame
    frame, names = stat_table(stats, n_ps_components=0)
    joined, how, missing = join_perception(frame, names, trials)
    assert how == "cell" and missing == []  # the table's ids carry an array suffix
    reg = gloss_regression(joined, names, n_boot=50, rng=rng)
    assert reg["depth_effect"]["ci_low"] > 0  # humanlike: deeper looks glossier
    share = {r["statistic"]: r["depth_share"] for r in reg["per_statistic"]}
    # highlight coverage was planted as the observers' cue; kurtosis ignores depth
    assert share["highlight_coverage"]["estimate"] == pytest.approx(1.0, abs=0.15)
    assert share["highlight_coverage"]["ci_low"] > 0.5
    assert abs(share["kurtosis"]["estimate"]) < 0.2
    assert reg["all"]["r2"]["estimate"] >= reg["r2_gloss_only"]["estimate"]
    obs = ImageStatsObserver.fit(stats, trials)
    assert obs.loo_r2 > 0.8 and obs.n_cells == 162
    again = ImageStatsObserver.from_json(obs.to_json())
    pd.testing.assert_series_equal(again.predict(stats), obs.predict(stats))
    pred = obs.predict_trials(trials, stats)
    assert pred.shape == (len(trials),) and np.isfinite(pred).all()
    with pytest.raises(ValueError, match="lacks"):
        obs.predict(stats.drop(columns="kurtosis"))
    # a subset of the cells: the rest are named, not silently dropped
    part = frame[frame["gloss_level"].isin([2, 6, 10])]
    joined, _, missing = join_perception(part, names, trials)
    assert len(missing) == 2 * 6 * 9 and set(joined["gloss_level"]) == {2, 6, 10}
    with pytest.raises(ValueError, match="no image of any"):
        join_perception(frame[frame["gloss_level"] == 11], names, trials)


def test_relate_cli_writes_a_report_and_never_overwrites_it(tmp_path, design, rng, capsys):
    _write_table(tmp_path / "s.parquet", design, rng, n_images_per_cell=1)
    write_sessions(tmp_path / "data", design, rng, n_participants=3, kind="humanlike")
    args = ["relate", str(tmp_path / "s.parquet"), "--sessions", str(tmp_path / "data"),
            "--out", str(tmp_path / "rep"), "--n-boot", "20"]
    assert main(args) == 0
    results = json.loads((tmp_path / "rep" / "results.json").read_text())
    assert results["joined_by"] == "cell"
    for name in ("index.html", "depth_effects.png", "grid_highlight_coverage.png",
                 "observer_fit.png", "observer.json", "depth_effects.csv"):
        assert (tmp_path / "rep" / name).is_file(), name
    assert main(args) == 1
    assert "exists" in capsys.readouterr().err
    assert main(["relate", str(tmp_path / "missing.parquet"), "--out",
                 str(tmp_path / "rep2")]) == 1
    assert "not found" in capsys.readouterr().err


def test_relate_without_ps_columns_uses_the_pixel_statistics(tmp_path, design, rng):
    stats = _write_table(tmp_path / "s.parquet", design, rng, n_images_per_cell=1)
    frame, names = stat_table(stats.drop(columns=[c for c in stats if c.startswith("ps_")]))
    assert names == ["mean_luminance", "rms_contrast", "skewness", "kurtosis",
                     "highlight_coverage"]
    effects, _ = depth_effects(frame, names)
    assert [e.statistic for e in effects] == names
