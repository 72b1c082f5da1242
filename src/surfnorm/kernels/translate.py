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

import numpy as np

from .._bands import whole
from .._config import njit, pixel, row
from ._rows import centred_columns, fast_row, fill_pixels, segment, stencil, store_unit, store_unit_flat
from .gradients import (
    dag_gradient,
    dlf_code,
    fd_gradient,
    kernel_tau,
    laplacian_row,
    softmin_pair,
    softmin_ratio,
    softmin_weights_row,
)

__all__ = ["d2nt", "cp2tv", "d2nt_normal", "prepare_dag_row", "dag_row"]


@pixel
def d2nt_normal(z, z_u, z_v, f_x, f_y, u_c, v_c):
    """Eq. 9 (camera-facing sign) with u_c = u - c_x, v_c = v - c_y; not normalised."""
    return f_x * z_u, f_y * z_v, -(z + u_c * z_u + v_c * z_v)


# --- D2NT with finite differences (d2nt_basic) ------------------------------------------------


@pixel
def d2nt_fd_pixel(z, valid, v, u, f_x, f_y, u_c, v_c, reflect, fill, out_row):
    """The general rule at one pixel: per pixel gradients (one-sided at gaps) -> eq. 9 -> unit length."""
    z_u, ok_u = fd_gradient(z, valid, v, u, 0, 1, reflect)
    z_v, ok_v = fd_gradient(z, valid, v, u, 1, 0, reflect)
    n_x, n_y, n_z = d2nt_normal(z[v, u], z_u, z_v, f_x, f_y, u_c, v_c)
    store_unit(out_row, u, n_x, n_y, n_z, valid[v, u] & ok_u & ok_v, fill)


@row
def d2nt_fd_row(z, valid, v, f_x, f_y, u_c, v_c, reflect, fill, col, runs, out_row):
    """Row v of D2NT with finite-difference gradients (``d2nt_basic``): gradients -> eq. 9 -> unit length.

    Where the 3x3 neighbourhood is valid, central differences in a branch-free loop; elsewhere the per-pixel
    rule :func:`d2nt_fd_pixel` (one-sided differences at gaps, mirrored with ``reflect``). Same arithmetic in both.

    Parameters
    ----------
    z : ndarray of float32, shape (H, W)
        Validated depth (never read where ``valid`` is False).
    valid : ndarray of bool, shape (H, W)
        Pixels whose depth may be used.
    v : int
        The row.
    f_x, f_y : float32
        Focal lengths (pixels).
    u_c : ndarray of float32, shape (W,)
        u - c_x of every column (:func:`surfnorm.kernels._rows.centred_columns`).
    v_c : float32
        v - c_y.
    reflect : bool
        ``border="reflect"``: a neighbour outside the image is mirrored (OpenCV BORDER_REFLECT_101).
    fill : float32
        Value written into all three components where there is no normal.
    col, runs : ndarray
        Scratch for :func:`surfnorm.kernels._rows.fast_row`: bool (W,), int64 (W // 2 + 1, 2).
    out_row : ndarray of float32, shape (W, 3)
        Row v of the output.
    """
    H, W = z.shape
    n_runs = fast_row(valid, v, col, runs)
    up, mid, dn = z[max(v - 1, 0)], z[v], z[min(v + 1, H - 1)]
    out_flat = out_row.reshape(3 * W)
    valid_v = valid[v]
    two = np.float32(2.0)
    u = 0
    for k in range(n_runs + 1):
        a, b = segment(runs, n_runs, k, W)
        fill_pixels(out_flat, u, a, fill)  # pixels without depth (the rule's value for them)
        for x in range(u, a):
            if valid_v[x]:
                d2nt_fd_pixel(z, valid, v, x, f_x, f_y, u_c[x], v_c, reflect, fill, out_row)
        if b > a:  # 3x3 all valid: central differences, no checks (views start at a: see laplacian_row)
            left, centre, right, above, below = mid[a - 1 : b - 1], mid[a:b], mid[a + 1 : b + 1], up[a:b], dn[a:b]
            u_cs, run_out = u_c[a:b], out_flat[3 * a : 3 * b]
            for i in range(b - a):
                z_u = (right[i] - left[i]) / two
                z_v = (below[i] - above[i]) / two
                n_x, n_y, n_z = d2nt_normal(centre[i], z_u, z_v, f_x, f_y, u_cs[i], v_c)
                store_unit_flat(run_out, i, n_x, n_y, n_z, True, fill)
        u = b


