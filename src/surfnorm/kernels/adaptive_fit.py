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
Noise correlated across pixels (a stereo matcher's, a camera SDK's smooth float
error) shows less in the second differences than in a wide window's residual:
kappa is then raised, up to 2x (:func:`~surfnorm.kernels.sensor_noise.kappa_gain`).
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

Every fourth row and column. Windows of a few pixels' radius or more, centred a pixel apart, share most of
their pixels, and so their planes. By default (``stride`` 4, ``CELL``) the windows are fitted on the pixels of
every fourth row and column only, a sixteenth of them, each window still holding every valid pixel in it. Every
pixel takes the planes of the four fitted pixels at the corners of its 4x4 cell, each carried to it: the mean of
those that predict its own w within the noise test's limit, weighted bilinearly by the pixel's place in the cell
(on a smooth surface, the plane interpolated to the pixel; a pixel on a fitted row or column reads the two on its
line, a fitted pixel its own plane), or, where none does, the one of them that predicts it closest (at an edge,
its own side's); where none of those has a plane, the closest of the four. Depth with too many pixels whose cell
has no valid corner (many holes) is fitted on every other row and column (``stride`` 2): every other pixel takes
the planes of the fitted pixels next to it (its 3x3 neighbourhood: the two on its left and right, or above and
below, or the four diagonal ones), their mean where they predict its w within the noise, else the closest, and
where none of them has a plane, the closest of the fitted pixels of its 5x5 neighbourhood. Depth with too many
pixels that no fitted pixel reaches even so (LiDAR scanlines: :func:`choose_stride`) is fitted at every pixel
(``stride`` 1). Any of the three on request. On the sensor benchmark's seven dense frames stride 4 gave angles
0.0-0.2 degrees lower than stride 2, and on the simulated sensors e_A from 0.4 % lower to 1.1 % higher.

Not local: the noise profile is a statistic of the whole frame, so masking a
region (or a hole) changes the samples it is measured from and can move the
chosen windows, and so normals, far from it (on a 3F2N frame in millimetres, a
10x10 hole moved 242 normals more than 10 pixels away). The normals do not
depend on the unit of depth.

Where each part is: the noise profile in :mod:`surfnorm.kernels.sensor_noise`; the radius tables and the
integral rows of the moments in :mod:`surfnorm.kernels._windows`; the assembly of strides 2 and 4 and eq. (2) in
:mod:`surfnorm.kernels._assembly`; the bands on threads in :mod:`surfnorm.kernels._schedule`; here, the fit
(1), the noise and edge tests, the widening and the kernel of a band of rows.
"""

from __future__ import annotations

import math

import numpy as np

from .._aot import ahead_of_time
from .._bands import whole
from .._config import njit, pixel, select

# The constants shared with surfnorm.torch._adaptive, with their meaning: surfnorm._constants (loads no Numba).
from .._constants import ALPHA, KAPPA, MAX_WINDOW, MIN_POINTS, N_WIDEN, RHO_FLOOR, SHIFTS, TIE
from ._assembly import (
    CELL,
    CELL_ROWS,
    cell_scale,
    emit_row,
    first_fitted_row,
    last_fitted_row,
    row_done,
    unit_normal,
)
from ._schedule import choose_stride, release, run_bands
from ._windows import (
    _BOXED,
    _COORDS,
    _COUNT,
    _N_MOMENTS,
    _W_SUMS,
    growth_table,
    make_rows,
    noise_limit,
    picked_sums,
    radius_table,
    table_entry,
    widen_table,
    window_sums,
)
from .sensor_noise import NoiseProfile, kappa_gain, noise_profile
from .uncertainty import (
    MISFIT_GAIN,
    MISFIT_SIGNIFICANCE,
    angle_variance_cov,
    correlated_share,
    fit_covariance,
    noise_gain,
)

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
    (floats, holding integers and half-integers exactly: int64 operands would not vectorise); as many pixels as
    ``a`` holds (the moment arrays may be wider)."""
    for u in range(a.shape[0]):
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
def window_moments(sums, W, v, cols, valid_row, dof, r_row, shifted, m, moments):
    """The coordinate moments (u', v', u'u', u'v', v'v') of each fitted pixel's window that is not the full square
    (where it has a fit: valid, ``dof`` > 0; radius ``r_row``, centre ``shifted`` from the pixel) into
    ``moments`` (5, fitted pixels), read again from the integral rows (``sums``). Its count is the fit's, dof + 3;
    a full square's moments are known (as in :func:`affine_fit`), and most windows of dense depth are one. The
    fitted pixel i is at column ``cols[i]``."""
    ring, slot, H, _, pos = sums
    _, shift_u, shift_v = shifted
    for i in range(r_row.shape[0]):
        r = r_row[i]
        if not (valid_row[i] and dof[i] > 0.0) or dof[i] + 3.0 == (2 * r + 1) * (2 * r + 1):
            continue
        window_sums(ring, slot, pos, H, W, v + int(shift_v[i]), cols[i] + int(shift_u[i]), r, _COORDS, m)
        for c in range(5):
            moments[c, i] = m[c + 1]


@njit(noalias=True, _nrt=False)
def variance_row(row, fit, window, noise, cam, gains, out_row):
    """Each fitted pixel of a row: its normal's angular variance (radians^2) from the fit its plane came from
    (:func:`surfnorm.kernels.uncertainty.fit_covariance`, :func:`~surfnorm.kernels.uncertainty.angle_variance_cov`),
    NaN where it has no fit. Branch-free.

    ``row``: (z_row, valid_row, x_row, v, y, cols), the fitted pixels' depth, validity and centred abscissae,
    the row, its centred ordinate and the fitted pixels' columns; ``fit``: (a, g_u, g_v, rss, dof); ``window``:
    (r_row, shifted, moments), the radius, the centre's offset (``shifted``: (record, shift_u, shift_v) of
    :func:`_edge_row`) and the coordinate moments (:func:`window_moments`; the count is dof + 3); ``noise``:
    (rho_table, t_row), the noise at each pixel's depth; ``gains`` as in :func:`_adaptive_fit_kernel`.
    """
    z_row, valid_row, x_row, v, y, cols = row
    r_row, shifted, moments = window
    rho_table, t_row = noise
    a, g_u, g_v, rss, dof = fit
    _, shift_u, shift_v = shifted
    fx, fy, cx, cy = cam
    f = math.sqrt(fx * fy)
    for i in range(out_row.shape[0]):
        ok = valid_row[i] & (dof[i] > 0.0)
        d = select(ok, dof[i], 1.0)
        zp = select(ok, z_row[i], 1.0)
        noise = rho_table[t_row[i]] / (zp * f)
        r = r_row[i]
        n = d + 3.0  # the fit's count (4 where it has none)
        full = n == (2 * r + 1) * (2 * r + 1)
        inv_n = 1.0 / max(n, 1.0)
        s_u = moments[0, i]
        s_v = moments[1, i]
        mu = select(full, x_row[i] + shift_u[i], s_u * inv_n)
        mv = select(full, y + shift_v[i], s_v * inv_n)
        c_full = n * (r * (r + 1)) * (1.0 / 3.0)
        cuu = select(full, c_full, moments[2, i] - s_u * mu)
        cuv = select(full, 0.0, moments[3, i] - s_u * mv)
        cvv = select(full, c_full, moments[4, i] - s_v * mv)
        g_uu, g_vv, g_uv, var_a, c_u, c_v = fit_covariance(
            rss[i] / d,
            n,
            cuu,
            cuv,
            cvv,
            x_row[i] - mu,
            y - mv,
            noise * noise,
            gains[0],
            gains[1],
            gains[2],
            gains[3],
            gains[4],
        )
        u = cols[i]
        nx, ny, nz = unit_normal(zp, a[i], g_u[i], g_v[i], u, v, fx, fy, cx, cy)
        out_row[i] = select(
            ok, angle_variance_cov(nx, ny, nz, zp, u, v, fx, fy, cx, cy, g_uu, g_vv, g_uv, var_a, c_u, c_v), np.nan
        )


#: The shifted windows of the edge test: the four quadrants (Kuwahara), each with the pixel at a corner.
_SHIFTS = np.array(SHIFTS, np.int64)


# --- the kernel: a band of rows ----------------------------------------------------------------------
#
# Per fitted row: each pixel's radius from its depth, grown where its window holds too few valid pixels
# (:func:`_grown_sums`); the fits and the noise test; the windows of the fits that pass widened while they
# still pass (:func:`_widened_sums`, :func:`widened_row`); the edge test on those that fail (:func:`_edge_row`);
# then the row's planes to the assembly (:func:`surfnorm.kernels._assembly.row_done`). ``sums`` is what reads a
# window's moments, (ring, slot, H, stride, pos): the ring of integral rows, integral row i at slot[i], and the
# columns' places ``pos`` (:mod:`surfnorm.kernels._windows`).


@pixel
def _start_radii(z_row, valid_row, tables, t_row, r_row, need, present):
    """Each fitted pixel's radius from its depth (``tables``: :func:`radius_table`'s) into ``r_row``, its table
    entry into ``t_row``, and what its window must pin into ``need`` (see :func:`_grown_sums`); ``present``: the
    radii of the valid pixels."""
    z0, inv_step, r_table, _ = tables
    n_table = r_table.shape[0]
    present[:] = False
    for u in range(z_row.shape[0]):
        t = table_entry(z_row[u], z0, inv_step, n_table)
        t_row[u] = t
        r0 = r_table[t]
        r_row[u] = r0
        need[u] = (2 * r0 + 1) * (2 * r0 + 1) * (r0 * (r0 + 1))
        if valid_row[u]:
            present[r0] = True


@pixel
def _grown_sums(sums, v, grow, r_max, cols, valid_row, r_row, need, present, pick, m_a, m_b, m_coords):
    """The window sums of row v's valid fitted pixels at their radii ``r_row``, radius by radius, into ``m_coords``
    and the returned array (``m_a`` or ``m_b``, the other one its scratch: :func:`picked_sums`).

    Sparse depth: a window grows (x1.5, ``grow``) until its valid pixels pin the slope at least half as well as
    the full window of the noise's radius r0 (sum of squared offsets ~ n r (r + 1) / 3 against ``need``), with
    at least MIN_POINTS of them; ``r_row`` and ``present`` follow.
    """
    ring, slot, H, stride, pos = sums
    m_src = m_a
    m_row = m_b
    first = True
    for r in range(1, r_max + 1):
        if not present[r]:
            continue
        count = 0
        for u in range(r_row.shape[0]):
            p = valid_row[u] & (r_row[u] == r)
            pick[u] = p
            count += p
        m_row, m_src = picked_sums(ring, slot, H, v, r, stride, pos, cols, pick, count, first, m_row, m_src, m_coords)
        first = False
        if r == r_max:
            continue
        r_big = grow[r]
        spread = float(r * (r + 1))
        grew = False
        for u in range(r_row.shape[0]):
            sparse = pick[u] & ((m_row[0, u] < MIN_POINTS) | (2.0 * m_row[0, u] * spread < need[u]))
            r_row[u] = select(sparse, r_big, r_row[u])
            grew |= sparse
        if grew:
            present[r_big] = True
    return m_row


@pixel
def _widened_sums(
    sums, v, widen, r_max, cols, r_row, passed, present, widened, tried, pick, r_try, r_try_f, m_c, m_d, m_coords
):
    """The window sums at the next radius (``widen``) of the pixels whose fit ``passed`` (at a radius of
    ``present``), into ``m_coords`` and the returned array (``m_c`` or ``m_d``): ``tried`` where they were taken,
    at radius ``r_try`` (``r_try_f`` as floats), ``widened`` the radii. Returns (that array, whether any was)."""
    ring, slot, H, stride, pos = sums
    for u in range(tried.shape[0]):
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
        for u in range(tried.shape[0]):
            p = passed[u] & (r_row[u] == r)
            pick[u] = p
            tried[u] |= p
            r_try[u] = select(p, r2, r_try[u])
            r_try_f[u] = select(p, r2_f, r_try_f[u])
            count += p
        if count == 0:
            continue
        widened[r2] = True
        m_try, m_old = picked_sums(ring, slot, H, v, r2, stride, pos, cols, pick, count, first, m_try, m_old, m_coords)
        first = False
    return m_try, not first


@pixel
def _edge_row(sums, W, v, y, cols, x_row, z_row, valid_row, fit, limit, r_row, counts, kappa, m, shifted):
    """The edge test on row v: a valid pixel whose fit (``fit``: a, g_u, g_v, rss, dof, updated in place) fails
    the noise test takes the best of the four quadrant windows of its radius (smallest residual per dof) among
    those whose plane passes through the pixel itself; ``counts``: the centred windows' counts; ``m`` scratch
    (_N_MOMENTS,). ``shifted``: (record, shift_u, shift_v): where recording, the chosen window's residual stays
    in rss and its offset goes to shift_u, shift_v (the centred window's is 0). The fitted pixel i is at column
    ``cols[i]``."""
    ring, slot, H, _, pos = sums
    a, g_u, g_v, rss, dof = fit
    record, shift_u, shift_v = shifted
    if record:
        shift_u[:] = 0.0
        shift_v[:] = 0.0
    for i in range(x_row.shape[0]):
        if not valid_row[i]:
            continue
        ok = dof[i] > 0.0
        if ok and rss[i] <= limit[i] * dof[i]:
            continue
        u = cols[i]
        x = x_row[i]
        r = r_row[i]
        # A candidate is consistent when its plane passes through the pixel itself (within kappa
        # times its residual or the noise): a thin part seen against a far background must not
        # take the background's plane because that one fits its own points better.
        w_p = 1.0 / z_row[i]
        best = max(rss[i] / dof[i], TIE * limit[i]) if ok else np.inf
        best_in = ok and (a[i] - w_p) ** 2 <= kappa * kappa * max(best, limit[i])
        n_min = max(6.0, 0.25 * counts[i])
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


#: A fitted row works on its valid pixels alone (compacted) where fewer than one in COMPACT of them are valid.
COMPACT = 2


@pixel
def _scatter(dst, empty, cols, stride, src):
    """dst[cols[i] // stride] = src[i], and ``empty`` elsewhere in ``dst``."""
    dst[:] = empty
    for i in range(src.shape[0]):
        dst[cols[i] // stride] = src[i]


@pixel
def _floats(n):
    """Five float64 rows of ``n``."""
    return np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n)


@pixel
def _flags(n):
    """Four bool rows of ``n``."""
    return np.empty(n, np.bool_), np.empty(n, np.bool_), np.empty(n, np.bool_), np.empty(n, np.bool_)


@pixel
def _ints(n):
    """Four int64 rows of ``n``."""
    return np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64)


