"""Fit the simulated observers (``experiment/observers.toml``) to a lab's own session data.

A two-stage hierarchical maximum-likelihood fit of the ``humanlike`` model of
:mod:`experiment.observers` (the same equations, in physical units)::

    depth_hat = m_d + b_d (depth - m_d) + a_d + e_d,               e_d ~ N(0, s_d)
    gloss_hat = m_g + b_g (gloss - m_g) + c (depth - m_d) + k (gloss - m_g)(depth - m_d)
                + a_g + e_g,                                         e_g ~ N(0, s_g)
    log rt    ~ N(log rt_median, rt_log_sd)

1. **Each participant** (stage 1): the answers, converted from slider positions to cm and % by the
   design's slider (:meth:`studydesign.SliderSpec.to_depth_cm`, ``to_gloss_pct``), are fitted by
   maximum likelihood with the slider's ends as censoring points (a Tobit model: an answer at
   ``slider.min`` says only "at most this", one at ``slider.max`` "at least this"; a real slider
   clips there, and at the extreme gloss levels a large share of answers sit at an end, so an
   ordinary least-squares or MixedLM fit would pull the slopes towards zero). This gives each
   participant's ten parameters and their standard errors (observed information).
2. **The population** (stage 2): for each parameter, the participants' estimates ``theta_i`` with
   standard errors ``s_i`` are modelled as ``theta_i ~ N(mean, sd^2 + s_i^2)``, and ``mean`` and the
   between-observer ``sd`` are fitted by restricted maximum likelihood (REML, as lme4 and statsmodels'
   MixedLM do by default: ML would bias the variances down by about 1/k, 9 % with 11
   participants). This separates the true spread between observers from each estimate's own
   noise. The noise SDs and response-time parameters, whose SEs grow with their own value, are
   weighted by their relative SEs (see :func:`fit_observer_params`).

The exact one-stage likelihood of a mixed model with censored answers has no closed form (it
integrates a multivariate normal CDF over the random effects); the two-stage fit is exact within a
participant and uses the normal approximation of each participant's estimate, which with the
study's full set of trials per participant is close (see ``bench/experiment_observer_recovery.py`` for the measured
recovery). Where nothing is censored it agrees with statsmodels' MixedLM (REML, independent
random intercept and slope) to a small fraction of a standard error
(``tests/experiment/test_observer_fit.py``). The ``ideal`` observer (truth + noise) is fitted too, by censored ML pooled over all
trials, so that a fitted file holds both kinds, as the shipped one does.
"""

from __future__ import annotations

import math
import warnings
from datetime import UTC, datetime

import numpy as np
import pandas as pd
from scipy import optimize, special

from experiment.datafile import simulated_rows
from studydesign import StudyDesign

__all__ = ["ObserverFitError", "ObserverFitWarning", "fit_observer_params"]

#: Stage-1 parameters of one participant, in the order of ``observers.toml``'s humanlike table.
HUMANLIKE_PARAMS = ("depth_slope", "depth_intercept_cm", "depth_noise_cm", "gloss_slope",
                    "gloss_intercept_pct", "crosstalk_pct_per_cm", "interaction_per_cm",
                    "gloss_noise_pct", "rt_median_s", "rt_log_sd")
_NEEDED_COLUMNS = ("participant", "session", "true_gloss_pct", "true_depth_cm", "gloss_match",
                   "depth_match", "rt_s", "app_version")
#: A participant needs this many answered trials (the gloss fit has 5 parameters).
MIN_TRIALS_PER_PARTICIPANT = 20
#: Slider positions this close to slider.min / slider.max count as at the end (slider units).
_END_TOL = 1e-6
_LOG_2PI = math.log(2.0 * math.pi)


class ObserverFitError(ValueError):
    """Session data an observer cannot be fitted to; the message names the problem and the fix."""


class ObserverFitWarning(UserWarning):
    """Data that can be fitted but deserves a look (e.g. simulated rows among real ones)."""


