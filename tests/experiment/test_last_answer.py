"""The end of a session and the records of a killed run (issue 44, items 3 and 4), by the real
app under Xvfb (small design: 6 trials a session), killed or signalled as an operator would.

- Ctrl-C or SIGTERM right after the last answer (the operator closing the window) printed "run
  the same command to continue" while the same command then said "already complete", and the
  run's log (versions, inputs, frame timing, dropped frames) and its end event were never
  written; a run killed with kill -9 there lost them for good.
- A crashed run's session CSV, slider file *and* frames file moved aside: the session started
  over at trial 1, although the run history records run 1 starting and never ending.
"""

from __future__ import annotations

import json
import shutil
import signal

import pytest

from experiment import read_session
from experiment.datafile import read_run_events

from .test_resume import _cmd, _kill_after, _run

pytestmark = [pytest.mark.xvfb, pytest.mark.slow]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_after_the_last_answer_ends_the_run_with_its_log(
        sig, small_design, small_design_path, session_files):
    """The signal lands once the CSV holds every row (the run then writes its frame plot and
    log): the session is complete, its log and end event are written, and the line says so."""
    f = session_files
    n = small_design.sessions.trials_per_session
    path = f["data"] / "sessions" / "L1_s1.csv"
    logs = f["data"] / "logs"
    kept = _kill_after(_cmd(small_design_path, f, "L1", 1), path, n, sig=sig)
    err = _kill_after.stderr
    assert kept == n
    assert _kill_after.returncode == 0, err
    assert "run the same command to continue" not in err and "Traceback" not in err, err
    log = json.loads((logs / "L1_s1_run1.json").read_text())
    assert log["status"] == "complete" and log["trials_this_run"] == n
    assert log["versions"]["psychopy"] and log["frame_intervals"]["n"] > 0
    end = read_run_events(logs / "L1_s1_runs.jsonl")[-1]
    assert end["event"] == "complete" and end["trials_this_run"] == n, end
    assert read_session(path)["trial"].tolist() == list(range(1, n + 1))


def test_a_run_killed_after_its_last_answer_gets_its_log_from_the_next_command(
        small_design, small_design_path, session_files):
    """kill -9 once the last row is written: the same command says the session is complete,
    writes the run's log from its records (marked recovered: frame intervals from its frames
    file, dropped frames and trials from its rows, inputs from its start event) and the end
    event it lacked; a third run changes nothing."""
    f = session_files
    n = small_design.sessions.trials_per_session
    cmd = _cmd(small_design_path, f, "L2", 1)
    path = f["data"] / "sessions" / "L2_s1.csv"
    logs = f["data"] / "logs"
    assert _kill_after(cmd, path, n) == n
    events = logs / "L2_s1_runs.jsonl"
    assert [e["event"] for e in read_run_events(events)] == ["start"]
    rows_before = path.read_bytes()
    frames_before = (logs / "L2_s1_run1_frames.csv").read_bytes()
    res = _run(cmd)
    assert res.returncode == 0, res.stderr
    assert "is already complete" in res.stdout + res.stderr
    assert f"its log {logs / 'L2_s1_run1.json'} (marked 'recovered'" in res.stdout, res.stdout
    log = json.loads((logs / "L2_s1_run1.json").read_text())
    assert log["status"] == "complete" and log["recovered"]["why"]
    assert log["trials_this_run"] == n and [t["trial"] for t in log["trials"]] == \
        list(range(1, n + 1))
    assert log["frame_intervals"]["n"] == len(frames_before.splitlines()) - 1 > 0
    assert log["inputs"]["stimuli_sha256"] == read_run_events(events)[0]["stimuli_sha256"]
    assert log["calibration_age_days"] is not None and log["calibration_age_days"] >= 0
    history = read_run_events(events)
    assert [e["event"] for e in history] == ["start", "complete"]
    assert history[1]["trials_this_run"] == n and history[1]["recovered"]
    assert path.read_bytes() == rows_before  # nothing recorded is rewritten
    assert (logs / "L2_s1_run1_frames.csv").read_bytes() == frames_before
    again = _run(cmd)
    assert again.returncode == 0 and "recovered" not in again.stdout, again.stdout
    assert len(read_run_events(events)) == 2


def test_the_run_history_alone_refuses_a_start_over(small_design, small_design_path,
                                                    session_files, tmp_path, capsys):
    """kill -9 after 2 answers, then the session CSV, the slider file and the run's frames file
    moved aside: the run history (run 1 started at trial 1, never ended) refuses the run,
    naming the three files and the fix; nothing is started over; put back, the session
    resumes at trial 3."""
    f = session_files
    n = small_design.sessions.trials_per_session
    cmd = _cmd(small_design_path, f, "X2", 1)
    path = f["data"] / "sessions" / "X2_s1.csv"
    logs = f["data"] / "logs"
    sliders = f["data"] / "sliders" / "X2_s1.jsonl"
    frames = logs / "X2_s1_run1_frames.csv"
    killed_with = _kill_after(cmd, path, 2)
    aside = tmp_path / "aside"
    aside.mkdir()
    for moved in (path, sliders, frames):
        shutil.move(moved, aside / moved.name)
    res = _run(cmd)
    assert res.returncode == 2, res.stdout + res.stderr
    assert f"the run history {logs / 'X2_s1_runs.jsonl'} records run 1 starting at trial 1 " \
           "and never ending" in res.stderr, res.stderr
    assert f"{frames} and {path} and {sliders} are missing" in res.stderr, res.stderr
    assert "Put the original files back" in res.stderr
    assert not path.exists() and not sliders.exists() and not frames.exists()
    from experiment.__main__ import main

    assert main(["--design", str(small_design_path), "status", "--participant", "X2",
                 "--data", str(f["data"])]) == 1
    assert "DAMAGED" in capsys.readouterr().out
    for moved in (path, sliders, frames):
        shutil.move(aside / moved.name, moved)
    res = _run(cmd)
    assert res.returncode == 0, res.stderr
    assert f"X2 session 1 run 2: trials {killed_with + 1}-{n}" in res.stdout
    assert read_session(path)["trial"].tolist() == list(range(1, n + 1))
