"""The observer layer in its own units (issue 38): the misfit in slider units and the study's
units (gloss %, depth cm; a rating study's scale) before, after and for the flexible model,
in diagnosis.json and the words; the design's practical tolerance ([gap]
observer_tolerance_slider), under which a significant remainder is no gap that matters."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from analysis.gap import diagnose
from analysis.gap.observer import base_from_params, to_slider_units
from analysis.gap.report import write_report
from analysis.gapbench import inject
from experiment import load_observer_params
from studydesign import DesignError, load_design

DESIGN = load_design()
IDEAL = base_from_params(load_observer_params()["ideal"], "ideal", DESIGN.slider)


def _precise(seed: int, bias: float, noise: float = 0.1):
    """Session rows of 4 observers whose settings are the truth plus ``noise`` (slider units,
    a far more precise observer than a human) and a gloss bias of +-``bias`` slider units
    alternating between stimuli (outside the catalogue)."""
    rng = np.random.default_rng(seed)
    frame = inject.simulate_sessions(DESIGN, 4, rng)
    gu, du = to_slider_units(DESIGN.slider, frame["true_gloss_pct"], frame["true_depth_cm"])
    sign = np.where((frame["gloss_level"] * 7 + frame["depth_level"] * 3) % 2 == 1, 1.0, -1.0)
    frame["gloss_match"] = np.clip(gu + bias * sign + noise * rng.standard_normal(len(frame)),
                                   DESIGN.slider.min, DESIGN.slider.max)
    frame["depth_match"] = np.clip(du + noise * rng.standard_normal(len(frame)),
                                   DESIGN.slider.min, DESIGN.slider.max)
    return frame


def test_shipped_observer_tolerance_is_a_quarter_slider_unit():
    assert DESIGN.gap.observer_tolerance_slider == 0.25


@pytest.mark.parametrize("value", [0, -0.1, 2.5])
def test_observer_tolerance_outside_its_range_is_refused_with_the_range(value):
    with pytest.raises(DesignError, match=r"gap\.observer_tolerance_slider must lie in \(0, 2\]"):
        replace(DESIGN.gap, observer_tolerance_slider=value)


def test_misfit_is_in_slider_units_and_the_studys_units_before_and_after(tmp_path):
    """Central tendency injected (30 % of the way to the middle): the plain simulation's
    settings lie about 0.3 x the spread of the truth (2.6 slider units) from the data's, the
    chosen model's next to nothing; gloss in % (10 per slider unit) and depth in cm (0.4)."""
    rng = np.random.default_rng(3)
    real = inject.simulate_sessions(DESIGN, 4, rng, "central_tendency", 0.3)
    diag, local = diagnose("observer", real, IDEAL, DESIGN, seed=3, n_boot=300)
    assert [s["added"] for s in diag.steps] == ["central_tendency"]
    assert diag.misfit_unit == "slider units"
    assert 0.7 < diag.misfit_before < 1.6
    assert diag.misfit_after < 0.15 < diag.misfit_before
    by = diag.misfit_by_response
    assert by["gloss"]["unit"] == "%" and by["depth"]["unit"] == "cm"
    for r, per in (("gloss", 10.0), ("depth", 0.4)):
        for k in ("before", "after", "ceiling"):
            assert by[r][k] == pytest.approx(per * by[r][f"{k}_slider"])
    # Both responses together: the distance in the (gloss, depth) plane.
    assert diag.misfit_before == pytest.approx(np.hypot(by["gloss"]["before_slider"],
                                                        by["depth"]["before_slider"]))
    # The ideal observer's noise (8 % gloss, 0.3 cm depth): what no model of the mean removes.
    assert by["gloss"]["ceiling"] == pytest.approx(8.0, rel=0.2)
    assert by["depth"]["ceiling"] == pytest.approx(0.3, rel=0.2)
    assert (f"{diag.misfit_before:.2g} slider units (gloss {by['gloss']['before']:.2g} %, "
            f"depth {by['depth']['before']:.2g} cm) before -> {diag.misfit_after:.2g}") in (
        diag.summary)
    # Nats stay beside the units in the record.
    assert diag.remaining["size"] == pytest.approx(diag.misfit_after)
    assert diag.remaining["size_unit"] == "slider units" and np.isfinite(diag.gap_before)
    path = write_report(diag, local, tmp_path / "rep")
    saved = json.loads((path.parent / "diagnosis.json").read_text())
    assert saved["misfit_before"] == pytest.approx(diag.misfit_before)
    assert saved["misfit_unit"] == "slider units"
    assert saved["misfit_by_response"]["depth"]["after"] == pytest.approx(by["depth"]["after"])
    page = path.read_text()
    assert page.index("slider units") < page.index("Chosen effects")


def test_a_significant_remainder_under_the_tolerance_is_no_gap_that_matters():
    """Precise observers (noise 0.1 slider units) with a stimulus bias of +-0.1 slider units:
    far beyond the nats' tolerance (about 0.5 nats per trial) but a tenth of a slider unit. It
    is reported with its size and place and not counted; held to a tolerance of 0.05 slider
    units, the same remainder is a gap."""
    frame = _precise(21, bias=0.1)
    diag, _ = diagnose("observer", frame, IDEAL, DESIGN, seed=1, n_boot=300)
    rem = diag.remaining
    assert rem["gap"] > 0.1 and rem["p"] < 0.01
    assert rem["within_tolerance"] and not rem["significant"]
    assert rem["size"] == pytest.approx(0.1, abs=0.04)
    assert rem["tolerance"] == 0.25 and rem["size_unit"] == "slider units"
    assert not diag.unexplained_remains and not diag.steps
    assert diag.verdict == "no_gap_that_matters"
    assert diag.misfit_upper < diag.tolerance
    assert "within the tolerance" in diag.summary
    assert "below the tolerance of 0.25 slider units" in diag.summary
    assert "gloss response" in rem["where"] and rem["where"] in diag.summary
    strict = replace(DESIGN, gap=replace(DESIGN.gap, observer_tolerance_slider=0.05))
    diag, _ = diagnose("observer", frame, IDEAL, strict, seed=1, n_boot=300)
    assert diag.remaining["significant"] and diag.unexplained_remains
