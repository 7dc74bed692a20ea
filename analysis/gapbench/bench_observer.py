"""The harder blind benchmark, observer part: human-like observers written apart from
``experiment.make_observer`` and from the diagnosis's candidates (their own code here, not the
candidates' injectors), diagnosed against the ideal observer.

Each case is a group of human-like observers whose *base* always carries the in-catalogue
effects real observers show (central tendency: responses compressed toward the middle; depth
to gloss crosstalk), each observer with its own intercepts and slopes (random effects), on
top of which a case adds nothing, a further catalogue effect, an effect outside the catalogue,
or both; a fifth kind of case is an observer with no effect at all (the null). Plans are the
app's (``experiment.make_plan``: same stimuli and orders as real sessions); files are written
in the session format, with a lab's own illumination names and stimulus ids.

Out-of-catalogue effects (none is a catalogue candidate or a sum of them):

================== =========================================================================
interaction        gloss response + k (gloss - mid)(depth - mid): the depth effect on gloss
                   grows with gloss (k in slider units per unit^2)
depth_noise        the depth response's noise SD grows with depth: x (1 + s (depth - mid)/mid)
stimulus_bias      each stimulus (gloss x depth level) has its own gloss bias, N(0, s^2), the
                   same for every observer
illumination_depth the depth response is shifted by +s under one illumination, -s under the
                   other
================== =========================================================================

A further kind of case, run after the schedule's (one per :data:`PAIR_EVERY` cases), adds a
pair of catalogue effects (:data:`PAIRS`): responses pulled toward the slider's labels beside
serial dependence, or settings pulled halfway to the labels and then a quarter of the way
toward the previous setting (issue 38); both must be found.

Scores (:func:`run_harder_observer`): top-1 (the added catalogue effect among the chosen, at
its moderate strength), both effects of a pair found, exact verdicts (the chosen set is the base's effects plus the added
one), false attribution (anything attributed, or a remaining gap flagged, for the null),
'unexplained' rate (a remaining gap flagged when an out-of-catalogue effect is present, with
or without co-occurring catalogue effects), wrong 'remaining' flags
(a gap flagged where only catalogue effects are present), shrinkage error (held-out loss the
chosen model removed vs that of the generating process at population level), and verdict
agreement across seeds (the same files diagnosed with other bootstrap seeds).
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

__all__ = [
    "CATALOGUE_ADDED",
    "OUT_EFFECTS",
    "HarderCase",
    "format_harder",
    "generate_sessions",
    "run_harder_observer",
    "run_observer_cases",
    "score_harder",
]

MID_NOISE = {"gloss": 0.9, "depth": 0.7}  # slider units: the generator's trial noise SD
#: The human-like base (population means, slider units) and its between-observer SDs.
BASE = {"compress_gloss": (0.10, 0.03), "compress_depth": (0.30, 0.04),
        "crosstalk": (0.25, 0.04), "intercept_gloss": (0.0, 0.15),
        "intercept_depth": (0.0, 0.10)}
BASE_EFFECTS = ("central_tendency", "crosstalk")
#: Catalogue effects a case may add to the base, at their moderate strength.
CATALOGUE_ADDED = {"illumination_gain": 0.3, "label_rounding": 0.4, "lapses": 0.15,
                   "serial_dependence": 0.3}
#: Pairs of catalogue effects a case may add together: rounding toward the slider's labels (a
#: pull a share of the way to the nearest label, none landing on it; an outside check's
#: generator) beside serial dependence, which was found as serial dependence alone (issue 29);
#: and the setting, once pulled toward a label, pulled toward the previous setting
#: (``setting_pull``: after the noise and the rounding), also found as serial dependence
#: alone (issue 38, item 4).
PAIRS = {"labels_and_serial": {"label_pull": 0.4, "serial_dependence": 0.3},
         "labels_then_serial": {"label_pull": 0.5, "setting_pull": 0.25}}
#: The candidate an added effect of a pair is found as, where its name differs.
CANDIDATE_OF = {"label_pull": "label_rounding", "setting_pull": "serial_dependence"}
#: One pair case per this many cases of the schedule, run after them (their draws come after
#: the schedule's, so the other cases of a seed stay as they were).
PAIR_EVERY = 10
#: Effects outside the catalogue, at their moderate strength.
OUT_EFFECTS = {"interaction": 0.06, "depth_noise": 0.6, "stimulus_bias": 0.5,
               "illumination_depth": 0.5}


@dataclass(frozen=True)
class HarderCase:
    """One benchmark case: ``base`` (the human-like in-catalogue effects) or not, plus added
    effects ``{name: strength}`` from :data:`CATALOGUE_ADDED` or :data:`OUT_EFFECTS`."""

    kind: str
    base: bool = True
    added: dict = field(default_factory=dict)

    def expected(self) -> set:
        out = set(BASE_EFFECTS) if self.base else set()
        return out | {CANDIDATE_OF.get(n, n) for n in self.added
                      if n in CATALOGUE_ADDED or n in CANDIDATE_OF}

    def has_out(self) -> bool:
        return any(n in OUT_EFFECTS for n in self.added)


def _slider(design):
    s = design.slider
    lo = float(s.min)
    g0, g1 = float(s.to_gloss_pct(lo)), float(s.to_gloss_pct(lo + 1))
    d0, d1 = float(s.to_depth_cm(lo)), float(s.to_depth_cm(lo + 1))
    return lo, float(s.max), (g0, g1 - g0), (d0, d1 - d0)


def generate_sessions(design, case: HarderCase, n_participants: int,
                      rng: np.random.Generator) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Session rows (experiment.SESSION_COLUMNS) of ``n_participants`` observers of ``case``,
    and per trial the population mean response and noise SD the generator used (columns
    ``gloss_mean``, ``depth_mean``, ``gloss_sd``, ``depth_sd``, slider units; the mean
    includes the pull toward the previous response where that effect is present, but no
    observer's own deviation)."""
    from experiment import SESSION_COLUMNS, make_plan, participant_seed

    lo, hi, (g0, gs), (d0, ds) = _slider(design)
    mid = 0.5 * (lo + hi)
    ills = [i.name for i in design.illuminations]
    lab = {name: f"room_{chr(ord('A') + k)}" for k, name in enumerate(ills)}
    stim_bias = {}
    rows, truth_rows = [], []
    for p in range(n_participants):
        pid = f"H{p:02d}"
        plan = make_plan(design, pid, np.random.default_rng(participant_seed(pid)),
                         seed=participant_seed(pid)).drop(columns="seed")
        plan = plan.sort_values(["session", "trial"], ignore_index=True)
        own = {k: (rng.normal(m, sd) if case.base else 0.0) for k, (m, sd) in BASE.items()}
        tg = lo + (plan["true_gloss_pct"].to_numpy(float) - g0) / gs
        td = lo + (plan["true_depth_cm"].to_numpy(float) - d0) / ds
        ill = plan["illumination"].astype(str).to_numpy()
        n = len(plan)
        # Population and own means, before the sequence and mixture effects.
        pop = {"depth": mid + (1 - (BASE["compress_depth"][0] if case.base else 0.0))
               * (td - mid),
               "gloss": mid + (1 - (BASE["compress_gloss"][0] if case.base else 0.0))
               * (tg - mid) + (BASE["crosstalk"][0] if case.base else 0.0) * (td - mid)}
        mine = {"depth": mid + (1 - own["compress_depth"]) * (td - mid) + own["intercept_depth"],
                "gloss": mid + (1 - own["compress_gloss"]) * (tg - mid)
                + own["crosstalk"] * (td - mid) + own["intercept_gloss"]}
        sd = {r: np.full(n, MID_NOISE[r]) for r in ("gloss", "depth")}
        a = case.added
        if "illumination_gain" in a:
            sign = np.where(ill == ills[0], 1.0, -1.0)
            for m in (pop, mine):
                m["gloss"] = m["gloss"] + sign * a["illumination_gain"] * (tg - mid)
        if "interaction" in a:
            for m in (pop, mine):
                m["gloss"] = m["gloss"] + a["interaction"] * (tg - mid) * (td - mid)
        if "depth_noise" in a:
            sd["depth"] = sd["depth"] * np.maximum(1 + a["depth_noise"] * (td - mid) / mid, 0.2)
        if "stimulus_bias" in a:
            keys = list(zip(plan["gloss_level"], plan["depth_level"]))
            for k in keys:
                if k not in stim_bias:
                    stim_bias[k] = rng.normal(0.0, a["stimulus_bias"])
            b = np.array([stim_bias[k] for k in keys])
            for m in (pop, mine):
                m["gloss"] = m["gloss"] + b
        if "illumination_depth" in a:
            sign = np.where(ill == ills[0], 1.0, -1.0)
            for m in (pop, mine):
                m["depth"] = m["depth"] + sign * a["illumination_depth"]
        serial = a.get("serial_dependence", 0.0)
        resp = {r: np.empty(n) for r in ("gloss", "depth")}
        used = {r: np.empty(n) for r in ("gloss", "depth")}
        ses = plan["session"].to_numpy(int)
        for k in range(n):
            for r in ("gloss", "depth"):
                m_own, m_pop = mine[r][k], pop[r][k]
                if serial and k and ses[k] == ses[k - 1]:
                    m_own = m_own + serial * (resp[r][k - 1] - m_own)
                    m_pop = m_pop + serial * (resp[r][k - 1] - m_pop)
                v = m_own + sd[r][k] * rng.standard_normal()
                if rng.random() < a.get("label_rounding", 0.0):
                    v = np.round(v)
                if "label_pull" in a:
                    v = v + a["label_pull"] * (np.round(v) - v)
                if "setting_pull" in a and k and ses[k] == ses[k - 1]:
                    # The setting, once made, pulled toward the previous one (after the pull
                    # toward a label: the hand stops short of where it aimed).
                    v = v + a["setting_pull"] * (resp[r][k - 1] - v)
                    m_pop = m_pop + a["setting_pull"] * (resp[r][k - 1] - m_pop)
                if rng.random() < a.get("lapses", 0.0):
                    v = rng.uniform(lo, hi)
                resp[r][k] = min(max(v, lo), hi)
                used[r][k] = m_pop
        rt = np.exp(rng.normal(np.log(4.5), 0.4, n))
        onset = np.zeros(n)
        for s in np.unique(ses):
            idx = np.flatnonzero(ses == s)
            onset[idx] = np.r_[0.0, np.cumsum(rt[idx] + 0.6)[:-1]]
        out = plan.copy()
        out["illumination"] = [lab[i] for i in ill]
        out["stimulus_id"] = [f"{pid}-img{k:04d}" for k in range(n)]
        out["gloss_match"], out["depth_match"] = resp["gloss"], resp["depth"]
        out["rt_s"], out["onset_s"], out["dropped_frames"] = rt, onset, 0
        out["timestamp_utc"] = [(pd.Timestamp("2026-03-02T10:00:00Z")
                                 + pd.Timedelta(seconds=float(t))).strftime(
                                     "%Y-%m-%dT%H:%M:%S.%fZ") for t in onset + rt]
        out["app_version"] = "lab-pilot"
        out["calibration_id"] = "lab"
        rows.append(out[list(SESSION_COLUMNS)])
        truth_rows.append(pd.DataFrame({
            "participant": pid, "session": ses, "order": plan["order"].to_numpy(int),
            "gloss_mean": used["gloss"], "depth_mean": used["depth"],
            "gloss_sd": sd["gloss"], "depth_sd": sd["depth"]}))
    return pd.concat(rows, ignore_index=True), pd.concat(truth_rows, ignore_index=True)


