"""New result arrays (normals, sigma) in the memory of earlier results that nothing uses any more.

A result allocated new is memory that the system maps in and zeroes page by page when the kernels first write it.
Where the process has just freed large blocks (another library's work between two frames: decoding an image,
OpenCV's normals), the allocator hands out fresh pages again: a 450x375 frame's normals (2 MB) then cost about 580
page faults, and the default's call on two cores about 1.2 ms more (4.6 instead of 3.4 ms, measured on a 2-core VM,
where a fresh page costs about 2.4 us). So the memory of a result is kept once no array refers to it, and the next
result of the same size takes it.

The results are ordinary NumPy arrays whose memory belongs to a small holder (their ``base``, or their base's): a
view or anything else made from a result keeps the holder alive, exactly as it would keep a NumPy-owned array's
memory, and only when the last of them is freed does the memory go back, for the next call to take. In a stream
(``n = estimate(depth, K)`` once per frame) the call makes its result while the last frame's is still held, so two
blocks take turns. At most :data:`KEEP` blocks of a size are kept, :data:`BUDGET` bytes in all; results under
:data:`SMALLEST` bytes are plain ``np.empty`` (the allocator keeps small blocks itself); :func:`release` lets the
kept ones go.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

__all__ = ["new_result", "release", "kept_bytes"]

#: Results of fewer bytes are plain ``np.empty``.
SMALLEST = 1 << 18
#: Blocks kept per size: two take turns in a stream of frames.
KEEP = 2
#: Bytes kept in all.
BUDGET = 64 << 20

_kept: dict[int, deque] = {}


class _Holder:
    """Owns one block (a uint8 array) and lends it, typed and shaped, through ``__array_interface__``; gives the block
    back to :data:`_kept` when freed (no array refers to it then)."""

    __slots__ = ("block", "__array_interface__", "__weakref__")

    def __init__(self, block: np.ndarray, shape: tuple, typestr: str):
        self.block = block
        self.__array_interface__ = {
            "shape": shape,
            "typestr": typestr,
            "data": (block.ctypes.data, False),
            "version": 3,
        }

    def __del__(self):
        try:
            _give(self.block)
        except Exception:  # noqa: BLE001 - at interpreter exit the module may be gone: nothing to keep then
            pass


def _give(block: np.ndarray) -> None:
    # No lock: __del__ runs wherever a result is freed (in a garbage collection, in any thread, inside new_result
    # itself); appending to and popping from a deque are atomic.
    kept = _kept.setdefault(block.size, deque())
    if len(kept) < KEEP and kept_bytes() + block.size <= BUDGET:
        kept.append(block)


def kept_bytes() -> int:
    """Bytes held for later results."""
    return sum(size * len(blocks) for size, blocks in list(_kept.items()))


def new_result(shape: tuple, dtype=np.float32) -> np.ndarray:
    """An uninitialised C-contiguous array of ``shape`` and ``dtype``, in a kept block where one of its size is free
    (see the module docstring)."""
    dtype = np.dtype(dtype)
    nbytes = math.prod(shape) * dtype.itemsize
    if nbytes < SMALLEST:
        return np.empty(shape, dtype)
    try:
        block = _kept[nbytes].pop()
    except (KeyError, IndexError):
        block = np.empty(nbytes, np.uint8)
    return np.asarray(_Holder(block, tuple(shape), dtype.str))


def release() -> None:
    """Let go of the kept blocks."""
    _kept.clear()
