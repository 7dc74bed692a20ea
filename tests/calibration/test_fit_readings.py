"""`python -m calibration fit READINGS.csv`: a calibration from any tool's readings file.

The readings are written here by hand, as another lab's tool would (8-bit levels, only the
two required columns, a decimal comma, a NaN), from the simulated CRT's equations.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from calibration import READINGS_COLUMNS, CalibrationError, SimulatedCRT, load_calibration
from calibration.readings import parse_level_scale, read_readings

T0 = "2026-08-01T10:00:00Z"


def _tool_file(path, *, rng, crt=None, scale=255, extra_rows=(), header="level,luminance_cd_m2"):
    """A readings file in another tool's layout: level on 0..scale, two repeats."""
    crt = crt or SimulatedCRT()
    levels = np.append(np.arange(0, 256, 16), 255)
    lines = [header]
    for _ in range(2):
        for lv in levels:
            lines.append(f"{lv * scale // 255},{float(crt.luminance(lv / 255, rng=rng)):.4f}")
    lines += list(extra_rows)
    path.write_text("\n".join(lines) + "\n")
    return path


def test_fit_of_another_tools_file_writes_every_output(tmp_path, rng, cli):
    src = _tool_file(tmp_path / "lab.csv", rng=rng)
    out = tmp_path / "cal"
    display = tmp_path / "display.toml"
    display.write_text("[display]\nwidth_cm = 33.1\nresolution_px = [1024, 768]\n"
                       "distance_cm = 57.0\nrefresh_hz = 100.0\nmonitor_name = 'lab-crt'\n")
    res = cli(["fit", src, "--out", out, "--level-scale", "0-255", "--measured-utc", T0,
                   "--display", display])
    assert res.returncode == 0, res.stderr
    cal = load_calibration(out)
    crt = SimulatedCRT()
    x = np.linspace(0, 1, 11)
    assert cal.luminance_for_drive(x) == pytest.approx(crt.luminance(x), rel=0.03, abs=0.1)
    assert (cal.width_cm, cal.distance_cm, cal.refresh_hz) == (33.1, 57.0, 100.0)
    assert cal.measured_utc.startswith("2026-08-01T10:00:00")
    assert cal.calibration_id == "import-lab"
    for name in ("report.txt", "gamma.png", "monitors/lab-crt.json", "readings.csv",
                 "run_meta.json"):
        assert (out / name).stat().st_size > 0, name
    # The folder holds the readings in the procedure's columns, so it refits on its own.
    assert tuple(pd.read_csv(out / "readings.csv").columns) == READINGS_COLUMNS
    again = cli(["fit", "--out", out])
    assert again.returncode == 0, again.stderr
    assert load_calibration(out).gamma_params == cal.gamma_params


def test_report_states_white_fitted_and_measured_noise_and_misfit(tmp_path, rng, cli):
    """What a user checks first: the fitted white against the measured one, the held-out error
    in % of white, the noise model and floor used, and which models were flagged."""
    src = _tool_file(tmp_path / "lab.csv", rng=rng)
    out = tmp_path / "cal"
    res = cli(["fit", src, "--out", out, "--level-scale", "0-255", "--measured-utc", T0])
    assert res.returncode == 0, res.stderr
    cal = load_calibration(out)
    fit = cal.chosen_fit
    white = np.mean([y for x, y in zip(fit.levels, fit.luminance_cd_m2) if x == 1.0])
    report = (out / "report.txt").read_text()
    assert (f"white (drive 1): fitted {cal.max_luminance_cd_m2:.3f} cd/m^2, measured "
            f"{white:.3f} cd/m^2") in report
    assert f"= {100 * fit.heldout_rmse_cd_m2 / white:.3f} % of white" in report
    assert "(fitted to repeated readings); meter floor" in report
    assert f"instrument: unknown (readings from {src.resolve()})" in report
    assert "readings at or below it, fitted as censored" in report
    rows = {line.split()[1 if line.startswith(" *") else 0]: line
            for line in report.splitlines() if line.startswith(("   ", " *"))}
    assert "FLAGGED" in rows["power"]  # the simulated CRT has a threshold power cannot fit
    assert "FLAGGED" not in rows[cal.gamma_model]


