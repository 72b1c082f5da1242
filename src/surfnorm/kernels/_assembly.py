"""From the fitted pixels' planes to every pixel's normal (eq. (2) of :mod:`surfnorm.kernels.adaptive_fit`).

With ``stride`` 1 every pixel has its own fit (:func:`normal_row`). With ``stride`` 2 the windows are fitted on
the even rows and columns only, and every other pixel takes the planes of the fitted pixels next to it
(:func:`assembled_row`): the mean of those that predict its own w within their noise limit, else the closest.
With ``stride`` 4 the windows are fitted on every fourth row and column, and every pixel takes the planes of the
four fitted pixels at the corners of its 4x4 cell (:func:`cell_row`): their mean weighted bilinearly, of those that
predict its own w within their noise limit, else the closest.
A band of rows keeps the planes of its last three fitted rows in a ring (:func:`row_done`) and writes a row's
normals as soon as the planes it reads are known (:func:`emit_row`).
"""

from __future__ import annotations

import math

import numpy as np

from .._config import njit, pixel, select
from .._constants import CELL, TIE

__all__ = [
    "unit_normal",
    "normal_row",
    "assembled_row",
    "cell_row",
    "emit_row",
    "holds_normal",
    "mark_row",
    "row_done",
    "first_fitted_row",
    "last_fitted_row",
    "cell_scale",
]


@pixel
def unit_normal(zp, a, g_u, g_v, u, v, fx, fy, cx, cy):
    """Eq. (2) at pixel (u, v) of depth ``zp`` from its plane (a: w there, g_u, g_v), as float32."""
    a = select(a > 0.0, a, 1.0 / zp)  # a fit that passes behind the camera: the pixel's own w
    nx = fx * g_u
    ny = fy * g_v
    nz = a - g_u * (u - cx) - g_v * (v - cy)
    inv_norm = -1.0 / math.sqrt(nx * nx + ny * ny + nz * nz)
    return np.float32(nx * inv_norm), np.float32(ny * inv_norm), np.float32(nz * inv_norm)


@njit(noalias=True, _nrt=False)
def normal_row(z_row, valid_row, v, g_u, g_v, a, dof, fx, fy, cx, cy, fill, out_row):
    """Eq. (2): the unit normal facing the camera from each pixel's fit; ``fill`` without one."""
    W = z_row.shape[0]
    for u in range(W):
        ok = valid_row[u] & (dof[u] > 0.0)
        nx, ny, nz = unit_normal(z_row[u], a[u], g_u[u], g_v[u], u, v, fx, fy, cx, cy)
        out_row[3 * u] = select(ok, nx, fill)
        out_row[3 * u + 1] = select(ok, ny, fill)
        out_row[3 * u + 2] = select(ok, nz, fill)


@njit(noalias=True, _nrt=False)
def expand_row(a, g_u, g_v, ok, limit, e):
    """The planes of a row's fitted pixels (columns 0, 2, 4, ...: a, g_u, g_v, ok and the noise limit, each
    (n_fit,)) at full width: e[:, u] is column 2 (u // 2)'s, for u = 0 .. W (none at u = W for an even W)."""
    W = e.shape[1] - 1
    for i in range(a.shape[0]):
        for c, x in ((0, a[i]), (1, g_u[i]), (2, g_v[i]), (3, ok[i]), (4, limit[i])):
            e[c, 2 * i] = x
            if 2 * i + 1 <= W:
                e[c, 2 * i + 1] = x
    if W % 2 == 0:
        e[3, W] = 0.0


@pixel
def carried(rows, k, du, dv, w_p):
    """The plane of the fitted pixel held at ``k`` in ``rows`` (:func:`expand_row`) carried to a pixel ``du``
    columns and ``dv`` rows from it: (w there, g_u, g_v, squared error to the pixel's own w_p: inf where that
    fitted pixel has no plane, and the fitted pixel's noise limit: -1 there)."""
    has = rows[3, k] > 0.0
    p = rows[0, k] + rows[1, k] * du + rows[2, k] * dv
    return p, rows[1, k], rows[2, k], select(has, (p - w_p) * (p - w_p), np.inf), select(has, rows[4, k], -1.0)


