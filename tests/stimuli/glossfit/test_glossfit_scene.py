"""The gloss fit's sphere scene: the camera's sub-pixel image shift."""

from __future__ import annotations

import numpy as np
import pytest

from stimuli.glossfit import Camera, SphereScene


def _dark_centroid(shift_px):
    """Centroid (x, y, px) of a black sphere's silhouette in a uniform white panorama."""
    cam = Camera(20.0, (48, 40), 27.5, 2.0, shift_px=shift_px)
    env = np.ones((16, 32, 3), np.float32)
    with SphereScene(env, cam, spp=64, seed=3,
                     bsdf=lambda *_a: {"type": "diffuse",
                                       "reflectance": {"type": "rgb", "value": 0.0}}) as scene:
        dark = 1.0 - scene.render(0, 0, 0)[..., 1]
    yy, xx = np.mgrid[0:dark.shape[0], 0:dark.shape[1]]
    return np.array([(dark * xx).sum(), (dark * yy).sum()]) / dark.sum()


@pytest.mark.parametrize("shift", [(0.5, 0.0), (0.0, -0.25), (0.3, 0.7)])
def test_camera_shift_moves_the_image_content_by_that_many_pixels(shift):
    moved = _dark_centroid(shift) - _dark_centroid((0.0, 0.0))
    assert moved == pytest.approx(shift, abs=0.01)


@pytest.mark.parametrize("shift", [(0.5,), (np.nan, 0.0), (0.0, np.inf)])
def test_camera_refuses_a_shift_that_is_not_two_finite_numbers(shift):
    with pytest.raises(ValueError, match="shift_px"):
        Camera(20.0, (48, 40), 27.5, 2.0, shift_px=shift)
