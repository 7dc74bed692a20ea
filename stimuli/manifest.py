"""The render manifest: one CSV row per rendered stimulus, the contract between stimuli and its users.

The experiment checks a manifest before a session (every PNG present, checksums match); analysis
keys image statistics by it. Paths in the manifest are relative to the manifest's folder.

Columns written by ``python -m stimuli render`` (protocol.md section 4): the stimulus's levels and
true values, ``light_field`` (its tone-mapping condition), ``array_index`` and ``seed`` (of the
array), the Ward ``rho_d, rho_s, alpha``, ``spp`` (multijitter's real count), ``width_px,
height_px``, ``image_width_cm`` (show the image this wide on the CRT: physical size) and
``distance_cm`` (the viewing distance it was rendered for), the Mitsuba ``variant``, the probe
(``envmap``, ``envmap_sha256``, ``rotation_deg``), ``tonemap_lmax`` (L_max of its light field's
tone curve, render units; the whole curve of each light field is in ``tonemaps.csv`` beside the
manifest), ``calibration_id`` (whose inverse gamma the PNG carries), the files and their SHA-256,
and ``calibration_sha256``: the SHA-256 of that calibration's file, so that a recalibration that
kept its id is told apart (empty for the built-in default curve, which has no file, and in
manifests written before the column existed: they still load, and a resumed render appends to
them in their own columns).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import pandas as pd

from labfiles import LabFileError, append_csv_record, read_csv_records

__all__ = [
    "MANIFEST_COLUMNS",
    "ManifestError",
    "append_manifest_row",
    "load_manifest",
    "sha256_file",
    "verify_manifest",
]

MANIFEST_COLUMNS = [
    "stimulus_id",
    "illumination",
    "gloss_level",
    "depth_level",
    "true_gloss_pct",
    "true_depth_cm",
    "light_field",
    "array_index",
    "seed",
    "rho_d",
    "rho_s",
    "alpha",
    "spp",
    "width_px",
    "height_px",
    "image_width_cm",
    "variant",
    "envmap",
    "calibration_id",
    "exr_path",
    "png_path",
    "exr_sha256",
    "png_sha256",
    "envmap_sha256",
    "rotation_deg",
    "tonemap_lmax",
    "distance_cm",
    "calibration_sha256",
]
#: The columns of manifests written before ``calibration_sha256`` (issue 40): read, with that
#: column empty, and appended to in their own layout.
_LEGACY_COLUMNS = MANIFEST_COLUMNS[:-1]


class ManifestError(ValueError):
    """A manifest is missing, malformed, or disagrees with the files beside it."""


def sha256_file(path: str | Path, chunk_bytes: int = 1 << 20) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(chunk_bytes), b""):
            h.update(chunk)
    return h.hexdigest()


def append_manifest_row(path: str | Path, row: dict) -> None:
    """Append one row (all of ``MANIFEST_COLUMNS``) to a manifest, writing the header if new.

    The row is flushed and fsynced before returning, so a crash never loses a finished render's
    record; a torn last row (a crash mid-write) is moved aside first (``labfiles``' rule).
    """
    missing = [c for c in MANIFEST_COLUMNS if c not in row]
    if missing:
        raise ManifestError(f"manifest row lacks {missing}")
    columns = _LEGACY_COLUMNS if _header(path) == _LEGACY_COLUMNS else MANIFEST_COLUMNS
    append_csv_record(path, columns, [row[c] for c in columns])


def _header(path) -> list[str] | None:
    """The names in a manifest's first line (None for a missing or empty file)."""
    try:
        with open(path, "rb") as fh:
            line = fh.readline()
    except FileNotFoundError:
        return None
    text = line.decode("utf-8", "replace").lstrip("\ufeff").rstrip("\r\n")
    return [name.strip('"') for name in text.split(",")] if text else None


def load_manifest(path: str | Path) -> pd.DataFrame:
    """Read and check a manifest CSV.

    Raises
    ------
    ManifestError
        If the file is missing, lacks columns, or repeats a stimulus id.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "manifest.csv"
    if not path.is_file():
        raise ManifestError(
            f"stimulus manifest {path} not found; render the stimuli first "
            "(python -m stimuli render --set experiment --out DIR)"
        )
    try:
        frame = read_csv_records(path, repair=False,
                                 dtype={"stimulus_id": str, "exr_sha256": str, "png_sha256": str,
                                        "calibration_sha256": str})
    except LabFileError as exc:
        raise ManifestError(f"stimulus manifest {exc}") from None
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise ManifestError(f"stimulus manifest {path} is not a readable CSV: {exc}") from exc
    if "calibration_sha256" not in frame.columns:
        frame["calibration_sha256"] = ""  # written before the column existed
    frame["calibration_sha256"] = frame["calibration_sha256"].fillna("")
    missing = [c for c in MANIFEST_COLUMNS if c not in frame.columns]
    if missing:
        raise ManifestError(f"stimulus manifest {path} lacks columns {missing}; re-render with this version")
    dup = frame["stimulus_id"][frame["stimulus_id"].duplicated()].tolist()
    if dup:
        raise ManifestError(f"stimulus manifest {path} lists {dup[:5]} more than once")
    frame.attrs["manifest_path"] = str(path)
    return frame


def verify_manifest(path: str | Path, *, kinds: tuple[str, ...] = ("png",), stimulus_ids=None) -> list[str]:
    """Check that the files a manifest lists exist and match their checksums.

    Parameters
    ----------
    path : path-like
        The manifest CSV (or its folder).
    kinds : tuple of {"png", "exr"}
        Which files to check.
    stimulus_ids : iterable of str, optional
        Check only these stimuli (and report any of them missing from the manifest).

    Returns
    -------
    list of str
        One message per problem, naming the file and the fix; empty when all is well.
    """
    frame = load_manifest(path)
    root = Path(frame.attrs["manifest_path"]).parent
    problems = []
    if stimulus_ids is not None:
        wanted = list(stimulus_ids)
        absent = sorted(set(wanted) - set(frame["stimulus_id"]))
        problems += [f"{sid}: not in the manifest; render it" for sid in absent]
        frame = frame[frame["stimulus_id"].isin(wanted)]
    for row in frame.itertuples(index=False):
        for kind in kinds:
            rel = getattr(row, f"{kind}_path")
            file = root / str(rel)
            if not file.is_file():
                problems.append(f"{row.stimulus_id}: {file} is missing; re-render it")
            elif sha256_file(file) != getattr(row, f"{kind}_sha256"):
                problems.append(
                    f"{row.stimulus_id}: {file} does not match its checksum in the manifest "
                    "(changed after rendering); re-render it"
                )
    return problems
