"""The Numba internals that surfnorm relies on, in one place, with the versions they were verified with.

surfnorm uses more of Numba than its public API: a cache locator added to Numba's list of them (a
last-resort cache directory, :func:`_temp_cache_fallback`), a subclass of its per-function disk cache
(:class:`_SafeCache`), a compiler pipeline class (:class:`_NoAliasCompiler`, LLVM's ``noalias``) and the
private ``_nrt=False`` option of ``numba.njit`` (:data:`NO_NRT`). Any Numba release may change these, so
importing this module (which :mod:`surfnorm._config`, and so every kernel, does) checks the installed Numba
against :data:`NUMBA_SUPPORTED` and raises an ImportError that names the supported range and the version
found. pyproject.toml declares the same range (tests/test_project.py checks that they agree). To support a
newer Numba: run ``make test`` with it, then raise the upper bound here and in pyproject.toml (both the
build-system requires and the dependencies).
"""

from __future__ import annotations

import os
import re
import stat
import tempfile

import numba
from numba.core import caching
from numba.core.compiler import CompilerBase, DefaultPassBuilder

#: The Numba versions surfnorm is verified with: at least the first, below the second (major, minor).
NUMBA_SUPPORTED = ((0, 59), (0, 69))

#: ``numba.njit`` options of a function compiled without Numba's runtime (no reference counting).
NO_NRT = {"_nrt": False}


def _version_tuple(version: str) -> tuple[int, int]:
    """(major, minor) of a version string such as ``"0.68.1"`` or ``"0.70.0rc1"``."""
    match = re.match(r"(\d+)\.(\d+)", version)
    if match is None:
        raise ImportError(f"surfnorm: could not read the Numba version {version!r}")
    return int(match.group(1)), int(match.group(2))


def check_numba_version(version: str) -> None:
    """Raise ImportError unless ``version`` (a Numba version string) lies in :data:`NUMBA_SUPPORTED`."""
    low, high = NUMBA_SUPPORTED
    if not low <= _version_tuple(version) < high:
        raise ImportError(
            f"surfnorm supports numba>={low[0]}.{low[1]},<{high[0]}.{high[1]} (it relies on Numba internals: its "
            f"cache, a compiler pipeline, the _nrt option), found numba {version}: install a supported one, "
            f'e.g. pip install "numba>={low[0]}.{low[1]},<{high[0]}.{high[1]}"'
        )


check_numba_version(numba.__version__)


def _private_dir(path: str) -> bool:
    """Create ``path`` (mode 0700) if needed; True if it is a directory that only we own and may write."""
    try:
        os.makedirs(path, mode=0o700, exist_ok=True)
        st = os.lstat(path)
    except OSError:
        return False
    return (
        stat.S_ISDIR(st.st_mode)
        and st.st_uid == os.getuid()
        and not st.st_mode & (stat.S_IWGRP | stat.S_IWOTH)
        and os.access(path, os.W_OK)
    )


def _temp_cache_fallback() -> None:
    """Numba caches a kernel beside its source (``__pycache__``), else in ``NUMBA_CACHE_DIR`` or the user's cache
    directory (``~/.cache/numba``); where none of them is writable (a read-only image run with a read-only or
    missing home) it refuses to define the kernel at all ("cannot cache function ...: no locator available").
    This adds a last resort after Numba's own: a private directory (mode 0700, ours) in the temporary directory,
    ``surfnorm-numba-<uid>``. It serves any function that Numba could otherwise not cache, and none other."""
    impl = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)
    base = getattr(caching, "UserProvidedCacheLocator", None) or getattr(caching, "_UserProvidedCacheLocator", None)
    if impl is None or base is None or not hasattr(os, "getuid"):
        return
    if any(getattr(cls, "surfnorm_fallback", False) for cls in impl._locator_classes):
        return
    root = os.path.join(tempfile.gettempdir(), f"surfnorm-numba-{os.getuid()}")

    class TempDirCacheLocator(base):
        surfnorm_fallback = True

        def __init__(self, py_func, py_file):
            super().__init__(py_func, py_file)
            self._cache_path = os.path.join(root, self.get_suitable_cache_subpath(py_file))

        @classmethod
        def from_function(cls, py_func, py_file):
            if not _private_dir(root):
                return None
            return super(base, cls).from_function(py_func, py_file)  # (base's own checks NUMBA_CACHE_DIR)

    impl._locator_classes = [*impl._locator_classes, TempDirCacheLocator]


