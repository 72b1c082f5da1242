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

from .._bands import whole
from .._config import njit, pixel, row
from .gradients import (clamp, copy_row, dlf_code, fast_row, fd_gradient, kernel_tau, laplacian_row, segment, softmin_pair,
                        softmin_ratio, softmin_weights_row, stencil, usable)
from .mnr import mnr_row, self_smoothness_row

__all__ = ["d2nt", "d2nt_v3", "cp2tv"]


@pixel
def write_unit(out, v, u, n_x, n_y, n_z, fill):
    """Store n / |n| at (v, u), or the fill value when n has no direction; returns whether stored.

    Written with selects, not branches (see :func:`surfnorm.kernels.gradients.clamp`).
    """
    norm = math.sqrt(n_x * n_x + n_y * n_y + n_z * n_z)
    ok = (norm > 0) & (norm < np.inf)
    u_x, u_y, u_z = n_x / norm, n_y / norm, n_z / norm
    out[v, u, 0] = u_x if ok else fill
    out[v, u, 1] = u_y if ok else fill
    out[v, u, 2] = u_z if ok else fill
    return ok


@pixel
def store_unit_flat(out_flat, i, n_x, n_y, n_z, fill):
    """:func:`store_pixel` into a flat run of pixels (x, y, z, x, y, z, ...).

    LLVM cannot tell that out[u, 0], out[u, 1], out[u, 2] of a 2-D view do not
    overlap (its strides are run-time values), so it vectorises only the flat form.
    """
    norm = math.sqrt(n_x * n_x + n_y * n_y + n_z * n_z)
    ok = (norm > 0) & (norm < np.inf)
    u_x, u_y, u_z = n_x / norm, n_y / norm, n_z / norm  # divided outside the selects, which LLVM then keeps branch-free
    out_flat[3 * i] = u_x if ok else fill
    out_flat[3 * i + 1] = u_y if ok else fill
    out_flat[3 * i + 2] = u_z if ok else fill
    return ok


@pixel
def d2nt_normal(z, z_u, z_v, f_x, f_y, u_c, v_c):
    """Eq. 9 (camera-facing sign) with u_c = u - c_x, v_c = v - c_y; not normalised."""
    return f_x * z_u, f_y * z_v, -(z + u_c * z_u + v_c * z_v)


@pixel
def centred_columns(W, c_x):
    """u - c_x for every column, as float32 (one array instead of one conversion per pixel)."""
    u_c = np.empty(W, dtype=np.float32)
    for u in range(W):
        u_c[u] = np.float32(u - c_x)
    return u_c


# --- D2NT with finite differences (d2nt_basic) ------------------------------------------------


@pixel
def store_pixel(out_row, u, n_x, n_y, n_z, ok, fill):
    """Store n / |n| at u of a row if ``ok`` and n has a direction, else the fill value; returns whether stored."""
    norm = math.sqrt(n_x * n_x + n_y * n_y + n_z * n_z)
    ok = ok & (norm > 0) & (norm < np.inf)
    u_x, u_y, u_z = n_x / norm, n_y / norm, n_z / norm
    out_row[u, 0] = u_x if ok else fill
    out_row[u, 1] = u_y if ok else fill
    out_row[u, 2] = u_z if ok else fill
    return ok


@pixel
def d2nt_fd_pixel(z, valid, v, u, f_x, f_y, u_c, v_c, reflect, fill, out_row):
    """The general rule at one pixel: per pixel gradients (one-sided at gaps) -> eq. 9 -> unit length."""
    z_u, ok_u = fd_gradient(z, valid, v, u, 0, 1, reflect)
    z_v, ok_v = fd_gradient(z, valid, v, u, 1, 0, reflect)
    n_x, n_y, n_z = d2nt_normal(z[v, u], z_u, z_v, f_x, f_y, u_c, v_c)
    store_pixel(out_row, u, n_x, n_y, n_z, valid[v, u] & ok_u & ok_v, fill)


