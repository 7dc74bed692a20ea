"""The source study's figures, from loaded session data (matplotlib, no display needed).

Every function takes the frame of `analysis.load.SessionData` and the design and returns a
``matplotlib.figure.Figure`` built without pyplot (so nothing depends on a GUI backend);
`save_figure` writes it atomically. Group means are means of the observers' means, and 95 %
confidence intervals are across observers (t distribution, n - 1 degrees of freedom).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.colors import hsv_to_rgb
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from scipy import stats

from labfiles import atomic_path
from studydesign import StudyDesign

__all__ = [
    "Metamer",
    "bin_colour",
    "find_metamers",
    "group_means",
    "plot_depth_matches",
    "plot_gloss_contours",
    "plot_gloss_matches",
    "plot_observers",
    "save_figure",
]

BINS = ("low", "medium", "high")
# Hue per depth bin (blue, green, red) and saturation per gloss bin: colour = depth, saturation
# = gloss, as in the source study's figure.
_DEPTH_HUE = {"low": 0.6, "medium": 0.33, "high": 0.0}
_GLOSS_SAT = {"low": 0.3, "medium": 0.6, "high": 1.0}


def bin_colour(depth_bin: str, gloss_bin: str = "high") -> tuple:
    """RGB colour of a depth bin (hue) and gloss bin (saturation)."""
    return tuple(hsv_to_rgb((_DEPTH_HUE[depth_bin], _GLOSS_SAT[gloss_bin], 0.85)))


def group_means(frame: pd.DataFrame, value: str, by: list) -> pd.DataFrame:
    """Mean of the observers' means of ``value`` per cell of ``by``, with a 95 % CI.

    Returns
    -------
    DataFrame
        Columns ``by + [mean, ci, n]``: group mean, half-width of the 95 % CI across observers
        (NaN with one observer) and number of observers.
    """
    per = frame.groupby(["participant", *by], as_index=False)[value].mean()
    g = per.groupby(by)[value]
    out = g.agg(mean="mean", sd="std", n="count").reset_index()
    tq = stats.t.ppf(0.975, np.maximum(out["n"] - 1, 1))
    out["ci"] = np.where(out["n"] > 1, tq * out["sd"] / np.sqrt(out["n"]), np.nan)
    return out.drop(columns="sd")


def plot_depth_matches(frame: pd.DataFrame, design: StudyDesign) -> Figure:
    """(a) Perceived vs true depth; colour = depth bin, saturation = gloss bin; identity line."""
    fig = Figure(figsize=(5.2, 4.6), layout="constrained")
    ax = fig.add_subplot()
    m = group_means(frame, "depth_match_cm", ["true_depth_cm", "depth_bin", "gloss_bin"])
    step = float(np.min(np.diff(design.depth.rendered_cm)))
    offsets = {"low": -0.12 * step, "medium": 0.0, "high": 0.12 * step}
    for gb in BINS:
        for db in BINS:
            cell = m[(m["gloss_bin"] == gb) & (m["depth_bin"] == db)]
            if cell.empty:
                continue
            ax.errorbar(cell["true_depth_cm"] + offsets[gb], cell["mean"], yerr=cell["ci"],
                        fmt="o-", color=bin_colour(db, gb), ms=5, capsize=2, lw=1.2)
    lim = [min(design.depth.physical_cm), max(design.depth.physical_cm)]
    ax.plot(lim, lim, color="0.5", ls="--", lw=1)
    handles = [Line2D([], [], color=bin_colour(db), marker="o", label=f"depth {db}")
               for db in BINS]
    handles += [Line2D([], [], color=bin_colour("medium", gb), marker="o", label=f"gloss {gb}")
                for gb in BINS]
    handles.append(Line2D([], [], color="0.5", ls="--", label="identity"))
    ax.set_xlabel("true depth (cm)")
    ax.set_ylabel("perceived depth (cm)")
    ax.set_title("(a) Depth matches (95 % CI across observers)")
    ax.set_aspect("equal")
    ax.legend(handles=handles, fontsize=7, loc="upper left", ncols=2,
              title="colour = depth bin, saturation = gloss bin", title_fontsize=7)
    return fig


def plot_gloss_matches(frame: pd.DataFrame, design: StudyDesign) -> Figure:
    """(b) Perceived vs true gloss per depth bin, 95 % CIs across observers; identity line."""
    fig = Figure(figsize=(5.2, 4.6), layout="constrained")
    ax = fig.add_subplot()
    m = group_means(frame, "gloss_match_pct", ["true_gloss_pct", "depth_bin"])
    step = float(np.min(np.diff(design.gloss.rendered_pct)))
    for k, db in enumerate(BINS):
        cell = m[m["depth_bin"] == db]
        if cell.empty:
            continue
        x = cell["true_gloss_pct"] + (k - 1) * 0.12 * step
        ax.errorbar(x, cell["mean"], yerr=cell["ci"], fmt="o-", color=bin_colour(db), ms=5,
                    capsize=2, lw=1.2, label=f"depth {db}")
    lim = [min(design.gloss.physical_pct), max(design.gloss.physical_pct)]
    ax.plot(lim, lim, color="0.5", ls="--", lw=1, label="identity")
    ax.set_xlabel("true gloss (%)")
    ax.set_ylabel("perceived gloss (%)")
    ax.set_title("(b) Gloss matches (95 % CI across observers)")
    ax.set_aspect("equal")
    ax.legend(fontsize=8, loc="upper left")
    return fig


@dataclass(frozen=True)
class Metamer:
    """Two stimuli of different gloss and depth that look equally glossy.

    Attributes
    ----------
    gloss_a_pct, depth_a_cm : float
        The less glossy, deeper stimulus.
    gloss_b_pct, depth_b_cm : float
        The glossier, shallower one.
    perceived_a_pct, perceived_b_pct : float
        Mean perceived gloss of each.
    diff_ci : [float, float]
        95 % CI across observers of the difference in perceived gloss (a - b); contains 0.
    """

    gloss_a_pct: float
    depth_a_cm: float
    gloss_b_pct: float
    depth_b_cm: float
    perceived_a_pct: float
    perceived_b_pct: float
    diff_ci: list

    def describe(self) -> str:
        return (f"{self.gloss_a_pct:g} %/{self.depth_a_cm:g} cm vs "
                f"{self.gloss_b_pct:g} %/{self.depth_b_cm:g} cm")

    def to_dict(self) -> dict:
        return asdict(self)


def find_metamers(frame: pd.DataFrame, *, max_pairs: int = 3, tolerance_pct: float = 2.0) -> list:
    """Gloss metamers: stimuli on one equi-gloss contour, found automatically.

    A pair (lower true gloss at a larger depth, higher true gloss at a smaller depth) is a
    metamer when its mean perceived gloss differs by less than ``tolerance_pct`` and the 95 %
    CI across observers of the difference contains 0. Pairs are ranked by their difference in
    true gloss (largest first: the most striking trade of depth for gloss) and chosen so that
    no stimulus appears twice.

    Parameters
    ----------
    frame : DataFrame
        Loaded session data (gloss_match_pct, true_gloss_pct, true_depth_cm, participant).
    max_pairs : int
    tolerance_pct : float
        Largest difference in mean perceived gloss (percentage points).

    Returns
    -------
    list of Metamer
    """
    per = frame.groupby(["participant", "true_gloss_pct", "true_depth_cm"])[
        "gloss_match_pct"].mean().unstack("participant")
    cells = per.index.to_list()
    values = per.to_numpy()
    means = np.nanmean(values, axis=1)
    candidates = []
    for i, (ga, da) in enumerate(cells):
        for j, (gb, db) in enumerate(cells):
            if not (ga < gb and da > db):
                continue
            if abs(means[i] - means[j]) > tolerance_pct:
                continue
            diff = values[i] - values[j]
            diff = diff[np.isfinite(diff)]
            if diff.size < 2:
                continue
            half = stats.t.ppf(0.975, diff.size - 1) * diff.std(ddof=1) / np.sqrt(diff.size)
            lo, hi = diff.mean() - half, diff.mean() + half
            if lo <= 0 <= hi:
                candidates.append((gb - ga, -abs(means[i] - means[j]), i, j, [lo, hi]))
    candidates.sort(key=lambda c: (c[0], c[1]), reverse=True)
    used, out = set(), []
    for _, _, i, j, ci in candidates:
        if i in used or j in used:
            continue
        used.update((i, j))
        out.append(Metamer(float(cells[i][0]), float(cells[i][1]), float(cells[j][0]),
                           float(cells[j][1]), float(means[i]), float(means[j]),
                           [float(ci[0]), float(ci[1])]))
        if len(out) == max_pairs:
            break
    return out


def plot_gloss_contours(frame: pd.DataFrame, design: StudyDesign, metamers=None) -> Figure:
    """(c) Mean perceived gloss over true gloss x true depth, contour lines and metamers."""
    fig = Figure(figsize=(5.6, 5.2), layout="constrained")
    ax = fig.add_subplot()
    grid = frame.groupby(["participant", "true_depth_cm", "true_gloss_pct"])[
        "gloss_match_pct"].mean().groupby(["true_depth_cm", "true_gloss_pct"]).mean().unstack()
    g = grid.columns.to_numpy(float)
    d = grid.index.to_numpy(float)
    z = grid.to_numpy()
    levels = np.arange(0, 101, 10)
    filled = ax.contourf(g, d, z, levels=levels, cmap="viridis", alpha=0.85)
    lines = ax.contour(g, d, z, levels=levels, colors="white", linewidths=0.8)
    ax.clabel(lines, fmt="%d %%", fontsize=7)
    fig.colorbar(filled, ax=ax, label="mean perceived gloss (%)")
    metamers = find_metamers(frame) if metamers is None else metamers
    marks = ("o", "s", "^", "D", "v")
    for k, mm in enumerate(metamers):
        ax.plot([mm.gloss_a_pct, mm.gloss_b_pct], [mm.depth_a_cm, mm.depth_b_cm], "--",
                marker=marks[k % len(marks)], color="orange", mec="black", ms=8, lw=1.5,
                clip_on=False, label=f"{k + 1}: {mm.describe()}")
    ax.set_xlabel("true gloss (%)")
    ax.set_ylabel("true depth (cm)")
    ax.set_title("(c) Equi-gloss contours and gloss metamers")
    if metamers:
        fig.legend(fontsize=7, loc="outside lower center", ncols=2,
                   title="gloss metamers (same perceived gloss)", title_fontsize=7)
    return fig


def plot_observers(frame: pd.DataFrame, design: StudyDesign, *, response: str) -> Figure:
    """(d) One panel per observer: ``response`` "gloss" or "depth" matches vs truth by bin."""
    if response not in ("gloss", "depth"):
        raise ValueError(f"response must be 'gloss' or 'depth'; got {response!r}")
    value, truth = {"gloss": ("gloss_match_pct", "true_gloss_pct"),
                    "depth": ("depth_match_cm", "true_depth_cm")}[response]
    lim = ([min(design.gloss.physical_pct), max(design.gloss.physical_pct)] if response == "gloss"
           else [min(design.depth.physical_cm), max(design.depth.physical_cm)])
    unit = "%" if response == "gloss" else "cm"
    people = sorted(frame["participant"].unique())
    ncol = min(4, len(people))
    nrow = int(np.ceil(len(people) / ncol))
    fig = Figure(figsize=(2.6 * ncol, 2.5 * nrow + 0.4), layout="constrained")
    axes = fig.subplots(nrow, ncol, squeeze=False, sharex=True, sharey=True)
    for ax, who in zip(axes.flat, people):
        sub = frame[frame["participant"] == who]
        m = sub.groupby([truth, "depth_bin"], as_index=False)[value].mean()
        for db in BINS:
            cell = m[m["depth_bin"] == db]
            ax.plot(cell[truth], cell[value], "o-", color=bin_colour(db), ms=3, lw=1,
                    label=f"depth {db}")
        ax.plot(lim, lim, color="0.5", ls="--", lw=0.8)
        ax.set_title(who, fontsize=9)
    for ax in axes.flat[len(people):]:
        ax.set_visible(False)
    for col in range(ncol):
        # The lowest panel in use of each column carries the x axis.
        last = axes[(len(people) - 1 - col) // ncol, col]
        last.xaxis.set_tick_params(labelbottom=True)
        last.set_xlabel(f"true {response} ({unit})", fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel(f"perceived ({unit})", fontsize=8)
    axes.flat[0].legend(fontsize=6, loc="upper left")
    fig.suptitle(f"(d) {response.capitalize()} matches per observer (mean over illuminations)")
    return fig


def save_figure(fig: Figure, path, *, dpi: int = 110) -> Path:
    """Write a figure as PNG atomically, with the umask's permissions (``labfiles``)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    return path
