"""Manifests and gloss tables as a lab's tools re-save them (issue 29 item 6): read as written,
or refused naming the separator and the fix (they gave "lacks columns [...]" or a
UnicodeDecodeError)."""

from __future__ import annotations

import codecs
import shutil
from pathlib import Path

import pandas as pd
import pytest

from stimuli import MANIFEST_COLUMNS, append_manifest_row, load_manifest, sha256_file
from stimuli.__main__ import main
from stimuli.glosstable import default_gloss_table, default_gloss_table_path, load_gloss_table
from tests.tool_files import (
    crlf,
    excel_csv_utf8,
    excel_semicolons,
    notepad_unicode,
    quoted,
)

IDS = ("indoor_g02_d02", "indoor_g02_d03", "outdoor_g08_d05")


@pytest.fixture
def rendered(tmp_path) -> Path:
    """A folder with a manifest of real files (PNG and EXR bytes with their checksums)."""
    folder = tmp_path / "stim"
    for sid in IDS:
        for kind in ("png", "exr"):
            (folder / kind).mkdir(parents=True, exist_ok=True)
            (folder / kind / f"{sid}.{kind}").write_bytes(f"{kind} of {sid}".encode())
        row = {c: 0.25 for c in MANIFEST_COLUMNS}
        row.update(stimulus_id=sid, png_path=f"png/{sid}.png", exr_path=f"exr/{sid}.exr",
                   png_sha256=sha256_file(folder / "png" / f"{sid}.png"),
                   exr_sha256=sha256_file(folder / "exr" / f"{sid}.exr"))
        append_manifest_row(folder / "manifest.csv", row)
    return folder


@pytest.mark.parametrize("resave", [excel_csv_utf8, crlf, quoted, notepad_unicode],
                         ids=lambda f: f.__name__)
def test_a_manifest_resaved_by_another_tool_verifies(resave, rendered, capsys):
    before = load_manifest(rendered)
    resave(rendered / "manifest.csv")
    assert main(["verify", str(rendered)]) == 0, capsys.readouterr()
    pd.testing.assert_frame_equal(load_manifest(rendered), before, check_like=False)


def test_a_semicolon_manifest_is_refused_naming_the_separator(rendered, capsys):
    excel_semicolons(rendered / "manifest.csv")
    assert main(["verify", str(rendered)]) != 0
    out = capsys.readouterr()
    text = (out.out + out.err).strip().splitlines()[-1]
    assert "separated by semicolons" in text and "CSV UTF-8" in text, text


@pytest.mark.parametrize("resave", [excel_csv_utf8, notepad_unicode], ids=lambda f: f.__name__)
def test_a_gloss_table_resaved_by_another_tool_is_the_same_table(resave, tmp_path):
    """The shipped table (with its '#' comment lines) as Excel or Notepad saves it."""
    path = resave(Path(shutil.copy(default_gloss_table_path(), tmp_path / "gloss.csv")))
    pd.testing.assert_frame_equal(load_gloss_table(path), default_gloss_table(),
                                  check_like=False, check_exact=True, check_flags=False)


@pytest.mark.parametrize("bom, codec", [(codecs.BOM_UTF8, "utf-8"),
                                        (codecs.BOM_UTF16_LE, "utf-16-le")], ids=["utf8", "utf16"])
def test_a_photo_set_toml_saved_by_notepad_is_the_same_setup(bom, codec, tmp_path):
    """A photo set's setup.toml edited in Notepad (a BOM, CRLF; or "Unicode")."""
    from stimuli.glossfit import PhotoSetup, load_setup
    from stimuli.glossfit.photoset import write_setup

    setup = PhotoSetup(camera_distance_cm=27.5, sphere_radius_cm=2.0, fov_deg=20.0,
                       resolution_px=(40, 32))
    path = tmp_path / "setup.toml"
    write_setup(path, setup)
    path.write_bytes(bom + path.read_text(encoding="utf-8").replace("\n", "\r\n").encode(codec))
    assert load_setup(path) == setup
