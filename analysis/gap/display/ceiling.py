"""Display layer, the ceiling and the floor: how well any model of the readings could do.

The floor (:func:`display_floor`) is the loss of a model right up to the photometer's noise,
``0.5 log(2 pi sd^2) + 0.5`` per reading. The ceiling (:func:`display_ceiling`) is the held-out
loss of a penalised smooth of level, position and time fitted to the plain simulation's
residuals; a chosen model that stays significantly above it leaves a gap the catalogue does
not explain.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy import linalg

from analysis.gap.display.model import display_nll
from analysis.gap.display.noise import _bspline

#: Smoothing parameters the ceiling's cross-validation chooses from (relative to the data).
_CEIL_LAMBDAS = 10.0 ** np.arange(-3, 6)


def display_floor(data: pd.DataFrame) -> np.ndarray:
    """Expected NLL of a model right up to the photometer's noise; 0 for a censored reading
    (a model far below the floor predicts it with certainty)."""
    sd2 = data["sd"].to_numpy(float) ** 2
    expected = data["var_expected"].to_numpy(float) if "var_expected" in data else sd2
    floor = 0.5 * np.log(2 * np.pi * sd2) + 0.5 * expected / sd2
    if "censored" in data:
        floor[data["censored"].to_numpy(bool)] = 0.0
    return floor


# --- the ceiling: a penalised smooth of level, position and time ------------------------------

def _ceiling_design(data: pd.DataFrame, span: dict):
    """Columns of the ceiling's smooth (cd/m^2 per unit coefficient) with their penalty kinds.

    Blocks: a constant; a cubic spline in drive (8 interior knots), additive and times the
    predicted above-black light ``a``; per screen position a constant, ``a`` and
    ``a ln(drive)`` (an exponent change there); a line in time and a cubic spline in time (3
    interior knots) times ``a`` (a drift of the light); with the file's condition columns a
    gain per combination of conditions (a load that dims the screen). Each block has its own
    smoothing parameter: "level" and "time" blocks a second-difference penalty, "pos" and
    "cond" blocks a ridge.
    """
    lv = data["level"].to_numpy(float)
    a = np.maximum(data["mu0"].to_numpy(float) - data["lmin"].to_numpy(float), 0.0)
    t = data["t_s"].to_numpy(float)
    bl = _bspline(lv, 0.0, 1.0, 8)
    bt = _bspline(t, span["t_lo"], span["t_hi"], 3)
    pos = np.array([span["pos"].index(p) if p in span["pos"] else -1
                    for p in zip(np.round(data["x_norm"], 4), np.round(data["y_norm"], 4))])
    onehot = (pos[:, None] == np.arange(len(span["pos"]))[None, :]).astype(float)
    shape = a * np.log(np.maximum(lv, 1e-3))
    line = (t - span["t_lo"]) / max(span["t_hi"] - span["t_lo"], 1.0)
    blocks = [(np.ones((len(data), 1)), None), (line[:, None], None),
              (bl[:, 1:], "level"), (bl * a[:, None], "level"),
              (onehot, "pos"), (onehot * a[:, None], "pos"), (onehot * shape[:, None], "pos"),
              (bt[:, 1:] * a[:, None], "time")]
    if span["cond"]:
        combo = [span["cond"].index(c) if c in span["cond"] else -1 for c in _combos(data)]
        hot = (np.array(combo)[:, None] == np.arange(len(span["cond"]))[None, :]).astype(float)
        blocks.append((hot * a[:, None], "cond"))
    return blocks


def _combos(data: pd.DataFrame) -> list:
    """Each reading's combination of the file's condition values (empty tuples without)."""
    cols = data.attrs.get("conditions", [])
    return list(zip(*(data[c].astype(str) for c in cols))) if cols else [()] * len(data)


_PENALTY_KINDS = ("level", "pos", "time", "cond")


def _penalties(blocks, xtwx_diag) -> dict:
    """One penalty matrix per kind (level, time: second differences; pos: identity), each
    block scaled by its mean diagonal of X'WX so that one grid of smoothing parameters fits
    all."""
    sizes = [b[0].shape[1] for b in blocks]
    p = sum(sizes)
    out = {k: np.zeros((p, p)) for k in _PENALTY_KINDS}
    k = 0
    for (_, kind), n in zip(blocks, sizes):
        if kind is not None:
            scale = float(np.mean(xtwx_diag[k:k + n])) or 1.0
            if kind != "pos" and n >= 3:
                dm = np.diff(np.eye(n), 2, axis=0)
                out[kind][k:k + n, k:k + n] = scale * dm.T @ dm
            else:
                out[kind][k:k + n, k:k + n] = scale * np.eye(n)
        k += n
    return out


def _solve(x, r, w, pen):
    xtw = x.T * w
    # Least squares, not solve: with few readings the penalised system can be singular.
    try:
        return np.linalg.lstsq(xtw @ x + pen, xtw @ r, rcond=None)[0]
    except np.linalg.LinAlgError:
        # LAPACK's SVD can fail to converge on a badly scaled system (seen once in 30 refitted
        # clean displays); a complete orthogonal factorisation needs no SVD.
        return linalg.lstsq(xtw @ x + pen, xtw @ r, lapack_driver="gelsy")[0]


def display_ceiling(train: pd.DataFrame, test: pd.DataFrame, *, folds: int = 5,
                    seed: int = 0) -> np.ndarray:
    """Held-out loss (nats per reading, shape (len(test),)) of the flexible model
    :func:`ceiling_prediction` fitted on ``train``: the ceiling."""
    return display_nll(test, ceiling_prediction(train, test, folds=folds, seed=seed))


def ceiling_prediction(train: pd.DataFrame, test: pd.DataFrame, *, folds: int = 5,
                       seed: int = 0) -> np.ndarray:
    """Held-out prediction (cd/m^2) of a flexible data-driven model of the readings.

    The residual ``L - mu0`` of the plain simulation is fitted on ``train`` by penalised
    weighted least squares (weights 1 / sd^2, the noise model) on the smooth of
    :func:`_ceiling_design`: any systematic structure in level, position or time that the
    catalogue lacks (a gamma change in the mid-range, a position x level interaction) is
    fitted by it. The three smoothing parameters (level, position, time) are chosen by
    ``folds``-fold cross-validation on ``train`` (folds by patch, so a patch is predicted from
    the others; coordinate descent over a grid, two sweeps from the smoothest model). When
    the smooth predicts left-out patches no better than the plain simulation (too few
    readings), the ceiling is the plain simulation.

    Parameters
    ----------
    train, test : DataFrame
        :func:`display_frame` rows (the engine's split).
    folds : int
        Cross-validation folds.
    seed : int
        Seeds the fold assignment (the result hardly depends on it).

    Returns
    -------
    ndarray, shape (len(test),)
        The fitted smooth's prediction of each held-out reading, cd/m^2.
    """
    both = pd.concat([train, test])
    both.attrs = train.attrs
    span = {"t_lo": 0.0, "t_hi": float(both["t_s"].max()),
            "pos": sorted(set(zip(np.round(both["x_norm"], 4), np.round(both["y_norm"], 4)))),
            "cond": sorted(set(_combos(both))) if train.attrs.get("conditions") else []}

    def design(d):
        blocks = _ceiling_design(d, span)
        return np.concatenate([b[0] for b in blocks], axis=1), blocks
    x_tr, blocks = design(train)
    x_te, _ = design(test)
    r = (train["L"] - train["mu0"]).to_numpy(float)
    # A censored reading says only "at most the floor": the smooth is fitted without it.
    w = 1 / train["sd"].to_numpy(float) ** 2 * ~train["censored"].to_numpy(bool)
    pens = _penalties(blocks, np.einsum("ij,i,ij->j", x_tr, w, x_tr))
    cells = train["cell"].to_numpy()
    uniq = np.unique(cells)
    fold_of = dict(zip(uniq, np.random.default_rng(seed).permutation(uniq.size) % folds))
    fold = np.array([fold_of[c] for c in cells])

    def cv_error(lams):
        pen = sum(lams[k] * pens[k] for k in _PENALTY_KINDS)
        err = 0.0
        for k in range(folds):
            m = fold != k
            if m.all() or not m.any():
                continue
            beta = _solve(x_tr[m], r[m], w[m], pen)
            err += float(np.sum(w[~m] * (r[~m] - x_tr[~m] @ beta) ** 2))
        return err
    # Coordinate descent over the grid, from the smoothest model: two sweeps.
    lams = dict.fromkeys(_PENALTY_KINDS, float(_CEIL_LAMBDAS[-1]))
    for _ in range(2):
        for kind in [k for k in _PENALTY_KINDS if pens[k].any()]:
            errs = [cv_error(lams | {kind: float(v)}) for v in _CEIL_LAMBDAS]
            lams[kind] = float(_CEIL_LAMBDAS[int(np.argmin(errs))])
    pen = sum(lams[k] * pens[k] for k in _PENALTY_KINDS)
    # A smooth that predicts left-out patches worse than the plain simulation (too few
    # readings to fit one, e.g. a handful of validation readings) is no ceiling: use the plain
    # simulation's prediction instead.
    zero = float(sum(np.sum(w[fold == k] * r[fold == k] ** 2) for k in range(folds)))
    if cv_error(lams) >= zero:
        return test["mu0"].to_numpy(float)
    beta = _solve(x_tr, r, w, pen)
    return test["mu0"].to_numpy(float) + x_te @ beta
