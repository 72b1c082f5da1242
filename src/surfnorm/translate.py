"""Depth-to-normal translation: D2NT (eq. 9) and CP2TV.

D2NT (Feng et al., ICRA 2023, eq. 4-9) turns the depth z and its gradients
(z_u, z_v) at pixel (u, v) straight into a normal, with no 3D points:

    n = [f_x z_u,  f_y z_v,  -(z + (u - c_x) z_u + (v - c_y) z_v)]

This is eq. 9 multiplied by -1: the printed eq. 9 points away from the
camera, the authors' code (and our convention) points towards it, so a
fronto-parallel wall gets n = (0, 0, -1).

CP2TV (Nakagawa et al., 2015) back-projects the pixels to 3D points
P = z K^-1 [u, v, 1]^T, takes the tangent vectors t_u, t_v as finite
differences of those points, and crosses them: n = t_v x t_u (that order
faces the camera). With exact derivatives the two coincide; with finite
differences they do not, which is why D2NT needs no 3D points.
"""

from __future__ import annotations

import math

import numpy as np

from ._config import njit, pixel
from .gradients import dag_gradient, dlf_code, fd_gradient, stencil

__all__ = ["d2nt", "cp2tv"]


@pixel
def write_unit(out, v, u, n_x, n_y, n_z, fill):
    """Store n / |n| at (v, u), or the fill value when n has no direction."""
    norm = math.sqrt(n_x * n_x + n_y * n_y + n_z * n_z)
    ok = norm > 0 and math.isfinite(norm)
    if ok:
        out[v, u, 0] = n_x / norm
        out[v, u, 1] = n_y / norm
        out[v, u, 2] = n_z / norm
    else:
        out[v, u, 0] = fill
        out[v, u, 1] = fill
        out[v, u, 2] = fill
    return ok


@pixel
def d2nt_normal(z, z_u, z_v, f_x, f_y, u_c, v_c):
    """Eq. 9 (camera-facing sign) with u_c = u - c_x, v_c = v - c_y; not normalised."""
    return f_x * z_u, f_y * z_v, -(z + u_c * z_u + v_c * z_v)


@njit
def _d2nt_fd_kernel(z, valid, f_x, f_y, c_x, c_y, reflect, fill, out):
    """D2NT with finite-difference gradients: one pass, per pixel gradients -> eq. 9 -> unit length."""
    H, W = z.shape
    for v in range(H):
        v_c = np.float32(v - c_y)
        for u in range(W):
            ok = False
            if valid[v, u]:
                z_u, ok_u = fd_gradient(z, valid, v, u, 0, 1, reflect)
                z_v, ok_v = fd_gradient(z, valid, v, u, 1, 0, reflect)
                ok = ok_u and ok_v
                if ok:
                    n_x, n_y, n_z = d2nt_normal(z[v, u], z_u, z_v, f_x, f_y, np.float32(u - c_x), v_c)
                    ok = write_unit(out, v, u, n_x, n_y, n_z, fill)
            if not ok:
                out[v, u, 0] = fill
                out[v, u, 1] = fill
                out[v, u, 2] = fill


@njit
def _d2nt_dag_kernel(z, valid, f_x, f_y, c_x, c_y, dlf, tau, truncate, fill, out):
    """D2NT with DAG gradients (eq. 10-14): one pass, per pixel gradients -> eq. 9 -> unit length."""
    H, W = z.shape
    for v in range(H):
        v_c = np.float32(v - c_y)
        for u in range(W):
            ok = False
            if valid[v, u]:
                z_u, ok_u = dag_gradient(z, valid, v, u, 0, 1, dlf, 0, tau, truncate)
                z_v, ok_v = dag_gradient(z, valid, v, u, 1, 0, dlf, 1, tau, truncate)
                ok = ok_u and ok_v
                if ok:
                    n_x, n_y, n_z = d2nt_normal(z[v, u], z_u, z_v, f_x, f_y, np.float32(u - c_x), v_c)
                    ok = write_unit(out, v, u, n_x, n_y, n_z, fill)
            if not ok:
                out[v, u, 0] = fill
                out[v, u, 1] = fill
                out[v, u, 2] = fill


def d2nt(z, valid, cam, out, *, gradient="fd", dlf="1d", tau=1.0, truncate=True, border="one-sided", fill=0.0):
    """D2NT with finite-difference (``gradient="fd"``) or DAG (``"dag"``) gradients, into ``out`` (H, W, 3)."""
    f = (np.float32(cam.fx), np.float32(cam.fy), np.float32(cam.cx), np.float32(cam.cy))
    if gradient == "fd":
        _d2nt_fd_kernel(z, valid, *f, border == "reflect", np.float32(fill), out)
    else:
        _d2nt_dag_kernel(z, valid, *f, dlf_code(dlf), np.float32(tau), bool(truncate), np.float32(fill), out)
    return out


@pixel
def back_project(z, v, u, f_x, f_y, c_x, c_y):
    """The 3D point P = z K^-1 [u, v, 1]^T of pixel (v, u) (eq. 3)."""
    d = z[v, u]
    return d * (u - c_x) / f_x, d * (v - c_y) / f_y, d


@pixel
def tangent(z, valid, v, u, dv, du, f_x, f_y, c_x, c_y, reflect):
    """Finite-difference tangent vector dP along (dv, du); central, one-sided at gaps. Returns (t, ok)."""
    vb, ub, vf, uf, dist = stencil(valid, v, u, dv, du, reflect)
    xb, yb, zb = back_project(z, vb, ub, f_x, f_y, c_x, c_y)
    xf, yf, zf = back_project(z, vf, uf, f_x, f_y, c_x, c_y)
    d = np.float32(max(dist, 1))
    return (xf - xb) / d, (yf - yb) / d, (zf - zb) / d, dist > 0


@njit
def _cp2tv_kernel(z, valid, f_x, f_y, c_x, c_y, reflect, fill, out):
    H, W = z.shape
    for v in range(H):
        for u in range(W):
            ok = False
            if valid[v, u]:
                ux, uy, uz, ok_u = tangent(z, valid, v, u, 0, 1, f_x, f_y, c_x, c_y, reflect)
                vx, vy, vz, ok_v = tangent(z, valid, v, u, 1, 0, f_x, f_y, c_x, c_y, reflect)
                ok = ok_u and ok_v
                if ok:  # n = t_v x t_u
                    ok = write_unit(out, v, u, vy * uz - vz * uy, vz * ux - vx * uz, vx * uy - vy * ux, fill)
            if not ok:
                out[v, u, 0] = fill
                out[v, u, 1] = fill
                out[v, u, 2] = fill


def cp2tv(z, valid, cam, out, *, border="one-sided", fill=0.0):
    """CP2TV (Nakagawa et al. 2015): cross product of finite-difference tangent vectors, into ``out``."""
    _cp2tv_kernel(z, valid, np.float32(cam.fx), np.float32(cam.fy), np.float32(cam.cx), np.float32(cam.cy),
                  border == "reflect", np.float32(fill), out)
    return out
