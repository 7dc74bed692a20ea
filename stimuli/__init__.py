"""Offline stimulus rendering: ellipsoid arrays, Ward BSDF, Mitsuba, tone mapping, gloss fitting.

Public API
----------
stimulus_set, SET_NAMES, MANIFEST_COLUMNS, load_manifest, verify_manifest, append_manifest_row
"""

from stimuli.manifest import (
    MANIFEST_COLUMNS,
    ManifestError,
    append_manifest_row,
    load_manifest,
    sha256_file,
    verify_manifest,
)
from stimuli.sets import SET_NAMES, stimulus_set

__all__ = [
    "MANIFEST_COLUMNS",
    "SET_NAMES",
    "ManifestError",
    "append_manifest_row",
    "load_manifest",
    "sha256_file",
    "stimulus_set",
    "verify_manifest",
]
