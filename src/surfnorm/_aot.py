"""Kernels compiled ahead of time: the default method's first call in a fresh environment without compiling.

A Numba kernel is compiled on its first call (seconds to tens of seconds: about
40 s of CPU for ``d2nt_v3``) and then cached on disk. A wheel built with
``python -m build`` (or ``pip wheel``/``pip install`` of the source) also holds
the kernels of the default method (``auto``: the validity map, the noise
profile, ``d2nt_v3`` and ``adaptive_fit``) compiled ahead of time by Numba's
AOT compiler (:mod:`surfnorm._aot_build`, run by ``setup.py``): an extension
module per CPU level (x86-64 with AVX-512, with AVX2 and FMA, and the baseline
of the architecture) and an index of the exported signatures. At run time a kernel
decorated with :func:`ahead_of_time` runs the AOT code where the AOT module
exports exactly the argument types of the call and was built from the same
sources (a hash of the package's ``.py`` files in the index): no compilation
at all, and no Numba cache to load either (loading a cached kernel costs more:
Numba's code generator must be set up first). Otherwise (other types, another
CPU architecture, an editable install, sources edited since) the JIT runs,
compiling and caching as before.

The AOT code is the same Numba IR as the JIT's (each export is a one-line
function calling the kernel's dispatcher, so the kernel and its callees are
compiled with their own options: ``nogil``, ``error_model``, ``noalias``,
``fastmath`` contraction where set), code-generated for a fixed CPU level
instead of the host's. Without fast-math reassociation a vector width does not
change results, and the AVX-512 and AVX2+FMA levels are taken only where the
host has FMA (as the JIT's host code then does), so both give the same bits
(checked by ``tests/test_aot.py`` and ``benchmarks/cold_start.py``). The level
matters for speed: on an AMD Zen 5 host the AVX2 level's default method took
1.3x the AVX-512 level's time (which is the JIT's), so AVX-512 hosts get their
own level.

``SURFNORM_AOT=0`` in the environment switches the AOT code off (always the JIT); ``SURFNORM_AOT=<module>``
(e.g. ``_aot_x86_64``, the baseline) takes that level whatever the host has (for tests).
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import json
import os
import threading
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["ahead_of_time", "Kernel", "jit_only", "available", "source_hash", "REGISTRY", "INDEX", "LEVELS"]

PACKAGE = Path(__file__).resolve().parent
#: The index the build writes beside the extension modules.
INDEX = "_aot_index.json"
_V3 = ("avx", "avx2", "bmi", "bmi2", "f16c", "fma", "lzcnt", "movbe")
#: CPU levels, best first: (module name, LLVM CPU name, host features it needs). The last one needs nothing.
LEVELS = {
    "x86_64": [
        ("_aot_x86_64_v4", "x86-64-v4", _V3 + ("avx512f", "avx512bw", "avx512cd", "avx512dq", "avx512vl")),
        ("_aot_x86_64_v3", "x86-64-v3", _V3),
        ("_aot_x86_64", "", ()),
    ],
}
#: Every kernel decorated with :func:`ahead_of_time`: "module.qualname" -> Kernel.
REGISTRY: dict[str, "Kernel"] = {}

_lock = threading.Lock()
_state: dict[str, Any] = {"jit_only": 0, "module": None, "loaded": False, "epoch": 0}


def source_hash(root: Path = PACKAGE) -> str:
    """SHA-256 over the package's ``.py`` files (relative path and contents, in path order)."""
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        if "__pycache__" in rel:
            continue
        h.update(rel.encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()


def _host_level(levels) -> str | None:
    """The first level whose features the host CPU has."""
    from llvmlite import binding as llvm

    features = llvm.get_host_cpu_features()
    for module, _, needs in levels:
        if all(features.get(f, False) for f in needs):
            return module
    return None


def _load() -> tuple[object, dict] | None:
    """(the AOT module for this CPU, index entries by kernel name), or None where there is none that fits."""
    if _state["loaded"]:
        return _state["module"]
    with _lock:
        if _state["loaded"]:
            return _state["module"]
        found = None
        try:
            index_path = PACKAGE / INDEX
            wanted = os.environ.get("SURFNORM_AOT", "1")
            if wanted != "0" and index_path.is_file():
                index = json.loads(index_path.read_text())
                built = index.get("modules", [])
                levels = [lv for lv in LEVELS.get(index.get("arch"), [(m, "", ()) for m in built]) if lv[0] in built]
                if wanted not in ("", "1"):  # one level by name (tests: the baseline on a host that has more)
                    levels = [(m, cpu, ()) for m, cpu, _ in levels if m == wanted]
                name = _host_level(levels) if levels else None
                if name is not None and index.get("source") == source_hash():
                    found = (importlib.import_module(f"{__package__}.{name}"), index["kernels"])
        except Exception:  # a broken or foreign build: the JIT works without it
            found = None
        _state["module"] = found
        _state["loaded"] = True
    return found


def available() -> bool:
    """Whether AOT code that fits this CPU and these sources is installed (and not switched off)."""
    return _load() is not None


@contextlib.contextmanager
def jit_only():
    """Within: kernels run (and compile) the JIT's code, never the AOT code (``python -m surfnorm.precompile``
    fills Numba's cache for every kernel; the AOT build compiles by the JIT first)."""
    with _lock:
        _state["jit_only"] += 1
    try:
        yield
    finally:
        with _lock:
            _state["jit_only"] -= 1
            _state["epoch"] += 1  # choose again: the JIT may have code now


def _key(value):
    """What numba.typeof of an argument depends on, cheaply (a key for the choice cache)."""
    if type(value) is np.ndarray:
        f = value.flags
        return (value.dtype, value.ndim, f.c_contiguous, f.f_contiguous, f.writeable, f.aligned)
    if type(value) is int:
        return (int, -(1 << 63) <= value < (1 << 63))
    return type(value)


class Kernel:
    """A Numba dispatcher that runs AOT code where it can (see the module docstring); other attributes are the
    dispatcher's (``py_func``, ``signatures``, ...), and ``jit`` is the dispatcher itself."""

    def __init__(self, dispatcher):
        self.jit = dispatcher
        self.name = f"{dispatcher.py_func.__module__}.{dispatcher.py_func.__qualname__}"
        self.__doc__ = dispatcher.py_func.__doc__
        self.__name__ = dispatcher.py_func.__name__
        self.__wrapped__ = dispatcher.py_func
        self._chosen: dict = {}
        self._epoch = 0

    def __getattr__(self, name):
        return getattr(self.jit, name)

    def __repr__(self):
        return f"<surfnorm AOT kernel {self.name}>"

    def __call__(self, *args):
        # Without AOT code (none built, another CPU, sources edited) the JIT at once: no key to compute (tens of
        # microseconds a frame for the default method's kernels, whose arguments are many).
        if _state["jit_only"] or (_state["loaded"] and _state["module"] is None):
            return self.jit(*args)
        if self._epoch != _state["epoch"]:
            self._chosen = {}
            self._epoch = _state["epoch"]
        key = tuple(_key(a) for a in args)
        func = self._chosen.get(key)
        if func is None:
            func = self._choose(args)
            if len(self._chosen) < 64:
                self._chosen[key] = func
        return func(*args)

    def _choose(self, args):
        found = _load()
        if found is None:
            return self.jit
        module, kernels = found
        import numba

        try:
            types = tuple(numba.typeof(a, numba.core.typing.typeof.Purpose.argument) for a in args)
        except Exception:
            return self.jit
        for symbol, argtypes in kernels.get(self.name, []):
            if argtypes == str(types):
                return getattr(module, symbol)
        return self.jit


def ahead_of_time(dispatcher):
    """Register a top-level kernel (called from Python only) for the AOT build; returns its :class:`Kernel`."""
    kernel = Kernel(dispatcher)
    REGISTRY[kernel.name] = kernel
    return kernel
