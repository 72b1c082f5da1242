"""Depth files: 3F2N .bin, NumPy .npy/.npz, 16-bit PNG (with a depth scale) and float TIFF.

Every reader returns float32 (H, W) and never judges the values: 0, negative,
NaN and inf stay as they are and are masked as invalid by
:func:`surfnorm.estimate`. Anything that cannot be read as a depth image
raises :class:`~surfnorm.errors.DataFileError` naming the file.

Disparity
---------
Stereo cameras give disparity d = f_x B / z (pixels) instead of depth.
:func:`disparity_to_depth` converts it when the baseline ``B`` is known;
``surfnorm.estimate(d, K, disparity=True)`` takes disparity (or any inverse
depth known only up to scale) directly, see :mod:`surfnorm.units`.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import cv2
import numpy as np

from .._validate import check_positive
from ..errors import DataFileError
from ._files import as_path, check_shape, decode_image, read_bytes
from .threef2n import HEIGHT, WIDTH, read_depth_bin

__all__ = ["read_depth", "read_mask", "disparity_to_depth", "depth_suffix", "DEPTH_SUFFIXES"]

DEPTH_SUFFIXES = (".bin", ".bin.gz", ".npy", ".npz", ".png", ".tif", ".tiff")

#: Common depth scales of 16-bit PNG depth: raw units per metre.
DEPTH_SCALES = {"mm": 1000.0, "tum": 5000.0}


def depth_suffix(path) -> str:
    """The depth-file suffix of ``path``, lower case; ``.bin.gz`` counts as one suffix."""
    name = Path(path).name.lower()
    return ".bin.gz" if name.endswith(".bin.gz") else Path(name).suffix


def _read_numpy(path: Path, suffix: str, name: str = "depth") -> np.ndarray:
    """The array of a .npy file, or of a .npz archive (the array called ``name``, or its only array)."""
    try:
        with open(path, "rb") as fh:
            data = np.load(fh, allow_pickle=False)
            if suffix == ".npz":
                with data:
                    keys = list(data.keys())
                    if name in keys:
                        return np.asarray(data[name])
                    if len(keys) != 1:
                        raise DataFileError(f"{path}: expected an array named {name!r} or a single array in the .npz archive, "
                                            f"got {len(keys)} arrays ({', '.join(keys) or 'none'})")
                    return np.asarray(data[keys[0]])
            return np.asarray(data)
    except DataFileError:
        raise
    except OSError as exc:
        raise DataFileError(f"{path}: cannot read {name} file ({exc.strerror or exc})") from exc
    except (ValueError, EOFError, zipfile.BadZipFile, KeyError) as exc:
        raise DataFileError(f"{path}: cannot read as NumPy {suffix} {name} (truncated or corrupt: {exc})") from exc


def _read_image(path: Path) -> np.ndarray:
    img = decode_image(path, read_bytes(path, "depth"), cv2.IMREAD_UNCHANGED)
    if img.ndim != 2:
        raise DataFileError(f"{path}: expected a single-channel depth image, got {img.shape[2]} channels "
                            f"(shape {img.shape}); a colour picture is not depth")
    if img.dtype == np.uint8:
        raise DataFileError(f"{path}: expected 16-bit integer or 32-bit float depth, got an 8-bit image "
                            "(8 bits cannot hold sensor depth; is this a picture?)")
    return img


def read_depth(path, *, depth_scale: float | None = None, shape=(HEIGHT, WIDTH)) -> np.ndarray:
    """Read a depth image as float32 (H, W).

    Parameters
    ----------
    path : str or Path
        ``.png`` (16-bit, one channel), ``.tif``/``.tiff`` (float or 16-bit),
        ``.npy``, ``.npz`` (array ``depth`` or the only array), 3F2N ``.bin``
        or ``.bin.gz`` (raw float32 of ``shape``).
    depth_scale : float, optional
        Raw units per depth unit: the values are divided by it (1000 turns
        millimetres into metres, 5000 is TUM RGB-D's PNG scale). 0 stays 0,
        i.e. invalid. None keeps the values as stored.
    shape : (int, int)
        Rows and columns of a ``.bin`` file (3F2N: 480 x 640).

    Raises
    ------
    DataFileError (a ValueError)
        Missing, unreadable, truncated or corrupt file, or not one depth channel.
    InputError (a ValueError)
        ``path`` not a path, ``shape`` not two positive integers, ``depth_scale``
        not a positive finite number.
    """
    path = as_path(path)
    shape = check_shape(shape)
    if depth_scale is not None:
        depth_scale = check_positive("depth_scale", depth_scale)
    if path.is_dir():
        raise DataFileError(f"{path}: expected a depth file, got a directory")
    suffix = depth_suffix(path)
    if suffix in (".bin", ".bin.gz"):
        depth = read_depth_bin(path, shape)
    elif suffix in (".npy", ".npz"):
        depth = _read_numpy(path, suffix)
    elif suffix in (".png", ".tif", ".tiff"):
        depth = _read_image(path)
    else:
        raise DataFileError(f"{path}: unknown depth file type {suffix!r}; expected one of {', '.join(DEPTH_SUFFIXES)}")
    if depth.ndim != 2:
        raise DataFileError(f"{path}: expected a 2-D depth image, got an array of shape {depth.shape}")
    if depth.dtype == bool or not (np.issubdtype(depth.dtype, np.integer) or np.issubdtype(depth.dtype, np.floating)):
        raise DataFileError(f"{path}: expected real-valued depth (float or integer), got dtype {depth.dtype}")
    if depth_scale is not None and depth_scale != 1:
        return (depth.astype(np.float64) / depth_scale).astype(np.float32)
    return np.ascontiguousarray(depth, dtype=np.float32)


def read_mask(path) -> np.ndarray:
    """A mask file as bool (H, W): any image, ``.npy`` or ``.npz`` (array ``mask`` or the only one); non-zero = usable."""
    path = as_path(path)
    suffix = depth_suffix(path)
    if suffix in (".npy", ".npz"):
        arr = _read_numpy(path, suffix, "mask")
    else:
        arr = decode_image(path, read_bytes(path, "mask"), cv2.IMREAD_GRAYSCALE)
    real = arr.dtype == bool or np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)
    if arr.ndim != 2 or not real:  # not strings, complex numbers, objects or records
        raise DataFileError(f"{path}: expected a 2-D mask, got an array of shape {arr.shape} and dtype {arr.dtype} "
                            "(a mask holds booleans or real numbers)")
    return np.ascontiguousarray(arr != 0)


def disparity_to_depth(disparity, baseline: float, fx: float) -> np.ndarray:
    """Depth z = f_x B / d from disparity ``d`` in pixels, float32 (H, W).

    ``baseline`` B is in the depth unit wanted (metres gives metres). Pixels
    with a disparity that is 0, negative or not finite get depth 0 (invalid).
    When B is unknown, pass the disparity to ``surfnorm.estimate(...,
    disparity=True)`` instead: every estimator's normals depend on depth only
    up to scale there.
    """
    baseline = check_positive("baseline", baseline)
    fx = check_positive("fx", fx)
    d = np.asarray(disparity, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        ok = np.isfinite(d) & (d > 0)
        z = np.where(ok, fx * baseline / np.where(ok, d, 1.0), 0.0)
    return z.astype(np.float32)
