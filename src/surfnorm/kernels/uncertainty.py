"""Each normal's predicted RMS angular error, in degrees (ours, not in the paper).

A normal from a least-squares plane fit of inverse depth w = 1/z (``adaptive_fit``, eq. (1)-(2) of
:mod:`surfnorm.kernels.adaptive_fit`) has a covariance that follows from the fit itself. A window of n points
and radius r, whose points scatter by n r (r + 1) / 3 squared pixels along each axis (exactly so for the full
square), fitted with a residual variance s^2 per point, gives the slopes g_u, g_v each the variance::

    var_g = s^2 / (n r (r + 1) / 3)                                                      (1)

and the plane's value a at a pixel offset (o_u, o_v) from the window's centre (the pixel itself for the
centred window, a corner for a quadrant window, one pixel more where a pixel took a neighbour's plane) the
variance s^2 / n + (o_u^2 + o_v^2) var_g, with cov(a, g_u) = o_u var_g and cov(a, g_v) = o_v var_g. The
normal is m / |m| with m = -(f_x g_u, f_y g_v, a - g_u (u - c_x) - g_v (v - c_y)) (eq. (2) there); to first
order its angular error is the part of dm across the normal, over |m| = w / (-n . (x, y, 1)), so::

    sigma^2 = (trace C - n^T C n) / |m|^2,   C = J cov(g_u, g_v, a) J^T                  (2)

with J = d m / d(g_u, g_v, a). For s^2 the fit's own residual per degree of freedom is taken, or the frame's
noise (``rho``, :class:`~surfnorm.kernels.sensor_noise.NoiseProfile`, as sigma_w = rho / (z f)) where that is
larger: a window whose few points happen to fit well is not trusted beyond the noise the frame shows. Sensor
noise is correlated between neighbours (a matcher's window, a spatial filter, quantisation terraces), which
a residual does not see and a slope does: the frame's noise correlation (:func:`noise_gain`, ``FIT_GAIN`` times
``NoiseProfile.correlation``) multiplies the noise for it. The numbers set from data are ``CORRELATION_WIDTH``
(on the simulated sensors of :mod:`surfnorm.bench.simulate`) and ``CORRELATION_SIGNIFICANCE`` (white noise).

Noise correlated over a few pixels also tilts a small window's plane as a whole, which the window's residual
does not show at all (the plane takes it up). Taken as Gaussian-correlated over ``CORRELATION_WIDTH`` = l
pixels (correlation exp(-d^2 / 4 l^2)) with variance s_c^2, it adds k_s s_c^2 to the mean square of the second
differences at stride s (k_s = 6 - 8 exp(-s^2 / 4 l^2) + 2 exp(-s^2 / l^2); white noise adds 6 s^2 at every
stride), so the profile's correlation c (stride 2 over stride 1) gives s_c^2 = 6 (c - 1) / (c (k_2 - k_1))
times the noise, whose rho is the stride-2 estimate where the noise is correlated (``correlated_share``).
Each slope then varies by that field's gradient, s_c^2 / (2 l^2), in a window narrower than l, and by its mean
over the 4 pi l^2 pixels of a correlation, s_c^2 4 pi l^2 / C, in a wider one (C the points' scatter per
axis); between them::

    var_g += s_c^2 / (2 l^2 + C / (4 pi l^2))                                             (3)

The scatter in (1) and (3) is the window's own (its count and coordinate moments): a window cut by a hole or
the frame's border has fewer points on one side, a centroid off the pixel and slopes that are less certain
and carried further (:func:`fit_covariance`).

``d2nt_v3`` takes the gradients of its DAG filter from one pixel's neighbours: its error is that of the 3x3
neighbourhood's plane, the same formulas at r = 1 (a fit of every pixel's 3x3 window, its own residual;
``D2NT_GAIN``). Two more terms see what the noise does not:

- A surface that turns between pixels (a mesh's facets, a crease) is not where any one pixel's plane says: the
  mean squared sine of the angles between the pixel's plane and those of its eight neighbours' windows that fit
  within the noise (the adaptive fit's noise test), times ``D2NT_TURN``, is added to the variance. Planes give 0.
- The angle between the normal and the pixel's best plane, times ``D2NT_DISAGREEMENT``.

On a clean frame (``adaptive_weight`` 0: its noise reading clean, no grid, no white noise; where ``auto`` runs
``d2nt_v3`` alone) there is no noise to weigh, the 3x3 fits would cost as much as ``d2nt_v3`` itself, and the error
is the surface's shape between pixels. Sigma there comes from two quantities that cost a pass over the normals and the depth
(:func:`_clean_sigma`):

- the bend b: the larger of the relative second differences |w_- - 2 w + w_+| / w of w = 1/z down the pixel's
  column and along its row; 1 where a neighbour on that line is invalid (a discontinuity), nothing where the line
  leaves the frame. f b is the angle (radians) between the slopes on the pixel's two sides, of which DAG's
  gradient carries a share, ``CLEAN_BEND``;
- the turn t: the mean squared sine of the angles between neighbouring normals (each pixel with its right and its
  lower neighbour, both with a normal), over the pairs of the pixels of the 5x5 neighbourhood: the facets and
  creases around the pixel, which the ground truth of a rendered mesh smooths over::

    sigma^2 = CLEAN_FLOOR_DEG^2 + (180 / pi)^2 ((CLEAN_BEND f b)^2 + CLEAN_TURN t),  sigma <= CLEAN_MAX_DEG   (4)

Where every window beside a pixel spans a discontinuity (a thin part, detail finer than a pixel) DAG takes its
gradients from the smoother side and errs by less than the bend says: at most ``CLEAN_MAX_DEG``. The numbers of
(4) were set on the simulator's clean preset (``exact``: the 10 3F2N frames of the calibration), whose error is
mostly the ground truth's own (smooth-shaded normals of faceted meshes); on sensor depth the default runs the
adaptive fit, and (4) does not apply to it.

A pixel that has a normal always gets a sigma (a normal whose window says nothing, for lack of points, gets
``NO_FIT_DEG``); NaN exactly where the normal is fill.
"""

from __future__ import annotations

import math

import numpy as np

from .._bands import whole
from .._config import njit, pixel, select
from .._constants import CORRELATION_WIDTH, KAPPA, RHO_FLOOR
from ._assembly import CELL, holds_normal, mark_row
from ._rows import valid_span
from ._windows import noise_limit, radius_table, table_entry
from .sensor_noise import adaptive_weight, noise_profile, stride_gain

