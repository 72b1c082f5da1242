"""Check the kernels' exp on every float32 in [-104.5, 0] (about 1.1e9 values).

    python benchmarks/exp32_exhaustive.py      # about 2 minutes on one core

The softmin (eq. 13) needs exp(-s / tau) with s >= 0, tau > 0; the kernels
get it from ``softmin_row`` (exp32 compiled with FMA contraction), which is
what is checked here, with tau = 1 and s = -x: bit for bit against exp in
float64 rounded to float32 (correctly rounded but for double-rounding
cases), and against the C library's expf (what ``math.exp`` of a float32
compiles to in Numba, and what the kernels called before they were
vectorised). exp32 as compiled without contraction is checked too.
"""

from __future__ import annotations

import math
import time

import numba
import numpy as np

from surfnorm.kernels.gradients import exp32, softmin_row


@numba.njit(nogil=True)
def _ours(x, out):
    for i in range(x.size):
        out[i] = exp32(x[i])


@numba.njit(nogil=True)
def _libm(x, out):
    for i in range(x.size):
        out[i] = math.exp(x[i])


@numba.njit(nogil=True)
def _via_float64(x, out):
    for i in range(x.size):
        out[i] = np.float32(math.exp(np.float64(x[i])))


def main():
    top = int(np.array([104.5], np.float32).view(np.uint32)[0])
    step = 1 << 24
    n = vs_float64 = vs_libm = libm_vs_float64 = plain_vs_float64 = 0
    t0 = time.perf_counter()
    for lo in range(0, top + 1, step):
        bits = np.arange(lo, min(lo + step, top + 1), dtype=np.uint32) | np.uint32(0x80000000)  # negative floats
        x = bits.view(np.float32)
        ours, plain, libm, ref = np.empty_like(x), np.empty_like(x), np.empty_like(x), np.empty_like(x)
        softmin_row(-x, np.float32(1.0), ours)
        _ours(x, plain)
        _libm(x, libm)
        _via_float64(x, ref)
        ob, lb, rb = ours.view(np.uint32), libm.view(np.uint32), ref.view(np.uint32)
        vs_float64 += int(np.count_nonzero(ob != rb))
        vs_libm += int(np.count_nonzero(ob != lb))
        plain_vs_float64 += int(np.count_nonzero(plain.view(np.uint32) != rb))
        libm_vs_float64 += int(np.count_nonzero(lb != rb))
        n += x.size
    print(f"{n} float32 values in [-104.5, 0] ({time.perf_counter() - t0:.0f} s):")
    print(f"  softmin_row != float32(exp(float64 x)): {vs_float64}")
    print(f"  softmin_row != C library expf:          {vs_libm}")
    print(f"  exp32 without FMA != float32(exp(float64 x)): {plain_vs_float64}")
    print(f"  expf  != float32(exp(float64 x)): {libm_vs_float64}")


if __name__ == "__main__":
    main()
