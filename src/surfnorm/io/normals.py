"""Normal-map files: NumPy float32, 16-bit PNG in the 3F2N encoding, 8-bit PNG pictures.

=========  ===========  ======================================================
format     suffix       content
=========  ===========  ======================================================
``npy``    ``.npy``     float32 (H, W, 3), exactly what ``estimate`` returned
``png16``  ``.png``     uint16 RGB, png = (1 - n) * 65535 / 2 (the 3F2N ground
                        truth encoding), lossless to 1.5e-5 per component
``png8``   ``.png``     uint8 RGB picture: (1 - n) / 2 ("3f2n" colouring, as in
                        the 3F2N data and the D2NT paper) or (n + 1) / 2
                        ("opengl"), to look at, not to measure with
=========  ===========  ======================================================

Pixels without a normal (zero or non-finite vector) are written as white
(65535 or 255 in every channel, as the 3F2N ground truth's background). That
decodes to a vector of length sqrt(3), which no unit normal has, so the
readers return them as missing: a decoded vector whose length is further than
:data:`MISSING_TOLERANCE` from 1 is missing. Every write is atomic and gives
the same bytes for the same normals.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from .._validate import check_choice, check_fill
from ..errors import DataFileError, InputError
from ._atomic import atomic_write
from ._files import check_npy_header, decode_image, read_bytes
from .pictures import COLOURINGS, normal_to_rgb8

__all__ = [
    "NORMAL_FORMATS",
    "OUTPUT_FORMATS",
    "FORMAT_SUFFIX",
    "write_normals",
    "read_normals",
    "encode_png16",
    "decode_png",
]

NORMAL_FORMATS = ("npy", "png16", "png8")
#: What a batch (surfnorm.convert) and the command line write: a normal map, or a PLY point cloud (surfnorm.io.ply).
OUTPUT_FORMATS = NORMAL_FORMATS + ("ply",)
FORMAT_SUFFIX = {"npy": ".npy", "png16": ".png", "png8": ".png", "ply": ".ply"}
#: A decoded vector whose length differs from 1 by more than this is a missing normal.
MISSING_TOLERANCE = 0.1
_PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 3]  # fixed, so equal normals give equal bytes


def _as_normals(normals) -> np.ndarray:
    n = np.asarray(normals)
    if n.ndim != 3 or n.shape[-1] != 3 or not np.issubdtype(n.dtype, np.floating):
        raise InputError(f"normals: expected a float array of shape (H, W, 3), got shape {n.shape} and dtype {n.dtype}")
    return np.ascontiguousarray(n, dtype=np.float32)


def _missing(n: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", over="ignore"):
        sq = np.einsum("hwc,hwc->hw", n.astype(np.float64), n.astype(np.float64))
    return ~(np.isfinite(sq) & (sq > 0))


def encode_png16(normals) -> np.ndarray:
    """Unit normals (H, W, 3) to uint16 RGB in the 3F2N encoding; missing pixels 65535 (white)."""
    n = _as_normals(normals)
    img = np.rint((1.0 - np.nan_to_num(n.astype(np.float64))) * (65535.0 / 2.0))
    img = np.clip(img, 0, 65535).astype(np.uint16)
    img[_missing(n)] = 65535
    return img


def decode_png(img: np.ndarray, *, colouring: str = "3f2n", fill: float = 0.0) -> np.ndarray:
    """RGB uint16 (3F2N encoding) or uint8 (picture of ``colouring``) to unit normals float32 (H, W, 3)."""
    check_choice("colouring", colouring, COLOURINGS)
    scale = 65535.0 if img.dtype == np.uint16 else 255.0
    x = img.astype(np.float64) / scale
    n = 1.0 - 2.0 * x if (img.dtype == np.uint16 or colouring == "3f2n") else 2.0 * x - 1.0
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    ok = np.abs(norm - 1.0) <= MISSING_TOLERANCE
    out = np.where(ok, n / np.where(ok, norm, 1.0), fill)
    return out.astype(np.float32)


class _Chunks:
    """A file that NumPy writes through ``write`` (a real file it would write with ``ndarray.tofile``)."""

    def __init__(self, fh):
        self.write = fh.write


def write_normals(path, normals, *, fmt: str = "npy", colouring: str = "3f2n") -> Path:
    """Write a normal map atomically as ``fmt`` (see the module docstring); returns the path.

    ``colouring`` applies to ``png8`` only. The bytes depend only on the normals. A file that cannot be
    written (no such folder, a full disk) is a DataFileError naming ``path`` and the system's reason.
    """
    check_choice("fmt", fmt, NORMAL_FORMATS)
    check_choice("colouring", colouring, COLOURINGS)
    n = _as_normals(normals)
    path = Path(path)
    if fmt == "npy":

        def write(tmp: Path):
            with open(tmp, "wb") as fh:
                # Through fh.write in chunks (not ndarray.tofile, whose error on a full disk is "921600 requested
                # and 262112 written", without the system's reason): the same bytes.
                np.save(_Chunks(fh), n, allow_pickle=False)
    else:
        rgb = encode_png16(n) if fmt == "png16" else normal_to_rgb8(n, colouring=colouring)
        bgr = np.ascontiguousarray(rgb[:, :, ::-1])

        def write(tmp: Path):
            ok, buf = cv2.imencode(".png", bgr, _PNG_PARAMS)
            if not ok:  # pragma: no cover - OpenCV encodes any uint8/uint16 RGB array
                raise DataFileError(f"{path}: could not encode PNG")
            with open(tmp, "wb") as fh:
                fh.write(buf.tobytes())

    return atomic_write(path, write)


def read_normals(path, *, colouring: str = "3f2n", fill: float = 0.0) -> np.ndarray:
    """Read a normal map written by :func:`write_normals` (or a 3F2N ground-truth PNG) as float32 (H, W, 3).

    ``.npy``: returned as stored. ``.png``: 16-bit is the 3F2N encoding,
    8-bit a picture of ``colouring``; decoded vectors are normalised and
    missing pixels (white) get ``fill`` in all three components.
    """
    path = Path(path)
    fill = check_fill(fill)
    suffix = path.suffix.lower()
    raw = read_bytes(path, "normal")
    if suffix == ".npy":
        import io

        check_npy_header(path, io.BytesIO(raw), len(raw), "normal map")
        try:
            n = np.load(io.BytesIO(raw), allow_pickle=False)
        except MemoryError as exc:
            raise DataFileError(f"{path}: cannot read as a NumPy normal map: it does not fit in memory") from exc
        except (ValueError, EOFError, OSError) as exc:
            raise DataFileError(f"{path}: cannot read as a NumPy normal map (truncated or corrupt: {exc})") from exc
        if n.ndim != 3 or n.shape[-1] != 3 or not np.issubdtype(n.dtype, np.floating):
            raise DataFileError(
                f"{path}: expected a float array of shape (H, W, 3), got shape {n.shape} and dtype {n.dtype}"
            )
        return np.ascontiguousarray(n, dtype=np.float32)
    if suffix != ".png":
        raise DataFileError(f"{path}: unknown normal file type {suffix!r}; expected .npy or .png")
    img = decode_image(path, raw, cv2.IMREAD_UNCHANGED, "PNG")
    if img.ndim != 3 or img.shape[2] < 3 or img.dtype not in (np.uint8, np.uint16):
        raise DataFileError(
            f"{path}: expected an 8- or 16-bit RGB PNG normal map, got shape {img.shape} and dtype {img.dtype}"
        )
    return decode_png(np.ascontiguousarray(img[:, :, 2::-1]), colouring=colouring, fill=fill)
