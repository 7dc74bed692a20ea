"""An independent display for the blind display benchmark: a gain-offset-gamma CRT and its
photometer, written apart from ``calibration.SimulatedCRT`` and from the diagnosis.

The gain-offset-gamma model of Berns (1996) ("Methods for characterizing CRT displays",
Displays 16(4)), cos^4-like vignetting instead of a quadratic falloff, a warm-up with its own
time constant, and a photometer whose noise has a shot-noise part (variance proportional to the
luminance) and which reports four significant digits, unlike the diagnosis's noise model
``sd^2 = a^2 + (b L)^2``. :func:`write_calibration_folder` and :func:`write_check_folder` write
a lab's files (the layout of ``python -m calibration run`` and ``check``); the cases and their
scoring are in :mod:`analysis.gapbench.bench_display`.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from labfiles import atomic_write_text

__all__ = ["T0", "GOGDisplay", "display_params", "display_schedule", "measure", "measure_warmup",
           "with_effect", "write_calibration_folder", "write_check_folder"]

_READING_S = 2.5  # one photometer reading (settle + integrate), s
#: The calibration run's power-on time (the readings' time stamps count from it).
T0 = pd.Timestamp("2026-03-02T08:00:00Z")


@dataclass(frozen=True)
class GOGDisplay:
    """A CRT by the gain-offset-gamma model, with its own vignetting, warm-up and photometer.

    Luminance at drive ``d`` (8-bit DAC), position (x, y) norm, ``t_s`` s after power-on::

        above = white * max(kg d + ko, 0)^gamma       kg + ko = 1 (Berns 1996, eq. 1)
        above *= 1 / (1 + vignetting r^2)^2             r^2 = x^2 + y^2 (cos^4-like)
        above *= 1 - warmup_frac exp(-t / warmup_tau_s)
        L = black + ambient + above
        read: L + N(0, floor^2 + shot L + (rel L)^2), rounded to ``digits`` significant digits

    ================  =======  ====================================================
    parameter         unit     meaning
    ================  =======  ====================================================
    white_cd_m2       cd/m^2   light above black at full drive, centre, warm
    gain              -        GOG gain kg (the offset is 1 - kg)
    gamma             -        GOG exponent
    black_cd_m2       cd/m^2   light emitted at drive 0
    ambient_cd_m2     cd/m^2   room light reflected by the screen
    vignetting        -        cos^4-like loss towards the corners
    gradient_x        -        left-right gradient of the above-black light, per norm
    warmup_frac       -        deficit of the above-black light at power-on
    warmup_tau_s      s        warm-up time constant
    dac_bits          -        DAC bits per gun
    floor_cd_m2       cd/m^2   photometer's dark noise (SD)
    shot_cd_m2        cd/m^2   shot-noise variance per cd/m^2
    rel_noise         -        relative noise (SD)
    digits            -        significant digits the photometer reports
    mid_gamma_bump    -        out of catalogue: above-black light x (1 + b sin(pi d)^2)
    gamma_gradient    -        out of catalogue: gamma + this x (a position x level interaction)
    load_dimming      -        out of catalogue: above-black light x (1 - this x area), area
                               the bright share of the screen (a condition of the reading)
    meter_floor_cd_m2 cd/m^2   the photometer reads 0 below this (its floor)
    ================  =======  ====================================================
    """

    white_cd_m2: float = 82.0
    gain: float = 1.05
    gamma: float = 2.3
    black_cd_m2: float = 0.15
    ambient_cd_m2: float = 0.2
    vignetting: float = 0.09
    gradient_x: float = 0.015
    warmup_frac: float = 0.0
    warmup_tau_s: float = 450.0
    dac_bits: int = 8
    floor_cd_m2: float = 0.004
    shot_cd_m2: float = 2e-4
    rel_noise: float = 0.0025
    digits: int = 4
    mid_gamma_bump: float = 0.0
    gamma_gradient: float = 0.0
    load_dimming: float = 0.0
    meter_floor_cd_m2: float = 0.0

    def luminance(self, drive, x_norm, y_norm, t_s, area=0.0) -> np.ndarray:
        """Noiseless luminance, cd/m^2 (``t_s`` = inf: warmed up; ``area``: the bright share
        of the rest of the screen)."""
        d = np.asarray(drive, float)
        x, y = np.asarray(x_norm, float), np.asarray(y_norm, float)
        steps = 2 ** int(self.dac_bits) - 1
        q = np.round(d * steps) / steps
        g = self.gamma + self.gamma_gradient * x
        above = self.white_cd_m2 * np.maximum(self.gain * q + 1 - self.gain, 0.0) ** g
        above = above * (1 + self.mid_gamma_bump * np.sin(np.pi * q) ** 2)
        above = above / (1 + self.vignetting * (x**2 + y**2)) ** 2 * (1 + self.gradient_x * x)
        above = above * (1 - self.warmup_frac * np.exp(-np.asarray(t_s, float)
                                                         / self.warmup_tau_s))
        above = above * (1 - self.load_dimming * np.asarray(area, float))
        return self.black_cd_m2 + self.ambient_cd_m2 + above

    def read(self, drive, x_norm, y_norm, t_s, rng: np.random.Generator,
             area=0.0) -> np.ndarray:
        """What the photometer reports, cd/m^2 (0 below its floor)."""
        lum = self.luminance(drive, x_norm, y_norm, t_s, area)
        sd = np.sqrt(self.floor_cd_m2**2 + self.shot_cd_m2 * lum + (self.rel_noise * lum) ** 2)
        out = np.maximum(lum + sd * rng.standard_normal(lum.shape), 1e-4)
        mag = np.floor(np.log10(out))
        scale = 10.0 ** (self.digits - 1 - mag)
        return np.where(out < self.meter_floor_cd_m2, 0.0, np.round(out * scale) / scale)

    def extended_power(self) -> dict:
        """The centre's warm transfer function as ``extended_power`` parameters (exact for the
        GOG model: a + k max(d - x0, 0)^gamma, k = white kg^gamma, x0 = (kg - 1) / kg)."""
        return {"a": self.black_cd_m2 + self.ambient_cd_m2,
                "k": self.white_cd_m2 * self.gain**self.gamma,
                "x0": (self.gain - 1) / self.gain, "gamma": self.gamma}


# --- measuring ----------------------------------------------------------------------------

def display_schedule(rng: np.random.Generator, *, positions=3, extent: float = 0.6,
                     n_levels: int = 17, n_other: int = 5, repeats: int = 2,
                     order: str = "shuffled") -> pd.DataFrame:
    """Patches to measure, in measuring order.

    ``order``: "shuffled" (every position's patches and repeats shuffled, the calibration
    procedure's order), "passes" (all patches once, then all again: repeats far apart in time)
    or "consecutive" (each patch's repeats back to back).
    """
    if order not in ("shuffled", "passes", "consecutive"):
        raise ValueError(f"order {order!r}: use 'shuffled', 'passes' or 'consecutive'")
    v = np.linspace(-extent, extent, positions) if positions > 1 else np.zeros(1)
    pos = [(0.0, 0.0)] + [(float(x), float(y)) for y in v[::-1] for x in v
                          if (abs(x), abs(y)) != (0.0, 0.0)]
    patches = []
    for x, y in pos:
        n = n_levels if (x, y) == (0.0, 0.0) else n_other
        patches += [(x, y, float(lv)) for lv in np.unique(np.round(np.linspace(0, 1, n) * 255))
                    / 255]
    if order == "consecutive":
        rows = [(*p, r) for i in rng.permutation(len(patches)) for p in [patches[i]]
                for r in range(repeats)]
    elif order == "passes":
        rows = [(*patches[i], r) for r in range(repeats) for i in rng.permutation(len(patches))]
    else:
        rows = []
        for x, y in pos:
            block = [(*p, r) for r in range(repeats) for p in patches if p[:2] == (x, y)]
            rows += [block[i] for i in rng.permutation(len(block))]
    return pd.DataFrame(rows, columns=["x_norm", "y_norm", "level", "repeat"])


def measure(display: GOGDisplay, schedule: pd.DataFrame, rng: np.random.Generator, *,
            calibration_id: str, start_s: float, device: str = "pr655") -> pd.DataFrame:
    """Readings (calibration.READINGS_COLUMNS) of the schedule, one every 2.5 s from
    ``start_s`` s after power-on."""
    t = start_s + _READING_S * np.arange(len(schedule))
    area = schedule.get("bright_area", 0.0)
    lum = display.read(schedule["level"], schedule["x_norm"], schedule["y_norm"], t, rng, area)
    out = schedule.copy()
    out["calibration_id"] = calibration_id
    out["timestamp_utc"] = [(T0 + pd.Timedelta(seconds=float(s))).strftime(
        "%Y-%m-%dT%H:%M:%S.%fZ") for s in t]
    out["device"] = device
    out["luminance_cd_m2"] = lum
    out["raw_reply"] = [f"0,{v:.5g}" for v in lum]
    extra = ["bright_area"] if "bright_area" in schedule else []
    return out[["calibration_id", "timestamp_utc", "device", "x_norm", "y_norm", "level",
                "repeat", "luminance_cd_m2", "raw_reply", *extra]]


def measure_warmup(display: GOGDisplay, rng: np.random.Generator, *, calibration_id: str,
                   n: int = 40, every_s: float = 15.0) -> pd.DataFrame:
    """White at the centre from power-on, every ``every_s`` s (repeat = index in time)."""
    sched = pd.DataFrame({"x_norm": 0.0, "y_norm": 0.0, "level": 1.0,
                          "repeat": np.arange(n)})
    out = measure(display, sched, rng, calibration_id=calibration_id, start_s=0.0)
    t = every_s * np.arange(n)
    out["luminance_cd_m2"] = display.read(np.ones(n), np.zeros(n), np.zeros(n), t, rng)
    out["timestamp_utc"] = [(T0 + pd.Timedelta(seconds=float(s))).strftime(
        "%Y-%m-%dT%H:%M:%S.%fZ") for s in t]
    out["raw_reply"] = [f"0,{v:.5g}" for v in out["luminance_cd_m2"]]
    return out


def _write_csv(frame: pd.DataFrame, path: Path) -> Path:
    atomic_write_text(path, frame.to_csv(index=False))
    return path


def write_calibration_folder(folder, display: GOGDisplay, rng: np.random.Generator, *,
                             calibration_id: str = "lab-cal", repeats: int = 3,
                             fit: str = "truth", order: str = "shuffled",
                             start_s: float = 3600.0, n_validation: int = 17) -> Path:
    """A lab's calibration folder measured on ``display`` (warm: ``start_s`` after power-on).

    ``fit``: "truth" writes the display's own transfer function (a calibration whose gamma fit
    is right, so no case depends on the gamma fit's accuracy); "fitted" fits the extended
    power model to the centre's readings with ``calibration.fit_gamma_models``. The
    uniformity map is fitted to the readings either way; validation readings at
    ``n_validation`` gamma-corrected fractions follow the readings. Returns the folder.
    """
    from calibration import Calibration, fit_gamma_models, fit_uniformity, save_calibration

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    sched = display_schedule(rng, repeats=repeats, order=order)
    read = measure(display, sched, rng, calibration_id=calibration_id, start_s=start_s)
    centre = read[(read["x_norm"] == 0) & (read["y_norm"] == 0)]
    fits = fit_gamma_models(centre["level"].to_numpy(float),
                            centre["luminance_cd_m2"].to_numpy(float))
    if fit == "truth":
        params = display.extended_power()
    elif fit == "fitted":
        params = dict(next(f for f in fits if f.model == "extended_power").params)
    else:
        raise ValueError(f"fit {fit!r}: use 'truth' or 'fitted'")
    from calibration import gamma_luminance

    lmin = float(gamma_luminance(0.0, model="extended_power", params=params))
    lmax = float(gamma_luminance(1.0, model="extended_power", params=params))
    cal = Calibration(calibration_id=calibration_id, created_utc="2026-03-02T09:30:00Z",
                      device="pr655", monitor_name="lab-crt", resolution_px=(1280, 1024),
                      width_cm=40.0, distance_cm=57.0, refresh_hz=85.0,
                      gamma_model="extended_power", gamma_params=params,
                      min_luminance_cd_m2=lmin, max_luminance_cd_m2=lmax, fits=fits,
                      uniformity=fit_uniformity(read), readings_file="readings.csv")
    _write_csv(read, folder / "readings.csv")
    if n_validation:
        frac = np.linspace(0, 1, n_validation)
        drive = np.round(cal.drive_for_fraction(frac) * 255) / 255
        vs = pd.DataFrame({"x_norm": 0.0, "y_norm": 0.0, "level": drive, "repeat": 0})
        val = measure(display, vs, rng, calibration_id=calibration_id,
                      start_s=start_s + _READING_S * (len(read) + 5))
        val["target_fraction"] = frac
        _write_csv(val, folder / "validation.csv")
    save_calibration(cal, folder / "calibration.json")
    return folder


def write_check_folder(folder, display: GOGDisplay, rng: np.random.Generator, *,
                       calibration: Path, checked_id: str = "lab-cal", repeats: int = 2,
                       order: str = "shuffled", warmup: bool = True,
                       start_s: float = 1800.0, positions: int = 3,
                       n_levels: int = 9, n_other: int = 5, areas=None) -> Path:
    """A check run's folder as ``python -m calibration check`` writes it: ``readings.csv`` (a
    few levels at a few positions, the check's own calibration_id), ``warmup.csv`` (white at
    the centre from power-on) and ``check.json``. ``areas``: measure the patches once per
    bright share of the screen, in blocks in this order (column ``bright_area``, a lab's
    condition). Returns the folder."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    check_id = f"{checked_id}-check-20260309T0800Z"
    sched = display_schedule(rng, positions=positions, n_levels=n_levels, n_other=n_other,
                             repeats=repeats, order=order)
    if areas is not None:
        sched = pd.concat([sched.assign(bright_area=float(a)) for a in areas],
                          ignore_index=True)
    read = measure(display, sched, rng, calibration_id=check_id, start_s=start_s)
    _write_csv(read, folder / "readings.csv")
    summary = {}
    if warmup:
        wu = measure_warmup(display, rng, calibration_id=check_id)
        _write_csv(wu, folder / "warmup.csv")
        summary = {"n": len(wu), "first_cd_m2": float(wu["luminance_cd_m2"].iloc[0]),
                   "last_cd_m2": float(wu["luminance_cd_m2"].iloc[-1])}
    record = {"kind": "check", "check_id": check_id, "checked_calibration_id": checked_id,
              "checked_calibration": str(calibration), "created_utc": "2026-03-09T09:00:00Z",
              "deviation": [], "warmup": summary}
    atomic_write_text(folder / "check.json", json.dumps(record, indent=1))
    return folder


def display_params(display: GOGDisplay) -> dict:
    """The display's parameters (recorded with a case)."""
    return asdict(display)


# --- catalogue effects on the independent display ------------------------------------------
# Each catalogue effect as a change of the GOG display's own parameters (its physics, not the
# candidate's formula), and the parameters a right fit should recover.

#: Each effect as a change of the GOG display's own parameters: (display, strength) -> display.
_GOG_EFFECTS = {
    "black_offset": lambda d, s: replace(d, ambient_cd_m2=d.ambient_cd_m2 + s),
    "nonuniformity": lambda d, s: replace(d, vignetting=d.vignetting + s,
                                          gradient_x=d.gradient_x + s / 2),
    "warmup_drift": lambda d, s: replace(d, warmup_frac=s),
    "quantisation": lambda d, s: replace(d, dac_bits=round(d.dac_bits - s)),
    "mid_gamma_bump": lambda d, s: replace(d, mid_gamma_bump=s),
    "gamma_gradient": lambda d, s: replace(d, gamma_gradient=s),
    "gain_change": lambda d, s: replace(d, white_cd_m2=d.white_cd_m2 * (1 + s)),
    "load_dimming": lambda d, s: replace(d, load_dimming=s),
}


def with_effect(display: GOGDisplay, effect: str, strength: float) -> GOGDisplay:
    """``display`` with one effect (a catalogue effect or one of :data:`OUT_OF_CATALOGUE`)."""
    if effect not in _GOG_EFFECTS:
        raise ValueError(f"no GOG display change for effect {effect!r}; known: "
                         f"{sorted(_GOG_EFFECTS)}")
    return _GOG_EFFECTS[effect](display, float(strength))
