"""A slow, obvious 3F2N written from the project's spec, to check the torch backend before the NumPy one has it.

Per pixel, in float64 Python: gradients of inverse depth, 8 neighbour
candidates n_z,q = -(n_x dX + n_y dY) / dZ, mean or median, the authors'
fallbacks, unit length, then turned to face the camera. ``border="reflect"``
mirrors indices across the image border (OpenCV BORDER_REFLECT_101);
``"one-sided"`` leaves outside neighbours out. Invalid depth is never read.
"""

from __future__ import annotations

import math
import statistics


def _mirror(i, n):
    if i < 0:
        return -i
    if i >= n:
        return 2 * (n - 1) - i
    return i


def three_f2n(depth, valid, fx, fy, cx, cy, *, third="median", border="one-sided", fill=0.0):
    H, W = len(depth), len(depth[0])
    reflect = border == "reflect"
    out = [[[fill] * 3 for _ in range(W)] for _ in range(H)]

    def ok(v, u):
        return 0 <= v < H and 0 <= u < W and bool(valid[v][u])

    def point(v, u):
        z = float(depth[v][u])
        return ((u - cx) * z / fx, (v - cy) * z / fy, z)

    def inverse_gradient(v, u, dv, du):
        """dD/du (du=1) or dD/dv (dv=1) of D = 1/z; None if no neighbour along the axis is usable."""
        back, front = ok(v - dv, u - du), ok(v + dv, u + du)
        inside_back = 0 <= v - dv < H and 0 <= u - du < W
        inside_front = 0 <= v + dv < H and 0 <= u + du < W
        D = lambda a, b: 1.0 / float(depth[a][b])  # noqa: E731
        if back and front:
            return (D(v + dv, u + du) - D(v - dv, u - du)) / 2
        if front:
            return 0.0 if reflect and not inside_back else D(v + dv, u + du) - D(v, u)
        if back:
            return 0.0 if reflect and not inside_front else D(v, u) - D(v - dv, u - du)
        return None

    for v in range(H):
        for u in range(W):
            if not ok(v, u):
                continue
            g_u, g_v = inverse_gradient(v, u, 0, 1), inverse_gradient(v, u, 1, 0)
            if g_u is None or g_v is None:
                continue
            n_x, n_y = fx * g_u, fy * g_v
            X, Y, Z = point(v, u)
            candidates = []
            for dv in (-1, 0, 1):
                for du in (-1, 0, 1):
                    if dv == 0 and du == 0:
                        continue
                    q_v, q_u = v + dv, u + du
                    if reflect:
                        q_v, q_u = _mirror(q_v, H), _mirror(q_u, W)
                    if not ok(q_v, q_u):
                        continue
                    Xq, Yq, Zq = point(q_v, q_u)
                    if Z - Zq == 0:
                        continue
                    candidates.append(-(n_x * (X - Xq) + n_y * (Y - Yq)) / (Z - Zq))
            if not candidates:
                n_x = n_y = 0.0
                n_z = 0.0
            else:
                n_z = statistics.median(candidates) if third == "median" else sum(candidates) / len(candidates)
            if n_x == 0 and n_y == 0:
                n_z = -1.0
            norm = math.sqrt(n_x * n_x + n_y * n_y + n_z * n_z)
            n = [n_x / norm, n_y / norm, n_z / norm]
            if n[0] * X + n[1] * Y + n[2] * Z > 0:
                n = [-c for c in n]
            out[v][u] = n
    return out