# ----------------------------------------------------------------------------- stage 1: Tobit
def _tobit_nll(theta, y, X, offset, left, right, lo, hi):
    """Negative log-likelihood and gradient of a censored normal regression.

    ``y ~ N(offset + X beta, sigma)``, observed exactly except where ``left`` (the answer is at
    the lower end: only ``y* <= lo`` is known) or ``right`` (``y* >= hi``). ``theta`` is
    ``(beta, log sigma)``.
    """
    beta, log_s = theta[:-1], theta[-1]
    s = math.exp(log_s)
    mu = offset + X @ beta
    mid = ~(left | right)
    z = (y[mid] - mu[mid]) / s
    a = (lo - mu[left]) / s
    b = (mu[right] - hi) / s
    ll = (-0.5 * np.sum(z * z) - mid.sum() * (log_s + 0.5 * _LOG_2PI)
          + np.sum(special.log_ndtr(a)) + np.sum(special.log_ndtr(b)))
    # d log Phi(x) / dx = phi(x) / Phi(x) (the inverse Mills ratio), computed in logs.
    lam_a = np.exp(-0.5 * a * a - 0.5 * _LOG_2PI - special.log_ndtr(a))
    lam_b = np.exp(-0.5 * b * b - 0.5 * _LOG_2PI - special.log_ndtr(b))
    d_mu = np.zeros_like(mu)
    d_mu[mid] = z / s
    d_mu[left] = -lam_a / s
    d_mu[right] = lam_b / s
    g_beta = X.T @ d_mu
    g_log_s = np.sum(z * z - 1.0) - np.sum(lam_a * a) - np.sum(lam_b * b)
    return -ll, -np.append(g_beta, g_log_s)


def _tobit_fit(y, X, offset, left, right, lo, hi, who: str):
    """Censored ML fit -> (beta, sigma, covariance of (beta, sigma), log-likelihood)."""
    X = np.asarray(X, float).reshape(len(y), -1)
    mid = ~(left | right)
    if mid.sum() < X.shape[1] + 2:
        raise ObserverFitError(f"{who}: only {int(mid.sum())} answers lie inside the slider's "
                               "range (the rest are at its ends); the fit cannot separate the "
                               "parameters. Leave this participant out")
    start_beta = (np.linalg.lstsq(X[mid], (y - offset)[mid], rcond=None)[0] if X.shape[1]
                  else np.zeros(0))
    resid = (y - offset - X @ start_beta)[mid]
    if np.std(resid) <= 1e-9 * max(1.0, abs(lo), abs(hi)):
        raise ObserverFitError(f"{who}: the answers have no trial-to-trial spread (the same "
                               "answer on every trial?); the noise cannot be fitted. Look at this "
                               "participant's answers or leave the participant out")
    start = np.append(start_beta, math.log(max(np.std(resid), 1e-6)))
    args = (y, X, offset, left, right, lo, hi)
    res = optimize.minimize(_tobit_nll, start, args=args, jac=True, method="BFGS",
                            options={"gtol": 1e-8, "maxiter": 2000})
    grad = res.jac
    if not np.all(np.isfinite(res.x)) or np.max(np.abs(grad)) > 1e-3:
        raise ObserverFitError(f"{who}: the censored fit did not converge ({res.message}); "
                               "look at this participant's answers (all at the slider's ends?)")
    # Observed information by central differences of the analytic gradient.
    n = res.x.size
    hess = np.empty((n, n))
    for j in range(n):
        h = 1e-5 * max(1.0, abs(res.x[j]))
        e = np.zeros(n)
        e[j] = h
        hess[:, j] = (_tobit_nll(res.x + e, *args)[1] - _tobit_nll(res.x - e, *args)[1]) / (2 * h)
    hess = 0.5 * (hess + hess.T)
    try:
        cov = np.linalg.inv(hess)
    except np.linalg.LinAlgError as exc:
        raise ObserverFitError(f"{who}: the parameters are not identified (singular "
                               "information); does the participant see several gloss and depth "
                               "levels?") from exc
    # ML divides the residual variance by n, not n - p: scale sigma as the unbiased
    # least-squares variance would be (exact without censoring, close with a few censored).
    if not np.all(np.isfinite(cov)) or np.any(np.diag(cov) <= 0):
        raise ObserverFitError(f"{who}: the fit's information matrix is not positive definite "
                               "(answers that do not vary?); look at this participant's answers "
                               "or leave the participant out")
    sigma = math.exp(res.x[-1]) * math.sqrt(len(y) / (len(y) - X.shape[1]))
    jac = np.eye(n)
    jac[-1, -1] = sigma  # delta method: log sigma -> sigma
    return res.x[:-1], sigma, jac @ cov @ jac.T, -float(res.fun)


