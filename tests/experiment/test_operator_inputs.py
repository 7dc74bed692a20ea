"""Operator faults at ``python -m experiment`` (issue 33, items 5-7), run as the operator would:
the real app under Xvfb (small design: 2 sessions x 6 trials), real files, real signals.

- SIGTERM and SIGHUP (a shutdown, a closed terminal, ``kill``) ended a session with the shell's
  bare "Terminated": no line on what was kept, no end event, no run log;
- a resume whose start record is lost let every image be swapped with a warning only;
- session 2 ran on a re-rendered set with the same calibration;
- a stimulus 10x too large in a manifest row was not compared with the others;
- ``simulate --participants S01 S01`` was a traceback, ``..`` and ``--seed -1`` were blamed on
  --observer-params, and fit-observer into a read-only folder hid its error.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from experiment.__main__ import main
from tests.readonly import read_only_folder

from .conftest import REPO, app_env
from .fixtures import make_calibration, make_manifest

DEMO = Path(__file__).resolve().parents[1] / "data" / "demo_sessions"


def _args(design_path, files, participant, session, *extra, manifest=None) -> list[str]:
    return ["--design", str(design_path), "run", "--participant", participant, "--session",
            str(session), "--stimuli", str(manifest or files["manifest"]), "--calibration",
            str(files["calibration"]), "--data", str(files["data"]), "--simulate", "ideal",
            "--fast", *extra]


def _rows(path: Path) -> int:
    return max(0, len(path.read_text().splitlines()) - 1) if path.exists() else 0


@pytest.fixture(scope="module")
def stopped(tmp_path_factory, stimuli_dir, small_design, small_design_path):
    """Session 1 of P01 run by the real app under Xvfb and ended by SIGTERM after its first
    answered trial; ``(files, returncode, stderr, trials kept)``."""
    root = tmp_path_factory.mktemp("stopped")
    files = {"manifest": stimuli_dir / "manifest.csv",
             "calibration": make_calibration(root / "cal", small_design), "data": root / "data"}
    data = files["data"] / "sessions" / "P01_s1.csv"
    proc = subprocess.Popen([sys.executable, "-m", "experiment",
                             *_args(small_design_path, files, "P01", 1)],
                            cwd=REPO, env=app_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    t_end = time.monotonic() + 120
    while _rows(data) < 1 and proc.poll() is None and time.monotonic() < t_end:
        time.sleep(0.005)
    os.kill(proc.pid, signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    return files, proc.returncode, err, _rows(data)


@pytest.mark.xvfb
def test_sigterm_ends_the_session_saying_what_was_kept(stopped):
    files, rc, err, kept = stopped
    assert rc == 128 + signal.SIGTERM, err
    assert 1 <= kept < 6
    last = err.strip().splitlines()[-1]
    assert last.startswith("ended by SIGTERM") and f"{kept} of 6 trials are saved" in last
    assert "run the same command to continue" in last
    logs = files["data"] / "logs"
    end = json.loads((logs / "P01_s1_runs.jsonl").read_text().splitlines()[-1])
    assert end["event"] == "interrupted" and end["signal"] == "SIGTERM"
    assert json.loads((logs / "P01_s1_run1.json").read_text())["ended_by"] == "SIGTERM"


def test_a_signal_during_a_trials_commit_is_raised_after_its_last_write():
    """CI once read "0 of 6 trials are saved" beside a session file holding 1: SIGTERM landed
    between the row's write and the run's count. Held, it ends the run after the commit."""
    from experiment.signals import SessionSignal, ending_signals, held_signals

    writes = []
    with pytest.raises(SessionSignal) as caught, ending_signals():
        with held_signals():
            writes.append("row")
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.2)
            writes.append("count")
            os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C on top: the first signal wins
            time.sleep(0.2)
            writes.append("frames")
        writes.append("next trial")
    assert writes == ["row", "count", "frames"] and caught.value.name == "SIGTERM"
    with pytest.raises(KeyboardInterrupt), held_signals():
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.2)
        writes.append("held Ctrl-C")
    assert writes[-1] == "held Ctrl-C"


def test_a_signal_inside_a_ctypes_call_ends_the_run_as_that_signal():
    """CI once saw exit 1 and ``ctypes.ArgumentError`` where SIGTERM should end the session: the
    handler raised while pyglet's Python code converted a ctypes call's argument. A real SIGTERM
    to this process lands inside a real libc call's argument conversion here."""
    import ctypes

    from experiment.signals import SessionSignal, ending_signals, unwrapped_signals

    class Landing:
        @classmethod
        def from_param(cls, value):
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.2)  # the handler runs here, inside the conversion
            return ctypes.c_int(value)

    labs = ctypes.CDLL(None).abs
    labs.argtypes = [Landing]
    with pytest.raises(ctypes.ArgumentError, match="SessionSignal"), ending_signals():
        labs(-3)  # without the unwrapping: what CI saw
    with pytest.raises(SessionSignal) as caught, ending_signals(), unwrapped_signals():
        labs(-3)
    assert caught.value.name == "SIGTERM"
    labs.argtypes = [ctypes.c_int]
    with pytest.raises(ctypes.ArgumentError, match="argument 1"), unwrapped_signals():
        labs("not a number")  # any other ArgumentError stays what it is


