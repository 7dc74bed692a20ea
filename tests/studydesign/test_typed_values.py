"""A design value of the wrong TOML type is refused by ``studydesign check`` naming the key and
what to write (issue 33, item 7: a quoted number gave Python's "'>' not supported between
instances of 'str' and 'int'"; ``true`` passed as a refresh rate; 2.5 sessions gave a sum)."""

from __future__ import annotations

import re

import pytest

from studydesign import default_design_path
from studydesign.__main__ import main


@pytest.mark.parametrize("pattern, replacement, said", [
    (r"nominal_refresh_hz = 85\.0", 'nominal_refresh_hz = "85"',
     '[display] nominal_refresh_hz = "85": write a number, without quotes'),
    (r"nominal_refresh_hz = 85\.0", "nominal_refresh_hz = true",
     "[display] nominal_refresh_hz = true: write a number"),
    (r"n_sessions = 2", "n_sessions = 2.5", "[sessions] n_sessions = 2.5: write a whole number"),
    (r"trials_per_session = 81", 'trials_per_session = "81"',
     '[sessions] trials_per_session = "81": write a whole number'),
    (r"resolution_px = \[1024, 768\]", 'resolution_px = ["1024", 768]',
     "[display] resolution_px = [\"1024\", 768]: write a list of whole numbers"),
    (r'name = "indoor"', "name = 5", "[illuminations] name = 5: write text in quotes"),
])
def test_wrong_types_are_named(pattern, replacement, said, tmp_path, capsys):
    text, n = re.subn(pattern, replacement, default_design_path().read_text(encoding="utf-8"),
                      count=1)
    assert n == 1
    path = tmp_path / "design.toml"
    path.write_text(text, encoding="utf-8")
    assert main(["--design", str(path), "check"]) == 1
    err = capsys.readouterr().err
    assert said in err and err.count("\n") == 1


def test_stimuli_out_into_a_missing_folder_is_one_line(tmp_path, capsys):
    """It was pandas' OSError traceback."""
    target = tmp_path / "no" / "such" / "stimuli.csv"
    assert main(["stimuli", "--out", str(target)]) == 1
    err = capsys.readouterr().err
    assert f"{target.parent}: no such folder: create it first (mkdir -p {target.parent})" in err
    assert not target.exists()
