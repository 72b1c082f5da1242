"""SDA-SNE: spatial discontinuity-aware depth gradients by multi-directional dynamic programming.

Ming, Feng, Fan et al., "SDA-SNE: Spatial Discontinuity-Aware Surface Normal
Estimation via Multi-Directional Dynamic Programming", 3DV 2022. Following
the authors' Python demo (``SDA_demo.py``), which the paper's figures come from:

Initialisation. For each pixel and each axis, three gradients of the depth
Z are candidates: central (Z[u+1] - Z[u-1]) / 2, forward Z[u+1] - Z[u] and
backward Z[u] - Z[u-1]. A candidate's energy is the roughness of the pixels
it uses, the absolute 1D Laplacian A = |-Z[u-1] + 2 Z[u] - Z[u+1]| of p
(central), of p + 1 (forward) or of p - 1 (backward). The cheapest wins (the
central one on ties); its energy E and its kind s (2 central, 1 forward,
0 backward) are kept.

Dynamic programming (iteration i = 1, 2, ..., c = 1 / (i + 1)). Every pixel
chooses, for G_u, among nine candidates built from the previous iteration
(all pixels at once), each with a path energy:

    0  G_u + c ((Z - Z_l) - G_u,l)   A_u,l + B (|s_u| + |s_u,l| + con_l)     extend the backward run
    1  G_u + c ((Z_r - Z) - G_u,r)   A_u,r + B (|s_u - 1| + |s_u,r - 1| + con_r)   extend the forward run
    2  G_u                           E_u                                          keep
    3  G_u,up                        2 (A_v,up + E_u,up)                          copy from above
    4  G_u,down                      2 (A_v,down + E_u,down)                      copy from below
    5  G_u,up - G_v,ul + G_v         A_v,up + E_u,up + A_u,ul + E_v,ul            around the corner
    6..8 the same through ur, dl, dr

(G_v is the same with the roles of the axes exchanged.) con_l is 0 when the
Laplacians at p - 1 and p - 2 have the same non-zero sign (one smooth
curve), 1 when one is 0, 2 when the signs differ; B = 1e10, so candidates
0 and 1 are in practice allowed only along a run of the same kind. The
cheapest candidate wins, the lowest index on ties (so 0 and 1 win ties
against 2 - why planes keep iterating for long), its index becomes the new
state s. The iteration stops when every pixel keeps (index 2) along both
axes, or after ``iterations`` passes (the authors' demo: 3).

The gradients (derivatives of Z in pixels) become normals with CP2TV in the
form the demo uses, which is D2NT's eq. 9:
n = (f_x G_u, f_y G_v, -(Z + (u - c_x) G_u + (v - c_y) G_v)), facing the
camera. The demo also pairs SDA with 3F2N (``base="3f2n"``): the dynamic
programming then runs on the inverse depth 1/Z, and its gradients go into
3F2N's median filter (see :mod:`surfnorm.three_filters`).

Everything is float64, as in the authors' code. Image border: the Laplacian
mirrors the missing neighbour (OpenCV BORDER_REFLECT_101, as the authors'
code); ``border="reflect"`` also keeps their central-difference candidate at
the border, which the mirror makes 0, while the default ``"one-sided"``
leaves it out. Invalid depth is never read: an invalid pixel is treated like
a pixel outside the image (no candidate reads it; a Laplacian mirrors across
it; a central difference needs both neighbours). A pixel that ends without a
gradient along an axis gets the fill value.
"""

from __future__ import annotations

import math

import numpy as np

from ._config import njit, pixel
from .three_filters import camera_facing, fill_pixel, fronto_parallel_fallback, median_nz, write_unit

__all__ = ["sda_gradients", "sda_sne", "SDA_PENALTY", "MAX_ITERATIONS", "BASES"]

#: B, the weight of the state penalty in the energies of candidates 0 and 1 (authors' code: 1e10).
SDA_PENALTY = 1e10

#: Safety cap on the passes of ``iterations=None`` (run until stable). On the
#: 3F2N sample the authors' stop test fires after 6 to 228 passes (planar
#: scenes take longest, because extending a run wins ties against keeping).
MAX_ITERATIONS = 1000

