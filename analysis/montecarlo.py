"""Monte-Carlo decision rates and the search for the data size (or effect size) that decides.

One machine for two questions that are the same question:

- the study's power (``python -m analysis power``): simulate whole studies from a fitted model,
  refit, test, count rejections; the smallest number of participants for 80 % power;
- the gap diagnosis's ``detectable`` and ``to_decide`` (``analysis.gap``): simulate the layer's
  data from its fitted models at a larger size (or with a misfit of a given size), diagnose,
  count how often the verdict is decided.

Both are "draw data, decide, repeat" over a grid of sizes. Nothing here assumes normality or a
closed-form power formula: a rate is a count of simulated decisions, with its exact
(Clopper-Pearson) 95 % interval.

Reproducibility: draws are made in chunks; chunk ``i`` of size point ``j`` draws from
``SeedSequence(seed, spawn_key=(j, i))``, so the result depends on the seed and the chunk size
only, not on how many workers ran it or in which order.

Written by hand because no library does this for our own simulate-and-refit functions: simr's
``powerSim`` / ``powerCurve`` (R) are the model, statsmodels' power module is closed-form only.
"""

from __future__ import annotations

import itertools
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

__all__ = [
    "Progress",
    "Rate",
    "SizeSearch",
    "decision_rate",
    "decision_rates",
    "one_at_a_time",
    "rate_curve",
    "rates_curve",
    "size_search",
    "smallest_size",
]

DrawBatch = Callable[[np.random.Generator, int], np.ndarray]
"""``draws(rng, k) -> bool array (k,)``: k independent simulated decisions (True = decided /
rejected)."""


@dataclass(frozen=True)
class Rate:
    """``hits`` decisions out of ``n`` simulated draws, with the exact (Clopper-Pearson) 95 %
    interval of the rate."""

    hits: int
    n: int

    @property
    def rate(self) -> float:
        return self.hits / self.n if self.n else float("nan")

    @property
    def ci(self) -> tuple[float, float]:
        if not self.n:
            return (float("nan"), float("nan"))
        ci = stats.binomtest(self.hits, self.n).proportion_ci(0.95, method="exact")
        return (float(ci.low), float(ci.high))

    @property
    def mc_se(self) -> float:
        """Monte-Carlo standard error of the rate, sqrt(p (1 - p) / n)."""
        p = self.rate
        return math.sqrt(max(p * (1 - p), 0.0) / self.n) if self.n else float("nan")

    def to_dict(self) -> dict:
        lo, hi = self.ci
        return {"hits": self.hits, "n": self.n, "rate": self.rate, "ci_low": lo, "ci_high": hi}


@dataclass(frozen=True)
class SizeSearch:
    """The rate at each size tried (in increasing order) and the smallest size that reaches the
    target.

    ``size`` is None when no size tried reaches it. ``size_range`` brackets the answer by the
    Monte-Carlo intervals: from the smallest size whose interval's upper end reaches the target
    to the smallest whose lower end does (None where none does).
    """

    target: float
    curve: tuple  # ((size, Rate), ...)
    size: float | None
    size_range: tuple

    def to_dict(self) -> dict:
        return {"target": self.target, "size": self.size, "size_range": list(self.size_range),
                "curve": [{"size": s, **r.to_dict()} for s, r in self.curve]}


class Progress:
    """Progress and ETA on standard error, at most one line every ``every_s`` seconds.

    Call with ``(done, total)``; ``label`` names the run (e.g. ``"power N=12"``).
    """

    def __init__(self, label: str = "simulations", *, every_s: float = 5.0, stream=None):
        self.label = label
        self.every_s = every_s
        self.stream = stream if stream is not None else sys.stderr
        self.t0 = time.monotonic()
        self._last = -math.inf

    def __call__(self, done: int, total: int) -> None:
        now = time.monotonic()
        if done < total and now - self._last < self.every_s:
            return
        self._last = now
        elapsed = now - self.t0
        eta = elapsed / done * (total - done) if done else float("nan")
        eta_txt = f", about {eta:.0f} s left" if done and done < total else ""
        print(f"{self.label}: {done}/{total} draws, {elapsed:.0f} s{eta_txt}",
              file=self.stream, flush=True)


