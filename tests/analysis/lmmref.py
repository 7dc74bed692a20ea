"""Run R (lme4 1.1-31, car 3.1-1, lmerTest 3.1-3, from Debian) live for the mixed-model tests.

`r_reference` writes a data frame to CSV, runs ``analysis/r/lmm_formula_reference.R`` on it and
returns its output as ``{key: {name: value}}``. It fails (never skips) when Rscript is missing.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "analysis" / "r" / "lmm_formula_reference.R"


def rscript() -> str:
    path = shutil.which("Rscript")
    assert path, "Rscript not found: install r-base-core r-cran-lme4 r-cran-car (make test does)"
    return path


def export_dataset(name: str, folder: Path) -> pd.DataFrame:
    """One of lme4's data sets (sleepstudy, Penicillin, Pastes, Dyestuff), exported by R now."""
    path = folder / f"{name}.csv"
    subprocess.run([rscript(), str(SCRIPT), "export", name, str(path)], check=True,
                   capture_output=True, timeout=120)
    return pd.read_csv(path, dtype=str).apply(
        lambda c: pd.to_numeric(c) if c.str.fullmatch(r"-?[0-9.eE+-]+").all() else c)


def read_reference(path: Path) -> dict:
    t = pd.read_csv(path, dtype={"name": str}, keep_default_na=False)
    out: dict = {}
    for key, grp in t.groupby("key", sort=False):
        out[key] = dict(zip(grp["name"], grp["value"].astype(float)))
    return out


def r_reference(folder: Path, data: pd.DataFrame, formula: str, *, reml: bool, factors,
                thetas=None, contrasts: pd.DataFrame | None = None, start=None) -> dict:
    """lme4's fit of ``formula`` on ``data``, as `read_reference` parses it."""
    folder.mkdir(parents=True, exist_ok=True)
    data.to_csv(folder / "data.csv", index=False, float_format="%.17g")
    args = [rscript(), str(SCRIPT), f"data={folder / 'data.csv'}", f"formula={formula}",
            f"reml={int(reml)}", f"factors={','.join(factors)}", f"out={folder / 'out.csv'}"]
    if thetas is not None:
        np.savetxt(folder / "thetas.csv", np.atleast_2d(thetas), delimiter=",", fmt="%.17g")
        args.append(f"thetas={folder / 'thetas.csv'}")
    if contrasts is not None:
        contrasts.to_csv(folder / "L.csv", index=False, float_format="%.17g")
        args.append(f"contrasts={folder / 'L.csv'}")
    if start is not None:
        np.savetxt(folder / "start.csv", np.atleast_2d(start), delimiter=",", fmt="%.17g")
        args.append(f"start={folder / 'start.csv'}")
    proc = subprocess.run(args, capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 0, f"R failed on {formula}:\n{proc.stderr[-3000:]}"
    return read_reference(folder / "out.csv")