def test_sighup_raises_the_session_signal_in_the_block():
    """The handler the app installs (the same for SIGTERM), with a real SIGHUP to this
    process; outside the block the shell's own handling is back."""
    from experiment.signals import SessionSignal, ending_signals

    before = signal.getsignal(signal.SIGHUP)
    with pytest.raises(SessionSignal) as caught, ending_signals():
        os.kill(os.getpid(), signal.SIGHUP)
        time.sleep(1)
    assert caught.value.name == "SIGHUP" and caught.value.signum == signal.SIGHUP
    assert signal.getsignal(signal.SIGHUP) is before


@pytest.mark.xvfb
def test_session_2_on_a_re_rendered_set_is_refused(stopped, small_design, small_design_path,
                                                   tmp_path, capsys):
    files = stopped[0]
    rerendered = make_manifest(tmp_path / "rerendered", small_design, size_px=32)
    assert main(_args(small_design_path, files, "P01", 2, manifest=rerendered)) == 2
    err = capsys.readouterr().err
    assert "session 1 of P01 was shown the images of" in err
    assert f"Pass --stimuli {files['manifest'].resolve()}" in err
    assert err.strip().endswith("(restore its images if they were replaced)")
    assert not (files["data"] / "sessions" / "P01_s2.csv").exists()
    # After a recalibration, a set rendered for the new calibration is what the protocol asks
    # for: allowed, and said.
    from experiment.session import SessionRequest, prepare_session

    newcal = make_calibration(tmp_path / "newcal", small_design, calibration_id="recal")
    renew = make_manifest(tmp_path / "renew", small_design, calibration_id="recal", size_px=32)
    prep = prepare_session(SessionRequest(
        design=small_design, participant="P01", session=2, manifest=str(renew),
        calibration=str(newcal), data_dir=str(files["data"])))
    assert any("for the new calibration 'recal'" in w for w in prep.warnings)


@pytest.mark.xvfb
def test_session_2_under_a_recalibration_of_the_same_id_is_said_or_refused(
        stopped, small_design, small_design_path, tmp_path, capsys):
    """Issue 40, item 1: the display recalibrated (white 100 -> 80 cd/m^2, gamma 2.2 -> 2.0)
    and saved under the id of session 1's calibration. Session 2 ran with no word. Now, on
    images rendered for session 1's calibration file (the manifest records its SHA-256) it is
    refused as another id is; on a manifest that records no file, it runs and says at its
    start and in its run log what changed."""
    from experiment.session import SessionRequest, prepare_session
    from stimuli import sha256_file

    files = dict(stopped[0], data=tmp_path / "data")
    shutil.copytree(stopped[0]["data"], files["data"])
    old = files["calibration"]
    files["calibration"] = make_calibration(tmp_path / "recal", small_design, white_cd_m2=80.0,
                                            gamma=2.0)
    said = (f"session 1 of P01 used calibration 'test' ({old.resolve()}, SHA-256 "
            f"{sha256_file(old)[:12]}...; black 0.50, white 100.0 cd/m^2, offset_power gamma "
            f"2.20), this run 'test' ({files['calibration'].resolve()}, SHA-256 "
            f"{sha256_file(files['calibration'])[:12]}...; black 0.50, white 80.0 cd/m^2, "
            "offset_power gamma 2.00): another file under the same id (the display was "
            "recalibrated)")
    rendered = make_manifest(tmp_path / "rendered", small_design,
                             calibration_sha256=sha256_file(old))
    assert main(_args(small_design_path, files, "P01", 2, manifest=rendered)) == 2
    err = capsys.readouterr().err
    assert (f"gamma-corrected for calibration 'test' as in the file of SHA-256 "
            f"{sha256_file(old)} (recalibrated under the same id?), but this session uses "
            "calibration 'test'") in err and "--accept-calibration-mismatch" in err
    prep = prepare_session(SessionRequest(
        design=small_design, participant="P01", session=2, manifest=str(rendered),
        calibration=str(files["calibration"]), data_dir=str(files["data"]),
        accept_calibration_mismatch=True))
    assert any(said in w for w in prep.warnings), prep.warnings
    # The manifest of session 1 records no calibration file: the session runs, and says it.
    res = subprocess.run([sys.executable, "-m", "experiment",
                          *_args(small_design_path, files, "P01", 2)], cwd=REPO, env=app_env(),
                         capture_output=True, text=True, timeout=300, check=False)
    assert res.returncode == 0, res.stderr
    assert f"warning: {said}" in res.stdout
    log = json.loads((files["data"] / "logs" / "P01_s2_run1.json").read_text())
    assert any(said in w for w in log["warnings"])
    assert log["inputs"]["calibration_fit"]["max_luminance_cd_m2"] == 80.0