# ---------------------------------------------------------------------- stage 2: the population
#: Parameters whose standard error grows with the value itself (SDs, the median RT).
_SCALE_PARAMS = ("depth_noise_cm", "gloss_noise_pct", "rt_median_s", "rt_log_sd")


def _population_reml(theta, se):
    """REML fit of ``theta_i ~ N(mean, sd^2 + se_i^2)`` -> dict of mean, sd, their SEs, loglik.

    The SE of ``mean`` is ``(sum w_i)^-1/2``, ``w_i = 1 / (sd^2 + se_i^2)``, widened by the
    modified Knapp-Hartung factor ``max(1, (Q / (k - 1))^1/2)``, ``Q = sum w_i (theta_i - mean)^2``
    (Knapp & Hartung 2003; Roever et al. 2015): with about 11 participants the plain REML SE is
    too small, and ``mean +- t(k-1) SE`` then covers the truth about 95 % of the time.
    The SE of ``sd`` comes from the REML information of ``sd^2`` (``I = tr(P^2) / 2``) as the
    change of ``sd`` that moves ``sd^2`` up by one SE: ``(sd^2 + SE(sd^2))^1/2 - sd`` (the delta
    method's ``SE(sd^2) / (2 sd)`` for a large ``sd``, finite on the boundary ``sd = 0``).
    """
    theta = np.asarray(theta, float)
    var_e = np.asarray(se, float) ** 2
    k = theta.size

    def parts(tau2):
        w = 1.0 / (tau2 + var_e)
        mean = float(np.sum(w * theta) / np.sum(w))
        ll = -0.5 * (np.sum(np.log(tau2 + var_e)) + np.sum(w * (theta - mean) ** 2)
                     + math.log(np.sum(w)) + (k - 1) * _LOG_2PI)
        return mean, w, ll

    scale = float(np.var(theta) + np.max(var_e)) * 10 + 1e-12
    res = optimize.minimize_scalar(lambda t: -parts(t * t)[2], bounds=(0.0, math.sqrt(scale)),
                                   method="bounded", options={"xatol": 1e-10})
    tau = float(res.x)
    if parts(0.0)[2] >= parts(tau * tau)[2]:
        tau = 0.0
    mean, w, ll = parts(tau * tau)
    sw = np.sum(w)
    q = float(np.sum(w * (theta - mean) ** 2))
    se_mean = math.sqrt(1.0 / sw) * max(1.0, math.sqrt(q / (k - 1)))
    tr_p2 = np.sum(w ** 2) - 2 * np.sum(w ** 3) / sw + np.sum(w ** 2) ** 2 / sw ** 2
    se_tau2 = math.sqrt(2.0 / tr_p2) if tr_p2 > 0 else math.inf
    se_tau = math.sqrt(tau * tau + se_tau2) - tau
    return {"mean": mean, "sd": tau, "se_mean": float(se_mean), "se_sd": float(se_tau),
            "loglik": float(ll)}


