"""Fit display transfer functions (gamma models) to photometer readings and choose one.

The models are in :mod:`calibration.gamma_models` (PsychoPy's eq. 1, 2 and 4, the extended
power function, Psychtoolbox's sigmoid and Weibull, its crtPolyLinear table and a monotone
spline). The fit, for each model:

1. **Noise.** Each reading's SD is ``sqrt(a^2 + (b L)^2)`` (:mod:`calibration.noise`): fitted
   to repeated readings when there are any, else the documented default.
2. **Censoring.** A reading at or below the meter's floor is censored: its likelihood is
   ``P(L <= floor)`` under the model (a Tobit term), not a point at the floor.
3. **Likelihood.** Parametric models maximise the Gaussian likelihood (weighted least squares
   with the noise SDs plus the censored terms). Every model is ``a + K f(x; theta)``: a grid
   over the shape parameters theta (the drive threshold x0 included, over its whole range)
   with ``a, K`` solved exactly at each node, then the best nodes polished by bounded
   least squares (several starts, so a local optimum is not taken for the fit).
4. **Held-out error.** Leave-one-level-out: each level predicted by a fit without it, scored in
   noise SDs (``z``; a censored reading scores only a prediction above the floor).
5. **Misfit flag.** The lack-of-fit chi-square of the standardised residuals and a runs test
   of their signs along the drive axis; a fit that fails either (p < :data:`MISFIT_P`) carries
   a warning.

:func:`choose_gamma_model` takes the simplest model whose held-out loss is within one
standard error of the best (the one-standard-error rule of Breiman et al. 1984).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy import stats

from calibration.errors import CalibrationError
from calibration.gamma_likelihood import (
    CensoredReadings,
    censored_readings,
    fit_one,
    heldout_error,
    leave_one_level_out,
)
from calibration.gamma_models import (
    GAMMA_MODELS,
    INTERPOLATING_MODELS,
    gamma_drive_for_luminance,
    gamma_luminance,
    model_complexity,
)
from calibration.noise import NoiseModel, fit_noise

__all__ = [
    "DAC_BITS",
    "GAMMA_MODELS",
    "MISFIT_P",
    "GammaFit",
    "choose_gamma_model",
    "displayed_drive",
    "error_scale",
    "fit_gamma",
    "fit_gamma_models",
    "gamma_drive_for_luminance",
    "gamma_luminance",
]

#: A fit whose lack-of-fit chi-square or runs test has p below this is flagged as a misfit.
MISFIT_P = 1e-3
#: Order in which equally complex models are preferred (the more familiar first).
_PREFERENCE = ("power", "inner_power", "offset_power", "extended_power", "ptb_sigmoid",
               "ptb_weibull",
               "ptb_crt_poly_linear", "monotone_spline")


@dataclass(frozen=True)
class GammaFit:
    """One gamma model fitted to photometer readings.

    Attributes
    ----------
    model : str
        Model name (:data:`GAMMA_MODELS`).
    params : dict[str, float]
        Fitted parameters; luminance parameters in cd/m^2 (knots for interpolating models).
    rmse_cd_m2 : float
        Root-mean-square residual on all readings.
    heldout_rmse_cd_m2 : float
        Leave-one-level-out RMS error, cd/m^2: each level predicted by a fit without it.
    levels : tuple[float, ...]
        Drive values of the readings used (on the DAC grid when ``dac_bits`` is set).
    luminance_cd_m2 : tuple[float, ...]
        The readings.
    residuals_cd_m2 : tuple[float, ...]
        Reading minus fitted luminance.
    heldout_rms_pct : float
        The held-out error relative to each reading (:func:`error_scale`), RMS in %; a
        censored reading counts only a prediction above the floor (as in ``heldout_rms_z``).
    heldout_rms_z : float
        The held-out error in noise SDs, RMS over readings (a censored reading counts only a
        prediction above the floor): about 1 for a model right up to noise. NaN in records
        written before it existed.
    heldout_level_loss : tuple[float, ...]
        Mean squared held-out z of each level (sorted by level): the model choice compares
        their mean and its standard error.
    n_params : int
        Free parameters (knots for interpolating models); 0 in old records.
    noise : dict
        The :class:`~calibration.noise.NoiseModel` used (empty in old records).
    censored : tuple[bool, ...]
        Readings at or below the meter's floor, fitted as censored.
    misfit : dict
        ``chi2``, ``dof``, ``chi2_p``, ``runs``, ``runs_p`` (None where not testable).
    warnings : tuple[str, ...]
        The misfit flag, when raised.
    dac_bits : int or None
        The levels were rounded to this DAC's grid before the fit (the drive the display
        showed); None: used as given (and in old records).
    """

    model: str
    params: dict
    rmse_cd_m2: float
    heldout_rmse_cd_m2: float
    levels: tuple
    luminance_cd_m2: tuple
    residuals_cd_m2: tuple
    heldout_rms_pct: float = float("nan")
    heldout_rms_z: float = float("nan")
    heldout_level_loss: tuple = ()
    n_params: int = 0
    noise: dict = field(default_factory=dict)
    censored: tuple = ()
    misfit: dict = field(default_factory=dict)
    warnings: tuple = ()
    dac_bits: int | None = None

    def luminance(self, drive) -> np.ndarray:
        """Fitted luminance in cd/m^2 at ``drive`` in [0, 1]."""
        return gamma_luminance(drive, model=self.model, params=self.params)

    def to_dict(self) -> dict:
        d = asdict(self)
        # JSON has no NaN: a held-out error old records lack is written as null.
        for k in ("heldout_rms_pct", "heldout_rms_z"):
            if not math.isfinite(d[k]):
                d[k] = None
        return d

    @classmethod
    def from_dict(cls, d: dict) -> GammaFit:
        def num(v):
            return float("nan") if v is None else float(v)

        try:
            return cls(
                model=str(d["model"]),
                params={k: float(v) for k, v in d["params"].items()},
                rmse_cd_m2=float(d["rmse_cd_m2"]),
                heldout_rmse_cd_m2=float(d["heldout_rmse_cd_m2"]),
                levels=tuple(float(v) for v in d["levels"]),
                luminance_cd_m2=tuple(float(v) for v in d["luminance_cd_m2"]),
                residuals_cd_m2=tuple(float(v) for v in d["residuals_cd_m2"]),
                heldout_rms_pct=num(d.get("heldout_rms_pct")),
                heldout_rms_z=num(d.get("heldout_rms_z")),
                heldout_level_loss=tuple(float(v) for v in d.get("heldout_level_loss", ())),
                n_params=int(d.get("n_params", 0)),
                noise=dict(d.get("noise", {})),
                censored=tuple(bool(v) for v in d.get("censored", ())),
                misfit={k: (None if v is None else float(v) if k != "dof" else int(v))
                        for k, v in d.get("misfit", {}).items()},
                warnings=tuple(str(w) for w in d.get("warnings", ())),
                dac_bits=None if d.get("dac_bits") is None else int(d["dac_bits"]),
            )
        except (KeyError, TypeError, AttributeError, ValueError) as exc:
            raise CalibrationError(f"gamma fit record is malformed ({exc!r})") from exc


# --- input checks --------------------------------------------------------------------------------
#: Bits per gun of the display's DAC (the frame buffer's 8 bits on the lab's CRT).
DAC_BITS = 8


def displayed_drive(levels, dac_bits: int | None) -> np.ndarray:
    """The drive a display shows for requested levels: rounded to its DAC grid, k / (2^bits - 1).

    A level off the grid (PsychoPy's ``DACrange``, a 1/30 step) is shown as the nearest grid
    value; fitting the requested value instead biases the fit (gamma 2.287 for 2.3 on a clean
    simulated CRT measured at 17 evenly spaced levels). ``dac_bits=None`` leaves the levels as
    given (a display with a deeper DAC than the levels' grid).
    """
    x = np.asarray(levels, dtype=float)
    if dac_bits is None:
        return x
    if not (isinstance(dac_bits, (int, np.integer)) and 1 <= dac_bits <= 16):
        raise CalibrationError(f"dac_bits must be an int in 1..16 or None, got {dac_bits!r}")
    steps = 2**int(dac_bits) - 1
    return np.round(x * steps) / steps


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


#: Floor of the error scale as a fraction of the brightest reading (see :func:`error_scale`).
ERROR_FLOOR_FRACTION = 1e-3


def error_scale(luminance_cd_m2) -> np.ndarray:
    """Scale of each reading for the report's relative error, cd/m^2: the reading, floored at
    0.1 % of the brightest (``heldout_rms_pct``; the fit itself uses the noise model)."""
    y = np.abs(np.asarray(luminance_cd_m2, dtype=float))
    floor = ERROR_FLOOR_FRACTION * max(float(y.max(initial=0.0)), 1e-6)
    return np.maximum(y, floor)


# --- misfit --------------------------------------------------------------------------------------
def _runs_test(signs: np.ndarray) -> tuple[int, float]:
    """Wald-Wolfowitz runs test (one-sided: too few runs = systematic misfit)."""
    s = signs[signs != 0]
    n1, n2 = int(np.sum(s > 0)), int(np.sum(s < 0))
    if n1 == 0 or n2 == 0 or s.size < 6:
        return int(s.size > 0), float("nan")
    runs = 1 + int(np.sum(s[1:] != s[:-1]))
    n = n1 + n2
    mean = 1 + 2 * n1 * n2 / n
    var = 2 * n1 * n2 * (2 * n1 * n2 - n) / (n * n * (n - 1))
    if var <= 0:
        return runs, float("nan")
    return runs, float(stats.norm.cdf((runs + 0.5 - mean) / math.sqrt(var)))


def _misfit(model: str, d: CensoredReadings, mu: np.ndarray, n_params: int,
            noise: NoiseModel) -> tuple[dict, tuple]:
    u = ~d.censored
    z = (d.y[u] - mu[u]) / d.sd[u]
    chi2 = float(np.sum(z**2))
    dof = int(u.sum()) - n_params
    chi2_p = float(stats.chi2.sf(chi2, dof)) if dof > 0 else float("nan")
    _, inv = np.unique(d.x[u], return_inverse=True)
    mean_z = np.bincount(inv, weights=z) / np.bincount(inv)
    tol = 1e-9 * max(1.0, float(np.max(np.abs(mean_z), initial=0.0)))
    signs = np.sign(np.where(np.abs(mean_z) <= tol, 0.0, mean_z))
    runs, runs_p = _runs_test(signs) if model not in INTERPOLATING_MODELS else (0, float("nan"))
    out = {"chi2": chi2, "dof": dof, "runs": runs,
           "chi2_p": chi2_p if np.isfinite(chi2_p) else None,
           "runs_p": runs_p if np.isfinite(runs_p) else None}
    failed = []
    if np.isfinite(chi2_p) and chi2_p < MISFIT_P:
        failed.append(f"lack-of-fit chi-square {chi2:.1f} on {dof} df, p = {chi2_p:.2g}")
    if np.isfinite(runs_p) and runs_p < MISFIT_P:
        failed.append(f"{runs} runs of residual signs over {signs.size} levels, "
                      f"p = {runs_p:.2g}")
    if not failed:
        return out, ()
    where = ("fitted to repeated readings" if noise.source == "repeats" else
             "the default noise: no repeated readings, so measure repeats to test the fit "
             "against the real noise")
    msg = (f"gamma model {model}: residuals are not noise-like ({'; '.join(failed)}) under the "
           f"noise model SD = sqrt(a^2 + (b L)^2), a = {noise.abs_cd_m2:.3g} cd/m^2, "
           f"b = {noise.rel:.3g} ({where}); the model misses the curve's shape: look at the "
           "residual plot, check the photometer's aim and the warm-up, or remeasure")
    return out, (msg,)


def _check_fittable(d: CensoredReadings, noise: NoiseModel) -> None:
    """Refuse readings no model can be fitted to: fewer than 3 levels above the meter's floor,
    or level means that do not rise by more than 5 noise SDs."""
    x, y = d.x, d.y
    if (~d.censored).sum() < 3 or np.unique(x[~d.censored]).size < 3:
        raise CalibrationError(
            f"only {int((~d.censored).sum())} readings lie above the meter's floor "
            f"({noise.floor_cd_m2:.3g} cd/m^2); measure brighter levels or pass a lower floor"
        )
    uniq = np.unique(x)
    means = np.array([y[x == v].mean() for v in uniq])
    if means.max() - means.min() <= 5 * float(noise.sd(means.max())):
        raise CalibrationError(
            f"the readings do not rise with the drive (level means {means.min():.4g} to "
            f"{means.max():.4g} cd/m^2, within 5 noise SDs): check that the photometer is "
            "aimed at the patch and the display is on, then remeasure"
        )


# --- public API ----------------------------------------------------------------------------------
def fit_gamma(levels, luminance_cd_m2, *, model: str = "extended_power",
              noise: NoiseModel | None = None, floor_cd_m2: float | None = None,
              dac_bits: int | None = DAC_BITS,
              zero_floor_cd_m2: float | None = None) -> GammaFit:
    """Fit a display transfer function to photometer readings by maximum likelihood.

    Parameters
    ----------
    levels : array_like, shape (n,)
        Drive values in [0, 1]; repeats allowed (they give the noise model).
    luminance_cd_m2 : array_like, shape (n,)
        Measured luminance at each level, cd/m^2.
    model : str
        One of :data:`GAMMA_MODELS` (equations in :mod:`calibration.gamma_models`).
    noise : NoiseModel or None
        The readings' noise; default :func:`calibration.noise.fit_noise` of these readings.
    floor_cd_m2 : float or None
        The meter's floor (readings at or below it are censored), cd/m^2; default the noise
        model's. Ignored when ``noise`` is given.
    dac_bits : int or None
        The display's DAC bits: levels are rounded to its grid (:func:`displayed_drive`);
        None uses them as given.
    zero_floor_cd_m2 : float or None
        What a reading of 0 stands for, cd/m^2 (the meter's own floor:
        :func:`calibration.noise.zero_bound`); default the floor. Ignored when ``noise`` is
        given (its own ``zero_floor_cd_m2`` counts).

    Returns
    -------
    GammaFit
        Parameters, residuals, leave-one-level-out errors, the noise model, the censored
        readings and the misfit statistics (with a warning when the fit fails them).

    Raises
    ------
    CalibrationError
        If the shapes differ, a level lies outside [0, 1], a reading is not finite, fewer than
        4 distinct levels are given, fewer than 3 levels lie above the meter's floor, the
        readings do not rise with the drive, or the model is unknown.
    """
    if model not in GAMMA_MODELS:
        raise CalibrationError(
            f"gamma model {model!r} is unknown; use one of {sorted(GAMMA_MODELS)}"
        )
    x, y = _check_readings(levels, luminance_cd_m2)
    x = displayed_drive(x, dac_bits)
    noise = noise or fit_noise(x, y, floor_cd_m2=floor_cd_m2, zero_floor_cd_m2=zero_floor_cd_m2)
    d = censored_readings(x, y, noise)
    _check_fittable(d, noise)
    params, linear = fit_one(model, d)
    fitted = gamma_luminance(x, model=model, params=params)
    heldout, z_all, level_loss = leave_one_level_out(model, d, linear)
    n_params = model_complexity(model, params)
    misfit, warnings = _misfit(model, d, fitted, n_params, noise)
    return GammaFit(
        model=model,
        params=params,
        rmse_cd_m2=float(np.sqrt(np.mean((y - fitted) ** 2))),
        heldout_rmse_cd_m2=float(np.sqrt(np.mean((y - heldout) ** 2))),
        levels=tuple(float(v) for v in x),
        luminance_cd_m2=tuple(float(v) for v in y),
        residuals_cd_m2=tuple(float(v) for v in y - fitted),
        heldout_rms_pct=float(100 * np.sqrt(np.mean((heldout_error(heldout, d)
                                                     / error_scale(y)) ** 2))),
        heldout_rms_z=float(np.sqrt(np.mean(z_all**2))),
        heldout_level_loss=tuple(float(v) for v in level_loss),
        n_params=int(n_params),
        noise=noise.to_dict(),
        censored=tuple(bool(c) for c in d.censored),
        misfit=misfit,
        warnings=warnings,
        dac_bits=dac_bits,
    )


def fit_gamma_models(levels, luminance_cd_m2, *, models=None, noise: NoiseModel | None = None,
                     floor_cd_m2: float | None = None,
                     dac_bits: int | None = DAC_BITS,
                     zero_floor_cd_m2: float | None = None) -> tuple[GammaFit, ...]:
    """Fit every model (default all of :data:`GAMMA_MODELS`) with one noise model.

    Same arguments as :func:`fit_gamma`; ``models`` restricts the family.
    """
    x, y = _check_readings(levels, luminance_cd_m2)
    x = displayed_drive(x, dac_bits)
    noise = noise or fit_noise(x, y, floor_cd_m2=floor_cd_m2, zero_floor_cd_m2=zero_floor_cd_m2)
    return tuple(fit_gamma(x, y, model=m, noise=noise, dac_bits=dac_bits)
                 for m in (models or GAMMA_MODELS))


def _rank(f: GammaFit) -> tuple[int, int]:
    n = f.n_params or len(GAMMA_MODELS.get(f.model, ()))
    pref = _PREFERENCE.index(f.model) if f.model in _PREFERENCE else len(_PREFERENCE)
    return n, pref


def choose_gamma_model(fits, *, tolerance: float = 0.02) -> GammaFit:
    """The simplest model whose held-out loss is within one standard error of the best.

    The loss is each level's mean squared held-out error in noise SDs
    (``heldout_level_loss``); its mean over levels is compared, and the standard error is that
    of the best model's mean (the one-standard-error rule). Simplicity: fewer parameters, then
    the order power, inner_power, offset_power, extended_power, ptb_sigmoid, ptb_weibull,
    ptb_crt_poly_linear, monotone_spline. Records written before the loss existed fall back to
    ``heldout_rms_pct`` (or ``heldout_rmse_cd_m2``), where a model with more parameters must
    beat a simpler one by more than ``tolerance`` (a fraction).

    Parameters
    ----------
    fits : sequence of GammaFit
    tolerance : float
        Only for old records (see above).

    Raises
    ------
    CalibrationError
        If ``fits`` is empty.
    """
    fits = list(fits)
    if not fits:
        raise CalibrationError("no gamma fits to choose from")
    if all(f.heldout_level_loss for f in fits):
        means = [float(np.mean(f.heldout_level_loss)) for f in fits]
        best = int(np.argmin(means))
        loss = np.asarray(fits[best].heldout_level_loss)
        se = float(np.std(loss, ddof=1) / np.sqrt(loss.size)) if loss.size > 1 else 0.0
        ok = [f for f, m in zip(fits, means) if m <= means[best] + se]
        return min(ok, key=_rank)
    relative = all(np.isfinite(f.heldout_rms_pct) for f in fits)

    def err(f: GammaFit) -> float:
        return f.heldout_rms_pct if relative else f.heldout_rmse_cd_m2

    fits = sorted(fits, key=lambda f: (_rank(f), err(f)))
    chosen = fits[0]
    for f in fits[1:]:
        if err(f) < err(chosen) * (1 - tolerance):
            chosen = f
    return chosen
