"""The gloss table: round trip, default, interpolation, bad tables with clear errors."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from stimuli import default_gloss_table, ward_params_for_gloss
from stimuli.errors import GlossTableError
from stimuli.glosstable import GLOSS_TABLE_COLUMNS, load_gloss_table, write_gloss_table


def test_default_table_covers_the_design(design):
    table = default_gloss_table()
    assert list(table.columns[:6]) == GLOSS_TABLE_COLUMNS
    rho_d, rho_s, alpha = ward_params_for_gloss(table, design.gloss.rendered_pct)
    assert np.all(np.diff(rho_s) > 0) and np.all(np.diff(alpha) < 0)
    assert np.all(rho_d + rho_s <= 1)


def test_round_trip_keeps_extra_columns(tmp_path):
    table = default_gloss_table()
    table["sample_id"] = [f"S{i}" for i in range(len(table))]
    table["fit_error"] = 0.01
    write_gloss_table(table, tmp_path / "t.csv")
    back = load_gloss_table(tmp_path / "t.csv")
    pd.testing.assert_frame_equal(back, table, check_dtype=False)
    assert not list(tmp_path.glob(".*tmp*"))


def test_interpolation_hits_rows_exactly():
    table = default_gloss_table()
    _, rho_s, alpha = ward_params_for_gloss(table, table["gloss_pct"])
    np.testing.assert_allclose(rho_s, table["rho_s"])
    np.testing.assert_allclose(alpha, table["alpha"])
    with pytest.raises(GlossTableError, match="outside"):
        ward_params_for_gloss(table.iloc[2:5].reset_index(drop=True), 5.0)


def _bad_tables():
    ok = default_gloss_table()
    yield ok.drop(columns=["alpha"]), "lacks columns"
    yield ok.iloc[::-1], "strictly increasing"
    yield ok.assign(alpha=0.0), "alpha"
    yield ok.assign(rho_d=0.95), "create energy"
    yield ok.assign(rho_s="x"), "not numeric"
    yield ok.iloc[:1], ">= 2"
    yield ok.assign(gloss_pct=ok["gloss_pct"] + 50), r"\[0, 100\]"
    t = ok.copy()
    t.loc[3, "rho_d"] = np.nan
    yield t, "not finite"


@pytest.mark.parametrize("frame,match", list(_bad_tables()))
def test_bad_tables_are_refused(tmp_path, frame, match):
    path = tmp_path / "bad.csv"
    frame.to_csv(path, index=False)
    with pytest.raises(GlossTableError, match=match) as info:
        load_gloss_table(path)
    assert "bad.csv" in str(info.value)
    with pytest.raises(GlossTableError, match=match):
        write_gloss_table(frame, tmp_path / "out.csv")
    assert not (tmp_path / "out.csv").exists()


def test_missing_table_names_the_fix(tmp_path):
    with pytest.raises(GlossTableError, match="fit-gloss"):
        load_gloss_table(tmp_path / "nope.csv")