# -------------------------------------------------------------------------------- data checks
def _check_frame(sessions: pd.DataFrame, simulated_sessions) -> pd.DataFrame:
    """Refuse what cannot be fitted; warn about simulated rows among real ones."""
    if not isinstance(sessions, pd.DataFrame) or sessions.empty:
        raise ObserverFitError("no session rows to fit: give the lab's session CSVs "
                               "(data/sessions/<participant>_s<n>.csv)")
    missing = [c for c in _NEEDED_COLUMNS if c not in sessions.columns]
    if missing:
        raise ObserverFitError(f"session rows lack the columns {missing}; read them with "
                               "experiment.read_session")
    frame = sessions.copy()
    frame["participant"] = frame["participant"].astype(str)
    numeric = ["true_gloss_pct", "true_depth_cm", "gloss_match", "depth_match", "rt_s"]
    frame[numeric] = frame[numeric].apply(pd.to_numeric, errors="coerce")
    bad = ~np.isfinite(frame[numeric].to_numpy(float)).all(axis=1)
    if bad.any():
        rows = frame.loc[bad, ["participant", "session"]].drop_duplicates().to_numpy().tolist()
        raise ObserverFitError(f"{int(bad.sum())} rows have empty or non-numeric truth, answers "
                               f"or rt_s (participant, session: {rows[:5]}); repair or remove them")
    slow = frame["rt_s"] <= 0
    if slow.any():
        rows = frame.loc[slow, ["participant", "session"]].drop_duplicates().to_numpy().tolist()
        raise ObserverFitError(f"{int(slow.sum())} rows have rt_s <= 0 s (participant, session: "
                               f"{rows[:5]}); response times are from onset to the response, "
                               "so these rows are damaged: repair or remove them")
    counts = frame.groupby("participant").size()
    few = counts[counts < MIN_TRIALS_PER_PARTICIPANT]
    if len(few):
        raise ObserverFitError(f"participants {few.to_dict()} have fewer than "
                               f"{MIN_TRIALS_PER_PARTICIPANT} answered trials; leave their files "
                               "out of the fit")
    if len(counts) < 2:
        raise ObserverFitError(f"only one participant ({counts.index[0]}): the between-observer "
                               "SDs need at least 2 participants (the study has 11); fit a pilot "
                               "of several participants")
    sim = simulated_rows(frame)
    for who, session in simulated_sessions or ():
        sim |= (frame["participant"] == str(who)) & (frame["session"] == session)
    if sim.any() and not sim.all():
        listed = sorted(frame.loc[sim, ["participant", "session"]].drop_duplicates()
                        .itertuples(index=False, name=None))
        warnings.warn(f"{int(sim.sum())} of {len(frame)} rows come from a simulated observer, "
                      f"mixed with real ones (participant, session: {listed}); they are fitted "
                      "as if real. Leave their files out to fit the real observers only",
                      ObserverFitWarning, stacklevel=3)
    frame["simulated"] = sim
    return frame


def _to_physical(frame: pd.DataFrame, design: StudyDesign) -> pd.DataFrame:
    """Slider positions -> cm and % (the design's conversion), with the censoring flags."""
    s = design.slider
    out = frame.copy()
    for col, conv in (("gloss_match", s.to_gloss_pct), ("depth_match", s.to_depth_cm)):
        v = out[col].to_numpy(float)
        outside = (v < s.min - _END_TOL) | (v > s.max + _END_TOL)
        if outside.any():
            rows = out.loc[outside, ["participant", "session"]].drop_duplicates()
            raise ObserverFitError(
                f"{int(outside.sum())} {col} values lie outside the slider's range "
                f"[{s.min:g}, {s.max:g}] (participant, session: "
                f"{rows.to_numpy().tolist()[:5]}); these files were not written for this "
                "design: pass the design they were run with (--design)")
        v = np.clip(v, s.min, s.max)  # within the tolerance: a slider's end
        out[col + "_phys"] = conv(v)
        out[col + "_low"] = v <= s.min + _END_TOL
        out[col + "_high"] = v >= s.max - _END_TOL
    return out


def _middle(design: StudyDesign) -> tuple[float, float]:
    """The slider's middle in cm and % (the humanlike model's m_d, m_g)."""
    s = design.slider
    mid = 0.5 * (s.min + s.max)
    return float(s.to_depth_cm(mid)), float(s.to_gloss_pct(mid))


