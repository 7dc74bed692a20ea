"""Display layer, the ceiling and the floor: how well any model of the readings could do, and
how far the readings are, in the lab's units.

The floor (:func:`display_floor`) is the loss of a model right up to the photometer's noise,
``0.5 log(2 pi sd^2) + 0.5`` per reading. The ceiling (:func:`display_ceiling`) is the held-out
loss of a penalised smooth of level, position and time fitted to the plain simulation's
residuals; a chosen model that stays significantly above it leaves a gap the catalogue does
not explain.

How far (:func:`display_misfit`, :func:`display_misfit_size`): a reading's misfit is
``L - prediction`` (cd/m^2), the prediction held out as the diagnosis scores it (each reading
predicted by the fold that did not see it, the calibration moved within its own uncertainty:
:func:`~analysis.gap.display.model.display_mean_given`, without the between-pass wander, which
only decides significance); censored readings carry no number.
``% of luminance`` is ``100 (L - prediction) / prediction`` over the readings above
:data:`NEAR_BLACK_FRACTION` of the calibration's white (a lab reads it as the Weber fraction:
about 1 % is the smallest step of luminance seen at photopic levels); near black the misfit is
in cd/m^2 (the eye's threshold there is no longer a constant fraction, and the meter's
absolute noise dominates). RMS figures include the meter's noise (what a comparison of two
passes shows); the ``size`` held to the tolerance takes the noise's mean square out (the
meter's, with the calibration's own misfit; not the change between passes, which is the
display's), so a check no further off than a repeat reads about 0.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy import linalg

from analysis.gap.display.model import display_mean_given, display_nll
from analysis.gap.display.null.noise import _bspline

__all__ = ["DARK_LIGHT_CD_M2", "DISPLAY_SIZE_UNIT", "NEAR_BLACK_FRACTION", "ceiling_prediction",
           "display_ceiling", "display_floor", "display_misfit", "display_misfit_size",
           "display_misfit_upper", "group_codes", "size_bounds"]

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
    # The smooth is fitted without censored readings and knows nothing below the meter's
    # floor: there it predicts what the plain simulation does (its extrapolation to a zero
    # read at black cost up to 1e4 nats per reading, a ceiling no model had to beat).
    mu0 = test["mu0"].to_numpy(float)
    return np.where(test["censored"].to_numpy(bool), mu0, mu0 + x_te @ beta)


# --- how far, in the lab's units ------------------------------------------------------------

#: Readings predicted below this fraction of the calibration's white count as near black:
#: their misfit is given in cd/m^2, not in % (5 % of a 100 cd/m^2 white is 5 cd/m^2, where
#: photopic contrast thresholds begin to rise above the Weber fraction).
NEAR_BLACK_FRACTION = 0.05

#: The eye's dark light, cd/m^2: a luminance step is seen when it is about the Weber fraction
#: of ``L + DARK_LIGHT_CD_M2`` (Weber's law at photopic levels, thresholds that level off in
#: cd/m^2 toward black; with 1 cd/m^2 the fraction at 0.5 cd/m^2 is 3 times that at 100, as
#: contrast thresholds on displays are, e.g. the DICOM grayscale function's). The tolerance
#: is held to misfits in % of that light.
DARK_LIGHT_CD_M2 = 1.0

#: The unit of the display layer's tolerance, in words (the summary's).
DISPLAY_SIZE_UNIT = ("% of luminance (systematic RMS at the worst screen position or drive "
                     "level, in % of the light plus 1 cd/m^2)")


def _near_black(data: pd.DataFrame) -> float:
    """The light (cd/m^2) below which a reading counts as near black."""
    return NEAR_BLACK_FRACTION * float(data.attrs["cal"].max_luminance_cd_m2)


def _parts(data: pd.DataFrame, pred: np.ndarray) -> dict:
    """Above near black: relative misfit ``rel``, relative noise SD ``sd``, ``cell`` and
    screen position ``pos``; near black: misfit ``dark`` and noise SD ``dark_sd`` (cd/m^2);
    uncensored readings only; ``black_below``, where near black ends (cd/m^2)."""
    lum, pred = data["L"].to_numpy(float), np.asarray(pred, float)
    use = ~data["censored"].to_numpy(bool) & np.isfinite(pred)
    bright = use & (pred >= _near_black(data)) & (pred > 0)
    dark = use & ~bright
    var = (data["var_expected"] if "var_expected" in data else data["sd"] ** 2).to_numpy(float)
    pos = np.array([f"{x:+.3f},{y:+.3f}" for x, y in zip(data["x_norm"], data["y_norm"])])
    band = np.array([f"{v:.4f}" for v in data["level"].to_numpy(float)])
    seen = pred[use] + DARK_LIGHT_CD_M2
    return {"rel": (lum[bright] - pred[bright]) / pred[bright],
            "sd": np.sqrt(var[bright]) / pred[bright], "cell": data["cell"].to_numpy()[bright],
            "dark": lum[dark] - pred[dark], "dark_sd": np.sqrt(var[dark]),
            "seen": (lum[use] - pred[use]) / seen, "seen_sd": np.sqrt(var[use]) / seen,
            "group": np.concatenate([np.char.add("pos ", pos[use]),
                                     np.char.add("level ", band[use])]),
            "black_below": _near_black(data)}


def _systematic(r: np.ndarray, sd: np.ndarray) -> float:
    """RMS of ``r`` with the noise's mean square (``sd``) taken out (0 if noise explains it)."""
    return float(np.sqrt(max(np.mean(r**2 - sd**2), 0.0))) if r.size else float("nan")


