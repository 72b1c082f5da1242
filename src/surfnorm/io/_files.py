"""Reading a file's bytes and decoding an image, with errors that name the file (shared by the readers)."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from ..errors import DataFileError, InputError


def as_path(path, name: str = "path") -> Path:
    """``path`` (str, os.PathLike or bytes) as a Path; an InputError naming ``name`` for anything else."""
    if isinstance(path, bytes):
        path = os.fsdecode(path)
    if not isinstance(path, (str, os.PathLike)):
        raise InputError(f"{name}: expected a file path (str or os.PathLike), got {type(path).__name__} {path!r:.60}")
    path = Path(path)
    if not str(path) or str(path) == ".":
        raise InputError(f"{name}: expected a file path, got an empty one")
    return path


def check_shape(shape, name: str = "shape") -> tuple[int, int]:
    """``shape`` as (rows, cols) of positive ints; an InputError naming ``name`` otherwise."""
    try:
        rows, cols = shape
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected (rows, cols), two positive integers, got {shape!r:.60}") from None
    for v in (rows, cols):
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or v < 1:
            raise InputError(f"{name}: expected (rows, cols), two positive integers, got {shape!r:.60}")
    return int(rows), int(cols)


def read_bytes(path: Path, name: str) -> bytes:
    """The bytes of ``path``; a DataFileError "cannot read <name> file (reason)" if it cannot be read."""
    try:
        return path.read_bytes()
    except OSError as exc:
        raise DataFileError(f"{path}: cannot read {name} file ({exc.strerror or exc})") from exc


def decode_image(path: Path, raw: bytes, flags: int, kind: str = "an image") -> np.ndarray:
    """``cv2.imdecode`` of a file's bytes; a DataFileError naming the file where they are empty or not an image."""
    try:
        img = cv2.imdecode(np.frombuffer(raw, dtype=np.uint8), flags) if raw else None
    except cv2.error as exc:
        raise DataFileError(f"{path}: cannot decode as {kind} (truncated or corrupt)") from exc
    if img is None:
        raise DataFileError(f"{path}: cannot decode as {kind} (empty, truncated or corrupt)")
    return img
