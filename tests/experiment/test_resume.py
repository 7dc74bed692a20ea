"""kill -9 in the middle of a session, resume with the same command, and count what survived.

Uses the small design (2 sessions x 6 trials) of conftest, so that several kill points stay
quick; the code path is the full app's (real window, XTEST input, fsynced rows).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest

from analysis.load import load_sessions
from experiment import read_session
from experiment.datafile import read_run_events

from .conftest import REPO, app_env

pytestmark = [pytest.mark.xvfb, pytest.mark.slow]


def _cmd(design_path, files, participant, session, *extra):
    return [sys.executable, "-m", "experiment", "--design", str(design_path), "run",
            "--participant", participant, "--session", str(session), "--stimuli",
            str(files["manifest"]), "--calibration", str(files["calibration"]), "--data",
            str(files["data"]), "--simulate", "humanlike", "--fast", *extra]


def _run(cmd):
    return subprocess.run(cmd, cwd=REPO, env=app_env(), capture_output=True, text=True,
                          timeout=300, check=False)


def _rows(path) -> int:
    if not path.exists():
        return 0
    return max(0, len(path.read_text().splitlines()) - 1)


def _kill_after(cmd, path, n_rows: int, *, sig=signal.SIGKILL, on_rows=None) -> int:
    """Start the app, send ``sig`` (kill -9) once ``path`` holds ``n_rows`` rows; returns rows
    then. With ``on_rows``, call it instead of sending a signal and wait for the app's end."""
    proc = subprocess.Popen(cmd, cwd=REPO, env=app_env(), stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    t_end = time.monotonic() + 120
    try:
        while _rows(path) < n_rows:
            if proc.poll() is not None:
                pytest.fail(f"the app ended before trial {n_rows}: {proc.stderr.read()}")
            if time.monotonic() > t_end:
                pytest.fail("no progress in 120 s")
            time.sleep(0.005)
        if on_rows is None:
            os.kill(proc.pid, sig)
        else:
            on_rows()
    finally:
        proc.wait(timeout=60)
        _kill_after.stderr = proc.stderr.read()
        proc.stderr.close()
    _kill_after.returncode = proc.returncode
    if sig == signal.SIGKILL and on_rows is None:
        assert proc.returncode == -signal.SIGKILL
    return _rows(path)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_kill_then_resume_shows_every_stimulus_once(seed, small_design, small_design_path,
                                                    session_files):
    rng = np.random.default_rng(seed)
    f = session_files
    n = small_design.sessions.trials_per_session
    participant = f"K{seed}"
    killed_session = int(rng.integers(1, 3))  # one session killed, the other run through
    for session in (1, 2):
        path = f["data"] / "sessions" / f"{participant}_s{session}.csv"
        cmd = _cmd(small_design_path, f, participant, session)
        killed_with = 0
        if session == killed_session:
            kill_at = int(rng.integers(1, n))  # after 1..n-1 answered trials
            killed_with = _kill_after(cmd, path, kill_at)
            assert kill_at <= killed_with < n
        res = _run(cmd)
        assert res.returncode == 0, res.stderr
        data = read_session(path)
        assert data["trial"].tolist() == list(range(1, n + 1)), f"kill after {killed_with}"
        runs = [json.loads(line) for line in
                (f["data"] / "logs" / f"{participant}_s{session}_runs.jsonl").read_text()
                .splitlines()]
        starts = [r["first_trial"] for r in runs if r["event"] == "start"]
        assert starts == ([1, killed_with + 1] if killed_with else [1])
        sliders = (f["data"] / "sliders" / f"{participant}_s{session}.jsonl").read_text()
        assert len(sliders.splitlines()) >= n
    both = load_sessions(f["data"], small_design).frame
    assert sorted(both["stimulus_id"]) == sorted(small_design.stimuli()["stimulus_id"])
    assert not both.duplicated(["participant", "stimulus_id"]).any()


def test_quit_from_pause_then_resume(small_design, small_design_path, session_files, capsys):
    """Esc, Esc at trial 3 (after early space presses that must not count), then the same
    command continues at trial 3; a finished session is not run again."""
    f = session_files
    n = small_design.sessions.trials_per_session
    cmd = _cmd(small_design_path, f, "Q1", 1)
    res = _run([*cmd, "--simulate-quit-at", "3", "--simulate-early-space", "1"])
    assert res.returncode == 3, res.stderr
    assert "run the same command to continue" in res.stderr
    path = f["data"] / "sessions" / "Q1_s1.csv"
    assert read_session(path)["trial"].tolist() == [1, 2]
    hist = [json.loads(line) for line in
            (f["data"] / "sliders" / "Q1_s1.jsonl").read_text().splitlines()]
    assert all(len(h["early_space_s"]) == 1 for h in hist), "early space presses not seen"
    from experiment.__main__ import main

    assert main(["--design", str(small_design_path), "status", "--participant", "Q1",
                 "--data", str(f["data"])]) == 0
    assert f"session 1: 2/{n} trials, to resume; 1 run(s), last event 'quit'" in \
        capsys.readouterr().out
    res = _run(cmd)
    assert res.returncode == 0, res.stderr
    assert read_session(path)["trial"].tolist() == list(range(1, n + 1))
    again = _run(cmd)
    assert again.returncode == 0
    assert "already complete" in again.stdout
    assert read_session(path)["trial"].tolist() == list(range(1, n + 1))


def test_ctrl_c_keeps_the_answers_and_a_torn_history_is_repaired_on_resume(
        small_design, small_design_path, session_files, capsys):
    """Ctrl-C ends the run cleanly (exit 130, what was kept, the run's log); a torn slider
    history (a full disk during its write) and a torn run log are then named by `status`, moved
    aside by the resume, and both files read as JSON lines again."""
    f = session_files
    n = small_design.sessions.trials_per_session
    cmd = _cmd(small_design_path, f, "C1", 1)
    path = f["data"] / "sessions" / "C1_s1.csv"
    kept = _kill_after(cmd, path, 2, sig=signal.SIGINT)
    assert _kill_after.returncode == 130, _kill_after.stderr
    assert "Traceback" not in _kill_after.stderr
    assert f"interrupted (Ctrl-C): {kept} of {n} trials are saved in {path}" in \
        _kill_after.stderr
    events = read_run_events(f["data"] / "logs" / "C1_s1_runs.jsonl")
    assert [e["event"] for e in events] == ["start", "interrupted"]
    log = json.loads((f["data"] / "logs" / "C1_s1_run1.json").read_text())
    assert log["status"] == "interrupted" and log["trials_this_run"] == kept
    hist = f["data"] / "sliders" / "C1_s1.jsonl"
    with open(hist, "a") as fh:
        fh.write('{"participant": "C1", "session": 1, "trial": 3, "gloss_hi')
    runs = f["data"] / "logs" / "C1_s1_runs.jsonl"
    with open(runs, "a") as fh:  # a run log torn too: `run` and `status` crashed on it
        fh.write('{"event": "sta')
    from experiment.__main__ import main

    assert main(["--design", str(small_design_path), "status", "--participant", "C1",
                 "--data", str(f["data"])]) == 0
    assert f"WARNING: {hist}: line {kept + 1} is torn" in capsys.readouterr().out
    res = _run(cmd)
    assert res.returncode == 0, res.stderr
    assert f"warning: {hist}: line {kept + 1} is torn" in res.stdout
    # Said once, by the run that moves it (not also announced as "the next run moves ...").
    assert res.stdout.count(f"warning: {hist}: line {kept + 1} is torn") == 1
    assert res.stdout.count(f"warning: {runs}: line") == 1
    assert read_session(path)["trial"].tolist() == list(range(1, n + 1))
    assert pd.read_json(hist, lines=True)["trial"].tolist() == list(range(1, n + 1))
    assert len(list(hist.parent.glob("C1_s1.jsonl.torn-*"))) == 1
    assert [e["event"] for e in read_run_events(runs)] == ["start", "interrupted", "start",
                                                           "complete"]
    assert len(list(runs.parent.glob("C1_s1_runs.jsonl.torn-*"))) == 1


def test_full_disk_mid_session_is_named_and_the_resume_completes(
        small_design, small_design_path, session_files, small_disk):
    """The disk fills up after the first trial (a real small file system): the app ends with the
    full disk named (not a later error, not a traceback), keeps every whole trial, and the same
    command finishes the session once space is free."""
    f = session_files
    n = small_design.sessions.trials_per_session
    with small_disk("24m") as disk:
        files = {**f, "data": disk / "data"}
        cmd = _cmd(small_design_path, files, "D1", 1)
        path = files["data"] / "sessions" / "D1_s1.csv"
        filler = disk / "filler"

        def fill():
            fd = os.open(filler, os.O_WRONLY | os.O_CREAT)
            try:
                while os.write(fd, b"x" * 65536) > 0:
                    pass
            except OSError:
                pass
            finally:
                os.close(fd)

        # Without --fast the observer takes its response times, so the run's frame log grows
        # by new pages during the next trial (a record that fits a page already held would not
        # meet the full disk).
        slow = [a for a in cmd if a != "--fast"]
        kept = _kill_after(slow, path, 1, on_rows=fill)
        assert _kill_after.returncode == 1, (kept, _kill_after.stderr)
        assert "disk is full" in _kill_after.stderr and "Traceback" not in _kill_after.stderr
        assert "free space, then run the same command to continue" in _kill_after.stderr
        assert _kill_after.stderr.count("free space") == 1
        assert read_session(path)["trial"].tolist() == list(range(1, kept + 1))
        filler.unlink()
        res = _run(cmd)
        assert res.returncode == 0, res.stderr
        assert read_session(path)["trial"].tolist() == list(range(1, n + 1))
        hist = pd.read_json(files["data"] / "sliders" / "D1_s1.jsonl", lines=True)
        assert hist.drop_duplicates("trial", keep="last")["trial"].tolist() == \
            list(range(1, n + 1))


def test_a_killed_run_is_never_started_over_nor_its_files_written_again(
        small_design, small_design_path, session_files, tmp_path, capsys):
    """Issue 40, items 2 and 3. A run killed with kill -9 leaves its rows, its slider histories,
    a start event with no end in the run history and its frames file. (2) With the CSV and the
    slider file moved aside, the session started over at trial 1: refused now, naming the run
    history and the frames file. (3) With the run history deleted and
    --accept-unverified-resume, the next run was numbered 1 again and appended its frames to
    the killed run's file: it is run 2 now, in files of its own."""
    import shutil

    f = session_files
    n = small_design.sessions.trials_per_session
    cmd = _cmd(small_design_path, f, "X1", 1)
    path = f["data"] / "sessions" / "X1_s1.csv"
    logs = f["data"] / "logs"
    killed_with = _kill_after(cmd, path, 2)
    frames1 = logs / "X1_s1_run1_frames.csv"
    shown = int(pd.read_csv(frames1)["trial"].max())  # trials whose frames were appended
    assert 1 <= shown <= killed_with < n
    assert [e["event"] for e in read_run_events(logs / "X1_s1_runs.jsonl")] == ["start"]
    assert not (logs / "X1_s1_run1.json").exists()

    # (2) The session CSV and its slider histories moved aside.
    sliders = f["data"] / "sliders" / "X1_s1.jsonl"
    shutil.move(path, tmp_path / "aside.csv")
    shutil.move(sliders, tmp_path / "aside.jsonl")
    res = _run(cmd)
    assert res.returncode == 2, res.stdout + res.stderr
    assert f"{path} holds 0 answered trial(s), but {frames1} records {shown} (the run history " \
           f"{logs / 'X1_s1_runs.jsonl'}: run 1 started at trial 1 and never ended" in res.stderr
    assert f"Put the original X1_s1.csv back in {path.parent} and X1_s1.jsonl in " \
           f"{sliders.parent}" in res.stderr
    assert not path.exists() and not sliders.exists()  # nothing started over
    from experiment.__main__ import main

    assert main(["--design", str(small_design_path), "status", "--participant", "X1",
                 "--data", str(f["data"])]) == 1
    out = capsys.readouterr().out
    assert "DAMAGED" in out and "run 1 started at trial 1 and never ended" in out

    # (3) Both put back, the run history deleted: the resume needs the operator's word, then
    # takes the next free run number.
    shutil.move(tmp_path / "aside.csv", path)
    shutil.move(tmp_path / "aside.jsonl", sliders)
    (logs / "X1_s1_runs.jsonl").unlink()
    before = frames1.read_bytes()
    res = _run([*cmd, "--accept-unverified-resume"])
    assert res.returncode == 0, res.stderr
    assert f"X1 session 1 run 2: trials {killed_with + 1}-{n}" in res.stdout
    assert frames1.read_bytes() == before
    frames2 = pd.read_csv(logs / "X1_s1_run2_frames.csv")
    assert frames2["trial"].min() == killed_with + 1 and frames2["trial"].max() == n
    assert json.loads((logs / "X1_s1_run2.json").read_text())["run"] == 2
    assert not (logs / "X1_s1_run1.json").exists()
    assert read_session(path)["trial"].tolist() == list(range(1, n + 1))