__all__ = [
    "sigma_map",
    "sigma_from_fits",
    "d2nt_sigma",
    "fit_variance",
    "fit_covariance",
    "angle_variance",
    "angle_variance_cov",
    "correlated_share",
    "CORRELATION_WIDTH",
    "FIT_GAIN",
    "D2NT_GAIN",
    "CLEAN_BEND",
    "CLEAN_TURN",
    "CLEAN_FLOOR_DEG",
    "CLEAN_MAX_DEG",
    "NO_FIT_DEG",
]

#: Variance factor of the adaptive fit's slopes over the independent-noise formula (1), times the frame's
#: ``NoiseProfile.correlation`` (at least 1, at most ``MAX_CORRELATION``): :func:`noise_gain`.
FIT_GAIN = 1.0
#: The most that a frame's noise correlation multiplies the slopes' variance by.
MAX_CORRELATION = 16.0
#: How far above 1 ``NoiseProfile.correlation`` must be before it is read as correlated noise: white noise on a
#: plane measures 0.985-1.004 (frames of 240 x 320); the simulated sensors without a correlated part (primesense,
#: tof) 0.97-1.07 on the sample's smooth objects (quantisation, curvature).
CORRELATION_SIGNIFICANCE = 0.05
_L2 = 2.0 * CORRELATION_WIDTH**2  # the gradient's variance of unit correlated noise is 1 / _L2 per axis
_AREA = 4.0 * math.pi * CORRELATION_WIDTH**2  # pixels per correlation (the correlation's integral)
#: Variance factor of the 3x3 fits that stand for ``d2nt_v3``'s gradients.
D2NT_GAIN = 1.0
#: How far (in standard deviations of a residual per degree of freedom under noise alone) a fit's residual must
#: exceed the noise before the excess counts as misfit.
MISFIT_SIGNIFICANCE = 3.0
#: Variance factor of the misfit (a fit's residual beyond the noise), which tilts a plane by about its size over
#: the window's radius, however many points it has.
MISFIT_GAIN = 1.0
#: Misfit's variance factor for ``d2nt_v3``.
D2NT_MISFIT_GAIN = 0.3
#: Weight (on the variance) of the angle between ``d2nt_v3``'s normal and its pixel's best 3x3 plane.
D2NT_DISAGREEMENT = 0.3
#: Weight (on the variance) of how far the planes of the pixel's neighbours' 3x3 windows turn from its own, for
#: ``d2nt_v3`` (:func:`_d2nt_sigma`).
D2NT_TURN = 1.0
#: Added in quadrature to every sigma (degrees) but the clean model's.
FLOOR_DEG = 3.0
#: ``d2nt_v3``'s sigma on a clean frame (``adaptive_weight`` 0), eq. (4): the share of the bend (the angle
#: between the slopes on a pixel's two sides) that DAG's gradient carries.
CLEAN_BEND = 0.075
#: Eq. (4): the weight (on the variance) of the mean squared sine of the angles between neighbouring normals in a
#: pixel's 5x5 neighbourhood.
CLEAN_TURN = 1.0
#: Eq. (4): added in quadrature (degrees).
CLEAN_FLOOR_DEG = 1.25
#: Eq. (4): the largest sigma (degrees). An edge or detail finer than a pixel bends the depth, not noise, and DAG's
#: one-sided gradients err by about this much (RMS) where every window beside a pixel has it.
CLEAN_MAX_DEG = 25.0
#: Sigma (degrees) of a normal without a fit to judge it by.
NO_FIT_DEG = 30.0
#: Square degrees per square radian.
_DEG2 = math.degrees(1.0) ** 2
#: The largest sigma (degrees): a direction known to face the camera, nothing more.
MAX_DEG = 60.0


@pixel
def fit_variance(s2, n, r, o_u, o_v, noise2, gain, misfit_gain, significance):
    """(var_g, var_a, cov(a, g_u), cov(a, g_v)) of a fit (residual per dof s2, n points, radius r) carried to a
    pixel offset (o_u, o_v) from its window's centre, its points scattered as the full square's (n r (r + 1) / 3
    per axis, no cross term) and its noise white: :func:`fit_covariance` of eq. (1)."""
    spread = n * (r * (r + 1.0) / 3.0)
    var_g, _, _, var_a, c_u, c_v = fit_covariance(
        s2, n, spread, 0.0, spread, o_u, o_v, noise2, gain, misfit_gain, significance, 0.0, 1.0
    )
    return var_g, var_a, c_u, c_v


@pixel
def fit_covariance(s2, n, cuu, cuv, cvv, o_u, o_v, noise2, gain, misfit_gain, significance, share, residual):
    """(var g_u, var g_v, cov(g_u, g_v), var_a, cov(a, g_u), cov(a, g_v)) of a fit (residual per dof s2) of n points
    whose coordinates scatter by (cuu, cuv; cuv, cvv) about their centroid, carried to a pixel offset (o_u, o_v)
    from that centroid: the frame's noise at its depth (``noise2``, times ``gain``) averaged over the n points,
    and the misfit (the residual beyond what noise alone gives in ``significance`` standard deviations of a
    residual of n - 3 degrees of freedom, times ``misfit_gain``), which the points do not average away. The
    slopes' covariance is (noise / n + misfit) times n (C)^-1 (eq. (1) for the full square): a window cut by a hole or the frame's border (fewer points on one side, a centroid off
    the pixel) pins its slopes less, and carries them further, than the full square would. The noise's
    correlated part (``share`` times ``noise2``, :func:`correlated_share`) adds eq. (3) to both slopes. ``residual``:
    how much more noise a residual shows than ``noise2`` (the square of the fit's
    :func:`~surfnorm.kernels.sensor_noise.kappa_gain`: the noise test's premise for correlated noise), so that
    the residual it lets through is not taken for misfit; 1 for white noise."""
    s = gain * noise2
    chance = residual * noise2 * (1.0 + significance * math.sqrt(2.0 / max(n - 3.0, 1.0)))
    mis = misfit_gain * max(s2 - chance, 0.0)
    q = (s + n * mis) / max(cuu * cvv - cuv * cuv, 1e-12)
    s_c = share * noise2
    tilt = s_c / (_L2 + 0.5 * (cuu + cvv) / _AREA)
    g_uu = q * cvv + tilt
    g_vv = q * cuu + tilt
    g_uv = -q * cuv
    c_u = g_uu * o_u + g_uv * o_v
    c_v = g_uv * o_u + g_vv * o_v
    var_a = s / n + mis + s_c / (1.0 + n / _AREA) + o_u * c_u + o_v * c_v
    return g_uu, g_vv, g_uv, var_a, c_u, c_v


