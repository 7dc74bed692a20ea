"""Layer-independent ranking of candidate extensions by held-out gain.

A candidate is a parameterised extension of a layer's simulation. It is fitted on a training
split and scored by the per-unit loss (negative log-likelihood) it removes on held-out units.
Gains get percentile-bootstrap CIs and one-sided bootstrap p-values (H1: gain > 0), corrected
for the number of candidates by Holm (1979). Nothing significant -> verdict 'unexplained'.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["Candidate", "CandidateScore", "Diagnosis", "GapError", "candidate", "catalogue",
           "diagnose_losses", "holm", "register", "split_held_out"]


class GapError(ValueError):
    """Bad input to the sim-to-real gap diagnosis."""


def split_held_out(data, held_out, rng: np.random.Generator):
    """(train, test) rows of a data frame; ``held_out`` is a boolean mask, or None for a random
    half of the rows. Both parts keep ``data.attrs`` (the loaders' metadata)."""
    if held_out is None:
        held_out = np.zeros(len(data), bool)
        held_out[rng.permutation(len(data))[: len(data) // 2]] = True
    train, test = data[~held_out].copy(), data[held_out].copy()
    train.attrs, test.attrs = dict(data.attrs), dict(data.attrs)
    return train, test


@dataclass(frozen=True)
class Candidate:
    """One catalogue entry: ``fit(train, active) -> params``; ``loss(test, params_list)``.

    ``loss`` returns the per-unit loss of the simulation extended by every fitted candidate in
    the list (``[]`` is the plain simulation), shape (n_units,).

    ``apply``: the candidate's term in the layer's mean or likelihood; ``inject``: its
    injector for the benchmark; ``default_strength`` (in ``units``): the benchmark's moderate
    strength; ``truth(strength) -> params``: the fitted parameters a right fit should recover.
    """

    name: str
    fit: Callable
    description: str = ""
    apply: Callable | None = None
    inject: Callable | None = None
    default_strength: float | None = None
    units: str = ""
    truth: Callable | None = None


_REGISTRY: dict[str, dict[str, Candidate]] = {}


def register(layer: str, cand: Candidate) -> Candidate:
    """Add ``cand`` to ``layer``'s catalogue (a second candidate of the same name replaces it)."""
    _REGISTRY.setdefault(layer, {})[cand.name] = cand
    return cand


def catalogue(layer: str) -> list[Candidate]:
    """The registered candidates of ``layer``, in registration order."""
    return list(_REGISTRY.get(layer, {}).values())


def candidate(layer: str, name: str) -> Candidate:
    """One registered candidate; GapError naming the known ones for an unknown name."""
    try:
        return _REGISTRY[layer][name]
    except KeyError:
        known = sorted(_REGISTRY.get(layer, {}))
        raise GapError(f"no {layer} candidate {name!r}; known: {known}") from None


@dataclass(frozen=True)
class CandidateScore:
    name: str
    gain: float
    ci_low: float
    ci_high: float
    p_one_sided: float
    p_holm: float
    significant: bool


@dataclass(frozen=True)
class Diagnosis:
    """Ranking, greedy steps and before/after gap (loss units: mean NLL per held-out unit)."""

    layer: str
    ranking: tuple
    steps: tuple
    verdict: str
    gap_before: float
    gap_after: float
    shrink_abs: float
    shrink_abs_ci: tuple
    shrink_pct: float
    shrink_pct_ci: tuple
    seed: int
    loss_before: float = float("nan")
    loss_after: float = float("nan")
    heldout: tuple = ()
    explained_share: float = float("nan")
    min_share: float = 0.0
    min_gain: float = 0.0
    loss_info: dict | None = None
    gap_before_ci: tuple = ()
    gap_after_ci: tuple = ()
    remaining: dict | None = None

    def to_dict(self) -> dict:
        out = asdict(self)
        out["ranking"] = [asdict(s) if not isinstance(s, dict) else s for s in self.ranking]
        return out


def holm(p: np.ndarray) -> np.ndarray:
    """Holm step-down adjusted p-values (Holm 1979), monotone and capped at 1."""
    p = np.asarray(p, float)
    order = np.argsort(p)
    m = p.size
    adj = np.empty(m)
    running = 0.0
    for rank, idx in enumerate(order):
        running = max(running, min(1.0, (m - rank) * p[idx]))
        adj[idx] = running
    return adj


def _boot(diff: np.ndarray, rng: np.random.Generator, n_boot: int) -> np.ndarray:
    idx = rng.integers(0, diff.size, size=(n_boot, diff.size))
    return diff[idx].mean(axis=1)


def diagnose_losses(
    layer: str,
    candidates: list[Candidate],
    train,
    test,
    loss: Callable,
    gap_floor: Callable,
    *,
    rng: np.random.Generator,
    seed: int,
    alpha: float = 0.05,
    n_boot: int = 2000,
    max_steps: int | None = None,
    unit_ids: Callable | None = None,
    min_share: float = 0.0,
    min_gain: float = 0.0,
    loss_info: dict | None = None,
    ceiling: Callable | None = None,
) -> Diagnosis:
    """Rank candidates, combine greedily, and measure the held-out gap before and after.

    Parameters
    ----------
    loss : callable ``loss(data, fitted) -> ndarray (n_units,)``
        ``fitted`` is a list of ``(name, params)``.
    gap_floor : callable ``gap_floor(data) -> ndarray (n_units,)``
        Per-unit loss the simulation would have on data it generated itself (its own noise);
        gap = loss - floor, so a perfect simulation has gap 0.
    unit_ids : callable ``unit_ids(test) -> sequence of str``, optional
        Names of the held-out units, recorded in ``Diagnosis.heldout`` so a reader (or the
        benchmark's scorer) can evaluate other models on exactly the same units.
    max_steps : int, optional
        Most candidates the greedy combination adds (default: the whole catalogue). Each step
        must reduce the held-out loss of the combination so far significantly (one-sided
        bootstrap p times the number of candidates left < alpha), so it stops by itself when
        nothing more helps; real photos often carry several effects at once.
    min_share : float
        An attribution needs the chosen candidates to remove at least this share of the
        held-out gap; below it the verdict is 'unexplained' (the partial steps are kept). 0:
        any significant gain attributes.
    min_gain : float
        A candidate (or a greedy step) counts only if its held-out gain is also at least this
        many nats per unit: a significant but negligible gain (a few thousandths of a nat per
        trial, which a large data set makes significant) is no cause of a gap. 0: none.
    loss_info : dict, optional
        Parameters of the loss itself (e.g. the noise model), recorded as given.
    ceiling : callable ``ceiling(train, test) -> ndarray (n_units,)``, optional
        Per-held-out-unit loss of a flexible data-driven model fitted on ``train``; the chosen
        model's loss minus it is the gap that remains (``Diagnosis.remaining``: mean, 95 % CI
        and one-sided bootstrap p that it is > 0).
    """
    if not candidates:
        raise GapError(f"layer {layer!r}: empty candidate catalogue; pass at least one candidate")
    base = loss(test, [])
    floor = gap_floor(test)
    scores = []
    fitted = {}
    for cand in candidates:
        params = cand.fit(train, [])
        fitted[cand.name] = params
        diff = base - loss(test, [(cand.name, params)])
        b = _boot(diff, rng, n_boot)
        p = (np.sum(b <= 0) + 1) / (n_boot + 1)
        scores.append((cand.name, float(diff.mean()), *np.percentile(b, [2.5, 97.5]), p))
    p_adj = holm(np.array([s[4] for s in scores]))
    ranking = sorted(
        (
            CandidateScore(n, g, float(lo), float(hi), float(p), float(pa),
                           bool(pa < alpha and g >= min_gain))
            for (n, g, lo, hi, p), pa in zip(scores, p_adj)
        ),
        key=lambda s: -s.gain,
    )
    if max_steps is None:
        max_steps = len(candidates)
    chosen: list = []
    steps = []
    current = base
    remaining = [s.name for s in ranking if s.significant]
    by_name = {c.name: c for c in candidates}
    while remaining and len(chosen) < max_steps:
        best = None
        for name in remaining:
            params = by_name[name].fit(train, chosen)
            trial = loss(test, chosen + [(name, params)])
            diff = current - trial
            b = _boot(diff, rng, n_boot)
            p = (np.sum(b <= 0) + 1) / (n_boot + 1)
            # Later steps are tested against the remaining count (Holm-like step-down).
            if (p * len(remaining) < alpha and diff.mean() >= min_gain
                    and (best is None or diff.mean() > best[1])):
                best = (name, float(diff.mean()), params, trial, p)
        if best is None:
            break
        name, gain, params, trial, p = best
        chosen.append((name, params))
        current = trial
        remaining.remove(name)
        steps.append({"added": name, "gain": gain, "p": float(p),
                      "params": _jsonable(params)})
    gap_b = base - floor
    gap_a = current - floor
    d = gap_b - gap_a
    idx = rng.integers(0, d.size, size=(n_boot, d.size))
    shrink_b = d[idx].mean(axis=1)
    pct_b = 100 * shrink_b / np.maximum(gap_b[idx].mean(axis=1), 1e-12)
    gb, ga = float(gap_b.mean()), float(gap_a.mean())
    share = (gb - ga) / gb if gb > 0 else 0.0
    remaining = None
    if ceiling is not None:
        rest = current - np.asarray(ceiling(train, test), float)
        b = _boot(rest, rng, n_boot)
        remaining = {"gap": float(rest.mean()),
                     "ci": [float(x) for x in np.percentile(b, [2.5, 97.5])],
                     "p": float((np.sum(b <= 0) + 1) / (n_boot + 1))}
    explained = bool(steps) and share >= min_share
    verdict = " + ".join(s["added"] for s in steps) if explained else "unexplained"
    return Diagnosis(
        layer=layer,
        ranking=tuple(asdict(s) for s in ranking),
        steps=tuple(steps),
        verdict=verdict,
        gap_before=gb,
        gap_after=ga,
        shrink_abs=gb - ga,
        shrink_abs_ci=tuple(float(x) for x in np.percentile(shrink_b, [2.5, 97.5])),
        shrink_pct=100 * (gb - ga) / gb if gb > 0 else 0.0,
        shrink_pct_ci=tuple(float(x) for x in np.percentile(pct_b, [2.5, 97.5])),
        seed=seed,
        loss_before=float(base.mean()),
        loss_after=float(current.mean()),
        heldout=tuple(str(u) for u in unit_ids(test)) if unit_ids is not None else (),
        explained_share=float(share),
        min_share=float(min_share),
        min_gain=float(min_gain),
        loss_info=loss_info,
        gap_before_ci=tuple(float(x) for x in np.percentile(gap_b[idx].mean(axis=1),
                                                              [2.5, 97.5])),
        gap_after_ci=tuple(float(x) for x in np.percentile(gap_a[idx].mean(axis=1),
                                                             [2.5, 97.5])),
        remaining=remaining,
    )


def _jsonable(params):
    if isinstance(params, dict):
        return {str(k): _jsonable(v) for k, v in params.items()}
    if isinstance(params, (np.floating, np.integer)):
        return params.item()
    if isinstance(params, np.ndarray):
        return params.tolist()
    return params
