"""HTML report of a diagnosis: localisation figure, ranked candidates, before/after, verdict."""

from __future__ import annotations

import html
import json
import os
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from analysis.gap.engine import Diagnosis, GapError

__all__ = ["no_significant_gap", "verdict_text", "write_multi_report", "write_report"]


def no_significant_gap(d: Diagnosis) -> bool:
    """True when nothing was attributed and the held-out gap's 95 % CI reaches 0."""
    return not d.steps and bool(d.gap_before_ci) and d.gap_before_ci[0] <= 0


def verdict_text(d: Diagnosis) -> str:
    """Plain-language verdict (HTML)."""
    if no_significant_gap(d):
        lo, hi = d.gap_before_ci
        return (f"The simulation matches the data: the held-out gap ({d.gap_before:.3f} nats per "
                f"unit, 95 % CI {lo:.3f} to {hi:.3f}) is not significantly above the data's own "
                "noise floor, so there is <b>no significant gap</b> to explain.")
    if not d.steps:
        least = (f" by at least {d.min_gain:g} nats per unit" if d.min_gain > 0 else "")
        return ("No candidate in the catalogue reduces the held-out gap significantly "
                f"(Holm-corrected, alpha 0.05){least}: the gap is <b>unexplained</b> by the "
                "catalogue.")
    if d.verdict == "unexplained":
        names = " + ".join(s["added"] for s in d.steps)
        return (f"{html.escape(names)} reduce(s) the held-out gap significantly but remove(s) "
                f"only {100 * d.explained_share:.0f} % of it (an attribution needs "
                f"{100 * d.min_share:.0f} %): the gap is <b>unexplained</b> by the catalogue; "
                "something outside it dominates.")
    text = (f"The gap is best explained by <b>{html.escape(d.verdict)}</b>; adding it shrinks "
            f"the held-out gap by {d.shrink_abs:.3f} nats per held-out unit "
            f"({d.shrink_pct:.0f} %, 95 % CI {d.shrink_pct_ci[0]:.0f} to "
            f"{d.shrink_pct_ci[1]:.0f} %).")
    if d.gap_after < 0 or d.gap_before <= 0:
        text += (" The loss fell below the simulation's own noise floor: the effect changes the "
                 "data's own spread (e.g. rounding, lapses), so the % is not meaningful here; the "
                 "absolute shrinkage is the measure.")
    return text


def _errorbars(ax, sub, labels):
    x = range(len(sub))
    ax.errorbar(x, sub["mean_residual"], yerr=[sub["mean_residual"] - sub["ci_low"],
                sub["ci_high"] - sub["mean_residual"]], fmt="o")
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
    fig.savefig(path, dpi=100)
    plt.close(fig)


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
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _plot_maps(maps: dict, path) -> None:
    """Per gloss level: the photo, and the residual in noise SDs before and after the chosen
    extensions (the same colour scale, +-5 SD)."""
    names = list(maps)
    fig, axes = plt.subplots(len(names), 3, figsize=(7.5, 2.5 * len(names)), squeeze=False)
    for row, name in zip(axes, names):
        m = maps[name]
        row[0].imshow(m["photo"], cmap="gray")
        row[0].set_ylabel(name)
        for ax, key in zip(row[1:], ("before", "after")):
            im = ax.imshow(m[key], cmap="RdBu_r", vmin=-5, vmax=5)
        for ax, title in zip(row, ("photo", "residual, plain render", "residual, extended")):
            ax.set_title(title, fontsize=8)
            ax.set_xticks([])
            ax.set_yticks([])
    fig.colorbar(im, ax=axes.ravel().tolist(), shrink=0.6, label="(photo - render) / noise SD")
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _figures(local, folder: Path) -> str:
    """Write the layer's figures into ``folder``; returns the extra HTML for the maps."""
    if "axis" in local.columns:
        _plot_generic(local, folder / "localisation.png")
    else:
        _plot_observer(local, folder / "localisation.png")
    if local.attrs.get("maps"):
        _plot_maps(local.attrs["maps"], folder / "residual_maps.png")
        return "residual_maps.png"
    return ""


