"""scripts/make_lightfields.py as an operator runs it (issue 44, item 9): the command its docstring
gave replaced the shipped light fields' provenance table (stimuli/probes/lightfields.tsv) with
rows of 256 x 128 files; a missing capture folder and ``--factor 3`` ended in tracebacks. Now
nothing is replaced, and both are one line with the fix. The captures here are two synthetic
64 x 32 RGBE maps; the shipped folder is a copy in tmp_path (the script's SHIPPED_PROBES)."""

from __future__ import annotations

import importlib.util
import sys

import numpy as np
import pytest

from stimuli.rgbe import write_rgbe
from tests.conftest import REPO_ROOT

COLUMNS = "file\tclass\tscene\tresolution\tformat\torigin\tlicence\tauthor_site"


@pytest.fixture
def script(tmp_path, monkeypatch):
    spec = importlib.util.spec_from_file_location(
        "make_lightfields", REPO_ROOT / "scripts" / "make_lightfields.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    shipped = tmp_path / "probes"
    shipped.mkdir()
    (shipped / "lightfields.tsv").write_text("file\tkind\nroom_32x16.hdr\tindoor\n")
    monkeypatch.setattr(mod, "SHIPPED_PROBES", shipped)
    monkeypatch.setattr(mod, "MANIFEST", shipped / "lightfields.tsv")

    def run(*argv):
        monkeypatch.setattr(sys, "argv", ["make_lightfields.py", *map(str, argv)])
        return mod.main()
    return run, shipped


@pytest.fixture
def captures(tmp_path):
    src = tmp_path / "polyhaven"
    src.mkdir()
    rows = [COLUMNS]
    rng = np.random.default_rng(0)
    for name, kind in (("room", "indoor"), ("field", "outdoor")):
        write_rgbe(src / f"{name}_1k.hdr", rng.lognormal(0, 1, (32, 64, 3)).astype(np.float32))
        rows.append(f"{name}_1k.hdr\t{kind}\ta {kind} scene\t64x32\tRGBE\torigin\tCC0\tsite")
    (src / "SOURCES.tsv").write_text("\n".join(rows) + "\n")
    return src


def _snapshot(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_the_docstrings_command_keeps_the_shipped_provenance_table(script, captures, capsys):
    run, shipped = script
    before = _snapshot(shipped)
    assert run(captures, "--factor", "4") == 1  # the command the docstring gave
    assert "--out NEW_FOLDER" in capsys.readouterr().err
    assert run(captures, "--factor", "4", "--out", shipped) == 1
    assert "already holds lightfields.tsv" in capsys.readouterr().err
    assert _snapshot(shipped) == before


def test_a_new_out_folder_gets_the_light_fields_and_their_table(script, captures, tmp_path,
                                                                capsys):
    run, _ = script
    assert run(captures, "--out", tmp_path / "new") == 0, capsys.readouterr().err
    assert sorted(p.name for p in (tmp_path / "new").iterdir()) == [
        "field_32x16.hdr", "lightfields.tsv", "room_32x16.hdr"]
    assert run(captures, "--out", tmp_path / "new") == 1  # a second build replaces nothing
    assert "give a new --out folder" in capsys.readouterr().err


@pytest.mark.parametrize("fault, said", [
    ("missing folder", "holds no SOURCES.tsv (no such folder)"),
    ("--factor 3", "--factor 3 does not divide room_1k.hdr's 64 x 32 px"),
])
def test_a_missing_folder_or_a_factor_that_splits_pixels_is_one_line(fault, said, script,
                                                                     captures, tmp_path, capsys):
    run, _ = script
    out = tmp_path / "new"
    if fault == "missing folder":
        rc = run(tmp_path / "no_such_folder", "--out", out)
    else:
        rc = run(captures, "--factor", "3", "--out", out)
    err = capsys.readouterr().err
    assert rc == 1 and said in err and "Traceback" not in err, err
    assert not out.exists()  # nothing written before the refusal
