"""Bad input: each problem is found before any window opens, with a message naming the fix."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
from pathlib import Path

import pandas as pd
import pytest
from PIL import Image

from calibration import load_calibration, save_calibration
from experiment import SESSION_COLUMNS
from experiment.checks import PreflightError
from experiment.datafile import append_run_event, runs_path
from experiment.session import SessionRequest, prepare_session

from .conftest import REPO, app_env, run_app
from .fixtures import make_calibration, make_manifest

pytestmark = pytest.mark.xvfb


def _request(design, files, **kw) -> SessionRequest:
    args = {"design": design, "participant": "P01", "session": 1,
            "manifest": str(files["manifest"]), "calibration": str(files["calibration"]),
            "data_dir": str(files["data"])}
    args.update(kw)
    return SessionRequest(**args)


def _session_png(design, files, k=0):
    prep = prepare_session(_request(design, files))
    return prep.stimuli.frame["png"].iloc[k], prep.stimuli.frame["stimulus_id"].iloc[k]


def test_good_input_passes(design, session_files):
    prep = prepare_session(_request(design, session_files))
    assert len(prep.todo) == design.sessions.trials_per_session
    assert prep.done.empty and prep.warnings == []


@pytest.mark.parametrize("participant", ["P 01", "", "x" * 33, "../P01", "P01;rm", "Pé"])
def test_bad_participant_ids(design, session_files, participant):
    with pytest.raises(PreflightError, match="participant id .* is not valid"):
        prepare_session(_request(design, session_files, participant=participant))


@pytest.mark.parametrize("session", ["0", "3", "x", "1.5", -1])
def test_bad_session_numbers(design, session_files, session):
    with pytest.raises(PreflightError, match="session .* is not valid; the design has sessions"):
        prepare_session(_request(design, session_files, session=session))


def test_missing_manifest(design, session_files, tmp_path):
    with pytest.raises(PreflightError, match="not found; render the stimuli first"):
        prepare_session(_request(design, session_files, manifest=str(tmp_path / "none.csv")))
    with pytest.raises(PreflightError, match="no stimulus manifest given"):
        prepare_session(_request(design, session_files, manifest=None))


def test_missing_stimulus_png(design, session_files):
    png, sid = _session_png(design, session_files, 5)
    os.remove(png)
    with pytest.raises(PreflightError, match=rf"{sid}: .* is missing; re-render it"):
        prepare_session(_request(design, session_files))


def test_changed_stimulus_png(design, session_files):
    png, sid = _session_png(design, session_files, 7)
    with open(png, "ab") as fh:
        fh.write(b"\0")
    with pytest.raises(PreflightError, match=rf"{sid}: .* does not match its checksum"):
        prepare_session(_request(design, session_files))


def test_stimulus_absent_from_manifest(design, session_files, tmp_path):
    manifest = make_manifest(tmp_path / "few", design,
                             stimulus_ids=set(design.stimuli()["stimulus_id"][:10]))
    with pytest.raises(PreflightError, match="not in the manifest; render it"):
        prepare_session(_request(design, session_files, manifest=str(manifest)))


def test_stale_calibration(design, session_files, tmp_path):
    old = make_calibration(tmp_path / "old", design, age_days=45)
    with pytest.raises(PreflightError, match=r"45\.0 days old, more than the allowed 30"):
        prepare_session(_request(design, session_files, calibration=str(old)))
    prep = prepare_session(_request(design, session_files, calibration=str(old),
                                    max_calibration_age_days=60))
    assert prep.calibration.calibration_id == "test"


def test_missing_calibration(design, session_files, tmp_path):
    with pytest.raises(PreflightError, match="calibration file .* not found"):
        prepare_session(_request(design, session_files, calibration=str(tmp_path / "c.json")))
    with pytest.raises(PreflightError, match="no calibration given"):
        prepare_session(_request(design, session_files, calibration=None))


@pytest.mark.parametrize("change, match", [
    ({"resolution_px": (800, 600)}, "was made at 800x600 px"),
    ({"distance_cm": 70.0}, "viewing distance of 70 cm"),
    ({"refresh_hz": 60.0}, "measured 60.0 Hz"),
])
def test_calibration_of_another_display(design, session_files, tmp_path, change, match):
    cal = dataclasses.replace(load_calibration(session_files["calibration"]), **change)
    path = save_calibration(cal, tmp_path / "other" / "calibration.json")
    with pytest.raises(PreflightError, match=match):
        prepare_session(_request(design, session_files, calibration=str(path)))


def test_stimuli_corrected_for_another_calibration(design, session_files, tmp_path):
    other = make_calibration(tmp_path / "other", design, calibration_id="lab-2026-10")
    with pytest.raises(PreflightError, match=r"gamma-corrected for calibration \['test'\]"):
        prepare_session(_request(design, session_files, calibration=str(other)))
    prep = prepare_session(_request(design, session_files, calibration=str(other),
                                    accept_calibration_mismatch=True))
    assert "re-render the stimuli" in prep.warnings[0]


def test_fullscreen_needs_the_design_resolution(design, session_files):
    with pytest.raises(PreflightError, match="set the display mode"):
        prepare_session(_request(design, session_files, fullscr=True))


def test_no_display(design, session_files, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    with pytest.raises(PreflightError, match="no X display"):
        prepare_session(_request(design, session_files))


def test_recorded_rows_that_disagree_with_the_plan(design, session_files):
    prep = prepare_session(_request(design, session_files))
    row = prep.plan.iloc[[0]].drop(columns="seed").assign(
        stimulus_id=prep.plan["stimulus_id"].iloc[1], gloss_match=5, depth_match=5, rt_s=1,
        onset_s=0, dropped_frames=0, timestamp_utc="x", app_version="x", calibration_id="test")
    path = session_files["data"] / "sessions" / "P01_s1.csv"
    path.parent.mkdir(parents=True)
    row[list(SESSION_COLUMNS)].to_csv(path, index=False)
    with pytest.raises(PreflightError, match="the plan file was replaced"):
        prepare_session(_request(design, session_files))


def test_torn_last_row_is_announced_and_left_for_the_run(design, session_files):
    """A row cut off mid-write (a crash, a full disk) is not a recorded trial: pre-flight says
    so and resumes at that trial; the file is not changed before the run holds its lock."""
    prep = prepare_session(_request(design, session_files))
    rows = prep.plan.iloc[:2].drop(columns="seed").assign(
        gloss_match=5, depth_match=5, rt_s=1, onset_s=0, dropped_frames=0,
        timestamp_utc="x", app_version="x", calibration_id="test")
    path = session_files["data"] / "sessions" / "P01_s1.csv"
    path.parent.mkdir(parents=True)
    text = rows[list(SESSION_COLUMNS)].to_csv(index=False)
    path.write_text(text[:-9])  # the second row loses its last fields and its newline
    # Rows written by hand have no start record (_runs.jsonl): vouched for, as an operator would.
    prep = prepare_session(_request(design, session_files, accept_unverified_resume=True))
    assert len(prep.done) == 1 and prep.todo["trial"].iloc[0] == 2
    assert any("line 3 is torn" in w and "takes that record again" in w for w in prep.warnings)
    assert path.read_text() == text[:-9]


def _no_session_started(files):
    assert not (files["data"] / "sessions").exists()
    assert not (files["data"] / "logs").exists()


def test_command_line_refuses_before_any_window(design, session_files, tmp_path):
    """Exit status 2 with the message on stderr; nothing written but the plan."""
    f = session_files
    old = make_calibration(tmp_path / "old", design, age_days=100)
    for args, match in [
        (["--participant", "P 01"], "participant id 'P 01' is not valid"),
        (["--participant", "P01", "--calibration", old], "days old"),
    ]:
        base = {"--participant": "P01", "--session": "1", "--stimuli": f["manifest"],
                "--calibration": f["calibration"], "--data": f["data"]}
        base.update(dict(zip(args[::2], args[1::2])))
        res = run_app("run", *[str(x) for kv in base.items() for x in kv], "--simulate",
                      "ideal", "--fast")
        assert res.returncode == 2, res.stderr
        assert match in res.stderr
        _no_session_started(f)


def test_screen_smaller_than_the_design(design, session_files):
    """Under an 800x600 X screen the app refuses before opening its window."""
    f = session_files
    cmd = ["xvfb-run", "-a", "-s", "-screen 0 800x600x24", str(REPO / ".venv/bin/python"),
           "-m", "experiment", "run", "--participant", "P01", "--session", "1", "--stimuli",
           str(f["manifest"]), "--calibration", str(f["calibration"]), "--data",
           str(f["data"]), "--simulate", "ideal", "--fast"]
    res = subprocess.run(cmd, cwd=REPO, env=app_env(), capture_output=True, text=True,
                         timeout=120, check=False)
    assert res.returncode == 2, res.stderr
    w, h = design.display.resolution_px
    assert f"the screen is 800x600 px, smaller than the design's {w}x{h}" in res.stderr
    _no_session_started(f)


def test_plan_and_session_files_are_never_overwritten(design, session_files):
    prep = prepare_session(_request(design, session_files))
    plan_file = session_files["data"] / "plans" / "P01_plan.csv"
    before = plan_file.read_bytes()
    prepare_session(_request(design, session_files, session=2))
    assert plan_file.read_bytes() == before
    assert json.dumps(list(prep.plan["stimulus_id"]))  # the plan is usable
    assert pd.read_csv(plan_file)["stimulus_id"].nunique() == design.n_stimuli


def test_keyboard_libraries_missing(design, session_files, monkeypatch):
    import ctypes.util

    real = ctypes.util.find_library
    monkeypatch.setattr(ctypes.util, "find_library",
                        lambda name: None if name == "jack" else real(name))
    with pytest.raises(PreflightError, match=r"needs \['libjack-jackd2-0'\]"):
        prepare_session(_request(design, session_files))


def test_stimulus_too_large_for_the_screen(design, session_files, tmp_path):
    big = make_manifest(tmp_path / "big", design, width_cm=30.0)
    with pytest.raises(PreflightError, match="does not fit above the sliders"):
        prepare_session(_request(design, session_files, manifest=str(big)))


def test_monitor_profile_must_match_the_calibration(design, session_files):
    """The PsychoPy profile saved beside calibration.json (as `calibration run` writes it)."""
    cal_path = session_files["calibration"]
    cal = load_calibration(cal_path)
    folder = cal_path.parent / "monitors"
    folder.mkdir()
    entry = {"width": cal.width_cm, "distance": cal.distance_cm,
             "sizePix": list(cal.resolution_px)}
    profile = folder / f"{cal.monitor_name}.json"
    profile.write_text(json.dumps({cal.calibration_id: entry}))
    assert prepare_session(_request(design, session_files)).monitor_profile == profile
    profile.write_text(json.dumps({cal.calibration_id: {**entry, "width": 40.0}}))
    with pytest.raises(PreflightError, match="says width 40 cm"):
        prepare_session(_request(design, session_files))
    profile.write_text(json.dumps({"other": entry}))
    with pytest.raises(PreflightError, match="has no calibration 'test'"):
        prepare_session(_request(design, session_files))


def _rewrite_manifest_checksum(manifest, stimulus_id):
    """Update a stimulus's checksum in the manifest, as an operator 'fixing' a changed PNG would."""
    from stimuli import sha256_file

    frame = pd.read_csv(manifest, dtype=str, keep_default_na=False)
    row = frame["stimulus_id"] == stimulus_id
    png = manifest.parent / frame.loc[row, "png_path"].iloc[0]
    frame.loc[row, "png_sha256"] = sha256_file(png)
    frame.to_csv(manifest, index=False)


