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
3F2N's median filter (see :mod:`surfnorm.kernels.three_filters`).

Everything is float64, as in the authors' code. Image border: the Laplacian
mirrors the missing neighbour (OpenCV BORDER_REFLECT_101, as the authors'
code); ``border="reflect"`` also keeps their central-difference candidate at
the border, which the mirror makes 0, while the default ``"one-sided"``
leaves it out. Invalid depth is never read: an invalid pixel is treated like
a pixel outside the image (no candidate reads it; a Laplacian mirrors across
it; a central difference needs both neighbours). A pixel that ends without a
gradient along an axis gets the fill value.

Near-ties. Every comparison above is exact in the paper-faithful mode. The
scale-invariant mode passes ``tie_tol`` = :data:`surfnorm.units.TIE_TOLERANCE`:
a Laplacian with |L| <= tie_tol |S_p| counts as 0 (for the continuity signs
and the energies), and a candidate (initial or of the dynamic programming)
beats an earlier one only if cheaper by more than tie_tol |S_p|, so that depth
in another unit (rounded differently in float32) breaks ties the same way;
see :mod:`surfnorm.units` for the choice of the value.
"""

from __future__ import annotations

import threading

import numba
import numba.extending
import numpy as np

from .._bands import whole
from .._choices import SDA_BASES, SDA_MAX_ITERATIONS
from .._config import njit, pixel, select
from .._constants import SDA_PENALTY  # B, the weight of the state penalty (shared with surfnorm.torch)
from ._rows import fill_pixel, store_unit_flat
from ._spare import Spares
from .three_filters import gradient_normal

__all__ = ["sda_gradients", "sda_sne", "SDA_PENALTY", "MAX_ITERATIONS", "BASES"]


#: The iteration cap of ``iterations=None``, and the bases (defined beside the other choices, in _choices.py).
MAX_ITERATIONS, BASES = SDA_MAX_ITERATIONS, SDA_BASES

_NO_STATE = np.int8(-1)  # the state of a pixel without gradient (or outside the image)
_INF = np.inf


_P = 3  # padding of the working arrays: every read of a step stays inside, and the margin is "missing"


@pixel
def state_cost(s, target):
    """|s - target| for a state code, inf for a pixel without one."""
    return select(s >= 0, abs(np.float64(s) - target), _INF)


# Near-ties. In the kernels ``tol`` is a float (the scale-invariant mode) or None (exact comparisons):
# Numba compiles a version of each kernel per type, so the paper-faithful mode runs without the
# tolerance's arithmetic (tol = 0.0 gives the same numbers, in about 1.2x the time per pass).
# Plain Python below (the meaning); the overloads are what the kernels inline.


def minus_tol(x, tol):
    """x - tol; x when tol is None. A later candidate e beats the best so far if e < minus_tol(best, tol)."""
    return x if tol is None else x - tol


def tolerance_at(tol, s_p):
    """The tolerance at a pixel of signal ``s_p``: tol |s_p| (None stays None)."""
    return None if tol is None else tol * abs(s_p)


def snap(lap, tol_p):
    """A Laplacian with |lap| <= tol_p counts as exactly 0 (tol_p None: unchanged)."""
    return lap if tol_p is None or abs(lap) > tol_p else 0.0


def _exact(tol):
    return isinstance(tol, numba.types.NoneType)


@numba.extending.overload(minus_tol, inline="always")
def _minus_tol(x, tol):
    return (lambda x, tol: x) if _exact(tol) else (lambda x, tol: x - tol)


@numba.extending.overload(tolerance_at, inline="always")
def _tolerance_at(tol, s_p):
    return (lambda tol, s_p: None) if _exact(tol) else (lambda tol, s_p: tol * abs(s_p))


@numba.extending.overload(snap, inline="always")
def _snap(lap, tol_p):
    return (lambda lap, tol_p: lap) if _exact(tol_p) else (lambda lap, tol_p: select(abs(lap) <= tol_p, 0.0, lap))


# Helpers below take scalars only: a Numba helper that takes arrays and branches keeps reference
# counting of those arrays per call (measured 7x slower); the kernels read the arrays themselves.


@pixel
def laplacian(s_b, s_p, s_f, has_b, has_f):
    """1D Laplacian -S[p - d] + 2 S[p] - S[p + d], a missing neighbour mirrored (BORDER_REFLECT_101);
    0 with neither. Returns (value, has a neighbour)."""
    s_b = s_b if has_b else s_f
    s_f = s_f if has_f else s_b
    lap = -s_b + 2.0 * s_p - s_f
    return lap if (has_b or has_f) else 0.0, has_b or has_f


@pixel
def continuity(lap_1, lap_2):
    """con = 1 - sign(L[p + d] L[p + 2d]): 0 for one smooth curve, 1 if either is 0, 2 if the signs differ."""
    prod = lap_1 * lap_2
    return 1 - (np.int64(prod > 0.0) - np.int64(prod < 0.0))


@pixel
def initial_gradient(s_b, s_p, s_f, has_b, has_f, a_b, a_p, a_f, mirrored, reflect, tol):
    """Cheapest of central / forward / backward difference: (gradient, energy, state 2 / 1 / 0).

    Central (S_f - S_b) / 2 with energy A_p; with ``reflect`` a neighbour mirrored at the image border
    (``mirrored``: the missing neighbour lies outside the image, the other is valid) makes it 0, as in the authors' code. Forward S_f - S_p with energy A_f, backward
    S_p - S_b with A_b. The first wins ties, and near-ties: a later candidate wins only if cheaper by more
    than ``tol`` (None in the paper-faithful mode: exact; see :data:`surfnorm.units.TIE_TOLERANCE`). (Selects, no
    branches: the loop of :func:`_sda_init` vectorises.)
    """
    central = has_b & has_f
    has_central = central | (reflect & mirrored)
    g = select(central, 0.5 * s_f - 0.5 * s_b, 0.0)
    e = select(has_central, a_p, _INF)
    state = select(has_central, np.int8(2), _NO_STATE)
    forward = has_f & (a_f < minus_tol(e, tol))
    g, e, state = select(forward, s_f - s_p, g), select(forward, a_f, e), select(forward, np.int8(1), state)
    backward = has_b & (a_b < minus_tol(e, tol))
    g, e, state = select(backward, s_p - s_b, g), select(backward, a_b, e), select(backward, np.int8(0), state)
    return g, e, state


@njit
def _sda_laplacians(s, ok, tol, l_u, l_v, a_u, a_v, r0, r1):
    """Signed Laplacians L (1 where missing, as the authors' padding) and roughness A = |L| (inf where missing).

    Padded rows r0 .. r1 - 1 (within 1 .. Hp - 2). |L| <= ``tol`` |S_p| counts as exactly 0 (``tol`` None:
    only an exact 0; see :data:`surfnorm.units.TIE_TOLERANCE`)."""
    Hp, Wp = s.shape
    for v in range(r0, r1):
        for u in range(1, Wp - 1):
            if ok[v, u]:
                tol_p = tolerance_at(tol, s[v, u])
                lap, has = laplacian(s[v, u - 1], s[v, u], s[v, u + 1], ok[v, u - 1], ok[v, u + 1])
                lap = snap(lap, tol_p)
                l_u[v, u] = lap
                a_u[v, u] = abs(lap) if has else _INF
                lap, has = laplacian(s[v - 1, u], s[v, u], s[v + 1, u], ok[v - 1, u], ok[v + 1, u])
                lap = snap(lap, tol_p)
                l_v[v, u] = lap
                a_v[v, u] = abs(lap) if has else _INF
            else:
                l_u[v, u] = 1.0
                l_v[v, u] = 1.0
                a_u[v, u] = _INF
                a_v[v, u] = _INF


@njit(noalias=True)
def _sda_init(s, ok, reflect, tol, l_u, l_v, a_u, a_v, con, g_u, g_v, e_u, e_v, s_u, s_v, v0, v1):
    """Continuity flags (packed 2 bits each: l, r, u, d) and initial gradients, at the inner pixels of image rows v0 .. v1 - 1.

    Branch-free over i = u - _P (see :func:`_sda_step`); an invalid pixel gets no flags and no gradient.
    Halo: the Laplacians of 2 rows above and below.
    """
    Hp, Wp = s.shape
    n = Wp - 2 * _P
    for v in range(v0 + _P, v1 + _P):
        # Three loops per row, each of which LLVM vectorises (fused, it did not).
        for i in range(n):
            u = i + _P
            flags = np.uint8(
                continuity(l_u[v, u - 1], l_u[v, u - 2])
                | (continuity(l_u[v, u + 1], l_u[v, u + 2]) << 2)
                | (continuity(l_v[v - 1, u], l_v[v - 2, u]) << 4)
                | (continuity(l_v[v + 1, u], l_v[v + 2, u]) << 6)
            )
            con[v, u] = select(ok[v, u], flags, np.uint8(0))
        for i in range(n):
            u = i + _P
            g, e, st = initial_gradient(
                s[v, u - 1],
                s[v, u],
                s[v, u + 1],
                ok[v, u - 1],
                ok[v, u + 1],
                a_u[v, u - 1],
                a_u[v, u],
                a_u[v, u + 1],
                ((u == _P) & ok[v, u + 1]) | ((u == Wp - _P - 1) & ok[v, u - 1]),
                reflect,
                tolerance_at(tol, s[v, u]),
            )
            g_u[v, u] = select(ok[v, u], g, 0.0)
            e_u[v, u] = select(ok[v, u], e, _INF)
            s_u[v, u] = select(ok[v, u], st, _NO_STATE)
        for i in range(n):
            u = i + _P
            g, e, st = initial_gradient(
                s[v - 1, u],
                s[v, u],
                s[v + 1, u],
                ok[v - 1, u],
                ok[v + 1, u],
                a_v[v - 1, u],
                a_v[v, u],
                a_v[v + 1, u],
                ((v == _P) & ok[v + 1, u]) | ((v == Hp - _P - 1) & ok[v - 1, u]),
                reflect,
                tolerance_at(tol, s[v, u]),
            )
            g_v[v, u] = select(ok[v, u], g, 0.0)
            e_v[v, u] = select(ok[v, u], e, _INF)
            s_v[v, u] = select(ok[v, u], st, _NO_STATE)


@pixel
def challenge(j, e_j, k, best, bar, tol):
    """Candidate j (energy e_j) against the best so far, (k, best) with bar = best - tol: it wins if e_j < bar.

    Returns the new (k, best, bar). Carrying bar, rather than forming best - tol at each comparison, keeps
    the subtractions off the chain of comparisons (measured: passes about 4 % faster with a tolerance).
    """
    wins = e_j < bar
    return select(wins, j, k), select(wins, e_j, best), select(wins, minus_tol(e_j, tol), bar)


@pixel
def cheapest(e0, e1, e2, e3, e4, e5, e6, e7, e8, tol):
    """(index, energy) of the cheapest of nine candidates, the lowest index on ties; keep (2) if all are inf.

    A later candidate wins only if cheaper by more than ``tol`` (None: any amount; see :data:`surfnorm.units.TIE_TOLERANCE`).
    """
    k, best, bar = 0, e0, minus_tol(e0, tol)
    k, best, bar = challenge(1, e1, k, best, bar, tol)
    k, best, bar = challenge(2, e2, k, best, bar, tol)
    k, best, bar = challenge(3, e3, k, best, bar, tol)
    k, best, bar = challenge(4, e4, k, best, bar, tol)
    k, best, bar = challenge(5, e5, k, best, bar, tol)
    k, best, bar = challenge(6, e6, k, best, bar, tol)
    k, best, bar = challenge(7, e7, k, best, bar, tol)
    k, best, bar = challenge(8, e8, k, best, bar, tol)
    return select(best == _INF, 2, k), best


@pixel
def pick(k, c0, c1, c2, c3, c4, c5, c6, c7, c8):
    """Candidate number k (a chain of selects, no branches)."""
    g = c2
    g = select(k == 0, c0, g)
    g = select(k == 1, c1, g)
    g = select(k == 3, c3, g)
    g = select(k == 4, c4, g)
    g = select(k == 5, c5, g)
    g = select(k == 6, c6, g)
    g = select(k == 7, c7, g)
    g = select(k == 8, c8, g)
    return g


@njit(noalias=True)
def _sda_step(s, ok, c, tol, a_u, a_v, con, g_u, g_v, e_u, e_v, s_u, s_v, g_u2, g_v2, e_u2, e_v2, s_u2, s_v2, v0, v1):
    """One Jacobi pass of the dynamic programming, from the first set of buffers into the second.

    Every inner pixel of image rows v0 .. v1 - 1 of the second set is written (halo: the first set's rows
    v0 - 1 .. v1; a pass reads only the previous pass, so row bands of one pass run side by side). Returns True if some pixel
    took another candidate than keep (index 2). Written without branches (all
    nine candidates are formed, one is selected with :func:`select`) so that
    LLVM vectorises it; every array read here is surfnorm's own (depth is zeroed
    where invalid). The two sets must be distinct arrays (``noalias``), and the
    loop runs over i = u - _P from 0, so that every column index is i plus a
    constant (LLVM then sees consecutive addresses, not gathers).
    """
    Hp, Wp = s.shape
    B = SDA_PENALTY
    moved = 0
    for v in range(v0 + _P, v1 + _P):
        for i in range(Wp - 2 * _P):
            u = i + _P
            valid_p = ok[v, u]
            flags = con[v, u]
            z_p = s[v, u]
            tol_p = tolerance_at(tol, z_p)  # near-ties at p (None in the paper-faithful mode)
            gu_p = g_u[v, u]
            gv_p = g_v[v, u]
            # ---- G_u: energies (see the module docstring) ----
            p_up = a_v[v - 1, u] + e_u[v - 1, u]
            p_dn = a_v[v + 1, u] + e_u[v + 1, u]
            has_gv = e_v[v, u] < _INF  # candidates 5-8 use G_v at p
            e0 = a_u[v, u - 1] + B * ((state_cost(s_u[v, u], 0.0) + state_cost(s_u[v, u - 1], 0.0)) + (flags & 3))
            e1 = a_u[v, u + 1] + B * (
                (state_cost(s_u[v, u], 1.0) + state_cost(s_u[v, u + 1], 1.0)) + ((flags >> 2) & 3)
            )
            e5 = (p_up + a_u[v - 1, u - 1]) + e_v[v - 1, u - 1]
            e6 = (p_up + a_u[v - 1, u + 1]) + e_v[v - 1, u + 1]
            e7 = (p_dn + a_u[v + 1, u - 1]) + e_v[v + 1, u - 1]
            e8 = (p_dn + a_u[v + 1, u + 1]) + e_v[v + 1, u + 1]
            k_u, best_u = cheapest(
                e0,
                e1,
                e_u[v, u],
                2.0 * p_up,
                2.0 * p_dn,
                select(has_gv, e5, _INF),
                select(has_gv, e6, _INF),
                select(has_gv, e7, _INF),
                select(has_gv, e8, _INF),
                tol_p,
            )
            new_gu = pick(
                k_u,
                (gu_p + c * z_p) - c * (s[v, u - 1] + g_u[v, u - 1]),
                (gu_p - c * z_p) + c * (s[v, u + 1] - g_u[v, u + 1]),
                gu_p,
                g_u[v - 1, u],
                g_u[v + 1, u],
                (g_u[v - 1, u] - g_v[v - 1, u - 1]) + gv_p,
                (g_u[v - 1, u] + g_v[v - 1, u + 1]) - gv_p,
                (g_u[v + 1, u] + g_v[v + 1, u - 1]) - gv_p,
                (g_u[v + 1, u] - g_v[v + 1, u + 1]) + gv_p,
            )
            # ---- G_v ----
            q_l = a_u[v, u - 1] + e_v[v, u - 1]
            q_r = a_u[v, u + 1] + e_v[v, u + 1]
            has_gu = e_u[v, u] < _INF  # candidates 5-8 use G_u at p
            e0 = a_v[v - 1, u] + B * (
                (state_cost(s_v[v, u], 0.0) + state_cost(s_v[v - 1, u], 0.0)) + ((flags >> 4) & 3)
            )
            e1 = a_v[v + 1, u] + B * (
                (state_cost(s_v[v, u], 1.0) + state_cost(s_v[v + 1, u], 1.0)) + ((flags >> 6) & 3)
            )
            e5 = (q_l + a_v[v - 1, u - 1]) + e_u[v - 1, u - 1]
            e6 = (q_l + a_v[v + 1, u - 1]) + e_u[v + 1, u - 1]
            e7 = (q_r + a_v[v - 1, u + 1]) + e_u[v - 1, u + 1]
            e8 = (q_r + a_v[v + 1, u + 1]) + e_u[v + 1, u + 1]
            k_v, best_v = cheapest(
                e0,
                e1,
                e_v[v, u],
                2.0 * q_l,
                2.0 * q_r,
                select(has_gu, e5, _INF),
                select(has_gu, e6, _INF),
                select(has_gu, e7, _INF),
                select(has_gu, e8, _INF),
                tol_p,
            )
            new_gv = pick(
                k_v,
                (gv_p + c * z_p) - c * (s[v - 1, u] + g_v[v - 1, u]),
                (gv_p - c * z_p) + c * (s[v + 1, u] - g_v[v + 1, u]),
                gv_p,
                g_v[v, u - 1],
                g_v[v, u + 1],
                (g_v[v, u - 1] - g_u[v - 1, u - 1]) + gu_p,
                (g_v[v, u - 1] + g_u[v + 1, u - 1]) - gu_p,
                (g_v[v, u + 1] + g_u[v - 1, u + 1]) - gu_p,
                (g_v[v, u + 1] - g_u[v + 1, u + 1]) + gu_p,
            )
            # ---- write; an invalid pixel stays missing ----
            g_u2[v, u] = select(valid_p, new_gu, 0.0)
            e_u2[v, u] = select(valid_p, best_u, _INF)
            s_u2[v, u] = select(valid_p & (best_u < _INF), np.int8(k_u), _NO_STATE)
            g_v2[v, u] = select(valid_p, new_gv, 0.0)
            e_v2[v, u] = select(valid_p, best_v, _INF)
            s_v2[v, u] = select(valid_p & (best_v < _INF), np.int8(k_v), _NO_STATE)
            moved += np.int64(valid_p & ((k_u != 2) | (k_v != 2)))
    return moved > 0


def _kernel_tol(tie_tol):
    """The kernels' ``tol``: None for exact comparisons (tie_tol 0), which Numba compiles without the tolerance."""
    return float(tie_tol) if tie_tol else None


