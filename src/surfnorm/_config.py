"""Numba settings shared by every kernel, in one place.

``cache=True`` writes compiled machine code next to the sources, so a fresh
process only loads it; ``nogil=True`` lets threads run kernels side by side
(used for batches). ``fastmath`` stays off: the kernels must give the same
numbers as the naive references and the authors' code, and NaN/inf checks
must not be optimised away.
"""

from __future__ import annotations

import numba
import numba.extending

# Everything here that reaches into Numba's internals (its cache, its compiler pipeline, its runtime switch)
# lives in surfnorm._numba_internals, which refuses a Numba outside the versions it was verified with.
from ._numba_internals import NO_NRT, _NoAliasCompiler, _numba_njit

NJIT = dict(cache=True, nogil=True, fastmath=False, error_model="numpy")


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
    options = {**NJIT, **NO_NRT, **kwargs}
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
