"""The 3F2N dataset layout (Fan et al., Three-Filters-to-Normal, RA-L 2021).

::

    ROOT/<level>/<object>/depth/000001.bin   float32, 480x640, row-major; background depth exactly 1.0
    ROOT/<level>/<object>/normal/000001.png  16-bit RGB ground truth, n = 1 - 2 png / 65535 (RGB order)
    ROOT/<level>/<object>/params.txt         "fx fy u0 v0 count", principal point 1-based

Levels are Easy, Medium and Hard. Depth files may also be gzip-compressed
(``000001.bin.gz``), as in the sample shipped inside surfnorm.
"""

from __future__ import annotations

import gzip
import os
import zlib
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..camera import Intrinsics
from ..errors import DataFileError

__all__ = [
    "Frame",
    "read_params",
    "params_for",
    "read_frame",
    "find_frames",
    "sample_root",
    "LEVELS",
    "HEIGHT",
    "WIDTH",
]

LEVELS = ("Easy", "Medium", "Hard")
HEIGHT, WIDTH = 480, 640
BACKGROUND_DEPTH = 1.0


@dataclass
class Frame:
    """One frame of the 3F2N dataset.

    Depth (H, W) float32, ground-truth normals (H, W, 3) float32 (camera-facing), mask (foreground,
    depth != 1), intrinsics (0-based) and its name ``level/object/frame``.
    """

    name: str
    level: str
    depth: np.ndarray
    normals: np.ndarray
    mask: np.ndarray
    K: Intrinsics


def sample_root() -> Path:
    """The 3F2N frames shipped inside surfnorm (one per level, gzip-compressed)."""
    return Path(__file__).resolve().parent.parent / "data" / "3f2n-sample"


def read_params(path) -> Intrinsics:
    """Intrinsics from a 3F2N ``params.txt`` (``fx fy u0 v0 count``), converted to 0-based pixel centres."""
    path = Path(path)
    try:
        fields = path.read_text().split()
        fx, fy, u0, v0 = (float(x) for x in fields[:4])
    except OSError as exc:
        raise DataFileError(f"{path}: cannot read 3F2N params.txt ({exc.strerror or exc})") from exc
    except (ValueError, UnicodeDecodeError) as exc:
        raise DataFileError(f"{path}: expected 'fx fy u0 v0 count' numbers, got {path.read_bytes()[:80]!r}") from exc
    return Intrinsics(fx, fy, u0 - 1.0, v0 - 1.0)


def params_for(depth_path) -> Path | None:
    """The ``params.txt`` that holds the camera of a depth file, or None.

    Looked for beside the file, then in the folder above it (the 3F2N layout
    ``<object>/depth/<frame>.bin`` -> ``<object>/params.txt``), from the file's
    absolute path: ``f.bin`` and ``$PWD/f.bin`` find the same file.
    """
    path = Path(depth_path).absolute()
    for folder in (path.parent, path.parent.parent):
        if (folder / "params.txt").is_file():
            return folder / "params.txt"
    return None


def _read_at_most(fh, n: int, chunk: int = 1 << 24) -> bytes:
    """Up to ``n`` bytes of ``fh``, in chunks.

    ``read(n)`` would allocate ``n`` bytes first, however short the stream (a ``shape`` of 100000 x 100000 is
    40 GB).
    """
    parts, total = [], 0
    while total < n:
        part = fh.read(min(chunk, n - total))
        if not part:
            break
        parts.append(part)
        total += len(part)
    return b"".join(parts)


