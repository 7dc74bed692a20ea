"""``python -m stimuli``: render and manage stimulus sets."""

from __future__ import annotations

import argparse
import sys

from studydesign import load_design


def _cmd_list(args) -> int:
    from stimuli.sets import stimulus_set

    try:
        table = stimulus_set(load_design(args.design), args.set)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    table.to_csv(sys.stdout, index=False)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m stimuli", description="Render stimulus sets.")
    parser.add_argument("--design", help="a design.toml (default: the shipped one)")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("list", help="list the stimuli of a set as CSV")
    p.add_argument("--set", default="experiment", help="set name (default: experiment)")
    p.set_defaults(func=_cmd_list)
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
