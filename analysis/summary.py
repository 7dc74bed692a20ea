"""A fitted mixed model as text, laid out as R's ``summary(lmer(...))`` and ``car::Anova``."""

from __future__ import annotations

import numpy as np
import pandas as pd

from analysis.formula import LmmError
from analysis.lmm import LmmFit
from labfiles import LabFileError, read_csv_frame

__all__ = ["format_summary", "read_model_data"]


def _fmt(x: float) -> str:
    return f"{x:.4g}" if abs(x) < 1e-3 or abs(x) >= 1e5 else f"{x:.4f}"


def format_summary(fit: LmmFit, tests=(), satterthwaite=None) -> str:
    """The fit as lme4 prints it, with the Type II tests (and Satterthwaite t tests if given).

    Parameters
    ----------
    fit : LmmFit
    tests : sequence of analysis.typeii.WaldTest
    satterthwaite : dict of str to (df, t, p), optional
        Per coefficient (`analysis.satterthwaite.coefficient_tests`).

    Returns
    -------
    str
    """
    method = "REML" if fit.reml else "maximum likelihood"
    n_par = len(fit.fixef) + len(fit.theta) + 1
    lines = [f"Linear mixed model fit by {method}",
             f"Formula: {fit.formula}",
             (f"  logLik {fit.loglik:.4f}   {'REML criterion' if fit.reml else 'deviance'} "
             f"{fit.deviance:.4f}   AIC {fit.deviance + 2 * n_par:.4f}"),
             "", "Random effects:",
             f"  {'Groups':<16}{'Name':<16}{'Std.Dev.':>10}  Corr"]
    for r in fit.random:
        for i, name in enumerate(r["names"]):
            cors = [r["cor"][f"{a},{name}"] for a in r["names"][:i]]
            corr = " ".join(f"{c:5.2f}" for c in cors)
            group = r["group"] if i == 0 else ""
            lines.append(f"  {group:<16}{name:<16}{r['sd'][name]:>10.4f}  {corr}")
    lines.append(f"  {'Residual':<16}{'':<16}{fit.sigma:>10.4f}")
    groups = "; ".join(f"{r['group']}, {r['n_levels']}" for r in fit.random)
    lines.append(f"Number of obs: {fit.n_obs}, groups: {groups}"
                 + (f" ({fit.n_dropped} rows with missing values left out)"
                    if fit.n_dropped else ""))
    if fit.singular:
        lines.append("boundary (singular) fit: see help('isSingular') in R")
    lines += ["", "Fixed effects:"]
    head = f"  {'':<28}{'Estimate':>12}{'Std. Error':>12}"
    if satterthwaite:
        head += f"{'df':>10}{'t value':>10}{'Pr(>|t|)':>11}"
    lines.append(head)
    for name, b in fit.fixef.items():
        row = f"  {name:<28}{_fmt(b):>12}{_fmt(fit.se[name]):>12}"
        if satterthwaite:
            df, t, p = satterthwaite[name]
            row += f"{df:>10.2f}{t:>10.3f}{p:>11.3g}"
        lines.append(row)
    if tests:
        lines += ["", "Type II Wald chi-square tests (car::Anova(type = 2)):",
                  f"  {'':<28}{'Chisq':>12}{'Df':>5}{'Pr(>Chisq)':>12}"]
        for t in tests:
            lines.append(f"  {t.term:<28}{t.chi2:>12.4f}{t.df:>5d}{t.p:>12.3g}")
    return "\n".join(lines) + "\n"


def _refuse_misaligned_header(path) -> None:
    """Refuse a CSV whose header has another number of fields than every row: a column name
    holding a comma written unquoted (PsychoPy's "participant ID (two digits, e.g. 01)")
    splits it in two, and every column after it would be read one place off (``expName``
    holding the frame rate)."""
    import csv
    import io
    import itertools

    from labfiles import read_text

    rows = [r for r in csv.reader(io.StringIO(read_text(path), newline=""))
            if any(v.strip() for v in r)]
    if len(rows) < 2:
        return
    header, widths = rows[0], {len(r) for r in rows[1:]}
    if len(widths) != 1 or len(header) in widths:
        return
    width = widths.pop()
    split = [f"{a},{b}" for a, b in itertools.pairwise(header)
             if a.count("(") > a.count(")") and b.count(")") > b.count("(")]
    guess = (f" ({', '.join(repr(n) for n in split)} looks like one name split at its comma)"
             if split else "")
    raise LmmError(
        f"{path}: the header has {len(header)} fields but every row {width}, so every column "
        f"after the first misplaced one would be read one place off{guess}: a column name "
        "holding a comma was written unquoted. Quote it in the header line (\"name, with "
        "comma\") or remove the comma, then fit again")


def read_model_data(path, design) -> pd.DataFrame:
    """The data of ``python -m analysis fit``: a session folder or a CSV file.

    A folder is loaded and validated as sessions (`analysis.load.load_sessions`) and gets the
    report's model frame (standardised ``gloss`` and ``depth``, ``depth_match_bc``); a CSV is
    read as it is, text columns as text.

    Raises
    ------
    LmmError
        If ``path`` is neither a folder nor a CSV file, or a CSV separated by ';' or tabs.
    """
    from pathlib import Path

    from analysis.load import load_sessions
    from analysis.models import model_frame

    path = Path(path)
    if path.is_dir():
        return model_frame(load_sessions(path, design).frame, design)
    if path.is_file() and path.suffix.lower() == ".csv":
        try:
            frame = read_csv_frame(path)  # first: a ';' file is named as such
            _refuse_misaligned_header(path)
        except LabFileError as exc:
            raise LmmError(str(exc)) from None
        for col in frame.columns:
            if frame[col].dtype == object:
                frame[col] = frame[col].astype(str).where(frame[col].notna(), np.nan)
        return frame
    raise LmmError(f"{path}: not a session folder or a .csv file; pass one of those as DATA")
