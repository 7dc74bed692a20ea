"""Session CSVs for the analysis tests, in the experiment's format (plain numpy observers).

`write_sessions` makes each participant's plan with ``experiment.make_plan`` and answers every
trial with a simple observer: ``humanlike`` compresses depth towards the middle and sees deeper
surfaces as glossier (the source study's pattern); ``ideal`` reports the truth plus noise.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from experiment import SESSION_COLUMNS, make_plan


def answer(plan: pd.DataFrame, design, rng: np.random.Generator, kind: str) -> pd.DataFrame:
    """Slider settings (gloss_match, depth_match) for every row of a plan."""
    depth = plan["true_depth_cm"].to_numpy(float)
    gloss = plan["true_gloss_pct"].to_numpy(float)
    mid = float(np.mean(design.depth.rendered_cm))
    if kind == "humanlike":
        depth_cm = mid + 0.6 * (depth - mid) + rng.normal(0, 0.1) + rng.normal(0, 0.35, depth.size)
        gloss_pct = (gloss + 8.0 * (depth - mid) + 0.05 * (gloss - 50) * (depth - mid)
                     + rng.normal(0, 4) + rng.normal(0, 10, gloss.size))
    elif kind == "ideal":
        depth_cm = depth + rng.normal(0, 0.3, depth.size)
        gloss_pct = gloss + rng.normal(0, 8, gloss.size)
    else:
        raise ValueError(kind)
    s = design.slider
    out = plan.copy()
    out["gloss_match"] = s.from_gloss_pct(gloss_pct, clip=True)
    out["depth_match"] = s.from_depth_cm(depth_cm, clip=True)
    return out


def write_sessions(folder: Path, design, rng: np.random.Generator, *, n_participants: int,
                   kind: str = "humanlike") -> list[Path]:
    """Write ``folder/sessions/<participant>_s<session>.csv`` for simulated participants."""
    (folder / "sessions").mkdir(parents=True, exist_ok=True)
    paths = []
    for k in range(n_participants):
        participant = f"S{k + 1:02d}"
        plan = answer(make_plan(design, participant, rng, seed=k), design, rng, kind)
        plan["rt_s"] = rng.uniform(2, 9, len(plan))
        plan["onset_s"] = np.cumsum(plan["rt_s"] + 1.0)
        plan["dropped_frames"] = 0
        plan["timestamp_utc"] = "2026-11-22T12:00:00Z"
        plan["app_version"] = "test"
        plan["calibration_id"] = "default"
        for session, rows in plan.groupby("session"):
            path = folder / "sessions" / f"{participant}_s{session}.csv"
            rows[list(SESSION_COLUMNS)].to_csv(path, index=False)
            paths.append(path)
    return paths
