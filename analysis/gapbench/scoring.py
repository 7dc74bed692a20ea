"""Scores shared by the blind benchmarks: rates over cases, seed agreement, shrinkage truth.

The harder benchmarks of each layer (``bench_display``, ``bench_render``) and the plain one
(``benchmark``) score their records the same way; the rules live here once.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

__all__ = ["balanced_draw", "per_case", "rate", "render_true_shrink", "score_line",
           "seed_agreement", "shrink_errors"]


def balanced_draw(rng: np.random.Generator, names, n: int) -> list[str]:
    """``n`` names, each as often as the others up to one (which get the extra one is drawn):
    whole shuffled rounds of ``names``, cut at ``n``. The order within a round is random, so
    shuffle the result before use if cut rounds must not come last."""
    reps = -(-n // len(names)) if n else 0
    return [str(e) for _ in range(reps) for e in rng.permutation(list(names))][:n]


def rate(records: list[dict], where, ok: Callable[[dict], bool]) -> tuple:
    """``(share of the selected records for which ``ok`` holds, how many)``; NaN when none.

    ``where``: the case names to select (``record["case"]``), or a predicate on a record."""
    if not callable(where):
        cases = set(where)

        def where(r):
            return r["case"] in cases
    sel = [r for r in records if where(r)]
    return (float(np.mean([ok(r) for r in sel])) if sel else float("nan")), len(sel)


def shrink_errors(records: list[dict], cases: Iterable[str],
                  right: Callable[[dict], bool]) -> list[float]:
    """|predicted - true| / true shrinkage of the records of ``cases`` diagnosed right (true
    shrinkage > 0)."""
    cases = set(cases)
    return [abs(r["pred_shrink"] - r["true_shrink"]) / r["true_shrink"] for r in records
            if r["case"] in cases and right(r) and r["true_shrink"] > 0]


def seed_agreement(records: list[dict]) -> float:
    """Share of (case, seed) verdicts equal to the case's first seed's (``seed_verdicts``)."""
    agree = [np.mean([v == r["seed_verdicts"][0] for v in r["seed_verdicts"]])
             for r in records]
    return float(np.mean(agree)) if agree else float("nan")


def per_case(records: list[dict], right: Callable[[dict], bool]) -> dict:
    """``{case: [right, total]}``."""
    out = {}
    for r in records:
        k = out.setdefault(r["case"], [0, 0])
        k[0] += right(r)
        k[1] += 1
    return out


def score_line(prefix: str, name: str, value: float, n: int, target: str, ok: bool) -> str:
    """``"<prefix>: <name> 0.917 (n=12; target >= 0.95) NOT met"`` (``n/a`` with no cases)."""
    mark = "n/a (no runs)" if n == 0 else ("met" if ok else "NOT met")
    return f"{prefix}: {name} {value:.3f} (n={n}; target {target}) {mark}"


def render_true_shrink(diag, fit_folder: Path, truth: dict) -> float:
    """Held-out loss of the plain simulation minus that of the generating photo (``truth``:
    noiseless image per level name), under the diagnosis's noise model (read and shot noise,
    ``loss_info['noise_a2_b']``), on the diagnosis's held-out pixels."""
    from analysis.gap import noise_sd

    photos, renders = {}, {}
    for name in truth:
        with np.load(Path(fit_folder) / "residuals" / f"{name}.npz") as a:
            photos[name] = a["photo"][..., 0].astype(float)
            renders[name] = a["render"][..., 0].astype(float)
    noise = diag.loss_info["noise_a2_b"]
    nll = []
    for u in diag.heldout:
        name, y, x = u.split("|")
        at = (int(y), int(x))
        sd = float(noise_sd(renders[name][at], *noise[name]))
        r = (photos[name][at] - truth[name][at]) / sd
        nll.append(0.5 * np.log(2 * np.pi * sd**2) + 0.5 * r**2)
    return float(diag.loss_before - np.mean(nll))