@njit
def _d2nt_fd_kernel(z, valid, f_x, f_y, c_x, c_y, reflect, fill, out, v0, v1):
    """D2NT with finite-difference gradients: one pass, row by row (rows v0 .. v1 - 1; halo 1 row)."""
    H, W = z.shape
    u_c = centred_columns(W, c_x)
    col, runs = np.empty(W, np.bool_), np.empty((W // 2 + 1, 2), np.int64)
    for v in range(v0, v1):
        d2nt_fd_row(z, valid, v, f_x, f_y, u_c, np.float32(v - c_y), reflect, fill, col, runs, out[v])


# --- D2NT with the DAG filter (d2nt_v2, and the first stage of d2nt_v3) ----------------------


@pixel
def dag_pixel(z, valid, v, u, p_h, p_up, p_dn, f_x, f_y, u_c, v_c, ratio, fill, out_row):
    """D2NT with DAG gradients at one pixel, any neighbours missing; returns whether it got a normal."""
    W = z.shape[1]
    z_u, ok_u = dag_gradient(z, valid, v, u, 0, 1, p_h[max(u - 1, 0)], p_h[min(u + 1, W - 1)], ratio)
    z_v, ok_v = dag_gradient(z, valid, v, u, 1, 0, p_up[u], p_dn[u], ratio)
    n_x, n_y, n_z = d2nt_normal(z[v, u], z_u, z_v, f_x, f_y, u_c, v_c)
    return store_unit(out_row, u, n_x, n_y, n_z, valid[v, u] & ok_u & ok_v, fill)


@row
def prepare_dag_row(z, valid, r, dlf, tau, rel, col, runs_r, s, p_v_r):
    """Row data of row r for the DAG filter: its fast runs, and the softmin weights of its pixels.

    ``z``, ``valid``: as in :func:`d2nt_fd_row`.

    Parameters
    ----------
    r : int
        The row.
    dlf : int
        Index of the DLF in ``DLF_NAMES`` (eq. 11): the smoothness is the vertical 1D one or the 3x3 one.
    tau : float
        Softness of the softmin (eq. 13), as :func:`surfnorm.kernels.gradients.kernel_tau` gives it.
    rel : float
        0: tau in depth units; > 0: tau relative to each pixel's depth
        (:func:`surfnorm.kernels.gradients.softmin_weights_row`).
    col : ndarray of bool, shape (W,)
        Scratch.
    runs_r : ndarray of int64, shape (W // 2 + 1, 2)
        Receives the fast runs of row r.
    s : ndarray of float32, shape (W,)
        Scratch: the smoothness s_p = |nabla^2 z_p| (eq. 11).
    p_v_r : ndarray of float32, shape (W,)
        Receives p = exp(-s / tau), the unnormalised softmin weight of each pixel (eq. 13).

    Returns
    -------
    int
        The number of fast runs of row r.
    """
    n_runs = fast_row(valid, r, col, runs_r)
    laplacian_row(z, valid, r, runs_r, n_runs, dlf, np.int64(1), s)
    softmin_weights_row(s, z[r], tau, rel, p_v_r)
    return n_runs


@row
def dag_row(z, valid, v, runs, n_runs, weights, cam, v_c, ratio, fill, out_row, ok_row):
    """Unit D2NT normals of row v with DAG gradients (eq. 9-14); ok_row[u] says whether (v, u) got one.

    Each gradient is lambda_b Delta_b z + lambda_f Delta_f z (eq. 10) with (lambda_b, lambda_f) the (truncated)
    softmin of the two neighbours' weights (eq. 12-14, :func:`surfnorm.kernels.gradients.softmin_pair`): in a
    branch-free loop where the 3x3 neighbourhood is valid, by the per-pixel rule
    :func:`surfnorm.kernels.gradients.dag_gradient` (one-sided at gaps) elsewhere.

    ``z``, ``valid``, ``v``, ``v_c``, ``fill``, ``out_row``: as in :func:`d2nt_fd_row`.

    Parameters
    ----------
    runs, n_runs : ndarray of int64 (W // 2 + 1, 2), int
        The fast runs of row v (:func:`prepare_dag_row`).
    weights : (p_h, p_up, p_dn), ndarrays of float32, shape (W,)
        Softmin weights exp(-s / tau) of row v, with the horizontal smoothness (they weigh left and right), and
        those of rows v - 1 and v + 1, with the vertical smoothness (they weigh up and down).
    cam : (f_x, f_y, u_c)
        Focal lengths (pixels, float32), and u - c_x of every column (ndarray of float32, shape (W,):
        :func:`surfnorm.kernels._rows.centred_columns`).
    ratio : float32
        e^(1/tau): the truncation of eq. 14 (inf: none; :func:`surfnorm.kernels.gradients.softmin_ratio`).
    ok_row : ndarray of bool, shape (W,)
        Receives whether each pixel got a normal.
    """
    p_h, p_up, p_dn = weights
    f_x, f_y, u_c = cam
    H, W = z.shape
    up, mid, dn = z[max(v - 1, 0)], z[v], z[min(v + 1, H - 1)]
    out_flat = out_row.reshape(3 * W)
    valid_v = valid[v]
    u = 0
    for k in range(n_runs + 1):
        a, b = segment(runs, n_runs, k, W)
        fill_pixels(out_flat, u, a, fill)  # pixels without depth (the rule's value for them)
        for x in range(u, a):
            ok = False
            if valid_v[x]:
                ok = dag_pixel(z, valid, v, x, p_h, p_up, p_dn, f_x, f_y, u_c[x], v_c, ratio, fill, out_row)
            ok_row[x] = ok
        if b > a:  # 3x3 all valid: both neighbours exist along both axes (views start at a: see laplacian_row)
            left, centre, right, above, below = mid[a - 1 : b - 1], mid[a:b], mid[a + 1 : b + 1], up[a:b], dn[a:b]
            p_l, p_r, p_a, p_b = p_h[a - 1 : b - 1], p_h[a + 1 : b + 1], p_up[a:b], p_dn[a:b]
            u_cs, run_out, run_ok = u_c[a:b], out_flat[3 * a : 3 * b], ok_row[a:b]
            for i in range(b - a):
                z_p = centre[i]
                lambda_l, lambda_r = softmin_pair(p_l[i], p_r[i], ratio)
                z_u = lambda_l * (z_p - left[i]) + lambda_r * (right[i] - z_p)
                lambda_u, lambda_d = softmin_pair(p_a[i], p_b[i], ratio)
                z_v = lambda_u * (z_p - above[i]) + lambda_d * (below[i] - z_p)
                n_x, n_y, n_z = d2nt_normal(z_p, z_u, z_v, f_x, f_y, u_cs[i], v_c)
                run_ok[i] = store_unit_flat(run_out, i, n_x, n_y, n_z, True, fill)
        u = b


@njit
def _d2nt_dag_kernel(z, valid, f_x, f_y, c_x, c_y, dlf, tau, rel, ratio, fill, out, v0, v1):
    """D2NT with DAG gradients (eq. 9-14), row by row (rows v0 .. v1 - 1 of out).

    Row buffers (rolling, row r in slot r % 3) hold each row's fast runs and
    each pixel's softmin weight exp(-s/tau), so every smoothness and
    exponential is computed once per pixel instead of once per neighbour.
    Halo: row v needs the weights of rows v - 1 .. v + 1 (each from its 3x3
    neighbourhood), so a band starting at v0 > 0 first prepares row v0 - 1.
    """
    H, W = z.shape
    cam = (f_x, f_y, centred_columns(W, c_x))
    col, ok_row = np.empty(W, np.bool_), np.empty(W, np.bool_)
    runs, n_runs = np.empty((3, W // 2 + 1, 2), np.int64), np.zeros(3, np.int64)
    p_v = np.empty((3, W), np.float32)
    s, p_h = np.empty(W, np.float32), np.empty(W, np.float32)
    if v0 > 0:
        n_runs[(v0 - 1) % 3] = prepare_dag_row(
            z, valid, v0 - 1, dlf, tau, rel, col, runs[(v0 - 1) % 3], s, p_v[(v0 - 1) % 3]
        )
    n_runs[v0 % 3] = prepare_dag_row(z, valid, v0, dlf, tau, rel, col, runs[v0 % 3], s, p_v[v0 % 3])
    for v in range(v0, v1):
        if v + 1 < H:
            n_runs[(v + 1) % 3] = prepare_dag_row(
                z, valid, v + 1, dlf, tau, rel, col, runs[(v + 1) % 3], s, p_v[(v + 1) % 3]
            )
        if dlf == 0:  # 1D DLF: the horizontal neighbours are scored with the horizontal filter
            laplacian_row(z, valid, v, runs[v % 3], n_runs[v % 3], np.int64(0), np.int64(0), s)
            softmin_weights_row(s, z[v], tau, rel, p_h)
        else:
            p_h[:] = p_v[v % 3]
        weights = (p_h, p_v[(v - 1) % 3], p_v[(v + 1) % 3])
        dag_row(z, valid, v, runs[v % 3], n_runs[v % 3], weights, cam, np.float32(v - c_y), ratio, fill, out[v], ok_row)


def d2nt(
    z,
    valid,
    cam,
    out,
    *,
    gradient="fd",
    dlf="1d",
    tau=1.0,
    truncate=True,
    border="one-sided",
    fill=0.0,
    relative=0.0,
    bands=whole,
):
    """D2NT with finite-difference (``gradient="fd"``) or DAG (``"dag"``) gradients, into ``out`` (H, W, 3).

    ``relative`` > 0 (the scale-invariant mode): DAG's tau is relative to each pixel's depth, tau z / relative
    (see :func:`surfnorm.kernels.gradients.softmin_weights_row`); 0: tau in depth units (paper-faithful).
    ``bands``: how rows are split over threads (see :mod:`surfnorm._bands`).
    """
    f = (np.float32(cam.fx), np.float32(cam.fy), np.float32(cam.cx), np.float32(cam.cy))
    if gradient == "fd":
        reflect, fill32 = border == "reflect", np.float32(fill)
        bands(lambda a, b: _d2nt_fd_kernel(z, valid, *f, reflect, fill32, out, a, b), z.shape[0])
    else:
        dag = (dlf_code(dlf), kernel_tau(tau), float(relative), softmin_ratio(tau, truncate), np.float32(fill))
        bands(lambda a, b: _d2nt_dag_kernel(z, valid, *f, *dag, out, a, b), z.shape[0])
    return out


# --- CP2TV -------------------------------------------------------------------------------------


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


@pixel
def cp2tv_pixel(z, valid, v, u, f_x, f_y, c_x, c_y, reflect, fill, out_row):
    ux, uy, uz, ok_u = tangent(z, valid, v, u, 0, 1, f_x, f_y, c_x, c_y, reflect)
    vx, vy, vz, ok_v = tangent(z, valid, v, u, 1, 0, f_x, f_y, c_x, c_y, reflect)
    # n = t_v x t_u
    store_unit(out_row, u, vy * uz - vz * uy, vz * ux - vx * uz, vx * uy - vy * ux, valid[v, u] & ok_u & ok_v, fill)


@row
def cp2tv_row(z, valid, v, f_x, f_y, c_x, c_y, u_c, reflect, fill, col, runs, out_row):
    """Row v of CP2TV: n = t_v x t_u of the finite-difference tangent vectors of the back-projected points.

    ``z``, ``valid``, ``v``, ``f_x``, ``f_y``, ``reflect``, ``fill``, ``col``, ``runs``, ``out_row``: as in
    :func:`d2nt_fd_row`.

    Parameters
    ----------
    c_x, c_y : float32
        Principal point (pixels, 0-based).
    u_c : ndarray of float64, shape (W,)
        u - c_x in float64, as :func:`back_project` computes it (the 3D points are float64).
    """
    H, W = z.shape
    f_x64, f_y64 = np.float64(f_x), np.float64(f_y)
    two = np.float32(2.0)
    n_runs = fast_row(valid, v, col, runs)
    up, mid, dn = z[max(v - 1, 0)], z[v], z[min(v + 1, H - 1)]
    out_flat = out_row.reshape(3 * W)
    valid_v = valid[v]
    v_c, v_up, v_dn = v - c_y, (v - 1) - c_y, (v + 1) - c_y
    u = 0
    for k in range(n_runs + 1):
        a, b = segment(runs, n_runs, k, W)
        fill_pixels(out_flat, u, a, fill)  # pixels without depth (the rule's value for them)
        for x in range(u, a):
            if valid_v[x]:
                cp2tv_pixel(z, valid, v, x, f_x, f_y, c_x, c_y, reflect, fill, out_row)
        if b > a:  # central differences of back-projected neighbours, no checks (views: see laplacian_row)
            left, right, above, below = mid[a - 1 : b - 1], mid[a + 1 : b + 1], up[a:b], dn[a:b]
            uc_l, uc_r, uc_c, run_out = u_c[a - 1 : b - 1], u_c[a + 1 : b + 1], u_c[a:b], out_flat[3 * a : 3 * b]
            for i in range(b - a):
                z_l, z_r, z_u, z_d = left[i], right[i], above[i], below[i]
                t_ux = (z_r * uc_r[i] / f_x64 - z_l * uc_l[i] / f_x64) / two
                t_uy = (z_r * v_c / f_y64 - z_l * v_c / f_y64) / two
                t_uz = (z_r - z_l) / two
                t_vx = (z_d * uc_c[i] / f_x64 - z_u * uc_c[i] / f_x64) / two
                t_vy = (z_d * v_dn / f_y64 - z_u * v_up / f_y64) / two
                t_vz = (z_d - z_u) / two
                store_unit_flat(
                    run_out,
                    i,
                    t_vy * t_uz - t_vz * t_uy,
                    t_vz * t_ux - t_vx * t_uz,
                    t_vx * t_uy - t_vy * t_ux,
                    True,
                    fill,
                )
        u = b


@njit
def _cp2tv_kernel(z, valid, f_x, f_y, c_x, c_y, reflect, fill, out, v0, v1):
    """CP2TV, rows v0 .. v1 - 1 (halo 1 row)."""
    H, W = z.shape
    u_c = np.empty(W, np.float64)
    for u in range(W):
        u_c[u] = u - c_x
    col, runs = np.empty(W, np.bool_), np.empty((W // 2 + 1, 2), np.int64)
    for v in range(v0, v1):
        cp2tv_row(z, valid, v, f_x, f_y, c_x, c_y, u_c, reflect, fill, col, runs, out[v])


def cp2tv(z, valid, cam, out, *, border="one-sided", fill=0.0, bands=whole):
    """CP2TV (Nakagawa et al. 2015): cross product of finite-difference tangent vectors, into ``out``."""
    args = (
        np.float32(cam.fx),
        np.float32(cam.fy),
        np.float32(cam.cx),
        np.float32(cam.cy),
        border == "reflect",
        np.float32(fill),
    )
    bands(lambda a, b: _cp2tv_kernel(z, valid, *args, out, a, b), z.shape[0])
    return out
