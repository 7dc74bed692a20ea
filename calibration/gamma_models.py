"""The family of display transfer functions (gamma models): equations, evaluation, inverse.

Luminance ``L`` (cd/m^2) against drive ``x`` in [0, 1]. Six parametric models, each written as
``L = a + K f(x; theta)`` so that, for fixed shape parameters ``theta``, the black ``a`` and the
gain ``K`` are linear (the fit grids ``theta`` and solves ``a, K`` exactly):

=======================  ====================================  ===============================
name                     equation                              reference
=======================  ====================================  ===============================
``power``                L = a + (b x)^gamma                   PsychoPy eq. 1
                                                               (``calibTools.gammaFun``);
                                                               Psychtoolbox's simple power
                                                               function above the ambient
``inner_power``          L = (b + k x)^gamma, b >= 0           PsychoPy eq. 2
``offset_power``         L = a + (b + k x)^gamma, b >= 0       PsychoPy eq. 4 (Pelli & Zhang
                                                               1991)
``extended_power``       L = a + k max(x - x0, 0)^gamma        Brainard, Pelli & Robson (2002),
                                                               extended power function with
                                                               offset (Psychtoolbox
                                                               ``ComputeGammaExtP``,
                                                               ``crtGamma``): threshold x0
``ptb_sigmoid``          L = a + k (1+c^g) x^g / (x^g + c^g)   Psychtoolbox ``ComputeGammaSig``
                                                               normalised at x = 1 (its two
                                                               scales reduce to one, c)
``ptb_weibull``          L = a + k W(x) / W(1),                Psychtoolbox ``ComputeGammaWeib``
                         W(x) = 1 - exp(-(x/alpha)^beta)
=======================  ====================================  ===============================

Two interpolating models, whose parameters are knots (drive ``kxNN``, luminance ``klNN``):

``ptb_crt_poly_linear``
    Psychtoolbox's default for CRTs (``CalibrateFitGamma``, ``crtPolyLinear``): readings below
    0.1 % of the range above the lowest are set to it, a cubic spline through the level means,
    linear interpolation at and below the last level under 2 % of the range, tabulated at 1024
    drives and made non-decreasing.
``monotone_spline``
    Isotonic regression of the level means (pool-adjacent-violators, weights = inverse
    variance of each mean), then a monotone cubic (PCHIP) through them; constant beyond the
    outer knots.

``a`` is the luminance at zero drive (the display's black plus reflected ambient light).
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline, PchipInterpolator

from calibration.errors import CalibrationError

__all__ = [
    "GAMMA_MODELS",
    "INTERPOLATING_MODELS",
    "PARAMETRIC_MODELS",
    "SHAPE_BOUNDS",
    "gamma_drive_for_luminance",
    "gamma_luminance",
    "knots_from_params",
    "model_complexity",
    "params_from_linear",
    "params_to_linear",
    "shape",
]

#: Parameter names of each parametric model, in the order records list them.
PARAMETRIC_MODELS: dict[str, tuple[str, ...]] = {
    "power": ("a", "b", "gamma"),
    "inner_power": ("b", "k", "gamma"),
    "offset_power": ("a", "b", "k", "gamma"),
    "extended_power": ("a", "k", "x0", "gamma"),
    "ptb_sigmoid": ("a", "k", "c", "gamma"),
    "ptb_weibull": ("a", "k", "alpha", "beta"),
}
#: Models whose parameters are knots ``kx00, kx01, ...`` and ``kl00, kl01, ...``.
INTERPOLATING_MODELS: tuple[str, ...] = ("ptb_crt_poly_linear", "monotone_spline")
#: Every model; interpolating models have no fixed parameter names.
GAMMA_MODELS: dict[str, tuple[str, ...]] = {
    **PARAMETRIC_MODELS, **{m: () for m in INTERPOLATING_MODELS}
}

#: Bounds of the shape parameters theta of each parametric model (the grid and the search use
#: them). ``r`` of the inner/offset power models is b / k (the offset as a fraction of the gain).
SHAPE_BOUNDS: dict[str, dict[str, tuple[float, float]]] = {
    "power": {"gamma": (0.3, 6.0)},
    "inner_power": {"r": (0.0, 1.0), "gamma": (0.3, 6.0)},
    "offset_power": {"r": (0.0, 1.0), "gamma": (0.3, 6.0)},
    "extended_power": {"x0": (-0.2, 0.6), "gamma": (0.3, 6.0)},
    "ptb_sigmoid": {"c": (0.02, 5.0), "gamma": (0.3, 12.0)},
    "ptb_weibull": {"alpha": (0.02, 5.0), "beta": (0.3, 12.0)},
}

_CLOSED_FORM_INVERSE = ("power", "inner_power", "offset_power", "extended_power")
#: Psychtoolbox's crtPolyLinear settings (``contrastThresh``, ``fitBreakThresh``, table size).
_PTB_CONTRAST_THRESH = 0.001
_PTB_FIT_BREAK_THRESH = 0.02
_PTB_TABLE_SIZE = 1024


def model_complexity(model: str, params: dict) -> int:
    """Number of free parameters (knots count one each for interpolating models)."""
    if model in PARAMETRIC_MODELS:
        return len(PARAMETRIC_MODELS[model])
    return len(knots_from_params(params)[0])


def _check_model(model: str, params: dict) -> None:
    if model not in GAMMA_MODELS:
        raise CalibrationError(
            f"gamma model {model!r} is unknown; use one of {sorted(GAMMA_MODELS)}"
        )
    missing = [p for p in GAMMA_MODELS[model] if p not in params]
    if missing:
        raise CalibrationError(
            f"gamma model {model!r} needs parameters {list(GAMMA_MODELS[model])}; "
            f"missing {missing}"
        )


# --- the linear-in-(a, K) form -------------------------------------------------------------------
def shape(model: str, x: np.ndarray, theta: dict) -> np.ndarray:
    """The shape ``f(x; theta)`` of a parametric model, so that ``L = a + K f``.

    Every shape is 0 at the black (x = 0, or below the threshold x0) except the inner and
    offset power functions (``r^gamma`` at 0), and 1 at x = 1 except power-law shapes with an
    offset (``(r + 1)^gamma``).
    """
    x = np.asarray(x, dtype=float)
    g = theta.get("gamma")
    if model == "power":
        return np.maximum(x, 0.0) ** g
    if model in ("inner_power", "offset_power"):
        return np.maximum(theta["r"] + x, 0.0) ** g
    if model == "extended_power":
        return np.maximum(x - theta["x0"], 0.0) ** g
    if model == "ptb_sigmoid":
        c = theta["c"]
        xg = np.maximum(x, 0.0) ** g
        return xg * (1.0 + c**g) / (xg + c**g)
    if model == "ptb_weibull":
        al, be = theta["alpha"], theta["beta"]
        w1 = -np.expm1(-((1.0 / al) ** be))
        return -np.expm1(-((np.maximum(x, 0.0) / al) ** be)) / w1
    raise CalibrationError(f"gamma model {model!r} has no parametric shape")


def params_from_linear(model: str, a: float, gain: float, theta: dict) -> dict:
    """Public parameters from the linear form ``a + K f(x; theta)``."""
    theta = {k: float(v) for k, v in theta.items()}
    a, gain = float(a), float(gain)
    g = theta.get("gamma")
    if model == "power":
        return {"a": a, "b": max(gain, 0.0) ** (1.0 / g), "gamma": g}
    if model in ("inner_power", "offset_power"):
        k = max(gain, 0.0) ** (1.0 / g)
        out = {"b": theta["r"] * k, "k": k, "gamma": g}
        return out if model == "inner_power" else {"a": a, **out}
    if model == "extended_power":
        return {"a": a, "k": gain, "x0": theta["x0"], "gamma": g}
    if model == "ptb_sigmoid":
        return {"a": a, "k": gain, "c": theta["c"], "gamma": g}
    if model == "ptb_weibull":
        return {"a": a, "k": gain, "alpha": theta["alpha"], "beta": theta["beta"]}
    raise CalibrationError(f"gamma model {model!r} has no parametric form")


def params_to_linear(model: str, params: dict) -> tuple[float, float, dict]:
    """``(a, K, theta)`` of a parametric model's public parameters (inverse of
    :func:`params_from_linear`)."""
    p = {k: float(v) for k, v in params.items()}
    g = p.get("gamma")
    if model == "power":
        return p["a"], p["b"] ** g, {"gamma": g}
    if model in ("inner_power", "offset_power"):
        k = max(p["k"], 1e-12)
        a = 0.0 if model == "inner_power" else p["a"]
        return a, k**g, {"r": p["b"] / k, "gamma": g}
    if model == "extended_power":
        return p["a"], p["k"], {"x0": p["x0"], "gamma": g}
    if model == "ptb_sigmoid":
        return p["a"], p["k"], {"c": p["c"], "gamma": g}
    if model == "ptb_weibull":
        return p["a"], p["k"], {"alpha": p["alpha"], "beta": p["beta"]}
    raise CalibrationError(f"gamma model {model!r} has no parametric form")


# --- interpolating models --------------------------------------------------------------------------
def knots_from_params(params: dict) -> tuple[np.ndarray, np.ndarray]:
    """Knot drives and luminances (cd/m^2) stored as ``kxNN`` / ``klNN`` parameters."""
    kx = sorted(k for k in params if k.startswith("kx"))
    if not kx or any(f"kl{k[2:]}" not in params for k in kx):
        raise CalibrationError(
            "an interpolating gamma model needs knot parameters kx00, kl00, kx01, kl01, ...; "
            f"got {sorted(params)}"
        )
    x = np.array([float(params[k]) for k in kx])
    y = np.array([float(params[f"kl{k[2:]}"]) for k in kx])
    return x, y


def knots_to_params(x, y) -> dict:
    """Parameters ``kxNN`` / ``klNN`` for knots (drive, luminance in cd/m^2)."""
    out = {}
    for i, (a, b) in enumerate(zip(x, y)):
        out[f"kx{i:02d}"] = float(a)
        out[f"kl{i:02d}"] = float(b)
    return out


def _ptb_table(kx: np.ndarray, ky: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Psychtoolbox's crtPolyLinear table (1024 drives) through knots; see module docstring."""
    lo, span = ky[0], max(ky[-1] - ky[0], 1e-12)
    norm = (ky - lo) / span
    norm = np.where(norm < _PTB_CONTRAST_THRESH, 0.0, norm)
    norm = np.maximum.accumulate(np.maximum(norm, 0.0))
    grid = np.linspace(kx[0], kx[-1], _PTB_TABLE_SIZE)
    if kx.size >= 4:
        table = CubicSpline(kx, norm, bc_type="not-a-knot")(grid)
    else:
        table = np.interp(grid, kx, norm)
    low = np.flatnonzero(norm < _PTB_FIT_BREAK_THRESH)
    if low.size:
        brk = kx[low.max()]
        table = np.where(grid <= brk, np.interp(grid, kx, norm), table)
    table = np.maximum.accumulate(table)
    return grid, lo + span * table


