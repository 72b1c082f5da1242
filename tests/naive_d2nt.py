"""Slow, obvious reference for the D2NT family, CP2TV and MNR (whole-image NumPy, no Numba).

Written from the paper (Feng et al., ICRA 2023, eq. 9-14 and Sec. III-C/IV-A)
and the semantics of the authors' d2nt 0.1.3 package, with surfnorm's rules
for missing depth:

* a pixel q is *usable* if it lies inside the image and its depth is valid;
* a gradient is central where both neighbours are usable, one-sided where one
  is, undefined where none is (``border="reflect"``: a neighbour outside the
  image mirrors the one inside, so the central difference there is 0);
* a Laplacian neighbour q + d that is missing is replaced by its mirror q - d
  (and contributes 0 if that is missing too);
* softmin weights p_i = exp(-s_i / tau), lambda_b = (p_b + eps/2) / (p_b + p_f + eps)
  with eps = 1e-8; truncated to (1, 0) or (0, 1) when lambda_b / (lambda_f + eps)
  (or the reverse) exceeds e^(1/tau);
* MNR: each pixel with a normal takes the normal of the argmin of |Laplacian|
  over [left, right, up, down, self], first index on ties, neighbours without
  a normal excluded; with the 1D DLF left/right use the horizontal filter,
  up/down the vertical one, self their mean.

Every operation is done in float32 in the order written here (CP2TV's 3D
points in float64), so results agree with the kernels to float32 rounding.
Each map is built with shifted copies of padded arrays: ``shifted(a, dv, du)[v, u]
== a[v + dv, u + du]`` (fill value outside the image).
"""

from __future__ import annotations

import numpy as np

F32 = np.float32
EPS = F32(1e-8)
# (edge weight, corner weight) of the 3x3 DLFs; centre weight is minus their sum.
DLF_WEIGHTS = {"alpha": (1.0, 0.0), "beta": (1.0, 1.0), "gamma": (0.5, 0.25)}


def clean(z, valid):
    """Depth with invalid pixels replaced by 1 (never read, but keeps NumPy quiet about inf - inf)."""
    return np.where(valid, z, F32(1)).astype(F32)


def shifted(a, dv, du, fill):
    """b[v, u] = a[v + dv, u + du], ``fill`` outside the image."""
    H, W = a.shape
    p = np.full((H + 2, W + 2), fill, dtype=a.dtype)
    p[1:-1, 1:-1] = a
    return p[1 + dv:1 + dv + H, 1 + du:1 + du + W]


def neighbour_diff(z, valid, dv, du):
    """z_q - z_p for q = p + d, or the mirrored q = p - d if p + d is missing, else 0."""
    zf, ok_f = shifted(z, dv, du, 0), shifted(valid, dv, du, False)
    zb, ok_b = shifted(z, -dv, -du, 0), shifted(valid, -dv, -du, False)
    return np.where(ok_f, zf - z, np.where(ok_b, zb - z, F32(0))).astype(F32)


def laplacian_abs(z, valid, dlf, axis=0):
    """|nabla^2 z| per pixel (eq. 11); 1D DLF along ``axis`` (0: [1,-2,1] horizontally, 1: vertically)."""
    d = lambda dv, du: neighbour_diff(z, valid, dv, du)  # noqa: E731
    if dlf == "1d":
        lap = d(0, -1) + d(0, 1) if axis == 0 else d(-1, 0) + d(1, 0)
        return np.abs(lap)
    edge_w, corner_w = DLF_WEIGHTS[dlf]
    lap = F32(edge_w) * (((d(-1, 0) + d(1, 0)) + d(0, -1)) + d(0, 1))
    if corner_w:
        lap = lap + F32(corner_w) * (((d(-1, -1) + d(-1, 1)) + d(1, -1)) + d(1, 1))
    return np.abs(lap).astype(F32)


def unit_or_fill(n, ok, fill, dtype=F32):
    """n / |n| where ok and |n| is finite and positive, else ``fill`` in all components."""
    n = [np.asarray(c, dtype=dtype) for c in n]
    norm = np.sqrt((n[0] * n[0] + n[1] * n[1]) + n[2] * n[2])
    with np.errstate(invalid="ignore", divide="ignore"):
        good = ok & (norm > 0) & np.isfinite(norm)
        out = np.stack([c / norm for c in n], axis=-1).astype(F32)
    out[~good] = F32(fill)
    return out


