"""The study design of the gloss x depth experiment, as data.

Shared by every package (calibration -> stimuli -> experiment -> analysis): one typed, validated,
frozen :class:`StudyDesign` loaded from ``design.toml``.

>>> from studydesign import load_design
>>> design = load_design()
>>> design.n_stimuli
162
"""

from studydesign.colour import REC709_Y, rec709_luminance
from studydesign.design import (
    MODEL_RESPONSES,
    RENDER_VARIANTS,
    STIMULUS_COLUMNS,
    AnalysisModel,
    AnalysisSpec,
    ArraySpec,
    ClusterSpec,
    DepthSpec,
    DesignError,
    DisplaySpec,
    GapSpec,
    GlossSpec,
    Illumination,
    ImageStatsSpec,
    LightField,
    RenderSpec,
    SessionSpec,
    SliderSpec,
    StudyDesign,
    ToneMapSpec,
    default_design_path,
    load_design,
)

__all__ = [
    "MODEL_RESPONSES",
    "REC709_Y",
    "RENDER_VARIANTS",
    "STIMULUS_COLUMNS",
    "AnalysisModel",
    "AnalysisSpec",
    "ArraySpec",
    "ClusterSpec",
    "DepthSpec",
    "DesignError",
    "DisplaySpec",
    "GapSpec",
    "GlossSpec",
    "Illumination",
    "ImageStatsSpec",
    "LightField",
    "RenderSpec",
    "SessionSpec",
    "SliderSpec",
    "StudyDesign",
    "ToneMapSpec",
    "default_design_path",
    "load_design",
    "rec709_luminance",
]
