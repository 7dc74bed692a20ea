"""The simulated CRT the fake photometer measures: every display effect a named parameter.

Luminance at drive ``d`` in [0, 1], position (x_norm, y_norm) in norm units ([-1, 1], centre 0,
y up), ``t_s`` seconds after the display was switched on::

    q      = round(d * (2**bits - 1)) / (2**bits - 1)            # the DAC's quantisation
    beam   = max(q - cutoff, 0) / (1 - cutoff)                     # gun threshold (black level knob)
    space  = 1 - falloff * (x^2 + y^2) / 2 + tilt_x * x            # spatial non-uniformity
    warm   = 1 - warmup_drift * exp(-t_s / warmup_tau_s)           # warm-up drift
    L      = ambient + black + white * beam^gamma * space * warm   # cd/m^2, before noise
    L_meas = L * (1 + noise_rel * N(0, 1)) + noise_abs * N(0, 1)   # photometer noise

so the true transfer function at the centre after warm-up is the extended power function with
offset (:mod:`calibration.gamma`), with a = ambient + black, k = white / (1 - cutoff)^gamma,
x0 = cutoff.

==================  =====  ========  ===========================================================
parameter           unit   default   meaning
==================  =====  ========  ===========================================================
gamma               -      2.4       exponent of the gun's transfer function
white_cd_m2         cd/m2  95.0      peak luminance above black at the centre, warmed up
black_cd_m2         cd/m2  0.25      light emitted at drive 0
ambient_cd_m2       cd/m2  0.35      room light reflected by the screen (adds to black)
cutoff              -      0.04      drive below which the gun emits nothing
falloff             -      0.12      fractional loss at the corners (x = y = +-1)
tilt_x              -      0.02      left-right gradient (fraction per norm unit)
warmup_drift        -      0.0       fractional deficit at switch-on (0: warmed up)
warmup_tau_s        s      600.0     time constant of the warm-up
noise_rel           -      0.003     relative measurement noise (SD)
noise_abs           cd/m2  0.005     absolute measurement noise (SD)
bits                -      8         DAC bits per gun
==================  =====  ========  ===========================================================
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from calibration.errors import CalibrationError

__all__ = ["SimulatedCRT", "default_crt_path", "load_crt"]


@dataclass(frozen=True)
class SimulatedCRT:
    """A CRT as a pure function of drive, position, time since switch-on and a generator.

    See the module docstring for the equations and the table of parameters.
    """

    gamma: float = 2.4
    white_cd_m2: float = 95.0
    black_cd_m2: float = 0.25
    ambient_cd_m2: float = 0.35
    cutoff: float = 0.04
    falloff: float = 0.12
    tilt_x: float = 0.02
    warmup_drift: float = 0.0
    warmup_tau_s: float = 600.0
    noise_rel: float = 0.003
    noise_abs: float = 0.005
    bits: int = 8

    def __post_init__(self) -> None:
        checks = [
            (0.3 <= self.gamma <= 6, "gamma must lie in [0.3, 6]"),
            (self.white_cd_m2 > 0, "white_cd_m2 must be > 0"),
            (self.black_cd_m2 >= 0 and self.ambient_cd_m2 >= 0,
             "black_cd_m2 and ambient_cd_m2 must be >= 0"),
            (0 <= self.cutoff < 0.5, "cutoff must lie in [0, 0.5)"),
            (0 <= self.falloff < 1 and abs(self.tilt_x) < 0.5,
             "falloff must lie in [0, 1) and |tilt_x| < 0.5"),
            (0 <= self.warmup_drift < 1 and self.warmup_tau_s > 0,
             "warmup_drift must lie in [0, 1) and warmup_tau_s > 0"),
            (self.noise_rel >= 0 and self.noise_abs >= 0, "noise_rel and noise_abs must be >= 0"),
            (isinstance(self.bits, int) and 1 <= self.bits <= 16, "bits must be an int in 1..16"),
        ]
        for ok, msg in checks:
            if not ok:
                raise CalibrationError(f"simulated CRT: {msg} (got {self})")

    @property
    def black_total_cd_m2(self) -> float:
        """Luminance at drive 0 including reflected ambient light, cd/m^2."""
        return self.ambient_cd_m2 + self.black_cd_m2

    def luminance(self, drive, x_norm=0.0, y_norm=0.0, t_s=math.inf, rng=None) -> np.ndarray:
        """Luminance a photometer would read, cd/m^2.

        Parameters
        ----------
        drive : array_like
            Drive values in [0, 1].
        x_norm, y_norm : array_like
            Position of the measured spot in norm units ([-1, 1], centre 0, y up).
        t_s : array_like
            Seconds since the display was switched on (``inf``: fully warmed up).
        rng : numpy.random.Generator or None
            Source of measurement noise; ``None`` gives the noiseless luminance.

        Returns
        -------
        ndarray
            Broadcast shape of the inputs.

        Raises
        ------
        CalibrationError
            If a drive value lies outside [0, 1].
        """
        d = np.asarray(drive, dtype=float)
        if np.any(~np.isfinite(d) | (d < 0) | (d > 1)):
            raise CalibrationError(f"drive must lie in [0, 1], got {drive!r}")
        x = np.asarray(x_norm, dtype=float)
        y = np.asarray(y_norm, dtype=float)
        t = np.asarray(t_s, dtype=float)
        steps = 2**self.bits - 1
        q = np.round(d * steps) / steps
        beam = np.maximum(q - self.cutoff, 0.0) / (1.0 - self.cutoff)
        space = 1.0 - self.falloff * (x**2 + y**2) / 2.0 + self.tilt_x * x
        warm = 1.0 - self.warmup_drift * np.exp(-t / self.warmup_tau_s)
        lum = self.black_total_cd_m2 + self.white_cd_m2 * beam**self.gamma * space * warm
        if rng is not None:
            shape = np.broadcast(lum, x, y, t).shape
            lum = lum * (1 + self.noise_rel * rng.standard_normal(shape))
            lum = lum + self.noise_abs * rng.standard_normal(shape)
        return lum

    def true_gamma_params(self) -> dict:
        """The centre's warmed-up transfer function as ``extended_power`` parameters."""
        return {
            "a": self.black_total_cd_m2,
            "k": self.white_cd_m2 / (1 - self.cutoff) ** self.gamma,
            "x0": self.cutoff,
            "gamma": self.gamma,
        }

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> SimulatedCRT:
        known = {f.name: f for f in fields(cls)}
        unknown = sorted(set(d) - set(known))
        if unknown:
            raise CalibrationError(
                f"simulated CRT: unknown parameter(s) {unknown}; known: {sorted(known)}"
            )
        kw = {}
        for k, v in d.items():
            kw[k] = int(v) if k == "bits" else float(v)
        return cls(**kw)


def default_crt_path() -> Path:
    """The shipped ``crt.toml`` (the simulated CRT's parameters)."""
    return Path(__file__).with_name("crt.toml")


def load_crt(path=None) -> SimulatedCRT:
    """Load a simulated CRT from a TOML file whose ``[crt]`` table holds the parameters.

    Raises
    ------
    CalibrationError
        If the file is missing, not TOML, or holds an unknown or invalid parameter.
    """
    from calibration.tomlfile import read_toml

    path = Path(path) if path is not None else default_crt_path()
    data = read_toml(path, "display file", missing_fix="pass --display crt.toml")
    if "crt" not in data:
        raise CalibrationError(f"display file {path} has no [crt] table")
    try:
        return SimulatedCRT.from_dict(data["crt"])
    except CalibrationError as exc:
        raise CalibrationError(f"display file {path}: {exc}") from exc
