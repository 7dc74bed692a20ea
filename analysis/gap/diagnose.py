"""Diagnose a layer from files: read real and simulated data, rank candidates, localise."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from analysis.gap.engine import Diagnosis, GapError, diagnose_losses
from analysis.gap.observer import (
    OBSERVER_CANDIDATES,
    load_sessions,
    localise_observer,
    observer_floor,
    observer_frame,
    observer_loss,
    observer_unit_ids,
    split_observer,
)

__all__ = ["diagnose_observer", "diagnose_observer_files"]


def diagnose_observer(real, sim, design, *, rng: np.random.Generator, seed: int,
                      n_boot: int = 1000) -> tuple[Diagnosis, object]:
    """Observer layer on data frames (session-CSV format). ``sim`` fixes the ideal's noise."""
    real_u = observer_frame(real, design)
    sim_u = observer_frame(sim, design)
    train, test = split_observer(real_u, rng)
    diag = diagnose_losses("observer", OBSERVER_CANDIDATES, train, test, observer_loss(train),
                           lambda d: observer_floor(d, sim_u), rng=rng, seed=seed,
                           n_boot=n_boot, unit_ids=observer_unit_ids)
    return diag, localise_observer(real_u, design, rng, n_boot=min(n_boot, 500))


def diagnose_observer_files(real_path: str | Path, sim_path: str | Path, design, *, seed: int,
                            n_boot: int = 1000):
    """Read session CSVs under ``real_path`` and ``sim_path`` and diagnose the observer layer."""
    if Path(real_path).resolve() == Path(sim_path).resolve():
        raise GapError(f"--real and --sim are the same path ({real_path}); pass the simulation")
    return diagnose_observer(load_sessions(real_path), load_sessions(sim_path), design,
                             rng=np.random.default_rng(seed), seed=seed, n_boot=n_boot)
