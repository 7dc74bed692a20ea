"""Figures of a calibration: luminance vs level with fits and residuals; uniformity maps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from calibration.readings import at_centre
from calibration.record import Calibration
from labfiles import atomic_path

__all__ = ["plot_gamma", "plot_uniformity"]


def _save(fig, path) -> Path:
    """Save a figure atomically, with the umask's permissions."""
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    return path


def plot_gamma(cal: Calibration, readings: pd.DataFrame, path,
               validation: pd.DataFrame | None = None) -> Path:
    """Centre readings, every fitted model, residuals (and validation, when given)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    centre = readings[at_centre(readings)]
    n = 3 if validation is not None and len(validation) else 2
    fig, axes = plt.subplots(n, 1, figsize=(6.5, 3.2 * n), constrained_layout=True,
                             gridspec_kw={"height_ratios": [2, 1, 1.4][:n]})
    x = np.linspace(0, 1, 256)
    colours = {f.model: f"C{i % 10}" for i, f in enumerate(cal.fits)}
    shift = {f.model: 0.004 * (i - (len(cal.fits) - 1) / 2) for i, f in enumerate(cal.fits)}
    ax = axes[0]
    ax.plot(centre["level"], centre["luminance_cd_m2"], "k.", ms=5, label="readings")
    for f in cal.fits:
        chosen = " (chosen)" if f.model == cal.gamma_model else ""
        ax.plot(x, f.luminance(x), color=colours[f.model], lw=2 if chosen else 1,
                label=f"{f.model}{chosen}: held-out RMSE {f.heldout_rmse_cd_m2:.3f} cd/m²")
    ax.set(xlabel="drive level", ylabel="luminance (cd/m²)",
           title=f"{cal.calibration_id}: {cal.device}, screen centre")
    ax.legend(fontsize=8)
    ax = axes[1]
    for f in cal.fits:
        ax.plot(np.array(f.levels) + shift[f.model], f.residuals_cd_m2, ".",
                color=colours[f.model], ms=4, label=f.model)
    ax.axhline(0, color="k", lw=0.5)
    ax.set(xlabel="drive level", ylabel="residual (cd/m²)")
    if n == 3:
        ax = axes[2]
        span = cal.max_luminance_cd_m2 - cal.min_luminance_cd_m2
        frac = (validation["luminance_cd_m2"] - cal.min_luminance_cd_m2) / span
        ax.plot([0, 1], [0, 1], "k-", lw=0.5, label="linear")
        ax.plot(validation["target_fraction"], frac, "o", color="tab:red", ms=4,
                label=f"corrected: max deviation {cal.validation_max_deviation_pct:.2f} %")
        ax.set(xlabel="requested fraction of luminance range",
               ylabel="measured fraction", title="validation after gamma correction")
        ax.legend(fontsize=8)
    path = _save(fig, path)
    plt.close(fig)
    return path


def plot_uniformity(cal: Calibration, path) -> Path | None:
    """Heat maps of relative luminance and correction gain over the screen (None: no map)."""
    if cal.uniformity is None:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    u = cal.uniformity
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6), constrained_layout=True)
    xs, ys = np.array(u.x_norm), np.array(u.y_norm)
    for ax, data, title, cmap in (
        (axes[0], np.array(u.relative), (f"relative luminance (non-uniformity "
                                         f"{u.nonuniformity_pct:.1f} %)"), "magma"),
        (axes[1], np.array(u.gain), "correction gain", "viridis"),
    ):
        im = ax.imshow(data, origin="lower", cmap=cmap, aspect="auto",
                       extent=(xs.min() - 0.3, xs.max() + 0.3, ys.min() - 0.3, ys.max() + 0.3))
        for j, y in enumerate(ys):
            for i, x in enumerate(xs):
                ax.text(x, y, f"{data[j, i]:.3f}", ha="center", va="center", fontsize=9,
                        color="w" if data[j, i] < np.median(data) else "k")
        ax.set(xlabel="x (norm units)", ylabel="y (norm units)", title=title)
        fig.colorbar(im, ax=ax, shrink=0.8)
    path = _save(fig, path)
    plt.close(fig)
    return path
