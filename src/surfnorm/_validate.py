"""Input checks of the front door, and which pixels are valid.

The array rules (dtype, shape, contiguity), the validity of depth, and the
checkers of options that the registry (:mod:`surfnorm.methods`) and the
command line use. Other modules check what only they know and raise the same
:class:`~surfnorm.errors.InputError`: intrinsics (:mod:`surfnorm.camera`),
files (:mod:`surfnorm.io`, :class:`~surfnorm.errors.DataFileError` naming the
file), batch arguments (:mod:`surfnorm.batch`), method names and options
(:mod:`surfnorm.methods`).

Kernels below the front door trust what comes out of here: depth is a
C-contiguous float32 array, ``valid`` a C-contiguous bool array of the same
shape, intrinsics are finite with positive focal lengths.
"""

from __future__ import annotations

import functools
import math
import numbers

import numpy as np

from .errors import InputError

__all__ = [
    "as_depth",
    "as_mask",
    "split_masked",
    "valid_pixels",
    "valid_map",
    "as_normals",
    "as_output",
    "check_choice",
    "check_positive",
    "check_bool",
    "check_iterations",
    "check_window",
]

MIN_SIZE = 3


def _describe(arr: np.ndarray) -> str:
    return f"an array of shape {arr.shape} and dtype {arr.dtype}"


def as_depth(depth, *, name: str = "depth", batch: bool = True) -> np.ndarray:
    """Return depth as C-contiguous float32, shape (H, W) or (N, H, W) when ``batch``.

    Integer depth (16-bit sensor images, millimetres) is accepted and converted;
    booleans, complex numbers and objects are refused. Invalid values (0,
    negative, NaN, inf) are kept here and masked by :func:`valid_pixels`.
    """
    if depth is None:
        raise InputError(f"{name}: expected a 2-D array of depth values, got None")
    try:
        arr = np.asarray(depth)
    except Exception as exc:
        raise InputError(f"{name}: expected a 2-D array of depth values, got {type(depth).__name__}") from exc
    if arr.dtype == bool:
        raise InputError(
            f"{name}: expected real-valued depth (float or integer), got {_describe(arr)}; a boolean array is a mask, pass it as mask="
        )
    if arr.dtype.kind not in "fiu":  # (timedelta64 counts as an integer to np.issubdtype)
        raise InputError(f"{name}: expected real-valued depth (float or integer), got {_describe(arr)}")
    ndims = (2, 3) if batch else (2,)
    if arr.ndim not in ndims:
        want = "a 2-D array (H, W) or a stack (N, H, W)" if batch else "a 2-D array (H, W)"
        raise InputError(f"{name}: expected {want}, got {_describe(arr)}")
    # (H, W, 3) looks like a colour image; unless its H would be too few rows for one, so that only a stack of
    # N frames of H x W fits, as a (H, 3) frame is one frame of 3 columns
    if arr.ndim == 3 and arr.shape[-1] <= 4 < arr.shape[-2] and arr.shape[0] >= MIN_SIZE:
        raise InputError(
            f"{name}: expected one depth channel, (H, W) or a stack (N, H, W), got shape {arr.shape}, "
            f"which looks like an image with {arr.shape[-1]} channel(s); pass depth[..., 0] if that channel is depth"
        )
    if arr.shape[-2] < MIN_SIZE or arr.shape[-1] < MIN_SIZE:
        raise InputError(f"{name}: expected at least {MIN_SIZE}x{MIN_SIZE} pixels, got shape {arr.shape}")
    if arr.ndim == 3 and arr.shape[0] == 0:
        raise InputError(f"{name}: expected at least one frame in the stack, got shape {arr.shape}")
    with np.errstate(over="ignore", under="ignore"):  # beyond float32: rescaled from the caller's values later
        return np.ascontiguousarray(arr, dtype=np.float32)


def split_masked(value):
    """(data, usable): a NumPy masked array's data and ``~mask`` (True where not masked); (value, None) otherwise.

    surfnorm honours ``np.ma`` masks: a masked depth pixel is invalid, whatever value lies under the mask.
    """
    if isinstance(value, np.ma.MaskedArray):
        return np.ma.getdata(value), ~np.ma.getmaskarray(value)
    return value, None


def as_mask(mask, shape: tuple, *, name: str = "mask") -> np.ndarray | None:
    """Return the user mask (True = use this pixel) as C-contiguous bool of ``shape``, or None.

    A masked entry of an ``np.ma`` mask counts as False (do not use the pixel).
    """
    if mask is None:
        return None
    if isinstance(mask, np.ma.MaskedArray):
        mask = np.ma.filled(mask, 0)
    arr = np.asarray(mask)
    if arr.dtype.kind not in "bfiu":
        raise InputError(f"{name}: expected a boolean array (True where depth is usable), got {_describe(arr)}")
    if arr.shape != tuple(shape):
        if arr.shape == tuple(shape[-2:]) and len(shape) == 3:
            arr = np.broadcast_to(arr, shape)
        else:
            raise InputError(f"{name}: expected shape {tuple(shape)} to match depth, got shape {arr.shape}")
    if arr.dtype != bool:
        if not np.all(np.isfinite(arr)):
            raise InputError(f"{name}: expected a boolean array, got non-finite values in {_describe(arr)}")
        arr = arr != 0
    return np.ascontiguousarray(arr)