#: Most bytes of working arrays kept for the next frame: 1280x960 takes 135 MB.
KEEP_BYTES = 256 << 20
#: A call's working arrays, kept for the next frame of the same size (the latest ones, at most
#: :data:`KEEP_BYTES` in all). Allocated new for every frame, their pages were mapped in afresh each time, and on
#: two threads the allocator returned them to the system after almost every frame (7100 page faults per 1280x960
#: frame instead of 500): 60 of the 147 ms of CPU time that one frame cost on two threads. Reused, a frame on two
#: threads costs the CPU time of one thread, and no pages are faulted in. :func:`release` lets them go.
_working = Spares(KEEP_BYTES)


def release() -> None:
    """Free the working arrays kept for the next frame."""
    _working.release()


@njit(noalias=True)
def _gradients_to_normals_kernel(s, g_u, g_v, e_u, e_v, f_x, f_y, c_x, c_y, fill, out, v0, v1):
    """The SDA-SNE demo's last step, which it calls CP2TV but computes as D2NT's eq. 9 (camera-facing sign):
    n = (f_x G_u, f_y G_v, -(Z + v_c G_v + u_c G_u)). (:func:`surfnorm.kernels.translate.cp2tv`, the method
    ``cp2tv``, is the cross product of tangent vectors.)

    ``s`` (depth, zero where invalid), gradients and energies are padded by _P; a gradient with
    infinite energy does not exist. Branch-free, into a flat view of each row of ``out`` (C-contiguous),
    so that the loop vectorises (see :func:`surfnorm.kernels._rows.store_unit_flat`). Rows v0 .. v1 - 1.
    """
    W = out.shape[1]
    for v in range(v0, v1):
        v_c = v - c_y
        out_flat = out[v].reshape(3 * W)
        for u in range(W):
            gu = g_u[v + _P, u + _P]
            gv = g_v[v + _P, u + _P]
            n_x = f_x * gu
            n_y = f_y * gv
            n_z = -((s[v + _P, u + _P] + v_c * gv) + (u - c_x) * gu)
            store_unit_flat(
                out_flat, u, n_x, n_y, n_z, (e_u[v + _P, u + _P] < _INF) & (e_v[v + _P, u + _P] < _INF), fill
            )


