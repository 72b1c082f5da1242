"""The frame's noise, measured from its own depth: :func:`noise_profile` and :class:`NoiseProfile`.

The second differences of inverse depth w = 1/z vanish on planes (w is affine there), so their robust RMS in bins
of depth, at strides 1, 2 and 4, separates a sensor's noise from the scene's shape. In units of the distance
between neighbouring pixels' points (z / f) the noise is rho(z) = sigma_z f / z. :mod:`surfnorm.kernels.adaptive_fit`
sizes its windows from it (:func:`surfnorm.kernels._windows.radius_table`), :mod:`surfnorm.kernels.auto` decides
from it what the frame is (clean, sensor or between: its floor, terraces and smooth noise), and
:mod:`surfnorm.kernels.uncertainty` predicts each normal's error from it. ``surfnorm.torch`` measures the same
statistics on tensors (:mod:`surfnorm.torch._adaptive`).

A statistic of the whole frame, sampled on every step-th row and column (:func:`surfnorm._constants.noise_step`: every
5th on frames up to 640x480, about 12,000 pixels on larger ones).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .._aot import ahead_of_time
from .._bands import Part
from .._config import njit, pixel, select
from .._constants import (
    _CLIP_ROUNDS,
    _CLIP_SIGMAS,
    _FOURTH_RMS,
    _MAX_GAP,
    _MAX_SPREAD,
    _SMOOTH_GAUSS,
    _SMOOTH_SAMPLES,
    _STRIDES_SOLVE,
    CLEAN_FLOOR,
    CONSISTENT_MAX,
    CORRELATED_HIGH,
    CORRELATED_KAPPA_GAIN,
    CORRELATED_LOW,
    GEOMETRY_RHO_HIGH,
    GEOMETRY_RHO_LOW,
    GRID_HIGH,
    GRID_LOW,
    GRID_SHARE,
    GRID_STEPS,
    GRID_TOLERANCE,
    MIN_SAMPLES,
    N_BINS,
    NOISY_FLOOR,
    SMOOTH_ERROR_FLOOR_HIGH,
    SMOOTH_ERROR_FLOOR_LOW,
    SMOOTH_ERROR_HIGH,
    SMOOTH_ERROR_LOW,
    SMOOTH_ERROR_PIXEL_HIGH,
    SMOOTH_ERROR_PIXEL_LOW,
    SMOOTH_ERROR_SHAPE_HIGH,
    SMOOTH_ERROR_SHAPE_LOW,
    SMOOTH_SHARE,
    STEP_CONSISTENT,
    TERRACED_CHECK,
    TERRACED_HIGH,
    TERRACED_LOW,
    UPSAMPLED_CONTRAST,
    UPSAMPLED_DRIFT_SPAN,
    UPSAMPLED_MAX,
    UPSAMPLED_MIN,
    UPSAMPLED_SHARE,
    UPSAMPLED_SMALL,
    UPSAMPLED_SMALL_SHARE,
    UPSAMPLED_STEP,
    WHITE_FLOOR_HIGH,
    WHITE_FLOOR_LOW,
    WHITE_PIXEL_HIGH,
    WHITE_PIXEL_LOW,
    fourth_passes,
    noise_step,
    stride_gain,
)
from ._schedule import choose_stride
from ._spare import Spares

__all__ = [
    "NoiseProfile",
    "noise_profile",
    "depth_range",
    "terrace_statistics",
    "stride_gain",
    "adaptive_weight",
    "kappa_gain",
    "geometry_share",
    "reading",
    "quantisation",
    "quantisation_step",
    "grid_share",
    "depth_grid",
    "terraced_share",
    "smooth_error_share",
    "white_noise_share",
    "step_limit",
    "upsampling_factor",
]


@ahead_of_time
@njit
def _depth_range(z, valid):
    zmin = np.inf
    zmax = 0.0
    for v in range(z.shape[0]):
        for u in range(z.shape[1]):
            if valid[v, u]:
                zmin = min(zmin, z[v, u])
                zmax = max(zmax, z[v, u])
    return zmin, zmax


@ahead_of_time
@njit(noalias=True, _nrt=False)
def _depth_range_bits(bits, valid):
    """:func:`_depth_range` of float32 depth from its bits (``z.view(np.int32)``): positive floats order as their
    bits do, and integer minima and maxima vectorise. Returns the bits of the nearest and farthest valid depth
    (2**31 - 1 and 0 without any)."""
    lo = np.int32(2147483647)
    hi = np.int32(0)
    for v in range(bits.shape[0]):
        b = bits[v]
        m = valid[v]
        for u in range(b.shape[0]):
            lo = min(lo, select(m[u], b[u], np.int32(2147483647)))
            hi = max(hi, select(m[u], b[u], np.int32(0)))
    return lo, hi


def depth_range(z: np.ndarray, valid: np.ndarray) -> tuple[float, float]:
    """The nearest and farthest valid depth (inf and 0 without any)."""
    if z.dtype != np.float32 or not z.flags.c_contiguous:
        return _depth_range(z, valid)
    lo, hi = _depth_range_bits(z.view(np.int32), valid)
    if lo == 2147483647:
        return np.inf, 0.0
    return float(np.int32(lo).view(np.float32)), float(np.int32(hi).view(np.float32))


@pixel
def _spread(z0, z1, z2, z3, z4, z5, z6):
    """True when the depths of a stencil differ by more than ``_MAX_SPREAD`` (a discontinuity)."""
    lo = min(z0, z1, z2, z3, z4, z5, z6)
    hi = max(z0, z1, z2, z3, z4, z5, z6)
    return hi > _MAX_SPREAD * lo


@pixel
def _terrace(z_m, z_0, z_p, f, jumps, n_jumps):
    """(1 when the depth changes along z_m, z_0, z_p at all, else 0; ``n_jumps``, plus 1 after writing a jump's
    height into ``jumps``) for a flat step beside a jump: one neighbour at exactly z_0's depth, the other not.
    The height |1/z_0 - 1/z_other| z_0 f is in point spacings (z_0 / f)."""
    flat_m = z_m == z_0
    flat_p = z_p == z_0
    if flat_m and flat_p:
        return 0, n_jumps
    if flat_m != flat_p:
        other = z_p if flat_m else z_m
        jumps[n_jumps] = abs(1.0 / z_0 - 1.0 / other) * z_0 * f
        n_jumps += 1
    return 1, n_jumps


@ahead_of_time
@njit(noalias=True, _nrt=False)
def _grid(z, valid, step, tolerance):
    """(q, n, on, steps, moved, inverse) over the pixels on every ``step``-th row and column and their right-hand
    neighbours where both are valid (n pairs): q the smallest positive difference between the two depths (0 without
    any), ``on`` how many pairs differ by a whole multiple k of q within ``tolerance`` of it (k = 0 included),
    ``steps`` how many of those by k 0 or 2 and more (a grid's steps, not a plane's even slope, along which
    neighbours all differ by about as much), ``moved`` how many by k 1 and more, and ``inverse`` the sum of 1/z over
    those (the left one's). Two sweeps over the pairs, the first for q: no scratch."""
    H, W = z.shape
    q = np.inf
    n = 0
    for v in range(0, H, step):
        zv, ok = z[v], valid[v]
        for u in range(0, W - 1, step):
            if ok[u] and ok[u + 1]:
                d = abs(float(zv[u + 1]) - float(zv[u]))
                if d > 0.0:
                    q = min(q, d)
                n += 1
    if q == np.inf:
        return 0.0, n, 0, 0, 0, 0.0
    per_q = 1.0 / q
    on = steps = moved = 0
    inverse = 0.0
    for v in range(0, H, step):
        zv, ok = z[v], valid[v]
        for u in range(0, W - 1, step):
            if ok[u] and ok[u + 1]:
                r = abs(float(zv[u + 1]) - float(zv[u])) * per_q
                k = math.floor(r + 0.5)
                hit = abs(r - k) <= tolerance
                on += hit
                steps += hit and k != 1.0
                moves = hit and k > 0.0
                moved += moves
                inverse += select(moves, 1.0 / zv[u], 0.0)
    return q, n, on, steps, moved, inverse


def depth_grid(z: np.ndarray, valid: np.ndarray, f: float) -> float:
    """:attr:`NoiseProfile.grid`: the step of the grid the depth is stored on, in point spacings (z / f), 0 where it
    is not on one (see ``GRID_SHARE`` in :mod:`surfnorm._constants`)."""
    H, W = z.shape
    q, n, on, steps, moved, inverse = _grid(z, valid, noise_step(H, W), GRID_TOLERANCE)
    if n < MIN_SAMPLES or moved == 0 or on < GRID_SHARE * n or steps < GRID_STEPS * n:
        return 0.0
    return q * f * inverse / moved


@ahead_of_time
@njit
def _second_differences(z, valid, f, zmin, zmax, nbins, step, rows, xs, bins, jumps, firsts, at):
    """Second differences of w = 1/z at strides a, 2a and 4a along rows and columns, in units of
    the point spacing z/f.

    For each pixel on every ``step``-th row and column and each direction, the smallest a in
    1..``_MAX_GAP`` for which the pixels at +-a, +-2a, +-4a are valid (sparse depth has gaps)
    gives x_s = (w_{-sa} - 2 w_0 + w_{+sa}) z_0 f / sqrt(6) in ``xs[0, k]``, ``xs[1, k]``,
    ``xs[2, k]`` (s = 1, 2, 4), and the centre's depth bin in ``bins[k]``. On a plane they vanish
    (w is affine there); white noise sigma_z in depth gives each the RMS rho = sigma_z f / z; a
    smooth curved surface gives x_2 = 4 x_1 and x_4 = 4 x_2. A stencil whose depths differ by more
    than ``_MAX_SPREAD`` (x1.25) spans a discontinuity and is left out (only a surface seen at
    over 80 degrees from its normal changes depth that fast).

    Terraces: where the stencil is found at a = 1, its centre and two neighbours are also tested for
    quantisation terraces (:func:`terrace_statistics`): a stencil whose depth changes at all
    (``changed``) and whose one neighbour has exactly the centre's depth while the other differs (a
    flat step beside a jump) puts the jump's height |w_0 - w_+-1| z_0 f (point spacings) into
    ``jumps``. ``firsts[k]``: whether sample k was found at a = 1 (the pixel scale: where a pixel's neighbours are
    missing, a wider stencil on fine geometry sees its curvature; :func:`noise_profile` measures the floor and the
    smooth noise at the pixel scale where there are enough such samples). Returns (how many samples, changed, how
    many jumps).

    ``rows``: (first, end) of the rows sampled (a multiple of ``step`` first); ``at``: (samples, jumps) already in
    ``xs`` and ``jumps``, written after. Two parts of the rows, each in its own place, give the samples of one sweep
    in two pieces, in the same order.
    """
    H, W = z.shape
    k, n_jumps = at
    changed = 0
    scale = f / math.sqrt(6.0)
    lo = math.log(zmin)
    span = math.log(zmax) - lo
    for v in range(rows[0], rows[1], step):
        for u in range(0, W, step):
            if not valid[v, u]:
                continue
            zb = z[v, u]
            w0 = 2.0 / zb
            b = 0
            if span > 0.0:
                b = min(nbins - 1, int((math.log(zb) - lo) / span * nbins))
            for a in range(1, _MAX_GAP + 1):
                if (
                    u - 4 * a >= 0
                    and u + 4 * a < W
                    and valid[v, u - 4 * a]
                    and valid[v, u - 2 * a]
                    and valid[v, u - a]
                    and valid[v, u + a]
                    and valid[v, u + 2 * a]
                    and valid[v, u + 4 * a]
                ):
                    if _spread(
                        z[v, u - 4 * a], z[v, u - 2 * a], z[v, u - a], zb, z[v, u + a], z[v, u + 2 * a], z[v, u + 4 * a]
                    ):
                        break  # across a depth discontinuity: not noise
                    xs[0, k] = (1.0 / z[v, u - a] - w0 + 1.0 / z[v, u + a]) * zb * scale
                    xs[1, k] = (1.0 / z[v, u - 2 * a] - w0 + 1.0 / z[v, u + 2 * a]) * zb * scale
                    xs[2, k] = (1.0 / z[v, u - 4 * a] - w0 + 1.0 / z[v, u + 4 * a]) * zb * scale
                    bins[k] = b
                    firsts[k] = a == 1
                    k += 1
                    if a == 1:
                        c, n_jumps = _terrace(z[v, u - 1], zb, z[v, u + 1], f, jumps, n_jumps)
                        changed += c
                    break
            for a in range(1, _MAX_GAP + 1):
                if (
                    v - 4 * a >= 0
                    and v + 4 * a < H
                    and valid[v - 4 * a, u]
                    and valid[v - 2 * a, u]
                    and valid[v - a, u]
                    and valid[v + a, u]
                    and valid[v + 2 * a, u]
                    and valid[v + 4 * a, u]
                ):
                    if _spread(
                        z[v - 4 * a, u], z[v - 2 * a, u], z[v - a, u], zb, z[v + a, u], z[v + 2 * a, u], z[v + 4 * a, u]
                    ):
                        break
                    xs[0, k] = (1.0 / z[v - a, u] - w0 + 1.0 / z[v + a, u]) * zb * scale
                    xs[1, k] = (1.0 / z[v - 2 * a, u] - w0 + 1.0 / z[v + 2 * a, u]) * zb * scale
                    xs[2, k] = (1.0 / z[v - 4 * a, u] - w0 + 1.0 / z[v + 4 * a, u]) * zb * scale
                    bins[k] = b
                    firsts[k] = a == 1
                    k += 1
                    if a == 1:
                        c, n_jumps = _terrace(z[v - 1, u], zb, z[v + 1, u], f, jumps, n_jumps)
                        changed += c
                    break
    return k - at[0], changed, n_jumps - at[1]


@ahead_of_time
@njit
def _clipped_rms(xs, starts, rounds, sigmas, rms):
    """Per row i of ``xs`` and bin b: the RMS of xs[i, starts[b]:starts[b + 1]], then ``rounds`` times the
    RMS of those within ``sigmas`` times it, into rms[i, b] (0 for an empty bin).

    ``xs`` holds each bin's samples together (see :func:`_by_bin`). The kept sets only shrink from round to
    round (dropping values above sigmas >= 1 times the RMS lowers the RMS, and so the bound), so a round
    that keeps as many values as the one before kept the same ones, and every later round would too: a bin
    is left as it is once that holds for each of its rows, and the loop stops once it holds for every bin,
    with the same result. Each bin's squares are summed in the order of its samples, three rows at once
    (independent chains of additions).
    """
    n_rows = xs.shape[0]
    nbins = starts.shape[0] - 1
    counts = np.zeros((n_rows, nbins), np.int64)
    before = np.full((n_rows, nbins), -1, np.int64)
    settled = np.zeros(nbins, np.bool_)
    rms[:, :] = np.inf
    for _ in range(rounds + 1):
        for b in range(nbins):
            if settled[b]:
                continue
            for i0 in range(0, n_rows, 3):
                i1 = min(i0 + 1, n_rows - 1)
                i2 = min(i0 + 2, n_rows - 1)
                x0, x1, x2 = xs[i0], xs[i1], xs[i2]
                l0, l1, l2 = sigmas * rms[i0, b], sigmas * rms[i1, b], sigmas * rms[i2, b]
                s0 = s1 = s2 = 0.0
                c0 = c1 = c2 = 0
                for j in range(starts[b], starts[b + 1]):
                    k0, k1, k2 = abs(x0[j]) <= l0, abs(x1[j]) <= l1, abs(x2[j]) <= l2
                    s0 += select(k0, x0[j] * x0[j], 0.0)
                    s1 += select(k1, x1[j] * x1[j], 0.0)
                    s2 += select(k2, x2[j] * x2[j], 0.0)
                    c0 += k0
                    c1 += k1
                    c2 += k2
                for i, s, c in ((i0, s0, c0), (i1, s1, c1), (i2, s2, c2)):
                    rms[i, b] = math.sqrt(s / c) if c > 0 else 0.0
                    counts[i, b] = c
        for b in range(nbins):
            settled[b] = np.array_equal(counts[:, b], before[:, b])
        if settled.all():
            break
        before[:, :] = counts


@ahead_of_time
@njit
def _by_bin(xs, bins, nbins, grouped, keep):
    """The columns of ``xs`` where ``keep`` (all where it is empty) grouped by bin, in their order within each bin,
    into ``grouped`` (the shape of ``xs``); returns each bin's start (nbins + 1)."""
    every = keep.shape[0] == 0
    starts = np.zeros(nbins + 1, np.int64)
    for j in range(bins.shape[0]):
        if every or keep[j]:
            starts[bins[j] + 1] += 1
    for b in range(nbins):
        starts[b + 1] += starts[b]
    at = starts[:-1].copy()
    for j in range(bins.shape[0]):
        if not (every or keep[j]):
            continue
        k = at[bins[j]]
        at[bins[j]] = k + 1
        for i in range(xs.shape[0]):
            grouped[i, k] = xs[i, j]
    return starts


@pixel
def _select(a, k):
    """The k-th smallest value of ``a`` (1-D), reordering ``a`` in place (Hoare's selection; no allocation)."""
    lo, hi = 0, a.size - 1
    while lo < hi:
        pivot = a[(lo + hi) // 2]
        i, j = lo, hi
        while i <= j:
            while a[i] < pivot:
                i += 1
            while a[j] > pivot:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            break
    return a[k]


@ahead_of_time
@njit
def _quiet(xs, keep, share, gauss, fourth_rms, most):
    """:attr:`NoiseProfile.smooth` from the samples ``xs`` (3, n > 0) where ``keep`` (n,) (all where ``keep`` is
    empty), every s-th of those m kept (s = ceil(m / ``most``)): the geometric mean of two estimates of the noise at
    strides 2 and 4, each the value at rank floor(share (m' - 1)) of its m' magnitudes sorted, over ``gauss``: of
    |x_2|, which curvature raises (a sphere filling the frame) but fine detail does not reach where the scene is
    smooth; and of |x_4 - 4 x_2| / ``fourth_rms``, a fourth difference in which curvature cancels but fine detail
    does not (the foliage of a tree). Noise raises both; either kind of geometry only one. White noise of RMS rho
    reads rho in each, so in their mean. Without the GIL."""
    every = keep.shape[0] == 0
    n = xs.shape[1]
    if not every:
        n = 0
        for i in range(keep.shape[0]):
            n += keep[i]
    s = (n + most - 1) // most
    m = (n + s - 1) // s
    second = np.empty(m)
    fourth = np.empty(m)
    i = 0
    c = 0  # kept samples passed
    for j in range(xs.shape[1]):
        if not (every or keep[j]):
            continue
        if c % s == 0:
            second[i] = abs(xs[1, j])
            fourth[i] = abs(xs[2, j] - 4.0 * xs[1, j]) / fourth_rms
            i += 1
        c += 1
    k = int(share * (m - 1))
    return math.sqrt(_select(second, k) * _select(fourth, k)) / gauss


@ahead_of_time
@njit
def _median_in_place(a):
    """np.median(a) (the same value: the mean of the two middle values when a.size is even), reordering ``a``."""
    return _median_of(a)


@pixel
def _median_of(a):
    """:func:`_median_in_place`, inlined where a kernel calls it."""
    n = a.size
    k = (n - 1) // 2
    lower = _select(a, k)
    if n % 2 == 1:
        return lower
    upper = a[k + 1]
    for i in range(k + 2, n):
        upper = min(upper, a[i])
    return (lower + upper) / 2.0


@ahead_of_time
@njit
def _median_abs(x, keep, mags):
    """np.median(np.abs(x[keep])) (the same value; all of ``x`` where ``keep`` is empty), with ``mags`` (the size of
    ``x``) for the magnitudes, without holding the GIL: another band's thread runs beside it."""
    n = 0
    for i in range(x.shape[0]):
        if keep.shape[0] == 0 or keep[i]:
            mags[n] = abs(x[i])
            n += 1
    return _median_of(mags[:n])


@ahead_of_time
@njit
def _bin_floors(x, starts, min_samples, mags):
    """Per bin b: np.median(np.abs(x[starts[b]:starts[b + 1]])) (each bin's samples together: :func:`_by_bin`), NaN
    where the bin has fewer than ``min_samples``; ``mags`` (the size of ``x``) for the magnitudes."""
    nbins = starts.shape[0] - 1
    out = np.full(nbins, np.nan)
    for b in range(nbins):
        lo, hi = starts[b], starts[b + 1]
        if hi - lo < min_samples:
            continue
        for i in range(lo, hi):
            mags[i] = abs(x[i])
        out[b] = _median_of(mags[lo:hi])
    return out


#: The measurement's working arrays (:func:`_working_set`), kept for the next frame of the same size: made new for
#: every frame, they came from fresh pages wherever another library had just freed large blocks (about 140 page
#: faults on a 450x375 frame after OpenCV's LINEMOD, 2.4 us each on a 2-core VM).
_working = Spares(16 << 20)
#: ``keep`` of :func:`_median_abs` and :func:`_quiet` for every sample.
_EVERY = np.zeros(0, np.bool_)


def _working_set(size: int) -> tuple:
    """(samples (3, size), bins (size,) int64, jumps (size,), samples grouped by bin (3, size), magnitudes (size,),
    whether each sample is at the pixel scale (size,) bool, magnitudes at stride 2 (size,))."""
    return (
        np.empty((3, size)),
        np.empty(size, np.int64),
        np.empty(size),
        np.empty((3, size)),
        np.empty(size),
        np.empty(size, np.bool_),
        np.empty(size),
    )


#: Sampled rows that each half needs for the second differences to be split between two threads.
_SPLIT_ROWS = 16


def _samples(z, valid, f, work=None, offers=None):
    """(zmin, zmax, the second differences (3, n), their depth bins (n), the terraces' jump heights, how many
    stencils changed depth, whether each sample is at the pixel scale (n)): see :func:`_second_differences`; in
    ``work`` (:func:`_working_set` of :func:`sample_capacity`) where given.

    ``offers`` (a :class:`surfnorm._bands.Offers`): the lower half of the rows is offered to a waiting band, which
    writes its samples beyond those the upper half can give; they are then moved up behind the upper half's, so
    the arrays are those of one sweep."""
    zmin, zmax = depth_range(z, valid)
    if not zmax > 0.0:
        return zmin, zmax, np.empty((3, 0)), np.empty(0, np.int64), np.empty(0), 0, np.empty(0, np.bool_)
    H, W = z.shape
    step = noise_step(H, W)
    work = work or _working_set(sample_capacity(H, W))
    xs, bins, jumps, firsts = work[0], work[1], work[2], work[5]
    sweep = (z, valid, float(f), zmin, zmax, N_BINS, step)
    n_rows = (H + step - 1) // step
    if offers is None or n_rows < 2 * _SPLIT_ROWS:
        n, changed, n_jumps = _second_differences(*sweep, (0, H), xs, bins, jumps, firsts, (0, 0))
        return zmin, zmax, xs[:, :n], bins[:n], jumps[:n_jumps], changed, firsts[:n]
    mid = step * (n_rows // 2)
    room = 2 * (n_rows // 2) * ((W + step - 1) // step)  # the most samples (and jumps) the upper half gives
    lower = offers.offer(
        Part(lambda: _second_differences(*sweep, (mid, H), xs, bins, jumps, firsts, (room, room))), first=True
    )
    n, changed, n_jumps = _second_differences(*sweep, (0, mid), xs, bins, jumps, firsts, (0, 0))
    n_2, changed_2, n_jumps_2 = lower.result()
    xs[:, n : n + n_2] = xs[:, room : room + n_2]  # (overlapping ranges: NumPy copies through a buffer)
    bins[n : n + n_2] = bins[room : room + n_2]
    jumps[n_jumps : n_jumps + n_jumps_2] = jumps[room : room + n_jumps_2]
    firsts[n : n + n_2] = firsts[room : room + n_2]
    n, n_jumps = n + n_2, n_jumps + n_jumps_2
    return zmin, zmax, xs[:, :n], bins[:n], jumps[:n_jumps], changed + changed_2, firsts[:n]


def sample_capacity(H: int, W: int) -> int:
    """The most second differences an H x W frame gives: two (along its row and its column) per sampled pixel."""
    step = noise_step(H, W)
    return 2 * ((H + step - 1) // step) * ((W + step - 1) // step)


class NoiseProfile(NamedTuple):
    """The frame's noise, measured by :func:`noise_profile`.

    depths, rho : ndarray
        rho (units of the point spacing z / f) at the centres of log-spaced depth bins. On dense
        depth, of the same stencils as ``floor`` (so too ``correlation`` and ``floors``); on sparse depth
        (:func:`noise_profile`), of every stencil.
    floor : float
        The median |second difference of inverse depth| at stride 1 in the same units, over
        0.6745 (white Gaussian noise of rho gives rho). Depth rendered without noise has most
        second differences at 0 (smooth surfaces between edges) however detailed the scene:
        the 12 3F2N sample frames give 0.00-0.08. Sensor depth has a floor: 0.3-4 on the
        PrimeSense, Kinect v1 (registered), RealSense D435 and LiDAR frames we measured; raw
        structured light and stereo matchers often 0 (their depth lies on flat terraces: see
        ``terraced``). NaN when too few pixels have valid neighbours. Of the stencils found at gap 1
        (the pixel scale) where there are ``MIN_SAMPLES`` of them: where a pixel's neighbours are
        missing, a stencil that bridges the gap sees fine geometry's curvature (3F2N's tree with a
        fifth of its pixels dropped at random read 0.56 from every stencil, 0.06 from these). The
        smooth noise is read from the same stencils.
    terraced : float
        Of the stencils found at gap 1 whose three central depths are not all equal, the share
        that are a flat step beside a jump (one neighbour at exactly the centre's depth, the
        other not): quantised depth on surfaces that are not fronto-parallel. The 12 3F2N sample
        frames give 0.00-0.10 (exactly equal neighbours only on fronto-parallel surfaces); raw
        Kinect v1 and Xtion frames (TUM RGB-D, NYU raw, SUN RGB-D), stereo matchers' depth and
        millimetre-stored RealSense depth 0.4-0.9. 0 when fewer than ``MIN_SAMPLES`` changed.
    step : float
        The median height of those jumps, in point spacings (0 without any). For disparity in
        1/8-pixel steps it is z / (8 B) at depth z and baseline B: about 4 for a Kinect at 2.5 m.
    smooth : float
        The noise at strides 2 and 4 in the quietest tenth of the samples: the geometric mean
        of the 10 % quantiles of |x_2| and of the fourth difference |x_4 - 4 x_2| / sqrt(70 / 6),
        each over 0.12566 (white noise of RMS rho gives rho). Error smooth over a few pixels
        (a stereo network's float output) shows less at stride 1 than here; curvature raises
        only the first (a sphere filling the frame), fine detail only the second (a tree's
        foliage), noise both. The 12 3F2N sample frames give 0.000-0.012.
    correlation : float
        The clipped mean square of the second differences at stride 2 over that at stride 1, the curvature's
        part taken out (the three strides tell white noise, noise correlated over ``CORRELATION_WIDTH`` pixels
        and curvature apart: :func:`_correlation`): 1 for noise independent from pixel to pixel, more where
        neighbours' errors go together (a matcher's window, a spatial filter: about 1.3 for the simulated raw
        Kinect v1, 3 for SGBM, 10 for error smooth over 2 pixels), where a fitted slope moves more than its
        residual says. 1 without enough samples.
    floors : ndarray or None
        The floor of each depth bin (the bins of ``depths``: the median |x_1| of its samples over 0.6745), NaN
        where a bin has fewer than ``MIN_SAMPLES``; where the noise grows with depth, the far bins' floors exceed
        the frame's. Measured only where ``auto`` may check its two estimators against each other: where the frame is
        not terraced in full (:func:`terraced_share` under 1), or where its quantisation's step
        (:func:`quantisation_step`) is small enough for a limit of ``STEP_CONSISTENT`` times it; None elsewhere.
    floor2 : float
        The same median as ``floor`` of |x_2|, the second differences at stride 2 (of the same stencils): the floor
        of stride 2. A smooth shape gives 4 times the floor, white noise the floor; noise correlated over a pixel or
        two between. NaN where the floor is (and on profiles made without it).
    grid : float
        The step of the grid the depth is stored on (:func:`depth_grid`: whole millimetres, 1/5000 m, float16's
        steps within a power of two), in point spacings at the depths of the pixels measured (their mean of f / z
        times the step), where ``GRID_SHARE`` of the differences between the sampled pixels' valid depths and their
        right-hand neighbours' are whole multiples of the smallest one and ``GRID_STEPS`` of them 0 or 2 and more
        of it; 0 elsewhere. Float32 renders read their own rounding, under 0.0002; whole millimetres at 2.5 m and
        580 px about 0.23; the Azure Kinect, RealSense, NYU and KITTI frames we measured 0.2-1.7; raw Kinect v1
        disparity and stereo matchers' float depth 0 (their grid is in 1 / z: see ``step``).
    """

    depths: np.ndarray
    rho: np.ndarray
    floor: float
    terraced: float = 0.0
    step: float = 0.0
    smooth: float = 0.0
    correlation: float = 1.0
    floors: np.ndarray | None = None
    floor2: float = float("nan")
    grid: float = 0.0


def _correlation(rms, starts, min_samples):
    """:attr:`NoiseProfile.correlation` from the clipped RMS ``rms`` (3, nbins) of the second differences at
    strides 1, 2 and 4 and the bins' ``starts``: per bin, the mean square at stride 2 over that at stride 1 with
    the curvature's part taken out (``_STRIDES_SOLVE``; none where it solves to less than nothing), averaged over
    the bins with at least ``min_samples`` samples (weighted by their samples); 1 without any."""
    num = den = 0.0
    for b in range(rms.shape[1]):
        n = starts[b + 1] - starts[b]
        if n >= min_samples and rms[0, b] > 0.0:
            m = rms[:, b] * rms[:, b]
            curvature = max(float(_STRIDES_SOLVE[2] @ m), 0.0)
            m_1, m_2 = m[0] - curvature, m[1] - 16.0 * curvature
            num += n * (m_2 / m_1 if m_1 > 0.0 and m_2 > 0.0 else m[1] / m[0])
            den += n
    return num / den if den > 0.0 else 1.0


def terrace_statistics(jumps: np.ndarray, changed: int) -> tuple[float, float]:
    """(terraced, step) of :class:`NoiseProfile` from the jump heights and the count of stencils that changed
    depth (:func:`_second_differences`): the share of jumps among them (0 when fewer than ``MIN_SAMPLES``
    changed), and the median height (0 without jumps)."""
    if changed < MIN_SAMPLES or jumps.size == 0:
        return 0.0, 0.0
    return jumps.size / changed, float(_median_in_place(jumps))


def noise_profile(
    z: np.ndarray, valid: np.ndarray, f: float, offers=None, *, sparse: bool | None = None
) -> NoiseProfile:
    """The frame's noise against depth (see :class:`NoiseProfile`).

    In each depth bin (log-spaced between the nearest and farthest valid depth),
    the sigma-clipped mean squares v_1, v_2, v_4 of the second differences of
    inverse depth at strides 1, 2 and 4 (see :func:`_second_differences`)
    separate noise from shape: white noise adds rho^2 to each, smooth curvature
    adds c, 16 c and 256 c, so rho^2 = (16 v_1 - v_2) / 15 (the curvature of
    clean depth is not taken for noise). Noise correlated between neighbours
    (stereo matchers aggregate over windows) shows less at stride 1 than at
    stride 2 while it still moves a fitted slope, so rho is the larger of the
    stride-1 estimate and (16 v_2 - v_4) / 15. Sampled on every step-th row and column
    (:func:`surfnorm._constants.noise_step`). Bins with fewer than ``MIN_SAMPLES`` samples
    take the value of the nearest bins that have enough; with none, rho is 0
    (3x3 windows). On dense depth with holes, of the stencils at the pixel scale alone where there are
    ``MIN_SAMPLES`` of them, as the floor (``sparse``: whether the depth is sparse, as
    :func:`surfnorm.kernels._schedule.choose_stride` finds it; found here where not given).

    ``offers``: a :class:`surfnorm._bands.Offers` of the bands waiting for this profile, one of which may take
    the floor's median while this thread sums the bins (the same value either way).
    """
    size = sample_capacity(*z.shape)
    work = _working.take(size) or _working_set(size)
    zmin, zmax, xs, bins, jumps, changed, firsts = _samples(z, valid, f, work, offers)
    n = xs.shape[1]
    if n < MIN_SAMPLES:
        _working.give(size, work)
        return NoiseProfile(np.array([zmin if zmax > 0.0 else 1.0]), np.zeros(1), float("nan"))
    # The floor (a median), the smooth noise and the terraces do not depend on the rest: another band's thread may
    # take them (``offers``, see surfnorm._bands.Offers) while this one sums the bins. The floor and the smooth noise
    # are the pixel scale's where it has enough samples (random holes on fine geometry: wider stencils see its
    # curvature); the same samples where no stencil had to bridge a gap.
    n_first = int(np.count_nonzero(firsts))
    keep = firsts if MIN_SAMPLES <= n_first < n else _EVERY
    if sparse is None:
        sparse = choose_stride(valid) == 1
    # The bins (rho, the correlation, the bins' floors) from the same samples on dense depth: there the wider stencils
    # bridge random holes and read fine geometry's curvature as noise (the 12 3F2N frames with white noise of 0.005 %
    # of depth and a fifth of their pixels dropped: their median rho over that without holes was 0.8-1.2 on 5 frames
    # from every stencil, on 9 from these; 1.57 and 1.02 in the median). Sparse depth (LiDAR scanlines,
    # :func:`surfnorm.kernels._schedule.choose_stride`) has stencils at gap 1 along its lines alone. The choice is the
    # frame's, not each bin's: where a dense frame's stencils at gap 1 lie in part of its depth range only, the other
    # bins take the nearest measured bins' rho, as bins with too few samples do.
    binned = _EVERY if sparse else keep
    median = Part(lambda: (_median_abs(xs[0], keep, work[4][:n]), _median_abs(xs[1], keep, work[6][:n])))
    smooth = Part(lambda: _quiet(xs, keep, SMOOTH_SHARE, _SMOOTH_GAUSS, _FOURTH_RMS, _SMOOTH_SAMPLES))
    terraces = Part(lambda: terrace_statistics(jumps, changed))
    if offers is not None:
        for part in (median, smooth, terraces):
            offers.offer(part)
    ms = np.empty((3, N_BINS))
    grouped = work[3][:, :n]
    starts = _by_bin(xs, bins, N_BINS, grouped, binned)
    grouped = grouped[:, : starts[-1]]
    _clipped_rms(grouped, starts, _CLIP_ROUNDS, _CLIP_SIGMAS, ms)
    centres, rho = _by_depth(ms, starts, zmin, zmax, MIN_SAMPLES)
    terraced, step = terraces.result()
    correlation = _correlation(ms, starts, MIN_SAMPLES)
    at_1, at_2 = median.result()  # before its scratch is used again below
    floor, floor2 = at_1 / 0.6745, at_2 / 0.6745
    profile = NoiseProfile(
        centres, rho, floor, terraced, step, smooth.result(), correlation, None, floor2, depth_grid(z, valid, f)
    )
    if _may_check(profile):  # auto may check its estimators against each other (consistency_limits)
        profile = profile._replace(floors=_bin_floors(grouped[0], starts, MIN_SAMPLES, work[4][:n]) / 0.6745)
    # every part has ended (result() waits for one another thread runs), so nothing reads the arrays any more; on an
    # error they are dropped instead (a part may still be running)
    _working.give(size, work)
    return profile


@ahead_of_time
@njit
def _by_depth(rms, starts, zmin, zmax, min_samples):
    """The bins' centres and rho (see :func:`noise_profile`) from the clipped RMS ``rms`` (3, nbins) of the second
    differences at strides 1, 2 and 4 and the bins' ``starts`` (nbins + 1): the centres are the geometric means of
    log-spaced edges (np.geomspace's arithmetic), and a bin with fewer than ``min_samples`` samples takes rho
    interpolated in log depth between the nearest that have enough (0 everywhere without any)."""
    nbins = rms.shape[1]
    rho = np.empty(nbins)
    for b in range(nbins):
        m0, m1, m2 = rms[0, b] * rms[0, b], rms[1, b] * rms[1, b], rms[2, b] * rms[2, b]
        rho[b] = math.sqrt(max(max(16.0 * m0 - m1, 16.0 * m1 - m2), 0.0) / 15.0)
    edges = np.full(nbins + 1, zmin)
    if zmax > zmin:
        lo, hi = math.log10(zmin), math.log10(zmax)
        step = (hi - lo) / nbins
        for i in range(1, nbins):
            edges[i] = 10.0 ** (i * step + lo)
        edges[nbins] = zmax
    centres = np.empty(nbins)
    for b in range(nbins):
        centres[b] = math.sqrt(edges[b] * edges[b + 1])
    ok = np.empty(nbins, np.bool_)
    for b in range(nbins):
        ok[b] = starts[b + 1] - starts[b] >= min_samples
    if not ok.any():
        return centres, np.zeros(nbins)
    log_c = np.log(centres)
    return centres, np.interp(log_c, log_c[ok], rho[ok])


# --- what the frame is, from its profile (``auto``'s decision) ---------------------------------------------


def quantisation(profile: NoiseProfile) -> float:
    """The quantisation noise of the frame's terraces in point spacings: ``step`` / sqrt(12) (the RMS of
    rounding to steps of that height), times the share in which the frame counts as terraced (0 at or below
    ``TERRACED_LOW``, 1 at or above ``TERRACED_HIGH``, linear between)."""
    return terraced_share(profile) * profile.step / math.sqrt(12.0)


def terraced_share(profile: NoiseProfile, low: float = TERRACED_LOW) -> float:
    """How far the frame counts as terraced: 0 at or below ``low`` (``TERRACED_LOW``; ``auto``'s consistency check
    starts from ``TERRACED_CHECK``), 1 at or above ``TERRACED_HIGH``, linear between."""
    return _ramp(profile.terraced, low, TERRACED_HIGH)


def grid_share(profile: NoiseProfile) -> float:
    """How far the frame counts as stored on a grid (:attr:`NoiseProfile.grid`): 0 at or below ``GRID_LOW``, 1 at or
    above ``GRID_HIGH`` point spacings, linear between."""
    return _ramp(profile.grid, GRID_LOW, GRID_HIGH)


def _may_check(profile: NoiseProfile) -> bool:
    """Whether ``auto`` may check its estimators against each other on this frame, so that its profile needs the
    bins' floors (``auto.consistency_limits``): where the frame is not terraced in full, or where its
    :func:`step_limit` (every limit is at least that one) is under ``CONSISTENT_MAX``."""
    if profile.terraced < TERRACED_HIGH:
        return True
    share = smooth_error_share(profile)
    return share < 1.0 and step_limit(profile, kappa_gain(profile), share) < CONSISTENT_MAX


def step_limit(profile: NoiseProfile, gain: float, share: float) -> float:
    """The least limit of ``auto``'s consistency check on this frame (radians; ``auto.consistency_limits``):
    ``STEP_CONSISTENT`` times the kappa ``gain`` (:func:`kappa_gain`) times the quantisation's step
    (:func:`quantisation_step`), widened as 1 / (1 - ``share``), the smooth error's share
    (:func:`smooth_error_share`, under 1)."""
    return STEP_CONSISTENT * gain * quantisation_step(profile) / (1.0 - share)


def quantisation_step(profile: NoiseProfile) -> float:
    """The step of the frame's quantisation in point spacings, in the share in which it is one: the terraces' step
    (``step``) in the share in which the frame is terraced (from ``TERRACED_CHECK`` to ``TERRACED_HIGH``), or the
    grid's (``grid``, :func:`grid_share`), the larger. ``auto``'s consistency check takes it as the noise of
    ``d2nt_v3``'s normals there (``STEP_CONSISTENT``)."""
    return max(terraced_share(profile, TERRACED_CHECK) * profile.step, grid_share(profile) * profile.grid)


def _ramp(x: float, low: float, high: float) -> float:
    """0 at or below ``low``, 1 at or above ``high``, linear between."""
    return min(max((x - low) / (high - low), 0.0), 1.0)


def smooth_error_share(profile: NoiseProfile) -> float:
    """How far the frame's error is small and smooth over a few pixels (a phone's LiDAR depth, a learned stereo
    matcher's output), from 0 to 1: the noise ``rho`` (its median over the depth bins) over the ``floor`` from
    ``SMOOTH_ERROR_LOW`` to ``SMOOTH_ERROR_HIGH`` (white noise reads about 1, error that neighbours share more), and
    down again from ``SMOOTH_ERROR_SHAPE_LOW`` to ``SMOOTH_ERROR_SHAPE_HIGH`` (there rho is the scene's shape), times
    the ``floor`` over ``floor2`` from ``SMOOTH_ERROR_PIXEL_LOW`` to ``SMOOTH_ERROR_PIXEL_HIGH`` (a smooth shape
    reads 0.25: the error must show at the pixel scale, where a render's fine geometry does not), the floor from
    ``SMOOTH_ERROR_FLOOR_LOW`` to ``SMOOTH_ERROR_FLOOR_HIGH`` and the share of rho that is noise
    (``GEOMETRY_RHO_LOW`` to ``GEOMETRY_RHO_HIGH``); each a linear ramp (see :mod:`surfnorm._constants`). 0 where
    either floor is 0 or not a number."""
    ratios = _noise_ratios(profile)
    if ratios is None:
        return 0.0
    rho, ratio, pixel_ratio = ratios
    correlated = _ramp(ratio, SMOOTH_ERROR_LOW, SMOOTH_ERROR_HIGH) * (
        1.0 - _ramp(ratio, SMOOTH_ERROR_SHAPE_LOW, SMOOTH_ERROR_SHAPE_HIGH)
    )
    pixel = _ramp(pixel_ratio, SMOOTH_ERROR_PIXEL_LOW, SMOOTH_ERROR_PIXEL_HIGH)
    noise = _ramp(profile.floor, SMOOTH_ERROR_FLOOR_LOW, SMOOTH_ERROR_FLOOR_HIGH)
    return correlated * pixel * noise * (1.0 - _geometry(rho))


def white_noise_share(profile: NoiseProfile) -> float:
    """How far the frame's error is white noise, from 0 to 1, however small: the ``floor`` over ``floor2`` from
    ``WHITE_PIXEL_LOW`` to ``WHITE_PIXEL_HIGH`` (white noise shows as much at the pixel scale as at stride 2, a
    render's fine geometry far less), 1 less the ramp of the noise ``rho`` (its median over the depth bins) over the
    floor from ``SMOOTH_ERROR_LOW`` to ``SMOOTH_ERROR_HIGH`` (where the smooth error's share starts), the share of rho
    that is noise (``GEOMETRY_RHO_LOW`` to ``GEOMETRY_RHO_HIGH``) and the floor from ``WHITE_FLOOR_LOW`` to
    ``WHITE_FLOOR_HIGH``; each a linear ramp (see :mod:`surfnorm._constants`). 0 where either floor is 0 or not a
    number. Where rho over the floor lies between those two, the rest of its ramp is the smooth error's share
    (:func:`smooth_error_share`): :func:`adaptive_weight` is at least the sum of the two, error either way. (The
    share of rho that is noise falls under 1 only where the floor is over about 0.8, which reads as sensor depth
    anyway: it moves the share reported, not the weight.)"""
    ratios = _noise_ratios(profile)
    if ratios is None:
        return 0.0
    rho, ratio, pixel_ratio = ratios
    pixel = _ramp(pixel_ratio, WHITE_PIXEL_LOW, WHITE_PIXEL_HIGH)
    uncorrelated = 1.0 - _ramp(ratio, SMOOTH_ERROR_LOW, SMOOTH_ERROR_HIGH)
    noise = _ramp(profile.floor, WHITE_FLOOR_LOW, WHITE_FLOOR_HIGH)
    return pixel * uncorrelated * noise * (1.0 - _geometry(rho))


def _noise_ratios(profile: NoiseProfile) -> tuple[float, float, float] | None:
    """(the median rho over the depth bins, rho over the ``floor``, the floor over ``floor2``) that the smooth error's
    and the white noise's shares read; None where either floor is 0 or not a number, or rho is not a number."""
    rho = _median(profile.rho)
    if not (profile.floor > 0.0 and profile.floor2 > 0.0 and rho == rho):
        return None
    return rho, rho / profile.floor, profile.floor / profile.floor2


def smooth_error_reading(profile: NoiseProfile) -> float:
    """The reading that :func:`smooth_error_share` s gives: s of the way from ``CLEAN_FLOOR`` to ``NOISY_FLOOR``,
    0 where s is 0."""
    s = smooth_error_share(profile)
    return CLEAN_FLOOR + (NOISY_FLOOR - CLEAN_FLOOR) * s if s > 0.0 else 0.0


def reading(profile: NoiseProfile) -> float:
    """The noise level ``auto`` decides on: the largest of the floor, the smooth noise, :func:`quantisation`,
    ``NOISY_FLOOR`` times :func:`terraced_share` and :func:`smooth_error_reading` (NaN with the floor).

    The fourth: depth stored in steps (terraced) is not a float render, whose terraces measure at most 0.10, so its
    steps are error, however low: a frame terraced in full reads as sensor depth. Without it, millimetre depth
    smoothed by a median filter (steps of a quarter of a point spacing, the noise filtered away) read 0.08-0.17,
    and ``auto`` gave 15.8 degrees where ``adaptive_fit`` gives 13.3 (``benchmarks/families.py``).

    The last: small error smooth over a few pixels reads floors of 0.04-0.09, as renders do, and ``d2nt_v3``
    followed it (a phone's LiDAR depth: 5.0 and 5.7 degrees, where ``auto`` now gives 3.5 and 4.2; docs/choosing.md)."""
    if not profile.floor == profile.floor:
        return float("nan")
    return max(
        profile.floor,
        profile.smooth,
        quantisation(profile),
        NOISY_FLOOR * terraced_share(profile),
        smooth_error_reading(profile),
    )


def _median(values) -> float:
    """np.median of a few values (the same value: the mean of the two middle ones for an even count; NaN where one
    is NaN or there are none), in Python: the decision reads the median of the profile's ``N_BINS`` rho several times
    a frame, on the calling thread between the noise and the fit, where np.median took 0.09 ms of a 3.5 ms call and a
    compiled selection 5 us each."""
    a = np.asarray(values, dtype=np.float64).ravel().tolist()
    if not a or any(v != v for v in a):
        return float("nan")
    a.sort()
    k = (len(a) - 1) // 2
    return a[k] if len(a) % 2 else (a[k] + a[k + 1]) / 2.0


def geometry_share(profile: NoiseProfile) -> float:
    """How far the frame's noise ``rho`` is its fine geometry, not its noise, from 0 to 1: its median over the depth
    bins from ``GEOMETRY_RHO_LOW`` to ``GEOMETRY_RHO_HIGH`` point spacings (3F2N's tree, temple and batman read 3-6,
    clean or with white noise of up to 0.05 % of depth; white noise over smooth shapes reads its floor). 0 where it
    is not a number."""
    rho = _median(profile.rho)
    return _geometry(rho) if rho == rho else 0.0


def _geometry(rho: float) -> float:
    """:func:`geometry_share` of a median rho (a number)."""
    return _ramp(rho, GEOMETRY_RHO_LOW, GEOMETRY_RHO_HIGH)


def kappa_gain(profile: NoiseProfile) -> float:
    """The adaptive fit's gain on its noise test's kappa for this frame: 1, up to ``CORRELATED_KAPPA_GAIN`` where the
    noise is correlated across pixels (``correlation`` from ``CORRELATED_LOW`` to ``CORRELATED_HIGH``), the
    measured rho is not the scene's fine geometry (median rho from ``GEOMETRY_RHO_HIGH`` down to
    ``GEOMETRY_RHO_LOW``) and the frame reads as sensor depth (:func:`reading_weight` of its :func:`reading`: on clean
    depth, a grid's steps aside, there is no noise whose correlation a ratio of second differences could tell);
    linear in each, so that the normals move
    continuously with the profile (see :mod:`surfnorm._constants`). 1 where a measure is not a number."""
    correlated = (profile.correlation - CORRELATED_LOW) / (CORRELATED_HIGH - CORRELATED_LOW)
    noise = (GEOMETRY_RHO_HIGH - _median(profile.rho)) / (GEOMETRY_RHO_HIGH - GEOMETRY_RHO_LOW)
    if not (correlated == correlated and noise == noise):
        return 1.0
    share = min(max(correlated, 0.0), 1.0) * min(max(noise, 0.0), 1.0) * reading_weight(reading(profile))
    return float(1.0 + (CORRELATED_KAPPA_GAIN - 1.0) * share)


def adaptive_weight(profile: NoiseProfile) -> float:
    """The weight of ``adaptive_fit`` in the blend, from 0 (clean depth) to 1 (sensor depth): from :func:`reading`, or
    where larger the frame's :func:`grid_share` (depth stored on a grid is not a float render: its steps are error)
    or its :func:`white_noise_share` plus its :func:`smooth_error_share`, at most 1 (noise however small, white or
    smooth over a few pixels, is error too: the two shares split the ramp of rho over the floor between them).

    A NaN floor (too few pixels with valid neighbours to measure one: sparse depth, as from a LiDAR) gives 1.
    """
    noise = min(white_noise_share(profile) + smooth_error_share(profile), 1.0)
    return max(reading_weight(reading(profile)), grid_share(profile), noise)


def reading_weight(r: float) -> float:
    """:func:`adaptive_weight` of a frame whose :func:`reading` is ``r`` (1 where NaN)."""
    if not r == r:
        return 1.0
    return _ramp(r, CLEAN_FLOOR, NOISY_FLOOR)


# --- depth upsampled from a lower resolution ----------------------------------------------------------------------


@pixel
def _bend(a, b, c):
    """|a - 2 b + c| / b, the relative second difference of three valid depths; 0 across a discontinuity (their
    depths differ by more than ``_MAX_SPREAD``)."""
    lo = min(a, b, c)
    hi = max(a, b, c)
    return select(hi <= _MAX_SPREAD * lo, abs(a - 2.0 * b + c) / b, 0.0)


@ahead_of_time
@njit(noalias=True)
def _bends(z, valid, step, along_u, along_v):
    """The relative second differences of depth (:func:`_bend`) summed by position: along every ``step``-th row
    into ``along_u`` (W,) by column, along every ``step``-th column into ``along_v`` (H,) by row (where the three
    pixels are valid; branch-free, so that the loops vectorise). Returns how many were summed along each."""
    H, W = z.shape
    along_u[:] = 0.0
    along_v[:] = 0.0
    n_u = 0
    n_v = 0
    for v in range(0, H, step):
        z_row = z[v]
        ok_row = valid[v]
        for u in range(1, W - 1):
            ok = ok_row[u - 1] & ok_row[u] & ok_row[u + 1]
            b = select(ok, z_row[u], 1.0)
            along_u[u] += select(ok, _bend(select(ok, z_row[u - 1], 1.0), b, select(ok, z_row[u + 1], 1.0)), 0.0)
            n_u += ok
    for v in range(1, H - 1):
        up, mid, down = z[v - 1], z[v], z[v + 1]
        ok_up, ok_mid, ok_down = valid[v - 1], valid[v], valid[v + 1]
        total = 0.0
        for u in range(0, W, step):
            ok = ok_up[u] & ok_mid[u] & ok_down[u]
            b = select(ok, mid[u], 1.0)
            total += select(ok, _bend(select(ok, up[u], 1.0), b, select(ok, down[u], 1.0)), 0.0)
            n_v += ok
        along_v[v] = total
    return n_u, n_v


@pixel
def _fourth(a, b, c, d, e):
    """|a - 4 b + 6 c - 4 d + e| / c, the relative fourth difference of five valid depths; 0 across a discontinuity
    (their depths differ by more than ``_MAX_SPREAD``). It vanishes on any cubic: between the seams of a bicubic
    resize."""
    lo = min(a, b, c, d, e)
    hi = max(a, b, c, d, e)
    return select(hi <= _MAX_SPREAD * lo, abs(a - 4.0 * b + 6.0 * c - 4.0 * d + e) / c, 0.0)


@ahead_of_time
@njit(noalias=True)
def _fourths(z, valid, step, along_u, along_v):
    """The relative fourth differences of depth (:func:`_fourth`) summed by the position of their centre, as
    :func:`_bends` sums the second ones: along every ``step``-th row into ``along_u`` (W,), along every ``step``-th
    column into ``along_v`` (H,), where the five pixels are valid. Returns how many were summed along each."""
    H, W = z.shape
    along_u[:] = 0.0
    along_v[:] = 0.0
    n_u = 0
    n_v = 0
    for v in range(0, H, step):
        z_row = z[v]
        ok_row = valid[v]
        for i in range(W - 4):  # centred on u = i + 2 (a loop from 2 did not vectorise: 5x slower)
            ok = ok_row[i] & ok_row[i + 1] & ok_row[i + 2] & ok_row[i + 3] & ok_row[i + 4]
            x = _fourth(
                select(ok, z_row[i], 1.0),
                select(ok, z_row[i + 1], 1.0),
                select(ok, z_row[i + 2], 1.0),
                select(ok, z_row[i + 3], 1.0),
                select(ok, z_row[i + 4], 1.0),
            )
            along_u[i + 2] += select(ok, x, 0.0)
            n_u += ok
    for v in range(2, H - 2):
        r0, r1, r2, r3, r4 = z[v - 2], z[v - 1], z[v], z[v + 1], z[v + 2]
        k0, k1, k2, k3, k4 = valid[v - 2], valid[v - 1], valid[v], valid[v + 1], valid[v + 2]
        total = 0.0
        for u in range(0, W, step):
            ok = k0[u] & k1[u] & k2[u] & k3[u] & k4[u]
            x = _fourth(
                select(ok, r0[u], 1.0),
                select(ok, r1[u], 1.0),
                select(ok, r2[u], 1.0),
                select(ok, r3[u], 1.0),
                select(ok, r4[u], 1.0),
            )
            total += select(ok, x, 0.0)
            n_v += ok
        along_v[v] = total
    return n_u, n_v


@pixel
def seam_share(bends, k, width, chunks, q):
    """Of the differences summed by position (:func:`_bends`, :func:`_fourths`), the largest share on ``width``
    neighbouring positions modulo the factor k / q (0 without any): 1 where depth bends only at the seams of a
    k / q-times resize (a stencil of width + 1 pixels straddles each seam at ``width`` positions), about width q / k
    elsewhere. The positions are folded into k phases of 1 / q pixel (position i at phase q i modulo k), so that a
    factor that is not a whole number (q 2: 7.5, whose seams lie 7 and 8 pixels apart in turn) piles its seams on
    the q width phases of ``width`` pixels as a whole one (q 1) does. With ``chunks`` over 1, the positions are cut
    into that many consecutive parts, each with its own best phase, and the share is the sum of their best over their
    total (seams that drift: ``UPSAMPLED_DRIFT_SPAN``)."""
    n = bends.shape[0]
    phases = np.zeros(k)
    total = 0.0
    most_sum = 0.0
    span = q * width
    for c in range(chunks):
        lo = c * n // chunks
        hi = (c + 1) * n // chunks
        part = 0.0
        phases[:] = 0.0
        at = (q * lo) % k  # position i's phase, q i modulo k, kept by steps (no division per position)
        for i in range(lo, hi):
            phases[at] += bends[i]
            at += q
            if at >= k:
                at -= k
        for p in range(k):
            part += phases[p]
        most = 0.0
        for p in range(k):
            run = 0.0
            for j in range(span):
                run += phases[(p + j) % k]
            most = max(most, run)
        total += part
        most_sum += most
    return most_sum / total if total > 0.0 else 0.0


@ahead_of_time
@njit
def _seam_factor(along_u, along_v, k_low, k_high, share, width, chunks_u, chunks_v, q):
    """The largest factor k / q from ``k_high`` down to ``k_low`` (both included where they are such factors: whole
    factors for ``q`` 1; for ``q`` 2 those halfway between whole ones) whose :func:`seam_share` on ``width`` positions
    (in ``chunks_u`` and ``chunks_v`` parts) reaches ``share`` along both, and exceeds that of the factor + 1 by
    ``UPSAMPLED_CONTRAST`` along both (seams repeat every k / q pixels: differences piled at a few places, a clean
    planar scene's creases, hold as much at every factor): its numerator k, or 1."""
    lo = math.ceil(q * k_low)
    hi = math.floor(q * k_high)
    top = hi + q
    shares = np.zeros((2, max(top + 1, 1)))  # each factor's shares once: f is also the f + 1 of f - 1
    for k in range(lo, top + 1):
        if q == 1 or k % q != 0:
            shares[0, k] = seam_share(along_u, k, width, chunks_u, q)
            shares[1, k] = seam_share(along_v, k, width, chunks_v, q)
    for k in range(hi, lo - 1, -1):
        if q > 1 and k % q == 0:
            continue
        passes = True
        for a in range(2):
            passes &= shares[a, k] >= share and shares[a, k + q] <= shares[a, k] - UPSAMPLED_CONTRAST
        if passes:
            return k
    return 1


def upsampling_factor(z: np.ndarray, valid: np.ndarray) -> float:
    """The factor K by which the depth was resized from a lower resolution (bilinear, bicubic or nearest), or 1: a whole
    number, or one halfway between two.

    Such depth bends only at the seams between the low-resolution samples, the same columns in every row and the
    same rows in every column: K is the largest factor from ``UPSAMPLED_MIN`` to ``UPSAMPLED_MAX`` for which, along
    the rows and along the columns, at least ``UPSAMPLED_SHARE`` of the bends (second differences, :func:`_bends`)
    fall on two neighbouring positions modulo K (:func:`seam_share`). A bicubic resize bends everywhere between its
    seams, but it is a cubic there, whose fourth differences vanish (:func:`_fourths`): where no factor passes on
    the bends, the same is asked of the fourth differences on four neighbouring positions, in the passes of
    ``UPSAMPLED_FOURTH_PASSES``: K from ``UPSAMPLED_CUBIC_CLOSE`` to ``UPSAMPLED_MAX`` with ``UPSAMPLED_SHARE``, then
    from ``UPSAMPLED_CUBIC_MIN`` to ``UPSAMPLED_CUBIC_CLOSE`` - 1 with ``UPSAMPLED_CUBIC_CLOSE_SHARE`` (depth without
    seams puts about 4 / K there). Measured on every ``UPSAMPLED_STEP``-th row and column that the noise measurement
    samples; 1 where no factor passes, or where fewer than ``MIN_SAMPLES`` stencils were valid along either
    direction. In every pass the share modulo K + 1 must be at least ``UPSAMPLED_CONTRAST`` lower (seams repeat every
    K pixels; differences piled at a few places do not). A factor K makes its divisors pass too, hence the largest.
    A factor halfway between whole ones (a phone's 256x192 depth brought to its 1920x1440 colour: 7.5) puts its seams
    7 and 8 pixels apart in turn, spread over the phases of any whole K; after each pass for whole factors the same is
    asked of those between its bounds (K + 0.5, the positions folded modulo K + 0.5 in half-pixel phases:
    :func:`seam_share`'s ``q``; 4.5 to 14.5 on the bends, 6.5 to 14.5 and 5.5 on the fourth differences), whose
    factor is then returned (a float). Where no pass finds one on a frame of at
    least 2 ``UPSAMPLED_DRIFT_SPAN`` pixels along a side, they run again with the positions in parts of about that
    many pixels, each part at its own phase: the seams of a factor that is neither drift against it. Last, where none
    passes, the factors under ``UPSAMPLED_MIN`` in ``UPSAMPLED_SMALL`` (2.5, 3, 3.5: a phone's 256x192 depth brought
    to 640x480) on the bends, with ``UPSAMPLED_SMALL_SHARE``: depth without seams fills most of their two positions of
    every 2.5-3.5, a resize leaves the rest empty. See :mod:`surfnorm._constants`."""
    H, W = z.shape
    k_high = min(UPSAMPLED_MAX, W // 4, H // 4)
    if k_high < UPSAMPLED_MIN:
        return 1
    step = UPSAMPLED_STEP * noise_step(H, W)
    bends = np.empty(W), np.empty(H)
    n_u, n_v = _bends(z, valid, step, *bends)
    if n_u < MIN_SAMPLES or n_v < MIN_SAMPLES:
        return 1
    # the positions whole, then (frames of 2 UPSAMPLED_DRIFT_SPAN and more) in parts: seams that drift
    rounds = [(1, 1)]
    drift = (max(1, W // UPSAMPLED_DRIFT_SPAN), max(1, H // UPSAMPLED_DRIFT_SPAN))
    if drift != (1, 1):
        rounds.append(drift)
    fourths = None
    for chunks in rounds:
        k = int(_seam_factor(*bends, float(UPSAMPLED_MIN), float(k_high), UPSAMPLED_SHARE, 2, *chunks, 1))
        if k > 1:
            return k
        # a factor halfway between whole ones: its seams 7 and 8 pixels apart in turn (7.5x), folded modulo 7.5; before
        # the fourth differences, whose wider stencils pile 10.5x's seams on four of every 7 pixels
        k = int(_seam_factor(*bends, float(UPSAMPLED_MIN), float(k_high), UPSAMPLED_SHARE, 2, *chunks, 2))
        if k > 1:
            return k / 2
        if fourths is None:
            fourths = np.empty(W), np.empty(H)
            n_u, n_v = _fourths(z, valid, step, *fourths)
            if n_u < MIN_SAMPLES or n_v < MIN_SAMPLES:
                fourths = ()
        if not fourths:
            continue
        for q in (1, 2):  # whole factors, then those halfway between them (in parts: the close share only)
            for k_low, k_top, share in fourth_passes(q, chunks != (1, 1)):
                k = int(_seam_factor(*fourths, float(k_low), float(min(k_top, k_high)), share, 4, *chunks, q))
                if k > 1:
                    return k if q == 1 else k / 2
    # factors under UPSAMPLED_MIN (2.5, 3, 3.5), which depth without seams fills most positions of: a resize leaves
    # the rest empty (UPSAMPLED_SMALL_SHARE)
    low, high = UPSAMPLED_SMALL
    for chunks in rounds:
        k = int(_seam_factor(*bends, low, high, UPSAMPLED_SMALL_SHARE, 2, *chunks, 2))
        if k > 1:
            return k / 2
        k = int(_seam_factor(*bends, low, high, UPSAMPLED_SMALL_SHARE, 2, *chunks, 1))
        if k > 1:
            return k
    return 1
