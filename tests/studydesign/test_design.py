"""The design object carries the source study's numbers, validates its input, and is the only copy."""

from __future__ import annotations

import dataclasses
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from studydesign import DesignError, default_design_path, load_design


def test_gloss_levels_match_seed(design):
    assert design.gloss.labels == tuple(range(1, 12))
    assert design.gloss.physical_pct == tuple(float(v) for v in range(0, 101, 10))
    assert design.gloss.rendered_levels == tuple(range(2, 11))
    assert design.gloss.rendered_pct == tuple(float(v) for v in range(10, 91, 10))


def test_depth_levels_are_0p4_cm_steps(design):
    # d_i = 0.4 i cm, i = 1..11 -> 0.4..4.4 cm; rendered 2..10 -> 0.8..4.0 cm
    # (the source study's ranges).
    assert design.depth.physical_cm == pytest.approx([0.4 * i for i in range(1, 12)])
    assert design.depth.physical_cm[0] == pytest.approx(0.4)
    assert design.depth.physical_cm[-1] == pytest.approx(4.4)
    assert design.depth.rendered_cm == pytest.approx([0.8, 1.2, 1.6, 2.0, 2.4, 2.8, 3.2, 3.6, 4.0])


def test_array_geometry_matches_seed(design):
    a = design.array
    assert (a.n_x, a.n_y, a.n_ellipsoids) == (5, 5, 25)
    assert a.extent_cm == 5.0 and a.radius_xy_cm == 1.0 and a.jitter_cm == 0.2
    centres = a.grid_centres_cm()
    assert centres.shape == (25, 2)
    assert centres.mean(axis=0) == pytest.approx([0.0, 0.0])
    # Cell centres of a 5 x 5 cm square: outermost centres at +-2 cm with the default pitch.
    assert np.abs(centres).max() == pytest.approx(2.0)


def test_stimulus_set_is_two_by_nine_by_nine(design):
    table = design.stimuli()
    assert len(table) == design.n_stimuli == 162
    assert table["stimulus_id"].is_unique
    assert sorted(table["illumination"].unique()) == ["indoor", "outdoor"]
    assert table.groupby("illumination").size().tolist() == [81, 81]
    assert design.sessions.n_sessions == 2 and design.sessions.trials_per_session == 81
    assert set(table["true_depth_cm"]) == set(design.depth.rendered_cm)
    assert set(table["true_gloss_pct"]) == set(design.gloss.rendered_pct)


def test_imagestats_set_is_the_seeds_58564_images(design):
    assert design.imagestats.n_light_fields == 22 and design.imagestats.n_arrays == 22
    assert design.n_imagestats_images == 22 * 11 * 11 * 22 == 58_564


def test_light_fields_are_22_distinct_captures_11_indoor_11_outdoor(design):
    lfs = design.imagestats.light_fields
    assert len({lf.envmap for lf in lfs}) == len({lf.name for lf in lfs}) == 22
    assert sorted(lf.kind for lf in lfs) == ["indoor"] * 11 + ["outdoor"] * 11
    assert all(lf.scale > 0 for lf in lfs) and design.imagestats.scale_rule == "diffuse_white"
    # the experiment's two conditions are two of them, with the same scale
    for il in design.illuminations:
        same = [lf for lf in lfs if lf.envmap == il.envmap]
        assert len(same) == 1 and same[0].kind == il.kind and same[0].scale == il.scale


def _with_imagestats(tmp_path, text: str):
    src = default_design_path().read_text(encoding="utf-8")
    start, end = src.index("[imagestats]"), src.index("[render]")
    path = tmp_path / "design.toml"
    path.write_text(src[:start] + text + "\n" + src[end:], encoding="utf-8")
    return path


_ONE = '[imagestats]\nn_arrays = 2\nlight_fields = [\n{{ name = "a", kind = "{k}", envmap = "x.hdr", scale = {s} }}{more}]\n'


