"""``python -m analysis``: turn session data into results.

Subcommands: ``units`` (slider matches to %/cm), ``fit`` (one mixed model by lme4 formula),
``report`` (the HTML analysis report), ``power`` (power by simulation for planning a study,
`analysis.power_cli`), ``gap``, ``gapbench`` and ``imagestats`` (passed on to
``analysis.gap``, ``analysis.gapbench`` and ``analysis.imagestats``; ``gap benchmark`` goes to
``analysis.gapbench``, where the blind benchmarks moved).
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

from labfiles.outdir import OutDirError, prepare_out_dir, write_error_line
from studydesign import DesignError, load_design

# Subcommands owned by subpackages: everything after the name goes to their own main(argv).
_PASSTHROUGH = {
    "gap": ("analysis.gap.__main__",
            "sim-to-real gap: diagnose (see `gap --help`); `gap benchmark` runs gapbench"),
    "gapbench": ("analysis.gapbench.__main__",
                 "blind benchmarks of the gap diagnosis (see `gapbench --help`)"),
    "imagestats": ("analysis.imagestats.__main__", "image statistics (see `imagestats --help`)"),
}


def _bad_jobs(args) -> bool:
    """Refuse ``--jobs`` below 1 in the command's words (joblib's would name no option)."""
    if args.jobs >= 1:
        return False
    print(f"error: --jobs {args.jobs}: use 1 or more parallel workers (e.g. --jobs 2)",
          file=sys.stderr)
    return True


def _cmd_units(args) -> int:
    from analysis.units import matches_to_physical, read_matches_csv
    from labfiles import LabFileError

    try:
        raw, notes = read_matches_csv(args.csv)
        for note in notes:
            print(f"note: {note}", file=sys.stderr)
        frame = matches_to_physical(raw, load_design(args.design))
    except LabFileError as exc:  # names the file itself
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except (ValueError, DesignError, FileNotFoundError) as exc:
        print(f"error: {args.csv}: {exc}", file=sys.stderr)
        return 1
    frame.to_csv(sys.stdout, index=False)
    return 0


def _cmd_fit(args) -> int:
    import json
    from dataclasses import asdict

    from analysis.bootstrap import parametric_bootstrap
    from analysis.formula import LmmError
    from analysis.lmm import fit
    from analysis.load import SessionDataError
    from analysis.satterthwaite import coefficient_tests, satterthwaite_terms
    from analysis.summary import format_summary, read_model_data
    from analysis.typeii import type2_wald
    from labfiles import atomic_write_text, write_new_file

    for flag in ("bootstrap", "lrt"):
        if getattr(args, flag) < 0:
            print(f"error: --{flag} {getattr(args, flag)}: use 0 (none) or a positive number of "
                  "runs", file=sys.stderr)
            return 2
    if _bad_jobs(args):
        return 2
    out = Path(args.out)
    if (out / "fit.json").exists():
        print(f"error: {out / 'fit.json'} exists; fits are never overwritten: pass another --out",
              file=sys.stderr)
        return 1
    try:
        prepare_out_dir(out)
    except OutDirError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    try:
        data = read_model_data(args.data, load_design(args.design))
        result = fit(args.formula, data, reml=args.reml)
    except (LmmError, SessionDataError, DesignError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    tests = type2_wald(result)
    satt = coefficient_tests(result, data)
    record = {"data": str(args.data), "fit": asdict(result),
              "type2_wald": [asdict(t) for t in tests],
              "satterthwaite_t": {k: dict(zip(("df", "t", "p"), v)) for k, v in satt.items()},
              "satterthwaite_f": {k: dict(zip(("F", "num_df", "den_df", "p"), v))
                                  for k, v in satterthwaite_terms(result, data).items()}}
    if args.bootstrap:
        boot = parametric_bootstrap(data, result, observed_chi2={t.term: t.chi2 for t in tests},
                                    n_boot=args.bootstrap, seed=args.seed, n_jobs=args.jobs,
                                    progress=not args.quiet)
        record["bootstrap"] = asdict(boot)
    if args.lrt:
        from analysis.lrt import bootstrap_lrt

        record["bootstrap_lrt"] = [
            asdict(bootstrap_lrt(data, result, term, n_boot=args.lrt, seed=args.seed + k,
                                 n_jobs=args.jobs, progress=not args.quiet))
            for k, term in enumerate(result.terms)]
    text = format_summary(result, tests, satt)
    for lrt in record.get("bootstrap_lrt", []):
        text += (f"Bootstrap LRT (PBmodcomp) {lrt['term']}: LRT = {lrt['lrt']:.4f}, df = "
                 f"{lrt['df']}, p (chi2) = {lrt['p_chi2']:.3g}, p (bootstrap, {lrt['n_ok']} runs)"
                 f" = {lrt['p_boot']:.3g}\n")
    try:
        out.mkdir(parents=True, exist_ok=True)
        write_new_file(out / "fit.json", json.dumps(record, indent=1))
        atomic_write_text(out / "summary.txt", text)
    except FileExistsError as exc:
        print(f"error: {exc.strerror}", file=sys.stderr)
        return 1
    except OSError as exc:  # the disk filled or went read-only during the fit
        print(f"error: {write_error_line(exc)}", file=sys.stderr)
        return 1
    print(text, end="")
    print(f"fit: {out / 'fit.json'}")
    return 0


def _cmd_report(args) -> int:
    from analysis.load import SessionDataError, load_sessions
    from analysis.report import ReportExistsError, build_report

    if args.bootstrap < 0:
        print(f"error: --bootstrap {args.bootstrap}: use 0 (none) or a positive number of runs",
              file=sys.stderr)
        return 2
    if _bad_jobs(args):
        return 2
    try:
        if not (Path(args.out) / "index.html").exists():  # an existing report: refused below
            prepare_out_dir(args.out)
        design = load_design(args.design)
        # What the report includes, said here too: simulated participants, torn rows left
        # out, more than one calibration (the report lists them under "Data warnings").
        for note in load_sessions(args.data_dir, design).warnings:
            print(f"warning: {note}", file=sys.stderr)
        index = build_report(args.data_dir, args.out, design,
                             n_boot=args.bootstrap, seed=args.seed, n_jobs=args.jobs,
                             progress=not args.quiet, power_dirs=args.power)
    except (ReportExistsError, SessionDataError, DesignError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # a write that failed after the checks (a full disk)
        print(f"error: {write_error_line(exc)}", file=sys.stderr)
        return 1
    print(f"report: {index}")
    return 0


def _passthrough(name: str, argv: list[str]) -> int:
    if name == "gap" and argv[:1] == ["benchmark"]:
        # The blind benchmarks moved to analysis.gapbench; lab scripts and protocol.md's
        # `gap benchmark ...` lines still run them.
        name, argv = "gapbench", argv[1:]
    module, _ = _PASSTHROUGH[name]
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name and module.startswith(exc.name):
            print(f"error: `python -m analysis {name}` is not built yet ({module} missing)",
                  file=sys.stderr)
            return 2
        raise
    return int(mod.main(argv) or 0)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    # Subpackage commands take the rest of the line verbatim (their own argparse parses it).
    for i, word in enumerate(argv):
        if word in _PASSTHROUGH:
            if i == 0:
                return _passthrough(word, argv[1:])
            break
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command in _PASSTHROUGH:
        return _passthrough(args.command, argv[argv.index(args.command) + 1:])
    return args.func(args)


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m analysis``; ``gap``, ``gapbench`` and ``imagestats`` are
    listed here and parsed by their own packages' ``build_parser``."""
    parser = argparse.ArgumentParser(prog="python -m analysis", description="Analyse session data.")
    parser.add_argument("--design", help="a design.toml (default: the shipped one)")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("units", help="add physical units (%%, cm) to a session CSV's matches")
    p.add_argument("csv", help="a session CSV")
    p.set_defaults(func=_cmd_units)
    p = sub.add_parser(
        "fit", help="fit one linear mixed model given by an lme4 formula",
        description="Fit a linear mixed model as lme4's lmer does (same formula syntax, same "
        "estimates) to a session folder (standardised gloss and depth, depth_match_bc; see "
        "`report`) or to any CSV, and write OUT/fit.json and OUT/summary.txt. Formula: fixed "
        "effects as in R (a * b, a:b, C(f, contr.sum) for sum contrasts; factors get treatment "
        "contrasts), random effects (1 + a | g) correlated, (1 + a || g) uncorrelated, "
        "(1 | g1/g2) nested, several terms crossed.",
        epilog='example: python -m analysis fit data/ --formula "gloss_match_pct ~ gloss * depth '
        '+ illumination + (1 + gloss + depth | participant) + (1 | stimulus_id)" --out fits/crossed')
    p.add_argument("data", help="a session folder (holding sessions/) or a CSV file")
    p.add_argument("--formula", required=True, help="lme4 formula, e.g. 'y ~ x + (1 | g)'")
    p.add_argument("--reml", action="store_true", help="REML instead of maximum likelihood")
    p.add_argument("--out", required=True, help="output folder (must not hold a fit.json)")
    p.add_argument("--bootstrap", type=int, default=0, metavar="N",
                   help="parametric bootstrap runs (default 0 = none)")
    p.add_argument("--lrt", type=int, default=0, metavar="N",
                   help="parametric bootstrap likelihood-ratio test of each term with N runs, as "
                   "pbkrtest::PBmodcomp (default 0 = none)")
    p.add_argument("--seed", type=int, default=0, help="bootstrap seed (recorded)")
    p.add_argument("--jobs", type=int, default=2, help="parallel bootstrap workers")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_fit)
    p = sub.add_parser(
        "report", help="figures, mixed models and bootstrap of DATA_DIR/sessions as HTML",
        description="Load and validate every session CSV of DATA_DIR, draw the source study's figures, "
        "fit the mixed models (Type II Wald tests), bootstrap them and write "
        "REPORT_DIR/index.html. An existing report is never overwritten.")
    p.add_argument("data_dir", help="folder holding sessions/<participant>_s<n>.csv")
    p.add_argument("--out", required=True, help="report folder (must not hold an index.html)")
    p.add_argument("--bootstrap", type=int, default=10_000, metavar="N",
                   help="parametric bootstrap runs per model (default 10000; 0 = none)")
    p.add_argument("--seed", type=int, default=0, help="bootstrap seed (recorded)")
    p.add_argument("--jobs", type=int, default=2, help="parallel bootstrap workers")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--power", metavar="POWER_DIR", nargs="+", default=[],
                   help="include `python -m analysis power` results (section 'Planning a study: "
                   "power')")
    p.set_defaults(func=_cmd_report)
    from analysis.power_cli import add_power_parser

    add_power_parser(sub)
    for name, (_, help_text) in _PASSTHROUGH.items():
        sub.add_parser(name, help=help_text, add_help=False)
    return parser


if __name__ == "__main__":
    sys.exit(main())
