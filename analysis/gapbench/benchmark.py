"""Blind benchmark: inject a hidden effect, write the layer's data files, diagnose only the
files, score the verdict.

Scores (per layer): top-1 identification rate over in-catalogue runs at moderate strength
(0.5-1.5 times the layer's moderate strength); false attributions when nothing was injected;
'unexplained' rate for out-of-catalogue effects; shrinkage error; and, with
:func:`run_thresholds`, the detection threshold per effect.

Shrinkage error: |predicted - true| / true, where predicted = the held-out loss the diagnosis
removed (plain simulation minus the chosen extension, fitted on the training split) and true =
the plain simulation's held-out loss minus the loss of the generating process itself (the
injector's model at the injected strength, evaluated here with the injector's own code on the
diagnosis's held-out units and the diagnosis's loss). 'Injected effect removed' is taken as
the generating process, not as effect-free data: lapses, label rounding or quantisation change
the data's own entropy, so no model of the real data reaches the loss of effect-free data.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.gap import (
    NOT_A_GAP,
    OutOfCatalogue,
    candidate,
    catalogue,
    diagnose,
    observer_frame,
    observer_nll,
    out_of_catalogue,
    read_session_csvs,
)
from analysis.gap import effect as _effect
from analysis.gap import strengths as _strengths
from analysis.gapbench import inject
from analysis.gapbench.scoring import balanced_draw, render_true_shrink
from analysis.gapbench.scoring import rate as _rate

__all__ = ["TARGETS", "draw_schedule", "format_scores", "run_benchmark", "run_layer_benchmark",
           "run_observer_benchmark", "run_thresholds"]

#: The issue's targets.
TARGETS = {"top1": 0.95, "false_attribution": 0.05, "unexplained_out": 0.90,
           "shrink_error": 0.10, "threshold_hit_rate": 0.80, "seed_agreement": 0.95}


def _is_out(layer: str, name: str) -> bool:
    """True for an out-of-catalogue effect of ``layer`` (GapError for an unknown name)."""
    return name != "none" and isinstance(_effect(layer, name), OutOfCatalogue)


# --- observer -----------------------------------------------------------------------------

def _observer_trial(design, effect, strength, rng, tmp: Path, n_boot, n_participants=4):
    real = inject.simulate_sessions(design, n_participants, rng, effect, strength,
                                    lab_files=True)
    inject.write_sessions(real, tmp / "real")
    sim = inject.simulate_sessions(design, n_participants, rng)
    inject.write_sessions(sim, tmp / "sim")
    diag, _ = diagnose("observer", tmp / "real", tmp / "sim", design,
                       seed=int(rng.integers(2**31)), n_boot=n_boot)
    if effect == "none" or _is_out("observer", effect):
        return diag, float("nan")
    # The generating process: the effect's true parameters on the ideal observer, every trial
    # (each is held out once), at the ideal observer's noise.
    frame = observer_frame(read_session_csvs(tmp / "real"), design)
    names = inject.lab_names(design)
    truth = candidate("observer", effect).truth(
        strength, illuminations=[names[i.name] for i in design.illuminations])
    sigma = inject.ideal_noise_sd(design)
    return diag, float(diag.loss_before - observer_nll(frame, truth, sigma).mean())


# --- display ------------------------------------------------------------------------------

def _display_trial(design, effect, strength, rng, tmp: Path, n_boot):
    inject.write_calibration(rng, tmp / "sim")
    real = inject.simulate_readings(rng, effect, strength)
    inject.write_readings(real, tmp / "real")
    diag, _ = diagnose("display", tmp / "real", tmp / "sim", design,
                       seed=int(rng.integers(2**31)), n_boot=n_boot)
    if _is_out("display", effect):
        return diag, float("nan")
    # The generating display's noiseless luminance, under the diagnosis's noise model.
    read = pd.read_csv(tmp / "real" / "readings.csv")
    rows = np.array([int(u.rsplit("|", 1)[1]) for u in diag.heldout])
    t_s = np.asarray(real.attrs["t_s"], float)
    truth = inject.display_truth(effect, strength, read, t_s)[rows]
    lum = read["luminance_cd_m2"].to_numpy(float)[rows]
    info = diag.loss_info
    sd = np.sqrt(info["noise_abs_cd_m2"] ** 2 + (info["noise_rel"] * lum) ** 2)
    nll = 0.5 * np.log(2 * np.pi * sd**2) + 0.5 * ((lum - truth) / sd) ** 2
    return diag, float(diag.loss_before - nll.mean())


# --- render -------------------------------------------------------------------------------

def _render_trial(design, effect, strength, rng, tmp: Path, n_boot):
    truth = inject.write_render_fit(tmp / "fit", rng, effect, strength)
    diag, _ = diagnose("render", tmp / "fit", None, design, seed=int(rng.integers(2**31)),
                       n_boot=n_boot)
    if _is_out("render", effect):
        return diag, float("nan")
    return diag, render_true_shrink(diag, tmp / "fit", truth)


_TRIALS = {"observer": _observer_trial, "display": _display_trial, "render": _render_trial}


def _layer(layer: str):
    """(catalogue names, out-of-catalogue names, moderate strength per effect, trial) of a
    layer, all from the effect objects (engine registry; inject registers the
    out-of-catalogue ones)."""
    return (tuple(c.name for c in catalogue(layer)),
            tuple(e.name for e in out_of_catalogue(layer)), _strengths(layer), _TRIALS[layer])


def _top(diag) -> str:
    """The first effect named: of the verdict, or of the steps of a "no gap that matters" or
    "inconclusive" verdict (an effect found and named, smaller than the layer's tolerance)."""
    if diag.verdict in NOT_A_GAP and diag.steps:
        return diag.steps[0]["added"]
    return ("unexplained" if diag.verdict == "unexplained" or diag.verdict in NOT_A_GAP
            else diag.verdict.split(" + ")[0])


def _says_unexplained(diag) -> bool:
    """The diagnosis says a gap is left that the catalogue does not explain (not merely that
    nothing was attributed: 'no significant gap' is no such statement)."""
    return diag.unexplained_remains


def _run_one(design, layer, effect, strength, rng, n_boot):
    trial = _TRIALS[layer]
    with tempfile.TemporaryDirectory() as tmp:
        diag, true_shrink = trial(design, effect, strength, rng, Path(tmp), n_boot)
    return {"layer": layer, "effect": effect, "strength": float(strength), "top": _top(diag),
            "verdict": diag.verdict, "remains": bool(diag.unexplained_remains),
            "says_unexplained": _says_unexplained(diag), "gap_before": diag.gap_before,
            "gap_after": diag.gap_after, "pred_shrink": diag.shrink_abs,
            "true_shrink": true_shrink, "shrink_pct": diag.shrink_pct}


def draw_schedule(rng: np.random.Generator, trials: int, effects, out) -> list[tuple[str, str]]:
    """The hidden (effect, kind) of each run, in random order: a quarter 'none', a quarter
    out-of-catalogue, the rest catalogue effects, each effect of a kind as often as the others
    (up to one; which ones get the extra runs is drawn), so that every effect is scored."""
    n_none, n_out = trials // 4, trials // 4
    n_in = trials - n_none - n_out
    runs = ([("none", "none")] * n_none + [(e, "out") for e in balanced_draw(rng, out, n_out)]
            + [(e, "in") for e in balanced_draw(rng, effects, n_in)])
    return [runs[i] for i in rng.permutation(len(runs))]


def run_benchmark(design, layer: str, *, trials: int, seed: int, n_boot: int = 500,
                  log=print) -> dict:
    """Score one layer over ``trials`` runs (:func:`draw_schedule`: none, out-of-catalogue and
    catalogue effects, the latter at 0.5-1.5 times their moderate strength); only the written
    files reach the diagnosis."""
    effects, out, strength0, _ = _layer(layer)
    rng = np.random.default_rng(seed)
    records = []
    for t, (effect, kind) in enumerate(draw_schedule(rng, trials, effects, out)):
        strength = 0.0 if effect == "none" else strength0[effect] * rng.uniform(0.5, 1.5)
        rec = _run_one(design, layer, effect, strength, rng, n_boot) | {"kind": kind}
        records.append(rec)
        if log:
            log(f"{layer} trial {t}: injected {effect} ({strength:.3g}) -> {rec['verdict']} "
                f"(gap {rec['gap_before']:.3f} -> {rec['gap_after']:.3f})")
    return _score(records)


def run_observer_benchmark(design, *, trials: int, seed: int, n_participants: int = 4,
                           n_boot: int = 500) -> dict:
    """The observer layer's benchmark (kept for callers of the first version)."""
    return run_benchmark(design, "observer", trials=trials, seed=seed, n_boot=n_boot)


def run_thresholds(design, layer: str, *, reps: int, seed: int,
                   multipliers=(0.125, 0.25, 0.5, 1.0), n_boot: int = 300, log=print) -> dict:
    """Detection threshold per effect: the smallest strength (a multiple of the moderate one)
    from which on every larger multiple is identified top-1 in >= 80 % of ``reps`` runs.

    Returns ``{effect: {"threshold": strength or None, "hit_rate": {strength: rate}}}``.
    """
    effects, _, strength0, _ = _layer(layer)
    rng = np.random.default_rng(seed)
    out = {}
    for effect in effects:
        rates = {}
        for m in multipliers:
            s = strength0[effect] * m
            hits = [_run_one(design, layer, effect, s, rng, n_boot)["top"] == effect
                    for _ in range(reps)]
            rates[float(s)] = float(np.mean(hits))
        threshold = None
        for s in sorted(rates, reverse=True):
            if rates[s] < TARGETS["threshold_hit_rate"]:
                break
            threshold = s
        out[effect] = {"threshold": threshold, "hit_rate": rates}
        if log:
            log(f"{layer} threshold {effect}: {threshold} (hit rates {rates})")
    return out


def run_layer_benchmark(design, *, trials: int, seed: int, n_boot: int = 300,
                        log=print) -> dict:
    """Which layer carries the gap: each run injects one catalogue effect at moderate strength
    into one layer chosen at random (nothing into the others), diagnoses all three from their
    files and checks :func:`analysis.gap.which_layer` names that layer."""
    from analysis.gap import which_layer

    rng = np.random.default_rng(seed)
    hits = []
    for t in range(trials):
        layer = str(rng.choice(list(_TRIALS)))
        effects, _, strength0, _ = _layer(layer)
        effect = str(rng.choice(effects))
        strength = strength0[effect] * rng.uniform(0.5, 1.5)
        diags = {}
        with tempfile.TemporaryDirectory() as tmp:
            for name, trial in _TRIALS.items():
                e, s = (effect, strength) if name == layer else ("none", 0.0)
                (Path(tmp) / name).mkdir()
                diags[name], _ = trial(design, e, s, rng, Path(tmp) / name, n_boot)
        which = which_layer(diags)
        hits.append(which["layer"] == layer)
        if log:
            log(f"layers trial {t}: injected {effect} into {layer} -> {which['layer']} "
                f"(gaps {', '.join(f'{n} {g[0]:.3f}' for n, g in which['gaps'].items())})")
    return {"layer_rate": float(np.mean(hits)), "n": trials}


def _score(records):
    def rate(sel, ok):
        return _rate(records, sel, ok)
    top1, n_in = rate(lambda r: r["kind"] == "in", lambda r: r["top"] == r["effect"])
    false_attr, n_none = rate(lambda r: r["kind"] == "none",
                              lambda r: r["top"] != "unexplained" or r.get("remains", False))
    unexpl, n_out = rate(lambda r: r["kind"] == "out",
                         lambda r: r.get("says_unexplained", r["top"] == "unexplained"))
    errs = [abs(r["pred_shrink"] - r["true_shrink"]) / r["true_shrink"] for r in records
            if r["kind"] == "in" and r["top"] == r["effect"] and r["true_shrink"] > 0]
    per_effect = {}
    for r in records:
        if r["kind"] != "none":
            hit = (r["top"] == r["effect"] if r["kind"] == "in"
                   else r.get("says_unexplained", r["top"] == "unexplained"))
            k = per_effect.setdefault(r["effect"], [0, 0])
            k[0] += hit
            k[1] += 1
    return {"top1": top1, "n_in": n_in, "false_attribution": false_attr, "n_none": n_none,
            "per_effect": per_effect,
            "unexplained_out": unexpl, "n_out": n_out,
            "shrink_error": float(np.median(errs)) if errs else float("nan"),
            "shrink_error_p90": float(np.percentile(errs, 90)) if errs else float("nan"),
            "records": records}


def format_scores(layer: str, r: dict, thresholds: dict | None = None) -> str:
    """The scores against the issue's targets, one line each."""
    def mark(ok, n=1):
        return "n/a (no runs)" if n == 0 else ("met" if ok else "NOT met")
    lines = [
        (f"{layer}: top-1 {r['top1']:.3f} (n={r['n_in']}; target >= {TARGETS['top1']}) "
        f"{mark(r['top1'] >= TARGETS['top1'], r['n_in'])}"),
        (f"{layer}: false attributions {r['false_attribution']:.3f} (n={r['n_none']}; target "
        f"<= {TARGETS['false_attribution']}) "
        f"{mark(r['false_attribution'] <= TARGETS['false_attribution'], r['n_none'])}"),
        (f"{layer}: unexplained for out-of-catalogue {r['unexplained_out']:.3f} (n={r['n_out']}; "
        f"target >= {TARGETS['unexplained_out']}) "
        f"{mark(r['unexplained_out'] >= TARGETS['unexplained_out'], r['n_out'])}"),
        (f"{layer}: shrinkage error median {100 * r['shrink_error']:.1f} % of the gap, 90th "
        f"percentile {100 * r['shrink_error_p90']:.1f} % (target <= "
        f"{100 * TARGETS['shrink_error']:.0f} %) "
        f"{mark(r['shrink_error'] <= TARGETS['shrink_error'])}"),
    ]
    if r.get("per_effect"):
        lines.append(f"{layer}: right verdict per effect (catalogue: the effect; outside: "
                     "'unexplained'): " + ", ".join(
                         f"{e} {k[0]}/{k[1]}" for e, k in sorted(r["per_effect"].items())))
    for effect, t in (thresholds or {}).items():
        rates = ", ".join(f"{s:.3g}: {v:.2f}" for s, v in t["hit_rate"].items())
        thr = "none in the tested range" if t["threshold"] is None else f"{t['threshold']:.3g}"
        lines.append(f"{layer}: detection threshold {effect}: {thr} "
                     f"(top-1 rate per strength: {rates})")
    return "\n".join(lines)
