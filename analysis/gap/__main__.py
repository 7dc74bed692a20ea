"""``python -m analysis.gap diagnose`` (also ``python -m analysis gap diagnose``).

The blind benchmarks moved to :mod:`analysis.gapbench` (``python -m analysis gapbench``;
``python -m analysis gap benchmark`` forwards there); ``benchmark`` here only says so.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from analysis.gap.engine import LAYER_NAMES, GapError
from labfiles.outdir import OutDirError, prepare_out_dir, write_error_line
from studydesign import load_design

LAYERS = LAYER_NAMES
#: What ``python -m analysis.gap benchmark`` answers: the benchmarks are a package of their own,
#: which this one (the diagnosis) never imports.
MOVED = ("the blind benchmarks moved to the package analysis.gapbench: run `python -m analysis "
         "gapbench ARGS` (or `python -m analysis.gapbench ARGS`; `python -m analysis gap "
         "benchmark ARGS` forwards there)")


def _diagnose(args, design) -> int:
    from analysis.gap.diagnose import diagnose
    from analysis.gap.report import write_multi_report, write_report

    opts = {"sim_kind": args.sim_kind} if args.sim_kind else {}
    if args.study or args.participants:
        if args.layer != "observer":
            raise GapError("--study and --participants are for --layer observer (another "
                           "lab's rating study)")
        opts |= {"study": args.study, "participants": args.participants}
    if args.lights:
        if args.layer != "render":
            raise GapError("--lights holds out photos of a directional-light set, or a "
                           "lighting of a panorama set: use it with --layer render")
        opts["lights"] = args.lights
    if args.layer == "all":
        from analysis.gap.layers import parse_layer_paths, which_layer

        results = diagnose("all", parse_layer_paths(args.real), parse_layer_paths(args.sim),
                           design, seed=args.seed, **opts)
        which = which_layer({n: d for n, (d, _) in results.items()})
        notes: list[str] = []
        path = write_multi_report(results, which, args.out, notes=notes)
        for name, (diag, _) in results.items():
            _print(diag, name)
        _print_notes(notes)
        print(f"{which['text']}\nreport {path}")
        return 0

    diag, local = diagnose(args.layer, args.real, args.sim, design, seed=args.seed, **opts)
    notes: list[str] = []
    path = write_report(diag, local, args.out, notes=notes)
    _print(diag, diag.layer)
    _print_notes(notes)
    print(f"report {path}")
    return 0


def _print_notes(notes: list[str]) -> None:
    """The report's figures that failed to draw (the verdict and diagnosis.json are written)."""
    for line in notes:
        print(f"warning: {line}", file=sys.stderr)


def _print(diag, name: str) -> None:
    for w in diag.warnings:
        print(f"warning ({name}): {w}", file=sys.stderr)
    from analysis.gap.engine import NOT_A_GAP
    from analysis.gap.report import misfit_words, power_words

    verdict = (diag.verdict.replace("_", " ") if diag.verdict in NOT_A_GAP
               else f"gap: {diag.verdict}")
    more = power_words(diag)
    verdict += f" ({more})" if more else ""
    remains = " (and a gap remains)" if diag.unexplained_remains and diag.steps else ""
    units = misfit_words(diag)
    print(f"{name}: verdict {verdict}{remains}; {units + '; ' if units else ''}gap "
          f"{diag.gap_before:.4f} -> {diag.gap_after:.4f} nats per unit; {diag.summary}",
          flush=True)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["benchmark"]:
        print(f"error: {MOVED}", file=sys.stderr)
        return 2
    args = build_parser().parse_args(argv)
    design = load_design()
    out = Path(args.out)
    created = not out.exists()
    try:
        if not (out / "index.html").exists():  # an existing report: refused later
            prepare_out_dir(args.out)
        return _diagnose(args, design)
    except (GapError, OutDirError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        _remove_if_made_empty(out, created)
        return 2
    except OSError as exc:  # a write that failed after the check (a full disk)
        print(f"error: {write_error_line(exc)}", file=sys.stderr)
        return 1


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m analysis gap``."""
    ap = argparse.ArgumentParser(prog="python -m analysis.gap")
    sub = ap.add_subparsers(dest="cmd", required=True)
    # Listed so that --help shows where the benchmark went (main answers before parsing).
    sub.add_parser("benchmark", add_help=False,
                   help="moved: the blind benchmarks are `python -m analysis gapbench`")
    d = sub.add_parser("diagnose", help="diagnose real data against the simulation")
    d.add_argument("--layer", choices=[*LAYERS, "all"], required=True)
    d.add_argument("--real", required=True,
                   help="observer: session CSV folder; display: readings.csv or its folder; "
                        "render: the gloss-fit output folder; all: LAYER=PATH,... ")
    d.add_argument("--sim", required=True,
                   help="observer: an observers TOML (python -m experiment fit-observer) or a "
                        "simulated session CSV folder; display: calibration.json or its folder; "
                        "render: the gloss-fit output folder; all: LAYER=PATH,...")
    d.add_argument("--sim-kind", choices=("humanlike", "ideal"), default=None,
                   help="observer layer with an observers TOML: which table is the simulation "
                        "(default humanlike)")
    d.add_argument("--study", help="observer layer: another lab's study.toml (its folder is "
                                   "--real; --sim from python -m experiment fit-observer "
                                   "--study); see protocol.md, 'Another lab's study'")
    d.add_argument("--participants", nargs="+",
                   help="with --study: diagnose only these participants")
    d.add_argument("--lights", default=None,
                   help="render layer, directional-light sets: the lights held out, e.g. 25-48 "
                        "(REAL the photo set, SIM the fit of other lights: python -m stimuli "
                        "fit-gloss SET --lights 1-24 --out FIT); panorama sets in several "
                        "lightings: the lighting held out, e.g. lamp (SIM fitted another)")
    d.add_argument("--out", required=True)
    d.add_argument("--seed", type=int, default=0,
                   help="the bootstrap's seed (the observer layer's folds do not depend on it)")
    return ap


def _remove_if_made_empty(out: Path, created: bool) -> None:
    """A refused diagnosis leaves no trace: the ``--out`` folder this run created is removed
    again while it is still empty (an empty REPORT read as a report that failed half-way)."""
    if created and out.is_dir() and not any(out.iterdir()):
        out.rmdir()


if __name__ == "__main__":
    sys.exit(main())
