"""Reading a file's bytes and decoding an image, with errors that name the file (shared by the readers)."""

from __future__ import annotations

import contextlib
import math
import os
import threading
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


_QUIET = threading.Lock()
_quiet_calls = 0
_saved_level = 0


@contextlib.contextmanager
def _opencv_quiet():
    """OpenCV's log silent for the duration, restored after the last of overlapping calls.

    OpenCV prints ``[ WARN ]``/``[ERROR]`` lines on stderr for a truncated PNG, TIFF or PGM, before surfnorm's
    own one-line error.
    """
    global _quiet_calls, _saved_level
    logging = getattr(getattr(cv2, "utils", None), "logging", None)
    if logging is None:  # pragma: no cover - an OpenCV without the logging module
        yield
        return
    with _QUIET:
        if _quiet_calls == 0:
            _saved_level = logging.getLogLevel()
            logging.setLogLevel(logging.LOG_LEVEL_SILENT)
        _quiet_calls += 1
    try:
        yield
    finally:
        with _QUIET:
            _quiet_calls -= 1
            if _quiet_calls == 0:
                logging.setLogLevel(_saved_level)


def decode_image(path: Path, raw: bytes, flags: int, kind: str = "an image") -> np.ndarray:
    """``cv2.imdecode`` of a file's bytes; a DataFileError naming the file where they are empty or not an image."""
    try:
        with _opencv_quiet():
            img = cv2.imdecode(np.frombuffer(raw, dtype=np.uint8), flags) if raw else None
    except cv2.error as exc:
        raise DataFileError(f"{path}: cannot decode as {kind} (truncated or corrupt)") from exc
    if img is None:
        raise DataFileError(f"{path}: cannot decode as {kind} (empty, truncated or corrupt)")
    return img


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (or cannot be looked at): compare the paths
        return os.path.abspath(a) == os.path.abspath(b)


def check_outputs(outputs, reads, *, overwrite: bool = False, name: str = "output") -> None:
    """Refuse to write ``outputs`` over a file that the command reads (``reads``, None entries ignored), always,
    and over any file that exists unless ``overwrite``; an InputError naming the file otherwise.

    A command never replaces its own input, whatever ``overwrite`` says (the 16-bit depth would be lost to its
    normal picture); an existing output is replaced only when the user asked for it.
    """
    reads = [Path(r) for r in reads if r is not None]
    for out in map(Path, outputs):
        for src in reads:
            if _same_file(out, src):
                raise InputError(
                    f"{name}: expected a path other than the files this command reads, got {out}, which is {src}; "
                    "choose another output name"
                )
        if out.is_dir():
            raise InputError(f"{name}: expected a file path, got {out}, which is a folder")
        if (out.exists() or out.is_symlink()) and not overwrite:
            raise InputError(f"{name}: {out} exists; pass --overwrite to replace it, or choose another output name")


def _size_text(n: int) -> str:
    for unit, size in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{n} bytes"


def check_npy_header(path: Path, fh, available: int, what: str) -> None:
    """Refuse a ``.npy`` stream whose header declares more data than the stream holds, before NumPy allocates it.

    ``fh`` is at the start of the ``.npy`` data (a file, or a member of an ``.npz`` archive) and holds
    ``available`` bytes from there; it is left wherever the header ends. A 1 KB file whose header claims
    (100000, 100000) would otherwise make NumPy allocate 37 GiB (MemoryError) before finding the file short.
    A header NumPy cannot parse is left for ``np.load`` to report.
    """
    fmt = np.lib.format
    try:
        start = fh.tell()
        version = fmt.read_magic(fh)
        read_header = fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0
        shape, _, dtype = read_header(fh, max_header_size=10_000)
        held = available - (fh.tell() - start)
    except Exception:  # noqa: BLE001 - not a .npy header NumPy understands: np.load says why
        return
    need = dtype.itemsize * math.prod(shape)
    if need > held:
        raise DataFileError(
            f"{path}: cannot read as NumPy {what} (truncated or corrupt: its header declares shape {tuple(shape)} "
            f"of {dtype}, {_size_text(need)}, but the file holds {_size_text(max(held, 0))} of data)"
        )