@pixel
def angle_variance_cov(n0, n1, n2, zp, u, v, fx, fy, cx, cy, g_uu, g_vv, g_uv, var_a, c_u, c_v):
    """Eq. (2): the normal's angular variance (radians^2) at pixel (u, v) with unit normal (n0, n1, n2) and
    depth ``zp``, from the slopes' full covariance (:func:`fit_covariance`); inf where the normal does not face
    the camera."""
    du = u - cx
    dv = v - cy
    facing = -(n0 * du / fx + n1 * dv / fy + n2)
    zf = zp * facing  # 1 / |m|
    trace = g_uu * (fx * fx + du * du) + g_vv * (fy * fy + dv * dv) + 2.0 * g_uv * du * dv
    trace += var_a - 2.0 * (c_u * du + c_v * dv)
    p_u = n0 * fx - n2 * du  # n . J_gu
    p_v = n1 * fy - n2 * dv  # n . J_gv
    along = g_uu * p_u * p_u + g_vv * p_v * p_v + 2.0 * g_uv * p_u * p_v
    along += var_a * n2 * n2 + 2.0 * n2 * (c_u * p_u + c_v * p_v)
    return select(facing > 1e-6, max(trace - along, 0.0) * zf * zf, np.inf)


def noise_gain(profile) -> float:
    """The noise's variance factor of a frame's fits: ``FIT_GAIN`` times its noise correlation (1 to
    ``MAX_CORRELATION``; 1 for white noise, whose residual tells a slope's variance as it is)."""
    c = profile.correlation
    return FIT_GAIN * (min(max(c, 1.0), MAX_CORRELATION) if c == c else 1.0)


def correlated_share(profile) -> float:
    """The variance of a frame's correlated noise in units of its noise (s_c^2 / sigma_w^2, eq. (3)):
    6 (c - 1 - d) / (c (k_2 - k_1)), c its ``NoiseProfile.correlation`` (1 to ``MAX_CORRELATION``), d
    ``CORRELATION_SIGNIFICANCE``; 0 for white noise (c within d of 1)."""
    c = profile.correlation
    c = min(max(c, 1.0), MAX_CORRELATION) if c == c else 1.0
    k1, k2 = stride_gain(1.0), stride_gain(2.0)
    return 6.0 * max(c - 1.0 - CORRELATION_SIGNIFICANCE, 0.0) / (c * (k2 - k1))


@pixel
def angle_variance(n0, n1, n2, zp, u, v, fx, fy, cx, cy, var_g, var_a, c_u, c_v):
    """Eq. (2): the normal's angular variance (radians^2) at pixel (u, v) with unit normal (n0, n1, n2) and
    depth ``zp``, both slopes of variance ``var_g`` and uncorrelated; inf where the normal does not face the
    camera (:func:`angle_variance_cov`)."""
    return angle_variance_cov(n0, n1, n2, zp, u, v, fx, fy, cx, cy, var_g, var_g, 0.0, var_a, c_u, c_v)


@pixel
def _degrees(var, floor2):
    """sigma in degrees from an angular variance (radians^2), ``floor2`` (degrees^2) added, at most ``MAX_DEG``."""
    return min(math.sqrt(_DEG2 * var + floor2), MAX_DEG)


@njit(nogil=True, noalias=True, _nrt=False)
def _pair_sums(var, i, W, total, count):
    """Fitted row i's variances at full width: at column u, the sum and count of the finite ones among the fitted
    pixels of columns u and u + 1's pair (u even: its own twice; u odd: its left and right ones). Branch-free,
    over the fitted columns j (u = 2 j and 2 j + 1), unsigned so that the loads vectorise."""
    row = var[i]
    last = np.uint64(row.shape[0] - 1)
    one, two = np.uint64(1), np.uint64(2)
    for j in range(np.uint64(W >> 1)):  # u = 2 j and 2 j + 1, both inside the frame
        a = row[j]
        b = row[min(j + one, last)]
        ok_a = a == a
        ok_b = b == b
        s_a = select(ok_a, a, 0.0)
        c_a = select(ok_a, 1.0, 0.0)
        total[two * j] = s_a + s_a
        count[two * j] = c_a + c_a
        total[two * j + one] = s_a + select(ok_b, b, 0.0)
        count[two * j + one] = c_a + select(ok_b, 1.0, 0.0)
    if W & 1:  # the last column, even: its own
        a = row[W >> 1]
        ok_a = a == a
        total[W - 1] = select(ok_a, a, 0.0) + select(ok_a, a, 0.0)
        count[W - 1] = select(ok_a, 1.0, 0.0) + select(ok_a, 1.0, 0.0)


@njit(nogil=True)
def _spread_cells(has, var, floor2, no_fit, out, v0, v1):
    """:func:`_spread` with ``stride`` ``CELL``: a pixel with a normal the mean of the variances of its 4x4 cell's
    corners of weight above 0 that have one, weighted bilinearly as its plane was (:func:`_assembly.cell_row`; a
    fitted pixel its own); where none of those has one, the plain mean of the four corners' that have one; else
    ``no_fit``."""
    Hf, Wf = var.shape
    W = has.shape[1]
    s = float(CELL)
    for v in range(v0, v1):
        i = v // CELL
        f_v = (v % CELL) / s
        row = out[v]
        has_row = has[v]
        for u in range(W):
            if not has_row[u]:
                row[u] = np.nan
                continue
            j = u // CELL
            f_u = (u % CELL) / s
            total = 0.0
            weights = 0.0
            near = 0.0
            k = 0
            for di in range(2):
                for dj in range(2):
                    if i + di >= Hf or j + dj >= Wf:
                        continue
                    x = var[i + di, j + dj]
                    if not x == x:
                        continue
                    w = (f_v if di else 1.0 - f_v) * (f_u if dj else 1.0 - f_u)
                    total += w * x
                    weights += w
                    near += x
                    k += 1
            if weights > 0.0:
                row[u] = _degrees(total / weights, floor2)
            elif k > 0:
                row[u] = _degrees(near / k, floor2)
            else:
                row[u] = no_fit


