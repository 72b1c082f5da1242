"""Averaging of the normals of the triangles around a pixel: AreaWeighted, AngleWeighted.

The averaging-based estimators of Table I of Feng et al. (D2NT, ICRA 2023),
after Klasing et al. (ICRA 2009) and Jin et al. (2005). Eq. 2:

    n_i = 1/k sum_j w_j (r_ij x r_i,j+1) / ||r_ij x r_i,j+1||,   r_ij = q_ij - p_i,  r_i,k+1 = r_i1

over the k = 8 neighbours q_ij of p_i in its 8-neighbourhood, taken as a
ring. The weight w_j is the triangle's area, 1/2 ||r_ij x r_i,j+1||
(AreaWeighted), or its angle at p_i, acos(<r_ij, r_i,j+1> / (||r_ij|| ||r_i,j+1||))
(AngleWeighted, computed as atan2(||r_ij x r_i,j+1||, <r_ij, r_i,j+1>), the
same angle without acos's loss of precision near 0, by a polynomial good to
3e-13 rad: 8 libm calls per pixel would cost more than everything else). The sum is then scaled to
unit length (1/k and 1/2 change no direction).

Ring order (:data:`RING`, as (dv, du) pixel steps): right, up-right, up,
up-left, left, down-left, down, down-right, i.e. counter-clockwise as the
image is displayed (v down). With x right and y down, r_1 x r_2 for
r_1 ~ +x (right) and r_2 ~ -y (up) is ~ -z: every triangle normal faces the
camera. It does so exactly, not only on fronto-parallel walls: for points
p = z K^-1 [u, v, 1]^T with z > 0, (q_j - p) x (q_j+1 - p) . p =
det[p, q_j, q_j+1] has the sign of the pixel triangle's orientation, which the
ring fixes; so no sign needs choosing afterwards and n . p < 0.

Invalid depth: a triangle needs both of its ring neighbours valid (a
neighbour outside the image counts as invalid); a pixel with no triangle left,
or invalid itself, gets the fill value.
"""

from __future__ import annotations

import math

import numpy as np

from .._bands import whole
from .._config import njit, pixel, select
from ._rows import point_cloud, unit_or_fill, valid_span

__all__ = ["area_weighted", "angle_weighted", "RING"]

#: The 8-neighbourhood ring, (dv, du): counter-clockwise on screen, starting at the right neighbour.
RING = ((0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1), (1, 0), (1, 1))

# atan(x) = x * sum_k _ATAN[k] x^(2k) for |x| <= tan(pi/8): a least-squares fit on Chebyshev nodes of
# atan(sqrt(y)) / sqrt(y), y in [0, tan(pi/8)^2]; largest error 3e-13 rad (tested against np.arctan2).
_ATAN = (
    0.9999999999992706,
    -0.3333333327838444,
    0.19999993188896323,
    -0.14285391260192437,
    0.11103534935103436,
    -0.08993217486701027,
    0.06977006279223774,
    -0.03770175791065335,
)
_TAN_PI_8 = math.tan(math.pi / 8)


@pixel
def angle_from(s, c):
    """The angle atan2(s, c) in [0, pi] for s >= 0, to 3e-13 rad, without a libm call; 0 for (0, 0).

    Reduced to atan(x), |x| <= tan(pi/8): with a = min(s, |c|), b = max(s, |c|),
    atan(a / b) = a / b, or pi/4 + atan((a - b) / (a + b)) when a / b > tan(pi/8).
    Written as selects, not branches: the branches are unpredictable from one triangle to the next.
    """
    abs_c = abs(c)
    a, b = min(s, abs_c), max(s, abs_c)
    big = a > _TAN_PI_8 * b
    num = select(big, a - b, a)
    den = select(big, a + b, b)
    x = num / select(den > 0.0, den, 1.0)
    y = x * x
    atan_x = x * (
        _ATAN[0]
        + y
        * (_ATAN[1] + y * (_ATAN[2] + y * (_ATAN[3] + y * (_ATAN[4] + y * (_ATAN[5] + y * (_ATAN[6] + y * _ATAN[7]))))))
    )
    theta = atan_x + select(big, 0.25 * math.pi, 0.0)  # atan(a / b), in [0, pi/4]
    theta = select(s > abs_c, 0.5 * math.pi - theta, theta)
    return select(c < 0.0, math.pi - theta, theta)


@pixel
def cross(a_x, a_y, a_z, b_x, b_y, b_z):
    """a x b."""
    return a_y * b_z - a_z * b_y, a_z * b_x - a_x * b_z, a_x * b_y - a_y * b_x


