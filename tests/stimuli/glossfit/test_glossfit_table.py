"""From per-level fits to the gloss table: common albedo, rho_s line, leave-one-out errors."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from stimuli.glossfit import GlossFitError, gloss_table_from_fits, line_with_loo


def fits(alpha=(0.3, 0.2, 0.1, 0.05)):
    g = np.array([0.0, 30.0, 60.0, 90.0])
    return pd.DataFrame({"gloss_pct": g, "rho_d": [0.40, 0.42, 0.38, 0.40],
                         "rho_s": 0.01 + 0.001 * g + np.array([0, 0.002, -0.002, 0]),
                         "alpha": alpha, "rmse": 0.05})


def test_line_with_loo_by_hand():
    # On an exact line every held-out point is predicted exactly.
    coef, loo = line_with_loo(np.arange(4.0), 1 + 2 * np.arange(4.0))
    np.testing.assert_allclose(coef, [1, 2])
    np.testing.assert_allclose(loo, 0, atol=1e-12)
    # Three points (0,0), (1,1), (2,0): leaving out the middle one predicts 0, error 1.
    _, loo = line_with_loo(np.array([0.0, 1, 2]), np.array([0.0, 1, 0]))
    assert loo[1] == pytest.approx(1.0)


def test_table_common_albedo_and_line():
    table, summary = gloss_table_from_fits(fits())
    assert np.allclose(table["rho_d"], 0.40)
    assert summary["common_rho_d"] == pytest.approx(0.40)
    assert summary["rho_s_slope_per_pct"] == pytest.approx(0.001, rel=0.1)
    assert table["loo_error"].notna().all()
    np.testing.assert_allclose(table["alpha"], [0.3, 0.2, 0.1, 0.05])
    assert set(table["alpha_source"]) == {"fitted"}


def test_undetermined_alpha_comes_from_the_other_levels():
    table, _ = gloss_table_from_fits(fits(alpha=(0.01, 0.2, 0.1, 0.05)), (0.0,))
    # log alpha is a line through the other three: 0.2 * 2^(-g/30) gives 0.4 at 0 %.
    assert table["alpha"][0] == pytest.approx(0.4, rel=1e-6)
    assert table["alpha_source"][0].startswith("log-linear")


def test_too_few_levels():
    with pytest.raises(GlossFitError, match=">= 2"):
        gloss_table_from_fits(fits().iloc[:1])
