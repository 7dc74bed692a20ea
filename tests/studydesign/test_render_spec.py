"""The design's [render] section: variant, displayed-error target, spp per gloss level."""

from __future__ import annotations

from pathlib import Path

import pytest

from studydesign import DesignError, load_design


def _edited(tmp_path, old, new):
    """The shipped design with ``old`` replaced by ``new``; an ``old`` ending in "= " stands for
    the whole line that starts with it (so the test does not depend on the shipped value)."""
    text = Path(load_design().source).read_text()
    if old.endswith("= "):
        old = next((ln for ln in text.splitlines() if ln.startswith(old)), old)
    assert old in text, f"test set-up: {old!r} not in design.toml"
    path = tmp_path / "design.toml"
    path.write_text(text.replace(old, new, 1))
    return path


def test_shipped_render_spec(design):
    r = design.render
    assert r.variant == "auto" and 0 < r.displayed_error_pct <= 10
    assert len(r.spp_by_gloss_level) == design.gloss.n_levels
    assert r.spp(1) == r.spp_by_gloss_level[0] and r.spp(11) == r.spp_by_gloss_level[-1]


@pytest.mark.parametrize("old, new, message", [
    ('variant = "auto"', 'variant = "llvm_ad_mono_polarized"', r"render\.variant .* is not one of"),
    ("displayed_error_pct = ", "displayed_error_pct = 0", r"displayed_error_pct must lie in"),
    ("spp_by_gloss_level = [", "spp_by_gloss_level = [0, ", r"integers >= 1"),
    ("spp_by_gloss_level = [", "spp_by_gloss_level = [7, ", r"one per physical gloss level \(11"),
    ("spp_planned_at_px = ", "spp_planned_at_px = 2", r"spp_planned_at_px must be"),
    ("[render]", "[rendering]", r"missing section \[render\]"),
])
def test_bad_render_spec_is_rejected_with_the_fix(tmp_path, old, new, message):
    with pytest.raises(DesignError, match=message):
        load_design(_edited(tmp_path, old, new))
