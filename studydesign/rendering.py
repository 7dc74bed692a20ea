"""How the stimuli are made: ``[tonemap]`` (the source study's tone map), ``[render]`` (the
Mitsuba variant and samples per pixel) and ``[cluster]`` (the batch jobs that render them)."""

from __future__ import annotations

import re
from dataclasses import asdict, dataclass
from pathlib import Path

from studydesign.errors import DesignError, require
from studydesign.tables import build, section

__all__ = ["RENDER_VARIANTS", "ClusterSpec", "RenderSpec", "ToneMapSpec", "read_cluster",
           "read_render", "read_tonemap"]


@dataclass(frozen=True)
class ToneMapSpec:
    """The source study's tone mapping: linear below the knee, asymptotic logistic above
    (8-bit values)."""

    linear_fraction: float
    knee_value: int
    max_value: int

    def __post_init__(self) -> None:
        require(
            0.0 < self.linear_fraction < 1.0,
            f"tonemap.linear_fraction must lie in (0, 1), got {self.linear_fraction}",
        )
        require(
            0 < self.knee_value < self.max_value,
            "tonemap.knee_value must lie between 0 and tonemap.max_value",
        )


#: Mitsuba variants a render may name ("auto": monochrome for grey materials, CUDA when found).
RENDER_VARIANTS = ("auto", "llvm_ad_mono", "llvm_ad_rgb", "llvm_ad_spectral", "cuda_ad_mono",
                   "cuda_ad_rgb", "cuda_ad_spectral")


@dataclass(frozen=True)
class RenderSpec:
    """How stimuli are rendered: variant, the displayed-error target and the spp it implies.

    Attributes
    ----------
    variant : str
        One of :data:`RENDER_VARIANTS`.
    displayed_error_pct : float
        Target RMS difference between a render and its noise-free expectation after the tone
        map, in % of the display range (0-255), in (0, 10].
    spp_by_gloss_level : tuple of int
        Samples per pixel of each physical gloss level (labels 1..n), each >= 1: the smallest
        that reaches ``displayed_error_pct`` (measured by ``python -m stimuli plan-spp``).
    spp_planned_at_px : int
        Image width (px) the spp were measured at.
    spp_by_light_field : tuple of (str, tuple of int)
        ``[render.spp_by_light_field]``: per light field (its name), the spp of each gloss level
        measured under that light field alone (``plan-spp --light-fields all``); a light field
        not listed takes ``spp_by_gloss_level``.
    """

    variant: str
    displayed_error_pct: float
    spp_by_gloss_level: tuple[int, ...]
    spp_planned_at_px: int
    spp_by_light_field: tuple[tuple[str, tuple[int, ...]], ...] = ()

    def __post_init__(self) -> None:
        require(self.variant in RENDER_VARIANTS,
                f"render.variant {self.variant!r} is not one of {list(RENDER_VARIANTS)}")
        require(0.0 < float(self.displayed_error_pct) <= 10.0,
                f"render.displayed_error_pct must lie in (0, 10] (% of the display range), got "
                f"{self.displayed_error_pct}")
        require(all(isinstance(v, int) and v >= 1 for v in self.spp_by_gloss_level),
                f"render.spp_by_gloss_level must hold integers >= 1, got "
                f"{list(self.spp_by_gloss_level)}")
        require(isinstance(self.spp_planned_at_px, int) and self.spp_planned_at_px >= 8,
                f"render.spp_planned_at_px must be an integer >= 8, got {self.spp_planned_at_px}")
        for name, spp in self.spp_by_light_field:
            require(all(isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in spp),
                    f"render.spp_by_light_field.{name} = {list(spp)}: give one whole number "
                    ">= 1 per gloss level, as `python -m stimuli plan-spp --light-fields all` "
                    "prints them")

    def spp(self, gloss_level: int, light_field: str | None = None) -> int:
        """Samples per pixel of a gloss level label (1..n), under ``light_field`` where its own
        counts are listed (``spp_by_light_field``), else the design-wide ones."""
        own = dict(self.spp_by_light_field).get(light_field) if light_field else None
        return (own or self.spp_by_gloss_level)[int(gloss_level) - 1]


@dataclass(frozen=True)
class ClusterSpec:
    """Batch jobs of ``--cluster slurm|pbs|sge`` (renders, image statistics): one Dask worker
    per job; the command line's ``--cores`` etc. override each.

    Attributes
    ----------
    cores : int
        Cores per job, >= 1.
    memory : str
        Memory per job (``"8GiB"``).
    walltime : str
        Run time per job, ``HH:MM:SS`` (a job that ends is replaced).
    queue : str
        Queue or SLURM partition; empty: the system's default.
    jobs : int
        Jobs kept running at once, >= 1.
    account : str
        Account or project charged; empty: the user's default.

    A design without ``[cluster]`` takes these defaults.
    """

    cores: int = 4
    memory: str = "8GiB"
    walltime: str = "04:00:00"
    queue: str = ""
    jobs: int = 4
    account: str = ""

    def __post_init__(self) -> None:
        require(isinstance(self.cores, int) and self.cores >= 1,
                f"cluster.cores must be an integer >= 1, got {self.cores!r}")
        require(isinstance(self.jobs, int) and self.jobs >= 1,
                f"cluster.jobs must be an integer >= 1, got {self.jobs!r}")
        require(re.fullmatch(r"(\d+-)?\d{1,3}:\d{2}:\d{2}", str(self.walltime)) is not None,
                f"cluster.walltime must be HH:MM:SS, got {self.walltime!r}")


def read_tonemap(raw: dict, path: Path) -> ToneMapSpec:
    """The ``[tonemap]`` table of a design file's ``raw`` tables."""
    return build(ToneMapSpec, section(raw, "tonemap", path), "tonemap", path)


def read_render(raw: dict, path: Path) -> RenderSpec:
    """The ``[render]`` table of a design file's ``raw`` tables (a file whose ``[render]``
    holds only ``[render.spp_by_light_field]`` takes the shipped design's other keys)."""
    if set(raw.get("render", {"variant": ""})) <= {"spp_by_light_field"}:
        raw = {k: v for k, v in raw.items() if k != "render"}
    rd = section(raw, "render", path, RenderSpec)
    return build(RenderSpec, rd, "render", path,
                 spp_by_gloss_level=tuple(rd.get("spp_by_gloss_level", ())),
                 spp_by_light_field=_spp_by_light_field(rd.get("spp_by_light_field", {}), path))


def _spp_by_light_field(raw, path: Path) -> tuple[tuple[str, tuple[int, ...]], ...]:
    if not isinstance(raw, dict) or not all(isinstance(v, list) for v in raw.values()):
        raise DesignError(f"{path}: [render.spp_by_light_field] must hold one list of spp per "
                          "light field (name = [30, 30, ...]), as `python -m stimuli plan-spp "
                          "--light-fields all` prints it")
    return tuple((str(k), tuple(v)) for k, v in raw.items())


def read_cluster(raw: dict, path: Path) -> ClusterSpec:
    """The ``[cluster]`` table of a design file's ``raw`` tables; its defaults when absent."""
    return build(ClusterSpec, {**asdict(ClusterSpec()), **raw.get("cluster", {})}, "cluster",
                 path)
