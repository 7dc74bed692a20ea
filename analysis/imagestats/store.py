"""The statistics table on disk: one Parquet file, built from batch parts so runs can resume.

While a run is going, each finished batch is written at once, atomically, as
``<out>.partial/part-NNNNNN.parquet``; a kill loses only the batches still being computed. At the
end the parts and any earlier ``<out>`` are merged into a new ``<out>`` (``labfiles``' atomic
write), and the parts are removed. The options that define the table (`StatsConfig`, the array
extent) are stored in the Parquet metadata and in ``<out>.partial/meta.json``; resuming with
other options is refused.

A part that does not read as Parquet (a copy cut short, a disk that filled up under another
writer) is moved to ``<out>.damaged/`` with a :class:`DamagedPartWarning` naming it; its images
are not in the table, so the run measures them again.
"""

from __future__ import annotations

import json
import warnings
from datetime import UTC, datetime
from pathlib import Path

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from analysis.imagestats.images import ImageStatsError
from labfiles import TEMPORARY_GLOB, atomic_path, atomic_write_text

__all__ = [
    "META_KEY",
    "DamagedPartWarning",
    "consolidate",
    "discard_parts",
    "has_parts",
    "load_stats",
    "parts_dir",
    "read_done",
    "read_meta",
    "start",
    "write_part",
]

#: Key of the table's options in the Parquet schema metadata.
META_KEY = b"glossdepth.imagestats"


def parts_dir(out: Path) -> Path:
    return out.with_name(out.name + ".partial")


class DamagedPartWarning(UserWarning):
    """A part file did not read and was moved aside; its images are measured again."""


def read_meta(out: Path) -> dict | None:
    """The options stored in a statistics file, or None if it has none."""
    meta = pq.read_schema(out).metadata or {}
    return json.loads(meta[META_KEY]) if META_KEY in meta else None


def load_stats(path: str | Path) -> pd.DataFrame:
    """Read a statistics table written by ``python -m analysis imagestats``.

    Returns
    -------
    DataFrame
        One row per image: the manifest columns, ``region_px``, the pixel statistics, ``stats_s``
        and (unless computed with ``--no-ps``) ``ps_*``; ``frame.attrs["imagestats"]`` holds the
        options it was computed with.

    Raises
    ------
    ImageStatsError
        If the file is missing or not a statistics table.
    """
    path = Path(path)
    if not path.is_file():
        hint = (f"; a run was interrupted: resume it (its parts are in {parts_dir(path)})"
                if parts_dir(path).is_dir() else "")
        raise ImageStatsError(
            f"image statistics {path} not found{hint}; compute them with "
            "`python -m analysis imagestats RENDER_DIR --out FILE`"
        )
    try:
        meta = read_meta(path)
        frame = pd.read_parquet(path)
    except (pa.ArrowInvalid, OSError) as exc:
        raise ImageStatsError(f"{path} is not a readable Parquet file ({exc})") from exc
    if meta is None or "stimulus_id" not in frame.columns:
        raise ImageStatsError(
            f"{path} is not an image-statistics table (no {META_KEY.decode()} metadata)"
        )
    frame.attrs["imagestats"] = meta
    return frame


def start(out: Path, meta: dict) -> None:
    """Check that ``out`` and its parts were made with ``meta``; record it for a new run."""
    if out.exists():
        old = read_meta(out) if out.is_file() else None
        if old != meta:
            raise ImageStatsError(
                f"{out} was computed with other options ({old}) than this run ({meta}); "
                "write to a new --out or rerun with the same options"
            )
    parts = parts_dir(out)
    meta_file = parts / "meta.json"
    if meta_file.is_file():
        old = json.loads(meta_file.read_text())
        if old != meta:
            raise ImageStatsError(
                f"the interrupted run in {parts} used other options ({old}) than this run "
                f"({meta}); rerun with the same options, or remove {parts} to start over"
            )
        return
    parts.mkdir(parents=True, exist_ok=True)
    atomic_write_text(meta_file, json.dumps(meta, sort_keys=True))