@njit(nogil=True)
def _spread(has, var, stride, floor2, no_fit, out, v0, v1):
    """Rows v0 .. v1 - 1 of sigma: a fitted pixel's own variance; every other pixel with a normal the mean of those
    of the fitted pixels whose planes it may have taken (with ``stride`` 2: left and right, above and below, or
    the four diagonal ones; else those of its 5x5 neighbourhood), as the adaptive fit assembles it; ``no_fit``
    (degrees) where none has one; NaN where there is no normal (not ``has``: :func:`_assembly.mark_row`)."""
    Hf, Wf = var.shape
    W = has.shape[1]
    if stride == 1:
        for v in range(v0, v1):
            has_row, var_row, row = has[v], var[v], out[v]
            for u in range(W):
                x = var_row[u]
                row[u] = select(has_row[u], select(x == x, _degrees(x, floor2), no_fit), np.nan)
        return
    up_t = np.empty(W)
    up_c = np.empty(W)
    dn_t = np.zeros(W)
    dn_c = np.zeros(W)
    made = -1  # the fitted row whose sums up_t, up_c hold
    scale = _DEG2
    for v in range(v0, v1):
        i = v >> 1
        if made != i:
            _pair_sums(var, i, W, up_t, up_c)
            made = i
        row = out[v]
        if v & 1 == 0:
            for u in range(W):
                c = up_c[u]
                row[u] = select(c > 0.0, min(math.sqrt(scale * up_t[u] / max(c, 1.0) + floor2), MAX_DEG), np.inf)
        else:
            if i + 1 < Hf:
                _pair_sums(var, i + 1, W, dn_t, dn_c)
            else:
                dn_t[:] = 0.0
                dn_c[:] = 0.0
            for u in range(W):
                c = up_c[u] + dn_c[u]
                mean = (up_t[u] + dn_t[u]) / max(c, 1.0)
                row[u] = select(c > 0.0, min(math.sqrt(scale * mean + floor2), MAX_DEG), np.inf)
            up_t, dn_t = dn_t, up_t  # the row below is the next even row's
            up_c, dn_c = dn_c, up_c
            made = i + 1
        has_row = has[v]
        lonely = False
        for u in range(W):
            row[u] = select(has_row[u], row[u], np.float32(np.nan))
            lonely |= row[u] == np.inf
        if not lonely:
            continue
        for u in range(W):
            if row[u] == np.inf:  # the few without a neighbour's fit: those of the 5x5 neighbourhood
                total = 0.0
                k = 0
                for ii in range(max((v - 1) // 2, 0), min((v + 2) // 2, Hf - 1) + 1):
                    for jj in range(max((u - 1) // 2, 0), min((u + 2) // 2, Wf - 1) + 1):
                        x = var[ii, jj]
                        if x == x:
                            total += x
                            k += 1
                row[u] = _degrees(total / k, floor2) if k > 0 else no_fit


def _cam(cam):
    return float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy)


@njit(nogil=True)
def _marks(valid, normals, fill, has, v0, v1):
    """Rows v0 .. v1 - 1 of :func:`_assembly.mark_row`."""
    for v in range(v0, v1):
        mark_row(valid[v], normals[v].reshape(-1), fill, has[v])


def sigma_from_fits(
    valid, normals, variance, stride, *, has=None, floor=None, fill=0.0, out=None, bands=whole
) -> np.ndarray:
    """Each normal's sigma (degrees; NaN where it is ``fill`` or not finite) from the angular variances of the fits
    its plane came from: ``variance`` (H / stride, W / stride), radians^2, NaN where a fitted pixel has no fit (as
    the adaptive fit's kernel records it); ``has``: which pixels hold a normal, as the kernel records it (default:
    read from ``normals``); ``floor`` (degrees, default ``FLOOR_DEG``) added in quadrature. ``bands``: rows on
    several threads (:mod:`surfnorm._bands`), the same result.
    """
    out = np.empty(valid.shape, np.float32) if out is None else out
    if has is None:
        has = np.empty(valid.shape, np.bool_)
        normals = np.ascontiguousarray(normals, np.float32)
        bands(lambda a, b: _marks(valid, normals, np.float32(fill), has, a, b), valid.shape[0])
    floor2 = float(FLOOR_DEG if floor is None else floor) ** 2
    if int(stride) == CELL:
        cells = (has, variance, floor2, float(NO_FIT_DEG), out)
        bands(lambda a, b: _spread_cells(*cells, a, b), valid.shape[0])
        return out
    args = (has, variance, int(stride), floor2, float(NO_FIT_DEG), out)
    bands(lambda a, b: _spread(*args, a, b), valid.shape[0])
    return out


# --- d2nt_v3: each pixel's best 3x3 plane ------------------------------------------------------------------------
#
# The kernels below index columns with unsigned integers: Numba then adds no wraparound of negative indices, and
# LLVM loads neighbouring columns as vectors (with signed indices it gathered them one element at a time, and the
# per-pixel pass ran 2.5x slower).


@njit(nogil=True, noalias=True, _nrt=False)
def _inputs_row(z, valid, y, lo, hi, dst):
    """Input row y's points per column, for the 3x3 fits: (1, w = 1/z, w^2) where valid, else 0, into ``dst``
    (3, W + 2) at columns 1 .. W (column u at u + 1; the pad columns 0 and W + 1, and a row y outside the frame,
    0). ``lo`` .. ``hi`` - 1: the columns that may hold valid pixels (the span of the row's; 0 elsewhere). Each
    row is read once for the three fitted rows that use it. Branch-free."""
    H = z.shape[0]
    dst[:, :] = 0.0
    if y < 0 or y >= H:
        return
    zr = z[y]
    ok_r = valid[y]
    c, s, ss = dst[0], dst[1], dst[2]
    one = np.uint64(1)
    for u in range(np.uint64(lo), np.uint64(hi)):
        ok = ok_r[u]
        w = select(ok, 1.0 / zr[u], 0.0)
        c[u + one] = select(ok, 1.0, 0.0)
        s[u + one] = w
        ss[u + one] = w * w


@njit(nogil=True, noalias=True, _nrt=False)
def _fits3_row(inputs, v, H, cam, c0, c1, col, dst):
    """Row v of the least-squares planes of w = 1/z over the valid pixels of each pixel's 3x3 window (the pixel
    itself valid or not), offsets from the centre as coordinates, for the columns c0 .. c1 - 1, into ``dst``
    (8, W + 2), column u at u + 1: rss / dof, n, g_u, g_v, w at the centre, and the plane's unit normal there
    (eq. (2); ``cam``: (fx, fy, cx, cy)). rss / dof is inf where fewer than 4 points or points on a line, in
    every other column (the pads included), and for v outside the frame (0 .. H - 1). ``inputs``:
    :func:`_inputs_row` of rows v - 1, v, v + 1, row y at y % 3; ``col`` is scratch (6, W + 2). The sums come
    from column sums of the three rows, then of three columns (separable). Branch-free."""
    fx, fy, cx, cy = cam
    dst[0, :] = np.inf
    if v < 0 or v >= H or c0 >= c1:
        return
    up, mid, dn = inputs[(v - 1) % 3], inputs[v % 3], inputs[(v + 1) % 3]
    one, two = np.uint64(1), np.uint64(2)
    # per column of the window's three rows (dy = -1, 0, +1): count, sum dy, sum dy^2, sum w, sum dy w, sum w^2
    for p in range(np.uint64(c0), np.uint64(c1 + 2)):
        col[0, p] = up[0, p] + mid[0, p] + dn[0, p]
        col[1, p] = dn[0, p] - up[0, p]
        col[2, p] = up[0, p] + dn[0, p]
        col[3, p] = up[1, p] + mid[1, p] + dn[1, p]
        col[4, p] = dn[1, p] - up[1, p]
        col[5, p] = up[2, p] + mid[2, p] + dn[2, p]
    for u in range(np.uint64(c0), np.uint64(c1)):
        # columns u - 1, u, u + 1 at col[:, u], col[:, u + 1], col[:, u + 2]: dx = -1, 0, +1
        l, c, r = u, u + one, u + two
        n = col[0, l] + col[0, c] + col[0, r]
        s_x = col[0, r] - col[0, l]
        s_xx = col[0, r] + col[0, l]
        s_y = col[1, l] + col[1, c] + col[1, r]
        s_xy = col[1, r] - col[1, l]
        s_yy = col[2, l] + col[2, c] + col[2, r]
        s_w = col[3, l] + col[3, c] + col[3, r]
        s_xw = col[3, r] - col[3, l]
        s_yw = col[4, l] + col[4, c] + col[4, r]
        s_ww = col[5, l] + col[5, c] + col[5, r]
        inv_n = 1.0 / max(n, 1.0)
        mx, my, mw = s_x * inv_n, s_y * inv_n, s_w * inv_n
        cxx = s_xx - s_x * mx
        cxy = s_xy - s_x * my
        cyy = s_yy - s_y * my
        cxw = s_xw - s_x * mw
        cyw = s_yw - s_y * mw
        cww = s_ww - s_w * mw
        det = cxx * cyy - cxy * cxy
        ok = (n >= 4.0) & (det > 1e-6 * cxx * cyy)
        inv_det = 1.0 / select(ok, det, 1.0)
        g_u = (cyy * cxw - cxy * cyw) * inv_det
        g_v = (cxx * cyw - cxy * cxw) * inv_det
        rss = cww - g_u * cxw - g_v * cyw
        a = mw - g_u * mx - g_v * my
        k0 = fx * g_u
        k1 = fy * g_v
        k2 = a - g_u * (u - cx) - g_v * (v - cy)
        inv = 1.0 / math.sqrt(max(k0 * k0 + k1 * k1 + k2 * k2, 1e-300))
        dst[0, c] = select(ok, select(rss > 0.0, rss, 0.0) / max(n - 3.0, 1.0), np.inf)
        dst[1, c] = n
        dst[2, c] = g_u
        dst[3, c] = g_v
        dst[4, c] = a
        dst[5, c] = k0 * inv
        dst[6, c] = k1 * inv
        dst[7, c] = k2 * inv


@pixel
def _take(best, fits, p, du, dv):
    """The 3x3 fit of column p of ``fits`` (offset (du, dv) from the pixel) where its residual per dof is less
    than the best so far, else ``best``: (rss / dof, n, g_u, g_v, a, o_u, o_v). Branch-free."""
    t, n, g_u, g_v, a, o_u, o_v = best
    c = fits[0, p]
    take = c < t
    return (
        select(take, c, t),
        select(take, fits[1, p], n),
        select(take, fits[2, p], g_u),
        select(take, fits[3, p], g_v),
        select(take, fits[4, p], a),
        select(take, -du, o_u),
        select(take, -dv, o_v),
    )


@pixel
def _turn(sums, fits, p, limit, m0, m1, m2):
    """(total, count) of ``sums`` plus, where the 3x3 fit of column p of ``fits`` is within ``limit`` (its
    residual per dof; -1: never), the squared sine of the angle between its plane's unit normal and (m0, m1, m2),
    and 1. Branch-free."""
    total, count = sums
    ok = fits[0, p] <= limit
    d = m0 * fits[5, p] + m1 * fits[6, p] + m2 * fits[7, p]
    t = 1.0 - d * d
    return total + select(ok & (t > 0.0), t, 0.0), count + select(ok, 1.0, 0.0)


@njit(nogil=True, noalias=True, _nrt=False)
def _sigma_row(z, valid, normals, fill, v, fits, cam, noise, gains, tail, lo, hi, out):
    """Row v of ``d2nt_v3``'s sigma, pixels lo .. hi - 1, into ``out`` (the row; see :func:`_d2nt_sigma`):
    ``normals``, row v's (3 W); ``fits``, :func:`_fits3_row` of rows v - 1, v, v + 1 (row y at y % 3); ``gains``:
    (gain, misfit_gain, significance, disagreement, turn); ``tail``: (floor2, no_fit). Branch-free."""
    fx, fy, cx, cy = cam
    f = math.sqrt(fx * fy)
    rho_z0, rho_inv_step, rho_t = noise
    gain, misfit_gain, significance, disagreement, turn = gains
    floor2, no_fit = tail
    up, mid, dn = fits[(v - 1) % 3], fits[v % 3], fits[(v + 1) % 3]
    zr = z[v]
    ok_r = valid[v]
    n_table = rho_t.shape[0]
    one, three = np.uint64(1), np.uint64(3)
    for u in range(np.uint64(lo), np.uint64(hi)):
        n0, n1, n2 = normals[three * u], normals[three * u + one], normals[three * u + one + one]
        ok = ok_r[u] & holds_normal(n0, n1, n2, fill)
        # of the windows centred on the pixel and with it at a corner, the one with the smallest residual per dof
        # (the first of equals, in this order)
        p = u + one
        s = (mid[0, p], mid[1, p], mid[2, p], mid[3, p], mid[4, p], 0.0, 0.0)
        s = _take(s, up, p - one, -1.0, -1.0)
        s = _take(s, up, p + one, 1.0, -1.0)
        s = _take(s, dn, p - one, -1.0, 1.0)
        best, nb, g_u, g_v, a, o_u, o_v = _take(s, dn, p + one, 1.0, 1.0)
        fitted = best < np.inf
        zp = select(ok, np.float64(zr[u]), 1.0)
        rho = rho_t[table_entry(zp, rho_z0, rho_inv_step, n_table)]  # the frame's noise at this depth
        s_w = rho / (zp * f)  # ... as the noise of w = 1/z
        noise2 = s_w * s_w
        g, va, c_u, c_v = fit_variance(
            select(fitted, best, 0.0), nb, 1.0, o_u, o_v, noise2, gain, misfit_gain, significance
        )
        var = angle_variance(n0, n1, n2, zp, u, v, fx, fy, cx, cy, g, va, c_u, c_v)
        # the plane's own normal at the pixel, and the sine of its angle to d2nt_v3's
        m0 = fx * g_u
        m1 = fy * g_v
        m2 = a + g_u * o_u + g_v * o_v - g_u * (u - cx) - g_v * (v - cy)
        m2n = m0 * m0 + m1 * m1 + m2 * m2
        dot = n0 * m0 + n1 * m1 + n2 * m2
        planar = m2n > 0.0
        var += select(planar, disagreement * max(1.0 - dot * dot / select(planar, m2n, 1.0), 0.0), 0.0)
        inv = 1.0 / math.sqrt(select(planar, m2n, 1.0))
        m0, m1, m2 = m0 * inv, m1 * inv, m2 * inv
        # the turn to the planes of its eight neighbours' windows that pass the adaptive fit's noise test
        limit = select(planar, noise_limit(zp, rho, f, KAPPA, RHO_FLOOR), -1.0)
        t = (0.0, 0.0)
        t = _turn(t, up, p - one, limit, m0, m1, m2)
        t = _turn(t, up, p, limit, m0, m1, m2)
        t = _turn(t, up, p + one, limit, m0, m1, m2)
        t = _turn(t, mid, p - one, limit, m0, m1, m2)
        t = _turn(t, mid, p + one, limit, m0, m1, m2)
        t = _turn(t, dn, p - one, limit, m0, m1, m2)
        t = _turn(t, dn, p, limit, m0, m1, m2)
        total, count = _turn(t, dn, p + one, limit, m0, m1, m2)
        sigma = _degrees(var + turn * total / max(count, 1.0), floor2)
        out[u] = select(ok, select(fitted, sigma, no_fit), np.nan)


@njit(nogil=True)
def _band_spans(valid, v0, v1):
    """The spans (:func:`valid_span`) of the valid pixels of rows v0 - 2 .. v1 + 2 around a band of rows
    v0 .. v1 - 1, row y at y - v0 + 2; (0, 0) for a row outside the frame."""
    H = valid.shape[0]
    spans = np.zeros((v1 - v0 + 5, 2), np.int64)
    for y in range(max(v0 - 2, 0), min(v1 + 3, H)):
        spans[y - v0 + 2, 0], spans[y - v0 + 2, 1] = valid_span(valid[y])
    return spans


@njit(nogil=True)
def _d2nt_sigma(z, valid, normals, fill, cam, noise, gains, floor2, no_fit, out, v0, v1):
    """Rows v0 .. v1 - 1 of ``d2nt_v3``'s sigma: of the 3x3 windows centred on the pixel and with it at a corner
    (``fits`` of :func:`_fits3_row`), the one with the smallest residual per dof (a pixel beside a
    discontinuity is judged by its own side, as DAG takes its gradient from the smoother side): its plane's
    variance at the pixel (:func:`fit_variance` at r = 1), plus ``disagreement`` times the squared sine of the angle
    between the normal and that plane's, plus ``turn`` times the mean squared sine of the angles to the planes of
    its eight neighbours' windows that fit within the noise (the adaptive fit's noise test: a surface that turns
    between pixels, as a mesh's facets do, is not where its pixels' planes say); at most ``MAX_DEG``; ``no_fit``
    where no window has a fit. ``gains``: (gain, misfit_gain, significance, disagreement, turn). Only the columns
    from a row's first to its last valid pixel are worked on."""
    H, W = z.shape
    tail = (floor2, no_fit)
    spans = _band_spans(valid, v0, v1)
    inputs = np.zeros((3, 3, W + 2))
    fits = np.zeros((3, 8, W + 2))
    col = np.empty((6, W + 2))

    def read(y):  # input row y, over its span
        _inputs_row(z, valid, y, spans[y - v0 + 2, 0], spans[y - v0 + 2, 1], inputs[y % 3])

    def fit(y):
        # the fits of row y over the span of the valid pixels of rows y - 1 .. y + 1: a window centred outside it
        # holds at most the three pixels of the span's end column, and has no fit
        c0, c1 = W, 0
        for k in range(y - v0 + 1, y - v0 + 4):
            a, b = spans[k, 0], spans[k, 1]
            if a < b:
                c0, c1 = min(c0, a), max(c1, b)
        _fits3_row(inputs, y, H, cam, c0, c1, col, fits[y % 3])

    read(v0 - 2)
    read(v0 - 1)
    for y in range(v0 - 1, v0 + 1):  # the fits of rows v0 - 1 and v0
        read(y + 1)
        fit(y)
    for v in range(v0, v1):
        read(v + 2)
        fit(v + 1)
        a, b = spans[v - v0 + 2, 0], spans[v - v0 + 2, 1]
        out[v, :a] = np.nan
        out[v, max(a, b) :] = np.nan
        if a < b:
            _sigma_row(z, valid, normals[v].reshape(-1), fill, v, fits, cam, noise, gains, tail, a, b, out[v])


# --- d2nt_v3's sigma on a clean frame -----------------------------------------------------------------------------
# Rows travel in rings, padded by two columns each side (column u at u + 2), in float32: a row's normals (planar,
# with whether each pixel holds one), its pairs' turn summed over five columns, its w = 1/z. Only the span of a
# row's valid pixels is worked on; the rest of each ring row is 0.


@njit(nogil=True, noalias=True, _nrt=False)
def _clean_normals_row(valid, normals, fill, y, lo, hi, dst):
    """Row y's normals into ``dst`` (4, W + 4): (n0, n1, n2, 1) where the pixel holds a normal, else 0 (and for a
    row outside the frame); ``lo`` .. ``hi`` - 1: the span of the row's valid pixels. Branch-free."""
    H = valid.shape[0]
    if y < 0 or y >= H or lo >= hi:
        dst[:, :] = 0.0
        return
    dst[:, : lo + 2] = 0.0
    dst[:, hi + 2 :] = 0.0
    nr = normals[y].reshape(-1)
    ok_r = valid[y]
    one, two, three = np.uint64(1), np.uint64(2), np.uint64(3)
    zero = np.float32(0.0)
    for u in range(np.uint64(lo), np.uint64(hi)):
        n0, n1, n2 = nr[three * u], nr[three * u + one], nr[three * u + two]
        h = ok_r[u] & holds_normal(n0, n1, n2, fill)
        dst[0, u + two] = select(h, n0, zero)
        dst[1, u + two] = select(h, n1, zero)
        dst[2, u + two] = select(h, n2, zero)
        dst[3, u + two] = select(h, np.float32(1.0), zero)


@pixel
def _pair(rows, a, p, b, q):
    """(squared sine of the angle between the normals at column p of ``rows[a]`` and q of ``rows[b]``, 1) where
    both pixels hold one, else (0, 0). Branch-free."""
    d = rows[a, 0, p] * rows[b, 0, q] + rows[a, 1, p] * rows[b, 1, q] + rows[a, 2, p] * rows[b, 2, q]
    both = rows[a, 3, p] * rows[b, 3, q]
    return both * max(np.float32(1.0) - d * d, np.float32(0.0)), both


@njit(nogil=True, noalias=True, _nrt=False)
def _clean_pairs_row(rows, y, lo, hi, scratch, dst):
    """Row y's pairs of neighbouring normals, each pixel's with its right and its lower neighbour, summed over five
    columns, into ``dst`` (2, W + 4): at column u, the sum over the pixels of columns u - 2 .. u + 2 of their
    pairs' squared sines, and the count of those pairs. ``rows``: :func:`_clean_normals_row` of rows y and y + 1
    (row y at y % 4); ``lo`` .. ``hi`` - 1: row y's span; ``scratch`` (2, W + 4). Branch-free."""
    P = dst.shape[1]
    if lo >= hi:
        dst[:, :] = 0.0
        return
    a, b = y % 4, (y + 1) % 4
    one, two = np.uint64(1), np.uint64(2)
    total, count = scratch[0], scratch[1]
    scratch[:, : lo + 2] = 0.0
    scratch[:, hi + 2 :] = 0.0
    for p in range(np.uint64(lo) + two, np.uint64(hi) + two):
        right, n_right = _pair(rows, a, p, a, p + one)
        down, n_down = _pair(rows, a, p, b, p)
        total[p] = right + down
        count[p] = n_right + n_down
    c0, c1 = max(lo, 2), min(hi + 4, P - 2)
    dst[:, :c0] = 0.0
    dst[:, c1:] = 0.0
    for p in range(np.uint64(c0), np.uint64(c1)):
        dst[0, p] = total[p - two] + total[p - one] + total[p] + total[p + one] + total[p + two]
        dst[1, p] = count[p - two] + count[p - one] + count[p] + count[p + one] + count[p + two]


@njit(nogil=True, noalias=True, _nrt=False)
def _clean_depth_row(z, valid, y, lo, hi, dst):
    """Row y's w = 1/z (0 where invalid) and its code, 2 valid, 1 invalid, 0 outside the frame, into ``dst``
    (2, W + 4); ``lo`` .. ``hi`` - 1: the span of the row's valid pixels. Branch-free."""
    H, W = z.shape
    if y < 0 or y >= H:
        dst[:, :] = 0.0
        return
    dst[0, : lo + 2] = 0.0
    dst[0, hi + 2 :] = 0.0
    dst[1, :2] = 0.0
    dst[1, 2 : lo + 2] = 1.0
    dst[1, hi + 2 : W + 2] = 1.0
    dst[1, W + 2 :] = 0.0
    zr = z[y]
    ok_r = valid[y]
    two = np.uint64(2)
    one_f, zero_f = np.float32(1.0), np.float32(0.0)
    for u in range(np.uint64(lo), np.uint64(hi)):
        ok = ok_r[u]
        dst[0, u + two] = select(ok, one_f / np.float32(zr[u]), zero_f)
        dst[1, u + two] = select(ok, np.float32(2.0), one_f)


@pixel
def _bend(e, depth, a, pa, b, pb, w, inv_w):
    """The larger of ``e`` and |w_a - 2 w + w_b| / w, the relative second difference of w = 1/z along the line
    through the pixel (``w``; ``inv_w`` its inverse) and its neighbours at column pa of ``depth[a]`` and pb of
    ``depth[b]``: 1 where either neighbour is invalid (a discontinuity), ``e`` where either is outside the
    frame. Branch-free."""
    half, one = np.float32(0.5), np.float32(1.0)
    ca, cb = depth[a, 1, pa], depth[b, 1, pb]
    d2 = abs(depth[a, 0, pa] - np.float32(2.0) * w + depth[b, 0, pb]) * inv_w
    d2 = select((ca > one + half) & (cb > one + half), d2, one)
    return max(e, select((ca > half) & (cb > half), d2, np.float32(0.0)))


@njit(nogil=True, noalias=True, _nrt=False)
def _clean_sigma_row(v, rows, depth, pairs, gains, lo, hi, out):
    """Row v of the clean model's sigma, pixels lo .. hi - 1, into ``out`` (the row; see :func:`_clean_sigma`):
    ``rows``, :func:`_clean_normals_row` with row v at v % 4; ``depth``, :func:`_clean_depth_row` of rows
    v - 1 .. v + 1 (row y at y % 3); ``pairs``, :func:`_clean_pairs_row` of rows v - 2 .. v + 2 (row y at
    y % 5); ``gains``: (f times the bend's gain, the turn's gain, the floor^2 in degrees^2, the largest sigma).
    Branch-free."""
    bend_gain, turn_gain, floor2, max_deg = gains
    bend_gain, turn_gain = np.float32(bend_gain), np.float32(turn_gain)
    floor2, max_deg, deg2 = np.float32(floor2), np.float32(max_deg), np.float32(_DEG2)
    has_r = rows[v % 4, 3]
    a, b, c = (v - 1) % 3, v % 3, (v + 1) % 3
    one, two = np.uint64(1), np.uint64(2)
    one_f = np.float32(1.0)
    for u in range(np.uint64(lo), np.uint64(hi)):
        p = u + two
        has = has_r[p] > np.float32(0.5)
        w = depth[b, 0, p]
        inv_w = one_f / select(has, w, one_f)
        e = _bend(np.float32(0.0), depth, a, p, c, p, w, inv_w)  # down the column
        e = _bend(e, depth, b, p - one, b, p + one, w, inv_w)  # along the row
        total = pairs[0, 0, p] + pairs[1, 0, p] + pairs[2, 0, p] + pairs[3, 0, p] + pairs[4, 0, p]
        count = pairs[0, 1, p] + pairs[1, 1, p] + pairs[2, 1, p] + pairs[3, 1, p] + pairs[4, 1, p]
        bend = bend_gain * e
        var = bend * bend + turn_gain * total / max(count, one_f)
        out[u] = select(has, min(math.sqrt(deg2 * var + floor2), max_deg), np.float32(np.nan))


@njit(nogil=True)
def _clean_sigma(z, valid, normals, fill, gains, out, v0, v1):
    """Rows v0 .. v1 - 1 of ``d2nt_v3``'s sigma on a clean frame (see :func:`d2nt_sigma`); ``gains``: see
    :func:`_clean_sigma_row`."""
    H, W = z.shape
    spans = _band_spans(valid, v0, v1)
    rows = np.zeros((4, 4, W + 4), np.float32)
    pairs = np.zeros((5, 2, W + 4), np.float32)
    depth = np.zeros((3, 2, W + 4), np.float32)
    scratch = np.zeros((2, W + 4), np.float32)

    def span(y):
        return spans[y - v0 + 2, 0], spans[y - v0 + 2, 1]

    _clean_normals_row(valid, normals, fill, v0 - 2, *span(v0 - 2), rows[(v0 - 2) % 4])
    _clean_depth_row(z, valid, v0 - 1, *span(v0 - 1), depth[(v0 - 1) % 3])
    _clean_depth_row(z, valid, v0, *span(v0), depth[v0 % 3])
    for y in range(v0 - 2, v1 + 2):
        _clean_normals_row(valid, normals, fill, y + 1, *span(y + 1), rows[(y + 1) % 4])
        _clean_pairs_row(rows, y, *span(y), scratch, pairs[y % 5])
        v = y - 2
        if v < v0:
            continue
        _clean_depth_row(z, valid, v + 1, *span(v + 1), depth[(v + 1) % 3])
        lo, hi = span(v)
        out[v, :lo] = np.nan
        out[v, max(lo, hi) :] = np.nan
        if lo < hi:
            _clean_sigma_row(v, rows, depth, pairs, gains, lo, hi, out[v])


def d2nt_sigma(z, valid, cam, normals, noise, *, clean=False, fill=0.0, out=None, bands=whole) -> np.ndarray:
    """``d2nt_v3``'s sigma (degrees; NaN where the normal is ``fill``): on a ``clean`` frame the clean model
    (:func:`_clean_sigma`, with ``CLEAN_BEND``, ``CLEAN_TURN``, ``CLEAN_FLOOR_DEG``, at most ``CLEAN_MAX_DEG``),
    else the 3x3 fits' (:func:`_d2nt_sigma`, with ``D2NT_GAIN``, ``D2NT_MISFIT_GAIN``, ``D2NT_DISAGREEMENT``,
    ``D2NT_TURN`` and ``FLOOR_DEG``); ``noise``: the frame's rho against depth as (z0, inv_step, table) of
    :func:`surfnorm.kernels._windows.radius_table` (not read on a clean frame)."""
    out = np.empty(z.shape, np.float32) if out is None else out
    normals = np.ascontiguousarray(normals, np.float32)
    if clean:
        f = math.sqrt(cam.fx * cam.fy)
        gains = (f * float(CLEAN_BEND), float(CLEAN_TURN), float(CLEAN_FLOOR_DEG) ** 2, float(CLEAN_MAX_DEG))
        args = (z, valid, normals, np.float32(fill), gains, out)
        bands(lambda a, b: _clean_sigma(*args, a, b), z.shape[0])
        return out
    args = (z, valid, normals, np.float32(fill), _cam(cam), noise)
    gains = (
        float(D2NT_GAIN),
        float(D2NT_MISFIT_GAIN),
        float(MISFIT_SIGNIFICANCE),
        float(D2NT_DISAGREEMENT),
        float(D2NT_TURN),
    )
    tail = (float(FLOOR_DEG) ** 2, float(NO_FIT_DEG))
    bands(lambda a, b: _d2nt_sigma(*args, gains, *tail, out, a, b), z.shape[0])
    return out


def sigma_map(method: str, record: dict, z, valid, cam, normals, fill, out, bands=whole) -> np.ndarray:
    """Each normal's sigma (degrees) into ``out`` after ``method`` ("auto", "adaptive_fit" or "d2nt_v3") wrote
    ``normals``; ``record``: what the fit recorded (see ``record`` of :func:`surfnorm.kernels.adaptive_fit.adaptive_fit`
    and :func:`surfnorm.kernels.auto.auto`; empty for ``d2nt_v3``).

    ``auto``'s blend weights the variances as it weights the normals; where only one of the two has a fit, its
    sigma alone; where its consistency check took d2nt_v3's normal (``record["took_d2nt"]``), d2nt_v3's sigma.
    """
    t = 1.0 if method == "adaptive_fit" else record.get("weight", 0.0)
    took = record.get("took_d2nt") if method == "auto" else None
    fit_alone = t == 1.0 and took is None
    if t > 0.0:
        # the kernel's own record of which pixels hold a normal, unless the blend or the check below changes them
        has = record["has"] if fit_alone else None
        fitted = sigma_from_fits(
            valid,
            normals,
            record["variance"],
            record["stride"],
            has=has,
            fill=fill,
            out=out if fit_alone else None,
            bands=bands,
        )
    if not fit_alone:
        profile = record.get("profile") or noise_profile(z, valid, math.sqrt(cam.fx * cam.fy))
        clean = adaptive_weight(profile) == 0.0
        noise = None  # the clean model does not read it
        if not clean:
            z0, inv_step, _, rho = radius_table(profile.depths, profile.rho)
            noise = (z0, inv_step, rho)
        d2nt = d2nt_sigma(
            z,
            valid,
            cam,
            normals,
            noise,
            clean=clean,
            fill=fill,
            out=out if t == 0.0 else None,
            bands=bands,
        )
    if t > 0.0 and not fit_alone:  # the variances weighted as the normals are; one alone where the other has no fit
        weight = t if took is None else np.where(took, 0.0, t)
        both = np.sqrt((1.0 - weight) * np.square(d2nt) + weight * np.square(fitted))
        only_d2nt = np.isnan(fitted) if took is None else np.isnan(fitted) | took
        out[...] = np.where(only_d2nt, d2nt, np.where(np.isnan(d2nt), fitted, both))
    return out
