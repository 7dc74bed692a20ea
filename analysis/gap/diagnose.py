"""Diagnose a layer from files: read real and simulated data, rank candidates, localise."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from analysis.gap.display import (
    DISPLAY_CANDIDATES,
    DISPLAY_MIN_SHARE,
    display_ceiling,
    display_floor,
    display_frame,
    display_loss,
    display_loss_info,
    display_unit_ids,
    load_display,
    localise_display,
    split_display,
)
from analysis.gap.engine import Diagnosis, GapError, diagnose_losses
from analysis.gap.observer import (
    OBSERVER_CANDIDATES,
    OBSERVER_MIN_GAIN,
    load_sessions,
    localise_observer,
    observer_floor,
    observer_frame,
    observer_loss,
    observer_unit_ids,
    split_observer,
)
from analysis.gap.render import (
    RENDER_CANDIDATES,
    RENDER_MIN_SHARE,
    load_render,
    localise_render,
    render_ceiling,
    render_floor,
    render_loss,
    render_unit_ids,
    residual_maps,
    split_render,
)

__all__ = ["diagnose_all_files", "diagnose_display", "diagnose_display_files", "diagnose_files", "diagnose_observer",
           "diagnose_observer_files", "diagnose_render", "diagnose_render_files"]


def diagnose_observer(real, sim, design, *, rng: np.random.Generator, seed: int,
                      n_boot: int = 1000) -> tuple[Diagnosis, object]:
    """Observer layer on data frames (session-CSV format). ``sim`` fixes the ideal's noise."""
    real_u = observer_frame(real, design)
    sim_u = observer_frame(sim, design)
    train, test = split_observer(real_u, rng)
    diag = diagnose_losses("observer", OBSERVER_CANDIDATES, train, test, observer_loss(train),
                           lambda d: observer_floor(d, sim_u), rng=rng, seed=seed,
                           n_boot=n_boot, unit_ids=observer_unit_ids,
                           min_gain=OBSERVER_MIN_GAIN)
    return diag, localise_observer(real_u, design, rng, n_boot=min(n_boot, 500))


def diagnose_observer_files(real_path: str | Path, sim_path: str | Path, design, *, seed: int,
                            n_boot: int = 1000):
    """Read session CSVs under ``real_path`` and ``sim_path`` and diagnose the observer layer."""
    if Path(real_path).resolve() == Path(sim_path).resolve():
        raise GapError(f"--real and --sim are the same path ({real_path}); pass the simulation")
    return diagnose_observer(load_sessions(real_path), load_sessions(sim_path), design,
                             rng=np.random.default_rng(seed), seed=seed, n_boot=n_boot)


def diagnose_display(readings, cal, *, rng: np.random.Generator, seed: int,
                     n_boot: int = 1000) -> tuple[Diagnosis, object]:
    """Display layer on a readings frame (``readings.csv`` format) and a Calibration."""
    data = display_frame(readings, cal)
    train, test = split_display(data, rng)
    diag = diagnose_losses("display", DISPLAY_CANDIDATES, train, test, display_loss,
                           display_floor, rng=rng, seed=seed, n_boot=n_boot,
                           unit_ids=display_unit_ids, min_share=DISPLAY_MIN_SHARE,
                           loss_info=display_loss_info(data), ceiling=display_ceiling)
    return diag, localise_display(data, rng, n_boot=min(n_boot, 500))


def diagnose_display_files(real_path: str | Path, sim_path: str | Path, *, seed: int,
                           n_boot: int = 1000):
    """Read ``readings.csv`` (REAL) and ``calibration.json`` (SIM); diagnose the display."""
    readings, cal = load_display(real_path, sim_path)
    return diagnose_display(readings, cal, rng=np.random.default_rng(seed), seed=seed,
                            n_boot=n_boot)


def diagnose_render(data, *, rng: np.random.Generator, seed: int,
                    n_boot: int = 1000) -> tuple[Diagnosis, object]:
    """Render layer on loaded residual files (:func:`analysis.gap.render.load_render`)."""
    train, test = split_render(data, rng)
    diag = diagnose_losses("render", RENDER_CANDIDATES, train, test, render_loss, render_floor,
                           rng=rng, seed=seed, n_boot=n_boot, unit_ids=render_unit_ids,
                           min_share=RENDER_MIN_SHARE, ceiling=render_ceiling,
                           loss_info={"noise_a2_b": {lv["name"]: lv["noise"]
                                                     for lv in data.levels}})
    local = localise_render(data, rng, n_boot=min(n_boot, 500))
    local.attrs["maps"] = residual_maps(data, [(s["added"], s["params"]) for s in diag.steps])
    return diag, local


def diagnose_render_files(real_path: str | Path, sim_path: str | Path, *, seed: int,
                          n_boot: int = 1000):
    """Photos from REAL's and renders from SIM's ``residuals/*.npz`` (the gloss fit's output
    folder; usually the same folder)."""
    return diagnose_render(load_render(real_path, sim_path), rng=np.random.default_rng(seed),
                           seed=seed, n_boot=n_boot)


def diagnose_all_files(real: dict, sim: dict, design, *, seed: int, n_boot: int = 1000) -> dict:
    """Diagnose every layer given ({layer: path} for REAL and SIM; a render layer without a SIM
    path uses its REAL folder). Returns {layer: (Diagnosis, localisation)}."""
    missing = [n for n in real if n not in sim and n != "render"]
    if missing:
        raise GapError(f"--sim lacks {missing}; give LAYER=PATH for every layer in --real")
    return {n: diagnose_files(n, real[n], sim.get(n, real[n]), design, seed=seed,
                              n_boot=n_boot) for n in real}


def diagnose_files(layer: str, real_path, sim_path, design, *, seed: int, n_boot: int = 1000):
    """Diagnose one layer from its files (see ``python -m analysis.gap diagnose --help``)."""
    if layer == "observer":
        return diagnose_observer_files(real_path, sim_path, design, seed=seed, n_boot=n_boot)
    if layer == "display":
        return diagnose_display_files(real_path, sim_path, seed=seed, n_boot=n_boot)
    if layer == "render":
        return diagnose_render_files(real_path, sim_path, seed=seed, n_boot=n_boot)
    raise GapError(f"unknown layer {layer!r}; use observer, display or render")
