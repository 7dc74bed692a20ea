"""Reading and writing linear HDR images as OpenEXR files (photos and synthetic photo sets)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenEXR

from labfiles import atomic_path

__all__ = ["read_exr", "write_exr"]


def read_exr(path: str | Path) -> np.ndarray:
    """Read an OpenEXR image as linear RGB.

    Parameters
    ----------
    path : str or Path
        An OpenEXR file with channels R, G, B (an alpha channel is ignored) or a single Y channel
        (grayscale, repeated into R, G, B).

    Returns
    -------
    ndarray, float32, shape (height, width, 3)
        Linear radiance in the file's own units.

    Raises
    ------
    ValueError
        If the file cannot be read as OpenEXR or has neither RGB nor Y channels.
    """
    path = Path(path)
    try:
        with OpenEXR.File(str(path)) as f:
            channels = {name: np.asarray(ch.pixels) for name, ch in f.channels().items()}
    except Exception as exc:  # OpenEXR raises bare RuntimeErrors/OSErrors on malformed files
        raise ValueError(f"{path}: cannot be read as OpenEXR ({exc}); export it as a linear "
                         f"float OpenEXR (.exr) file") from exc
    for name in ("RGB", "RGBA"):
        if name in channels:
            return np.ascontiguousarray(channels[name][..., :3], dtype=np.float32)
    if all(c in channels for c in "RGB"):
        return np.stack([channels[c] for c in "RGB"], axis=-1).astype(np.float32)
    if "Y" in channels:
        y = channels["Y"].astype(np.float32)
        return np.repeat(y[..., None], 3, axis=-1)
    raise ValueError(f"{path}: has channels {sorted(channels)}; expected R, G, B (or Y)")


def write_exr(path: str | Path, image: np.ndarray) -> None:
    """Write linear RGB as a float32 OpenEXR file, atomically (temporary file + rename).

    Parameters
    ----------
    path : str or Path
        Destination; an existing file is replaced only once the new one is complete.
    image : ndarray, shape (height, width, 3) or (height, width)
        Linear radiance; a 2-D array is written as gray RGB.
    """
    path = Path(path)
    image = np.asarray(image, dtype=np.float32)
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=-1)
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image of shape {image.shape}; expected (height, width, 3)")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path) as tmp, \
            OpenEXR.File(header, {"RGB": np.ascontiguousarray(image)}) as f:
        f.write(str(tmp))
