"""Benchmark injectors: pseudo-real data with a hidden effect (observer, display, render).

The diagnosis never imports this module, nor the simulators used here (the experiment's
observers, calibration.SimulatedCRT); tests/analysis/gap/test_gap.py and
tests/analysis/gapbench/test_independence.py check the import graph."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from analysis.gap import OutOfCatalogue, catalogue, out_of_catalogue, strengths
from analysis.gap import effect as _effect
from analysis.gap import register_out_of_catalogue as _register_out
from analysis.gapbench.inject_render import (  # noqa: F401  (the render part, re-exported)
    _LEVELS,
    _PHOTONS,
    _READ_REL,
    _LightStudio,
    _masks,
    _sphere_r,
    _Studio,
    write_fit_setup,
    write_light_set_with,
    write_render_fit,
)

# Also public, derived when read (module __getattr__, see _DERIVED): OBSERVER_EFFECTS,
# OUT_OF_CATALOGUE, OUT_OF_CATALOGUE_STRENGTH, DISPLAY_EFFECTS, DISPLAY_OUT_OF_CATALOGUE,
# DISPLAY_STRENGTH, RENDER_EFFECTS, RENDER_OUT_OF_CATALOGUE, RENDER_STRENGTH.
__all__ = [
    "display_truth",
    "ideal_noise_sd",
    "lab_names",
    "observer_injector",
    "simulate_readings",
    "simulate_sessions",
    "write_calibration",
    "write_fit_setup",
    "write_light_set_with",
    "write_readings",
    "write_render_fit",
    "write_sessions",
]

#: The tables the benchmark reads, each derived from the effect objects (the candidates
#: registered with the engine by the layer modules, the out-of-catalogue effects registered
#: below), so that an effect's name and strength are written once, in its object.
_DERIVED = {
    "OBSERVER_EFFECTS": lambda: _names("observer"),
    "OUT_OF_CATALOGUE": lambda: _names("observer", out=True),
    "OUT_OF_CATALOGUE_STRENGTH": lambda: _strength("observer", out=True),
    "DISPLAY_EFFECTS": lambda: _names("display"),
    "DISPLAY_OUT_OF_CATALOGUE": lambda: _names("display", out=True),
    "DISPLAY_STRENGTH": lambda: strengths("display"),
    "RENDER_EFFECTS": lambda: _names("render"),
    "RENDER_OUT_OF_CATALOGUE": lambda: _names("render", out=True),
    "RENDER_STRENGTH": lambda: strengths("render"),
}


def __getattr__(name: str):
    """The derived tables (:data:`_DERIVED`), computed when read: the catalogues load their
    layer modules on first use."""
    if name in _DERIVED:
        return _DERIVED[name]()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _names(layer: str, *, out: bool = False) -> tuple[str, ...]:
    return tuple(e.name for e in (out_of_catalogue(layer) if out else catalogue(layer)))


def _strength(layer: str, *, out: bool) -> dict[str, float]:
    return {e.name: float(e.default_strength)
            for e in (out_of_catalogue(layer) if out else catalogue(layer))}


def ideal_noise_sd(design) -> dict:
    """The experiment's ideal observer's trial noise in slider units ({'gloss', 'depth'})."""
    from experiment import load_observer_params

    p = load_observer_params()["ideal"]
    return {"gloss": float(p["gloss_noise_pct"]) / design.slider.gloss_pct_per_unit,
            "depth": float(p["depth_noise_cm"]) / design.slider.depth_cm_per_unit}


def lab_names(design) -> dict:
    """Illumination names the benchmark's pseudo-real files use (not the design's)."""
    return {i.name: f"lab_probe_{k + 1}" for k, i in enumerate(design.illuminations)}


def _depth_noise_scaling(ctx, s, rng):
    """Noise SD growing with depth: x (1 + 3 s (depth - mid) / mid), at least 0.1."""
    scale = np.maximum(1 + s * 3 * (ctx["truth"]["depth"] - ctx["mid"]) / ctx["mid"], 0.1)
    return {r: np.clip(ctx["mu"][r] + scale * ctx["noise"][r], ctx["lo"], ctx["hi"])
            for r in ("gloss", "depth")}


def _stimulus_bias(ctx, s, rng):
    """A gloss bias of +-3 s slider units alternating between stimuli (a checkerboard)."""
    sign = np.where((ctx["gloss_level"] * 7 + ctx["depth_level"] * 3) % 2 == 1, 1.0, -1.0)
    mu = dict(ctx["mu"])
    mu["gloss"] = mu["gloss"] + s * 3 * sign
    return {r: np.clip(mu[r] + ctx["noise"][r], ctx["lo"], ctx["hi"]) for r in ("gloss", "depth")}


_register_out("observer", OutOfCatalogue(
    "depth_noise_scaling", _depth_noise_scaling, 0.3, "relative noise growth across depth",
    "response noise growing with depth (heteroscedastic)"))
_register_out("observer", OutOfCatalogue(
    "stimulus_bias", _stimulus_bias, 0.3, "x 3 slider units",
    "a gloss bias alternating between stimuli (a checkerboard)"))


def observer_injector(name: str):
    """The injector of an observer effect: the catalogue candidate's own or an
    out-of-catalogue effect's (:func:`analysis.gap.effect`). Raises GapError for an
    unknown name, listing the known ones."""
    return _effect("observer", name).inject


def simulate_sessions(design, n_participants: int, rng: np.random.Generator,
                      effect: str = "none", strength: float = 0.0, *,
                      lab_files: bool = False) -> pd.DataFrame:
    """Session rows (experiment.SESSION_COLUMNS) of the experiment's ``ideal`` observers
    (experiment.make_observer / simulate_dataset: the app's plans, noise and file format),
    with one effect added in slider units before the slider's clipping by the effect's
    injector (:func:`observer_injector`).

    ``lab_files``: rename illuminations (:func:`lab_names`) and stimulus ids as a lab's own
    files might, so the diagnosis cannot rely on the design's names.
    """
    from analysis.gap import to_slider_units
    from experiment import make_observer, simulate_dataset

    s = design.slider
    mid = 0.5 * (s.min + s.max)
    inject = None if effect == "none" else observer_injector(effect)
    names = lab_names(design) if lab_files else {i.name: i.name for i in design.illuminations}
    frames = []
    for p in range(n_participants):
        obs = make_observer("ideal", f"B{p:02d}", rng, design=design)
        frame = simulate_dataset(design, [obs], rng, calibration_id="bench")
        frame = frame.sort_values(["session", "trial"], ignore_index=True)
        tg = frame["true_gloss_pct"].to_numpy(float)
        td = frame["true_depth_cm"].to_numpy(float)
        eg, ed = obs.estimate(tg, td, rng)
        tgu, tdu = to_slider_units(s, tg, td)
        egu, edu = to_slider_units(s, eg, ed)
        truth = {"gloss": tgu, "depth": tdu}
        if inject is None:
            resp = {"gloss": np.clip(egu, s.min, s.max), "depth": np.clip(edu, s.min, s.max)}
        else:
            ses = frame["session"].to_numpy(int)
            ctx = {"truth": truth, "mu": dict(truth),
                   "noise": {"gloss": egu - tgu, "depth": edu - tdu},
                   "mid": mid, "lo": float(s.min), "hi": float(s.max),
                   "illumination": frame["illumination"].map(names).to_numpy(str),
                   "illuminations": [names[i.name] for i in design.illuminations],
                   "session_start": np.r_[True, ses[1:] != ses[:-1]],
                   "gloss_level": frame["gloss_level"].to_numpy(int),
                   "depth_level": frame["depth_level"].to_numpy(int)}
            resp = inject(ctx, float(strength), rng)
        frame["gloss_match"] = resp["gloss"]
        frame["depth_match"] = resp["depth"]
        frames.append(frame)
    out = pd.concat(frames, ignore_index=True)
    if lab_files:
        out["illumination"] = out["illumination"].map(lab_names(design))
        out["stimulus_id"] = [f"LAB-{i:05d}" for i in range(len(out))]
    return out


def write_sessions(frame: pd.DataFrame, folder: Path) -> None:
    """One CSV per participant and session, ``folder/<P>_s<N>.csv`` (the app's naming and
    columns, experiment.SESSION_COLUMNS); an existing file is never replaced."""
    from experiment import SESSION_COLUMNS
    from labfiles import write_new_file

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for (p, ses), grp in frame.groupby(["participant", "session"]):
        write_new_file(folder / f"{p}_s{ses}.csv",
                       grp[list(SESSION_COLUMNS)].to_csv(index=False))


# --- display layer ------------------------------------------------------------------------
# Pseudo-real photometer readings from calibration.SimulatedCRT with one effect changed; the
# diagnosis reads only readings.csv and calibration.json.

_SECONDS_PER_READING = 3.0
_BLEMISH_AT = (0.6, 0.6)


def display_schedule(rng: np.random.Generator, *, grid: int = 3, extent: float = 0.6,
                     n_levels: int = 17, n_uniformity: int = 5, repeats: int = 2):
    """Patches as the calibration procedure measures them: every level at the centre, a few
    levels elsewhere, each repeated, shuffled within each position."""
    v = np.linspace(-extent, extent, grid)
    rows = []
    for y in v[::-1]:
        for x in v:
            centre = abs(x) < 1e-9 and abs(y) < 1e-9
            n = n_levels if centre else n_uniformity
            lv = np.unique(np.round(np.linspace(0, 1, n) * 255)) / 255
            block = [(float(x), float(y), float(level), r) for r in range(repeats) for level in lv]
            rows += [block[i] for i in rng.permutation(len(block))]
    return pd.DataFrame(rows, columns=["x_norm", "y_norm", "level", "repeat"])


def display_crt(name: str = "none", strength: float = 0.0):
    """The benchmark's display: the shipped simulated CRT with one effect changed by its
    object's injector (a candidate's or an out-of-catalogue effect's, ``(crt, strength) ->
    display``; a display has ``luminance(level, x_norm, y_norm, t_s)``)."""
    from calibration import load_crt

    crt = load_crt()
    if name == "none":
        return crt
    return _effect("display", name).inject(crt, strength)


def _scaled_gamma(crt, strength):
    from dataclasses import replace

    return replace(crt, gamma=crt.gamma * (1 + strength))


class _Blemished:
    """The CRT with a blemish at one measured position (``_BLEMISH_AT``): the light above
    black there dimmed by a share ``strength``."""

    def __init__(self, crt, strength: float):
        self.crt, self.strength = crt, float(strength)

    def luminance(self, level, x_norm, y_norm, t_s):
        lum = self.crt.luminance(level, x_norm, y_norm, t_s)
        at = np.isclose(x_norm, _BLEMISH_AT[0]) & np.isclose(y_norm, _BLEMISH_AT[1])
        black = self.crt.black_total_cd_m2
        return np.where(at, black + (lum - black) * (1 - self.strength), lum)


_register_out("display", OutOfCatalogue(
    "gamma_change", _scaled_gamma, 0.03, "relative change of the gamma exponent",
    "the display's gamma changed since the calibration"))
_register_out("display", OutOfCatalogue(
    "local_blemish", _Blemished, 0.03, "share of the light lost at one position",
    "a blemish dimming one measured position"))


def display_truth(name: str, strength: float, schedule: pd.DataFrame,
                  t_s: np.ndarray) -> np.ndarray:
    """Noiseless luminance (cd/m^2) of the benchmark's display with the effect."""
    crt = display_crt(name, strength)
    t = t_s if name == "warmup_drift" else np.full(len(schedule), np.inf)
    return crt.luminance(schedule["level"].to_numpy(float), schedule["x_norm"].to_numpy(float),
                         schedule["y_norm"].to_numpy(float), t)


