"""Tone mapping (protocol.md, Stimuli): continuity, monotonicity, range; gamma correction."""

from __future__ import annotations

import numpy as np
import pytest

from calibration import default_calibration
from stimuli.tonemap import display_fraction, gamma_encode, tone_curve, tonemap


@pytest.fixture
def curve(design):
    return tone_curve(design.tonemap, 3.0)


def test_knee_is_continuous_in_value_and_slope(curve, design):
    lk, eps = curve.knee_luminance, 1e-7
    below, at, above = tonemap(np.array([lk - eps, lk, lk + eps]), curve)
    assert at == pytest.approx(design.tonemap.knee_value)
    assert above - at == pytest.approx(at - below, rel=1e-4)
    assert tonemap(np.array([0.0]), curve)[0] == 0.0


def test_monotonic_and_in_range(curve, design):
    L = np.linspace(0, 3 * curve.max_luminance, 200_001)
    v = tonemap(L, curve)
    assert np.all(np.diff(v) > 0)
    # far above L_max tanh saturates in floating point: still never decreasing
    assert np.all(np.diff(tonemap(np.linspace(0, 1e3, 10_001), curve)) >= 0)
    assert v.min() >= 0 and v.max() < design.tonemap.max_value
    # the bottom linear_fraction of the range goes to [0, knee]; the rest above the knee
    assert np.all(v[L <= curve.knee_luminance] <= design.tonemap.knee_value)
    assert np.all(v[L > curve.knee_luminance] > design.tonemap.knee_value)
    assert tonemap(np.array([curve.max_luminance]), curve)[0] > 230


def test_bad_range_and_nan_are_refused(design, curve):
    for bad in (0.0, np.nan, np.inf):
        with pytest.raises(ValueError, match="L_max"):
            tone_curve(design.tonemap, bad)
    with pytest.raises(ValueError, match="NaN"):
        tonemap(np.array([1.0, np.nan]), curve)


@pytest.mark.parametrize("gamma", [1.8, 2.2, 2.6])
def test_gamma_encoding_inverts_the_display_model(design, gamma):
    """Drive values shown through the calibration's display model reproduce the wanted luminance."""
    import dataclasses

    cal = default_calibration(design)
    params = dict(cal.gamma_params, gamma=gamma, k=(100 - 0.5) ** (1 / gamma))
    cal = dataclasses.replace(cal, gamma_params=params)
    fraction = np.linspace(0, 1, 256)
    lo, hi = cal.luminance_for_drive(0.0), cal.luminance_for_drive(1.0)
    wanted = lo + fraction * (hi - lo)
    # unquantised: exact inverse
    np.testing.assert_allclose(cal.luminance_for_drive(cal.drive_for_fraction(fraction)), wanted,
                               rtol=1e-9, atol=1e-9)
    # 8-bit: within half of the larger luminance step of a drive level on either side
    drive = gamma_encode(fraction, cal) / 255.0
    shown = cal.luminance_for_drive(drive)
    up = cal.luminance_for_drive(np.minimum(drive + 1 / 255, 1)) - shown
    down = shown - cal.luminance_for_drive(np.maximum(drive - 1 / 255, 0))
    assert np.all(np.abs(shown - wanted) <= 0.5 * np.maximum(up, down) + 1e-9 * hi)
    # and far better than no correction (drive = fraction)
    assert np.abs(shown - wanted).max() < 0.2 * np.abs(cal.luminance_for_drive(fraction) - wanted).max()
    assert gamma_encode(np.array([0.0]), cal)[0] == 0 and gamma_encode(np.array([1.0]), cal)[0] == 255


def test_display_fraction_below_one(curve):
    assert display_fraction(np.array([1e9]), curve)[0] <= 1.0
