"""Averaging of the normals of the triangles around a pixel: AreaWeighted, AngleWeighted.

The averaging-based estimators of Table I of Feng et al. (D2NT, ICRA 2023),
after Klasing et al. (ICRA 2009) and Jin et al. (2005). Eq. 2:

    n_i = 1/k sum_j w_j (r_ij x r_i,j+1) / ||r_ij x r_i,j+1||,   r_ij = q_ij - p_i,  r_i,k+1 = r_i1

over the k = 8 neighbours q_ij of p_i in its 8-neighbourhood, taken as a
ring. The weight w_j is the triangle's area, 1/2 ||r_ij x r_i,j+1||
(AreaWeighted), or its angle at p_i, acos(<r_ij, r_i,j+1> / (||r_ij|| ||r_i,j+1||))
(AngleWeighted, computed as atan2(||r_ij x r_i,j+1||, <r_ij, r_i,j+1>), the
same angle without acos's loss of precision near 0). The sum is then scaled to
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
from .gradients import usable
from .plane_fit import point_cloud

__all__ = ["area_weighted", "angle_weighted", "RING"]

#: The 8-neighbourhood ring, (dv, du): counter-clockwise on screen, starting at the right neighbour.
RING = ((0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1), (1, 0), (1, 1))


@pixel
def ring_offset(P, valid, v, u, j):
    """r_j = q_j - p for ring neighbour j of p = (v, u), and whether q_j is usable."""
    dv, du = RING[j % 8]
    ok = usable(valid, v + dv, u + du)
    r_x = r_y = r_z = 0.0
    if ok:
        r_x = P[v + dv, u + du, 0] - P[v, u, 0]
        r_y = P[v + dv, u + du, 1] - P[v, u, 1]
        r_z = P[v + dv, u + du, 2] - P[v, u, 2]
    return r_x, r_y, r_z, ok


@pixel
def write_sum(out, v, u, n_x, n_y, n_z, fill):
    """Store n / ||n||, or the fill value when no triangle contributed (n = 0)."""
    norm = math.sqrt(n_x * n_x + n_y * n_y + n_z * n_z)
    if norm > 0.0 and math.isfinite(norm):
        out[v, u, 0] = n_x / norm
        out[v, u, 1] = n_y / norm
        out[v, u, 2] = n_z / norm
    else:
        out[v, u, 0] = fill
        out[v, u, 1] = fill
        out[v, u, 2] = fill


@njit
def _area_weighted_kernel(P, valid, fill, out):
    """AreaWeighted: w_j * unit(r_j x r_j+1) with w_j = ||r_j x r_j+1|| / 2 is (r_j x r_j+1) / 2."""
    H, W = valid.shape
    for v in range(H):
        for u in range(W):
            n_x = n_y = n_z = 0.0
            if valid[v, u]:
                a_x, a_y, a_z, a_ok = ring_offset(P, valid, v, u, 0)
                for j in range(1, 9):
                    b_x, b_y, b_z, b_ok = ring_offset(P, valid, v, u, j)
                    if a_ok and b_ok:  # the triangle (p, q_j, q_j+1)
                        n_x += 0.5 * (a_y * b_z - a_z * b_y)
                        n_y += 0.5 * (a_z * b_x - a_x * b_z)
                        n_z += 0.5 * (a_x * b_y - a_y * b_x)
                    a_x, a_y, a_z, a_ok = b_x, b_y, b_z, b_ok
            write_sum(out, v, u, n_x, n_y, n_z, fill)


@njit
def _angle_weighted_kernel(P, valid, fill, out):
    """AngleWeighted: w_j = the angle between r_j and r_j+1, times the unit triangle normal."""
    H, W = valid.shape
    for v in range(H):
        for u in range(W):
            n_x = n_y = n_z = 0.0
            if valid[v, u]:
                a_x, a_y, a_z, a_ok = ring_offset(P, valid, v, u, 0)
                for j in range(1, 9):
                    b_x, b_y, b_z, b_ok = ring_offset(P, valid, v, u, j)
                    if a_ok and b_ok:
                        c_x = a_y * b_z - a_z * b_y
                        c_y = a_z * b_x - a_x * b_z
                        c_z = a_x * b_y - a_y * b_x
                        area2 = math.sqrt(c_x * c_x + c_y * c_y + c_z * c_z)  # ||r_j x r_j+1||
                        if area2 > 0.0:
                            w = math.atan2(area2, a_x * b_x + a_y * b_y + a_z * b_z)
                            n_x += w * c_x / area2
                            n_y += w * c_y / area2
                            n_z += w * c_z / area2
                    a_x, a_y, a_z, a_ok = b_x, b_y, b_z, b_ok
            write_sum(out, v, u, n_x, n_y, n_z, fill)


def area_weighted(z, valid, cam, out, *, fill=0.0):
    """AreaWeighted (eq. 2, Table I): triangle normals around p weighted by triangle area."""
    _area_weighted_kernel(point_cloud(z, valid, cam), valid, np.float32(fill), out)
    return out


def angle_weighted(z, valid, cam, out, *, fill=0.0):
    """AngleWeighted (eq. 2, Table I): triangle normals around p weighted by their angle at p."""
    _angle_weighted_kernel(point_cloud(z, valid, cam), valid, np.float32(fill), out)
    return out
