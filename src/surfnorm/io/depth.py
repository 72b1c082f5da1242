"""Depth files: 3F2N .bin, NumPy .npy/.npz, 16-bit PNG (with a depth scale) and float TIFF."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ..errors import DataFileError
from .threef2n import HEIGHT, WIDTH, read_depth_bin

__all__ = ["read_depth", "DEPTH_SUFFIXES"]

DEPTH_SUFFIXES = (".bin", ".bin.gz", ".npy", ".npz", ".png", ".tif", ".tiff", ".exr")


def _suffix(path: Path) -> str:
    name = path.name.lower()
    return ".bin.gz" if name.endswith(".bin.gz") else path.suffix.lower()


def read_depth(path, *, depth_scale: float | None = None, shape=(HEIGHT, WIDTH)) -> np.ndarray:
    """Read a depth image as float32 (H, W).

    ``depth_scale`` divides integer images (1000 for millimetres, 5000 for
    TUM RGB-D); 0 stays 0, i.e. invalid. ``.bin`` files are 3F2N raw float32
    of ``shape``.
    """
    path = Path(path)
    suffix = _suffix(path)
    if suffix in (".bin", ".bin.gz"):
        depth = read_depth_bin(path, shape)
    elif suffix in (".npy", ".npz"):
        try:
            data = np.load(path, allow_pickle=False)
            if suffix == ".npz":
                keys = list(data.keys())
                if not keys:
                    raise DataFileError(f"{path}: empty .npz archive")
                depth = data["depth"] if "depth" in keys else data[keys[0]]
            else:
                depth = data
        except (OSError, ValueError, EOFError) as exc:
            raise DataFileError(f"{path}: cannot read as NumPy depth ({exc})") from exc
    elif suffix in (".png", ".tif", ".tiff", ".exr"):
        depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if depth is None:
            raise DataFileError(f"{path}: cannot read as an image (missing, truncated or corrupt)")
        if depth.ndim != 2:
            raise DataFileError(f"{path}: expected a single-channel depth image, got shape {depth.shape}")
    else:
        raise DataFileError(f"{path}: unknown depth file type {suffix!r}; expected one of {', '.join(DEPTH_SUFFIXES)}")
    depth = np.asarray(depth)
    if np.issubdtype(depth.dtype, np.integer) and depth_scale is not None:
        return (depth.astype(np.float64) / depth_scale).astype(np.float32)
    if depth_scale is not None and depth_scale != 1:
        return (depth.astype(np.float64) / depth_scale).astype(np.float32)
    return depth
