"""Gamma models: parameter recovery, inverse, model choice by held-out error."""

from __future__ import annotations

import numpy as np
import pytest

from calibration import (
    CalibrationError,
    SimulatedCRT,
    choose_gamma_model,
    fit_gamma,
    fit_gamma_models,
    gamma_drive_for_luminance,
    gamma_luminance,
)

LEVELS = np.repeat(np.linspace(0, 1, 17), 2)


@pytest.mark.parametrize("gamma", [1.8, 2.2, 2.6])
def test_power_recovers_exponent(gamma, rng):
    # eq. 1 with a = 0.4, b such that white = 110.4 cd/m^2.
    lum = 0.4 + (110 ** (1 / gamma) * LEVELS) ** gamma + rng.normal(0, 0.05, LEVELS.size)
    fit = fit_gamma(LEVELS, lum, model="power")
    assert fit.params["gamma"] == pytest.approx(gamma, abs=0.03)
    assert fit.params["a"] == pytest.approx(0.4, abs=0.1)


def test_offset_power_recovers_parameters(rng):
    # eq. 4: a + (b + k x)^g with a positive offset inside the power.
    true = {"a": 0.3, "b": 1.2, "k": 7.0, "gamma": 2.3}
    lum = gamma_luminance(LEVELS, model="offset_power", params=true)
    lum = lum + rng.normal(0, 0.03, LEVELS.size)
    fit = fit_gamma(LEVELS, lum, model="offset_power")
    for name in ("b", "k", "gamma"):
        assert fit.params[name] == pytest.approx(true[name], rel=0.08), name
    assert np.max(np.abs(fit.residuals_cd_m2)) < 0.2


@pytest.mark.parametrize("x0", [0.0, 0.05, 0.1])
def test_extended_power_recovers_threshold(x0, rng):
    true = {"a": 0.6, "k": 90.0, "x0": x0, "gamma": 2.5}
    lum = gamma_luminance(LEVELS, model="extended_power", params=true)
    lum = lum + rng.normal(0, 0.03, LEVELS.size)
    fit = fit_gamma(LEVELS, lum, model="extended_power")
    assert fit.params["x0"] == pytest.approx(x0, abs=0.015)
    assert fit.params["gamma"] == pytest.approx(2.5, abs=0.1)
    assert fit.params["a"] == pytest.approx(0.6, abs=0.05)


def test_simulated_crt_threshold_picks_extended_model(rng):
    crt = SimulatedCRT(cutoff=0.08, falloff=0, tilt_x=0)
    lum = crt.luminance(LEVELS, rng=rng)
    best = choose_gamma_model(fit_gamma_models(LEVELS, lum))
    assert best.model == "extended_power"
    # 17 levels put only 0 and 0.0625 below the threshold, so x0 is known to a level step.
    assert best.params["x0"] == pytest.approx(0.08, abs=0.03)
    assert best.params["gamma"] == pytest.approx(crt.gamma, abs=0.15)


def test_pure_power_display_keeps_simplest_model(rng):
    lum = 0.5 + (100 ** (1 / 2.2) * LEVELS) ** 2.2 + rng.normal(0, 0.02, LEVELS.size)
    assert choose_gamma_model(fit_gamma_models(LEVELS, lum)).model == "power"


@pytest.mark.parametrize(
    "model, params",
    [
        ("power", {"a": 0.5, "b": 8.0, "gamma": 2.2}),
        ("offset_power", {"a": 0.5, "b": 0.7, "k": 8.0, "gamma": 2.4}),
        ("extended_power", {"a": 0.5, "k": 90.0, "x0": 0.05, "gamma": 2.6}),
    ],
)
def test_inverse_round_trips(model, params):
    x = np.linspace(0.06, 1, 50)
    lum = gamma_luminance(x, model=model, params=params)
    assert gamma_drive_for_luminance(lum, model=model, params=params) == pytest.approx(x, abs=1e-9)


@pytest.mark.parametrize(
    "levels, lum, message",
    [
        ([0, 0.5, 1], [0, 1, 2], "at least 4 distinct levels"),
        ([0, 0.3, 0.6, 1.2], [0, 1, 2, 3], r"levels must lie in \[0, 1\]"),
        ([0, 0.3, 0.6, 1], [0, 1, 2], "differ in length"),
        ([0, 0.3, 0.6, 1], [0, 1, np.nan, 3], "NaN"),
    ],
)
def test_bad_readings_are_rejected(levels, lum, message):
    with pytest.raises(CalibrationError, match=message):
        fit_gamma(levels, lum)


def test_unknown_model_is_rejected():
    with pytest.raises(CalibrationError, match="unknown"):
        fit_gamma(np.linspace(0, 1, 5), np.linspace(0, 1, 5), model="cubic")
