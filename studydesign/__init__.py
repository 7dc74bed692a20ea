"""The study design of the gloss x depth experiment, as data.

Shared by every package (calibration -> stimuli -> experiment -> analysis): one typed, validated,
frozen :class:`StudyDesign` loaded from ``design.toml``.

>>> from studydesign import load_design
>>> design = load_design()
>>> design.n_stimuli
162
"""

from studydesign.design import (
    STIMULUS_COLUMNS,
    AnalysisSpec,
    ArraySpec,
    DepthSpec,
    DesignError,
    DisplaySpec,
    GlossSpec,
    Illumination,
    RenderSpec,
    SessionSpec,
    SliderSpec,
    StudyDesign,
    ToneMapSpec,
    default_design_path,
    load_design,
)

__all__ = [
    "STIMULUS_COLUMNS",
    "AnalysisSpec",
    "ArraySpec",
    "DepthSpec",
    "DesignError",
    "DisplaySpec",
    "GlossSpec",
    "Illumination",
    "RenderSpec",
    "SessionSpec",
    "SliderSpec",
    "StudyDesign",
    "ToneMapSpec",
    "default_design_path",
    "load_design",
]