def diagnosis_html(diag: Diagnosis, figure: str | None = "localisation.png",
                   maps: str = "") -> str:
    """The body of one layer's report section."""
    rows = "".join(
        f"<tr><td>{html.escape(s['name'])}</td><td>{s['gain']:.4f}</td>"
        f"<td>[{s['ci_low']:.4f}, {s['ci_high']:.4f}]</td><td>{s['p_holm']:.4f}</td>"
        f"<td>{'yes' if s['significant'] else 'no'}</td></tr>" for s in diag.ranking)
    steps = "".join(f"<li>+ {html.escape(s['added'])}: held-out gain {s['gain']:.4f} "
                    f"(p={s['p']:.4f}), parameters {html.escape(json.dumps(s['params']))}</li>"
                    for s in diag.steps) or "<li>none</li>"
    img = f'<h3>Where</h3><img src="{figure}" alt="localisation">' if figure else ""
    maps_html = (f'<h3>Residual maps (noise SDs; before and after the chosen extensions)</h3>'
                 f'<img src="{maps}" alt="residual maps">' if maps else "")
    min_gain = (f" and its gain is at least {diag.min_gain:g} nats per unit"
                if diag.min_gain > 0 else "")
    return f"""<p>{verdict_text(diag)}</p>
<h3>Before / after (held-out mean NLL above the simulation's noise floor, nats per unit)</h3>
<p>before {diag.gap_before:.4f}; after {diag.gap_after:.4f}; shrink {diag.shrink_abs:.4f}
(95 % CI {diag.shrink_abs_ci[0]:.4f} to {diag.shrink_abs_ci[1]:.4f}),
{diag.shrink_pct:.1f} % (95 % CI {diag.shrink_pct_ci[0]:.1f} to {diag.shrink_pct_ci[1]:.1f} %)</p>
<h3>Ranked candidates (held-out gain, bootstrap 95 % CI, Holm-adjusted one-sided p)</h3>
<p>A candidate counts when its Holm p is below 0.05{min_gain}.</p>
<table border="1"><tr><th>candidate</th><th>gain</th><th>CI</th><th>p (Holm)</th>
<th>counts</th></tr>{rows}</table>
<h3>Greedy combination</h3><ol>{steps}</ol>{img}{maps_html}"""


def _atomic_page(out: Path, page: str) -> Path:
    fd, tmp = tempfile.mkstemp(dir=out, suffix=".html")
    with os.fdopen(fd, "w") as fh:
        fh.write(page)
        fh.flush()
        os.fsync(fh.fileno())
    os.link(tmp, out / "index.html")  # never replaces an existing report
    os.unlink(tmp)
    return out / "index.html"


def _check_new(out: Path) -> None:
    if (out / "index.html").exists():
        raise GapError(f"report {out / 'index.html'} exists; pass a new --out folder")
    out.mkdir(parents=True, exist_ok=True)


def write_report(diag: Diagnosis, local, out_dir: str | Path) -> Path:
    """Write ``out_dir/index.html`` (+ figure, JSON, localisation CSV). Refuses an existing
    report."""
    out = Path(out_dir)
    _check_new(out)
    maps = _figures(local, out)
    page = f"""<!doctype html><html><head><meta charset="utf-8">
<title>Sim-to-real gap: {html.escape(diag.layer)}</title></head><body>
<h1>Sim-to-real gap, {html.escape(diag.layer)} layer</h1>
{diagnosis_html(diag, maps=maps)}
<p>seed {diag.seed}</p></body></html>"""
    (out / "diagnosis.json").write_text(json.dumps(diag.to_dict(), indent=1))
    local.to_csv(out / "localisation.csv", index=False)
    return _atomic_page(out, page)


def write_multi_report(results: dict, which: dict, out_dir: str | Path) -> Path:
    """``out_dir/index.html`` with the carrying layer and each layer's section (figures in
    ``out_dir/<layer>/``)."""
    out = Path(out_dir)
    _check_new(out)
    sections = []
    for name, (diag, local) in results.items():
        sub = out / name
        sub.mkdir(exist_ok=True)
        maps = _figures(local, sub)
        (sub / "diagnosis.json").write_text(json.dumps(diag.to_dict(), indent=1))
        local.to_csv(sub / "localisation.csv", index=False)
        sections.append(f"<h2>{html.escape(name)} layer</h2>"
                        + diagnosis_html(diag, f"{name}/localisation.png",
                                         f"{name}/{maps}" if maps else ""))
    rows = "".join(f"<tr><td>{html.escape(n)}</td><td>{g[0]:.4f}</td><td>[{g[1]:.4f}, "
                   f"{g[2]:.4f}]</td></tr>" for n, g in which["gaps"].items())
    page = f"""<!doctype html><html><head><meta charset="utf-8">
<title>Sim-to-real gap: all layers</title></head><body>
<h1>Sim-to-real gap, all layers</h1>
<p><b>{html.escape(which["text"])}</b></p>
<table border="1"><tr><th>layer</th><th>held-out gap (nats per unit)</th><th>95 % CI</th></tr>
{rows}</table>
{"".join(sections)}</body></html>"""
    return _atomic_page(out, page)
