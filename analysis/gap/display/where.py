"""Display layer, where: where the chosen model falls short, in words and in numbers.

:func:`display_where` names the drive level, screen position or part of the run that carries
most of the chosen model's held-out excess over the ceiling; :func:`localise_display` gives the
plain simulation's mean relative residual per luminance band and screen position, with
bootstrap CIs.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from analysis.gap.display.candidates import _CONFOUNDED_R2, _time_explained_by_conditions
from analysis.gap.display.model import _mean, display_loss


def _where_cells(test: pd.DataFrame) -> dict[str, list[str]]:
    """Each held-out reading's cell on the axes the words use: drive level in five bands,
    screen position and third of the run's time span (the file's conditions:
    :func:`_following`)."""
    t = test["t_s"].to_numpy(float)
    span = max(float(t.max() - t.min()), 1e-9)
    third = np.clip(((t - t.min()) / span * 3).astype(int), 0, 2)
    names = ("the first third", "the middle third", "the last third")
    cells = {"drive level": [f"drive levels {b}" for b in _fifths(test["level"])],
             "screen position": [f"screen position {p}" for p in _positions(test)]}
    return cells | {"time in the run": [f"{names[k]} of the run" for k in third]}


#: A condition is named where it explains at least this share of the variance of the
#: readings' relative residuals (adjusted R^2).
_CONDITION_R2 = 0.3


def _following(data: pd.DataFrame, conditions: list) -> str:
    """'following <condition> (<R2> % of the residuals' variance, darker as it rises)' for
    the condition column that explains the most of the variance of the readings' relative
    residuals from the extended model (adjusted R^2 of their means per value, at least
    :data:`_CONDITION_R2`); '' where none does. A change that follows a condition measured in
    blocks is named by the condition, not by the time in the run."""
    best = (0.0, "")
    data = data[np.isfinite(data["resid"].to_numpy(float))]
    r = data["resid"].to_numpy(float)
    tot = float(np.sum((r - r.mean()) ** 2))
    for c in conditions:
        groups = data.groupby(f"_v_{c}")["resid"]
        k = groups.ngroups
        if tot <= 0 or k < 2 or len(r) <= k:
            continue
        within = float(np.sum((r - groups.transform("mean").to_numpy(float)) ** 2))
        adj = 1 - (within / (len(r) - k)) / (tot / (len(r) - 1))
        if adj > best[0]:
            best = (adj, c)
    if best[0] < _CONDITION_R2:
        return ""
    return (f"following {best[1]} ({100 * best[0]:.0f} % of the variance of the readings' "
            f"residuals{_trend(data, best[1])})")


def _trend(data: pd.DataFrame, axis: str) -> str:
    """', darker as <condition> rises' (or brighter) where the readings' mean residual
    (noise SDs) from the extended model falls (rises) monotonically over 3 or more numeric
    values of a condition (Spearman |rho| >= 0.8); else ''."""
    col = f"_v_{axis}"
    if col not in data or not pd.api.types.is_numeric_dtype(data[col]):
        return ""
    means = data.groupby(col)["resid"].mean()
    if means.size < 3:
        return ""
    rho = float(pd.Series(means.index, dtype=float).corr(pd.Series(means.to_numpy()),
                                                          method="spearman"))
    if not np.isfinite(rho) or abs(rho) < 0.8:
        return ""
    return f", {'brighter' if rho > 0 else 'darker'} as {axis} rises"


def _fifths(frac) -> list[str]:
    """Labels of the fifth of [0, 1] each value lies in ("0.2-0.4")."""
    edges = np.linspace(0, 1, 6)
    band = np.clip(np.digitize(np.asarray(frac, float), edges[1:-1]), 0, 4)
    return [f"{edges[k]:.1f}-{edges[k + 1]:.1f}" for k in band]


def _positions(data: pd.DataFrame) -> list[str]:
    """Labels of the readings' screen positions ("(+0.60, -0.60)", normalised units)."""
    return [f"({a:+.2f}, {b:+.2f})" for a, b in zip(data["x_norm"], data["y_norm"])]


