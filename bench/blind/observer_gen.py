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

NEW_CASES = ("rest_drift", "highlight_depth", "slider_swap", "gloss_depth", "illum_depth")
CASES = ("none", "label_pull", "serial", "both", *NEW_CASES)
#: Expected names; the new cases lie outside the catalogue: any gap ("unexplained" or a name).
EXPECTED = {"none": [], "label_pull": ["label_rounding"], "serial": ["serial_dependence"],
            "both": ["label_rounding", "serial_dependence"],
            **{c: ["unexplained"] for c in NEW_CASES}}
#: Catalogue names (diagnosis.json "ranking") whose description comes close to a new case.
NEAR = {"gloss_depth": ["crosstalk"], "illum_depth": ["illumination_gain"],
        "slider_swap": ["lapses"]}
STRENGTH_UNIT = {"rest_drift": "slider units per minute since the rest",
                 "highlight_depth": "slider units per unit of relative highlight size",
                 "slider_swap": "fraction of the first participant's trials swapped",
                 "gloss_depth": "slider units of depth per gloss label",
                 "illum_depth": "fractional inflation of depth (above 1) under outdoor"}
TOLERANCE_SLIDER = 0.25  # design.toml [gap] observer_tolerance_slider
COLUMNS = ("participant", "session", "trial", "order", "stimulus_id", "illumination",
           "gloss_level", "depth_level", "true_gloss_pct", "true_depth_cm", "gloss_match",
           "depth_match", "rt_s", "onset_s", "dropped_frames", "timestamp_utc", "app_version",
           "calibration_id")
ILLUMINATIONS = ("indoor", "outdoor")
LEVELS = tuple(range(2, 11))
N_PILOT, N_REAL = 8, 20
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


def draw_trials(obs, rng, day0):
    """Everything random about one participant's 162 trials, drawn in a fixed order (the same
    stream gives the same trials whatever effect is added afterwards).

    Returns a dict of arrays in trial order (both sessions): ``stim`` (index into
    ``stimuli()``), ``session``, ``gloss`` and ``depth`` (base settings before the slider's
    ends, slider units), ``rt_s``, and ``start`` (each session's start, datetimes)."""
    stim = stimuli()
    order = rng.permutation(len(stim))
    parts = {"stim": [], "session": [], "gloss": [], "depth": [], "rt_s": []}
    starts = []
    for session in (1, 2):
        idx = order[(session - 1) * TRIALS_PER_SESSION: session * TRIALS_PER_SESSION]
        g = np.array([stim[i][2] for i in idx], float)
        d = np.array([stim[i][3] for i in idx], float)
        gloss, depth = base_settings(obs, g, d, rng)
        rt = obs["rt_median_s"] * np.exp(obs["rt_log_sd"] * rng.normal(size=len(idx)))
        starts.append(day0 + timedelta(days=session - 1, hours=float(rng.uniform(9, 17))))
        for key, val in (("stim", idx), ("session", np.full(len(idx), session)),
                         ("gloss", gloss), ("depth", depth), ("rt_s", rt)):
            parts[key].append(val)
    out = {k: np.concatenate(v) for k, v in parts.items()}
    out["start"] = starts
    return out


def onsets(trials, pauses_s=None):
    """Onset of each trial from its session's start, s (2 s lead-in, 0.6 s between a
    response and the next onset); ``pauses_s`` (trial index -> s) adds a rest before a trial."""
    out = np.empty(len(trials["rt_s"]))
    onset, session = 2.0, trials["session"][0]
    for t, rt in enumerate(trials["rt_s"]):
        if trials["session"][t] != session:
            onset, session = 2.0, trials["session"][t]
        onset += (pauses_s or {}).get(t, 0.0)
        out[t] = onset
        onset += rt + 0.6
    return out


def recorded(trials, label_frac=0.0, serial_frac=0.0):
    """Recorded settings of the base observer with label and serial pulls (see
    ``apply_effects``), on the slider: (gloss, depth) in trial order."""
    res = []
    for v in (trials["gloss"], trials["depth"]):
        v = np.clip(v, 1.0, 11.0)
        out = np.empty_like(v)
        for session in (1, 2):
            m = trials["session"] == session
            out[m] = apply_effects(v[m], label_frac, serial_frac)
        res.append(on_slider(out))
    return tuple(res)


