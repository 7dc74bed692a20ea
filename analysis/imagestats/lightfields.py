"""How each image statistic follows gloss and depth within and across light fields.

The seed rendered every array under 22 light fields (11 indoor, 11 outdoor) to ask whether the
statistics that change with gloss and depth do so whatever the light (protocol.md, Image
statistics). For each statistic, standardised over all images (z, SD units):

- *within light fields*: OLS ``z ~ C(light_field) + gloss + depth``: the slopes on true gloss
  (SD per 10 % gloss) and true depth (SD per cm) with each light field's own level removed,
  i.e. estimated from the differences between images of one light field (needs light fields
  with >= 2 images of different levels);
- *indoor*, *outdoor*: ``z ~ gloss + depth`` over the images of the light fields of one kind:
  the slopes across those light fields, which include how the light fields differ;
- *across light fields*: the share of the statistic's variance that lies between light fields
  (R^2 of ``z ~ C(light_field)``), and the difference between the mean of the indoor and of the
  outdoor light fields (SD units; Welch's t over the light fields' means).

All CIs are HC3 robust 95 % intervals (statsmodels).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from analysis.imagestats.images import ImageStatsError

__all__ = ["light_field_effects", "light_field_means", "light_field_spread"]

#: Gloss slopes are given per this many % of gloss (one step of the reference set).
GLOSS_STEP_PCT = 10.0


def _z(values: pd.Series) -> pd.Series:
    sd = values.std(ddof=0)
    return (values - values.mean()) / sd if sd > 0 else values * 0.0


def _check(frame: pd.DataFrame) -> None:
    missing = [c for c in ("light_field", "illumination", "true_gloss_pct", "true_depth_cm")
               if c not in frame.columns]
    if missing:
        raise ImageStatsError(f"the statistics table lacks {missing}; compute it from a render "
                              "folder whose manifest has light_field (python -m stimuli render)")
    if frame["light_field"].nunique() < 2:
        raise ImageStatsError("statistics across light fields need images of >= 2 light fields")


def _kind(frame: pd.DataFrame) -> pd.Series:
    """indoor/outdoor of each image: its illumination condition's name where that is a kind."""
    return frame["illumination"].astype(str)


def _separable(sub: pd.DataFrame, *, within: bool) -> bool:
    """Whether gloss and depth slopes are estimable from ``sub`` with a residual left: the
    gloss and depth columns (each light field's mean removed when ``within``) of full rank."""
    x = sub[["true_gloss_pct", "true_depth_cm"]].to_numpy(np.float64, copy=True)
    groups = sub["light_field"].to_numpy() if within else np.zeros(len(sub))
    for g in np.unique(groups):
        x[groups == g] -= x[groups == g].mean(axis=0)
    n_params = 2 + len(np.unique(groups))
    return len(sub) > n_params and np.linalg.matrix_rank(x) == 2


def light_field_effects(frame: pd.DataFrame, names: list[str]) -> pd.DataFrame:
    """Slopes of each statistic on gloss and depth, within light fields and per kind.

    Parameters
    ----------
    frame : DataFrame
        `stat_table` output with ``light_field`` (one row per image).
    names : list of str
        Statistics.

    Returns
    -------
    DataFrame
        ``statistic, scope`` ("within light fields", or a kind), ``gloss_slope_sd_per_10pct,
        gloss_ci_low, gloss_ci_high, depth_slope_sd_per_cm, depth_ci_low, depth_ci_high,
        n_images, n_light_fields``. A scope whose images cannot separate gloss from depth is
        left out.
    """
    import statsmodels.formula.api as smf

    _check(frame)
    data = frame.copy()
    data["_kind"] = _kind(data)
    rows = []
    for name in names:
        data["_y"] = _z(data[name].astype(float))
        scopes = [("within light fields", data, ("_y ~ C(light_field) + true_gloss_pct + "
                   "true_depth_cm"))]
        scopes += [(k, sub, "_y ~ true_gloss_pct + true_depth_cm")
                   for k, sub in data.groupby("_kind")]
        for scope, sub, formula in scopes:
            if not _separable(sub, within=scope == "within light fields"):
                continue
            fit = smf.ols(formula, data=sub).fit(cov_type="HC3")
            if fit.df_resid < 1 or not np.isfinite(fit.bse[["true_gloss_pct",
                                                            "true_depth_cm"]]).all():
                continue
            ci = fit.conf_int()
            rows.append({"statistic": name, "scope": scope,
                         "gloss_slope_sd_per_10pct": GLOSS_STEP_PCT
                         * fit.params["true_gloss_pct"],
                         "gloss_ci_low": GLOSS_STEP_PCT * ci.loc["true_gloss_pct", 0],
                         "gloss_ci_high": GLOSS_STEP_PCT * ci.loc["true_gloss_pct", 1],
                         "depth_slope_sd_per_cm": fit.params["true_depth_cm"],
                         "depth_ci_low": ci.loc["true_depth_cm", 0],
                         "depth_ci_high": ci.loc["true_depth_cm", 1],
                         "n_images": len(sub), "n_light_fields": sub["light_field"].nunique()})
    return pd.DataFrame(rows)


def light_field_spread(frame: pd.DataFrame, names: list[str]) -> pd.DataFrame:
    """How much each statistic differs between light fields, and indoor vs outdoor.

    Returns
    -------
    DataFrame
        ``statistic, between_light_field_r2`` (variance share between light fields),
        ``indoor_minus_outdoor_sd`` (difference of the kinds' mean over their light fields'
        means, SD units), ``welch_t, welch_p`` (NaN unless both kinds have >= 2 light fields).
    """
    from scipy import stats as st

    _check(frame)
    data = frame.copy()
    data["_kind"] = _kind(data)
    rows = []
    for name in names:
        y = _z(data[name].astype(float))
        lf_mean = y.groupby(data["light_field"]).transform("mean")
        total = float(np.sum(y**2))
        r2 = float(1 - np.sum((y - lf_mean) ** 2) / total) if total > 0 else np.nan
        means = y.groupby([data["_kind"], data["light_field"]]).mean()
        kinds = means.index.get_level_values(0)
        a, b = means[kinds == "indoor"], means[kinds == "outdoor"]
        diff = float(a.mean() - b.mean()) if len(a) and len(b) else np.nan
        t, p = (st.ttest_ind(a, b, equal_var=False) if len(a) > 1 and len(b) > 1
                else (np.nan, np.nan))
        rows.append({"statistic": name, "between_light_field_r2": r2,
                     "indoor_minus_outdoor_sd": diff, "welch_t": float(t), "welch_p": float(p)})
    return pd.DataFrame(rows)


def light_field_means(frame: pd.DataFrame, names: list[str]) -> pd.DataFrame:
    """Mean of each statistic per light field (its kind, its number of images), ordered by kind
    and name: the statistics across the light fields, as the report tabulates them."""
    _check(frame)
    data = frame.copy()
    data["kind"] = _kind(data)
    out = data.groupby(["kind", "light_field"], as_index=False).agg(
        n_images=("true_gloss_pct", "size"), **{n: (n, "mean") for n in names})
    return out.sort_values(["kind", "light_field"]).reset_index(drop=True)
