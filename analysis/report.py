"""The analysis report: session data in, an HTML page with the source study's figures and tests.

`build_report` loads and validates the sessions, draws the figures, fits the source study's two
mixed models and the design's extra ones (``[analysis.models]``, e.g. stimuli crossed with
participants) with Type II Wald tests, runs the parametric bootstrap, checks the source study's
qualitative findings under its models and under their re-specifications, and writes
``REPORT_DIR/index.html`` (plus the figures as PNG and every number in
``results.json``). An existing report is never overwritten: if ``REPORT_DIR/index.html`` exists
the build stops before computing anything (choose another ``--out`` or move the old report
away); ``index.html`` is written last (``labfiles.write_new_file``), which fails rather than
replace a file. Every file gets the umask's permissions, so the lab's other accounts can read it.
"""

from __future__ import annotations

import functools
import html
import json
import operator
import platform
import shutil
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pandas as pd

from analysis.bootstrap import parametric_bootstrap, re_labels
from analysis.figures import (
    find_metamers,
    group_means,
    plot_depth_matches,
    plot_gloss_contours,
    plot_gloss_matches,
    plot_observers,
    save_figure,
)
from analysis.load import load_sessions
from analysis.models import fit_design_models, fit_source_study_models, model_frame
from labfiles import atomic_write_text, write_new_file
from studydesign import StudyDesign

__all__ = ["ReportExistsError", "build_report", "chi2_sentence", "format_p",
           "source_study_pattern"]

ALPHA = 0.05


class ReportExistsError(FileExistsError):
    """The output folder already holds a report."""


def format_p(p: float, *, floor: float | None = None) -> str:
    """"p < 0.001" below 0.001, else "p = 0.023"; ``floor`` marks a bootstrap's smallest p."""
    if floor is not None and p <= floor * (1 + 1e-9):
        return f"p ≤ {floor:.2g}" if floor >= 0.001 else "p < 0.001"
    return "p < 0.001" if p < 0.001 else f"p = {p:.3f}"


def chi2_sentence(test, n_participants: int) -> str:
    """The source study's style: "χ²(1, N = 11) = 3716.04, p < 0.001"."""
    return f"χ²({test.df}, N = {n_participants}) = {test.chi2:.2f}, {format_p(test.p)}"


def source_study_pattern(models: dict, frame: pd.DataFrame, *, alpha: float = ALPHA) -> dict:
    """The source study's qualitative findings, each checked on these data.

    Parameters
    ----------
    models : dict
        ModelResult under the keys "gloss" and "depth" (the source study's models or models
        that re-specify them, e.g. with stimuli crossed); each needs the terms gloss, depth and
        gloss:depth.
    frame : DataFrame
        The loaded sessions.
    alpha : float

    Returns
    -------
    dict of str to (bool, str)
        Finding -> (holds, the numbers behind it).
    """
    dm, gm = models["depth"], models["gloss"]
    p = {m: {t.term: t.p for t in models[m].tests} for m in models}
    # Depth error (perceived - true) per depth bin, mean and 95 % CI across observers.
    err = frame.assign(depth_error_cm=frame["depth_match_cm"] - frame["true_depth_cm"])
    depth_err = group_means(err, "depth_error_cm", ["depth_bin"]).set_index("depth_bin")
    over_low = depth_err.loc["low", "mean"]
    over_high = depth_err.loc["high", "mean"]
    low_ci, high_ci = depth_err.loc["low", "ci"], depth_err.loc["high", "ci"]
    gloss_bins = group_means(frame, "gloss_match_pct", ["depth_bin"]).set_index("depth_bin")
    deeper = gloss_bins.loc["high", "mean"] - gloss_bins.loc["low", "mean"]
    return {
        "large depth effect on estimated depth": (
            p["depth"]["depth"] < alpha and dm.fit.fixef["depth"] > 0,
            f"depth χ² = {dm.chi2()['depth']:.2f}, {format_p(p['depth']['depth'])}"),
        "no gloss effect on estimated depth": (
            p["depth"]["gloss"] >= alpha, f"{format_p(p['depth']['gloss'])}"),
        "no gloss × depth interaction on estimated depth": (
            p["depth"]["gloss:depth"] >= alpha, f"{format_p(p['depth']['gloss:depth'])}"),
        "gloss effect on estimated gloss": (
            p["gloss"]["gloss"] < alpha, f"{format_p(p['gloss']['gloss'])}"),
        "depth effect on estimated gloss": (
            p["gloss"]["depth"] < alpha, f"{format_p(p['gloss']['depth'])}"),
        "gloss × depth interaction on estimated gloss": (
            p["gloss"]["gloss:depth"] < alpha, f"{format_p(p['gloss']['gloss:depth'])}"),
        "depth compression (low depths overestimated, high underestimated)": (
            bool(over_low - low_ci > 0 and over_high + high_ci < 0),
            (f"perceived − true: low bin {over_low:+.2f} ± {low_ci:.2f} cm, high bin "
            f"{over_high:+.2f} ± {high_ci:.2f} cm (95 % CI across observers)")),
        "deeper looks glossier": (
            deeper > 0 and gm.fit.fixef["depth"] > 0 and p["gloss"]["depth"] < alpha,
            f"high − low depth bin: {deeper:+.1f} % perceived gloss"),
    }


