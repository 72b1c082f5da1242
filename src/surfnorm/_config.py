"""Numba settings shared by every kernel, in one place.

``cache=True`` writes compiled machine code next to the sources, so a fresh
process only loads it; ``nogil=True`` lets threads run kernels side by side
(used for batches). ``fastmath`` stays off: the kernels must give the same
numbers as the naive references and the authors' code, and NaN/inf checks
must not be optimised away.
"""

from __future__ import annotations

import os
import stat
import tempfile

import numba
import numba.extending
from numba.core import caching
from numba.core.compiler import CompilerBase, DefaultPassBuilder

NJIT = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")


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
    from numba.core import caching

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


def njit(*args, noalias=False, **kwargs):
    """``numba.njit`` with the project's settings (compiled lazily, on first call).

    ``noalias=True``: the caller promises that no array argument overlaps another
    one that the kernel writes. Without it LLVM must check at run time that every
    written array is apart from every read one, and gives up vectorising a loop
    that reads many arrays ("too many memory checks").
    """
    options = {**NJIT, **kwargs}
    if noalias:
        options["pipeline_class"] = _NoAliasCompiler
    return _numba_njit(*args, **options)


def row(*args, **kwargs):
    """``njit`` for a row function: called by a kernel once per image row, it allocates nothing.

    Compiled without Numba's runtime (``_nrt=False``), so without reference
    counting: every view of a row that such a function takes (and the kernels
    take a dozen per row and stage) otherwise costs two atomic count updates,
    measured at about 0.1 ms per 480x640 frame and stage. Allocating inside
    one is a compile error, which keeps the rule honest.

    Call one with ``np.int64(0)``, not ``0``, where an argument is a constant:
    Numba compiles a separate specialisation of a jitted callee for every
    literal integer it is passed (``laplacian_row`` was compiled twice for
    d2nt_v3 alone), which costs seconds on a fresh install's first call.
    """
    options = {**NJIT, "_nrt": False, **kwargs}
    return _numba_njit(*args, **options)


def pixel(func):
    """A per-pixel helper, inlined into the kernels that call it.

    Numba does not reliably inline small functions that take arrays; a call
    then costs array reference counting per pixel (measured: 10x slower
    kernels). ``inline="always"`` splices the helper into its caller at the
    Numba IR level, so kernels stay written as calls to readable helpers.
    """
    return _numba_njit(func, inline="always", **NJIT)


@numba.extending.intrinsic
def select(typingctx, cond, a, b):
    """``a if cond else b`` as one LLVM select (no branch, so a loop using it stays vectorisable).

    Numba lowers a conditional expression to branches; LLVM turns those back into
    selects only while few values depend on them (measured: a chain of them
    became a ``switch`` and the loop stayed scalar). Both values are computed.
    """
    if not isinstance(cond, numba.types.Boolean):
        return None
    common = typingctx.unify_types(a, b)
    if common is None:
        return None

    def codegen(context, builder, signature, args):
        _, ta, tb = signature.args
        va = context.cast(builder, args[1], ta, common)
        vb = context.cast(builder, args[2], tb, common)
        return builder.select(args[0], va, vb)

    return numba.core.typing.signature(common, cond, a, b), codegen


@numba.extending.intrinsic
def as_float64(typingctx, bits):
    """The float64 whose IEEE-754 bit pattern is the int64 ``bits`` (a register move; vectorises)."""
    from llvmlite import ir

    sig = numba.types.float64(numba.types.int64)

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.DoubleType())

    return sig, codegen
