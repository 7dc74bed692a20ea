"""GPU: the preview set rendered under ``cuda_ad_mono`` equals the ``llvm_ad_mono`` renders within
Monte-Carlo error (same renderer, same Ward plugin, another back end).

Marked ``gpu``. Where Dr.Jit finds no CUDA GPU the test is skipped with a reason that starts with
"NOT RUN", which ``-ra`` lists, and the session ends with a banner saying the GPU check did not
run (tests/stimuli/conftest.py): never a silent pass. Run it on a GPU machine with
``pytest -m gpu tests/stimuli``.

A GPU machine without libLLVM >= 17 (a CUDA image often has none) can compare with LLVM renders
made on a CPU machine by this same code: there, ``python tests/stimuli/test_gpu.py OUT.npz``
writes them; on the GPU machine ``GLOSSDEPTH_LLVM_REFERENCE=OUT.npz pytest -m gpu tests/stimuli``
reads them. The file records its size, spp, seeds and Mitsuba version, and the test refuses a file
whose settings differ from its own.
"""

from __future__ import annotations

import os
import sys

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
from stimuli.mitsuba_env import SUPPORTED_VARIANTS, cuda_available
from stimuli.noise import compare_renders
from stimuli.render import StimulusRenderer

SIZE_PX, SPP, SEEDS = 32, 16, 8
LLVM_SEEDS = range(100, 100 + SEEDS)
REFERENCE_ENV = "GLOSSDEPTH_LLVM_REFERENCE"


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


def _settings():
    import mitsuba as mi

    return {"size_px": SIZE_PX, "spp": SPP, "seeds": list(LLVM_SEEDS),
            "mitsuba": mi.__version__}


def write_llvm_reference(path, design):
    """Render the preview set under ``llvm_ad_mono`` and save it, with its settings, to ``path``."""
    renders = _preview_renders("llvm_ad_mono", design, LLVM_SEEDS)
    meta = _settings() | {"variant": "llvm_ad_mono"}
    np.savez_compressed(path, meta=np.array(repr(meta)), **renders)


def _llvm_renders(design):
    path = os.environ.get(REFERENCE_ENV)
    if not path:
        return _preview_renders("llvm_ad_mono", design, LLVM_SEEDS)
    import ast

    with np.load(path) as z:
        meta = ast.literal_eval(str(z["meta"]))
        renders = {k: z[k] for k in z.files if k != "meta"}
    wanted = _settings() | {"variant": "llvm_ad_mono"}
    if meta != wanted:
        pytest.fail(f"{REFERENCE_ENV}={path} was made with {meta}, this test renders with {wanted}; "
                    "write it again with `python tests/stimuli/test_gpu.py OUT.npz`")
    return renders


@pytest.mark.gpu
def test_cuda_preview_matches_llvm_within_mc_error(design):
    if not cuda_available():
        pytest.skip("NOT RUN: no CUDA GPU found by Dr.Jit; this test compares cuda_ad_mono with "
                    "llvm_ad_mono on the preview set; run `pytest -m gpu tests/stimuli` on a GPU "
                    "machine")
    import mitsuba as mi

    previous = mi.variant()  # put back what the session's other tests selected
    try:
        cuda = _preview_renders("cuda_ad_mono", design, range(SEEDS))
        llvm = _llvm_renders(design)
    finally:
        if previous in SUPPORTED_VARIANTS:
            setup_mitsuba(previous, smoke_test=False)
    assert cuda.keys() == llvm.keys() and len(cuda) == 8
    for sid in cuda:
        agree = compare_renders(cuda[sid], llvm[sid])
        print(f"{sid}: chi2/df {agree.chi2_per_df:.2f}, max |z| {agree.max_abs_z:.2f}, "
              f"mean {100 * agree.mean_rel_diff:+.2f} %")
        assert agree.chi2_per_df < 2.5 and agree.max_abs_z < 5.5 and abs(agree.mean_z) < 4.0, sid


if __name__ == "__main__":
    from studydesign import load_design

    os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")
    if len(sys.argv) != 2:
        sys.exit("usage: python tests/stimuli/test_gpu.py OUT.npz  (LLVM reference renders)")
    write_llvm_reference(sys.argv[1], load_design())
    print(f"wrote {sys.argv[1]}")
