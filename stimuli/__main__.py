"""``python -m stimuli``: render and manage stimulus sets.

Commands: ``list``, ``render``, ``verify``, ``contact-sheet``, ``export-print``, ``check-env``
(and the gloss-fitting commands of :mod:`stimuli.glossfit`). ``python -m stimuli CMD --help``.
"""

from __future__ import annotations

import argparse
import errno
import json
import os
import sys
from pathlib import Path

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


def _load_calibration(design, path):
    from calibration import default_calibration, load_calibration

    return load_calibration(path) if path else default_calibration(design)


def _load_gloss(path):
    from stimuli.glosstable import default_gloss_table, default_gloss_table_path, load_gloss_table

    if path:
        return load_gloss_table(path), str(path)
    return default_gloss_table(), str(default_gloss_table_path())


def _cmd_render(args) -> int:
    from stimuli.mitsuba_env import setup_mitsuba
    from stimuli.pipeline import RenderJob, render_set
    from stimuli.render import camera_geometry

    design, table = _select(args)
    gloss, gloss_name = _load_gloss(args.gloss_table)
    cal = _load_calibration(design, args.calibration)
    variant = setup_mitsuba(args.variant)  # fails here, with the fix, before any worker starts
    from stimuli.render import multijitter_spp

    spp = multijitter_spp(args.spp)
    if spp != args.spp:
        print(f"note: the multijitter sampler takes {spp} samples per pixel for --spp {args.spp} "
              "(an a x b grid); recording and using that", file=sys.stderr)
    camera = camera_geometry(design, cal)
    size = args.size or camera.native_px
    cores = os.cpu_count() or 1
    client = cluster = None
    workers = args.workers if args.workers is not None else min(cores, 4)
    threads = max(1, cores // max(workers, 1)) if not args.scheduler else 0
    job = RenderJob(camera=camera, size_px=size, spp=spp, variant=variant,
                    design_path=str(design.source), threads=threads)
    print(f"stimuli render: set {args.set}, {len(table)} stimuli, {size} px, {spp} spp, "
          f"variant {variant}, image width {camera.image_width_cm:.3f} cm at "
          f"{camera.distance_cm:g} cm, gloss table {gloss_name}, calibration "
          f"{cal.calibration_id} -> {args.out}", file=sys.stderr)
    try:
        if args.scheduler:
            from dask.distributed import Client

            client = Client(args.scheduler)
        elif workers > 0:
            from dask.distributed import Client, LocalCluster

            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                   dashboard_address=":0")
            client = Client(cluster)
        summary = render_set(table, args.out, job=job, gloss_table=gloss, calibration=cal,
                             tonemap_spec=design.tonemap, client=client,
                             progress=not args.no_progress, gloss_table_name=gloss_name)
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    print(json.dumps(summary, indent=1, default=str))
    return 0


def _cmd_verify(args) -> int:
    from stimuli.manifest import verify_manifest

    problems = verify_manifest(args.folder, kinds=("png", "exr"))
    for p in problems:
        print(p, file=sys.stderr)
    print(f"{'OK' if not problems else 'FAILED'}: {len(problems)} problems in {args.folder}")
    return 0 if not problems else 1


def _cmd_contact_sheet(args) -> int:
    from stimuli.contactsheet import contact_sheet

    print(contact_sheet(args.folder, args.out, tile_px=args.tile_px))
    return 0


def _cmd_export_print(args) -> int:
    from stimuli.geometry import draw_array, mesh_edges_ok, print_mesh, stimulus_seed, write_mesh

    design = load_design(args.design)
    if args.depth_level not in design.depth.labels:
        raise ValueError(f"--depth-level {args.depth_level} is not a depth level; "
                         f"choose one of {list(design.depth.labels)}")
    seed = args.seed if args.seed is not None else stimulus_seed(args.depth_level, args.array_index)
    geometry = draw_array(design, float(design.depth.cm(args.depth_level)), seed)
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


def _cmd_check_env(args) -> int:
    from stimuli.mitsuba_env import setup_mitsuba

    variant = setup_mitsuba(args.variant)
    print(json.dumps({"variant": variant,
                      "DRJIT_LIBLLVM_PATH": os.environ.get("DRJIT_LIBLLVM_PATH")}))
    return 0


def _add_selection(p) -> None:
    p.add_argument("--set", default="experiment",
                   help="set name: experiment, imagestats or preview (default: experiment)")
    p.add_argument("--filter", action="append", metavar="COL=V1,V2",
                   help="keep rows whose COL is one of the values (repeatable), "
                        "e.g. --filter depth_level=2,5 --filter illumination=indoor")
    p.add_argument("--limit", type=int, help="keep only the first N selected rows")


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
    p.add_argument("--spp", type=int, default=64, help="samples per pixel (default: 64)")
    p.add_argument("--gloss-table", help="gloss table CSV (default: the shipped placeholder)")
    p.add_argument("--calibration", help="calibration.json (default: the documented default curve)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--workers", type=int, help="Dask LocalCluster worker processes (default: "
                   "min(cores, 4)); 0 renders in this process")
    g.add_argument("--scheduler", help="address of an existing Dask scheduler (tcp://host:8786); "
                   "its workers must see --out at the same path (shared file system)")
    p.add_argument("--variant", help="Mitsuba variant (default: llvm_ad_spectral, else llvm_ad_rgb)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_render)

    p = sub.add_parser("verify", help="check a rendered folder's files against its manifest")
    p.add_argument("folder", type=Path)
    p.set_defaults(func=_cmd_verify)

    p = sub.add_parser("contact-sheet", help="tile a rendered folder's PNGs into one image")
    p.add_argument("folder", type=Path)
    p.add_argument("out", type=Path)
    p.add_argument("--tile-px", type=int, default=160)
    p.set_defaults(func=_cmd_contact_sheet)

    p = sub.add_parser("export-print", help="write a watertight STL/PLY of an array for 3-D printing")
    p.add_argument("--depth-level", type=int, required=True, help="depth level label (1-11)")
    p.add_argument("--array-index", type=int, default=0, help="which array (default 0, as rendered)")
    p.add_argument("--seed", type=int, help="array seed (default: that of the rendered stimuli)")
    p.add_argument("--spacing-cm", type=float, default=0.02, help="height-field grid, cm")
    p.add_argument("--base-cm", type=float, default=0.3, help="base slab thickness, cm")
    p.add_argument("--units", choices=["mm", "cm"], default="mm",
                   help="length unit in the file (default mm: slicers read STL as mm)")
    p.add_argument("out", type=Path, help="output .stl or .ply")
    p.set_defaults(func=_cmd_export_print)

    p = sub.add_parser("check-env", help="select the Mitsuba variant and smoke-test a render")
    p.add_argument("--variant")
    p.set_defaults(func=_cmd_check_env)
    __import__("stimuli.glossfit.cli").glossfit.cli.register(sub)  # fit-gloss, synth-photos
    return parser


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
        print(f"error: {exc}{hint}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