@pytest.mark.parametrize("image, match", [
    (lambda p: Image.new("RGB", (32, 32), (40, 200, 60)).save(p), "decodes to 32x32 px"),
    (lambda p: Image.new("RGBA", (64, 64)).save(p), "colour type 'RGBA'"),
    (lambda p: Image.new("L", (64, 64), 128).save(p), "one colour type for all"),
    (lambda p: p.write_bytes(p.read_bytes()[:-30]), "does not decode"),
    (lambda p: p.write_bytes(b"not a png at all"), "does not decode"),
])
def test_every_stimulus_png_is_decoded_before_the_session(design, session_files, image, match):
    """A PNG whose checksum was updated in the manifest but that decodes to another size or
    colour type, or not at all, is refused before any window (it used to reach the window)."""
    png, sid = _session_png(design, session_files)
    image(Path(png))
    _rewrite_manifest_checksum(session_files["manifest"], sid)
    with pytest.raises(PreflightError, match=match) as info:
        prepare_session(_request(design, session_files))
    assert sid in str(info.value) and "re-render" in str(info.value).lower()


def test_a_damaged_image_of_a_later_session_is_refused_before_the_first(design,
                                                                        session_files):
    """Every image of the participant's sessions is decoded at each start: a truncated PNG that
    session 2 would show stops session 1, not the participant's return a week later (when only a
    re-rendered set could be shown)."""
    prep = prepare_session(_request(design, session_files, session=2))
    png, sid = prep.stimuli.frame["png"].iloc[0], prep.stimuli.frame["stimulus_id"].iloc[0]
    Path(png).write_bytes(Path(png).read_bytes()[:-30])
    _rewrite_manifest_checksum(session_files["manifest"], sid)
    with pytest.raises(PreflightError, match="does not decode") as info:
        prepare_session(_request(design, session_files, session=1))
    assert sid in str(info.value) and "participant's" in str(info.value)