# ----------------------------------------------------------------------------------- the fits
def _fit_participant(rows: pd.DataFrame, design: StudyDesign) -> dict:
    """Stage 1: one participant's ten parameters, their SEs and log-likelihood."""
    s = design.slider
    who = f"participant {rows['participant'].iloc[0]}"
    m_d, m_g = _middle(design)
    d = rows["true_depth_cm"].to_numpy(float) - m_d
    g = rows["true_gloss_pct"].to_numpy(float) - m_g
    if np.unique(d).size < 3 or np.unique(g).size < 3:
        raise ObserverFitError(f"{who} saw fewer than 3 depth or gloss levels; slopes and the "
                               "interaction cannot be fitted. Leave this participant out")
    one = np.ones_like(d)
    beta_d, sd_d, cov_d, ll_d = _tobit_fit(
        rows["depth_match_phys"].to_numpy(float), np.column_stack([one, d]), np.full_like(d, m_d),
        rows["depth_match_low"].to_numpy(), rows["depth_match_high"].to_numpy(),
        float(s.to_depth_cm(s.min)), float(s.to_depth_cm(s.max)), who + " (depth)")
    beta_g, sd_g, cov_g, ll_g = _tobit_fit(
        rows["gloss_match_phys"].to_numpy(float), np.column_stack([one, g, d, g * d]),
        np.full_like(g, m_g), rows["gloss_match_low"].to_numpy(),
        rows["gloss_match_high"].to_numpy(), float(s.to_gloss_pct(s.min)),
        float(s.to_gloss_pct(s.max)), who + " (gloss)")
    se_d, se_g = np.sqrt(np.diag(cov_d)), np.sqrt(np.diag(cov_g))
    log_rt = np.log(rows["rt_s"].to_numpy(float))
    n = log_rt.size
    rt_log_sd = float(np.std(log_rt, ddof=1))
    rt_median = float(np.exp(np.mean(log_rt)))
    est = {"depth_slope": (beta_d[1], se_d[1]), "depth_intercept_cm": (beta_d[0], se_d[0]),
           "depth_noise_cm": (sd_d, se_d[2]), "gloss_slope": (beta_g[1], se_g[1]),
           "gloss_intercept_pct": (beta_g[0], se_g[0]),
           "crosstalk_pct_per_cm": (beta_g[2], se_g[2]),
           "interaction_per_cm": (beta_g[3], se_g[3]), "gloss_noise_pct": (sd_g, se_g[4]),
           "rt_median_s": (rt_median, rt_median * rt_log_sd / math.sqrt(n)),
           "rt_log_sd": (rt_log_sd, rt_log_sd / math.sqrt(2.0 * (n - 1)))}
    ll_rt = float(np.sum(-0.5 * ((log_rt - np.log(rt_median)) / rt_log_sd) ** 2
                         - math.log(rt_log_sd) - 0.5 * _LOG_2PI - log_rt))
    return {"estimates": {k: (float(v), float(e)) for k, (v, e) in est.items()},
            "loglik": ll_d + ll_g + ll_rt, "n_trials": n}


def _fit_ideal(frame: pd.DataFrame, design: StudyDesign) -> tuple[dict, dict, float]:
    """Truth + noise, pooled over all trials: (table, standard errors, log-likelihood)."""
    s = design.slider
    empty = np.zeros((len(frame), 0))
    table, ses, ll = {}, {}, 0.0
    for resp, truth, conv, name in (
            ("depth_match", "true_depth_cm", s.to_depth_cm, "depth_noise_cm"),
            ("gloss_match", "true_gloss_pct", s.to_gloss_pct, "gloss_noise_pct")):
        _, sigma, cov, ll_k = _tobit_fit(
            frame[resp + "_phys"].to_numpy(float), empty, frame[truth].to_numpy(float),
            frame[resp + "_low"].to_numpy(), frame[resp + "_high"].to_numpy(),
            float(conv(s.min)), float(conv(s.max)), f"ideal observer ({resp})")
        table[name], ses[name], ll = float(sigma), float(math.sqrt(cov[0, 0])), ll + ll_k
    log_rt = np.log(frame["rt_s"].to_numpy(float))
    n = log_rt.size
    sd = float(np.std(log_rt, ddof=1))
    table["rt_median_s"] = float(np.exp(np.mean(log_rt)))
    table["rt_log_sd"] = sd
    ses["rt_median_s"] = table["rt_median_s"] * sd / math.sqrt(n)
    ses["rt_log_sd"] = sd / math.sqrt(2.0 * (n - 1))
    ll += float(np.sum(-0.5 * ((log_rt - np.mean(log_rt)) / sd) ** 2 - math.log(sd)
                       - 0.5 * _LOG_2PI - log_rt))
    return table, ses, ll


