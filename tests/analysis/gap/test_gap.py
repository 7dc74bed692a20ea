"""Observer-layer gap diagnosis: parameter recovery, blind identification, null, report."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from analysis.gap import GapError, diagnose_observer, holm, inject
from analysis.gap.__main__ import main
from analysis.gap.benchmark import run_observer_benchmark
from studydesign import load_design

DESIGN = load_design()
GAP_DIR = Path(__file__).resolve().parents[3] / "analysis" / "gap"


def _diag(effect, strength, seed):
    rng = np.random.default_rng(seed)
    real = inject.simulate_sessions(DESIGN, 4, rng, effect, strength)
    sim = inject.simulate_sessions(DESIGN, 4, rng)
    return diagnose_observer(real, sim, DESIGN, rng=rng, seed=seed, n_boot=400)


@pytest.mark.parametrize("effect,strength", [("crosstalk", 0.3), ("central_tendency", 0.3),
                                             ("illumination_gain", 0.3), ("lapses", 0.15),
                                             ("label_rounding", 0.4),
                                             ("serial_dependence", 0.3)])
def test_injected_effect_is_top_ranked(effect, strength):
    diag, local = _diag(effect, strength, 3)
    assert diag.steps and diag.steps[0]["added"] == effect
    assert diag.shrink_abs > 0
    assert set(local["response"]) == {"gloss", "depth"}


def test_crosstalk_slope_recovered():
    diag, _ = _diag("crosstalk", 0.3, 5)
    assert diag.steps[0]["params"]["c"] == pytest.approx(0.3, abs=0.05)


def test_nothing_injected_is_unexplained():
    diag, _ = _diag("none", 0.0, 11)
    assert diag.verdict == "unexplained"


def test_out_of_catalogue_is_unexplained():
    diag, _ = _diag("stimulus_bias", 0.3, 13)
    assert diag.verdict == "unexplained"


def test_holm_reference():
    # Worked example: p = (0.01, 0.04, 0.03) -> Holm (0.03, 0.06, 0.06).
    assert holm(np.array([0.01, 0.04, 0.03])) == pytest.approx([0.03, 0.06, 0.06])


def test_diagnosis_never_imports_injectors():
    """Blindness: no diagnosis module imports analysis.gap.inject (only the benchmark does)."""
    for path in GAP_DIR.glob("*.py"):
        # The CLI (__main__) may start the benchmark; the diagnosis modules may not.
        if path.name in ("benchmark.py", "inject.py", "__main__.py"):
            continue
        tree = ast.parse(path.read_text())
        names = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
        names += [f"{n.module}.{a.name}" for n in ast.walk(tree)
                  if isinstance(n, ast.ImportFrom) for a in n.names]
        assert not any("inject" in n or "benchmark" in n for n in names), path
        # Nor the simulators the injectors generate pseudo-real data with.
        assert not any(n.endswith(("SimulatedCRT", "load_crt", "make_observer", "simulate_dataset",
                                   "write_simulated_sessions")) for n in names), path


def test_cli_diagnose_writes_report_and_refuses_overwrite(tmp_path, capsys):
    rng = np.random.default_rng(2)
    real = inject.simulate_sessions(DESIGN, 2, rng, "crosstalk", 0.3)
    real["illumination"] = real["illumination"].map({"indoor": "lab_A", "outdoor": "lab_B"})
    real["stimulus_id"] = [f"photo{i:04d}" for i in range(len(real))]
    inject.write_sessions(real, tmp_path / "real")
    inject.write_sessions(inject.simulate_sessions(DESIGN, 2, rng), tmp_path / "sim")
    args = ["diagnose", "--layer", "observer", "--real", str(tmp_path / "real"),
            "--sim", str(tmp_path / "sim"), "--out", str(tmp_path / "rep")]
    assert main(args) == 0
    page = (tmp_path / "rep" / "index.html").read_text()
    assert "crosstalk" in page and "localisation.png" in page
    assert main(args) == 2
    assert "exists" in capsys.readouterr().err


def test_bad_input(tmp_path):
    (tmp_path / "x.csv").write_text("a,b\n1,2\n")
    with pytest.raises(GapError, match="columns"):
        from analysis.gap import load_sessions
        load_sessions(tmp_path)
    with pytest.raises(GapError, match="no session CSVs"):
        load_sessions(tmp_path / "empty") if (tmp_path / "empty").mkdir() is None else None


def test_benchmark_small():
    r = run_observer_benchmark(DESIGN, trials=4, seed=1, n_boot=300)
    assert len(r["records"]) == 4


@pytest.mark.slow
def test_benchmark_targets():
    r = run_observer_benchmark(DESIGN, trials=24, seed=3, n_boot=400)
    assert r["false_attribution"] <= 0.34
    assert r["top1"] >= 0.8
    assert r["shrink_error"] <= 0.10


def _diagnosis(**kw):
    from analysis.gap.engine import Diagnosis

    base = {"layer": "display", "ranking": (), "steps": (), "verdict": "unexplained",
            "gap_before": 0.3, "gap_after": 0.3, "shrink_abs": 0.0, "shrink_abs_ci": (0.0, 0.0),
            "shrink_pct": 0.0, "shrink_pct_ci": (0.0, 0.0), "seed": 1}
    return Diagnosis(**(base | kw))


def test_verdict_says_no_significant_gap_when_the_gap_ci_reaches_zero():
    from analysis.gap.report import no_significant_gap, verdict_text

    none = _diagnosis(gap_before_ci=(-0.09, 0.88))
    some = _diagnosis(gap_before_ci=(0.2, 0.9))
    assert no_significant_gap(none) and "no significant gap" in verdict_text(none)
    assert not no_significant_gap(some) and "unexplained" in verdict_text(some)
