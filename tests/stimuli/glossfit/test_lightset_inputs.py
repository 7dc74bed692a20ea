"""Directional-light photo sets an operator got wrong (issue 40, item 10): a frame with y
flipped (in the lights or the normals), photos clipped below the 16-bit top code, 8-bit photos
mixed into a 16-bit set, and another sphere's fit diagnosing these photos. Each is refused with
the file, the value and the fix, or (the clip) censored with a warning kept in fit.json.

The sets are synthetic Ward spheres (stimuli.glossfit.lightsynth, 24 px, 8 lights)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from analysis.gap.__main__ import main as gap_main
from stimuli.glossfit.cli import main as glossfit_main
from stimuli.glossfit.lightset import load_light_set, read_png16
from stimuli.glossfit.lightsynth import _write_png16, synth_light_set
from stimuli.glossfit.photoset import GlossFitError


@pytest.fixture(scope="module")
def clean_set(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lights") / "set"
    synth_light_set(folder, size=24, n_lights=8, material="ward", seed=3, spp=4)
    return folder


@pytest.fixture
def ball(clean_set, tmp_path):
    return shutil.copytree(clean_set, tmp_path / "ball")


def _fit_refused(ball, tmp_path, capsys, *words) -> str:
    out = tmp_path / "fit"
    rc = glossfit_main(["fit-gloss", str(ball), "--lights", "1-4", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc != 0 and not (out / "fit.json").exists(), err
    line = err.strip().splitlines()[-1]
    assert line.startswith("error: ")
    for w in words:
        assert w in line, line
    return line


def test_light_directions_with_y_flipped_are_refused(ball, tmp_path, capsys):
    dirs = np.loadtxt(ball / "light_directions.txt")
    np.savetxt(ball / "light_directions.txt", dirs * [1, -1, 1], fmt="%.6f")
    _fit_refused(ball, tmp_path, capsys, "light_directions.txt", "with the lights' y negated",
                 "Negate that column")


def test_normals_with_y_flipped_are_refused(ball, tmp_path, capsys):
    normals = np.load(ball / "normal_gt.npy")
    np.save(ball / "normal_gt.npy", normals * np.array([1, -1, 1], np.float32))
    _fit_refused(ball, tmp_path, capsys, "normal_gt.npy", "y flipped",
                 "Negate the normals' y")


def test_photos_clipped_below_the_top_code_are_censored_and_said(ball):
    codes, top = read_png16(ball / "images" / "002.png")
    clip = 0.5 * codes.max()
    _write_png16(ball / "images" / "002.png", np.minimum(codes, clip))
    n_clipped = int(np.any(np.round(np.minimum(codes, clip)) >= round(clip), axis=-1).sum())
    ls = load_light_set(ball, "1-3")
    assert ls.saturated[2].sum() == n_clipped > 4
    said = [w for w in ls.warnings if w.startswith("002.png")]
    assert said and f"below the file's top ({top})" in said[0] and "censored" in said[0]
    assert not any(w.startswith(("001.png", "003.png")) for w in ls.warnings)


def test_an_8_bit_photo_in_a_16_bit_set_is_refused_naming_it(ball):
    from stimuli.glossfit.mitsuba_setup import mitsuba

    mi = mitsuba()
    codes, _ = read_png16(ball / "images" / "006.png")
    img8 = np.ascontiguousarray(np.clip(np.round(codes / 257), 0, 255).astype(np.uint8))
    (ball / "images" / "006.png").unlink()
    mi.Bitmap(img8, mi.Bitmap.PixelFormat.RGB).write(str(ball / "images" / "006.png"))
    # Refused when the fit's lights are loaded too: held-out photos must be on their scale.
    with pytest.raises(GlossFitError, match=r"images \['006.png'\] are \[8\]-bit PNGs, the "
                                            r"set's other 7 are 16-bit"):
        load_light_set(ball, "1-4")


def test_another_spheres_fit_is_refused_for_these_photos(clean_set, tmp_path, capsys):
    other = tmp_path / "other"
    synth_light_set(other, size=28, n_lights=8, material="ward", seed=4, spp=4)
    assert glossfit_main(["fit-gloss", str(other), "--lights", "1-4", "--out",
                          str(tmp_path / "fit")]) == 0
    capsys.readouterr()
    out = tmp_path / "gap"
    rc = gap_main(["diagnose", "--layer", "render", "--real", str(clean_set), "--lights", "5-8",
                   "--sim", str(tmp_path / "fit"), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and not (out / "diagnosis.json").exists(), err
    assert "a fit of another sphere cannot predict these photos" in err
    assert "radius 11.2 px" in err and "radius 9.6 px" in err


def test_the_clean_set_fits_without_a_word(clean_set, tmp_path):
    assert glossfit_main(["fit-gloss", str(clean_set), "--lights", "1-4", "--out",
                          str(tmp_path / "fit")]) == 0
    info = json.loads((tmp_path / "fit" / "fit.json").read_text())
    assert info["warnings"] == [] and info["misfit_pct_fit"] < 20


def test_an_over_exposed_set_is_refused_naming_the_saturation(ball, tmp_path, capsys):
    """8x the exposure (issue 44, item 8): 70-92 % of the sphere at 65535; the fit gave Ward
    parameters with only "alpha at the search bound". Now refused before any render."""
    for png in sorted((ball / "images").glob("*.png")):
        codes, _ = read_png16(png)
        _write_png16(png, np.minimum(codes * 8, 65535))
    line = _fit_refused(ball, tmp_path, capsys, "over-exposed", "of the sphere is saturated",
                        "shorter exposure")
    assert "lights 1-4" in line


def test_a_photo_with_much_of_the_sphere_saturated_is_warned(ball):
    from stimuli.glossfit.lightset import refuse_over_exposed

    codes, _ = read_png16(ball / "images" / "002.png")
    _write_png16(ball / "images" / "002.png", np.minimum(codes * 8, 65535))
    said = refuse_over_exposed(load_light_set(ball, "1-4"))  # one photo of four: warned
    assert len(said) == 1 and said[0].startswith("002.png: ") and "saturated" in said[0]
    assert refuse_over_exposed(load_light_set(ball, "3-6")) == []
