"""Command lines ``python -m stimuli fit-gloss`` and ``python -m stimuli synth-photos``."""

from __future__ import annotations

import argparse
import sys

__all__ = ["register"]


def _levels(text: str | None, design) -> tuple[float, ...]:
    if text is None:
        return design.gloss.physical_pct
    try:
        levels = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"--levels {text!r}: give gloss percentages separated by commas, "
                         f"e.g. 0,50,100") from None
    unknown = [v for v in levels if v not in design.gloss.physical_pct]
    if unknown:
        raise ValueError(f"--levels {unknown} are no gloss levels of the design "
                         f"({list(design.gloss.physical_pct)})")
    return levels


def _design(args):
    from studydesign import load_design

    return load_design(getattr(args, "design", None))


def _cmd_fit_lights(args) -> int:
    from stimuli.glossfit.lightfit import fit_lights

    try:
        info = fit_lights(args.photo_set, args.out, args.lights or f"1-{_n_images(args)}",
                          spp=args.spp if args.spp_given else 4, seed=args.seed,
                          min_cos=args.min_cos, alpha_bounds=(args.alpha_min, args.alpha_max),
                          progress=lambda line: print(line, flush=True))
    except (ValueError, FileExistsError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    for w in info["warnings"]:
        print(f"warning: {w}", file=sys.stderr)
    print(f"fit: {args.out}/fit.json\nreport: {args.out}/report.html")
    return 0


def _n_images(args) -> int:
    from pathlib import Path

    return len((Path(args.photo_set) / "filenames.txt").read_text().split())


def _cmd_fit(args) -> int:
    from stimuli.glossfit.fit import fit_gloss
    from stimuli.glossfit.lightings import lighting_names
    from stimuli.glossfit.lightset import is_light_set
    from stimuli.glossfit.methods import FitSettings

    if is_light_set(args.photo_set):
        return _cmd_fit_lights(args)
    if args.lights and not lighting_names(args.photo_set):
        print(f"error: --lights: {args.photo_set} is a panorama photo set of one lighting (no "
              "light_directions.txt, no lightings/); leave --lights out, or pass a "
              "directional-light set", file=sys.stderr)
        return 1
    if not args.spp_given:
        args.spp = 36
    try:
        design = _design(args)
        settings = FitSettings(method=args.method,
                               alpha_bounds=(args.alpha_min, args.alpha_max),
                               grid_points=args.grid_points)
        run = fit_gloss(args.photo_set, args.out, design.gloss.physical_pct, settings=settings,
                        resolution_px=args.resolution, spp=args.spp, seed=args.seed,
                        max_highlight_offset_px=args.max_highlight_offset,
                        lighting=args.lights,
                        progress=lambda line: print(line, flush=True))
    except (ValueError, FileExistsError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    for w in run.warnings:
        print(f"warning: {w}", file=sys.stderr)
    print(f"{run.n_renders} renders, {run.wall_s:.1f} s")
    if run.table is None:
        print(f"error: no gloss table written; see {run.out_dir / 'report.html'}", file=sys.stderr)
        return 1
    print(f"gloss table: {run.out_dir / 'gloss_table.csv'}")
    print(f"report: {run.out_dir / 'report.html'}")
    return 0


def _cmd_synth(args) -> int:
    from stimuli.glossfit.exr import read_exr
    from stimuli.glossfit.synth import parse_effects, synth_photo_set

    try:
        design = _design(args)
        envmap = read_exr(args.envmap) if args.envmap else None
        out = synth_photo_set(args.out, _levels(args.levels, design), material=args.material,
                              effects=parse_effects(args.effects), seed=args.seed, spp=args.spp,
                              envmap=envmap, exposure=args.exposure)
    except (ValueError, FileExistsError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"photo set: {out} (ground truth in {out / 'truth.json'})")
    return 0


def _cmd_synth_lights(args) -> int:
    from stimuli.glossfit.lightsynth import synth_light_set

    try:
        synth_light_set(args.out, size=args.size, n_lights=args.lights, material=args.material,
                        seed=args.seed, spp=args.spp)
    except (ValueError, FileExistsError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"photo set: {args.out} ({args.lights} lights; truth in {args.out}/truth.json)")
    return 0


def _spp_default(cmd):
    """``cmd`` told whether --spp was given (its default depends on the photo set's kind)."""
    def run(args):
        args.spp_given = args.spp is not None
        return cmd(args)
    return run


def register(subparsers) -> None:
    """Add ``fit-gloss`` and ``synth-photos`` to ``python -m stimuli``'s subcommands."""
    p = subparsers.add_parser(
        "fit-gloss", help="fit Ward parameters to HDR photos of the gloss spheres",
        description="Fit Ward parameters (rho_d, rho_s, alpha) to a photo set (protocol.md, "
                    "'Gloss fitting'); writes gloss_table.csv, fits.csv, residuals/, figures/, "
                    "fit.json and report.html into OUT.")
    p.add_argument("photo_set", help="folder with setup.toml, envmap.exr, photos/gloss_XXX.exr; or "
                   "a directional-light set (filenames.txt, images/, light_directions.txt, "
                   "light_intensities.txt, mask.png)")
    p.add_argument("--lights", default=None,
                   help="directional-light sets: the lights to fit, counted from 1, e.g. 1-24 "
                        "(default: all); the others can be held out (python -m analysis gap "
                        "diagnose --layer render --real SET --lights 25-48 --sim OUT); panorama "
                        "sets in several lightings (lightings/NAME/): the lighting to fit, "
                        "e.g. day (hold another out the same way)")
    p.add_argument("--min-cos", type=float, default=0.1,
                   help="directional-light sets: fit pixels with n.l above this (default 0.1)")
    p.add_argument("--out", required=True, help="new output folder")
    p.add_argument("--method", choices=("basis", "grid"), default="basis",
                   help="basis: closed-form albedos + 1-D alpha search (default); grid: the "
                        "source study's shrinking 2-D grid")
    p.add_argument("--resolution", type=int, default=64, help="fit render size, px (default 64)")
    p.add_argument("--spp", type=int, default=None,
                   help="samples per pixel (default 36; directional-light sets 4)")
    p.add_argument("--seed", type=int, default=0, help="sampler seed of the fit renders")
    p.add_argument("--alpha-min", type=float, default=0.01)
    p.add_argument("--alpha-max", type=float, default=0.5)
    p.add_argument("--grid-points", type=int, default=5, help="grid points per axis (odd)")
    p.add_argument("--max-highlight-offset", type=float, default=3.0,
                   help="flag registrations whose highlights lie further apart (fit px)")
    p.set_defaults(func=_spp_default(_cmd_fit))

    s = subparsers.add_parser(
        "synth-photos", help="render a synthetic photo set (tests, demo)",
        description="Render 'photos' of the gloss spheres with camera effects; ground truth in "
                    "truth.json.")
    s.add_argument("out", help="new folder")
    s.add_argument("--material", choices=("rich", "ward"), default="rich",
                   help="rich: clear coat over a diffuse base (roughplastic, with Fresnel); "
                        "ward: the fit's own model")
    s.add_argument("--effects", default=None,
                   help="'none' or a comma list of misregistration, glare, vignetting, noise, "
                        "clipping, each with optional ':key=value;key=value' (default: "
                        "misregistration,glare,vignetting,noise)")
    s.add_argument("--levels", default=None, help="gloss %% to render, e.g. 0,50,100 (default: all)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--spp", type=int, default=64)
    s.add_argument("--envmap", default=None, help="a lat-long .exr (default: a procedural room)")
    s.add_argument("--exposure", type=float, default=1.0,
                   help="photo units per panorama unit (default 1)")
    s.set_defaults(func=_cmd_synth)

    t = subparsers.add_parser(
        "synth-lights", help="render a synthetic directional-light photo set (tests, demo)",
        description="A sphere under a ring of directional lights, DiLiGenT's layout (16-bit "
                    "PNGs, light_directions.txt, light_intensities.txt, mask.png); fit it with "
                    "fit-gloss --lights and hold the other lights out.")
    t.add_argument("out", help="new folder")
    t.add_argument("--size", type=int, default=48, help="photo width = height, px (default 48)")
    t.add_argument("--lights", type=int, default=12, help="number of lights (default 12)")
    t.add_argument("--material", choices=("rich", "ward"), default="rich",
                   help="rich: clear-coated plastic (roughplastic); ward: the fit's own model")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--spp", type=int, default=16)
    t.set_defaults(func=_cmd_synth_lights)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m stimuli.glossfit")
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
