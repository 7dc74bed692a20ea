"""``python -m analysis.gap benchmark|diagnose``."""

from __future__ import annotations

import argparse
import sys

from analysis.gap.engine import GapError
from studydesign import load_design


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m analysis.gap")
    sub = ap.add_subparsers(dest="cmd", required=True)
    b = sub.add_parser("benchmark", help="blind benchmark with injected effects")
    b.add_argument("--layer", choices=["observer", "display", "render", "all"], default="all")
    b.add_argument("--trials", type=int, default=20)
    b.add_argument("--seed", type=int, default=0)
    d = sub.add_parser("diagnose", help="diagnose real data against the simulation")
    d.add_argument("--layer", choices=["observer", "display", "render"], required=True)
    d.add_argument("--real", required=True)
    d.add_argument("--sim", required=True)
    d.add_argument("--out", required=True)
    d.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    design = load_design()
    try:
        if args.cmd == "benchmark":
            if args.layer in ("display", "render"):
                raise GapError(f"layer {args.layer!r} is not built yet; use --layer observer")
            from analysis.gap.benchmark import run_observer_benchmark
            r = run_observer_benchmark(design, trials=args.trials, seed=args.seed)
            print(f"observer: top-1 {r['top1']:.3f} (n={r['n_in']}), false attributions "
                  f"{r['false_attribution']:.3f} (n={r['n_none']}), unexplained for "
                  f"out-of-catalogue {r['unexplained_out']:.3f} (n={r['n_out']}), median shrinkage error "
                  f"{100 * r['shrink_error']:.1f} % of the gap (90th percentile "
                  f"{100 * r['shrink_error_p90']:.1f} %), seed {args.seed}")
            if args.layer == "all":
                print("display, render: not built yet")
            return 0
        if args.layer != "observer":
            raise GapError(f"layer {args.layer!r} is not built yet; use --layer observer")
        from analysis.gap.diagnose import diagnose_observer_files
        from analysis.gap.report import write_report
        diag, local = diagnose_observer_files(args.real, args.sim, design, seed=args.seed)
        path = write_report(diag, local, args.out)
        print(f"verdict: {diag.verdict}; gap {diag.gap_before:.4f} -> {diag.gap_after:.4f} "
              f"({diag.shrink_pct:.1f} %); report {path}")
        return 0
    except GapError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
