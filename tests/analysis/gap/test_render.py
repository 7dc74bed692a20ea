"""Render-layer gap diagnosis on residual files in the gloss fit's format."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.gap import GapError, diagnose
from analysis.gap.__main__ import main
from analysis.gap.engine import catalogue, strengths
from analysis.gapbench import inject
from studydesign import load_design


def _diag(tmp_path, effect, seed, times=1.0):
    rng = np.random.default_rng(seed)
    inject.write_render_fit(tmp_path / "fit", rng, effect,
                            times * strengths("render").get(effect, 0))
    return diagnose("render", tmp_path / "fit", tmp_path / "fit", load_design(), seed=seed, n_boot=300)


#: Veiling glare at its default strength (0.15 of the light) leaves the plain render a misfit of
#: 0.99 % of the photos' RMS (bound 1.2 %), the tolerance itself: named as a gap only through
#: what the fit took up (test_glare_the_fitted_material_took_up_is_a_gap); twice that is named
#: on the plain misfit alone.
_TWICE = {"veiling_glare": 2.0}


@pytest.mark.parametrize("effect", [c.name for c in catalogue("render")])
def test_injected_render_effect_is_identified(tmp_path, effect):
    diag, local = _diag(tmp_path, effect, 5, _TWICE.get(effect, 1.0))
    assert diag.verdict.split(" + ")[0] == effect
    assert set(local["axis"]) == {"region"}
    assert any(c.endswith(": highlight") for c in local["cell"])
    # The residual maps shrink towards noise (1 SD) once the chosen extensions are added.
    for maps in local.attrs["maps"].values():
        before, after = np.nanmean(maps["before"] ** 2), np.nanmean(maps["after"] ** 2)
        assert after < before


@pytest.mark.parametrize("effect", ["none", "anisotropy", "albedo_texture"])
def test_render_nothing_or_out_of_catalogue_is_unexplained(tmp_path, effect):
    diag, _ = _diag(tmp_path, effect, 7)
    # Nothing injected: the data exclude a gap of the tolerance (the misfit's upper bound
    # lies below it), and the JSON's verdict says so as the words do.
    assert diag.verdict == ("no_gap_that_matters" if effect == "none" else "unexplained")


def test_a_named_effect_smaller_than_the_tolerance_is_no_gap_that_matters(tmp_path):
    """Veiling glare of 0.01 of the light: significant in nats and named (the photos are
    clean), but the plain render misses the photos by about 0.2 % of their RMS, its upper bound
    lies below the design's 1 %, and the fit took up less than that (0.85 %): no gap that
    matters, the effect named in the words. (Blind render seed 1002's plain Ward sphere read
    "broad_lobe" at 1.4 % raw misfit, 0.17 % net of noise, before the render layer held named
    effects to the tolerance.)"""
    diag, _ = _diag(tmp_path, "veiling_glare", 5, 1 / 15)
    assert [s["added"] for s in diag.steps][:1] == ["veiling_glare"]
    rem = diag.remaining
    assert rem["size_before"] < rem["size_before_upper"] < 1.0, rem
    assert rem["absorbed"] < 1.0, rem
    assert diag.verdict == "no_gap_that_matters"
    assert diag.misfit_upper == pytest.approx(rem["size_before_upper"])
    assert "veiling glare is statistically significant, but the plain simulation" in (
        diag.summary), diag.summary


def test_glare_the_fitted_material_took_up_is_a_gap(tmp_path):
    """Veiling glare of 0.05 of the light in every photo: the Ward fit to those photos takes
    most of it into its material, so the plain render predicts held-out photos within 0.4 %
    (bound 0.5 %), which read "no gap that matters"; but modelled, the material moves by about
    3.9 % of the photos' RMS, and the stimuli are rendered from that material: a gap, named
    (blind unseen render seeds 1002-1005 and 1009-1012: glare 1.2-3.9x the tolerance read "no
    gap that matters" 8/8)."""
    diag, _ = _diag(tmp_path, "veiling_glare", 5, 1 / 3)
    rem = diag.remaining
    assert rem["size_before_upper"] < 1.0 <= rem["absorbed"], rem
    assert diag.verdict == "veiling_glare", diag.summary
    assert diag.summary.startswith("A gap in the fitted model: the simulation's own fit "
                                   "took veiling glare up"), diag.summary
    assert "fit it again with it modelled" in diag.summary


def test_fresnel_amplitude_recovered(tmp_path):
    diag, _ = _diag(tmp_path, "fresnel", 9)
    # Injected F0 = 1 / (1 + 6): Schlick's grazing gain (1 - F0) / F0 = 6.
    assert diag.steps[0]["params"]["c"] == pytest.approx(6.0, rel=0.25)


def test_studio_clear_coat_is_explained_without_a_remaining_gap(tmp_path):
    """A clear coat under the studio's room (Mitsuba's plastic: a window, a lamp and a floor)
    is named alone with its strength, and leaves no gap beyond the catalogue: its entry
    factor comes from the room as the glossiest level's specular render mirrors it, seen by
    the fit's perspective camera (fit.json). Fitting the room as a surround plus a key light
    left 0.32 nats/px (CI 0.28-0.36), flagged, in the body of the 20 % level."""
    diag, _ = _diag(tmp_path, "clearcoat", 5)
    assert diag.verdict == "clearcoat"
    assert not diag.unexplained_remains
    assert diag.steps[0]["params"]["c"] == pytest.approx(strengths("render")["clearcoat"],
                                                         rel=0.15)


def test_noise_model_refuses_a_photo_without_noise():
    from analysis.gap.render import noise_model

    render = np.tile(np.linspace(0.1, 1.0, 32), (32, 1))
    with pytest.raises(GapError, match="no measurable noise"):
        noise_model(np.zeros_like(render), render, np.ones(render.shape, bool))


def test_render_bad_input(tmp_path):
    with pytest.raises(GapError, match="residuals"):
        diagnose("render", tmp_path, tmp_path, load_design(), seed=0)
    (tmp_path / "residuals").mkdir()
    np.savez(tmp_path / "residuals" / "gloss_010.npz", photo=np.zeros((8, 8, 3)))
    with pytest.raises(GapError, match="missing"):
        diagnose("render", tmp_path, tmp_path, load_design(), seed=0)


def test_cli_render_report(tmp_path):
    inject.write_render_fit(tmp_path / "fit", np.random.default_rng(1), "vignetting", 0.5)
    args = ["diagnose", "--layer", "render", "--real", str(tmp_path / "fit"), "--sim",
            str(tmp_path / "fit"), "--out", str(tmp_path / "rep")]
    assert main(args) == 0
    page = (tmp_path / "rep" / "index.html").read_text()
    assert "vignetting" in page
    # Where in image space: residual maps before and after the chosen extension.
    assert 'src="residual_maps.png"' in page and (tmp_path / "rep" / "residual_maps.png").is_file()


@pytest.mark.slow
def test_render_layer_reads_the_gloss_fit_output(tmp_path):
    """The gloss fit's own output folder (synthetic photos, Mitsuba fit) diagnoses end to end."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "DRJIT_LIBLLVM_PATH": os.environ.get(
        "DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")}
    for cmd in (["synth-photos", str(tmp_path / "photos"), "--levels", "20,60", "--seed", "1",
                 "--spp", "16"],
                ["fit-gloss", str(tmp_path / "photos"), "--out", str(tmp_path / "fit"),
                 "--spp", "16"]):
        subprocess.run([sys.executable, "-m", "stimuli", *cmd], check=True, env=env,
                       capture_output=True)
    diag, local = diagnose("render", tmp_path / "fit", tmp_path / "fit", load_design(), seed=0, n_boot=300)
    assert len(diag.heldout) > 500 and diag.gap_before > 0
    assert {c.split(": ")[0] for c in local["cell"]} == {"gloss_020", "gloss_060"}


@pytest.mark.parametrize("a2,b", [(1e-4, 0.0), (1e-6, 4e-4), (4e-6, 1e-4)])
def test_noise_model_recovers_read_and_shot_noise(a2, b):
    """Poisson-Gaussian noise (var = a2 + b render) on a smooth image with a bright blob, and a
    smooth misfit added (which the second differences must ignore)."""
    from analysis.gap.render import noise_model

    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[0:96, 0:96] / 95.0
    render = 0.2 + 0.6 * xx + 3.0 * np.exp(-((xx - 0.6) ** 2 + (yy - 0.4) ** 2) / 0.02)
    photo = render * (1.02 + 0.03 * yy) + np.sqrt(a2 + b * render) * rng.standard_normal(
        render.shape)
    got_a2, got_b = noise_model(photo - render, render, np.ones(render.shape, bool))
    # Compare the SD the model gives at a dark and a bright level.
    for level in (0.2, 3.0):
        assert np.sqrt(got_a2 + got_b * level) == pytest.approx(np.sqrt(a2 + b * level),
                                                                 rel=0.15)


def test_misregistration_model_explains_a_rendered_shift(tmp_path):
    """A photo rendered 0.5 px off (the camera's principal point moved) is explained almost
    wholly by the shift candidate: shifting the silhouette's pixel coverage as geometry, not
    interpolating the step, matters (interpolation alone left 8-13 % of this gap)."""
    rng = np.random.default_rng(1)
    inject.write_render_fit(tmp_path / "fit", rng, "misregistration", 0.5)
    diag, _ = diagnose("render", tmp_path / "fit", tmp_path / "fit", load_design(), seed=1, n_boot=300)
    assert diag.steps[0]["added"] == "misregistration"
    assert diag.explained_share >= 0.95
    for dy, dx in diag.steps[0]["params"]["shift_px"].values():
        assert np.hypot(dy, dx) == pytest.approx(0.5, abs=0.1)


@pytest.mark.slow
def test_an_effect_at_the_tolerance_is_inconclusive_with_the_plain_renders_power(tmp_path):
    """A highlight with longer tails than Ward's at 0.36 of its default strength: named, but the
    plain render misses the photos by about the tolerance itself (0.91 %, bound 1.1 %), and it
    is a material term (nothing a camera term made the fit take up): inconclusive, and how many
    more photos decide it is simulated for that misfit (the plain render's, which the verdict
    judged), not for the 0.26 % the chosen model leaves. (Veiling glare at its default strength
    read so before the render layer weighed what its fit took up; now a gap.)"""
    diag, _ = _diag(tmp_path, "long_tail", 5, 0.36)
    rem = diag.remaining
    assert [s["added"] for s in diag.steps] == ["long_tail"]
    assert rem["absorbed"] == 0.0
    assert diag.verdict == "inconclusive"
    assert rem["size_before"] < 1.0 < rem["size_before_upper"] and rem["size"] < 0.5, rem
    assert diag.to_decide["truth"] == pytest.approx(rem["size_before"])
    assert diag.detectable["value"] > rem["size"]