#: How the gradients become normals: CP2TV on depth, or 3F2N's median on inverse depth.
BASES = ("cp2tv", "3f2n")

_NO_STATE = np.int8(-1)  # the state of a pixel without gradient (or outside the image)
_INF = np.inf


@pixel
def state_cost(s, target):
    """|s - target| for a state code, inf for a pixel without one."""
    cost = _INF
    if s >= 0:
        cost = abs(np.float64(s) - target)
    return cost


@pixel
def continuity(lap, v, u, dv, du, inside):
    """con = 1 - sign(L[p + d] L[p + 2d]); a Laplacian outside the image or at invalid depth counts as 1."""
    a = 1.0
    b = 1.0
    if inside[v + dv, u + du]:
        a = lap[v + dv, u + du]
    if inside[v + 2 * dv, u + 2 * du]:
        b = lap[v + 2 * dv, u + 2 * du]
    prod = a * b
    sign = 0.0
    if prod > 0.0:
        sign = 1.0
    elif prod < 0.0:
        sign = -1.0
    return 1.0 - sign


@pixel
def laplacian(s, ok, v, u, dv, du):
    """-S[p - d] + 2 S[p] - S[p + d], a missing neighbour mirrored; (0, False) with neither."""
    has_b = ok[v - dv, u - du]
    has_f = ok[v + dv, u + du]
    lap = 0.0
    if has_b and has_f:
        lap = -s[v - dv, u - du] + 2.0 * s[v, u] - s[v + dv, u + du]
    elif has_b:
        lap = -s[v - dv, u - du] + 2.0 * s[v, u] - s[v - dv, u - du]
    elif has_f:
        lap = -s[v + dv, u + du] + 2.0 * s[v, u] - s[v + dv, u + du]
    return lap, has_b or has_f


@pixel
def initial_gradient(s, ok, rough, v, u, dv, du, at_border_b, at_border_f, reflect):
    """Cheapest of central / forward / backward difference: (gradient, energy, state)."""
    has_b = ok[v - dv, u - du]
    has_f = ok[v + dv, u + du]
    # central, energy A_p; at the image border with reflect, the mirror makes it 0
    g = 0.0
    e = _INF
    state = _NO_STATE
    if has_b and has_f:
        g = 0.5 * s[v + dv, u + du] - 0.5 * s[v - dv, u - du]
        e = rough[v, u]
        state = np.int8(2)
    elif reflect and ((has_f and at_border_b) or (has_b and at_border_f)):
        e = rough[v, u]
        state = np.int8(2)
    if has_f and rough[v + dv, u + du] < e:  # forward, energy A_{p+d}
        g = s[v + dv, u + du] - s[v, u]
        e = rough[v + dv, u + du]
        state = np.int8(1)
    if has_b and rough[v - dv, u - du] < e:  # backward, energy A_{p-d}
        g = s[v, u] - s[v - dv, u - du]
        e = rough[v - dv, u - du]
        state = np.int8(0)
    return g, e, state


