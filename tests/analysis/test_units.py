"""Slider matches convert to physical units through the design."""

import pandas as pd
import pytest

from analysis import matches_to_physical


def test_matches_convert_to_percent_and_cm(design):
    frame = pd.DataFrame({"gloss_match": [1.0, 6.0, 11.0], "depth_match": [1.0, 5.5, 11.0]})
    out = matches_to_physical(frame, design)
    assert out["gloss_match_pct"].tolist() == pytest.approx([0.0, 50.0, 100.0])
    assert out["depth_match_cm"].tolist() == pytest.approx([0.4, 2.2, 4.4])
    assert "gloss_match_pct" not in frame.columns  # input untouched


def test_out_of_range_match_is_an_error(design):
    with pytest.raises(ValueError, match="outside"):
        matches_to_physical(pd.DataFrame({"gloss_match": [12.0], "depth_match": [3.0]}), design)
