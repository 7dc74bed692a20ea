"""Sim-to-real gap diagnosis: where the gap lies, which unmodelled effect causes it, how far it
shrinks once the effect is added, and whether a gap remains that the catalogue does not
explain, all on held-out data.

Layers: ``observer`` (session CSVs vs a simulated observer, fitted to a pilot or ideal),
``display`` (photometer readings vs the calibration), ``render`` (photos vs fitted Ward
renders, the gloss fit's residual files); ``all`` diagnoses several and names the layer that
carries the gap. One entry point, :func:`diagnose`; each layer's catalogue is a list of
:class:`Candidate` objects registered with :func:`register` (:func:`catalogue`,
:func:`candidate`). The blind benchmarks (``python -m analysis.gap benchmark``) live in
:mod:`analysis.gap.benchmark` with their injectors in :mod:`analysis.gap.inject` and an
independent generators in :mod:`analysis.gap.bench_observer`, :mod:`analysis.gap.bench_display`
and :mod:`analysis.gap.bench_render` (``--harder``); out-of-catalogue effects are
:class:`analysis.gap.engine.OutOfCatalogue` objects the injectors register beside the
candidates. The diagnosis imports none of them.
"""

from analysis.gap.diagnose import LAYERS, diagnose
from analysis.gap.engine import (
    Candidate,
    CandidateScore,
    Diagnosis,
    GapError,
    candidate,
    catalogue,
    diagnose_losses,
    holm,
    register,
)
from analysis.gap.layers import parse_layer_paths, which_layer
from analysis.gap.observer import (
    OBSERVER_CANDIDATES,
    load_sim,
    localise_observer,
    read_session_csvs,
)
from analysis.gap.report import write_multi_report, write_report

__all__ = [
    "LAYERS",
    "OBSERVER_CANDIDATES",
    "Candidate",
    "CandidateScore",
    "Diagnosis",
    "GapError",
    "candidate",
    "catalogue",
    "diagnose",
    "diagnose_losses",
    "holm",
    "load_sim",
    "localise_observer",
    "parse_layer_paths",
    "read_session_csvs",
    "register",
    "which_layer",
    "write_multi_report",
    "write_report",
]
