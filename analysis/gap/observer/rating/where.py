"""Where a rating study's remaining gap lies: stimulus to stimulus (consistently across
participants, or not), per participant, or along the factor.

The held-out residuals of the chosen model (response - its expected response, scale units)
are averaged per stimulus; their consistency is the split-half correlation of the stimulus
means of two halves of the participants (alternate participants in sorted order;
Spearman-Brown corrected to all participants), and their size the SD of the stimulus means
less their sampling noise (reliability-corrected). :func:`stimulus_deviations` computes these
figures; :func:`rating_where` says them in words; :func:`localise_rating` is the report's
table (per stimulus, against the plain simulation).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from analysis.gap.observer.rating.model import _fit_sigma, rating_expected, rating_predict

__all__ = ["localise_rating", "rating_misfit", "rating_misfit_terms", "rating_tolerance",
           "rating_unit", "rating_where", "stimulus_deviations"]

_TOP = 5  # stimuli named in the words


def _residuals(fits, cands: dict) -> pd.DataFrame:
    rows = []
    for train, test, fitted, _ in fits:
        sigma = _fit_sigma(train, rating_predict(train, fitted, cands))
        e = rating_expected(test, rating_predict(test, fitted, cands), sigma)
        rows.append(pd.DataFrame({"participant": test["participant"].to_numpy(str),
                                  "stimulus": test["stimulus"].to_numpy(str),
                                  "factor": test["factor"].to_numpy(float),
                                  "res": test["response"].to_numpy(float) - e}))
    return pd.concat(rows, ignore_index=True)


def stimulus_deviations(res: pd.DataFrame) -> dict:
    """Figures of the per-stimulus deviation from residuals (columns participant, stimulus,
    factor, res): ``table`` (per stimulus: factor, mean, n, half_a, half_b), ``split_half_r``
    (halves of the participants), ``reliability`` (Spearman-Brown), ``sd`` (raw SD of the
    stimulus means), ``sd_true`` (less their sampling noise), ``share_stimulus`` (share of the
    residual variance the stimulus means hold), ``share_participant``, ``halves``."""
    parts = sorted(res["participant"].unique())
    half = {p: i % 2 for i, p in enumerate(parts)}
    res = res.assign(half=res["participant"].map(half))
    by = res.groupby("stimulus")
    table = pd.DataFrame({"factor": by["factor"].first(), "mean": by["res"].mean(),
                          "n": by["res"].size(), "var": by["res"].var(ddof=1)})
    halves = res.groupby(["stimulus", "half"])["res"].mean().unstack()
    table["half_a"], table["half_b"] = halves.get(0), halves.get(1)
    ok = table[["half_a", "half_b"]].notna().all(axis=1)
    r = (float(np.corrcoef(table.loc[ok, "half_a"], table.loc[ok, "half_b"])[0, 1])
         if ok.sum() > 2 and len(parts) > 1 else float("nan"))
    rel = 2 * r / (1 + r) if np.isfinite(r) and r > -1 else float("nan")
    noise = float(np.nanmean(table["var"] / table["n"]))
    sd = float(table["mean"].std(ddof=1))
    total = float(res["res"].var(ddof=1))
    stim_var = float(res.groupby("stimulus")["res"].transform("mean").var(ddof=1))
    part_var = float(res.groupby("participant")["res"].transform("mean").var(ddof=1))
    return {"table": table.sort_values("factor"), "split_half_r": r, "reliability": rel,
            "sd": sd, "sd_true": float(np.sqrt(max(sd ** 2 - noise, 0.0))),
            "share_stimulus": stim_var / max(total, 1e-12),
            "share_participant": part_var / max(total, 1e-12),
            "halves": ([p for p in parts if half[p] == 0], [p for p in parts if half[p] == 1])}


def _smooth_r2(table: pd.DataFrame) -> float:
    """Share of the stimulus means' variance a cubic in the factor holds."""
    x, y = table["factor"].to_numpy(float), table["mean"].to_numpy(float)
    if y.size < 6 or np.var(y) == 0:
        return 0.0
    fit = np.polyval(np.polyfit(x, y, 3), x)
    return float(1 - np.var(y - fit) / np.var(y))


