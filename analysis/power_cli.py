"""``python -m analysis power``: the command line of `analysis.powerplan`."""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path

__all__ = ["add_power_parser", "parse_participants"]

_EPILOG = """examples:
  python -m analysis power PILOT --out power/ --model gloss --term gloss:depth
  python -m analysis power PILOT --out power-half/ --model gloss --term gloss:depth \\
      --scale gloss:depth=0.5 --detect 12
  python -m analysis power --simulate observers --observers observers.toml --out power-obs/ \\
      --model gloss --sessions 1,2 --repeats 1,2
"""


def parse_participants(text: str) -> tuple:
    """``"4:24:2"`` (first:last:step, last included) or ``"4,6,10"`` -> (4, 6, ..., 24)."""
    try:
        if ":" in text:
            parts = [int(p) for p in text.split(":")]
            if len(parts) not in (2, 3) or (len(parts) == 3 and parts[2] < 1):
                raise ValueError
            step = parts[2] if len(parts) == 3 else 1
            return tuple(range(parts[0], parts[1] + 1, step))
        return tuple(int(p) for p in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: give first:last:step (e.g. 4:24:2) or a list (e.g. 4,8,12)") from None


def _ints(text: str) -> tuple:
    try:
        return tuple(int(p) for p in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give whole numbers, e.g. 1,2") from None


def _effect(text: str) -> tuple:
    term, sep, value = text.partition("=")
    try:
        if not sep or not term.strip():
            raise ValueError
        return term.strip(), float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: give TERM=NUMBER, e.g. gloss:depth=0.5") from None


def add_power_parser(sub) -> None:
    p = sub.add_parser(
        "power", help="power by simulation for planning a study (as R's simr)",
        description="Simulate planned studies, refit the mixed model and test each term (Type II "
        "Wald chi-square, as the report), as simr's powerSim/powerCurve: the power over numbers "
        "of participants and trials per participant with Monte-Carlo 95 % intervals, the "
        "smallest N for the target power, the smallest effect a given N detects. Writes "
        "OUT/power.json, power.csv, power.png, summary.txt (an existing power.json is never "
        "overwritten).", epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("data", nargs="?", help="session folder or CSV the model is fitted to "
                   "(--simulate model: a pilot's or the study's own data)")
    p.add_argument("--out", required=True, help="output folder (must not hold a power.json)")
    p.add_argument("--simulate", choices=["model", "observers"], default="model",
                   help="model: new participants from the fitted model's random effects (simr); "
                   "observers: whole sessions of simulated observers through the plan")
    p.add_argument("--observers", metavar="TOML", help="observers.toml for --simulate observers "
                   "(default: the shipped one; `experiment fit-observer` fits one to a pilot)")
    p.add_argument("--model", nargs="+", default=["gloss", "depth"],
                   help="source-study models (gloss, depth) or the design's [analysis.models]")
    p.add_argument("--formula", help="any lme4 formula instead of --model")
    p.add_argument("--term", nargs="+", help="terms to test (default gloss, depth, gloss:depth "
                   "on the gloss model, depth on the depth model)")
    p.add_argument("--participants", type=parse_participants, default=tuple(range(4, 25, 2)),
                   help="numbers of participants, first:last:step or a list (default 4:24:2)")
    p.add_argument("--sessions", type=_ints, default=(None,), help="sessions of the plan per "
                   "participant, a list (default all of the design's)")
    p.add_argument("--repeats", type=_ints, default=(1,),
                   help="times each participant does them, a list (default 1)")
    p.add_argument("--n-sim", type=int, default=1000, help="simulated studies per point")
    p.add_argument("--seed", type=int, default=0, help="root seed (recorded)")
    p.add_argument("--alpha", type=float, default=0.05)
    p.add_argument("--target", type=float, default=0.8, help="target power (default 0.8)")
    p.add_argument("--scale", type=_effect, action="append", default=[], metavar="TERM=F",
                   help="simulate TERM at F times its fitted size (repeatable)")
    p.add_argument("--effect", type=_effect, action="append", default=[], metavar="TERM=V",
                   help="simulate TERM at V in the study's units: per %% gloss and per cm "
                   "depth, e.g. gloss:depth=0.05 (%% per %% per cm) (repeatable)")
    p.add_argument("--detect", type=int, metavar="N", help="also find the smallest effect with "
                   "the target power at N participants")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=1, help="1: this process (default); "
                       "more: a local Dask cluster of that many processes")
    where.add_argument("--scheduler", metavar="ADDRESS", help="an existing Dask cluster")
    from stimuli.dask_cluster import add_cluster_arguments

    add_cluster_arguments(p, where)
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=cmd_power)


@contextlib.contextmanager
def _client(args, design):
    """None (this process), or a Dask client from --workers/--scheduler/--cluster."""
    if args.workers == 1 and not args.scheduler and not args.cluster:
        yield None
        return
    from stimuli.dask_cluster import open_client

    def local():
        from distributed import LocalCluster

        return LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                            dashboard_address=None)

    spec = _job_spec(args, design) if args.cluster else None
    with open_client(scheduler=args.scheduler, spec=spec, local=local) as (client, _):
        yield client