@pytest.mark.xvfb
def test_a_resume_without_its_start_record_is_refused(stopped, small_design, small_design_path,
                                                      tmp_path, capsys):
    """runs.jsonl and the run log lost: the resume used to warn and show other images."""
    files = dict(stopped[0], data=tmp_path / "data")
    shutil.copytree(stopped[0]["data"], files["data"])
    (files["data"] / "logs" / "P01_s1_runs.jsonl").unlink()
    (files["data"] / "logs" / "P01_s1_run1.json").unlink()
    other = make_manifest(tmp_path / "other", small_design, size_px=32)
    assert main(_args(small_design_path, files, "P01", 1, manifest=other)) == 2
    err = capsys.readouterr().err
    assert "no record of the stimuli and calibration file this session started with" in err
    assert err.strip().endswith("add --accept-unverified-resume (recorded in the log)")
    assert _rows(files["data"] / "sessions" / "P01_s1.csv") == stopped[3]


@pytest.mark.xvfb
def test_a_stimulus_larger_than_the_others_is_refused_before_any_session(
        small_design_path, session_files, capsys):
    f = session_files
    manifest = pd.read_csv(f["manifest"], dtype=str, keep_default_na=False)
    row = manifest.index[manifest["stimulus_id"] == "outdoor_g08_d09"][0]
    manifest.loc[row, "image_width_cm"] = str(10 * float(manifest.loc[row, "image_width_cm"]))
    manifest.to_csv(f["manifest"], index=False)
    assert main(_args(small_design_path, f, "P01", 1)) == 2
    assert "outdoor_g08_d09 is 80 cm wide, the other stimuli 8 cm" in capsys.readouterr().err
    assert not (f["data"] / "sessions").exists()


@pytest.mark.parametrize("ids, said", [
    (["S01", "S01"], "--participants names 'S01' and 'S01': give each participant once"),
    (["s01", "S01"], "--participants names 's01' and 'S01'"),
    ([".."], "--participants: participant id '..' is not valid"),
])
def test_simulate_participants_are_checked_by_name(ids, said, tmp_path, capsys):
    rc = main(["simulate", "--observer", "ideal", "--participants", *ids,
               "--data", str(tmp_path / "sim")])
    err = capsys.readouterr().err
    assert rc == 2 and said in err and "observer-params" not in err
    assert not (tmp_path / "sim" / "sessions").exists()


@pytest.mark.parametrize("command", ["simulate", "run"])
def test_a_negative_seed_names_the_seed(command, tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        main([command, "--seed", "-1", "--participant" if command == "run" else "--participants",
              "P01", "--data", str(tmp_path), *(["--observer", "ideal"]
                                                if command == "simulate" else [])])
    assert stop.value.code == 2
    assert "argument --seed: -1: a seed is a whole number >= 0" in capsys.readouterr().err


def test_fit_observer_into_a_read_only_folder_is_one_line(tmp_path, capsys):
    with read_only_folder(tmp_path) as ro:
        rc = main(["fit-observer", str(DEMO / "humanlike"), "--out", str(ro / "obs.toml")])
    err = capsys.readouterr().err
    assert rc == 1 and f"cannot write {ro} (Read-only file system)" in err
    assert "Traceback" not in err and ".tmp-" not in err


def test_empty_data_and_a_folder_as_observers_file_are_refused(tmp_path, capsys, monkeypatch):
    """simulate --data '' wrote sessions/ into the current folder; fit-observer --out FOLDER
    said the folder 'is never overwritten'."""
    monkeypatch.chdir(tmp_path)
    rc = main(["simulate", "--observer", "ideal", "--participants", "Q01", "--data", ""])
    assert rc == 2 and "--data is empty" in capsys.readouterr().err
    assert not (tmp_path / "sessions").exists()
    rc = main(["fit-observer", str(DEMO / "humanlike"), "--out", str(tmp_path)])
    assert rc == 2 and "is a folder: give it a file name" in capsys.readouterr().err
