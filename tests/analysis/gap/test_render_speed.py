"""The render layer's fast paths give the answers of the slow ones (issue 38: the held-out-light
diagnosis of the ball took 25 min and 11.8 GB): the glare blurs by FFT with a remembered kernel
spectrum equal ndimage's Gaussian and scipy's power-law convolution; an amplitude's SSE from one
Gram matrix equals the SSE of the extended render at every amplitude, and a term that is not
affine in its amplitude falls back to rendering; bootstrap resamples too many to hold are
drawn in blocks, the same at every use.

The images are built here (a numpy sphere), not rendered."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage, signal

from analysis.gap.engine import stats
from analysis.gap.render.candidates import _affine_sse
from analysis.gap.render.data import RenderData, make_level
from analysis.gap.render.model import _glare_kernel, _scaled_sse


@pytest.mark.parametrize("shape", [(40, 40), (36, 50)])
@pytest.mark.parametrize("width_frac", [0.125, 0.5, -0.03])
def test_glare_blur_by_fft_is_the_direct_kernel(shape, width_frac):
    img = np.random.default_rng(1).random(shape)
    width = width_frac * shape[1]
    if width > 0:
        ref = ndimage.gaussian_filter(img, width, mode="constant")
    else:
        yy, xx = np.mgrid[-shape[0]:shape[0] + 1, -shape[1]:shape[1] + 1]
        kern = (1 + (yy**2 + xx**2) / width**2) ** -1.5
        ref = signal.fftconvolve(img, kern / kern.sum(), mode="same")
    assert np.abs(_glare_kernel(img, width) - ref).max() < 1e-12 * np.abs(ref).max()


def _sphere(size: int = 40, seed: int = 0) -> RenderData:
    """One level of a Lambert + lobe sphere with glare and noise in the photo."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:size, 0:size].astype(float)
    r = np.hypot(yy - (size - 1) / 2, xx - (size - 1) / 2) / (0.4 * size)
    sphere = r < 1
    diffuse = np.where(sphere, 0.5 * np.sqrt(np.clip(1 - r**2, 0, 1)), 0.0)
    spec = np.where(sphere, 0.3 * np.exp(-((yy - 0.4 * size) ** 2 + (xx - 0.45 * size) ** 2)
                                         / 8), 0.0)
    photo = 1.05 * diffuse + spec + 0.05 * ndimage.gaussian_filter(diffuse + spec, 6)
    photo += 0.003 * rng.standard_normal(photo.shape)
    inner = r < 0.9
    a = {"photo": photo, "highlight": inner & (spec > 0.1), "body": inner & (spec <= 0.1),
         "rim": sphere & ~inner, "background": ~sphere, "sphere": inner}
    b = {"render": diffuse + spec, "diffuse": diffuse, "specular": spec}
    return RenderData([make_level("gloss_050", a, b, coat_lights=False)]).view("train")


@pytest.mark.parametrize("name,key,form,hi", [("veiling_glare", "sigma_frac", -0.03, 1.0),
                                              ("veiling_glare", "sigma_frac", 0.25, 1.0),
                                              ("clearcoat", "entry", "view", 1.0),
                                              ("fresnel", "kappa", 0.15, 50.0)])
def test_amplitude_sse_from_one_gram_matrix_is_the_rendered_sse(name, key, form, hi):
    train = _sphere()
    base = [("vignetting", {"c": 0.1, "c2": 0.0})]  # a later term, linear: still affine

    def params(c):
        return {key: form, "c": c}
    fast = _affine_sse(train, base, name, params, 0.0, hi)
    assert fast is not None
    for c in (0.0, 0.013 * hi, 0.4 * hi, hi):
        slow = _scaled_sse(train, base + [(name, params(c))])[0]
        assert fast(c) == pytest.approx(slow, rel=1e-9, abs=1e-12)


def test_a_term_not_affine_in_its_amplitude_is_rendered_at_each_amplitude():
    """A long tail's power form (the lobe raised to 0.5, rescaled to its energy) applies after
    the Fresnel term and bends its line: the Gram shortcut is refused, and the fit renders each
    amplitude (the same answer as without the shortcut)."""
    from analysis.gap.engine import candidate

    train = _sphere()
    tail = [("long_tail", {"c": {"gloss_050": 0.5}, "width": {"gloss_050": 0.5}})]
    assert _affine_sse(train, tail, "fresnel", lambda c: {"kappa": 0.0, "c": c}, 0.0,
                       50.0) is None
    q = candidate("render", "fresnel").fit(train, tail)
    sse = _scaled_sse(train, tail + [("fresnel", q)])[0]
    for c in (0.0, q["c"] * 1.1 + 0.01):
        assert sse <= _scaled_sse(train, tail + [("fresnel", q | {"c": c})])[0] + 1e-12


def test_resamples_too_many_to_hold_are_the_same_at_every_use(monkeypatch):
    monkeypatch.setattr(stats, "MAX_STORED_INDICES", 4000)
    rng = np.random.default_rng(3)
    x = rng.standard_normal(500)
    idx = stats.boot_idx(rng, 500, 300)
    assert isinstance(idx, stats.Resamples) and idx.shape == (300, 500)
    a, b = stats.boot_means(x, idx), stats.boot_means(x, idx)
    assert np.array_equal(a, b)  # paired: every test sees the same resamples
    both = stats.boot_means(np.stack([x, 2 * x]), idx)
    assert np.array_equal(both[0], a) and np.allclose(both[1], 2 * a)
    # A bootstrap of the mean: centred on it, spread as its standard error.
    assert abs(a.mean() - x.mean()) < 0.3 * x.std() / np.sqrt(500)
    assert a.std() == pytest.approx(x.std() / np.sqrt(500), rel=0.2)
    small = stats.boot_idx(np.random.default_rng(3), 10, 20)
    assert isinstance(small, np.ndarray) and small.shape == (20, 10)


def test_a_remembered_blur_holds_only_its_own_pixels():
    """The FFT's result is cropped from an array 9 times its size: the cache must hold a copy,
    not a view that keeps the whole alive (2.5 GB at 24 lights of 158 px)."""
    from analysis.gap.render.model import _glare_blur

    out = _glare_blur(np.random.default_rng(2).random((30, 30)), -1.0)
    assert out.base is None and out.shape == (30, 30) and not out.flags.writeable
