"""One entry point for every layer: :func:`diagnose` reads real and simulated data (files or
loaded objects), ranks the layer's registered candidates, tests what remains, and localises.

It is written once for all layers: each layer package ``analysis.gap.<layer>`` hands it a
:class:`analysis.gap.engine.LayerPlan` from its ``plan(real, sim, design, rng, *, n_boot,
**options)`` (the files read and checked, the held-out units, the floor, the ceiling, where),
and :func:`analysis.gap.engine.diagnose_losses` does the rest."""

from __future__ import annotations

import importlib
from dataclasses import replace

import numpy as np

from analysis.gap.engine import (
    LAYER_NAMES,
    Diagnosis,
    GapError,
    catalogue,
    diagnose_losses,
    summarise,
)
from analysis.gap.engine.departures import with_departures
from analysis.gap.engine.power import power_analysis
from analysis.gap.engine.steps import INCONCLUSIVE, NO_GAP_THAT_MATTERS

__all__ = ["LAYERS", "diagnose"]

#: The layers :func:`diagnose` knows (each a package ``analysis.gap.<layer>`` with ``plan``).
LAYERS = LAYER_NAMES


def _diagnose_layer(layer: str, real, sim, design, *, seed: int, n_boot: int, **options):
    """One layer: its plan, the engine's diagnosis, then the layer's localisation, all drawing
    from one Generator seeded with ``seed`` in that order."""
    rng = np.random.default_rng(seed)
    plan = importlib.import_module(f"analysis.gap.{layer}").plan(
        real, sim, design, rng, n_boot=n_boot, **options)
    diag = diagnose_losses(layer, list(plan.candidates) or catalogue(layer), plan.functions,
                           plan.settings, rng=rng, seed=seed, train=plan.train, test=plan.test,
                           folds=plan.folds, loss_info=plan.loss_info, split=plan.split,
                           warnings=plan.warnings, not_identifiable=plan.not_identifiable)
    if plan.sizes is not None:
        # Words again: the sizes (the misfit in the data's units) are part of the verdict.
        diag = replace(diag, **plan.sizes(diag))
        diag = replace(diag, summary=summarise(diag))
    held = diag.verdict == NO_GAP_THAT_MATTERS and bool(plan.cannot_exclude)
    if held:
        # The bound excludes a gap of the tolerance only in what the data could measure.
        diag = replace(diag, verdict=INCONCLUSIVE)
    if plan.departures is not None:
        # Single units that depart from the others where the misfit cannot see them.
        diag = with_departures(diag, plan.departures(diag))
        diag = replace(diag, summary=summarise(diag))
        held = held and diag.verdict == INCONCLUSIVE
    if diag.verdict == INCONCLUSIVE and plan.power is not None:
        model = plan.power(diag)
        if model is not None:
            diag = replace(diag, **power_analysis(model, seed=seed))
            diag = replace(diag, summary=summarise(diag))
    if held:
        words = summarise(diag).replace(" is excluded.", f" is excluded {plan.excluded_where}.")
        diag = replace(diag, summary=words + " The data cannot exclude a gap: "
                       + " ".join(plan.cannot_exclude))
    return diag, plan.localise(diag, rng)


def diagnose(layer: str, real, sim, design, *, seed: int, n_boot: int = 1000,
             **options) -> tuple[Diagnosis, object] | dict:
    """Diagnose the sim-to-real gap of one layer, or of several (``layer='all'``).

    Parameters
    ----------
    layer : {"observer", "display", "render", "all"}
    real, sim
        observer: session CSVs (folder, file or frame) and the simulated observer (an
        observers TOML, simulated session CSVs or a frame); display: readings and calibration
        (paths or loaded); render: the gloss fit's output folders (SIM may be None: REAL's).
        ``all``: dicts ``{layer: real}`` and ``{layer: sim}`` (render may be missing from SIM).
    design : StudyDesign
    seed : int
        The bootstrap's random seed (held-out folds do not depend on it in the observer layer).
    n_boot : int
        Bootstrap resamples.
    **options
        Passed to the layer: observer ``sim_kind`` ('humanlike' or 'ideal', the table of an
        observers TOML), ``k_folds``; ``study`` (another lab's study.toml: one response on
        a rating scale, :mod:`analysis.gap.observer.rating`) and ``participants``; render
        ``lights`` (held-out lights of a directional-light set, e.g. "25-48", with REAL the
        photo set).

    Returns
    -------
    (Diagnosis, localisation) or, for ``all``, ``{layer: (Diagnosis, localisation)}``.

    Raises
    ------
    GapError
        Unknown layer, bad input files, or ``all`` with a real layer missing its SIM.
    """
    if layer == "all":
        if not isinstance(real, dict) or not isinstance(sim, dict):
            raise GapError("layer 'all' needs {layer: path} for real and sim")
        missing = [n for n in real if n not in sim and n != "render"]
        if missing:
            raise GapError(f"--sim lacks {missing}; give LAYER=PATH for every layer in --real")
        return {n: diagnose(n, real[n], sim.get(n, real[n]), design, seed=seed, n_boot=n_boot,
                            **options) for n in real}
    if layer not in LAYERS:
        raise GapError(f"unknown layer {layer!r}; use {', '.join(LAYERS)} or all")
    opts = options if layer == "observer" else {
        k: v for k, v in options.items() if layer == "render" and k == "lights"}
    return _diagnose_layer(layer, real, sim, design, seed=seed, n_boot=n_boot, **opts)
