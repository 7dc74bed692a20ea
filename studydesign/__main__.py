"""``python -m studydesign``: show, check and export the study design."""

from __future__ import annotations

import argparse
import errno
import json
import os
import sys

from studydesign.design import DesignError, load_design


def _summary(design) -> str:
    g, d, a = design.gloss, design.depth, design.array
    lines = [
        f"design file: {design.source}",
        (
            f"gloss: {g.n_levels} physical levels "
            f"{g.physical_pct[0]:g}-{g.physical_pct[-1]:g} % (labels 1-{g.n_levels}); "
            f"rendered labels {g.rendered_levels[0]}-{g.rendered_levels[-1]} "
            f"({g.rendered_pct[0]:g}-{g.rendered_pct[-1]:g} %)"
        ),
        (
            f"depth: d_i = {d.step_cm:g} * i cm, i = 1..{d.n_levels} "
            f"({d.physical_cm[0]:g}-{d.physical_cm[-1]:g} cm); rendered levels "
            f"{d.rendered_levels[0]}-{d.rendered_levels[-1]} "
            f"({d.rendered_cm[0]:g}-{d.rendered_cm[-1]:g} cm)"
        ),
        (
            f"array: {a.n_x}x{a.n_y} half-ellipsoids over {a.extent_cm:g} cm, "
            f"pitch {a.pitch_cm:g} cm, "
            f"x/y radius {a.radius_xy_cm:g} cm, jitter +-{a.jitter_cm:g} cm"
        ),
        (
            "illuminations: "
            + ", ".join(f"{il.name} ({il.kind}, {il.envmap}, "
                        + (f"scale {il.scale:.4g})" if il.scale is not None
                           else "scaled to mean luminance 1)")
                        for il in design.illuminations)
        ),
        (
            f"stimuli: {design.n_stimuli} in {design.sessions.n_sessions} sessions of "
            f"{design.sessions.trials_per_session} trials"
        ),
        (
            f"image-statistics set: {design.imagestats.n_light_fields} light fields x "
            f"{design.gloss.n_levels} gloss x {design.depth.n_levels} depth x "
            f"{design.imagestats.n_arrays} arrays = {design.n_imagestats_images} images"
        ),
        _light_fields(design),
        (
            f"display: {design.display.resolution_px[0]}x{design.display.resolution_px[1]} px at "
            f"{design.display.viewing_distance_cm:g} cm"
        ),
        (
            f"slider: {design.slider.min:g}-{design.slider.max:g}; depth_cm = "
            f"{design.slider.depth_cm_per_unit:g} v, "
            f"gloss_pct = {design.slider.gloss_pct_per_unit:g} (v - 1)"
        ),
    ]
    return "\n".join(lines)


#: Why each light field has the scale it has, per ``[imagestats] scale_rule``.
_SCALE_WHY = {
    "diffuse_white": "the captures are not absolutely calibrated (each file has its own "
    "arbitrary scale); each is scaled so that a matte white facing the viewer has luminance 1 "
    "(relative units) under it: the light fields then differ in how their light is laid out, "
    "not in the exposure of the file, as for an observer adapted to each scene, and light from "
    "behind the array (which never reaches its visible side) does not set the scale, as it "
    "would if the mean luminance were equalised; the PNGs' range is set per light field by "
    "the tone map anyway (protocol.md, section 4)",
}


def _light_fields(design) -> str:
    lfs = design.imagestats.light_fields
    kinds = {k: sum(lf.kind == k for lf in lfs) for k in ("indoor", "outdoor")}
    files = {lf.envmap for lf in lfs}
    head = (f"light fields: {len(lfs)} ({kinds['indoor']} indoor, {kinds['outdoor']} "
            f"outdoor), {len(files)} distinct files; scale rule "
            f"{design.imagestats.scale_rule}: {_SCALE_WHY[design.imagestats.scale_rule]}")
    lines = [head]
    width = max(len(lf.name) for lf in lfs)
    for lf in lfs:
        lines.append(f"  {lf.kind:7s} {lf.name:{width}s}  {lf.envmap}  scale {lf.scale:.6g}")
    return "\n".join(lines)


def _check(design) -> int:
    """The design check: the file's values (checked on loading), then every panorama it names
    (read from the design's folder where relative): a light field, at its own scale."""
    from stimuli.probecheck import design_light_field_report

    problems, warnings = design_light_field_report(design)
    for w in warnings:
        print(f"warning: {w}", file=sys.stderr)
    if problems:
        print(f"error: {design.source}: {len(problems)} problem(s) with its panoramas:\n  "
              + "\n  ".join(problems), file=sys.stderr)
        return 1
    files = {il.envmap for il in design.illuminations} | {
        lf.envmap for lf in design.imagestats.light_fields}
    print(f"ok: {design.source} is a valid design ({design.n_stimuli} stimuli)\n"
          f"ok: its {len(files)} panoramas are light fields at their own scales")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``python -m studydesign``: one subparser per subcommand."""
    parser = argparse.ArgumentParser(
        prog="python -m studydesign", description="Show, check and export the study design."
    )
    parser.add_argument("--design", help="a design.toml (default: the shipped one)")
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("show", help="print a summary of the design")
    sub.add_parser("check", help="validate the design file; exit 1 with the reason if invalid")
    st = sub.add_parser("stimuli", help="write the stimulus table as CSV")
    st.add_argument("--out", default="-", help="CSV path, '-' for stdout (never replaced "
                                               "without --force)")
    st.add_argument("--force", action="store_true", help="replace an existing --out")
    sub.add_parser("json", help="print the design as JSON")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        design = load_design(args.design)
    except DesignError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    if args.command == "show":
        print(_summary(design))
    elif args.command == "check":
        return _check(design)
    elif args.command == "stimuli":
        table = design.stimuli()
        if args.out == "-":
            table.to_csv(sys.stdout, index=False)
        else:
            from pathlib import Path

            from labfiles import atomic_write_text
            from labfiles.outdir import write_error_line

            out = Path(args.out)
            if out.is_dir():
                print(f"error: --out {out} is a folder; name the CSV file to write, e.g. "
                      f"--out {out / 'stimuli.csv'}", file=sys.stderr)
                return 1
            if out.exists() and not args.force:
                print(f"error: {out} exists and would be replaced by the stimulus table; "
                      "choose another --out, or add --force to replace it", file=sys.stderr)
                return 1
            try:  # a missing or read-only folder: one line, with the fix
                folder = os.path.dirname(os.path.abspath(out))
                if not os.path.isdir(folder):
                    raise FileNotFoundError(errno.ENOENT, "no such folder", folder)
                atomic_write_text(out, table.to_csv(index=False))
            except OSError as exc:
                print(f"error: {write_error_line(exc)}", file=sys.stderr)
                return 1
    elif args.command == "json":
        print(json.dumps(design.to_dict(), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
