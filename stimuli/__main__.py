"""``python -m stimuli``: render and manage stimulus sets.

Commands: ``list``, ``render``, ``verify``, ``contact-sheet``, ``export-print``, ``check-env``
(and the gloss-fitting commands of :mod:`stimuli.glossfit`). ``python -m stimuli CMD --help``.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import json
import math
import os
import signal
import sys
from pathlib import Path

from labfiles.outdir import write_error_line
from studydesign import load_design


def _select(args):
    from stimuli.sets import apply_filters, parse_filters, stimulus_set

    design = load_design(args.design)
    table = stimulus_set(design, args.set)
    table = apply_filters(table, parse_filters(args.filter), limit=args.limit)
    return design, table


def _cmd_list(args) -> int:
    _, table = _select(args)
    table.to_csv(sys.stdout, index=False)
    return 0


#: The age past which the session app refuses a calibration by default (its
#: ``--max-calibration-age-days``), days: stimuli corrected with an older one are named.
SESSION_MAX_CALIBRATION_AGE_DAYS = 30.0


def _load_calibration(design, path):
    """The calibration and the SHA-256 of its file ("" for the default curve, no file)."""
    from calibration import default_calibration, load_calibration
    from stimuli.manifest import sha256_file

    if not path:
        return default_calibration(design), ""
    cal = load_calibration(path)
    file = Path(path) / "calibration.json" if Path(path).is_dir() else Path(path)
    age = cal.age_days()
    if age > SESSION_MAX_CALIBRATION_AGE_DAYS:
        print(f"warning: calibration {cal.calibration_id} ({path}) is {age:.1f} days old, older "
              f"than the {SESSION_MAX_CALIBRATION_AGE_DAYS:g} days a session accepts: the "
              "stimuli's gamma correction may no longer fit the CRT; recalibrate (`python -m "
              "calibration run`, or `calibration check` to test it) and render with the new "
              "calibration", file=sys.stderr)
    return cal, sha256_file(file)


def _load_gloss(path):
    from stimuli.glosstable import default_gloss_table, default_gloss_table_path, load_gloss_table

    if path:
        return load_gloss_table(path), str(path)
    return default_gloss_table(), str(default_gloss_table_path())


@contextlib.contextmanager
def _workers_ignore_ctrl_c():
    """Start Dask's nannies and workers with SIGINT ignored (inherited, and kept by Python and
    by the processes they start), so that Ctrl-C reaches only this process, which closes the
    cluster and its workers: no worker prints a KeyboardInterrupt traceback. A Ctrl-C during
    these seconds of start-up is ignored (press it again)."""
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


def _cmd_render(args) -> int:
    from stimuli.mitsuba_env import setup_mitsuba
    from stimuli.pipeline import RenderJob, render_set
    from stimuli.render import camera_geometry

    design, table = _select(args)
    spec = None
    if args.cluster:
        from stimuli.dask_cluster import job_script, job_spec_from

        spec = job_spec_from(args, design)
        if args.dry_run:
            print(job_script(spec))
            return 0
    elif args.dry_run:
        raise ValueError("--dry-run prints a batch job script: add --cluster slurm|pbs|sge")
    gloss, gloss_name = _load_gloss(args.gloss_table)
    cal, cal_sha256 = _load_calibration(design, args.calibration)
    # fails here, with the fix, before any worker starts
    variant = setup_mitsuba(args.variant or design.render.variant)
    from stimuli.render import multijitter_spp

    camera = camera_geometry(design, cal)
    size = args.size or camera.native_px
    by_light_field = ()
    if args.spp is not None:
        spp, by_level = multijitter_spp(args.spp), ()
        if spp != args.spp:
            print(f"note: the multijitter sampler takes {spp} samples per pixel for --spp "
                  f"{args.spp} (an a x b grid); recording and using that", file=sys.stderr)
        spp_text = f"{spp} spp"
    else:
        from stimuli.noise import spp_table

        by_level, by_light_field = spp_table(design, table["light_field"])
        spp = max([*by_level, *(max(v) for _, v in by_light_field)])
        own = sum(lf in dict(design.render.spp_by_light_field) or tuple(v) != by_level
                  for lf, v in by_light_field)
        spp_text = (f"spp per gloss level {list(by_level)}, {own} of {len(by_light_field)} light "
                    f"field(s) with their own (displayed error "
                    f"{design.render.displayed_error_pct:g} %)")
        if size != design.render.spp_planned_at_px:
            print(f"note: the design's spp per gloss level were planned at "
                  f"{design.render.spp_planned_at_px} px and this run is {size} px; run "
                  f"`python -m stimuli plan-spp --size {size}` for counts measured at this size",
                  file=sys.stderr)
    cores = os.cpu_count() or 1
    workers = args.workers if args.workers is not None else 1
    if args.scheduler:
        threads = 0  # each worker: the cores its process may use
    elif spec is not None:
        threads = spec.cores
    else:
        threads = max(1, cores // max(workers, 1))
    job = RenderJob(camera=camera, size_px=size, spp=spp, variant=variant,
                    design_path=str(design.source), threads=threads,
                    spp_by_gloss_level=by_level, spp_by_light_field=by_light_field,
                    llvm_path=os.environ.get("DRJIT_LIBLLVM_PATH", ""))
    print(f"stimuli render: set {args.set}, {len(table)} stimuli, {size} px, {spp_text}, "
          f"variant {variant}, image width {camera.image_width_cm:.3f} cm at "
          f"{camera.distance_cm:g} cm, gloss table {gloss_name}, calibration "
          f"{cal.calibration_id} -> {args.out}", file=sys.stderr)
    run = {"table": table, "out_dir": args.out, "job": job, "gloss_table": gloss,
           "calibration": cal, "tonemap_spec": design.tonemap,
           "progress": not args.no_progress, "gloss_table_name": gloss_name,
           "calibration_sha256": cal_sha256}
    if not args.scheduler and spec is None and workers <= 0:
        summary = render_set(**run)
    else:
        from stimuli.dask_cluster import open_client

        def local():
            from dask.distributed import LocalCluster

            print(f"starting {workers} Dask worker process(es) (Ctrl-C is taken once they "
                  "run)", file=sys.stderr, flush=True)
            with _workers_ignore_ctrl_c():
                return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                    dashboard_address=":0")

        with open_client(scheduler=args.scheduler, spec=spec, local=local) as (client, advice):
            summary = render_set(**run, client=client,
                                 workers={"what_to_start": advice,
                                          "no_worker_s": args.no_worker_timeout,
                                          "expected": {} if spec is None else
                                          {f"job {i}": spec.cores for i in range(spec.jobs)}})
    print(json.dumps(summary, indent=1, default=str))
    return 0


def _cmd_verify(args) -> int:
    from stimuli.manifest import verify_folder

    problems = verify_folder(args.folder)
    for p in problems:
        print(p, file=sys.stderr)
    print(f"{'OK' if not problems else 'FAILED'}: {len(problems)} problems in {args.folder}")
    return 0 if not problems else 1


def _cmd_contact_sheet(args) -> int:
    from stimuli.contactsheet import contact_sheet

    if args.out.exists() and not args.force:
        raise ValueError(f"{args.out} exists and would be replaced by the contact sheet; "
                         "choose another file name, or add --force to replace it")
    print(contact_sheet(args.folder, args.out, tile_px=args.tile_px))
    return 0


def _cmd_export_print(args) -> int:
    from stimuli.geometry import draw_array, mesh_edges_ok, print_mesh, stimulus_seed, write_mesh

    design = load_design(args.design)
    if not (math.isfinite(args.base_cm) and args.base_cm > 0):
        raise ValueError(f"--base-cm {args.base_cm:g}: the base slab holding the bumps needs a "
                         "finite thickness above 0 cm, e.g. --base-cm 0.3 (the default)")
    if args.depth_level not in design.depth.labels:
        raise ValueError(f"--depth-level {args.depth_level} is not a depth level; "
                         f"choose one of {list(design.depth.labels)}")
    if args.out.exists() and not args.force:
        raise ValueError(f"{args.out} exists and would be replaced by the mesh; choose another "
                         "file name, or add --force to replace it")
    seed = args.seed if args.seed is not None else stimulus_seed(args.depth_level, args.array_index)
    geometry = draw_array(design, float(design.depth.cm(args.depth_level)), seed)
    side = int(2 * (geometry.half_extent_cm + 0.5) / args.spacing_cm) + 1  # print_mesh's grid
    if side > _MAX_PRINT_GRID:
        raise ValueError(f"--spacing-cm {args.spacing_cm:g} makes a {side} x {side} height field, "
                         f"too large to mesh; use {_fine_spacing(geometry):.3g} cm or more (0.02 "
                         "cm, the default, is about a printer's resolution)")
    _refuse_coarse_spacing(args.spacing_cm, geometry)
    mesh = print_mesh(geometry, spacing_cm=args.spacing_cm, base_cm=args.base_cm)
    ok, why = mesh_edges_ok(mesh)
    if not ok:
        raise ValueError(f"print mesh is not watertight ({why}); report this as a bug")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    path = write_mesh(mesh, args.out, units=args.units)
    scale = 10.0 if args.units == "mm" else 1.0
    size = (mesh.vertices.max(axis=0) - mesh.vertices.min(axis=0)) * scale
    print(json.dumps({"file": str(path), "depth_level": args.depth_level, "seed": seed,
                      "vertices": len(mesh.vertices), "faces": len(mesh.faces),
                      "units": args.units,
                      "size": f"{size[0]:.1f} x {size[1]:.1f} x {size[2]:.1f} {args.units}",
                      "watertight": why}, indent=1))
    return 0


#: The largest height-field side export-print meshes (4000^2 = 16 M vertices, about 1.5 GB of
#: STL): finer than any printer resolves for the design's arrays.
_MAX_PRINT_GRID = 4000


#: Height-field samples a bump's x/y radius must span at least: with 4, a grid point lies
#: within spacing / sqrt(2) of each bump's top, whose height is then met within 1.6 % (the
#: default 0.02 cm gives 50 on the design's 1 cm radius; 10 cm gave a flat slab).
_MIN_SAMPLES_PER_RADIUS = 4


def _refuse_coarse_spacing(spacing_cm: float, geometry) -> None:
    """Refuse a --spacing-cm too coarse to resolve the bumps: the height field would miss
    them (a flat slab, watertight all the same)."""
    widest = geometry.radius_xy_cm / _MIN_SAMPLES_PER_RADIUS
    if spacing_cm > widest:
        raise ValueError(f"--spacing-cm {spacing_cm:g} is too coarse for bumps of x/y radius "
                         f"{geometry.radius_xy_cm:g} cm: the height field would sample each "
                         f"{geometry.radius_xy_cm / spacing_cm:.2g} times across its radius and "
                         f"miss its shape (a flat slab); use <= {widest:.3g} cm (0.02 cm, the "
                         "default, is about a printer's resolution)")


def _fine_spacing(geometry) -> float:
    """The finest --spacing-cm whose grid stays within :data:`_MAX_PRINT_GRID`."""
    return 2 * (geometry.half_extent_cm + 0.5) / (_MAX_PRINT_GRID - 1)


def _cmd_check_env(args) -> int:
    from stimuli.mitsuba_env import setup_mitsuba

    variant = setup_mitsuba(args.variant)
    print(json.dumps({"variant": variant,
                      "DRJIT_LIBLLVM_PATH": os.environ.get("DRJIT_LIBLLVM_PATH")}))
    return 0


def _cmd_plan_spp(args) -> int:
    from stimuli.mitsuba_env import setup_mitsuba
    from stimuli.noise import plan_spp
    from stimuli.render import camera_geometry

    design = load_design(args.design)
    gloss, gloss_name = _load_gloss(args.gloss_table)
    variant = setup_mitsuba(args.variant or design.render.variant)
    camera = camera_geometry(design, _load_calibration(design, args.calibration)[0])
    target = design.render.displayed_error_pct if args.target_pct is None else args.target_pct
    print(f"stimuli plan-spp: {variant}, {args.size} px, target {target:g} % of the display "
          f"range, pilot {args.pilot_spp} spp x {args.repeats} seeds, gloss table {gloss_name}",
          file=sys.stderr)
    probes = names = None
    if args.light_fields:
        from stimuli.illumination import load_light_probe

        wanted = ([lf.name for lf in design.imagestats.light_fields]
                  if args.light_fields == ["all"] else args.light_fields)
        fields = [design.imagestats.light_field(n) for n in wanted]
        probes = [load_light_probe(lf.envmap, scale=lf.scale) for lf in fields]
        names = [lf.name for lf in fields]
    plan = plan_spp(design, camera, size_px=args.size, pilot_spp=args.pilot_spp,
                    repeats=args.repeats, target=target / 100.0, gloss_table=gloss,
                    max_spp=args.max_spp, progress=lambda m: print(m, file=sys.stderr),
                    probes=probes, light_fields=names)
    print(json.dumps(plan.summary()))
    print(f"displayed error per light field (target {target:g} %):\n{plan.report()}",
          file=sys.stderr)
    print(f"# paste into [render] of {design.source}:\n{plan.toml()}", file=sys.stderr)
    return 0


def _cmd_probe_scale(args) -> int:
    import numpy as np

    from stimuli.errors import IlluminationError
    from stimuli.illumination import (
        diffuse_white_luminance,
        diffuse_white_scale,
        load_light_probe,
        luminance,
    )
    from stimuli.probecheck import NEEDS, light_field_problems

    probe = load_light_probe(args.file, normalise="none")
    problems, warnings = light_field_problems(probe.rgb)
    for w in warnings:
        print(f"warning: {probe.path}: {w}; {NEEDS}", file=sys.stderr)
    if problems:
        raise IlluminationError(f"{probe.path} is not a light field: {'; '.join(problems)}; "
                                f"{NEEDS}")
    scale = diffuse_white_scale(probe.rgb)
    y = luminance(probe.rgb)
    row, col = np.unravel_index(int(np.argmax(y)), y.shape)
    h, w = y.shape
    print(json.dumps({"file": probe.path, "sha256": probe.sha256, "width_px": w, "height_px": h,
                      "diffuse_white_luminance": diffuse_white_luminance(probe.rgb),
                      "scale": float(f"{scale:.6g}"), "brightest_luminance": float(y.max()),
                      "brightest_elevation_deg": round(90 - 180 * (row + 0.5) / h, 1),
                      "brightest_azimuth_deg_from_viewer": round(360 * (col + 0.5) / w - 180, 1),
                      "brightest_over_median": float(y.max() / max(np.median(y), 1e-30))}))
    print(f"# in design.toml: envmap = \"{args.file}\", scale = {scale:.6g}  (a matte white "
          "facing the viewer at luminance 1)", file=sys.stderr)
    return 0


def _add_selection(p) -> None:
    p.add_argument("--set", default="experiment",
                   help="set name: experiment, imagestats, imagestats_slice or preview "
                        "(default: experiment)")
    p.add_argument("--filter", action="append", metavar="COL=V1,V2",
                   help="keep rows whose COL is one of the values (repeatable), "
                        "e.g. --filter depth_level=2,5 --filter illumination=indoor")
    p.add_argument("--limit", type=int, help="keep only the first N selected rows")


def _render_variant(text: str) -> str:
    """A Mitsuba variant the stimulus renderer can use (argparse type)."""
    from studydesign import RENDER_VARIANTS

    if text not in RENDER_VARIANTS:
        hint = (" (scalar variants trace one ray at a time and cannot build the stimulus "
                "meshes)" if text.startswith("scalar") else "")
        raise argparse.ArgumentTypeError(f"{text!r} cannot render the stimuli{hint}; use one of "
                                         f"{', '.join(RENDER_VARIANTS)}")
    return text


def _positive_cm(text: str) -> float:
    """A finite length > 0 in cm (argparse type)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of cm") from None
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"{text} cm: give a length above 0 (e.g. 0.02)")
    return value


