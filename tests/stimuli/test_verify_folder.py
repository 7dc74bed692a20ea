"""`stimuli verify` checks a rendered folder as a whole, and a folder holds one set (issue 44,
item 9): verify said OK with rendered files the manifest no longer listed and after
``tonemaps.csv`` was hand-edited; rendering the image-statistics set into the experiment's
stimulus folder mixed the two sets in one manifest. One real render (8 px, 1 spp) is shared."""

from __future__ import annotations

import shutil

import pandas as pd
import pytest

from stimuli.__main__ import main

TINY = ["--size", "8", "--spp", "1", "--no-progress", "--workers", "0"]


@pytest.fixture(scope="module")
def rendered_once(tmp_path_factory, mitsuba_variant):
    out = tmp_path_factory.mktemp("render") / "stim"
    assert main(["render", "--set", "preview", "--out", str(out), *TINY]) == 0
    return out


@pytest.fixture
def rendered(rendered_once, tmp_path):
    return shutil.copytree(rendered_once, tmp_path / "stim")


def _verify(folder, capsys):
    rc = main(["verify", str(folder)])
    out = capsys.readouterr()
    return rc, out.out + out.err


def test_a_complete_folder_verifies(rendered, capsys):
    rc, text = _verify(rendered, capsys)
    assert rc == 0 and "OK: 0 problems" in text, text


def test_rendered_files_the_manifest_lost_fail_verify(rendered, capsys):
    manifest = rendered / "manifest.csv"
    lines = manifest.read_text().splitlines(keepends=True)
    manifest.write_text("".join(lines[:3]))  # the header and two of the eight rows
    rc, text = _verify(rendered, capsys)
    assert rc == 1 and "FAILED: 12 problems" in text, text  # 6 EXRs and 6 PNGs
    assert text.count("rendered but not in the manifest") == 12
    assert "re-run the same `stimuli render` command" in text


@pytest.mark.parametrize("column, factor", [("tonemap_lmax", 2.0), ("knee_value", 0.9),
                                            ("logistic_rate", 1.5)])
def test_a_hand_edited_tone_curve_fails_verify(column, factor, rendered, capsys):
    path = rendered / "tonemaps.csv"
    curves = pd.read_csv(path, dtype={"envmap_sha256": str})
    curves.loc[0, column] *= factor
    curves.to_csv(path, index=False)
    rc, text = _verify(rendered, capsys)
    lf = curves.loc[0, "light_field"]
    assert rc == 1 and f"the curve of light field '{lf}'" in text, text
    assert "was changed after rendering" in text


def test_a_missing_tone_curve_record_fails_verify(rendered, capsys):
    (rendered / "tonemaps.csv").unlink()
    rc, text = _verify(rendered, capsys)
    assert rc == 1 and "tonemaps.csv is missing" in text, text


def test_the_image_statistics_set_is_not_rendered_into_the_experiments_folder(rendered, capsys):
    before = {p: p.read_bytes() for p in rendered.rglob("*") if p.is_file()}
    rc = main(["render", "--set", "imagestats_slice", "--limit", "1", "--out", str(rendered),
               *TINY])
    err = capsys.readouterr().err
    assert rc == 1 and "holds the experiment's stimuli" in err and "another --out" in err, err
    after = {p: p.read_bytes() for p in rendered.rglob("*") if p.is_file()}
    assert after == before
    rc = main(["render", "--set", "preview", "--out", str(rendered), *TINY])  # the same set
    assert rc == 0, capsys.readouterr().err
