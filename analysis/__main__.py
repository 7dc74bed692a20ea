"""``python -m analysis``: turn session data into results."""

from __future__ import annotations

import argparse
import sys

import pandas as pd

from studydesign import DesignError, load_design


def _cmd_units(args) -> int:
    from analysis.units import matches_to_physical

    try:
        frame = matches_to_physical(pd.read_csv(args.csv), load_design(args.design))
    except (ValueError, DesignError, FileNotFoundError) as exc:
        print(f"error: {args.csv}: {exc}", file=sys.stderr)
        return 1
    frame.to_csv(sys.stdout, index=False)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m analysis", description="Analyse session data.")
    parser.add_argument("--design", help="a design.toml (default: the shipped one)")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("units", help="add physical units (%%, cm) to a session CSV's matches")
    p.add_argument("csv", help="a session CSV")
    p.set_defaults(func=_cmd_units)
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
