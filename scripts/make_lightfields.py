"""Build the shipped light fields (stimuli/probes/*_WxH.hdr) and their manifest from the captures.

    PYTHONPATH=. .venv/bin/python scripts/make_lightfields.py ../shared/data/hdr/polyhaven \\
        --factor 4 [--check]

For each capture listed in SOURCE/SOURCES.tsv (Poly Haven, CC0, 1024 x 512 Radiance RGBE,
linear, unclipped): shrink it by ``--factor`` with the solid-angle-weighted box filter
(``stimuli.illumination.downsample_latlong``, which keeps the power from every region of the
sphere), write it as run-length encoded RGBE into stimuli/probes/, and append a row to
stimuli/probes/lightfields.tsv: the shipped file, its kind and scene, the source file and its
SHA-256, where the source came from (repository, commit, path), the licence, both resolutions,
the shipped file's SHA-256, and its scale by the design's rule (a matte white facing the viewer
has luminance 1, ``stimuli.diffuse_white_scale``). Prints the ``light_fields`` lines of
design.toml. ``--check`` rebuilds in memory and compares with what is shipped (exit 1 if any
file or row differs).
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


def build(source: Path, factor: int, out_dir: Path) -> list[dict]:
    rows = []
    with open(source / "SOURCES.tsv", encoding="utf-8", newline="") as fh:
        sources = list(csv.DictReader(fh, delimiter="\t"))
    for src in sources:
        original = read_rgbe(source / src["file"])
        small = downsample_latlong(original, factor)
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


def _tsv(rows: list[dict]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, COLUMNS, delimiter="\t", lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return buf.getvalue()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("source", type=Path, help="folder with SOURCES.tsv and the 1k .hdr files")
    ap.add_argument("--factor", type=int, default=4, help="shrink factor (4: 256 x 128)")
    ap.add_argument("--check", action="store_true",
                    help="rebuild into a temporary folder and compare with what is shipped")
    args = ap.parse_args()
    if args.check:
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            rows = build(args.source, args.factor, Path(tmp))
        shipped = MANIFEST.read_text(encoding="utf-8") if MANIFEST.is_file() else ""
        bad = [r["file"] for r in rows if not (SHIPPED_PROBES / r["file"]).is_file()
               or sha256_file(SHIPPED_PROBES / r["file"]) != r["sha256"]]
        same = shipped == _tsv(rows)
        print(f"{len(rows)} light fields rebuilt: {len(bad)} differ from the shipped files "
              f"{bad}; manifest {'identical' if same else 'DIFFERS'}")
        return 0 if not bad and same else 1
    rows = build(args.source, args.factor, SHIPPED_PROBES)
    atomic_write_text(MANIFEST, _tsv(rows))
    print(f"wrote {len(rows)} light fields and {MANIFEST}; design.toml [imagestats]:")
    print("light_fields = [")
    for r in rows:
        print(f'  {{ name = "{r["light_field"]}", kind = "{r["kind"]}", '
              f'envmap = "{r["file"]}", scale = {r["scale_diffuse_white"]} }},')
    print("]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