def _interpolate(model: str, x: np.ndarray, params: dict) -> np.ndarray:
    kx, ky = knots_from_params(params)
    xc = np.clip(x, kx[0], kx[-1])
    if kx.size == 1:
        return np.full_like(x, ky[0])
    if model == "monotone_spline":
        return PchipInterpolator(kx, ky)(xc)
    grid, table = _ptb_table(kx, ky)
    return np.interp(xc, grid, table)


# --- evaluation and inverse ----------------------------------------------------------------------
def gamma_luminance(drive, *, model: str, params: dict) -> np.ndarray:
    """Luminance the fitted display produces at a drive value.

    Parameters
    ----------
    drive : array_like
        Drive values in [0, 1] (0 = black, 1 = full gun output).
    model : str
        One of :data:`GAMMA_MODELS` (equations in the module docstring).
    params : dict
        The model's parameters; luminance parameters in cd/m^2.

    Returns
    -------
    ndarray
        Luminance in cd/m^2, same shape as ``drive``.

    Raises
    ------
    CalibrationError
        If the model is unknown or a parameter is missing.
    """
    _check_model(model, params)
    x = np.asarray(drive, dtype=float)
    if model in INTERPOLATING_MODELS:
        return _interpolate(model, x, params)
    a, gain, theta = params_to_linear(model, params)
    return a + gain * shape(model, x, theta)