def _versions() -> dict:
    import matplotlib
    import nlopt
    import scipy

    return {"python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "pandas": pd.__version__,
            "matplotlib": matplotlib.__version__, "nlopt": nlopt.__version__}


def _table(header, rows) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>" for row in rows
    )
    return f"<table><tr>{head}</tr>{body}</table>"


def _ci(boot, table: str, key) -> str:
    if boot is None:
        return ""
    values = boot.sigma_ci if table == "sigma" else getattr(boot, table)[key]
    return "[{:.3f}, {:.3f}]".format(*values)


def _model_section(res, boot) -> str:
    fit = res.fit
    n_part = fit.n_groups().get("participant", 0)
    groups = ", ".join(f"{r['group']} ({r['n_levels']})" for r in fit.random)
    parts = [f"<h3>{html.escape(res.label)}</h3>",
             (f"<p><code>{html.escape(fit.formula)}</code>, {'REML' if fit.reml else 'ML'}; "
             f"{fit.n_obs} trials; grouping factors (levels): {html.escape(groups)}.</p>")]
    if res.boxcox_lambda is not None:
        parts.append(f"<p>Response: car::bcPower(depth, λ = {res.boxcox_lambda:g}) = "
                     "(depth<sup>λ</sup> − 1)/λ.</p>")
    sentences = "; ".join(f"{t.term}: {chi2_sentence(t, n_part)}" for t in res.tests)
    parts.append(f"<p class='sentence'>Type II Wald tests — {html.escape(sentences)}.</p>")
    rows = []
    for t in res.tests:
        bp = "" if boot is None else format_p(boot.chi2_p[t.term], floor=1 / (boot.n_ok + 1))
        F, q, ddf, fp = res.f_tests.get(t.term, [float("nan")] * 4)
        rows.append([t.term, f"{t.chi2:.2f}", t.df, format_p(t.p), bp,
                     f"F({q:g}, {ddf:.1f}) = {F:.2f}", format_p(fp)])
    parts.append(_table(["term", "χ²", "df", "p (χ²)", "p (bootstrap)", "F (Satterthwaite df)",
                         "p (F)"], rows))
    rows = [[t, f"{fit.fixef[t]:.3f}", f"{fit.se[t]:.3f}", _ci(boot, "fixef_ci", t)]
            for t in fit.fixef]
    parts.append("<p>Fixed effects (gloss and depth per SD of the design's levels):</p>")
    parts.append(_table(["coefficient", "estimate", "SE", "95 % bootstrap CI"], rows))
    sds = [sd for r in fit.random for sd in r["sd"].values()]
    rows = [[label, f"{sd:.3f}", _ci(boot, "re_sd_ci", label)]
            for label, sd in zip(re_labels(fit), sds)]
    rows.append(["residual", f"{fit.sigma:.3f}", _ci(boot, "sigma", None)])
    parts.append(_table(["random effect", "SD", "95 % bootstrap CI"], rows))
    cors = ", ".join(f"{r['group']}: {k}: {v:.2f}" for r in fit.random for k, v in r["cor"].items())
    singular = (" <b>Singular fit</b> (a random-effect variance or correlation on the boundary, "
                "as lme4's isSingular)." if fit.singular else "")
    parts.append(f"<p>Random-effect correlations: {html.escape(cors or 'none')}. "
                 f"Log-likelihood {fit.loglik:.2f}.{singular}</p>")
    return "\n".join(parts)


