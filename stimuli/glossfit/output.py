"""Writing a gloss fit's output folder (read by the sim-to-real diagnosis, analysis.gap).

    OUT_DIR/gloss_table.csv          stimuli.glosstable format (+ rho_d_fit, rho_s_fit)
    OUT_DIR/fits.csv                 one row per gloss level (FITS_COLUMNS), appended as fitted
    OUT_DIR/residuals/gloss_XXX.npz  photo, render, residual, diffuse, specular (float32, h x w x 3,
                                     linear, photo units), masks highlight, body, rim, background,
                                     sphere, valid (bool, h x w)
    OUT_DIR/figures/gloss_XXX.png    photo | render | residual
    OUT_DIR/fit.json                 settings, setup, summary, warnings, renders, time, and per level
                                     the registration (incl. sse, background ratio and mismatch),
                                     the objective at the optimum, r and the iterations
    OUT_DIR/report.html              short summary with the figures
"""

from __future__ import annotations

import csv
import html
import json
import os
from pathlib import Path

import numpy as np

from labfiles import atomic_path

__all__ = ["FITS_COLUMNS", "append_fit_row", "write_json", "write_level_figure",
           "write_report", "write_residuals"]

FITS_COLUMNS = ["gloss_pct", "method", "rho_d", "rho_s", "alpha", "reg_sx", "reg_sy",
                "reg_dx_px", "reg_dy_px", "reg_flag", "clipped_fraction", "rmse",
                "rmse_highlight", "rmse_body", "rmse_rim", "rmse_background", "n_renders",
                "warnings"]


def append_fit_row(path: Path, row: dict) -> None:
    """Append one level's row to fits.csv (header first if new), flushed and fsynced."""
    new = not path.exists()
    with open(path, "a", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=FITS_COLUMNS, extrasaction="raise")
        if new:
            writer.writeheader()
        writer.writerow({k: ("" if isinstance(v, float) and not np.isfinite(v) else v)
                         for k, v in row.items()})
        fh.flush()
        os.fsync(fh.fileno())


def _atomic(path: Path, write) -> None:
    with atomic_path(path) as tmp:  # a temporary file, fsync, os.replace
        write(tmp)


def write_residuals(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Save a level's residual arrays as .npz, atomically."""

    def write(tmp):
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)
            fh.flush()
            os.fsync(fh.fileno())

    _atomic(path, write)


def write_json(path: Path, data: dict) -> None:
    _atomic(path, lambda tmp: tmp.write_text(json.dumps(data, indent=2, default=float)))


def _display(rgb: np.ndarray, white: float) -> np.ndarray:
    """Linear RGB to sRGB-ish display values in [0, 1] (white = the given level)."""
    return np.clip(np.clip(rgb / white, 0, None) ** (1 / 2.2), 0, 1)


def write_level_figure(path: Path, photo: np.ndarray, render: np.ndarray, residual: np.ndarray,
                       sphere: np.ndarray, title: str) -> None:
    """photo | render | residual (luminance, diverging colours, symmetric range) as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stimuli.glossfit.scene import luminance

    lum = luminance(photo)
    white = float(np.quantile(lum[sphere], 0.99)) if sphere.any() else float(lum.max())
    res = luminance(residual)
    lim = float(np.quantile(np.abs(res[sphere]), 0.99)) if sphere.any() else 1.0
    fig, axes = plt.subplots(1, 3, figsize=(9, 3.3))
    axes[0].imshow(_display(photo, white))
    axes[0].set_title("photo (registered)")
    axes[1].imshow(_display(render, white))
    axes[1].set_title("best render")
    im = axes[2].imshow(res, cmap="RdBu_r", vmin=-lim, vmax=lim)
    axes[2].set_title("photo - render (luminance)")
    fig.colorbar(im, ax=axes[2], fraction=0.046)
    for ax in axes:
        ax.set_axis_off()
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    _atomic(path, lambda tmp: fig.savefig(tmp, dpi=90, format="png"))
    plt.close(fig)


def write_report(path: Path, info: dict, rows: list[dict], table_rows: list[dict]) -> None:
    """A short HTML report: settings, warnings, the gloss table and each level's figure."""
    esc = html.escape
    parts = ["<!doctype html><meta charset='utf-8'><title>gloss fit</title>",
             ("<style>body{font-family:sans-serif;max-width:60em}td,th{padding:2px 8px;"
              "text-align:right}</style>"),
             f"<h1>Gloss fit: {esc(str(info['photo_set']))}</h1>",
             (f"<p>Method <b>{esc(info['settings']['method'])}</b>, "
              f"{info['n_renders']} renders, {info['wall_s']:.1f} s wall time; fit renders "
              f"{info['resolution_px']} px, {info['spp']} spp, seed {info['seed']}.</p>")]
    if info["warnings"]:
        parts.append("<h2>Warnings</h2><ul>"
                     + "".join(f"<li>{esc(w)}</li>" for w in info["warnings"]) + "</ul>")
    if table_rows:
        cols = ["gloss_pct", "rho_d", "rho_s", "alpha", "fit_error", "loo_error"]
        parts.append("<h2>Gloss table</h2><table><tr>"
                     + "".join(f"<th>{c}</th>" for c in cols) + "</tr>")
        for r in table_rows:
            parts.append("<tr>" + "".join(f"<td>{r[c]:.4g}</td>" for c in cols) + "</tr>")
        parts.append("</table>")
        s = info.get("summary", {})
        if s:
            parts.append(f"<p>Common albedo rho_d = {s['common_rho_d']:.4g}; rho_s = "
                         f"{s['rho_s_intercept']:.4g} + {s['rho_s_slope_per_pct']:.4g} x gloss %, "
                         f"leave-one-out RMSE {s['rho_s_loo_rmse']:.3g}.</p>")
    parts.append("<h2>Levels</h2><p>RMSE relative to the photo's mean luminance on the sphere.</p>")
    for r in rows:
        name = f"gloss_{round(r['gloss_pct']):03d}"
        parts.append(f"<h3>{r['gloss_pct']:g} %</h3><p>rho_d {r['rho_d']:.4g}, rho_s "
                     f"{r['rho_s']:.4g}, alpha {r['alpha']:.4g}; RMSE {r['rmse']:.3g} (highlight "
                     f"{r['rmse_highlight']:.3g}, body {r['rmse_body']:.3g}, rim "
                     f"{r['rmse_rim']:.3g}, background {r['rmse_background']:.3g})"
                     + (f"; <b>{esc(r['warnings'])}</b>" if r["warnings"] else "") + "</p>")
        if (path.parent / "figures" / f"{name}.png").exists():
            parts.append(f"<img src='figures/{name}.png' width='600'>")
    _atomic(path, lambda tmp: tmp.write_text("\n".join(parts)))
