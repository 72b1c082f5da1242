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

from ._config import njit, pixel
from .plane_fit import point_cloud

__all__ = ["area_weighted", "angle_weighted", "RING"]

#: The 8-neighbourhood ring, (dv, du): counter-clockwise on screen, starting at the right neighbour.
RING = ((0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1), (1, 0), (1, 1))
# The same as arrays, closed (the 9th entry repeats the 1st) so that a triangle is (j, j + 1).
_RING_DV = np.array([dv for dv, _ in RING + RING[:1]], dtype=np.int64)
_RING_DU = np.array([du for _, du in RING + RING[:1]], dtype=np.int64)

# atan(x) = x * sum_k _ATAN[k] x^(2k) for |x| <= tan(pi/8): a least-squares fit on Chebyshev nodes of
# atan(sqrt(y)) / sqrt(y), y in [0, tan(pi/8)^2]; largest error 3e-13 rad (tested against np.arctan2).
_ATAN = (0.9999999999992706, -0.3333333327838444, 0.19999993188896323, -0.14285391260192437,
         0.11103534935103436, -0.08993217486701027, 0.06977006279223774, -0.03770175791065335)
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
    num = a - b if big else a
    den = a + b if big else b
    x = num / (den if den > 0.0 else 1.0)
    y = x * x
    atan_x = x * (_ATAN[0] + y * (_ATAN[1] + y * (_ATAN[2] + y * (_ATAN[3] + y * (_ATAN[4] + y * (
        _ATAN[5] + y * (_ATAN[6] + y * _ATAN[7])))))))
    theta = atan_x + (0.25 * math.pi if big else 0.0)  # atan(a / b), in [0, pi/4]
    theta = 0.5 * math.pi - theta if s > abs_c else theta
    return math.pi - theta if c < 0.0 else theta


@pixel
def ring_offset(P, valid, v, u, j):
    """r_j = q_j - p for ring neighbour j of p = (v, u) in the padded cloud; 0 when q_j is invalid.

    A zero r_j makes both triangles that use it vanish (zero cross product), which is how a
    triangle needs both of its neighbours: weighting by 0 instead of branching is several times faster.
    """
    q_v, q_u = v + _RING_DV[j], u + _RING_DU[j]
    w = 1.0 if valid[q_v, q_u] else 0.0
    return (P[0, q_v, q_u] - P[0, v, u]) * w, (P[1, q_v, q_u] - P[1, v, u]) * w, (P[2, q_v, q_u] - P[2, v, u]) * w


@pixel
def cross(a_x, a_y, a_z, b_x, b_y, b_z):
    """a x b."""
    return a_y * b_z - a_z * b_y, a_z * b_x - a_x * b_z, a_x * b_y - a_y * b_x


@pixel
def write_sum(out, v, u, n_x, n_y, n_z, ok, fill):
    """Store n / ||n||, or the fill value when p is invalid or no triangle contributed (n = 0)."""
    norm = math.sqrt(n_x * n_x + n_y * n_y + n_z * n_z)
    if ok and norm > 0.0 and math.isfinite(norm):
        out[v, u, 0] = n_x / norm
        out[v, u, 1] = n_y / norm
        out[v, u, 2] = n_z / norm
    else:
        out[v, u, 0] = fill
        out[v, u, 1] = fill
        out[v, u, 2] = fill


# Both kernels go row by row: for each triangle j of the ring, over all pixels of the row. That inner
# loop has no branches (invalid neighbours are weighted 0, selects instead of ifs), so the compiler
# vectorises it (AngleWeighted pixel by pixel, 8 triangles each, was 2x slower).

@njit
def _area_weighted_kernel(P, valid, fill, out):
    """AreaWeighted: w_j * unit(r_j x r_j+1) with w_j = ||r_j x r_j+1|| / 2 is (r_j x r_j+1) / 2."""
    H, W = out.shape[:2]
    n = np.empty((3, W))  # the sum of eq. 2 along one row
    for o_v in range(H):
        v = o_v + 1  # the row in the padded cloud
        n[:, :] = 0.0
        for j in range(8):  # the triangle (p, q_j, q_j+1)
            for o_u in range(W):
                a_x, a_y, a_z = ring_offset(P, valid, v, o_u + 1, j)
                b_x, b_y, b_z = ring_offset(P, valid, v, o_u + 1, j + 1)
                c_x, c_y, c_z = cross(a_x, a_y, a_z, b_x, b_y, b_z)
                n[0, o_u] += 0.5 * c_x
                n[1, o_u] += 0.5 * c_y
                n[2, o_u] += 0.5 * c_z
        for o_u in range(W):
            write_sum(out, o_v, o_u, n[0, o_u], n[1, o_u], n[2, o_u], valid[v, o_u + 1], fill)


@njit
def _angle_weighted_kernel(P, valid, fill, out):
    """AngleWeighted: w_j = the angle between r_j and r_j+1 at p, times the unit triangle normal."""
    H, W = out.shape[:2]
    n = np.empty((3, W))
    for o_v in range(H):
        v = o_v + 1
        n[:, :] = 0.0
        for j in range(8):
            for o_u in range(W):
                a_x, a_y, a_z = ring_offset(P, valid, v, o_u + 1, j)
                b_x, b_y, b_z = ring_offset(P, valid, v, o_u + 1, j + 1)
                c_x, c_y, c_z = cross(a_x, a_y, a_z, b_x, b_y, b_z)
                area2 = math.sqrt(c_x * c_x + c_y * c_y + c_z * c_z)  # ||r_j x r_j+1||; 0 without a triangle
                # w_j / ||c||, and 0 (no triangle) where c = 0
                w = angle_from(area2, a_x * b_x + a_y * b_y + a_z * b_z) / (area2 if area2 > 0.0 else math.inf)
                n[0, o_u] += w * c_x
                n[1, o_u] += w * c_y
                n[2, o_u] += w * c_z
        for o_u in range(W):
            write_sum(out, o_v, o_u, n[0, o_u], n[1, o_u], n[2, o_u], valid[v, o_u + 1], fill)


def area_weighted(z, valid, cam, out, *, fill=0.0):
    """AreaWeighted (eq. 2, Table I): triangle normals around p weighted by triangle area."""
    _area_weighted_kernel(*point_cloud(z, valid, cam, pad=1), np.float32(fill), out)
    return out


def angle_weighted(z, valid, cam, out, *, fill=0.0):
    """AngleWeighted (eq. 2, Table I): triangle normals around p weighted by their angle at p."""
    _angle_weighted_kernel(*point_cloud(z, valid, cam, pad=1), np.float32(fill), out)
    return out
