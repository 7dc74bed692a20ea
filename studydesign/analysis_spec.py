"""What the analysis fits: ``[analysis]`` (bins, the Box-Cox lambda, the extra mixed models)
and ``[gap]`` (the sim-to-real diagnosis's practical tolerances)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from studydesign.errors import DesignError, require
from studydesign.tables import build, section

__all__ = ["MODEL_RESPONSES", "AnalysisModel", "AnalysisSpec", "GapSpec", "read_analysis",
           "read_gap"]


#: Responses of the analysis's model frame a mixed model may use (analysis.models.model_frame).
MODEL_RESPONSES = ("gloss_match_pct", "depth_match_bc", "depth_match_cm")


@dataclass(frozen=True)
class AnalysisModel:
    """An extra mixed model the report fits (a table of ``[analysis.models]``).

    Attributes
    ----------
    name : str
        The table's name, e.g. ``gloss_crossed`` (letters, digits, ``_``).
    response : str
        One of `MODEL_RESPONSES`.
    formula : str
        The right-hand side of ``response ~ ...`` in lme4 syntax, with at least one random term,
        e.g. ``gloss * depth + (1 + gloss + depth | participant) + (1 | stimulus_id)``.
    label : str
        What the model is, for the report.
    source_model : str
        ``"gloss"`` or ``"depth"`` when the model re-specifies that model of the source study
        (the report then checks the source's findings under it), else ``""``.
    """

    name: str
    response: str
    formula: str
    label: str = ""
    source_model: str = ""

    def __post_init__(self) -> None:
        where = f"analysis.models.{self.name}"
        require(self.name.replace("_", "").isalnum(),
                f"{where}: use letters, digits or '_' in a model name")
        require(self.name not in ("gloss", "depth"),
                f"{where}: 'gloss' and 'depth' name the source study's models; choose another "
                "name (e.g. gloss_crossed)")
        require(self.response in MODEL_RESPONSES,
                f"{where}.response {self.response!r} is not one of {list(MODEL_RESPONSES)}")
        require(isinstance(self.formula, str) and "~" not in self.formula,
                f"{where}.formula must be the right-hand side only (no '~'; the response is "
                f"{where}.response), e.g. 'gloss * depth + (1 | participant)'")
        depth = 0
        for ch in self.formula:
            depth += {"(": 1, ")": -1}.get(ch, 0)
            require(depth >= 0, f"{where}.formula {self.formula!r} has an unmatched ')'")
        require(depth == 0, f"{where}.formula {self.formula!r} has an unmatched '('")
        require("|" in self.formula,
                f"{where}.formula {self.formula!r} has no random-effect term such as "
                "(1 | participant)")
        require(self.source_model in ("", "gloss", "depth"),
                f"{where}.source_model {self.source_model!r} must be 'gloss', 'depth' or "
                "left out")
        require(not self.source_model
                or {"gloss": "gloss_match_pct", "depth": "depth_match_bc"}[self.source_model]
                == self.response,
                f"{where}: source_model {self.source_model!r} needs the source model's "
                "response (gloss: gloss_match_pct, depth: depth_match_bc)")


@dataclass(frozen=True)
class AnalysisSpec:
    depth_bins_cm: dict[str, tuple[float, ...]]
    gloss_bins_pct: dict[str, tuple[float, ...]]
    depth_boxcox_lambda: float
    models: tuple[AnalysisModel, ...] = ()


@dataclass(frozen=True)
class GapSpec:
    """Practical tolerances of the sim-to-real gap diagnosis (``analysis.gap``).

    Attributes
    ----------
    render_tolerance_pct : float
        The render layer's tolerance for what the catalogue leaves: a remaining misfit between
        the photos and the extended renders counts as a gap beyond the catalogue only if it is
        statistically significant *and* at least this large, as an RMS over the sphere's pixels
        in % of the photos' RMS luminance; a smaller one is reported with its size but not
        flagged. In (0, 20]. Default 1.0 (see the shipped design.toml for why).
    observer_tolerance_slider : float
        The observer layer's tolerance, in slider units: what the catalogue leaves counts as a
        gap beyond it only if it is statistically significant *and* the chosen model's
        predicted settings lie at least this far (RMS over held-out trials, gloss and depth
        together) from a flexible model of the data. In (0, 2]. Default 0.25 (2.5 % gloss,
        0.1 cm depth in the shipped slider; see the shipped design.toml for why). Another
        lab's rating study is held to the same share of its own scale (0.25 of the slider's
        span of 10 is 2.5 % of the scale's span).
    display_tolerance_pct : float
        The display layer's tolerance: a remaining misfit between a check's photometer
        readings and the calibration (with the effects the diagnosis chose) counts as a gap
        only if it is statistically significant *and* its systematic RMS, in % of each
        reading's luminance (readings above near black), is at least this large; a smaller one
        is "no gap that matters", reported with its size and where it lies. In (0, 20].
        Default 1.0 (see the shipped design.toml for why).

    A design written before this section existed has no ``[gap]``: it takes these defaults,
    so an older lab design still runs sessions and renders (the diagnosis reports the
    tolerance it used).
    """

    render_tolerance_pct: float = 1.0
    observer_tolerance_slider: float = 0.25
    display_tolerance_pct: float = 1.0

    def __post_init__(self) -> None:
        require(0.0 < float(self.render_tolerance_pct) <= 20.0,
                f"gap.render_tolerance_pct must lie in (0, 20] (% of the photos' RMS "
                f"luminance), got {self.render_tolerance_pct}")
        require(0.0 < float(self.observer_tolerance_slider) <= 2.0,
                f"gap.observer_tolerance_slider must lie in (0, 2] (slider units, RMS), got "
                f"{self.observer_tolerance_slider}")
        require(0.0 < float(self.display_tolerance_pct) <= 20.0,
                f"gap.display_tolerance_pct must lie in (0, 20] (% of luminance), got "
                f"{self.display_tolerance_pct}")


def _models(raw: Any, path: Path) -> tuple[AnalysisModel, ...]:
    if not isinstance(raw, dict):
        raise DesignError(f"{path}: [analysis.models] must hold one table per model")
    out = []
    for name, table in raw.items():
        if not isinstance(table, dict):
            raise DesignError(f"{path}: analysis.models.{name} must be a table "
                              "(response, formula, label, source_model)")
        defaults = {"name": name, "label": "", "source_model": ""}
        out.append(build(AnalysisModel, {**defaults, **table}, f"analysis.models.{name}", path))
    return tuple(out)


def read_analysis(raw: dict, path: Path) -> AnalysisSpec:
    """The ``[analysis]`` table (and its ``[analysis.models.*]``) of a design file's ``raw``
    tables."""
    an = section(raw, "analysis", path, AnalysisSpec)
    return build(
        AnalysisSpec, an, "analysis", path,
        depth_bins_cm={
            k: tuple(float(x) for x in v) for k, v in an.get("depth_bins_cm", {}).items()
        },
        gloss_bins_pct={
            k: tuple(float(x) for x in v) for k, v in an.get("gloss_bins_pct", {}).items()
        },
        models=_models(an.get("models", {}), path),
    )


def read_gap(raw: dict, path: Path) -> GapSpec:
    """The ``[gap]`` table of a design file's ``raw`` tables; its defaults when absent."""
    return build(GapSpec, {**asdict(GapSpec()), **raw.get("gap", {})}, "gap", path)
