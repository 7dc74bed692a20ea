"""Image statistics: images per second on 1 and 2 Dask workers, side by side.

    .venv/bin/python bench/imagestats_workers.py [--render-dir DIR] [--n 48] [--size 256]

Without --render-dir, writes ``--n`` luminance EXRs of ``--size`` px with the renderer's geometry
(image 7.4 cm wide on the array's plane, so the 5 cm array square is 173 px at 256 px and the
Portilla-Simoncelli window 160 px) into a temporary folder; the statistics' cost depends on the
image size, not on its content. Each worker count gets its own LocalCluster, warmed up (imports,
PS model) before timing, so the figures are steady-state throughput; cluster start-up is printed
apart. Also prints the mean per-image cost measured inside the workers (``stats_s``).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import OpenEXR

from analysis.imagestats import StatsConfig, compute_stats, dask_client, load_stats
from stimuli import MANIFEST_COLUMNS, append_manifest_row, sha256_file
from studydesign import load_design

IMAGE_WIDTH_CM = 7.4  # the renderer's image width at the design's viewing geometry (manifest)


def write_images(folder: Path, n: int, size: int, rng: np.random.Generator) -> None:
    (folder / "exr").mkdir(parents=True)
    for k in range(n):
        sid = f"bench_{k:05d}"
        lum = rng.gamma(2.0, 0.25, size=(size, size)).astype(np.float32)
        exr = folder / "exr" / f"{sid}.exr"
        OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                     {"Y": lum}).write(str(exr))
        png = folder / "exr" / f"{sid}.png"
        png.write_bytes(b"")  # the statistics never read PNGs; the manifest wants one listed
        append_manifest_row(folder / "manifest.csv", dict.fromkeys(MANIFEST_COLUMNS, "") | {
            "stimulus_id": sid, "illumination": "indoor", "gloss_level": 2, "depth_level": 2,
            "true_gloss_pct": 10.0, "true_depth_cm": 0.8, "light_field": "bench",
            "array_index": k, "width_px": size, "height_px": size,
            "image_width_cm": IMAGE_WIDTH_CM, "exr_path": f"exr/{sid}.exr",
            "png_path": f"exr/{sid}.png", "exr_sha256": sha256_file(exr),
            "png_sha256": sha256_file(png)})


def run(render_dir: Path, tmp: Path, workers: int, batch_size: int, ps: bool) -> dict:
    design = load_design()
    config = StatsConfig(ps=ps)
    t0 = time.perf_counter()
    with dask_client(workers=workers) as client:
        started = time.perf_counter() - t0
        client.run(_warm_up)  # imports and the PS model on every worker, before timing
        out = tmp / f"stats{workers}.parquet"
        t1 = time.perf_counter()
        result = compute_stats(render_dir, out, design=design, config=config,
                               scheduler=client.scheduler.address, batch_size=batch_size,
                               progress=False)
        wall = time.perf_counter() - t1
    if not result.ok:
        sys.exit(f"problems: {result.problems[:3]}")
    frame = load_stats(out)
    return {"workers": workers, "images": result.n_computed, "wall_s": wall,
            "img_per_s": result.n_computed / wall, "start_s": started,
            "stats_s_mean": float(frame["stats_s"].mean())}


def _warm_up() -> None:
    import torch  # noqa: F401

    from analysis.imagestats import ps_names, ps_statistics

    ps_statistics(np.random.default_rng(0).random((160, 160)))
    ps_names(160)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--render-dir", type=Path, help="a real render folder (default: synthetic)")
    parser.add_argument("--n", type=int, default=48, help="synthetic images (default 48)")
    parser.add_argument("--size", type=int, default=256, help="synthetic image side, px")
    parser.add_argument("--batch-size", type=int, default=4)
    parser.add_argument("--no-ps", action="store_true")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        render_dir = args.render_dir
        if render_dir is None:
            render_dir = tmp / "renders"
            write_images(render_dir, args.n, args.size, np.random.default_rng(0))
        rows = [run(render_dir, tmp, w, args.batch_size, not args.no_ps) for w in (1, 2)]
    print(f"{'workers':>7} {'images':>6} {'wall s':>7} {'img/s':>7} {'per-image s':>11} "
          f"{'cluster start s':>15}")
    for r in rows:
        print(f"{r['workers']:>7} {r['images']:>6} {r['wall_s']:>7.2f} {r['img_per_s']:>7.2f} "
              f"{r['stats_s_mean']:>11.4f} {r['start_s']:>15.1f}")
    print(f"speed-up 2 vs 1 workers: {rows[1]['img_per_s'] / rows[0]['img_per_s']:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
