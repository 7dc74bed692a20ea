"""Claim: the project's Ward fit through its Mitsuba renders predicts a real sphere's photos under
held-out lights within 1.1x of a direct numpy Ward fit (issue 30), and its diagnosis's extended
model does better still.

Both sides in one run, on DiLiGenT's ball (lights 1-48 in ../shared; research-use data, read in
place): the independent numpy fit of ``bench/heldout_lights_reference.py`` (its own PNG decoder
and Ward) and ``python -m stimuli fit-gloss BALL --lights FIT`` followed by the fitted material
rendered under the held-out lights; with ``--diagnose`` also ``python -m analysis gap diagnose
--layer render --real BALL --lights HELD --sim FIT`` (minutes per split on a shared machine),
whose diagnosis.json gives ``misfit_pct_before`` / ``misfit_pct_after``. Figures: held-out RMS
misfit in % of the held-out photos' RMS luminance.

Usage: ``.venv/bin/python bench/heldout_lights_project.py [BALL_DIR] [--diagnose]``
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))
os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")

import heldout_lights_reference as ref

SPLITS = (("1-24", "25-48"), ("25-48", "1-24"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("ball", nargs="?", default=str(ref.BALL))
    ap.add_argument("--diagnose", action="store_true", help="also run the gap diagnosis")
    args = ap.parse_args()
    ball = Path(args.ball)
    if not ball.is_dir():
        print(f"NOT RUN: {ball} is absent (research-use data, kept in ../shared only)")
        return 0
    from analysis.gap import diagnose
    from stimuli.glossfit.lightfit import _misfit_pct, fit_lights, predict_lights

    data = ref.load(ball)
    with tempfile.TemporaryDirectory() as tmp:
        for fit_l, held in SPLITS:
            train = ref.samples(*data, ref.parse(fit_l))
            test = ref.samples(*data, ref.parse(held))
            numpy_pct, _, _ = ref.fit_score(train, test, lambda x: [(x[0], None)], [0.15],
                                            [(0.01, 0.6)])
            out = Path(tmp) / f"fit{fit_l}"
            info = fit_lights(ball, out, fit_l)
            pct = _misfit_pct(list(predict_lights(out, ball, held).values()))
            print(f"fit {fit_l} -> held out {held}: numpy Ward {numpy_pct:.2f} %, project Ward "
                  f"(Mitsuba renders) {pct:.2f} %, ratio {pct / numpy_pct:.3f} "
                  f"(alpha {info['ward']['alpha']:.4f}, {info['n_renders']} renders)")
            if args.diagnose:
                d, _ = diagnose("render", ball, out, None, seed=0, n_boot=300, lights=held)
                print(f"  diagnosis: {d.misfit_pct_before:.2f} % -> {d.misfit_pct_after:.2f} % "
                      f"with {' + '.join(s['added'] for s in d.steps) or 'nothing'} "
                      f"(verdict {d.verdict}); "
                      + json.dumps({s["added"]: {k: v for k, v in s["params"].items()
                                                 if k != "scale"} for s in d.steps}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
