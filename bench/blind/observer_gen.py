"""Blind observer generator: participants of the gloss x depth matching study, written from a
description of the task alone.

Written by helper "blind" without reading the gap diagnosis (analysis/gap, analysis/gapbench),
the project's observer models (experiment/observers.py, experiment/observer_fit.py) or protocol
7.2 beyond its command lines. Plain NumPy; nothing of the project is imported. The files are in
the session CSV format of experiment/datafile.py (``SESSION_COLUMNS``).

The task
--------
162 stimuli (2 illuminations x gloss labels 2-10 x depth levels 2-10) in a fresh random order per
participant, split into two sessions of 81 (two days). On each trial the participant sets two
continuous sliders (1-11) to match the gloss and the depth of physical references labelled 1-11.

The base observer (every participant, pilot and real)
-----------------------------------------------------
Internal magnitude of a level x (label units, 1-11) by Stevens' power law, compressive:

    m(x) = 1 + 10 ((x - 1) / 10) ** kappa,     kappa_gloss ~ U(0.70, 0.95),
                                               kappa_depth ~ U(0.60, 0.90)

Settings, in slider units, before the slider's ends:

    gloss = 6 + a_g + b_g (m_g(g) - 6) + c_dg (d - 6) + sd_g e
    depth = 6 + a_d + b_d (m_d(d) - 6) + c_gd (g - 6) + sd_d e'

    a_g, a_d ~ N(0, 0.5)            offsets (a participant's own use of the scale)
    b_g ~ N(1.0, 0.12), b_d ~ N(0.95, 0.12)   slopes
    c_dg ~ N(0.15, 0.06)            deeper arrays look glossier (more highlights)
    c_gd ~ N(0.04, 0.04)            glossier arrays look a little deeper
    sd_g ~ U(0.6, 1.1), sd_d ~ U(0.5, 0.9)    trial-to-trial noise (slider units)

A setting is clipped to the slider's range [1, 11] and lies on its pixel grid (1/60 unit: a
600-px slider over 10 units). Response times are log-normal (median U(4, 8) s, log-SD 0.4);
0.6 s between a response and the next onset.

Effects (the "real" participants only; the pilot never has them)
-----------------------------------------------------------------
label_pull   each setting moves a fraction f ~ U(0.3, 0.6) (per participant) of the way to the
             nearest integer label (the references are labelled 1-11; people think in labels).
             Expected name: label_rounding.
serial       each setting moves a fraction s ~ U(0.15, 0.35) (per participant) of the way toward
             the same slider's setting on the previous trial of the session (serial dependence;
             none on a session's first trial). Expected name: serial_dependence.
both         pulled halfway to the nearest integer label, then a quarter of the way toward the
             previous trial's setting. Expected: both names.
none         no effect: the same population as the pilot. Expected: no gap.

Output
------
OUT/pilot/sessions/P01_s1.csv ...   8 pilot participants (identical for every case of a seed)
OUT/real/sessions/R01_s1.csv ...    6 real participants of the case
OUT/truth.json                      every parameter drawn, the effect, the expected names

Usage
-----
    python bench/blind/observer_gen.py --case both --seed 3 --out /tmp/obs/both-3
    python -m experiment fit-observer /tmp/obs/both-3/pilot --out /tmp/obs/both-3/observers.toml
    python -m analysis gap diagnose --layer observer --real /tmp/obs/both-3/real/sessions \
        --sim /tmp/obs/both-3/observers.toml --out /tmp/obs/both-3/REPORT
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

CASES = ("none", "label_pull", "serial", "both")
EXPECTED = {"none": [], "label_pull": ["label_rounding"], "serial": ["serial_dependence"],
            "both": ["label_rounding", "serial_dependence"]}
COLUMNS = ("participant", "session", "trial", "order", "stimulus_id", "illumination",
           "gloss_level", "depth_level", "true_gloss_pct", "true_depth_cm", "gloss_match",
           "depth_match", "rt_s", "onset_s", "dropped_frames", "timestamp_utc", "app_version",
           "calibration_id")
ILLUMINATIONS = ("indoor", "outdoor")
LEVELS = tuple(range(2, 11))
N_PILOT, N_REAL = 8, 6
TRIALS_PER_SESSION = 81
SLIDER_PX_PER_UNIT = 60
APP_VERSION = "0.9.2+gblindlab"
CALIBRATION_ID = "crt-2026-02-27"


def stimuli():
    """(stimulus_id, illumination, gloss label, depth level) of the 162 stimuli."""
    return [(f"{il}_g{g:02d}_d{d:02d}", il, g, d)
            for il in ILLUMINATIONS for g in LEVELS for d in LEVELS]


def draw_observer(rng):
    """One participant's parameters (see the module docstring)."""
    return {
        "kappa_gloss": float(rng.uniform(0.70, 0.95)),
        "kappa_depth": float(rng.uniform(0.60, 0.90)),
        "a_gloss": float(rng.normal(0.0, 0.5)), "a_depth": float(rng.normal(0.0, 0.5)),
        "b_gloss": float(rng.normal(1.0, 0.12)), "b_depth": float(rng.normal(0.95, 0.12)),
        "c_depth_to_gloss": float(rng.normal(0.15, 0.06)),
        "c_gloss_to_depth": float(rng.normal(0.04, 0.04)),
        "sd_gloss": float(rng.uniform(0.6, 1.1)), "sd_depth": float(rng.uniform(0.5, 0.9)),
        "rt_median_s": float(rng.uniform(4.0, 8.0)), "rt_log_sd": 0.4,
    }


