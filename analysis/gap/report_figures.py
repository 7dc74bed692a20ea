"""The report's figures (matplotlib, written as PNG beside the page): the localisation
(mean residual per cell with its 95 % CI) and, in the render layer, the residual maps.

Each figure is saved cropped to what it draws (``bbox_inches="tight"``) and sized from its
content -- the maps' rows from the photos' aspect ratio -- so the page shows no empty band
(the maps once took 2.5 inches a row and a fixed share of the figure as margin, a screen of
white above and below the rows for 11 gloss levels or for landscape photos).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from labfiles import atomic_open

__all__ = ["write_figures"]

#: Width of one residual-map panel, inches (three panels a row).
_PANEL_IN = 2.0
#: Height a panel's title takes, inches.
_TITLE_IN = 0.3


def _save(fig, path, dpi: int) -> None:
    """Write ``fig`` as a PNG at ``path`` atomically (a stopped run leaves no torn image)."""
    with atomic_open(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=dpi, bbox_inches="tight", pad_inches=0.05)
    plt.close(fig)


def _errorbars(ax, sub, labels):
    """Each cell's mean with its CI as error bars. A CI that does not contain its mean is
    drawn from the mean to its far end only: a cell of one resampled block has a CI of one
    value that differs from the pixels' mean in the last bits (a negative bar matplotlib
    refuses, issue 40 item 4), and a percentile bootstrap of a ratio can exclude its own
    point estimate. The CSV keeps the CI as computed."""
    x = range(len(sub))
    mean = sub["mean_residual"].to_numpy(float)
    below = np.fmax(mean - sub["ci_low"].to_numpy(float), 0.0)
    above = np.fmax(sub["ci_high"].to_numpy(float) - mean, 0.0)
    ax.errorbar(x, mean, yerr=[below, above], fmt="o")
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xticks(list(x))
    ax.set_xticklabels(labels, rotation=90, fontsize=6)


def _plot_observer(local, path) -> None:
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for ax, resp in zip(axes, ("gloss", "depth")):
        sub = local[local["response"] == resp].reset_index(drop=True)
        _errorbars(ax, sub, [f"{g}/{d}/{i}" for g, d, i in
                             zip(sub["gloss_bin"], sub["depth_bin"], sub["illumination"])])
        ax.set_title(f"{resp} response - truth (slider units), 95 % CI")
        ax.set_xlabel("gloss bin / depth bin / illumination")
    fig.tight_layout()
    _save(fig, path, 100)


def _plot_generic(local, path) -> None:
    """One panel per localisation axis: mean residual per cell with its 95 % CI."""
    names = list(dict.fromkeys(local["axis"]))
    fig, axes = plt.subplots(1, len(names), figsize=(5.5 * len(names), 4), squeeze=False)
    for ax, name in zip(axes[0], names):
        sub = local[local["axis"] == name].reset_index(drop=True)
        _errorbars(ax, sub, list(sub["cell"]))
        ax.set_xlabel(name)
        ax.set_ylabel(f"residual, 95 % CI\n({sub['unit'].iloc[0]})")
    fig.tight_layout()
    _save(fig, path, 100)


def _plot_maps(maps: dict, path) -> None:
    """Per gloss level (or held-out light): the photo, the prediction with the chosen
    extensions (where the maps hold one; the photo's grey scale), and the residual in noise
    SDs before and after the chosen extensions (the same colour scale, +-5 SD). A row is as
    tall as the photo's aspect ratio makes a panel, plus its title."""
    names = list(maps)
    h, w = np.shape(maps[names[0]]["photo"])[:2]
    pred = "prediction" in maps[names[0]]
    cols = 4 if pred else 3
    row_in = _PANEL_IN * h / max(w, 1) + _TITLE_IN
    fig, axes = plt.subplots(len(names), cols,
                             figsize=(cols * _PANEL_IN + 1.2, row_in * len(names)),
                             squeeze=False, layout="constrained")
    titles = (("photo", "prediction, extended") if pred else ("photo",)) + (
        "residual, plain render", "residual, extended")
    for row, name in zip(axes, names):
        m = maps[name]
        top = float(np.nanpercentile(m["photo"], 99.5)) if np.isfinite(m["photo"]).any() else 1.0
        row[0].imshow(m["photo"], cmap="gray", vmin=0, vmax=top)
        row[0].set_ylabel(name)
        if pred:
            row[1].imshow(m["prediction"], cmap="gray", vmin=0, vmax=top)
        for ax, key in zip(row[cols - 2:], ("before", "after")):
            im = ax.imshow(m[key], cmap="RdBu_r", vmin=-5, vmax=5)
        for ax, title in zip(row, titles):
            ax.set_title(title, fontsize=8)
            ax.set_xticks([])
            ax.set_yticks([])
    # The colour bar at most about 3 inches tall, whatever the number of levels.
    shrink = min(0.8, 3.0 / (row_in * len(names)))
    fig.colorbar(im, ax=axes, shrink=shrink, label="(photo - render) / noise SD")
    _save(fig, path, 90)


def write_figures(local, folder: Path) -> tuple[dict, list[str]]:
    """Write the layer's figures into ``folder``: ``localisation.png`` (cells of an ``axis``
    column, or the observer's gloss / depth bins) and, where ``local.attrs["maps"]`` holds
    residual maps, ``residual_maps.png``.

    A figure that fails to draw is not written and costs nothing else: the report is written
    without it (the diagnosis's JSON before any figure), and the failure is said.

    Returns
    -------
    (dict, list of str)
        ``{"localisation": file name or "", "maps": file name or ""}`` of the figures
        written, and one line per figure that failed (its file, the error).
    """
    plot = _plot_generic if "axis" in local.columns else _plot_observer
    jobs = [("localisation", "localisation.png", lambda path: plot(local, path))]
    if local.attrs.get("maps"):
        jobs.append(("maps", "residual_maps.png",
                     lambda path: _plot_maps(local.attrs["maps"], path)))
    written, failed = {"localisation": "", "maps": ""}, []
    for key, name, draw in jobs:
        try:
            draw(folder / name)
        except Exception as exc:  # noqa: BLE001 - any figure's failure: said, never fatal
            plt.close("all")
            failed.append(f"figure {folder / name} not drawn ({type(exc).__name__}: {exc}); "
                          "the diagnosis and its numbers are written without it")
        else:
            written[key] = name
    return written, failed
