"""Benchmark injectors: pseudo-real observer data with a hidden effect. The diagnosis never
imports this module (tests/analysis/gap/test_blind.py checks the import graph)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

__all__ = ["OBSERVER_EFFECTS", "OUT_OF_CATALOGUE", "simulate_sessions", "write_sessions"]

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
