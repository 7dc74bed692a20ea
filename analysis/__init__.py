"""Analysis: load sessions, figures, linear mixed models, image statistics, sim-to-real gap.

Public API
----------
matches_to_physical
    Slider matches to % and cm through the design.
load_sessions, SessionData, SessionDataError
    Read and validate a data folder's session CSVs (with ``experiment.read_session``; the
    column list is ``experiment.SESSION_COLUMNS``).
fit, LmmFit, LmmError, FormulaError, bc_power, standardise_predictors
    Linear mixed models by lme4 formula, fitted as lme4 (ML or REML); car's Box-Cox.
type2_wald, WaldTest
    Type II Wald chi-square tests as car::Anova(type = 2).
coefficient_tests, satterthwaite_terms
    t tests per coefficient and F tests per term with Satterthwaite's df, as lmerTest.
parametric_bootstrap, BootstrapResult
    Parametric bootstrap (as lme4's bootMer) of any fitted model, with percentile CIs and
    p-values.
bootstrap_lrt, LrtResult
    Parametric bootstrap likelihood-ratio test of a term (as pbkrtest::PBmodcomp).
fit_source_study_models, fit_design_models, ModelResult
    The source study's gloss and depth models, and the design's extra models.
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
from analysis.formula import FormulaError, LmmError
from analysis.lmm import LmmFit, bc_power, fit, standardise_predictors
from analysis.load import SessionData, SessionDataError, load_sessions
from analysis.lrt import LrtResult, bootstrap_lrt
from analysis.models import ModelResult, fit_design_models, fit_source_study_models
from analysis.report import ReportExistsError, build_report
from analysis.satterthwaite import coefficient_tests, satterthwaite_terms
from analysis.typeii import WaldTest, type2_wald
from analysis.units import matches_to_physical

__all__ = [
    "BootstrapResult",
    "FormulaError",
    "LmmError",
    "LmmFit",
    "LrtResult",
    "Metamer",
    "ModelResult",
    "ReportExistsError",
    "SessionData",
    "SessionDataError",
    "WaldTest",
    "bc_power",
    "bootstrap_lrt",
    "build_report",
    "coefficient_tests",
    "find_metamers",
    "fit",
    "fit_design_models",
    "fit_source_study_models",
    "load_sessions",
    "matches_to_physical",
    "parametric_bootstrap",
    "plot_depth_matches",
    "plot_gloss_contours",
    "plot_gloss_matches",
    "plot_observers",
    "satterthwaite_terms",
    "standardise_predictors",
    "type2_wald",
]
