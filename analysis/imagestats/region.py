"""The stimulus region of a render: which pixels the statistics are computed on."""

from __future__ import annotations

__all__ = ["ps_window", "stimulus_region"]


def stimulus_region(width_px: int, height_px: int, *, image_width_cm: float,
                    extent_cm: float) -> tuple[slice, slice]:
    """Rows and columns of the square the ellipsoid array covers, centred in the image.

    The renderer's camera looks fronto-parallel at the centre of the array and records the image
    width on the array's plane (``image_width_cm`` in the manifest), so one pixel spans
    ``image_width_cm / width_px`` cm (square pixels). The region is the design's array square
    (``array.extent_cm``) about the image centre: every pixel in it shows the array, none of the
    backing around it.

    Parameters
    ----------
    width_px, height_px : int
        Image size in pixels.
    image_width_cm : float
        Width of the image on the array's plane, cm.
    extent_cm : float
        Side of the array square, cm (``design.array.extent_cm``).

    Returns
    -------
    (slice, slice)
        Row and column slices of the region, side ``round(extent_cm * width_px /
        image_width_cm)`` pixels.

    Raises
    ------
    ValueError
        If a size is not positive or the square does not fit in the image.
    """
    if width_px <= 0 or height_px <= 0 or not image_width_cm > 0 or not extent_cm > 0:
        raise ValueError(
            f"image {width_px}x{height_px} px, {image_width_cm} cm wide, array {extent_cm} cm: "
            "all sizes must be positive"
        )
    side = round(extent_cm * width_px / image_width_cm)
    height_cm = image_width_cm * height_px / width_px
    if side > width_px or side > height_px:
        raise ValueError(
            f"the {extent_cm} cm array square ({side} px) does not fit in the "
            f"{image_width_cm:g} x {height_cm:g} cm image ({width_px}x{height_px} px); "
            "check image_width_cm in the manifest"
        )
    if side < 2:
        raise ValueError(f"the array square is {side} px; render larger images")
    top = (height_px - side) // 2
    left = (width_px - side) // 2
    return slice(top, top + side), slice(left, left + side)


def ps_window(side_px: int, *, n_scales: int) -> slice:
    """Central part of a square region whose side suits the Portilla-Simoncelli pyramid.

    plenoptic's ``PortillaSimoncelli`` needs a side divisible by 2**n_scales; the window is the
    largest such side that fits, centred, as an index range into the region.

    Raises
    ------
    ValueError
        If the region is smaller than 2**n_scales pixels.
    """
    step = 2**n_scales
    size = (side_px // step) * step
    if size == 0:
        raise ValueError(
            f"the stimulus region ({side_px} px) is smaller than 2**n_scales = {step} px; "
            "render larger images or lower ps_n_scales"
        )
    start = (side_px - size) // 2
    return slice(start, start + size)
