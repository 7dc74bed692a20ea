"""Scientific check: simulated observers through the whole analysis give the source study's pattern.

With the source study's 11 observers, ``humanlike`` observers must show a large depth effect on
estimated depth with no gloss effect and no interaction, significant gloss, depth and
interaction effects on estimated gloss, depth compression and "deeper looks glossier";
``ideal`` observers must show no depth effect on estimated gloss.

The observers are the experiment's (``experiment.simulate_dataset`` / ``make_observer``) when
that API exists, else the plain-numpy observers of ``tests/analysis/sessions.py``; the source
is named in every assertion message.
"""

from __future__ import annotations

import numpy as np
import pytest

import experiment
from analysis.load import load_sessions
from analysis.models import fit_source_study_models
from analysis.report import source_study_pattern
from experiment import SESSION_COLUMNS

from .sessions import write_sessions

N_OBSERVERS = 11
HAS_EXPERIMENT = hasattr(experiment, "simulate_dataset") and hasattr(experiment, "make_observer")
SOURCE = "experiment.simulate_dataset" if HAS_EXPERIMENT else "tests/analysis/sessions.py"


def _write(folder, design, kind: str, seed: int) -> None:
    rng = np.random.default_rng(seed)
    if not HAS_EXPERIMENT:
        write_sessions(folder, design, rng, n_participants=N_OBSERVERS, kind=kind)
        return
    observers = [experiment.make_observer(kind, f"S{k + 1:02d}", rng)
                 for k in range(N_OBSERVERS)]
    frame = experiment.simulate_dataset(design, observers, rng)
    (folder / "sessions").mkdir(parents=True)
    for (who, session), rows in frame.groupby(["participant", "session"]):
        rows[list(SESSION_COLUMNS)].to_csv(folder / "sessions" / f"{who}_s{session}.csv",
                                           index=False)


def _pattern(tmp_path, design, kind, seed):
    _write(tmp_path, design, kind, seed)
    frame = load_sessions(tmp_path, design).frame
    assert frame["participant"].nunique() == N_OBSERVERS
    return source_study_pattern(fit_source_study_models(frame, design), frame)


@pytest.mark.parametrize("seed", [11, 12])
def test_humanlike_observers_show_the_source_studys_pattern(tmp_path, design, seed):
    pattern = _pattern(tmp_path, design, "humanlike", seed)
    failed = {k: v[1] for k, v in pattern.items() if not v[0]}
    assert not failed, f"observers from {SOURCE}: pattern missing: {failed}"


@pytest.mark.parametrize("seed", [21, 22])
def test_ideal_observers_show_no_depth_effect_on_gloss(tmp_path, design, seed):
    pattern = _pattern(tmp_path, design, "ideal", seed)
    for finding in ("depth effect on estimated gloss", "deeper looks glossier",
                    "depth compression (low depths overestimated, high underestimated)"):
        holds, detail = pattern[finding]
        assert not holds, f"observers from {SOURCE}: ideal observers show '{finding}': {detail}"
    assert pattern["large depth effect on estimated depth"][0]
    assert pattern["gloss effect on estimated gloss"][0]