def _array_index(text: str) -> int:
    """An array index >= 0 (argparse type)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"{value}: arrays are numbered from 0 (default 0, the "
                                         "rendered one)")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m stimuli", description="Render stimulus sets.")
    parser.add_argument("--design", help="a design.toml (default: the shipped one)")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("list", help="list the stimuli of a set as CSV")
    _add_selection(p)
    p.set_defaults(func=_cmd_list)

    p = sub.add_parser("render", help="render a set into DIR (manifest.csv, exr/, png/); resumable")
    _add_selection(p)
    p.add_argument("--out", required=True, type=Path, help="output folder")
    p.add_argument("--size", type=int, help="image width = height in px (default: the native "
                   "size at the display's pixel pitch)")
    p.add_argument("--spp", type=int, help="samples per pixel of every image (default: the "
                   "design's render.spp_by_gloss_level, the counts that reach its displayed-error "
                   "target)")
    p.add_argument("--gloss-table", help="gloss table CSV (default: the shipped placeholder)")
    p.add_argument("--calibration", help="calibration.json (default: the documented default curve)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", type=int, help="Dask LocalCluster worker processes (default 1, "
                   "whose Dr.Jit threads use all cores: faster than several processes on one "
                   "machine); 0 renders in this process")
    g.add_argument("--scheduler", help="address of an existing Dask scheduler (tcp://host:8786; "
                   "start it with `dask scheduler`, workers with `dask worker ADDRESS` on any "
                   "machines, joining and leaving at will); its workers must see --out at the "
                   "same path (shared file system)")
    from stimuli.dask_cluster import add_cluster_arguments

    add_cluster_arguments(p, g)
    p.add_argument("--variant", type=_render_variant,
                   help="Mitsuba variant (default: the design's render.variant; "
                   "'auto' = llvm_ad_mono, or cuda_ad_mono on a GPU: exact for the grey stimuli)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_render)

    p = sub.add_parser("verify", help="check a rendered folder: its files against the manifest, "
                       "rendered files the manifest lacks, and tonemaps.csv")
    p.add_argument("folder", type=Path)
    p.set_defaults(func=_cmd_verify)

    p = sub.add_parser("contact-sheet", help="tile a rendered folder's PNGs into one image")
    p.add_argument("folder", type=Path)
    p.add_argument("out", type=Path)
    p.add_argument("--tile-px", type=int, default=160)
    p.add_argument("--force", action="store_true", help="replace an existing OUT")
    p.set_defaults(func=_cmd_contact_sheet)

    p = sub.add_parser("export-print", help="write a watertight STL/PLY of an array for 3-D printing")
    p.add_argument("--depth-level", type=int, required=True, help="depth level label (1-11)")
    p.add_argument("--array-index", type=_array_index, default=0,
                   help="which array (default 0, as rendered)")
    p.add_argument("--seed", type=int, help="array seed (default: that of the rendered stimuli)")
    p.add_argument("--spacing-cm", type=_positive_cm, default=0.02,
                   help="height-field grid, cm")
    p.add_argument("--base-cm", type=float, default=0.3, help="base slab thickness, cm")
    p.add_argument("--units", choices=["mm", "cm"], default="mm",
                   help="length unit in the file (default mm: slicers read STL as mm)")
    p.add_argument("out", type=Path, help="output .stl or .ply (never replaced without --force)")
    p.add_argument("--force", action="store_true", help="replace an existing output file")
    p.set_defaults(func=_cmd_export_print)

    p = sub.add_parser("plan-spp", help="measure the spp each gloss level needs for the design's "
                       "displayed-error target (prints the [render] lines for design.toml)")
    p.add_argument("--size", type=int, default=256, help="image width = height in px (256)")
    p.add_argument("--pilot-spp", type=int, default=16, help="first measurement's spp (16)")
    p.add_argument("--repeats", type=int, default=4, help="renders per measurement (4)")
    p.add_argument("--max-spp", type=int, default=1024, help="upper bound of the search (1024)")
    p.add_argument("--target-pct", type=float, help="displayed-error target in %% of the display "
                   "range (default: the design's render.displayed_error_pct)")
    p.add_argument("--variant", type=_render_variant,
                   help="Mitsuba variant (default: the design's render.variant)")
    p.add_argument("--gloss-table", help="gloss table CSV (default: the shipped placeholder)")
    p.add_argument("--calibration", help="calibration.json (default: the documented default curve)")
    p.add_argument("--light-fields", nargs="+", metavar="NAME",
                   help="plan under these [imagestats] light fields, each apart ('all': the 22); "
                        "default: the design's illuminations")
    p.set_defaults(func=_cmd_plan_spp)

    p = sub.add_parser("probe-scale", help="the design's scale of a light probe (a matte white "
                       "facing the viewer at luminance 1) and where its brightest pixel is")
    p.add_argument("file", help="a lat-long OpenEXR or Radiance .hdr panorama, or a shipped "
                   "probe's name")
    p.set_defaults(func=_cmd_probe_scale)

    p = sub.add_parser("check-env", help="select the Mitsuba variant and smoke-test a render")
    p.add_argument("--variant")
    p.set_defaults(func=_cmd_check_env)
    __import__("stimuli.glossfit.cli").glossfit.cli.register(sub)  # fit-gloss, synth-photos
    return parser


#: Write errors said as what to do (labfiles.outdir) rather than as errno's words.
_NAMED_WRITE_ERRORS = (errno.EROFS, errno.EACCES, errno.EPERM, errno.ENOTDIR)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print("interrupted: finished files are kept (written atomically); re-run the same command "
              "to resume", file=sys.stderr)
        return 130
    except (ValueError, OSError) as exc:  # every package error is a ValueError subclass
        hint = ""
        if isinstance(exc, OSError) and exc.errno == errno.ENOSPC:
            hint = ("; the disk is full: free space and re-run the same command (finished files "
                    "are kept, no half-written file remains)")
        elif isinstance(exc, OSError) and exc.errno in _NAMED_WRITE_ERRORS:
            option = "--out" if "--out" in (argv if argv is not None else sys.argv) else "OUT"
            exc = write_error_line(exc, option=option)
        print(f"error: {exc}{hint}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