def _record_first_run(design, files, n_rows=2):
    """The state after a first run answered ``n_rows`` trials: rows and the run's start event."""
    prep = prepare_session(_request(design, files))
    rows = prep.plan.iloc[:n_rows].drop(columns="seed").assign(
        gloss_match=5, depth_match=5, rt_s=1, onset_s=0, dropped_frames=0,
        timestamp_utc="x", app_version="x", calibration_id=prep.calibration.calibration_id)
    path = files["data"] / "sessions" / "P01_s1.csv"
    path.parent.mkdir(parents=True)
    rows[list(SESSION_COLUMNS)].to_csv(path, index=False)
    append_run_event(runs_path(files["data"], "P01", 1), {"event": "start", **prep.inputs})
    return prep


def test_resume_keeps_the_calibration_and_stimuli_it_started_with(design, session_files,
                                                                  tmp_path):
    f = session_files
    first = _record_first_run(design, f)
    assert prepare_session(_request(design, f)).inputs == first.inputs  # the same: resumes
    other_id = make_calibration(tmp_path / "other", design, calibration_id="other")
    with pytest.raises(PreflightError, match=r"used calibration \['test'\].*--calibration"):
        prepare_session(_request(design, f, calibration=str(other_id),
                                 accept_calibration_mismatch=True))
    same_id = make_calibration(tmp_path / "same-id", design, age_days=2)
    with pytest.raises(PreflightError, match="differs although its id is the same") as info:
        prepare_session(_request(design, f, calibration=str(same_id)))
    assert first.inputs["calibration"] in str(info.value)
    small = make_manifest(tmp_path / "small", design, size_px=32)
    with pytest.raises(PreflightError, match="are not the same") as info:
        prepare_session(_request(design, f, manifest=str(small)))
    assert "--stimuli" in str(info.value) and first.inputs["manifest"] in str(info.value)


