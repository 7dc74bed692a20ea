"""Display transfer functions (gamma models): evaluate, invert, fit, choose by held-out error.

Three nested models of luminance ``L`` (cd/m^2) against drive ``x`` in [0, 1]:

=================  ==============================  ==========================================
name               equation                        reference
=================  ==============================  ==========================================
``power``          L = a + (b x)^gamma             PsychoPy eq. 1 (``calibTools.gammaFun``)
``offset_power``   L = a + (b + k x)^gamma, b >= 0 PsychoPy eq. 4 (Pelli & Zhang 1991)
``extended_power`` L = a + k max(x - x0, 0)^gamma  Brainard, Pelli & Robson (2002), "Display
                                                   characterization", the extended power
                                                   function with offset: a drive threshold x0
                                                   below which the gun emits nothing.
=================  ==============================  ==========================================

``a`` is the luminance at zero drive (the CRT's black plus reflected ambient light). They are
implemented here rather than through PsychoPy's ``GammaCalculator``, whose interpolation code has
an operator-precedence bug.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy.optimize import least_squares

from calibration.errors import CalibrationError

__all__ = [
    "GAMMA_MODELS",
    "GammaFit",
    "choose_gamma_model",
    "fit_gamma",
    "fit_gamma_models",
    "gamma_drive_for_luminance",
    "gamma_luminance",
]

#: Parameter names of each model, in the order the fit uses.
GAMMA_MODELS: dict[str, tuple[str, ...]] = {
    "power": ("a", "b", "gamma"),
    "offset_power": ("a", "b", "k", "gamma"),
    "extended_power": ("a", "k", "x0", "gamma"),
}


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


def gamma_luminance(drive, *, model: str, params: dict) -> np.ndarray:
    """Luminance the fitted display produces at a drive value.

    Parameters
    ----------
    drive : array_like
        Drive values in [0, 1] (0 = black, 1 = full gun output).
    model : {"power", "offset_power", "extended_power"}
        See the module docstring for the equations.
    params : dict
        The model's parameters (``GAMMA_MODELS[model]``); luminance parameters in cd/m^2.

    Returns
    -------
    ndarray
        Luminance in cd/m^2, same shape as ``drive``.
    """
    _check_model(model, params)
    x = np.asarray(drive, dtype=float)
    p = params
    g = float(p["gamma"])
    if model == "power":
        base = np.maximum(p["b"] * x, 0.0)
    elif model == "offset_power":
        base = np.maximum(p["b"] + p["k"] * x, 0.0)
    else:
        return p["a"] + p["k"] * np.maximum(x - p["x0"], 0.0) ** g
    return p["a"] + base**g


def gamma_drive_for_luminance(luminance_cd_m2, *, model: str, params: dict) -> np.ndarray:
    """Inverse of :func:`gamma_luminance`: the drive that produces a luminance.

    Parameters
    ----------
    luminance_cd_m2 : array_like
        Wanted luminance in cd/m^2. Values below the model's black give drive 0, values above its
        white give drive 1.
    model, params
        As in :func:`gamma_luminance`.

    Returns
    -------
    ndarray
        Drive values in [0, 1].
    """
    _check_model(model, params)
    y = np.asarray(luminance_cd_m2, dtype=float)
    p = params
    g = float(p["gamma"])
    above = np.maximum(y - p["a"], 0.0)
    root = above ** (1.0 / g)
    if model == "power":
        x = root / p["b"]
    elif model == "offset_power":
        x = (root - p["b"]) / p["k"]
    else:
        x = p["x0"] + (above / p["k"]) ** (1.0 / g)
    # At or below black every drive up to the threshold gives the same luminance: use 0.
    x = np.where(above <= 0.0, 0.0, x)
    return np.clip(x, 0.0, 1.0)


@dataclass(frozen=True)
class GammaFit:
    """One gamma model fitted to photometer readings.

    Attributes
    ----------
    model : str
        Model name (see :data:`GAMMA_MODELS`).
    params : dict[str, float]
        Fitted parameters; ``a`` (and ``k`` of the extended model) in cd/m^2.
    rmse_cd_m2 : float
        Root-mean-square residual on all readings.
    heldout_rmse_cd_m2 : float
        Leave-one-level-out cross-validated RMS error: each level predicted by a fit without it.
    levels : tuple[float, ...]
        Drive values of the readings used.
    luminance_cd_m2 : tuple[float, ...]
        The readings.
    residuals_cd_m2 : tuple[float, ...]
        Reading minus fitted luminance.
    heldout_rms_pct : float
        The held-out error relative to each reading (:func:`error_scale`), RMS in %: what the
        fit minimises and the model choice compares (NaN in records written before it existed).
    """

    model: str
    params: dict
    rmse_cd_m2: float
    heldout_rmse_cd_m2: float
    levels: tuple
    luminance_cd_m2: tuple
    residuals_cd_m2: tuple
    heldout_rms_pct: float = float("nan")

    def luminance(self, drive) -> np.ndarray:
        """Fitted luminance in cd/m^2 at ``drive`` in [0, 1]."""
        return gamma_luminance(drive, model=self.model, params=self.params)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> GammaFit:
        try:
            return cls(
                model=str(d["model"]),
                params={k: float(v) for k, v in d["params"].items()},
                rmse_cd_m2=float(d["rmse_cd_m2"]),
                heldout_rmse_cd_m2=float(d["heldout_rmse_cd_m2"]),
                levels=tuple(float(v) for v in d["levels"]),
                luminance_cd_m2=tuple(float(v) for v in d["luminance_cd_m2"]),
                residuals_cd_m2=tuple(float(v) for v in d["residuals_cd_m2"]),
                heldout_rms_pct=float(d.get("heldout_rms_pct", float("nan"))),
            )
        except (KeyError, TypeError, AttributeError, ValueError) as exc:
            raise CalibrationError(f"gamma fit record is malformed ({exc!r})") from exc


def _check_readings(levels, luminance_cd_m2) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(levels, dtype=float).ravel()
    y = np.asarray(luminance_cd_m2, dtype=float).ravel()
    if x.shape != y.shape:
        raise CalibrationError(
            f"levels ({x.size}) and luminance_cd_m2 ({y.size}) differ in length; "
            "pass one luminance per level"
        )
    if not np.all(np.isfinite(x)) or np.any((x < 0) | (x > 1)):
        raise CalibrationError(f"levels must lie in [0, 1]; got min {x.min()}, max {x.max()}")
    if not np.all(np.isfinite(y)):
        raise CalibrationError("luminance_cd_m2 holds NaN or inf; drop flagged readings first")
    if np.unique(x).size < 4:
        raise CalibrationError(
            f"a gamma fit needs at least 4 distinct levels, got {np.unique(x).size}; "
            "measure more levels (--levels)"
        )
    return x, y


def _starts(model: str, x: np.ndarray, y: np.ndarray) -> list[tuple[np.ndarray, tuple]]:
    """Starting points and bounds for each model, from the readings' black and white."""
    lo = float(y[x == x.min()].mean())
    hi = float(y[x == x.max()].mean())
    span = max(hi - lo, 1e-6)
    top = max(abs(hi), abs(lo), 1e-3) * 10 + 10
    starts = []
    for g in (1.8, 2.4, 3.0):
        if model == "power":
            p0 = [lo, span ** (1 / g), g]
            bounds = ([-top, 0.0, 0.3], [top, np.inf, 6.0])
        elif model == "offset_power":
            p0 = [lo, 0.01 * span ** (1 / g), span ** (1 / g), g]
            bounds = ([-top, 0.0, 0.0, 0.3], [top, np.inf, np.inf, 6.0])
        else:
            p0 = [lo, span, 0.02, g]
            bounds = ([-top, 0.0, -0.5, 0.3], [top, np.inf, 0.5, 6.0])
        starts.append((np.array(p0, dtype=float), bounds))
    return starts