def rating_where(fits, cands: dict, estimates: str) -> str:
    """Words for where the remaining gap lies (``fits`` as the engine gives them)."""
    res = _residuals(fits, cands)
    dev = stimulus_deviations(res)
    t = dev["table"]
    smooth = _smooth_r2(t)
    a, b = dev["halves"]
    top = t.reindex(t["mean"].abs().sort_values(ascending=False).index[:_TOP])
    named = ", ".join(f"{s} ({estimates} {f:g}: {m:+.2f})"
                      for s, f, m in zip(top.index, top["factor"], top["mean"]))
    figures = (f"the stimuli's mean deviations have an SD of {dev['sd_true']:.2f} scale units "
               f"beyond their sampling noise, split-half r {dev['split_half_r']:.2f} between "
               f"participants {', '.join(a)} and {', '.join(b)} "
               f"(Spearman-Brown {dev['reliability']:.2f}), and hold "
               f"{100 * dev['share_stimulus']:.0f} % of the residual variance; deviating most: "
               f"stimulus {named}")
    if dev["share_participant"] > 2 * dev["share_stimulus"]:
        return (f"in the responses, differing between participants ({100 * dev['share_participant']:.0f} % "
                f"of the residual variance lies in participants' means); {figures}")
    if smooth > 0.5:
        return f"in the responses, a smooth function of {estimates} ({figures})"
    consistent = np.isfinite(dev["split_half_r"]) and dev["split_half_r"] >= 0.5
    how = ("consistently across participants" if consistent
           else "not consistently across participants")
    return (f"in the responses, from stimulus to stimulus, {how}, without a smooth trend in "
            f"{estimates}: {figures}")


def localise_rating(data: pd.DataFrame, fitted: list, cands: dict,
                    rng: np.random.Generator, n_boot: int = 500) -> pd.DataFrame:
    """Per stimulus (sorted by the factor): the mean residual of the responses against the
    chosen model fitted to all trials (scale units) with a 95 % bootstrap CI over trials, and
    the two halves of the participants' means (the report's 'where' table)."""
    sigma = _fit_sigma(data, rating_predict(data, fitted, cands))
    e = rating_expected(data, rating_predict(data, fitted, cands), sigma)
    res = pd.DataFrame({"participant": data["participant"].to_numpy(str),
                        "stimulus": data["stimulus"].to_numpy(str),
                        "factor": data["factor"].to_numpy(float),
                        "res": data["response"].to_numpy(float) - e})
    dev = stimulus_deviations(res)
    rows = []
    for stim, row in dev["table"].iterrows():
        v = res.loc[res["stimulus"] == stim, "res"].to_numpy()
        boot = v[rng.integers(0, v.size, (n_boot, v.size))].mean(axis=1)
        lo, hi = np.percentile(boot, [2.5, 97.5])
        rows.append({"axis": f"stimulus (by {data.attrs['estimates']})", "cell": stim,
                     data.attrs["estimates"]: row["factor"], "n": int(row["n"]),
                     "mean_residual": row["mean"], "ci_low": lo, "ci_high": hi,
                     "half_a": row["half_a"], "half_b": row["half_b"],
                     "unit": "scale units"})
    out = pd.DataFrame(rows)
    out.attrs["split_half_r"] = dev["split_half_r"]
    return out


# How far: the misfit in the rating scale's own units (issue 38).
#
# How far the simulated rating observer is off, in the rating scale's own units (observer
# layer, another lab's study; the two-response layer's :func:`analysis.gap.observer.where.observer_misfit`).
#
# On the held-out trials: how far the expected rating of the plain simulation and of the
# chosen model lies from that of the flexible model of the data (the ceiling built on the
# chosen model, :func:`analysis.gap.observer.rating.ceiling.rating_ceiling_fit`), RMS over
# trials, in scale units; and how far held-out ratings scatter about the flexible model's
# expected rating (their noise, which no model of the mean removes). Each expected rating is
# read out on the scale's own steps at the flexible model's noise SD and without lapses, so the
# misfit is the latent means' (a uniformly noisier lab, or lapses the catalogue names, are no
# distance on the scale). The chosen model's misfit is the size held to the tolerance: the
# design's ``[gap] observer_tolerance_slider`` as the same share of the study's scale as of the
# design's slider (:func:`rating_tolerance`).


