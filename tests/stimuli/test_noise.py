"""Displayed error (Monte-Carlo noise after the tone map) and the spp per gloss level."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from stimuli import camera_geometry, load_manifest, setup_mitsuba, tone_curve
from stimuli.__main__ import main
from stimuli.noise import displayed_error, plan_spp, spp_for_displayed_error


def test_displayed_error_recovers_known_noise(design, rng):
    """Gaussian noise of SD s on the linear part of the tone curve shows as s * slope / 255."""
    curve = tone_curve(design.tonemap, 10.0)
    truth = rng.uniform(1.0, 5.0, (64, 64))  # below the knee (6.7): v = 171 L / 6.7
    sd = 0.05
    stack = truth + rng.normal(0.0, sd, (6, 64, 64))
    expected = sd * design.tonemap.knee_value / (design.tonemap.linear_fraction * 10.0) / 255
    assert displayed_error(stack, curve) == pytest.approx(expected, rel=0.02)
    assert displayed_error(np.repeat(truth[None], 3, axis=0), curve) == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("bad", [np.zeros((1, 4, 4)), np.zeros((4, 4))])
def test_displayed_error_needs_two_renders(design, bad):
    with pytest.raises(ValueError, match="k >= 2"):
        displayed_error(bad, tone_curve(design.tonemap, 1.0))


def test_spp_for_displayed_error_follows_the_variance_law(mitsuba_variant):
    assert spp_for_displayed_error(0.02, 16, 0.01) == 64
    assert spp_for_displayed_error(0.005, 16, 0.01) == 4
    assert spp_for_displayed_error(0.0, 16, 0.01) == 1
    assert spp_for_displayed_error(0.011, 100, 0.01) == 121  # 11 x 11, a multijitter grid
    assert spp_for_displayed_error(0.0113, 100, 0.01) == 132  # 128 -> 11 x 12
    with pytest.raises(ValueError, match="target > 0"):
        spp_for_displayed_error(0.01, 16, 0.0)


@pytest.mark.slow
def test_plan_spp_meets_the_target_by_measurement(design, mitsuba_variant, sun_probe):
    """Real renders (24 px): each chosen count was rendered and met the target; a stricter
    target needs more samples; the glossiest level needs more than the matte one."""
    from calibration import default_calibration

    setup_mitsuba("llvm_ad_mono", smoke_test=False)
    cam = camera_geometry(design, default_calibration(design))
    kw = {"size_px": 24, "pilot_spp": 4, "repeats": 3, "probes": [sun_probe(0.3, 30.0, 0.02)],
          "gloss_levels": [1, 11], "max_spp": 200}
    loose = plan_spp(design, cam, target=0.03, **kw)
    strict = plan_spp(design, cam, target=0.015, **kw)
    setup_mitsuba(mitsuba_variant, smoke_test=False)
    print(loose, strict, sep="\n")
    for plan in (loose, strict):
        assert all(e <= plan.target for e in plan.error_at_spp)
        assert plan.gloss_levels == (1, 11) and plan.variant == "llvm_ad_mono"
        # one light field: its own counts are the design-wide ones, each measured at its count
        assert plan.spp_by_light_field == (plan.spp,) and len(plan.light_fields) == 1
        assert all(e <= plan.target for e in plan.measured_by_light_field[0])
        assert f"{plan.light_fields[0]} = [{plan.spp[0]}, {plan.spp[1]}]" in plan.toml()
        assert "<= target" in plan.report() and "ABOVE" not in plan.report()
    assert all(s >= lo for s, lo in zip(strict.spp, loose.spp, strict=True))
    assert sum(strict.spp) > sum(loose.spp)
    assert strict.spp[1] > strict.spp[0]


def _design_text_without_light_field_spp() -> str:
    """The shipped design.toml with its [render.spp_by_light_field] table left out."""
    from studydesign import load_design

    text = Path(load_design().source).read_text()
    if "[render.spp_by_light_field]" in text:
        head, tail = text.split("[render.spp_by_light_field]", 1)
        text = head + tail[tail.index("\n[gap]"):]
    return text


def test_render_takes_each_gloss_levels_spp(tmp_path, capsys, mitsuba_variant):
    """Without --spp the design's spp per gloss level are used and recorded per image."""
    text = _design_text_without_light_field_spp()
    line = next(ln for ln in text.splitlines() if ln.startswith("spp_by_gloss_level"))
    design_path = tmp_path / "design.toml"
    design_path.write_text(text.replace(line, "spp_by_gloss_level = [1, 2, 4, 4, 4, 4, 4, 4, 4, 4, 9]"))
    out = tmp_path / "r"
    rc = main(["--design", str(design_path), "render", "--set", "preview", "--filter",
               "illumination=indoor", "--filter", "depth_level=2", "--out", str(out),
               "--workers", "0", "--size", "16", "--no-progress"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    assert "px and this run is 16 px" in captured.err
    m = load_manifest(out).set_index("gloss_level")
    assert json.loads(captured.out)["rendered"] == 2
    assert m.loc[2, "spp"] == 2 and m.loc[10, "spp"] == 4


def test_render_takes_each_light_fields_own_spp(tmp_path, capsys, mitsuba_variant):
    """A light field listed in [render.spp_by_light_field] renders at its own counts (recorded
    per image in the manifest); the experiment's illumination takes the counts of the light
    field with its file and scale; one not listed keeps the design-wide counts."""
    from studydesign import load_design

    text = _design_text_without_light_field_spp()
    line = next(ln for ln in text.splitlines() if ln.startswith("spp_by_gloss_level"))
    design_path = tmp_path / "design.toml"
    design_path.write_text(text.replace(line, "spp_by_gloss_level = [4, 4, 4, 4, 4, 4, 4, 4, 4, "
                                              "4, 4]").replace(
        "\n[gap]", "\n[render.spp_by_light_field]\naerodynamics_workshop = "
        "[1, 1, 1, 1, 1, 1, 1, 1, 1, 2, 9]\n\n[gap]", 1))
    design = load_design(design_path)
    assert design.spp(11, "aerodynamics_workshop") == 9 and design.spp(11, "indoor") == 9
    assert design.spp(11, "outdoor") == 4 and design.spp(10, "noon_grass") == 4
    out = tmp_path / "r"
    rc = main(["--design", str(design_path), "render", "--set", "preview", "--filter",
               "depth_level=2", "--out", str(out), "--workers", "0", "--size", "16",
               "--no-progress"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    m = load_manifest(out).set_index(["illumination", "gloss_level"])
    assert m.loc[("indoor", 2), "spp"] == 1 and m.loc[("indoor", 10), "spp"] == 2
    assert m.loc[("outdoor", 2), "spp"] == 4 and m.loc[("outdoor", 10), "spp"] == 4


def test_spp_by_light_field_names_a_known_light_field(tmp_path):
    from studydesign import DesignError, load_design

    text = _design_text_without_light_field_spp()
    path = tmp_path / "design.toml"
    path.write_text(text.replace("\n[gap]", "\n[render.spp_by_light_field]\nnowhere = "
                                 "[1, 1, 1, 1, 1, 1, 1, 1, 1, 2, 9]\n\n[gap]", 1))
    with pytest.raises(DesignError, match="nowhere.*no light field"):
        load_design(path)
    path.write_text(text.replace("\n[gap]", "\n[render.spp_by_light_field]\nlebombo = "
                                 "[1, 2]\n\n[gap]", 1))
    with pytest.raises(DesignError, match="one whole number >= 1 per gloss level"):
        load_design(path)


def test_plan_spp_plans_each_light_field_apart(capsys, mitsuba_variant):
    """plan-spp --light-fields: one set of counts per named light field with the predicted and
    measured displayed error of each, per light field in the report, and the TOML table; the
    design-wide count of a level is the largest over them (16 px, a loose target)."""
    rc = main(["plan-spp", "--size", "16", "--repeats", "2", "--pilot-spp", "4", "--max-spp",
               "64", "--target-pct", "3", "--light-fields", "noon_grass", "lebombo"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    out = json.loads(captured.out)
    own = out["spp_by_light_field"]
    assert set(own) == {"noon_grass", "lebombo"}
    assert out["spp"] == [max(a, b) for a, b in zip(own["noon_grass"], own["lebombo"],
                                                    strict=True)]
    assert set(out["measured_error_pct"]) == set(out["predicted_error_pct"]) == set(own)
    assert "[render.spp_by_light_field]" in captured.err
    assert "\nnoon_grass " in captured.err and "\nlebombo " in captured.err
    assert captured.err.count(" largest ") == 2