def test_resume_without_its_run_history_checks_the_run_logs_and_numbers_the_next_run(
        design, session_files, tmp_path):
    """An operator moved ``*_runs.jsonl`` away: the resume still refuses other images (the
    first run's log holds its inputs; the check used to be skipped, mixing image sizes in one
    session), and the next run takes a free number (run 1's log used to be 'not written')."""
    from experiment.runlog import run_logs as _run_logs

    f = session_files
    first = _record_first_run(design, f)
    logs = f["data"] / "logs"
    (logs / "P01_s1_run1.json").write_text(json.dumps({"run": 1, "inputs": first.inputs}))
    runs_path(f["data"], "P01", 1).unlink()
    small = make_manifest(tmp_path / "small", design, size_px=32)
    with pytest.raises(PreflightError, match="are not the same"):
        prepare_session(_request(design, f, manifest=str(small)))
    assert [k for k, _ in _run_logs(f["data"], "P01_s1")] == [1]
    (logs / "P01_s1_run1.json").unlink()
    # With no record left, the resume is refused (it used to warn and show the other images),
    # unless the operator vouches for the inputs (then the warning stays in the log).
    with pytest.raises(PreflightError, match="--accept-unverified-resume"):
        prepare_session(_request(design, f, manifest=str(small)))
    prep = prepare_session(_request(design, f, manifest=str(small),
                                    accept_unverified_resume=True))
    assert any("cannot check" in w for w in prep.warnings)


