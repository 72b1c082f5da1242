"""Pictures people look at: normal maps and angular-error maps as 8-bit PNG."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ..errors import DataFileError, InputError
from ._atomic import atomic_write

__all__ = ["normals_to_rgb", "normal_to_rgb8", "error_to_rgb8", "write_rgb8"]

COLOURINGS = ("3f2n", "opengl")


def normal_to_rgb8(normals: np.ndarray, *, colouring: str = "3f2n", background=(255, 255, 255)) -> np.ndarray:
    """Normals (H, W, 3) to an RGB uint8 picture.

    ``"3f2n"`` colours n as (1 - n) / 2 (the 3F2N dataset's and the D2NT
    paper's pictures); ``"opengl"`` as (n + 1) / 2. Pixels without a normal
    (zero or non-finite) get ``background``.
    """
    if colouring not in COLOURINGS:
        raise InputError(f"colouring: expected one of {', '.join(COLOURINGS)}, got {colouring!r}")
    n = np.asarray(normals, dtype=np.float32)
    rgb = (1.0 - n) / 2.0 if colouring == "3f2n" else (n + 1.0) / 2.0
    img = np.clip(np.rint(np.nan_to_num(rgb) * 255.0), 0, 255).astype(np.uint8)
    with np.errstate(invalid="ignore"):
        sq = np.einsum("hwc,hwc->hw", n, n)
    img[~(np.isfinite(sq) & (sq > 0))] = background
    return img


def normals_to_rgb(normals, *, colouring: str = "3f2n", background=(255, 255, 255)) -> np.ndarray:
    """A normal map (H, W, 3) as an RGB picture (H, W, 3) uint8, as ``surfnorm estimate`` and the demo draw it.

    Parameters
    ----------
    normals : ndarray of shape (H, W, 3)
        Unit normals in surfnorm's camera frame (x right, y down, z forward), e.g. from
        :func:`surfnorm.estimate`.
    colouring : {"3f2n", "opengl"}
        ``"3f2n"`` (default) colours n as (1 - n) / 2, the 3F2N dataset's and the D2NT paper's pictures (a
        wall facing the camera is light blue); ``"opengl"`` as (n + 1) / 2.
    background : tuple of 3 ints
        Colour of pixels without a normal (zero or non-finite).

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        RGB; write it with ``cv2.imwrite(path, rgb[:, :, ::-1])`` (OpenCV wants BGR) or show it with Matplotlib.

    Examples
    --------
    >>> import numpy as np
    >>> from surfnorm.io import normals_to_rgb
    >>> n = np.zeros((1, 2, 3), np.float32); n[0, 0] = [0, 0, -1]
    >>> normals_to_rgb(n).tolist()
    [[[128, 128, 255], [255, 255, 255]]]
    """
    n = np.asarray(normals)
    if n.ndim != 3 or n.shape[-1] != 3 or not np.issubdtype(n.dtype, np.floating):
        raise InputError(f"normals: expected a float array of shape (H, W, 3), got shape {n.shape} and dtype {n.dtype}")
    return normal_to_rgb8(n, colouring=colouring, background=background)


def error_to_rgb8(
    error_deg: np.ndarray, *, vmax: float = 30.0, cmap: str = "inferno", background=(255, 255, 255)
) -> np.ndarray:
    """Angular error in degrees (H, W) to an RGB uint8 picture on a fixed scale [0, vmax]; NaN -> background."""
    from matplotlib import colormaps

    err = np.asarray(error_deg, dtype=np.float64)
    rgba = colormaps[cmap](np.clip(np.nan_to_num(err, nan=0.0) / vmax, 0.0, 1.0))
    img = np.rint(rgba[..., :3] * 255).astype(np.uint8)
    img[~np.isfinite(err)] = background
    return img


def write_rgb8(path, rgb: np.ndarray) -> Path:
    """Write an RGB uint8 image as PNG, atomically."""
    path = Path(path)

    def write(tmp: Path):
        if not cv2.imwrite(str(tmp), np.ascontiguousarray(rgb[:, :, ::-1])):  # tmp ends in .png
            raise DataFileError(f"{path}: could not write PNG")

    return atomic_write(path, write)
