"""Inputs that passed without a word (issue 40, item 11): a jitter that carries centres out of
their cells, a print spacing that misses the bumps, a torn last row printed as data, a PsychoPy
profile's per-gun gammas folded into one curve, and a PsychoPy CSV whose split header shifts its
columns. Each is now refused (rc != 0, the error line names the input, the value and the fix,
nothing written) or, where legitimate, said in a warning kept in the output."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from analysis.__main__ import main as analysis_main
from calibration import load_calibration
from calibration.__main__ import main as calibration_main
from stimuli.__main__ import main as stimuli_main
from studydesign import load_design
from studydesign.__main__ import main as studydesign_main
from tests.analysis.sessions import write_sessions


def _last_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err and err[-1].startswith("error: "), err
    return err[-1]


def test_a_jitter_of_half_the_pitch_or_more_fails_the_design_check(tmp_path, capsys):
    text = Path(load_design().source).read_text()
    assert "jitter_cm = 0.2" in text
    path = tmp_path / "design.toml"
    path.write_text(text.replace("jitter_cm = 0.2", "jitter_cm = 5.0"))
    assert studydesign_main(["--design", str(path), "check"]) == 1
    line = _last_error(capsys)
    assert "array.jitter_cm 5 is not under half the pitch_cm 1" in line
    assert "use jitter_cm < 0.5" in line


def test_a_print_spacing_coarser_than_the_bumps_is_refused(tmp_path, capsys):
    out = tmp_path / "d5.stl"
    assert stimuli_main(["export-print", "--depth-level", "5", "--spacing-cm", "10",
                         str(out)]) == 1
    line = _last_error(capsys)
    assert "--spacing-cm 10 is too coarse for bumps of x/y radius 1 cm" in line
    assert "use <= 0.25 cm" in line
    assert not out.exists()


def test_units_leaves_a_torn_last_row_out_and_says_so(tmp_path, design, capsys):
    path = write_sessions(tmp_path / "data", design, np.random.default_rng(2),
                          n_participants=1)[0]
    assert analysis_main(["units", str(path)]) == 0
    whole = capsys.readouterr().out
    with open(path, "ab") as fh:  # a crash in the middle of writing the next row
        fh.write(b"P01,1,82,3,0.4,")
    before = path.read_bytes()
    assert analysis_main(["units", str(path)]) == 0
    out, err = capsys.readouterr()
    assert out == whole
    n = whole.count("\n")
    assert f"line {n + 1} is torn (no newline at its end" in err and "left out" in err
    assert path.read_bytes() == before  # the file is not changed


def _profile(folder, guns) -> str:
    grid = [[0.3, 80.0, 2.2]] + [[0.1, 30.0, g] for g in guns]
    profile = {"2024_06_01 12:00": {
        "calibDate": 1717243200.0, "gamma": None, "width": 34.0, "distance": 57.0,
        "notes": None, "psychopyVersion": "2026.2.5", "usebits": False, "gammaGrid": grid,
        "linearizeMethod": 1, "sizePix": [1280, 1024]}}
    folder.mkdir()
    path = folder / "pergun.json"
    path.write_text(json.dumps(profile, indent=2))
    return str(path)


def test_a_profile_with_per_gun_gammas_is_imported_with_a_warning(tmp_path, capsys):
    """Legitimate for grey stimuli (glossdepth's): imported, the warning printed and kept in
    calibration.json; guns within 5 % of each other say nothing."""
    out = tmp_path / "cal"
    assert calibration_main(["import-psychopy", _profile(tmp_path / "m", [1.9, 2.2, 2.6]),
                             "--out", str(out)]) == 0
    said = [w for w in load_calibration(out).warnings if "guns have gammas" in w]
    assert said and "R 1.9, G 2.2, B 2.6 (luminance 2.2)" in said[0]
    assert "guns have gammas R 1.9" in capsys.readouterr().out
    same = tmp_path / "same"
    assert calibration_main(["import-psychopy", _profile(tmp_path / "n", [2.2, 2.2, 2.25]),
                             "--out", str(same)]) == 0
    assert not any("guns have gammas" in w for w in load_calibration(same).warnings)


def test_a_psychopy_csv_with_a_split_header_is_refused_by_fit(tmp_path, capsys):
    rng = np.random.default_rng(1)
    lines = ["y,gloss,participant ID (two digits, e.g. 01),expName,frameRate,"]
    for p in range(6):
        for g in (0.2, 0.4, 0.6, 0.8):
            lines.append(f"{g + rng.normal(0, 0.1):.3f},{g},{p:02d},gloss_task,59.95,")
    src = tmp_path / "psychopy.csv"
    src.write_text("\n".join(lines) + "\n")
    out = tmp_path / "fit"
    rc = analysis_main(["fit", str(src), "--formula", "y ~ gloss + (1 | expName)", "--out",
                        str(out), "--quiet"])
    line = _last_error(capsys)
    assert rc != 0 and not (out / "fit.json").exists()
    assert "the header has 7 fields but every row 6" in line
    assert "'participant ID (two digits, e.g. 01)' looks like one name" in line
