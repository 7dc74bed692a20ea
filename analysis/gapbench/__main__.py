"""``python -m analysis gapbench`` (also ``python -m analysis.gapbench``, and the older
``python -m analysis gap benchmark``): the blind benchmarks of the gap diagnosis, plain or
``--harder``, printing their scores beside the targets."""

from __future__ import annotations

import argparse
import sys

from analysis.gap import LAYERS, GapError
from studydesign import load_design


def _harder(args, design, layers) -> int:
    """The harder benchmark: the observer part (``analysis.gapbench.bench_observer``), the
    display part (``analysis.gapbench.bench_display``: ``run_display_cases``,
    ``score_display_cases``, ``format_display_scores``) and the
    render part (``analysis.gapbench.bench_render``). With several ``--seed`` values each layer's
    cases of every seed are scored together (one case more or less moves a rate over 6 cases
    by 0.17; pooled over seeds the rates carry their larger n)."""
    from analysis.gapbench import bench_observer

    log = None if args.quiet else print
    for layer in layers:
        if layer == "observer":
            records = [r for seed in args.seed for r in bench_observer.run_observer_cases(
                design, trials=args.trials, seed=seed, n_participants=args.participants,
                log=log)]
            print(bench_observer.format_harder(bench_observer.score_harder(records)),
                  flush=True)
        elif layer == "display":
            from analysis.gapbench import bench_display

            records = [r for seed in args.seed for r in bench_display.run_display_cases(
                design, trials=args.trials, seed=seed, log=log)]
            print(bench_display.format_display_scores(
                bench_display.score_display_cases(records)), flush=True)
        else:
            from analysis.gapbench import bench_render

            records = [r for seed in args.seed for r in bench_render.run_render_cases(
                design, trials=args.trials, seed=seed, log=log)]
            print(bench_render.format_render_scores(
                bench_render.score_render_cases(records)), flush=True)
    seeds = ", ".join(str(s) for s in args.seed)
    print(f"seed{'s' if len(args.seed) > 1 else ''} {seeds}"
          f"{' (cases pooled)' if len(args.seed) > 1 else ''}, {args.trials} cases per layer "
          f"and seed, {args.participants} observers per observer case (harder benchmark)")
    return 0


def _benchmark(args, design) -> int:
    from analysis.gapbench.benchmark import format_scores, run_benchmark, run_thresholds

    layers = LAYERS if args.layer == "all" else (args.layer,)
    if args.harder:
        return _harder(args, design, layers)
    if len(args.seed) > 1:
        raise GapError(f"--seed {' '.join(map(str, args.seed))}: the benchmark without "
                       "--harder takes one seed; run it once per seed, or pool seeds with "
                       "--harder")
    args.seed = args.seed[0]
    for layer in layers:
        log = None if args.quiet else print
        r = run_benchmark(design, layer, trials=args.trials, seed=args.seed, log=log)
        thr = (run_thresholds(design, layer, reps=args.threshold_reps, seed=args.seed + 1,
                              log=log) if args.threshold_reps > 0 else None)
        print(format_scores(layer, r, thr), flush=True)
    if args.layer == "all":
        from analysis.gapbench.benchmark import run_layer_benchmark

        lr = run_layer_benchmark(design, trials=args.trials, seed=args.seed + 2,
                                 log=None if args.quiet else print)
        print(f"all: carrying layer named correctly in {lr['layer_rate']:.3f} of {lr['n']} runs "
              "(one layer injected, the others clean)")
    print(f"seed {args.seed}, {args.trials} trials per layer")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m analysis gapbench``."""
    b = argparse.ArgumentParser(prog="python -m analysis gapbench",
                                description="blind benchmark with injected effects")
    b.add_argument("--layer", choices=[*LAYERS, "all"], default="all")
    b.add_argument("--trials", type=int, default=20, help="runs per layer")
    b.add_argument("--seed", type=int, nargs="+", default=[0],
                   help="the draws' seed; with --harder, several seeds pool their cases into "
                        "one score (e.g. --seed 1 2 3)")
    b.add_argument("--threshold-reps", type=int, default=0,
                   help="runs per effect and strength for the detection thresholds (0: skip)")
    b.add_argument("--quiet", action="store_true", help="print only the scores")
    b.add_argument("--harder", action="store_true",
                   help="the harder benchmark: human-like observers (in-catalogue effects always "
                        "present) with effects outside the catalogue on top, co-occurring "
                        "effects, generators written apart from the diagnosis's own injectors "
                        "(observers, display, an analytic render sphere), verdict agreement "
                        "across seeds; --trials cases")
    b.add_argument("--participants", type=int, default=4,
                   help="harder benchmark: observers per observer case (the seed study has 11 "
                        "participants x 162 trials)")
    return b


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    design = load_design()
    try:
        if args.trials < 1:
            raise GapError(f"--trials {args.trials}: use at least 1")
        if args.participants < 1:
            raise GapError(f"--participants {args.participants}: use at least 1")
        return _benchmark(args, design)
    except GapError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
