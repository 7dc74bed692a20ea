"""Light probes: OpenEXR decoding, checks with clear errors, rotation, normalisation, envmap."""

from __future__ import annotations

import numpy as np
import pytest

from stimuli import load_light_probe
from stimuli.errors import IlluminationError
from stimuli.illumination import (
    luminance,
    read_exr,
    rotate_latlong,
    solid_angle_weights,
    write_exr,
)


@pytest.mark.parametrize("name", ["interior.exr", "courtyard.exr"])
def test_design_probes_ship_with_the_package(design, name):
    assert name in {il.envmap for il in design.illuminations}
    probe = load_light_probe(name)
    h, w, c = probe.rgb.shape
    assert (w, c) == (2 * h, 3) and probe.rgb.dtype == np.float32
    mean = np.sum(probe.luminance * solid_angle_weights(h, w)) / (4 * np.pi)
    assert mean == pytest.approx(1.0, rel=1e-4)
    assert len(probe.sha256) == 64


def test_exr_round_trip_is_lossless(tmp_path, rng):
    img = rng.random((16, 32, 3)).astype(np.float32) * 100
    write_exr(tmp_path / "a.exr", img)
    assert np.array_equal(read_exr(tmp_path / "a.exr"), img)
    grey = img[..., 0]
    write_exr(tmp_path / "y.exr", grey)
    assert np.array_equal(read_exr(tmp_path / "y.exr"), grey)
    assert [p.name for p in tmp_path.iterdir()] != [] and not list(tmp_path.glob(".*tmp*"))


def test_luminance_is_cie_y_of_rec709():
    assert luminance(np.array([1.0, 1.0, 1.0])) == pytest.approx(1.0)
    assert luminance(np.array([0.0, 1.0, 0.0])) == pytest.approx(0.7152)


def test_rotation_by_whole_and_fractional_pixels(rng):
    img = rng.random((4, 8, 3)).astype(np.float32)
    assert np.array_equal(rotate_latlong(img, 45.0), np.roll(img, 1, axis=1))
    assert np.array_equal(rotate_latlong(img, 360.0), img)
    half = rotate_latlong(img, 22.5)
    np.testing.assert_allclose(half, 0.5 * (img + np.roll(img, 1, axis=1)), rtol=1e-6)


def test_rotation_and_scale_options(tmp_path):
    img = np.ones((8, 16, 3), np.float32)
    img[:, 0] = 10.0
    write_exr(tmp_path / "p.exr", img)
    raw = load_light_probe(tmp_path / "p.exr", normalise="none")
    assert raw.scale == 1.0 and np.array_equal(raw.rgb, img)
    rot = load_light_probe(tmp_path / "p.exr", normalise="none", rotation_deg=90.0)
    assert np.all(rot.rgb[:, 4] == 10.0)
    bright = load_light_probe(tmp_path / "p.exr", target=5.0)
    mean = np.sum(bright.luminance * solid_angle_weights(8, 16)) / (4 * np.pi)
    assert mean == pytest.approx(5.0, rel=1e-5)


def _bad_files(tmp_path):
    good = np.ones((8, 16, 3), np.float32)
    nan = good.copy()
    nan[2, 3, 1] = np.nan
    inf = good.copy()
    inf[0, 0, 0] = np.inf
    neg = good.copy()
    neg[1, 1, 2] = -1
    for name, arr in (("nan", nan), ("inf", inf), ("neg", neg), ("square", good[:, :8])):
        write_exr(tmp_path / f"{name}.exr", arr)
    write_exr(tmp_path / "ok.exr", good)
    data = (tmp_path / "ok.exr").read_bytes()
    (tmp_path / "truncated.exr").write_bytes(data[: len(data) // 2])
    (tmp_path / "text.exr").write_text("not an exr")
    return {
        "missing.exr": "not found",
        "nan.exr": "NaN/Inf",
        "inf.exr": "NaN/Inf",
        "neg.exr": "negative",
        "square.exr": "twice as wide",
        "truncated.exr": "corrupt",
        "text.exr": "not an OpenEXR",
    }


def test_bad_probes_raise_clear_errors(tmp_path):
    for name, match in _bad_files(tmp_path).items():
        with pytest.raises(IlluminationError, match=match) as info:
            load_light_probe(tmp_path / name)
        assert name in str(info.value)


def test_envmap_emitter_lights_a_scene(mitsuba_variant):
    import mitsuba as mi

    probe = load_light_probe("interior.exr")
    env = mi.load_dict(probe.emitter())
    assert "EnvironmentMapEmitter" in str(env) or "envmap" in str(env).lower()