@row
def d2nt_fd_row(z, valid, v, f_x, f_y, u_c, v_c, reflect, fill, col, runs, out_row):
    """Row v of D2NT with finite-difference gradients: per pixel gradients -> eq. 9 -> unit length."""
    H, W = z.shape
    n_runs = fast_row(valid, v, col, runs)
    up, mid, dn = z[max(v - 1, 0)], z[v], z[min(v + 1, H - 1)]
    out_flat = out_row.reshape(3 * W)
    two = np.float32(2.0)
    u = 0
    for k in range(n_runs + 1):
        a, b = segment(runs, n_runs, k, W)
        for x in range(u, a):
            d2nt_fd_pixel(z, valid, v, x, f_x, f_y, u_c[x], v_c, reflect, fill, out_row)
        if b > a:  # 3x3 all valid: central differences, no checks (views start at a: see laplacian_row)
            left, centre, right, above, below = mid[a - 1:b - 1], mid[a:b], mid[a + 1:b + 1], up[a:b], dn[a:b]
            u_cs, run_out = u_c[a:b], out_flat[3 * a:3 * b]
            for i in range(b - a):
                z_u = (right[i] - left[i]) / two
                z_v = (below[i] - above[i]) / two
                n_x, n_y, n_z = d2nt_normal(centre[i], z_u, z_v, f_x, f_y, u_cs[i], v_c)
                store_unit_flat(run_out, i, n_x, n_y, n_z, fill)
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
def dag_pixel_gradient(z, valid, v, u, dv, du, p_b, p_f, ratio):
    """DAG gradient along (dv, du) from the neighbours' softmin weights p_b, p_f (eq. 10, 12-14).

    lambda_b Delta_b z + lambda_f Delta_f z; one-sided where only one
    neighbour is usable. Returns (gradient, ok).
    """
    H, W = z.shape
    v_b, u_b, v_f, u_f = clamp(v - dv, H), clamp(u - du, W), clamp(v + dv, H), clamp(u + du, W)
    has_b = usable(valid, v - dv, u - du)
    has_f = usable(valid, v + dv, u + du)
    lambda_b, lambda_f = softmin_pair(p_b, p_f, ratio)
    if not (has_b & has_f):
        lambda_b = np.float32(1.0) if has_b else np.float32(0.0)
        lambda_f = np.float32(1.0) if has_f else np.float32(0.0)
    z_p, z_b, z_f = z[v, u], z[v_b, u_b], z[v_f, u_f]  # read unconditionally: see gradients.clamp
    delta_b = (z_p - z_b) if has_b else np.float32(0.0)
    delta_f = (z_f - z_p) if has_f else np.float32(0.0)
    return lambda_b * delta_b + lambda_f * delta_f, has_b | has_f


@pixel
def dag_pixel(z, valid, v, u, p_h, p_up, p_dn, f_x, f_y, u_c, v_c, ratio, fill, out_row):
    """D2NT with DAG gradients at one pixel, any neighbours missing; returns whether it got a normal."""
    W = z.shape[1]
    z_u, ok_u = dag_pixel_gradient(z, valid, v, u, 0, 1, p_h[max(u - 1, 0)], p_h[min(u + 1, W - 1)], ratio)
    z_v, ok_v = dag_pixel_gradient(z, valid, v, u, 1, 0, p_up[u], p_dn[u], ratio)
    n_x, n_y, n_z = d2nt_normal(z[v, u], z_u, z_v, f_x, f_y, u_c, v_c)
    return store_pixel(out_row, u, n_x, n_y, n_z, valid[v, u] & ok_u & ok_v, fill)


@row
def prepare_dag_row(z, valid, r, dlf, tau, rel, col, runs_r, s, p_v_r):
    """For row r: its fast runs (returns their number), and p = exp(-s / tau) with the vertical (1D) or 3x3 smoothness
    (``rel``: see :func:`surfnorm.kernels.gradients.softmin_weights_row`)."""
    n_runs = fast_row(valid, r, col, runs_r)
    laplacian_row(z, valid, r, runs_r, n_runs, dlf, np.int64(1), s)
    softmin_weights_row(s, z[r], tau, rel, p_v_r)
    return n_runs