try:
    _temp_cache_fallback()
except Exception:  # another Numba's internals: its own behaviour stays
    pass


def _package_stamp() -> tuple[int, int, int]:
    """(how many, latest modification in ns, total size) of the package's ``.py`` files, read once per process."""
    global _STAMP
    if _STAMP is None:
        root = os.path.dirname(os.path.abspath(__file__))
        count = latest = total = 0
        for folder, dirs, files in os.walk(root):
            dirs[:] = [d for d in dirs if d != "__pycache__"]
            for name in files:
                if name.endswith(".py"):
                    st = os.stat(os.path.join(folder, name))
                    count, latest, total = count + 1, max(latest, st.st_mtime_ns), total + st.st_size
        _STAMP = (count, latest, total)
    return _STAMP


_STAMP: tuple[int, int, int] | None = None


class _SafeCache(caching.FunctionCache):
    """Numba's disk cache of one kernel, where a damaged or concurrently written cache never fails a call, and
    which is stale once any of the package's sources changed.

    Numba judges a cached kernel by its own file only (its modification time and size), but a kernel compiles
    in the functions it calls from other modules (a pixel function of :mod:`surfnorm.kernels.uncertainty` inside
    the adaptive fit's kernel): after an edit there, the cache would keep running the old code. So the stamp
    also holds :func:`_package_stamp`.

    Numba raises from its cache when an index file cannot be unpickled (truncated, overwritten by a crashed or
    concurrent writer, or left by another Numba), and when saving fails (a full disk, a read-only folder, or
    ``ReferenceError: underlying object has vanished``): the user's call then failed although the kernel had
    compiled. Here a cache that cannot be loaded is a miss (the kernel compiles), and a save that fails removes
    the index it could not read and tries once more, else leaves the cache as it is.
    """

    def __init__(self, py_func):
        super().__init__(py_func)
        cache_file = getattr(self, "_cache_file", None)
        if cache_file is not None and hasattr(cache_file, "_source_stamp"):  # (another Numba: its own stamp)
            cache_file._source_stamp = (cache_file._source_stamp, _package_stamp())

    def load_overload(self, sig, target_context):
        try:
            return super().load_overload(sig, target_context)
        except Exception:  # noqa: BLE001 - whatever a damaged cache raises: compile instead
            return None

    def save_overload(self, sig, data):
        try:
            super().save_overload(sig, data)
        except Exception:  # noqa: BLE001 - a damaged index: start a new one (once); else keep what is there
            try:
                os.unlink(self._cache_file._index_path)
                super().save_overload(sig, data)
            except Exception:  # noqa: BLE001
                pass


def _safe_cache(dispatcher):
    """``dispatcher`` with :class:`_SafeCache` in place of Numba's own disk cache (where it has one)."""
    if type(getattr(dispatcher, "_cache", None)) is caching.FunctionCache:
        dispatcher._cache = _SafeCache(dispatcher.py_func)
    return dispatcher


def _numba_njit(*args, **options):
    """``numba.njit`` whose dispatchers use :class:`_SafeCache` (a decorator, or the dispatcher of ``args[0]``)."""
    if args and callable(args[0]):
        return _safe_cache(numba.njit(**options)(args[0]))
    decorate = numba.njit(*args, **options)
    return lambda func: _safe_cache(decorate(func))


class _NoAliasCompiler(CompilerBase):
    """Numba's nopython pipeline with the ``noalias`` flag set: LLVM may assume that the arrays
    passed in do not overlap (one written through one argument is never read through another)."""

    def define_pipelines(self):
        self.state.flags.noalias = True
        pm = DefaultPassBuilder.define_nopython_pipeline(self.state)
        pm.finalize()
        return [pm]
