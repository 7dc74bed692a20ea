"""A population of gloss x depth observers, written here from a physical description (not
from the diagnosis's model), for tests of the observer layer's verdicts (issue 43).

Each observer sets the sliders by a compressive Stevens power law of the level,
``m(x) = 1 + 10 ((x - 1) / 10) ** kappa`` (kappa U(0.75, 0.95) gloss, U(0.65, 0.9) depth),
with an own offset N(0, 0.5) slider units, an own slope (N(1.0, 0.1) gloss, N(0.95, 0.1)
depth), a depth -> gloss crosstalk N(0.15, 0.05) per level and Gaussian noise (SD U(0.6, 1.0)
gloss, U(0.5, 0.8) depth), clipped to the slider (1-11) and set on its pixel grid (600 px). The plans (stimuli, orders,
sessions) are the experiment's own (:func:`analysis.gapbench.inject.simulate_sessions`);
only the settings are replaced. A pilot of 8 such observers is fitted with the experiment's
``fit-observer`` (:func:`experiment.observer_fit.fit_observer_params`): that is the
simulation the real participants are diagnosed against.

Effects added to the real participants' depth settings (slider units), before the clipping:
``gloss`` depth rising with the gloss level, ``size`` slider units RMS over the stimuli;
``illumination`` depth inflated by ``size`` slider units under one illumination (the first
in sorted order); ``drift`` both settings creeping up by ``size`` slider units per minute
since the session's start (fatigue, adaptation; each participant a share U(0.5, 1.5) of it);
``swap`` the first real participant setting gloss on the depth slider and depth on the gloss
slider on a random share ``size`` of their trials (the others do nothing of the kind);
``own_crosstalk`` each real participant's depth setting leaning on the gloss level by their
own amount, N(0, ``size``) slider units per level (individual differences the simulation
has no term for; none on average). This one was added on 2026-11-28 by a writer who had read
the diagnosis (to reproduce blind seed 1021's false gap): it is not independent of it.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from analysis.gapbench import inject
from studydesign import load_design

DESIGN = load_design()


def stevens(x: np.ndarray, kappa: float) -> np.ndarray:
    return 1.0 + 10.0 * (np.clip(x - 1.0, 0.0, None) / 10.0) ** kappa


def _on_pixels(v: np.ndarray, width_px: int = 600) -> np.ndarray:
    """Settings on the slider's pixel grid (a handle ``width_px`` pixels long over 1-11)."""
    step = 10.0 / (width_px - 1)
    return 1.0 + np.round((v - 1.0) / step) * step


def _settings(frame: pd.DataFrame, rng: np.random.Generator, effect: str,
              size: float) -> pd.DataFrame:
    s = DESIGN.slider
    g_lab = frame["true_gloss_pct"].to_numpy(float) / 10.0 + 1.0   # gloss label 1-11
    d_lab = frame["true_depth_cm"].to_numpy(float) / 0.4            # depth level 1-11
    ill = frame["illumination"].to_numpy(str)
    first = min(set(ill))
    g_c = g_lab - 6.0
    add = {"none": np.zeros(len(frame)), "drift": np.zeros(len(frame)),
           "swap": np.zeros(len(frame)), "own_crosstalk": np.zeros(len(frame)),
           "gloss": size * g_c / np.sqrt(np.mean(g_c ** 2)),
           "illumination": size * (ill == first)}[effect]
    minutes = frame["onset_s"].to_numpy(float) / 60.0
    gloss, depth = np.empty(len(frame)), np.empty(len(frame))
    for k, idx in enumerate(frame.groupby("participant").indices.values()):
        kg, kd = rng.uniform(0.75, 0.95), rng.uniform(0.65, 0.9)
        a_g, a_d = rng.normal(0.0, 0.5, 2)
        b_g, b_d = rng.normal(1.0, 0.1), rng.normal(0.95, 0.1)
        c = rng.normal(0.15, 0.05)
        sg, sd = rng.uniform(0.6, 1.0), rng.uniform(0.5, 0.8)
        gloss[idx] = (6.0 + a_g + b_g * (stevens(g_lab[idx], kg) - 6.0)
                      + c * (d_lab[idx] - 6.0) + sg * rng.standard_normal(idx.size))
        depth[idx] = (6.0 + a_d + b_d * (stevens(d_lab[idx], kd) - 6.0) + add[idx]
                      + sd * rng.standard_normal(idx.size))
        if effect == "drift":
            creep = size * rng.uniform(0.5, 1.5) * minutes[idx]
            gloss[idx] += creep
            depth[idx] += creep
        if effect == "own_crosstalk":
            depth[idx] += rng.normal(0.0, size) * g_c[idx]
        if effect == "swap" and k == 0:
            swapped = rng.random(idx.size) < size
            g_i, d_i = gloss[idx].copy(), depth[idx].copy()
            gloss[idx] = np.where(swapped, d_i, g_i)
            depth[idx] = np.where(swapped, g_i, d_i)
    out = frame.copy()
    out["gloss_match"] = _on_pixels(np.clip(gloss, s.min, s.max))
    out["depth_match"] = _on_pixels(np.clip(depth, s.min, s.max))
    out["app_version"] = "lab"
    return out


def population(seed: int, n_real: int, effect: str = "none", size: float = 0.0,
               n_pilot: int = 8) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``(pilot, real)`` session rows: ``n_pilot`` pilot observers (ids P..) with no effect and
    ``n_real`` real ones (ids R..) with ``effect`` of ``size`` slider units."""
    rng = np.random.default_rng([seed, 43])
    frames = []
    for n, tag, eff in ((n_pilot, "P", "none"), (n_real, "R", effect)):
        f = inject.simulate_sessions(DESIGN, n, rng)
        f["participant"] = f["participant"].astype(str).str.replace("B", tag, regex=False)
        frames.append(_settings(f.sort_values(["participant", "session", "order"],
                                              ignore_index=True), rng, eff, size))
    return frames[0], frames[1]


def fitted_simulation(pilot: pd.DataFrame):
    """The pilot's fitted observer (``fit-observer``'s table) as the diagnosis reads it."""
    from analysis.gap.observer import base_from_params
    from experiment.observer_fit import fit_observer_params

    params = fit_observer_params(pilot, DESIGN)
    return base_from_params(params["humanlike"], "fitted", DESIGN.slider, source="pilot",
                            fit_info=params["fit"])