def _job_spec(args, design):
    """--cluster's job: one single-threaded worker process per core (the refits are Python and
    small LAPACK calls that hold the GIL in parts), as `analysis imagestats`."""
    from dataclasses import replace

    from stimuli.dask_cluster import job_spec_from

    spec = job_spec_from(args, design)
    return replace(spec, processes=spec.cores)


def _settings(args):
    from analysis.power import Effect
    from analysis.powerplan import PowerSettings

    models = (args.formula,) if args.formula else tuple(args.model)
    terms = {m: list(args.term) for m in models} if args.term else {}
    effects = tuple([Effect(t, scale=v) for t, v in args.scale]
                    + [Effect(t, value=v) for t, v in args.effect])
    return PowerSettings(simulate=args.simulate, models=models, terms=terms,
                         participants=args.participants, sessions=args.sessions,
                         repeats=args.repeats, n_sim=args.n_sim, seed=args.seed,
                         alpha=args.alpha, target=args.target, effects=effects,
                         detect_n=args.detect)


def cmd_power(args) -> int:
    from analysis.formula import LmmError
    from analysis.load import SessionDataError
    from analysis.power import PowerError
    from analysis.powerplan import run_power, write_power
    from labfiles.outdir import OutDirError, prepare_out_dir, write_error_line
    from stimuli.dask_cluster import ClusterError
    from studydesign import DesignError, load_design

    out = Path(args.out)
    if (out / "power.json").exists():
        print(f"error: {out / 'power.json'} exists; results are never overwritten: pass another "
              "--out", file=sys.stderr)
        return 1
    if args.workers < 1:
        print(f"error: --workers {args.workers}: use 1 (this process) or more", file=sys.stderr)
        return 2
    if args.dry_run:
        if not args.cluster:
            print("error: --dry-run prints a batch job script: add --cluster slurm|pbs|sge",
                  file=sys.stderr)
            return 2
        from stimuli.dask_cluster import job_script

        try:
            print(job_script(_job_spec(args, load_design(args.design))))
        except (ClusterError, DesignError, ValueError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1
        return 0
    try:
        prepare_out_dir(out)
        design = load_design(args.design)
        settings = _settings(args)
        data = observers = None
        if args.simulate == "model":
            if not args.data:
                raise PowerError("--simulate model needs DATA (a pilot's or the study's "
                                 "sessions) to fit the model to; or use --simulate observers")
            from analysis.summary import read_model_data

            data = read_model_data(args.data, design)
        else:
            from experiment.observers import load_observer_params

            observers = load_observer_params(args.observers)["humanlike"]
        with _client(args, design) as client:
            result = run_power(settings, design, data=data, observers=observers,
                               client=client, quiet=args.quiet)
        result["source"] = str(args.data if args.simulate == "model" else
                               args.observers or "experiment/observers.toml (shipped)")
        paths = write_power(result, out)
    except (PowerError, LmmError, SessionDataError, DesignError, ClusterError, OutDirError,
            FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"error: {write_error_line(exc)}", file=sys.stderr)
        return 1
    print(paths["summary"].read_text(), end="")
    print(f"power: {paths['json']} ({paths['csv'].name}, {paths['png'].name})")
    return 0
