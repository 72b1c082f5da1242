"""Reading a file's bytes and decoding an image, with errors that name the file (shared by the readers)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ..errors import DataFileError


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