def _bisect_inverse(y: np.ndarray, model: str, params: dict) -> np.ndarray:
    """Smallest drive whose luminance reaches ``y`` (the curve is non-decreasing)."""
    lo = np.zeros_like(y)
    hi = np.ones_like(y)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        above = gamma_luminance(mid, model=model, params=params) >= y
        hi = np.where(above, mid, hi)
        lo = np.where(above, lo, mid)
    return hi


def gamma_drive_for_luminance(luminance_cd_m2, *, model: str, params: dict) -> np.ndarray:
    """Inverse of :func:`gamma_luminance`: the drive that produces a luminance.

    Closed form for the power-law models; bisection (60 halvings, exact to 1e-15 in drive) on
    the non-decreasing curve for the others.

    Parameters
    ----------
    luminance_cd_m2 : array_like
        Wanted luminance in cd/m^2. Values at or below the model's black give drive 0, values
        above its white give drive 1.
    model, params
        As in :func:`gamma_luminance`.

    Returns
    -------
    ndarray
        Drive values in [0, 1].
    """
    _check_model(model, params)
    y = np.asarray(luminance_cd_m2, dtype=float)
    if model not in _CLOSED_FORM_INVERSE:
        black = gamma_luminance(0.0, model=model, params=params)
        x = _bisect_inverse(np.atleast_1d(y).astype(float), model, params).reshape(y.shape)
        return np.clip(np.where(y <= black, 0.0, x), 0.0, 1.0)
    p = params
    g = float(p["gamma"])
    a = 0.0 if model == "inner_power" else p["a"]
    above = np.maximum(y - a, 0.0)
    root = above ** (1.0 / g)
    if model == "power":
        x = root / p["b"]
    elif model in ("offset_power", "inner_power"):
        x = (root - p["b"]) / p["k"]
    else:
        x = p["x0"] + (above / p["k"]) ** (1.0 / g)
    # At or below black every drive up to the threshold gives the same luminance: use 0.
    x = np.where(above <= 0.0, 0.0, x)
    return np.clip(x, 0.0, 1.0)