@pixel
def interpolated(p0, gu0, gv0, e0, l0, p1, gu1, gv1, e1, l1, p2, gu2, gv2, e2, l2, p3, gu3, gv3, e3, l3):
    """The plane at a pixel from those of up to four fitted pixels next to it (:func:`carried`; a missing one
    has e = inf): the mean of those that predict the pixel's w within their noise limit (e <= l), else the
    one that predicts it closest (one closer by more than TIE of the squared error replaces the one before
    it). Returns (a, g_u, g_v, found); limits of -1 give the closest one."""
    q0 = e0 <= l0
    q1 = e1 <= l1
    q2 = e2 <= l2
    q3 = e3 <= l3
    n = q0 + q1 + q2 + q3
    s_a = select(q0, p0, 0.0) + select(q1, p1, 0.0) + select(q2, p2, 0.0) + select(q3, p3, 0.0)
    s_u = select(q0, gu0, 0.0) + select(q1, gu1, 0.0) + select(q2, gu2, 0.0) + select(q3, gu3, 0.0)
    s_v = select(q0, gv0, 0.0) + select(q1, gv1, 0.0) + select(q2, gv2, 0.0) + select(q3, gv3, 0.0)
    best = e0
    a_c = p0
    gu_c = gu0
    gv_c = gv0
    c = e1 < best * (1.0 - TIE)
    best, a_c, gu_c, gv_c = select(c, e1, best), select(c, p1, a_c), select(c, gu1, gu_c), select(c, gv1, gv_c)
    c = e2 < best * (1.0 - TIE)
    best, a_c, gu_c, gv_c = select(c, e2, best), select(c, p2, a_c), select(c, gu2, gu_c), select(c, gv2, gv_c)
    c = e3 < best * (1.0 - TIE)
    best, a_c, gu_c, gv_c = select(c, e3, best), select(c, p3, a_c), select(c, gu3, gu_c), select(c, gv3, gv_c)
    mean = n > 0
    inv_n = select(n == 2, 0.5, select(n == 4, 0.25, select(n == 3, 1.0 / 3.0, 1.0)))  # 1 / n, multiplied
    return (
        select(mean, s_a * inv_n, a_c),
        select(mean, s_u * inv_n, gu_c),
        select(mean, s_v * inv_n, gv_c),
        best < np.inf,
    )


@pixel
def _put_normal(z_row, valid_row, u, o, a, gu, gv, found, fx, fy, cx, cy, fill, out_row):
    """Eq. (2) at pixel u of row o from its plane into ``out_row`` (``fill`` where it is invalid or has none);
    returns whether it got one."""
    ok = valid_row[u] & found
    nx, ny, nz = unit_normal(z_row[u], a, gu, gv, u, o, fx, fy, cx, cy)
    out_row[3 * u] = select(ok, nx, fill)
    out_row[3 * u + 1] = select(ok, ny, fill)
    out_row[3 * u + 2] = select(ok, nz, fill)
    return ok


