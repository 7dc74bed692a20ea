"""HTML report of a diagnosis: the verdict once at the top beside its lead figure, then the
chosen effects with their parameters as tables, before / after, the gap against the ceiling,
the ranked candidates and the figures (``analysis.gap.report_figures``).

Every number of ``diagnosis.json`` that the page showed before still shows; a chosen effect's
parameters read as a table (``analysis.gap.params_table``: names, units, 3 significant digits)
instead of raw JSON.
"""

from __future__ import annotations

import html
import json
import math
from pathlib import Path

from analysis.gap.engine import Diagnosis, GapError
from analysis.gap.engine.steps import INCONCLUSIVE, NO_GAP_THAT_MATTERS, NOT_A_GAP
from analysis.gap.params_table import format_sig, param_rows
from analysis.gap.report_figures import write_figures
from labfiles import atomic_open, atomic_write_text, write_new_file

__all__ = ["badge", "lead_figure", "misfit_words", "outcome", "params_html", "remaining_html",
           "verdict_text", "write_multi_report", "write_report"]

#: The page's style: a readable measure, the verdict in a band with its lead figure beside it,
#: figures never wider than the page (and never stretched into empty bands).
_CSS = """
body{font-family:"DejaVu Sans",Arial,sans-serif;color:#222;max-width:1180px;margin:1.2em auto;
padding:0 1em;line-height:1.4}
h1{font-size:1.6em;margin:0 0 .5em}
h2{margin:1.6em 0 .5em;padding-top:.6em;border-top:2px solid #ccc}
h3{font-size:1.08em;margin:1.2em 0 .35em}
.verdict{display:flex;gap:1.4em;align-items:center;background:#f1f5fa;
border-left:6px solid #3568b0;padding:.7em 1em;margin:.4em 0 1em}
.lead{flex:0 0 auto;text-align:center;min-width:10em}
.lead .figure{display:block;font-size:1.6em;font-weight:bold;white-space:nowrap}
.lead .what{display:block;font-size:.8em;color:#555;max-width:14em;margin:0 auto .3em}
.verdict .words{flex:1 1 auto}
.verdict .words p{margin:.2em 0}
.warning{color:#8a4400}
table{border-collapse:collapse;margin:.3em 0 .8em}
th,td{border:1px solid #bbb;padding:.15em .55em;text-align:left;vertical-align:top}
th{background:#f4f4f4}
td.num{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
ol.steps>li{margin-bottom:.6em}
img{display:block;max-width:100%;height:auto;margin:.3em 0 1em}
.badge{display:inline-block;padding:.15em .6em;border-radius:.8em;font-weight:bold;
font-size:.95em;color:#fff;white-space:nowrap;margin:.1em 0 .3em}
.badge.gap{background:#b3261e}.badge.none{background:#1e7b34}.badge.inconclusive{background:#a86a00}
"""

#: The three outcomes of a diagnosis: the badge's class and words.
_OUTCOMES = {"gap": ("gap", "gap"), NO_GAP_THAT_MATTERS: ("none", "no gap that matters"),
             INCONCLUSIVE: ("inconclusive", "inconclusive")}


def outcome(d: Diagnosis) -> str:
    """The diagnosis's outcome of three: ``'gap'`` (named effects or unexplained),
    ``'no_gap_that_matters'`` or ``'inconclusive'``."""
    return d.verdict if d.verdict in NOT_A_GAP else "gap"


def badge(d: Diagnosis) -> str:
    """The outcome at a glance (HTML): a coloured badge, red for a gap, green for no gap that
    matters, amber for inconclusive."""
    cls, words = _OUTCOMES[outcome(d)]
    return f'<span class="badge {cls}">{html.escape(words)}</span>'


def power_words(d: Diagnosis) -> str:
    """For an inconclusive verdict: the smallest misfit these data would detect and how much
    more data would decide, in words ('' otherwise or where the layer simulates neither)."""
    if d.verdict != INCONCLUSIVE or not d.detectable:
        return ""
    det, dec = d.detectable, d.to_decide
    seen = (f"detectable with {100 * det['power']:.0f} % power: {det['value']:.2g} "
            f"{det['unit']}" if det.get("value") is not None else
            f"not detectable up to {det['tried_up_to']:.2g} {det['unit']}")
    return f"{seen}; to decide: {dec['words']}"


