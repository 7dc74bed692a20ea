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
import pytest

from analysis.load import load_sessions
from experiment import read_session

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


def _kill_after(cmd, path, n_rows: int) -> int:
    """Start the app, kill -9 it once ``path`` holds ``n_rows`` rows; returns rows then."""
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
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
        proc.stderr.close()
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
