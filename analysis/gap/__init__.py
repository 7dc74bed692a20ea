"""Sim-to-real gap diagnosis: where the gap lies, which unmodelled effect causes it, how far it
shrinks once the effect is added, and whether a gap remains that the catalogue does not
explain, all on held-out data.

Layers: ``observer`` (session CSVs vs a simulated observer, fitted to a pilot or ideal),
``display`` (photometer readings vs the calibration), ``render`` (photos vs fitted Ward
renders, the gloss fit's residual files); ``all`` diagnoses several and names the layer that
carries the gap. One entry point, :func:`diagnose`; each layer's catalogue is a list of
:class:`Candidate` objects registered with :func:`register` (:func:`catalogue`,
:func:`candidate`).

The blind benchmarks live apart, in the package :mod:`analysis.gapbench`
(``python -m analysis gapbench``); the diagnosis imports nothing of it, and it imports the
diagnosis only through the names listed here (tests/analysis/gapbench/test_independence.py
checks both). Besides :func:`diagnose` and the catalogue, the names the benchmark needs are
public on purpose:

* the effect registry: :func:`effect` (a candidate or an out-of-catalogue effect by name),
  :func:`strengths` (each effect's moderate strength), :func:`out_of_catalogue`, and
  :class:`OutOfCatalogue` objects registered beside the candidates with
  :func:`register_out_of_catalogue` (the benchmark's injectors register theirs);
* the observer layer's slider units and likelihood: :func:`to_slider_units`,
  :func:`base_from_params` (the simulation an observers-TOML table describes),
  :func:`observer_frame`, :func:`observer_nll` and :func:`observer_loss` (the loss the
  diagnosis scores with), with which the benchmark measures the true shrinkage;
* the render layer's noise model :func:`noise_sd` (per-pixel SD from the ``noise_a2_b`` the
  diagnosis records), for the same purpose.
"""

from analysis.gap.diagnose import LAYERS, diagnose
from analysis.gap.engine import (
    Candidate,
    CandidateScore,
    Diagnosis,
    GapError,
    OutOfCatalogue,
    candidate,
    catalogue,
    diagnose_losses,
    effect,
    holm,
    out_of_catalogue,
    register,
    register_out_of_catalogue,
    strengths,
)
from analysis.gap.engine.steps import INCONCLUSIVE, NO_GAP_THAT_MATTERS, NOT_A_GAP
from analysis.gap.layers import parse_layer_paths, which_layer
from analysis.gap.observer import (
    OBSERVER_CANDIDATES,
    base_from_params,
    load_sim,
    localise_observer,
    observer_frame,
    observer_loss,
    observer_nll,
    read_session_csvs,
    to_slider_units,
)
from analysis.gap.render import noise_sd
from analysis.gap.report import write_multi_report, write_report

__all__ = [
    "INCONCLUSIVE",
    "LAYERS",
    "NOT_A_GAP",
    "NO_GAP_THAT_MATTERS",
    "OBSERVER_CANDIDATES",
    "Candidate",
    "CandidateScore",
    "Diagnosis",
    "GapError",
    "OutOfCatalogue",
    "base_from_params",
    "candidate",
    "catalogue",
    "diagnose",
    "diagnose_losses",
    "effect",
    "holm",
    "load_sim",
    "localise_observer",
    "noise_sd",
    "observer_frame",
    "observer_loss",
    "observer_nll",
    "out_of_catalogue",
    "parse_layer_paths",
    "read_session_csvs",
    "register",
    "register_out_of_catalogue",
    "strengths",
    "to_slider_units",
    "which_layer",
    "write_multi_report",
    "write_report",
]
