"""Relating image statistics to depth and to perceived gloss.

Three questions (protocol.md, "Image statistics"):

1. `depth_effects`: which statistics change with depth at fixed gloss? For each statistic,
   standardised over all images (z), an OLS fit ``z ~ C(illumination:gloss_level) + true_depth_cm``:
   the depth slope at fixed gloss and illumination, SD per cm, with HC3 robust 95 % CIs and
   Holm-adjusted p-values over the statistics; and the slope within each illumination x gloss cell
   for the figures.
2. `gloss_regression`: perceived gloss (cell means of ``gloss_match_pct``) on true gloss and
   each statistic in place of depth: how much of the observers' depth-to-gloss effect each
   statistic reproduces ("depth share"). CIs by a participant bootstrap.
3. `ImageStatsObserver` (observer.py): perceived gloss predicted from the statistics alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from analysis.imagestats.images import ImageStatsError

__all__ = [
    "CELL",
    "SCALAR_STATS",
    "DepthEffect",
    "cell_means",
    "depth_effects",
    "gloss_regression",
    "ps_components",
    "stat_table",
]

#: The pixel statistics related to perception (``diffuse_luminance`` is the threshold's base).
SCALAR_STATS = ("mean_luminance", "rms_contrast", "skewness", "kurtosis", "highlight_coverage")
#: Columns that name a stimulus cell of the design.
CELL = ("illumination", "gloss_level", "depth_level")


def ps_components(stats: pd.DataFrame, *, n_components: int) -> tuple[pd.DataFrame, dict]:
    """Principal components of the standardised Portilla-Simoncelli statistics.

    The ~700 PS values are z-scored over the images (constant ones dropped) and projected on their
    first ``n_components`` principal axes, a documented reduction for analyses that cannot take
    700 correlated predictors.

    Returns
    -------
    scores : DataFrame
        ``ps_pc1..ps_pcK`` per image (same index as ``stats``).
    basis : dict
        ``columns``, ``mean``, ``sd``, ``axes`` (K x columns) and ``explained`` (variance fractions),
        enough to project new images (`project_ps`).
    """
    cols = [c for c in stats.columns if c.startswith("ps_") and not c.startswith("ps_pc")]
    if not cols:
        raise ImageStatsError("the table has no Portilla-Simoncelli columns (computed --no-ps)")
    x = stats[cols].to_numpy(np.float64)
    sd = x.std(axis=0)
    keep = sd > 1e-12 * np.maximum(1.0, np.abs(x).max(axis=0))
    cols = [c for c, k in zip(cols, keep) if k]
    x = x[:, keep]
    mean, sd = x.mean(axis=0), x.std(axis=0)
    z = (x - mean) / sd
    k = int(min(n_components, z.shape[0] - 1, z.shape[1]))
    if k < 1:
        raise ImageStatsError(f"{len(stats)} images are too few for PS components")
    _, s, vt = np.linalg.svd(z, full_matrices=False)
    axes = vt[:k]
    # sign convention: each axis points where its largest loading is positive (reproducible)
    axes *= np.sign(axes[np.arange(k), np.abs(axes).argmax(axis=1)])[:, None]
    basis = {"columns": cols, "mean": mean.tolist(), "sd": sd.tolist(), "axes": axes.tolist(),
             "explained": (s[:k] ** 2 / np.sum(s**2)).tolist()}
    return project_ps(stats, basis), basis


def project_ps(stats: pd.DataFrame, basis: dict) -> pd.DataFrame:
    """Scores of images on PS axes from `ps_components`."""
    missing = [c for c in basis["columns"] if c not in stats.columns]
    if missing:
        raise ImageStatsError(f"the table lacks PS columns {missing[:3]} the basis needs")
    z = (stats[basis["columns"]].to_numpy(np.float64) - np.asarray(basis["mean"])) \
        / np.asarray(basis["sd"])
    scores = z @ np.asarray(basis["axes"]).T
    return pd.DataFrame(scores, index=stats.index,
                        columns=[f"ps_pc{i + 1}" for i in range(scores.shape[1])])


def stat_table(stats: pd.DataFrame, *, n_ps_components: int = 3) -> tuple[pd.DataFrame, list]:
    """Keys, the scalar statistics and (if the table has PS columns) their first components.

    Returns
    -------
    frame : DataFrame
        ``stimulus_id``, `CELL`, ``true_gloss_pct``, ``true_depth_cm``, ``light_field`` (when the
        table has it), the statistics.
    names : list of str
        The statistics' column names.
    """
    keys = ["stimulus_id", *CELL, "true_gloss_pct", "true_depth_cm"]
    missing = [c for c in keys + list(SCALAR_STATS) if c not in stats.columns]
    if missing:
        raise ImageStatsError(f"the statistics table lacks columns {missing}")
    if "light_field" in stats.columns:  # the light fields, for statistics across them
        keys.append("light_field")
    frame = stats[keys + list(SCALAR_STATS)].copy()
    names = list(SCALAR_STATS)
    has_ps = any(c.startswith("ps_") for c in stats.columns)
    if has_ps and n_ps_components > 0 and len(stats) > 2:
        scores, _ = ps_components(stats, n_components=n_ps_components)
        frame = pd.concat([frame, scores], axis=1)
        names += list(scores.columns)
    return frame, names


@dataclass(frozen=True)
class DepthEffect:
    """Depth slope of one statistic at fixed gloss and illumination.

    Attributes
    ----------
    statistic : str
    slope_sd_per_cm, ci_low, ci_high : float
        Slope of the standardised statistic on true depth (SD per cm) and its HC3 95 % CI.
    slope_per_cm : float
        The same slope in the statistic's own unit per cm.
    p, p_holm : float
        Wald p-value and its Holm adjustment over all statistics tested.
    n_images : int
    """

    statistic: str
    slope_sd_per_cm: float
    ci_low: float
    ci_high: float
    slope_per_cm: float
    p: float
    p_holm: float
    n_images: int


def depth_effects(frame: pd.DataFrame, names: list[str]) -> tuple[list[DepthEffect], pd.DataFrame]:
    """Which statistics change with depth at fixed gloss (see the module docstring).

    Parameters
    ----------
    frame : DataFrame
        From `stat_table`.
    names : list of str
        Statistics to test.

    Returns
    -------
    effects : list of DepthEffect
        One per statistic, in the order of ``names``.
    per_cell : DataFrame
        ``statistic, illumination, gloss_level, true_gloss_pct, slope_sd_per_cm, ci_low,
        ci_high`` from an OLS fit within each illumination x gloss cell (NaN CI where the cell has
        fewer than 3 depths).

    Raises
    ------
    ImageStatsError
        If the table has fewer than 2 depth levels.
    """
    import statsmodels.formula.api as smf
    from statsmodels.stats.multitest import multipletests

    if frame["true_depth_cm"].nunique() < 2:
        raise ImageStatsError("depth effects need images of at least 2 depth levels")
    data = frame.copy()
    data["cell"] = data["illumination"].astype(str) + ":" + data["gloss_level"].astype(str)
    one_cell = data["cell"].nunique() == 1
    rows, cells = [], []
    for name in names:
        values = data[name].to_numpy(np.float64)
        sd = values.std()
        data["_z"] = (values - values.mean()) / sd if sd > 0 else 0.0
        formula = "_z ~ true_depth_cm" if one_cell else "_z ~ C(cell) + true_depth_cm"
        fit = smf.ols(formula, data=data).fit(cov_type="HC3")
        lo, hi = fit.conf_int().loc["true_depth_cm"]
        rows.append([name, fit.params["true_depth_cm"], lo, hi,
                     fit.params["true_depth_cm"] * sd, fit.pvalues["true_depth_cm"], len(data)])
        for (illum, gloss), sub in data.groupby(["illumination", "gloss_level"]):
            if sub["true_depth_cm"].nunique() < 2:
                continue
            cell_fit = smf.ols("_z ~ true_depth_cm", data=sub).fit()
            if sub["true_depth_cm"].nunique() >= 3 and len(sub) >= 3:
                c_lo, c_hi = cell_fit.conf_int().loc["true_depth_cm"]
            else:
                c_lo = c_hi = np.nan
            cells.append([name, illum, gloss, float(sub["true_gloss_pct"].iloc[0]),
                          cell_fit.params["true_depth_cm"], c_lo, c_hi])
    p = np.array([r[5] for r in rows])
    p_holm = multipletests(np.nan_to_num(p, nan=1.0), method="holm")[1]
    effects = [DepthEffect(r[0], float(r[1]), float(r[2]), float(r[3]), float(r[4]), float(r[5]),
                           float(ph), int(r[6])) for r, ph in zip(rows, p_holm)]
    per_cell = pd.DataFrame(cells, columns=["statistic", "illumination", "gloss_level",
                                            "true_gloss_pct", "slope_sd_per_cm", "ci_low",
                                            "ci_high"])
    return effects, per_cell


def cell_means(frame: pd.DataFrame, names: list[str]) -> pd.DataFrame:
    """Mean of each statistic per design cell (illumination, gloss_level, depth_level)."""
    cols = ["true_gloss_pct", "true_depth_cm", *names]
    return frame.groupby(list(CELL), as_index=False)[cols].mean()


def join_perception(frame: pd.DataFrame, names: list[str], trials: pd.DataFrame) \
        -> tuple[pd.DataFrame, str, list]:
    """Per participant and stimulus cell: mean perceived gloss with the cell's statistics.

    Trials are matched to images by ``stimulus_id`` when the table holds every stimulus the
    sessions show (the statistics were computed on the experiment's own renders); otherwise by
    design cell, with each cell's statistics averaged over its images (light fields, arrays).
    Cells the sessions show but the table has no image of are left out and returned, so a
    subset of the render set can be related (the report lists them).

    Returns
    -------
    joined : DataFrame
        ``participant``, `CELL`, ``true_gloss_pct``, ``true_depth_cm``, ``gloss_match_pct`` (mean
        over the participant's trials of the cell), the statistics.
    how : {"stimulus_id", "cell"}
    missing : list of tuple
        Cells ``(illumination, gloss_level, depth_level)`` shown but without images.

    Raises
    ------
    ImageStatsError
        If no cell the sessions show has an image in the table.
    """
    per = trials.groupby(["participant", "stimulus_id", *CELL], as_index=False)[
        "gloss_match_pct"].mean()
    if set(per["stimulus_id"]) <= set(frame["stimulus_id"]):
        stats = frame.set_index("stimulus_id")[["true_gloss_pct", "true_depth_cm", *names]]
        return per.join(stats, on="stimulus_id"), "stimulus_id", []
    stats = cell_means(frame, names)
    joined = per.merge(stats, on=list(CELL), how="left")
    absent = joined[names[0]].isna()
    missing = sorted({tuple(c) for c in
                      joined.loc[absent, list(CELL)].drop_duplicates().itertuples(index=False)})
    joined = joined[~absent].reset_index(drop=True)
    if joined.empty:
        raise ImageStatsError(
            f"the statistics table has no image of any stimulus cell the sessions show (e.g. "
            f"{missing[:3]}); compute statistics of a render set that covers them"
        )
    return joined, "cell", missing


def _ols(y: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OLS with intercept: coefficients (intercept first) and fitted values."""
    design = np.column_stack([np.ones(len(y)), x])
    beta = np.linalg.lstsq(design, y, rcond=None)[0]
    return beta, design @ beta


def _r2(y: np.ndarray, fitted: np.ndarray) -> float:
    return float(1 - np.sum((y - fitted) ** 2) / np.sum((y - y.mean()) ** 2))


def _fit_all(y, gloss, depth, z, names) -> dict:
    """Every estimate of `gloss_regression` on one (re)sample."""
    design_vars = np.column_stack([gloss, depth])
    beta_a, fit_a = _ols(y, design_vars)
    depth_effect = beta_a[2]
    _, fit_g = _ols(y, gloss)
    out = {"depth_effect": depth_effect, "r2_A": _r2(y, fit_a), "r2_gloss_only": _r2(y, fit_g)}

    def share(fitted):  # depth slope the model reproduces, relative to the observers'
        return _ols(fitted, design_vars)[0][2] / depth_effect

    for j, name in enumerate(names):
        beta, fitted = _ols(y, np.column_stack([gloss, z[:, j]]))
        out[f"coef:{name}"] = beta[2]
        out[f"r2:{name}"] = _r2(y, fitted)
        out[f"share:{name}"] = share(fitted)
    _, fitted = _ols(y, np.column_stack([gloss, z]))
    out["r2:all"] = _r2(y, fitted)
    out["share:all"] = share(fitted)
    return out


def gloss_regression(joined: pd.DataFrame, names: list[str], *, n_boot: int,
                     rng: np.random.Generator) -> dict:
    """Can the statistics stand in for depth in explaining perceived gloss?

    On the participant x cell means of perceived gloss (``gloss_match_pct``, %):

    - model A, ``gloss ~ true_gloss_pct + true_depth_cm``: the observers' depth effect (% per cm);
    - per statistic S (standardised), ``gloss ~ true_gloss_pct + S``: its coefficient (% per SD),
      R^2, and the *depth share*: the depth slope of the model's fitted values (regressed on true
      gloss and depth) divided by model A's, i.e. how much of the observed depth-to-gloss effect
      the statistic reproduces (1 = all of it, 0 = none);
    - all statistics together, ``gloss ~ true_gloss_pct + S_1 + ... + S_k``.

    True depth and a statistic are not put in one model: a statistic computed on cell means is
    nearly a linear function of gloss and depth, so their coefficients would not be identifiable.
    95 % percentile CIs from ``n_boot`` resamples of participants (with replacement).

    Returns
    -------
    dict
        ``depth_effect``, ``r2_A``, ``r2_gloss_only`` (each {"estimate", "ci_low", "ci_high"}),
        ``per_statistic`` (list of {"statistic", "coef", "r2", "depth_share"}, each with CI),
        ``all`` ({"r2", "depth_share"}), ``n_rows``, ``n_participants``, ``n_boot``.
    """
    data = joined.reset_index(drop=True)
    z = data[names].to_numpy(np.float64)
    sd = z.std(axis=0)
    sd[sd == 0] = 1.0
    z = (z - z.mean(axis=0)) / sd
    gloss = data["true_gloss_pct"].to_numpy(np.float64)
    depth = data["true_depth_cm"].to_numpy(np.float64)
    y = data["gloss_match_pct"].to_numpy(np.float64)
    est = _fit_all(y, gloss, depth, z, names)
    participants = data["participant"].to_numpy()
    ids = np.unique(participants)
    rows_of = {p: np.flatnonzero(participants == p) for p in ids}
    boots = []
    for _ in range(n_boot):
        take = np.concatenate([rows_of[p] for p in rng.choice(ids, size=ids.size)])
        boots.append(_fit_all(y[take], gloss[take], depth[take], z[take], names))

    def ci(key):
        values = np.array([b[key] for b in boots], dtype=float)
        lo, hi = (np.nanpercentile(values, [2.5, 97.5]) if n_boot else (np.nan, np.nan))
        return {"estimate": float(est[key]), "ci_low": float(lo), "ci_high": float(hi)}

    return {
        "depth_effect": ci("depth_effect"), "r2_A": ci("r2_A"),
        "r2_gloss_only": ci("r2_gloss_only"),
        "per_statistic": [{"statistic": n, "coef": ci(f"coef:{n}"), "r2": ci(f"r2:{n}"),
                           "depth_share": ci(f"share:{n}")} for n in names],
        "all": {"r2": ci("r2:all"), "depth_share": ci("share:all")},
        "n_rows": len(data), "n_participants": int(ids.size), "n_boot": int(n_boot),
    }
