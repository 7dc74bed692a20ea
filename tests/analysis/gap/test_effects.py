"""Effect objects: candidates and out-of-catalogue effects, one object each, and the strength
tables derived from them."""

from __future__ import annotations

import pytest

from analysis.gap import engine
from analysis.gap.engine import (
    Candidate,
    GapError,
    OutOfCatalogue,
    effect,
    out_of_catalogue,
    register,
    register_out_of_catalogue,
    registry,
    strengths,
)
from analysis.gapbench import inject


@pytest.fixture
def scratch_layer(monkeypatch):
    """A layer of one candidate and one out-of-catalogue effect, registered in copies of the
    engine's registries (the real ones are left as they are)."""
    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))
    monkeypatch.setattr(registry, "_OUT_REGISTRY", dict(registry._OUT_REGISTRY))
    register("scratch", Candidate("tilt", lambda train, chosen: {}, default_strength=0.2))
    register_out_of_catalogue("scratch", OutOfCatalogue("ripple", lambda *a: None, 0.7))
    return "scratch"


@pytest.mark.parametrize("layer", ["observer", "display", "render"])
def test_unknown_effect_error_names_the_known_ones(layer):
    with pytest.raises(GapError) as err:
        effect(layer, "no_such_effect")
    text = str(err.value)
    assert "no_such_effect" in text
    for e in engine.catalogue(layer) + out_of_catalogue(layer):
        assert e.name in text


@pytest.mark.parametrize("layer", ["observer", "display", "render"])
def test_strength_table_is_each_objects_default_strength(layer):
    table = strengths(layer)
    objects = engine.catalogue(layer) + out_of_catalogue(layer)
    assert table == {e.name: e.default_strength for e in objects}
    assert out_of_catalogue(layer), "the benchmark's injectors register out-of-catalogue effects"


def test_inject_tables_are_derived_from_the_objects():
    assert inject.RENDER_STRENGTH == strengths("render")
    assert inject.DISPLAY_STRENGTH == strengths("display")
    assert inject.OUT_OF_CATALOGUE_STRENGTH == {e.name: e.default_strength
                                                for e in out_of_catalogue("observer")}
    assert inject.RENDER_OUT_OF_CATALOGUE == tuple(e.name for e in out_of_catalogue("render"))
    assert inject.RENDER_EFFECTS == tuple(c.name for c in engine.catalogue("render"))


def test_a_registered_effect_appears_in_every_table(scratch_layer):
    assert strengths(scratch_layer) == {"tilt": 0.2, "ripple": 0.7}
    assert isinstance(effect(scratch_layer, "ripple"), OutOfCatalogue)
    assert isinstance(effect(scratch_layer, "tilt"), Candidate)


def test_out_of_catalogue_name_may_not_shadow_a_candidate(scratch_layer):
    with pytest.raises(GapError, match="has a candidate 'tilt'"):
        register_out_of_catalogue(scratch_layer, OutOfCatalogue("tilt", lambda *a: None, 1.0))
    with pytest.raises(GapError, match="out-of-catalogue effect 'ripple'"):
        register(scratch_layer, Candidate("ripple", lambda train, chosen: {}))


def test_only_effect_objects_register(scratch_layer):
    with pytest.raises(GapError, match="not an engine.OutOfCatalogue"):
        register_out_of_catalogue(scratch_layer, {"name": "x"})