@njit
def _tf2n_base_kernel(z, valid, g_u, g_v, e_u, e_v, f_x, f_y, c_x, c_y, reflect, fill, out, v0, v1):
    """3F2N's median filter on SDA gradients of inverse depth (the demo's SDA + 3F2N); padded as above. Rows v0 .. v1 - 1."""
    H, W = z.shape
    buf = np.empty(8)
    for v in range(v0, v1):
        for u in range(W):
            ok = False
            if e_u[v + _P, u + _P] < _INF and e_v[v + _P, u + _P] < _INF:
                gu = g_u[v + _P, u + _P]
                gv = g_v[v + _P, u + _P]
                ok = gradient_normal(z, valid, v, u, gu, gv, f_x, f_y, c_x, c_y, reflect, True, buf, fill, out)
            if not ok:
                fill_pixel(out, v, u, fill)


# ---- the stages of one frame, fused ----------------------------------------------------------------------------
#
# One frame is a sequence of stages, each a sweep over the rows: load (the signal and validity into the padded
# arrays, and every array's margin), the Laplacians, the initial gradients, the passes of the dynamic programming,
# the normals. Stage after stage over the whole frame, the working arrays (135 MB at 1280x960) stream through
# memory once per stage: on two cores the memory bus, not the cores, was then the limit (each stage 1.3-1.5x faster
# on two threads than on one). A stage reads only the rows next to the one it writes (its halo: 1 row for the
# Laplacians and a pass, 2 for the initial gradients, 0 for load and normals), so :func:`_sda_sweep` runs them as a
# wavefront instead: stage k computes row t - C_k at step t (C_k: the halos of the stages before it, added up),
# while the rows that it reads are still in the cache. A pass writes into the set of arrays that the pass before
# the previous one wrote; at step t it overwrites a row that the stage between read for the last time at that
# same step, earlier (stages run in their order within a step), so the wavefront computes what stage after stage
# computes, bit for bit.
#
# Row bands (threads): a band computes, per stage, the rows that need no row of another band (a trapezoid,
# C_k rows less at each inner edge); once every band is done, the band that finished last computes the rows
# around each inner edge (C_k rows either side), in the same wavefront order. The rows that they read are either theirs or the trapezoids' rows, which
# the trapezoids' later passes have not overwritten (a pass overwrites rows C_k + 1 and further from the edge).
# Bands shorter than 2 C + 2 rows (tests split frames into one-row bands) run the stages one by one instead.

