"""Freezing the render (``dr.freeze``, the GPU's default) gives the images of the traced render."""

from __future__ import annotations

import numpy as np

from stimuli import camera_geometry, draw_array, load_light_probe, stimulus_seed
from stimuli.render import StimulusRenderer


def test_a_frozen_render_equals_the_traced_one(design, mitsuba_variant):
    """Same scene, materials, seeds and sample counts, rendered frozen and traced (16 px): the
    images agree to float rounding, also after the Ward parameters and the sample count change between
    renders (a recording that missed the parameter update would repeat the first image)."""
    from calibration import default_calibration

    cam = camera_geometry(design, default_calibration(design))
    depth = design.depth.rendered_levels[-1]
    geometry = draw_array(design, float(design.depth.cm(depth)), stimulus_seed(depth))
    probe = load_light_probe(design.illuminations[1].envmap, scale=design.illuminations[1].scale)
    traced = StimulusRenderer(cam, size_px=16, spp=4, freeze=False)
    frozen = StimulusRenderer(cam, size_px=16, spp=4, freeze=True)
    traced.load(geometry, probe)
    frozen.load(geometry, probe)
    runs = [((0.3, 0.1, 0.02), 1, 4), ((0.3, 0.0, 0.3), 2, 4), ((0.3, 0.05, 0.08), 3, 9),
            ((0.3, 0.1, 0.02), 4, 4)]
    images = []
    for material, seed, spp in runs:
        a = traced.render(*material, seed=seed, spp=spp)
        b = frozen.render(*material, seed=seed, spp=spp)
        np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-7)  # float rounding: the seed is
        # a kernel input when frozen, a literal when traced
        images.append(b)
    assert not np.array_equal(images[0], images[1])  # the update reached the frozen render
    assert set(frozen._frozen) == {4, 9}  # one recording per sample count
