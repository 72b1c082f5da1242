"""Adaptive plane fit of inverse depth: the estimator for real sensor depth (ours, not in the paper).

Why inverse depth. A plane n . P = d seen through a pinhole camera has an
inverse depth w = 1/z that is exactly affine in the pixel (u, v)::

    w(u, v) = (n_x (u - c_x) / f_x + n_y (v - c_y) / f_y + n_z) / d                  (1)

so the slopes g_u = dw/du, g_v = dw/dv and the value w at a pixel give its
normal without approximation (the relation 3F2N builds on)::

    n = -(f_x g_u, f_y g_v, w - g_u (u - c_x) - g_v (v - c_y)) / norm                (2)

The minus sign makes n face the camera for any fit: n . (x, y, 1) = -w / norm < 0.
Fitting (1) by least squares to the valid pixels of a window therefore gives
exact normals on planes at any orientation and distance, whatever the window
size, with or without holes; and the residual is measured along the ray, as
depth noise is (for stereo and structured light, whose noise is uniform in
disparity ~ w, it is exactly the right norm).

Constant cost per pixel. The ten moment sums of the fit (count, u, v, uu, uv,
vv, w, uw, vw, ww over the window's valid pixels) come from integral images
(as PCL's IntegralImageNormalEstimation does for the covariance), so a window
of any size costs four look-ups per moment.

Support chosen from the data. Sensor depth is quantised and noisy at a level
that depends on the sensor and on the distance. The frame's own noise is
measured first (:func:`noise_profile`): the second differences of w vanish on
planes (w is affine there), so their robust RMS (sigma-clipped at 5 sigma, which
drops depth discontinuities; at strides 1, 2 and 4, which separates noise from
curvature) in bins of depth gives the noise sigma_z(z). In units of the distance
between neighbouring pixels' points (z / f) this is rho(z) = sigma_z f / z. A
window of radius r estimates a slope with standard deviation
rho * sqrt(3) / ((2r + 1) sqrt(r (r + 1))) ~ rho / r^2 (radians). Each pixel
starts from the radius ceil(ALPHA sqrt(rho)) (on a x2 ladder of radii), and
the widening below makes it as wide as the data allow. Where the window holds
too few valid pixels (sparse LiDAR depth, holes) it grows (x1.5, up to
``max_window``) until its n valid pixels pin the slope at least half as well
as the full window would (2 n r (r + 1) at least (2 r_0 + 1)^2 r_0 (r_0 + 1)),
and hold at least ``MIN_POINTS``.

Edge awareness. A window across a depth discontinuity or a crease fits badly:
its residual per degree of freedom exceeds the noise level (kappa sigma_w)^2.
Such a pixel is refitted on the four quadrant windows of the same size (shifted
by r diagonally, each with the pixel at a corner), and keeps the fit with the
smallest residual per degree of freedom (the Kuwahara principle) among those
whose plane passes through the pixel itself (within kappa times the fit's
residual or the noise): a pixel near an edge takes its normal from its own
side, and a thin part seen against a far background does not take the
background's plane. Residuals within ``TIE`` of each other tie (and so do
residuals far below the noise, which are rounding), and ties go to the first
window (the centred one, then the quadrants in a fixed order), so that the
choice does not depend on the unit of depth. A window that fits within the noise is tried twice as
wide, up to ``N_WIDEN`` times, and kept while it still fits: planes get wide
windows, curved surfaces and edges keep small ones. A window whose valid pixels
lie on a line (they fix no plane), or with fewer than 4 of them, gives no fit;
a pixel without any fit gets the fill value.

Every other row and column. Windows of a few pixels' radius or more, centred a pixel apart, share most of
their pixels, and so their planes. By default (``stride`` 2) the windows are fitted on the pixels of the even
rows and even columns only, a quarter of them. Every other pixel takes the planes of the fitted pixels next
to it (its 3x3 neighbourhood: the two on its left and right, or above and below, or the four diagonal
ones): the mean of those that predict its own w within the noise test's limit (on a smooth surface, the
plane interpolated to the pixel), or, where none does, the one that predicts it closest (at an edge, its own
side's); where none of them has a plane, the closest of the fitted pixels of its 5x5 neighbourhood. Depth
with too many pixels that no fitted pixel reaches (LiDAR scanlines: :func:`choose_stride`) is fitted at
every pixel (``stride`` 1, also on request).

Not local: the noise profile is a statistic of the whole frame, so masking a
region (or a hole) changes the samples it is measured from and can move the
chosen windows, and so normals, far from it (on a 3F2N frame in millimetres, a
10x10 hole moved 242 normals more than 10 pixels away). The normals do not
depend on the unit of depth.
"""

from __future__ import annotations

import functools
import math
import threading
import time
from typing import NamedTuple

import numpy as np

from .._aot import ahead_of_time
from .._bands import Offers, Part, whole
from .._config import njit, pixel, select

# The constants shared with surfnorm.torch._adaptive, with their meaning: surfnorm._constants (loads no Numba).
from .._constants import (
    _CLIP_ROUNDS,
    _CLIP_SIGMAS,
    _FOURTH_RMS,
    _MAX_GAP,
    _MAX_SPREAD,
    _NOISE_SAMPLES,
    _SMOOTH_GAUSS,
    _SMOOTH_SAMPLES,
    _TABLE,
    ALPHA,
    KAPPA,
    MAX_UNREACHED,
    MAX_WINDOW,
    MIN_POINTS,
    MIN_SAMPLES,
    N_BINS,
    N_WIDEN,
    RADII,
    RHO_FLOOR,
    SHIFTS,
    SMOOTH_SHARE,
    TIE,
)
from ._spare import Spares
from .uncertainty import MISFIT_GAIN, MISFIT_SIGNIFICANCE, angle_variance, fit_variance, noise_gain

__all__ = [
    "adaptive_fit",
    "noise_profile",
    "NoiseProfile",
    "radius_table",
    "release",
    "choose_stride",
    "ALPHA",
    "KAPPA",
    "RHO_FLOOR",
    "MAX_WINDOW",
]

_N_MOMENTS = 10


# --- noise profile -------------------------------------------------------------------------------


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
@njit
def _second_differences(z, valid, f, zmin, zmax, nbins, step, xs, bins, jumps):
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
    ``jumps``. Returns (how many samples, changed, how many jumps).
    """
    H, W = z.shape
    k = 0
    changed = 0
    n_jumps = 0
    scale = f / math.sqrt(6.0)
    lo = math.log(zmin)
    span = math.log(zmax) - lo
    for v in range(0, H, step):
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
                    k += 1
                    if a == 1:
                        c, n_jumps = _terrace(z[v - 1, u], zb, z[v + 1, u], f, jumps, n_jumps)
                        changed += c
                    break
    return k, changed, n_jumps


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
def _by_bin(xs, bins, nbins):
    """The columns of ``xs`` grouped by bin, in their order within each bin, and each bin's start (nbins + 1)."""
    starts = np.zeros(nbins + 1, np.int64)
    for b in bins:
        starts[b + 1] += 1
    for b in range(nbins):
        starts[b + 1] += starts[b]
    at = starts[:-1].copy()
    grouped = np.empty_like(xs)
    for j in range(bins.shape[0]):
        k = at[bins[j]]
        at[bins[j]] = k + 1
        for i in range(xs.shape[0]):
            grouped[i, k] = xs[i, j]
    return grouped, starts


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
def _quiet(xs, share, gauss, fourth_rms, most):
    """:attr:`NoiseProfile.smooth` from the samples ``xs`` (3, n > 0), every s-th of them (s = ceil(n / ``most``)):
    the geometric mean of two estimates of the noise at strides 2 and 4, each the value at rank
    floor(share (m - 1)) of its m magnitudes sorted, over ``gauss``: of |x_2|, which curvature raises (a sphere
    filling the frame) but fine detail does not reach where the scene is smooth; and of |x_4 - 4 x_2| /
    ``fourth_rms``, a fourth difference in which curvature cancels but fine detail does not (the foliage of a
    tree). Noise raises both; either kind of geometry only one. White noise of RMS rho reads rho in each, so in
    their mean. Without the GIL."""
    n = xs.shape[1]
    s = (n + most - 1) // most
    m = (n + s - 1) // s
    second = np.empty(m)
    fourth = np.empty(m)
    for i in range(m):
        j = i * s
        second[i] = abs(xs[1, j])
        fourth[i] = abs(xs[2, j] - 4.0 * xs[1, j]) / fourth_rms
    k = int(share * (m - 1))
    return math.sqrt(_select(second, k) * _select(fourth, k)) / gauss


@ahead_of_time
@njit
def _median_in_place(a):
    """np.median(a) (the same value: the mean of the two middle values when a.size is even), reordering ``a``."""
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
def _median_abs(x):
    """np.median(np.abs(x)) (the same value), without holding the GIL: another band's thread runs beside it."""
    return np.median(np.abs(x))


