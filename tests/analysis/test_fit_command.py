"""``python -m analysis fit``: a CSV or a session folder in, fit.json and summary.txt out."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from analysis.lmm import LmmFit, fit
from analysis.load import load_sessions
from analysis.models import model_frame

from .sessions import write_sessions

REF = Path(__file__).parent / "reference"
CROSSED = ("gloss_match_pct ~ gloss * depth + illumination + (1 + gloss + depth | participant)"
           " + (1 | stimulus_id)")


def _run(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "analysis", "fit", *map(str, args)],
                          capture_output=True, text=True, timeout=timeout, check=False)


def test_csv_fit_writes_the_same_fit_as_the_function(tmp_path):
    formula = "y ~ gloss * depth + (1 + gloss + depth | participant)"
    out = _run(REF / "unbalanced_5_data.csv", "--formula", formula, "--out", tmp_path / "f",
               "--lrt", "5", "--quiet")
    assert out.returncode == 0, out.stderr
    assert "Bootstrap LRT (PBmodcomp) gloss:depth" in out.stdout
    assert "Type II Wald chi-square tests" in out.stdout
    record = json.loads((tmp_path / "f" / "fit.json").read_text())
    data = pd.read_csv(REF / "unbalanced_5_data.csv", dtype={"participant": str})
    assert LmmFit(**record["fit"]) == fit(formula, data)
    assert [t["term"] for t in record["type2_wald"]] == ["gloss", "depth", "gloss:depth"]
    assert [t["n_ok"] for t in record["bootstrap_lrt"]] == [5, 5, 5]
    assert (tmp_path / "f" / "summary.txt").read_text() in out.stdout
    # Never overwritten.
    again = _run(REF / "unbalanced_5_data.csv", "--formula", formula, "--out", tmp_path / "f")
    assert again.returncode == 1 and "never overwritten" in again.stderr


def test_session_folder_gets_the_reports_model_frame(tmp_path, design):
    write_sessions(tmp_path / "data", design, np.random.default_rng(7), n_participants=3)
    out = _run(tmp_path / "data", "--formula", CROSSED, "--reml", "--out", tmp_path / "f",
               "--bootstrap", "20", "--quiet")
    assert out.returncode == 0, out.stderr
    record = json.loads((tmp_path / "f" / "fit.json").read_text())
    mf = model_frame(load_sessions(tmp_path / "data", design).frame, design)
    assert LmmFit(**record["fit"]) == fit(CROSSED, mf, reml=True)
    assert record["bootstrap"]["n_boot"] == 20
    assert "stimulus_id" in out.stdout and "REML" in out.stdout
    assert set(record["satterthwaite_t"]) == set(record["fit"]["fixef"])
    assert "Pr(>|t|)" in out.stdout


@pytest.mark.parametrize("formula, message", [
    ("gloss_match_pct ~ gloss + (1 | observer)", "'observer' is not a column"),
    ("gloss_match_pct ~ gloss", "no random-effect term"),
])
def test_bad_formula_is_an_error_that_names_the_fix(tmp_path, design, formula, message):
    write_sessions(tmp_path / "data", design, np.random.default_rng(8), n_participants=2)
    out = _run(tmp_path / "data", "--formula", formula, "--out", tmp_path / "f")
    assert out.returncode == 1
    assert message in out.stderr
    assert not (tmp_path / "f" / "fit.json").exists()


def test_data_that_is_neither_folder_nor_csv(tmp_path):
    (tmp_path / "x.txt").write_text("a")
    out = _run(tmp_path / "x.txt", "--formula", "y ~ (1 | g)", "--out", tmp_path / "f")
    assert out.returncode == 1 and "not a session folder or a .csv file" in out.stderr