def _respecified(models: dict, extra: dict) -> dict:
    """The source models with each replaced by the design model that re-specifies it."""
    out = dict(models)
    for res in extra.values():
        if res.source_model and {"gloss", "depth", "gloss:depth"} <= set(res.fit.terms):
            out[res.source_model] = res
    return out


def build_report(data_dir, out_dir, design: StudyDesign, *, n_boot: int = 10_000,
                 seed: int = 0, n_jobs: int = 2, progress: bool = True,
                 power_dirs=()) -> Path:
    """Analyse a data folder into ``out_dir/index.html``.

    Parameters
    ----------
    data_dir : str or Path
        Folder with ``sessions/`` (see `analysis.load.load_sessions`).
    out_dir : str or Path
        Report folder; created if needed. Must not already hold an ``index.html``.
    design : StudyDesign
    n_boot : int
        Parametric bootstrap runs per model (0 skips the bootstrap).
    seed : int
        Bootstrap seed (recorded in the report).
    n_jobs : int
        Parallel bootstrap workers.
    progress : bool
        Show progress bars.
    power_dirs : sequence of str or Path
        ``python -m analysis power`` result folders: their curves and sentences become the
        report's section "Planning a study: power" (each power.png copied beside index.html
        as power-<k>.png).

    Returns
    -------
    Path
        The index.html written.

    Raises
    ------
    ReportExistsError
        If ``out_dir/index.html`` exists.
    analysis.load.SessionDataError
        If the sessions do not validate.
    """
    out = Path(out_dir)
    index = out / "index.html"
    if index.exists():
        raise ReportExistsError(
            f"{index} exists; reports are never overwritten: pass another --out or move it away")
    data = load_sessions(data_dir, design)
    frame = data.frame
    powers = [_read_power(d) for d in power_dirs]
    out.mkdir(parents=True, exist_ok=True)
    n_part = len(data.participants)
    models = fit_source_study_models(frame, design)
    extra = fit_design_models(frame, design)
    every = {**models, **extra}
    boots = _bootstraps(every, model_frame(frame, design), n_boot, seed, n_jobs, progress)
    # Metamers exist only if depth changes perceived gloss: without a significant depth effect
    # in the gloss model, pairs that happen to match are noise (hundreds of pairs are tried).
    depth_p = {t.term: t.p for t in models["gloss"].tests}["depth"]
    metamers = find_metamers(frame) if depth_p < ALPHA else []
    figures = {
        "depth_matches.png": plot_depth_matches(frame, design),
        "gloss_matches.png": plot_gloss_matches(frame, design),
        "gloss_contours.png": plot_gloss_contours(frame, design, metamers),
        "observers_gloss.png": plot_observers(frame, design, response="gloss"),
        "observers_depth.png": plot_observers(frame, design, response="depth"),
    }
    for name, fig in figures.items():
        save_figure(fig, out / name)
    respecified = _respecified(models, extra)
    patterns = {"source": source_study_pattern(models, frame)}
    if respecified != models:
        patterns["respecified"] = source_study_pattern(respecified, frame)
    results = _results(data_dir, data, design, every, boots, seed, metamers, patterns,
                       respecified)
    for k, d in enumerate(power_dirs):
        shutil.copyfile(Path(d) / "power.png", out / f"power-{k + 1}.png")
    if powers:
        results["power"] = powers
    atomic_write_text(out / "results.json", json.dumps(results, indent=1, ensure_ascii=False))
    page = _page(data, every, boots, metamers, patterns, figures, results, n_part, n_boot, seed)
    _write_new(index, page)
    return index


