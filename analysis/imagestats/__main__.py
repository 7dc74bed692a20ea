"""``python -m analysis imagestats``: image statistics of a render folder, and their relation to
perceived gloss.

    python -m analysis imagestats RENDER_DIR --out stats.parquet [--workers N | --scheduler ADDR
        | --cluster slurm|pbs|sge [--cores C --memory M --walltime HH:MM:SS --queue Q --jobs J]]
    python -m analysis imagestats relate stats.parquet --sessions DATA_DIR --out REPORT_DIR
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from studydesign import DesignError, load_design

_USAGE = __doc__.split("\n\n", 1)[1]


def compute_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m analysis imagestats",
        description="Per-image statistics (mean luminance, RMS contrast, skewness, kurtosis, "
        "highlight coverage, Portilla-Simoncelli) of every image a render folder's manifest "
        "lists, on the array square of the EXR luminance, into one Parquet table. Resumable: "
        "images already in --out are skipped. Second form: `imagestats relate --help`.",
        epilog=_USAGE, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("render_dir", help="folder with manifest.csv (python -m stimuli render)")
    p.add_argument("--out", required=True, help="the Parquet table (created or resumed)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=2,
                       help="worker processes of a local Dask cluster (default 2)")
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help="use an existing Dask cluster (tcp://host:8786: `dask scheduler`, "
                       "then `dask worker ADDRESS` on any machines, joining and leaving at will)")
    from stimuli.dask_cluster import add_cluster_arguments

    add_cluster_arguments(p, where)
    p.add_argument("--batch-size", type=int, default=64, metavar="B",
                   help="images per Dask task and per saved part (default 64)")
    p.add_argument("--no-ps", action="store_true",
                   help="pixel statistics only, no Portilla-Simoncelli statistics")
    p.add_argument("--highlight-factor", type=float, default=2.0,
                   help="highlight threshold as a multiple of the diffuse (median) level "
                   "(default 2)")
    p.add_argument("--design", help="a design.toml (default: the shipped one)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def relate_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m analysis imagestats relate",
        description="Which statistics change with depth at fixed gloss, regression of perceived "
        "gloss on the statistics, the image-statistics observer model, figures over the "
        "gloss x depth grid; an HTML report in --out (never overwritten).")
    p.add_argument("stats", help="a table from `python -m analysis imagestats`")
    p.add_argument("--sessions", metavar="DATA_DIR",
                   help="data folder with sessions/*.csv (without it: no perception analyses)")
    p.add_argument("--out", required=True, help="report folder (must not hold an index.html)")
    p.add_argument("--n-boot", type=int, default=1000, help="bootstrap resamples for CIs")
    p.add_argument("--seed", type=int, default=0, help="bootstrap seed (recorded)")
    p.add_argument("--ps-components", type=int, default=3, metavar="K",
                   help="principal components of the PS statistics analysed (default 3; 0 = none)")
    p.add_argument("--design", help="a design.toml (default: the shipped one)")
    return p


def _compute(argv: list[str]) -> int:
    from analysis.imagestats.config import StatsConfig
    from analysis.imagestats.images import ImageStatsError
    from analysis.imagestats.run import compute_stats, problems_path
    from analysis.imagestats.store import parts_dir

    args = compute_parser().parse_args(argv)
    try:
        design = load_design(args.design)
        spec = None
        if args.cluster:
            from dataclasses import replace

            from stimuli.dask_cluster import job_script, job_spec_from

            # one single-threaded worker process per core, as the local cluster
            spec = job_spec_from(args, design)
            spec = replace(spec, processes=spec.cores)
            if args.dry_run:
                print(job_script(spec))
                return 0
        elif args.dry_run:
            raise ValueError("--dry-run prints a batch job script: add --cluster slurm|pbs|sge")
        config = StatsConfig(highlight_factor=args.highlight_factor, ps=not args.no_ps)
        run = compute_stats(args.render_dir, args.out, design=design,
                            config=config, workers=args.workers, scheduler=args.scheduler,
                            batch_size=args.batch_size, progress=not args.quiet,
                            cluster=spec, no_worker_s=args.no_worker_timeout)
    except (ImageStatsError, DesignError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        parts = parts_dir(Path(args.out).absolute())
        n = len(list(parts.glob("part-*.parquet"))) if parts.is_dir() else 0
        print(f"interrupted (Ctrl-C): {n} finished batch(es) are kept in {parts}; run the same "
              "command to resume (images already measured are not measured again)",
              file=sys.stderr)
        return 130
    for note in run.notes:
        print(f"warning: {note}", file=sys.stderr)
    print(f"{run.path}: {run.n_images} images in the manifest, {run.n_skipped} already done, "
          f"{run.n_computed} computed on {run.workers} workers in {run.seconds:.1f} s")
    if run.problems:
        print(f"error: {len(run.problems)} problems (also in {problems_path(run.path)}):",
              file=sys.stderr)
        for item, message in run.problems:
            print(f"  {item}: {message}", file=sys.stderr)
        return 1
    return 0


def _relate(argv: list[str]) -> int:
    from analysis.imagestats.images import ImageStatsError
    from analysis.imagestats.report import ReportExistsError, build_relate_report
    from analysis.load import SessionDataError

    args = relate_parser().parse_args(argv)
    try:
        index = build_relate_report(args.stats, args.out, load_design(args.design),
                                    data_dir=args.sessions, n_boot=args.n_boot, seed=args.seed,
                                    n_ps_components=args.ps_components)
    except (ImageStatsError, ReportExistsError, SessionDataError, DesignError,
            ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    _print_light_fields(index.parent / "results.json")
    print(f"report: {index}")
    return 0


def _print_light_fields(results_path: Path) -> None:
    """One line per statistic: its slopes within light fields and per kind, and the indoor -
    outdoor difference (when the table held several light fields)."""
    import json

    lf = json.loads(results_path.read_text(encoding="utf-8")).get("light_fields")
    if not lf:
        return
    spread = {r["statistic"]: r for r in lf["spread"]}
    print(f"light fields: {len(lf['means'])}; slopes of each standardised statistic (SD per 10 % "
          "gloss, SD per cm depth), within light fields | indoor | outdoor; between-light-field "
          "variance share; indoor - outdoor (SD)")
    by_stat: dict = {}
    for r in lf["effects"]:
        by_stat.setdefault(r["statistic"], {})[r["scope"]] = r
    for name, scopes in by_stat.items():
        cells = [f"{s.split()[0]:7s} g {scopes[s]['gloss_slope_sd_per_10pct']:+.2f} "
                 f"d {scopes[s]['depth_slope_sd_per_cm']:+.2f}"
                 for s in ("within light fields", "indoor", "outdoor") if s in scopes]
        sp = spread.get(name, {})
        print(f"  {name:20s} " + " | ".join(cells)
              + f" | between {sp.get('between_light_field_r2', float('nan')):.2f}"
              f" | in-out {sp.get('indoor_minus_outdoor_sd', float('nan')):+.2f}"
              f" (p {sp.get('welch_p', float('nan')):.2g})")


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] == "relate":
        return _relate(argv[1:])
    return _compute(argv)


if __name__ == "__main__":
    sys.exit(main())
