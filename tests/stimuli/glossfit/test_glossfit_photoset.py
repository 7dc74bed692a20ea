"""The photo-set format: loading, and a clear error or warning for each kind of bad input."""

from __future__ import annotations

import numpy as np
import pytest

from stimuli.glossfit import GlossFitError, PhotoSetup, load_photo_set, load_setup
from stimuli.glossfit.exr import read_exr, write_exr
from stimuli.glossfit.photoset import write_setup

SETUP = PhotoSetup(camera_distance_cm=27.5, sphere_radius_cm=2.0, fov_deg=20.0,
                   resolution_px=(40, 32))


def make_set(folder, levels=(0, 50, 100), photo=None, envmap=None):
    (folder / "photos").mkdir(parents=True)
    write_setup(folder / "setup.toml", SETUP)
    write_exr(folder / "envmap.exr", np.ones((8, 16, 3)) if envmap is None else envmap)
    rng = np.random.default_rng(0)
    for pct in levels:
        img = rng.uniform(0.1, 1.0, (32, 40, 3)) if photo is None else photo
        write_exr(folder / "photos" / f"gloss_{pct:03d}.exr", img)
    return folder


def test_exr_round_trip(tmp_path):
    img = np.random.default_rng(0).uniform(0, 5, (5, 7, 3)).astype(np.float32)
    write_exr(tmp_path / "a.exr", img)
    np.testing.assert_array_equal(read_exr(tmp_path / "a.exr"), img)


def test_setup_round_trip(tmp_path):
    write_setup(tmp_path / "setup.toml", SETUP)
    assert load_setup(tmp_path / "setup.toml") == SETUP


def test_loads_and_reports_missing_levels(tmp_path, design):
    ps = load_photo_set(make_set(tmp_path / "s"), design.gloss.physical_pct)
    assert sorted(ps.photos) == [0.0, 50.0, 100.0]
    assert 10.0 in ps.missing_pct and len(ps.missing_pct) == 8
    assert any("missing gloss levels" in w for w in ps.warnings)


@pytest.mark.parametrize("edit, match", [
    (lambda f: (f / "setup.toml").unlink(), "setup.toml not found"),
    (lambda f: (f / "envmap.exr").unlink(), "envmap.exr not found"),
    (lambda f: (f / "setup.toml").write_text("fov_deg = 20\ncamera_distance_cm = 27.5\n"
                                              "sphere_radius_cm = 2\nresolution_px = [40, 32]\n"
                                              "fov = 3\n"), "unknown keys"),
    (lambda f: (f / "setup.toml").write_text("fov_deg = 20\n"), "missing keys"),
    (lambda f: (f / "setup.toml").write_text("fov_deg = 20\ncamera_distance_cm = 1\n"
                                              "sphere_radius_cm = 2\nresolution_px = [40, 32]\n"),
     "not beyond the sphere"),
    (lambda f: write_exr(f / "photos" / "gloss_050.exr", np.ones((30, 40, 3))),
     "photos and setup must match"),
    (lambda f: write_exr(f / "photos" / "gloss_050.exr",
                         np.where(np.arange(40) == 3, np.nan, 1.0)[None, :, None]
                         * np.ones((32, 40, 3))), "NaN or infinite"),
    (lambda f: write_exr(f / "photos" / "gloss_050.exr", -np.ones((32, 40, 3))), "negative"),
    (lambda f: write_exr(f / "photos" / "gloss_055.exr", np.ones((32, 40, 3))),
     "name no gloss level"),
    (lambda f: write_exr(f / "envmap.exr", np.ones((8, 8, 3))), "twice as wide"),
    (lambda f: write_exr(f / "photos" / "gloss_050.exr",
                         np.minimum(np.random.default_rng(1).uniform(0, 2, (32, 40, 3)), 1.0)),
     "clipped"),
    (lambda f: [p.unlink() for p in (f / "photos").glob("*.exr")], "holds no photos"),
])
def test_bad_input_is_a_clear_error(tmp_path, design, edit, match):
    folder = make_set(tmp_path / "s")
    edit(folder)
    with pytest.raises(GlossFitError, match=match):
        load_photo_set(folder, design.gloss.physical_pct)


def test_few_clipped_pixels_are_a_warning_and_left_out(tmp_path, design):
    photo = np.random.default_rng(2).uniform(0.1, 1.0, (32, 40, 3))
    photo[3:5, 3:5] = 7.0  # a 2 x 2 plateau: the camera saturated there
    ps = load_photo_set(make_set(tmp_path / "s", photo=photo), design.gloss.physical_pct)
    assert ps.clipped[50.0].sum() == 4
    assert ps.clipped_fraction(50.0) == pytest.approx(4 / (32 * 40))
    assert any("clipped" in w for w in ps.warnings)


def test_saturation_level_from_setup(tmp_path, design):
    folder = make_set(tmp_path / "s")
    text = (folder / "setup.toml").read_text() + "saturation_level = 0.9\n"
    (folder / "setup.toml").write_text(text)
    with pytest.raises(GlossFitError, match="clipped"):
        load_photo_set(folder, design.gloss.physical_pct)