@pixel
def offset(q_x, q_y, q_z, q_ok, p_x, p_y, p_z):
    """r = q - p for a ring neighbour q (values read beforehand); 0 when q is invalid (q_ok == 0).

    A zero r makes both triangles that use it vanish (zero cross product), which is how a triangle
    needs both of its neighbours: weighting by 0 instead of branching is several times faster.
    """
    w = select(q_ok != 0, 1.0, 0.0)
    return (q_x - p_x) * w, (q_y - p_y) * w, (q_z - p_z) * w


@pixel
def area_term(a_x, a_y, a_z, b_x, b_y, b_z):
    """AreaWeighted's term of eq. 2: w_j unit(r_j x r_j+1) with w_j = ||r_j x r_j+1|| / 2, i.e. (r_j x r_j+1) / 2."""
    c_x, c_y, c_z = cross(a_x, a_y, a_z, b_x, b_y, b_z)
    return 0.5 * c_x, 0.5 * c_y, 0.5 * c_z


@pixel
def angle_term(a_x, a_y, a_z, b_x, b_y, b_z):
    """AngleWeighted's term of eq. 2: the angle between r_j and r_j+1 times unit(r_j x r_j+1); 0 without a triangle."""
    c_x, c_y, c_z = cross(a_x, a_y, a_z, b_x, b_y, b_z)
    area2 = math.sqrt(c_x * c_x + c_y * c_y + c_z * c_z)  # ||r_j x r_j+1||; 0 without a triangle
    # w_j / ||c||, and 0 (no triangle) where c = 0
    w = angle_from(area2, a_x * b_x + a_y * b_y + a_z * b_z) / select(area2 > 0.0, area2, math.inf)
    return w * c_x, w * c_y, w * c_z


# Both kernels go row by row, and along a row pixel by pixel with the 8 triangles of the ring in
# registers: each ring offset is computed once (it serves two triangles), the sum never goes through
# memory, and the loop has no branches (invalid neighbours are weighted 0, selects instead of ifs),
# so the compiler vectorises it over pixels. The sums are taken in the order of eq. 2 (j = 1 .. 8)
# from 0, as the naive reference does.


def _make_row(term):
    """The row function of an averaging kernel whose triangle term (a @pixel helper) is ``term``."""

    def averaging_row(X, Y, Z, OK, v, fill, out):
        """out[v - 1, 3 u : 3 u + 3] for every u: row v of the padded cloud X, Y, Z (planes), OK (validity as uint8).

        ``out`` is the output as (H, 3 W): with a constant stride of 3 the stores vectorise (as (H, W, 3)
        the stride is a run-time value and the loop stayed scalar).
        """
        W = out.shape[1] // 3
        # Only the columns [a, b) from the first to the last valid pixel of the row are computed: an
        # invalid pixel gets the fill value whatever its neighbours (a masked-out background costs nothing).
        a, b = valid_span(OK[v, 1 : W + 1])
        row_out = out[v - 1]
        for i in range(3 * a):
            row_out[i] = fill
        for i in range(3 * b, 3 * W):
            row_out[i] = fill
        # Views from column a - 1 (padded a), so that the loop index starts at 0.
        x_u, x_m, x_d = X[v - 1, a:], X[v, a:], X[v + 1, a:]
        y_u, y_m, y_d = Y[v - 1, a:], Y[v, a:], Y[v + 1, a:]
        z_u, z_m, z_d = Z[v - 1, a:], Z[v, a:], Z[v + 1, a:]
        k_u, k_m, k_d = OK[v - 1, a:], OK[v, a:], OK[v + 1, a:]
        o = row_out[3 * a :]
        for u in range(b - a):
            p_x, p_y, p_z = x_m[u + 1], y_m[u + 1], z_m[u + 1]
            # RING: right, up-right, up, up-left, left, down-left, down, down-right
            r0 = offset(x_m[u + 2], y_m[u + 2], z_m[u + 2], k_m[u + 2], p_x, p_y, p_z)
            r1 = offset(x_u[u + 2], y_u[u + 2], z_u[u + 2], k_u[u + 2], p_x, p_y, p_z)
            r2 = offset(x_u[u + 1], y_u[u + 1], z_u[u + 1], k_u[u + 1], p_x, p_y, p_z)
            r3 = offset(x_u[u], y_u[u], z_u[u], k_u[u], p_x, p_y, p_z)
            r4 = offset(x_m[u], y_m[u], z_m[u], k_m[u], p_x, p_y, p_z)
            r5 = offset(x_d[u], y_d[u], z_d[u], k_d[u], p_x, p_y, p_z)
            r6 = offset(x_d[u + 1], y_d[u + 1], z_d[u + 1], k_d[u + 1], p_x, p_y, p_z)
            r7 = offset(x_d[u + 2], y_d[u + 2], z_d[u + 2], k_d[u + 2], p_x, p_y, p_z)
            t_x, t_y, t_z = term(r0[0], r0[1], r0[2], r1[0], r1[1], r1[2])
            n_x, n_y, n_z = 0.0 + t_x, 0.0 + t_y, 0.0 + t_z
            t_x, t_y, t_z = term(r1[0], r1[1], r1[2], r2[0], r2[1], r2[2])
            n_x, n_y, n_z = n_x + t_x, n_y + t_y, n_z + t_z
            t_x, t_y, t_z = term(r2[0], r2[1], r2[2], r3[0], r3[1], r3[2])
            n_x, n_y, n_z = n_x + t_x, n_y + t_y, n_z + t_z
            t_x, t_y, t_z = term(r3[0], r3[1], r3[2], r4[0], r4[1], r4[2])
            n_x, n_y, n_z = n_x + t_x, n_y + t_y, n_z + t_z
            t_x, t_y, t_z = term(r4[0], r4[1], r4[2], r5[0], r5[1], r5[2])
            n_x, n_y, n_z = n_x + t_x, n_y + t_y, n_z + t_z
            t_x, t_y, t_z = term(r5[0], r5[1], r5[2], r6[0], r6[1], r6[2])
            n_x, n_y, n_z = n_x + t_x, n_y + t_y, n_z + t_z
            t_x, t_y, t_z = term(r6[0], r6[1], r6[2], r7[0], r7[1], r7[2])
            n_x, n_y, n_z = n_x + t_x, n_y + t_y, n_z + t_z
            t_x, t_y, t_z = term(r7[0], r7[1], r7[2], r0[0], r0[1], r0[2])
            n_x, n_y, n_z = n_x + t_x, n_y + t_y, n_z + t_z
            o[3 * u], o[3 * u + 1], o[3 * u + 2], _ = unit_or_fill(n_x, n_y, n_z, k_m[u + 1] != 0, fill)

    return njit(noalias=True, _nrt=False)(averaging_row)