_LOAD, _LAPLACIANS, _INIT, _PASS, _NORMALS = 0, 1, 2, 3, 4
_HALO = (0, 1, 2, 1, 0)  # rows of the stage before that a stage reads above and below the row it writes


@njit
def _margin(a, v, value):
    """The margin of padded row ``v`` of ``a``: the whole row in the first and last _P rows, else the first and
    last _P columns."""
    Hp, Wp = a.shape
    if v < _P or v >= Hp - _P:
        a[v, :] = value
    else:
        for u in range(_P):
            a[v, u] = value
            a[v, Wp - 1 - u] = value


@njit
def _margins(v, s, ok, l_u, l_v, a_u, a_v, con, x, y):
    """The margin of every working array at padded row ``v``: missing (see :func:`_sda_laplacians`)."""
    _margin(s, v, 0.0)
    _margin(ok, v, False)
    _margin(l_u, v, 1.0)
    _margin(l_v, v, 1.0)
    _margin(a_u, v, _INF)
    _margin(a_v, v, _INF)
    _margin(con, v, np.uint8(0))
    for g in (x, y):
        _margin(g[0], v, 0.0)
        _margin(g[1], v, 0.0)
        _margin(g[2], v, _INF)
        _margin(g[3], v, _INF)
        _margin(g[4], v, _NO_STATE)
        _margin(g[5], v, _NO_STATE)


