"""One entry point for every layer: :func:`diagnose` reads real and simulated data (files or
loaded objects), ranks the layer's registered candidates, tests what remains, and localises."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from analysis.gap.engine import (
    Diagnosis,
    DiagnosisSettings,
    GapError,
    LayerFunctions,
    catalogue,
    diagnose_losses,
)

__all__ = ["LAYERS", "diagnose"]


def _same_path(real, sim) -> None:
    if (isinstance(real, (str, Path)) and isinstance(sim, (str, Path))
            and Path(real).resolve() == Path(sim).resolve()):
        raise GapError(f"--real and --sim are the same path ({real}); pass the simulation")


def _observer(real, sim, design, *, seed: int, n_boot: int, sim_kind: str | None = None,
              k_folds: int = 5):
    """Observer layer: session CSVs (or a session frame) against the simulated observer
    (``sim``: an observers TOML, simulated session CSVs or a frame; see
    :func:`analysis.gap.observer.load_sim`)."""
    from analysis.gap.observer import (
        OBSERVER_MIN_GAIN,
        adapt_base,
        ceiling_floor,
        ceiling_loss,
        check_sim,
        fit_ceiling,
        load_sim,
        localise_observer,
        observer_folds,
        observer_frame,
        observer_loss,
        observer_unit_ids,
        observer_where,
        read_session_csvs,
    )

    _same_path(real, sim)
    frame = real if not isinstance(real, (str, Path)) else read_session_csvs(real)
    base = load_sim(sim, design, kind=sim_kind)
    notes = check_sim(frame, base)
    data = observer_frame(frame, design, base)
    folds, text = observer_folds(data, k_folds)
    rng = np.random.default_rng(seed)
    floor, shared = {}, {}
    for tr, te in folds:
        shared[id(te)] = bool(set(tr["participant"]) & set(te["participant"]))
        adapt_base(tr, te, base)
        # The floor: the noise of the ceiling over the plain simulation (data-driven).
        model = fit_ceiling(tr, by_participant=shared[id(te)])
        floor[id(te)] = ceiling_floor(model, te, rng)

    def ceiling(tr, te, fitted):
        # The ceiling over the chosen model: what a flexible extension of it still gains.
        return ceiling_loss(fit_ceiling(tr, by_participant=shared[id(te)], fitted=fitted), te)
    functions = LayerFunctions(loss=observer_loss, floor=lambda te: floor[id(te)],
                               ceiling=ceiling, ceiling_given_chosen=True, where=observer_where,
                               unit_ids=observer_unit_ids)
    diag = diagnose_losses(
        "observer", catalogue("observer"), functions,
        DiagnosisSettings(n_boot=n_boot, min_gain=OBSERVER_MIN_GAIN),
        rng=rng, seed=seed, folds=folds, split=text, warnings=notes,
        loss_info={"base": {"kind": base.kind, "source": base.source,
                            "coef_slider_units": {r: list(v) for r, v in base.coef.items()}},
                   "floor": "the ceiling model's own loss on data it draws (data-driven)"})
    return diag, localise_observer(data, design, rng, n_boot=min(n_boot, 500))


def _display(real, sim, design, *, seed: int, n_boot: int, **_):
    """Display layer: photometer readings (``readings.csv``, its folder or a frame) against
    the calibration (``calibration.json``, its folder or a Calibration)."""
    from analysis.gap.display import (
        DISPLAY_MIN_SHARE,
        display_ceiling,
        display_floor,
        display_folds,
        display_frame,
        display_loss,
        display_loss_info,
        display_unit_ids,
        display_where,
        load_display,
        localise_display,
    )

    readings, cal = (load_display(real, sim) if isinstance(real, (str, Path)) else (real, sim))
    rng = np.random.default_rng(seed)
    data = display_frame(readings, cal)
    folds, text = display_folds(data, rng)
    functions = LayerFunctions(loss=lambda _train: display_loss, floor=display_floor,
                               ceiling=display_ceiling, where=display_where,
                               unit_ids=display_unit_ids)
    diag = diagnose_losses("display", catalogue("display"), functions,
                           DiagnosisSettings(n_boot=n_boot, min_share=DISPLAY_MIN_SHARE),
                           rng=rng, seed=seed, folds=folds,
                           loss_info=display_loss_info(data), split=text)
    return diag, localise_display(data, rng, n_boot=min(n_boot, 500))


def _render(real, sim, design, *, seed: int, n_boot: int, **_):
    """Render layer: photos from REAL's and renders from SIM's ``residuals/*.npz`` (the gloss
    fit's output folder, usually the same), or loaded residual files. A remaining gap counts
    only from the design's ``[gap] render_tolerance_pct`` (the shipped design's when
    ``design`` is None)."""
    from analysis.gap.render import (
        RENDER_MIN_GAIN,
        RENDER_MIN_SHARE,
        RENDER_SIZE_UNIT,
        load_render,
        localise_render,
        render_ceiling,
        render_floor,
        render_loss,
        render_misfit_pct,
        render_unit_ids,
        render_where,
        residual_maps,
        split_render,
    )

    data = load_render(real, sim if sim is not None else real) if isinstance(
        real, (str, Path)) else real
    if design is None:
        from studydesign import load_design

        design = load_design()
    rng = np.random.default_rng(seed)
    train, test = split_render(data, rng)
    functions = LayerFunctions(
        loss=render_loss, floor=render_floor, ceiling=render_ceiling, ceiling_given_chosen=True,
        where=render_where, size=render_misfit_pct, unit_ids=render_unit_ids,
        # Each held-out pixel its own cluster: the tests' normal limit, with no Monte-Carlo
        # error (the split is fixed, so the verdict does not depend on the seed). Under the
        # null of nothing systematic left, the pixels' camera noise is independent.
        cluster_of=str)
    settings = DiagnosisSettings(n_boot=n_boot, min_share=RENDER_MIN_SHARE,
                                 min_gain=RENDER_MIN_GAIN,
                                 min_size=design.gap.render_tolerance_pct,
                                 size_unit=RENDER_SIZE_UNIT,
                                 size_source="the design's [gap] render_tolerance_pct")
    diag = diagnose_losses("render", catalogue("render"), functions, settings, rng=rng,
                           seed=seed, train=train, test=test,
                           loss_info={"noise_a2_b": {lv["name"]: lv["noise"]
                                                     for lv in data.levels}})
    local = localise_render(data, rng, n_boot=min(n_boot, 500))
    local.attrs["maps"] = residual_maps(data, [(s["added"], s["params"]) for s in diag.steps])
    return diag, local


#: The layers :func:`diagnose` knows, each ``fn(real, sim, design, *, seed, n_boot, **options)
#: -> (Diagnosis, localisation)``.
LAYERS = {"observer": _observer, "display": _display, "render": _render}


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
        observers TOML), ``k_folds``.

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
    opts = options if layer == "observer" else {}
    return LAYERS[layer](real, sim, design, seed=seed, n_boot=n_boot, **opts)