def one_at_a_time(decide: Callable[[np.random.Generator], bool]) -> DrawBatch:
    """Turn ``decide(rng) -> bool`` (one simulated data set) into a batch function."""

    def draws(rng: np.random.Generator, k: int) -> np.ndarray:
        return np.array([bool(decide(rng)) for _ in range(k)], dtype=bool)

    return draws


def _chunk(draws: DrawBatch, seed: int, key: tuple, k: int, columns: int | None = None):
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))
    out = np.asarray(draws(rng, k), dtype=bool)
    want = (k,) if columns is None else (k, columns)
    if out.shape != want:
        raise ValueError(f"a draw function returned shape {out.shape}; it must return "
                         f"{k if columns is None else want} "
                         "decisions (a bool array of the batch size it was asked for)")
    return int(out.sum()) if columns is None else out.sum(axis=0).astype(int)


def _chunks(n_sim: int, chunk: int) -> list[int]:
    sizes = [chunk] * (n_sim // chunk)
    if n_sim % chunk:
        sizes.append(n_sim % chunk)
    return sizes


def decision_rate(draws: DrawBatch, n_sim: int, *, seed: int, point: int = 0, chunk: int = 25,
                  client=None, progress: Callable[[int, int], None] | None = None) -> Rate:
    """How often ``draws`` decides, over ``n_sim`` simulated data sets.

    Parameters
    ----------
    draws : callable
        ``draws(rng, k) -> bool array (k,)``; see :func:`one_at_a_time` for a one-draw function.
        Must use only ``rng`` for its randomness.
    n_sim : int
        Number of simulated data sets (>= 1).
    seed : int
        Root seed; with ``point`` and ``chunk`` it fixes every draw.
    point : int
        Index of this size point in a curve (keeps points' draws independent).
    chunk : int
        Draws per task (per Dask task when ``client`` is given).
    client : distributed.Client, optional
        Spread the chunks over a Dask cluster (the one the renders use); ``draws`` must pickle.
    progress : callable, optional
        ``progress(done, total)`` after each chunk (see :class:`Progress`).

    Returns
    -------
    Rate
    """
    return _count(draws, n_sim, seed=seed, point=point, chunk=chunk, client=client,
                  progress=progress, columns=None)


def decision_rates(draws, n_sim: int, *, columns: int, seed: int, point: int = 0,
                   chunk: int = 25, client=None,
                   progress: Callable[[int, int], None] | None = None) -> tuple:
    """`decision_rate` for draws that make ``columns`` decisions on each simulated data set
    (``draws(rng, k) -> bool (k, columns)``: e.g. one test per term of a refitted model), one
    `Rate` per column, from the same draws."""
    if columns < 1:
        raise ValueError(f"columns is {columns}; a draw makes at least 1 decision")
    return _count(draws, n_sim, seed=seed, point=point, chunk=chunk, client=client,
                  progress=progress, columns=columns)


def _count(draws, n_sim, *, seed, point, chunk, client, progress, columns):
    if n_sim < 1:
        raise ValueError(f"n_sim is {n_sim}; ask for at least 1 simulated data set")
    if chunk < 1:
        raise ValueError(f"chunk is {chunk}; use at least 1 draw per chunk")
    sizes = _chunks(n_sim, chunk)
    hits = 0 if columns is None else np.zeros(columns, int)
    done = 0

    def result():
        if columns is None:
            return Rate(int(hits), n_sim)
        return tuple(Rate(int(h), n_sim) for h in hits)

    if client is None:
        for i, k in enumerate(sizes):
            hits = hits + _chunk(draws, seed, (point, i), k, columns)
            done += k
            if progress is not None:
                progress(done, n_sim)
        return result()
    from distributed import as_completed

    # Sent to the workers once, not with every chunk (a model's matrices are megabytes).
    shared = client.scatter(draws, hash=False)
    futures = [client.submit(_chunk, shared, seed, (point, i), k, columns, pure=False)
               for i, k in enumerate(sizes)]
    size_of = {f.key: k for f, k in zip(futures, sizes)}
    for fut in as_completed(futures):
        hits = hits + fut.result()
        done += size_of[fut.key]
        if progress is not None:
            progress(done, n_sim)
    return result()


def _curve(rate_at: Callable, sizes: Sequence, n_sim: int, progress) -> tuple:
    """``((size, rate_at(size, j, tick)), ...)``: one simulated point per size, with one
    progress count over all of them (``tick`` is that point's progress callback)."""
    sizes = list(sizes)
    if not sizes:
        raise ValueError("no sizes given; give at least one size to simulate")
    total = n_sim * len(sizes)
    out = []
    for j, size in enumerate(sizes):
        base = j * n_sim

        def tick(done, _total, base=base):
            if progress is not None:
                progress(base + done, total)

        out.append((size, rate_at(size, j, tick)))
    return tuple(out)


def rate_curve(draws_at: Callable[[float], DrawBatch], sizes: Sequence[float], n_sim: int, *,
               seed: int, chunk: int = 25, client=None,
               progress: Callable[[int, int], None] | None = None) -> tuple:
    """The decision rate at each size: ``((size, Rate), ...)``.

    ``draws_at(size)`` returns the batch draw function for data (or an effect) of that size.
    """
    return _curve(lambda size, j, tick: decision_rate(
        draws_at(size), n_sim, seed=seed, point=j, chunk=chunk, client=client, progress=tick),
        sizes, n_sim, progress)


def rates_curve(draws_at: Callable, sizes: Sequence, n_sim: int, *, columns: int, seed: int,
                chunk: int = 25, client=None,
                progress: Callable[[int, int], None] | None = None) -> tuple:
    """`rate_curve` for draws of ``columns`` decisions each: ``((size, (Rate, ...)), ...)``.

    A size may be any value ``draws_at`` takes (e.g. (participants, sessions, repeats)).
    """
    return _curve(lambda size, j, tick: decision_rates(
        draws_at(size), n_sim, columns=columns, seed=seed, point=j, chunk=chunk, client=client,
        progress=tick), sizes, n_sim, progress)


def smallest_size(draws_at: Callable[[float], DrawBatch], sizes: Sequence[float], n_sim: int, *,
                  seed: int, target: float = 0.8, chunk: int = 25, client=None,
                  progress: Callable[[int, int], None] | None = None,
                  stop_early: bool = True) -> SizeSearch:
    """The smallest of ``sizes`` (increasing) whose decision rate reaches ``target``.

    With ``stop_early`` the walk stops once a size's interval lies wholly above the target (the
    sizes beyond it are then not simulated). The same search answers "how many participants
    for 80 % power" (sizes = participants) and "the smallest misfit these data detect with
    80 % power" (sizes = misfit sizes in the layer's unit).
    """
    if not 0 < target < 1:
        raise ValueError(f"target is {target}; give a rate between 0 and 1 (e.g. 0.8)")
    sizes = list(sizes)
    if not sizes:
        raise ValueError("no sizes given; give at least one size to simulate")
    if any(b <= a for a, b in itertools.pairwise(sizes)):
        raise ValueError(f"sizes {sizes} are not increasing; list them smallest first")
    curve = []
    total = n_sim * len(sizes)
    for j, size in enumerate(sizes):
        base = j * n_sim

        def tick(done, _total, base=base):
            if progress is not None:
                progress(base + done, total)

        r = decision_rate(draws_at(size), n_sim, seed=seed, point=j, chunk=chunk, client=client,
                          progress=tick)
        curve.append((size, r))
        if stop_early and r.ci[0] >= target:
            break
    return size_search(curve, target)


def size_search(curve, target: float) -> SizeSearch:
    """The smallest size of a curve already simulated (``((size, Rate), ...)``, sizes
    increasing) that reaches ``target``, bracketed by the rates' intervals (`SizeSearch`)."""
    size = next((s for s, r in curve if r.rate >= target), None)
    lo = next((s for s, r in curve if r.ci[1] >= target), None)
    hi = next((s for s, r in curve if r.ci[0] >= target), None)
    return SizeSearch(target=target, curve=tuple(curve), size=size, size_range=(lo, hi))
