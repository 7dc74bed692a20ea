"""The settings shared by every image of a render run (:class:`RenderJob`), shipped to the
workers: the camera, the size, the samples per pixel by gloss level and light field, the
variant and the design the workers load."""

from __future__ import annotations

from dataclasses import dataclass

from stimuli.render import CameraGeometry

__all__ = ["RenderJob"]


@dataclass(frozen=True)
class RenderJob:
    """Settings shared by every image of a run (shipped to the workers).

    Attributes
    ----------
    camera : CameraGeometry
    size_px : int
        Image width = height, px.
    spp : int
        Samples per pixel of every image when ``spp_by_gloss_level`` is empty (multijitter count).
    variant : str
        Mitsuba variant (recorded per EXR).
    design_path : str
        The design the workers load.
    threads : int
        Dr.Jit threads per worker process (0: Dr.Jit's default, all cores).
    spp_by_gloss_level : tuple of int
        Samples per pixel per physical gloss level label (1..n), multijitter counts; empty: ``spp``.
    llvm_path : str
        The client's libLLVM: a worker whose own ``DRJIT_LIBLLVM_PATH`` is unset uses it where it
        is a file (:func:`stimuli.mitsuba_env.use_llvm_hint`), else finds its own.
    spp_by_light_field : tuple of (str, tuple of int)
        Per light field (name), its own spp per gloss level (multijitter counts, planned from
        that light field's noise); a light field not listed takes ``spp_by_gloss_level``.
    """

    camera: CameraGeometry
    size_px: int
    spp: int
    variant: str
    design_path: str
    threads: int = 0
    spp_by_gloss_level: tuple[int, ...] = ()
    llvm_path: str = ""
    spp_by_light_field: tuple[tuple[str, tuple[int, ...]], ...] = ()

    def spp_for(self, gloss_level: int, light_field: str = "") -> int:
        """Samples per pixel of a stimulus of this gloss level label under ``light_field``."""
        by_level = dict(self.spp_by_light_field).get(light_field) or self.spp_by_gloss_level
        if not by_level:
            return self.spp
        return int(by_level[int(gloss_level) - 1])
