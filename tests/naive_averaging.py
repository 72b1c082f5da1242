"""Naive per-pixel references for AreaWeighted and AngleWeighted (D2NT eq. 2, Table I), plain NumPy.

Written from eq. 2 and Table I of Feng et al. (ICRA 2023): for each pixel, walk
the ring of its 8 neighbours (right, up-right, up, up-left, left, down-left,
down, down-right: counter-clockwise on screen), form r_j = q_j - p, and sum
w_j * (r_j x r_j+1) / ||r_j x r_j+1|| over the triangles whose two
neighbours are both valid, with w_j = ||r_j x r_j+1|| / 2 (area) or
w_j = arccos(<r_j, r_j+1> / (||r_j|| ||r_j+1||)) (angle, as Table I writes it).
"""

from __future__ import annotations

import numpy as np

from .naive_plane_fit import _valid, points

RING = [(0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1), (1, 0), (1, 1)]


def averaging(depth, K, weight, mask=None, fill=0.0):
    """Normals (H, W, 3) float64, ``weight`` in {"area", "angle"}."""
    depth = np.asarray(depth, dtype=np.float32)
    H, W = depth.shape
    P = points(depth, K)
    valid = _valid(depth, mask)
    out = np.full((H, W, 3), fill, dtype=np.float64)
    for v in range(H):
        for u in range(W):
            if not valid[v, u]:
                continue
            total = np.zeros(3)
            triangles = 0
            for j in range(8):
                (a, b), (c, d) = RING[j], RING[(j + 1) % 8]
                qa, qb = (v + a, u + b), (v + c, u + d)
                if not all(0 <= y < H and 0 <= x < W and valid[y, x] for y, x in (qa, qb)):
                    continue
                r1, r2 = P[qa] - P[v, u], P[qb] - P[v, u]
                cross = np.cross(r1, r2)
                length = np.linalg.norm(cross)
                if length == 0:
                    continue
                if weight == "area":
                    w = 0.5 * length
                else:
                    w = np.arccos(np.clip(r1 @ r2 / (np.linalg.norm(r1) * np.linalg.norm(r2)), -1, 1))
                total += w * cross / length
                triangles += 1
            if triangles:
                out[v, u] = total / np.linalg.norm(total)
    return out
