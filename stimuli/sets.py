"""Named stimulus sets: which stimuli a render job produces.

* ``experiment``: the design's stimuli (``design.stimuli()``, 162 = 2 illuminations x 9 gloss x
  9 depth). One array per depth level (array index 0), shared by all gloss levels and both
  illuminations, so stimuli of one depth differ only in material and light.
* ``imagestats``: for the image-statistics analysis, every physical gloss and depth level (11 x 11)
  x ``design.imagestats.n_arrays`` arrays x ``design.imagestats.n_light_fields`` light fields
  per illumination condition (seed: 2 x 11 x 11 x 11 x 22 = 58,564 images). A condition's light
  fields are its probe rotated about the vertical by ``k * 360 / n`` degrees (k = 0..n-1): the
  project ships one probe per condition, and a rotation moves every light source; a lab with
  more probes can point the conditions at them. Select subsets with filters.
* ``preview``: the lowest and highest rendered gloss and depth under both illuminations (8),
  for the demo and tests.

Every row carries ``light_field`` (the tone-mapping condition), ``array_index``, ``seed`` (the
array's, :func:`stimuli.geometry.stimulus_seed`), ``envmap`` and ``rotation_deg``.
"""

from __future__ import annotations

import pandas as pd

from stimuli.geometry import stimulus_seed
from studydesign import StudyDesign

__all__ = [
    "SET_COLUMNS",
    "SET_NAMES",
    "apply_filters",
    "parse_filters",
    "stimulus_set",
]

SET_NAMES = ("experiment", "imagestats", "preview")
SET_COLUMNS = ["stimulus_id", "illumination", "gloss_level", "depth_level", "true_gloss_pct",
               "true_depth_cm", "light_field", "array_index", "seed", "envmap", "rotation_deg"]


def _experiment(design: StudyDesign) -> pd.DataFrame:
    t = design.stimuli().copy()
    t["light_field"] = t["illumination"]
    t["array_index"] = 0
    t["seed"] = [stimulus_seed(d, 0) for d in t["depth_level"]]
    t["envmap"] = [design.illumination(il).envmap for il in t["illumination"]]
    t["rotation_deg"] = 0.0
    return t[SET_COLUMNS]


def _imagestats(design: StudyDesign) -> pd.DataFrame:
    rows = []
    n_lf = design.imagestats.n_light_fields
    for il in design.illuminations:
        for k in range(n_lf):
            lf = f"{il.name}_lf{k:02d}"
            for g in design.gloss.labels:
                for d in design.depth.labels:
                    for a in range(design.imagestats.n_arrays):
                        rows.append((f"{lf}_g{g:02d}_d{d:02d}_a{a:02d}", il.name, g, d,
                                     float(design.gloss.pct(g)), float(design.depth.cm(d)), lf, a,
                                     stimulus_seed(d, a), il.envmap, 360.0 * k / n_lf))
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
    builders = {"experiment": _experiment, "imagestats": _imagestats, "preview": _preview}
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
