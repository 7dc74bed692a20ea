"""Mitsuba for the gloss fit: the LLVM RGB variant with the Ward plugin registered.

The fit compares luminance of grey materials, which RGB renders exactly; on the synthetic Ward
photos the spectral variant recovered alpha 12 % low at 100 % gloss where RGB was within 3 %.
The stimulus renders keep their own variant: the fit switches to ``FIT_VARIANT`` while its scene
lives and switches back when it closes (stimuli.glossfit.scene.SphereScene).
"""

from __future__ import annotations

__all__ = ["FIT_VARIANT", "mitsuba", "use_fit_variant"]

FIT_VARIANT = "llvm_ad_rgb"


def mitsuba():
    """Check the Mitsuba set-up once (stimuli.setup_mitsuba: libLLVM, variants) and return it."""
    import mitsuba as mi

    from stimuli.mitsuba_env import setup_mitsuba

    if mi.variant() is None:
        setup_mitsuba(smoke_test=False)
    return mi


def use_fit_variant() -> str | None:
    """Switch to FIT_VARIANT (Ward registered); return the variant that was active before."""
    from stimuli.ward import register_ward

    mi = mitsuba()
    before = mi.variant()
    if before != FIT_VARIANT:
        mi.set_variant(FIT_VARIANT)
    register_ward()
    return before