def fit_observer_params(sessions: pd.DataFrame, design: StudyDesign, *, kind: str = "humanlike",
                        simulated_sessions=None) -> dict:
    """Fit the simulated observers' parameters to a lab's session data.

    Parameters
    ----------
    sessions : DataFrame
        Answered trials, the rows :func:`experiment.read_session` returns (several participants'
        sessions concatenated): ``participant``, ``session``, ``true_gloss_pct`` (%),
        ``true_depth_cm`` (cm), ``gloss_match`` and ``depth_match`` (raw slider positions),
        ``rt_s`` (s), ``app_version``.
    design : StudyDesign
        The design the sessions were run with: its slider converts positions to cm and %
        (``slider.to_depth_cm`` / ``to_gloss_pct``) and its ends are the censoring points.
    kind : {"humanlike", "ideal"}
        The kind the lab means to simulate with; ``fit["kind"]`` and ``fit["loglik"]`` refer to
        it. Both tables are always fitted (the file format holds both).
    simulated_sessions : iterable of (participant, session), optional
        Sessions known to come from a simulated observer (e.g. run logs of ``run --simulate``);
        rows of :func:`experiment.simulate_dataset` are recognised by their ``app_version``.

    Returns
    -------
    dict
        ``{"ideal": {...}, "humanlike": {...}, "fit": {...}}`` in the format of
        :func:`experiment.load_observer_params` (``write_observer_params`` writes it). Humanlike
        parameters are ``{mean, sd}`` (population mean and between-observer SD, units in the
        names); ``fit`` holds ``kind``, ``method``, ``date_utc``, ``n_participants``,
        ``n_trials``, ``participants``, ``sessions`` (``"<participant>_s<n>"``),
        ``simulated_sessions``, ``n_censored`` (answers at a slider end, per slider),
        ``loglik`` (of ``kind``), ``loglik_humanlike`` and ``loglik_ideal`` (responses and
        response times given the fitted parameters; humanlike: each participant's own),
        ``loglik_population`` (stage-2 REML, summed over parameters), ``design`` (its file) and
        ``standard_errors`` (``{"humanlike": {name: {mean, sd}}, "ideal": {name: se}}``).

    Raises
    ------
    ObserverFitError (a ValueError)
        No rows, missing columns, non-numeric values, answers outside the slider's range, a
        single participant (the between-observer SDs need >= 2), a participant with fewer than
        20 trials or 3 levels of gloss or depth, or a fit that does not converge.

    Warns
    -----
    ObserverFitWarning
        Simulated rows mixed with real ones (listed by participant and session).
    """
    from experiment.observers import OBSERVER_KINDS

    if kind not in OBSERVER_KINDS:
        raise ObserverFitError(f"unknown observer kind {kind!r}; use one of {OBSERVER_KINDS}")
    frame = _to_physical(_check_frame(sessions, simulated_sessions), design)
    per = {who: _fit_participant(rows, design) for who, rows in frame.groupby("participant")}
    humanlike, se_h, ll_pop = {}, {}, 0.0
    for name in HUMANLIKE_PARAMS:
        theta = np.array([per[w]["estimates"][name][0] for w in per])
        se = np.array([per[w]["estimates"][name][1] for w in per])
        if name in _SCALE_PARAMS:
            # Their SE is proportional to the estimate: weighting by 1/se^2 would favour the
            # participants whose noise happened to come out small (a downward bias). Use each
            # participant's relative SE times the participants' average instead.
            se = se / theta * float(np.mean(theta))
        pop = _population_reml(theta, se)
        humanlike[name] = {"mean": pop["mean"], "sd": pop["sd"]}
        se_h[name] = {"mean": pop["se_mean"], "sd": pop["se_sd"]}
        ll_pop += pop["loglik"]
    ideal, se_i, ll_ideal = _fit_ideal(frame, design)
    ll_h = float(sum(p["loglik"] for p in per.values()))
    sess = frame[["participant", "session"]].drop_duplicates().sort_values(["participant",
                                                                            "session"])
    sim = frame.loc[frame["simulated"], ["participant", "session"]].drop_duplicates()
    fit = {
        "kind": kind,
        "method": ("two-stage hierarchical ML: per participant, censored (Tobit) ML of the "
                   "humanlike equations with the slider's ends as censoring points; per "
                   "parameter, REML of theta_i ~ N(mean, sd^2 + se_i^2) across participants. "
                   "ideal: censored ML pooled over trials"),
        "date_utc": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "design": str(design.source),
        "n_participants": len(per),
        "n_trials": len(frame),
        "participants": sorted(per),
        "sessions": [f"{p}_s{int(s)}" for p, s in sess.itertuples(index=False)],
        "simulated_sessions": [f"{p}_s{int(s)}" for p, s in sim.itertuples(index=False)],
        "n_censored": {"gloss": int((frame["gloss_match_low"] | frame["gloss_match_high"]).sum()),
                       "depth": int((frame["depth_match_low"] | frame["depth_match_high"]).sum())},
        "loglik": ll_h if kind == "humanlike" else ll_ideal,
        "loglik_humanlike": ll_h,
        "loglik_ideal": ll_ideal,
        "loglik_population": ll_pop,
        "standard_errors": {"humanlike": se_h, "ideal": se_i},
    }
    return {"ideal": ideal, "humanlike": humanlike, "fit": fit}