def participant_rows(pid, trials, gloss, depth, onset_s):
    """The session rows of one participant (dicts of COLUMNS)."""
    stim = stimuli()
    rows = []
    for t, i in enumerate(trials["stim"]):
        sid, il, gl, dl = stim[i]
        session = int(trials["session"][t])
        n_before = (session - 1) * TRIALS_PER_SESSION
        stamp = trials["start"][session - 1] + timedelta(seconds=onset_s[t] + trials["rt_s"][t])
        rows.append({
            "participant": pid, "session": session, "trial": t - n_before + 1,
            "order": t + 1, "stimulus_id": sid,
            "illumination": il, "gloss_level": gl, "depth_level": dl,
            "true_gloss_pct": f"{10.0 * (gl - 1):.1f}", "true_depth_cm": f"{0.4 * dl:.1f}",
            "gloss_match": f"{gloss[t]:.6f}", "depth_match": f"{depth[t]:.6f}",
            "rt_s": f"{trials['rt_s'][t]:.4f}", "onset_s": f"{onset_s[t]:.4f}",
            "dropped_frames": 0, "timestamp_utc": stamp.strftime("%Y-%m-%dT%H:%M:%S.%fZ"),
            "app_version": APP_VERSION, "calibration_id": CALIBRATION_ID,
        })
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


def trial_table(trials, obs_list):
    """The real participants' trials stacked into one table of arrays (see ``shifted``)."""
    stim = stimuli()
    cols = {k: [] for k in ("g", "d", "outdoor", "gloss", "depth", "minutes", "person")}
    for p, tr in enumerate(trials):
        idx = tr["stim"]
        cols["g"].append(np.array([stim[i][2] for i in idx], float))
        cols["d"].append(np.array([stim[i][3] for i in idx], float))
        cols["outdoor"].append(np.array([stim[i][1] == "outdoor" for i in idx]))
        cols["gloss"].append(tr["gloss"])
        cols["depth"].append(tr["depth"])
        cols["minutes"].append(tr["minutes_since_rest"])
        cols["person"].append(np.full(len(idx), p))
    return {k: np.concatenate(v) for k, v in cols.items()}


def highlight_size(g):
    """Relative size of a highlight at gloss label g: the Ward roughness behind the labels
    falls about geometrically with the label (1 at label 2, 0.2 at label 10)."""
    return 0.2 ** ((np.asarray(g, float) - 2.0) / 8.0)


def shifted(case, strength, tab, person_k, swap_mask=None):
    """Recorded (gloss, depth) of the real participants with one new effect at ``strength``.

    The effect acts on the internal setting, before the slider's ends and its pixel grid;
    ``person_k`` (one per participant, U(0.5, 1.5)) sets each person's share of it."""
    k = person_k[tab["person"]] * strength
    gloss, depth = tab["gloss"].copy(), tab["depth"].copy()
    if case == "rest_drift":
        gloss += k * tab["minutes"]
        depth += k * tab["minutes"]
    elif case == "highlight_depth":
        depth += k * (np.mean(highlight_size(LEVELS)) - highlight_size(tab["g"]))
    elif case == "gloss_depth":
        depth += k * (tab["g"] - 6.0)
    elif case == "illum_depth":
        depth += np.where(tab["outdoor"], k * (np.clip(depth, 1.0, 11.0) - 1.0), 0.0)
    elif case == "slider_swap" and swap_mask is not None:
        gloss, depth = np.where(swap_mask, depth, gloss), np.where(swap_mask, gloss, depth)
    return on_slider(gloss), on_slider(depth)


