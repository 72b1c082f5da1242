"""Atomic file writes: write a temporary file beside the target, then rename it over.

A reader never sees a half-written output, and a run killed mid-write leaves
at most a hidden ``.<name>.<random>.tmp<suffix>`` file, never a truncated output.
Where that name would be longer than the filesystem allows (255 bytes) while
the output's own name is not, ``<name>`` is shortened and ends with ``~``
(:func:`temporary_affixes`).

The writer holds an exclusive ``flock`` on its temporary file until the
output is in place, so a cleanup of stale temporaries
(:func:`remove_if_stale`) can tell a killed run's leftover (no lock: its
process is gone) from another live run's file in flight (locked), which it
leaves alone.

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

from ..errors import DataFileError

__all__ = ["atomic_write", "new_file_mode", "temporary_affixes", "remove_if_stale", "TRUNCATED"]

#: The last character of a temporary file's ``<name>`` part when the output's name had to be shortened.
TRUNCATED = "~"
_RANDOM = 8  # characters of tempfile.mkstemp's random part


def _name_max(folder) -> int:
    try:
        return int(os.pathconf(folder, "PC_NAME_MAX"))
    except (OSError, ValueError, AttributeError):  # no pathconf (Windows), or no such folder yet
        return 255


def temporary_affixes(path) -> tuple[str, str]:
    """(prefix, suffix) of the temporary file of ``path``: ``.<name>.`` and ``.tmp<suffix>``.

    ``<name>`` is the output's name, shortened (ending with :data:`TRUNCATED`) where the temporary file's whole
    name would exceed the folder's limit (255 bytes on most filesystems) although the output's fits.
    """
    path = Path(path)
    name, suffix = path.name, ".tmp" + path.suffix
    budget = _name_max(path.parent) - len(os.fsencode(suffix)) - _RANDOM - 2  # the two dots around <name>
    if len(os.fsencode(name)) > budget:
        shortened = os.fsencode(name)[: max(budget - len(TRUNCATED), 1)]
        name = shortened.decode(errors="ignore") + TRUNCATED  # (a cut inside a UTF-8 character is dropped)
    return f".{name}.", suffix


def _lock(fd: int, blocking: bool) -> bool:
    """An exclusive flock on ``fd``; False where another open file holds one (non-blocking) or there is no flock."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        return not blocking
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | (0 if blocking else fcntl.LOCK_NB))
    except OSError:  # BlockingIOError: held by a live writer; or flock unsupported on this filesystem
        return False
    return True


def remove_if_stale(tmp: Path) -> bool:
    """Remove the temporary file ``tmp`` if no live writer holds it (its lock); True if it was removed.

    A writer locks its temporary file for as long as it exists, so an unlocked one was left by a killed run.
    Where locks are unavailable (no ``fcntl``), nothing is removed.
    """
    try:
        fd = os.open(tmp, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    except OSError:  # gone meanwhile, a link, or unreadable
        return False
    try:
        if not _lock(fd, blocking=False):
            return False
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            return False
        return True
    finally:
        os.close(fd)


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
    """Call ``write(tmp_path)`` and rename the result to ``path`` (same directory, same filesystem).

    Raises
    ------
    DataFileError
        The file could not be written: one line naming ``path`` (never the temporary file) and the system's
        reason, e.g. "cannot write out.npy (No space left on device)". Nothing is left behind.
    """
    path = Path(path)
    try:
        return _atomic_write(path, write)
    except OSError as exc:
        raise DataFileError(f"cannot write {path} ({exc.strerror or exc})") from exc


def _atomic_write(path: Path, write: Callable[[Path], object]) -> Path:
    mode = new_file_mode(path)
    prefix, suffix = temporary_affixes(path)
    fd, tmp_name = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=path.parent)
    tmp = Path(tmp_name)
    try:
        _lock(fd, blocking=True)  # held until the output is in place: the file is in flight, not stale
        write(tmp)
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    finally:
        os.close(fd)
    return path
