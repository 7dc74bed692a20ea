"""HTML report of a diagnosis: localisation figure, ranked candidates, before/after, verdict."""

from __future__ import annotations

import html
import json
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from analysis.gap.engine import Diagnosis, GapError, _size_words
from labfiles import atomic_open, atomic_write_text, write_new_file

__all__ = ["no_significant_gap", "verdict_text", "write_multi_report", "write_report"]


def no_significant_gap(d: Diagnosis) -> bool:
    """True when nothing was attributed, the floor is sound, and either (with a ceiling) the
    simulation falls short of the ceiling by nothing significant, or (without) the held-out
    gap's 95 % CI reaches the layer's tolerance (``min_gain``, 0 if none)."""
    if d.steps or d.floor_status != "ok":
        return False
    if d.remaining is not None:  # with a ceiling: the simulation does as well as it
        return not d.remaining.get("significant")
    return bool(d.gap_before_ci) and d.gap_before_ci[0] <= max(d.min_gain, 0.0)


def verdict_text(d: Diagnosis) -> str:
    """Plain-language verdict (HTML): the diagnosis's summary, the remaining gap, warnings."""
    text = html.escape(d.summary or d.verdict)
    if d.steps and d.verdict != "unexplained":
        text = text.replace(html.escape(d.steps[0]["added"].replace("_", " ")),
                            f"<b>{html.escape(d.steps[0]['added'].replace('_', ' '))}</b>", 1)
    if d.split:
        text += f" <i>Held out: {html.escape(d.split)}.</i>"
    rem = d.remaining
    if rem:
        text += (f"<br>Chosen model vs a flexible model of the data (ceiling): "
                 f"{rem['gap']:.3f} nats per unit above it (95 % CI {rem['ci'][0]:.3f} to "
                 f"{rem['ci'][1]:.3f}, one-sided p {rem['p']:.4f}); the catalogue explains "
                 f"{_pct(d.explained_share)} of the gap, the ceiling {_pct(d.ceiling_share)}.")
        if "size" in rem:
            state = ("a gap beyond the catalogue" if rem["significant"] else
                     "significant in nats but within the tolerance: not counted as a gap "
                     "beyond the catalogue" if rem.get("within_tolerance") else
                     "not significant")
            side = "below" if rem["size"] < rem["tolerance"] else "at or above"
            text += html.escape(f" What remains: {_size_words(rem, side)}; {state}.")
    for w in d.warnings:
        text += f"<br><b>Warning:</b> {html.escape(w)}"
    return text


def _pct(x: float) -> str:
    return f"{100 * x:.0f} %" if math.isfinite(x) else "n/a"


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
    try:
        return write_new_file(out / "index.html", page)  # never replaces an existing report
    except FileExistsError as exc:
        raise GapError(f"report {out / 'index.html'} exists; pass a new --out folder") from exc


def _write_parts(folder: Path, diag: Diagnosis, local) -> None:
    atomic_write_text(folder / "diagnosis.json", json.dumps(diag.to_dict(), indent=1))
    with atomic_open(folder / "localisation.csv", "w", newline="") as fh:
        local.to_csv(fh, index=False)


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
    _write_parts(out, diag, local)
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
        _write_parts(sub, diag, local)
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
