"""The study design as one typed, validated, frozen object.

Every number that defines the gloss x depth study (levels, array geometry, sessions, display,
slider scale, analysis bins) lives in ``design.toml`` and reaches code only through
:class:`StudyDesign`. Nothing here reads a file at import time: call :func:`load_design`.

Each of design.toml's sections has its typed class, its checks and its reader in the module
named for what it holds; this module joins them and checks what spans sections:

=================================  ==========================================================
``[gloss] [depth] [array]``        :mod:`studydesign.objects`
``[[illuminations]] [imagestats]`` :mod:`studydesign.lights`
``[sessions] [display] [slider]``  :mod:`studydesign.sessions`
``[tonemap] [render] [cluster]``   :mod:`studydesign.rendering`
``[analysis] [gap]``               :mod:`studydesign.analysis_spec`
reading any table                  :mod:`studydesign.tables`
=================================  ==========================================================
"""

from __future__ import annotations

import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from labfiles import LabFileError, read_toml
from studydesign.analysis_spec import (
    MODEL_RESPONSES,
    AnalysisModel,
    AnalysisSpec,
    GapSpec,
    read_analysis,
    read_gap,
)
from studydesign.errors import DesignError, require
from studydesign.lights import (
    LIGHT_KINDS,
    SCALE_RULES,
    Illumination,
    ImageStatsSpec,
    LightField,
    read_illuminations,
    read_imagestats,
)
from studydesign.objects import (
    FIRST_GLOSS_LABEL,
    ArraySpec,
    DepthSpec,
    GlossSpec,
    read_array,
    read_depth,
    read_gloss,
)
from studydesign.rendering import (
    RENDER_VARIANTS,
    ClusterSpec,
    RenderSpec,
    ToneMapSpec,
    read_cluster,
    read_render,
    read_tonemap,
)
from studydesign.sessions import (
    DisplaySpec,
    SessionSpec,
    SliderSpec,
    read_display,
    read_sessions,
    read_slider,
)
from studydesign.tables import default_design_path, refuse_non_finite

__all__ = [
    "FIRST_GLOSS_LABEL",
    "LIGHT_KINDS",
    "MODEL_RESPONSES",
    "RENDER_VARIANTS",
    "SCALE_RULES",
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
]

STIMULUS_COLUMNS = (
    "stimulus_id",
    "illumination",
    "gloss_level",
    "depth_level",
    "true_gloss_pct",
    "true_depth_cm",
)