def d2nt_normals(z, zu, zv, ok, cam, fill):
    """Eq. 9, sign chosen to face the camera: n = (fx z_u, fy z_v, -(z + (u-cx) z_u + (v-cy) z_v))."""
    H, W = z.shape
    uc = (np.arange(W) - np.float64(F32(cam.cx))).astype(F32)[None, :]
    vc = (np.arange(H) - np.float64(F32(cam.cy))).astype(F32)[:, None]
    with np.errstate(all="ignore"):
        n = (F32(cam.fx) * zu, F32(cam.fy) * zv, -((z + uc * zu) + vc * zv))
    return unit_or_fill(n, ok, fill)


def fd_gradient(z, valid, dv, du, reflect):
    """(gradient, ok) along (dv, du): central / one-sided / reflected at the image border."""
    H, W = z.shape
    ok_f, ok_b = shifted(valid, dv, du, False), shifted(valid, -dv, -du, False)
    in_f, in_b = shifted(np.ones((H, W), bool), dv, du, False), shifted(np.ones((H, W), bool), -dv, -du, False)
    zf, zb = shifted(z, dv, du, 0), shifted(z, -dv, -du, 0)
    with np.errstate(all="ignore"):
        g = np.where(ok_f & ok_b, (zf - zb) / F32(2),
                     np.where(ok_f, zf - z, np.where(ok_b, z - zb, F32(0))))
    if reflect:  # the missing neighbour is outside the image: mirrored, so the central difference is 0
        g = np.where((ok_f & ~ok_b & ~in_b) | (ok_b & ~ok_f & ~in_f), F32(0), g)
    return g.astype(F32), ok_f | ok_b


def d2nt_basic(z, valid, cam, *, border="one-sided", fill=0.0):
    z = clean(z, valid)
    zu, ok_u = fd_gradient(z, valid, 0, 1, border == "reflect")
    zv, ok_v = fd_gradient(z, valid, 1, 0, border == "reflect")
    return d2nt_normals(z, zu, zv, valid & ok_u & ok_v, cam, fill)


def softmin_weights(s_b, s_f, tau, truncate):
    """(lambda_b, lambda_f) of eq. 13-14 from the smoothness of the two neighbours."""
    tau = F32(tau)
    with np.errstate(all="ignore"):
        p_b = np.exp((-s_b / tau).astype(np.float64)).astype(F32)
        p_f = np.exp((-s_f / tau).astype(np.float64)).astype(F32)
        total = (EPS + p_b) + p_f
        lam_b = (p_b + F32(0.5) * EPS) / total
        lam_f = (p_f + F32(0.5) * EPS) / total
        if truncate:
            ratio = F32(np.exp(1.0 / np.float64(tau)))
            b_wins = lam_b / (lam_f + EPS) > ratio
            f_wins = ~b_wins & (lam_f / (lam_b + EPS) > ratio)
            lam_b, lam_f = np.where(b_wins, F32(1), np.where(f_wins, F32(0), lam_b)), \
                np.where(b_wins, F32(0), np.where(f_wins, F32(1), lam_f))
    return lam_b.astype(F32), lam_f.astype(F32)


def dag_gradient(z, valid, dv, du, dlf, tau, truncate):
    """Eq. 10: lambda_b (z_p - z_b) + lambda_f (z_f - z_p); one-sided where one neighbour is missing."""
    axis = 0 if dv == 0 else 1
    s = laplacian_abs(z, valid, dlf, axis)
    ok_f, ok_b = shifted(valid, dv, du, False), shifted(valid, -dv, -du, False)
    lam_b, lam_f = softmin_weights(shifted(s, -dv, -du, 0), shifted(s, dv, du, 0), tau, truncate)
    lam_b = np.where(ok_b & ok_f, lam_b, np.where(ok_b, F32(1), F32(0)))
    lam_f = np.where(ok_b & ok_f, lam_f, np.where(ok_f, F32(1), F32(0)))
    with np.errstate(all="ignore"):
        delta_b = np.where(ok_b, z - shifted(z, -dv, -du, 0), F32(0))
        delta_f = np.where(ok_f, shifted(z, dv, du, 0) - z, F32(0))
        g = lam_b * delta_b + lam_f * delta_f
    return g.astype(F32), ok_b | ok_f


def d2nt_dag(z, valid, cam, *, dlf="1d", tau=1.0, truncate=True, fill=0.0):
    z = clean(z, valid)
    zu, ok_u = dag_gradient(z, valid, 0, 1, dlf, tau, truncate)
    zv, ok_v = dag_gradient(z, valid, 1, 0, dlf, tau, truncate)
    return d2nt_normals(z, zu, zv, valid & ok_u & ok_v, cam, fill)