@njit(noalias=True, _nrt=False)
def assembled_row(z_row, valid_row, o, up2, up1, same, dn1, dn2, cam, fill, got, out_row):
    """Eq. (2) for every pixel of row ``o`` with ``stride`` 2, from the planes of the fitted rows around it
    (:func:`expand_row`, or a row without planes): ``same`` the row itself (o even), ``up2`` and ``dn2`` the
    fitted rows two above and below it, ``up1`` and ``dn1`` those just above and below it (o odd).

    A fitted pixel (even row and column) keeps its plane. Every other one takes :func:`interpolated` of the
    fitted pixels of its 3x3 neighbourhood (left and right; above and below; the four diagonal ones), and
    where none of them has a plane, the closest of the other fitted pixels of its 5x5 neighbourhood. On
    the full-width rows of :func:`expand_row` a pixel u finds the fitted pixels of its column pair at u and
    u + 1: its own plane twice (the mean of a value with itself is that value, to the bit), or its left
    and right ones, so that the first pass over the row reads contiguous memory, branch-free (it
    vectorises). ``got`` is scratch (W,).
    """
    W = z_row.shape[0]
    fx, fy, cx, cy = cam
    inf = np.inf
    odd = o % 2 == 1
    # two loops, not one with the choice inside: the compiler computed both sides of it for every pixel
    if odd:  # above and below, or the four diagonal ones
        for u in range(W):
            w_p = 1.0 / z_row[u]
            du = float(u % 2)
            p0, gu0, gv0, e0, l0 = carried(up1, u, du, 1.0, w_p)
            p1, gu1, gv1, e1, l1 = carried(up1, u + 1, -du, 1.0, w_p)
            p2, gu2, gv2, e2, l2 = carried(dn1, u, du, -1.0, w_p)
            p3, gu3, gv3, e3, l3 = carried(dn1, u + 1, -du, -1.0, w_p)
            a, gu, gv, found = interpolated(
                p0, gu0, gv0, e0, l0, p1, gu1, gv1, e1, l1, p2, gu2, gv2, e2, l2, p3, gu3, gv3, e3, l3
            )
            got[u] = _put_normal(z_row, valid_row, u, o, a, gu, gv, found, fx, fy, cx, cy, fill, out_row)
    else:  # its own plane twice, or the left and right ones; no others (the compiler drops them)
        for u in range(W):
            w_p = 1.0 / z_row[u]
            du = float(u % 2)
            p0, gu0, gv0, e0, l0 = carried(same, u, du, 0.0, w_p)
            p1, gu1, gv1, e1, l1 = carried(same, u + 1, -du, 0.0, w_p)
            a, gu, gv, found = interpolated(
                p0, gu0, gv0, e0, l0, p1, gu1, gv1, e1, l1, 0.0, 0.0, 0.0, inf, -1.0, 0.0, 0.0, 0.0, inf, -1.0
            )
            got[u] = _put_normal(z_row, valid_row, u, o, a, gu, gv, found, fx, fy, cx, cy, fill, out_row)
    for u in range(W):  # the few without a plane yet: the other fitted pixels of the 5x5 neighbourhood
        if got[u] or not valid_row[u] or u % 2 == o % 2:  # fitted, or diagonal to the fitted ones: no others
            continue
        w_p = 1.0 / z_row[u]
        if odd:  # even column: two columns left and right in the rows above and below
            left = max(u - 2, 0)
            right = min(u + 2, W)
            p0, gu0, gv0, e0, l0 = carried(up1, left, 2.0, 1.0, w_p)
            p1, gu1, gv1, e1, l1 = carried(up1, right, -2.0, 1.0, w_p)
            p2, gu2, gv2, e2, l2 = carried(dn1, left, 2.0, -1.0, w_p)
            p3, gu3, gv3, e3, l3 = carried(dn1, right, -2.0, -1.0, w_p)
            e0, e2 = select(u >= 2, e0, inf), select(u >= 2, e2, inf)
            e1, e3 = select(u + 2 <= W, e1, inf), select(u + 2 <= W, e3, inf)
        else:  # odd column: left and right in the rows two above and below
            p0, gu0, gv0, e0, l0 = carried(up2, u - 1, 1.0, 2.0, w_p)
            p1, gu1, gv1, e1, l1 = carried(up2, u + 1, -1.0, 2.0, w_p)
            p2, gu2, gv2, e2, l2 = carried(dn2, u - 1, 1.0, -2.0, w_p)
            p3, gu3, gv3, e3, l3 = carried(dn2, u + 1, -1.0, -2.0, w_p)
        a, gu, gv, found = interpolated(
            p0, gu0, gv0, e0, -1.0, p1, gu1, gv1, e1, -1.0, p2, gu2, gv2, e2, -1.0, p3, gu3, gv3, e3, -1.0
        )
        if found:
            nx, ny, nz = unit_normal(z_row[u], a, gu, gv, u, o, fx, fy, cx, cy)
            out_row[3 * u] = nx
            out_row[3 * u + 1] = ny
            out_row[3 * u + 2] = nz


