"""From readings to a calibration: uniformity recovery, warnings, validation, outputs."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from calibration import (
    READINGS_COLUMNS,
    SimulatedCRT,
    fit_uniformity,
    load_calibration,
)
from calibration.fit import fit_calibration, monotonicity_warnings, validation_deviation_pct
from calibration.report import report_text, write_outputs

META = {"calibration_id": "f1", "device": "pr655", "monitor_name": "crt-test",
        "resolution_px": (1024, 768), "width_cm": 32.0, "distance_cm": 55.0, "refresh_hz": 85.0}


def _readings(crt, rng, grid=(-0.6, 0.0, 0.6), n_levels=17) -> pd.DataFrame:
    levels = np.linspace(0, 1, n_levels)
    rows = []
    for x in grid:
        for y in grid:
            lv = levels if (x, y) == (0.0, 0.0) else np.linspace(0, 1, 5)
            for r in range(2):
                for level in lv:
                    rows.append({"calibration_id": "f1", "timestamp_utc": "t", "device": "pr655",
                                 "x_norm": x, "y_norm": y, "level": level, "repeat": r,
                                 "luminance_cd_m2": float(crt.luminance(level, x, y, rng=rng)),
                                 "raw_reply": "r"})
    return pd.DataFrame(rows, columns=READINGS_COLUMNS)


def test_uniformity_recovers_falloff_and_tilt(rng):
    crt = SimulatedCRT(falloff=0.2, tilt_x=0.05)
    u = fit_uniformity(_readings(crt, rng))
    rel = np.array(u.relative)
    for j, y in enumerate(u.y_norm):
        for i, x in enumerate(u.x_norm):
            want = 1 - 0.2 * (x * x + y * y) / 2 + 0.05 * x
            assert rel[j, i] == pytest.approx(want, abs=0.01)
    assert np.array(u.gain).max() == pytest.approx(1.0)
    assert u.gain_at(-0.6, 0.6) == pytest.approx(1.0, abs=0.01)  # the dimmest corner
    assert u.gain_at(0.0, 0.0) == pytest.approx(rel.min(), abs=0.01)


def test_fit_calibration_recovers_the_crt(rng):
    crt = SimulatedCRT()
    cal = fit_calibration(_readings(crt, rng), **META)
    assert cal.gamma_model == "extended_power"
    x = np.linspace(0, 1, 21)
    assert cal.luminance_for_drive(x) == pytest.approx(crt.luminance(x), rel=0.02, abs=0.1)
    assert cal.warnings == ()


def test_non_monotonic_curve_is_warned_in_the_report(rng, tmp_path):
    readings = _readings(SimulatedCRT(), rng)
    bump = (readings["level"] == 0.8125) & (readings["x_norm"] == 0) & (readings["y_norm"] == 0)
    readings.loc[bump, "luminance_cd_m2"] = 75.0  # above the next level (~ 72 cd/m^2)
    cal = fit_calibration(readings, **META)
    assert any("non-monotonic" in w and "0.812" in w for w in cal.warnings)
    paths = write_outputs(cal, readings, tmp_path)
    assert "non-monotonic" in paths["report"].read_text()
    assert load_calibration(tmp_path) == cal


def test_monotonic_noise_is_not_warned():
    levels = np.repeat(np.linspace(0, 1, 9), 2)
    lum = 0.5 + 100 * levels**2.2
    lum[0] += 0.3  # black's noise: far below 0.5 % of the range
    assert monotonicity_warnings(levels, lum) == []


def test_validation_deviation_pct(rng):
    cal = fit_calibration(_readings(SimulatedCRT(), rng), **META)
    f = np.linspace(0, 1, 5)
    span = cal.max_luminance_cd_m2 - cal.min_luminance_cd_m2
    lum = cal.min_luminance_cd_m2 + f * span
    lum[2] += 0.03 * span  # 3 % too bright at the middle
    max_dev, dev = validation_deviation_pct(
        pd.DataFrame({"target_fraction": f, "luminance_cd_m2": lum}), cal)
    assert max_dev == pytest.approx(3.0)
    assert dev[0] == pytest.approx(0.0)


def test_report_names_the_chosen_model(rng):
    readings = _readings(SimulatedCRT(), rng)
    cal = fit_calibration(readings, **META)
    text = report_text(cal, readings)
    assert "* extended_power" in text and "non-uniformity" in text