@njit
def _load_row(z, valid, inverse, s, ok, r):
    """Image row r of the signal (depth, or its inverse), 0 where invalid (user depth is never read there)."""
    v = r + _P
    for u in range(z.shape[1]):
        x = np.float64(z[r, u])
        if inverse:
            x = 1.0 / x
        s[v, u + _P] = select(valid[r, u], x, 0.0)
        ok[v, u + _P] = valid[r, u]


@njit
def _sda_sweep(
    z, valid, inverse, reflect, tol, s, ok, l_u, l_v, a_u, a_v, con, x, y,
    first_pass, n_passes, base, normals, f_x, f_y, c_x, c_y, fill, out, j0, j1, lo, hi, edge, moved,
):  # fmt: skip
    """Stages j0 .. j1 - 1 of one frame (see above) as a wavefront over image rows. The stages: 0 load, 1 the
    Laplacians, 2 the initial gradients (into set ``x``), then passes ``first_pass`` .. ``first_pass + n_passes - 1``
    (pass i reads set x for odd i and writes set y, the other way round for even i; a set is the tuple g_u, g_v, e_u,
    e_v, s_u, s_v), then, where ``base``, the normals from the last pass's set (``normals``: 1 CP2TV, 2 3F2N's
    median, 0 none). An integer, not the row function itself: a function argument's type is that function object,
    which differs in every process, so the compiled sweep never loaded from Numba's disk cache (it compiled for
    seconds in each new process and added a cache file each time).

    ``edge`` False: band lo .. hi - 1 (without the rows next to an inner edge that need another band's rows);
    True: the rows around the inner band edge ``lo``. ``moved[k]`` counts the rows in which pass first_pass + k
    moved a pixel.
    """
    H = z.shape[0]
    n_all = 3 + n_passes + (1 if base else 0)
    kind = np.empty(n_all, np.int64)
    reach = np.zeros(n_all, np.int64)  # C_k: the halos of the stages j0 + 1 .. k, added up
    start = np.zeros(n_all, np.int64)
    stop = np.zeros(n_all, np.int64)
    t0, t1 = H + n_all * 2, 0
    for k in range(j0, j1):
        kind[k] = k if k < 3 else (_PASS if k < 3 + n_passes else _NORMALS)
        if k > j0:
            reach[k] = reach[k - 1] + _HALO[kind[k]]
        if edge:
            start[k], stop[k] = max(0, lo - reach[k]), min(H, lo + reach[k])
        else:
            start[k] = lo if lo == 0 else lo + reach[k]
            stop[k] = hi if hi == H else hi - reach[k]
        if start[k] < stop[k]:
            t0 = min(t0, start[k] + reach[k])
            t1 = max(t1, stop[k] + reach[k])
    final = y if (first_pass + n_passes - 1) % 2 == 1 else x  # the last pass's set (first_pass - 1's if none)
    for t in range(t0, t1):
        for k in range(j0, j1):
            r = t - reach[k]
            if r < start[k] or r >= stop[k]:
                continue
            what = kind[k]
            if what == _LOAD:
                for v in range(0 if r == 0 else r + _P, H + 2 * _P if r == H - 1 else r + _P + 1):
                    _margins(v, s, ok, l_u, l_v, a_u, a_v, con, x, y)
                _load_row(z, valid, inverse, s, ok, r)
            elif what == _LAPLACIANS:
                _sda_laplacians(s, ok, tol, l_u, l_v, a_u, a_v, r + _P, r + _P + 1)
            elif what == _INIT:
                _sda_init(s, ok, reflect, tol, l_u, l_v, a_u, a_v, con, *x, r, r + 1)
            elif what == _PASS:
                i = first_pass + k - 3
                old, new = (x, y) if i % 2 == 1 else (y, x)
                if _sda_step(s, ok, 1.0 / (i + 1), tol, a_u, a_v, con, *old, *new, r, r + 1):
                    moved[k - 3] += 1
            elif normals == 1:
                _gradients_to_normals_kernel(s, *final[:4], f_x, f_y, c_x, c_y, fill, out, r, r + 1)
            elif normals == 2:
                _tf2n_base_kernel(z, valid, *final[:4], f_x, f_y, c_x, c_y, reflect, fill, out, r, r + 1)