@dataclass(frozen=True)
class StudyDesign:
    """The whole study design. Build it with :func:`load_design`."""

    gloss: GlossSpec
    depth: DepthSpec
    array: ArraySpec
    illuminations: tuple[Illumination, ...]
    tonemap: ToneMapSpec
    sessions: SessionSpec
    display: DisplaySpec
    slider: SliderSpec
    analysis: AnalysisSpec
    imagestats: ImageStatsSpec
    render: RenderSpec
    gap: GapSpec
    source: str = ""
    cluster: ClusterSpec = field(default_factory=ClusterSpec)

    def spp(self, gloss_level: int, light_field: str) -> int:
        """Samples per pixel of a gloss level label under a light field (an image-statistics
        light field's name, or an illumination's, which takes the counts of the light field
        with its file and scale where it has none of its own)."""
        own = dict(self.render.spp_by_light_field)
        if light_field not in own:
            il = next((il for il in self.illuminations if il.name == light_field), None)
            twin = next((lf.name for lf in self.imagestats.light_fields if il is not None
                         and Path(lf.envmap).name == Path(il.envmap).name
                         and lf.scale == il.scale), None)
            light_field = twin or light_field
        return self.render.spp(gloss_level, light_field)

    def __post_init__(self) -> None:
        require(
            len(self.render.spp_by_gloss_level) == self.gloss.n_levels,
            f"render.spp_by_gloss_level has {len(self.render.spp_by_gloss_level)} values; give "
            f"one per physical gloss level ({self.gloss.n_levels}, labels "
            f"1..{self.gloss.n_levels})",
        )
        names = [il.name for il in self.illuminations]
        require(len(names) >= 1, "the design needs at least one [[illuminations]] entry")
        require(len(set(names)) == len(names), f"illumination names repeat: {names}")
        self._check_spp_by_light_field(names)
        n = self.n_stimuli
        require(
            self.sessions.n_sessions * self.sessions.trials_per_session == n,
            f"sessions: {self.sessions.n_sessions} x {self.sessions.trials_per_session} trials "
            f"!= {n} stimuli ({len(names)} illuminations x {len(self.gloss.rendered_levels)} "
            f"gloss x {len(self.depth.rendered_levels)} depth); fix [sessions]",
        )
        # The slider and the physical reference set must describe the same units.
        require(
            np.isclose(self.slider.depth_cm_per_unit, self.depth.step_cm)
            and np.isclose(self.slider.gloss_pct_per_unit, self.gloss.step_pct),
            "slider units disagree with the reference sets: slider.depth_cm_per_unit must equal "
            "depth.step_cm and slider.gloss_pct_per_unit must equal gloss.step_pct",
        )
        rendered_depth = set(np.round(self.depth.rendered_cm, 9).tolist())
        for name, values in self.analysis.depth_bins_cm.items():
            require(
                set(np.round(values, 9)) <= rendered_depth,
                f"analysis.depth_bins_cm.{name} {list(values)} are not rendered depths "
                f"{sorted(rendered_depth)}",
            )
        rendered_gloss = set(np.round(self.gloss.rendered_pct, 9).tolist())
        for name, values in self.analysis.gloss_bins_pct.items():
            require(
                set(np.round(values, 9)) <= rendered_gloss,
                f"analysis.gloss_bins_pct.{name} {list(values)} are not rendered gloss values",
            )

    def _check_spp_by_light_field(self, names: list[str]) -> None:
        for lf, spp in self.render.spp_by_light_field:
            require(len(spp) == self.gloss.n_levels,
                    f"render.spp_by_light_field.{lf} = {list(spp)}: give one whole number >= 1 "
                    f"per gloss level ({self.gloss.n_levels}), as `python -m stimuli plan-spp "
                    "--light-fields all` prints them")
        known = {lf.name for lf in self.imagestats.light_fields} | set(names)
        unknown = sorted({n for n, _ in self.render.spp_by_light_field} - known)
        require(not unknown, f"render.spp_by_light_field names {unknown}, which are no light "
                             f"field of [imagestats] nor illumination: use one of {sorted(known)}")

    @property
    def n_stimuli(self) -> int:
        return (
            len(self.illuminations)
            * len(self.gloss.rendered_levels)
            * len(self.depth.rendered_levels)
        )

    @property
    def n_imagestats_images(self) -> int:
        """Images in the image-statistics set: light fields x every physical gloss and depth
        level x arrays."""
        return (self.imagestats.n_light_fields * self.gloss.n_levels * self.depth.n_levels
                * self.imagestats.n_arrays)

    def illumination_of_kind(self, kind: str) -> str:
        """The condition a light field of ``kind`` belongs to: the name of the design's one
        illumination of that kind (``indoor``), else the kind itself."""
        names = [il.name for il in self.illuminations if il.kind == kind]
        return names[0] if len(names) == 1 else kind

    def illumination(self, name: str) -> Illumination:
        for il in self.illuminations:
            if il.name == name:
                return il
        raise DesignError(
            f"unknown illumination {name!r}; the design has "
            f"{[il.name for il in self.illuminations]}"
        )

    @staticmethod
    def stimulus_id(illumination: str, gloss_level: int, depth_level: int) -> str:
        """Stable stimulus id, e.g. ``indoor_g05_d07``."""
        return f"{illumination}_g{int(gloss_level):02d}_d{int(depth_level):02d}"

    def stimuli(self) -> pd.DataFrame:
        """The experiment's stimulus set, one row per stimulus.

        Returns
        -------
        DataFrame
            Columns ``stimulus_id, illumination, gloss_level, depth_level, true_gloss_pct (%),
            true_depth_cm (cm)``; ``n_stimuli`` rows ordered illumination, gloss, depth.
        """
        rows = []
        for il in self.illuminations:
            for g in self.gloss.rendered_levels:
                for d in self.depth.rendered_levels:
                    rows.append(
                        (
                            self.stimulus_id(il.name, g, d),
                            il.name,
                            g,
                            d,
                            float(self.gloss.pct(g)),
                            float(self.depth.cm(d)),
                        )
                    )
        return pd.DataFrame(rows, columns=list(STIMULUS_COLUMNS))

    def depth_bin(self, depth_cm) -> np.ndarray:
        """Bin name ('low', 'medium', 'high') of each true depth in cm; '' when in no bin."""
        return _bin(depth_cm, self.analysis.depth_bins_cm)

    def gloss_bin(self, gloss_pct) -> np.ndarray:
        """Bin name of each true gloss in %; '' when in no bin."""
        return _bin(gloss_pct, self.analysis.gloss_bins_pct)

    def to_dict(self) -> dict:
        """Plain-dict form, e.g. to save beside data."""
        return asdict(self)


def _bin(values, bins: dict[str, tuple[float, ...]]) -> np.ndarray:
    v = np.round(np.asarray(values, dtype=float), 9)
    out = np.full(v.shape, "", dtype=object)
    for name, members in bins.items():
        out[np.isin(v, np.round(members, 9))] = name
    return out


def _read_raw(path: Path) -> dict:
    """The tables of the design file at ``path``, refused if missing, not TOML, nan or inf."""
    if not path.is_file():
        raise DesignError(f"design file {path} not found; pass an existing design.toml")
    try:
        # A BOM, CRLF line ends or UTF-16 (Notepad, Excel) read as UTF-8 does.
        raw = read_toml(path)
    except LabFileError as exc:
        raise DesignError(f"design file {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise DesignError(f"design file {path} is not valid TOML: {exc}") from exc
    refuse_non_finite(raw, path)
    return raw


def load_design(path: str | Path | None = None) -> StudyDesign:
    """Load and validate a study design.

    Parameters
    ----------
    path : path-like, optional
        A ``design.toml``; the shipped one when omitted.

    Returns
    -------
    StudyDesign

    Raises
    ------
    DesignError
        If the file is missing, is not TOML, or any value is inconsistent; the message names the
        key and the fix.
    """
    path = Path(path) if path is not None else default_design_path()
    path = Path(path) if path is not None else default_design_path()
    raw = _read_raw(path)
    # Read in the file's order, so that the first faulty section is the one named.
    return StudyDesign(
        gloss=read_gloss(raw, path),
        depth=read_depth(raw, path),
        array=read_array(raw, path),
        illuminations=read_illuminations(raw, path),
        tonemap=read_tonemap(raw, path),
        sessions=read_sessions(raw, path),
        display=read_display(raw, path),
        slider=read_slider(raw, path),
        analysis=read_analysis(raw, path),
        imagestats=read_imagestats(raw, path),
        render=read_render(raw, path),
        gap=read_gap(raw, path),
        source=str(path),
        cluster=read_cluster(raw, path),
    )