#: Floor of the error scale as a fraction of the brightest reading (see :func:`error_scale`).
ERROR_FLOOR_FRACTION = 1e-3


def error_scale(luminance_cd_m2) -> np.ndarray:
    """Scale of each reading's error, cd/m^2: the reading, floored at 0.1 % of the brightest.

    Photometer error is proportional to the reading (a spot photometer's precision is a fraction
    of what it reads) above a small absolute floor, so the fit weights each residual by
    ``1 / error_scale``: an unweighted fit lets the 0.3 cd/m^2 noise at white outweigh the
    0.6 cd/m^2 black level and biases the black (sim-to-real issue 8).
    """
    y = np.abs(np.asarray(luminance_cd_m2, dtype=float))
    floor = ERROR_FLOOR_FRACTION * max(float(y.max(initial=0.0)), 1e-6)
    return np.maximum(y, floor)


def _fit_params(model: str, x: np.ndarray, y: np.ndarray) -> dict:
    names = GAMMA_MODELS[model]
    scale = error_scale(y)

    def resid(p):
        return (gamma_luminance(x, model=model, params=dict(zip(names, p))) - y) / scale

    best = None
    for p0, bounds in _starts(model, x, y):
        p0 = np.clip(p0, np.array(bounds[0]) + 1e-9, np.array(bounds[1]) - 1e-9)
        res = least_squares(resid, p0, bounds=bounds, x_scale="jac", max_nfev=4000)
        if best is None or res.cost < best.cost:
            best = res
    return {n: float(v) for n, v in zip(names, best.x)}


