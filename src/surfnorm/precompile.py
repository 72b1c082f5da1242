"""Compile every kernel into Numba's cache ahead of the first call: ``python -m surfnorm.precompile``.

The kernels are compiled on their first call and cached on disk (``cache=True``),
so only the first process pays for it: tens of seconds of CPU for ``d2nt_v3`` in a
new environment, where a process that finds the cache starts in about a second. (A
wheel holds the default method's kernels compiled ahead of time, see
:mod:`surfnorm._aot`: its first call compiles nothing, precompiled or not.) Run
this once where the package is installed, e.g. in a container image build::

    RUN pip install surfnorm && python -m surfnorm.precompile

or at the end of a CI job's setup. Every later process on that machine (same
CPU, same Python and Numba) loads the compiled code. It calls
:func:`surfnorm.estimate` by the JIT (never the AOT code) on a small clean frame
and a small noisy one (``auto`` runs d2nt_v3 on the first, adaptive_fit on the
second) for each method (optionally only those named) in every variant that
compiles different code: the default options, with a mask, in the
scale-invariant mode, followed by ``+mnr``, with ``uncertainty=True`` (the methods
that give a sigma), and the options whose values select other kernels (a larger
plane-fit window, SDA-SNE's 3F2N base). New registered
methods are covered without change.

Where the cache goes: Numba writes it into ``__pycache__`` beside the sources
when that directory is writable; when it is not (a read-only image, a system
package), into its user-wide cache (``$XDG_CACHE_HOME/numba`` or
``~/.cache/numba``), which belongs to the user who ran it; where neither is
writable, into ``$TMPDIR/surfnorm-numba-<uid>`` (see :mod:`surfnorm._config`). Set
``NUMBA_CACHE_DIR`` to one directory for precompiling and running alike when
they are different users. The cache is keyed on the CPU: an image built on one
CPU model and run on another compiles again (correctly) on first use.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

__all__ = ["precompile", "variants"]

#: Option values that select other kernels than the defaults (applied where a method has the option).
KERNEL_CHOICES: dict[str, list] = {"window": [5], "base": ["3f2n"]}


def variants(name: str) -> list[dict]:
    """The keyword arguments of ``estimate`` that together compile every kernel of method ``name``."""
    from ._api import UNCERTAIN
    from .methods import _REGISTRY

    method = _REGISTRY[name]
    out: list[dict] = [{"method": name}, {"method": name, "mask": True}, {"method": name + "+mnr"}]
    if name in UNCERTAIN:
        out.append({"method": name, "uncertainty": True})
    if method.ties:
        out.append({"method": name, "scale_invariant": True})
    for option, values in KERNEL_CHOICES.items():
        if option in method.options:
            out += [{"method": name, option: value} for value in values]
            if method.ties:
                out += [{"method": name, option: value, "scale_invariant": True} for value in values]
    return out


def _frames():
    """A clean frame and a noisy one: ``auto`` runs d2nt_v3 on the first, adaptive_fit on the second."""
    v, u = np.mgrid[0:24, 0:32]
    z = (2.0 + 0.01 * u + 0.005 * v).astype(np.float32)
    noisy = z + np.random.default_rng(0).normal(0.0, 0.01, z.shape).astype(np.float32)
    z[5, 7] = noisy[5, 7] = 0.0
    return z, noisy


def precompile(names=None, *, verbose: bool = False) -> dict[str, float]:
    """Compile (or load) every kernel of the named methods (default: all); returns seconds per method."""
    from . import estimate, methods

    names = list(methods()) if not names else list(names)
    unknown = [n for n in names if n not in methods()]
    if unknown:
        from .errors import InputError

        raise InputError(f"methods: expected some of {', '.join(methods())}, got {', '.join(unknown)}")
    from ._aot import jit_only

    frames = _frames()
    mask = np.ones(frames[0].shape, bool)
    K = [[30.0, 0, 15.5], [0, 30.0, 11.5], [0, 0, 1]]
    times = {}
    for name in names:
        t0 = time.perf_counter()
        with jit_only():  # the host's own code into the cache, not the code compiled ahead of time
            for kwargs in variants(name):
                if kwargs.pop("mask", False):
                    kwargs["mask"] = mask
                for z in frames:
                    estimate(z, K, threads=1, **kwargs)
        times[name] = time.perf_counter() - t0
        if verbose:
            print(f"{name}: {times[name]:.1f} s", flush=True)
    return times


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m surfnorm.precompile", description="Compile every kernel of surfnorm into Numba's on-disk cache."
    )
    parser.add_argument("methods", nargs="*", help="only these methods (default: every registered one)")
    parser.add_argument("--quiet", action="store_true", help="print nothing")
    args = parser.parse_args(argv)
    from .errors import InputError

    try:
        times = precompile(args.methods, verbose=not args.quiet)
    except InputError as exc:
        print(f"surfnorm.precompile: {exc}", file=sys.stderr)
        return 2
    if not args.quiet:
        print(f"compiled {len(times)} method(s) in {sum(times.values()):.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
