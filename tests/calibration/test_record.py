"""The calibration record: JSON round trip, inverse gamma, default curve, bad files."""

from __future__ import annotations

import json
from datetime import UTC, datetime, timedelta

import numpy as np
import pandas as pd
import pytest

from calibration import (
    DEFAULT_CRT,
    Calibration,
    CalibrationError,
    default_calibration,
    fit_gamma_models,
    fit_uniformity,
    load_calibration,
    save_calibration,
)
from calibration.crt import SimulatedCRT


def _measured(rng) -> Calibration:
    crt = SimulatedCRT()
    levels = np.linspace(0, 1, 9)
    fits = fit_gamma_models(levels, crt.luminance(levels, rng=rng))
    rows = [{"x_norm": x, "y_norm": y, "level": lv,
             "luminance_cd_m2": float(crt.luminance(lv, x, y))}
            for x in (-0.5, 0, 0.5) for y in (-0.5, 0, 0.5) for lv in (0.0, 0.5, 1.0)]
    uni = fit_uniformity(pd.DataFrame(rows))
    best = fits[2]
    return Calibration(
        calibration_id="cal-1", created_utc="2026-11-20T10:00:00Z", device="pr655",
        monitor_name="crt", resolution_px=(800, 600), width_cm=30.0, distance_cm=50.0,
        refresh_hz=85.0, gamma_model=best.model, gamma_params=best.params,
        min_luminance_cd_m2=float(best.luminance(0.0)), max_luminance_cd_m2=float(best.luminance(1)),
        fits=fits, uniformity=uni, validation_max_deviation_pct=1.5, warnings=("w",),
        instrument={"port": "/dev/pts/3"}, readings_file="readings.csv",
    )


def test_json_round_trip(tmp_path, rng):
    cal = _measured(rng)
    path = save_calibration(cal, tmp_path / "calibration.json")
    back = load_calibration(path)
    assert back == cal
    assert load_calibration(tmp_path) == cal  # a folder means its calibration.json


def test_default_calibration_numbers(design):
    cal = default_calibration(design)
    assert cal.calibration_id == "default"
    assert cal.resolution_px == design.display.resolution_px
    assert cal.distance_cm == design.display.viewing_distance_cm
    assert cal.width_cm == DEFAULT_CRT["width_cm"]
    assert cal.luminance_for_drive(0.0) == pytest.approx(DEFAULT_CRT["black_cd_m2"])
    assert cal.luminance_for_drive(1.0) == pytest.approx(DEFAULT_CRT["white_cd_m2"])
    # Mid drive is (0.5)^2.2 of the range above black.
    assert (cal.luminance_for_drive(0.5) - 0.5) / 99.5 == pytest.approx(0.5**2.2)
    assert Calibration.from_dict(json.loads(cal.to_json())) == cal


def test_drive_for_fraction_linearises(design, rng):
    for cal in (default_calibration(design), _measured(rng)):
        f = np.linspace(0, 1, 101)
        drive = cal.drive_for_fraction(f)
        assert drive[0] == 0 and drive[-1] == 1
        assert np.all(np.diff(drive) > 0)
        lum = cal.luminance_for_drive(drive)
        frac = (lum - cal.min_luminance_cd_m2) / (cal.max_luminance_cd_m2 - cal.min_luminance_cd_m2)
        assert frac[1:] == pytest.approx(f[1:], abs=1e-9)


def test_age_days(rng):
    cal = _measured(rng)
    now = datetime(2026, 11, 22, 10, 0, tzinfo=UTC)
    assert cal.age_days(now) == pytest.approx(2.0)
    assert cal.age_days(now + timedelta(hours=12)) == pytest.approx(2.5)


@pytest.mark.parametrize(
    "content, message",
    [
        (None, "not found"),
        ("{not json", "not valid JSON"),
        ("[1, 2]", "JSON object"),
        ('{"calibration_id": "x"}', "lacks key"),
    ],
)
def test_bad_files_are_rejected(tmp_path, content, message):
    path = tmp_path / "calibration.json"
    if content is not None:
        path.write_text(content)
    with pytest.raises(CalibrationError, match=message):
        load_calibration(path)


@pytest.mark.parametrize(
    "change, message",
    [
        ({"gamma_model": "sigmoid"}, "unknown"),
        ({"refresh_hz": 0}, "refresh_hz must be a positive"),
        ({"created_utc": "yesterday"}, "ISO 8601"),
        ({"max_luminance_cd_m2": 0.0}, "must exceed"),
        ({"colour": 1}, "unknown key"),
    ],
)
def test_bad_values_are_rejected(design, change, message):
    d = default_calibration(design).to_dict()
    d.update(change)
    with pytest.raises(CalibrationError, match=message):
        Calibration.from_dict(d)


def test_default_command_writes_the_default_calibration(tmp_path, design):
    from tests.calibration.conftest import run_cli

    res = run_cli(["default", "--out", tmp_path / "default.json"])
    assert res.returncode == 0, res.stderr
    assert load_calibration(tmp_path / "default.json") == default_calibration(design)