@pytest.mark.parametrize("text, match", [
    ("[imagestats]\nn_light_fields = 11\nn_arrays = 22\n", "n_light_fields is gone"),
    (_ONE.format(k="indoor", s=1.0, more=',\n{ name = "b", kind = "indoor", envmap = "x.hdr", '
                 'scale = 1.0 }'), "files repeat"),
    (_ONE.format(k="indoor", s=0.0, more=""), "scale must be"),
    (_ONE.format(k="attic", s=1.0, more=""), "indoor' or 'outdoor"),
])
def test_bad_light_fields_are_refused_with_the_fix(tmp_path, text, match):
    with pytest.raises(DesignError, match=match):
        load_design(_with_imagestats(tmp_path, text))


def test_display_matches_seed(design):
    assert design.display.resolution_px == (1024, 768)
    assert design.display.viewing_distance_cm == 55.0


def test_analysis_bins_match_seed(design):
    assert design.analysis.depth_bins_cm == {
        "low": (0.8, 1.2, 1.6), "medium": (2.0, 2.4, 2.8), "high": (3.2, 3.6, 4.0)
    }
    assert design.analysis.gloss_bins_pct == {
        "low": (10.0, 20.0, 30.0), "medium": (40.0, 50.0, 60.0), "high": (70.0, 80.0, 90.0)
    }
    assert list(design.depth_bin([0.8, 2.4, 4.0, 4.4])) == ["low", "medium", "high", ""]
    assert list(design.gloss_bin([10, 50, 90])) == ["low", "medium", "high"]


@pytest.mark.parametrize(
    "v, depth_cm, gloss_pct", [(1, 0.4, 0.0), (2, 0.8, 10.0), (6.5, 2.6, 55.0), (11, 4.4, 100.0)]
)
def test_slider_to_physical_units(design, v, depth_cm, gloss_pct):
    assert design.slider.to_depth_cm(v) == pytest.approx(depth_cm)
    assert design.slider.to_gloss_pct(v) == pytest.approx(gloss_pct)


@pytest.mark.parametrize("slider_min", [1.0, 0.0, 2.5])
def test_physical_to_slider_inverts_slider_to_physical_whatever_the_minimum(design, slider_min):
    """One owner of both directions: a changed slider.min must not shift the inverse (a copy
    that added slider.min instead of the gloss offset did)."""
    import dataclasses

    s = dataclasses.replace(design.slider, min=slider_min)
    v = np.linspace(slider_min, s.max, 7)
    assert s.from_gloss_pct(s.to_gloss_pct(v), clip=False) == pytest.approx(v)
    assert s.from_depth_cm(s.to_depth_cm(v), clip=False) == pytest.approx(v)
    assert s.from_gloss_pct([-50.0, 500.0], clip=True).tolist() == [slider_min, s.max]


@pytest.mark.parametrize("slider_min", [0.0, 1.0, 2.5])
def test_slider_position_matches_the_reference_label_whatever_the_minimum(design, slider_min):
    """A changed slider.min bounds the marker; it does not move the scale: position v is still
    the reference object labelled v (gloss 10 (v - 1) %, depth 0.4 v cm)."""
    import dataclasses

    s = dataclasses.replace(design.slider, min=slider_min)
    labels = np.array([3.0, 6.0, 11.0])
    assert s.to_gloss_pct(labels) == pytest.approx(design.gloss.pct(labels))
    assert s.to_depth_cm(labels) == pytest.approx(design.depth.cm(labels))
    with pytest.raises(DesignError):
        s.to_gloss_pct(slider_min - 0.5)


@pytest.mark.parametrize("rgb, y", [((1, 1, 1), 1.0), ((1, 0, 0), 0.2126), ((0, 0, 2), 0.1444)])
def test_rec709_luminance_weights(rgb, y):
    """ITU-R BT.709-6 item 3.2: Y = 0.2126 R + 0.7152 G + 0.0722 B."""
    from studydesign import rec709_luminance

    assert rec709_luminance(np.array(rgb, float)) == pytest.approx(y)
    assert rec709_luminance(np.ones((2, 3, 3), np.float32)).dtype == np.float32


@pytest.mark.parametrize("v", [0.99, 11.01, float("nan")])
def test_slider_rejects_values_outside_scale(design, v):
    with pytest.raises(DesignError, match="outside"):
        design.slider.to_depth_cm(v)


