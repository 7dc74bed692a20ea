"""The demo's pilot, made as scripts/demo.sh makes it: four humanlike observers of the shipped
observers.toml (``experiment simulate --observer humanlike --participants PILOT1 PILOT2 PILOT3
PILOT4 --seed 2``, the same function without the command line)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from analysis.load import load_sessions
from analysis.models import model_frame
from experiment.observers import make_observer, write_simulated_sessions

PILOT = ("PILOT1", "PILOT2", "PILOT3", "PILOT4")


def pilot_frame(folder: Path, design, seed: int = 2):
    """The pilot's model frame (standardised gloss and depth, depth_match_bc)."""
    rng = np.random.default_rng(seed)
    observers = [make_observer("humanlike", p, rng, design=design) for p in PILOT]
    write_simulated_sessions(folder, design, observers, rng)
    return model_frame(load_sessions(folder, design).frame, design)
