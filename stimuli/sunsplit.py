"""A captured sun or lamp sampled as its own light: the brightest small region of a light probe
split from the environment map into an emitter of its own, the rest left in the map.

Exactness. Mitsuba's ``envmap`` evaluates the radiance of a direction by bilinear interpolation
of its texels, which is linear in the texel values: with ``sun`` the probe's texels inside the
region (zero elsewhere) and ``rest = probe - sun``, the two maps' radiances add up to the probe's
in every direction. The sun part is an :class:`SunPatchEmitter`: an ``envmap`` of ``sun`` alone
(not an environment of the scene, which holds one only), whose directions are drawn in
proportion to its own luminance (Mitsuba's warp of that map, no MIS compensation) and returned
as a light that BSDF-sampled rays never hit (``ds.delta``; its contribution comes only from
emitter sampling, with MIS weight 1, and escaped rays see ``rest``). Each part is then integrated
by an unbiased estimator of its own, so the sum is unbiased; ``tests/stimuli/test_sun_split.py``
checks it pixel by pixel against a high-spp render of the unsplit map, for an indoor and an
outdoor capture.

Variance. Emitter sampling picks the sun or the map with probabilities set by the emitters'
``sampling_weight`` (here the sun's share of the probe's power, at least ``min_sun_share``), and
the map's MIS compensation is then computed without the sun. It does NOT lower the displayed error
of these captures, so the renderer leaves it off (``split_sun=False``) and ``plan-spp`` plans
without it: ``bench/stimuli_sun_split.py --size 32`` (16 spp, 6 seeds, deepest array, load
average 18 on 2 cores) measured split / unsplit displayed error 1.11 and 1.08 on the outdoor
immenstadter_horn (sun share of the power 0.21) at gloss levels 6 and 11, 1.21 and 1.11 on the
indoor aerodynamics_workshop (brightest lamp 0.10); with the sun chosen by its power share alone
(``min_sun_share=0``) 1.01 and 1.09 at level 11. The envmap's own sampling (by luminance, MIS
compensation, combined with BSDF sampling by MIS) already draws the sun's texels; taking the sun
out of MIS (BSDF samples can no longer reach it) and choosing between two lights costs more than
the sky gains. Kept because it is exact and tested, for probes where a bench shows a gain.
"""

from __future__ import annotations

import numpy as np

__all__ = ["SunSplit", "register_sun_patch", "split_brightest_region", "split_emitters"]

_registered: set[str] = set()


class SunSplit:
    """The two parts of a probe and the sun's share of its power.

    Attributes
    ----------
    rest, sun : ndarray, shape (h, w) or (h, w, c)
        The probe's texels outside / inside the region (``rest + sun`` is the probe).
    share : float
        The sun's share of the probe's power (luminance x solid angle), in [0, 1].
    n_texels : int
        Texels in the region.
    """

    def __init__(self, rest, sun, share, n_texels):
        self.rest, self.sun, self.share, self.n_texels = rest, sun, float(share), int(n_texels)


