"""A contact sheet: the PNGs of a rendered folder tiled in one labelled image, to look at."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from labfiles import atomic_open
from stimuli.manifest import load_manifest

__all__ = ["contact_sheet"]


def contact_sheet(folder: str | os.PathLike, out_png: str | os.PathLike, *, columns: int = 0,
                  tile_px: int = 160, max_images: int = 200) -> Path:
    """Tile a rendered folder's PNGs (manifest order) with their stimulus ids; write atomically.

    Parameters
    ----------
    folder : path-like
        A folder with ``manifest.csv``.
    out_png : path-like
        The sheet to write.
    columns : int
        Tiles per row; 0 = one row per (light field, gloss level) when that fits, else square-ish.
    tile_px : int
        Size each PNG is scaled to.
    max_images : int
        At most this many tiles (the first in manifest order).
    """
    from PIL import Image, ImageDraw

    frame = load_manifest(folder)
    root = Path(frame.attrs["manifest_path"]).parent
    frame = frame.sort_values(["light_field", "gloss_level", "depth_level", "stimulus_id"])
    frame = frame.head(max_images)
    n = len(frame)
    if columns <= 0:
        per_row = frame.groupby(["light_field", "gloss_level"]).size().max()
        columns = int(per_row) if per_row * 2 >= np.sqrt(n) else int(np.ceil(np.sqrt(n)))
    rows = int(np.ceil(n / columns))
    label_px = 14
    sheet = Image.new("L", (columns * tile_px, rows * (tile_px + label_px)), color=255)
    draw = ImageDraw.Draw(sheet)
    for k, row in enumerate(frame.itertuples(index=False)):
        with Image.open(root / row.png_path) as im:
            tile = im.convert("L").resize((tile_px, tile_px), Image.Resampling.LANCZOS)
        x, y = (k % columns) * tile_px, (k // columns) * (tile_px + label_px)
        sheet.paste(tile, (x, y))
        label = str(row.stimulus_id)
        if tile_px < 8 * len(label):  # too narrow for the id: gloss and depth levels only
            label = f"g{int(row.gloss_level):02d} d{int(row.depth_level):02d}"
        draw.text((x + 2, y + tile_px + 1), label, fill=0)
    out = Path(out_png)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(out, "wb") as fh:
        sheet.save(fh, format="PNG")
    return out
