"""The report's mixed models: the source study's two, and the design's extra ones.

The source study fitted ``estimated gloss`` and Box-Cox ``estimated depth`` each with
``~ gloss * depth + (1 + gloss + depth | participant)`` by ML; the design's ``[analysis.models]``
adds models in lme4 syntax (e.g. with stimuli crossed with participants). All go through the one
general fit, `analysis.lmm.fit`.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field

import pandas as pd

from analysis.lmm import LmmFit, bc_power, fit, standardise_predictors
from analysis.satterthwaite import satterthwaite_terms
from analysis.typeii import WaldTest, type2_wald
from studydesign import StudyDesign

__all__ = [
    "SOURCE_STUDY_MODELS",
    "SOURCE_STUDY_RHS",
    "ModelResult",
    "fit_design_models",
    "fit_model",
    "fit_source_study_models",
    "model_frame",
]

#: The source study's fixed and random effects (right-hand side of both its models).
SOURCE_STUDY_RHS = "gloss * depth + (1 + gloss + depth | participant)"
#: Source-study model name -> (response column of the model frame, what it is).
SOURCE_STUDY_MODELS = {
    "gloss": ("gloss_match_pct", "estimated gloss (%)"),
    "depth": ("depth_match_bc", "estimated depth (cm), Box-Cox transformed"),
}


@dataclass(frozen=True)
class ModelResult:
    """One model: the fit and its Type II Wald tests.

    Attributes
    ----------
    name : str
        "gloss", "depth" or the design's model name.
    label : str
    fit : LmmFit
    tests : tuple of WaldTest
        One per fixed-effect term (car's order).
    boxcox_lambda : float or None
        The exponent applied to the response (Box-Cox depth only).
    source_model : str
        For a design model, the source-study model it re-specifies ("gloss", "depth" or "").
    f_tests : dict of str to [F, numerator df, denominator df, p]
        Each term's Type II hypothesis as an F test with Satterthwaite's denominator df
        (`analysis.satterthwaite`, as lmerTest).
    """

    name: str
    label: str
    fit: LmmFit
    tests: tuple
    boxcox_lambda: float | None
    source_model: str = ""
    f_tests: dict = field(default_factory=dict)

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=1)

    @classmethod
    def from_json(cls, text: str) -> ModelResult:
        d = json.loads(text)
        d["fit"] = LmmFit(**d["fit"])
        d["tests"] = tuple(WaldTest(**t) for t in d["tests"])
        return cls(**d)

    def chi2(self) -> dict:
        return {t.term: t.chi2 for t in self.tests}


def model_frame(frame: pd.DataFrame, design: StudyDesign) -> pd.DataFrame:
    """Standardised predictors and both responses (``depth_match_bc`` by ``car::bcPower``)."""
    out = standardise_predictors(frame, design)
    out["depth_match_bc"] = bc_power(out["depth_match_cm"].to_numpy(),
                                     design.analysis.depth_boxcox_lambda)
    return out


def fit_model(name: str, label: str, formula: str, mf: pd.DataFrame, design: StudyDesign, *,
              source_model: str = "") -> ModelResult:
    """Fit one model (ML) to a model frame and test its terms (Type II Wald; Satterthwaite F)."""
    result = fit(formula, mf)
    lam = (design.analysis.depth_boxcox_lambda if result.response == "depth_match_bc" else None)
    f_tests = {t: list(v) for t, v in satterthwaite_terms(result, mf).items()}
    return ModelResult(name=name, label=label, fit=result, tests=type2_wald(result),
                       boxcox_lambda=lam, source_model=source_model, f_tests=f_tests)


def fit_source_study_models(frame: pd.DataFrame, design: StudyDesign) -> dict:
    """Fit the gloss and depth models of the source study to loaded session data.

    Parameters
    ----------
    frame : DataFrame
        `analysis.load.SessionData.frame` (needs gloss_match_pct, depth_match_cm, the true
        values and participant).
    design : StudyDesign

    Returns
    -------
    dict of str to ModelResult
        Keys "gloss" and "depth".
    """
    mf = model_frame(frame, design)
    return {name: fit_model(name, label, f"{response} ~ {SOURCE_STUDY_RHS}", mf, design)
            for name, (response, label) in SOURCE_STUDY_MODELS.items()}


def fit_design_models(frame: pd.DataFrame, design: StudyDesign) -> dict:
    """Fit every model of the design's ``[analysis.models]``, keyed by its name."""
    mf = model_frame(frame, design)
    return {m.name: fit_model(m.name, m.label or m.name, f"{m.response} ~ {m.formula}", mf,
                              design, source_model=m.source_model)
            for m in design.analysis.models}
