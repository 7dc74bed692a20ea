"""Light probes: OpenEXR and RGBE decoding, checks with clear errors, rotation, normalisation
(the diffuse white's luminance, checked against a Mitsuba render), the shipped light fields."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from stimuli import load_light_probe
from stimuli.errors import IlluminationError
from stimuli.illumination import (
    SHIPPED_PROBES,
    LightProbe,
    diffuse_white_luminance,
    diffuse_white_scale,
    downsample_latlong,
    luminance,
    probe_path,
    read_exr,
    read_probe_image,
    rotate_latlong,
    solid_angle_weights,
    write_exr,
)
from stimuli.manifest import sha256_file
from stimuli.rgbe import read_rgbe, write_rgbe


def test_design_probes_ship_with_the_package(design):
    for il in design.illuminations:
        probe = load_light_probe(il.envmap, scale=il.scale)
        h, w, c = probe.rgb.shape
        assert (w, c) == (2 * h, 3) and probe.rgb.dtype == np.float32
        assert diffuse_white_luminance(probe.rgb) == pytest.approx(1.0, rel=1e-4)
        assert len(probe.sha256) == 64
    mean = load_light_probe(design.illuminations[0].envmap)  # default: mean luminance 1
    h, w = mean.luminance.shape
    assert np.sum(mean.luminance * solid_angle_weights(h, w)) / (4 * np.pi) == pytest.approx(
        1.0, rel=1e-4)


#: The old studio probes' clamp (Blender's studiolights, ``--clamp:max=32000``, stored through
#: DWAB, which moved the clamped values by up to ~12 %) and half float's largest value.
_CLAMPS = (32000.0, 65504.0)


def test_experiment_probes_are_unclipped_captures(design):
    """The brightest pixel of each condition's probe is not a clamp value, and the outdoor
    probe's sun is not cut off: a clipped sun (the old courtyard probe: 143 pixels at >= half
    its peak of 55, 1,025 x its median) is far dimmer than a real one (>= 1e4 x the median)."""
    manifest = pd.read_csv(SHIPPED_PROBES / "lightfields.tsv", sep="\t").set_index("file")
    for il in design.illuminations:
        raw = read_probe_image(probe_path(il.envmap))
        peak = float(raw.max())
        assert all(abs(peak / c - 1) > 0.15 for c in _CLAMPS), (il.envmap, peak)
        assert il.envmap in manifest.index  # a shipped capture, its origin recorded
        assert manifest.loc[il.envmap, "sha256"] == sha256_file(probe_path(il.envmap))
        y = luminance(raw)
        if il.kind == "outdoor":
            assert y.max() / np.median(y) > 1e4, il.envmap


def test_shipped_light_fields_match_their_manifest_and_design_scale(design):
    """Each light field's file is shipped, matches the checksum in lightfields.tsv, names its
    source's checksum and CC0 licence, and its design scale is the diffuse-white rule's."""
    manifest = pd.read_csv(SHIPPED_PROBES / "lightfields.tsv", sep="\t").set_index("file")
    assert len(manifest) == 22
    for lf in design.imagestats.light_fields:
        row = manifest.loc[lf.envmap]
        path = probe_path(lf.envmap)
        assert sha256_file(path) == row["sha256"] and len(row["source_sha256"]) == 64
        assert row["licence"].startswith("CC0") and row["kind"] == lf.kind
        assert diffuse_white_scale(read_probe_image(path)) == pytest.approx(lf.scale, rel=1e-5)
    assert sum(probe_path(f).stat().st_size for f in manifest.index) < 12e6


def test_rgbe_decodes_radiance_pixels_and_round_trips(tmp_path, rng):
    """Reference pixel from Radiance's definition (color.c): bytes (128, 64, 32, 129) are
    ((m + 0.5) 2^(129 - 136)) = (1.00390625, 0.50390625, 0.25390625); (0, 0, 0, 0) is black."""
    flat = tmp_path / "flat.hdr"  # width 4 < 8: stored flat, not run-length encoded
    flat.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 1 +X 4\n"
                     + bytes([128, 64, 32, 129] * 3 + [0, 0, 0, 0]))
    img = read_rgbe(flat)
    np.testing.assert_array_equal(img[0, 0], np.float32([1.00390625, 0.50390625, 0.25390625]))
    assert img.shape == (1, 4, 3) and np.all(img[0, 3] == 0)
    hdr = (rng.random((16, 32, 3)) ** 8 * 1e5).astype(np.float32)
    hdr[3, :20] = 7.0  # a run, written as one
    write_rgbe(tmp_path / "a.hdr", hdr)
    back = read_rgbe(tmp_path / "a.hdr")
    peak = hdr.max(axis=-1, keepdims=True)
    assert np.all(np.abs(back - hdr) <= peak / 128 + 1e-30)  # 8-bit mantissa of the shared peak
    assert (tmp_path / "a.hdr").stat().st_size < 4 * 16 * 32 + 100


def test_downsampling_keeps_the_power_of_every_region(rng):
    img = rng.random((16, 32, 3)).astype(np.float32)
    img[5, 7] = 1e4  # a sun
    small = downsample_latlong(img, 4)
    power = np.sum(luminance(img) * solid_angle_weights(16, 32))
    assert np.sum(luminance(small) * solid_angle_weights(4, 8)) == pytest.approx(power, rel=1e-5)
    assert diffuse_white_luminance(small) == pytest.approx(diffuse_white_luminance(img), rel=0.05)


def test_diffuse_white_scale_matches_a_rendered_matte_white(mitsuba_variant):
    """A Lambertian white square facing the camera (+z), under a probe with one bright patch in
    front of it and a brighter one behind it, renders at the luminance the scale promises (1):
    the patch behind does not count, so the envmap's orientation is the one assumed."""
    import mitsuba as mi

    h, w = 32, 64
    img = np.full((h, w, 3), 0.2, np.float32)
    img[8:14, 36:42] = 50.0   # in front (u ~ 0.6, 30-60 deg up): lights the square
    img[8:14, 2:8] = 500.0    # behind (u ~ 0.08): must not count
    scale = diffuse_white_scale(img)
    probe = LightProbe(name="t", path="", sha256="t", rgb=img * np.float32(scale),
                       rotation_deg=0.0, scale=scale)
    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "path", "max_depth": 2},
        "sensor": {"type": "perspective", "fov": 4,  # sees only the square
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 20], target=[0, 0, 0],
                                                              up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 8, "height": 8,
                            "pixel_format": "luminance"},
                   "sampler": {"type": "independent", "sample_count": 256}},
        "square": {"type": "rectangle", "bsdf": {"type": "diffuse", "reflectance": 1.0}},
        "env": probe.emitter()})
    value = float(np.mean(np.asarray(mi.render(scene, seed=1))))
    assert value == pytest.approx(1.0, rel=0.03)


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

    probe = load_light_probe("noon_grass_512x256.hdr")
    env = mi.load_dict(probe.emitter())
    assert "EnvironmentMapEmitter" in str(env) or "envmap" in str(env).lower()