def fit_gamma(levels, luminance_cd_m2, *, model: str = "extended_power") -> GammaFit:
    """Fit a display transfer function to photometer readings by weighted least squares.

    Each residual is divided by the reading's error scale (:func:`error_scale`: the reading,
    floored at 0.1 % of the brightest), so the fit minimises relative error and the black level
    is fitted as well as white.

    Parameters
    ----------
    levels : array_like, shape (n,)
        Drive values in [0, 1]; repeats allowed.
    luminance_cd_m2 : array_like, shape (n,)
        Measured luminance at each level, cd/m^2.
    model : {"power", "offset_power", "extended_power"}
        See the module docstring.

    Returns
    -------
    GammaFit
        Parameters, residuals and leave-one-level-out held-out error.

    Raises
    ------
    CalibrationError
        If the shapes differ, a level lies outside [0, 1], a reading is not finite, or fewer than
        4 distinct levels are given.
    """
    _check_model(model, {n: 0 for n in GAMMA_MODELS.get(model, ())})
    x, y = _check_readings(levels, luminance_cd_m2)
    params = _fit_params(model, x, y)
    fitted = gamma_luminance(x, model=model, params=params)
    heldout = np.empty_like(y)
    for level in np.unique(x):
        out = x == level
        p = _fit_params(model, x[~out], y[~out])
        heldout[out] = gamma_luminance(x[out], model=model, params=p)
    return GammaFit(
        model=model,
        params=params,
        rmse_cd_m2=float(np.sqrt(np.mean((y - fitted) ** 2))),
        heldout_rmse_cd_m2=float(np.sqrt(np.mean((y - heldout) ** 2))),
        levels=tuple(float(v) for v in x),
        luminance_cd_m2=tuple(float(v) for v in y),
        residuals_cd_m2=tuple(float(v) for v in y - fitted),
        heldout_rms_pct=float(100 * np.sqrt(np.mean(((y - heldout) / error_scale(y)) ** 2))),
    )


def fit_gamma_models(levels, luminance_cd_m2) -> tuple[GammaFit, ...]:
    """Fit every model in :data:`GAMMA_MODELS`; same arguments as :func:`fit_gamma`."""
    return tuple(fit_gamma(levels, luminance_cd_m2, model=m) for m in GAMMA_MODELS)


def choose_gamma_model(fits, *, tolerance: float = 0.02) -> GammaFit:
    """The fit with the smallest held-out error; near-ties go to the model with fewer parameters.

    The error compared is the relative one the fits minimise (``heldout_rms_pct``); records
    written before it existed fall back to ``heldout_rmse_cd_m2``.

    Parameters
    ----------
    fits : sequence of GammaFit
    tolerance : float
        A model with more parameters must beat a simpler one's held-out RMS error by more than
        this fraction (default 2 %) to be chosen.
    """
    fits = list(fits)
    if not fits:
        raise CalibrationError("no gamma fits to choose from")
    relative = all(np.isfinite(f.heldout_rms_pct) for f in fits)

    def err(f: GammaFit) -> float:
        return f.heldout_rms_pct if relative else f.heldout_rmse_cd_m2

    fits = sorted(fits, key=lambda f: (len(GAMMA_MODELS[f.model]), err(f)))
    best = fits[0]
    for f in fits[1:]:
        if err(f) < err(best) * (1 - tolerance):
            best = f
    return best
