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

from labfiles import LabFileError, append_csv_record, atomic_open, read_csv_records

__all__ = [
    "MANIFEST_COLUMNS",
    "TONEMAP_COLUMNS",
    "ManifestError",
    "append_manifest_row",
    "check_one_calibration",
    "load_manifest",
    "record_tone_curves",
    "sha256_file",
    "verify_folder",
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
#: ``tonemaps.csv``: per light field, its probe and the tone curve of its PNGs
#: (:mod:`stimuli.tonemap`; L_max over the images of the light field in the folder).
TONEMAP_COLUMNS = ["light_field", "illumination", "envmap", "envmap_sha256", "envmap_scale",
                   "n_images", "lmax_percentile", "tonemap_lmax", "knee_luminance",
                   "logistic_rate", "linear_fraction", "knee_value", "max_value"]
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
                                        "calibration_sha256": str, "envmap_sha256": str})
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


def verify_folder(folder: str | Path) -> list[str]:
    """Check a rendered folder as a whole: the manifest's files (:func:`verify_manifest`, PNGs
    and EXRs), the rendered files it does not list, and ``tonemaps.csv`` against it.

    A file under ``exr/`` or ``png/`` that the manifest does not list is a render not finished
    (pass 2 appends the rows) or a manifest that lost rows. ``tonemaps.csv`` must name each
    light field of the manifest once, with its L_max, probe and checksum, and a curve whose
    numbers agree with one another (L_k = f L_max; s = v_k / (L_k (v_max - v_k)),
    :mod:`stimuli.tonemap`): a hand edit breaks one of these.

    Returns
    -------
    list of str
        One message per problem, naming the file and the fix; empty when all is well.
    """
    folder = Path(folder)
    root = folder if folder.is_dir() else folder.parent
    problems = verify_manifest(folder, kinds=("png", "exr"))
    frame = load_manifest(folder)
    listed = set(frame["exr_path"].astype(str)) | set(frame["png_path"].astype(str))
    stray = sorted(str(f.relative_to(root).as_posix()) for kind in ("exr", "png")
                   for f in (root / kind).rglob(f"*.{kind}")
                   if not f.name.startswith(".") and f.relative_to(root).as_posix() not in listed)
    problems += [f"{root / rel}: rendered but not in the manifest (a render that did not finish, "
                 "or a manifest that lost rows); re-run the same `stimuli render` command to "
                 "finish it (finished EXRs are not rendered again), or restore the manifest"
                 for rel in stray]
    return problems + _tone_curve_problems(root, frame)


def _tone_curve_problems(root: Path, frame: pd.DataFrame) -> list[str]:
    """``tonemaps.csv`` against the manifest and against itself (:func:`verify_folder`)."""
    import numpy as np

    path = root / "tonemaps.csv"
    fix = (f"{path} was changed after rendering; restore it (the manifest's tonemap_lmax is the "
           "record), or render the set again into a new --out folder")
    if not path.is_file():
        return [f"{path} is missing: the PNGs' tone curves are not recorded; restore it"] if (
            root / "renders.csv").is_file() else []
    try:
        curves = read_csv_records(path, repair=False, dtype={"light_field": str,
                                                             "envmap_sha256": str})
    except (LabFileError, pd.errors.ParserError, pd.errors.EmptyDataError) as exc:
        return [f"{path} is not readable ({exc}); restore it"]
    need = {"light_field", "tonemap_lmax", "envmap_sha256", "knee_luminance", "logistic_rate",
            "linear_fraction", "knee_value", "max_value"}
    if not need <= set(curves.columns) or curves["light_field"].duplicated().any():
        return [(f"{path} lacks columns {sorted(need - set(curves.columns))} or repeats a light "
                f"field; {fix}")]
    curves = curves.set_index("light_field")
    problems = []
    for lf, rows in frame.groupby(frame["light_field"].astype(str)):
        if lf not in curves.index:
            problems.append(f"{path} has no tone curve of light field {lf!r}; {fix}")
            continue
        c = curves.loc[lf]
        knee = c["linear_fraction"] * c["tonemap_lmax"]
        rate = c["knee_value"] / (c["knee_luminance"] * (c["max_value"] - c["knee_value"]))
        if not (np.allclose(rows["tonemap_lmax"].astype(float), c["tonemap_lmax"], rtol=1e-6)
                and set(rows["envmap_sha256"].astype(str)) == {str(c["envmap_sha256"])}
                and np.isclose(c["knee_luminance"], knee, rtol=1e-6)
                and np.isclose(c["logistic_rate"], rate, rtol=1e-6)):
            problems.append(f"{path}: the curve of light field {lf!r} (L_max "
                            f"{c['tonemap_lmax']:.6g}, L_k {c['knee_luminance']:.6g}, s "
                            f"{c['logistic_rate']:.6g}) is not "
                            f"the one its {len(rows)} PNGs were made with (the manifest's L_max "
                            f"{float(rows['tonemap_lmax'].iloc[0]):.6g}); {fix}")
    return problems


def check_one_calibration(manifest_path: Path, calibration, calibration_sha256: str) -> None:
    """One manifest, one gamma correction: a resume into a folder whose PNGs were corrected
    for another calibration is refused before anything is rendered. Another calibration is
    another id, or the same id in a file of other content (a recalibration that kept its id:
    the SHA-256 the manifest records differs from ``calibration_sha256``)."""
    if not manifest_path.exists():
        return
    manifest = load_manifest(manifest_path)
    ids = sorted(set(manifest["calibration_id"].astype(str)))
    if ids and ids != [calibration.calibration_id]:
        raise ManifestError(
            f"{manifest_path} lists PNGs gamma-corrected for calibration {ids}; this run uses "
            f"{calibration.calibration_id!r}, and one manifest holds one calibration's images: "
            f"render into a new --out folder, or pass the calibration of {ids[0]!r} with "
            "--calibration to finish this set")
    shas = sorted(set(manifest["calibration_sha256"].astype(str)) - {""})
    if calibration_sha256 and shas and shas != [calibration_sha256]:
        from calibration import display_model_words

        raise ManifestError(
            f"{manifest_path} lists PNGs gamma-corrected for calibration {ids[0]!r} as in the "
            f"file of SHA-256 {' and '.join(shas)}; this run's calibration {ids[0]!r} is "
            f"another file (SHA-256 {calibration_sha256}: "
            f"{display_model_words(calibration.display_model)}): the display was recalibrated "
            "under the same id, and one manifest holds one calibration's images: render into a "
            "new --out folder, or pass the calibration file the folder was rendered with "
            "(`sha256sum` shows which) with --calibration to finish this set")


def record_tone_curves(path: Path, curves: list[dict]) -> None:
    """Write ``tonemaps.csv``: this run's light fields, and those of earlier runs into the same
    folder that this run did not touch (kept as recorded)."""
    frame = pd.DataFrame(curves, columns=TONEMAP_COLUMNS)
    if path.is_file():
        old = read_csv_records(path, dtype={"light_field": str, "envmap_sha256": str})
        old = old[~old["light_field"].isin(frame["light_field"])]
        frame = pd.concat([old[TONEMAP_COLUMNS], frame], ignore_index=True)
    with atomic_open(path, "w", newline="", encoding="utf-8") as fh:
        frame.to_csv(fh, index=False)