_NO_OUT = np.empty((1, 1, 3), np.float32)  # ``out`` of a sweep without normals (never written)


def _run_sda(z, valid, iterations, border, tie_tol=0.0, bands=whole, inverse=False, normals=None):
    """SDA on padded working arrays, from depth ``z`` (its inverse with ``inverse``), then the normals into
    ``normals = (base, (f_x, f_y, c_x, c_y), fill, out)`` (base 1 CP2TV, 2 3F2N's median) if given.

    Returns the result [g_u, g_v, e_u, e_v] (padded; a gradient with infinite energy does not exist), the passes
    applied, and the working arrays (to keep for the next frame once the caller is done with the first ones). Every stage
    runs in row bands (``bands``, see :mod:`surfnorm._bands`), fused into one sweep with a few passes (see
    :func:`_sda_sweep`), whose stop test comes at its end. A pass in which no pixel moves leaves every gradient and
    energy as it was (only the states become 2), so its set holds the result of the pass before: a sweep of 3
    passes keeps the result unless its first pass is the one that stops (then the stages run again one by one, each
    pass's stop test before the next), and sweeps of 2 (``iterations=None``) always keep it.
    """
    H, W = valid.shape
    shape = (H + 2 * _P, W + 2 * _P)
    arrays = _working.take(shape)
    if arrays is None:  # every element, margins included, is written by a stage before any stage reads it
        kinds = [np.float64, np.bool_] + [np.float64] * 4 + [np.uint8] + 2 * ([np.float64] * 4 + [np.int8] * 2)
        arrays = [np.empty(shape, dt) for dt in kinds]
    s, ok, l_u, l_v, a_u, a_v, con = arrays[:7]
    sets = (tuple(arrays[7:13]), tuple(arrays[13:19]))
    base, f, fill, out = normals if normals is not None else (0, (0.0, 0.0, 0.0, 0.0), np.float32(0), _NO_OUT)
    rows = base  # which normals (0: none, a sweep of sda_gradients)
    common = (z, valid, inverse, border == "reflect", _kernel_tol(tie_tol), s, ok, l_u, l_v, a_u, a_v, con, *sets)
    cap = MAX_ITERATIONS if iterations is None else iterations

    def sweep(first, n, base_, j0, j1):
        """Stages j0 .. j1 - 1 on row bands; whether each of the n passes moved a pixel, or None where a band is too
        short for the stages to run fused."""
        reach = sum(_HALO[k if k < 3 else _PASS if k < 3 + n else _NORMALS] for k in range(j0 + 1, j1))
        parts, lock = [], threading.Lock()

        def band(a, b):
            # The band that finishes last (its thread is running) computes the rows around every inner edge:
            # no second round of tasks on the pool, whose threads take a while to wake.
            short = b - a < 2 * reach + 2 and reach and (a > 0 or b < H)
            moved = np.zeros(max(n, 1), np.int64)
            if not short:
                _sda_sweep(*common, first, n, base_, rows, *f, fill, out, j0, j1, a, b, False, moved)
            with lock:
                parts.append((a, b, short))
                last = sum(q - p for p, q, _ in parts) == H
            if last and reach and not any(x for _, _, x in parts):
                for edge in sorted(q for _, q, _ in parts if q < H):
                    _sda_sweep(*common, first, n, base_, rows, *f, fill, out, j0, j1, edge, edge, True, moved)
            return None if short else moved

        done = bands(band, H)
        if any(m is None for m in done):
            return None
        return np.sum(done, axis=0)[:n] > 0

    def fused():
        """(passes, which set holds the result, normals written), or None to run the stages one by one."""
        passes, per = 0, (2 if iterations is None else 3)
        while True:
            n = min(per, cap - passes)
            last = passes + n == cap
            base_ = base if last else 0
            moved = sweep(passes + 1, n, base_, 0 if passes == 0 else 3, 3 + n + (1 if base_ else 0))
            if moved is None:
                return None
            if moved.all():
                passes += n
                if last:
                    return passes, passes % 2, bool(base_)
                continue
            j = passes + 1 + int(np.argmin(moved))  # the first pass that moved nothing: its set is pass j - 1's result
            if j < passes + n - 1:  # pass j + 2 overwrote it
                return None
            return j - 1, j % 2, bool(base_) and j == passes + n

    def staged():
        for k in range(3):
            sweep(1, 0, 0, k, k + 1)
        passes = 0
        for i in range(1, cap + 1):
            if not sweep(i, 1, 0, 3, 4)[0]:
                break
            passes = i
        return passes, passes % 2, False

    passes, which, written = fused() or staged()
    if base and not written:  # the normals from the result set (a sweep without passes: first_pass - 1's set)
        sweep(which + 1, 0, base, 3, 4)
    return list(sets[which][:4]), passes, arrays