@njit
def _sda_init(s, ok, reflect, a_u, a_v, con, g_u, g_v, e_u, e_v, s_u, s_v, p_u, q_v):
    """Roughness A, continuity flags, initial gradients; arrays padded by 2 pixels (ok False there)."""
    Hp, Wp = s.shape
    l_u = np.zeros((Hp, Wp))
    l_v = np.zeros((Hp, Wp))
    inside_u = np.zeros((Hp, Wp), dtype=np.bool_)  # has a Laplacian along u
    inside_v = np.zeros((Hp, Wp), dtype=np.bool_)
    for v in range(2, Hp - 2):
        for u in range(2, Wp - 2):
            if ok[v, u]:
                lap, has = laplacian(s, ok, v, u, 0, 1)
                l_u[v, u] = lap
                inside_u[v, u] = ok[v, u]
                a_u[v, u] = abs(lap) if has else _INF
                lap, has = laplacian(s, ok, v, u, 1, 0)
                l_v[v, u] = lap
                inside_v[v, u] = ok[v, u]
                a_v[v, u] = abs(lap) if has else _INF
    for v in range(2, Hp - 2):
        for u in range(2, Wp - 2):
            if ok[v, u]:
                con[0, v, u] = continuity(l_u, v, u, 0, -1, inside_u)
                con[1, v, u] = continuity(l_u, v, u, 0, 1, inside_u)
                con[2, v, u] = continuity(l_v, v, u, -1, 0, inside_v)
                con[3, v, u] = continuity(l_v, v, u, 1, 0, inside_v)
                g, e, st = initial_gradient(s, ok, a_u, v, u, 0, 1, u == 2, u == Wp - 3, reflect)
                g_u[v, u] = g
                e_u[v, u] = e
                s_u[v, u] = st
                g, e, st = initial_gradient(s, ok, a_v, v, u, 1, 0, v == 2, v == Hp - 3, reflect)
                g_v[v, u] = g
                e_v[v, u] = e
                s_v[v, u] = st
    for v in range(2, Hp - 2):
        for u in range(2, Wp - 2):
            if ok[v, u]:
                p_u[v, u] = a_v[v, u] + e_u[v, u]
                q_v[v, u] = a_u[v, u] + e_v[v, u]


@pixel
def cheapest(e0, e1, e2, e3, e4, e5, e6, e7, e8):
    """(index, energy) of the cheapest of nine candidates, the lowest index on ties; keep (2) if all are inf."""
    k = 0
    best = e0
    if e1 < best:
        k, best = 1, e1
    if e2 < best:
        k, best = 2, e2
    if e3 < best:
        k, best = 3, e3
    if e4 < best:
        k, best = 4, e4
    if e5 < best:
        k, best = 5, e5
    if e6 < best:
        k, best = 6, e6
    if e7 < best:
        k, best = 7, e7
    if e8 < best:
        k, best = 8, e8
    if best == _INF:
        k = 2
    return k, best