@ahead_of_time
@njit(noalias=True)
def _adaptive_fit_kernel(z, valid, tables, steps, cam, options, work, out, v0, v1, stride, info, gains, has):
    """Rows v0 .. v1 - 1 of the normals (a row band: see :mod:`surfnorm._bands`).

    ``tables``: (z0, inv_step, radius, rho) of :func:`radius_table`; ``steps``: (grow, widen) of
    :func:`growth_table` and :func:`widen_table`; ``cam``: (fx, fy, cx, cy); ``options``: (n_widen, kappa,
    rho_floor, r_max, fill); ``work``: (ring, col_sums, pos, w_scratch, made), the ``ring`` that holds the integral
    rows up to ``made`` and ``col_sums`` the column sums after it (:func:`surfnorm.kernels._windows.prime`), ``pos``:
    :func:`surfnorm.kernels._windows.integral_positions`, ``w_scratch``: (W,).

    A fitted row with under half of its fitted pixels valid (``COMPACT``: sparse depth) works on those alone, each at
    its column (the window sums pixel by pixel), and hands its planes back at every fitted pixel: the same
    arithmetic, so the same bits as a sweep over every fitted pixel, which denser rows take (whole rows at a time).

    The windows are fitted on the pixels of every ``stride``-th row and column; with ``stride`` 2 every other
    pixel takes its plane from the fitted pixels around it (:mod:`surfnorm.kernels._assembly`), so a band fits
    the rows up to two beyond its own; with ``stride`` 4 every pixel from the corners of its cell, so a band fits
    from the top of its first row's cell to the bottom of its last row's.

    Integral rows are sums from row 0 down, so a band starting at v0 first sums the columns of the rows above the
    ones it reads, then makes the integral rows it reads (no fits: :func:`~surfnorm.kernels._windows.prime`): the
    same additions in the same order as one sweep, so the same bits; the price is that pass over rows
    0 .. v0 + 2 ``r_max``, mostly column sums (vectorised).

    ``info``: (0, 0) for nothing, or (fitted rows, fitted columns) float64, where fitted pixel (v, stride i) gets its
    normal's angular variance (radians^2, :mod:`surfnorm.kernels.uncertainty`) from the fit its plane came from
    (its residual, its window's points and offset; the noise at its depth; ``gains``: the noise's variance factor,
    the misfit's, the misfit's significance, the noise's correlated share and the noise a residual shows over the
    profile's, :mod:`surfnorm.kernels.uncertainty`),
    NaN where it has no fit. Only written (it changes no normal). ``has``: (0, 0), or (H, W) bool, where each
    pixel of the band's rows gets whether it holds a normal (:func:`surfnorm.kernels._assembly.mark_row`).
    """
    H, W = z.shape
    rho_table = tables[3]
    grow, widen = steps
    fx, fy, cx, cy = cam
    n_widen, kappa, rho_floor, r_max, fill = options
    ring, col_sums, pos, w_scratch, made = work
    slot = np.arange(H + 1) % ring.shape[0]
    sums = (ring, slot, H, stride, pos)
    sums_any = (ring, slot, H, 0, pos)  # a compacted row's pixels: any columns (picked_sums)
    n_fit = (W + stride - 1) // stride
    m = np.zeros(_N_MOMENTS)
    m_a, m_b = np.zeros((len(_BOXED), n_fit)), np.zeros((len(_BOXED), n_fit))
    m_c, m_d = np.zeros((len(_BOXED), n_fit)), np.zeros((len(_BOXED), n_fit))
    m_coords, m_coords2 = np.zeros((len(_COORDS), n_fit)), np.zeros((len(_COORDS), n_fit))
    # every fitted pixel of a row (its column, centred abscissa, depth and validity), and the valid ones of a row
    # that has few (compacted)
    x_all, x_few, z_all, z_few = _floats(n_fit)[:4]
    cols_all, cols_few = np.empty(n_fit, np.int64), np.empty(n_fit, np.int64)
    valid_all, valid_few = np.empty(n_fit, np.bool_), np.ones(n_fit, np.bool_)
    for i in range(n_fit):
        cols_all[i] = stride * i
        x_all[i] = stride * i - 0.5 * W
    # the row's planes at every fitted pixel, for the assembly, where the row was compacted
    a_all, g_u_all, g_v_all, dof_all, limit_all = _floats(n_fit)
    need_b, limit_b, r_float_b, r_try_f_b, var_b = _floats(n_fit)
    g_u_b, g_v_b, a_b, rss_b, dof_b = _floats(n_fit)
    g_u3_b, g_v3_b, a3_b, rss3_b, dof3_b = _floats(n_fit)
    pick_b, passed_b, tried_b, _ = _flags(n_fit)
    r_row_b, r_try_b, r_next_b, t_row_b = _ints(n_fit)
    record = info.shape[0] > 0
    shift_u_b, shift_v_b = np.zeros(n_fit), np.zeros(n_fit)
    moments = np.zeros((5, n_fit if record else 0))
    present = np.zeros(r_max + 2, np.bool_)
    widened = np.zeros(r_max + 2, np.bool_)
    f = math.sqrt(fx * fy)
    # the planes of the last three fitted rows: (a, g_u, g_v, ok) at every pixel (stride 1), or those and the
    # noise limit at full width (stride 2: expand_row); stride CELL's in single precision, with their eq. (2)
    # vectors (expand_cells)
    wide = stride <= 2
    cells = np.zeros((3, CELL_ROWS, 0 if wide else W + CELL), np.float32)
    fitted = (np.zeros((3, 5, W + 1 if wide else 0)), cells, cell_scale(tables[0]))
    none = (np.zeros((5, fitted[0].shape[2])), np.zeros((CELL_ROWS, fitted[1].shape[2]), np.float32))
    ok_row = np.empty(n_fit)
    # The fitted rows: every stride-th row of the frame, whatever the band; with stride 2 those that the band's
    # rows take planes from (rows up to two above and below).
    reach = stride - 1
    v_first = first_fitted_row(v0, stride)
    v_last = last_fitted_row(v1, H, stride)
    got = np.zeros(W, np.bool_)
    out_flat = out.reshape(H, 3 * W)
    band = (z, valid, v0, v1, stride, v_first, fitted, none, cam, fill, got, out_flat, has)
    for v in range(v_first, v_last + 1, stride):
        if made < min(H, v + 2 * r_max + 1):  # the integral rows of this row's windows (``made``: the last one)
            made = make_rows(z, valid, ring, col_sums, pos, w_scratch, made, min(H, v + 2 * r_max + 1), 0)
        y = v - 0.5 * H
        n_valid = 0
        for i in range(n_fit):
            z_all[i] = z[v, stride * i]
            valid_all[i] = valid[v, stride * i]
            n_valid += valid_all[i]
        if n_valid == 0:  # no fits (a LiDAR frame's upper rows): valid_all alone gives the fill and no planes
            if record:
                info[v // stride, :] = np.nan
            row_done(v, valid_all, a_all, g_u_all, g_v_all, dof_all, limit_all, ok_row, band)
            continue
        # A row with few valid fitted pixels (sparse depth) works on those alone, each at its column, with the same
        # arithmetic (the same bits); a denser row on every fitted pixel, whole rows at a time (they vectorise).
        few = COMPACT * n_valid < n_fit
        if few:
            n = 0
            for i in range(n_fit):
                if valid_all[i]:
                    z_few[n] = z_all[i]
                    x_few[n] = x_all[i]
                    cols_few[n] = cols_all[i]
                    n += 1
            z_row, valid_row, x_row, cols, row_sums = z_few[:n], valid_few[:n], x_few[:n], cols_few[:n], sums_any
        else:
            n = n_fit
            z_row, valid_row, x_row, cols, row_sums = z_all, valid_all, x_all, cols_all, sums
        need, limit, r_float, r_try_f = need_b[:n], limit_b[:n], r_float_b[:n], r_try_f_b[:n]
        g_u, g_v, a, rss, dof = g_u_b[:n], g_v_b[:n], a_b[:n], rss_b[:n], dof_b[:n]
        g_u3, g_v3, a3, rss3, dof3 = g_u3_b[:n], g_v3_b[:n], a3_b[:n], rss3_b[:n], dof3_b[:n]
        pick, passed, tried = pick_b[:n], passed_b[:n], tried_b[:n]
        r_row, r_try, r_next, t_row = r_row_b[:n], r_try_b[:n], r_next_b[:n], t_row_b[:n]
        shifted = (record, shift_u_b[:n], shift_v_b[:n])
        _start_radii(z_row, valid_row, tables, t_row, r_row, need, present)
        m_row = _grown_sums(row_sums, v, grow, r_max, cols, valid_row, r_row, need, present, pick, m_a, m_b, m_coords)
        for u in range(n):
            r_float[u] = r_row[u]
        fit_row(m_row, m_coords, r_float, x_row, y, g_u, g_v, a, rss, dof)
        # The noise test: a fit is consistent with the noise when its residual per degree of
        # freedom is at most the limit (kappa sigma_w)^2.
        for u in range(n):
            limit[u] = noise_limit(z_row[u], rho_table[t_row[u]], f, kappa, rho_floor)
            passed[u] = valid_row[u] & (dof[u] > 0.0) & (rss[u] <= limit[u] * dof[u])
        # Wider where the data allow: a fit that passes is tried on a window twice as wide, kept
        # while it still passes (planes get wide windows, curved surfaces and edges keep theirs).
        for _ in range(n_widen):
            m_try, any_tried = _widened_sums(
                row_sums,
                v,
                widen,
                r_max,
                cols,
                r_row,
                passed,
                present,
                widened,
                tried,
                pick,
                r_try,
                r_try_f,
                m_c,
                m_d,
                m_coords2,
            )
            if not any_tried:
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
        fit = (a, g_u, g_v, rss, dof)
        _edge_row(row_sums, W, v, y, cols, x_row, z_row, valid_row, fit, limit, r_row, m_row[0], kappa, m, shifted)
        if record:
            window_moments(row_sums, W, v, cols, valid_row, dof, r_row, shifted, m, moments)
            row = (z_row, valid_row, x_row, v, y, cols)
            window = (r_row, shifted, moments)
            var_row = var_b[:n] if few else info[v // stride]
            variance_row(row, fit, window, (rho_table, t_row), cam, gains, var_row)
            if few:
                _scatter(info[v // stride], np.nan, cols, stride, var_row)
        if few:  # the planes at every fitted pixel again (none where invalid)
            _scatter(dof_all, 0.0, cols, stride, dof)
            for c in range(n):
                i = cols[c] // stride
                a_all[i], g_u_all[i], g_v_all[i], limit_all[i] = a[c], g_u[c], g_v[c], limit[c]
            row_done(v, valid_all, a_all, g_u_all, g_v_all, dof_all, limit_all, ok_row, band)
        else:
            row_done(v, valid_row, a, g_u, g_v, dof, limit, ok_row, band)
    # stride 2: the frame's last rows, if in the band; 3 or more: the rows of the last fitted row's cell
    lo, hi = (v_last + 1 - reach, v_last + 1 + reach) if stride <= 2 else (v_last, v_last + stride)
    for o in range(lo, hi):
        if v0 <= o < v1 and o < H:
            emit_row(z, valid, o, stride, fitted, v_first, v_last, none, cam, fill, got, out_flat, has)


#: ``info`` of :func:`_adaptive_fit_kernel` when nothing is recorded, its ``gains`` and ``has`` then.
_NO_INFO = np.empty((0, 0))
_NO_GAINS = np.zeros(5)
_NO_HAS = np.empty((0, 0), np.bool_)


class FitPlan:
    """One frame's adaptive fit, in the three steps that :func:`surfnorm.kernels._schedule.run_bands` runs:
    :meth:`measure` the noise, :meth:`tables` from it, :meth:`fit` a band of rows. :func:`adaptive_fit` runs them
    as they are; ``auto`` decides between :meth:`tables` and nothing once the noise is known. The arguments are
    :func:`adaptive_fit`'s."""

    def __init__(
        self,
        z,
        valid,
        cam,
        out,
        *,
        window=None,
        max_window: int = MAX_WINDOW,
        alpha: float = ALPHA,
        kappa: float = KAPPA,
        fill: float = 0.0,
        profile=None,
        stride=None,
        record: dict | None = None,
    ):
        self.z, self.valid, self.out, self.profile, self.record = z, valid, out, profile, record
        self.window, self.max_window, self.alpha, self.kappa = window, max_window, alpha, float(kappa)
        self.f = math.sqrt(cam.fx * cam.fy)
        self.r_max = (max_window - 1) // 2
        self.stride = choose_stride(valid) if stride is None else stride
        self.sparse = self.stride == 1 if stride is None else None  # (the noise profile's, when it is measured here)
        self.key = (z.shape, self.stride, max_window, window)  # the frame's kind, for the bands' balance
        H, W = z.shape
        if record is None:
            self.info, self.gains, self.has = _NO_INFO, _NO_GAINS, _NO_HAS
        else:  # every fitted row, and every row, is written by a band
            self.info = np.empty(((H + self.stride - 1) // self.stride, (W + self.stride - 1) // self.stride))
            # the noise's variance factor, set once the profile is known; misfit's; significance; the correlated share;
            # the noise a residual shows over the profile's (kappa_gain squared)
            self.gains = np.zeros(5)
            self.gains[1:3] = MISFIT_GAIN, MISFIT_SIGNIFICANCE
            self.has = np.empty((H, W), np.bool_)
            record.update(stride=self.stride, variance=self.info, has=self.has)
        self.steps = (growth_table(self.r_max), widen_table(self.r_max))
        self.cam = (float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy))
        self.options = (N_WIDEN, float(kappa), RHO_FLOOR, self.r_max, np.float32(fill))

    def measure(self, offers) -> NoiseProfile:
        """The frame's noise profile: ``profile`` as given (called, if a function), or :func:`noise_profile`."""
        if self.profile is None:
            return noise_profile(self.z, self.valid, self.f, offers, sparse=self.sparse)
        return self.profile() if callable(self.profile) else self.profile

    def tables(self, p: NoiseProfile, fit: bool = True):
        """The radius and noise tables of profile ``p`` (:func:`radius_table`), or None where not ``fit``; either way
        ``p`` is recorded (``record``)."""
        if self.record is None and not fit:
            return None
        gain = kappa_gain(p)  # the noise test's kappa for this frame's noise: wider where the noise is correlated
        if self.record is not None:
            self.record["profile"] = p
            self.gains[0] = noise_gain(p)
            self.gains[3] = correlated_share(p)
            self.gains[4] = gain * gain
        if not fit:
            return None
        # set before the bands fit, which wait for these tables
        n_widen, _, rho_floor, r_max, fill = self.options
        self.options = (n_widen, self.kappa * gain, rho_floor, r_max, fill)
        return radius_table(p.depths, p.rho, alpha=self.alpha, window=self.window, max_window=self.max_window)

    def fit(self, v0: int, v1: int, work, tables) -> None:
        """Rows v0 .. v1 - 1 (:func:`_adaptive_fit_kernel`)."""
        _adaptive_fit_kernel(
            self.z,
            self.valid,
            tables,
            self.steps,
            self.cam,
            self.options,
            work,
            self.out,
            v0,
            v1,
            self.stride,
            self.info,
            self.gains,
            self.has,
        )


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
    stride=None,
    bands=whole,
    record: dict | None = None,
) -> np.ndarray:
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
        (kappa sigma_w)^2 is replaced by the best shifted window. Multiplied by
        the frame's :func:`~surfnorm.kernels.sensor_noise.kappa_gain` (1, up to 2
        where the noise is correlated across pixels).
    fill : float
        Value of pixels without a normal.
    profile : NoiseProfile, callable or None
        The frame's :func:`noise_profile` when the caller has it already, or a function that returns it
        (``Part.result``: measured by the first band that needs it). None: measured here. Either way, with
        several bands, the one on the calling thread measures it while the others make the integral rows
        above their own rows, which do not depend on it, and then take the calling band's first integral rows
        and parts of its measuring (:class:`surfnorm._bands.Offers`).
    stride : 1, 2, 4 or None
        1: every pixel's own window. 2: windows on the pixels of the even rows and columns; every other
        pixel takes the planes of the fitted pixels next to it: the mean of those that pass through its
        depth within their noise limit, else the closest one (:func:`assembled_row`); a quarter of the
        fits. 4: windows on every fourth row and column; every pixel takes the planes of its 4x4 cell's
        corners, their bilinear mean where they pass through its depth within their noise limit, else the
        closest (:func:`cell_row`); a sixteenth of the fits. None (default): 4 on dense depth, 2 on depth with
        many holes, 1 on sparse depth (:func:`choose_stride`).
    bands : callable
        How rows are split over threads (see :mod:`surfnorm._bands`); each band has its own ring of
        integral rows.
    record : dict, optional
        Filled with what :mod:`surfnorm.kernels.uncertainty` needs: ``"profile"`` (the noise profile),
        ``"stride"`` and ``"variance"`` (each fitted pixel's angular variance: see ``info`` of
        :func:`_adaptive_fit_kernel`), with the gains ``FIT_GAIN`` and ``MISFIT_GAIN`` of that module, and
        ``"has"``: (H, W) bool, which pixels hold a normal.
        None (default): nothing recorded, nothing spent on it.
    """
    frame = FitPlan(
        z,
        valid,
        cam,
        out,
        window=window,
        max_window=max_window,
        alpha=alpha,
        kappa=kappa,
        fill=fill,
        profile=profile,
        stride=stride,
        record=record,
    )
    run_bands(frame, bands)
    return out
