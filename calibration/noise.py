"""Photometer noise: SD^2 = a^2 + (b L)^2, fitted to repeated readings, and the meter's floor.

The gamma fit weights each reading by this SD (:mod:`calibration.gamma`). ``a`` (cd/m^2) is
the absolute noise that dominates near black; ``b`` the relative noise that dominates near
white. With repeated readings of a level both are fitted by maximum likelihood to the spread of
the repeats about their level's mean (which no display model can explain). Without repeats the
documented default :func:`default_noise` is used: ``a`` = 0.1 % of the brightest reading (the
last digit of a 3 1/2-digit reading on the range that holds white) and ``b`` = 0.5 % (the order
of a spot photometer's repeatability; chosen generous, so that a fit without repeats does not
over-weight any reading).

A reading at or below the meter's floor says only "no more than the floor": the fit treats it
as censored. The floor defaults to :data:`FLOOR_SD_MULTIPLE` absolute SDs (a reading within two
SDs of zero light cannot be told from none).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy.optimize import minimize

from calibration.errors import CalibrationError

__all__ = [
    "DEFAULT_ABS_FRACTION",
    "DEFAULT_REL",
    "FLOOR_SD_MULTIPLE",
    "METER_FLOORS_CD_M2",
    "NoiseModel",
    "default_noise",
    "fit_noise",
    "zero_bound",
]

#: Default absolute noise as a fraction of the brightest reading (no repeats).
DEFAULT_ABS_FRACTION = 1e-3
#: Default relative noise (no repeats).
DEFAULT_REL = 5e-3
#: A reading at or below this many absolute SDs is at the meter's floor (censored).
FLOOR_SD_MULTIPLE = 2.0
#: Smallest noise the fit allows, as fractions of the brightest reading (absolute) and of the
#: reading (relative): repeats that agree exactly (a noise-free simulation) still carry the
#: reading's rounding, 4 significant digits in every supported meter's reply, SD up to
#: 1e-3 / sqrt(12) = 3e-4 of the reading.
_MIN_ABS_FRACTION = 1e-6
_MIN_REL = 3e-4


#: The documented lowest luminance (cd/m^2) of photometers a lab names by ``device``, from the
#: maker's specification: a reading of 0 from one says the light was below it. Konica Minolta
#: LS-100: measuring range 0.001-299,900 cd/m^2 (its manual, "Specifications"). Photo Research
#: PR-650/655/670 are not listed: their manuals give the range per lens, aperture and
#: sensitivity mode, which a readings file does not record; a zero from them is bounded as from
#: an unknown meter (:func:`zero_bound`).
METER_FLOORS_CD_M2 = {"ls100": 0.001}


def zero_bound(device, lowest_positive: float | None, fallback: float) -> tuple[float, str]:
    """The upper bound, cd/m^2, a reading of 0 (or less) stands for, and where it comes from.

    A meter reads 0 when the light lies below its own floor; that floor, not the noise model's
    (two absolute SDs, a few thousandths of a cd/m^2 on a precise meter), is what a zero says.
    It is the documented floor where ``device`` names a meter of :data:`METER_FLOORS_CD_M2`;
    else, the floor being unknown, the most it can be: the lowest positive reading
    (``lowest_positive``: the meter read that much, so its floor lies below), or without one
    ``fallback``. Only zeros are censored at it: a positive reading is never censored because
    a zero sits below it.

    Was: the calibration censored a zero at its noise floor (0.0014 cd/m^2) although the
    meter's floor was 0.39 cd/m^2 and the display's black 0.31: the fit bent its curve to a
    black of 0.017 cd/m^2, and every check of that display read "a gap at black".
    """
    key = str(device or "").lower().replace("-", "").replace(" ", "")
    if key in METER_FLOORS_CD_M2:
        return METER_FLOORS_CD_M2[key], f"the {device}'s documented lowest luminance"
    if lowest_positive is not None and np.isfinite(lowest_positive) and lowest_positive > 0:
        return float(lowest_positive), ("the lowest positive reading (the meter's floor is not "
                                        "documented here: at most that)")
    return float(fallback), "the noise model's floor (two absolute noise SDs)"


@dataclass(frozen=True)
class NoiseModel:
    """Noise of one reading: ``sd(L) = sqrt(abs_cd_m2^2 + (rel L)^2)``.

    Attributes
    ----------
    abs_cd_m2 : float
        Absolute SD, cd/m^2.
    rel : float
        Relative SD (fraction of the reading).
    floor_cd_m2 : float
        Readings at or below this luminance are censored (the meter's floor), cd/m^2.
    source : str
        ``"repeats"`` (fitted to repeated readings), ``"default"`` (:func:`default_noise`) or
        ``"given"``.
    n_repeats : int
        Readings that shared a level with another (0 for the default).
    zero_floor_cd_m2 : float or None
        What a reading of 0 (or less) stands for: light at most this, cd/m^2 (the meter's own
        floor, :func:`zero_bound`); None: ``floor_cd_m2``.
    """

    abs_cd_m2: float
    rel: float
    floor_cd_m2: float
    source: str
    n_repeats: int = 0
    zero_floor_cd_m2: float | None = None

    @property
    def zero_floor(self) -> float:
        """The bound a zero is censored at, cd/m^2 (never below ``floor_cd_m2``)."""
        z = self.zero_floor_cd_m2
        return self.floor_cd_m2 if z is None else max(float(z), self.floor_cd_m2)

    def __post_init__(self) -> None:
        for name in ("abs_cd_m2", "rel"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise CalibrationError(f"noise {name} must be a positive number, got {v!r}")
        if not np.isfinite(self.floor_cd_m2):
            raise CalibrationError(f"noise floor_cd_m2 must be finite, got {self.floor_cd_m2!r}")
        z = self.zero_floor_cd_m2
        if z is not None and not np.isfinite(z):
            raise CalibrationError(f"noise zero_floor_cd_m2 (what a reading of 0 stands for) must "
                                   f"be a finite cd/m^2 or absent, got {z!r}: refit the "
                                   "calibration (`calibration fit DIR --out NEW`)")

    def sd(self, luminance_cd_m2) -> np.ndarray:
        """SD of a reading of ``luminance_cd_m2`` (cd/m^2; negative readings count as 0)."""
        y = np.maximum(np.asarray(luminance_cd_m2, dtype=float), 0.0)
        return np.sqrt(self.abs_cd_m2**2 + (self.rel * y) ** 2)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> NoiseModel:
        try:
            return cls(abs_cd_m2=float(d["abs_cd_m2"]), rel=float(d["rel"]),
                       floor_cd_m2=float(d["floor_cd_m2"]), source=str(d["source"]),
                       n_repeats=int(d.get("n_repeats", 0)),
                       zero_floor_cd_m2=(None if d.get("zero_floor_cd_m2") is None
                                         else float(d["zero_floor_cd_m2"])))
        except (KeyError, TypeError, ValueError) as exc:
            raise CalibrationError(f"noise record is malformed ({exc!r})") from exc


def _brightest(y: np.ndarray) -> float:
    return max(float(np.max(np.abs(y), initial=0.0)), 1e-6)


def default_noise(luminance_cd_m2, *, floor_cd_m2: float | None = None,
                  zero_floor_cd_m2: float | None = None) -> NoiseModel:
    """The documented default noise for readings without repeats (module docstring).

    Parameters
    ----------
    luminance_cd_m2 : array_like
        The readings (only the brightest is used).
    floor_cd_m2 : float or None
        The meter's floor; default :data:`FLOOR_SD_MULTIPLE` absolute SDs.
    zero_floor_cd_m2 : float or None
        What a zero stands for (:func:`zero_bound`); default the floor.
    """
    a = DEFAULT_ABS_FRACTION * _brightest(np.asarray(luminance_cd_m2, float))
    floor = FLOOR_SD_MULTIPLE * a if floor_cd_m2 is None else float(floor_cd_m2)
    return NoiseModel(abs_cd_m2=a, rel=DEFAULT_REL, floor_cd_m2=floor, source="default",
                      zero_floor_cd_m2=zero_floor_cd_m2)


def fit_noise(levels, luminance_cd_m2, *, floor_cd_m2: float | None = None,
              zero_floor_cd_m2: float | None = None) -> NoiseModel:
    """Noise model from repeated readings of the same level, else :func:`default_noise`.

    Maximum likelihood: each reading's deviation from its level's mean is normal with variance
    ``sd(mean)^2 (n - 1) / n`` (n readings at the level). Levels read at or below the floor
    (or at 0 when no floor is given) are left out (their spread is the meter's, not the
    display's).

    Parameters
    ----------
    levels, luminance_cd_m2 : array_like, shape (n,)
        Drive values and readings (cd/m^2).
    floor_cd_m2 : float or None
        The meter's floor, cd/m^2; default :data:`FLOOR_SD_MULTIPLE` fitted absolute SDs.
    zero_floor_cd_m2 : float or None
        What a zero stands for (:func:`zero_bound`); default the floor.

    Returns
    -------
    NoiseModel
        ``source`` says whether it came from repeats or is the default (fewer than 3 levels
        with repeats).
    """
    x = np.asarray(levels, dtype=float).ravel()
    y = np.asarray(luminance_cd_m2, dtype=float).ravel()
    top = _brightest(y)
    _, inv, counts = np.unique(x, return_inverse=True, return_counts=True)
    n = counts[inv].astype(float)
    means = np.bincount(inv, weights=y) / counts
    # A level read as 0 (or less) is at the meter's floor whatever the floor is taken to be:
    # its agreeing repeats say nothing about the noise above it.
    keep = (n >= 2) & (means[inv] > (0.0 if floor_cd_m2 is None else floor_cd_m2))
    if np.unique(inv[keep]).size < 3:
        return default_noise(y, floor_cd_m2=floor_cd_m2, zero_floor_cd_m2=zero_floor_cd_m2)
    dev = (y - means[inv])[keep]
    mu = np.maximum(means[inv][keep], 0.0)
    factor = (n[keep] - 1) / n[keep]
    amin, rmin = _MIN_ABS_FRACTION * top, _MIN_REL

    def nll(p):
        a, b = np.exp(p)
        var = np.maximum((a**2 + (b * mu) ** 2) * factor, 1e-300)
        return 0.5 * np.sum(np.log(var) + dev**2 / var)

    p0 = np.log([max(np.std(dev), amin), 0.003])
    # Noise-free readings drive both terms towards 0; the floors below stop them there.
    p0 = np.maximum(p0, np.log([amin, rmin]))
    best = minimize(nll, p0, method="Nelder-Mead", options={"xatol": 1e-6, "fatol": 1e-9})
    a, b = (max(float(v), m) for v, m in zip(np.exp(best.x), (amin, rmin)))
    floor = FLOOR_SD_MULTIPLE * a if floor_cd_m2 is None else float(floor_cd_m2)
    return NoiseModel(abs_cd_m2=a, rel=b, floor_cd_m2=floor, source="repeats",
                      n_repeats=int(keep.sum()), zero_floor_cd_m2=zero_floor_cd_m2)