def test_wrong_level_scale_names_the_option(tmp_path, rng, cli):
    src = _tool_file(tmp_path / "lab.csv", rng=rng, scale=1023)
    res = cli(["fit", src, "--out", tmp_path / "a", "--measured-utc", T0])
    assert res.returncode == 1
    assert "--level-scale 0-1023" in res.stderr and "Traceback" not in res.stderr


@pytest.mark.parametrize("scale, option", [(255, "0-255"), (1023, "0-1023"), (4095, "4095")])
def test_level_scale_divides_the_levels(tmp_path, rng, scale, option):
    src = _tool_file(tmp_path / "lab.csv", rng=rng, scale=scale)
    table = read_readings(src, level_scale=parse_level_scale(option))
    assert table.frame["level"].max() == 1.0
    assert sorted(set(table.frame["level"].round(6)))[1] == pytest.approx(16 * (scale // 255)
                                                                          / scale, abs=1e-6)


@pytest.mark.parametrize("text", ["0-0", "abc", "-5", "0-nan"])
def test_bad_level_scale_is_refused(text):
    with pytest.raises(CalibrationError, match="--level-scale"):
        parse_level_scale(text)


def test_file_without_times_needs_measured_utc(tmp_path, rng, cli):
    src = _tool_file(tmp_path / "lab.csv", rng=rng)
    res = cli(["fit", src, "--out", tmp_path / "cal", "--level-scale", "0-255"])
    assert res.returncode == 1
    assert "--measured-utc" in res.stderr and "Traceback" not in res.stderr
    assert not (tmp_path / "cal" / "calibration.json").exists()


def test_each_unusable_row_is_reported_and_duplicates_count_once(tmp_path, rng, cli):
    """NaN, a decimal comma, an out-of-range level, a short row: each named by its line."""
    crt = SimulatedCRT()
    rows = []
    for r in range(2):
        for lv in np.linspace(0, 1, 9):
            rows.append(f"c1,2026-08-01T10:{r:02d}:{int(lv * 40):02d}Z,pr655,0,0,{lv},{r},"
                        f"{float(crt.luminance(lv, rng=rng)):.4f},ok")
    bad = ["c1,2026-08-01T10:05:03Z,pr655,0,0",
           "c1,2026-08-01T10:05:00Z,pr655,0,0,0.5,5,nan,x",
           'c1,2026-08-01T10:05:01Z,pr655,0,0,0.5,6,"12,5",x',
           "c1,2026-08-01T10:05:02Z,pr655,0,0,1.5,7,99.0,x"]
    lines = [",".join(READINGS_COLUMNS), *rows, rows[3], *bad]
    folder = tmp_path / "cal"
    folder.mkdir()
    (folder / "readings.csv").write_text("\n".join(lines) + "\n")
    meta = {"calibration_id": "c1", "fit": {
        "calibration_id": "c1", "device": "pr655", "monitor_name": "m",
        "resolution_px": [1024, 768], "width_cm": 32.0, "distance_cm": 55.0, "refresh_hz": 85.0}}
    (folder / "run_meta.json").write_text(json.dumps(meta))
    res = cli(["fit", "--out", folder])
    assert res.returncode == 0, res.stderr
    out = res.stdout
    n = len(lines)
    assert f"line {n - 3} dropped: 5 fields, the header has 9" in out
    assert f"line {n - 2} dropped: luminance_cd_m2 'nan' is not a finite number" in out
    assert f"line {n - 1} dropped: luminance_cd_m2 '12,5' has a decimal comma; write 12.5" in out
    assert f"line {n} dropped: level 1.5 lies outside [0, 1]" in out
    assert f"line {len(rows) + 2} repeats line 5 exactly; counted once" in out
    report = (folder / "report.txt").read_text()
    assert "readings: 18 accepted" in report and "decimal comma" in report


def test_calibration_id_mismatch_lists_the_ids_found(tmp_path, rng, cli):
    """A folder whose run_meta names another id: the message lists the file's ids."""
    src = _tool_file(tmp_path / "lab.csv", rng=rng)
    out = tmp_path / "cal"
    assert cli(["fit", src, "--out", out, "--level-scale", "0-255", "--measured-utc",
                    T0]).returncode == 0
    meta = json.loads((out / "run_meta.json").read_text())
    meta["calibration_id"] = "other-id"
    (out / "run_meta.json").write_text(json.dumps(meta))
    res = cli(["fit", "--out", out])
    assert res.returncode == 1
    assert "no reading of calibration 'other-id'" in res.stderr
    assert "'import-lab' (34 rows)" in res.stderr
    assert "screen centre" not in res.stderr


def test_several_calibrations_in_one_file_need_an_id(tmp_path, rng, cli):
    crt = SimulatedCRT()
    lines = ["calibration_id,timestamp_utc,level,luminance_cd_m2"]
    for cid, white in (("monday", 1.0), ("friday", 0.9)):
        for lv in np.linspace(0, 1, 9):
            lum = float(crt.luminance(lv, rng=rng)) * white
            lines.append(f"{cid},2026-08-0{1 if cid == 'monday' else 5}T10:00:00Z,{lv},{lum}")
    src = tmp_path / "two.csv"
    src.write_text("\n".join(lines))  # no line end after the last row: another tool's habit
    res = cli(["fit", src, "--out", tmp_path / "a"])
    assert res.returncode == 1 and "'friday' (9 rows), 'monday' (9 rows)" in res.stderr
    res = cli(["fit", src, "--out", tmp_path / "a", "--calibration-id", "friday"])
    assert res.returncode == 0, res.stderr
    cal = load_calibration(tmp_path / "a")
    assert cal.calibration_id == "friday" and cal.measured_utc.startswith("2026-08-05")
    assert cal.max_luminance_cd_m2 == pytest.approx(0.9 * 95.6, rel=0.02)
    assert src.read_text().endswith(f"{lum}")  # the source file is never changed


def test_position_option_fits_one_position(tmp_path, rng, cli):
    crt = SimulatedCRT()
    lines = ["x_norm,y_norm,level,luminance_cd_m2,timestamp_utc"]
    for x in (-0.6, 0.6):
        for lv in np.linspace(0, 1, 9):
            lines.append(f"{x},0.6,{lv},{float(crt.luminance(lv, x, 0.6, rng=rng))},{T0}")
    src = tmp_path / "corners.csv"
    src.write_text("\n".join(lines) + "\n")
    res = cli(["fit", src, "--out", tmp_path / "a"])
    assert res.returncode == 1
    assert "no readings at the screen centre" in res.stderr and "--position" in res.stderr
    assert "-0.6,0.6, 0.6,0.6" in res.stderr
    res = cli(["fit", src, "--out", tmp_path / "a", "--position", "0.6,0.6"])
    assert res.returncode == 0, res.stderr
    cal = load_calibration(tmp_path / "a")
    white = float(crt.luminance(1.0, 0.6, 0.6))
    assert cal.max_luminance_cd_m2 == pytest.approx(white, rel=0.01)
    assert cal.uniformity is None


@pytest.mark.parametrize("content, message", [
    ("", "holds no readings (it is empty)"),
    ("level,luminance_cd_m2\n", "holds no readings (a header only)"),
    ("drive,Y\n0,1\n", "needs at least the columns ['level', 'luminance_cd_m2']"),
    # A spreadsheet's export with a decimal comma separates the columns by ';' (or a tab).
    ("level;luminance_cd_m2\n0;0,5\n", "separated by ';': export it as CSV with commas"),
    ("level\tluminance_cd_m2\n0\t0.5\n", "separated by tabs: export it as CSV"),
])
def test_empty_or_foreign_file_is_a_clear_error(tmp_path, content, message, cli):
    src = tmp_path / "r.csv"
    src.write_text(content)
    res = cli(["fit", src, "--out", tmp_path / "a", "--measured-utc", T0])
    assert res.returncode == 1
    assert message in res.stderr and "Traceback" not in res.stderr


def test_empty_readings_in_a_folder_is_a_clear_error(tmp_path, cli):
    folder = tmp_path / "cal"
    folder.mkdir()
    (folder / "readings.csv").write_text("")
    (folder / "run_meta.json").write_text(json.dumps({"calibration_id": "c", "fit": {}}))
    res = cli(["fit", "--out", folder])
    assert res.returncode == 1
    assert "holds no readings (empty)" in res.stderr and "Traceback" not in res.stderr


def test_a_folder_with_other_readings_is_never_replaced(tmp_path, rng, cli):
    a = _tool_file(tmp_path / "a.csv", rng=rng)
    b = _tool_file(tmp_path / "b.csv", rng=rng)
    out = tmp_path / "cal"
    args = ["--out", out, "--level-scale", "0-255", "--measured-utc", T0]
    assert cli(["fit", a, *args]).returncode == 0
    before = (out / "readings.csv").read_bytes()
    res = cli(["fit", b, *args])
    assert res.returncode == 1 and "fitted from other readings" in res.stderr
    assert (out / "readings.csv").read_bytes() == before


def test_read_readings_fills_the_optional_columns(tmp_path):
    src = tmp_path / "r.csv"
    src.write_text("luminance_cd_m2,level\n1.0,0\n1.1,0\n50,1\n")
    table = read_readings(src)
    f = table.frame
    assert tuple(f.columns) == READINGS_COLUMNS
    assert list(f["repeat"]) == [0, 1, 0]  # repeats numbered in file order per patch
    assert (f[["x_norm", "y_norm"]] == 0).all().all()
    assert table.notes == ()


def _clean_readings(path, levels, fmt: str, **crt):
    """A readings file (level, luminance) of a noiseless CRT, gamma 2.3, black 0.15 cd/m^2 at
    ``levels``, luminance written with format ``fmt``."""
    crt = SimulatedCRT(gamma=2.3, black_cd_m2=0.15, ambient_cd_m2=0.0, cutoff=0.0,
                       falloff=0.0, tilt_x=0.0, noise_rel=0.0, noise_abs=0.0, **crt)
    path.write_text("level,luminance_cd_m2\n" + "".join(
        f"{float(x)!r},{float(crt.luminance(x)):{fmt}}\n" for x in levels))
    return path


def test_dac_bits_none_fits_levels_a_finer_lookup_table_showed(tmp_path, cli):
    """A display behind a 10-bit lookup table shows 17 evenly spaced levels as requested;
    rounded to the 8-bit default they are fitted where the display never was. `--dac-bits
    none` fits them as given, and the folder's refit keeps that."""
    src = _clean_readings(tmp_path / "lut10.csv", np.repeat(np.linspace(0, 1, 17), 2), ".4e",
                          bits=16)
    out = tmp_path / "cal"
    res = cli(["fit", src, "--out", out, "--measured-utc", T0, "--dac-bits", "none"])
    assert res.returncode == 0, res.stderr
    fit = load_calibration(out).chosen_fit
    assert fit.dac_bits is None
    assert fit.params["gamma"] == pytest.approx(2.3, abs=2e-3)
    assert cli(["fit", "--out", out]).returncode == 0
    assert load_calibration(out).chosen_fit.params == fit.params
    rounded = cli(["fit", src, "--out", tmp_path / "cal8", "--measured-utc", T0])
    assert rounded.returncode == 0, rounded.stderr
    assert load_calibration(tmp_path / "cal8").chosen_fit.dac_bits == 8
    bad = cli(["fit", src, "--out", tmp_path / "x", "--measured-utc", T0, "--dac-bits", "ten"])
    assert bad.returncode == 1 and "--dac-bits 'ten'" in bad.stderr


def test_floor_option_fits_a_clean_display_without_repeats_exactly(tmp_path, cli):
    """Without repeats the default floor (0.2 % of white) censors a black of 0.15 cd/m^2 on a
    100 cd/m^2 white and pulls the fit (black 0.133, gamma 2.298); given the meter's real floor
    the clean display (gamma 2.3, black 0.15) is fitted exactly, refits included."""
    src = _clean_readings(tmp_path / "clean.csv", np.round(np.linspace(0, 1, 17) * 255) / 255,
                          ".6g", white_cd_m2=99.85)
    out = tmp_path / "cal"
    res = cli(["fit", src, "--out", out, "--measured-utc", T0, "--floor-cd-m2", "0.01"])
    assert res.returncode == 0, res.stderr
    cal = load_calibration(out)
    assert cal.gamma_model == "power"
    assert cal.gamma_params["gamma"] == pytest.approx(2.3, abs=1e-3)
    assert cal.min_luminance_cd_m2 == pytest.approx(0.15, abs=1e-3)
    assert "meter floor 0.01 cd/m^2: 0 of 17" in (out / "report.txt").read_text()
    assert cli(["fit", "--out", out]).returncode == 0
    assert load_calibration(out).gamma_params == cal.gamma_params
    bad = cli(["fit", src, "--out", tmp_path / "x", "--measured-utc", T0, "--floor-cd-m2",
               "-1"])
    assert bad.returncode == 1 and "--floor-cd-m2" in bad.stderr