def stevens(x, kappa):
    """Compressive magnitude of a level in label units (1 -> 1, 11 -> 11)."""
    return 1.0 + 10.0 * ((np.asarray(x, float) - 1.0) / 10.0) ** kappa


def base_settings(obs, g, d, rng):
    """Settings of the base observer, slider units, before the slider's ends (arrays)."""
    gloss = (6.0 + obs["a_gloss"] + obs["b_gloss"] * (stevens(g, obs["kappa_gloss"]) - 6.0)
             + obs["c_depth_to_gloss"] * (d - 6.0) + obs["sd_gloss"] * rng.normal(size=g.shape))
    depth = (6.0 + obs["a_depth"] + obs["b_depth"] * (stevens(d, obs["kappa_depth"]) - 6.0)
             + obs["c_gloss_to_depth"] * (g - 6.0) + obs["sd_depth"] * rng.normal(size=d.shape))
    return gloss, depth


def on_slider(v):
    """Clipped to [1, 11] and put on the slider's pixel grid."""
    v = np.clip(v, 1.0, 11.0)
    return 1.0 + np.round((v - 1.0) * SLIDER_PX_PER_UNIT) / SLIDER_PX_PER_UNIT


def apply_effects(v, label_frac, serial_frac):
    """One session's settings of one slider, in trial order: label pull, then serial pull.

    ``v`` is the base observer's setting (already within the slider's range); the serial pull
    is toward the previous trial's *recorded* setting (after its own effects)."""
    out = np.empty_like(v)
    prev = None
    for t, x in enumerate(v):
        y = x + label_frac * (np.round(x) - x)
        if prev is not None:
            y = y + serial_frac * (prev - y)
        out[t] = y
        prev = y
    return out


