"""The likelihood of a gamma model given photometer readings, and its maximum (steps 2-4 of
:mod:`calibration.gamma`): readings with their censoring, the Tobit residuals, a grid over the
shape parameters with the offset and gain solved exactly at each node, bounded polish of the best
nodes, isotonic regression for the interpolating models, and the held-out error of a prediction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.special import log_ndtr

from calibration.errors import CalibrationError
from calibration.gamma_models import (
    INTERPOLATING_MODELS,
    SHAPE_BOUNDS,
    gamma_luminance,
    knots_to_params,
    params_from_linear,
    shape,
)
from calibration.noise import NoiseModel

__all__ = ["CensoredReadings", "censored_readings", "fit_one", "heldout_error",
           "leave_one_level_out", "subset", "z_scores"]

#: Grid nodes per shape parameter, and how many of the best nodes are polished.
GRID_N = 25
N_POLISH = 4


@dataclass(frozen=True)
class CensoredReadings:
    """Readings at drive levels ``x`` (0-1) of luminance ``y`` (cd/m^2), each with its noise SD
    and whether it is censored (at most ``floor``, cd/m^2: a reading at or below the meter's
    floor)."""

    x: np.ndarray
    y: np.ndarray
    sd: np.ndarray          # noise SD of each reading (at its bound for censored ones)
    censored: np.ndarray
    floor: np.ndarray       # each censored reading's bound, cd/m^2


def censored_readings(x, y, noise: NoiseModel) -> CensoredReadings:
    """Readings with their censoring: at or below the noise floor, at most that floor; a zero
    (or less), at most the meter's own floor (:attr:`NoiseModel.zero_floor`). A negative floor
    censors nothing (every reading taken as exact)."""
    zero = (y <= 0) & (noise.floor_cd_m2 >= 0)
    cens = (y <= noise.floor_cd_m2) | zero
    bound = np.where(zero, noise.zero_floor, noise.floor_cd_m2)
    sd = noise.sd(np.where(cens, bound, y))
    return CensoredReadings(x, y, sd, cens, bound)


def _residuals(mu: np.ndarray, d: CensoredReadings) -> np.ndarray:
    """Residuals whose half sum of squares is the negative log-likelihood (up to a constant).

    Uncensored: (y - mu) / sd. Censored: sqrt(-2 log P(L <= floor)), the Tobit term.
    """
    r = (d.y - mu) / d.sd
    if d.censored.any():
        z = (d.floor[d.censored] - mu[d.censored]) / d.sd[d.censored]
        r[d.censored] = np.sqrt(np.maximum(-2.0 * log_ndtr(z), 0.0))
    return r


def _theta_names(model: str) -> tuple[str, ...]:
    return tuple(SHAPE_BOUNDS[model])


def _grid(model: str, x_max: float) -> dict:
    """Grid nodes over the shape parameters: a dict of column arrays, shape (G, 1)."""
    names = _theta_names(model)
    axes = []
    for n in names:
        lo, hi = SHAPE_BOUNDS[model][n]
        if n == "x0":
            hi = min(hi, x_max - 1e-3)
            axes.append(np.linspace(lo, hi, 2 * GRID_N))
        elif n in ("gamma", "beta"):
            axes.append(np.geomspace(max(lo, 0.5), min(hi, 8.0), GRID_N))
        elif n == "r":
            axes.append(np.concatenate([[0.0], np.geomspace(1e-3, hi, GRID_N - 1)]))
        else:
            axes.append(np.geomspace(lo, hi, GRID_N))
    mesh = np.meshgrid(*axes, indexing="ij")
    return {n: m.reshape(-1, 1) for n, m in zip(names, mesh)}


def _grid_costs(model: str, d: CensoredReadings) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """(a, K) by weighted least squares on the uncensored readings at every grid node, and the
    negative log-likelihood with the censored terms; infeasible nodes (K < 0) cost inf."""
    theta = _grid(model, float(d.x.max()))
    f = shape(model, d.x[None, :], theta)
    u = ~d.censored
    w = 1.0 / d.sd[u] ** 2
    fu, yu = f[:, u], d.y[u]
    sff, sfy = fu**2 @ w, fu @ (w * yu)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if model == "inner_power":
            a = np.zeros(len(sff))
            gain = sfy / sff
        else:
            sw, sy, sf = w.sum(), np.sum(w * yu), fu @ w
            det = sw * sff - sf * sf
            gain = (sw * sfy - sf * sy) / det
            a = (sy - gain * sf) / sw
        mu = a[:, None] + gain[:, None] * f
        r = (d.y[None, :] - mu) / d.sd[None, :]
        if d.censored.any():
            z = (d.floor[d.censored] - mu[:, d.censored]) / d.sd[d.censored]
            r[:, d.censored] = np.sqrt(np.maximum(-2.0 * log_ndtr(z), 0.0))
        cost = 0.5 * np.sum(r**2, axis=1)
    cost = np.where(np.isfinite(cost) & (gain >= 0), cost, np.inf)
    return cost, a, gain, theta


def _polish(model: str, start: tuple[float, float, dict], d: CensoredReadings, top: float):
    names = _theta_names(model)
    bounds_t = [SHAPE_BOUNDS[model][n] for n in names]
    if "x0" in names:
        i = names.index("x0")
        bounds_t[i] = (bounds_t[i][0], min(bounds_t[i][1], float(d.x.max()) - 1e-6))
    has_a = model != "inner_power"
    lo = ([-top] if has_a else []) + [0.0] + [b[0] for b in bounds_t]
    hi = ([top] if has_a else []) + [np.inf] + [b[1] for b in bounds_t]
    a0, k0, t0 = start
    p0 = ([a0] if has_a else []) + [k0] + [t0[n] for n in names]
    p0 = np.clip(np.asarray(p0, float), np.asarray(lo) + 1e-12,
                 np.where(np.isfinite(hi), np.asarray(hi) - 1e-12, np.inf))

    def unpack(p):
        j = 1 if has_a else 0
        a = p[0] if has_a else 0.0
        return a, p[j], dict(zip(names, p[j + 1:]))

    def resid(p):
        a, gain, theta = unpack(p)
        return _residuals(a + gain * shape(model, d.x, theta), d)

    res = least_squares(resid, p0, bounds=(lo, hi), x_scale="jac", max_nfev=2000)
    return res.cost, unpack(res.x)


def _fit_parametric(model: str, d: CensoredReadings, extra_starts=(), n_polish: int = N_POLISH
                    ) -> tuple[dict, tuple]:
    """Grid over theta with (a, K) exact, then bounded polish of the best nodes.

    The ``extra_starts`` (a held-in refit gets the full fit's optimum) are polished first; a
    grid node is polished only if its cost beats the best polished so far, so a refit costs
    one polish unless the grid finds a better basin.
    """
    top = 10 * max(float(np.max(np.abs(d.y))), 1e-3) + 10
    cost, a, gain, theta = _grid_costs(model, d)
    order = [i for i in np.argsort(cost)[:n_polish] if np.isfinite(cost[i])]
    best = None
    for s in extra_starts:
        r = _polish(model, s, d, top)
        best = r if best is None or r[0] < best[0] else best
    for i in order:
        if best is not None and cost[i] >= best[0]:
            continue
        s = (float(a[i]), float(gain[i]), {n: float(v[i, 0]) for n, v in theta.items()})
        r = _polish(model, s, d, top)
        best = r if best is None or r[0] < best[0] else best
    if best is None:
        raise CalibrationError(f"gamma model {model!r}: no starting point fits the readings")
    a_, gain_, theta_ = best[1]
    return params_from_linear(model, float(a_), float(gain_), theta_), best[1]


def _pava(y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted isotonic (non-decreasing) regression by pool-adjacent-violators."""
    vals, wts, sizes = [], [], []
    for v, wt in zip(y, w):
        vals.append(v)
        wts.append(wt)
        sizes.append(1)
        while len(vals) > 1 and vals[-2] > vals[-1]:
            wsum = wts[-2] + wts[-1]
            v2 = (vals[-2] * wts[-2] + vals[-1] * wts[-1]) / wsum
            s = sizes[-2] + sizes[-1]
            vals[-2:], wts[-2:], sizes[-2:] = [v2], [wsum], [s]
    return np.repeat(vals, sizes)


def _fit_interpolating(model: str, d: CensoredReadings) -> dict:
    uniq, inv, counts = np.unique(d.x, return_inverse=True, return_counts=True)
    means = np.bincount(inv, weights=d.y) / counts
    if model == "monotone_spline":
        sd_mean = np.sqrt(np.bincount(inv, weights=d.sd**2) / counts) / np.sqrt(counts)
        means = _pava(means, 1.0 / sd_mean**2)
    return knots_to_params(uniq, means)


def fit_one(model: str, d: CensoredReadings, extra_starts=(), n_polish: int = N_POLISH
             ) -> tuple[dict, tuple | None]:
    if model in INTERPOLATING_MODELS:
        return _fit_interpolating(model, d), None
    return _fit_parametric(model, d, extra_starts, n_polish)


def subset(d: CensoredReadings, keep: np.ndarray) -> CensoredReadings:
    return CensoredReadings(d.x[keep], d.y[keep], d.sd[keep], d.censored[keep], d.floor[keep])


def heldout_error(mu: np.ndarray, d: CensoredReadings) -> np.ndarray:
    """Reading minus prediction, cd/m^2; a censored reading (it says only "at most the floor")
    counts only a prediction above the floor, as minus its excess."""
    return np.where(d.censored, -np.maximum(mu - d.floor, 0.0), d.y - mu)


def z_scores(mu: np.ndarray, d: CensoredReadings) -> np.ndarray:
    """Error in noise SDs; a censored reading counts only a prediction above the floor."""
    return heldout_error(mu, d) / d.sd


def leave_one_level_out(model: str, d: CensoredReadings, linear) -> tuple:
    """Each level predicted by a fit without it (step 4 of :mod:`calibration.gamma`).

    ``linear`` is the full fit's optimum (or None): it starts each refit, and the held-in
    grid's best nodes too if they are better. Returns the held-out prediction of every reading
    (cd/m^2), its error in noise SDs (:func:`z_scores`) and each level's mean squared z.
    """
    x = d.x
    uniq = np.unique(x)
    heldout = np.empty_like(d.y)
    level_loss = np.empty(uniq.size)
    z_all = np.empty_like(d.y)
    extra = [linear] if linear is not None else []
    for i, level in enumerate(uniq):
        out = x == level
        p, _ = fit_one(model, subset(d, ~out), extra)
        heldout[out] = gamma_luminance(x[out], model=model, params=p)
        z = z_scores(heldout[out], subset(d, out))
        z_all[out] = z
        level_loss[i] = float(np.mean(z**2))
    return heldout, z_all, level_loss
