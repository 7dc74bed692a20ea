"""Operator faults at ``python -m stimuli`` (issue 33, items 5-7): numpy's words, tracebacks
and a temporary file's name replaced by one line naming the option and the fix; a render
resumed with another calibration refused before anything is rendered."""

from __future__ import annotations

import pandas as pd
import pytest

from stimuli.__main__ import main
from tests.readonly import read_only_folder


@pytest.mark.parametrize("option, value, said", [
    ("--spacing-cm", "0", "0 cm: give a length above 0"),          # was ZeroDivisionError
    ("--spacing-cm", "-0.1", "-0.1 cm: give a length above 0"),    # was numpy's 'Number of samples'
    ("--spacing-cm", "nan", "nan cm: give a length above 0"),      # was 'cannot convert float NaN'
    ("--array-index", "-1", "-1: arrays are numbered from 0"),     # was 'expected non-negative'
])
def test_export_print_options_are_checked_by_name(option, value, said, tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        main(["export-print", "--depth-level", "5", option, value, str(tmp_path / "a.stl")])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and f"argument {option}: {said}" in err
    assert not (tmp_path / "a.stl").exists()


def test_export_print_into_a_read_only_folder_names_the_file(tmp_path, capsys):
    """It named the hidden temporary file ('.a.tmp-123-abc.stl')."""
    with read_only_folder(tmp_path) as ro:
        rc = main(["export-print", "--depth-level", "5", "--spacing-cm", "0.2",
                   str(ro / "a.stl")])
    err = capsys.readouterr().err
    assert rc == 1 and f"cannot write {ro / 'a.stl'} (Read-only file system)" in err
    assert ".tmp-" not in err and "Traceback" not in err


def test_plan_spp_with_a_scalar_variant_is_refused(capsys):
    """--variant scalar_rgb ended in a TypeError deep in the scene builder."""
    with pytest.raises(SystemExit) as stop:
        main(["plan-spp", "--variant", "scalar_rgb"])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and "'scalar_rgb' cannot render the stimuli" in err
    assert "llvm_ad_mono" in err


def test_render_resumed_with_another_calibration_is_refused(tmp_path, design, capsys):
    """A folder whose manifest holds PNGs corrected for calibration 'lab-a' took the rest of
    the set corrected for the default curve: one manifest, two gamma corrections."""
    from tests.experiment.fixtures import make_manifest

    out = tmp_path / "stim"
    ids = list(design.stimuli()["stimulus_id"])
    make_manifest(out, design, calibration_id="lab-a", stimulus_ids=ids[1:3])
    before = (out / "manifest.csv").read_bytes()
    rc = main(["render", "--set", "experiment", "--limit", "1", "--out", str(out),
               "--workers", "0", "--size", "16", "--spp", "1", "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 1 and "gamma-corrected for calibration ['lab-a']; this run uses 'default'" in err
    assert "render into a new --out folder" in err
    assert (out / "manifest.csv").read_bytes() == before
    assert set(pd.read_csv(out / "manifest.csv")["calibration_id"]) == {"lab-a"}


def test_export_print_spacing_too_fine_to_mesh_is_refused(tmp_path, capsys):
    """1e-4 cm asked numpy for 40 GiB and ended in a MemoryError traceback."""
    rc = main(["export-print", "--depth-level", "5", "--spacing-cm", "1e-4",
               str(tmp_path / "a.stl")])
    err = capsys.readouterr().err
    assert rc == 1 and "too large to mesh; use 0.00" in err and "Traceback" not in err


def _recalibrated(folder, design, *, white_cd_m2, gamma):
    """A calibration 'demo' of the default CRT curve with another white and gamma (a display
    that drifted, recalibrated under the id of its first calibration)."""
    import dataclasses
    from datetime import UTC, datetime, timedelta

    from calibration import default_calibration, save_calibration

    black = 0.5
    cal = dataclasses.replace(
        default_calibration(design), calibration_id="demo", max_luminance_cd_m2=white_cd_m2,
        created_utc=(datetime.now(UTC) - timedelta(days=1)).strftime("%Y-%m-%dT%H:%M:%SZ"),
        gamma_params={"a": black, "b": 0.0, "k": (white_cd_m2 - black) ** (1 / gamma),
                      "gamma": gamma})
    return save_calibration(cal, folder / "calibration.json")


def test_render_resumed_with_a_recalibration_of_the_same_id_is_refused(tmp_path, design,
                                                                       capsys):
    """Issue 40, item 1: a folder rendered (--limit 2) under calibration 'demo' took two more
    stimuli (of the other light field, so that no tone curve changes) corrected for a
    recalibration saved under the same id (white 95 -> 80 cd/m^2, gamma 2.4 -> 2.0): one
    manifest, images corrected for two displays, no word. The manifest records each
    calibration file's SHA-256, and the resume is refused naming both."""
    from stimuli import sha256_file

    old = _recalibrated(tmp_path / "old", design, white_cd_m2=95.0, gamma=2.4)
    new = _recalibrated(tmp_path / "new", design, white_cd_m2=80.0, gamma=2.0)
    out = tmp_path / "R"
    tiny = ["--workers", "0", "--size", "16", "--spp", "1", "--no-progress"]
    assert main(["render", "--set", "experiment", "--limit", "2", "--out", str(out),
                 "--calibration", str(old), *tiny]) == 0
    capsys.readouterr()
    before = (out / "manifest.csv").read_bytes()
    more = ["--filter", "illumination=outdoor", "--limit", "2"]
    rc = main(["render", "--set", "experiment", *more, "--out", str(out),
               "--calibration", str(new), *tiny])
    err = capsys.readouterr().err
    assert rc == 1, err
    assert (f"gamma-corrected for calibration 'demo' as in the file of SHA-256 "
            f"{sha256_file(old)}; this run's calibration 'demo' is another file (SHA-256 "
            f"{sha256_file(new)}: black 0.50, white 80.0 cd/m^2, offset_power gamma 2.00): the "
            "display was recalibrated under the same id") in err
    assert "render into a new --out folder" in err
    assert (out / "manifest.csv").read_bytes() == before
    assert len(list((out / "png").rglob("*.png"))) == 2
    # The calibration the folder was rendered with finishes it.
    assert main(["render", "--set", "experiment", *more, "--out", str(out),
                 "--calibration", str(old), *tiny]) == 0
    assert set(pd.read_csv(out / "manifest.csv")["calibration_sha256"]) == {sha256_file(old)}
    assert len(pd.read_csv(out / "manifest.csv")) == 4