def read_depth_bin(path, shape=(HEIGHT, WIDTH)) -> np.ndarray:
    """A 3F2N ``.bin`` (or ``.bin.gz``) depth file: raw float32, row-major."""
    path = Path(path)
    expected = shape[0] * shape[1] * 4
    try:
        if path.suffix == ".gz":
            # decompress at most one byte more than a frame holds: a small file that unpacks to
            # gigabytes ("gzip bomb") is refused once it passes the frame size, never held whole
            with gzip.open(path, "rb") as fh:
                raw = _read_at_most(fh, expected + 1)
            if len(raw) > expected:
                raise DataFileError(
                    f"{path}: expected {expected} bytes of float32 depth ({shape[0]}x{shape[1]}) "
                    f"once decompressed, got more"
                )
        else:
            with open(path, "rb") as fh:
                size = os.fstat(fh.fileno()).st_size
                # (a shape larger than the file is refused before a buffer of its size is allocated)
                raw = fh.read(expected + 1) if size == expected else b""
    except (EOFError, gzip.BadGzipFile, zlib.error) as exc:  # BadGzipFile is an OSError: test it first
        raise DataFileError(f"{path}: truncated or corrupt gzip stream ({exc})") from exc
    except OSError as exc:
        raise DataFileError(f"{path}: cannot read depth file ({exc.strerror or exc})") from exc
    if len(raw) != expected:
        got = len(raw) if path.suffix == ".gz" else size
        raise DataFileError(f"{path}: expected {expected} bytes of float32 depth ({shape[0]}x{shape[1]}), got {got}")
    return np.frombuffer(raw, dtype="<f4").reshape(shape).copy()


def read_normal_png(path) -> np.ndarray:
    """Ground truth from a 3F2N 16-bit PNG: n = 1 - 2 png / 65535 in RGB order, normalised, float32.

    Pixels whose decoded vector is zero are returned as zeros.
    """
    path = Path(path)
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise DataFileError(f"{path}: cannot read as an image (missing, truncated or not a PNG)")
    if img.ndim != 3 or img.shape[2] < 3 or img.dtype != np.uint16:
        raise DataFileError(f"{path}: expected a 16-bit RGB PNG, got shape {img.shape} dtype {img.dtype}")
    n = 1.0 - 2.0 * img[:, :, 2::-1].astype(np.float64) / 65535.0
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = np.where(norm > 0, n / norm, 0.0)
    return n.astype(np.float32)


def _depth_path(obj_dir: Path, frame: str) -> Path:
    for candidate in (obj_dir / "depth" / f"{frame}.bin", obj_dir / "depth" / f"{frame}.bin.gz"):
        if candidate.exists():
            return candidate
    return obj_dir / "depth" / f"{frame}.bin"


def read_frame(root, name: str) -> Frame:
    """Read frame ``level/object/frame`` (e.g. ``Easy/android/000001``) under ``root``."""
    root = Path(root)
    level, obj, frame = name.split("/")
    obj_dir = root / level / obj
    depth = read_depth_bin(_depth_path(obj_dir, frame))
    normals = read_normal_png(obj_dir / "normal" / f"{frame}.png")
    if normals.shape[:2] != depth.shape:
        raise DataFileError(
            f"{obj_dir / 'normal' / (frame + '.png')}: expected {depth.shape} pixels to match depth, got {normals.shape[:2]}"
        )
    K = read_params(obj_dir / "params.txt")
    return Frame(name, level, depth, normals, depth != BACKGROUND_DEPTH, K)


def find_frames(root, *, levels=LEVELS, frames_per_object: int | None = None) -> list[str]:
    """Names ``level/object/frame`` of every frame under ``root`` whose depth file exists, sorted.

    A frame counts when ``depth/<frame>.bin`` (or ``.bin.gz``) is present; missing
    ground truth or params are reported when the frame is read.
    """
    root = Path(root)
    names = []
    for level in levels:
        level_dir = root / level
        if not level_dir.is_dir():
            continue
        for obj_dir in sorted(p for p in level_dir.iterdir() if p.is_dir()):
            depth_dir = obj_dir / "depth"
            if not depth_dir.is_dir():
                continue
            stems = sorted({p.name.split(".")[0] for p in depth_dir.iterdir() if p.name.endswith((".bin", ".bin.gz"))})
            if frames_per_object is not None:
                stems = stems[:frames_per_object]
            names += [f"{level}/{obj_dir.name}/{s}" for s in stems]
    return names