def verdict_text(d: Diagnosis) -> str:
    """Plain-language verdict (HTML), each part once: the diagnosis's summary (the first
    chosen effect in bold), how the data were held out, and the warnings. The gap against the
    ceiling in numbers is :func:`remaining_html`'s table."""
    text = html.escape(d.summary or d.verdict)
    if d.steps and d.verdict != "unexplained" and d.verdict not in NOT_A_GAP:
        text = text.replace(html.escape(d.steps[0]["added"].replace("_", " ")),
                            f"<b>{html.escape(d.steps[0]['added'].replace('_', ' '))}</b>", 1)
    text = f"<p>{text}</p>"
    if misfit_words(d):
        text += f"<p>{html.escape(misfit_words(d))}.</p>"
    if d.split:
        text += f"<p><i>Held out: {html.escape(d.split)}.</i></p>"
    for w in d.warnings:
        text += f'<p class="warning"><b>Warning:</b> {html.escape(w)}</p>'
    return text


def _pct(x: float) -> str:
    return f"{100 * x:.0f} %" if math.isfinite(x) else "n/a"


def _lead(items: list[tuple[str, str]]) -> str:
    return '<div class="lead">' + "".join(
        f'<span class="figure">{html.escape(fig)}</span><span class="what">'
        f"{html.escape(what)}</span>" for fig, what in items) + "</div>"


def misfit_words(d: Diagnosis) -> str:
    """The held-out misfit in the data's own units, in words, or '' where the layer gives none:
    'RMS misfit 3.1 % -> 0.42 % of luminance (plain -> chosen effects; a flexible model of the
    readings 0.41 %; worst patch 0.9 %; near black 0.012 -> 0.010 cd/m^2)'."""
    if not math.isfinite(d.misfit_pct_before):
        return ""
    m = d.misfit or {}
    unit = m.get("unit", "of the photos' RMS luminance")
    text = (f"RMS misfit {d.misfit_pct_before:.2g} % \u2192 {d.misfit_pct_after:.2g} % {unit} "
            "(plain simulation \u2192 with the chosen effects")
    extra = []
    if math.isfinite(m.get("ceiling_pct", float("nan"))):
        extra.append(f"a flexible model of the data {m['ceiling_pct']:.2g} %")
    if math.isfinite(m.get("worst_pct_after", float("nan"))):
        extra.append(f"worst patch {m['worst_pct_before']:.2g} % \u2192 "
                     f"{m['worst_pct_after']:.2g} %")
    if math.isfinite(m.get("black_cd_m2_after", float("nan"))):
        extra.append(f"near black (below {m['black_below_cd_m2']:.2g} cd/m\u00b2) "
                     f"{m['black_cd_m2_before']:.2g} \u2192 {m['black_cd_m2_after']:.2g} "
                     "cd/m\u00b2 RMS")
    return text + "".join(f"; {e}" for e in extra) + ")"


def lead_figure(d: Diagnosis) -> str:
    """The figure beside the verdict (HTML): 'no gap that matters' or 'inconclusive' (with the
    misfit's upper bound and, inconclusive, what is detectable and what decides), or the
    held-out gap before -> after in nats per unit and the share the chosen effects explain
    (with a ceiling: of what the ceiling removes, the summary's share); first, where the layer
    measures it, the held-out RMS misfit before -> after in the data's own units (%)."""
    units = ([(f"{d.misfit_pct_before:.2g} % \u2192 {d.misfit_pct_after:.2g} %",
               "RMS misfit " + (d.misfit or {}).get("unit", "of the photos' RMS luminance")
               + ", before \u2192 after")]
             if math.isfinite(d.misfit_pct_before) else [])
    unit = (d.remaining or {}).get("size_unit", "")
    short = " %" if unit.startswith("%") else (f" {unit}" if unit else "")
    said = f"upper 95 % bound of the misfit (tolerance {d.tolerance:g}{short})"
    bound = ([(f"\u2264 {d.misfit_upper:.2g}", said)] if math.isfinite(d.misfit_upper)
             else [])
    if d.verdict == NO_GAP_THAT_MATTERS:
        return _lead([("no gap that matters", "the data exclude a misfit of the tolerance"),
                      *bound, *units, *_misfit_lead(d)])
    if d.verdict == INCONCLUSIVE:
        return _lead([("inconclusive", power_words(d) or "neither a gap nor excluded"),
                      *bound, *units, *_misfit_lead(d)])
    items = [*units, *_misfit_lead(d),
             (f"{format_sig(d.gap_before)} \u2192 {format_sig(d.gap_after)}",
              "nats per unit above the noise floor, before \u2192 after")]
    if d.steps:
        # With a ceiling the share is of what a flexible model of the data removes (as the
        # summary says), which may be far more than the share of the gap before -> after.
        of = ("of what a flexible model removes, explained" if d.remaining is not None
              else "of the gap explained")
        items.append((_pct(d.explained_share), of))
    else:
        items.append(("none", "of the gap explained by the catalogue"))
    return _lead(items)


