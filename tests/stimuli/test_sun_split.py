"""A probe's brightest region split off as a light of its own: the same expected image."""

from __future__ import annotations

import numpy as np
import pytest

from stimuli import camera_geometry, draw_array, load_light_probe, stimulus_seed
from stimuli.noise import compare_renders
from stimuli.render import StimulusRenderer
from stimuli.sunsplit import split_brightest_region


def test_the_split_parts_add_up_to_the_probe_and_the_sun_is_small(design):
    """rest + sun is the probe texel for texel (the envmap's bilinear radiance is linear in
    them); the region holds the brightest texel, is small, and carries the outdoor sun's power
    share above its share of texels."""
    lf = design.imagestats.light_field("immenstadter_horn")
    probe = load_light_probe(lf.envmap, scale=lf.scale)
    parts = split_brightest_region(probe.rgb)
    np.testing.assert_array_equal(parts.rest + parts.sun, probe.rgb)
    lum = probe.luminance
    peak = np.unravel_index(np.argmax(lum), lum.shape)
    assert parts.sun[peak].max() > 0 and parts.rest[peak].max() == 0
    assert 1 <= parts.n_texels <= 0.002 * lum.size
    assert parts.share > 100 * parts.n_texels / lum.size


@pytest.mark.slow
@pytest.mark.parametrize("light_field", ["immenstadter_horn", "aerodynamics_workshop"])
def test_split_sun_renders_match_the_unsplit_reference(design, mitsuba_variant, light_field):
    """32 px, the sharpest gloss (alpha 0.02), deepest array: 8 renders at 64 spp with the sun
    split off against 8 renders at 256 spp of the unsplit map, compared pixel block by pixel
    block (2 x 2) in Monte-Carlo standard errors (stimuli.noise.compare_renders)."""
    from calibration import default_calibration

    cam = camera_geometry(design, default_calibration(design))
    depth = design.depth.rendered_levels[-1]
    geometry = draw_array(design, float(design.depth.cm(depth)), stimulus_seed(depth))
    lf = design.imagestats.light_field(light_field)
    probe = load_light_probe(lf.envmap, scale=lf.scale)
    plain = StimulusRenderer(cam, size_px=32, spp=64)
    split = StimulusRenderer(cam, size_px=32, spp=64, split_sun=True)
    plain.load(geometry, probe)
    split.load(geometry, probe)
    material = (0.3, 0.1, 0.02)
    reference = np.stack([plain.render(*material, seed=1000 + i, spp=256) for i in range(8)])
    images = np.stack([split.render(*material, seed=i) for i in range(8)])
    agree = compare_renders(images, reference, block_px=2)
    print(light_field, agree)
    assert agree.chi2_per_df < 1.6 and abs(agree.mean_z) < 4
    assert abs(agree.mean_rel_diff) < 0.02