def _samples(z, valid, f):
    """(zmin, zmax, the second differences (3, n), their depth bins (n), the terraces' jump heights, how many
    stencils changed depth): see :func:`_second_differences`."""
    zmin, zmax = depth_range(z, valid)
    if not zmax > 0.0:
        return zmin, zmax, np.empty((3, 0)), np.empty(0, np.int64), np.empty(0), 0
    step = max(1, int(round(math.sqrt(z.size / _NOISE_SAMPLES))))
    size = 2 * ((z.shape[0] + step - 1) // step) * ((z.shape[1] + step - 1) // step)
    xs = np.empty((3, size))
    bins = np.empty(size, np.int64)
    jumps = np.empty(size)
    n, changed, n_jumps = _second_differences(z, valid, float(f), zmin, zmax, N_BINS, step, xs, bins, jumps)
    return zmin, zmax, xs[:, :n], bins[:n], jumps[:n_jumps], changed


class NoiseProfile(NamedTuple):
    """The frame's noise, measured by :func:`noise_profile`.

    depths, rho : ndarray
        rho (units of the point spacing z / f) at the centres of log-spaced depth bins.
    floor : float
        The median |second difference of inverse depth| at stride 1 in the same units, over
        0.6745 (white Gaussian noise of rho gives rho). Depth rendered without noise has most
        second differences at 0 (smooth surfaces between edges) however detailed the scene:
        the 12 3F2N sample frames give 0.00-0.08. Sensor depth has a floor: 0.3-4 on the
        PrimeSense, Kinect v1 (registered), RealSense D435 and LiDAR frames we measured; raw
        structured light and stereo matchers often 0 (their depth lies on flat terraces: see
        ``terraced``). NaN when too few pixels have valid neighbours.
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
        The clipped mean square of the second differences at stride 2 over that at stride 1: 1 for noise
        independent from pixel to pixel, more where neighbours' errors go together (a matcher's window, a
        spatial filter: 1.3 for the simulated raw Kinect v1, about 3 for SGBM, 11 for error smooth over 2
        pixels), where a fitted slope moves more than its residual says. Curvature raises it too. 1 without
        enough samples.
    """

    depths: np.ndarray
    rho: np.ndarray
    floor: float
    terraced: float = 0.0
    step: float = 0.0
    smooth: float = 0.0
    correlation: float = 1.0


def _correlation(rms, starts, min_samples):
    """:attr:`NoiseProfile.correlation` from the clipped RMS ``rms`` (3, nbins) of the second differences at
    strides 1, 2 and 4 and the bins' ``starts``: the mean square at stride 2 over that at stride 1, over the bins
    with at least ``min_samples`` samples (weighted by their samples); 1 without any."""
    num = den = 0.0
    for b in range(rms.shape[1]):
        n = starts[b + 1] - starts[b]
        if n >= min_samples and rms[0, b] > 0.0:
            num += n * rms[1, b] * rms[1, b] / (rms[0, b] * rms[0, b])
            den += n
    return num / den if den > 0.0 else 1.0


def terrace_statistics(jumps: np.ndarray, changed: int) -> tuple[float, float]:
    """(terraced, step) of :class:`NoiseProfile` from the jump heights and the count of stencils that changed
    depth (:func:`_second_differences`): the share of jumps among them (0 when fewer than ``MIN_SAMPLES``
    changed), and the median height (0 without jumps)."""
    if changed < MIN_SAMPLES or jumps.size == 0:
        return 0.0, 0.0
    return jumps.size / changed, float(_median_in_place(jumps))


def noise_profile(z: np.ndarray, valid: np.ndarray, f: float, offers=None) -> NoiseProfile:
    """The frame's noise against depth (see :class:`NoiseProfile`).

    In each depth bin (log-spaced between the nearest and farthest valid depth),
    the sigma-clipped mean squares v_1, v_2, v_4 of the second differences of
    inverse depth at strides 1, 2 and 4 (see :func:`_second_differences`)
    separate noise from shape: white noise adds rho^2 to each, smooth curvature
    adds c, 16 c and 256 c, so rho^2 = (16 v_1 - v_2) / 15 (the curvature of
    clean depth is not taken for noise). Noise correlated between neighbours
    (stereo matchers aggregate over windows) shows less at stride 1 than at
    stride 2 while it still moves a fitted slope, so rho is the larger of the
    stride-1 estimate and (16 v_2 - v_4) / 15. Sampled on every step-th row and column (about
    ``_NOISE_SAMPLES`` pixels). Bins with fewer than ``MIN_SAMPLES`` samples
    take the value of the nearest bins that have enough; with none, rho is 0
    (3x3 windows).

    ``offers``: a :class:`surfnorm._bands.Offers` of the bands waiting for this profile, one of which may take
    the floor's median while this thread sums the bins (the same value either way).
    """
    zmin, zmax, xs, bins, jumps, changed = _samples(z, valid, f)
    n = xs.shape[1]
    if n < MIN_SAMPLES:
        return NoiseProfile(np.array([zmin if zmax > 0.0 else 1.0]), np.zeros(1), float("nan"))
    # The floor (a median), the smooth noise and the terraces do not depend on the rest: another band's thread may
    # take them (``offers``, see surfnorm._bands.Offers) while this one sums the bins.
    median = Part(lambda: _median_abs(xs[0]))
    smooth = Part(lambda: _quiet(xs, SMOOTH_SHARE, _SMOOTH_GAUSS, _FOURTH_RMS, _SMOOTH_SAMPLES))
    terraces = Part(lambda: terrace_statistics(jumps, changed))
    if offers is not None:
        for part in (median, smooth, terraces):
            offers.offer(part)
    ms = np.empty((3, N_BINS))
    grouped, starts = _by_bin(xs, bins, N_BINS)
    _clipped_rms(grouped, starts, _CLIP_ROUNDS, _CLIP_SIGMAS, ms)
    centres, rho = _by_depth(ms, starts, zmin, zmax, MIN_SAMPLES)
    terraced, step = terraces.result()
    correlation = _correlation(ms, starts, MIN_SAMPLES)
    return NoiseProfile(centres, rho, median.result() / 0.6745, terraced, step, smooth.result(), correlation)


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


@ahead_of_time
@njit
def _unreached(valid):
    """(pixels that no valid fitted pixel reaches, valid pixels that are not fitted): see :func:`choose_stride`.

    The valid fitted pixels (even row and column) widened to their 5x5 neighbourhoods, separably: along each
    fitted row (``across``: any within two columns), then down the columns (the fitted rows within two rows of
    a row). Whole rows of bytes at a time, without branches, so that the loops vectorise.
    """
    H, W = valid.shape
    n_rows = (H + 1) // 2
    even = np.zeros(W + 4, np.uint8)  # even[u + 2]: column u is a fitted one; two zeros either side
    even[2 : W + 2 : 2] = 1
    odd = np.ones(W, np.uint8) - even[2 : W + 2]
    fitted = np.zeros(W + 4, np.uint8)
    across = np.zeros((n_rows + 2, W), np.uint8)  # fitted row i at i + 1, with a row of zeros above and below
    for i in range(n_rows):
        row = valid[2 * i]
        for u in range(W):
            fitted[u + 2] = row[u] & even[u + 2]
        out = across[i + 1]
        for u in range(W):
            out[u] = fitted[u] | fitted[u + 1] | fitted[u + 2] | fitted[u + 3] | fitted[u + 4]
    unreached = 0
    others = 0
    for v in range(H):
        row = valid[v]
        i = v // 2
        if v % 2 == 0:  # the pixels of odd columns; fitted rows v - 2, v, v + 2
            up, same, down = across[i], across[i + 1], across[i + 2]
            for u in range(W):
                other = row[u] & odd[u]
                others += other
                unreached += other & ~(up[u] | same[u] | down[u]) & 1
        else:  # every pixel; fitted rows v - 1, v + 1
            up, down = across[i + 1], across[i + 2]
            for u in range(W):
                other = row[u]
                others += other
                unreached += other & ~(up[u] | down[u]) & 1
    return unreached, others


@ahead_of_time
@njit
def _band_weights(valid, stride, factors):
    """Each row's cost on several threads (see :func:`adaptive_fit`): a quarter of the width, plus its valid
    pixels over ``stride`` on the fitted rows (every ``stride``-th), times its ``factors`` (:class:`Balance`)."""
    H, W = valid.shape
    weights = np.empty(H)
    for v in range(H):
        n = 0
        if v % stride == 0:
            row = valid[v]
            for u in range(W):
                n += row[u]
        weights[v] = (0.25 * W + n / stride) * factors[v]
    return weights


@ahead_of_time
@njit
def _balanced(factors, weights, edges, spent):
    """:meth:`Balance.learn`'s arithmetic, in place on ``factors``: band k (rows edges[k] .. edges[k + 1] - 1)
    took ``spent[k]`` seconds."""
    total = spent.sum() / max(weights.sum(), 1e-300)
    for k in range(spent.shape[0]):
        w = weights[edges[k] : edges[k + 1]].sum()
        if w > 0.0 and spent[k] > 0.0:
            step = math.sqrt(spent[k] / w / total)
            for v in range(edges[k], edges[k + 1]):
                factors[v] *= step
    mean = factors.mean()
    for v in range(factors.shape[0]):
        factors[v] = min(max(factors[v] / mean, 0.25), 4.0)


def choose_stride(valid: np.ndarray) -> int:
    """The default ``stride``: 2, unless more than MAX_UNREACHED of the valid pixels that are not fitted (not
    on an even row and column) have no valid fitted pixel in their 5x5 neighbourhood (sparse depth: LiDAR),
    then 1."""
    H, W = valid.shape
    if H < 2 or W < 2:
        return 1
    unreached, others = _unreached(np.ascontiguousarray(valid, dtype=np.bool_))
    return 2 if unreached <= MAX_UNREACHED * max(others, 1) else 1


#: Rings of integral rows kept for the next frame (a 640-pixel row's takes 3.2 MB: mapping its pages in
#: afresh cost about 1 ms a frame); :func:`release` lets them go.
_rings = Spares(64 << 20)


def release() -> None:
    """Free the rings of integral rows kept for the next frame, and forget the bands' balance."""
    _rings.release()
    _balance.forget()


class Balance:
    """Per-row cost factors of one frame on several threads, learnt from the time its bands took, by frame size.

    The band weights (valid pixels per row) miss where the work really lies (planes that widen their
    windows, edges that try the quadrants, the noise measured by the first band, the rows a later band makes
    before its own): at 640x480 the band that finished first waited 0.3-0.5 ms for the other. After a frame,
    each band's rows are weighed by how long the band took for its weight against the mean (square root of
    the ratio: a damped step, factors kept within 1/4 and 4), so the next frame of the same size (a camera's
    stream) splits closer to equal times. The bands give the same bits whatever the split (see
    :mod:`surfnorm._bands`): only the time moves. Kept for the last ``KEEP`` frame sizes.
    """

    KEEP = 8

    def __init__(self):
        self._lock = threading.Lock()
        self._factors: dict = {}

    def factors(self, key):
        with self._lock:
            return self._factors.get(key)

    def learn(self, key, weights: np.ndarray, spent: list) -> None:
        """From the row ``weights`` the bands were split by (factors included) and ``spent``: (first row, end row,
        seconds from the start of the bands to the band's end) of each band."""
        if len(spent) < 2:
            return
        old = self.factors(key)
        factors = np.ones(weights.shape[0]) if old is None else old.copy()
        spent = sorted(spent)
        edges = np.array([v0 for v0, _, _ in spent] + [spent[-1][1]], np.int64)
        _balanced(factors, weights, edges, np.array([t for _, _, t in spent]))
        with self._lock:
            self._factors.pop(key, None)
            if len(self._factors) >= self.KEEP:
                self._factors.pop(next(iter(self._factors)))
            self._factors[key] = factors

    def forget(self) -> None:
        with self._lock:
            self._factors.clear()


_balance = Balance()


def radius_table(
    depths: np.ndarray, rho: np.ndarray, *, alpha: float = ALPHA, window=None, max_window: int = MAX_WINDOW
) -> tuple[float, float, np.ndarray, np.ndarray]:
    """A look-up table from depth to the window radius and the noise rho.

    Returns (z0, inv_step, radius, rho): entry int((z - z0) * inv_step), clipped,
    holds the radius r = ceil(alpha sqrt(rho)) (or ``(window - 1) / 2``) and rho
    interpolated in log depth.
    """
    r_max = (max_window - 1) // 2
    fixed = -1 if window is None else (window - 1) // 2
    return _radius_table(
        np.asarray(depths, np.float64), np.asarray(rho, np.float64), float(alpha), fixed, r_max, np.asarray(RADII)
    )


@ahead_of_time
@njit
def _radius_table(depths, rho, alpha, fixed, r_max, ladder):
    """:func:`radius_table`, ``fixed``: the radius everywhere, or -1 (from rho); ``ladder``: RADII."""
    z0, z1 = depths[0], depths[-1]
    n = _TABLE
    if z1 > z0:
        step = (z1 - z0) / (n - 1)  # np.linspace's arithmetic
        zs = np.empty(n)
        for i in range(n):
            zs[i] = i * step + z0
        zs[n - 1] = z1
        rho_t = np.interp(np.log(zs), np.log(depths), rho)
        inv_step = (n - 1) / (z1 - z0)
    else:
        rho_t = np.full(n, rho[0])
        inv_step = 0.0
    r_t = np.empty(n, np.int64)
    for i in range(n):
        if fixed >= 0:
            r_t[i] = fixed
        else:
            r_t[i] = _allowed_radius(min(max(np.ceil(alpha * math.sqrt(rho_t[i])), 1.0), float(r_max)), r_max, ladder)
    return z0, inv_step, r_t, rho_t


@pixel
def _allowed_radius(r, r_max, ladder):
    """The smallest radius of ``ladder`` (RADII) that is at least r, at most r_max."""
    for k in range(ladder.shape[0]):
        if ladder[k] >= r:
            return min(ladder[k], r_max)
    return r_max


def allowed_radii(r: np.ndarray, r_max: int) -> np.ndarray:
    """For each r, the smallest radius of ``RADII`` that is at least r, at most r_max (int64): :func:`_allowed_radius`
    element by element (for the small tables of :func:`_tables`)."""
    ladder = np.asarray(RADII)
    r = np.asarray(r, np.float64)
    return np.array([_allowed_radius(x, r_max, ladder) for x in r.ravel()], np.int64).reshape(r.shape)


@functools.lru_cache(maxsize=None)
def _tables(r_max: int) -> tuple[np.ndarray, np.ndarray]:
    r = np.arange(r_max + 1)
    widen = np.where(r > 0, allowed_radii(2 * r, r_max), 1).astype(np.int64)
    grow = np.where(r > 0, allowed_radii(np.ceil(1.5 * r), r_max), 1).astype(np.int64)
    widen.flags.writeable = grow.flags.writeable = False  # cached: shared by every call
    return widen, grow


def widen_table(r_max: int) -> np.ndarray:
    """widen[r]: the radius a passing window of radius r is tried at next (x2)."""
    return _tables(r_max)[0]


def growth_table(r_max: int) -> np.ndarray:
    """grow[r]: the radius a window of radius r grows to when too few of its pixels are valid (x1.5)."""
    return _tables(r_max)[1]


# --- the fit ---------------------------------------------------------------------------------------
#
# Integral rows live in a ring of 4 r_max + 3 rows, channel-major: ring[slot[i], c, pos[u]] is moment c of
# integral row i at column u. A row of the image needs integral rows v - 2 r .. v + 2 r + 1 (the centred
# windows and the shifted ones), so the moments stay in cache instead of a full-size image. Each integral row
# is made from column sums kept beside the ring (:func:`integral_row`), so a band that starts lower down
# sums the columns of the rows above it and makes only the integral rows that it reads (:func:`make_rows`).
#
# ``pos`` (:func:`integral_positions`) places the columns: in order for ``stride`` 1; for ``stride`` 2 the even
# columns first, then the odd ones. A window centred on an even column u has one edge column of each
# parity (u - r and u + r + 1), so along a row of fitted pixels (u = 0, 2, 4, ...) both edges move one
# place at a time: the row's window sums read two contiguous runs (see :func:`box_row`).


@njit
def integral_positions(W, stride):
    """pos[u] for the integral columns u = 0 .. W (see above)."""
    pos = np.arange(W + 1, dtype=np.int64)
    if stride == 2:
        n_even = W // 2 + 1
        pos[0::2] = np.arange(n_even)
        pos[1::2] = n_even + np.arange((W + 1) // 2)
    return pos


#: Column sums kept beside the ring, per column u: over the valid pixels of the image rows made so far, of
#: (1, v', v'v', w, v'w, ww). Integral row i is the running sum along the row of those after row i - 1 with the
#: u' factors applied (:func:`integral_row`), so a band that starts further down sums its columns only
#: (:func:`column_row`) until it reaches the rows that it reads.
_N_COLUMNS = 6


@njit(noalias=True, _nrt=False)
def column_row(z_row, valid_row, y, w_row, cols):
    """Add image row ``z_row`` (at centred ordinate ``y``) to the column sums ``cols`` (_N_COLUMNS, W); ``w_row``
    is scratch (W,). An invalid pixel adds zeros (the same bits as adding nothing): no branch, it vectorises."""
    W = z_row.shape[0]
    for u in range(W):
        w_row[u] = select(valid_row[u], 1.0 / z_row[u], 0.0)
    yy = y * y
    for u in range(W):
        m = select(valid_row[u], 1.0, 0.0)
        w = w_row[u]
        cols[0, u] += m
        cols[1, u] += y * m
        cols[2, u] += yy * m
        cols[3, u] += w
        cols[4, u] += y * w
        cols[5, u] += w * w


@njit(noalias=True, _nrt=False)
def running_sums(W, cols, pos, row):
    """The running sums along the row of the column sums ``cols`` into the integral row ``row`` (column u at
    ``pos[u + 1]``; see :func:`integral_row`)."""
    # two loops, the coordinate moments and then those of w, each on its channels' rows: ten running sums in
    # one, on the 2-d arrays, held more values than the registers do (measured 20 % slower)
    n_col, nv_col, nvv_col = cols[0], cols[1], cols[2]
    r0, r1, r2, r3, r4, r5 = row[0], row[1], row[2], row[3], row[4], row[5]
    s0 = s1 = s2 = s3 = s4 = s5 = 0.0
    for u in range(W):
        x = u - 0.5 * W
        n = n_col[u]
        n_v = nv_col[u]
        s0 += n
        s1 += x * n
        s2 += n_v
        s3 += x * x * n
        s4 += x * n_v
        s5 += nvv_col[u]
        j = pos[u + 1]
        r0[j] = s0
        r1[j] = s1
        r2[j] = s2
        r3[j] = s3
        r4[j] = s4
        r5[j] = s5
    w_col, vw_col, ww_col = cols[3], cols[4], cols[5]
    r6, r7, r8, r9 = row[6], row[7], row[8], row[9]
    s6 = s7 = s8 = s9 = 0.0
    for u in range(W):
        x = u - 0.5 * W
        w = w_col[u]
        s6 += w
        s7 += x * w
        s8 += vw_col[u]
        s9 += ww_col[u]
        j = pos[u + 1]
        r6[j] = s6
        r7[j] = s7
        r8[j] = s8
        r9[j] = s9


@njit(noalias=True, _nrt=False)
def integral_row(z_row, valid_row, y, pos, w_row, cols, row):
    """Integral row i, adding image row i - 1 (``z_row``, ``valid_row``, at centred ordinate ``y``) to the column
    sums ``cols`` (:func:`column_row`) first; column u at ``pos[u]``; ``w_row`` is scratch (W,).

    Integral row i holds, per column u (0..W), the sums over the valid pixels of image rows < i
    and columns < u of (1, u', v', u'u', u'v', v'v', w, u'w, v'w, ww), with u' = u - W/2,
    v' = v - H/2 (centred coordinates keep the sums small) and w = 1/z: the running sums along the row of
    the column sums, those of u' and u'u' as u' times the column's sums (u' is the same down a column).
    The coordinate moments are sums of integers and half-integers, exact in any order.
    """
    W = z_row.shape[0]
    column_row(z_row, valid_row, y, w_row, cols)
    for c in range(_N_MOMENTS):
        row[c, pos[0]] = 0.0
    running_sums(W, cols, pos, row)


@pixel
def window_sums(ring, slot, pos, H, W, v, u, r, channels, m):
    """Moment sums ``channels`` of the window rows v-r..v+r, columns u-r..u+r (clipped to the image) into
    m[c] for c in ``channels``."""
    v0 = slot[min(max(v - r, 0), H)]
    v1 = slot[min(max(v + r + 1, 0), H)]
    u0 = pos[min(max(u - r, 0), W)]
    u1 = pos[min(max(u + r + 1, 0), W)]
    for c in channels:
        m[c] = ring[v1, c, u1] - ring[v0, c, u1] - ring[v1, c, u0] + ring[v0, c, u0]


#: Channels of a window's moments: the count and the four sums with w, summed by :func:`box_row` for
#: whole rows; the five coordinate sums (u', v', u'u', u'v', v'v') only where a window is not the full
#: square (:func:`coordinate_sums`), since :func:`affine_fit` replaces them by their known values there.
_BOXED = (0, 6, 7, 8, 9)
_COORDS = (1, 2, 3, 4, 5)
#: The count, and the other channels of ``_BOXED``: the edge test reads the count of a window first.
_COUNT = (0,)
_W_SUMS = (6, 7, 8, 9)


@njit(noalias=True, _nrt=False)
def box_row(top, bottom, r, stride, pos, pick, first, src, dst):
    """Window sums at radius r of the count and the w moments (``_BOXED``) of the fitted pixels of a row
    (columns u = stride i): dst[j, i] = sums of moment _BOXED[j] over columns u - r .. u + r (clipped)
    between integral rows ``top`` and ``bottom`` where ``pick``; elsewhere src[j, i], or anything when
    ``first``. ``src`` and ``dst`` are distinct arrays: a store that keeps the old value in place compiles
    to a masked store, microcoded and slow on some processors.

    Each sum is (bottom - top at the right edge) - (bottom - top at the left edge). Away from the image's
    borders both edges move one place in ``pos`` per fitted pixel: two contiguous runs.
    """
    W = pos.shape[0] - 1
    n_fit = dst.shape[1]
    lo = min((r + stride - 1) // stride, n_fit)  # the first pixel whose window is not clipped on the left
    hi = max(min((W - r - 1) // stride + 1, n_fit), lo)  # ... and past the last one not clipped on the right
    for j in range(len(_BOXED)):
        c = _BOXED[j]
        t = top[c]
        b = bottom[c]
        s = src[j]
        d = dst[j]
        for i in range(lo):  # left border: clipped windows
            u1 = pos[min(stride * i + r + 1, W)]
            d[i] = select(pick[i], (b[u1] - t[u1]) - (b[0] - t[0]), s[i])
        if hi > lo:  # interior
            p0 = pos[stride * lo - r]
            p1 = pos[stride * lo + r + 1]
            b0 = b[p0:]
            t0 = t[p0:]
            b1 = b[p1:]
            t1 = t[p1:]
            do = d[lo:]
            if first:
                for i in range(hi - lo):
                    do[i] = (b1[i] - t1[i]) - (b0[i] - t0[i])
            else:
                p = pick[lo:]
                so = s[lo:]
                for i in range(hi - lo):
                    do[i] = select(p[i], (b1[i] - t1[i]) - (b0[i] - t0[i]), so[i])
        e = pos[W]
        for i in range(hi, n_fit):  # right border
            u0 = pos[max(stride * i - r, 0)]
            d[i] = select(pick[i], (b[e] - t[e]) - (b[u0] - t[u0]), s[i])


#: A row's window sums go pixel by pixel (:func:`box_row_sparse`) where fewer than one in SPARSE of its fitted
#: pixels take them (sparse depth: LiDAR rows, the radii that few pixels grow to), else in runs (:func:`box_row`).
SPARSE = 8


@njit(noalias=True, _nrt=False)
def box_row_sparse(top, bottom, r, stride, pos, pick, dst):
    """:func:`box_row` pixel by pixel, in place: dst[j, i] for the pixels where ``pick`` only (the same sums)."""
    W = pos.shape[0] - 1
    for i in range(dst.shape[1]):
        if pick[i]:
            u = stride * i
            u0 = pos[max(u - r, 0)]
            u1 = pos[min(u + r + 1, W)]
            for j in range(len(_BOXED)):
                c = _BOXED[j]
                dst[j, i] = (bottom[c, u1] - top[c, u1]) - (bottom[c, u0] - top[c, u0])


@njit(noalias=True, _nrt=False)
def coordinate_sums(top, bottom, r, stride, pos, pick, counts, coords):
    """The coordinate sums (``_COORDS``) at radius r into coords[j, i] (columns u = stride i), for the pixels
    where ``pick`` whose window is not the full (2r + 1)^2 square (``counts``, from :func:`box_row`)."""
    W = pos.shape[0] - 1
    full = (2 * r + 1) * (2 * r + 1)
    for i in range(coords.shape[1]):
        if pick[i] and counts[i] != full:
            u = stride * i
            u0 = pos[max(u - r, 0)]
            u1 = pos[min(u + r + 1, W)]
            for j in range(len(_COORDS)):
                c = _COORDS[j]
                coords[j, i] = (bottom[c, u1] - top[c, u1]) - (bottom[c, u0] - top[c, u0])


@pixel
def picked_sums(ring, slot, H, v, r, stride, pos, pick, count, first, cur, spare, coords):
    """The window sums at radius r of the ``count`` pixels of row v where ``pick``: the count and w moments into
    ``cur`` (the others keep theirs), or into ``spare`` with the others copied (:func:`box_row`, where many take
    them), and the coordinate moments into ``coords``. Returns (cur, spare), swapped in the second case."""
    top = ring[slot[max(v - r, 0)]]
    bottom = ring[slot[min(v + r + 1, H)]]
    if SPARSE * count < cur.shape[1]:
        box_row_sparse(top, bottom, r, stride, pos, pick, cur)
    else:
        cur, spare = spare, cur
        box_row(top, bottom, r, stride, pos, pick, first, spare, cur)
    coordinate_sums(top, bottom, r, stride, pos, pick, cur[0], coords)
    return cur, spare


@pixel
def affine_fit(n, s_u, s_v, s_uu, s_uv, s_vv, s_w, s_uw, s_vw, s_ww, r, x, y):
    """Least-squares w = a + g_u (u' - x) + g_v (v' - y) over a window centred on (x, y), from its
    moment sums (count n; sums of u', v', u'u', u'v', v'v', w, u'w, v'w, ww).

    Returns (a, g_u, g_v, rss, dof): the residual sum of squares and its degrees of freedom n - 3,
    or dof = 0 where the fit is undetermined (fewer than 4 points, or points on a line:
    1 - corr(u, v)^2 below 1e-6). A window that is the whole (2r+1)^2 square (every pixel valid,
    none clipped) has known coordinate moments: mean (x, y), sum of squared offsets
    (2r+1)^2 r (r+1) / 3 per axis, no cross term. Branch-free (selects only), so that the row loop
    calling it vectorises.
    """
    k = 2 * r + 1
    full = n == k * k
    inv_n = 1.0 / max(n, 1.0)
    mw = s_w * inv_n
    mu = select(full, x, s_u * inv_n)
    mv = select(full, y, s_v * inv_n)
    c_full = n * (r * (r + 1)) * (1.0 / 3.0)
    cuu = select(full, c_full, s_uu - s_u * mu)
    cuv = select(full, 0.0, s_uv - s_u * mv)
    cvv = select(full, c_full, s_vv - s_v * mv)
    cuw = s_uw - n * mu * mw
    cvw = s_vw - n * mv * mw
    cww = s_ww - s_w * mw
    det = cuu * cvv - cuv * cuv
    ok = (n >= 4.0) & (cuu > 0.0) & (cvv > 0.0) & (det > 1e-6 * cuu * cvv)
    inv_det = 1.0 / select(ok, det, 1.0)
    g_u = (cvv * cuw - cuv * cvw) * inv_det
    g_v = (cuu * cvw - cuv * cuw) * inv_det
    a = mw + g_u * (x - mu) + g_v * (y - mv)
    rss = max(cww - g_u * cuw - g_v * cvw, 0.0)
    return a, g_u, g_v, rss, select(ok, n - 3.0, 0.0)


@pixel
def fit_at(m_box, m_coords, r_row, x_row, y, u):
    """:func:`affine_fit` of pixel u of a row from the row's window moments (see :func:`fit_row`)."""
    return affine_fit(
        m_box[0, u],
        m_coords[0, u],
        m_coords[1, u],
        m_coords[2, u],
        m_coords[3, u],
        m_coords[4, u],
        m_box[1, u],
        m_box[2, u],
        m_box[3, u],
        m_box[4, u],
        r_row[u],
        x_row[u],
        y,
    )


@njit(noalias=True, _nrt=False)
def fit_row(m_box, m_coords, r_row, x_row, y, g_u, g_v, a, rss, dof):
    """:func:`affine_fit` for every pixel of row ``y``, from the row's window moments (``m_box``: the
    ``_BOXED`` ones, ``m_coords``: the ``_COORDS`` ones), radii ``r_row`` and centred abscissae ``x_row``
    (floats, holding integers and half-integers exactly: int64 operands would not vectorise)."""
    W = m_box.shape[1]
    for u in range(W):
        a[u], g_u[u], g_v[u], rss[u], dof[u] = fit_at(m_box, m_coords, r_row, x_row, y, u)


@njit(noalias=True, _nrt=False)
def widened_row(
    m_box, m_coords, r2_f, x_row, y, tried, limit, r2, g_u, g_v, a, rss, dof, r, g_u3, g_v3, a3, rss3, dof3, r3, kept
):
    """The widened fits of a row (:func:`affine_fit` of its window moments at radii ``r2_f``, as :func:`fit_row`)
    where they were ``tried`` and still pass the noise test, the current ones (g_u ...) elsewhere, into g_u3 ...
    (distinct arrays: see :func:`box_row`); ``kept``: where the widened fit was kept."""
    for u in range(tried.shape[0]):
        a2, g_u2, g_v2, rss2, dof2 = fit_at(m_box, m_coords, r2_f, x_row, y, u)
        ok = tried[u] & (dof2 > 0.0) & (rss2 <= limit[u] * dof2)
        g_u3[u] = select(ok, g_u2, g_u[u])
        g_v3[u] = select(ok, g_v2, g_v[u])
        a3[u] = select(ok, a2, a[u])
        rss3[u] = select(ok, rss2, rss[u])
        dof3[u] = select(ok, dof2, dof[u])
        r3[u] = select(ok, r2[u], r[u])
        kept[u] = ok


@njit(noalias=True, _nrt=False)
def normal_row(z_row, valid_row, v, g_u, g_v, a, dof, fx, fy, cx, cy, fill, out_row):
    """Eq. (2): the unit normal facing the camera from each pixel's fit; ``fill`` without one."""
    W = z_row.shape[0]
    for u in range(W):
        ok = valid_row[u] & (dof[u] > 0.0)
        nx, ny, nz = unit_normal(z_row[u], a[u], g_u[u], g_v[u], u, v, fx, fy, cx, cy)
        out_row[3 * u] = select(ok, nx, fill)
        out_row[3 * u + 1] = select(ok, ny, fill)
        out_row[3 * u + 2] = select(ok, nz, fill)


@njit(noalias=True, _nrt=False)
def variance_row(
    z_row, valid_row, v, stride, a, g_u, g_v, rss, dof, r_row, shift_u, shift_v, rho_table, t_row, cam, gains, out_row
):
    """Each fitted pixel of row v: its normal's angular variance (radians^2) from the fit its plane came from
    (:func:`surfnorm.kernels.uncertainty.fit_variance`, :func:`~surfnorm.kernels.uncertainty.angle_variance`:
    residual per dof, points, radius, window offset ``shift_u``, ``shift_v``, the noise at its depth, ``gains``);
    NaN where it has no fit. Branch-free."""
    fx, fy, cx, cy = cam
    f = math.sqrt(fx * fy)
    for i in range(out_row.shape[0]):
        ok = valid_row[i] & (dof[i] > 0.0)
        d = select(ok, dof[i], 1.0)
        zp = select(ok, z_row[i], 1.0)
        noise = rho_table[t_row[i]] / (zp * f)
        var_g, var_a, c_u, c_v = fit_variance(
            rss[i] / d, d + 3.0, r_row[i], -shift_u[i], -shift_v[i], noise * noise, gains[0], gains[1], gains[2]
        )
        u = stride * i
        nx, ny, nz = unit_normal(zp, a[i], g_u[i], g_v[i], u, v, fx, fy, cx, cy)
        out_row[i] = select(ok, angle_variance(nx, ny, nz, zp, u, v, fx, fy, cx, cy, var_g, var_a, c_u, c_v), np.nan)


@pixel
def unit_normal(zp, a, g_u, g_v, u, v, fx, fy, cx, cy):
    """Eq. (2) at pixel (u, v) of depth ``zp`` from its plane (a: w there, g_u, g_v), as float32."""
    a = select(a > 0.0, a, 1.0 / zp)  # a fit that passes behind the camera: the pixel's own w
    nx = fx * g_u
    ny = fy * g_v
    nz = a - g_u * (u - cx) - g_v * (v - cy)
    inv_norm = -1.0 / math.sqrt(nx * nx + ny * ny + nz * nz)
    return np.float32(nx * inv_norm), np.float32(ny * inv_norm), np.float32(nz * inv_norm)


@pixel
def table_entry(zp, z0, inv_step, n_table):
    """The entry of the depth table (:func:`radius_table`) for depth ``zp``."""
    return min(max(int((zp - z0) * inv_step), 0), n_table - 1)


@pixel
def noise_limit(zp, rho, f, kappa, rho_floor):
    """The noise test's limit at depth ``zp``: (kappa sigma_w)^2, sigma_w = sigma_z / z^2 = rho / (z f) the noise
    of w (rho at least ``rho_floor``). A fit passes when its residual per degree of freedom is at most that."""
    zf = zp * f
    s_w = kappa * max(rho, rho_floor)
    return (s_w * s_w) / (zf * zf)


@njit(noalias=True, _nrt=False)
def expand_row(a, g_u, g_v, ok, limit, e):
    """The planes of a row's fitted pixels (columns 0, 2, 4, ...: a, g_u, g_v, ok and the noise limit, each
    (n_fit,)) at full width: e[:, u] is column 2 (u // 2)'s, for u = 0 .. W (none at u = W for an even W)."""
    W = e.shape[1] - 1
    for i in range(a.shape[0]):
        for c, x in ((0, a[i]), (1, g_u[i]), (2, g_v[i]), (3, ok[i]), (4, limit[i])):
            e[c, 2 * i] = x
            if 2 * i + 1 <= W:
                e[c, 2 * i + 1] = x
    if W % 2 == 0:
        e[3, W] = 0.0


@pixel
def carried(rows, k, du, dv, w_p):
    """The plane of the fitted pixel held at ``k`` in ``rows`` (:func:`expand_row`) carried to a pixel ``du``
    columns and ``dv`` rows from it: (w there, g_u, g_v, squared error to the pixel's own w_p: inf where that
    fitted pixel has no plane, and the fitted pixel's noise limit: -1 there)."""
    has = rows[3, k] > 0.0
    p = rows[0, k] + rows[1, k] * du + rows[2, k] * dv
    return p, rows[1, k], rows[2, k], select(has, (p - w_p) * (p - w_p), np.inf), select(has, rows[4, k], -1.0)


@pixel
def interpolated(p0, gu0, gv0, e0, l0, p1, gu1, gv1, e1, l1, p2, gu2, gv2, e2, l2, p3, gu3, gv3, e3, l3):
    """The plane at a pixel from those of up to four fitted pixels next to it (:func:`carried`; a missing one
    has e = inf): the mean of those that predict the pixel's w within their noise limit (e <= l), else the
    one that predicts it closest (one closer by more than TIE of the squared error replaces the one before
    it). Returns (a, g_u, g_v, found); limits of -1 give the closest one."""
    q0 = e0 <= l0
    q1 = e1 <= l1
    q2 = e2 <= l2
    q3 = e3 <= l3
    n = q0 + q1 + q2 + q3
    s_a = select(q0, p0, 0.0) + select(q1, p1, 0.0) + select(q2, p2, 0.0) + select(q3, p3, 0.0)
    s_u = select(q0, gu0, 0.0) + select(q1, gu1, 0.0) + select(q2, gu2, 0.0) + select(q3, gu3, 0.0)
    s_v = select(q0, gv0, 0.0) + select(q1, gv1, 0.0) + select(q2, gv2, 0.0) + select(q3, gv3, 0.0)
    best = e0
    a_c = p0
    gu_c = gu0
    gv_c = gv0
    c = e1 < best * (1.0 - TIE)
    best, a_c, gu_c, gv_c = select(c, e1, best), select(c, p1, a_c), select(c, gu1, gu_c), select(c, gv1, gv_c)
    c = e2 < best * (1.0 - TIE)
    best, a_c, gu_c, gv_c = select(c, e2, best), select(c, p2, a_c), select(c, gu2, gu_c), select(c, gv2, gv_c)
    c = e3 < best * (1.0 - TIE)
    best, a_c, gu_c, gv_c = select(c, e3, best), select(c, p3, a_c), select(c, gu3, gu_c), select(c, gv3, gv_c)
    mean = n > 0
    inv_n = select(n == 2, 0.5, select(n == 4, 0.25, select(n == 3, 1.0 / 3.0, 1.0)))  # 1 / n, multiplied
    return (
        select(mean, s_a * inv_n, a_c),
        select(mean, s_u * inv_n, gu_c),
        select(mean, s_v * inv_n, gv_c),
        best < np.inf,
    )


@pixel
def _put_normal(z_row, valid_row, u, o, a, gu, gv, found, fx, fy, cx, cy, fill, out_row):
    """Eq. (2) at pixel u of row o from its plane into ``out_row`` (``fill`` where it is invalid or has none);
    returns whether it got one."""
    ok = valid_row[u] & found
    nx, ny, nz = unit_normal(z_row[u], a, gu, gv, u, o, fx, fy, cx, cy)
    out_row[3 * u] = select(ok, nx, fill)
    out_row[3 * u + 1] = select(ok, ny, fill)
    out_row[3 * u + 2] = select(ok, nz, fill)
    return ok


@njit(noalias=True, _nrt=False)
def assembled_row(z_row, valid_row, o, up2, up1, same, dn1, dn2, cam, fill, got, out_row):
    """Eq. (2) for every pixel of row ``o`` with ``stride`` 2, from the planes of the fitted rows around it
    (:func:`expand_row`, or a row without planes): ``same`` the row itself (o even), ``up2`` and ``dn2`` the
    fitted rows two above and below it, ``up1`` and ``dn1`` those just above and below it (o odd).

    A fitted pixel (even row and column) keeps its plane. Every other one takes :func:`interpolated` of the
    fitted pixels of its 3x3 neighbourhood (left and right; above and below; the four diagonal ones), and
    where none of them has a plane, the closest of the other fitted pixels of its 5x5 neighbourhood. On
    the full-width rows of :func:`expand_row` a pixel u finds the fitted pixels of its column pair at u and
    u + 1: its own plane twice (the mean of a value with itself is that value, to the bit), or its left
    and right ones, so that the first pass over the row reads contiguous memory, branch-free (it
    vectorises). ``got`` is scratch (W,).
    """
    W = z_row.shape[0]
    fx, fy, cx, cy = cam
    inf = np.inf
    odd = o % 2 == 1
    # two loops, not one with the choice inside: the compiler computed both sides of it for every pixel
    if odd:  # above and below, or the four diagonal ones
        for u in range(W):
            w_p = 1.0 / z_row[u]
            du = float(u % 2)
            p0, gu0, gv0, e0, l0 = carried(up1, u, du, 1.0, w_p)
            p1, gu1, gv1, e1, l1 = carried(up1, u + 1, -du, 1.0, w_p)
            p2, gu2, gv2, e2, l2 = carried(dn1, u, du, -1.0, w_p)
            p3, gu3, gv3, e3, l3 = carried(dn1, u + 1, -du, -1.0, w_p)
            a, gu, gv, found = interpolated(
                p0, gu0, gv0, e0, l0, p1, gu1, gv1, e1, l1, p2, gu2, gv2, e2, l2, p3, gu3, gv3, e3, l3
            )
            got[u] = _put_normal(z_row, valid_row, u, o, a, gu, gv, found, fx, fy, cx, cy, fill, out_row)
    else:  # its own plane twice, or the left and right ones; no others (the compiler drops them)
        for u in range(W):
            w_p = 1.0 / z_row[u]
            du = float(u % 2)
            p0, gu0, gv0, e0, l0 = carried(same, u, du, 0.0, w_p)
            p1, gu1, gv1, e1, l1 = carried(same, u + 1, -du, 0.0, w_p)
            a, gu, gv, found = interpolated(
                p0, gu0, gv0, e0, l0, p1, gu1, gv1, e1, l1, 0.0, 0.0, 0.0, inf, -1.0, 0.0, 0.0, 0.0, inf, -1.0
            )
            got[u] = _put_normal(z_row, valid_row, u, o, a, gu, gv, found, fx, fy, cx, cy, fill, out_row)
    for u in range(W):  # the few without a plane yet: the other fitted pixels of the 5x5 neighbourhood
        if got[u] or not valid_row[u] or u % 2 == o % 2:  # fitted, or diagonal to the fitted ones: no others
            continue
        w_p = 1.0 / z_row[u]
        if odd:  # even column: two columns left and right in the rows above and below
            left = max(u - 2, 0)
            right = min(u + 2, W)
            p0, gu0, gv0, e0, l0 = carried(up1, left, 2.0, 1.0, w_p)
            p1, gu1, gv1, e1, l1 = carried(up1, right, -2.0, 1.0, w_p)
            p2, gu2, gv2, e2, l2 = carried(dn1, left, 2.0, -1.0, w_p)
            p3, gu3, gv3, e3, l3 = carried(dn1, right, -2.0, -1.0, w_p)
            e0, e2 = select(u >= 2, e0, inf), select(u >= 2, e2, inf)
            e1, e3 = select(u + 2 <= W, e1, inf), select(u + 2 <= W, e3, inf)
        else:  # odd column: left and right in the rows two above and below
            p0, gu0, gv0, e0, l0 = carried(up2, u - 1, 1.0, 2.0, w_p)
            p1, gu1, gv1, e1, l1 = carried(up2, u + 1, -1.0, 2.0, w_p)
            p2, gu2, gv2, e2, l2 = carried(dn2, u - 1, 1.0, -2.0, w_p)
            p3, gu3, gv3, e3, l3 = carried(dn2, u + 1, -1.0, -2.0, w_p)
        a, gu, gv, found = interpolated(
            p0, gu0, gv0, e0, -1.0, p1, gu1, gv1, e1, -1.0, p2, gu2, gv2, e2, -1.0, p3, gu3, gv3, e3, -1.0
        )
        if found:
            nx, ny, nz = unit_normal(z_row[u], a, gu, gv, u, o, fx, fy, cx, cy)
            out_row[3 * u] = nx
            out_row[3 * u + 1] = ny
            out_row[3 * u + 2] = nz


#: The shifted windows of the edge test: the four quadrants (Kuwahara), each with the pixel at a corner.
_SHIFTS = np.array(SHIFTS, np.int64)


@pixel
def _fitted_row(fitted, none, v, stride, first, last):
    """The planes of fitted row v in the ring ``fitted``, or ``none`` where v is not a fitted row there."""
    return fitted[(v // stride) % 3] if v % stride == 0 and first <= v <= last else none


@njit(noalias=True, _nrt=False)
def _emit_row(z, valid, o, stride, fitted, first, last, none, cam, fill, got, out_flat):
    """The normals of row ``o`` from the planes of the fitted rows ``first`` .. ``last`` held in ``fitted``
    (a ring of three: fitted row v at (v // stride) % 3; ``none`` for a row outside them); ``cam`` is
    (fx, fy, cx, cy); ``got`` is scratch (W,)."""
    if stride == 1:
        rows = fitted[o % 3]
        fx, fy, cx, cy = cam
        normal_row(z[o], valid[o], o, rows[1], rows[2], rows[0], rows[3], fx, fy, cx, cy, fill, out_flat[o])
        return
    assembled_row(
        z[o],
        valid[o],
        o,
        _fitted_row(fitted, none, o - 2, stride, first, last),
        _fitted_row(fitted, none, o - 1, stride, first, last),
        _fitted_row(fitted, none, o, stride, first, last),
        _fitted_row(fitted, none, o + 1, stride, first, last),
        _fitted_row(fitted, none, o + 2, stride, first, last),
        cam,
        fill,
        got,
        out_flat[o],
    )


@njit(noalias=True, _nrt=False)
def _row_done(v, valid_row, a, g_u, g_v, dof, limit, ok_row, band):
    """Fitted row v's planes (a, g_u, g_v where valid_row and dof > 0) into the ring ``fitted``, then the normals
    of the band's rows (``v0`` .. ``v1`` - 1) whose planes are all known now: row v (stride 1), or the two
    before it (stride 2; :func:`_emit_row`). ``band``: what stays the same from row to row, (z, valid, v0, v1,
    stride, v_first, fitted, none, cam, fill, got, out_flat) as in :func:`_adaptive_fit_kernel`."""
    z, valid, v0, v1, stride, v_first, fitted, none, cam, fill, got, out_flat = band
    W = z.shape[1]
    reach = stride - 1
    rows = fitted[(v // stride) % 3]
    for i in range(ok_row.shape[0]):
        ok_row[i] = select(valid_row[i] & (dof[i] > 0.0), 1.0, 0.0)
    if stride == 1:
        for u in range(W):
            rows[0, u] = a[u]
            rows[1, u] = g_u[u]
            rows[2, u] = g_v[u]
            rows[3, u] = ok_row[u]
    else:
        expand_row(a, g_u, g_v, ok_row, limit, rows)
    for o in range(v - 2 * reach, v + 1 - reach):
        if v0 <= o < v1:
            _emit_row(z, valid, o, stride, fitted, v_first, v, none, cam, fill, got, out_flat)


@pixel
def first_fitted_row(v0, stride):
    """The first fitted row that the band starting at row v0 reads: every stride-th row of the frame, with stride 2
    from the one above v0 (its rows take planes from the fitted rows up to two above and below them)."""
    v = max(v0 - (stride - 1), 0)
    return v - v % stride


@njit(noalias=True, _nrt=False)
def make_rows(z, valid, ring, cols, pos, w_scratch, made, upto, first_read):
    """Integral rows ``made`` + 1 .. ``upto`` into ``ring``, integral row i at i % len(ring) (see
    :func:`integral_row`; column sums ``cols``, columns at ``pos``, scratch ``w_scratch`` (W,)), those before
    ``first_read`` as column sums only (:func:`column_row`: a band's rows above the ones it reads); row 0,
    zeros, and ``cols`` zeroed where ``made`` is 0. Returns upto."""
    H, W = z.shape
    L = ring.shape[0]
    if made == 0:
        ring[0, :, :] = 0.0
        cols[:, :] = 0.0
    for i in range(made + 1, upto + 1):
        y = i - 1 - 0.5 * H
        row = valid[i - 1]
        n = 0
        for u in range(W):
            n += row[u]
        if n == 0 and (i - 1 >= first_read or i == 1):
            # an image row without valid pixels (a LiDAR frame's upper rows) adds nothing: the integral row
            # before, already in the ring, again (the same bits as summing the unchanged columns)
            src = ring[(i - 1) % L]
            dst = ring[i % L]
            for c in range(src.shape[0]):
                for u in range(src.shape[1]):
                    dst[c, u] = src[c, u]
        elif i < first_read:
            if n > 0:
                column_row(z[i - 1], row, y, w_scratch, cols)
        else:
            integral_row(z[i - 1], row, y, pos, w_scratch, cols, ring[i % L])
    return upto


@ahead_of_time
@njit(noalias=True)
def prime(z, valid, ring, cols, pos, w_scratch, made, upto, first_read):
    """:func:`make_rows` before the kernel: the rows above a band's first fitted row, made before the frame's noise
    is known."""
    return make_rows(z, valid, ring, cols, pos, w_scratch, made, upto, first_read)


@ahead_of_time
@njit(noalias=True)
def _adaptive_fit_kernel(
    z,
    valid,
    z0,
    inv_step,
    r_table,
    rho_table,
    grow,
    widen,
    n_widen,
    fx,
    fy,
    cx,
    cy,
    kappa,
    rho_floor,
    r_max,
    fill,
    ring,
    cols,
    made,
    pos,
    w_scratch,
    out,
    v0,
    v1,
    stride,
    info,
    gains,
):
    """Rows v0 .. v1 - 1 of the normals (a row band: see :mod:`surfnorm._bands`), in a ``ring`` that holds the
    integral rows up to ``made`` and ``cols`` the column sums after it (:func:`prime`); ``pos``:
    :func:`integral_positions`, ``w_scratch``: (W,).

    The windows are fitted on the pixels of every ``stride``-th row and column; with ``stride`` 2 every other
    pixel takes its plane from the fitted pixels around it (:func:`assemble_row`), so a band fits the rows
    up to two beyond its own.

    Integral rows are sums from row 0 down, so a band starting at v0 first sums the columns of the rows
    above the ones it reads, then makes the integral rows it reads (no fits: :func:`prime`): the same
    additions in the same order as one sweep, so the same bits; the price is that pass over rows
    0 .. v0 + 2 ``r_max``, mostly column sums (vectorised).

    ``info``: (0, 0) for nothing, or (fitted rows, fitted columns) float64, where fitted pixel (v, stride i) gets its
    normal's angular variance (radians^2, :mod:`surfnorm.kernels.uncertainty`) from the fit its plane came from
    (its residual, points, radius and window offset; the noise at its depth; ``gains``: the noise's and the
    misfit's variance factors), NaN where it has no fit. Only written (it changes no normal).
    """
    H, W = z.shape
    L = ring.shape[0]
    slot = np.arange(H + 1) % L
    n_fit = (W + stride - 1) // stride
    m = np.zeros(_N_MOMENTS)
    m_a = np.zeros((len(_BOXED), n_fit))
    m_b = np.zeros((len(_BOXED), n_fit))
    m_coords = np.zeros((len(_COORDS), n_fit))
    m_coords2 = np.zeros((len(_COORDS), n_fit))
    r_row = np.empty(n_fit, np.int64)
    r_float = np.empty(n_fit)
    x_row = np.empty(n_fit)
    for i in range(n_fit):
        x_row[i] = stride * i - 0.5 * W
    z_row = np.empty(n_fit)
    valid_row = np.empty(n_fit, np.bool_)
    t_row = np.empty(n_fit, np.int64)
    pick = np.empty(n_fit, np.bool_)
    g_u = np.empty(n_fit)
    g_v = np.empty(n_fit)
    a = np.empty(n_fit)
    rss = np.empty(n_fit)
    dof = np.empty(n_fit)
    limit = np.empty(n_fit)
    passed = np.empty(n_fit, np.bool_)
    r_try = np.empty(n_fit, np.int64)
    m_c = np.zeros((len(_BOXED), n_fit))
    m_d = np.zeros((len(_BOXED), n_fit))
    g_u3 = np.empty(n_fit)
    g_v3 = np.empty(n_fit)
    a3 = np.empty(n_fit)
    rss3 = np.empty(n_fit)
    dof3 = np.empty(n_fit)
    r_next = np.empty(n_fit, np.int64)
    r_try_f = np.empty(n_fit)
    need = np.empty(n_fit)
    tried = np.empty(n_fit, np.bool_)
    shift_u = np.zeros(n_fit)
    shift_v = np.zeros(n_fit)
    record = info.shape[0] > 0
    present = np.zeros(r_max + 2, np.bool_)
    widened = np.zeros(r_max + 2, np.bool_)
    f = math.sqrt(fx * fy)
    n_table = r_table.shape[0]
    out_flat = out.reshape(H, 3 * W)
    # the planes of the last three fitted rows: (a, g_u, g_v, ok) at every pixel (stride 1), or those and the
    # noise limit at full width (stride 2: expand_row)
    fitted = np.zeros((3, 5, W + 1))
    none = np.zeros((5, W + 1))
    got = np.zeros(W, np.bool_)
    ok_row = np.empty(n_fit)
    cam = (fx, fy, cx, cy)
    # The fitted rows: every stride-th row of the frame, whatever the band; with stride 2 those that the band's
    # rows take planes from (rows up to two above and below).
    reach = stride - 1
    v_first = first_fitted_row(v0, stride)
    v_last = min(v1 - 1 + 2 * reach, H - 1)
    v_last -= v_last % stride
    band = (z, valid, v0, v1, stride, v_first, fitted, none, cam, fill, got, out_flat)
    for v in range(v_first, v_last + 1, stride):
        if made < min(H, v + 2 * r_max + 1):  # the integral rows of this row's windows (``made``: the last one)
            made = make_rows(z, valid, ring, cols, pos, w_scratch, made, min(H, v + 2 * r_max + 1), 0)
        y = v - 0.5 * H
        any_valid = False
        for i in range(n_fit):
            z_row[i] = z[v, stride * i]
            valid_row[i] = valid[v, stride * i]
            any_valid |= valid_row[i]
        if not any_valid:  # no fits (a LiDAR frame's upper rows): valid_row alone gives the fill and no planes
            if record:
                info[v // stride, :] = np.nan
            _row_done(v, valid_row, a, g_u, g_v, dof, limit, ok_row, band)
            continue
        # Each pixel's radius from its depth; then window sums radius by radius, growing the
        # radius where too few of the window's pixels are valid (sparse depth).
        present[:] = False
        m_src = m_a
        m_row = m_b
        for u in range(n_fit):
            t = table_entry(z_row[u], z0, inv_step, n_table)
            t_row[u] = t
            r0 = r_table[t]
            r_row[u] = r0
            need[u] = (2 * r0 + 1) * (2 * r0 + 1) * (r0 * (r0 + 1))
            if valid_row[u]:
                present[r0] = True
        first = True
        for r in range(1, r_max + 1):
            if not present[r]:
                continue
            count = 0
            for u in range(n_fit):
                p = valid_row[u] & (r_row[u] == r)
                pick[u] = p
                count += p
            m_row, m_src = picked_sums(ring, slot, H, v, r, stride, pos, pick, count, first, m_row, m_src, m_coords)
            first = False
            if r == r_max:
                continue
            # Sparse depth: grow (x1.5) until the window's valid pixels pin the slope at least half as
            # well as the full window of the noise's radius r0 (sum of squared offsets ~ n r (r + 1) / 3,
            # ``need``), with at least MIN_POINTS of them.
            r_big = grow[r]
            spread = float(r * (r + 1))
            grew = False
            for u in range(n_fit):
                sparse = pick[u] & ((m_row[0, u] < MIN_POINTS) | (2.0 * m_row[0, u] * spread < need[u]))
                r_row[u] = select(sparse, r_big, r_row[u])
                grew |= sparse
            if grew:
                present[r_big] = True
        for u in range(n_fit):
            r_float[u] = r_row[u]
        fit_row(m_row, m_coords, r_float, x_row, y, g_u, g_v, a, rss, dof)
        # The noise test: a fit is consistent with the noise when its residual per degree of
        # freedom is at most the limit (kappa sigma_w)^2.
        for u in range(n_fit):
            limit[u] = noise_limit(z_row[u], rho_table[t_row[u]], f, kappa, rho_floor)
            passed[u] = valid_row[u] & (dof[u] > 0.0) & (rss[u] <= limit[u] * dof[u])
        # Wider where the data allow: a fit that passes is tried on a window twice as wide, kept
        # while it still passes (planes get wide windows, curved surfaces and edges keep theirs).
        for _ in range(n_widen):
            # ``present``: the radii of the windows just fitted, so those of the passing pixels.
            for u in range(n_fit):
                tried[u] = False
            widened[:] = False
            m_try = m_c
            m_old = m_d
            first = True
            for r in range(1, r_max + 1):
                r2 = widen[r]
                if not present[r] or r2 <= r:
                    continue
                r2_f = float(r2)
                count = 0
                for u in range(n_fit):
                    p = passed[u] & (r_row[u] == r)
                    pick[u] = p
                    tried[u] |= p
                    r_try[u] = select(p, r2, r_try[u])
                    r_try_f[u] = select(p, r2_f, r_try_f[u])
                    count += p
                if count == 0:
                    continue
                widened[r2] = True
                m_try, m_old = picked_sums(
                    ring, slot, H, v, r2, stride, pos, pick, count, first, m_try, m_old, m_coords2
                )
                first = False
            if first:
                break
            present, widened = widened, present
            widened_row(
                m_try,
                m_coords2,
                r_try_f,
                x_row,
                y,
                tried,
                limit,
                r_try,
                g_u,
                g_v,
                a,
                rss,
                dof,
                r_row,
                g_u3,
                g_v3,
                a3,
                rss3,
                dof3,
                r_next,
                passed,
            )
            g_u, g_u3 = g_u3, g_u
            g_v, g_v3 = g_v3, g_v
            a, a3 = a3, a
            rss, rss3 = rss3, rss
            dof, dof3 = dof3, dof
            r_row, r_next = r_next, r_row
        # The edge test: a pixel whose fit fails the noise test takes the best of the four
        # quadrant windows (smallest residual per dof).
        if record:
            shift_u[:] = 0.0
            shift_v[:] = 0.0
        for i in range(n_fit):
            if not valid_row[i]:
                continue
            ok = dof[i] > 0.0
            if ok and rss[i] <= limit[i] * dof[i]:
                continue
            u = stride * i
            x = x_row[i]
            r = r_row[i]
            # A candidate is consistent when its plane passes through the pixel itself (within kappa
            # times its residual or the noise): a thin part seen against a far background must not
            # take the background's plane because that one fits its own points better.
            w_p = 1.0 / z_row[i]
            best = max(rss[i] / dof[i], TIE * limit[i]) if ok else np.inf
            best_in = ok and (a[i] - w_p) ** 2 <= kappa * kappa * max(best, limit[i])
            n_min = max(6.0, 0.25 * m_row[0, i])
            for k in range(_SHIFTS.shape[0]):
                dv = _SHIFTS[k, 0] * r
                du = _SHIFTS[k, 1] * r
                # The count first: a window with too few points needs no more; a full square needs no
                # coordinate sums (affine_fit knows them).
                window_sums(ring, slot, pos, H, W, v + dv, u + du, r, _COUNT, m)
                if m[0] < n_min:
                    continue
                window_sums(ring, slot, pos, H, W, v + dv, u + du, r, _W_SUMS, m)
                if m[0] != (2 * r + 1) * (2 * r + 1):
                    window_sums(ring, slot, pos, H, W, v + dv, u + du, r, _COORDS, m)
                a_k, gu_k, gv_k, rss_k, dof_k = affine_fit(
                    m[0], m[1], m[2], m[3], m[4], m[5], m[6], m[7], m[8], m[9], r, x + du, y + dv
                )
                if not dof_k > 0.0:
                    continue
                score = max(rss_k / dof_k, TIE * limit[i])
                a_p = a_k - gu_k * du - gv_k * dv
                inside = (a_p - w_p) ** 2 <= kappa * kappa * max(score, limit[i])
                if (inside and not best_in) or (inside == best_in and score < best * (1.0 - TIE)):
                    best = score
                    best_in = inside
                    g_u[i] = gu_k
                    g_v[i] = gv_k
                    a[i] = a_p
                    dof[i] = dof_k
                    if record:
                        rss[i] = rss_k
                        shift_u[i] = du
                        shift_v[i] = dv
        if record:
            variance_row(
                z_row,
                valid_row,
                v,
                stride,
                a,
                g_u,
                g_v,
                rss,
                dof,
                r_row,
                shift_u,
                shift_v,
                rho_table,
                t_row,
                cam,
                gains,
                info[v // stride],
            )
        _row_done(v, valid_row, a, g_u, g_v, dof, limit, ok_row, band)
    for o in range(v_last + 1 - reach, v_last + 1 + reach):  # stride 2: the frame's last rows, if in the band
        if v0 <= o < v1 and o < H:
            _emit_row(z, valid, o, stride, fitted, v_first, v_last, none, cam, fill, got, out_flat)


#: ``info`` of :func:`_adaptive_fit_kernel` when nothing is recorded, and its ``gains`` then.
_NO_INFO = np.empty((0, 0))
_NO_GAINS = np.zeros(3)


def adaptive_fit(
    z: np.ndarray,
    valid: np.ndarray,
    cam,
    out: np.ndarray,
    *,
    window=None,
    max_window: int = MAX_WINDOW,
    alpha: float = ALPHA,
    kappa: float = KAPPA,
    fill: float = 0.0,
    profile=None,
    use=None,
    stride=None,
    bands=whole,
    record: dict | None = None,
) -> np.ndarray | None:
    """Adaptive plane fit of inverse depth; fills ``out`` (H, W, 3) float32 and returns it.

    Parameters
    ----------
    z : ndarray of float32, shape (H, W)
        Validated depth.
    valid : ndarray of bool, shape (H, W)
        True where the depth is usable.
    cam : Intrinsics
    out : ndarray of float32, shape (H, W, 3)
    window : int or None
        None (default): the window side follows from the frame's noise (see the
        module docstring). An odd int: that fixed side everywhere (still grown
        where too few pixels are valid).
    max_window : int
        Largest window side (odd).
    alpha : float
        Radius gain, r = ceil(alpha sqrt(rho)).
    kappa : float
        Edge test: a fit whose residual per degree of freedom exceeds
        (kappa sigma_w)^2 is replaced by the best shifted window.
    fill : float
        Value of pixels without a normal.
    profile : NoiseProfile, callable or None
        The frame's :func:`noise_profile` when the caller has it already, or a function that returns it
        (``Part.result``: measured by the first band that needs it). None: measured here. Either way, with
        several bands, the one on the calling thread measures it while the others make the integral rows
        above their own rows, which do not depend on it, and then take the calling band's first integral rows
        and parts of its measuring (:class:`surfnorm._bands.Offers`).
    use : callable, optional
        ``use(profile)``: False when the frame is not for this method after all (``auto`` on clean depth);
        then nothing is written and the result is None.
    stride : 1, 2 or None
        1: every pixel's own window. 2: windows on the pixels of the even rows and columns; every other
        pixel takes the planes of the fitted pixels next to it: the mean of those that pass through its
        depth within their noise limit, else the closest one (:func:`assembled_row`); a quarter of the
        fits. None (default): 2 unless the depth is sparse (:func:`choose_stride`).
    bands : callable
        How rows are split over threads (see :mod:`surfnorm._bands`); each band has its own ring of
        integral rows.
    record : dict, optional
        Filled with what :mod:`surfnorm.kernels.uncertainty` needs: ``"profile"`` (the noise profile),
        ``"stride"`` and ``"variance"`` (each fitted pixel's angular variance: see ``info`` of
        :func:`_adaptive_fit_kernel`), with the gains ``FIT_GAIN`` and ``MISFIT_GAIN`` of that module.
        None (default): nothing recorded, nothing spent on it.
    """
    f = math.sqrt(cam.fx * cam.fy)
    r_max = (max_window - 1) // 2
    grow, widen = growth_table(r_max), widen_table(r_max)
    stride = choose_stride(valid) if stride is None else stride
    H = z.shape[0]
    if record is None:
        info, gains = _NO_INFO, _NO_GAINS
    else:  # every fitted row is written by a band
        info = np.empty(((H + stride - 1) // stride, (z.shape[1] + stride - 1) // stride))
        gains = np.zeros(3)  # the noise's variance factor, set once the profile is known; misfit's; significance
        gains[1:] = MISFIT_GAIN, MISFIT_SIGNIFICANCE
        record.update(stride=stride, variance=info)

    # bands waiting for the noise take parts of its measuring (Offers.help) until it is done
    offers = None if bands is whole else Offers()

    def measured():
        if offers is not None:
            offers.open()
        try:
            if profile is None:
                p = noise_profile(z, valid, f, offers)
            else:
                p = profile() if callable(profile) else profile
        finally:
            if offers is not None:
                offers.close()
        if record is not None:
            record["profile"] = p
            gains[0] = noise_gain(p)
        if use is not None and not use(p):
            return None
        return radius_table(p.depths, p.rho, alpha=alpha, window=window, max_window=max_window)

    tables = Part(measured)
    shape = (4 * r_max + 3, _N_MOMENTS, z.shape[1] + 1)

    spent: list = []

    def rows(v0, v1):
        kept = _rings.take(shape)
        ring = kept[0] if kept is not None else np.empty(shape)
        primed = None
        try:
            v_first = first_fitted_row(v0, stride)
            upto = min(H, v_first + 2 * r_max + 1)
            first_read = v_first - 2 * r_max  # the first integral row that the band's windows read
            pos, w_scratch = integral_positions(z.shape[1], stride), np.empty(z.shape[1])
            cols = np.empty((_N_COLUMNS, z.shape[1]))

            def primer():
                # in two halves, so that a band stops early where the frame turns out not to be for this method
                made = prime(z, valid, ring, cols, pos, w_scratch, 0, upto // 2, first_read)
                if not (tables.done and tables.result() is None):
                    made = prime(z, valid, ring, cols, pos, w_scratch, made, upto, first_read)
                return made

            if v0 > 0:
                made = primer()
                if offers is not None:
                    offers.help()
            elif offers is None:
                tables.result()
                made = primer()
            else:  # the calling thread's band measures the noise; a waiting band may make its first integral rows
                primed = offers.offer(Part(primer))
                tables.result()
                made = primed.result()
            got = tables.result()
            if got is None:
                return False
            z0, inv_step, r_table, rho_table = got
            _adaptive_fit_kernel(
                z,
                valid,
                z0,
                inv_step,
                r_table,
                rho_table,
                grow,
                widen,
                N_WIDEN,
                float(cam.fx),
                float(cam.fy),
                float(cam.cx),
                float(cam.cy),
                float(kappa),
                RHO_FLOOR,
                r_max,
                np.float32(fill),
                ring,
                cols,
                made,
                pos,
                w_scratch,
                out,
                v0,
                v1,
                stride,
                info,
                gains,
            )
            return True
        finally:
            if v0 == 0 and offers is not None:  # never leave the other bands waiting for it
                offers.close()
            if primed is not None:
                primed.finish()  # nobody writes the ring once it is given back
            _rings.give(shape, (ring,))
            spent.append((v0, v1, time.perf_counter() - start))

    # A row costs its integral row and bookkeeping (every pixel) and its fits (its valid pixels on the fitted
    # columns, on the fitted rows only): sparse rows (a LiDAR frame's upper part) are cheap, so bands of equal
    # cost, not of equal rows.
    # Then each band's rows weigh what the bands took on the last frames of this size (Balance).
    if bands is whole:
        weights = None
    else:
        key = (z.shape, stride, max_window, window)
        factors = _balance.factors(key)
        weights = _band_weights(valid, stride, np.ones(H) if factors is None else factors)
    start = time.perf_counter()
    done = bands(rows, H, weights=weights)
    if weights is not None and all(done):
        _balance.learn(key, weights, spent)
    return out if all(done) else None