def _bootstraps(every: dict, mf, n_boot: int, seed: int, n_jobs: int, progress: bool) -> dict:
    """Each model's parametric bootstrap (model k with seed + k); none when n_boot is 0."""
    if n_boot <= 0:
        return {}
    return {name: parametric_bootstrap(mf, res.fit, observed_chi2=res.chi2(), n_boot=n_boot,
                                       seed=seed + k, n_jobs=n_jobs, progress=progress)
            for k, (name, res) in enumerate(every.items())}


def _results(data_dir, data, design, every, boots, seed, metamers, patterns,
             respecified) -> dict:
    """Every number of the report (results.json), power results aside."""
    frame = data.frame
    created = datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    return {
        "created_utc": created, "data_dir": str(data_dir), "files": list(data.files),
        "design": design.source, "participants": data.participants, "n_trials": len(frame),
        "warnings": list(data.warnings),
        "calibrations": [{"calibration_id": c, "participants": list(p), "n_trials": n}
                         for c, p, n in data.calibrations],
        "models": {k: json.loads(v.to_json()) for k, v in every.items()},
        "bootstrap": {k: asdict(v) for k, v in boots.items()}, "bootstrap_seed": seed,
        "metamers": [m.to_dict() for m in metamers],
        "source_study_pattern": {
            which: {"models": {k: respecified[k].name if which == "respecified" else k
                               for k in ("gloss", "depth")},
                    "findings": {k: {"holds": bool(v[0]), "detail": v[1]}
                                 for k, v in pattern.items()}}
            for which, pattern in patterns.items()},
        "versions": _versions(),
    }


def _read_power(power_dir):
    """A power result folder's power.json, checked before anything is computed."""
    path = Path(power_dir) / "power.json"
    if not path.is_file() or not (Path(power_dir) / "power.png").is_file():
        raise ValueError(f"--power {power_dir}: no power.json and power.png there; make them "
                         f"with `python -m analysis power DATA --out {power_dir}`")
    return json.loads(path.read_text())


def _power_section(powers) -> str:
    if not powers:
        return ""
    from analysis.powerplan import power_html

    return "<h2>Planning a study: power</h2>" + "".join(
        power_html(p, png=f"power-{k + 1}.png") for k, p in enumerate(powers))


def _calibrations_line(data) -> str:
    return "; ".join(f"{cid or '(none)'}: {', '.join(who)} ({n} trials)"
                     for cid, who, n in data.calibrations) or "none recorded"


def _pattern_table(patterns: dict, results: dict) -> str:
    header, cols = ["finding"], []
    for which, pattern in patterns.items():
        names = results["source_study_pattern"][which]["models"]
        header += [f"holds: {names['gloss']} / {names['depth']}", "numbers"]
        cols.append(pattern)
    rows = [[finding] + functools.reduce(operator.iadd, (["yes" if p[finding][0] else "NO", p[finding][1]] for p in cols), [])
            for finding in cols[0]]
    return _table(header, rows)