def valid_pixels(depth: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """Pixels whose depth may be used: finite, strictly positive and inside the user mask."""
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(depth) & (depth > 0)
    if mask is not None:
        valid &= mask
    return np.ascontiguousarray(valid)


def _valid_loop(z, out):
    H, W = z.shape
    for v in range(H):
        for u in range(W):
            d = z[v, u]
            out[v, u] = (d > 0) & (d < np.inf)  # finite and positive (NaN fails both)


def _valid_masked_loop(z, mask, out):
    H, W = z.shape
    for v in range(H):
        for u in range(W):
            d = z[v, u]
            out[v, u] = (d > 0) & (d < np.inf) & mask[v, u]


@functools.lru_cache(maxsize=None)
def _valid_kernels():
    """The two loops above compiled with Numba, on first use (so that ``import surfnorm`` loads no Numba)."""
    from ._aot import ahead_of_time
    from ._config import njit

    return ahead_of_time(njit(_valid_loop)), ahead_of_time(njit(_valid_masked_loop))


def valid_map(z: np.ndarray, mask: np.ndarray | None, out: np.ndarray | None = None) -> np.ndarray:
    """Pixels whose depth may be used (finite, positive, in ``mask``): one pass, one allocation (none with ``out``).

    Same result as :func:`valid_pixels` (NumPy, three passes); for validated depth (C-contiguous float32).
    """
    if out is None:
        out = np.empty(z.shape, dtype=np.bool_)
    valid_kernel, valid_masked_kernel = _valid_kernels()
    if mask is None:
        valid_kernel(z, out)
    else:
        valid_masked_kernel(z, mask, out)
    return out


def as_normals(normals, shape: tuple, *, name: str = "normals") -> np.ndarray:
    """Return a normal map as C-contiguous float32 of shape ``shape + (3,)``."""
    arr = np.asarray(normals)
    if not np.issubdtype(arr.dtype, np.floating):
        raise InputError(f"{name}: expected a float array of shape {tuple(shape) + (3,)}, got {_describe(arr)}")
    if arr.shape != tuple(shape) + (3,):
        raise InputError(f"{name}: expected shape {tuple(shape) + (3,)} to match depth, got shape {arr.shape}")
    return np.ascontiguousarray(arr, dtype=np.float32)


def as_output(out, shape: tuple, inputs=(), *, name: str = "out") -> np.ndarray:
    """Check a caller's output array: float32, C-contiguous, writeable, of ``shape``, apart from ``inputs``.

    It is written in place (not converted), so anything else is refused rather
    than copied; and the kernels assume that what they write never overlaps
    what they read.
    """
    if isinstance(out, np.ma.MaskedArray):  # its mask would hide the normals written into its data
        raise InputError(
            f"{name}: expected a plain NumPy array to write the normals into, got a masked array; "
            "pass its .data (np.ma.getdata(out)) or a plain array"
        )
    if not isinstance(out, np.ndarray):
        raise InputError(
            f"{name}: expected a float32 NumPy array of shape {tuple(shape)} to write the normals into, "
            f"got {type(out).__name__}"
        )
    if out.dtype != np.float32 or out.shape != tuple(shape):
        raise InputError(f"{name}: expected a float32 array of shape {tuple(shape)}, got {_describe(out)}")
    if not out.flags.c_contiguous:
        raise InputError(
            f"{name}: expected a C-contiguous array (written in place), got a non-contiguous view; "
            f"pass np.empty({tuple(shape)}, np.float32) or an array like it"
        )
    if not out.flags.writeable:
        raise InputError(f"{name}: expected a writeable array, got a read-only one")
    for input_name, arr in inputs:
        if arr is not None and np.may_share_memory(out, arr):
            raise InputError(f"{name}: expected an array apart from {input_name}, got one that shares memory with it")
    return out


def check_choice(name: str, value, choices) -> str:
    if not isinstance(value, str) or value not in choices:
        raise InputError(f"{name}: expected one of {', '.join(repr(c) for c in choices)}, got {value!r}")
    return value


def check_finite(name: str, value, what: str = "a finite number") -> float:
    """``value`` as a float where it is a finite real number (not a bool), else an InputError: expected ``what``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value):
        raise InputError(f"{name}: expected {what}, got {value!r}")
    return float(value)


def check_positive(name: str, value) -> float:
    if check_finite(name, value, "a positive finite number") <= 0:
        raise InputError(f"{name}: expected a positive finite number, got {value!r}")
    return float(value)


def check_bool(name: str, value) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise InputError(f"{name}: expected True or False, got {value!r}")
    return bool(value)


def check_iterations(name: str, value) -> int | None:
    """A number of passes: a non-negative integer, or None for "until stable"."""
    if value is None:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral) or value < 0:
        raise InputError(
            f"{name}: expected a non-negative integer number of passes, or None to run until stable, got {value!r}"
        )
    return int(value)


def check_fill(value) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InputError(
            f"fill: expected a number (0.0 or nan) written into every component of a pixel without a valid normal, got {value!r}"
        )
    value = float(value)
    with np.errstate(over="ignore", under="ignore"):
        stored = np.float32(value)
    if (np.isinf(stored) and np.isfinite(value)) or (stored == 0 and value != 0):
        raise InputError(
            f"fill: expected a value that the float32 output can hold (0, nan, +-inf, or a magnitude "
            f"between 1.4e-45 and 3.4e38), got {value!r}, which float32 stores as {float(stored)!r}"
        )
    return value


def check_window(name: str, value) -> int:
    """A square pixel neighbourhood's side: an odd integer >= 3 (the window is centred on the pixel)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral) or value < 3 or value % 2 == 0:
        raise InputError(
            f"{name}: expected an odd integer >= 3 (pixels per side of the square neighbourhood "
            f"centred on each pixel), got {value!r}"
        )
    return int(value)


def check_positive_int(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
        raise InputError(f"{name}: expected a positive whole number, got {value!r}")
    return int(value)