def test_slider_labels_land_on_reference_objects(design):
    # Setting the slider to a reference label reproduces that object's physical value.
    labels = np.arange(1, 12)
    assert design.slider.to_gloss_pct(labels) == pytest.approx(design.gloss.pct(labels))
    assert design.slider.to_depth_cm(labels) == pytest.approx(design.depth.cm(labels))


def _write_variant(tmp_path, old, new):
    src = load_design().source
    text = Path(src).read_text()
    assert old in text, f"test set-up: {old!r} not in design.toml"
    path = tmp_path / "design.toml"
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize(
    "old, new, message",
    [
        ("trials_per_session = 81", "trials_per_session = 80", r"sessions: 2 x 80"),
        ("rendered_levels = [2, 3, 4, 5, 6, 7, 8, 9, 10]\n\n[depth]",
         "rendered_levels = [2, 3, 12]\n\n[depth]", r"outside 1\.\.11"),
        ("step_cm = 0.4", "step_cm = 0.5", "slider units disagree"),
        ("pitch_cm = 1.0", "pitch_cm = 2.0", "outside the 5.0 cm square"),
        ('name = "indoor"', 'name = "In door"', "lower-case identifier"),
        ("jitter_cm = 0.2", "jitter_cm = 0.2\ncolour = 3", r"unknown key\(s\) \['colour'\]"),
        ("[display]", "[displays]", r"missing section \[display\]"),
        ("n_x = 5", "n_x = ", "not valid TOML"),
        ("n_arrays = 22", "n_arrays = 0", r"imagestats\.n_arrays must be >= 1"),
    ],
)
def test_invalid_design_is_rejected_with_the_fix(tmp_path, old, new, message):
    with pytest.raises(DesignError, match=message):
        load_design(_write_variant(tmp_path, old, new))


def test_missing_design_file_names_the_path(tmp_path):
    with pytest.raises(DesignError, match="not found"):
        load_design(tmp_path / "nope.toml")


def test_design_is_frozen(design):
    with pytest.raises(dataclasses.FrozenInstanceError):
        design.gloss.step_pct = 5.0  # type: ignore[misc]


def test_custom_design_file_is_honoured(tmp_path):
    path = _write_variant(tmp_path, "viewing_distance_cm = 55.0", "viewing_distance_cm = 57.0")
    assert load_design(path).display.viewing_distance_cm == 57.0
    assert load_design(path).source == str(path)


# Numbers that define the study and must come from the design object. A match in package code
# (outside studydesign/) means a second copy; use the design object instead.
_DESIGN_LITERALS = [
    (r"\b162\b", "number of stimuli"),
    (r"1024\s*[,x×*]\s*768", "display resolution"),
    (r"\b(viewing_distance|distance)\w*\s*=\s*55\b", "viewing distance"),
    (r"0\.4\s*\*\s*\w*(level|v\b|i\b)", "depth step"),
    (r"10(\.0)?\s*\*\s*\(\s*\w+\s*-\s*1", "gloss step"),
    (r"\[\s*0\.8\s*,\s*1\.2\s*,\s*1\.6", "depth bins"),
]


def test_design_numbers_have_no_second_copy_in_package_code(repo_root):
    offenders = []
    for pkg in ("experiment", "stimuli", "calibration", "analysis"):
        for path in (repo_root / pkg).rglob("*.py"):
            text = path.read_text(encoding="utf-8")
            for pattern, what in _DESIGN_LITERALS:
                for m in re.finditer(pattern, text):
                    line = text[: m.start()].count("\n") + 1
                    # Docstrings and comments may quote the source study's formulas.
                    src_line = text.splitlines()[line - 1].strip()
                    if src_line.startswith("#") or '"' in src_line or "'" in src_line:
                        continue
                    offenders.append(f"{path.relative_to(repo_root)}:{line}: {what}: {src_line}")
    assert not offenders, "design numbers copied outside the design object:\n" + "\n".join(offenders)


def test_shipped_design_file_is_in_the_installed_package():
    # The design ships as package data: an installed copy must find it.
    assert shutil.os.path.isfile(load_design().source)
