"""GPU: the preview set rendered under ``cuda_ad_mono`` equals the ``llvm_ad_mono`` renders within
Monte-Carlo error (same renderer, same Ward plugin, another back end).

Marked ``gpu``. Where Dr.Jit finds no CUDA GPU the test is skipped with a reason that starts with
"NOT RUN", which ``-ra`` lists, and the session ends with a banner saying the GPU check did not
run (tests/stimuli/conftest.py): never a silent pass. Run it on a GPU machine with
``pytest -m gpu tests/stimuli``.
"""

from __future__ import annotations

import numpy as np
import pytest

from stimuli import (
    camera_geometry,
    default_gloss_table,
    draw_array,
    load_light_probe,
    setup_mitsuba,
    stimulus_set,
    ward_params_for_gloss,
)
from stimuli.mitsuba_env import cuda_available
from stimuli.noise import compare_renders
from stimuli.render import StimulusRenderer

SIZE_PX, SPP, SEEDS = 32, 16, 8


def _preview_renders(variant, design, seeds):
    from calibration import default_calibration

    setup_mitsuba(variant)
    cam = camera_geometry(design, default_calibration(design))
    table = stimulus_set(design, "preview")
    rho_d, rho_s, alpha = ward_params_for_gloss(default_gloss_table(),
                                                table["true_gloss_pct"].to_numpy())
    out = {}
    renderer = StimulusRenderer(cam, size_px=SIZE_PX, spp=SPP)
    for i, row in enumerate(table.itertuples(index=False)):
        renderer.load(draw_array(design, row.true_depth_cm, int(row.seed)),
                      load_light_probe(row.envmap, rotation_deg=row.rotation_deg))
        out[row.stimulus_id] = np.stack([renderer.render(rho_d[i], rho_s[i], alpha[i], seed=s)
                                         for s in seeds])
    return out


@pytest.mark.gpu
def test_cuda_preview_matches_llvm_within_mc_error(design, mitsuba_variant):
    if not cuda_available():
        pytest.skip("NOT RUN: no CUDA GPU found by Dr.Jit; this test compares cuda_ad_mono with "
                    "llvm_ad_mono on the preview set; run `pytest -m gpu tests/stimuli` on a GPU "
                    "machine")
    try:
        cuda = _preview_renders("cuda_ad_mono", design, range(SEEDS))
        llvm = _preview_renders("llvm_ad_mono", design, range(100, 100 + SEEDS))
    finally:
        setup_mitsuba(mitsuba_variant, smoke_test=False)
    assert cuda.keys() == llvm.keys() and len(cuda) == 8
    for sid in cuda:
        agree = compare_renders(cuda[sid], llvm[sid])
        print(f"{sid}: chi2/df {agree.chi2_per_df:.2f}, max |z| {agree.max_abs_z:.2f}, "
              f"mean {100 * agree.mean_rel_diff:+.2f} %")
        assert agree.chi2_per_df < 2.5 and agree.max_abs_z < 5.5 and abs(agree.mean_z) < 4.0, sid
