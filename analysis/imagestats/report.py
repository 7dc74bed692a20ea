"""The HTML report of ``python -m analysis imagestats relate``."""

from __future__ import annotations

import html
import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.figures import save_figure
from analysis.imagestats.figures import (
    plot_depth_effects,
    plot_light_fields,
    plot_observer_fit,
    plot_stat_grid,
)
from analysis.imagestats.lightfields import (
    light_field_effects,
    light_field_means,
    light_field_spread,
)
from analysis.imagestats.observer import ImageStatsObserver
from analysis.imagestats.relate import (
    CELL,
    cell_means,
    depth_effects,
    gloss_regression,
    join_perception,
    stat_table,
)
from analysis.imagestats.store import load_stats
from analysis.load import load_sessions
from analysis.report import ReportExistsError
from labfiles import atomic_open, atomic_write_text
from studydesign import StudyDesign

__all__ = ["ReportExistsError", "build_relate_report"]


def _write_csv(frame: pd.DataFrame, path: Path) -> None:
    with atomic_open(path, "w", newline="", encoding="utf-8") as fh:
        frame.to_csv(fh, index=False)


def _table(frame: pd.DataFrame) -> str:
    return frame.to_html(index=False, float_format=lambda v: f"{v:.3g}", border=0)


def _light_field_section(frame: pd.DataFrame, names: list[str], out: Path,
                         results: dict) -> str:
    """The statistics across the light fields, and how they follow gloss and depth within
    and across them (analysis.imagestats.lightfields); tables also as CSV."""
    means = light_field_means(frame, names)
    effects = light_field_effects(frame, names)
    spread = light_field_spread(frame, names)
    _write_csv(means, out / "light_field_means.csv")
    _write_csv(effects, out / "light_field_effects.csv")
    _write_csv(spread, out / "light_field_spread.csv")
    save_figure(plot_light_fields(means, names), out / "light_fields.png")
    results["light_fields"] = {"means": means.to_dict("records"),
                               "effects": effects.to_dict("records"),
                               "spread": spread.to_dict("records")}
    kinds = means.groupby("kind").size().to_dict()
    return ("<h2>Across the light fields</h2>"
            f"<p>{len(means)} light fields ({', '.join(f'{v} {k}' for k, v in kinds.items())}). "
            "Mean of each statistic per light field:</p>" + _table(means)
            + '<img src="light_fields.png">'
            "<h3>How each statistic follows gloss and depth within and across light fields</h3>"
            "<p>Standardised statistic (SD units) regressed on true gloss (per 10 %) and true "
            "depth (per cm): <i>within light fields</i> with a fixed effect per light field "
            "(from differences between images of one light field), and over the light fields "
            "of each kind; HC3 95 % CIs.</p>" + _table(effects)
            + "<p>Share of each statistic's variance between light fields, and indoor minus "
            "outdoor (mean over light fields, SD units; Welch's t over the light fields' "
            "means):</p>" + _table(spread))


def _perception_sections(frame, names, stats, data_dir, design, out, results, *, n_boot, seed
                         ) -> list[str]:
    """The perception analyses of the report: perceived gloss regressed on the statistics
    (participant bootstrap) and the image-statistics observer (``observer.json``,
    ``observer_fit.png``); adds their figures to ``results``. Returns the HTML sections."""
    parts: list[str] = []
    trials = load_sessions(data_dir, design).frame
    joined, how, missing = join_perception(frame, names, trials)
    if missing:
        covered = ~pd.MultiIndex.from_frame(trials[list(CELL)]).isin(missing)
        trials = trials[covered]
    rng = np.random.default_rng(seed)
    reg = gloss_regression(joined, names, n_boot=n_boot, rng=rng)
    observer = ImageStatsObserver.fit(stats, trials)
    atomic_write_text(out / "observer.json", observer.to_json())
    obs_cells = trials.groupby(list(CELL), as_index=False)[
        ["gloss_match_pct", "true_depth_cm"]].mean()
    pred = pd.DataFrame({"pred": observer.predict_trials(trials, stats)},
                        index=trials.index).join(trials[list(CELL)])
    pred = pred.groupby(list(CELL), as_index=False)["pred"].mean()
    obs_cells = obs_cells.merge(pred, on=list(CELL))
    save_figure(plot_observer_fit(obs_cells["gloss_match_pct"].to_numpy(),
                                  obs_cells["pred"].to_numpy(),
                                  obs_cells["true_depth_cm"].to_numpy()),
                out / "observer_fit.png")
    if missing:
        parts.append(f"<p><b>Note:</b> {len(missing)} stimulus cells the sessions show have "
                     f"no image in the table and are left out, e.g. {missing[:5]}.</p>")
    results.update({"sessions": str(Path(data_dir).resolve()), "joined_by": how,
                    "cells_without_images": [list(c) for c in missing],
                    "gloss_regression": reg, "observer": json.loads(observer.to_json())})
    rows = [{"statistic": r["statistic"],
             **{f"{k} {part}": r[k][part] for k in ("coef", "r2", "depth_share")
                for part in ("estimate", "ci_low", "ci_high")}}
            for r in reg["per_statistic"]]
    rows.append({"statistic": "all together",
                 **{f"{k} {part}": reg["all"][k][part] for k in ("r2", "depth_share")
                    for part in ("estimate", "ci_low", "ci_high")}})
    de, r2a, r2g = reg["depth_effect"], reg["r2_A"], reg["r2_gloss_only"]
    parts.append(
        "<h2>Perceived gloss regressed on the statistics</h2>"
        f"<p>{reg['n_rows']} participant x cell means, {reg['n_participants']} participants, "
        f"trials matched to images by {how}. The observers' depth effect (gloss ~ true gloss "
        f"+ true depth): {de['estimate']:.2f} % per cm [{de['ci_low']:.2f}, "
        f"{de['ci_high']:.2f}], R² {r2a['estimate']:.3f} (true gloss alone: "
        f"{r2g['estimate']:.3f}). Below, each statistic replaces depth (gloss ~ true gloss + "
        "statistic): its coefficient (% per SD), R², and the share of the depth effect the "
        "model reproduces (1 = all). 95 % CIs from "
        f"{reg['n_boot']} participant-bootstrap resamples (seed {seed}). On cell means any "
        "statistic that changes monotonically with depth can stand in for depth; the "
        "observer model below must carry gloss as well.</p>" + _table(pd.DataFrame(rows)))
    parts.append(
        "<h2>Image-statistics observer</h2>"
        f"<p>Ridge regression of the cell-mean perceived gloss on {list(observer.features)} "
        f"(penalty {observer.penalty:g} by leave-one-out CV): R² = {observer.r2:.3f}, "
        f"leave-one-out R² = {observer.loo_r2:.3f} over {observer.n_cells} cells. "
        "Saved as observer.json (<code>ImageStatsObserver.from_json</code>).</p>"
        '<img src="observer_fit.png">')
    return parts


