"""The display null allows the room light and the gain to wander between and during passes
(issue 38): checked on the blind generator (bench/blind/display_gen.py, written from a physical
description apart from the diagnosis), dev seeds whose clean check read "a further gap at drive
levels 0.0-0.2" before the wander was modelled. Each runs with the wander switched off too, so
the test shows it is the wander that keeps the test against the ceiling quiet. (Since issue 43
the misfit's size in % decides too: without the wander the remainder is significant in nats,
but it is not a gap unless it is also at least the tolerance.)"""

from __future__ import annotations

import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from analysis.gap import NOT_A_GAP, diagnose
from analysis.gap.display import model

REPO = Path(__file__).resolve().parents[3]


def _clean_display(tmp_path: Path, seed: int) -> tuple[Path, Path]:
    out = tmp_path / f"clean-{seed}"
    for cmd in (["bench/blind/display_gen.py", "--case", "clean", "--seed", str(seed),
                 "--out", str(out)],
                ["-m", "calibration", "fit", str(out / "calib.csv"), "--out",
                 str(out / "CAL"), "--dac-bits", "none"]):
        subprocess.run([sys.executable, *cmd], cwd=REPO, check=True, capture_output=True)
    return out / "check.csv", out / "CAL"


def _diag(check: Path, cal: Path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return diagnose("display", check, cal, None, seed=0, n_boot=300)[0]


@pytest.mark.parametrize("seed", [18, 30])
def test_a_clean_display_whose_room_light_wandered_between_passes_is_no_gap(tmp_path, seed,
                                                                            monkeypatch):
    check, cal = _clean_display(tmp_path, seed)
    diag = _diag(check, cal)
    assert diag.verdict in NOT_A_GAP and diag.remaining["p"] >= 0.05, diag.summary
    monkeypatch.setattr(model, "PASS_BOUND_SD", 1e-9)  # the wander held at 0
    assert _diag(check, cal).remaining["p"] < 0.05
