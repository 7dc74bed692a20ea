"""The manifest records renders durably and detects missing or changed files."""

import pytest

from stimuli import (
    MANIFEST_COLUMNS,
    ManifestError,
    append_manifest_row,
    load_manifest,
    sha256_file,
    verify_manifest,
)


def _row(tmp_path, sid):
    png = tmp_path / "png" / f"{sid}.png"
    png.parent.mkdir(exist_ok=True)
    png.write_bytes(sid.encode())
    row = {c: 0 for c in MANIFEST_COLUMNS}
    row.update(stimulus_id=sid, png_path=f"png/{sid}.png", png_sha256=sha256_file(png),
               exr_path=f"exr/{sid}.exr", exr_sha256="")
    return row


def test_manifest_round_trip_and_verification(tmp_path):
    for sid in ("indoor_g02_d02", "indoor_g02_d03"):
        append_manifest_row(tmp_path / "manifest.csv", _row(tmp_path, sid))
    assert list(load_manifest(tmp_path)["stimulus_id"]) == ["indoor_g02_d02", "indoor_g02_d03"]
    assert verify_manifest(tmp_path) == []
    (tmp_path / "png" / "indoor_g02_d03.png").write_bytes(b"tampered")
    (tmp_path / "png" / "indoor_g02_d02.png").unlink()
    problems = verify_manifest(tmp_path, stimulus_ids=["indoor_g02_d02", "indoor_g02_d03", "x"])
    assert len(problems) == 3
    assert any("missing" in p for p in problems) and any("checksum" in p for p in problems)
    assert any(p.startswith("x: not in the manifest") for p in problems)


def test_missing_manifest_names_the_fix(tmp_path):
    with pytest.raises(ManifestError, match="python -m stimuli render"):
        load_manifest(tmp_path / "manifest.csv")


def test_torn_manifest_row_is_read_around_then_kept_aside_by_the_next_append(tmp_path):
    """A render killed mid-write leaves half a manifest row: readers skip it (never merging it
    with the next row), the next append moves it to a side file and starts on a fresh line."""
    from labfiles import TornTailWarning

    path = tmp_path / "manifest.csv"
    append_manifest_row(path, _row(tmp_path, "indoor_g02_d02"))
    whole = path.read_bytes()
    path.write_bytes(whole + b"indoor_g02_d03,0,0,")
    with pytest.warns(TornTailWarning, match="left as it is"):
        assert list(load_manifest(tmp_path)["stimulus_id"]) == ["indoor_g02_d02"]
    assert path.read_bytes().endswith(b"0,0,")  # the reader changed nothing
    with pytest.warns(TornTailWarning, match="moved to"):
        append_manifest_row(path, _row(tmp_path, "indoor_g02_d03"))
    assert list(load_manifest(tmp_path)["stimulus_id"]) == ["indoor_g02_d02", "indoor_g02_d03"]
    side = list(tmp_path.glob("manifest.csv.torn-*"))
    assert len(side) == 1 and side[0].read_bytes() == b"indoor_g02_d03,0,0,"


def test_a_manifest_from_before_calibration_checksums_loads_and_grows_in_its_own_columns(
        tmp_path):
    """Manifests written before ``calibration_sha256`` (issue 40) are a lab's rendered sets:
    they load with the column empty, and a resumed render appends rows in their header's
    columns (a row of another width would be refused as torn)."""
    from labfiles import append_csv_record

    path = tmp_path / "manifest.csv"
    legacy = [c for c in MANIFEST_COLUMNS if c != "calibration_sha256"]
    row = _row(tmp_path, "indoor_g02_d02")
    append_csv_record(path, legacy, [row[c] for c in legacy])
    header = path.read_bytes().splitlines()[0]
    append_manifest_row(path, _row(tmp_path, "indoor_g02_d03") | {"calibration_sha256": "ab"})
    assert path.read_bytes().splitlines()[0] == header
    frame = load_manifest(path)
    assert list(frame["stimulus_id"]) == ["indoor_g02_d02", "indoor_g02_d03"]
    assert list(frame["calibration_sha256"]) == ["", ""]
    new = tmp_path / "new" / "manifest.csv"
    new.parent.mkdir()
    append_manifest_row(new, _row(tmp_path, "indoor_g02_d02") | {"calibration_sha256": "ab"})
    assert list(load_manifest(new)["calibration_sha256"]) == ["ab"]
