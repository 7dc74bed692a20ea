"""The display layer in the lab's units (issue 38): how far in % of luminance, a practical
tolerance ("no gap that matters"), the meter's floor for a zero, and a second pass of the same
display.

The display here is written apart from the diagnosis, from issue 38's description: an offset
plus a power law, a centre-bright gain falling with the square of the distance from the centre,
17 levels x 3 x 3 positions x 2 repeats back to back, a meter with 0.4 % + 0.01 cd/m^2 noise
and four significant digits. The calibration is fitted from another run of the same display by
``python -m calibration fit`` as a lab runs it (the default 8-bit DAC grid).
"""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from analysis.gap import NO_GAP_THAT_MATTERS, NOT_A_GAP, diagnose

DATA = Path(__file__).resolve().parents[2] / "data" / "displays"
_T0 = datetime(2026, 3, 2, 9, 0, tzinfo=UTC)


def _run(seed, *, start_min=0.0, gain=1.0, rel=0.004, absolute=0.01, levels=17):
    """One run of the display: readings as a lab's file (cd/m^2, 2 s per reading)."""
    rng = np.random.default_rng(seed)
    rows, t = [], 0.0
    for x in (-0.6, 0.0, 0.6):
        for y in (-0.6, 0.0, 0.6):
            for v in np.linspace(0, 1, levels):
                for r in range(2):
                    light = 0.4 + gain * 110.0 * (1 - 0.075 * (x * x + y * y) / 0.36) * v**2.2
                    read = light + rng.normal(0, np.hypot(rel * light, absolute))
                    stamp = _T0 + timedelta(minutes=start_min, seconds=t)
                    rows.append({"x_norm": x, "y_norm": y, "level": v, "repeat": r,
                                 "luminance_cd_m2": float(f"{read:.4g}"),
                                 "timestamp_utc": stamp.strftime("%Y-%m-%dT%H:%M:%S.%fZ")})
                    t += 2.0
    return pd.DataFrame(rows)


def _cli(*args):
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True,
                          check=True)


def _lab(tmp_path, seed, **check):
    """Calibrate from one run (``python -m calibration fit``), measure another 30 min later."""
    _run(2 * seed).to_csv(tmp_path / "cal.csv", index=False)
    _run(2 * seed + 1, start_min=30, **check).to_csv(tmp_path / "check.csv", index=False)
    _cli("calibration", "fit", str(tmp_path / "cal.csv"), "--out", str(tmp_path / "CAL"))
    return tmp_path / "check.csv", tmp_path / "CAL"


def test_a_clean_display_checked_against_its_calibration_is_no_gap_in_percent(tmp_path):
    """Issue 38 item 3: was "the noise floor is mis-estimated" (held-out loss 0.1-0.2 nats per
    reading below the floor, verdict unexplained): the calibration, fitted on the 8-bit DAC grid
    that the display's levels fall between, missed its own readings, and that misfit was added
    to every reading's SD although the diagnosis predicts at the levels as given, where the model
    fits. The verdict line, diagnosis.json and the report's first lines give the misfit in % of
    luminance (about the meter's 0.4 %) beside the nats."""
    check, cal = _lab(tmp_path, 0)
    out = _cli("analysis", "gap", "diagnose", "--layer", "display", "--real", str(check),
               "--sim", str(cal), "--out", str(tmp_path / "R")).stdout
    d = json.loads((tmp_path / "R" / "diagnosis.json").read_text())
    assert d["floor_status"] == "ok" and d["verdict"] == NO_GAP_THAT_MATTERS, out
    assert 0.3 < d["misfit_pct_before"] < 0.6 and 0.3 < d["misfit_pct_after"] < 0.6
    m = d["misfit"]
    assert 0.3 < m["ceiling_pct"] < 0.6 and m["systematic_pct_before"] < 0.3
    assert 0.005 < m["black_cd_m2_before"] < 0.03  # the meter's 0.01 cd/m^2 near black
    line = next(v for v in out.splitlines() if v.startswith("display: verdict"))
    assert "% of luminance" in line and line.index("%") < line.index("nats")
    html = (tmp_path / "R" / "index.html").read_text()
    lead = html[html.index('class="verdict"'):][:1500]
    assert "RMS misfit" in lead and "% of luminance" in lead


