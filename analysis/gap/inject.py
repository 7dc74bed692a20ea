"""Benchmark injectors: pseudo-real observer data with a hidden effect. The diagnosis never
imports this module (tests/analysis/gap/test_blind.py checks the import graph)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

__all__ = ["DISPLAY_EFFECTS", "DISPLAY_OUT_OF_CATALOGUE", "DISPLAY_STRENGTH", "OBSERVER_EFFECTS",
           "OUT_OF_CATALOGUE", "display_truth", "simulate_readings", "simulate_sessions",
           "write_calibration", "write_readings", "write_sessions"]

OBSERVER_EFFECTS = ("crosstalk", "central_tendency", "illumination_gain", "label_rounding",
                    "lapses", "serial_dependence")
# Out of catalogue: heteroscedastic noise growing with depth, and a gloss bias on odd stimuli.
OUT_OF_CATALOGUE = ("depth_noise_scaling", "stimulus_bias")
NOISE_SD = 0.8  # slider units, the benchmark's ideal observer


def simulate_sessions(design, n_participants: int, rng: np.random.Generator,
                      effect: str = "none", strength: float = 0.0) -> pd.DataFrame:
    """Ideal observer (truth + noise) over the design's rendered stimuli, plus one effect."""
    s = design.slider
    gl = np.array(design.gloss.rendered_levels)
    dl = np.array(design.depth.rendered_levels)
    ills = [i.name for i in design.illuminations]
    rows = []
    for p in range(n_participants):
        stim = [(g, d, i) for g in gl for d in dl for i in ills]
        order = rng.permutation(len(stim))
        prev = {"gloss": None, "depth": None}
        for k, j in enumerate(order):
            g, d, ill = stim[j]
            gu = float(g)
            du = float(d)
            mid = 0.5 * (s.min + s.max)
            mu = {"gloss": gu, "depth": du}
            sd = {"gloss": NOISE_SD, "depth": NOISE_SD}
            if effect == "crosstalk":
                mu["gloss"] += strength * (du - mid)
            elif effect == "central_tendency":
                mu = {r: v - strength * (v - mid) for r, v in mu.items()}
            elif effect == "illumination_gain":
                sign = 1 if ill == ills[0] else -1
                mu["gloss"] += sign * strength * (gu - mid)
            elif effect == "serial_dependence" and prev["gloss"] is not None:
                mu = {r: v + strength * (prev[r] - v) for r, v in mu.items()}
            elif effect == "depth_noise_scaling":
                sd = {r: NOISE_SD * (1 + strength * 3 * (du - mid) / mid) for r in sd}
                sd = {r: max(v, 0.1) for r, v in sd.items()}
            elif effect == "stimulus_bias":
                mu["gloss"] += strength * 3 * (1 if (int(g) * 7 + int(d) * 3) % 2 else -1)
            resp = {r: mu[r] + rng.normal(0, sd[r]) for r in mu}
            for r in list(resp):
                if effect == "label_rounding" and rng.random() < strength:
                    resp[r] = float(np.round(resp[r]))
                if effect == "lapses" and rng.random() < strength:
                    resp[r] = rng.uniform(s.min, s.max)
                resp[r] = float(np.clip(resp[r], s.min, s.max))
            prev = dict(resp)
            rows.append({
                "participant": f"B{p:02d}", "session": 1, "trial": k + 1, "order": k + 1,
                "stimulus_id": f"g{g}_d{d}_{ill}", "illumination": ill,
                "gloss_level": int(g), "depth_level": int(d),
                "true_gloss_pct": (gu - s.min) * s.gloss_pct_per_unit,
                "true_depth_cm": du * s.depth_cm_per_unit,
                "gloss_match": resp["gloss"], "depth_match": resp["depth"],
                "rt_s": 2.0, "onset_s": 0.0, "dropped_frames": 0,
                "timestamp_utc": "", "app_version": "bench", "calibration_id": "bench",
            })
    return pd.DataFrame(rows)


def write_sessions(frame: pd.DataFrame, folder: Path) -> None:
    """One CSV per participant and session, ``<P>_s<N>.csv``."""
    folder.mkdir(parents=True, exist_ok=True)
    for (p, ses), grp in frame.groupby(["participant", "session"]):
        grp.to_csv(folder / f"{p}_s{ses}.csv", index=False)


# --- display layer ------------------------------------------------------------------------
# Pseudo-real photometer readings from calibration.SimulatedCRT with one effect changed; the
# diagnosis reads only readings.csv and calibration.json.

DISPLAY_EFFECTS = ("black_offset", "nonuniformity", "warmup_drift", "quantisation")
DISPLAY_OUT_OF_CATALOGUE = ("gamma_change", "local_blemish")
#: Moderate strength of each display effect (the benchmark draws 0.5-1.5 times this).
DISPLAY_STRENGTH = {"black_offset": 0.05, "nonuniformity": 0.03, "warmup_drift": 0.03,
                    "quantisation": 2.0, "gamma_change": 0.03, "local_blemish": 0.03}
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


def display_crt(effect: str = "none", strength: float = 0.0):
    """The benchmark's display: the shipped simulated CRT with one effect changed."""
    from dataclasses import replace

    from calibration import load_crt

    crt = load_crt()
    if effect == "black_offset":
        return replace(crt, ambient_cd_m2=crt.ambient_cd_m2 + strength)
    if effect == "nonuniformity":
        return replace(crt, falloff=crt.falloff + strength, tilt_x=crt.tilt_x + strength / 2)
    if effect == "warmup_drift":
        return replace(crt, warmup_drift=strength)
    if effect == "quantisation":
        return replace(crt, bits=round(crt.bits - strength))
    if effect == "gamma_change":
        return replace(crt, gamma=crt.gamma * (1 + strength))
    return crt


def display_truth(effect: str, strength: float, schedule: pd.DataFrame,
                  t_s: np.ndarray) -> np.ndarray:
    """Noiseless luminance (cd/m^2) of the benchmark's display with the effect."""
    crt = display_crt(effect, strength)
    t = t_s if effect == "warmup_drift" else np.full(len(schedule), np.inf)
    lum = crt.luminance(schedule["level"].to_numpy(float), schedule["x_norm"].to_numpy(float),
                        schedule["y_norm"].to_numpy(float), t)
    if effect == "local_blemish":
        at = (np.isclose(schedule["x_norm"].to_numpy(float), _BLEMISH_AT[0])
              & np.isclose(schedule["y_norm"].to_numpy(float), _BLEMISH_AT[1]))
        lum = np.where(at, crt.black_total_cd_m2 + (lum - crt.black_total_cd_m2)
                       * (1 - strength), lum)
    return lum


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