_area_weighted_row = _make_row(area_term)
_angle_weighted_row = _make_row(angle_term)


@njit
def _area_weighted_kernel(P, valid, fill, out, v0, v1):
    """AreaWeighted: w_j * unit(r_j x r_j+1) with w_j = ||r_j x r_j+1|| / 2 is (r_j x r_j+1) / 2 (rows v0 .. v1 - 1)."""
    ok, flat = valid.view(np.uint8), out.reshape(out.shape[0], out.shape[1] * 3)
    for v in range(v0 + 1, v1 + 1):
        _area_weighted_row(P[0], P[1], P[2], ok, v, fill, flat)


@njit
def _angle_weighted_kernel(P, valid, fill, out, v0, v1):
    """AngleWeighted: w_j = the angle between r_j and r_j+1 at p, times the unit triangle normal (rows v0 .. v1 - 1)."""
    ok, flat = valid.view(np.uint8), out.reshape(out.shape[0], out.shape[1] * 3)
    for v in range(v0 + 1, v1 + 1):
        _angle_weighted_row(P[0], P[1], P[2], ok, v, fill, flat)


def _run(kernel, z, valid, cam, out, fill, bands):
    # The kernels write rows of out as flat (3 W) views, which needs out C-contiguous; another layout
    # goes through a temporary. Two stages in row bands: the cloud, then the normals (halo: 1 row of the cloud).
    target = out if out.flags.c_contiguous else np.empty(out.shape, np.float32)
    P, P_valid = point_cloud(z, valid, cam, pad=1, bands=bands)
    fill32 = np.float32(fill)
    bands(lambda a, b: kernel(P, P_valid, fill32, target, a, b), z.shape[0])
    if target is not out:
        out[...] = target
    return out


def area_weighted(z, valid, cam, out, *, fill=0.0, bands=whole):
    """AreaWeighted (eq. 2, Table I): triangle normals around p weighted by triangle area."""
    return _run(_area_weighted_kernel, z, valid, cam, out, fill, bands)


def angle_weighted(z, valid, cam, out, *, fill=0.0, bands=whole):
    """AngleWeighted (eq. 2, Table I): triangle normals around p weighted by their angle at p."""
    return _run(_angle_weighted_kernel, z, valid, cam, out, fill, bands)
