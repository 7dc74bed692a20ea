"""Where the benchmark's command line answers: ``python -m analysis gapbench`` and
``python -m analysis.gapbench``; ``python -m analysis gap benchmark`` (the older line, in lab
scripts and protocol.md) forwards there; ``python -m analysis.gap benchmark`` says where it went."""

from __future__ import annotations

import subprocess
import sys

import pytest

from analysis.gapbench import bench_render as br

ARGS = ["--layer", "render", "--harder", "--trials", "1", "--seed", "3", "--quiet"]


@pytest.fixture
def fake_render_cases(monkeypatch):
    """The render cases replaced by one null record (no Mitsuba); the calls are recorded."""
    calls = []

    def fake_run(design, *, trials, seed, log):
        calls.append({"trials": trials, "seed": seed})
        return [{"case": "none", "inside": [], "verdict": "unexplained", "named": [],
                 "top": "unexplained", "steps": [], "flagged": False, "pred_shrink": 1.0,
                 "true_shrink": float("nan"), "seed_verdicts": [("unexplained", False)] * 3}]
    monkeypatch.setattr(br, "run_render_cases", fake_run)
    return calls


@pytest.mark.parametrize("words", [["gapbench"], ["gap", "benchmark"]])
def test_the_analysis_command_line_runs_the_benchmark(words, fake_render_cases, capsys):
    from analysis.__main__ import main

    assert main([*words, *ARGS]) == 0
    assert fake_render_cases == [{"trials": 1, "seed": 3}]
    assert "render (harder): false attributions" in capsys.readouterr().out


def test_the_diagnosis_command_line_says_where_the_benchmark_went(fake_render_cases, capsys):
    from analysis.gap.__main__ import main

    assert main(["benchmark", *ARGS]) == 2
    assert not fake_render_cases
    assert "python -m analysis gapbench" in capsys.readouterr().err


def test_the_package_runs_as_a_module():
    out = subprocess.run([sys.executable, "-m", "analysis.gapbench", "--help"],
                         capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == 0, out.stderr
    assert "--harder" in out.stdout and "--threshold-reps" in out.stdout
