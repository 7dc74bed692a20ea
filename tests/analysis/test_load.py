"""Loading and validating session CSVs: good folders load, each kind of damage is named."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from analysis.load import SessionDataError, load_sessions
from experiment import SESSION_COLUMNS

from .sessions import write_sessions


@pytest.fixture
def folder(tmp_path, design):
    write_sessions(tmp_path, design, np.random.default_rng(1), n_participants=2)
    return tmp_path


def test_complete_folder_loads_in_physical_units(folder, design):
    data = load_sessions(folder, design)
    assert len(data.frame) == 2 * design.n_stimuli
    assert data.warnings == ()
    assert data.participants == ["S01", "S02"]
    f = data.frame
    np.testing.assert_allclose(f["depth_match_cm"], design.slider.to_depth_cm(f["depth_match"]))
    np.testing.assert_allclose(f["gloss_match_pct"], design.slider.to_gloss_pct(f["gloss_match"]))
    assert set(f["depth_bin"]) == {"low", "medium", "high"}
    # The sessions folder itself is accepted too.
    assert len(load_sessions(folder / "sessions", design).frame) == len(f)


def _edit(folder, name, change):
    path = folder / "sessions" / name
    frame = pd.read_csv(path, dtype=str)
    change(frame).to_csv(path, index=False)


def test_incomplete_session_and_missing_session_are_warnings(folder, design):
    _edit(folder, "S01_s2.csv", lambda f: f.iloc[:40])
    (folder / "sessions" / "S02_s2.csv").unlink()
    data = load_sessions(folder, design)
    assert any("S01_s2.csv: incomplete session, 40 of" in w for w in data.warnings)
    assert any("participant S02: session(s) [2] not recorded" in w for w in data.warnings)
    per_session = design.sessions.trials_per_session
    # S01: 81 + 40 trials; S02: session 1 only.
    assert len(data.frame) == per_session + 40 + per_session


def _set(col, row, value):
    def change(f):
        f.loc[row, col] = value
        return f
    return change


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda f: f.drop(columns="rt_s"), r"wrong columns \(missing \['rt_s'\]"),
        (lambda f: f[list(SESSION_COLUMNS[::-1])], "out of order"),
        (_set("gloss_match", 3, "11.5"), r"gloss_match = 11.5, outside the slider"),
        (_set("depth_match", 0, "0.2"), r"depth_match = 0.2, outside the slider"),
        (_set("depth_match", 0, "abc"), r"depth_match = 'abc', not a number"),
        (_set("trial", 5, "5"), r"trial numbers \[5\] occur more than once"),
        (lambda f: f.drop(index=10), r"trials \[11\] are missing"),
        (_set("stimulus_id", 2, "moon_g05_d05"),
         r"stimuli \['moon_g05_d05'\] are not in the design"),
        (_set("true_depth_cm", 2, "9.9"), "has true_depth_cm = 9.9 but the design says"),
        (_set("participant", 2, "S09"), "but the file name says"),
    ],
)
def test_damaged_files_are_named_with_the_fix(folder, design, change, message):
    _edit(folder, "S01_s1.csv", change)
    with pytest.raises(SessionDataError, match=message):
        load_sessions(folder, design)


def test_overlapping_sessions_of_one_participant(folder, design):
    import shutil
    shutil.copy(folder / "sessions" / "S01_s1.csv", folder / "sessions" / "S01_s3.csv")
    _edit(folder, "S01_s3.csv", _set("session", slice(None), "3"))
    with pytest.raises(SessionDataError, match="shown twice"):
        load_sessions(folder, design)


def test_empty_folder_and_bad_file_name(tmp_path, design):
    with pytest.raises(SessionDataError, match="no session files"):
        load_sessions(tmp_path, design)
    (tmp_path / "sessions").mkdir()
    (tmp_path / "sessions" / "notes.csv").write_text("a,b\n1,2\n")
    with pytest.raises(SessionDataError, match="file name is not"):
        load_sessions(tmp_path, design)


def test_torn_last_row_is_left_out_and_named(folder, design):
    """A row cut off mid-write (fields missing, a number cut short) was accepted as a trial;
    the experiment's reader leaves it out, and the file is not changed."""
    path = folder / "sessions" / "S01_s1.csv"
    text = path.read_text()
    last = text.splitlines()[-1]
    torn = text[: len(text) - len(last) - 1] + last[: last.index(",", 60) + 3]
    path.write_text(torn)
    data = load_sessions(folder, design)
    n = design.sessions.trials_per_session
    assert (data.frame["participant"] == "S01").sum() == 2 * n - 1
    assert any("S01_s1.csv: torn last row left out" in w and f"line {n + 1} is torn" in w
               for w in data.warnings)
    assert path.read_text() == torn


def test_simulated_and_mixed_calibration_data_are_listed(folder, design):
    _edit(folder, "S02_s1.csv", _set("calibration_id", slice(None), "simulated"))
    _edit(folder, "S01_s2.csv", _set("calibration_id", slice(0, 9), "crt-2026-11"))
    data = load_sessions(folder, design)
    assert any("simulated data included: participants ['S02']" in w for w in data.warnings)
    assert any("S01 session 2: trials recorded with calibrations ['crt-2026-11', 'default']"
               in w for w in data.warnings)
    assert ("simulated", ("S02",), design.sessions.trials_per_session) in data.calibrations
    assert any(w.startswith("data of more than one calibration") for w in data.warnings)


def test_sessions_answered_by_the_apps_simulated_observer_are_listed(folder, design):
    """``experiment run --simulate`` writes the real calibration's id into the real data folder:
    its rows are still listed as simulated (their app_version says so), not as a participant."""
    from experiment.session import _session_row
    from experiment.trial import TrialResult

    path = folder / "sessions" / "S01_s1.csv"
    frame = pd.read_csv(path, dtype=str)
    plan_row = frame.iloc[0].to_dict()
    result = TrialResult(gloss_match=5.0, depth_match=5.0, rt_s=1.0, onset_s=0.0,
                         dropped_frames=0, gloss_history=(), depth_history=(), gloss_trace=(),
                         depth_trace=(), early_space_s=(), pauses=())
    row = _session_row(plan_row, result, "crt-2026-11", simulate="humanlike")
    assert row["calibration_id"] == "crt-2026-11"
    frame["app_version"] = row["app_version"]
    frame.to_csv(path, index=False)
    data = load_sessions(folder, design)
    assert any("simulated data included: participants ['S01']" in w for w in data.warnings)
