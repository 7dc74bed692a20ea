"""The options that define an image-statistics table, saved beside it so a resumed run matches."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass

__all__ = ["StatsConfig"]


@dataclass(frozen=True)
class StatsConfig:
    """How each image's statistics are computed (recorded in the Parquet file's metadata).

    Attributes
    ----------
    highlight_factor : float
        A pixel is a highlight when its luminance exceeds ``highlight_factor`` times the diffuse
        level (the median luminance of the stimulus region); > 1.
    ps : bool
        Compute the Portilla-Simoncelli statistics (plenoptic) as well as the pixel statistics.
    ps_n_scales, ps_n_orientations, ps_spatial_corr_width : int
        plenoptic's ``PortillaSimoncelli(n_scales, n_orientations, spatial_corr_width)``;
        the defaults are plenoptic's (4, 4, 7), those of Portilla & Simoncelli (2000).
    """

    highlight_factor: float = 2.0
    ps: bool = True
    ps_n_scales: int = 4
    ps_n_orientations: int = 4
    ps_spatial_corr_width: int = 7

    def __post_init__(self) -> None:
        if not float(self.highlight_factor) > 1.0:
            raise ValueError(
                f"highlight_factor {self.highlight_factor} must be > 1 (a highlight is brighter "
                "than the diffuse level)"
            )
        for name in ("ps_n_scales", "ps_n_orientations", "ps_spatial_corr_width"):
            value = getattr(self, name)
            if int(value) != value or value < 1:
                raise ValueError(f"{name} = {value!r}; use a positive integer")

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> StatsConfig:
        return cls(**json.loads(text))
