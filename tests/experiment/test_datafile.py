"""Session data files: one torn-tail rule for the session CSV, slider histories and run logs,
a full disk that leaves no torn record, and files written with the umask's permissions."""

from __future__ import annotations

import errno
import json
import os
import warnings

import pandas as pd
import pytest

from experiment import SESSION_COLUMNS, read_session
from experiment.__main__ import main
from experiment.datafile import (
    SessionWriter,
    append_run_event,
    read_run_events,
    runs_path,
    sliders_path,
)
from experiment.plan import load_or_create_plan
from labfiles import TornTailWarning


def _row(trial: int) -> dict:
    row = dict.fromkeys(SESSION_COLUMNS, 1)
    row.update(participant="P01", session=1, trial=trial, stimulus_id=f"s{trial}",
               illumination="indoor", timestamp_utc="t", app_version="v", calibration_id="c")
    return row


def _history(trial: int) -> dict:
    return {"gloss_history": [[float(trial), 0.5]] * 200, "depth_history": [[2.0, 0.7]]}


def test_torn_slider_history_is_moved_aside_and_the_resume_appends_cleanly(tmp_path):
    """A full disk during a history write left half a JSON line; the old writer appended the
    next trial onto it, so the whole file no longer read as JSON lines."""
    with SessionWriter(tmp_path, "P01", 1) as w:
        for t in (1, 2):
            w.append(_row(t), _history(t))
    hist = sliders_path(tmp_path, "P01", 1)
    whole = hist.read_bytes()
    with open(hist, "ab") as fh:
        fh.write(json.dumps({"trial": 3, **_history(3)}).encode()[:700])
    with warnings.catch_warnings(record=True) as caught, SessionWriter(tmp_path, "P01", 1) as w:
        assert [t.line for t in w.torn] == [3]
        w.append(_row(3), _history(3))
    assert [w.category for w in caught] == [TornTailWarning]
    assert "line 3 is torn" in str(caught[0].message)
    lines = pd.read_json(hist, lines=True)
    assert lines["trial"].tolist() == [1, 2, 3]
    side = list(hist.parent.glob(hist.name + ".torn-*"))
    assert len(side) == 1 and len(side[0].read_bytes()) == 700
    assert hist.read_bytes().startswith(whole)
    assert read_session(tmp_path / "sessions" / "P01_s1.csv")["trial"].tolist() == [1, 2, 3]


def test_torn_session_row_is_left_out_by_readers_and_moved_aside_by_the_writer(tmp_path):
    with SessionWriter(tmp_path, "P01", 1) as w:
        w.append(_row(1))
    path = tmp_path / "sessions" / "P01_s1.csv"
    with open(path, "a") as fh:
        fh.write("P01,1,2,1,s2,indoor,1,1,1")  # fields missing, a number cut short
    before = path.read_bytes()
    with pytest.warns(TornTailWarning, match="next run of this session moves"):
        assert read_session(path)["trial"].tolist() == [1]
    assert path.read_bytes() == before  # a reader does not change the file
    with warnings.catch_warnings(record=True) as caught, SessionWriter(tmp_path, "P01", 1) as w:
        w.append(_row(2))
    assert "damaged bytes were moved" in str(caught[0].message)
    assert read_session(path)["trial"].tolist() == [1, 2]


def test_status_fails_on_a_damaged_session_and_notes_simulated_trials(tmp_path, design, capsys):
    """A row damaged in the middle of a session CSV is not a torn tail: `status` exits 1 (a
    script checking the lab's sessions notices); trials of a simulated observer are noted."""
    import numpy as np

    from experiment import make_observer, write_simulated_sessions

    obs = [make_observer("ideal", "P01", np.random.default_rng(1), design=design)]
    first, _ = write_simulated_sessions(tmp_path, design, obs, np.random.default_rng(2))
    assert main(["status", "--participant", "P01", "--data", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert f"NOTE: {design.sessions.trials_per_session} of these trials were answered by a " \
           "simulated observer" in out
    lines = first.read_text().splitlines()
    lines[3] = lines[3][:20]
    first.write_text("\n".join(lines) + "\n")
    assert main(["status", "--participant", "P01", "--data", str(tmp_path)]) == 1
    assert "session 1: DAMAGED" in capsys.readouterr().out


def test_torn_run_log_is_named_in_status_and_repaired_by_the_next_run(tmp_path, design,
                                                                     capsys):
    """A torn last line of *_runs.jsonl crashed `status` and `run` with a JSONDecodeError that
    named no file."""
    load_or_create_plan(design, "P01", tmp_path)
    events = runs_path(tmp_path, "P01", 1)
    append_run_event(events, {"event": "start", "run": 1})
    with open(events, "a") as fh:
        fh.write('{"event": "compl')
    assert main(["status", "--participant", "P01", "--data", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "1 run(s), last event 'start'" in out
    assert f"WARNING: {events}: line 2 is torn" in out
    with pytest.warns(TornTailWarning):
        assert [e["event"] for e in read_run_events(events, repair=True)] == ["start"]
    append_run_event(events, {"event": "start", "run": 2})
    assert [e["run"] for e in read_run_events(events)] == [1, 2]


def test_full_disk_leaves_no_torn_record_and_names_the_file(tmp_path, small_disk):
    with small_disk("64k") as disk:
        with SessionWriter(disk, "P01", 1) as w:
            w.append(_row(1), _history(1))
            filler = disk / "filler"
            fd = os.open(filler, os.O_WRONLY | os.O_CREAT)
            try:
                while os.write(fd, b"x" * 512) == 512:
                    pass
            except OSError as exc:
                assert exc.errno == errno.ENOSPC
            finally:
                os.close(fd)
            with pytest.raises(OSError, match="disk is full: could not append to") as info:
                for t in range(2, 50):
                    w.append(_row(t), _history(t))
            assert info.value.errno == errno.ENOSPC
        n = len(read_session(disk / "sessions" / "P01_s1.csv"))
        hist = pd.read_json(sliders_path(disk, "P01", 1), lines=True)
        assert hist["trial"].tolist()[:n] == list(range(1, n + 1))
        assert not list(disk.rglob("*.torn-*"))
        filler.unlink()
        with SessionWriter(disk, "P01", 1) as w:
            assert w.torn == []
            w.append(_row(n + 1), _history(n + 1))
        assert read_session(disk / "sessions" / "P01_s1.csv")["trial"].iloc[-1] == n + 1


def test_plan_and_run_logs_get_the_umask_permissions(tmp_path, design):
    old = os.umask(0o002)
    try:
        load_or_create_plan(design, "P01", tmp_path)
        with SessionWriter(tmp_path, "P01", 1) as w:
            w.append(_row(1))
    finally:
        os.umask(old)
    for path in (tmp_path / "plans" / "P01_plan.csv", tmp_path / "sessions" / "P01_s1.csv"):
        assert path.stat().st_mode & 0o777 == 0o664, path
