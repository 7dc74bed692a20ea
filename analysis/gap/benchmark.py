"""Blind benchmark: inject a hidden effect, write session files, diagnose only the files."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from analysis.gap import inject
from analysis.gap.diagnose import diagnose_observer_files
from analysis.gap.observer import load_sessions, observer_frame, observer_nll

__all__ = ["run_observer_benchmark"]


def run_observer_benchmark(design, *, trials: int, seed: int, n_participants: int = 4,
                           n_boot: int = 500) -> dict:
    """Score identification, false attributions and 'unexplained' rate over ``trials`` runs.

    Each run draws: none (1/4), out-of-catalogue (1/4), or a catalogue effect (1/2) at a random
    strength; only the written CSVs reach the diagnosis.
    """
    rng = np.random.default_rng(seed)
    strengths = {"crosstalk": 0.3, "central_tendency": 0.3, "illumination_gain": 0.3,
                 "label_rounding": 0.4, "lapses": 0.15, "serial_dependence": 0.3,
                 "depth_noise_scaling": 0.3, "stimulus_bias": 0.3}
    records = []
    for t in range(trials):
        u = rng.random()
        if u < 0.25:
            effect, kind = "none", "none"
        elif u < 0.5:
            effect, kind = str(rng.choice(inject.OUT_OF_CATALOGUE)), "out"
        else:
            effect, kind = str(rng.choice(inject.OBSERVER_EFFECTS)), "in"
        strength = 0.0 if effect == "none" else strengths[effect] * rng.uniform(0.5, 1.5)
        with tempfile.TemporaryDirectory() as tmp:
            real = inject.simulate_sessions(design, n_participants, rng, effect, strength)
            sim = inject.simulate_sessions(design, n_participants, rng)
            inject.write_sessions(real, Path(tmp) / "real")
            inject.write_sessions(sim, Path(tmp) / "sim")
            diag, _ = diagnose_observer_files(Path(tmp) / "real", Path(tmp) / "sim", design,
                                              seed=int(rng.integers(2**31)), n_boot=n_boot)
            true_shrink = _observer_true_shrink(diag, Path(tmp) / "real", design, effect,
                                                strength)
        top = diag.steps[0]["added"] if diag.steps else "unexplained"
        records.append({"effect": effect, "kind": kind, "strength": strength, "top": top,
                        "verdict": diag.verdict, "shrink_pct": diag.shrink_pct,
                        "gap_before": diag.gap_before, "gap_after": diag.gap_after,
                        "pred_shrink": diag.shrink_abs, "true_shrink": true_shrink})
        print(f"trial {t}: injected {effect} ({strength:.2f}) -> {diag.verdict} "
              f"(gap {diag.gap_before:.3f} -> {diag.gap_after:.3f})", flush=True)
    return _score(records)


def _score(records):
    def rate(sel, ok):
        sel = [r for r in records if sel(r)]
        return (sum(ok(r) for r in sel) / len(sel) if sel else float("nan")), len(sel)
    top1, n_in = rate(lambda r: r["kind"] == "in", lambda r: r["top"] == r["effect"])
    false_attr, n_none = rate(lambda r: r["kind"] == "none", lambda r: r["top"] != "unexplained")
    unexpl, n_out = rate(lambda r: r["kind"] == "out", lambda r: r["top"] == "unexplained")
    # Shrinkage error (see _observer_true_shrink): |predicted - true| / true gap, over the
    # in-catalogue runs whose effect was identified.
    errs = [abs(r["pred_shrink"] - r["true_shrink"]) / r["true_shrink"] for r in records
            if r["kind"] == "in" and r["top"] == r["effect"] and r["true_shrink"] > 0]
    shrink_err = float(np.median(errs)) if errs else float("nan")
    shrink_p90 = float(np.percentile(errs, 90)) if errs else float("nan")
    return {"shrink_error": shrink_err, "shrink_error_p90": shrink_p90, "top1": top1,
            "n_in": n_in, "false_attribution": false_attr, "n_none": n_none,
            "unexplained_out": unexpl, "n_out": n_out, "records": records}


def _observer_truth(effect: str, strength: float, ills: list[str]) -> list:
    """The injected effect as the catalogue's parameters (the generating process)."""
    s = float(strength)
    if effect in ("none",) or effect in inject.OUT_OF_CATALOGUE:
        return []
    if effect == "crosstalk":
        return [(effect, {"c": s})]
    if effect in ("central_tendency", "serial_dependence"):
        return [(effect, {"gloss": s, "depth": s})]
    if effect == "illumination_gain":
        return [(effect, {"gain": {i: (s if k == 0 else -s) for k, i in enumerate(ills)}})]
    if effect == "label_rounding":
        return [(effect, {"weight": s})]
    if effect == "lapses":
        return [(effect, {"rate": s})]
    raise ValueError(f"no truth mapping for {effect!r}")


def _observer_true_shrink(diag, real_path: Path, design, effect: str, strength: float) -> float:
    """True shrinkage on the diagnosis's held-out trials: the plain simulation's loss (as the
    diagnosis measured it) minus the loss of the generating process itself (the simulation
    extended by the injected effect at its injected strength, noise SD at its injected value).

    'Injected effect removed' is the generating process, not the counterfactual data without
    the effect: lapses and label rounding change the data's own entropy, so no model of the
    real data can reach the loss of effect-free data. For out-of-catalogue effects the truth
    is not expressible in the catalogue: NaN.
    """
    if effect in inject.OUT_OF_CATALOGUE:
        return float("nan")
    real = observer_frame(load_sessions(real_path), design)
    ids = [f"{p}|{s}|{o}" for p, s, o in zip(real["participant"], real["session"],
                                             real["order"])]
    test = real[np.isin(ids, list(diag.heldout))].copy()
    test.attrs = dict(real.attrs)
    truth = _observer_truth(effect, strength, [i.name for i in design.illuminations])
    sigma = {"gloss": inject.NOISE_SD, "depth": inject.NOISE_SD}
    return float(diag.loss_before - observer_nll(test, truth, sigma).mean())
