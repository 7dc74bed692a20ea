"""Layer-independent ranking of candidate extensions by held-out gain, and the test of what
remains.

A candidate is a parameterised extension of a layer's simulation (one :class:`Candidate`
object per effect, registered per layer with :func:`register`; :mod:`.registry`). It is
fitted on training data and scored by the per-unit loss (negative log-likelihood) it removes
on held-out units. Gains get percentile-bootstrap CIs and one-sided bootstrap p-values (H1:
gain > 0), corrected for the number of candidates by Holm (1979). Candidates are then
combined greedily; after each step every remaining candidate is re-tested. Finally the chosen
model's held-out loss is compared with a flexible, data-driven *ceiling* model (paired
bootstrap): a significant difference is a gap the catalogue does not explain, reported with
where it lies.

Held-out units come either from one split (``train``, ``test``) or from cross-fitting
(``folds``: every unit held out once per repeat, per-unit losses averaged over repeats), so
that the verdict does not hinge on one random split (:mod:`.heldout`).

:func:`diagnose_losses` (:mod:`.pipeline`) runs the steps of :mod:`.steps` in order, given
the layer's functions (:class:`LayerFunctions`) and the statistical choices
(:class:`DiagnosisSettings`) of :mod:`.settings`; the tests they share are in :mod:`.stats`,
the result records in :mod:`.result`, the summary sentence in :mod:`.words`. Each layer
folder hands the engine one :class:`LayerPlan` (:mod:`.layer`).
"""

from analysis.gap.engine.errors import GapError
from analysis.gap.engine.heldout import split_held_out
from analysis.gap.engine.layer import LayerPlan
from analysis.gap.engine.pipeline import diagnose_losses
from analysis.gap.engine.power import (
    OUTCOME_GAP,
    OUTCOME_INCONCLUSIVE,
    OUTCOME_NONE,
    PowerModel,
    decide_size,
    power_analysis,
)
from analysis.gap.engine.registry import (
    LAYER_NAMES,
    Candidate,
    OutOfCatalogue,
    ParamDoc,
    candidate,
    catalogue,
    effect,
    out_of_catalogue,
    register,
    register_out_of_catalogue,
    strengths,
)
from analysis.gap.engine.result import CandidateScore, Diagnosis
from analysis.gap.engine.settings import DiagnosisSettings, LayerFunctions
from analysis.gap.engine.stats import holm
from analysis.gap.engine.steps import (
    INCONCLUSIVE,
    NO_GAP_THAT_MATTERS,
    NOT_A_GAP,
    judged_plain,
)
from analysis.gap.engine.words import summarise

__all__ = ["INCONCLUSIVE", "LAYER_NAMES", "NOT_A_GAP", "NO_GAP_THAT_MATTERS", "OUTCOME_GAP",
           "OUTCOME_INCONCLUSIVE", "OUTCOME_NONE", "Candidate", "CandidateScore", "Diagnosis",
           "DiagnosisSettings", "GapError", "LayerFunctions", "LayerPlan", "OutOfCatalogue",
           "ParamDoc", "PowerModel", "candidate", "catalogue", "decide_size",
           "diagnose_losses", "effect", "holm", "judged_plain", "out_of_catalogue",
           "power_analysis", "register",
           "register_out_of_catalogue", "split_held_out", "strengths", "summarise"]