def display_noise_sd(lum: np.ndarray) -> np.ndarray:
    from calibration import load_crt

    crt = load_crt()
    return np.sqrt((crt.noise_rel * lum) ** 2 + crt.noise_abs**2)


def simulate_readings(rng: np.random.Generator, effect: str = "none", strength: float = 0.0,
                      calibration_id: str = "bench", repeats: int = 2) -> pd.DataFrame:
    """A readings.csv frame: the schedule measured on the display with the effect (warm-up
    drift: measured from switch-on; otherwise warmed up)."""
    from calibration import READINGS_COLUMNS

    sched = display_schedule(rng, repeats=repeats)
    t_s = np.arange(len(sched)) * _SECONDS_PER_READING
    lum = display_truth(effect, strength, sched, t_s)
    lum = lum + display_noise_sd(lum) * rng.standard_normal(lum.shape)
    t0 = pd.Timestamp("2026-01-05T09:00:00Z")
    out = sched.copy()
    out["calibration_id"] = calibration_id
    out["timestamp_utc"] = [(t0 + pd.Timedelta(seconds=float(s))).strftime(
        "%Y-%m-%dT%H:%M:%S.%fZ") for s in t_s]
    out["device"] = "pr655"
    out["luminance_cd_m2"] = lum
    out["raw_reply"] = [f"0,{v:.4f}" for v in lum]
    out.attrs["t_s"] = t_s
    return out[list(READINGS_COLUMNS)]


