"""Directional-light photo sets: the light list, 16-bit decoding, saturation, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from stimuli.glossfit.lightfit import _fit_pixels
from stimuli.glossfit.lightset import load_light_set, parse_lights, read_png16
from stimuli.glossfit.lightsynth import ring_lights, write_light_set
from stimuli.glossfit.photoset import GlossFitError


def test_parse_lights_ranges_and_errors():
    assert parse_lights("1-3,7,5-6") == (1, 2, 3, 5, 6, 7)
    assert parse_lights("25-48", 48)[0] == 25
    for bad, words in (("0-3", "counted from 1"), ("4-2", "counted from 1"),
                       ("1-49", "lights 1-48 only"), ("a", "--lights 1-24"), ("", "names no")):
        with pytest.raises(GlossFitError, match=words):
            parse_lights(bad, 48)


def _set(folder, n=3, size=24, top=65535.0):
    yy, xx = np.mgrid[0:size, 0:size] + 0.5
    mask = np.hypot(yy - size / 2, xx - size / 2) < 0.4 * size
    photos = []
    for k in range(n):
        img = np.full((size, size, 3), 1000.0 + 17 * k)
        img[size // 2, size // 2] = top  # one saturated pixel in the highlight
        img[size // 2, size // 2 + 1] = 300.7  # a value 8 bits cannot hold
        photos.append(np.where(mask[..., None], img, 0.0))
    return write_light_set(folder, photos, ring_lights(n), np.ones((n, 3)), mask)


def test_16_bit_kept_and_saturation_censored(tmp_path):
    folder = _set(tmp_path / "set")
    codes, top = read_png16(folder / "images" / "001.png")
    assert top == 65535 and codes.max() == 65535  # Pillow would give 255 here
    assert codes[12, 13, 0] == 301  # rounded, not quantised to 8 bits
    ls = load_light_set(folder, "1-2")
    assert ls.lights == (1, 2) and set(ls.photos) == {1, 2}
    assert ls.saturated[1][12, 12] and ls.saturated[1].sum() == 1
    assert not _fit_pixels(ls, 1, -1.0)[12, 12]  # censored, never fitted
    assert ls.normals_source.startswith("the mask")


def test_bad_sets_say_what_to_fix(tmp_path):
    folder = _set(tmp_path / "set")
    (folder / "light_intensities.txt").write_text("1 1 1\n1 1 1\n")
    with pytest.raises(GlossFitError, match="give one row of 3 per image"):
        load_light_set(folder)
    with pytest.raises(GlossFitError, match="not a folder"):
        load_light_set(tmp_path / "nowhere")
    with pytest.raises(FileExistsError, match="new folder"):
        _set(tmp_path / "set")
