"""Slow, obvious references for 3F2N (Fan et al., RA-L 2021) and SNE-RoadSeg's estimator (ECCV 2020).

Written from the papers and the description of the authors' code, pixel by
pixel in plain Python with 3D points X, Y, Z computed the textbook way
(X = (u - c_x) Z / f_x). Not derived from surfnorm's kernels.

Conventions under test (see surfnorm.kernels.three_filters): float64; inverse depth
D = 1/Z; gradient = central difference / 2, one-sided beside an unusable
neighbour; with border "reflect" the image border mirrors (OpenCV
BORDER_REFLECT_101: gradient 0 across it, mirrored neighbour as candidate);
invalid pixels are never read; output unit length, facing the camera.
"""

from __future__ import annotations

import math
import statistics

import numpy as np

NEIGHBOURS = [(dv, du) for dv in (-1, 0, 1) for du in (-1, 0, 1) if (dv, du) != (0, 0)]


class _Scene:
    def __init__(self, depth, valid, K, border):
        self.z = np.asarray(depth, dtype=np.float32).astype(np.float64)  # the library computes from float32 depth
        self.valid = np.asarray(valid, dtype=bool)
        self.H, self.W = self.z.shape
        self.fx, self.fy, self.cx, self.cy = float(K[0][0]), float(K[1][1]), float(K[0][2]), float(K[1][2])
        self.reflect = border == "reflect"

    def inside(self, v, u):
        return 0 <= v < self.H and 0 <= u < self.W

    def usable(self, v, u):
        return self.inside(v, u) and bool(self.valid[v, u])

    def point(self, v, u):
        z = self.z[v, u]
        return (u - self.cx) * z / self.fx, (v - self.cy) * z / self.fy, z

    def stand_in(self, v, u):
        """The pixel used for neighbour (v, u): itself if usable, its mirror across the image border with
        reflect, or None."""
        if self.inside(v, u):
            return (v, u) if self.valid[v, u] else None
        if not self.reflect:
            return None
        mv = -v if v < 0 else (2 * (self.H - 1) - v if v >= self.H else v)
        mu = -u if u < 0 else (2 * (self.W - 1) - u if u >= self.W else u)
        return (mv, mu) if self.usable(mv, mu) else None

    def inverse_depth_derivative(self, v, u, dv, du):
        back, front = (v - dv, u - du), (v + dv, u + du)
        has_b, has_f = self.usable(*back), self.usable(*front)
        d = lambda q: 1.0 / self.z[q]  # noqa: E731
        if has_b and has_f:
            return (d(front) - d(back)) / 2.0
        if self.reflect and has_f and not self.inside(*back):
            return 0.0
        if self.reflect and has_b and not self.inside(*front):
            return 0.0
        if has_f:
            return d(front) - d((v, u))
        if has_b:
            return d((v, u)) - d(back)
        return None

    def nz_candidates(self, v, u, nx, ny):
        """-(n_x dX + n_y dY) / dZ for each neighbour with dZ != 0 (eq. 10)."""
        xp, yp, zp = self.point(v, u)
        out = []
        for dv, du in NEIGHBOURS:
            q = self.stand_in(v + dv, u + du)
            if q is None:
                continue
            xq, yq, zq = self.point(*q)
            if zp - zq == 0:
                continue
            out.append(-(nx * (xp - xq) + ny * (yp - yq)) / (zp - zq))
        return out

    def facing(self, n, v, u):
        n = np.asarray(n, dtype=np.float64)
        n = n / np.linalg.norm(n)
        ray = np.array([(u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0])
        return -n if n @ ray > 0 else n


def three_f2n(depth, valid, K, *, third="median", border="one-sided", fill=0.0, gradients=None):
    """3F2N: n_x = f_x dD/du, n_y = f_y dD/dv, n_z = mean / median of eq. 10 over the 8 neighbours.

    ``gradients``: optional (dD/du, dD/dv) maps to use instead of finite differences (NaN: none).
    """
    s = _Scene(depth, valid, K, border)
    out = np.full((s.H, s.W, 3), fill, dtype=np.float64)
    for v in range(s.H):
        for u in range(s.W):
            if not s.valid[v, u]:
                continue
            if gradients is None:
                gu = s.inverse_depth_derivative(v, u, 0, 1)
                gv = s.inverse_depth_derivative(v, u, 1, 0)
            else:
                gu, gv = (None if math.isnan(g[v, u]) else float(g[v, u]) for g in gradients)
            if gu is None or gv is None:
                continue
            nx, ny = s.fx * gu, s.fy * gv
            cands = s.nz_candidates(v, u, nx, ny)
            if not cands:  # the authors' fallbacks
                nx = ny = 0.0
                nz = math.nan
            else:
                nz = statistics.median(cands) if third == "median" else sum(cands) / len(cands)
            if nx == 0 and ny == 0:
                nz = -1.0
            out[v, u] = s.facing((nx, ny, nz), v, u)
    return out


def sne_roadseg(depth, valid, K, *, border="one-sided", fill=0.0):
    """SNE-RoadSeg: phi from (n_x, n_y); theta from the sum of the unit candidate normals; n from (theta, phi)."""
    s = _Scene(depth, valid, K, border)
    out = np.full((s.H, s.W, 3), fill, dtype=np.float64)
    for v in range(s.H):
        for u in range(s.W):
            if not s.valid[v, u]:
                continue
            gu = s.inverse_depth_derivative(v, u, 0, 1)
            gv = s.inverse_depth_derivative(v, u, 1, 0)
            if gu is None or gv is None:
                continue
            nx, ny = s.fx * gu, s.fy * gv
            cands = s.nz_candidates(v, u, nx, ny)
            if (nx == 0 and ny == 0) or not cands:
                out[v, u] = s.facing((0.0, 0.0, -1.0), v, u)
                continue
            phi = math.atan(ny / nx) + math.pi if nx != 0 else math.atan(math.copysign(math.inf, ny)) + math.pi
            total = np.zeros(3)
            for nz in cands:
                n = np.array([nx, ny, nz])
                total += n / np.linalg.norm(n)
            along = total[0] * math.cos(phi) + total[1] * math.sin(phi)
            theta = math.atan(along / total[2]) if total[2] != 0 else math.copysign(math.pi / 2, along)
            n = (math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta))
            out[v, u] = s.facing(n, v, u)
    return out
