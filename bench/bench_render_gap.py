"""Claim (issue 38): the render layer's held-out-light diagnosis takes at most 3 x the wall time
of the gloss fit that precedes it on the same photos, with a peak memory under 2 GB.

Both measured in one run, each as the lab runs it (its own process, so that its peak RSS is its
own): ``python -m stimuli fit-gloss BALL --lights 1-24 --out FIT``, then ``python -m analysis
gap diagnose --layer render --real BALL --lights 25-48 --sim FIT --out REPORT`` (the report's
figures included). BALL is DiLiGenT's ball in ../shared (research-use data, read in place; with
``--box K`` a K x K box-averaged copy in a temporary folder, for a quick look: 3 gives the
52 px copy of issue 40). Printed: each step's wall and CPU time and peak RSS (``os.wait4``'s
rusage of the child), the ratio of the wall times, the verdict and the held-out misfit
(RMS, % of the photos' RMS luminance) before and after the chosen effects.

Usage: ``.venv/bin/python bench/bench_render_gap.py [--ball DIR] [--box K] [--keep DIR]``
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BALL = "data/external/spheres/diligent_ball_lights_01-48"
#: The claim: diagnosis wall time / fit wall time, and the diagnosis's peak memory.
MAX_RATIO, MAX_PEAK_GB = 3.0, 2.0


def shared_ball() -> Path:
    """The ball: under $GLOSSDEPTH_SHARED, else ../shared beside the checkout or beside the
    folder of worktrees."""
    roots = [Path(os.environ["GLOSSDEPTH_SHARED"])] if os.environ.get("GLOSSDEPTH_SHARED") else []
    roots += [ROOT.parent / "shared", ROOT.parent.parent / "shared"]
    return next((r / BALL for r in roots if (r / BALL).is_dir()), roots[0] / BALL)


def timed(cmd: list[str]) -> dict:
    """Run ``cmd`` (a child process) and return its wall time (s), CPU time (user + system,
    s), peak RSS (GB) and exit code."""
    env = dict(os.environ)
    env.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    return {"wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime,
            "peak_gb": usage.ru_maxrss / 1024**2, "rc": os.waitstatus_to_exitcode(status)}


def box_copy(ball: Path, out: Path, k: int) -> Path:
    """A k x k box-averaged copy of the photo set (photos, mask, normals) under ``out``."""
    sys.path.insert(0, str(ROOT))
    from stimuli.glossfit.lightsynth import box_averaged_copy

    return box_averaged_copy(ball, out, k)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ball", default=None, help="the photo set (default: the ball in ../shared)")
    ap.add_argument("--box", type=int, default=1, help="box-average K x K first (1: full size)")
    ap.add_argument("--fit-lights", default="1-24")
    ap.add_argument("--held-out", default="25-48")
    ap.add_argument("--keep", default=None, help="write FIT and REPORT here (a new folder)")
    args = ap.parse_args(argv)
    ball = Path(args.ball) if args.ball else shared_ball()
    if not ball.is_dir():
        print(f"NOT RUN: {ball} is absent (research-use data, kept in ../shared only; set "
              "GLOSSDEPTH_SHARED to the shared folder)")
        return 0
    with tempfile.TemporaryDirectory(prefix="bench-render-gap-") as tmp:
        work = Path(args.keep) if args.keep else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        if args.box > 1:
            ball = box_copy(ball, work / f"ball_box{args.box}", args.box)
        py = sys.executable
        fit = timed([py, "-m", "stimuli", "fit-gloss", str(ball), "--lights", args.fit_lights,
                     "--out", str(work / "fit")])
        if fit["rc"] != 0:
            print(f"fit failed (rc {fit['rc']})")
            return 1
        diag = timed([py, "-m", "analysis", "gap", "diagnose", "--layer", "render", "--real",
                      str(ball), "--lights", args.held_out, "--sim", str(work / "fit"),
                      "--out", str(work / "report")])
        d = {}
        if (work / "report" / "diagnosis.json").is_file():
            d = json.loads((work / "report" / "diagnosis.json").read_text())
        ratio = diag["wall_s"] / fit["wall_s"]
        print(f"ball {ball} (box {args.box}), fit lights {args.fit_lights}, held out "
              f"{args.held_out}")
        for name, r in (("fit", fit), ("diagnosis", diag)):
            print(f"{name:9s}: wall {r['wall_s']:7.1f} s, CPU {r['cpu_s']:7.1f} s, peak RSS "
                  f"{r['peak_gb']:.2f} GB, rc {r['rc']}")
        print(f"diagnosis / fit wall time: {ratio:.2f} (claim <= {MAX_RATIO:g}); CPU time "
              f"ratio {diag['cpu_s'] / fit['cpu_s']:.2f}; diagnosis peak "
              f"{diag['peak_gb']:.2f} GB (claim < {MAX_PEAK_GB:g})")
        if d:
            print(f"verdict {d['verdict']}; held-out misfit {d['misfit_pct_before']:.2f} % -> "
                  f"{d['misfit_pct_after']:.2f} % of the photos' RMS luminance; chosen: "
                  f"{', '.join(s['added'] for s in d['steps']) or 'nothing'}")
        else:
            print("no diagnosis.json written")
        ok = diag["rc"] == 0 and ratio <= MAX_RATIO and diag["peak_gb"] < MAX_PEAK_GB
        print("claim holds" if ok else "claim does NOT hold")
    return 0


if __name__ == "__main__":
    sys.exit(main())
