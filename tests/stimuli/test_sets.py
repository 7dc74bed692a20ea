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
    assert t["light_field"].nunique() == design.imagestats.n_light_fields == 22
    sub = apply_filters(t, parse_filters(["depth_level=2,5", "light_field=noon_grass"]))
    assert set(sub["depth_level"]) == {2, 5} and len(sub) == 2 * 11 * 22


def test_imagestats_light_fields_are_distinct_files_not_rotations(design):
    t = stimulus_set(design, "imagestats")
    per_lf = t.groupby("light_field")[["envmap", "envmap_scale", "rotation_deg"]].nunique()
    assert (per_lf == 1).all().all()  # one file and one scale per light field, no rotation
    assert t["envmap"].nunique() == 22 and (t["rotation_deg"] == 0).all()
    assert t.groupby("illumination")["light_field"].nunique().to_dict() == {"indoor": 11,
                                                                            "outdoor": 11}


def test_imagestats_slice_covers_every_light_field_gloss_and_depth_level(design):
    import numpy as np

    t = stimulus_set(design, "imagestats_slice")
    full = stimulus_set(design, "imagestats").set_index("stimulus_id")
    assert len(t) == 44 and t["stimulus_id"].isin(full.index).all()
    assert t.groupby("light_field").size().eq(2).all() and t["light_field"].nunique() == 22
    for _, kind in t.groupby("illumination"):
        assert sorted(kind["gloss_level"]) == sorted(design.gloss.labels * 2)
        assert sorted(kind["depth_level"]) == sorted(design.depth.labels * 2)
        assert abs(np.corrcoef(kind["gloss_level"], kind["depth_level"])[0, 1]) < 0.05
    # the two images of a light field differ, so slopes are estimable within light fields
    diffs = t.groupby("light_field")[["gloss_level", "depth_level"]].agg(lambda v: v.iloc[1]
                                                                         - v.iloc[0])
    assert (diffs.abs().sum(axis=1) > 0).all()


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