def participant_rows(pid, obs, rng, *, label_frac=0.0, serial_frac=0.0, day0):
    """The 162 session rows of one participant (dicts of COLUMNS)."""
    stim = stimuli()
    order = rng.permutation(len(stim))
    rows = []
    for session in (1, 2):
        idx = order[(session - 1) * TRIALS_PER_SESSION: session * TRIALS_PER_SESSION]
        g = np.array([stim[i][2] for i in idx], float)
        d = np.array([stim[i][3] for i in idx], float)
        gloss, depth = base_settings(obs, g, d, rng)
        gloss = apply_effects(np.clip(gloss, 1.0, 11.0), label_frac, serial_frac)
        depth = apply_effects(np.clip(depth, 1.0, 11.0), label_frac, serial_frac)
        gloss, depth = on_slider(gloss), on_slider(depth)
        rt = obs["rt_median_s"] * np.exp(obs["rt_log_sd"] * rng.normal(size=len(idx)))
        start = day0 + timedelta(days=session - 1, hours=float(rng.uniform(9, 17)))
        onset = 2.0
        for t, i in enumerate(idx):
            sid, il, gl, dl = stim[i]
            stamp = start + timedelta(seconds=onset + rt[t])
            rows.append({
                "participant": pid, "session": session, "trial": t + 1,
                "order": (session - 1) * TRIALS_PER_SESSION + t + 1, "stimulus_id": sid,
                "illumination": il, "gloss_level": gl, "depth_level": dl,
                "true_gloss_pct": f"{10.0 * (gl - 1):.1f}", "true_depth_cm": f"{0.4 * dl:.1f}",
                "gloss_match": f"{gloss[t]:.6f}", "depth_match": f"{depth[t]:.6f}",
                "rt_s": f"{rt[t]:.4f}", "onset_s": f"{onset:.4f}", "dropped_frames": 0,
                "timestamp_utc": stamp.strftime("%Y-%m-%dT%H:%M:%S.%fZ"),
                "app_version": APP_VERSION, "calibration_id": CALIBRATION_ID,
            })
            onset += rt[t] + 0.6
    return rows


def write_sessions(folder, rows):
    """One CSV per participant and session, written whole (tmp file, then rename)."""
    folder = Path(folder) / "sessions"
    folder.mkdir(parents=True, exist_ok=True)
    keys = sorted({(r["participant"], r["session"]) for r in rows})
    for pid, session in keys:
        lines = [",".join(COLUMNS)]
        lines += [",".join(str(r[c]) for c in COLUMNS) for r in rows
                  if r["participant"] == pid and r["session"] == session]
        path = folder / f"{pid}_s{session}.csv"
        tmp = path.with_suffix(".csv.tmp")
        tmp.write_text("\n".join(lines) + "\n")
        os.replace(tmp, path)


def generate(case, seed, out):
    """Write OUT/pilot, OUT/real and OUT/truth.json for one case and seed."""
    if case not in CASES:
        raise ValueError(f"--case {case!r}: choose one of {', '.join(CASES)}")
    out = Path(out)
    day0 = datetime(2026, 3, 2, tzinfo=UTC)
    # The pilot depends on the seed only: the same for every case.
    rng_pilot = np.random.default_rng([seed, 31337])
    pilot, pilot_obs = [], {}
    for k in range(N_PILOT):
        pid = f"P{k + 1:02d}"
        pilot_obs[pid] = draw_observer(rng_pilot)
        pilot += participant_rows(pid, pilot_obs[pid], rng_pilot, day0=day0)
    rng = np.random.default_rng([seed, CASES.index(case), 271828])
    real, real_obs = [], {}
    for k in range(N_REAL):
        pid = f"R{k + 1:02d}"
        obs = draw_observer(rng)
        label_frac = serial_frac = 0.0
        if case == "label_pull":
            label_frac = float(rng.uniform(0.3, 0.6))
        elif case == "serial":
            serial_frac = float(rng.uniform(0.15, 0.35))
        elif case == "both":
            label_frac, serial_frac = 0.5, 0.25
        obs = {**obs, "label_pull_fraction": label_frac, "serial_pull_fraction": serial_frac}
        real_obs[pid] = obs
        real += participant_rows(pid, obs, rng, label_frac=label_frac,
                                 serial_frac=serial_frac, day0=day0 + timedelta(days=14))
    write_sessions(out / "pilot", pilot)
    write_sessions(out / "real", real)
    truth = {"generator": "bench/blind/observer_gen.py", "case": case, "seed": seed,
             "expected": EXPECTED[case], "pilot": pilot_obs, "real": real_obs}
    (out / "truth.json").write_text(json.dumps(truth, indent=2) + "\n")
    return truth


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--case", required=True, choices=CASES)
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--out", required=True, help="folder written: pilot/, real/, truth.json")
    args = ap.parse_args(argv)
    truth = generate(args.case, args.seed, args.out)
    print(json.dumps({"case": truth["case"], "seed": truth["seed"],
                      "expected": truth["expected"]}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