def rating_unit(study) -> str:
    """The misfit's unit in words: 'rating units' (of the study's scale; ``study`` for a
    scale that names its own unit one day)."""
    return "rating units"


def rating_tolerance(design, study) -> tuple[float, str]:
    """``(tolerance in scale units, where it comes from)``: the design's
    ``observer_tolerance_slider`` as a share of its slider's span, times the study's span."""
    s = design.slider
    share = float(design.gap.observer_tolerance_slider) / (float(s.max) - float(s.min))
    lo, hi = study.scale
    words = (f"{100 * share:.3g} % of the scale {lo:g}-{hi:g}: the design's [gap] "
             "observer_tolerance_slider as a share of its slider's span")
    return share * (float(hi) - float(lo)), words


def rating_misfit(fits: list, ceilings: dict, cands: dict, unit: str) -> dict:
    """The misfits of the plain simulation and the chosen model against the ceiling, and the
    ratings' scatter about the ceiling, on every fold's held-out trials.

    Parameters
    ----------
    fits : list of (train, test, chosen, ceiling loss)
        Per fold, as :func:`analysis.gap.engine.steps.remaining_gap` hands the layer's size.
    ceilings : dict
        ``{id(test): ceiling}`` (:func:`rating_ceiling_fit` on that fold's chosen model).
    cands : dict
        The candidates by name.
    unit : str
        The scale's unit in words (:func:`rating_unit`).

    Returns
    -------
    dict
        The :class:`Diagnosis` fields ``misfit_before``, ``misfit_after``, ``misfit_ceiling``
        (scale units), ``misfit_unit`` and ``misfit_by_response`` (``{"rating": ...}``).
    """
    sums, n = np.zeros(3), 0
    for _train, test, chosen, _ in fits:
        pred_c, sigma = ceilings[id(test)](test)
        y = test["response"].to_numpy(float)

        e_c = _expected(test, pred_c, sigma)
        plain = _expected(test, rating_predict(test, [], cands), sigma)
        after = _expected(test, rating_predict(test, list(chosen), cands), sigma)
        sums += (float(np.sum((plain - e_c) ** 2)), float(np.sum((after - e_c) ** 2)),
                 float(np.sum((y - rating_expected(test, pred_c, sigma)) ** 2)))
        n += len(test)
    if n == 0:
        return {}
    before, after, scatter = (float(v) for v in np.sqrt(sums / n))
    return {"misfit_before": before, "misfit_after": after, "misfit_ceiling": scatter,
            "misfit_unit": unit,
            "misfit_by_response": {"rating": {
                "unit": unit, "before": before,
                "after": after, "ceiling": scatter}}}


def rating_misfit_terms(fits: list, ceilings: dict, cands: dict) -> tuple:
    """Per held-out trial the squared distance (scale units^2) of the chosen model's expected
    rating from the ceiling's, and the trial's participant (the independent unit: each
    participant's trials share their own gain and offset); ``fits``, ``ceilings`` and
    ``cands`` as :func:`rating_misfit` takes them."""
    terms, units = [], []
    for _train, test, chosen, _ in fits:
        pred_c, sigma = ceilings[id(test)](test)
        after = _expected(test, rating_predict(test, list(chosen), cands), sigma)
        terms.append((after - _expected(test, pred_c, sigma)) ** 2)
        units.append(test["participant"].astype(str).to_numpy())
    if not terms:
        return np.zeros(0), np.zeros(0, dtype=object)
    return np.concatenate(terms), np.concatenate(units)


def _expected(data, pred: dict, sigma: float) -> np.ndarray:
    """Expected rating without lapses at noise SD ``sigma`` (scale units)."""
    return rating_expected(data, {**pred, "lapse": 0.0}, sigma)
