"""Regenerate the lme4 + car reference files the mixed-model tests compare with.

Run from the repository root: ``.venv/bin/python tests/analysis/reference/regenerate.py``.
For each case in ``tests/analysis/lmmdata.CASES`` it writes ``<case>_data.csv`` (simulated with a
fixed seed), ``<case>_thetas.csv``, ``<case>_start.csv`` (``analysis.lmm.moment_start``) and
``<case>_lme4.csv`` (R's output from
``analysis/r/lmm_formula_reference.R``: lme4 1.1-31, car 3.1-1, lmerTest 3.1-3 from Debian).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(HERE.parent))

from lmmdata import CASES, sample_thetas, simulate_case

from analysis.formula import build_model
from analysis.lmm import moment_start
from studydesign import load_design

SEED = 6
FORMULA = "y ~ gloss * depth + (1 + gloss + depth | participant)"


def regenerate(case: str, seed: int) -> None:
    rng = np.random.default_rng([SEED, seed])
    frame = simulate_case(case, load_design(), rng)
    frame.to_csv(HERE / f"{case}_data.csv", index=False, float_format="%.17g")
    np.savetxt(HERE / f"{case}_thetas.csv", sample_thetas(rng), delimiter=",", fmt="%.17g")
    spec = build_model(FORMULA, frame)
    np.savetxt(HERE / f"{case}_start.csv", moment_start(spec)[None, :], delimiter=",",
               fmt="%.17g")
    subprocess.run(
        ["Rscript", str(ROOT / "analysis/r/lmm_formula_reference.R"),
         f"data={HERE / f'{case}_data.csv'}", f"formula={FORMULA}", "reml=0",
         "factors=participant", f"thetas={HERE / f'{case}_thetas.csv'}",
         f"start={HERE / f'{case}_start.csv'}", f"out={HERE / f'{case}_lme4.csv'}"],
        check=True,
    )


if __name__ == "__main__":
    for k, name in enumerate(CASES):
        regenerate(name, k)
        print("wrote", name)