def build_relate_report(stats_path, out, design: StudyDesign, *, data_dir=None,
                        n_boot: int = 1000, seed: int = 0,
                        n_ps_components: int = 3) -> Path:
    """Relate image statistics to depth and perceived gloss; write ``out/index.html``.

    Parameters
    ----------
    stats_path : path-like
        A table from `compute_stats`.
    out : path-like
        Report folder; must not hold an ``index.html``.
    design : StudyDesign
        Validates the sessions.
    data_dir : path-like, optional
        Data folder with ``sessions/``; without it the report has no perception analyses.
    n_boot : int
        Participant-bootstrap resamples for the regression CIs.
    seed : int
        Seed of the bootstrap (recorded in results.json).
    n_ps_components : int
        PS principal components analysed beside the pixel statistics.

    Returns
    -------
    Path
        ``out/index.html``.

    Raises
    ------
    ReportExistsError
        If ``out/index.html`` exists.
    ImageStatsError, SessionDataError
        Bad statistics table or session data.
    """
    out = Path(out)
    if (out / "index.html").exists():
        raise ReportExistsError(f"{out / 'index.html'} exists; choose a new --out")
    stats = load_stats(stats_path)
    frame, names = stat_table(stats, n_ps_components=n_ps_components)
    effects, per_cell = depth_effects(frame, names)
    cells = cell_means(frame, names)
    out.mkdir(parents=True, exist_ok=True)
    results: dict = {"stats": str(Path(stats_path).resolve()), "n_images": len(stats),
                     "options": stats.attrs["imagestats"], "statistics": names,
                     "depth_effects": [asdict(e) for e in effects], "seed": seed}
    parts = [(f"<h1>Image statistics and perceived gloss</h1><p>{len(stats)} images from "
             f"{html.escape(str(stats_path))}; statistics on the array square of the EXR "
             "luminance (protocol.md, Image statistics).</p>")]
    eff = pd.DataFrame([asdict(e) for e in effects])
    parts.append("<h2>Which statistics change with depth at fixed gloss</h2>"
                 "<p>OLS of each standardised statistic on true depth with fixed effects for "
                 "each illumination x gloss cell; HC3 95 % CIs; Holm-adjusted p over the "
                 "statistics. Red: p_holm &lt; 0.05.</p>" + _table(eff))
    save_figure(plot_depth_effects(effects), out / "depth_effects.png")
    parts.append('<img src="depth_effects.png">')
    _write_csv(eff, out / "depth_effects.csv")
    _write_csv(per_cell, out / "depth_slopes_per_cell.csv")
    _write_csv(cells, out / "cell_means.csv")
    if "light_field" in frame.columns and frame["light_field"].nunique() >= 2:
        parts.append(_light_field_section(frame, names, out, results))
    parts.append("<h2>Each statistic over the gloss x depth grid</h2>"
                 "<p>Mean over the images of each cell (light fields, arrays).</p>")
    for name in names:
        save_figure(plot_stat_grid(cells, name), out / f"grid_{name}.png")
        parts.append(f'<h3>{name}</h3><img src="grid_{name}.png">')
    if data_dir is not None:
        parts += _perception_sections(frame, names, stats, data_dir, design, out, results,
                                      n_boot=n_boot, seed=seed)
    else:
        parts.append("<p>No session data given (--sessions): perception analyses left out.</p>")
    atomic_write_text(out / "results.json", json.dumps(results, indent=1, default=float))
    page = ("<!doctype html><html><head><meta charset='utf-8'><title>Image statistics</title>"
            "<style>body{font-family:sans-serif;max-width:70em;margin:auto}"
            "table{border-collapse:collapse;font-size:90%}td,th{padding:2px 8px}"
            "img{max-width:100%}</style></head><body>" + "\n".join(parts) + "</body></html>")
    atomic_write_text(out / "index.html", page)
    return out / "index.html"