def write_sessions(frame: pd.DataFrame, folder: Path) -> None:
    """``folder/<P>_s<N>.csv``, never replacing a file."""
    from labfiles import write_new_file

    folder.mkdir(parents=True, exist_ok=True)
    for (p, s), grp in frame.groupby(["participant", "session"]):
        write_new_file(folder / f"{p}_s{s}.csv", grp.to_csv(index=False))


def _true_loss(design, frame: pd.DataFrame, truth: pd.DataFrame, case: HarderCase) -> float:
    """Held-out loss of the generating process at population level: its population mean per
    trial, its mixtures at their true weights, noise SDs fitted (one per response; the
    observers' own deviations are noise to any population model), with the diagnosis's loss."""
    from analysis.gap import observer_frame, observer_loss

    data = observer_frame(frame, design)
    key = ["participant", "session", "order"]
    t = data[key].merge(truth, on=key, how="left")
    for r in ("gloss", "depth"):
        data[f"{r}_base"] = t[f"{r}_mean"].to_numpy(float)
    mix = [(n, {k: float(case.added[n])}) for n, k in (("label_rounding", "weight"),
                                                        ("lapses", "rate"))
           if n in case.added]
    return float(observer_loss(data)(data, mix).mean())


def _schedule(rng: np.random.Generator, n: int) -> list[HarderCase]:
    """A shuffled schedule: a fifth each of null, base only, base + catalogue effect, base +
    out-of-catalogue effect, base + both (each effect as often as the others).

    In 'both' cases the out-of-catalogue effect turns one further against the catalogue
    effect every four pairs, so 80 cases hold each of the 16 pairs once and the first 20
    the four that share a rotation (among them label rounding + depth noise and lapses +
    stimulus bias, which an earlier ceiling missed)."""
    cats, outs = list(CATALOGUE_ADDED), list(OUT_EFFECTS)
    cases = []
    for k in range(n):
        kind = ("null", "base", "catalogue", "out", "both")[k % 5]
        j = k // 5
        c = cats[j % len(cats)]
        o = outs[(j + j // len(cats)) % len(outs)]
        added = {"null": {}, "base": {}, "catalogue": {c: CATALOGUE_ADDED[c]},
                 "out": {o: OUT_EFFECTS[o]},
                 "both": {c: CATALOGUE_ADDED[c], o: OUT_EFFECTS[o]}}[kind]
        cases.append(HarderCase(kind=kind, base=kind != "null", added=added))
    return [cases[i] for i in rng.permutation(n)]


def run_harder_observer(design, *, trials: int, seed: int, n_participants: int = 4,
                        n_boot: int = 1000, agreement_seeds: int = 2, log=print) -> dict:
    """Run ``trials`` cases (:func:`run_observer_cases`) and score them (see the module
    docstring)."""
    return score_harder(run_observer_cases(design, trials=trials, seed=seed,
                                           n_participants=n_participants, n_boot=n_boot,
                                           agreement_seeds=agreement_seeds, log=log))


def run_observer_cases(design, *, trials: int, seed: int, n_participants: int = 4,
                       n_boot: int = 1000, agreement_seeds: int = 2, log=print) -> list[dict]:
    """Run ``trials`` cases (:func:`_schedule`), one record each (for :func:`score_harder`;
    records of several seeds may be pooled). Each case's files are diagnosed with a first
    seed and ``agreement_seeds`` further seeds, all drawn from ``seed``."""
    from analysis.gap import base_from_params, diagnose
    from experiment import load_observer_params

    rng = np.random.default_rng(seed)
    ideal = base_from_params(load_observer_params()["ideal"], "ideal", design.slider,
                             source="the shipped ideal observer")
    records = []
    pairs = [HarderCase(kind="pair", added=dict(PAIRS[name]))
             for name in (list(PAIRS) * trials)[:max(1, trials // PAIR_EVERY)]]
    for t, case in enumerate(_schedule(rng, trials) + pairs):
        frame, truth = generate_sessions(design, case, n_participants, rng)
        with tempfile.TemporaryDirectory() as tmp:
            write_sessions(frame, Path(tmp) / "real")
            seeds = [int(rng.integers(2**31)) for _ in range(1 + agreement_seeds)]
            diags = [diagnose("observer", Path(tmp) / "real", ideal, design, seed=s,
                              n_boot=n_boot)[0] for s in seeds]
        d = diags[0]
        chosen = {s["added"] for s in d.steps} if d.verdict != "unexplained" else set()
        verdicts = {(x.verdict, x.unexplained_remains) for x in diags}
        true_loss = _true_loss(design, frame, truth, case)
        pred, true = d.loss_before - d.loss_after, d.loss_before - true_loss
        rec = {"case": case.kind, "added": dict(case.added), "verdict": d.verdict,
               "remains": bool(d.unexplained_remains), "chosen": sorted(chosen),
               "expected": sorted(case.expected()), "agree": len(verdicts) == 1,
               "pred_shrink": pred, "true_shrink": true,
               "where": (d.remaining or {}).get("where", ""), "summary": d.summary,
               "within": bool((d.remaining or {}).get("within_tolerance"))}
        records.append(rec)
        if log:
            log(f"harder observer case {t} ({case.kind} {case.added}): {d.verdict}"
                f"{' + a remaining gap ' + rec['where'] if rec['remains'] else ''}"
                f"{'' if rec['agree'] else ' [seeds disagree]'}")
    return records


def score_harder(records: list[dict]) -> dict:
    """Rates over the records of :func:`run_harder_observer` (NaN where a kind has no case)."""
    from analysis.gapbench.scoring import rate as _rate
    from analysis.gapbench.scoring import shrink_errors

    def rate(sel, ok):
        return _rate(records, sel, ok)

    def added_cat(r):
        return [CANDIDATE_OF.get(n, n) for n in r["added"]
                if n in CATALOGUE_ADDED or n in CANDIDATE_OF]

    pair = rate(lambda r: r["case"] == "pair",
                lambda r: all(n in r["chosen"] for n in added_cat(r)))
    top1 = rate(lambda r: r["case"] in ("catalogue", "both"),
                lambda r: all(n in r["chosen"] for n in added_cat(r)))
    exact = rate(lambda r: r["case"] in ("base", "catalogue"),
                 lambda r: set(r["chosen"]) == set(r["expected"]) and not r["remains"])
    false_attr = rate(lambda r: r["case"] == "null",
                      lambda r: bool(r["chosen"]) or r["remains"])
    unexpl = rate(lambda r: r["case"] in ("out", "both"), lambda r: r["remains"])
    unexpl_both = rate(lambda r: r["case"] == "both", lambda r: r["remains"])
    # Found but under the design's tolerance (issue 38): reported with its size and place.
    found = rate(lambda r: r["case"] in ("out", "both"),
                 lambda r: r["remains"] or r.get("within", False))
    wrong_rem = rate(lambda r: r["case"] in ("base", "catalogue"), lambda r: r["remains"])
    agree = rate(lambda r: True, lambda r: r["agree"])
    errs = shrink_errors(records, ("base", "catalogue"),
                         lambda r: set(r["chosen"]) == set(r["expected"]))
    return {"top1": top1, "pair": pair, "exact": exact, "false_attribution": false_attr,
            "unexplained_out": unexpl, "unexplained_out_with_catalogue": unexpl_both,
            "found_out": found,
            "wrong_remaining": wrong_rem, "seed_agreement": agree,
            "shrink_error": (float(np.median(errs)) if errs else float("nan"), len(errs)),
            "records": records}


def format_harder(r: dict) -> str:
    """What was measured, beside the targets, one line each."""
    from analysis.gapbench.benchmark import TARGETS
    from analysis.gapbench.scoring import score_line

    def line(label, key, target, higher=True):
        v, n = r[key]
        return score_line("observer (harder)", label, v, n,
                          f"{'>=' if higher else '<='} {target}",
                          v >= target if higher else v <= target)
    lines = [
        line("top-1, added catalogue effect among the chosen", "top1", TARGETS["top1"]),
        line("both effects of a pair found (labels pulled toward + serial dependence)", "pair",
             TARGETS["top1"]),
        line("exact verdicts (base effects + added, nothing remaining)", "exact",
             TARGETS["top1"]),
        line("false attributions (null observer)", "false_attribution",
             TARGETS["false_attribution"], higher=False),
        line("'unexplained' for out-of-catalogue effects", "unexplained_out",
             TARGETS["unexplained_out"]),
        line("'unexplained' for out-of-catalogue effects with catalogue effects co-occurring",
             "unexplained_out_with_catalogue", TARGETS["unexplained_out"]),
        line("out-of-catalogue effects found: a gap, or a remainder reported within the "
             "design's tolerance", "found_out", TARGETS["unexplained_out"]),
        line("remaining gap wrongly flagged (catalogue effects only)", "wrong_remaining",
             TARGETS["false_attribution"], higher=False),
        line("shrinkage error (median)", "shrink_error", TARGETS["shrink_error"], higher=False),
        line("verdict agreement across seeds", "seed_agreement", TARGETS["seed_agreement"]),
    ]
    return "\n".join(lines)