def test_a_gain_change_smaller_than_the_tolerance_is_no_gap_that_matters(tmp_path):
    """The check's white 0.6 % brighter, read by a precise meter (0.05 % repeats): significant
    (was: gain_change, hundreds of nats per reading on precise meters), but below the design's
    1 % tolerance: no gap that matters, with its size in % and the effect named."""
    _run(0, rel=0.0005, absolute=0.002).to_csv(tmp_path / "cal.csv", index=False)
    _run(1, start_min=30, gain=1.006, rel=0.0005,
         absolute=0.002).to_csv(tmp_path / "check.csv", index=False)
    _cli("calibration", "fit", str(tmp_path / "cal.csv"), "--out", str(tmp_path / "CAL"),
         "--dac-bits", "none")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        diag = diagnose("display", tmp_path / "check.csv", tmp_path / "CAL", None, seed=0,
                        n_boot=300)[0]
    assert diag.verdict == NO_GAP_THAT_MATTERS, diag.summary
    assert diag.summary.startswith("No gap that matters")
    assert "so a misfit of the tolerance, 1 %" in diag.summary and "is excluded" in diag.summary
    assert diag.misfit_upper < 1.0 <= diag.tolerance
    assert 0.3 < diag.remaining["size_before"] < 1.0
    assert 0.4 < diag.misfit_pct_before < 1.0


def test_a_zero_never_censors_the_reading_above_it(tmp_path):
    """The Dell LCD's black reads exactly 0 and its next level 1.08 cd/m^2: the zero is
    censored (its meter's floor is not documented here: at most the lowest positive reading),
    and the 1.08 reading is a reading, not censored because a zero sits below it (was: both
    censored); the floor positive readings are held to is the noise model's, under 1 cd/m^2."""
    from test_display_real import _calibrate, _lcd, _meter

    rng = np.random.default_rng(0)
    lcd = _lcd()
    cal = _calibrate(lcd.assign(luminance_cd_m2=_meter(lcd["luminance_cd_m2"], rng)),
                     tmp_path / "cal")
    check = tmp_path / "check.csv"
    lcd.assign(luminance_cd_m2=_meter(lcd["luminance_cd_m2"], rng)).to_csv(check, index=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        diag = diagnose("display", check, cal, None, seed=0, n_boot=200)[0]
    info = diag.loss_info
    assert info["censored_readings"] == 1
    assert info["floor_cd_m2"] < 1.0 and "lowest positive" in info["zero_floor_source"]
    assert diag.verdict in NOT_A_GAP, diag.summary


@pytest.mark.parametrize("device, floor", [("ls100", 0.001), ("PR-670", None)])
def test_a_zeros_floor_is_the_meters_documented_one_where_known(device, floor):
    from analysis.gap.display.null.noise import zero_floor

    value, source = zero_floor(device, {"floor_cd_m2": 0.02}, 12.5)
    assert value == (floor if floor is not None else 12.5)
    assert ("documented lowest luminance" in source) == (floor is not None)


def test_no_gap_that_matters_is_the_engines_verdict_for_any_layer():
    """The engine's verdict, layer-agnostic: nothing chosen and the misfit's upper bound below
    the tolerance (the render layer's path too), or chosen effects whose plain simulation's
    misfit is bounded below it; a bound above the tolerance is inconclusive, never no gap."""
    from analysis.gap.engine.steps import verdict_of

    rem = {"significant": False, "size": 0.3, "size_upper": 0.7, "tolerance": 1.0}
    assert verdict_of([], float("nan"), 0.8, remaining=rem) == NO_GAP_THAT_MATTERS
    assert verdict_of([], float("nan"), 0.8, remaining=rem | {"size_upper": 1.2}) \
        == "inconclusive"
    steps = [{"added": "gain_change"}]
    held = rem | {"size_before": 0.6, "size_before_upper": 0.9}
    assert verdict_of(steps, 1.0, 0.8, remaining=held, tolerate_chosen=True) \
        == NO_GAP_THAT_MATTERS
    assert verdict_of(steps, 1.0, 0.8, remaining=held, tolerate_chosen=True,
                      floor_status="misestimated") == "gain_change"
    assert verdict_of(steps, 1.0, 0.8, remaining=held) == "gain_change"
