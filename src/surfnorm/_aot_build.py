"""Build the ahead-of-time kernels (see :mod:`surfnorm._aot`): ``python -m surfnorm._aot_build [PACKAGE_DIR]``.

Run by ``setup.py`` when a wheel is built (not for an editable install), in a
new process whose ``surfnorm`` is the copy being packaged; writes one
extension module per CPU level of this architecture and ``_aot_index.json``
into the package directory (default: this package's). Needs a C compiler
(Numba's ``pycc`` links its own small runtime) and takes a few minutes.

Steps: the default method is run by the JIT on small frames (clean depth, noisy
depth and depth between the two, with a mask, on two threads, scale-invariant) so that every kernel
decorated with :func:`surfnorm._aot.ahead_of_time` is compiled for exactly the
argument types that ``surfnorm.estimate`` passes it; each such signature is
exported through a one-line function that calls the kernel, so that Numba
compiles the kernel and its callees with their own options, and the linked
code is generated once per CPU level. The JIT's on-disk cache is a new empty
directory here (code loaded from a cache cannot be linked into a module).
"""

from __future__ import annotations

import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path


def _warm_up():
    """Run the default method (JIT only) the ways that ``estimate`` can call its kernels."""
    import numpy as np

    from . import estimate
    from ._aot import jit_only

    h, w = 80, 96
    v, u = np.mgrid[0:h, 0:w]
    clean = (2.0 + 0.004 * u + 0.002 * v).astype(np.float32)
    noisy = clean + np.random.default_rng(0).normal(0.0, 0.01, clean.shape).astype(np.float32)
    # a noise floor between auto's two: both estimators and their blend
    between = clean + np.random.default_rng(0).normal(0.0, 0.004, clean.shape).astype(np.float32)
    K = [[90.0, 0, 47.5], [0, 90.0, 39.5], [0, 0, 1]]
    with jit_only():
        for z in (clean, between, noisy):
            z[5, 7] = 0.0
            for kwargs in (
                {},
                {"mask": z > 0},
                {"threads": 2},
                {"scale_invariant": True},
                {"method": "d2nt_v3"},
                {"method": "adaptive_fit"},
            ):
                estimate(z, K, **kwargs)
            estimate(z.astype(np.float64), K)
            estimate(np.stack([z, z]), K, threads=2)


def _trampoline(dispatcher, n_args: int):
    """A Python function ``entry(a0, ..., an) -> dispatcher(a0, ..., an)`` for pycc to export."""
    names = ", ".join(f"a{i}" for i in range(n_args))
    namespace = {"kernel": dispatcher}
    exec(f"def entry({names}):\n    return kernel({names})\n", namespace)  # noqa: S102 (generated, no input)
    return namespace["entry"]


def build(package_dir: Path, verbose: bool = True, names=None, warm_up=None) -> dict:
    """Compile the AOT modules into ``package_dir``; returns the index written.

    ``names``: only these registered kernels ("module.qualname"; default: all); ``warm_up``: the function that
    runs them by the JIT first (default: the default method on small frames).
    """
    import numba
    from numba.pycc import CC
    from numba.pycc import compiler as pycc_compiler

    from . import _aot

    class Flags(pycc_compiler.Flags):
        """pycc's flags for the exported wrappers: release the GIL (as the kernels' ``nogil=True``) and Numpy's
        error model (as the kernels'); the kernels themselves keep their own options."""

        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.release_gil = True
            self.error_model = "numpy"

    pycc_compiler.Flags = Flags  # type: ignore[misc]
    t0 = time.perf_counter()
    (warm_up or _warm_up)()
    if verbose:
        print(f"surfnorm AOT: JIT warm-up {time.perf_counter() - t0:.1f} s", flush=True)
    exports: list = []
    kernels: dict = {}
    for name, kernel in sorted(_aot.REGISTRY.items()):
        if names is not None and name not in names:
            continue
        for i, cres in enumerate(kernel.jit.overloads.values()):
            symbol = f"k_{name.replace('.', '_')}_{i}"
            exports.append((symbol, cres.signature, _trampoline(kernel.jit, len(cres.signature.args))))
            kernels.setdefault(name, []).append([symbol, str(tuple(cres.signature.args))])
    arch = platform.machine().lower()
    levels = _aot.LEVELS.get(arch, [(f"_aot_{arch}", "", ())])
    built = []
    for module, cpu, _ in levels:
        t1 = time.perf_counter()
        cc = CC(module, source_module=sys.modules[__name__])
        cc.output_dir = str(package_dir)
        cc.target_cpu = cpu
        for symbol, sig, func in exports:
            cc.export(symbol, sig)(func)
        cc.compile()
        built.append(module)
        if verbose:
            print(f"surfnorm AOT: {module} ({cpu or 'baseline'}) {time.perf_counter() - t1:.1f} s", flush=True)
    index = {
        "arch": arch,
        "modules": built,
        "source": _aot.source_hash(package_dir),
        "numba": numba.__version__,
        "kernels": kernels,
    }
    (package_dir / _aot.INDEX).write_text(json.dumps(index, indent=1) + "\n")
    return index


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if "numba" in sys.modules:
        print("surfnorm._aot_build: run it in a new process (python -m surfnorm._aot_build)", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="surfnorm-aot-cache-") as cache:
        os.environ["NUMBA_CACHE_DIR"] = cache  # read when Numba is imported, below
        package_dir = Path(argv[0]).resolve() if argv else Path(__file__).resolve().parent
        import surfnorm

        if Path(surfnorm.__file__).resolve().parent != package_dir:
            print(
                f"surfnorm._aot_build: the surfnorm imported ({surfnorm.__file__}) is not the one in {package_dir}",
                file=sys.stderr,
            )
            return 2
        build(package_dir)
    return 0


if __name__ == "__main__":
    sys.exit(main())