def _page(data, models, boots, metamers, patterns, figures, results, n_part, n_boot,
          seed) -> str:
    esc = html.escape
    warn = ("<ul class='warn'>" + "".join(f"<li>{esc(w)}</li>" for w in data.warnings) + "</ul>"
            if data.warnings else "<p>None: every session is complete.</p>")
    meta = (", ".join(esc(m.describe()) for m in metamers) if metamers
            else "none (depth has no significant effect on estimated gloss, or no pair of stimuli "
                 "with different gloss and depth looks equally glossy within 2 % with a 95 % CI "
                 "containing 0)")
    respec = results["source_study_pattern"].get("respecified")
    respec_note = (
        f" and with the design's re-specified models ({esc(respec['models']['gloss'])} / "
        f"{esc(respec['models']['depth'])}, e.g. stimuli crossed with participants)."
        if respec else "; the design re-specifies neither model.")
    boot_note = (f"Parametric bootstrap: {n_boot} runs per model (seed {seed}; "
                 + "; ".join(f"{k}: {b.seconds:.1f} s, {b.n_ok} refits, "
                             f"{100 * b.singular_fraction:.0f} % singular"
                             for k, b in boots.items())
                 + "). CIs are percentile intervals; bootstrap p-values compare each term's Wald "
                   "statistic with its bootstrap distribution centred at the estimate."
                 if boots else "No bootstrap was run (--bootstrap 0).")
    captions = {
        "depth_matches.png": "(a) Perceived vs true depth; hue = depth bin, saturation = gloss "
                             "bin; mean of observer means ± 95 % CI across observers.",
        "gloss_matches.png": "(b) Perceived vs true gloss per depth bin, ± 95 % CI across "
                             "observers.",
        "gloss_contours.png": "(c) Mean perceived gloss over true gloss × true depth; gloss "
                              "metamers joined by dashed lines.",
        "observers_gloss.png": "(d) Gloss matches of each observer.",
        "observers_depth.png": "(d) Depth matches of each observer.",
    }
    figs = "".join(
        f"<figure><img src='{name}' alt='{name}'><figcaption>{esc(captions.get(name, name))}"
        "</figcaption></figure>" for name in figures)
    style = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;line-height:1.4}"
             "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #bbb;"
             "padding:2px 8px;text-align:left}img{max-width:100%}figure{display:inline-block;"
             "margin:4px;max-width:540px;vertical-align:top}figcaption{font-size:90%}"
             ".warn li{color:#a40}.sentence{font-style:italic}")
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>Gloss x depth: analysis report</title>
<style>{style}</style></head><body>
<h1>Gloss × depth matching: analysis report</h1>
<p>{n_part} participants ({esc(', '.join(data.participants))}), {results['n_trials']} trials
from {len(data.files)} session files in <code>{esc(results['data_dir'])}</code>; design
<code>{esc(str(results['design']))}</code>. Created {results['created_utc']}.</p>
<h2>Data warnings</h2>{warn}
<p>Calibrations in these data: {esc(_calibrations_line(data))}.</p>
<h2>The source study's findings</h2>
<p>Each finding checked with the source study's models (gloss / depth){respec_note}</p>
{_pattern_table(patterns, results)}
<h2>Figures</h2>
{figs}
<p>Gloss metamers (equal perceived gloss, different true gloss and depth): {meta}.</p>
<h2>Linear mixed models</h2>
<p>The source study's models, response ~ gloss × depth + (1 + gloss + depth | participant),
and the design's extra models ([analysis.models] in the design), each fitted by maximum
likelihood with lme4's profiled deviance (Bates et al. 2015) and BOBYQA. True gloss and depth
are centred and scaled by the mean and SD of the design's rendered levels (Type II χ² do not
depend on the scale). Type II Wald χ² as car::Anova(type = 2); the same hypotheses as F tests
with Satterthwaite's denominator degrees of freedom, as lmerTest (Kuznetsova et al. 2017).
{esc(boot_note)}</p>
{''.join(_model_section(models[k], boots.get(k)) for k in models)}
{_power_section(results.get("power"))}
<h2>Software</h2><p>{esc(', '.join(f'{k} {v}' for k, v in results['versions'].items()))}.
All numbers: <a href="results.json">results.json</a>.</p>
</body></html>
"""


def _write_new(path: Path, text: str) -> None:
    """Write a file that must not exist yet (``labfiles.write_new_file``)."""
    try:
        write_new_file(path, text)
    except FileExistsError as exc:
        raise ReportExistsError(f"{path} appeared while the report was built; kept it") from exc
