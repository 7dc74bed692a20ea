"""Every package answers ``python -m <package> --help`` with its subcommands."""

from __future__ import annotations

import subprocess
import sys

import pytest


@pytest.mark.parametrize(
    "package, subcommand",
    [
        ("studydesign", "show"),
        ("calibration", "ports"),
        ("stimuli", "list"),
        ("experiment", "plan"),
        ("analysis", "units"),
    ],
)
def test_package_help_lists_subcommands(package, subcommand):
    out = subprocess.run(
        [sys.executable, "-m", package, "--help"], capture_output=True, text=True, check=False, timeout=120
    )
    assert out.returncode == 0, out.stderr
    assert subcommand in out.stdout


def test_studydesign_check_reports_bad_file(tmp_path):
    bad = tmp_path / "design.toml"
    bad.write_text("[gloss]\n")
    out = subprocess.run(
        [sys.executable, "-m", "studydesign", "--design", str(bad), "check"],
        capture_output=True, text=True, check=False, timeout=60,
    )
    assert out.returncode == 1
    assert "missing" in out.stderr