def mnr(z, valid, normals, *, dlf="alpha", fill=0.0, tie_tol=0.0):
    """MNR (Sec. III-C as simplified in Sec. IV-A and the authors' code).

    ``tie_tol`` (scale-invariant mode): a candidate must be smoother than the
    best so far by more than tie_tol * z_p to replace it (float32 arithmetic).
    """
    z = clean(z, valid)
    tol = F32(tie_tol) * z
    with np.errstate(all="ignore"):
        sq = np.einsum("hwc,hwc->hw", normals, normals)
    has = valid & np.isfinite(sq) & (sq > 0)
    if dlf == "1d":
        s_h, s_v = laplacian_abs(z, valid, dlf, 0), laplacian_abs(z, valid, dlf, 1)
        s_self = F32(0.5) * (s_h + s_v)
    else:
        s_h = s_v = s_self = laplacian_abs(z, valid, dlf)
    offsets = [(0, -1, s_h), (0, 1, s_h), (-1, 0, s_v), (1, 0, s_v)]
    best_s = np.full(z.shape, np.inf, F32)
    best_dv, best_du = np.zeros(z.shape, int), np.zeros(z.shape, int)
    for dv, du, s in offsets:  # left, right, up, down: strict < keeps the first on ties
        s_q = np.where(shifted(has, dv, du, False), shifted(s, dv, du, 0), F32(np.inf))
        better = s_q < best_s - tol
        best_s = np.where(better, s_q, best_s)
        best_dv, best_du = np.where(better, dv, best_dv), np.where(better, du, best_du)
    self_better = s_self < best_s - tol
    best_dv, best_du = np.where(self_better, 0, best_dv), np.where(self_better, 0, best_du)
    H, W = z.shape
    vv, uu = np.mgrid[0:H, 0:W]
    out = normals[np.clip(vv + best_dv, 0, H - 1), np.clip(uu + best_du, 0, W - 1)].astype(F32)
    out[~has] = F32(fill)
    return out


def d2nt_v3(z, valid, cam, *, dlf="1d", tau=1.0, truncate=True, mnr_dlf="alpha", fill=0.0, tie_tol=0.0):
    raw = d2nt_dag(z, valid, cam, dlf=dlf, tau=tau, truncate=truncate, fill=fill)
    return mnr(z, valid, raw, dlf=mnr_dlf, fill=fill, tie_tol=tie_tol)


def cp2tv(z, valid, cam, *, border="one-sided", fill=0.0):
    """CP2TV: n = t_v x t_u with t = finite differences of the 3D points P = z K^-1 [u, v, 1]^T."""
    z = clean(z, valid)
    H, W = z.shape
    fx, fy, cx, cy = (np.float64(F32(c)) for c in (cam.fx, cam.fy, cam.cx, cam.cy))
    X = (z.astype(np.float64) * (np.arange(W) - cx)[None, :]) / fx
    Y = (z.astype(np.float64) * (np.arange(H) - cy)[:, None]) / fy
    reflect = border == "reflect"
    t = []
    for dv, du in ((0, 1), (1, 0)):
        ok_f, ok_b = shifted(valid, dv, du, False), shifted(valid, -dv, -du, False)
        inside_f = shifted(np.ones((H, W), bool), dv, du, False)
        inside_b = shifted(np.ones((H, W), bool), -dv, -du, False)
        comps = []
        for P, dtype in ((X, np.float64), (Y, np.float64), (z, F32)):
            Pf, Pb = shifted(P, dv, du, 0), shifted(P, -dv, -du, 0)
            with np.errstate(all="ignore"):
                d = np.where(ok_f & ok_b, (Pf - Pb) / dtype(2),
                             np.where(ok_f, Pf - P, np.where(ok_b, P - Pb, dtype(0))))
            if reflect:
                d = np.where((ok_f & ~ok_b & ~inside_b) | (ok_b & ~ok_f & ~inside_f), dtype(0), d)
            comps.append(d.astype(dtype))
        t.append((comps, ok_f | ok_b))
    (ux, uy, uz), ok_u = t[0]
    (vx, vy, vz), ok_v = t[1]
    uz, vz = uz.astype(np.float64), vz.astype(np.float64)
    with np.errstate(all="ignore"):
        n = (vy * uz - vz * uy, vz * ux - vx * uz, vx * uy - vy * ux)
    return unit_or_fill(n, valid & ok_u & ok_v, fill, dtype=np.float64)
