"""Figures of the image statistics: each statistic over the gloss x depth grid, the depth effects,
and the image-statistics observer against the observers' matches."""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

__all__ = ["plot_depth_effects", "plot_light_fields", "plot_observer_fit", "plot_stat_grid"]


def plot_stat_grid(cells: pd.DataFrame, statistic: str) -> Figure:
    """One statistic over the gloss x depth grid: mean over images against depth (cm), one line
    per gloss level (%), one panel per illumination.

    Parameters
    ----------
    cells : DataFrame
        `cell_means` output.
    statistic : str
        Column to plot.
    """
    from matplotlib import cm

    illums = sorted(cells["illumination"].unique())
    fig = Figure(figsize=(4.2 * len(illums), 3.4), layout="constrained")
    axes = fig.subplots(1, len(illums), sharey=True, squeeze=False)[0]
    gloss = sorted(cells["true_gloss_pct"].unique())
    colours = cm.viridis(np.linspace(0, 0.95, len(gloss)))
    for ax, illum in zip(axes, illums):
        sub = cells[cells["illumination"] == illum]
        for colour, g in zip(colours, gloss):
            line = sub[sub["true_gloss_pct"] == g].sort_values("true_depth_cm")
            ax.plot(line["true_depth_cm"], line[statistic], "o-", ms=3, color=colour,
                    label=f"{g:g} %")
        ax.set_title(illum)
        ax.set_xlabel("true depth (cm)")
    axes[0].set_ylabel(statistic)
    axes[-1].legend(title="gloss", fontsize=7, title_fontsize=8, loc="center left",
                    bbox_to_anchor=(1.0, 0.5))
    return fig


def plot_depth_effects(effects: list) -> Figure:
    """Depth slope (SD per cm, 95 % CI) of each statistic at fixed gloss."""
    fig = Figure(figsize=(5.5, 0.35 * len(effects) + 1.2), layout="constrained")
    ax = fig.subplots()
    y = np.arange(len(effects))[::-1]
    for yi, e in zip(y, effects):
        colour = "C3" if e.p_holm < 0.05 else "0.4"
        ax.errorbar(e.slope_sd_per_cm, yi, xerr=[[e.slope_sd_per_cm - e.ci_low],
                                                 [e.ci_high - e.slope_sd_per_cm]],
                    fmt="o", color=colour, capsize=3)
    ax.axvline(0, color="0.7", lw=1)
    ax.set_yticks(y, [e.statistic for e in effects])
    ax.set_xlabel("depth slope at fixed gloss (SD per cm)")
    return fig


def plot_observer_fit(observed: np.ndarray, predicted: np.ndarray, depth_cm: np.ndarray) -> Figure:
    """Mean perceived gloss of each stimulus cell against the observer model's prediction."""
    fig = Figure(figsize=(4.2, 4.0), layout="constrained")
    ax = fig.subplots()
    sc = ax.scatter(predicted, observed, c=depth_cm, cmap="magma", s=18)
    lo = float(min(observed.min(), predicted.min()))
    hi = float(max(observed.max(), predicted.max()))
    ax.plot([lo, hi], [lo, hi], color="0.6", lw=1)
    ax.set_xlabel("predicted gloss from image statistics (%)")
    ax.set_ylabel("perceived gloss, cell mean (%)")
    fig.colorbar(sc, ax=ax, label="true depth (cm)")
    return fig


def plot_light_fields(means: pd.DataFrame, names: list[str]) -> Figure:
    """Each statistic's mean per light field (``light_field_means``), one panel per statistic,
    light fields on the x axis grouped by kind (indoor blue, outdoor orange)."""
    fig = Figure(figsize=(0.22 * len(means) + 2.5, 1.6 * len(names) + 0.8), layout="constrained")
    axes = fig.subplots(len(names), 1, sharex=True, squeeze=False)[:, 0]
    x = np.arange(len(means))
    colours = np.where(means["kind"] == "indoor", "C0", "C1")
    for ax, name in zip(axes, names):
        ax.scatter(x, means[name], c=colours, s=14)
        ax.set_ylabel(name, fontsize=7)
    axes[-1].set_xticks(x, means["light_field"], rotation=90, fontsize=6)
    return fig
