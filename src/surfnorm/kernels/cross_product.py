"""Plain cross-product normals: the cross product of the central differences of the organised point cloud.

The estimator of kornia's ``depth_to_normals``, written here from its description: with the back-projected
points P(v, u) = z K^-1 [u, v, 1]^T (eq. 3 of D2NT), the horizontal and vertical central-difference vectors

    h = P(v, u + 1) - P(v, u - 1),    d = P(v + 1, u) - P(v - 1, u)

span the tangent plane at the pixel, and n = d x h / ||d x h||. (The central differences' factors 1/2 change
no direction and are left out.) No smoothing, no fit: one pixel's four neighbours.

Invalid depth and the image border: where one of the two neighbours of a difference is invalid or outside the
image, the difference is one-sided, from the pixel to the valid neighbour (as kornia's replicated border gives
there); where both are, there is no such difference and the pixel gets the fill value, as does an invalid pixel.

Orientation: d x h faces the camera for every positive depth, without a sign to choose. With P_c the pixel's
point, det[P_c, d, h] is a sum of the terms det[P_c, P_d, P_r], -det[P_c, P_d, P_l], -det[P_c, P_u, P_r] and
det[P_c, P_u, P_l] that the differences contain (those with P_c twice vanish): each is a product of three positive
depths and the determinant of three pixel rays, whose sign is the orientation of the pixel triangle (c, d, r),
(c, l, d), (c, r, u), (c, u, l): the same for all four. So n . P_c < 0 always (x right, y down: for a
fronto-parallel wall d ~ +y, h ~ +x and d x h ~ -z).
"""

from __future__ import annotations

import numpy as np

from .._bands import whole
from .._config import njit
from ._rows import point_cloud, unit_or_fill

__all__ = ["cross_product"]


@njit
def _cross_product_kernel(P, P_valid, fill, out, v0, v1):
    """n = d x h at every pixel of rows v0 .. v1 - 1; P, P_valid padded by one invalid pixel on every side."""
    W = out.shape[1]
    for v in range(v0, v1):
        r = v + 1  # the row of P (padded)
        for u in range(W):
            c = u + 1
            # each difference spans the valid neighbours: both (central), one (one-sided), or none (h or d = 0)
            right = c + 1 if P_valid[r, c + 1] else c
            left = c - 1 if P_valid[r, c - 1] else c
            down = r + 1 if P_valid[r + 1, c] else r
            up = r - 1 if P_valid[r - 1, c] else r
            h_x = P[0, r, right] - P[0, r, left]
            h_y = P[1, r, right] - P[1, r, left]
            h_z = P[2, r, right] - P[2, r, left]
            d_x = P[0, down, c] - P[0, up, c]
            d_y = P[1, down, c] - P[1, up, c]
            d_z = P[2, down, c] - P[2, up, c]
            n_x, n_y, n_z, _ = unit_or_fill(
                d_y * h_z - d_z * h_y, d_z * h_x - d_x * h_z, d_x * h_y - d_y * h_x, P_valid[r, c], fill
            )
            out[v, u, 0] = n_x
            out[v, u, 1] = n_y
            out[v, u, 2] = n_z


def cross_product(z, valid, cam, out, *, fill=0.0, bands=whole):
    """Cross-product normals (kornia's ``depth_to_normals``): n = d x h of the point cloud's central differences.

    Two stages in row bands: the point cloud (float64, padded by one invalid pixel), then the normals (halo: one
    row of the cloud on each side, read from the whole cloud).
    """
    P, P_valid = point_cloud(z, valid, cam, pad=1, bands=bands)
    fill64 = np.float64(np.float32(fill))
    bands(lambda a, b: _cross_product_kernel(P, P_valid, fill64, out, a, b), z.shape[0])
    return out
