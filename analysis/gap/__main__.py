"""``python -m analysis.gap benchmark|diagnose`` (also ``python -m analysis gap ...``)."""

from __future__ import annotations

import argparse
import sys

from analysis.gap.engine import GapError
from studydesign import load_design

LAYERS = ("observer", "display", "render")


def _benchmark(args, design) -> int:
    from analysis.gap.benchmark import format_scores, run_benchmark, run_thresholds

    layers = LAYERS if args.layer == "all" else (args.layer,)
    for layer in layers:
        log = None if args.quiet else print
        r = run_benchmark(design, layer, trials=args.trials, seed=args.seed, log=log)
        thr = (run_thresholds(design, layer, reps=args.threshold_reps, seed=args.seed + 1,
                              log=log) if args.threshold_reps > 0 else None)
        print(format_scores(layer, r, thr), flush=True)
    if args.layer == "all":
        from analysis.gap.benchmark import run_layer_benchmark

        lr = run_layer_benchmark(design, trials=args.trials, seed=args.seed + 2,
                                 log=None if args.quiet else print)
        print(f"all: carrying layer named correctly in {lr['layer_rate']:.3f} of {lr['n']} runs "
              "(one layer injected, the others clean)")
    print(f"seed {args.seed}, {args.trials} trials per layer")
    return 0


def _diagnose(args, design) -> int:
    from analysis.gap.diagnose import diagnose_all_files, diagnose_files
    from analysis.gap.report import write_multi_report, write_report

    if args.layer == "all":
        from analysis.gap.layers import parse_layer_paths, which_layer

        results = diagnose_all_files(parse_layer_paths(args.real), parse_layer_paths(args.sim),
                                     design, seed=args.seed)
        which = which_layer({n: d for n, (d, _) in results.items()})
        path = write_multi_report(results, which, args.out)
        for name, (diag, _) in results.items():
            print(f"{name}: verdict {diag.verdict}; gap {diag.gap_before:.4f} -> "
                  f"{diag.gap_after:.4f} ({diag.shrink_pct:.1f} %){_no_gap_note(diag)}")
        print(f"{which['text']}\nreport {path}")
        return 0

    diag, local = diagnose_files(args.layer, args.real, args.sim, design, seed=args.seed)
    path = write_report(diag, local, args.out)
    print(f"{diag.layer}: verdict {diag.verdict}; gap {diag.gap_before:.4f} -> "
          f"{diag.gap_after:.4f} ({diag.shrink_pct:.1f} %){_no_gap_note(diag)}; report {path}")
    return 0


def _no_gap_note(diag) -> str:
    from analysis.gap.report import no_significant_gap

    if not no_significant_gap(diag):
        return ""
    lo, hi = diag.gap_before_ci
    return f" - no significant gap (95 % CI {lo:.3f} to {hi:.3f})"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m analysis.gap")
    sub = ap.add_subparsers(dest="cmd", required=True)
    b = sub.add_parser("benchmark", help="blind benchmark with injected effects")
    b.add_argument("--layer", choices=[*LAYERS, "all"], default="all")
    b.add_argument("--trials", type=int, default=20, help="runs per layer")
    b.add_argument("--seed", type=int, default=0)
    b.add_argument("--threshold-reps", type=int, default=0,
                   help="runs per effect and strength for the detection thresholds (0: skip)")
    b.add_argument("--quiet", action="store_true", help="print only the scores")
    d = sub.add_parser("diagnose", help="diagnose real data against the simulation")
    d.add_argument("--layer", choices=[*LAYERS, "all"], required=True)
    d.add_argument("--real", required=True,
                   help="observer: session CSV folder; display: readings.csv or its folder; "
                        "render: the gloss-fit output folder; all: LAYER=PATH,... ")
    d.add_argument("--sim", required=True,
                   help="observer: simulated session CSV folder; display: calibration.json or "
                        "its folder; render: the gloss-fit output folder; all: LAYER=PATH,...")
    d.add_argument("--out", required=True)
    d.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    design = load_design()
    try:
        if args.cmd == "benchmark":
            if args.trials < 1:
                raise GapError(f"--trials {args.trials}: use at least 1")
            return _benchmark(args, design)
        return _diagnose(args, design)
    except GapError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