@njit(noalias=True, _nrt=False)
def expand_cells(a, g_u, g_v, ok, limit, v, cam, scale, e):
    """The planes of fitted row v's pixels (columns 0, s, 2 s, ... for stride s = ``CELL``: a, g_u, g_v, ok and the
    noise limit, each (n_fit,)) at full width, in single precision: e[:, u] is column s (u // s)'s, for u = 0 ..
    W + s - 1 (none, zeros and a limit of -1, past the last fitted column and where it has no plane): a, g_u, g_v,
    ok, the limit, and the plane's eq. (2) vector
    (f_x g_u, f_y g_v, a - g_u (x - c_x) - g_v (v - c_y)), the same at every pixel of the plane, made in double
    precision (its last component is a difference of nearly equal terms at grazing angles). Inverse depth and all
    of these in units of 1 / ``scale`` (the limit, a square, of 1 / ``scale``^2): ``scale`` is the power of two
    of the frame's nearest depth (:func:`cell_scale`), so that single precision holds them at any unit of depth."""
    fx, fy, cx, cy = cam
    n_fit = a.shape[0]
    for u in range(e.shape[1]):
        i = u // CELL
        j = min(i, n_fit - 1)
        inside = (i < n_fit) & (ok[j] > 0.0)  # zeros where it has no plane (its arrays hold anything there)
        e[0, u] = select(inside, a[j] * scale, 0.0)
        e[1, u] = select(inside, g_u[j] * scale, 0.0)
        e[2, u] = select(inside, g_v[j] * scale, 0.0)
        e[3, u] = select(inside, ok[j], 0.0)
        e[4, u] = select(inside, limit[j] * (scale * scale), -1.0)
        e[5, u] = select(inside, fx * g_u[j] * scale, 0.0)
        e[6, u] = select(inside, fy * g_v[j] * scale, 0.0)
        e[7, u] = select(inside, (a[j] - g_u[j] * (CELL * j - cx) - g_v[j] * (v - cy)) * scale, 0.0)


@pixel
def cell_scale(z0):
    """The power of two 2^e with z0 = m 2^e, 0.5 <= m < 1 (1 where z0 is not positive): :func:`expand_cells` holds
    inverse depth in units of 1 / that, a number of order 1 at the frame's nearest depth ``z0``."""
    if not z0 > 0.0:
        return 1.0
    return math.ldexp(1.0, math.frexp(z0)[1])


#: Rows of :func:`expand_cells`.
CELL_ROWS = 8


@pixel
def _corner(rows, k, du, dv, w_p):
    """The plane of the fitted pixel held at ``k`` in ``rows`` (:func:`expand_cells`) carried to a pixel ``du``
    columns and ``dv`` rows from it, in single precision: (w there, squared error to the pixel's own w_p: inf where
    that fitted pixel has no plane, its noise limit: -1 there, its eq. (2) vector)."""
    has = rows[3, k] > 0
    p = rows[0, k] + rows[1, k] * du + rows[2, k] * dv
    inf = np.float32(np.inf)
    return (
        p,
        select(has, (p - w_p) * (p - w_p), inf),
        select(has, rows[4, k], np.float32(-1.0)),
        rows[5, k],
        rows[6, k],
        rows[7, k],
    )


@pixel
def _closer(e, p, nx, ny, nz, best, p_c, x_c, y_c, z_c):
    """The closest plane so far (:func:`interpolated`'s rule): the candidate replaces it where it is closer by more
    than TIE of the squared error."""
    c = e < best * np.float32(1.0 - TIE)
    return select(c, e, best), select(c, p, p_c), select(c, nx, x_c), select(c, ny, y_c), select(c, nz, z_c)


