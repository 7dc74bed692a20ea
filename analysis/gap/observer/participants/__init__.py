"""Single participants who depart from the rest (observer layer, issue 43).

The misfit (:func:`analysis.gap.observer.where.observer_misfit`) compares the chosen model's
predicted settings with a flexible model of the *population's* settings by stimulus and time
on task; where participants are held out whole, one participant who does something the others
do not (now and then sets gloss on the depth slider and back, answers at random on a share of
the trials, misunderstood the task) moves that flexible model by a twentieth of their
behaviour and is all but invisible to it. A lab reading "no gap that matters" would then keep a
participant the simulation could never have produced.

:func:`participant_departures` asks of each participant whether their settings scatter about
the chosen model's prediction far more than the other participants' do, once their own offset
and slopes are taken out (a person's own offset is not a gap): the within-person residual mean
square of both responses, ``v_p`` (slider units^2), against the others' on a log scale, their
robust centre and spread (median and 1.4826 x MAD, leave-one-out; the spread at least
:data:`MIN_LOG_SPREAD`), widened by ``v_p``'s own sampling error; one-sided p-values, Holm
across participants. Natural differences in noise
between people (a noise SD of 0.6 to 1.1 slider units is usual) sit inside the others'
spread; a participant who swapped the sliders on a third of their trials scatters 4-5 times
as much. Beside the scatter, the correlation of a participant's gloss and depth errors is held
against the others' the same way (Fisher's z, two-sided): a participant who swaps the sliders
on one trial in ten scatters only 1.4 times the others' median, as ordinary as the noisiest of
them, but their two errors move against each other (a swapped trial's gloss error is minus its
depth error), which nobody else's do. The smaller of the two p-values counts, doubled.

Its size is in the misfit's units: each participant's excess mean square beyond the upper end
of what the others allow (their 95th percentile), summed over their trials and spread over
every trial, ``sqrt(sum_p n_p max(v_p - ref_p, 0) / N)`` slider units; the upper 95 % bound
takes ``v_p``'s upper 95 % bound (chi-square on the participant's residual degrees of freedom).
Fewer than :data:`MIN_PARTICIPANTS` participants: the others' spread cannot be estimated, the
check is not made, and no gap can be excluded on this count.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy import stats

from analysis.gap.engine import holm
from analysis.gap.observer.model import RESP, predict

__all__ = ["MIN_PARTICIPANTS", "participant_departures"]

#: Participants needed to judge one against the others (leave-one-out: 2 others).
MIN_PARTICIPANTS = 3

#: The least spread of people's log residual variance taken as ordinary (SD, natural log):
#: noise SDs about 16 % apart (1 SD) from person to person. Fitted pilots here put the
#: between-observer spread of the noise SD at 9-15 % of its mean (``experiment
#: fit-observer``: depth 0.025 of 0.29 cm, gloss 1.3 of 8.6 %), i.e. 0.18-0.30 in log variance;
#: a few others' median absolute deviation cannot be trusted to be wider than that.
MIN_LOG_SPREAD = 0.3

_OWN_TERMS = 3  # per response: the participant's own intercept, gloss and depth slopes


def _own_residuals(test: pd.DataFrame, fitted: list) -> pd.DataFrame:
    """Residuals of ``test``'s settings from the chosen model's mean, per trial and response,
    with each participant's own intercept and slopes (on gloss and depth) taken out by least
    squares."""
    mu = predict(test, list(fitted))["mu"]
    rows = []
    for who, idx in test.groupby("participant").indices.items():
        part = test.iloc[idx]
        x = np.c_[np.ones(len(part)), part["gloss_u"].to_numpy(float),
                  part["depth_u"].to_numpy(float)]
        res = {}
        for r in RESP:
            y = part[f"{r}_match"].to_numpy(float) - mu[r][idx]
            b = np.linalg.lstsq(x, y, rcond=None)[0]
            res[r] = y - x @ b
        rows.append(pd.DataFrame({"participant": str(who), **{r: res[r] for r in RESP}}))
    return pd.concat(rows, ignore_index=True) if rows else pd.DataFrame()


def _others(values: np.ndarray, i: int, least: float = MIN_LOG_SPREAD) -> tuple[float, float]:
    """Median and 1.4826 x MAD of ``values`` without entry ``i``, the spread at least
    ``least``."""
    rest = np.delete(values, i)
    centre = float(np.median(rest))
    return centre, max(float(1.4826 * np.median(np.abs(rest - centre))), least)


def _scatter_tests(v: np.ndarray, log_v: np.ndarray, dof: np.ndarray):
    """Per participant: the one-sided p-value of their mean square ``v`` against the others'
    (log scale, :func:`_others`, widened by its own sampling SD on ``dof`` degrees of
    freedom), the top of the others' spread (their 95th percentile) and ``v``'s upper 95 %
    bound (chi-square)."""
    k = len(v)
    p, ref, v_hi = np.empty(k), np.empty(k), np.empty(k)
    for i in range(k):
        centre, spread = _others(log_v, i)
        own_sd = np.sqrt(2.0 / dof[i])  # SD of log v_p from sampling alone
        z = (log_v[i] - centre) / np.sqrt(spread ** 2 * (1 + 1 / (k - 1)) + own_sd ** 2)
        p[i] = float(stats.norm.sf(z))
        ref[i] = float(np.exp(centre + stats.norm.ppf(0.95) * spread))
        v_hi[i] = v[i] * dof[i] / float(stats.chi2.ppf(0.05, dof[i]))
    return p, ref, v_hi


def _correlation_tests(res: pd.DataFrame, parts: list, n: np.ndarray):
    """Per participant the correlation of their gloss and depth residuals, a two-sided p-value
    against the others' (Fisher's z, the others' median and 1.4826 x MAD, at least the
    sampling SD of one participant's z), and the others' median correlation."""
    corr = np.array([float(np.corrcoef(res.loc[res["participant"] == q, RESP[0]],
                                       res.loc[res["participant"] == q, RESP[1]])[0, 1])
                     for q in parts])
    z = np.arctanh(np.clip(np.nan_to_num(corr), -0.999, 0.999))
    p, others = np.empty(len(parts)), np.empty(len(parts))
    for i in range(len(parts)):
        sampling = 1.0 / np.sqrt(max(n[i] - 2 * _OWN_TERMS, 2.0))
        centre, spread = _others(z, i, least=sampling)
        stat = (z[i] - centre) / (spread * np.sqrt(1 + 1 / (len(parts) - 1)))
        p[i] = float(2 * stats.norm.sf(abs(stat)))
        others[i] = float(np.tanh(centre))
    return corr, p, others


def participant_departures(fits: list, tolerance: float, *, alpha: float = 0.05) -> dict:
    """Whether single participants' settings depart from the others' (module docstring).

    Parameters
    ----------
    fits : list
        ``[(train, test, chosen, ...), ...]`` per fold (held-out frames of
        :func:`analysis.gap.observer.data.observer_frame` and the chosen effects).
    tolerance : float
        The design's ``[gap] observer_tolerance_slider`` (slider units).
    alpha : float
        Level of the Holm-adjusted one-sided tests.

    Returns
    -------
    dict
        ``tested`` (bool; False with fewer than :data:`MIN_PARTICIPANTS` participants, then
        ``reason``), ``size`` and ``size_upper`` (slider units), ``tolerance``,
        ``significant`` (some participant departs, Holm p < ``alpha``, and the size is at
        least the tolerance), ``departing`` (per flagged participant: ``participant``,
        ``scatter_ratio`` (their residual RMS over the others' median),
        ``error_correlation`` and ``others_error_correlation`` (their gloss and depth
        residuals' correlation, the others' median), ``p_holm``, ``trials``), ``where``
        (words) and ``per_participant`` (every participant's ``rms``, ``p``, ``p_holm``).
    """
    res = pd.concat([_own_residuals(te, ch) for _, te, ch, *_ in fits], ignore_index=True)
    out = {"tested": False, "tolerance": float(tolerance), "significant": False,
           "size": float("nan"), "size_upper": float("nan"), "departing": [], "where": "",
           "per_participant": []}
    parts = sorted(res["participant"].unique()) if len(res) else []
    if len(parts) < MIN_PARTICIPANTS:
        out["reason"] = (f"with {len(parts)} participant(s) (fewer than {MIN_PARTICIPANTS}) one "
                         "participant's departure from the others (swapped sliders, random "
                         "answers) cannot be told from ordinary differences between people, "
                         "so it is not tested")
        return out
    sq = sum(res[r].to_numpy(float) ** 2 for r in RESP)
    grouped = pd.Series(sq).groupby(res["participant"].to_numpy())
    n = grouped.size().reindex(parts).to_numpy(float)
    v = grouped.mean().reindex(parts).to_numpy(float)
    dof = np.maximum(len(RESP) * (n - _OWN_TERMS), 1.0)
    log_v = np.log(np.maximum(v, 1e-12))
    p, ref, v_hi = _scatter_tests(v, log_v, dof)
    corr, p_corr, corr_others = _correlation_tests(res, parts, n)
    # Either test may show a departure: the smaller p, doubled (Bonferroni within a person).
    p = np.minimum(1.0, 2.0 * np.minimum(p, p_corr))
    p_adj = holm(p)
    flagged = [i for i in np.argsort(p) if p_adj[i] < alpha]
    total = float(n.sum())
    size = float(np.sqrt(np.sum(n * np.maximum(v - ref, 0.0)) / total))
    upper = float(np.sqrt(np.sum(n * np.maximum(v_hi - ref, 0.0)) / total))
    median_rms = float(np.sqrt(np.median(v)))
    departing = [{"participant": parts[i], "scatter_ratio": float(np.sqrt(v[i]) / median_rms),
                  "error_correlation": float(corr[i]),
                  "others_error_correlation": float(corr_others[i]),
                  "p_holm": float(p_adj[i]), "trials": int(n[i])} for i in flagged]
    out.update(tested=True, size=size, size_upper=upper, departing=departing,
               significant=bool(departing) and size >= tolerance,
               per_participant=[{"participant": q, "rms": float(np.sqrt(v[i])),
                                 "p": float(p[i]), "p_holm": float(p_adj[i])}
                                for i, q in enumerate(parts)])
    if departing:
        who = ", ".join(f"{d['participant']} ({d['scatter_ratio']:.1f}x, gloss and depth errors "
                        f"correlated {d['error_correlation']:+.2f} against the others' "
                        f"{d['others_error_correlation']:+.2f})" for d in departing)
        verb = "departs" if len(departing) == 1 else "depart"
        out["where"] = (f"in single participants: {who} {verb} from the others once their own "
                        "offset and slopes are taken out (scatter about the chosen model, or "
                        "gloss and depth errors that move together or against each other: "
                        "swapped sliders, random answers on some trials, or a misunderstood "
                        "task?); look at their sessions")
    return out