@njit
def _sda_step(s, ok, c, a_u, a_v, con, g_u, g_v, e_u, e_v, s_u, s_v, p_u, q_v,
              g_u2, g_v2, e_u2, e_v2, s_u2, s_v2, p_u2, q_v2):
    """One Jacobi pass of the dynamic programming, from the first set of buffers into the second.

    Returns True if some pixel took another candidate than keep (index 2).
    """
    Hp, Wp = s.shape
    B = SDA_PENALTY
    changed = False
    for v in range(2, Hp - 2):
        for u in range(2, Wp - 2):
            if not ok[v, u]:
                continue
            # ---- G_u ----
            p_up = p_u[v - 1, u]
            p_dn = p_u[v + 1, u]
            e0 = a_u[v, u - 1] + B * ((state_cost(s_u[v, u], 0.0) + state_cost(s_u[v, u - 1], 0.0)) + con[0, v, u])
            e1 = a_u[v, u + 1] + B * ((state_cost(s_u[v, u], 1.0) + state_cost(s_u[v, u + 1], 1.0)) + con[1, v, u])
            e3 = 2.0 * p_up
            e4 = 2.0 * p_dn
            e5 = _INF
            e6 = _INF
            e7 = _INF
            e8 = _INF
            if e_v[v, u] < _INF:  # candidates 5-8 use G_v at p
                e5 = (p_up + a_u[v - 1, u - 1]) + e_v[v - 1, u - 1]
                e6 = (p_up + a_u[v - 1, u + 1]) + e_v[v - 1, u + 1]
                e7 = (p_dn + a_u[v + 1, u - 1]) + e_v[v + 1, u - 1]
                e8 = (p_dn + a_u[v + 1, u + 1]) + e_v[v + 1, u + 1]
            k_u, best_u = cheapest(e0, e1, e_u[v, u], e3, e4, e5, e6, e7, e8)
            g = g_u[v, u]
            if k_u == 0:
                g = (g + c * s[v, u]) - c * (s[v, u - 1] + g_u[v, u - 1])
            elif k_u == 1:
                g = (g - c * s[v, u]) + c * (s[v, u + 1] - g_u[v, u + 1])
            elif k_u == 3:
                g = g_u[v - 1, u]
            elif k_u == 4:
                g = g_u[v + 1, u]
            elif k_u == 5:
                g = (g_u[v - 1, u] - g_v[v - 1, u - 1]) + g_v[v, u]
            elif k_u == 6:
                g = (g_u[v - 1, u] + g_v[v - 1, u + 1]) - g_v[v, u]
            elif k_u == 7:
                g = (g_u[v + 1, u] + g_v[v + 1, u - 1]) - g_v[v, u]
            elif k_u == 8:
                g = (g_u[v + 1, u] - g_v[v + 1, u + 1]) + g_v[v, u]
            g_u2[v, u] = g
            e_u2[v, u] = best_u
            s_u2[v, u] = np.int8(k_u) if best_u < _INF else _NO_STATE
            # ---- G_v ----
            q_l = q_v[v, u - 1]
            q_r = q_v[v, u + 1]
            e0 = a_v[v - 1, u] + B * ((state_cost(s_v[v, u], 0.0) + state_cost(s_v[v - 1, u], 0.0)) + con[2, v, u])
            e1 = a_v[v + 1, u] + B * ((state_cost(s_v[v, u], 1.0) + state_cost(s_v[v + 1, u], 1.0)) + con[3, v, u])
            e3 = 2.0 * q_l
            e4 = 2.0 * q_r
            e5 = _INF
            e6 = _INF
            e7 = _INF
            e8 = _INF
            if e_u[v, u] < _INF:  # candidates 5-8 use G_u at p
                e5 = (q_l + a_v[v - 1, u - 1]) + e_u[v - 1, u - 1]
                e6 = (q_l + a_v[v + 1, u - 1]) + e_u[v + 1, u - 1]
                e7 = (q_r + a_v[v - 1, u + 1]) + e_u[v - 1, u + 1]
                e8 = (q_r + a_v[v + 1, u + 1]) + e_u[v + 1, u + 1]
            k_v, best_v = cheapest(e0, e1, e_v[v, u], e3, e4, e5, e6, e7, e8)
            g = g_v[v, u]
            if k_v == 0:
                g = (g + c * s[v, u]) - c * (s[v - 1, u] + g_v[v - 1, u])
            elif k_v == 1:
                g = (g - c * s[v, u]) + c * (s[v + 1, u] - g_v[v + 1, u])
            elif k_v == 3:
                g = g_v[v, u - 1]
            elif k_v == 4:
                g = g_v[v, u + 1]
            elif k_v == 5:
                g = (g_v[v, u - 1] - g_u[v - 1, u - 1]) + g_u[v, u]
            elif k_v == 6:
                g = (g_v[v, u - 1] + g_u[v + 1, u - 1]) - g_u[v, u]
            elif k_v == 7:
                g = (g_v[v, u + 1] + g_u[v - 1, u + 1]) - g_u[v, u]
            elif k_v == 8:
                g = (g_v[v, u + 1] - g_u[v + 1, u + 1]) + g_u[v, u]
            g_v2[v, u] = g
            e_v2[v, u] = best_v
            s_v2[v, u] = np.int8(k_v) if best_v < _INF else _NO_STATE
            p_u2[v, u] = a_v[v, u] + best_u
            q_v2[v, u] = a_u[v, u] + best_v
            if k_u != 2 or k_v != 2:
                changed = True
    return changed