def _misfit_lead(d: Diagnosis) -> list[tuple[str, str]]:
    """The misfit in the data's own units before -> after, where the layer measures it (the
    observer layer's ``misfit_*``), as a lead item; else none."""
    if not math.isfinite(d.misfit_before):
        return []
    return [(f"{format_sig(d.misfit_before)} \u2192 {format_sig(d.misfit_after)}",
             f"{d.misfit_unit}, RMS misfit of the predicted responses, before \u2192 after")]


def _verdict_block(lead: str, words: str, mark: str = "") -> str:
    return f'<div class="verdict">{lead}<div class="words">{mark}{words}</div></div>'


def _spans(keys: list) -> list[int]:
    """Row spans of a column whose equal neighbours share one cell: the first row of each
    run gets the run's length, the others 0."""
    spans = [0] * len(keys)
    start = 0
    for i in range(1, len(keys) + 1):
        if i == len(keys) or keys[i] != keys[start]:
            spans[start] = i - start
            start = i
    return spans


def params_html(layer: str, effect: str, params: dict) -> str:
    """One chosen effect's parameters as a table (:func:`analysis.gap.params_table.
    param_rows`): a parameter's rows share its name cell, and its unit cell where the unit
    is the same; a 'for' column where any value is per level, illumination, response or
    participant."""
    rows = param_rows(layer, effect, params)
    if not rows:
        return "<p>(no parameters)</p>"
    per = any(r.where for r in rows)
    head = "<tr><th>parameter</th>" + ("<th>for</th>" if per else "") + (
        "<th>value</th><th>unit</th></tr>")
    names = _spans([r.name for r in rows])
    units = _spans([(r.name, r.unit) for r in rows])
    body = []
    for r, n_name, n_unit in zip(rows, names, units):
        name = f'<th rowspan="{n_name}">{html.escape(r.name)}</th>' if n_name else ""
        # A single value beside per-level ones holds for all of them.
        where = f"<td>{html.escape(r.where or 'all')}</td>" if per else ""
        unit = f'<td rowspan="{n_unit}">{html.escape(r.unit)}</td>' if n_unit else ""
        body.append(f'<tr>{name}{where}<td class="num">{html.escape(r.value)}</td>{unit}</tr>')
    return f'<table class="params">{head}{"".join(body)}</table>'


def _steps_html(d: Diagnosis) -> str:
    if not d.steps:
        return "<p>No effect chosen.</p>"
    items = "".join(
        f"<li>+ <b>{html.escape(s['added'])}</b>: held-out gain {s['gain']:.4f} "
        f"(p={s['p']:.4f})" + params_html(d.layer, s["added"], s["params"]) + "</li>"
        for s in d.steps)
    return f'<ol class="steps">{items}</ol>'


def _rows_table(rows: list[tuple[str, str]]) -> str:
    return "<table>" + "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>"
                               for k, v in rows) + "</table>"


