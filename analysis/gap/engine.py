"""Layer-independent ranking of candidate extensions by held-out gain, and the test of what
remains.

A candidate is a parameterised extension of a layer's simulation (one :class:`Candidate`
object per effect, registered per layer with :func:`register`). It is fitted on training data
and scored by the per-unit loss (negative log-likelihood) it removes on held-out units. Gains
get percentile-bootstrap CIs and one-sided bootstrap p-values (H1: gain > 0), corrected for
the number of candidates by Holm (1979). Candidates are then combined greedily; after each
step every remaining candidate is re-tested. Finally the chosen model's held-out loss is
compared with a flexible, data-driven *ceiling* model (paired bootstrap): a significant
difference is a gap the catalogue does not explain, reported with where it lies.

Held-out units come either from one split (``train``, ``test``) or from cross-fitting
(``folds``: every unit held out once per repeat, per-unit losses averaged over repeats), so
that the verdict does not hinge on one random split.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd

__all__ = ["Candidate", "CandidateScore", "Diagnosis", "GapError", "OutOfCatalogue", "candidate",
           "catalogue", "diagnose_losses", "effect", "holm", "out_of_catalogue", "register",
           "register_out_of_catalogue", "split_held_out", "strengths"]

#: Layers whose catalogue is registered by importing ``analysis.gap.<layer>``.
_LAYER_MODULES = ("observer", "display", "render")


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
    """One catalogue entry: everything about one effect, in one place.

    ============== ============================ ===============================================
    field          type                         meaning
    ============== ============================ ===============================================
    name           str                          the effect's name in verdicts and reports
    fit            ``fit(train, chosen)``       its parameters fitted on training data, given
                                                the already chosen ``[(name, params), ...]``
    description    str                          one line for reports
    apply          callable or None             its term in the layer's mean or likelihood
                                                (signature per layer, e.g. the observer's
                                                ``apply(data, prediction, params)``)
    inject         callable or None             its injector for the blind benchmark (per
                                                layer; never called by the diagnosis)
    default_strength float                      the benchmark's moderate strength
    units          str                          units of the strength
    truth          ``truth(strength, **ctx)``   the fitted parameters the injected strength
                                                should give, ``[(name, params), ...]`` (the
                                                benchmark's shrinkage score)
    ============== ============================ ===============================================
    """

    name: str
    fit: Callable
    description: str = ""
    apply: Callable | None = None
    inject: Callable | None = None
    default_strength: float = float("nan")
    units: str = ""
    truth: Callable | None = None


_REGISTRY: dict[str, dict[str, Candidate]] = {}


def register(layer: str, cand: Candidate) -> Candidate:
    """Add ``cand`` to ``layer``'s catalogue (in registration order); returns it.

    Raises
    ------
    GapError
        If ``cand`` is not a Candidate, or another candidate of that name is registered.
    """
    return _add(layer, cand, Candidate, "register", _REGISTRY, "a candidate",
                _OUT_REGISTRY, "an out-of-catalogue effect")


def _add(layer, obj, kind, caller, registry, what, others, other_what):
    """Put ``obj`` into ``registry[layer]`` unless its name is taken (by another object there,
    or by one in ``others[layer]``)."""
    if not isinstance(obj, kind):
        raise GapError(f"{caller}({layer!r}, ...): {obj!r} is not an engine.{kind.__name__}")
    if obj.name in others.get(layer, {}):
        raise GapError(f"layer {layer!r} has {other_what} {obj.name!r}; {what} needs another "
                       "name")
    table = registry.setdefault(layer, {})
    old = table.get(obj.name)
    if old is not None and old != obj:
        raise GapError(f"layer {layer!r} already has {what} {obj.name!r}; pick another name")
    table[obj.name] = obj
    return obj


def catalogue(layer: str) -> list[Candidate]:
    """The registered candidates of ``layer``, in registration order.

    Raises
    ------
    GapError
        If no candidate is registered for ``layer``.
    """
    if layer not in _REGISTRY and layer in _LAYER_MODULES:
        module = importlib.import_module(f"analysis.gap.{layer}")
        # A layer module that lists its candidates without registering them (``<LAYER>_
        # CANDIDATES``) gets them registered in that order.
        for cand in getattr(module, f"{layer.upper()}_CANDIDATES", ()) if not _REGISTRY.get(
                layer) else ():
            register(layer, cand)
    if not _REGISTRY.get(layer):
        raise GapError(f"no candidates registered for layer {layer!r}; known layers: "
                       f"{sorted(set(_REGISTRY) | set(_LAYER_MODULES))}")
    return list(_REGISTRY[layer].values())


def candidate(layer: str, name: str) -> Candidate:
    """The candidate ``name`` of ``layer``.

    Raises
    ------
    GapError
        ``unknown candidate ...; known: ...`` for a name not in the catalogue.
    """
    table = {c.name: c for c in catalogue(layer)}
    if name not in table:
        raise GapError(f"unknown candidate {name!r} for layer {layer!r}; known: "
                       f"{', '.join(table)}")
    return table[name]


@dataclass(frozen=True)
class OutOfCatalogue:
    """An effect outside a layer's catalogue: the blind benchmark injects it to check that the
    diagnosis calls its gap unexplained; no candidate models it and the diagnosis never sees
    it. Registered per layer with :func:`register_out_of_catalogue`, beside the candidates.

    ================ ============ ======================================================
    field            type         meaning
    ================ ============ ======================================================
    name             str          the effect's name in the benchmark's records
    inject           callable     its injector, with the layer's candidates' signature
    default_strength float        the benchmark's moderate strength
    units            str          units of the strength
    description      str          one line for reports
    ================ ============ ======================================================
    """

    name: str
    inject: Callable
    default_strength: float
    units: str = ""
    description: str = ""


_OUT_REGISTRY: dict[str, dict[str, OutOfCatalogue]] = {}


def register_out_of_catalogue(layer: str, eff: OutOfCatalogue) -> OutOfCatalogue:
    """Add ``eff`` to ``layer``'s out-of-catalogue effects (in registration order); returns it.

    Raises
    ------
    GapError
        If ``eff`` is not an OutOfCatalogue, or its name is taken by another out-of-catalogue
        effect or by a candidate of the layer.
    """
    return _add(layer, eff, OutOfCatalogue, "register_out_of_catalogue", _OUT_REGISTRY,
                "an out-of-catalogue effect", _REGISTRY, "a candidate")


def out_of_catalogue(layer: str) -> list[OutOfCatalogue]:
    """The registered out-of-catalogue effects of ``layer``, in registration order (the
    benchmark's injectors register theirs on import; empty before)."""
    return list(_OUT_REGISTRY.get(layer, {}).values())


def effect(layer: str, name: str) -> Candidate | OutOfCatalogue:
    """The candidate or out-of-catalogue effect ``name`` of ``layer``.

    Raises
    ------
    GapError
        ``unknown effect ...; known: ...`` (the candidates, then the out-of-catalogue
        effects) for a name in neither.
    """
    table = {c.name: c for c in catalogue(layer)} | _OUT_REGISTRY.get(layer, {})
    if name not in table:
        out = ", ".join(_OUT_REGISTRY.get(layer, {})) or "none registered"
        raise GapError(f"unknown effect {name!r} for layer {layer!r}; known: candidates "
                       f"{', '.join(c.name for c in catalogue(layer))}; out of catalogue "
                       f"{out}")
    return table[name]


def strengths(layer: str) -> dict[str, float]:
    """Moderate strength per effect of ``layer``: each candidate's and each out-of-catalogue
    effect's ``default_strength`` (the one place it is written)."""
    return ({c.name: float(c.default_strength) for c in catalogue(layer)}
            | {e.name: float(e.default_strength) for e in out_of_catalogue(layer)})


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
    """Ranking, greedy steps, before/after gap and the remaining gap (loss units: mean NLL per
    held-out unit).

    ``verdict`` names the chosen candidates (``a + b``) or is ``'unexplained'``; ``summary`` is
    the plain-language sentence. ``remaining`` (with a ceiling) holds the chosen model's
    held-out loss above the ceiling's: ``gap``, ``ci``, ``p``, ``significant``, ``where``;
    in a layer with a practical tolerance also ``size`` (the misfit in the data's units),
    ``tolerance``, ``size_unit``, ``size_source`` and ``within_tolerance`` (significant in
    nats but smaller than the tolerance: then ``significant`` is False).
    ``floor_status`` is ``'ok'`` or ``'misestimated'`` (a gap, before or after, whose 95 % CI
    lies wholly below zero: the floor is wrong, not the simulation right).
    ``explained_share``, in [0, 1], is the share of the held-out loss above the floor that the
    chosen candidates remove or, with a ceiling that removes any, the share of what the ceiling
    removes (so a share never exceeds what a flexible model of the data allows; all of it
    where the ceiling removes nothing and the chosen candidates remove something);
    ``ceiling_share`` is the share of the gap above the floor that the ceiling removes.
    """

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
    ceiling_share: float = float("nan")
    floor_status: str = "ok"
    summary: str = ""
    split: str = ""
    warnings: tuple = ()

    @property
    def unexplained_remains(self) -> bool:
        """True when a gap is left that the catalogue does not explain: with a ceiling, the
        chosen model (or the plain simulation, if nothing is chosen) falls significantly short
        of it; without one, nothing (or too little) attributed of a gap above tolerance."""
        if self.remaining is not None:
            return bool(self.remaining.get("significant"))
        if self.verdict != "unexplained":
            return False
        return bool(self.steps) or bool(
            self.gap_before_ci and self.gap_before_ci[0] > max(self.min_gain, 0.0))

    def to_dict(self) -> dict:
        out = asdict(self)
        out["ranking"] = [asdict(s) if not isinstance(s, dict) else s for s in self.ranking]
        out["unexplained_remains"] = self.unexplained_remains
        return _jsonable(out)


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


def _boot_idx(rng: np.random.Generator, n: int, n_boot: int) -> np.ndarray:
    return rng.integers(0, n, size=(n_boot, n))


def _test(diff: np.ndarray, idx: np.ndarray,
          clusters: np.ndarray | None = None) -> tuple[float, float, float, float]:
    """(mean, CI low, CI high, one-sided p for mean > 0) of a per-unit difference.

    Without ``clusters``: percentile bootstrap over units (``idx``). With ``clusters`` (a code
    per unit; units sharing one are dependent): the normal approximation with a cluster-robust
    standard error (Liang & Zeger 1986), SE^2 = sum_g (sum_{i in g} (d_i - mean))^2 / n^2 --
    the limit of a bootstrap over clusters as its resamples grow, without its Monte-Carlo
    error (a p-value near alpha / k counted from a few hundred resamples rests on a handful of
    them, and flips with the seed)."""
    if clusters is None:
        b = diff[idx].mean(axis=1)
        lo, hi = np.percentile(b, [2.5, 97.5])
        p = (np.sum(b <= 0) + 1) / (b.size + 1)
        return float(diff.mean()), float(lo), float(hi), float(p)
    from scipy.stats import norm

    mean = float(diff.mean())
    se = float(np.sqrt(np.sum(np.bincount(clusters, weights=diff - mean) ** 2)) / diff.size)
    if se <= 0:
        return mean, mean, mean, 0.0 if mean > 0 else 1.0
    return mean, mean - 1.96 * se, mean + 1.96 * se, float(norm.sf(mean / se))


class _Folds:
    """Cross-fitting: per fold a (train, test, loss) triple; per-unit vectors are the held-out
    values of every fold, averaged over repeats by unit id."""

    def __init__(self, folds, loss, unit_ids):
        self.folds = folds
        self.loss = loss
        ids = [np.asarray([str(u) for u in unit_ids(te)]) if unit_ids else None
               for _, te, _ in folds]
        self.ids = ids
        if len(folds) > 1:
            flat = np.concatenate(ids)
            self.codes, self.units = pd.factorize(pd.Series(flat), sort=True)
        else:
            self.codes, self.units = None, ids[0]

    def per_unit(self, parts: list[np.ndarray]) -> np.ndarray:
        v = np.concatenate([np.asarray(p, float) for p in parts])
        if self.codes is None:
            return v
        sums = np.bincount(self.codes, weights=v, minlength=len(self.units))
        return sums / np.bincount(self.codes, minlength=len(self.units))

    def losses(self, chosen: list[list]) -> np.ndarray:
        return self.per_unit([lf(te, ch) for (_, te, lf), ch in zip(self.folds, chosen)])


def _mean_params(params: list):
    """The mean of a candidate's parameters over folds (numbers averaged, dicts recursively)."""
    first = params[0]
    if isinstance(first, dict):
        keys = [k for k in first if all(isinstance(p, dict) and k in p for p in params)]
        return {k: _mean_params([p[k] for p in params]) for k in keys}
    try:
        return float(np.mean([float(p) for p in params]))
    except (TypeError, ValueError):
        return first


def _backfit(by_name: dict, train, chosen: list, rounds: int) -> list:
    """Re-fit each of ``chosen`` given all the others, ``rounds`` times; returns the list in
    the original order of names."""
    order = [n for n, _ in chosen]
    current = list(chosen)
    for _ in range(rounds):
        for name in order:
            others = [(n, q) for n, q in current if n != name]
            current = others + [(name, by_name[name].fit(train, others))]
    params = dict(current)
    return [(n, params[n]) for n in order]


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
    folds: Sequence | None = None,
    where: Callable | None = None,
    size: Callable | None = None,
    min_size: float = 0.0,
    size_unit: str = "",
    size_source: str = "",
    split: str = "",
    warnings: Sequence[str] = (),
    refit_rounds: int = 2,
    ceiling_given_chosen: bool = False,
    cluster_of: Callable[[str], str] | None = None,
) -> Diagnosis:
    """Rank candidates, combine greedily, measure the held-out gap before and after, and test
    what remains against a flexible ceiling.

    Parameters
    ----------
    train, test
        One split (each a layer's data object). Pass None for both with ``folds``.
    loss : callable
        One split: ``loss(data, fitted) -> ndarray (n_units,)``, ``fitted`` a list of
        ``(name, params)``. With ``folds``: ``loss(train)`` returns that fold's
        ``loss(data, fitted)``.
    gap_floor : callable ``gap_floor(test) -> ndarray (n_units,)``
        Per-unit loss of a model right up to noise; gap = loss - floor.
    folds : sequence of (train, test), optional
        Cross-fitting: every unit held out once per repeat (needs ``unit_ids``, which
        identify units across repeats; per-unit losses are averaged over repeats).
    ceiling : callable ``ceiling(train, test) -> ndarray (n_units,)``, optional
        Per-held-out-unit loss (same units and order as ``loss``) of a flexible data-driven
        model that any systematic structure would fit. After the greedy combination the
        chosen model's held-out loss is compared with it (paired bootstrap, one-sided); a
        significant excess of at least ``min_gain`` is a gap the catalogue does not explain.
    ceiling_given_chosen : bool
        Call ``ceiling(train, test, fitted)`` with the fold's chosen candidates (fitted on its
        training data), for a ceiling that models what the chosen model leaves (e.g. a smooth
        of its residual): a ceiling of the plain simulation's residual alone can fall behind
        a chosen model that fits sharp structure, and then hide a gap that remains beside it.
    where : callable ``where(fits) -> str``, optional
        Words for where the remaining gap lies (e.g. "in the depth response, rising with
        gloss"); ``fits`` is a list of ``(train, test, fitted, ceiling_loss)`` per fold,
        ``fitted`` the chosen candidates fitted on that fold's training data and
        ``ceiling_loss`` the ceiling's held-out loss per unit of that fold (as ``ceiling``
        returned it).
    size : callable ``size(fits) -> float``, optional
        The remaining misfit's size in the data's own units (``fits`` as for ``where``), e.g.
        an RMS misfit in % of the data's RMS. With it, a remaining gap counts as a gap beyond
        the catalogue only if it is also at least ``min_size``: a statistically significant
        one below that is reported, with its size and where it lies, as within the tolerance
        (many units make an approximate form's small leftovers significant).
    min_size : float
        The practical tolerance for ``size`` (same units).
    size_unit : str
        Words for ``size``'s unit (e.g. "% of the photos' RMS luminance").
    size_source : str
        Where the tolerance is set (e.g. "the design's [gap] render_tolerance_pct"), for the
        summary.
    unit_ids : callable ``unit_ids(test) -> sequence of str``, optional
        Names of the held-out units, recorded in ``Diagnosis.heldout`` (in the order of the
        per-unit vectors).
    max_steps : int, optional
        Most candidates the greedy combination adds (default: the whole catalogue). At each
        step every candidate not yet chosen is re-fitted and re-tested; a step must reduce
        the held-out loss significantly (one-sided bootstrap p times the number of
        candidates left < alpha) by at least ``min_gain``.
    min_share : float
        An attribution needs the chosen candidates to remove at least this share of the
        held-out gap; below it the verdict is 'unexplained' (the partial steps are kept).
    min_gain : float
        A candidate, a greedy step or a remaining gap counts only if it is at least this many
        nats per unit.
    loss_info : dict, optional
        Parameters of the loss itself (e.g. the noise model), recorded as given.
    refit_rounds : int
        After each greedy step, rounds of backfitting: every chosen candidate re-fitted given
        the others (their parameters in the report are the re-fitted ones). 0: none.
    cluster_of : callable ``cluster_of(unit_id) -> str``, optional
        Groups of dependent units (e.g. the pixels of one block). With it, the tests of the
        ranking, the greedy steps and the remaining gap use a normal approximation with a
        cluster-robust SE (see ``_test``): deterministic, so with a fixed split the verdict
        does not depend on ``seed``; the other CIs stay bootstrap CIs. Needs ``unit_ids``.
    split : str
        How units were held out, in words (recorded).
    warnings : sequence of str
        Warnings about the inputs (recorded, shown in the report).
    """
    if not candidates:
        raise GapError(f"layer {layer!r}: empty candidate catalogue; pass at least one candidate")
    if folds is None:
        cv = _Folds([(train, test, loss)], loss, unit_ids)
    else:
        if not folds:
            raise GapError(f"layer {layer!r}: no folds given")
        if len(folds) > 1 and unit_ids is None:
            raise GapError("cross-fitting needs unit_ids to average a unit over repeats")
        cv = _Folds([(tr, te, loss(tr)) for tr, te in folds], loss, unit_ids)
    n_folds = len(cv.folds)
    empty = [[] for _ in range(n_folds)]
    base = cv.losses(empty)
    floor = cv.per_unit([gap_floor(te) for _, te, _ in cv.folds])
    idx = _boot_idx(rng, base.size, n_boot)
    groups = None
    if cluster_of is not None:
        if cv.units is None:
            raise GapError("cluster_of needs unit_ids to name the units")
        groups = pd.factorize(pd.Series([cluster_of(str(u)) for u in cv.units]))[0]

    def fit_all(cand, chosen):
        return [cand.fit(tr, ch) for (tr, _, _), ch in zip(cv.folds, chosen)]

    def with_added(chosen, name, params):
        return [ch + [(name, p)] for ch, p in zip(chosen, params)]

    scores = []
    for cand in candidates:
        params = fit_all(cand, empty)
        diff = base - cv.losses(with_added(empty, cand.name, params))
        scores.append((cand.name, *_test(diff, idx, groups)))
    p_adj = holm(np.array([s[4] for s in scores]))
    ranking = sorted(
        (CandidateScore(n, g, lo, hi, p, float(pa), bool(pa < alpha and g >= min_gain))
         for (n, g, lo, hi, p), pa in zip(scores, p_adj)),
        key=lambda s: -s.gain,
    )
    if max_steps is None:
        max_steps = len(candidates)
    chosen = [[] for _ in range(n_folds)]
    steps = []
    current = base
    remaining = [c.name for c in candidates]
    by_name = {c.name: c for c in candidates}
    while remaining and len(steps) < max_steps:
        best = None
        for name in remaining:
            params = fit_all(by_name[name], chosen)
            trial_chosen = with_added(chosen, name, params)
            trial = cv.losses(trial_chosen)
            gain, _, _, p = _test(current - trial, idx, groups)
            # Each step is tested against the number of candidates left (Holm-like).
            if (p * len(remaining) < alpha and gain >= min_gain
                    and (best is None or gain > best[1])):
                best = (name, gain, params, trial, p, trial_chosen)
        if best is None:
            break
        name, gain, params, trial, p, chosen = best
        if refit_rounds and len(chosen[0]) > 1:
            # Backfitting: each chosen candidate re-fitted given all the others, so that an
            # early candidate does not keep a share of an effect a later one explains.
            chosen = [_backfit(by_name, tr, ch, refit_rounds)
                      for (tr, _, _), ch in zip(cv.folds, chosen)]
            trial = cv.losses(chosen)
            params = [dict(ch)[name] for ch in chosen]
            for st in steps:
                st["params"] = _jsonable(_mean_params([dict(ch)[st["added"]] for ch in chosen]))
        current = trial
        remaining.remove(name)
        steps.append({"added": name, "gain": gain, "p": p,
                      "params": _jsonable(_mean_params(params)),
                      "params_per_fold": [_jsonable(x) for x in params]})

    gap_b, gap_a = base - floor, current - floor
    gb, ga = float(gap_b.mean()), float(gap_a.mean())
    gb_ci = tuple(float(x) for x in np.percentile(gap_b[idx].mean(axis=1), [2.5, 97.5]))
    ga_ci = tuple(float(x) for x in np.percentile(gap_a[idx].mean(axis=1), [2.5, 97.5]))
    d = base - current
    shrink_b = d[idx].mean(axis=1)
    gap_b_boot = gap_b[idx].mean(axis=1)
    pct_b = 100 * np.clip(shrink_b / np.maximum(gap_b_boot, 1e-12), 0.0, 1.0)
    share = float(np.clip((gb - ga) / gb, 0.0, 1.0)) if gb > 0 else float("nan")
    floor_bad = (gb_ci and gb_ci[1] < 0) or (ga_ci and ga_ci[1] < 0)

    rem = None
    ceiling_share = float("nan")
    if ceiling is not None:
        ceil_folds = [ceiling(tr, te, ch) if ceiling_given_chosen else ceiling(tr, te)
                      for (tr, te, _), ch in zip(cv.folds, chosen)]
        ceil = cv.per_unit(ceil_folds)
        r_gap, r_lo, r_hi, r_p = _test(current - ceil, idx, groups)
        detected = bool(r_p < alpha and r_gap >= min_gain)
        fits = [(tr, te, ch, cf) for (tr, te, _), ch, cf in zip(cv.folds, chosen, ceil_folds)]
        rem = {"gap": r_gap, "ci": (r_lo, r_hi), "p": r_p, "significant": detected,
               "loss_ceiling": float(ceil.mean()), "where": ""}
        if size is not None:
            rem_size = float(size(fits))
            within = bool(detected and np.isfinite(rem_size) and rem_size < min_size)
            rem.update(size=rem_size, tolerance=float(min_size), size_unit=size_unit,
                       size_source=size_source, within_tolerance=within,
                       significant=detected and not within)
        if detected and where is not None:
            rem["where"] = where(fits)
        reach = float((base - ceil).mean())
        if gb > 0:
            ceiling_share = float(np.clip(reach / gb, 0.0, 1.0))
        # Shares are bounded to what the ceiling allows: the share of the gap a flexible model
        # of the data removes, capped at 100 % (a catalogue may beat the ceiling). Where the
        # ceiling removes nothing, a catalogue that removes something reaches it: all of it.
        if reach > 0:
            share = float(np.clip(float(d.mean()) / reach, 0.0, 1.0))
        elif float(d.mean()) > 0:
            share = 1.0
    explained = bool(steps) and (share >= min_share if np.isfinite(share) else True)
    verdict = " + ".join(s["added"] for s in steps) if explained else "unexplained"
    diag = Diagnosis(
        layer=layer,
        ranking=tuple(asdict(s) for s in ranking),
        steps=tuple(steps),
        verdict=verdict,
        gap_before=gb,
        gap_after=ga,
        shrink_abs=gb - ga,
        shrink_abs_ci=tuple(float(x) for x in np.percentile(shrink_b, [2.5, 97.5])),
        shrink_pct=float(100 * np.clip((gb - ga) / gb, 0.0, 1.0)) if gb > 0 else float("nan"),
        shrink_pct_ci=tuple(float(x) for x in np.percentile(pct_b, [2.5, 97.5])),
        seed=seed,
        loss_before=float(base.mean()),
        loss_after=float(current.mean()),
        heldout=tuple(str(u) for u in cv.units) if cv.units is not None else (),
        explained_share=share,
        min_share=float(min_share),
        min_gain=float(min_gain),
        loss_info=loss_info,
        gap_before_ci=gb_ci,
        gap_after_ci=ga_ci,
        remaining=rem,
        ceiling_share=ceiling_share,
        floor_status="misestimated" if floor_bad else "ok",
        split=split,
        warnings=tuple(warnings),
    )
    return _with_summary(diag)


def _names(steps) -> str:
    return " + ".join(s["added"].replace("_", " ") for s in steps)


def summarise(d: Diagnosis) -> str:
    """The verdict in one or two plain sentences (no markup)."""
    ci = d.gap_before_ci or (float("nan"), float("nan"))
    if d.floor_status == "misestimated":
        which = ("before any extension" if d.gap_before_ci and d.gap_before_ci[1] < 0
                 else "after the chosen extensions")
        text = (f"The noise floor is mis-estimated: the held-out loss lies below it {which} "
                f"(gap {d.gap_before:.3f} -> {d.gap_after:.3f} nats per unit; 95 % CI before "
                f"{ci[0]:.3f} to {ci[1]:.3f}). This is not a match between simulation and data; "
                "check the floor's inputs.")
        if d.steps:
            text += f" Attributed: {_names(d.steps)}."
        return text
    rem = d.remaining or {}
    further = within = ""
    nats = (f"{rem.get('gap', float('nan')):.3f} nats per unit above a flexible model of the "
            f"data, 95 % CI {rem.get('ci', (float('nan'),) * 2)[0]:.3f} to "
            f"{rem.get('ci', (float('nan'),) * 2)[1]:.3f}")
    if rem.get("significant"):
        where = f" {rem['where']}" if rem.get("where") else ""
        size = f"; {_size_words(rem, 'above')}" if "size" in rem else ""
        further = (f"a further gap remains, unexplained by the catalogue,{where} ({nats}{size})")
    elif rem.get("within_tolerance"):
        where = f", {rem['where']}" if rem.get("where") else ""
        within = (f"what remains is statistically significant ({nats}) but within the "
                  f"tolerance: {_size_words(rem, 'below')}{where}; not counted as a gap beyond "
                  "the catalogue")
    if not d.steps:
        if further:
            return f"No catalogue effect explains the gap; {further}."
        if within:
            return f"No catalogue effect improves the simulation; {within}."
        if rem:
            return (f"No significant gap: the simulation predicts the held-out data as well as "
                    f"a flexible model of the data does ({-rem['gap']:+.3f} nats per unit, 95 % "
                    f"CI {-rem['ci'][1]:+.3f} to {-rem['ci'][0]:+.3f}; positive: the simulation "
                    "is better), and no catalogue effect improves it.")
        if d.gap_before_ci and d.gap_before_ci[0] <= max(d.min_gain, 0.0):
            above = (f"{d.min_gain:g} nats per unit above the noise floor" if d.min_gain > 0
                     else "above the noise floor")
            return (f"No significant gap: the held-out gap ({d.gap_before:.3f} nats per unit, "
                    f"95 % CI {ci[0]:.3f} to {ci[1]:.3f}) is not {above}.")
        return (f"The gap ({d.gap_before:.3f} nats per unit, 95 % CI {ci[0]:.3f} to "
                f"{ci[1]:.3f}) is unexplained: no catalogue effect reduces it significantly.")
    share = (f"{100 * d.explained_share:.0f} %" if np.isfinite(d.explained_share)
             else "all")
    if d.verdict == "unexplained":
        one = len(d.steps) == 1
        text = (f"{_names(d.steps)} {'reduces' if one else 'reduce'} the gap significantly but "
                f"{'explains' if one else 'explain'} only {share} of "
                f"it (an attribution needs {100 * d.min_share:.0f} %): unexplained by the "
                "catalogue")
    else:
        of = " a flexible model of the data removes" if rem else ""
        verb = "explains" if len(d.steps) == 1 else "explain"
        text = f"{_names(d.steps)} {verb} {share} of the gap{of}"
    if further:
        return f"{text}; {further}."
    if within:
        return f"{text}; {within}."
    if rem:
        return f"{text}; nothing significant remains beyond a flexible model of the data."
    return f"{text}."


def _size_words(rem: dict, side: str) -> str:
    """'a misfit of about 0.24 % of the photos' RMS luminance, below the tolerance of 1 % (the
    design's [gap] render_tolerance_pct)' from a remaining gap's size fields."""
    unit = rem.get("size_unit", "")
    tol_unit = " %" if unit.startswith("%") else (f" {unit}" if unit else "")
    source = f" ({rem['size_source']})" if rem.get("size_source") else ""
    return (f"a misfit of about {rem['size']:.2g} {unit}, {side} the tolerance of "
            f"{rem['tolerance']:g}{tol_unit}{source}").replace("  ", " ")


def _with_summary(d: Diagnosis) -> Diagnosis:
    from dataclasses import replace

    return replace(d, summary=summarise(d))


def _jsonable(params):
    if isinstance(params, dict):
        return {str(k): _jsonable(v) for k, v in params.items()}
    if isinstance(params, (list, tuple)):
        return [_jsonable(v) for v in params]
    if isinstance(params, (np.floating, np.integer, np.bool_)):
        return params.item()
    if isinstance(params, np.ndarray):
        return params.tolist()
    return params
