"""Sim-to-real gap diagnosis (issue 8): where the gap lies, which unmodelled effect causes it,
how far it shrinks once the effect is added, checked on held-out data.

Layers: ``observer`` (session CSVs vs simulated observers), ``display`` (photometer readings
vs the calibration), ``render`` (photos vs fitted Ward renders, the gloss fit's residual
files); ``all`` diagnoses several and names the layer that carries the gap. The blind benchmark
(``python -m analysis.gap benchmark``) lives in :mod:`analysis.gap.benchmark`, its injectors in
:mod:`analysis.gap.inject`; neither is imported by the diagnosis.
"""

from analysis.gap.diagnose import (
    diagnose_all_files,
    diagnose_display,
    diagnose_display_files,
    diagnose_files,
    diagnose_observer,
    diagnose_observer_files,
    diagnose_render,
    diagnose_render_files,
)
from analysis.gap.display import DISPLAY_CANDIDATES, load_display, localise_display
from analysis.gap.engine import Candidate, CandidateScore, Diagnosis, GapError, holm
from analysis.gap.layers import parse_layer_paths, which_layer
from analysis.gap.observer import OBSERVER_CANDIDATES, load_sessions, localise_observer
from analysis.gap.render import RENDER_CANDIDATES, load_render, localise_render
from analysis.gap.report import write_multi_report, write_report

__all__ = [
    "DISPLAY_CANDIDATES",
    "OBSERVER_CANDIDATES",
    "RENDER_CANDIDATES",
    "Candidate",
    "CandidateScore",
    "Diagnosis",
    "GapError",
    "diagnose_all_files",
    "diagnose_display",
    "diagnose_display_files",
    "diagnose_files",
    "diagnose_observer",
    "diagnose_observer_files",
    "diagnose_render",
    "diagnose_render_files",
    "holm",
    "load_display",
    "load_render",
    "load_sessions",
    "localise_display",
    "localise_observer",
    "localise_render",
    "parse_layer_paths",
    "which_layer",
    "write_multi_report",
    "write_report",
]