@njit(noalias=True, _nrt=False)
def cell_row(z_row, valid_row, o, top, bottom, scale, fill, got, out_row):
    """Eq. (2) for every pixel of row ``o`` with ``stride`` s = ``CELL``, from the planes of the fitted rows at the
    top and the bottom of its cell (:func:`expand_cells`, or a row without planes): the fitted rows o - o % s and
    o - o % s + s, and the fitted columns u - u % s and u - u % s + s.

    The plane at a pixel is the mean of those of the four corners (each carried to the pixel) that predict its own
    w within their noise limit, weighted bilinearly by the pixel's place in the cell (a corner of weight 0 is not
    read: a pixel on a fitted row or column reads the two on its line, a fitted pixel its own); where none does, the
    one of weight above 0 that predicts it closest; where none of those has a plane, the closest of the four; where
    none has, ``fill``. Eq. (2) is linear in the plane, so the normal is along the weighted sum of the planes' eq.
    (2) vectors (:func:`expand_cells`), with the pixel's own w where the plane passes behind the camera there.

    Single precision (8 lanes where double has 4), on planes and a w made in double precision: the squared errors
    against limits of at least (kappa rho_floor / f)^2 w^2 lose nothing that matters. Each pixel reads columns u and
    u + s of the two rows: contiguous memory, branch-free (it vectorises); the few that need the closest of the
    four, after it (``got``: scratch (W,)). Inverse depth in units of 1 / ``scale``, as :func:`expand_cells` holds
    it."""
    W = z_row.shape[0]
    f32 = np.float32
    inv_scale = 1.0 / scale
    one = f32(1.0)
    s = f32(CELL)
    inv_s = f32(1.0 / CELL)
    dv = f32(o % CELL)
    f_v = dv * inv_s
    inf = f32(np.inf)
    zero = f32(0.0)
    for u in range(W):
        w_p = one / f32(z_row[u] * inv_scale)
        du = f32(u & (CELL - 1))  # u % CELL, which vectorises (a stride known when compiling)
        f_u = du * inv_s
        p0, e0, l0, x0, y0, z0 = _corner(top, u, du, dv, w_p)
        p1, e1, l1, x1, y1, z1 = _corner(top, u + CELL, du - s, dv, w_p)
        p2, e2, l2, x2, y2, z2 = _corner(bottom, u, du, dv - s, w_p)
        p3, e3, l3, x3, y3, z3 = _corner(bottom, u + CELL, du - s, dv - s, w_p)
        w0 = (one - f_u) * (one - f_v)
        w1 = f_u * (one - f_v)
        w2 = (one - f_u) * f_v
        w3 = f_u * f_v
        k0 = select((w0 > zero) & (e0 <= l0), w0, zero)
        k1 = select((w1 > zero) & (e1 <= l1), w1, zero)
        k2 = select((w2 > zero) & (e2 <= l2), w2, zero)
        k3 = select((w3 > zero) & (e3 <= l3), w3, zero)
        total = k0 + k1 + k2 + k3
        # the closest of weight above 0 (inf: none of them has a plane)
        best, p_c, x_c, y_c, z_c = select(w0 > zero, e0, inf), p0, x0, y0, z0
        best, p_c, x_c, y_c, z_c = _closer(select(w1 > zero, e1, inf), p1, x1, y1, z1, best, p_c, x_c, y_c, z_c)
        best, p_c, x_c, y_c, z_c = _closer(select(w2 > zero, e2, inf), p2, x2, y2, z2, best, p_c, x_c, y_c, z_c)
        best, p_c, x_c, y_c, z_c = _closer(select(w3 > zero, e3, inf), p3, x3, y3, z3, best, p_c, x_c, y_c, z_c)
        mean = total > zero
        a = select(mean, k0 * p0 + k1 * p1 + k2 * p2 + k3 * p3, p_c)
        nx = select(mean, k0 * x0 + k1 * x1 + k2 * x2 + k3 * x3, x_c)
        ny = select(mean, k0 * y0 + k1 * y1 + k2 * y2 + k3 * y3, y_c)
        nz = select(mean, k0 * z0 + k1 * z1 + k2 * z2 + k3 * z3, z_c)
        # a plane that passes behind the camera at the pixel (w there a <= 0): the pixel's own w instead
        nz = nz + select(a > zero, zero, w_p * select(mean, total, one) - a)
        inv_norm = -one / math.sqrt(nx * nx + ny * ny + nz * nz)
        ok = valid_row[u] & (best < inf)
        got[u] = ok
        out_row[3 * u] = select(ok, nx * inv_norm, fill)
        out_row[3 * u + 1] = select(ok, ny * inv_norm, fill)
        out_row[3 * u + 2] = select(ok, nz * inv_norm, fill)
    for u in range(W):  # the few whose corners of weight above 0 have no plane: the closest of the four
        if got[u] or not valid_row[u]:
            continue
        w_p = one / f32(z_row[u] * inv_scale)
        du = f32(u & (CELL - 1))
        p0, e0, _, x0, y0, z0 = _corner(top, u, du, dv, w_p)
        p1, e1, _, x1, y1, z1 = _corner(top, u + CELL, du - s, dv, w_p)
        p2, e2, _, x2, y2, z2 = _corner(bottom, u, du, dv - s, w_p)
        p3, e3, _, x3, y3, z3 = _corner(bottom, u + CELL, du - s, dv - s, w_p)
        best, a, nx, ny, nz = e0, p0, x0, y0, z0
        best, a, nx, ny, nz = _closer(e1, p1, x1, y1, z1, best, a, nx, ny, nz)
        best, a, nx, ny, nz = _closer(e2, p2, x2, y2, z2, best, a, nx, ny, nz)
        best, a, nx, ny, nz = _closer(e3, p3, x3, y3, z3, best, a, nx, ny, nz)
        if best < inf:
            nz = nz + select(a > zero, zero, w_p - a)
            inv_norm = -one / math.sqrt(nx * nx + ny * ny + nz * nz)
            out_row[3 * u] = nx * inv_norm
            out_row[3 * u + 1] = ny * inv_norm
            out_row[3 * u + 2] = nz * inv_norm


