"""Display-layer gap diagnosis: identification, null, out of catalogue, CLI, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.gap import GapError, diagnose
from analysis.gap.__main__ import main
from analysis.gap.engine import catalogue, strengths
from analysis.gapbench import inject
from studydesign import load_design


def _diag(tmp_path, effect, strength, seed):
    rng = np.random.default_rng(seed)
    inject.write_calibration(rng, tmp_path / "sim")
    inject.write_readings(inject.simulate_readings(rng, effect, strength), tmp_path / "real")
    return diagnose("display", tmp_path / "real", tmp_path / "sim", load_design(), seed=seed, n_boot=300)


@pytest.mark.parametrize("effect", [c.name for c in catalogue("display")])
def test_injected_display_effect_is_identified(tmp_path, effect):
    diag, local = _diag(tmp_path, effect, strengths("display")[effect], 4)
    assert diag.verdict.split(" + ")[0] == effect
    assert diag.shrink_pct > 50
    assert {"luminance fraction", "screen position (x, y norm)"} == set(local["axis"])


def test_black_offset_recovered(tmp_path):
    diag, _ = _diag(tmp_path, "black_offset", 0.05, 6)
    assert diag.steps[0]["params"]["c"] == pytest.approx(0.05, abs=0.01)


@pytest.mark.parametrize("effect,verdict", [("none", "no_gap_that_matters"),
                                            ("gamma_change", "unexplained")])
def test_nothing_or_out_of_catalogue_is_unexplained(tmp_path, effect, verdict):
    diag, _ = _diag(tmp_path, effect, strengths("display").get(effect, 0.0), 8)
    assert diag.verdict == verdict


def test_cli_display_report(tmp_path, capsys):
    rng = np.random.default_rng(3)
    inject.write_calibration(rng, tmp_path / "cal")
    inject.write_readings(inject.simulate_readings(rng, "warmup_drift", 0.03), tmp_path / "r")
    args = ["diagnose", "--layer", "display", "--real", str(tmp_path / "r"), "--sim",
            str(tmp_path / "cal" / "calibration.json"), "--out", str(tmp_path / "rep")]
    assert main(args) == 0
    page = (tmp_path / "rep" / "index.html").read_text()
    assert "warmup_drift" in page and (tmp_path / "rep" / "localisation.png").stat().st_size
    assert "warmup_drift" in capsys.readouterr().out


def test_display_without_repeats_takes_the_noise_from_the_calibration_and_says_so(tmp_path):
    """Readings without repeats (issue 29): the photometer's noise is the one the calibration
    measured from its own repeats (was: refused, 'needs repeated readings'), named in the
    record; a clean display then shows no gap that matters."""
    rng = np.random.default_rng(1)
    inject.write_calibration(rng, tmp_path / "cal")
    inject.write_readings(inject.simulate_readings(rng, repeats=1), tmp_path / "r")
    diag, _ = diagnose("display", tmp_path / "r", tmp_path / "cal", load_design(), seed=0,
                       n_boot=200)
    assert diag.loss_info["noise_source"].startswith("the calibration's repeated readings")
    assert diag.loss_info["noise_pairs"] == 0
    assert diag.verdict == "no_gap_that_matters", diag.summary
    with pytest.raises(GapError, match="calibration.json"):
        diagnose("display", tmp_path / "r", tmp_path / "nothing", load_design(), seed=0)
