"""Power by simulation for planning a study, as R's simr does (``powerSim`` / ``powerCurve``).

A study of ``n`` participants, each doing ``sessions`` sessions of the experiment's own plan
``repeats`` times, is simulated, the mixed model refitted and each term tested (Type II Wald
chi-square at ``alpha``, as the report's tests and ``car::Anova(type = 2)``); the share of
simulated studies that reject is the power, counted by `analysis.montecarlo` with its exact 95 %
interval. Two ways to simulate, named in every output:

``model``
    From a fitted mixed model (a pilot's or the study's own data), as simr: new participants'
    random effects drawn from the fitted covariance, new residuals from the fitted SD (lme4's
    ``simulate(use.u = FALSE)`` on the new layout, simr's ``extend``), refitted from the fitted
    theta (`analysis.bootstrap.refit`, about 40x faster than ``bootMer``).
``observers``
    From simulated observers (``experiment/observers.toml`` or one fitted to a pilot by
    ``experiment fit-observer``): each new participant drawn from the observer population
    answers its whole plan (``experiment.plan``) through the design's slider (clipped at its
    ends), the answers converted to % and cm and, for depth, Box-Cox transformed, as the report
    does. What the observer model holds that a linear mixed model does not (the slider's
    clipping) is carried into the power.

An effect is set as a multiple of the fitted one (``scale``: 0.5 = half the pilot's size) or in
the study's units (``value``: the coefficient per % of gloss and per cm of depth, e.g. the
gloss x depth interaction in % per % per cm).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats

from analysis.bootstrap import refit, simulate_responses
from analysis.formula import build_model
from analysis.lmm import LmmFit, bc_power, standardise_predictors
from analysis.pls import make_problem, solve, with_y
from analysis.typeii import hypothesis_matrix, wald_chi2
from studydesign import StudyDesign

__all__ = ["ALPHA", "OBSERVER_EFFECTS", "Effect", "ModelDraws", "ObserverDraws", "PowerError",
           "check_terms", "layout_frame", "observer_params", "participant_ids", "scaled_fixef",
           "study_unit_scale"]

ALPHA = 0.05
#: Observer parameters that carry each term's effect, per response of the model.
OBSERVER_EFFECTS = {
    "gloss_match_pct": {"gloss": "gloss_slope", "depth": "crosstalk_pct_per_cm",
                        "gloss:depth": "interaction_per_cm"},
    "depth_match_bc": {"depth": "depth_slope"},
}


class PowerError(ValueError):
    """A power analysis that cannot run as asked; the message names the fix."""


@dataclass(frozen=True)
class Effect:
    """A term's effect in the simulated studies: ``scale`` times the fitted one, or ``value``
    in the study's units (see `study_unit_scale`); exactly one is set."""

    term: str
    scale: float | None = None
    value: float | None = None

    def describe(self) -> str:
        if self.value is not None:
            return f"{self.term} = {self.value:g} (study units)"
        return f"{self.term} x {self.scale:g} (of the fitted size)"


def check_terms(terms, fit_terms, where: str) -> list:
    """The terms asked for, each one of the model's; else a PowerError naming the model's."""
    bad = [t for t in terms if t not in fit_terms]
    if bad:
        raise PowerError(f"term(s) {bad} are not in {where}; its terms are {list(fit_terms)} "
                         "(write an interaction as gloss:depth)")
    return list(terms)


def _plan(design: StudyDesign, participant: str) -> pd.DataFrame:
    from experiment import make_plan, participant_seed

    seed = participant_seed(participant)
    return make_plan(design, participant, np.random.default_rng(seed), seed=seed)


def participant_ids(n: int) -> list[str]:
    return [f"SIM{k + 1:03d}" for k in range(n)]