@row
def dag_row(z, valid, v, runs, n_runs, p_h, p_up, p_dn, f_x, f_y, u_c, v_c, ratio, fill, out_row, ok_row):
    """Unit D2NT normals of row v with DAG gradients; ok_row[u] says whether (v, u) got one.

    p_h: softmin weights exp(-s/tau) of row v with the horizontal smoothness;
    p_up, p_dn: those of rows v - 1 and v + 1 with the vertical smoothness.
    """
    H, W = z.shape
    up, mid, dn = z[max(v - 1, 0)], z[v], z[min(v + 1, H - 1)]
    out_flat = out_row.reshape(3 * W)
    u = 0
    for k in range(n_runs + 1):
        a, b = segment(runs, n_runs, k, W)
        for x in range(u, a):
            ok_row[x] = dag_pixel(z, valid, v, x, p_h, p_up, p_dn, f_x, f_y, u_c[x], v_c, ratio, fill, out_row)
        if b > a:  # 3x3 all valid: both neighbours exist along both axes (views start at a: see laplacian_row)
            left, centre, right, above, below = mid[a - 1:b - 1], mid[a:b], mid[a + 1:b + 1], up[a:b], dn[a:b]
            p_l, p_r, p_a, p_b = p_h[a - 1:b - 1], p_h[a + 1:b + 1], p_up[a:b], p_dn[a:b]
            u_cs, run_out, run_ok = u_c[a:b], out_flat[3 * a:3 * b], ok_row[a:b]
            for i in range(b - a):
                z_p = centre[i]
                lambda_l, lambda_r = softmin_pair(p_l[i], p_r[i], ratio)
                z_u = lambda_l * (z_p - left[i]) + lambda_r * (right[i] - z_p)
                lambda_u, lambda_d = softmin_pair(p_a[i], p_b[i], ratio)
                z_v = lambda_u * (z_p - above[i]) + lambda_d * (below[i] - z_p)
                n_x, n_y, n_z = d2nt_normal(z_p, z_u, z_v, f_x, f_y, u_cs[i], v_c)
                run_ok[i] = store_unit_flat(run_out, i, n_x, n_y, n_z, fill)
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
    u_c = centred_columns(W, c_x)
    col, ok_row = np.empty(W, np.bool_), np.empty(W, np.bool_)
    runs, n_runs = np.empty((3, W // 2 + 1, 2), np.int64), np.zeros(3, np.int64)
    p_v = np.empty((3, W), np.float32)
    s, p_h = np.empty(W, np.float32), np.empty(W, np.float32)
    if v0 > 0:
        n_runs[(v0 - 1) % 3] = prepare_dag_row(z, valid, v0 - 1, dlf, tau, rel, col, runs[(v0 - 1) % 3], s, p_v[(v0 - 1) % 3])
    n_runs[v0 % 3] = prepare_dag_row(z, valid, v0, dlf, tau, rel, col, runs[v0 % 3], s, p_v[v0 % 3])
    for v in range(v0, v1):
        if v + 1 < H:
            n_runs[(v + 1) % 3] = prepare_dag_row(z, valid, v + 1, dlf, tau, rel, col, runs[(v + 1) % 3], s,
                                                  p_v[(v + 1) % 3])
        if dlf == 0:  # 1D DLF: the horizontal neighbours are scored with the horizontal filter
            laplacian_row(z, valid, v, runs[v % 3], n_runs[v % 3], np.int64(0), np.int64(0), s)
            softmin_weights_row(s, z[v], tau, rel, p_h)
        else:
            p_h[:] = p_v[v % 3]
        dag_row(z, valid, v, runs[v % 3], n_runs[v % 3], p_h, p_v[(v - 1) % 3], p_v[(v + 1) % 3], f_x, f_y, u_c,
                np.float32(v - c_y), ratio, fill, out[v], ok_row)


@row
def v3_estimate_row(z, valid, q, f_x, f_y, u_c, c_y, dlf, tau, rel, ratio, mnr_dlf, fill, fill_counts, col, runs, n_runs,
                    p_v, sm_v, s, p_h, ok_row, raw, has):
    """d2nt_v3, step 1 for row q: row data of row q + 1, then the unrefined normals of row q (slots: see the kernel)."""
    H, W = z.shape
    if q + 1 < H:
        j = (q + 1) % 4
        n_runs[j] = prepare_dag_row(z, valid, q + 1, dlf, tau, rel, col, runs[j], s, p_v[j])
        laplacian_row(z, valid, q + 1, runs[j], n_runs[j], mnr_dlf, np.int64(1), sm_v[j])
    if q < H:
        j = q % 4
        if dlf == 0:
            laplacian_row(z, valid, q, runs[j], n_runs[j], np.int64(0), np.int64(0), s)
            softmin_weights_row(s, z[q], tau, rel, p_h)
        else:
            copy_row(p_v[j], p_h)
        dag_row(z, valid, q, runs[j], n_runs[j], p_h, p_v[(q - 1) % 4], p_v[(q + 1) % 4], f_x, f_y, u_c,
                np.float32(q - c_y), ratio, fill, raw[q % 3], ok_row)
        has_q, valid_q = has[q % 3], valid[q]
        for u in range(W):
            has_q[u] = ok_row[u] | (valid_q[u] & fill_counts)


@row
def v3_refine_row(z, valid, v, mnr_dlf, tie_tol, fill, runs, n_runs, sm_v, sm_h, s_self, raw, has, col, mruns, choice,
                  out_row):
    """d2nt_v3, step 2 for row v: MNR of its unrefined normals into the output row."""
    H = z.shape[0]
    j = v % 4
    if mnr_dlf == 0:
        laplacian_row(z, valid, v, runs[j], n_runs[j], np.int64(0), np.int64(0), sm_h)
    else:
        copy_row(sm_v[j], sm_h)
    self_smoothness_row(sm_h, sm_v[j], mnr_dlf == 0, s_self)
    mnr_row(v, H, raw[(v - 1) % 3], raw[v % 3], raw[(v + 1) % 3], has[(v - 1) % 3], has[v % 3],
            has[(v + 1) % 3], sm_h, sm_v[(v - 1) % 4], sm_v[(v + 1) % 4], s_self, z[v], tie_tol, fill, col, mruns,
            choice, out_row)


@njit
def _d2nt_v3_kernel(z, valid, f_x, f_y, c_x, c_y, dlf, tau, rel, ratio, mnr_dlf, tie_tol, fill, out, v0, v1):
    """D2NT with DAG gradients, then MNR (eq. 9-20), fused into one sweep over rows v0 .. v1 - 1 of out.

    The unrefined normals live only in a rolling buffer of 3 rows: row v + 1
    is estimated just before row v is refined (MNR looks one row up and down).
    Row data (fast runs, softmin weights, MNR smoothness) use 4 slots, rows
    v - 1 .. v + 2. Halo: refining row v0 needs the unrefined normals of row
    v0 - 1, which need the weights of row v0 - 2 (3 rows of depth above the
    band); a band starting at v0 > 0 primes rows q0 - 1 and q0 = v0 - 1.
    """
    H, W = z.shape
    u_c = centred_columns(W, c_x)
    col, ok_row = np.empty(W, np.bool_), np.empty(W, np.bool_)
    runs, n_runs = np.empty((4, W // 2 + 1, 2), np.int64), np.zeros(4, np.int64)
    mruns, choice = np.empty((W // 2 + 1, 2), np.int64), np.empty(3 * W, np.int32)
    p_v, sm_v = np.empty((4, W), np.float32), np.empty((4, W), np.float32)
    s, p_h, sm_h, s_self = (np.empty(W, np.float32), np.empty(W, np.float32), np.empty(W, np.float32),
                            np.empty(W, np.float32))
    raw, has = np.empty((3, W, 3), np.float32), np.empty((3, W), np.bool_)
    # A pixel whose normal failed holds `fill`; MNR treats it as having a normal when fill is non-zero and finite
    # (as when MNR runs on a finished map): fill_counts.
    fill_sq = fill * fill + fill * fill + fill * fill
    fill_counts = (fill_sq > 0) & (fill_sq < np.inf)
    q0 = max(v0 - 1, 0)  # the first row estimated
    if q0 > 0:
        j = (q0 - 1) % 4
        n_runs[j] = prepare_dag_row(z, valid, q0 - 1, dlf, tau, rel, col, runs[j], s, p_v[j])
    j = q0 % 4
    n_runs[j] = prepare_dag_row(z, valid, q0, dlf, tau, rel, col, runs[j], s, p_v[j])
    laplacian_row(z, valid, q0, runs[j], n_runs[j], mnr_dlf, np.int64(1), sm_v[j])
    for r in range(q0 - 1, v1):
        # estimate row q = r + 1 (needs the weights of rows q - 1 .. q + 1), then refine row v = r
        v3_estimate_row(z, valid, r + 1, f_x, f_y, u_c, c_y, dlf, tau, rel, ratio, mnr_dlf, fill, fill_counts, col, runs,
                        n_runs, p_v, sm_v, s, p_h, ok_row, raw, has)
        if r >= v0:
            v3_refine_row(z, valid, r, mnr_dlf, tie_tol, fill, runs, n_runs, sm_v, sm_h, s_self, raw, has, col, mruns,
                          choice, out[r])


def d2nt(z, valid, cam, out, *, gradient="fd", dlf="1d", tau=1.0, truncate=True, border="one-sided", fill=0.0,
         relative=0.0, bands=whole):
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


def d2nt_v3(z, valid, cam, out, *, dlf="1d", tau=1.0, truncate=True, mnr_dlf="alpha", fill=0.0, tie_tol=0.0,
            relative=0.0, bands=whole):
    """D2NT with DAG gradients and MNR (``d2nt_v3``) in one sweep, into ``out`` (H, W, 3).

    ``tie_tol``: MNR's relative near-tie tolerance of the scale-invariant mode (see :func:`surfnorm.kernels.mnr.mnr_row`);
    ``relative``: DAG's tau relative to each pixel's depth in that mode (see :func:`d2nt`).
    ``bands``: how rows are split over threads (see :mod:`surfnorm._bands`).
    """
    f = (np.float32(cam.fx), np.float32(cam.fy), np.float32(cam.cx), np.float32(cam.cy))
    args = (dlf_code(dlf), kernel_tau(tau), float(relative), softmin_ratio(tau, truncate), dlf_code(mnr_dlf),
            np.float32(tie_tol), np.float32(fill))
    bands(lambda a, b: _d2nt_v3_kernel(z, valid, *f, *args, out, a, b), z.shape[0])
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
    store_pixel(out_row, u, vy * uz - vz * uy, vz * ux - vx * uz, vx * uy - vy * ux, valid[v, u] & ok_u & ok_v, fill)


@row
def cp2tv_row(z, valid, v, f_x, f_y, c_x, c_y, u_c, reflect, fill, col, runs, out_row):
    """Row v of CP2TV; ``u_c`` holds u - c_x in float64, as back_project computes it (3D points are float64)."""
    H, W = z.shape
    f_x64, f_y64 = np.float64(f_x), np.float64(f_y)
    two = np.float32(2.0)
    n_runs = fast_row(valid, v, col, runs)
    up, mid, dn = z[max(v - 1, 0)], z[v], z[min(v + 1, H - 1)]
    out_flat = out_row.reshape(3 * W)
    v_c, v_up, v_dn = v - c_y, (v - 1) - c_y, (v + 1) - c_y
    u = 0
    for k in range(n_runs + 1):
        a, b = segment(runs, n_runs, k, W)
        for x in range(u, a):
            cp2tv_pixel(z, valid, v, x, f_x, f_y, c_x, c_y, reflect, fill, out_row)
        if b > a:  # central differences of back-projected neighbours, no checks (views: see laplacian_row)
            left, right, above, below = mid[a - 1:b - 1], mid[a + 1:b + 1], up[a:b], dn[a:b]
            uc_l, uc_r, uc_c, run_out = u_c[a - 1:b - 1], u_c[a + 1:b + 1], u_c[a:b], out_flat[3 * a:3 * b]
            for i in range(b - a):
                z_l, z_r, z_u, z_d = left[i], right[i], above[i], below[i]
                t_ux = (z_r * uc_r[i] / f_x64 - z_l * uc_l[i] / f_x64) / two
                t_uy = (z_r * v_c / f_y64 - z_l * v_c / f_y64) / two
                t_uz = (z_r - z_l) / two
                t_vx = (z_d * uc_c[i] / f_x64 - z_u * uc_c[i] / f_x64) / two
                t_vy = (z_d * v_dn / f_y64 - z_u * v_up / f_y64) / two
                t_vz = (z_d - z_u) / two
                store_unit_flat(run_out, i, t_vy * t_uz - t_vz * t_uy, t_vz * t_ux - t_vx * t_uz,
                                t_vx * t_uy - t_vy * t_ux, fill)
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
    args = (np.float32(cam.fx), np.float32(cam.fy), np.float32(cam.cx), np.float32(cam.cy), border == "reflect",
            np.float32(fill))
    bands(lambda a, b: _cp2tv_kernel(z, valid, *args, out, a, b), z.shape[0])
    return out