def display_where(fits: list) -> str:
    """Words for where the chosen model falls short of the ceiling.

    On each axis (drive level in five bands, screen position, third of the run) the cell that
    carries the most held-out excess loss (the chosen model's loss minus the ceiling's) is
    found; the axis whose top cell is the most concentrated (its share of the excess over its
    share of the readings) is named, with the cell's share of the excess and whether the
    readings that carry it are brighter or darker than the extended model there (or some of
    each: a gamma that changes across the screen is brighter on one side, darker on the
    other). A second axis is named too where its top cell holds at least twice its share of
    the readings.

    ``fits``: ``[(train, test, fitted, ceiling_loss), ...]`` per fold (see
    engine.diagnose_losses; ``ceiling_loss`` from `display_ceiling`, in the test's row order).
    """
    rows = []
    for _train, test, fitted, ceiling_loss in fits:
        mu = _mean(test, list(fitted))
        conds = {f"_v_{c}": test[c].to_numpy() for c in test.attrs.get("conditions", [])}
        resid = (test["L"].to_numpy(float) - mu) / test["sd"].to_numpy(float)
        resid[test["censored"].to_numpy(bool)] = np.nan
        rows.append(pd.DataFrame(_where_cells(test) | conds | {
            "resid": resid,
            "excess": display_loss(test, list(fitted)) - np.asarray(ceiling_loss, float),
            "brighter": test["L"].to_numpy(float) > mu,
            "x": test["x_norm"].to_numpy(float), "y": test["y_norm"].to_numpy(float)}))
    if not rows:
        return ""
    data = pd.concat(rows, ignore_index=True)
    data["pos_excess"] = data["excess"].clip(lower=0.0)
    ranked = []
    follow = _following(data, fits[0][1].attrs.get("conditions", []))
    axes = [a for a in _where_cells(fits[0][1]) if a in data]
    if follow and _time_explained_by_conditions(fits[0][1])[0] >= _CONFOUNDED_R2:
        axes.remove("time in the run")  # the run's time is the conditions' blocks
    for axis in axes:
        net = data.groupby(axis)["excess"].sum()
        total = float(net.clip(lower=0.0).sum())
        if net.size < 2 or total <= 0:
            continue
        cell = net.idxmax()
        share = float(max(net[cell], 0.0)) / total
        ranked.append((share * len(data) / int((data[axis] == cell).sum()), axis, cell, share))
    if not ranked:
        return follow
    ranked.sort(key=lambda r: r[0], reverse=True)
    words = []
    for rank, (lift, axis, cell, share) in enumerate(ranked[:2]):
        if rank and lift < 2:
            break
        words.append(f"at {cell} (readings {_side(data[data[axis] == cell])}; "
                     f"{100 * share:.0f} % of the excess)")
    return (f"{follow}; " if follow else "") + "mostly " + ", and ".join(words)


def _side(cell: pd.DataFrame) -> str:
    """Brighter or darker than the extended model, where >= 75 % of the cell's excess is on one
    side; else which side of the screen is brighter, where the brighter readings'
    excess-weighted mean x (or y) differs from the darker ones' by more than a third of the
    screen (2 / 3 in normalised units)."""
    w = cell["pos_excess"].to_numpy(float)
    up = cell["brighter"].to_numpy(bool)
    frac = float(w[up].sum() / max(w.sum(), 1e-300))
    if frac >= 0.75:
        return "brighter than the extended model"
    if frac <= 0.25:
        return "darker than the extended model"
    best = ""
    for col, (lo, hi) in (("x", ("left", "right")), ("y", ("bottom", "top"))):
        v = cell[col].to_numpy(float)
        d = (np.average(v[up], weights=w[up] + 1e-300)
             - np.average(v[~up], weights=w[~up] + 1e-300))
        if abs(d) > 2 / 3 and (not best or abs(d) > best[0]):
            side = hi if d > 0 else lo
            other = lo if d > 0 else hi
            words = f"brighter than the extended model towards the {side}, darker towards the"
            best = (abs(d), f"{words} {other}")
    return best[1] if best else "some brighter, some darker than the extended model"


def localise_display(data: pd.DataFrame, rng: np.random.Generator,
                     n_boot: int = 1000) -> pd.DataFrame:
    """Mean relative residual (100 (L - mu0) / mu0, %) over the luminance range (the
    calibration's luminance fraction in 5 bins) and per screen position, with 95 % bootstrap
    CIs over readings. Generic localisation columns: axis, cell, n, mean_residual, ci_low,
    ci_high."""
    res = 100 * (data["L"] - data["mu0"]).to_numpy(float) / np.maximum(
        data["mu0"].to_numpy(float), 1e-6)
    cal = data.attrs["cal"]
    frac = (data["mu0"].to_numpy(float) - cal.min_luminance_cd_m2) / (
        cal.max_luminance_cd_m2 - cal.min_luminance_cd_m2)
    rows = []
    for axis, labels in (("luminance fraction", _fifths(frac)),
                         ("screen position (x, y norm)", _positions(data))):
        frame = pd.DataFrame({"cell": labels, "res": res})
        for cell, grp in frame.groupby("cell"):
            v = grp["res"].to_numpy()
            b = v[rng.integers(0, v.size, (n_boot, v.size))].mean(axis=1)
            lo, hi = np.percentile(b, [2.5, 97.5])
            rows.append({"axis": axis, "cell": cell, "n": v.size, "mean_residual": v.mean(),
                         "ci_low": lo, "ci_high": hi, "unit": "% of predicted luminance"})
    return pd.DataFrame(rows)
