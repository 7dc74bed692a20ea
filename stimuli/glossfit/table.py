"""From per-level fits to the gloss table (the seed's final steps).

The seed averages rho_d over all levels (one common albedo: the balls share a base and differ in
varnish), fits rho_s against gloss level by a line, checks the line by leave-one-out
cross-validation and moves rho_s onto it. alpha stays as fitted per level.
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
        |y_i - line fitted without point i, at x_i|; NaN for every point when n < 3.
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


def gloss_table_from_fits(fits: pd.DataFrame) -> tuple[pd.DataFrame, dict]:
    """The gloss table from fits.csv rows.

    Parameters
    ----------
    fits : DataFrame
        Columns gloss_pct, rho_d, rho_s, alpha, rmse (rows with NaN parameters, i.e. failed
        levels, are left out).

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
    table = pd.DataFrame({
        "gloss_pct": g,
        "rho_d": rho_d,
        "rho_s": rho_s_line,
        "alpha": ok["alpha"].to_numpy(float),
        "fit_error": ok["rmse"].to_numpy(float),
        "loo_error": loo,
        "rho_d_fit": ok["rho_d"].to_numpy(float),
        "rho_s_fit": ok["rho_s"].to_numpy(float),
    })
    summary = {"common_rho_d": rho_d, "rho_s_intercept": float(coef[0]),
               "rho_s_slope_per_pct": float(coef[1]),
               "rho_s_loo_rmse": float(np.sqrt(np.nanmean(loo ** 2))) if np.isfinite(loo).any()
               else float("nan")}
    return table, summary