# ------------------------------------------------------------------------- reading the files
def _session_files(sources) -> list:
    """Session CSVs named by ``sources``: data folders (``sessions/*.csv``), folders of CSVs,
    or CSV files."""
    from pathlib import Path

    files = []
    for src in map(Path, sources):
        if src.is_dir():
            folder = src / "sessions" if (src / "sessions").is_dir() else src
            found = sorted(folder.glob("*.csv"))
            if not found:
                raise ObserverFitError(f"{src} holds no session CSVs (looked for "
                                       f"{folder}/*.csv); give a data folder with sessions/ or "
                                       "the session files")
            files += found
        elif src.is_file():
            if src.suffix.lower() != ".csv":
                raise ObserverFitError(f"{src} is not a session CSV (data/sessions/<p>_s<n>.csv)")
            files.append(src)
        else:
            raise ObserverFitError(f"{src} does not exist; give a data folder or session CSVs")
    unique = []
    for f in files:
        if f.resolve() not in {u.resolve() for u in unique}:
            unique.append(f)
    return unique


def _app_simulated(path, rows: pd.DataFrame) -> list:
    """(participant, session) of a session file whose app run logs say ``--simulate``.

    The app writes ``<data>/logs/<stem>_run<k>.json`` beside ``<data>/sessions/<stem>.csv``;
    a simulated run's log has a ``simulated`` entry.
    """
    import json

    logs = path.parent.parent / "logs"
    found = []
    for log in sorted(logs.glob(f"{path.stem}_run*.json")):
        try:
            entry = json.loads(log.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if isinstance(entry, dict) and entry.get("simulated"):
            found += [(str(p), int(s)) for p, s in
                      rows[["participant", "session"]].drop_duplicates().itertuples(index=False)]
            break
    return found


def read_sessions_for_fit(sources) -> tuple[pd.DataFrame, list, list]:
    """Read the session CSVs to fit -> (rows, simulated (participant, session) pairs, files).

    Parameters
    ----------
    sources : iterable of path-like
        Data folders (their ``sessions/*.csv``), folders of session CSVs, or CSV files.

    Raises
    ------
    ObserverFitError
        A path that does not exist or is not a CSV, a file that is not a session file (wrong
        header, torn last row), or no answered trials at all.
    """
    from experiment.datafile import DataFileError, read_session

    files = _session_files(sources)
    frames, simulated = [], []
    for path in files:
        try:
            rows = read_session(path)
        except DataFileError as exc:
            raise ObserverFitError(f"{exc}; or leave this file out of the fit") from exc
        except (ValueError, UnicodeDecodeError) as exc:
            raise ObserverFitError(f"{path} is not a readable session CSV ({exc})") from exc
        if len(rows):
            frames.append(rows)
            simulated += _app_simulated(path, rows)
    if not frames:
        raise ObserverFitError(f"no answered trials in {[str(f) for f in files] or sources}; "
                               "the fit needs the sessions of a pilot (several participants)")
    return pd.concat(frames, ignore_index=True), simulated, files
