"""Naive per-pixel references for PlaneSVD, PlanePCA and VectorSVD (D2NT Table I), plain NumPy.

Written from Table I of Feng et al. (ICRA 2023), not from surfnorm's kernels:
every pixel gathers the valid points of its window into a matrix and calls
``np.linalg.svd`` / ``np.linalg.eigh`` on it. Slow (one LAPACK call per pixel);
for small test images only.
"""

from __future__ import annotations

import numpy as np


def points(depth, K):
    """Back-project: P = z K^-1 [u, v, 1]^T (float64), shape (H, W, 3)."""
    H, W = depth.shape
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    z = depth.astype(np.float64)
    return np.stack([z * (u - K[0][2]) / K[0][0], z * (v - K[1][2]) / K[1][1], z], axis=-1)


def _valid(depth, mask):
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(depth) & (depth > 0)
    return ok if mask is None else ok & mask


def _face_camera(n, p):
    return -n if np.dot(n, p) > 0 else n


def plane_fit(depth, K, method, window=3, mask=None, fill=0.0):
    """Normals (H, W, 3) float64 of ``method`` in {"plane_svd", "plane_pca", "vector_svd"}.

    A window whose valid pixels lie on one image line gets ``fill`` (their points lie in a plane through
    the camera centre, which every fit would return, seen edge-on). Also returns the relative eigen-gap (H, W): (lambda_2 - lambda_1) / lambda_max of the matrix whose
    smallest eigenvector is the normal (0 where there is none). Where it is tiny the normal is
    ill-determined and any two correct solvers may disagree.
    """
    depth = np.asarray(depth, dtype=np.float32)  # what the library computes from
    H, W = depth.shape
    P = points(depth, K)
    valid = _valid(depth, mask)
    h = window // 2
    out = np.full((H, W, 3), fill, dtype=np.float64)
    gap = np.zeros((H, W))
    for v in range(H):
        for u in range(W):
            if not valid[v, u]:
                continue
            p = P[v, u]
            Q_plus = [P[a, b] for a in range(v - h, v + h + 1) for b in range(u - h, u + h + 1)
                      if 0 <= a < H and 0 <= b < W and valid[a, b]]  # includes p itself
            if len(Q_plus) < 3:
                continue
            pixels = np.array([(a, b) for a in range(v - h, v + h + 1) for b in range(u - h, u + h + 1)
                               if 0 <= a < H and 0 <= b < W and valid[a, b]], dtype=np.float64)
            if np.linalg.matrix_rank(pixels - pixels.mean(axis=0)) < 2:
                continue  # the pixels lie on one image line: their points lie in a plane through the camera
            Q_plus = np.array(Q_plus)
            if method == "plane_svd":
                # min || [Q+, 1] b ||, ||b|| = 1: last right singular vector; n = b[:3]
                A = np.hstack([Q_plus, np.ones((len(Q_plus), 1))])
                s, vt = np.linalg.svd(A)[1:]
                b = vt[-1]
                n, rank_ok = b[:3], s[2] > 1e-12 * s[0]
                lam = s**2 if len(s) == 4 else np.r_[s**2, np.zeros(4 - len(s))]
                gap[v, u] = (lam[2] - lam[3]) / lam[0]
            elif method == "plane_pca":
                centred = Q_plus - Q_plus.mean(axis=0)
                w, V = np.linalg.eigh(centred.T @ centred)
                n, rank_ok = V[:, 0], w[1] > 1e-12 * w[2]
                gap[v, u] = (w[1] - w[0]) / w[2]
            elif method == "vector_svd":
                R = np.array([q - p for q in Q_plus if not np.array_equal(q, p)])
                s, vt = np.linalg.svd(R)[1:]
                lam = np.r_[s**2, np.zeros(3 - len(s))]
                n, rank_ok = vt[-1], lam[1] > 1e-12 * lam[0]
                gap[v, u] = (lam[1] - lam[2]) / lam[0]
            else:
                raise ValueError(method)
            if rank_ok:
                out[v, u] = _face_camera(n / np.linalg.norm(n), p)
            else:
                gap[v, u] = 0.0
    return out, gap