def write_calibration(rng: np.random.Generator, folder: Path) -> Path:
    """The lab's calibration of the benchmark display (warmed up, no effect): readings
    measured and fitted with the calibration package's public fitting functions. The gamma
    model is the display's own family (extended power), so the plain simulation is right up to
    its estimation error; a lab's choice of a worse-fitting model would be a gap of its own."""
    from calibration import (
        Calibration,
        fit_gamma_models,
        fit_uniformity,
        save_calibration,
    )

    # Six repeats: the lab's calibration is better measured than a check's readings, so its
    # own estimation error stays small next to the effects the benchmark injects.
    r = simulate_readings(rng, repeats=6)
    centre = r[(r["x_norm"] == 0) & (r["y_norm"] == 0)]
    fits = fit_gamma_models(centre["level"].to_numpy(float),
                            centre["luminance_cd_m2"].to_numpy(float))
    best = next(f for f in fits if f.model == "extended_power")
    cal = Calibration(calibration_id="bench", created_utc="2026-01-05T08:00:00Z",
                      device="pr655", monitor_name="bench", resolution_px=(1280, 1024),
                      width_cm=40.0, distance_cm=57.0, refresh_hz=85.0,
                      gamma_model=best.model, gamma_params=dict(best.params),
                      min_luminance_cd_m2=float(best.luminance(0.0)),
                      max_luminance_cd_m2=float(best.luminance(1.0)), fits=fits,
                      uniformity=fit_uniformity(r))
    return save_calibration(cal, Path(folder) / "calibration.json")


def write_readings(frame: pd.DataFrame, folder: Path) -> Path:
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    frame.to_csv(folder / "readings.csv", index=False)
    return folder / "readings.csv"
