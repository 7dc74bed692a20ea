"""Named stimulus sets: which stimuli a render job produces."""

from __future__ import annotations

import pandas as pd

from studydesign import StudyDesign

__all__ = ["SET_NAMES", "stimulus_set"]

SET_NAMES = ("experiment",)


def stimulus_set(design: StudyDesign, name: str) -> pd.DataFrame:
    """The stimuli of a named set, one row each (columns of ``design.stimuli()``).

    Raises
    ------
    ValueError
        If ``name`` is not one of ``SET_NAMES``.
    """
    if name == "experiment":
        return design.stimuli()
    raise ValueError(f"unknown stimulus set {name!r}; choose one of {list(SET_NAMES)}")
