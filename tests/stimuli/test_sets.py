"""Stimulus sets and filters."""

from __future__ import annotations

import pytest

from stimuli import apply_filters, stimulus_set
from stimuli.sets import parse_filters


def test_experiment_set_is_the_design_with_one_array_per_depth(design):
    t = stimulus_set(design, "experiment")
    assert len(t) == design.n_stimuli and t["stimulus_id"].is_unique
    assert t.groupby("depth_level")["seed"].nunique().eq(1).all()
    assert set(t["envmap"]) == {il.envmap for il in design.illuminations}


def test_imagestats_set_size_and_ids(design):
    t = stimulus_set(design, "imagestats")
    n = design.n_imagestats_images
    assert len(t) == n == 58_564
    assert t["stimulus_id"].is_unique
    assert t["light_field"].nunique() == (len(design.illuminations)
                                          * design.imagestats.n_light_fields)
    sub = apply_filters(t, parse_filters(["depth_level=2,5", "light_field=indoor_lf00"]))
    assert set(sub["depth_level"]) == {2, 5} and len(sub) == 2 * 11 * 22


def test_preview_is_small(design):
    t = stimulus_set(design, "preview")
    assert 0 < len(t) <= 8


@pytest.mark.parametrize("specs,match", [
    (["depth_level"], "column=value"),
    (["colour=red"], "unknown column"),
    (["depth_level=x"], "numeric"),
    (["depth_level=99"], "select no stimuli"),
])
def test_bad_filters(design, specs, match):
    with pytest.raises(ValueError, match=match):
        apply_filters(stimulus_set(design, "experiment"), parse_filters(specs))


def test_unknown_set(design):
    with pytest.raises(ValueError, match="unknown stimulus set"):
        stimulus_set(design, "everything")