@pixel
def _fitted_row(fitted, none, v, stride, first, last):
    """The planes of fitted row v in the ring ``fitted``, or ``none`` where v is not a fitted row there."""
    return fitted[(v // stride) % 3] if v % stride == 0 and first <= v <= last else none


@pixel
def holds_normal(n0, n1, n2, fill):
    """Whether (n0, n1, n2) is a normal: finite, and not ``fill`` in all three components (where the uncertainty
    writes NaN). Branch-free."""
    finite = (n0 - n0 == 0.0) & (n1 - n1 == 0.0) & (n2 - n2 == 0.0)
    return finite & ~((n0 == fill) & (n1 == fill) & (n2 == fill))


@njit(noalias=True, _nrt=False)
def mark_row(valid_row, out_row, fill, has_row):
    """``has_row[u]``: whether pixel u is valid and holds a normal in ``out_row`` (3 W) (:func:`holds_normal`)."""
    for u in range(has_row.shape[0]):
        has_row[u] = valid_row[u] & holds_normal(out_row[3 * u], out_row[3 * u + 1], out_row[3 * u + 2], fill)


@njit(noalias=True, _nrt=False)
def emit_row(z, valid, o, stride, fitted, first, last, none, cam, fill, got, out_flat, has):
    """The normals of row ``o`` from the planes of the fitted rows ``first`` .. ``last`` held in ``fitted``
    (rings of three: fitted row v at (v // stride) % 3; ``none`` for a row outside them; the rows of
    :func:`expand_row`, those of :func:`expand_cells`, which stride ``CELL`` takes, and the latter's scale, and
    ``none`` the first two's rows without planes); ``cam`` is
    (fx, fy, cx, cy); ``got`` is scratch (W,). Where ``has`` has rows (H, W; else (0, 0)), which pixels got a
    normal (:func:`mark_row`), while the row is in cache."""
    _emit(z, valid, o, stride, fitted, first, last, none, cam, fill, got, out_flat)
    if has.shape[0] > 0:
        mark_row(valid[o], out_flat[o], fill, has[o])


@njit(noalias=True, _nrt=False)
def _emit(z, valid, o, stride, fitted, first, last, none, cam, fill, got, out_flat):
    """:func:`emit_row`'s normals."""
    fitted, cells, scale = fitted
    none, no_cell = none
    if stride == 1:
        rows = fitted[o % 3]
        fx, fy, cx, cy = cam
        normal_row(z[o], valid[o], o, rows[1], rows[2], rows[0], rows[3], fx, fy, cx, cy, fill, out_flat[o])
        return
    if stride > 2:
        t = o - o % stride
        top = _fitted_row(cells, no_cell, t, stride, first, last)
        bottom = _fitted_row(cells, no_cell, t + stride, stride, first, last)
        cell_row(z[o], valid[o], o, top, bottom, scale, fill, got, out_flat[o])
        return
    assembled_row(
        z[o],
        valid[o],
        o,
        _fitted_row(fitted, none, o - 2, stride, first, last),
        _fitted_row(fitted, none, o - 1, stride, first, last),
        _fitted_row(fitted, none, o, stride, first, last),
        _fitted_row(fitted, none, o + 1, stride, first, last),
        _fitted_row(fitted, none, o + 2, stride, first, last),
        cam,
        fill,
        got,
        out_flat[o],
    )


@njit(noalias=True, _nrt=False)
def row_done(v, valid_row, a, g_u, g_v, dof, limit, ok_row, band):
    """Fitted row v's planes (a, g_u, g_v where valid_row and dof > 0) into the ring ``fitted``, then the normals
    of the band's rows (``v0`` .. ``v1`` - 1) whose planes are all known now: row v (stride 1), the two
    before it (stride 2), or the rows of the cell above it (stride s of 3 or more: rows v - s .. v - 1;
    :func:`emit_row`). ``band``: what stays the same from row to row, (z, valid, v0, v1,
    stride, v_first, fitted, none, cam, fill, got, out_flat, has) as in :func:`_adaptive_fit_kernel`."""
    z, valid, v0, v1, stride, v_first, fitted, none, cam, fill, got, out_flat, has = band
    W = z.shape[1]
    reach = stride - 1
    rows = fitted[0][(v // stride) % 3]
    for i in range(ok_row.shape[0]):
        ok_row[i] = select(valid_row[i] & (dof[i] > 0.0), 1.0, 0.0)
    if stride == 1:
        for u in range(W):
            rows[0, u] = a[u]
            rows[1, u] = g_u[u]
            rows[2, u] = g_v[u]
            rows[3, u] = ok_row[u]
    elif stride == 2:
        expand_row(a, g_u, g_v, ok_row, limit, rows)
    else:
        expand_cells(a, g_u, g_v, ok_row, limit, v, cam, fitted[2], fitted[1][(v // stride) % 3])
    lo, hi = (v - 2 * reach, v + 1 - reach) if stride <= 2 else (v - stride, v)
    for o in range(lo, hi):
        if v0 <= o < v1:
            emit_row(z, valid, o, stride, fitted, v_first, v, none, cam, fill, got, out_flat, has)


@pixel
def first_fitted_row(v0, stride):
    """The first fitted row that the band starting at row v0 reads: every stride-th row of the frame, with stride 2
    from the one above v0 (its rows take planes from the fitted rows up to two above and below them), with a stride
    of 3 or more the top of row v0's cell."""
    v = max(v0 - (stride - 1), 0) if stride <= 2 else v0
    return v - v % stride


@pixel
def last_fitted_row(v1, H, stride):
    """The last fitted row that the band ending before row v1 of H reads: with stride 1 or 2 the last at most two
    rows below v1 - 1 (stride 2: its rows take planes from the fitted rows up to two above and below them), with a
    stride of 3 or more the bottom of row v1 - 1's cell, or its top where the bottom is past the frame."""
    if stride <= 2:
        v = min(v1 - 1 + 2 * (stride - 1), H - 1)
        return v - v % stride
    top = v1 - 1 - (v1 - 1) % stride
    return top + stride if top + stride <= H - 1 else top
