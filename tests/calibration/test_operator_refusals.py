"""Refusals of ``python -m calibration`` that named the wrong cause or ended in a traceback
(issue 33, items 6-7), on a readings file nobody on the project made (PsychToolbox's Apple 17"
CRT, 2000, levels 0-1: tests/data/calibration/ptb_apple17_crt_2000, MIT licence)."""

from __future__ import annotations

from pathlib import Path

import pytest

PTB = Path(__file__).resolve().parents[1] / "data" / "calibration" / "ptb_apple17_crt_2000"


@pytest.mark.parametrize("scale", ["0-255", "0-1023"])
def test_a_level_scale_above_the_files_white_names_the_scale(scale, tmp_path, cli):
    """0-1 readings under --level-scale 0-255 said 'measure more levels' (and at 0-1023 advised
    a min_level the command has no option for): the scale is the cause."""
    res = cli(["fit", PTB / "readings.csv", "--out", tmp_path / "cal", "--level-scale", scale])
    assert res.returncode == 1
    line = res.stderr.strip().splitlines()[-1]
    assert f"levels run up to 1, but --level-scale {scale} says full white is" in line
    assert line.endswith("drop --level-scale (0-1 is the default)")
    assert "measure more levels" not in res.stderr and "min_level" not in res.stderr
    assert not (tmp_path / "cal" / "calibration.json").exists()


def test_8_bit_levels_under_a_10_bit_scale_name_the_8_bit_scale(tmp_path, cli):
    lines = PTB.joinpath("readings.csv").read_text().splitlines()
    header = lines[0].split(",")
    k = header.index("level")
    rows = [line.split(",") for line in lines[1:]]
    for row in rows:
        row[k] = str(round(float(row[k]) * 255))
    src = tmp_path / "readings_8bit.csv"
    src.write_text("\n".join([lines[0], *(",".join(r) for r in rows)]) + "\n")
    res = cli(["fit", src, "--out", tmp_path / "cal", "--level-scale", "0-1023"])
    assert res.returncode == 1 and "pass --level-scale 0-255 if that is full white" in res.stderr


def test_fake_photometer_with_an_unknown_fault_is_one_line(cli):
    """--fault bogus:3 printed the right words under a CalibrationError traceback."""
    res = cli(["fake-photometer", "--device", "pr655", "--fault", "bogus:3"])
    assert res.returncode == 2
    assert res.stderr.startswith("error: fault 'bogus:3': write KIND:WHEN with KIND one of")
    assert res.stderr.count("\n") == 1


def test_a_scale_a_little_above_the_files_white_and_an_empty_out(tmp_path, cli, monkeypatch):
    """0-300 on 8-bit readings fitted white as level 0.85 without a word; --out '' wrote
    calibration.json into the current folder."""
    lines = PTB.joinpath("readings.csv").read_text().splitlines()
    k = lines[0].split(",").index("level")
    rows = [line.split(",") for line in lines[1:]]
    for row in rows:
        row[k] = str(round(float(row[k]) * 255))
    src = tmp_path / "readings_8bit.csv"
    src.write_text("\n".join([lines[0], *(",".join(r) for r in rows)]) + "\n")
    res = cli(["fit", src, "--out", tmp_path / "cal", "--level-scale", "0-300"])
    assert res.returncode == 1 and "white would read as level 0.85" in res.stderr
    monkeypatch.chdir(tmp_path)
    res = cli(["fit", src, "--out", "", "--level-scale", "0-255"])
    assert res.returncode == 2 and "--out is empty" in res.stderr
    assert not (tmp_path / "calibration.json").exists()