def layout_frame(design: StudyDesign, n_participants: int, *, sessions: int | None = None,
                 repeats: int = 1) -> pd.DataFrame:
    """The trials of a planned study: ``n_participants`` new participants, each the first
    ``sessions`` sessions of its own plan (default all), the whole ``repeats`` times.

    Returns the plan's columns plus ``repeat``, ``gloss`` and ``depth`` (standardised as the
    report's, `analysis.lmm.standardise_predictors`).
    """
    n_sessions = math.ceil(design.n_stimuli / design.sessions.trials_per_session)
    sessions = n_sessions if sessions is None else int(sessions)
    if n_participants < 2:
        raise PowerError(f"{n_participants} participants: a mixed model needs at least 2 "
                         "(e.g. --participants 4:24:2)")
    if not 1 <= sessions <= n_sessions:
        raise PowerError(f"{sessions} sessions: the design's plan has 1 to {n_sessions}")
    if repeats < 1:
        raise PowerError(f"{repeats} repeats: use 1 (each planned trial once) or more")
    parts = []
    for pid in participant_ids(n_participants):
        plan = _plan(design, pid)
        plan = plan[plan["session"] <= sessions]
        for r in range(repeats):
            parts.append(plan.assign(repeat=r + 1))
    return standardise_predictors(pd.concat(parts, ignore_index=True), design)


def study_unit_scale(term: str, design: StudyDesign) -> float:
    """Coefficient on the standardised predictors per unit of the study's: the product of
    the SDs (over the design's rendered levels) of the term's variables, gloss in %, depth in
    cm. A term with another variable has no study unit (PowerError)."""
    sd = {"gloss": float(np.std(design.gloss.rendered_pct)),
          "depth": float(np.std(design.depth.rendered_cm))}
    parts = term.split(":")
    if any(p not in sd for p in parts):
        raise PowerError(f"term {term!r} has no study unit (only gloss, depth and their "
                         "interaction are in % and cm); set it as a multiple of the fitted "
                         f"effect instead (--scale {term}=0.5)")
    return float(np.prod([sd[p] for p in parts]))


def scaled_fixef(fit: LmmFit, effects, design: StudyDesign) -> np.ndarray:
    """The fitted fixed effects with each effect's coefficients scaled or set."""
    beta = fit.fixef_array().copy()
    assign = np.asarray(fit.assign)
    for e in effects:
        cols = np.flatnonzero(assign == fit.terms.index(e.term))
        if e.value is not None:
            if cols.size != 1:
                raise PowerError(f"term {e.term!r} has {cols.size} coefficients; set it as a "
                                 "multiple of the fitted effect instead (--scale)")
            beta[cols] = e.value * study_unit_scale(e.term, design)
        else:
            beta[cols] *= e.scale
    return beta


class _Tester:
    """Refit a simulated response and test terms; shared by both ways of simulating."""

    def _setup(self, pr, fit_like, terms, alpha, theta0):
        self.pr, self.terms_all = pr, list(fit_like.terms)
        self.assign, self.factors = list(fit_like.assign), list(fit_like.term_factors)
        self.terms, self.alpha = list(terms), float(alpha)
        self.theta0 = np.asarray(theta0, float)

    def reject(self, y: np.ndarray) -> np.ndarray:
        """Per tested term: does the Type II Wald test of the refit reject at alpha?"""
        prb = with_y(self.pr, y)
        try:
            th, _ = refit(prb, self.theta0)
            sol = solve(th, prb)
        except (np.linalg.LinAlgError, ValueError):
            return np.zeros(len(self.terms), bool)  # a failed refit rejects nothing
        out = np.zeros(len(self.terms), bool)
        for i, term in enumerate(self.terms):
            L = hypothesis_matrix(term, sol.vcov, terms=self.terms_all, assign=self.assign,
                                  term_factors=self.factors)
            chi2 = wald_chi2(L, sol.beta, sol.vcov)
            out[i] = stats.chi2.sf(chi2, L.shape[0]) < self.alpha
        return out


class ModelDraws(_Tester):
    """``draws(rng, k) -> bool (k, n_terms)``: simulated studies from a fitted mixed model.

    Parameters
    ----------
    fit : LmmFit
        The fitted model (its formula is rebuilt on ``layout``).
    layout : DataFrame
        The planned study's trials (`layout_frame`).
    beta : ndarray
        The fixed effects to simulate with (`scaled_fixef`).
    terms : list of str
    alpha : float
    """

    def __init__(self, fit: LmmFit, layout: pd.DataFrame, beta, terms, *, alpha=ALPHA):
        frame = layout.assign(**{fit.response: 0.0})
        spec = build_model(fit.formula, frame)
        if list(spec.fixed.names) != list(fit.fixef):
            raise PowerError(f"the planned layout gives the coefficients {list(spec.fixed.names)}"
                             f", the fit {list(fit.fixef)}; a factor level the plan lacks?")
        self._setup(make_problem(spec, reml=fit.reml), fit, terms, alpha, fit.theta)
        self.beta, self.sigma = np.asarray(beta, float), float(fit.sigma)

    def __call__(self, rng: np.random.Generator, k: int) -> np.ndarray:
        ys = simulate_responses(self.pr, self.beta, self.theta0, self.sigma, rng, k)
        return np.array([self.reject(y) for y in ys]).reshape(k, len(self.terms))