def test_screenshot_into_a_missing_folder_is_refused(design, session_files, tmp_path):
    with pytest.raises(PreflightError, match="does not exist; create it"):
        prepare_session(_request(design, session_files,
                                 screenshot=str(tmp_path / "no" / "shot.png")))


def test_observer_params_that_are_not_toml(design, session_files, tmp_path):
    bad = tmp_path / "observers.toml"
    bad.write_text("this is = = not toml\n")
    with pytest.raises(PreflightError, match="not valid TOML"):
        prepare_session(_request(design, session_files, simulate="ideal",
                                 observer_params=str(bad)))


def test_read_only_data_folder_is_refused_before_anything(design, session_files, small_disk,
                                                          capsys):
    from experiment.__main__ import main

    with small_disk("64k", read_only=True) as folder:
        with pytest.raises(PreflightError, match="read-only file system"):
            prepare_session(_request(design, session_files, data_dir=str(folder / "data")))
        assert main(["plan", "--participant", "P01", "--data", str(folder)]) == 1
        assert f"cannot write the plan in {folder}" in capsys.readouterr().err


def test_full_disk_is_refused_at_start(design, session_files, small_disk):
    with small_disk("64k") as folder:
        with pytest.raises(PreflightError, match="MB free, less than"):
            prepare_session(_request(design, session_files, data_dir=str(folder)))
        assert not any(folder.iterdir())


def test_data_folder_must_be_given(design, session_files, tmp_path, monkeypatch):
    """Without --data or GLOSSDEPTH_DATA the app refuses (a ./data of the working directory
    would start the session over from another directory)."""
    from experiment.__main__ import main

    monkeypatch.delenv("GLOSSDEPTH_DATA", raising=False)
    monkeypatch.chdir(tmp_path)
    assert main(["status", "--participant", "P01"]) == 2
    assert main(["plan", "--participant", "P01"]) == 2
    assert not (tmp_path / "data").exists()
    monkeypatch.setenv("GLOSSDEPTH_DATA", str(session_files["data"]))
    assert main(["plan", "--participant", "P01"]) == 0
    assert (session_files["data"] / "plans" / "P01_plan.csv").is_file()


def test_a_relative_lab_data_root_is_refused(tmp_path, monkeypatch, capsys):
    """GLOSSDEPTH_DATA=data (set once in a profile) would follow the working directory: the same
    command from another directory started the session over in another ./data."""
    from experiment.__main__ import main

    monkeypatch.setenv("GLOSSDEPTH_DATA", "data")
    monkeypatch.chdir(tmp_path)
    assert main(["plan", "--participant", "P01"]) == 2
    assert "relative path" in capsys.readouterr().err
    assert not (tmp_path / "data").exists()
    # So would a relative --data (issue 33): refused the same way, naming the absolute path.
    assert main(["plan", "--participant", "P01", "--data", "data"]) == 2
    assert f"--data {tmp_path / 'data'}" in capsys.readouterr().err
    assert not (tmp_path / "data").exists()


def test_complete_session_whose_run_log_failed_says_so(monkeypatch, capsys, tmp_path):
    """A run whose log could not be written (a full disk at the end) names what is missing,
    rather than printing ``log None``."""
    from types import SimpleNamespace

    import experiment.session
    from experiment.__main__ import main_run
    from experiment.session import SessionOutcome

    out = SessionOutcome("complete", "P01", 1, 6, 6, str(tmp_path / "P01_s1.csv"), None)
    monkeypatch.setattr(experiment.session, "run_session", lambda req: out)
    assert main_run(SimpleNamespace(data_dir=tmp_path)) == 0
    said = capsys.readouterr().out
    assert "None" not in said and "run log could not be written" in said
