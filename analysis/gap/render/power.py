"""Render layer: how large a misfit these photos would detect, and how many more photos (or
held-out lights) would decide an inconclusive diagnosis (the engine's
:class:`~analysis.gap.engine.PowerModel`).

Simulated from the fitted models, reused as they are: each held-out photo is the prediction
of the model the verdict judged (the chosen model's, or the plain render's where named effects
were held to the tolerance) plus a misfit of the shape the photos show (a local smooth of what the
chosen model leaves, 3 px wide; a uniform change of light where that is nearly nothing),
scaled to a size in % of the photos' RMS luminance, plus camera noise drawn from the layer's
noise model (``sd`` per pixel). The size and its bounds are those of the diagnosis
(:func:`~analysis.gap.render.ceiling.misfit_bounds` over tiles of lagged residual products),
and each simulated data set is decided as the diagnosis decides the real one
(:func:`~analysis.gap.engine.decide_size`).

Cheap by construction: a tile's sum of lagged products of ``a m + e`` (misfit ``m`` scaled
by ``a``, noise ``e``) is ``a^2 C0 + a C1 + C2``, with ``C0`` fixed and ``(C1, C2)`` drawn
from :data:`POOL` noise images per photo made once; a simulated data set ``f`` times larger
takes, for each tile of each of its ``f`` copies, one of the pool's draws (different draws up
to 32 copies; beyond, copies may repeat a draw, which overstates the spread a little, so
``to_decide`` errs on the side of more data).
"""

from __future__ import annotations

import numpy as np

from analysis.gap.engine import Diagnosis, PowerModel, decide_size, judged_plain
from analysis.gap.render.ceiling import _local_mean, misfit_bounds, sized_pixels, tile_products
from analysis.gap.render.data import RenderData
from analysis.gap.render.model import _predict

__all__ = ["POOL", "RENDER_FACTORS", "render_power"]

#: Noise images simulated per held-out photo, from which every data set draws its tiles.
POOL = 32

#: How many times the held-out photos a larger data set would take.
RENDER_FACTORS = (2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64)

#: Misfits tried for ``detectable``, in multiples of the tolerance.
_MISFITS_X_TOL = (1.0, 1.25, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0)

#: Width (px) of the local smooth that gives the simulated misfit its shape.
_SHAPE_SIGMA_PX = 3.0


def _shape(lv: dict, fitted: list) -> tuple[np.ndarray, np.ndarray]:
    """(prediction, misfit shape) of one held-out photo, 0 off its sized pixels."""
    m = sized_pixels(lv)
    pred = _predict(lv, fitted)
    res = np.where(m, lv["P"] - pred, 0.0)
    # Weights 1 / sd^2, the SD held to the lit pixels' median: where the render is black the
    # noise model's SD is its read noise alone, often fitted as 0.
    sd = np.maximum(lv["sd"], float(np.median(lv["sd"][lv["use"]])) if lv["use"].any() else 1.0)
    w = np.where(m, 1 / sd ** 2, 0.0)
    return np.where(m, pred, 0.0), np.where(m, _local_mean(res, w, _SHAPE_SIGMA_PX), 0.0)


def _pool(test: RenderData, fitted: list, rng: np.random.Generator) -> dict:
    """The tiles' fixed and drawn parts (``C0``, ``pairs``; ``C1``, ``C2`` per pool draw)
    for the misfit's shape and, as a fallback, a uniform change of light (``U0``, ``U1``)."""
    out = {k: [] for k in ("C0", "U0", "pairs", "C1", "U1", "C2")}
    sq = n = 0.0
    for lv in test.levels:
        m = sized_pixels(lv)
        pred, shape = _shape(lv, fitted)
        c0, pairs = tile_products(lv, shape)
        u0, _ = tile_products(lv, pred)
        c1, u1, c2 = [], [], []
        for _ in range(POOL):
            e = np.where(m, lv["sd"] * rng.standard_normal(m.shape), 0.0)
            c1.append(tile_products(lv, shape, e)[0] + tile_products(lv, e, shape)[0])
            u1.append(tile_products(lv, pred, e)[0] + tile_products(lv, e, pred)[0])
            c2.append(tile_products(lv, e)[0])
        for key, val in (("C0", c0), ("U0", u0), ("pairs", pairs), ("C1", np.array(c1)),
                         ("U1", np.array(u1)), ("C2", np.array(c2))):
            out[key].append(val)
        sq += float(np.sum(lv["P"][m] ** 2))
        n += float(m.sum())
    pooled = {k: np.concatenate(v, axis=-1) for k, v in out.items()}
    pooled["mean_sq"] = sq / max(n, 1.0)
    return pooled


def render_power(test: RenderData, diag: Diagnosis, *, noun: str = "held-out photos",
                 seed: int = 0) -> PowerModel | None:
    """The :class:`~analysis.gap.engine.PowerModel` of a render diagnosis (see the module's
    docstring); None where no pixel pairs are left.

    Parameters
    ----------
    test : RenderData
        The held-out photos (with the layer's noise SD per pixel).
    diag : Diagnosis
        The finished diagnosis (its chosen effects, tolerance and remaining size).
    noun : str
        What a larger data set has more of, in words ("held-out lights' photos").
    seed : int
        Seeds the pool of noise images.
    """
    rem = diag.remaining or {}
    # Named effects held to the tolerance (tolerate_chosen): the verdict judged the plain
    # render's misfit, so its power is the plain render's.
    holds_plain = judged_plain(diag)
    fitted = [] if holds_plain else [(s["added"], s["params"]) for s in diag.steps]
    pool = _pool(test, fitted, np.random.default_rng(seed))
    pairs, mean_sq = pool["pairs"], pool["mean_sq"]
    if pairs.sum() == 0 or mean_sq <= 0 or not np.isfinite(diag.tolerance):
        return None
    size_of = misfit_bounds(pool["C0"], pairs, mean_sq)[0]
    fixed, drawn = ("C0", "C1") if size_of > 1e-3 else ("U0", "U1")
    unit_size = misfit_bounds(pool[fixed], pairs, mean_sq)[0]
    tol = float(diag.tolerance)
    now = float(rem["size_before"] if holds_plain else rem.get("size", 0.0))
    n_tiles = pairs.size
    n_photos = len(test.levels)

    def draws(misfit: float, factor: float):
        f = max(round(factor), 1)
        a = misfit / unit_size
        many = np.tile(pairs, f)

        def run(rng: np.random.Generator, k: int) -> np.ndarray:
            if f <= POOL:  # each copy of a tile a different draw of the pool
                idx = np.argsort(rng.random((k, POOL, n_tiles)), axis=1)[:, :f]
            else:
                idx = rng.integers(0, POOL, size=(k, f, n_tiles))
            cols = np.arange(n_tiles)
            cross = (a * a * pool[fixed] + a * pool[drawn][idx, cols]
                     + pool["C2"][idx, cols]).reshape(k, f * n_tiles)
            return decide_size(*misfit_bounds(cross, many, mean_sq), tol)
        return run

    def more(factor: float) -> str:
        return (f"{round(factor * n_photos)} {noun} instead of {n_photos} "
                f"({factor:g}x the pixels)")

    return PowerModel(draws=draws, misfit_now=now if np.isfinite(now) else 0.0,
                      misfits=tuple(tol * x for x in _MISFITS_X_TOL), factors=RENDER_FACTORS,
                      unit=rem.get("size_unit", "%"), more=more)
