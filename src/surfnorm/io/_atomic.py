"""Atomic file writes: write a temporary file beside the target, then rename it over.

A reader never sees a half-written output, and a run killed mid-write leaves
at most a hidden ``.<name>.<random>.tmp`` file, never a truncated output.

The output gets the permissions an ordinary ``open(path, "w")`` would give it:
those of the file it replaces, or ``0666 & ~umask`` for a new file (a
temporary file is created ``0600``, which would hide outputs from the other
users of a shared filesystem).
"""

from __future__ import annotations

import os
import stat
import tempfile
from pathlib import Path
from typing import Callable

__all__ = ["atomic_write", "new_file_mode"]


def _umask() -> int:
    """This process's umask, read without changing it where Linux says it (/proc/self/status), else set and restored."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)  # no way to read it without setting it elsewhere
    os.umask(mask)
    return mask


def new_file_mode(path) -> int:
    """The mode an ordinary write of ``path`` gives: that of the file there, else ``0o666 & ~umask``."""
    try:
        return stat.S_IMODE(os.stat(path).st_mode)
    except OSError:
        return 0o666 & ~_umask()


def atomic_write(path, write: Callable[[Path], object]) -> Path:
    """Call ``write(tmp_path)`` and rename the result to ``path`` (same directory, same filesystem)."""
    path = Path(path)
    mode = new_file_mode(path)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp" + path.suffix, dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        write(tmp)
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path
