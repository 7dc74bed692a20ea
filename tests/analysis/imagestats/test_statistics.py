"""The statistics of one image: closed forms, the stimulus region, PS, and bad values."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.imagestats import (
    PIXEL_STATS,
    StatsConfig,
    measure_image,
    pixel_statistics,
    ps_names,
    ps_statistics,
    stimulus_region,
)
from tests.analysis.imagestats.renders import BORDER, EXTENT_CM, expected_stats, two_level_image


@pytest.mark.parametrize("p", [0.05, 0.2, 0.45])
def test_two_level_image_has_the_bernoulli_moments(p, rng):
    """Closed forms of the scaled Bernoulli distribution (renders.py's docstring)."""
    n = 100 * 100
    lum = np.full(n, 1.5)
    lum[rng.permutation(n)[: round(p * n)]] = 6.0
    got = pixel_statistics(lum.reshape(100, 100), highlight_factor=2.0)
    assert list(got) == list(PIXEL_STATS)
    for name, value in expected_stats(p, 1.5, 6.0).items():
        assert got[name] == pytest.approx(value, rel=1e-9), name


def test_uniform_distribution_moments():
    """A uniform ramp: skewness 0, Pearson kurtosis 9/5 (as N grows), RMS contrast 1/sqrt(3)."""
    lum = np.linspace(0.0, 2.0, 200_001)
    got = pixel_statistics(lum, highlight_factor=1.5)
    assert got["skewness"] == pytest.approx(0.0, abs=1e-9)
    assert got["kurtosis"] == pytest.approx(1.8, rel=1e-4)
    assert got["rms_contrast"] == pytest.approx(1 / np.sqrt(3), rel=1e-4)
    # above 1.5 x median (1.0): L in (1.5, 2], a quarter of the range
    assert got["highlight_coverage"] == pytest.approx(0.25, abs=1e-4)


def test_statistics_but_the_mean_ignore_the_luminance_unit(rng):
    lum = rng.gamma(2.0, 1.0, size=(64, 64))
    a = pixel_statistics(lum, highlight_factor=2.0)
    b = pixel_statistics(lum * 683.0, highlight_factor=2.0)
    assert b["mean_luminance"] == pytest.approx(683 * a["mean_luminance"])
    for name in ("rms_contrast", "skewness", "kurtosis", "highlight_coverage"):
        assert b[name] == pytest.approx(a[name], rel=1e-9)


@pytest.mark.parametrize("values, match", [
    (np.array([1.0, np.nan, 2.0]), "NaN or Inf"),
    (np.array([1.0, np.inf, 2.0]), "NaN or Inf"),
    (np.array([1.0, -0.5, 2.0]), "negative luminance"),
    (np.zeros(10), "black"),
    (np.full(10, 3.0), "uniform"),
    (np.array([]), "no pixels"),
])
def test_bad_values_are_named(values, match):
    with pytest.raises(ValueError, match=match):
        pixel_statistics(values, highlight_factor=2.0)


def test_stimulus_region_is_the_centred_array_square():
    rows, cols = stimulus_region(160, 144, image_width_cm=6.25, extent_cm=5.0)
    assert (rows.start, rows.stop, cols.start, cols.stop) == (8, 136, 16, 144)
    with pytest.raises(ValueError, match="does not fit"):
        stimulus_region(160, 100, image_width_cm=6.25, extent_cm=5.0)
    with pytest.raises(ValueError, match="positive"):
        stimulus_region(160, 144, image_width_cm=0.0, extent_cm=5.0)


def test_shipped_design_array_extent_matches_the_test_renders(design):
    assert design.array.extent_cm == EXTENT_CM


def test_measure_image_uses_only_the_region(rng):
    """The border (BORDER everywhere outside the square) must not enter any statistic."""
    p = 1600 / 128**2  # a whole number of bright pixels
    img = two_level_image(rng, side_px=128, width_px=160, height_px=144, p=p, low=1.0,
                          high=5.0)
    got = measure_image(img, image_width_cm=6.25, extent_cm=5.0, config=StatsConfig())
    assert got["region_px"] == 128 and got["texture_window_px"] == 128
    for name, value in expected_stats(p, 1.0, 5.0).items():
        assert got[name] == pytest.approx(value, rel=1e-6), name
    assert BORDER > 5.0
    # PS pixel statistics of the same square: mean and the corrected (n - 1) variance
    square = img[8:136, 16:144].astype(np.float64)
    assert got["ps_pixel_statistics_0"] == pytest.approx(square.mean(), rel=1e-5)
    assert got["ps_pixel_statistics_1"] == pytest.approx(square.var(ddof=1), rel=1e-4)


def test_ps_vector_is_named_and_sized_by_the_pyramid(rng):
    names = ps_names(128)
    assert len(names) == len(set(names)) == 710
    assert names[0] == "ps_pixel_statistics_0" and names[-1] == "ps_var_highpass_residual_0"
    values = ps_statistics(rng.random((128, 128)))
    assert values.shape == (710,) and np.isfinite(values).all()
    assert len(ps_names(64, n_scales=3)) == ps_statistics(rng.random((64, 64)),
                                                         n_scales=3).size
    with pytest.raises(ValueError, match="square"):
        ps_statistics(rng.random((128, 64)))
    with pytest.raises(ValueError, match="Portilla-Simoncelli on 64 px"):
        ps_statistics(rng.random((64, 64)))


def test_config_is_checked_and_round_trips():
    cfg = StatsConfig(highlight_factor=3.0, ps=False)
    assert StatsConfig.from_json(cfg.to_json()) == cfg
    with pytest.raises(ValueError, match="highlight_factor"):
        StatsConfig(highlight_factor=0.5)
    with pytest.raises(ValueError, match="ps_n_scales"):
        StatsConfig(ps_n_scales=0)