def remaining_html(d: Diagnosis) -> str:
    """The chosen model against a flexible model of the data (the ceiling), as a table: the
    held-out loss above it with its CI and p, the shares of the gap the catalogue and the
    ceiling explain, and (in a layer with a practical tolerance) the misfit's size, the
    tolerance and whether it counts. "" without a ceiling."""
    rem = d.remaining
    if not rem:
        return ""
    above = (f"{rem['gap']:.3f} nats per unit (95 % CI {rem['ci'][0]:.3f} to "
             f"{rem['ci'][1]:.3f}), one-sided p {rem['p']:.4f}")
    rows = [("chosen model above the ceiling", above),
            ("share of the gap the catalogue explains", _pct(d.explained_share)),
            ("share of the gap the ceiling explains", _pct(d.ceiling_share))]
    if "size" in rem:
        unit = rem.get("size_unit", "")
        tol_unit = " %" if unit.startswith("%") else (f" {unit}" if unit else "")
        source = f" ({rem['size_source']})" if rem.get("size_source") else ""
        side = "below" if rem["size"] < rem["tolerance"] else "at or above"
        state = ("a gap beyond the catalogue" if rem["significant"] else
                 "significant in nats but within the tolerance (not a gap beyond the "
                 "catalogue)" if rem.get("within_tolerance") else "not significant")
        rows += [("what remains, its size", f"about {rem['size']:.2g} {unit}".strip())]
        if "size_upper" in rem:
            rows.append(("its upper 95 % bound", f"{rem['size_upper']:.2g}{tol_unit}"))
        rows += [
                 ("tolerance", f"{rem['tolerance']:g}{tol_unit}{source}; the misfit is {side} it"),
                 ("what remains counts as", state)]
    return ("<h3>Against a flexible model of the data (the ceiling)</h3>" + _rows_table(rows))


def _before_after(d: Diagnosis) -> str:
    shrink = (f"{d.shrink_abs:.4f} (95 % CI {d.shrink_abs_ci[0]:.4f} to "
              f"{d.shrink_abs_ci[1]:.4f})")
    share = (f"{d.shrink_pct:.1f} % (95 % CI {d.shrink_pct_ci[0]:.1f} to "
             f"{d.shrink_pct_ci[1]:.1f} %)")
    rows = [("before", f"{d.gap_before:.4f}"), ("after", f"{d.gap_after:.4f}"),
            ("shrink", shrink), ("shrink, share", share)]
    if math.isfinite(d.misfit_pct_before):
        unit = (d.misfit or {}).get("unit", "of the photos' RMS luminance")
        rows.append((f"held-out RMS misfit, % {unit}",
                     f"{d.misfit_pct_before:.2f} % before, {d.misfit_pct_after:.2f} % after"))
    return ("<h3>Before / after (held-out mean NLL above the simulation's noise floor, nats "
            "per unit)</h3>" + _rows_table(rows))


def _ranking(d: Diagnosis) -> str:
    rows = "".join(
        f'<tr><td>{html.escape(s["name"])}</td><td class="num">{s["gain"]:.4f}</td>'
        f'<td class="num">[{s["ci_low"]:.4f}, {s["ci_high"]:.4f}]</td>'
        f'<td class="num">{s["p_holm"]:.4f}</td>'
        f"<td>{'yes' if s['significant'] else 'no'}</td></tr>" for s in d.ranking)
    min_gain = (f" and its gain is at least {d.min_gain:g} nats per unit"
                if d.min_gain > 0 else "")
    return ("<h3>Ranked candidates (held-out gain, bootstrap 95 % CI, Holm-adjusted one-sided "
            f"p)</h3><p>A candidate counts when its Holm p is below 0.05{min_gain}.</p>"
            "<table><tr><th>candidate</th><th>gain</th><th>CI</th><th>p (Holm)</th>"
            f"<th>counts</th></tr>{rows}</table>")


def diagnosis_html(diag: Diagnosis, figure: str | None = "localisation.png",
                   maps: str = "") -> str:
    """The body of one layer's report section: the verdict with its lead figure, the chosen
    effects and their parameters, before / after, the ceiling, the ranking, the figures."""
    img = f'<h3>Where</h3><img src="{figure}" alt="localisation">' if figure else ""
    maps_html = ('<h3>Residual maps (held-out photo, prediction with the chosen extensions, '
                 'residual in noise SDs before and after them)</h3>'
                 f'<img src="{maps}" alt="residual maps">' if maps else "")
    return (_verdict_block(lead_figure(diag), verdict_text(diag), badge(diag))
            + "<h3>Chosen effects (greedy combination) and their fitted parameters</h3>"
            + _steps_html(diag) + _before_after(diag) + remaining_html(diag) + _ranking(diag)
            + img + maps_html)


def _page(title: str, body: str) -> str:
    return (f'<!doctype html><html><head><meta charset="utf-8"><title>{html.escape(title)}'
            f"</title><style>{_CSS}</style></head><body>\n{body}\n</body></html>")


def _atomic_page(out: Path, page: str) -> Path:
    try:
        return write_new_file(out / "index.html", page)  # never replaces an existing report
    except FileExistsError as exc:
        raise GapError(f"report {out / 'index.html'} exists; pass a new --out folder") from exc


