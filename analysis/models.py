"""The seed's two mixed models: estimated gloss and Box-Cox estimated depth on gloss x depth."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass

import pandas as pd

from analysis.lmm import LmmFit, bc_power, fit_lmm, standardise_predictors
from analysis.typeii import WaldTest, type2_wald
from studydesign import StudyDesign

__all__ = ["MODELS", "ModelResult", "fit_seed_models", "model_frame"]

#: Model name -> (response column of the model frame, what it is).
MODELS = {
    "gloss": ("gloss_match_pct", "estimated gloss (%)"),
    "depth": ("depth_match_bc", "estimated depth (cm), Box-Cox transformed"),
}


@dataclass(frozen=True)
class ModelResult:
    """One model: the fit and its Type II Wald tests.

    Attributes
    ----------
    name : str
        "gloss" or "depth".
    label : str
    fit : LmmFit
    tests : tuple of WaldTest
        gloss, depth, gloss:depth.
    boxcox_lambda : float or None
        The exponent applied to the response (depth model only).
    """

    name: str
    label: str
    fit: LmmFit
    tests: tuple
    boxcox_lambda: float | None

    def to_json(self) -> str:
        d = asdict(self)
        return json.dumps(d, indent=1)

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


def fit_seed_models(frame: pd.DataFrame, design: StudyDesign) -> dict:
    """Fit the gloss and depth models of the seed to loaded session data.

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
    out = {}
    for name, (response, label) in MODELS.items():
        fit = fit_lmm(mf, response=response)
        tests = type2_wald(fit.fixef_array(), fit.vcov_array())
        lam = design.analysis.depth_boxcox_lambda if name == "depth" else None
        out[name] = ModelResult(name=name, label=label, fit=fit, tests=tests, boxcox_lambda=lam)
    return out
