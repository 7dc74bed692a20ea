"""Named stimulus sets: which stimuli a render job produces.

* ``experiment``: the design's stimuli (``design.stimuli()``, 162 = 2 illuminations x 9 gloss x
  9 depth). One array per depth level (array index 0), shared by all gloss levels and both
  illuminations, so stimuli of one depth differ only in material and light.
* ``imagestats``: for the image-statistics analysis, every light field of
  ``design.imagestats.light_fields`` (22 captures, 11 indoor and 11 outdoor, each its own file)
  x every physical gloss and depth level (11 x 11) x ``design.imagestats.n_arrays`` arrays
  (seed: 22 x 11 x 11 x 22 = 58,564 images). ``illumination`` is the condition of the light
  field's kind (``design.illumination_of_kind``). Select subsets with filters.
* ``imagestats_slice``: the stratified slice of ``imagestats`` that measures the full set's
  cost and previews its statistics: two images per light field (44), which within each kind
  cover every physical gloss and depth level twice, uncorrelated (:func:`slice_levels`).
* ``preview``: the lowest and highest rendered gloss and depth under both illuminations (8),
  for the demo and tests.

Every row carries ``light_field`` (the tone-mapping condition), ``array_index``, ``seed`` (the
array's, :func:`stimuli.geometry.stimulus_seed`), ``envmap``, ``envmap_scale`` (the factor the
probe file's values are multiplied by; NaN: mean luminance 1) and ``rotation_deg``.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import pandas as pd

from stimuli.geometry import stimulus_seed
from stimuli.illumination import SHIPPED_PROBES
from studydesign import StudyDesign

__all__ = [
    "SET_COLUMNS",
    "SET_NAMES",
    "apply_filters",
    "design_envmap",
    "parse_filters",
    "refuse_mixed_sets",
    "set_family",
    "slice_levels",
    "stimulus_set",
]

SET_NAMES = ("experiment", "imagestats", "imagestats_slice", "preview")
SET_COLUMNS = ["stimulus_id", "illumination", "gloss_level", "depth_level", "true_gloss_pct",
               "true_depth_cm", "light_field", "array_index", "seed", "envmap", "envmap_scale",
               "rotation_deg"]


def design_envmap(design: StudyDesign, envmap: str) -> str:
    """The panorama a design's ``envmap`` names, as recorded in the set and the manifest.

    A relative path is read from the design file's folder (never the current directory, so a
    design renders the same panoramas from wherever the command runs) and given as an absolute
    path; a bare name with no such file there is the shipped probe of that name, given by its
    name. An absolute path is kept. A missing file is returned too (the render names it).
    """
    path = Path(envmap)
    if path.is_absolute():
        return str(path)
    here = Path(design.source).resolve().parent / path
    if not here.is_file() and not path.parent.parts and (SHIPPED_PROBES / path.name).is_file():
        return path.name
    return str(here)


def _experiment(design: StudyDesign) -> pd.DataFrame:
    t = design.stimuli().copy()
    t["light_field"] = t["illumination"]
    t["array_index"] = 0
    t["seed"] = [stimulus_seed(d, 0) for d in t["depth_level"]]
    t["envmap"] = [design_envmap(design, design.illumination(il).envmap)
                   for il in t["illumination"]]
    scales = [design.illumination(il).scale for il in t["illumination"]]
    t["envmap_scale"] = [math.nan if v is None else float(v) for v in scales]
    t["rotation_deg"] = 0.0
    return t[SET_COLUMNS]


def _imagestats_rows(design: StudyDesign, lf, cells) -> list[tuple]:
    """Rows of light field ``lf`` for ``(gloss, depth, array)`` label triples."""
    condition = design.illumination_of_kind(lf.kind)
    pct = dict(zip(design.gloss.labels, design.gloss.physical_pct))
    cm = dict(zip(design.depth.labels, design.depth.physical_cm))
    envmap = design_envmap(design, lf.envmap)
    return [(f"{lf.name}_g{g:02d}_d{d:02d}_a{a:02d}", condition, g, d, pct[g], cm[d], lf.name, a,
             stimulus_seed(d, a), envmap, float(lf.scale), 0.0) for g, d, a in cells]


def _imagestats(design: StudyDesign) -> pd.DataFrame:
    cells = [(g, d, a) for g in design.gloss.labels for d in design.depth.labels
             for a in range(design.imagestats.n_arrays)]
    rows = [r for lf in design.imagestats.light_fields for r in _imagestats_rows(design, lf, cells)]
    return pd.DataFrame(rows, columns=SET_COLUMNS)


def slice_levels(i: int, r: int, kind_index: int, n_gloss: int, n_depth: int) -> tuple[int, int]:
    """Gloss and depth level indices (0-based) of image ``r`` (0 or 1) of the ``i``-th light
    field of a kind in the ``imagestats_slice`` set.

    Image 0: (i, 3 i + k), image 1: (2 i, 2 i + 7 + k), modulo the numbers of levels, with k = 0
    indoor and 1 outdoor. With 11 light fields per kind and 11 levels (the shipped design) each
    kind covers every gloss and every depth level exactly twice, gloss and depth are uncorrelated
    over the kind's 22 images (r = 0.00), and so are the two images' differences in gloss and in
    depth within a light field (r = 0.00), so that the slopes on gloss and on depth are
    estimable both across and within light fields.
    """
    if r == 0:
        return i % n_gloss, (3 * i + kind_index) % n_depth
    return (2 * i) % n_gloss, (2 * i + 7 + kind_index) % n_depth


def _imagestats_slice(design: StudyDesign) -> pd.DataFrame:
    rows = []
    gl, dl = design.gloss.labels, design.depth.labels
    for k, kind in enumerate(("indoor", "outdoor")):
        lfs = [lf for lf in design.imagestats.light_fields if lf.kind == kind]
        for i, lf in enumerate(lfs):
            for r in (0, 1):
                g, d = slice_levels(i, r, k, len(gl), len(dl))
                rows += _imagestats_rows(design, lf, [(gl[g], dl[d],
                                                       (i + r) % design.imagestats.n_arrays)])
    return pd.DataFrame(rows, columns=SET_COLUMNS)


def _preview(design: StudyDesign) -> pd.DataFrame:
    t = _experiment(design)
    g = design.gloss.rendered_levels
    d = design.depth.rendered_levels
    keep = t["gloss_level"].isin([g[0], g[-1]]) & t["depth_level"].isin([d[0], d[-1]])
    return t[keep].reset_index(drop=True)


def stimulus_set(design: StudyDesign, name: str) -> pd.DataFrame:
    """The stimuli of a named set, one row each (columns :data:`SET_COLUMNS`).

    Raises
    ------
    ValueError
        If ``name`` is not one of ``SET_NAMES``.
    """
    builders = {"experiment": _experiment, "imagestats": _imagestats,
                "imagestats_slice": _imagestats_slice, "preview": _preview}
    if name not in builders:
        raise ValueError(f"unknown stimulus set {name!r}; choose one of {list(SET_NAMES)}")
    return builders[name](design).reset_index(drop=True)


def parse_filters(specs: list[str] | None) -> dict[str, list[str]]:
    """Parse ``["depth_level=2,5", "illumination=indoor"]`` into ``{column: [values]}``.

    Raises
    ------
    ValueError
        If a filter is not ``column=value[,value...]`` or names an unknown column.
    """
    out: dict[str, list[str]] = {}
    for spec in specs or []:
        col, sep, values = spec.partition("=")
        col = col.strip()
        if not sep or not col or not values.strip():
            raise ValueError(f"filter {spec!r} must look like column=value[,value...], "
                             "e.g. depth_level=2,5")
        if col not in SET_COLUMNS:
            raise ValueError(f"filter {spec!r}: unknown column {col!r}; use one of {SET_COLUMNS}")
        out.setdefault(col, []).extend(v.strip() for v in values.split(",") if v.strip())
    return out


def apply_filters(table: pd.DataFrame, filters: dict[str, list[str]], *,
                  limit: int | None = None) -> pd.DataFrame:
    """Rows whose columns match every filter (values compared as numbers where they parse),
    then the first ``limit`` rows. Raises ``ValueError`` when nothing is left."""
    keep = pd.Series(True, index=table.index)
    for col, values in filters.items():
        column = table[col]
        if pd.api.types.is_numeric_dtype(column):
            try:
                wanted = [float(v) for v in values]
            except ValueError as exc:
                raise ValueError(f"filter {col}={','.join(values)}: {col} is numeric") from exc
            keep &= column.astype(float).isin(wanted)
        else:
            keep &= column.astype(str).isin(values)
    out = table[keep]
    if limit is not None:
        if limit < 1:
            raise ValueError(f"--limit must be >= 1, got {limit}")
        out = out.head(limit)
    if out.empty:
        raise ValueError(f"the filters {filters} select no stimuli; check the values "
                         "(`python -m stimuli list --set NAME` shows them)")
    return out.reset_index(drop=True)


#: The two kinds of folder a set renders into: the experiment's stimuli (``experiment`` and its
#: ``preview``; ids ``indoor_g05_d07``) and the image-statistics images (``imagestats`` and its
#: ``imagestats_slice``; ids end in the array, ``noon_grass_g05_d07_a03``).
_FAMILIES = {"experiment": "the experiment's stimuli (--set experiment or preview)",
             "imagestats": "the image-statistics set (--set imagestats or imagestats_slice)"}


def set_family(stimulus_id: str) -> str:
    """``"imagestats"`` for an image-statistics id (ending ``_aNN``), else ``"experiment"``."""
    return "imagestats" if re.search(r"_a\d+$", str(stimulus_id)) else "experiment"


def refuse_mixed_sets(out, plan: pd.DataFrame) -> None:
    """Refuse to render one family of sets into a folder that holds the other's images.

    The experiment reads a folder's manifest as its stimuli, and the image statistics a folder
    as its set: the two mixed in one manifest would show image-statistics images in sessions,
    or measure the experiment's. Looks at ``manifest.csv`` and ``renders.csv`` of ``out``.

    Raises
    ------
    ValueError
        Naming what the folder holds and the fix (another ``--out``).
    """
    from labfiles import read_csv_records

    new = {set_family(s) for s in plan["stimulus_id"]}
    held: set[str] = set()
    for name in ("manifest.csv", "renders.csv"):
        path = Path(out) / name
        if path.is_file():
            ids = read_csv_records(path, usecols=["stimulus_id"], dtype=str)["stimulus_id"]
            held |= {set_family(s) for s in ids}
    if held and held != new:
        raise ValueError(f"{out} holds {' and '.join(_FAMILIES[f] for f in sorted(held))}; this "
                         f"run renders {' and '.join(_FAMILIES[f] for f in sorted(new))}, and one "
                         "folder (one manifest) holds one set: render into another --out folder "
                         "(nothing was rendered or changed)")
