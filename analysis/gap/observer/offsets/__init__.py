"""The ceiling's per-stimulus and per-cell offsets, shrunk across participants (observer
layer): :func:`_cell_offsets` (empirical Bayes), :func:`_cv_offsets` (each level kept where it
lowers the inner held-out error) and their helpers, used by
:func:`analysis.gap.observer.ceiling.fit_ceiling` and the rating study's ceiling. Moved here from
``ceiling.py`` unchanged (issue 43: the file outgrew 500 lines)."""

from __future__ import annotations

import numpy as np
import pandas as pd

__all__ = ["_cell_offsets", "_cv_offsets", "_inner_offsets", "_offsets_at"]


def _cell_offsets(res: np.ndarray, keys: np.ndarray, participants: np.ndarray,
                  weights: np.ndarray | None = None) -> dict:
    """Per-cell mean residuals shrunk across participants (empirical Bayes, one-way random
    effects by the method of moments).

    Each participant's mean residual in a cell, ``m_cp`` (responses weighted by ``weights``,
    default 1: a response's chance of being no lapse), is taken as the cell's offset ``u_c``
    plus noise of variance ``v / w_cp``, ``w_cp`` the participant's summed weight there (its
    effective number of responses). Then, per cell, the precision-weighted mean
    ``m_c = sum w_cp m_cp / W_c`` (``W_c = sum w_cp``) has noise variance ``v / W_c``; ``v`` is
    the weighted spread of the participants' means about it, ``sum w_cp (m_cp - m_c)^2`` over
    ``sum (n_c - 1)``; the between-cell variance ``tau2`` is the part that replicates *across*
    participants, the weighted mean product of two different participants' means in the same
    cell (``E[m_cp m_c'p'] = tau2`` for p != p'), so one participant's own pattern is not taken
    as the population's. Each cell mean is shrunk by ``tau2 / (tau2 + v / W_c)``. With equal
    weights this is the unweighted estimator (``v / W_c`` = the spread of participants' means
    over their number).

    The weights must reach the cross-participant products, not only the mean within a
    participant's cell: with one response per participant and cell (a cell of the harder
    benchmark) that mean *is* the response, lapse or not, and a few products of two lapses
    (residuals of 3-7 slider units) made ``tau2`` of the cell level positive by chance with
    two participants; the noisy cell offsets then cost more held-out error than the
    per-stimulus offsets gained (:func:`_cv_offsets`).
    """
    cells, cell_of = np.unique(keys, return_inverse=True)
    _, pair_of = np.unique(np.char.add(np.char.add(keys.astype(str), "\x1f"),
                                       participants.astype(str)), return_inverse=True)
    # Per (cell, participant): the participant's weighted mean residual and summed weight.
    w = np.ones(res.size) if weights is None else np.asarray(weights, float)
    w_cp = np.bincount(pair_of, weights=w)
    m_cp = np.bincount(pair_of, weights=w * res) / np.maximum(w_cp, 1e-12)
    cell_of_pair = np.zeros(m_cp.size, int)
    cell_of_pair[pair_of] = cell_of

    def per_cell(values):
        return np.bincount(cell_of_pair, weights=values, minlength=cells.size)
    n_c = per_cell(np.ones(m_cp.size))
    w_c, s_c = per_cell(w_cp), per_cell(w_cp * m_cp)
    pairs = float((w_c ** 2 - per_cell(w_cp ** 2)).sum())
    if pairs <= 1e-12 or (n_c - 1).sum() == 0:
        return {}
    tau2 = max(0.0, float((s_c ** 2 - per_cell((w_cp * m_cp) ** 2)).sum()) / pairs)
    if tau2 == 0:
        return {}
    m_c = s_c / np.maximum(w_c, 1e-12)
    v = max(float((w_cp * (m_cp - m_c[cell_of_pair]) ** 2).sum()) / float((n_c - 1).sum()),
            1e-6)
    return dict(zip(cells.tolist(), (m_c * tau2 / (tau2 + v / np.maximum(w_c, 1e-12))).tolist()))


def _offsets_at(stim_off: dict, cell_off: dict, stim, keys) -> np.ndarray:
    return (pd.Series(stim).map(stim_off).fillna(0.0).to_numpy(float)
            + pd.Series(keys).map(cell_off).fillna(0.0).to_numpy(float))


def _inner_offsets(res, stim, keys, who, w, groups, *, stimulus: bool):
    """The stimulus and cell offsets each unit gets from the inner fold it was held out of
    (:func:`_cell_offsets` fitted without it; the cell level on what that fold's stimulus
    level leaves, none with ``stimulus=False``): ``(held_stimulus, held_cell)``."""
    held_s, held_c = np.zeros(res.size), np.zeros(res.size)
    for g in np.unique(groups):
        m = groups == g
        s_in = _cell_offsets(res[~m], stim[~m], who[~m], w[~m]) if stimulus else {}
        left = res[~m] - _offsets_at(s_in, {}, stim[~m], keys[~m])
        c_in = _cell_offsets(left, keys[~m], who[~m], w[~m])
        held_s[m] = _offsets_at(s_in, {}, stim[m], keys[m])
        held_c[m] = _offsets_at({}, c_in, stim[m], keys[m])
    return held_s, held_c


def _cv_offsets(res, stim, keys, who, w, groups) -> tuple[dict, dict, np.ndarray]:
    """Offsets per stimulus (gloss x depth level, pooled over illuminations), then per cell
    (x illumination) on what the stimulus offsets leave (:func:`_cell_offsets`), each level
    kept on its own where it lowers the held-out weighted squared error over ``groups``
    (inner folds); and the offsets each unit gets from the folds it was held out of (zero
    where none are kept).

    The held-out mean error decides, not one standard error more: with lapses, three inner
    participants rarely gave one standard error, and a per-stimulus bias (SD 0.5 slider
    units) beside lapses was missed (remaining gap 0.002-0.022 nats per trial in three
    cases, 0.021-0.029 with the mean rule); the empirical-Bayes shrinkage already keeps the
    offsets small where the between-cell variance is estimated small.

    Each level on its own: kept or dropped together, noisy cell offsets vetoed per-stimulus
    offsets that lowered every inner fold's error (a stimulus bias beside lapses, drawn with
    seed 11, one outer fold: the stimulus level lowered the three inner folds' weighted
    squared error by 5.5, 2.6 and 6.4, both levels together raised one by 15.6, and nothing
    was kept; remaining gap 0.015 nats per trial, not flagged, now 0.040)."""
    def err(x):
        return float(np.sum(w * x * x))
    held_s, held_c = _inner_offsets(res, stim, keys, who, w, groups, stimulus=True)
    use_stim = err(res - held_s) < err(res)
    if not use_stim:
        held_s, held_c = _inner_offsets(res, stim, keys, who, w, groups, stimulus=False)
    use_cell = err(res - held_s - held_c) < err(res - held_s)
    stim_off = _cell_offsets(res, stim, who, w) if use_stim else {}
    left = res - _offsets_at(stim_off, {}, stim, keys)
    cell_off = _cell_offsets(left, keys, who, w) if use_cell else {}
    return stim_off, cell_off, held_s + (held_c if use_cell else 0.0)
