"""The adaptive fit's windows: their radii from the noise, and their moment sums from integral rows.

:func:`radius_table` turns the frame's noise profile (:mod:`surfnorm.kernels.sensor_noise`) into a look-up table
from depth to the window radius r = ceil(ALPHA sqrt(rho)) on the ladder ``RADII``, and :func:`widen_table` and
:func:`growth_table` give the radii a window widens and grows to. The ten moment sums of a window (count, u', v',
u'u', u'v', v'v', w, u'w, v'w, ww over its valid pixels) come from integral rows kept in a ring, four look-ups a
moment whatever the window's size (see below). Used by :mod:`surfnorm.kernels.adaptive_fit`.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from .._aot import ahead_of_time
from .._config import njit, pixel, select
from .._constants import _TABLE, ALPHA, MAX_WINDOW, RADII

__all__ = [
    "radius_table",
    "table_entry",
    "noise_limit",
    "allowed_radii",
    "widen_table",
    "growth_table",
    "integral_positions",
    "make_rows",
    "prime",
]

#: The moments of a window: count, u', v', u'u', u'v', v'v', w, u'w, v'w, ww.
_N_MOMENTS = 10


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


def widen_table(r_max: int) -> np.ndarray:
    """widen[r]: the radius a passing window of radius r is tried at next (x2)."""
    return _tables(r_max)[0]


def growth_table(r_max: int) -> np.ndarray:
    """grow[r]: the radius a window of radius r grows to when too few of its pixels are valid (x1.5)."""
    return _tables(r_max)[1]


# --- integral rows ------------------------------------------------------------------------------------
#
# Integral rows live in a ring of 4 r_max + 3 rows, channel-major: ring[slot[i], c, pos[u]] is moment c of
# integral row i at column u. A row of the image needs integral rows v - 2 r .. v + 2 r + 1 (the centred
# windows and the shifted ones), so the moments stay in cache instead of a full-size image. Each integral row
# is made from column sums kept beside the ring (:func:`integral_row`), so a band that starts lower down
# sums the columns of the rows above it and makes only the integral rows that it reads (:func:`make_rows`).
#
# ``pos`` (:func:`integral_positions`) places the columns by their remainder modulo ``stride``: in order for
# ``stride`` 1; for ``stride`` 2 the even columns first, then the odd ones. A window centred on a fitted column
# u (a multiple of the stride) has its edge columns u - r and u + r + 1 at fixed remainders, so along a row of
# fitted pixels (u = 0, stride, 2 stride, ...) both edges move one place at a time: the row's window sums read
# two contiguous runs (see :func:`box_row`).


@njit
def integral_positions(W, stride):
    """pos[u] for the integral columns u = 0 .. W (see above)."""
    pos = np.empty(W + 1, dtype=np.int64)
    k = 0
    for remainder in range(stride):
        for u in range(remainder, W + 1, stride):
            pos[u] = k
            k += 1
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
def box_row_sparse(top, bottom, r, cols, pos, pick, dst):
    """:func:`box_row` pixel by pixel, in place: dst[j, i] for the pixels where ``pick`` only (the same sums), the
    fitted pixel i at column ``cols[i]`` (any columns, in any order)."""
    W = pos.shape[0] - 1
    for i in range(pick.shape[0]):
        if pick[i]:
            u = cols[i]
            u0 = pos[max(u - r, 0)]
            u1 = pos[min(u + r + 1, W)]
            for j in range(len(_BOXED)):
                c = _BOXED[j]
                dst[j, i] = (bottom[c, u1] - top[c, u1]) - (bottom[c, u0] - top[c, u0])


@njit(noalias=True, _nrt=False)
def coordinate_sums(top, bottom, r, cols, pos, pick, counts, coords):
    """The coordinate sums (``_COORDS``) at radius r into coords[j, i] (the fitted pixel i at column ``cols[i]``), for
    the pixels where ``pick`` whose window is not the full (2r + 1)^2 square (``counts``, from :func:`box_row`)."""
    W = pos.shape[0] - 1
    full = (2 * r + 1) * (2 * r + 1)
    for i in range(pick.shape[0]):
        if pick[i] and counts[i] != full:
            u = cols[i]
            u0 = pos[max(u - r, 0)]
            u1 = pos[min(u + r + 1, W)]
            for j in range(len(_COORDS)):
                c = _COORDS[j]
                coords[j, i] = (bottom[c, u1] - top[c, u1]) - (bottom[c, u0] - top[c, u0])


@pixel
def picked_sums(ring, slot, H, v, r, stride, pos, cols, pick, count, first, cur, spare, coords):
    """The window sums at radius r of the ``count`` pixels of row v where ``pick``: the count and w moments into
    ``cur`` (the others keep theirs), or into ``spare`` with the others copied (:func:`box_row`, where many take
    them), and the coordinate moments into ``coords``. Returns (cur, spare), swapped in the second case.

    The row's fitted pixels are at columns ``cols``: every ``stride``-th column of the row (``stride`` > 0), or any
    columns (``stride`` 0: the valid ones of a sparse row, :func:`surfnorm.kernels.adaptive_fit._adaptive_fit_kernel`),
    which go pixel by pixel."""
    top = ring[slot[max(v - r, 0)]]
    bottom = ring[slot[min(v + r + 1, H)]]
    if stride == 0 or SPARSE * count < pick.shape[0]:
        box_row_sparse(top, bottom, r, cols, pos, pick, cur)
    else:
        cur, spare = spare, cur
        box_row(top, bottom, r, stride, pos, pick, first, spare, cur)
    coordinate_sums(top, bottom, r, cols, pos, pick, cur[0], coords)
    return cur, spare


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
