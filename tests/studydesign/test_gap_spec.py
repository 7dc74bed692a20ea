"""The design's [gap] section: the render layer's tolerance for what the catalogue leaves."""

from __future__ import annotations

from pathlib import Path

import pytest

from studydesign import DesignError, load_design


def _edited(tmp_path, old, new):
    text = Path(load_design().source).read_text()
    assert old in text, f"test set-up: {old!r} not in design.toml"
    path = tmp_path / "design.toml"
    path.write_text(text.replace(old, new, 1))
    return path


def test_shipped_gap_tolerance_is_one_percent_of_the_photos_luminance(design):
    assert design.gap.render_tolerance_pct == 1.0


@pytest.mark.parametrize("old, new, message", [
    ("render_tolerance_pct = 1.0", "render_tolerance_pct = 0",
     r"gap\.render_tolerance_pct must lie in \(0, 20\]"),
    ("render_tolerance_pct = 1.0", "render_tolerance_pct = 35",
     r"gap\.render_tolerance_pct must lie in \(0, 20\]"),
    ("render_tolerance_pct = 1.0", "tolerance_pct = 1.0", r"unknown key\(s\) \['tolerance_pct'\]"),
])
def test_bad_gap_spec_is_rejected_with_the_fix(tmp_path, old, new, message):
    with pytest.raises(DesignError, match=message):
        load_design(_edited(tmp_path, old, new))


def test_a_design_written_before_the_gap_section_loads_with_the_default(tmp_path):
    """A lab's older design.toml has no [gap]: it still loads (sessions and renders must not
    stop for an analysis setting), with the documented default tolerance."""
    text = Path(load_design().source).read_text()
    old = text[:text.index("[gap]")]
    path = tmp_path / "design.toml"
    path.write_text(old)
    assert load_design(path).gap.render_tolerance_pct == 1.0