def sda_gradients(signal, valid, *, iterations=3, border="one-sided", tie_tol=0.0):
    """SDA gradients of ``signal`` (H, W) along u and v, and the number of passes that ran.

    Returns ``(g_u, g_v, passes)``: float64 (H, W) arrays, NaN where a pixel
    has no gradient, and how many passes of the dynamic programming were
    applied (the pass whose stop test fired is not counted). ``iterations``
    None runs until stable, at most :data:`MAX_ITERATIONS` passes. ``tie_tol``: see :data:`surfnorm.units.TIE_TOLERANCE`.
    """
    signal = np.asarray(signal, dtype=np.float64)
    (g_u, g_v, e_u, e_v), passes, work = _run_sda(signal, valid, iterations, border, tie_tol)
    inner = (slice(_P, -_P), slice(_P, -_P))
    out = (np.where(e_u[inner] < _INF, g_u[inner], np.nan), np.where(e_v[inner] < _INF, g_v[inner], np.nan), passes)
    _working.give(work[0].shape, work)
    return out


def sda_sne(z, valid, cam, out, *, iterations=3, base="cp2tv", border="one-sided", fill=0.0, tie_tol=0.0, bands=whole):
    """SDA-SNE (Ming et al., 3DV 2022): SDA gradients, then CP2TV (or 3F2N's median), into ``out``.

    ``tie_tol`` 0 (the paper-faithful mode) compares exactly; the scale-invariant mode passes
    :data:`surfnorm.units.TIE_TOLERANCE` (see there). ``bands``: how rows are split over threads
    (see :mod:`surfnorm._bands`): the dynamic programming is a sequence of Jacobi passes (each pixel
    from the previous pass only), so every pass runs in row bands side by side (see :func:`_sda_sweep`)."""
    f = (float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy))
    inverse = base == "3f2n"  # the demo's SDA + 3F2N: the dynamic programming on inverse depth
    normals = (2 if inverse else 1, f, np.float32(fill), out)
    _, _, work = _run_sda(z, valid, iterations, border, tie_tol, bands, inverse, normals)
    _working.give(work[0].shape, work)
    return out