class ObserverDraws(_Tester):
    """``draws(rng, k) -> bool (k, n_terms)``: simulated studies of simulated observers.

    Parameters
    ----------
    design : StudyDesign
    params : dict
        The humanlike observers' table (``observers.toml``), effects already applied
        (`observer_params`).
    layout : DataFrame
        The planned study's trials (`layout_frame`), in each participant's plan order.
    formula : str
        The model, response ``gloss_match_pct`` or ``depth_match_bc``.
    terms : list of str
    theta0 : array_like
        Start of each refit (a fit to one large simulated study).
    alpha : float
    """

    def __init__(self, design, params, layout, formula, terms, theta0, *, alpha=ALPHA):
        from analysis.lmm import fit as fit_lmm

        self.design, self.params = design, dict(params)
        self.layout = layout
        self.response = formula.split("~")[0].strip()
        if self.response not in OBSERVER_EFFECTS:
            raise PowerError(f"observers answer gloss_match_pct or depth_match_bc; the formula's "
                             f"response is {self.response!r}")
        self.rows = layout.groupby("participant", sort=False).indices
        frame = layout.assign(**{self.response: 0.0})
        spec = build_model(formula, frame)
        if theta0 is None:
            y = self.response_of(np.random.default_rng(0))
            theta0 = fit_lmm(formula, frame.assign(**{self.response: y})).theta
        summary = type("FitTerms", (), {"terms": list(spec.fixed.terms),
                                        "assign": list(spec.fixed.assign),
                                        "term_factors": [sorted(f) for f in
                                                         spec.fixed.term_factors]})
        self._setup(make_problem(spec, reml=False), summary, terms, alpha, theta0)

    def response_of(self, rng: np.random.Generator) -> np.ndarray:
        """One simulated study's responses, in the layout's rows."""
        from experiment import make_observer

        y = np.empty(len(self.layout))
        slider = self.design.slider
        for pid, idx in self.rows.items():
            obs = make_observer("humanlike", pid, rng, self.params, design=self.design)
            gloss, depth = obs.respond_all(self.layout.iloc[idx], rng)
            if self.response == "gloss_match_pct":
                y[idx] = slider.to_gloss_pct(gloss)
            else:
                y[idx] = bc_power(slider.to_depth_cm(depth),
                                  self.design.analysis.depth_boxcox_lambda)
        return y

    def __call__(self, rng: np.random.Generator, k: int) -> np.ndarray:
        return np.array([self.reject(self.response_of(rng)) for _ in range(k)]).reshape(
            k, len(self.terms))


def observer_params(params: dict, response: str, effects) -> dict:
    """The humanlike table with each effect applied to its parameter (mean and between-observer
    SD scaled, or the mean set in the study's units with the SD kept). A term the observers do
    not carry stays zero when scaled; set to a value it is refused."""
    import copy

    out = copy.deepcopy(params)
    carried = OBSERVER_EFFECTS[response]
    for e in effects:
        if e.term not in carried and e.value is None:
            continue  # the observers have no such effect: scaled, it stays zero
        if e.term not in carried:
            raise PowerError(f"the observer model has no {e.term!r} effect on {response} (it "
                             f"carries {sorted(carried)}); simulate from a fitted model instead "
                             "(--simulate model)")
        name = carried[e.term]
        spec = out[name]
        if e.value is not None:
            out[name] = ({"mean": float(e.value), "sd": spec["sd"]} if isinstance(spec, dict)
                         else float(e.value))
        elif isinstance(spec, dict):
            out[name] = {"mean": spec["mean"] * e.scale, "sd": spec["sd"] * abs(e.scale)}
        else:
            out[name] = spec * e.scale
    return out
