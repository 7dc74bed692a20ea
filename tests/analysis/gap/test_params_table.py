"""A chosen effect's parameters as rows for people (analysis.gap.params_table): readable
names, units, 3 significant digits, one row per level / illumination / response."""

from __future__ import annotations

import pytest

from analysis.gap import catalogue
from analysis.gap.engine import ParamDoc
from analysis.gap.params_table import ParamRow, format_sig, param_rows


@pytest.mark.parametrize("value,text", [
    (0.7857862614134724, "0.786"), (-0.17338036235935594, "-0.173"), (1.062474840957927, "1.06"),
    (600.0, "600"), (17.4778, "17.5"), (1234.5, "1230"), (9.996, "10"), (0.0012345, "0.00123"),
    (0.5, "0.5"), (0.0, "0"), (-0.0, "0"), (1e-7, "1e-07"), (2.5e7, "2.5e+07"), (6, "6"),
    (True, "yes"), ("gloss_020", "gloss_020"), (float("nan"), "nan"), (None, ""),
])
def test_format_sig(value, text):
    assert format_sig(value) == text


def test_format_sig_needs_a_digit():
    with pytest.raises(ValueError, match="at least 1 significant digit"):
        format_sig(1.0, 0)


def test_render_parameters_per_level_as_rows():
    """The vignetting step of a real render diagnosis (analysis gap diagnose on
    inject.write_render_fit(vignetting 0.5, seed 1)): scales per level split into their
    diffuse and specular parts, each part's levels together."""
    params = {"c": 0.5009257904710719, "c2": -0.17338036235935594,
              "scale": {"gloss_020": [1.062474840957927, 1.0744645174266922],
                        "gloss_050": [1.0630221503736024, 1.0629456120249399]}}
    rows = param_rows("render", "vignetting", params)
    assert [(r.name, r.where, r.value) for r in rows] == [
        ("darkening \u221d \u03c1\u00b2", "", "0.501"),
        ("darkening \u221d \u03c1\u2074", "", "-0.173"),
        ("diffuse scale", "gloss_020", "1.06"), ("diffuse scale", "gloss_050", "1.06"),
        ("specular scale", "gloss_020", "1.07"), ("specular scale", "gloss_050", "1.06")]
    assert rows[0].unit.startswith("fraction") and "gloss fit" in rows[2].unit


def test_units_follow_the_value_where_the_form_does():
    rows = param_rows("render", "long_tail", {"c": {"g20": 0.3, "g50": 0.1},
                                              "width": {"g20": "g10", "g50": -4.0, "g80": 2.0}})
    width = {r.where: r for r in rows if r.name == "wing form"}
    assert width["g20"].value == "g10" and "less glossy level" in width["g20"].unit
    assert "GTR1" in width["g50"].unit and "Gaussian" in width["g80"].unit
    assert param_rows("render", "misregistration", {"shift_px": {"g20": [0.1, -0.25]}}) == [
        ParamRow("render shift down", "g20", "0.1", "px"),
        ParamRow("render shift right", "g20", "-0.25", "px")]


def test_observer_and_display_parameters():
    assert param_rows("observer", "central_tendency", {"gloss": 0.2, "depth": 0.1}) == [
        ParamRow("pull toward the slider's middle", f"{r} response", v,
                 "share of the distance to the middle") for r, v in (("gloss", "0.2"),
                                                                     ("depth", "0.1"))]
    gain = param_rows("observer", "illumination_gain", {"gain": {"lab_A": 0.31, "lab_B": -0.29}})
    assert [(r.where, r.value) for r in gain] == [("lab_A", "0.31"), ("lab_B", "-0.29")]
    assert param_rows("display", "warmup_drift", {"w": 0.0288555, "tau_s": 801.668}) == [
        ParamRow("luminance deficit at switch-on", "", "0.0289", "fraction"),
        ParamRow("warm-up time constant", "", "802", "s")]


def test_an_unlisted_effect_reads_its_keys():
    """A candidate registered later still gets a table: its keys as names, a unit suffix as
    the unit, nested values per participant as rows."""
    rows = param_rows("observer", "new_effect", {"offset_px": 1.23456,
                                                 "per": {"P01": [1, 2.5]}, "on": True})
    assert rows == [ParamRow("offset", "", "1.23", "px"), ParamRow("per", "P01 / [0]", "1", ""),
                    ParamRow("per", "P01 / [1]", "2.5", ""), ParamRow("on", "", "yes", "")]
    assert param_rows("display", "black_offset", {}) == []
    with pytest.raises(TypeError, match="not a dict"):
        param_rows("display", "black_offset", [0.05])


@pytest.mark.parametrize("layer", ["observer", "display", "render"])
def test_every_registered_candidate_describes_its_parameters(layer):
    """Each candidate of the catalogue says how its parameters read (Candidate.params, written
    beside its fit), so its table has names and units, not bare keys."""
    for cand in catalogue(layer):
        assert cand.params, f"{layer}/{cand.name} describes none of its parameters"
        for key, doc in cand.params.items():
            assert isinstance(doc, ParamDoc) and doc.name, (layer, key)
            assert doc.name != key or doc.parts, f"{layer}/{cand.name}: {key!r} not put in words"


def test_held_out_light_steps_read_without_blanks_or_signs():
    """The steps of a held-out-light diagnosis (issue 38): the broad lobe (registered apart,
    in render_lights) named and with units, the scales shared by every photo said in words
    (not ``*``), the coat's entry explained, a power-law glare's spread as its size (the fit
    codes the kernel in the sign: -0.03 read as "-0.03 -x image width"); no empty cell."""
    from analysis.gap.report import params_html

    steps = {"broad_lobe": {"alpha2": 0.4, "c": 0.0512, "scale": {"*": [0.93, 1.02]}},
             "veiling_glare": {"sigma_frac": -0.03, "c": 0.05, "scale": {"*": [1.0, 0.97]}},
             "clearcoat": {"entry": "lights", "c": 0.572, "scale": {"*": [1.01, 0.979]}}}
    for effect, params in steps.items():
        rows = param_rows("render", effect, params)
        assert all(r.value and r.unit for r in rows), rows
        assert all(r.name not in params for r in rows), rows  # named, not the bare key
        assert not any("*" in r.where or r.value.startswith("-") for r in rows), rows
        assert "<td></td>" not in params_html("render", effect, params)
    glare = param_rows("render", "veiling_glare", steps["veiling_glare"])[0]
    assert (glare.value, glare.unit.split(",")[0]) == ("0.03", "× image width")
    assert "power-law" in glare.unit
    lobe = param_rows("render", "broad_lobe", steps["broad_lobe"])
    assert [r.name for r in lobe][:2] == ["broad lobe's width", "broad lobe's albedo"]
    assert lobe[2].where == "every photo (one material)"