def _write_parts(folder: Path, diag: Diagnosis, local) -> None:
    atomic_write_text(folder / "diagnosis.json", json.dumps(diag.to_dict(), indent=1))
    with atomic_open(folder / "localisation.csv", "w", newline="") as fh:
        local.to_csv(fh, index=False)


def _check_new(out: Path, layers=()) -> None:
    """Refuse a folder that holds a report, or a diagnosis written before its figures (a run
    stopped while drawing): nothing recorded is overwritten."""
    for path in (out / "index.html", out / "diagnosis.json",
                 *(out / name / "diagnosis.json" for name in layers)):
        if path.exists():
            raise GapError(f"report {path} exists; pass a new --out folder")
    out.mkdir(parents=True, exist_ok=True)


def _figure_lines(failed: list[str]) -> str:
    """The figures that failed to draw, as warning lines of the page."""
    return "".join(f'<p class="warning"><b>Figure not drawn:</b> {html.escape(f)}</p>'
                   for f in failed)


def write_report(diag: Diagnosis, local, out_dir: str | Path, *,
                 notes: list | None = None) -> Path:
    """Write ``out_dir/index.html`` (+ figures, JSON, localisation CSV). Refuses an existing
    report.

    ``diagnosis.json`` and ``localisation.csv`` are written first, then the figures, then the
    page: a figure that fails to draw never costs the verdict; it is left out of the page
    with a warning line there, and the same line is appended to ``notes`` (a list, for the
    caller to print) when given."""
    out = Path(out_dir)
    _check_new(out)
    _write_parts(out, diag, local)
    figs, failed = write_figures(local, out)
    if notes is not None:
        notes.extend(failed)
    page = _page(f"Sim-to-real gap: {diag.layer}",
                 f"<h1>Sim-to-real gap, {html.escape(diag.layer)} layer</h1>\n"
                 f"{diagnosis_html(diag, figs['localisation'] or None, figs['maps'])}"
                 f"{_figure_lines(failed)}\n<p>seed {diag.seed}</p>")
    return _atomic_page(out, page)


def _which_lead(which: dict) -> str:
    layer = which.get("layer")
    if not layer:
        return _lead([("no gap found", "at any layer given")])
    gap = which["gaps"][layer][0]
    return _lead([(f"{layer} layer", "carries the gap"),
                  (format_sig(gap), "nats per unit")])


def write_multi_report(results: dict, which: dict, out_dir: str | Path, *,
                       notes: list | None = None) -> Path:
    """``out_dir/index.html`` with the carrying layer and each layer's section (figures in
    ``out_dir/<layer>/``). Every layer's ``diagnosis.json`` is written before any figure is
    drawn; a figure that fails is said as in :func:`write_report`."""
    out = Path(out_dir)
    _check_new(out, results)
    for name, (diag, local) in results.items():
        (out / name).mkdir(exist_ok=True)
        _write_parts(out / name, diag, local)
    sections = []
    for name, (diag, local) in results.items():
        figs, failed = write_figures(local, out / name)
        if notes is not None:
            notes.extend(failed)
        sections.append(f"<h2>{html.escape(name)} layer</h2>"
                        + diagnosis_html(diag, f"{name}/{figs['localisation']}"
                                         if figs["localisation"] else None,
                                         f"{name}/{figs['maps']}" if figs["maps"] else "")
                        + _figure_lines(failed))
    rows = "".join(f'<tr><td>{html.escape(n)}</td><td>{badge(results[n][0])}</td>'
                   f'<td>{html.escape(power_words(results[n][0]))}</td>'
                   f'<td class="num">{g[0]:.4f}</td>'
                   f'<td class="num">[{g[1]:.4f}, {g[2]:.4f}]</td></tr>'
                   for n, g in which["gaps"].items())
    body = ("<h1>Sim-to-real gap, all layers</h1>\n"
            + _verdict_block(_which_lead(which), f"<p>{html.escape(which['text'])}</p>")
            + "<table><tr><th>layer</th><th>outcome</th><th>detectable; to decide</th>"
            "<th>held-out gap (nats per unit)</th><th>95 % CI</th>"
            f"</tr>{rows}</table>\n" + "".join(sections))
    return _atomic_page(out, _page("Sim-to-real gap: all layers", body))
