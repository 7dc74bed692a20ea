"""Analysis: load sessions, figures, linear mixed models, image statistics, sim-to-real gap.

Public API
----------
matches_to_physical
    Slider matches to % and cm through the design.
load_sessions, SessionData, SessionDataError
    Read and validate a data folder's session CSVs (with ``experiment.read_session``; the
    column list is ``experiment.SESSION_COLUMNS``).
fit_lmm, LmmFit, LmmError, bc_power, standardise_predictors
    Linear mixed models by lme4's profiled deviance (ML); car's Box-Cox.
type2_wald, WaldTest
    Type II Wald chi-square tests as car::Anova(type = 2).
parametric_bootstrap, BootstrapResult
    Parametric bootstrap (as lme4's bootMer) with percentile CIs and p-values.
fit_seed_models, ModelResult
    The seed's gloss and depth models.
find_metamers, Metamer, plot_depth_matches, plot_gloss_matches, plot_gloss_contours,
plot_observers
    The source study's figures.
build_report, ReportExistsError
    The HTML report (``python -m analysis report``).
"""

from analysis.bootstrap import BootstrapResult, parametric_bootstrap
from analysis.figures import (
    Metamer,
    find_metamers,
    plot_depth_matches,
    plot_gloss_contours,
    plot_gloss_matches,
    plot_observers,
)
from analysis.lmm import LmmError, LmmFit, bc_power, fit_lmm, standardise_predictors
from analysis.load import SessionData, SessionDataError, load_sessions
from analysis.models import ModelResult, fit_seed_models
from analysis.report import ReportExistsError, build_report
from analysis.typeii import WaldTest, type2_wald
from analysis.units import matches_to_physical

__all__ = [
    "BootstrapResult",
    "LmmError",
    "LmmFit",
    "Metamer",
    "ModelResult",
    "ReportExistsError",
    "SessionData",
    "SessionDataError",
    "WaldTest",
    "bc_power",
    "build_report",
    "find_metamers",
    "fit_lmm",
    "fit_seed_models",
    "load_sessions",
    "matches_to_physical",
    "parametric_bootstrap",
    "plot_depth_matches",
    "plot_gloss_contours",
    "plot_gloss_matches",
    "plot_observers",
    "standardise_predictors",
    "type2_wald",
]