def _summary(parts: list) -> dict:
    """RMS %, systematic % (overall and at the worst screen position), worst patch %, near-black
    RMS and systematic cd/m^2, and the size held to the tolerance, of folds' ``_parts``."""
    p = {k: np.concatenate([q[k] for q in parts])
         for k in ("rel", "sd", "cell", "dark", "dark_sd", "seen", "seen_sd")}
    rel, sd = p["rel"], p["sd"]
    out = dict.fromkeys(("rms_pct", "systematic_pct", "worst_pct"), float("nan"))
    if rel.size:
        out["rms_pct"] = float(100 * np.sqrt(np.mean(rel**2)))
        out["systematic_pct"] = 100 * _systematic(rel, sd)
        out["worst_pct"] = float(100 * pd.Series(rel).groupby(p["cell"]).mean().abs().max())
    dark = p["dark"]
    out["black_cd_m2"] = float(np.sqrt(np.mean(dark**2))) if dark.size else float("nan")
    out["black_systematic_cd_m2"] = _systematic(dark, p["dark_sd"])
    # Each reading is in two groups (its screen position, its drive level).
    seen, seen_sd, codes, names = group_codes(parts)
    sizes = {q: 100 * _systematic(seen[(codes == i).any(axis=0)],
                                  seen_sd[(codes == i).any(axis=0)])
             for i, q in enumerate(names)}
    where = max(sizes, key=sizes.get) if sizes else ""
    out["size_pct"] = float(sizes[where]) if sizes else float("nan")
    out["size_where"] = where.replace("level ", "drive level ").replace("pos ", "position ")
    return out


def display_misfit_size(fits: list) -> float:
    """The engine's ``size`` (%, the meter's noise taken out) of what the chosen model leaves
    on the held-out readings: each reading's misfit in % of its light plus the eye's dark
    light (:data:`DARK_LIGHT_CD_M2`), systematic RMS over each screen position and each drive
    level, the largest of these (a misfit confined to one region or to the dark levels, a
    black offset, is not diluted by the rest). ``fits``: per fold
    ``(train, test, fitted, ceiling_loss)``."""
    return _summary([_parts(te, display_mean_given(tr, te, list(ch), wander=False))
                     for tr, te, ch, _ in fits])["size_pct"]


def group_codes(parts: list) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Folds' ``_parts`` pooled for :func:`size_bounds`: each reading's ``seen`` misfit and
    noise SD (fractions of its light plus the dark light), and, for the two groups each
    reading is in (its screen position, its drive level), an integer code per reading and
    group (shape (2, n)) with the groups' names."""
    seen = np.concatenate([q["seen"] for q in parts])
    seen_sd = np.concatenate([q["seen_sd"] for q in parts])
    # Each part's groups are its readings' positions, then their levels.
    pos = [q["group"][:q["seen"].size] for q in parts]
    lvl = [q["group"][q["seen"].size:] for q in parts]
    group = np.concatenate(pos + lvl)
    codes, names = pd.factorize(pd.Series(group))
    return seen, seen_sd, codes.reshape(2, -1), np.asarray(names)