def sda_gradients(signal, valid, *, iterations=3, border="one-sided"):
    """SDA gradients of ``signal`` (H, W) along u and v, and the number of passes that ran.

    Returns ``(g_u, g_v, passes)``: float64 (H, W) arrays, NaN where a pixel
    has no gradient, and how many passes of the dynamic programming were
    applied (the pass whose stop test fired is not counted). ``iterations``
    None runs until stable, at most :data:`MAX_ITERATIONS` passes.
    """
    H, W = signal.shape
    shape = (H + 4, W + 4)  # padded by 2: every neighbour read stays inside, and is "not ok" there
    s = np.zeros(shape)
    s[2:-2, 2:-2] = np.where(valid, signal, 0.0)
    ok = np.zeros(shape, dtype=np.bool_)
    ok[2:-2, 2:-2] = valid
    a_u = np.full(shape, _INF)
    a_v = np.full(shape, _INF)
    con = np.ones((4,) + shape)
    bufs = []
    for _ in range(2):
        bufs.append([np.zeros(shape), np.zeros(shape), np.full(shape, _INF), np.full(shape, _INF),
                     np.full(shape, _NO_STATE, dtype=np.int8), np.full(shape, _NO_STATE, dtype=np.int8),
                     np.full(shape, _INF), np.full(shape, _INF)])
    _sda_init(s, ok, border == "reflect", a_u, a_v, con, *bufs[0])
    for arr, src in zip(bufs[1], bufs[0]):  # pixels never updated (invalid, margin) agree in both sets
        arr[...] = src
    cap = MAX_ITERATIONS if iterations is None else iterations
    passes = 0
    cur = 0
    for i in range(1, cap + 1):
        if not _sda_step(s, ok, 1.0 / (i + 1), a_u, a_v, con, *bufs[cur], *bufs[1 - cur]):
            break
        cur = 1 - cur
        passes = i
    g_u, g_v, e_u, e_v = (b[2:-2, 2:-2] for b in bufs[cur][:4])
    g_u = np.where(e_u < _INF, g_u, np.nan)
    g_v = np.where(e_v < _INF, g_v, np.nan)
    return g_u, g_v, passes


@njit
def _cp2tv_kernel(z, g_u, g_v, f_x, f_y, c_x, c_y, fill, out):
    """CP2TV as in the SDA-SNE demo (D2NT eq. 9): n = (f_x G_u, f_y G_v, -(Z + v_c G_v + u_c G_u))."""
    H, W = z.shape
    for v in range(H):
        v_c = v - c_y
        for u in range(W):
            ok = False
            gu = g_u[v, u]
            gv = g_v[v, u]
            if math.isfinite(gu) and math.isfinite(gv):
                n_z = -((np.float64(z[v, u]) + v_c * gv) + (u - c_x) * gu)
                ok = write_unit(out, v, u, f_x * gu, f_y * gv, n_z, fill)
            if not ok:
                fill_pixel(out, v, u, fill)


@njit
def _tf2n_base_kernel(z, valid, g_u, g_v, f_x, f_y, c_x, c_y, reflect, fill, out):
    """3F2N's median filter on given gradients of inverse depth (the demo's SDA + 3F2N)."""
    H, W = z.shape
    buf = np.empty(8)
    for v in range(H):
        for u in range(W):
            ok = False
            gu = g_u[v, u]
            gv = g_v[v, u]
            if math.isfinite(gu) and math.isfinite(gv):
                n_z, count = median_nz(z, valid, v, u, gu, gv, c_x, c_y, reflect, buf)
                n_x, n_y, n_z = fronto_parallel_fallback(f_x * gu, f_y * gv, n_z, count)
                n_x, n_y, n_z = camera_facing(n_x, n_y, n_z, u - c_x, v - c_y, f_x, f_y)
                ok = write_unit(out, v, u, n_x, n_y, n_z, fill)
            if not ok:
                fill_pixel(out, v, u, fill)


def sda_sne(z, valid, cam, out, *, iterations=3, base="cp2tv", border="one-sided", fill=0.0):
    """SDA-SNE (Ming et al., 3DV 2022): SDA gradients, then CP2TV (or 3F2N's median), into ``out``."""
    f = (float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy))
    z64 = z.astype(np.float64)
    if base == "3f2n":
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = np.where(valid, 1.0 / z64, 0.0)
        g_u, g_v, _ = sda_gradients(inv, valid, iterations=iterations, border=border)
        _tf2n_base_kernel(z, valid, g_u, g_v, *f, border == "reflect", np.float32(fill), out)
    else:
        g_u, g_v, _ = sda_gradients(z64, valid, iterations=iterations, border=border)
        _cp2tv_kernel(z, g_u, g_v, *f, np.float32(fill), out)
    return out
