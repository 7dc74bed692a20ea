"""Variance where it matters: the Ward lobe's sampling and the environment emitter's sampling are
combined by multiple importance sampling (MIS), and MIS compensation leaves the image unchanged.

Mitsuba's ``direct`` integrator draws ``bsdf_samples`` directions from the BSDF (here: the Ward
plugin's ``sample``) and ``emitter_samples`` from the envmap's luminance distribution, and weights
them by the power heuristic using both pdfs (the plugin's ``pdf`` and the emitter's). Each
strategy alone is unbiased, so the three estimates agree in expectation only if the plugin's
``sample``, ``eval`` and ``pdf`` agree and the emitter's pdf is right; the MIS estimate has the
lower variance on a sharp glossy lobe under a small bright light. Renders are 16 px; blocks of
4 x 4 px compared in Monte-Carlo standard errors.
"""

from __future__ import annotations

import numpy as np
import pytest

from stimuli import camera_geometry, draw_array, setup_mitsuba, stimulus_seed
from stimuli.noise import compare_renders
from stimuli.render import StimulusRenderer

GLOSSY = (0.2, 0.3, 0.05)  # rho_d, rho_s, alpha: a sharp lobe


@pytest.fixture
def sun(sun_probe):
    """This module's probe: a bright, small sun (sharp highlights)."""
    return sun_probe(0.2, 60.0, 0.01)


def _stack(design, probe, integrator, seeds, spp=16, mis_compensation=None):
    from calibration import default_calibration

    if mis_compensation is not None:  # the renderer's emitter, with the option overridden
        emitter = probe.emitter()
        probe = type("P", (), {"emitter": lambda self: emitter | {"mis_compensation":
                                                                  mis_compensation},
                                "sha256": f"sun{mis_compensation}", "rotation_deg": 0.0,
                                "scale": 1.0})()
    r = StimulusRenderer(camera_geometry(design, default_calibration(design)), size_px=16,
                         spp=spp, integrator=integrator)
    r.load(draw_array(design, float(design.depth.cm(8)), stimulus_seed(8)), probe)
    return np.stack([r.render(*GLOSSY, seed=s) for s in seeds])


@pytest.fixture(autouse=True)
def _mono(mitsuba_variant):
    setup_mitsuba("llvm_ad_mono", smoke_test=False)
    yield
    setup_mitsuba(mitsuba_variant, smoke_test=False)


def test_bsdf_sampling_emitter_sampling_and_mis_agree(design, sun):
    # plain emitter sampling: compensated emitter sampling alone is biased by construction (it
    # never draws the dim texels; see the next test)
    def direct(emitter_samples, bsdf_samples, seeds):
        return _stack(design, sun, {"type": "direct", "emitter_samples": emitter_samples,
                                    "bsdf_samples": bsdf_samples}, seeds,
                      mis_compensation=False)

    bsdf_only = direct(0, 4, range(24))
    emitter_only = direct(4, 0, range(100, 124))
    mis = direct(2, 2, range(200, 224))
    for name, other in (("bsdf only", bsdf_only), ("emitter only", emitter_only)):
        agree = compare_renders(mis, other)
        print(f"MIS vs {name}: chi2/df {agree.chi2_per_df:.2f}, max |z| {agree.max_abs_z:.2f}, "
              f"mean {100 * agree.mean_rel_diff:+.2f} %")
        assert agree.chi2_per_df < 2.5 and agree.max_abs_z < 5.0 and abs(agree.mean_z) < 4.0
    # equal sample counts (4 per pixel sample): MIS is less noisy than either strategy alone
    sd = {k: float(np.mean(v.std(axis=0, ddof=1))) for k, v in
          (("bsdf", bsdf_only), ("emitter", emitter_only), ("mis", mis))}
    print("per-pixel SD:", {k: round(v, 4) for k, v in sd.items()})
    assert sd["mis"] < min(sd["bsdf"], sd["emitter"])


def test_mis_compensation_is_unbiased_and_helps(design, sun):
    """Compensated emitter sampling is only unbiased inside MIS, which the path tracer uses."""
    path = {"type": "path", "max_depth": 3}
    on = _stack(design, sun, path, range(24), mis_compensation=True)
    off = _stack(design, sun, path, range(100, 124), mis_compensation=False)
    agree = compare_renders(on, off)
    print(f"MIS compensation on vs off: chi2/df {agree.chi2_per_df:.2f}, "
          f"mean {100 * agree.mean_rel_diff:+.2f} %; per-pixel SD on "
          f"{np.mean(on.std(axis=0, ddof=1)):.4f}, off {np.mean(off.std(axis=0, ddof=1)):.4f}")
    assert agree.chi2_per_df < 2.5 and abs(agree.mean_z) < 4.0
    alone = _stack(design, sun, {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0},
                   range(8), mis_compensation=True)
    assert alone.mean() < 0.8 * off.mean()  # the test can tell a biased strategy
    assert np.mean(on.std(axis=0, ddof=1)) < np.mean(off.std(axis=0, ddof=1))
