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
