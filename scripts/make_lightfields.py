"""Build the shipped light fields (stimuli/probes/*_WxH.hdr) and their manifest from the captures.

    PYTHONPATH=. .venv/bin/python scripts/make_lightfields.py ../shared/data/hdr/polyhaven --check
    PYTHONPATH=. .venv/bin/python scripts/make_lightfields.py ../shared/data/hdr/polyhaven \\
        --out NEW_FOLDER [--factor 2]

For each capture listed in SOURCE/SOURCES.tsv (Poly Haven, CC0, 1024 x 512 Radiance RGBE,
linear, unclipped): shrink it by ``--factor`` (2, the default, gives the shipped 512 x 256) with
the solid-angle-weighted box filter (``stimuli.illumination.downsample_latlong``, which keeps the
power from every region of the sphere), write it as run-length encoded RGBE into ``--out``, and
write a row of ``--out``/lightfields.tsv: the file, its kind and scene, the source file and its
SHA-256, where the source came from (repository, commit, path), the licence, both resolutions,
the file's SHA-256, and its scale by the design's rule (a matte white facing the viewer has
luminance 1, ``stimuli.diffuse_white_scale``). Prints the ``light_fields`` lines of design.toml.
``--check`` rebuilds in a temporary folder and compares with what is shipped (exit 1 if any file
or row differs).

Nothing is replaced: ``--out`` must not hold lightfields.tsv or any file the build writes (the
shipped folder, stimuli/probes, holds them all: its provenance table is a record). To change
what is shipped, build into a new folder, compare, and copy by hand.
"""

from __future__ import annotations

import argparse
import csv
import io
import sys
from pathlib import Path

from labfiles import atomic_write_text
from stimuli.illumination import SHIPPED_PROBES, diffuse_white_scale, downsample_latlong
from stimuli.manifest import sha256_file
from stimuli.rgbe import read_rgbe, write_rgbe

MANIFEST = SHIPPED_PROBES / "lightfields.tsv"
COLUMNS = ["file", "kind", "light_field", "scene", "resolution", "sha256", "scale_diffuse_white",
           "source_file", "source_resolution", "source_sha256", "downsampling", "origin",
           "licence", "author_site"]


def read_sources(source: Path, factor: int) -> list[dict]:
    """The rows of SOURCE/SOURCES.tsv, each with its capture read (``"image"``), checked first.

    Raises
    ------
    ValueError
        A missing folder, table or capture, or a factor that does not divide a capture's sides.
    """
    table = source / "SOURCES.tsv"
    if not table.is_file():
        what = "no such folder" if not source.is_dir() else "not a capture folder"
        raise ValueError(f"{source} holds no SOURCES.tsv ({what}); give the folder of the 1k "
                         "captures, e.g. ../shared/data/hdr/polyhaven")
    with open(table, encoding="utf-8", newline="") as fh:
        sources = list(csv.DictReader(fh, delimiter="\t"))
    for src in sources:
        if not (source / src["file"]).is_file():
            raise ValueError(f"{table} lists {src['file']}, which is not in {source}; restore it")
        src["image"] = read_rgbe(source / src["file"])
        h, w = src["image"].shape[:2]
        if factor < 1 or h % factor or w % factor:
            fits = [f for f in (1, 2, 4, 8, 16) if not h % f and not w % f]
            raise ValueError(f"--factor {factor} does not divide {src['file']}'s {w} x {h} px "
                             f"(a pixel cannot be split); use one of {fits} (2 gives the shipped "
                             f"{w // 2} x {h // 2})")
    return sources


def build(sources: list[dict], source: Path, factor: int, out_dir: Path) -> list[dict]:
    rows = []
    for src in sources:
        small = downsample_latlong(src["image"], factor)
        h, w = small.shape[:2]
        name = src["file"].removesuffix(".hdr").removesuffix("_1k")
        out = out_dir / f"{name}_{w}x{h}.hdr"
        write_rgbe(out, small)
        shipped = read_rgbe(out)  # the scale of what is shipped, RGBE rounding included
        rows.append({
            "file": out.name, "kind": src["class"], "light_field": name, "scene": src["scene"],
            "resolution": f"{w}x{h}", "sha256": sha256_file(out),
            "scale_diffuse_white": f"{diffuse_white_scale(shipped):.6g}",
            "source_file": src["file"], "source_resolution": src["resolution"],
            "source_sha256": sha256_file(source / src["file"]),
            "downsampling": f"solid-angle-weighted {factor}x{factor} box mean, RGBE RLE",
            "origin": src["origin"], "licence": src["licence"], "author_site": src["author_site"],
        })
    return rows


def _taken(sources: list[dict], factor: int, out_dir: Path) -> list[str]:
    """The files of a build already in ``out_dir`` (which it would replace)."""
    names = ["lightfields.tsv"]
    for src in sources:
        h, w = (n // factor for n in src["image"].shape[:2])
        names.append(f"{src['file'].removesuffix('.hdr').removesuffix('_1k')}_{w}x{h}.hdr")
    return [n for n in names if (out_dir / n).exists()]


def _tsv(rows: list[dict]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, COLUMNS, delimiter="\t", lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return buf.getvalue()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("source", type=Path, help="folder with SOURCES.tsv and the 1k .hdr files")
    ap.add_argument("--factor", type=int, default=2,
                    help="shrink factor (2, the default: the shipped 512 x 256; 4: 256 x 128)")
    ap.add_argument("--out", type=Path, help="a new folder for the light fields and their "
                    "lightfields.tsv (never the shipped stimuli/probes: nothing is replaced)")
    ap.add_argument("--check", action="store_true",
                    help="rebuild into a temporary folder and compare with what is shipped")
    args = ap.parse_args(argv)
    try:
        return _run(args)
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


def _run(args) -> int:
    if not args.check and args.out is None:
        raise ValueError("give --out NEW_FOLDER for the light fields (the shipped ones in "
                         f"{SHIPPED_PROBES} and their provenance table are never replaced), or "
                         "--check to compare a rebuild with them")
    sources = read_sources(args.source, args.factor)
    if args.check:
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            rows = build(sources, args.source, args.factor, Path(tmp))
        shipped = MANIFEST.read_text(encoding="utf-8") if MANIFEST.is_file() else ""
        bad = [r["file"] for r in rows if not (SHIPPED_PROBES / r["file"]).is_file()
               or sha256_file(SHIPPED_PROBES / r["file"]) != r["sha256"]]
        same = shipped == _tsv(rows)
        print(f"{len(rows)} light fields rebuilt: {len(bad)} differ from the shipped files "
              f"{bad}; manifest {'identical' if same else 'DIFFERS'}")
        return 0 if not bad and same else 1
    taken = _taken(sources, args.factor, args.out)
    if taken:
        raise ValueError(f"{args.out} already holds {', '.join(taken[:4])}"
                         f"{' ...' if len(taken) > 4 else ''}, which this build would replace "
                         "(the shipped light fields' table is a record); give a new --out folder")
    args.out.mkdir(parents=True, exist_ok=True)
    rows = build(sources, args.source, args.factor, args.out)
    atomic_write_text(args.out / "lightfields.tsv", _tsv(rows))
    print(f"wrote {len(rows)} light fields and {args.out / 'lightfields.tsv'}; design.toml "
          "[imagestats] (files given by path unless copied into stimuli/probes):")
    print("light_fields = [")
    for r in rows:
        print(f'  {{ name = "{r["light_field"]}", kind = "{r["kind"]}", '
              f'envmap = "{r["file"]}", scale = {r["scale_diffuse_white"]} }},')
    print("]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
