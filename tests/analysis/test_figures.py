"""Figures: metamers found where they were built in; every figure renders to a PNG."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from matplotlib.image import imread

from analysis.figures import (
    find_metamers,
    plot_depth_matches,
    plot_gloss_contours,
    plot_gloss_matches,
    plot_observers,
    save_figure,
)
from analysis.load import load_sessions

from .sessions import write_sessions


def _exact_frame(design, slope_pct_per_cm: float, n: int = 4) -> pd.DataFrame:
    """Perceived gloss = true gloss + slope x (depth - 2.4 cm), tiny observer noise."""
    rng = np.random.default_rng(0)
    stim = design.stimuli()
    rows = []
    for k in range(n):
        f = stim.copy()
        f["participant"] = f"P{k}"
        f["gloss_match_pct"] = (f["true_gloss_pct"] + slope_pct_per_cm * (f["true_depth_cm"] - 2.4)
                                + rng.normal(0, 0.3, len(f)))
        rows.append(f)
    return pd.concat(rows, ignore_index=True)


def test_metamers_lie_on_the_built_in_contour(design):
    # 25 % per cm: 1.2 cm of depth buys 30 % of gloss.
    frame = _exact_frame(design, 25.0)
    found = find_metamers(frame, max_pairs=3)
    assert found
    for m in found:
        traded = (m.gloss_b_pct - m.gloss_a_pct) / (m.depth_a_cm - m.depth_b_cm)
        assert traded == pytest.approx(25.0, rel=0.01)
        assert m.diff_ci[0] <= 0 <= m.diff_ci[1]
    # Ranked by the gloss traded: the first pair spans the most.
    assert found[0].gloss_b_pct - found[0].gloss_a_pct == max(
        m.gloss_b_pct - m.gloss_a_pct for m in found)


def test_no_metamers_without_a_depth_effect(design):
    assert find_metamers(_exact_frame(design, 0.0)) == []


def test_every_figure_renders(tmp_path, design):
    write_sessions(tmp_path, design, np.random.default_rng(2), n_participants=3)
    frame = load_sessions(tmp_path, design).frame
    figs = {
        "a": plot_depth_matches(frame, design),
        "b": plot_gloss_matches(frame, design),
        "c": plot_gloss_contours(frame, design),
        "d": plot_observers(frame, design, response="gloss"),
    }
    for name, fig in figs.items():
        path = save_figure(fig, tmp_path / f"{name}.png")
        img = imread(path)
        assert img.shape[0] > 300 and img.shape[1] > 300
        # Not a blank canvas.
        assert img[..., :3].std() > 0.05
    assert sorted(p.name for p in tmp_path.glob("*.png")) == ["a.png", "b.png", "c.png", "d.png"]
    with pytest.raises(ValueError, match="response must be"):
        plot_observers(frame, design, response="shape")
