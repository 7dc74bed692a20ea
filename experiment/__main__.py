"""``python -m experiment``: the session app's command line."""

from __future__ import annotations

import argparse
import sys

from studydesign import DesignError, load_design


def _cmd_plan(args) -> int:
    from experiment.plan import PlanError, load_or_create_plan, plan_path

    design = load_design(args.design)
    try:
        plan = load_or_create_plan(design, args.participant, args.data_dir)
    except (PlanError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    counts = plan.groupby("session").size().to_dict()
    print(f"plan: {plan_path(args.data_dir, args.participant)} (seed {plan['seed'].iloc[0]}, "
          f"trials per session {counts})")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiment", description="The gloss x depth session app.")
    parser.add_argument("--design", help="a design.toml (default: the shipped one)")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("plan", help="make (or show) a participant's trial plan")
    p.add_argument("--participant", required=True, help="participant id, e.g. P01")
    p.add_argument("--data-dir", default="data", help="data folder (default: data)")
    p.set_defaults(func=_cmd_plan)
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except DesignError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