def size_bounds(seen: np.ndarray, seen_sd: np.ndarray, codes: np.ndarray) -> tuple:
    """The size held to the tolerance (:func:`display_misfit_size`, %) with its lower and
    upper 95 % bounds, for one set of readings or many at once.

    Per group g (a screen position, a drive level) the systematic mean square is the mean of
    ``seen^2 - seen_sd^2`` over its readings, with its standard error from their spread; the
    size is 100 sqrt of the largest (0 if none is positive); the SE is at least the noise
    model's (a group of one reading has no spread). Upper bound: 100 sqrt of the
    largest one-sided 95 % bound (mean + 1.645 SE): whichever group's misfit is largest, its
    own bound holds it with 95 %, so the largest bound holds the size. ``significant``: the
    size where the readings' misfit is significantly more than their noise over all readings
    (squared z-scores in excess of 1, one-sided 5 %, as the diagnosis's test against the
    ceiling pools all readings), else 0 (the ``lower`` that
    :func:`~analysis.gap.engine.decide_size` takes).

    Parameters
    ----------
    seen, seen_sd : ndarray, shape (..., n) and (n,)
        Misfits and noise SDs as fractions (:func:`group_codes`); leading axes are draws.
    codes : ndarray of int, shape (2, n)

    Returns
    -------
    (size, significant, upper) : float or ndarray of shape ``seen.shape[:-1]``, %
    """
    from scipy.stats import norm

    v = np.asarray(seen, float) ** 2 - np.asarray(seen_sd, float) ** 2
    n_groups = int(codes.max()) + 1 if codes.size else 0
    if not n_groups:
        nan = np.full(v.shape[:-1], np.nan)
        return (nan, nan, nan) if nan.ndim else (float("nan"),) * 3
    onehot = np.zeros((v.shape[-1], n_groups))
    for row in codes:
        onehot[np.arange(row.size), row] = 1.0
    n = onehot.sum(axis=0)
    mean = (v @ onehot) / n
    var = np.maximum((v**2 @ onehot) - n * mean**2, 0.0) / np.maximum(n - 1, 1)
    # A group of one or a few readings shows no spread to take an SE from: at least what the
    # noise alone gives, Var(r^2 - sd^2) = 2 sd^4 + 4 m^2 sd^2 for r = m + noise.
    sd2 = np.asarray(seen_sd, float) ** 2
    noise_var = (2 * sd2**2) @ onehot + 4 * np.maximum(mean, 0.0) * (sd2 @ onehot)
    se = np.sqrt(np.maximum(var / n, noise_var / n**2))

    def pct(ms):
        out = 100 * np.sqrt(np.maximum(ms.max(axis=-1), 0.0))
        return float(out) if out.ndim == 0 else out
    size = pct(mean)
    # Significance over all readings, as the diagnosis's test against the ceiling pools them:
    # the readings' squared z-scores in excess of 1, one-sided 5 % (a chi-square's mean and SD).
    z2 = np.asarray(seen, float) ** 2 / np.maximum(sd2, 1e-300)
    excess = np.sum(z2 - 1, axis=-1) / np.sqrt(2 * z2.shape[-1])
    return size, np.where(excess > norm.isf(0.05), size, 0.0)[()], pct(mean + norm.isf(0.05) * se)


def display_misfit_upper(fits: list) -> float:
    """The engine's ``size_upper``: the upper 95 % bound (%) of :func:`display_misfit_size`
    (:func:`size_bounds`) on the held-out readings. ``fits`` as for the size."""
    parts = [_parts(te, display_mean_given(tr, te, list(ch), wander=False))
             for tr, te, ch, _ in fits]
    return size_bounds(*group_codes(parts)[:3])[2]


def display_misfit(folds: list, chosen: list) -> dict:
    """The held-out misfit in the lab's units before, after the chosen effects and of the
    ceiling (:func:`~analysis.gap.display.ceiling.ceiling_prediction`), pooled over the
    cross-fitting ``folds`` ``[(train, test), ...]`` (each reading held out once).

    Parameters
    ----------
    folds : list of (DataFrame, DataFrame)
    chosen : list of (name, params)
        The chosen effects with their (fold-mean) parameters.

    Returns
    -------
    dict
        ``misfit_pct_before``, ``misfit_pct_after`` (RMS % of luminance, noise included: the
        :class:`~analysis.gap.engine.Diagnosis` fields) and ``misfit``: ``unit``,
        ``ceiling_pct``; each ``_before`` / ``_after``: ``systematic_pct`` (noise removed),
        ``worst_pct`` (the patch whose mean misfit is largest, noise included),
        ``black_cd_m2`` (RMS near black), ``black_systematic_cd_m2`` (noise removed),
        ``size_pct`` and ``size_where`` (what the tolerance is held to and where:
        :func:`display_misfit_size`); ``ceiling_black_cd_m2`` and ``black_below_cd_m2``
        (where near black ends). NaN where no reading qualifies.
    """
    before = _summary([_parts(te, display_mean_given(tr, te, [], wander=False))
                       for tr, te in folds])
    after = _summary([_parts(te, display_mean_given(tr, te, chosen, wander=False))
                      for tr, te in folds])
    ceil = _summary([_parts(te, ceiling_prediction(tr, te)) for tr, te in folds])
    misfit = {"unit": "of luminance", "ceiling_pct": ceil["rms_pct"],
              "black_below_cd_m2": _near_black(folds[0][1]),
              "ceiling_black_cd_m2": ceil["black_cd_m2"]}
    for key in ("systematic_pct", "worst_pct", "black_cd_m2", "black_systematic_cd_m2",
                "size_pct", "size_where"):
        misfit[f"{key}_before"], misfit[f"{key}_after"] = before[key], after[key]
    return {"misfit_pct_before": before["rms_pct"], "misfit_pct_after": after["rms_pct"],
            "misfit": misfit}
