"""The observer layer on small or damaged data (issues 43 and 44): simulated sessions holding
NaN are refused by file and row, not crashed on inside scipy."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.gap import GapError, diagnose
from analysis.gapbench import inject
from studydesign import load_design

DESIGN = load_design()


def _sessions(seed: int, n: int):
    return inject.simulate_sessions(DESIGN, n, np.random.default_rng(seed))


def test_simulated_sessions_holding_nan_are_refused_naming_the_file_and_rows(tmp_path):
    real, sim = _sessions(1, 4), _sessions(2, 4)
    sim.loc[[3, 7], "depth_match"] = np.nan
    inject.write_sessions(sim, tmp_path / "sim")
    before = {p.name: p.read_bytes() for p in (tmp_path / "sim").iterdir()}
    with pytest.raises(GapError, match=r"(?s)2 of \d+ rows have empty or non-numeric "
                       r"\['depth_match'\].*B00_s1\.csv data rows \[\d+, \d+\].*simulate "
                       "these sessions again"):
        diagnose("observer", real, tmp_path / "sim", DESIGN, seed=1, n_boot=50)
    assert {p.name: p.read_bytes() for p in (tmp_path / "sim").iterdir()} == before


def test_a_simulated_frame_holding_nan_is_refused_naming_participant_and_session():
    real, sim = _sessions(1, 4), _sessions(2, 4)
    sim.loc[5, "gloss_match"] = np.nan
    with pytest.raises(GapError, match=r"1 of \d+ rows .*participant, session: \[\['B00'"):
        diagnose("observer", real, sim, DESIGN, seed=1, n_boot=50)
