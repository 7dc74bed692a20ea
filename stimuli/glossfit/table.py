"""From per-level fits to the gloss table (the source study's final steps).

The seed averages rho_d over all levels (one common albedo: the balls share a base and differ in
varnish), fits rho_s against gloss level by a line, checks the line by leave-one-out
cross-validation and moves rho_s onto it. alpha stays as fitted per level, except where a photo
does not determine it (almost no specular light, e.g. the matte 0 % ball): there alpha comes from
a line in log alpha through the levels that do determine it (column ``alpha_source``).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from stimuli.glossfit.photoset import GlossFitError

__all__ = ["gloss_table_from_fits", "line_with_loo"]


def line_with_loo(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares line y = a + b x and its leave-one-out prediction errors.

    Parameters
    ----------
    x, y : ndarray, shape (n,)

    Returns
    -------
    coef : ndarray, shape (2,)
        (a, b).
    loo_error : ndarray, shape (n,)
        abs(y_i - line fitted without point i, at x_i); NaN for every point when n < 3.
    """
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    if x.size < 2:
        raise GlossFitError(f"a line needs >= 2 fitted gloss levels, got {x.size}")
    b, a = np.polyfit(x, y, 1)
    loo = np.full(x.size, np.nan)
    if x.size >= 3:
        for i in range(x.size):
            keep = np.arange(x.size) != i
            bi, ai = np.polyfit(x[keep], y[keep], 1)
            loo[i] = abs(y[i] - (ai + bi * x[i]))
    return np.array([a, b]), loo


def gloss_table_from_fits(fits: pd.DataFrame, alpha_undetermined: tuple[float, ...] = ()
                          ) -> tuple[pd.DataFrame, dict]:
    """The gloss table from fits.csv rows.

    Parameters
    ----------
    fits : DataFrame
        Columns gloss_pct, rho_d, rho_s, alpha, rmse (rows with NaN parameters, i.e. failed
        levels, are left out).
    alpha_undetermined : tuple of float
        Gloss levels (%) whose photo does not determine alpha.

    Returns
    -------
    table : DataFrame
        gloss_pct, rho_d (common), rho_s (on the line), alpha, fit_error (the level's relative
        RMSE on the sphere), loo_error (leave-one-out error of rho_s), and the level's own
        rho_d_fit, rho_s_fit.
    summary : dict
        common_rho_d, rho_s_intercept, rho_s_slope_per_pct, rho_s_loo_rmse.

    Raises
    ------
    GlossFitError
        If fewer than 2 levels were fitted.
    """
    ok = fits.dropna(subset=["rho_d", "rho_s", "alpha"]).sort_values("gloss_pct")
    if len(ok) < 2:
        raise GlossFitError(f"only {len(ok)} gloss levels were fitted; the gloss table needs >= 2 "
                            f"(see the warnings in fits.csv)")
    g = ok["gloss_pct"].to_numpy(float)
    rho_d = float(ok["rho_d"].mean())
    coef, loo = line_with_loo(g, ok["rho_s"].to_numpy(float))
    rho_s_line = np.clip(coef[0] + coef[1] * g, 0.0, None)
    alpha = ok["alpha"].to_numpy(float)
    fill = np.isin(g, np.asarray(alpha_undetermined, float))
    source = np.where(fill, "log-linear from the other levels", "fitted")
    if fill.any():
        if (~fill).sum() >= 2:
            b_log, a_log = np.polyfit(g[~fill], np.log(alpha[~fill]), 1)
            alpha = np.where(fill, np.exp(a_log + b_log * g), alpha)
        else:
            source = np.where(fill, "fitted (undetermined; too few other levels)", source)
    table = pd.DataFrame({
        "gloss_pct": g,
        "rho_d": rho_d,
        "rho_s": rho_s_line,
        "alpha": alpha,
        "fit_error": ok["rmse"].to_numpy(float),
        "loo_error": loo,
        "rho_d_fit": ok["rho_d"].to_numpy(float),
        "rho_s_fit": ok["rho_s"].to_numpy(float),
        "alpha_fit": ok["alpha"].to_numpy(float),
        "alpha_source": source,
    })
    summary = {"common_rho_d": rho_d, "rho_s_intercept": float(coef[0]),
               "rho_s_slope_per_pct": float(coef[1]),
               "rho_s_loo_rmse": float(np.sqrt(np.nanmean(loo ** 2))) if np.isfinite(loo).any()
               else float("nan")}
    return table, summary