def _part_files(parts: Path) -> list[Path]:
    return sorted(parts.glob("part-*.parquet")) if parts.is_dir() else []


def has_parts(out: Path) -> bool:
    """Whether an interrupted run left batches not yet merged into ``out``."""
    return bool(_part_files(parts_dir(out)))


def read_done(out: Path) -> pd.DataFrame:
    """Every row already computed: ``out`` (if it exists) and the parts of an interrupted run
    (a row can appear in both after a kill during `consolidate`; it is then kept once)."""
    frames = [pd.read_parquet(out)] if out.is_file() else []
    frames += [f for f in map(_read_part, _part_files(parts_dir(out))) if f is not None]
    frames = [f for f in frames if len(f)]
    if not frames:
        return pd.DataFrame(columns=["stimulus_id", "exr_sha256"])
    return pd.concat(frames, ignore_index=True).drop_duplicates(
        subset=["stimulus_id", "exr_sha256"], keep="first").reset_index(drop=True)


def _read_part(part: Path) -> pd.DataFrame | None:
    """A part's rows; None when it does not read (it is then moved aside, with a warning)."""
    try:
        return pd.read_parquet(part)
    except (pa.ArrowInvalid, OSError) as exc:
        damaged = part.parent.with_name(part.parent.name.removesuffix(".partial") + ".damaged")
        damaged.mkdir(exist_ok=True)
        stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
        kept = part.rename(damaged / f"{part.stem}-{stamp}{part.suffix}")
        warnings.warn(f"{part} does not read as Parquet ({exc}); moved it to {kept}, and its "
                      "images are measured again", DamagedPartWarning, stacklevel=3)
        return None


def write_part(out: Path, records: list[dict]) -> Path:
    """Write one batch's rows as the next part file, atomically."""
    parts = parts_dir(out)
    existing = _part_files(parts)
    index = int(existing[-1].stem.split("-")[1]) + 1 if existing else 0
    final = parts / f"part-{index:06d}.parquet"
    with atomic_path(final) as tmp:
        pd.DataFrame.from_records(records).to_parquet(tmp, index=False)
    return final


def consolidate(out: Path, meta: dict, columns: list[str]) -> int:
    """Merge ``out`` and the parts into a new ``out`` (atomic), then remove the parts.

    Parameters
    ----------
    columns : list of str
        Column order of the table (the manifest's, then the statistics').

    Returns
    -------
    int
        Rows in the table.
    """
    frame = read_done(out)
    # a kill between the rename of the new table and the removal of the parts leaves rows twice;
    # the same image measured from the same file is the same row
    frame = frame.drop_duplicates(subset=["stimulus_id", "exr_sha256"], keep="first")
    dup = frame["stimulus_id"][frame["stimulus_id"].duplicated()].tolist()
    if dup:
        raise ImageStatsError(
            f"{out} and its parts hold {dup[:5]} more than once; remove {parts_dir(out)} and rerun"
        )
    ordered = [c for c in columns if c in frame.columns]
    ordered += [c for c in frame.columns if c not in ordered]
    frame = frame[ordered].sort_values("stimulus_id", kind="stable").reset_index(drop=True)
    table = pa.Table.from_pandas(frame, preserve_index=False)
    table = table.replace_schema_metadata(
        {**(table.schema.metadata or {}), META_KEY: json.dumps(meta, sort_keys=True).encode()}
    )
    with atomic_path(out) as tmp:
        pq.write_table(table, tmp)
    discard_parts(out)
    return len(frame)


def discard_parts(out: Path) -> None:
    """Remove ``<out>.partial`` once its rows are in ``out`` (or there were none)."""
    parts = parts_dir(out)
    if not parts.is_dir():
        return
    for p in _part_files(parts):
        p.unlink()
    (parts / "meta.json").unlink(missing_ok=True)
    for pattern in (TEMPORARY_GLOB, ".*.tmp"):  # an interrupted write's leftovers
        for leftover in parts.glob(pattern):
            leftover.unlink()
    parts.rmdir()
