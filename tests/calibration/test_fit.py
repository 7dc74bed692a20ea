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
    load_crt,
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


# Seed 20 gives the demo's failure under the unweighted fit (eq. 1 chosen, black 0.37 cd/m^2).
@pytest.mark.parametrize("seed", [*range(8), 20])
def test_fit_reproduces_black_and_curve_of_the_shipped_crt(seed):
    # Found by the sim-to-real diagnosis: the demo's run (9 levels x 2 repeats, crt.toml) once chose eq. 1 with
    # black 0.38 cd/m^2 against 0.60 measured, because unweighted least squares let the noise at
    # white (0.3 cd/m^2 SD) outweigh the black level. Tolerances: black within 3 % (about 5 s.e.
    # of the mean of its 2 readings), drive 0.125 within 3 %, drive >= 0.25 within 0.6 % (the
    # photometer's relative noise is 0.3 % per reading; the unweighted fit erred by 1-5 %).
    crt = load_crt()
    readings = _readings(crt, np.random.default_rng(seed), n_levels=9)
    # The procedure records the drive it showed (the 8-bit grid); the CRT quantises the same way.
    readings["level"] = np.round(readings["level"] * 255) / 255
    cal = fit_calibration(readings, **META)
    assert cal.min_luminance_cd_m2 == pytest.approx(crt.black_total_cd_m2, rel=0.03)
    assert cal.luminance_for_drive(0.0) == pytest.approx(crt.luminance(0.0), rel=0.03)
    low = np.array([0.125])
    assert cal.luminance_for_drive(low) == pytest.approx(crt.luminance(low), rel=0.03)
    x = np.round(np.linspace(0.25, 1, 13) * 255) / 255
    assert cal.luminance_for_drive(x) == pytest.approx(crt.luminance(x), rel=0.006)


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


def test_a_centre_a_hair_off_zero_is_the_centre_for_every_use(rng, tmp_path):
    """Another tool may write the centre as 1e-12 or -0: read, it is the centre for the gamma
    fit, the uniformity map's grid and reference, the plots and the profile alike."""
    from calibration.readings import at_centre, read_readings

    crt = SimulatedCRT(falloff=0.2, tilt_x=0.05)
    exact = _readings(crt, rng)
    hair = exact.copy()
    centre = (hair["x_norm"] == 0) & (hair["y_norm"] == 0)
    hair["x_norm"] = hair["x_norm"].astype(object)
    hair.loc[centre, "x_norm"] = "1e-12"
    hair.loc[centre, "y_norm"] = -0.0
    hair.to_csv(tmp_path / "hair.csv", index=False)
    read = read_readings(tmp_path / "hair.csv").frame
    assert at_centre(read).sum() == centre.sum() == 34
    assert set(read["x_norm"]) == {-0.6, 0.0, 0.6}
    assert np.allclose(fit_uniformity(read).relative, fit_uniformity(exact).relative)
