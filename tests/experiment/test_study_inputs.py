"""Another lab's study read by ``experiment fit-observer DIR --study`` (issue 40, item 8): a
study.toml or trial files that would fit nonsense are refused with the input, the value and
the fix (rc 2, nothing written), a suspicious scale is said in a note kept in the output; the
real Storrs files (../shared, NOT RUN where absent) still load."""

from __future__ import annotations

import shutil
import tomllib
from pathlib import Path

import numpy as np
import pytest

from experiment.__main__ import main as experiment_main
from experiment.study import load_study, read_study_trials
from tests.analysis.gap.rating_study import STUDY_TOML, write_study
from tests.analysis.gap.test_rating_study import STORRS, _shared_storrs


def _study(tmp_path, n_participants=2, n_stimuli=10) -> Path:
    return write_study(tmp_path / "s", np.random.default_rng(5),
                       n_participants=n_participants, n_stimuli=n_stimuli)


def _fit(study: Path, capsys, *extra) -> tuple[int, str, Path]:
    out = study.parent.parent / "observers.toml"
    rc = experiment_main(["fit-observer", str(study.parent), "--study", str(study),
                          *extra, "--out", str(out)])
    return rc, capsys.readouterr().err, out


def _refused(study, capsys, *words):
    rc, err, out = _fit(study, capsys)
    assert rc == 2 and not out.exists(), err
    line = err.strip().splitlines()[-1]
    assert line.startswith("error: ")
    for w in words:
        assert w in line, line
    return line


def _edit_toml(study: Path, old: str, new: str) -> None:
    assert old in study.read_text()
    study.write_text(study.read_text().replace(old, new))


def test_a_response_column_mapped_to_an_empty_column_is_refused(tmp_path, capsys):
    study = _study(tmp_path)
    _edit_toml(study, 'response = "rating"', 'response = "age"')
    _refused(study, capsys, "'age'", "holds no number", "[columns] response")


def test_a_copy_of_a_participants_file_is_refused_naming_the_copy(tmp_path, capsys):
    study = _study(tmp_path)
    f = study.parent / "01_ratings.csv"
    shutil.copy(f, study.parent / "01_ratings - Copy.csv")
    _edit_toml(study, 'files = "*_ratings.csv"', 'files = "*_ratings*.csv"')
    _refused(study, capsys, "01_ratings.csv", "holds the same trials as", "a copy")


def test_two_peoples_files_under_one_id_are_refused(tmp_path, capsys):
    study = _study(tmp_path)
    f = study.parent / "02_ratings.csv"
    text = f.read_bytes().decode("utf-8-sig").replace(",02,,", ",01,,")
    f.write_bytes(text.encode())
    _refused(study, capsys, "participant 01", "01_ratings.csv, 02_ratings.csv",
             "their own ID")


def test_a_trial_column_that_repeats_within_a_file_is_refused(tmp_path, capsys):
    """Pointed at a column that counts within a repeat (thisTrialN): each number 3 times."""
    study = _study(tmp_path)
    _edit_toml(study, 'trial = "trials.thisN"', 'trial = "trials.thisIndex"')
    _refused(study, capsys, "'trials.thisIndex'", "3 times", "[columns] trial")


def test_unknown_keys_are_named_with_the_key_meant(tmp_path, capsys):
    study = _study(tmp_path)
    _edit_toml(study, "step = 1", "stpe = 1")
    _edit_toml(study, 'rt_s = "decisionTime"', 'rt = "decisionTime"')
    _refused(study, capsys, "'[response] stpe' (did you mean 'step'?)", "'[columns] rt'")


def test_labels_outside_the_scale_are_refused(tmp_path, capsys):
    study = _study(tmp_path)
    _edit_toml(study, "step = 1", "step = 1\nlabels = [1, 7]")
    _refused(study, capsys, "labels ['7']", "outside the scale [1, 6]")


def test_a_participant_with_one_trial_is_no_split_half(tmp_path, capsys):
    """The fit refused one already; the diagnosis took it as a split half."""
    from analysis.gap.__main__ import main as gap_main

    study = _study(tmp_path, n_participants=3)
    rc, err, obs = _fit(study, capsys, "--participants", "01", "02")
    assert rc == 0, err
    f = study.parent / "03_ratings.csv"
    lines = f.read_bytes().decode("utf-8-sig").splitlines()
    f.write_text("\n".join(lines[:2]) + "\n")
    out = tmp_path / "report"
    rc = gap_main(["diagnose", "--layer", "observer", "--real", str(study.parent), "--study",
                   str(study), "--sim", str(obs), "--participants", "01", "03", "--out",
                   str(out), "--seed", "1"])
    err = capsys.readouterr().err
    assert rc != 0 and not (out / "diagnosis.json").exists()
    assert "participants {'03': 1} have fewer than 10 trials" in err
    assert "--participants" in err


def test_a_scale_whose_top_is_never_used_is_said_and_kept_in_the_output(tmp_path, capsys):
    """[1, 10] for ratings that never exceed 6: a note (a study whose stimuli never earn the
    top is possible), printed and written into the observers file's [fit] notes."""
    study = _study(tmp_path)
    _edit_toml(study, "scale = [1, 6]", "scale = [1, 10]")
    rc, err, out = _fit(study, capsys)
    assert rc == 0
    assert "note: no response of 60 comes near the scale's top (10)" in err
    notes = tomllib.loads(out.read_text())["fit"]["notes"]
    assert any("fix [response] scale" in n for n in notes)


def test_the_synthetic_study_as_written_is_fitted_without_a_refusal(tmp_path, capsys):
    rc, err, out = _fit(_study(tmp_path), capsys)
    assert rc == 0 and out.exists(), err
    assert STUDY_TOML  # the generator's study.toml, unedited


def test_the_storrs_files_still_load(tmp_path):
    folder = _shared_storrs()
    if folder is None:
        pytest.skip(f"NOT RUN: ../shared/{STORRS} is absent (read from the shared folder, "
                    "never copied here)")
    trials, notes = read_study_trials(load_study(folder))
    assert len(trials) == 1500 and trials["participant"].nunique() == 10
    assert not any("scale" in n for n in notes)
