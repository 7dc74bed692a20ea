"""Display layer: how large a misfit these readings would detect, and how many more readings
would decide an inconclusive check (the engine's :class:`~analysis.gap.engine.PowerModel`).

Simulated from the fitted models, reused as they are: each held-out reading's prediction (the
model the verdict judges: the chosen effects', or the plain calibration's where the layer
holds chosen effects to the tolerance, as the diagnosis predicts it, without the between-pass
wander) and the photometer's noise model (its SD per reading). A simulated check adds to the
prediction a misfit of the shape a flexible model of the readings finds (the ceiling's
prediction minus the judged one; a uniform change of light where the ceiling finds nothing),
scaled to a size in the lab's unit (:data:`~analysis.gap.display.ceiling.DISPLAY_SIZE_UNIT`),
plus noise drawn from the noise model; a larger check repeats every reading ``factor`` times.
Each simulated check is decided as the diagnosis decides the real one
(:func:`~analysis.gap.display.ceiling.size_bounds`, :func:`~analysis.gap.engine.decide_size`).
The refit of the calibration and the effects on each simulated check is left out (the fitted
models are reused), which keeps 40 draws per grid point to milliseconds.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from analysis.gap.display.ceiling import (
    DARK_LIGHT_CD_M2,
    ceiling_prediction,
    group_codes,
    size_bounds,
)
from analysis.gap.display.model import display_mean_given
from analysis.gap.engine import Diagnosis, PowerModel, decide_size, judged_plain

__all__ = ["DISPLAY_FACTORS", "display_power"]

#: How many times the readings a larger check would take (repeats of each patch).
DISPLAY_FACTORS = (2, 3, 4, 6, 8, 12, 16, 24, 32)

#: Misfits tried for ``detectable``, in multiples of the tolerance.
_MISFITS_X_TOL = (1.0, 1.25, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0)


def _pooled(folds: list, fitted: list) -> dict:
    """The held-out readings of every fold: prediction of the judged model, noise SD and the
    flexible model's misfit, each in fractions of the light plus the dark light, with the
    readings' group codes (:func:`~analysis.gap.display.ceiling.group_codes`)."""
    parts, shape = [], []
    for train, test in folds:
        pred = display_mean_given(train, test, fitted, wander=False)
        ceil = ceiling_prediction(train, test)
        use = ~test["censored"].to_numpy(bool) & np.isfinite(pred)
        var = (test["var_expected"] if "var_expected" in test else test["sd"] ** 2).to_numpy(float)
        seen = pred[use] + DARK_LIGHT_CD_M2
        pos = np.array([f"pos {x:+.3f},{y:+.3f}" for x, y in
                        zip(test["x_norm"].to_numpy()[use], test["y_norm"].to_numpy()[use])])
        band = np.array([f"level {v:.4f}" for v in test["level"].to_numpy(float)[use]])
        parts.append({"seen": np.zeros(use.sum()), "seen_sd": np.sqrt(var[use]) / seen,
                      "group": np.concatenate([pos, band])})
        shape.append((ceil[use] - pred[use]) / seen)
    _, seen_sd, codes, _ = group_codes(parts)
    return {"sd": seen_sd, "codes": codes, "shape": np.concatenate(shape)}


def _unit_shape(shape: np.ndarray, codes: np.ndarray) -> np.ndarray:
    """``shape`` scaled so that its size (largest RMS over a group) is 1; a uniform change
    where it is nearly nothing (below 0.01 %)."""
    size = size_bounds(shape, np.zeros_like(shape), codes)[0] / 100
    if not np.isfinite(size) or size < 1e-4:
        return np.ones_like(shape)
    return shape / size


def _repeats(folds: list) -> int:
    """Readings per patch in the whole check (both halves)."""
    data = pd.concat([te for _, te in folds])
    return int(np.median(data.groupby("cell").size())) if len(data) else 1


def display_power(folds: list, diag: Diagnosis) -> PowerModel | None:
    """The :class:`~analysis.gap.engine.PowerModel` of a display diagnosis (see the module's
    docstring); None where no reading above the meter's floor is left to simulate.

    Parameters
    ----------
    folds : list of (DataFrame, DataFrame)
        The diagnosis's cross-fitting folds.
    diag : Diagnosis
        The finished diagnosis (its chosen effects, tolerance and remaining misfit).
    """
    rem = diag.remaining or {}
    holds_plain = judged_plain(diag)
    fitted = [] if holds_plain else [(s["added"], s["params"]) for s in diag.steps]
    pooled = _pooled(folds, fitted)
    if not pooled["sd"].size or not np.isfinite(diag.tolerance):
        return None
    unit = _unit_shape(pooled["shape"], pooled["codes"])
    sd, codes, tol = pooled["sd"], pooled["codes"], float(diag.tolerance)
    now = float(rem["size_before"] if holds_plain else rem.get("size", np.nan))
    repeats = _repeats(folds)

    def draws(misfit: float, factor: float):
        f = max(round(factor), 1)
        mean = np.tile(unit * misfit / 100, f)
        noise_sd = np.tile(sd, f)
        many = np.tile(codes, (1, f))

        def run(rng: np.random.Generator, k: int) -> np.ndarray:
            seen = mean + noise_sd * rng.standard_normal((k, mean.size))
            return decide_size(*size_bounds(seen, noise_sd, many), tol)
        return run

    def more(factor: float) -> str:
        return (f"{round(factor * repeats)} repeats of each patch instead of {repeats} "
                f"({factor:g}x the readings; as many more levels or positions do as well)")

    return PowerModel(draws=draws, misfit_now=now if np.isfinite(now) else 0.0,
                      misfits=tuple(tol * x for x in _MISFITS_X_TOL), factors=DISPLAY_FACTORS,
                      unit=diag.remaining.get("size_unit", "%") if rem else "%", more=more)