def split_brightest_region(image, *, threshold: float = 0.02,
                           max_fraction: float = 0.002) -> SunSplit:
    """Split off the connected region around the brightest texel (the sun or the main lamp).

    Parameters
    ----------
    image : ndarray, shape (h, w) or (h, w, c)
        A lat-long probe (luminance, or RGB whose luminance is taken), h x 2h.
    threshold : float
        A texel belongs to the region when its luminance >= ``threshold`` x the maximum and it
        is connected (8-neighbours, across the 0/360 degree seam) to the brightest texel.
    max_fraction : float
        The region is grown no further than this fraction of the map's texels ("small").

    Returns
    -------
    SunSplit
    """
    from scipy import ndimage

    img = np.asarray(image, dtype=np.float32)
    if img.ndim == 3 and img.shape[2] == 1:
        lum = img[..., 0]
    else:
        lum = img if img.ndim == 2 else img @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    h, w = lum.shape
    peak = np.unravel_index(int(np.argmax(lum)), lum.shape)
    # the region on a map rolled so that the peak sits mid-width (no seam inside the region)
    shift = w // 2 - peak[1]
    rolled = np.roll(lum, shift, axis=1)
    labels, _ = ndimage.label(rolled >= threshold * lum[peak], structure=np.ones((3, 3)))
    region = labels == labels[peak[0], w // 2]
    limit = max(1, int(max_fraction * h * w))
    if region.sum() > limit:  # keep the brightest texels of the component
        cut = np.sort(rolled[region])[::-1][limit - 1]
        region &= rolled >= cut
    mask = np.roll(region, -shift, axis=1)
    weight = np.sin((np.arange(h) + 0.5) / h * np.pi)[:, None]  # solid angle per texel row
    share = float((lum * mask * weight).sum() / max((lum * weight).sum(), 1e-30))
    m = mask if img.ndim == 2 else mask[..., None]
    sun = np.where(m, img, 0.0).astype(np.float32)
    return SunSplit(rest=(img - sun).astype(np.float32), sun=sun, share=share,
                    n_texels=int(mask.sum()))


def _make_class():
    import mitsuba as mi

    class SunPatchEmitter(mi.Emitter):
        """A small part of a light probe as a light of its own (the module docstring).

        ========  =======  =======  =========================================================
        Property  Type     Default  Meaning
        ========  =======  =======  =========================================================
        bitmap    Bitmap   --       The part (lat-long, the probe's size; zero outside it).
        ========  =======  =======  =========================================================

        ``sampling_weight`` (Mitsuba's emitter property) sets how often it is chosen.
        """

        def __init__(self, props):
            mi.Emitter.__init__(self, props)
            self.inner = mi.load_dict({"type": "envmap", "bitmap": props["bitmap"],
                                       "mis_compensation": False})
            self.m_flags = mi.EmitterFlags.DeltaDirection | mi.EmitterFlags.Infinite

        def sample_direction(self, it, sample, active=True):
            ds, weight = self.inner.sample_direction(it, sample, active)
            far = 1e5  # cm: far beyond the scene, so the shadow ray tests every occluder
            ds.delta = mi.Bool(True)  # reached by emitter sampling only (MIS weight 1)
            ds.dist = mi.Float(far)
            ds.p = it.p + ds.d * far
            return ds, weight

        def pdf_direction(self, it, ds, active=True):
            return mi.Float(0.0)

        def eval_direction(self, it, ds, active=True):
            return self.inner.eval_direction(it, ds, active)

        def eval(self, si, active=True):
            return mi.Spectrum(0.0)  # never hit: escaped rays see the rest of the map

        def sample_ray(self, time, sample1, sample2, sample3, active=True):
            return self.inner.sample_ray(time, sample1, sample2, sample3, active)

        def to_string(self):
            return "SunPatchEmitter[]"

    return SunPatchEmitter


def register_sun_patch() -> None:
    """Register the ``sunpatch`` emitter for the current Mitsuba variant (idempotent)."""
    from stimuli.plugins import register_plugin

    register_plugin("emitter", "sunpatch", _make_class, _registered)


def split_emitters(probe, *, min_sun_share: float = 0.5, **region) -> dict:
    """The scene entries of a probe with its brightest region split off (needs a variant set).

    Parameters
    ----------
    probe : LightProbe
    min_sun_share : float
        Least probability of choosing the sun in emitter sampling (else its power share).
    **region
        ``threshold``, ``max_fraction`` of :func:`split_brightest_region`.

    Returns
    -------
    dict
        ``{"emitter": envmap of the rest (MIS compensation), "sun": sunpatch}``.
    """
    import mitsuba as mi

    from stimuli.mitsuba_env import is_monochrome

    register_sun_patch()
    image = probe.luminance[..., None] if is_monochrome(mi.variant()) else probe.rgb
    parts = split_brightest_region(image, **region)
    w_sun = float(np.clip(max(parts.share, min_sun_share), 0.0, 0.99))
    return {"emitter": {"type": "envmap", "bitmap": mi.Bitmap(np.ascontiguousarray(parts.rest)),
                        "mis_compensation": True, "sampling_weight": 1.0 - w_sun},
            "sun": {"type": "sunpatch", "bitmap": mi.Bitmap(np.ascontiguousarray(parts.sun)),
                    "sampling_weight": w_sun}}