def size_slider(a, b):
    """RMS over trials of the distance between two sets of (gloss, depth) settings, slider
    units: sqrt(mean((g_a - g_b)^2 + (d_a - d_b)^2)) (a depth-only shift of c gives c)."""
    return float(np.sqrt(np.mean((a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2)))


def size_within_person(a, b, person):
    """``size_slider`` after each participant's mean change of each slider is taken out: the
    part of the effect a person's own offset cannot absorb, slider units."""
    total = 0.0
    for p in np.unique(person):
        m = person == p
        for i in (0, 1):
            d = a[i][m] - b[i][m]
            total += np.sum((d - d.mean()) ** 2)
    return float(np.sqrt(total / len(person)))


def scale_effect(case, target, tab, person_k, rng):
    """The strength (and swap mask) at which the effect's size is ``target`` slider units."""
    ref = (on_slider(tab["gloss"]), on_slider(tab["depth"]))
    if case == "slider_swap":
        # One participant (the first) swaps now and then: trials taken in a random order,
        # each kept while the summed squared distance stays within the target's.
        cost = 2.0 * (ref[0] - ref[1]) ** 2 * (tab["person"] == 0)
        budget, total = target ** 2 * len(cost), 0.0
        mask = np.zeros(len(cost), bool)
        for t in rng.permutation(np.flatnonzero(tab["person"] == 0)):
            if total + cost[t] <= budget:
                mask[t], total = True, total + cost[t]
        return float(mask.sum() / max(1, (tab["person"] == 0).sum())), mask
    lo, hi = 0.0, 0.05
    while size_slider(shifted(case, hi, tab, person_k), ref) < target:
        hi *= 2.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if size_slider(shifted(case, mid, tab, person_k), ref) < target \
            else (lo, mid)
    return 0.5 * (lo + hi), None


def rest_pauses(rng):
    """Rest breaks (trial index within both sessions -> pause, s): 1-3 min before the 28th
    and 55th trial of each session."""
    return {s * TRIALS_PER_SESSION + t: float(rng.uniform(60.0, 180.0))
            for s in (0, 1) for t in (27, 54)}


def minutes_since_rest(onset_s, pauses_s):
    """Minutes since the block began (a session's start or the end of a rest), per trial."""
    out = np.empty(len(onset_s))
    block0 = 0.0
    for t in range(len(onset_s)):
        if t % TRIALS_PER_SESSION == 0 or t in pauses_s:
            block0 = onset_s[t]
        out[t] = (onset_s[t] - block0) / 60.0
    return out


def pilot_participants(seed, day0):
    """(rows, parameters) of the 8 pilot participants: the seed's alone, the same for every
    case, never with an effect."""
    rng_pilot = np.random.default_rng([seed, 31337])
    pilot, pilot_obs = [], {}
    for k in range(N_PILOT):
        pid = f"P{k + 1:02d}"
        pilot_obs[pid] = draw_observer(rng_pilot)
        tr = draw_trials(pilot_obs[pid], rng_pilot, day0)
        pilot += participant_rows(pid, tr, *recorded(tr), onsets(tr))
    return pilot, pilot_obs


def generate(case, seed, out, *, participants=N_REAL, multiple=1.0):
    """Write OUT/pilot, OUT/real and OUT/truth.json for one case and seed.

    ``multiple``: the new cases' effect size in units of the tolerance (0.25 slider units)."""
    if case not in CASES:
        raise ValueError(f"--case {case!r}: choose one of {', '.join(CASES)}")
    if participants < 1:
        raise ValueError(f"--participants {participants}: give at least 1")
    out = Path(out)
    day0 = datetime(2026, 3, 2, tzinfo=UTC)
    pilot, pilot_obs = pilot_participants(seed, day0)
    new = case in NEW_CASES
    # The new cases take the real participants of `none` (the same stream), their effect
    # from a stream of their own: `none` of the same seed is their no-effect data.
    rng = np.random.default_rng([seed, 0 if new else CASES.index(case), 271828])
    rng_eff = np.random.default_rng([seed, CASES.index(case), 271828, 7])
    real_obs, trials, fracs = {}, [], []
    for k in range(participants):
        obs = draw_observer(rng)
        label_frac = serial_frac = 0.0
        if case == "label_pull":
            label_frac = float(rng.uniform(0.3, 0.6))
        elif case == "serial":
            serial_frac = float(rng.uniform(0.15, 0.35))
        elif case == "both":
            label_frac, serial_frac = 0.5, 0.25
        tr = draw_trials(obs, rng, day0 + timedelta(days=14))
        pauses = rest_pauses(rng_eff) if case == "rest_drift" else {}
        tr["onset_s"] = onsets(tr, pauses)
        tr["minutes_since_rest"] = minutes_since_rest(tr["onset_s"], pauses)
        real_obs[f"R{k + 1:02d}"] = {**obs, "label_pull_fraction": label_frac,
                                     "serial_pull_fraction": serial_frac,
                                     "rest_pauses_s": {str(t): v for t, v in pauses.items()}}
        trials.append(tr)
        fracs.append((label_frac, serial_frac))
    none = [recorded(tr) for tr in trials]
    ref = tuple(np.concatenate([n[i] for n in none]) for i in (0, 1))
    effect = {}
    if new:
        tab = trial_table(trials, real_obs)
        person_k = rng_eff.uniform(0.5, 1.5, participants)
        strength, mask = scale_effect(case, multiple * TOLERANCE_SLIDER, tab, person_k, rng_eff)
        got = shifted(case, strength, tab, person_k, mask)
        effect = {"strength": strength, "person_share": person_k.tolist(),
                  "unit": STRENGTH_UNIT[case]}
        if case == "slider_swap":
            # A swap on a fraction p of trials moves the expected setting by p x the swap and
            # adds the rest as spread: the mean's part of the size is sqrt(p) of it.
            effect["size_of_the_mean_only"] = float(np.sqrt(strength)) * size_slider(got, ref)
        cuts = np.cumsum([len(tr["rt_s"]) for tr in trials])[:-1]
        settings = list(zip(np.split(got[0], cuts), np.split(got[1], cuts), strict=True))
    else:
        settings = [recorded(tr, *fr) for tr, fr in zip(trials, fracs, strict=True)]
        got = tuple(np.concatenate([s[i] for s in settings]) for i in (0, 1))
    real = []
    for k, (tr, (gl, dp)) in enumerate(zip(trials, settings, strict=True)):
        real += participant_rows(f"R{k + 1:02d}", tr, gl, dp, tr["onset_s"])
    write_sessions(out / "pilot", pilot)
    write_sessions(out / "real", real)
    size = size_slider(got, ref)
    person = np.concatenate([np.full(len(tr["rt_s"]), k) for k, tr in enumerate(trials)])
    within = size_within_person(got, ref, person)
    truth = {"generator": "bench/blind/observer_gen.py", "case": case, "seed": seed,
             "expected": EXPECTED[case], "in_catalogue": case not in NEW_CASES,
             "near_catalogue": NEAR.get(case, []), "participants": participants,
             "multiple_asked": multiple if new else None,
             "size": size, "size_unit": "slider units, RMS distance (gloss, depth) over trials",
             "tolerance": TOLERANCE_SLIDER, "size_in_tolerances": size / TOLERANCE_SLIDER,
             "size_within_person": within,
             "size_within_person_in_tolerances": within / TOLERANCE_SLIDER,
             "effect": effect, "pilot": pilot_obs, "real": real_obs}
    (out / "truth.json").write_text(json.dumps(truth, indent=2) + "\n")
    return truth


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--case", required=True, choices=CASES)
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--out", required=True, help="folder written: pilot/, real/, truth.json")
    ap.add_argument("--participants", type=int, default=N_REAL,
                    help=f"real participants (default {N_REAL}, the full size; also 3, 6, 11)")
    ap.add_argument("--multiple", type=float, default=1.0,
                    help="new cases: effect size in tolerances (0.25 slider units); default 1")
    args = ap.parse_args(argv)
    truth = generate(args.case, args.seed, args.out, participants=args.participants,
                     multiple=args.multiple)
    print(json.dumps({k: truth[k] for k in ("case", "seed", "expected", "participants",
                                            "size", "size_in_tolerances")}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
