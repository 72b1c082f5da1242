"""Depth gradients z_u = dz/du and z_v = dz/dv: finite differences and the DAG filter.

Equation numbers are those of Feng et al., "D2NT: A High-Performing
Depth-to-Normal Translator", ICRA 2023 (numbered in the order they appear):

* eq. 10  G_h = lambda_l Delta_b + lambda_r Delta_f, G_v likewise (DAG filter)
* eq. 11  s_p = |nabla^2 z_p|, the local smoothness from a discrete Laplace filter (DLF)
* eq. 12  (lambda_l, lambda_r) = M(s_l, s_r), (lambda_u, lambda_d) = M(s_u, s_d)
* eq. 13  softmin M(s_i) = exp(-s_i / tau) / sum_j exp(-s_j / tau)
* eq. 14  truncated softmin: weights 1 and 0 when |s_2 - s_1| > 1

The per-pixel ``@pixel`` functions below are the readable statement of the
rules (:func:`fd_gradient`, :func:`smoothness`, :func:`softmin_pair`,
:func:`dag_gradient`), and the general path of the kernels, used near the
image border and near missing depth. The kernels in ``translate.py``,
``mnr.py`` and ``d2nt_v3.py`` sweep the image row by row: each pixel's
smoothness and softmin weight exp(-s/tau) is computed once into a small row
buffer (:func:`laplacian_row`, :func:`softmin_weights_row`; not once per
neighbour that uses it), and inside runs of pixels whose 3x3 neighbourhood is
all valid (``_rows.fast_row``, ``_rows.segment``) a branch-free loop does the
same arithmetic without any validity or bounds checks, so that LLVM can
vectorise it. The row-level
functions are ordinary ``@njit`` functions (called once per row, so the call
costs nothing), not inlined: inlining them into every kernel made compiling
d2nt_v3 take minutes.

Invalid depth (``valid[v, u] == False``) is never read. Where a neighbour is
missing (invalid or outside the image) a gradient falls back to the one-sided
difference, and a Laplacian uses the mirrored neighbour in its place (what
OpenCV's default BORDER_REFLECT_101 does at the image border, and so what the
authors' code does there); a pixel with neither neighbour along an axis has
no gradient along it.
"""

from __future__ import annotations

import math

import numpy as np

from .._choices import DLF_NAMES
from .._config import pixel, row
from ._rows import clamp, exp32, segment, stencil, usable

__all__ = [
    "dlf_code",
    "kernel_tau",
    "softmin_ratio",
    "smoothness",
    "softmin_pair",
    "fd_gradient",
    "dag_gradient",
    "laplacian_row",
    "softmin_weights_row",
    "softmin_row",
]

# Weights of the 3x3 DLFs, as (edge neighbour weight, corner neighbour weight);
# the centre weight is minus their sum, so nabla^2 z = sum_k w_k (z_k - z_c).
#   alpha = [[0,1,0],[1,-4,1],[0,1,0]]      beta = [[1,1,1],[1,-8,1],[1,1,1]]
#   gamma = [[1,2,1],[2,-12,2],[1,2,1]] / 4 (the authors' code divides the
#   paper's footnote kernel by 4; we follow the code, whose numbers Table II reports)
_DLF_EDGE = np.array([0.0, 1.0, 1.0, 0.5], dtype=np.float32)
_DLF_CORNER = np.array([0.0, 0.0, 1.0, 0.25], dtype=np.float32)


def dlf_code(name: str) -> int:
    """Index of a DLF name in :data:`DLF_NAMES` (the kernels take the index)."""
    return DLF_NAMES.index(name)


@pixel
def neighbour_difference(z, valid, v, u, dv, du):
    """z_q - z_p for the neighbour q = p + (dv, du), mirrored to p - (dv, du) if q is missing (0 if both are)."""
    H, W = z.shape
    has_f = usable(valid, v + dv, u + du)
    has_b = usable(valid, v - dv, u - du)
    z_f = z[clamp(v + dv, H), clamp(u + du, W)]  # read unconditionally (see clamp), used only if usable
    z_b = z[clamp(v - dv, H), clamp(u - du, W)]
    z_p = z[v, u]
    diff = np.float32(0.0)
    if has_b:
        diff = z_b - z_p
    if has_f:
        diff = z_f - z_p
    return diff


@pixel
def smoothness(z, valid, v, u, dlf, axis):
    """Local smoothness s_p = |nabla^2 z_p| (eq. 11) of the valid pixel p = (v, u).

    ``dlf`` indexes :data:`DLF_NAMES`. The 1D DLF is [1, -2, 1] along ``axis``
    (0: horizontal, 1: vertical); the 3x3 filters ignore ``axis``. (All eight
    differences are taken whatever the filter: see :func:`clamp`.)
    """
    d_up = neighbour_difference(z, valid, v, u, -1, 0)
    d_dn = neighbour_difference(z, valid, v, u, 1, 0)
    d_l = neighbour_difference(z, valid, v, u, 0, -1)
    d_r = neighbour_difference(z, valid, v, u, 0, 1)
    d_ul = neighbour_difference(z, valid, v, u, -1, -1)
    d_ur = neighbour_difference(z, valid, v, u, -1, 1)
    d_dl = neighbour_difference(z, valid, v, u, 1, -1)
    d_dr = neighbour_difference(z, valid, v, u, 1, 1)
    lap_1d = (d_l + d_r) if axis == 0 else (d_up + d_dn)
    lap = _DLF_EDGE[dlf] * (((d_up + d_dn) + d_l) + d_r)
    corner_w = _DLF_CORNER[dlf]
    if corner_w != 0:
        lap += corner_w * (((d_ul + d_ur) + d_dl) + d_dr)
    return abs(lap_1d) if dlf == 0 else abs(lap)


#: Regulariser of the softmin, as in the authors' code. Where both neighbours
#: are very rough (both exp(-s / tau) far below it), the two weights tend to
#: 1/2 and the DAG gradient falls back to the central difference instead of
#: trusting either side: a one-pixel spike or ridge has no smooth side.
SOFTMIN_EPS = np.float32(1e-8)


def kernel_tau(tau: float) -> float:
    """tau as the kernels use it: rounded to float32 (as the paper-faithful kernels always did), unless that
    rounding would make it 0 or inf (tau below about 1e-45 or above 3.4e38), where it stays float64.

    Any positive finite tau that the validation accepts then gives finite weights (see :func:`softmin_weights_row`).
    """
    with np.errstate(over="ignore", under="ignore"):
        t32 = np.float32(tau)
    return float(t32) if 0 < t32 < np.inf else float(tau)


#: exp(x) overflows float32 above this: a truncation ratio e^(1/tau) beyond it is +inf.
_EXP32_MAX_ARG = 88.72


def softmin_ratio(tau: float, truncate: bool) -> np.float32:
    """The weight ratio beyond which the truncated softmin (eq. 14) snaps to (1, 0): e^(1/tau), or inf (no truncation).

    For tau below about 0.0113 e^(1/tau) exceeds float32 (and, below 0.0014, float64): the ratio is +inf
    then, which changes nothing, since two regularised weights never differ by more than about
    1 / SOFTMIN_EPS = 1e8 = e^18.4; the truncation cannot fire for tau < 1 / 18.5 anyway.
    """
    if not truncate:
        return np.float32(np.inf)
    inv = 1.0 / kernel_tau(tau)
    return np.float32(math.exp(inv)) if inv < _EXP32_MAX_ARG else np.float32(np.inf)


@pixel
def softmin_pair(p_b, p_f, ratio):
    """Weights (lambda_b, lambda_f) from p_i = exp(-s_i / tau) of the two neighbours (eq. 13-14).

    softmin regularised by :data:`SOFTMIN_EPS`; truncated to (1, 0) or (0, 1)
    when one weight exceeds ``ratio`` = e^(1/tau) times the other (|s_b - s_f| > 1
    for tau = 1); ``ratio`` = inf switches truncation off.
    """
    total = SOFTMIN_EPS + p_b + p_f
    half_eps = np.float32(0.5) * SOFTMIN_EPS
    lambda_b = (p_b + half_eps) / total
    lambda_f = (p_f + half_eps) / total
    b_wins = lambda_b / (lambda_f + SOFTMIN_EPS) > ratio
    f_wins = lambda_f / (lambda_b + SOFTMIN_EPS) > ratio
    one, zero = np.float32(1.0), np.float32(0.0)
    out_b = one if b_wins else (zero if f_wins else lambda_b)
    out_f = zero if b_wins else (one if f_wins else lambda_f)
    return out_b, out_f


@pixel
def fd_gradient(z, valid, v, u, dv, du, reflect):
    """Finite-difference gradient along (dv, du): Delta = [-1, 0, 1] / 2, one-sided at gaps.

    Returns (gradient, ok); ok is False when neither neighbour is usable.
    """
    vb, ub, vf, uf, dist = stencil(valid, v, u, dv, du, reflect)
    return (z[vf, uf] - z[vb, ub]) / np.float32(max(dist, 1)), dist > 0


@pixel
def dag_gradient(z, valid, v, u, dv, du, p_b, p_f, ratio):
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
    z_p, z_b, z_f = z[v, u], z[v_b, u_b], z[v_f, u_f]  # read unconditionally: see _rows.clamp
    delta_b = (z_p - z_b) if has_b else np.float32(0.0)
    delta_f = (z_f - z_p) if has_f else np.float32(0.0)
    return lambda_b * delta_b + lambda_f * delta_f, has_b | has_f


# ---------------------------------------------------------------------------
# Row functions: one row of smoothness, one row of softmin weights.


@row
def laplacian_row(z, valid, r, runs, n_runs, dlf, axis, s):
    """s[u] = smoothness s_p = |nabla^2 z_p| (eq. 11) of every valid pixel of row r (0 where invalid).

    Branch-free inside the fast runs of row r (all neighbours valid, so no mirroring), the per-pixel rule
    :func:`smoothness` elsewhere; the same sums in the same order.

    Parameters
    ----------
    z, valid : ndarray, shape (H, W)
        Validated depth (float32) and its validity (bool).
    r : int
        The row.
    runs, n_runs : ndarray of int64 (W // 2 + 1, 2), int
        The fast runs of row r (:func:`surfnorm.kernels._rows.fast_row`).
    dlf : int
        Index of the DLF in ``DLF_NAMES``: 1D [1, -2, 1], or the 3x3 alpha, beta, gamma.
    axis : int
        For the 1D DLF: 0 horizontal, 1 vertical (ignored by the 3x3 filters).
    s : ndarray of float32, shape (W,)
        Receives the smoothness.
    """
    H, W = z.shape
    up, mid, dn = z[max(r - 1, 0)], z[r], z[min(r + 1, H - 1)]
    valid_r = valid[r]
    edge_w, corner_w = _DLF_EDGE[dlf], _DLF_CORNER[dlf]
    u = 0
    for k in range(n_runs + 1):
        a, b = segment(runs, n_runs, k, W)
        for x in range(u, a):
            s_x = np.float32(0.0)  # pixels without depth
            if valid_r[x]:
                s_x = smoothness(z, valid, r, x, dlf, axis)
            s[x] = s_x
        if b > a:
            # Views shifted so that the loop index starts at 0: Numba's negative-index
            # handling otherwise hides the address pattern and LLVM does not vectorise.
            out, left, centre, right, above, below = (
                s[a:b],
                mid[a - 1 : b - 1],
                mid[a:b],
                mid[a + 1 : b + 1],
                up[a:b],
                dn[a:b],
            )
            if dlf == 0 and axis == 0:
                for i in range(b - a):
                    out[i] = abs((left[i] - centre[i]) + (right[i] - centre[i]))
            elif dlf == 0:
                for i in range(b - a):
                    out[i] = abs((above[i] - centre[i]) + (below[i] - centre[i]))
            elif corner_w == 0:
                for i in range(b - a):
                    c = centre[i]
                    out[i] = abs(edge_w * ((((above[i] - c) + (below[i] - c)) + (left[i] - c)) + (right[i] - c)))
            else:
                above_l, above_r, below_l, below_r = (
                    up[a - 1 : b - 1],
                    up[a + 1 : b + 1],
                    dn[a - 1 : b - 1],
                    dn[a + 1 : b + 1],
                )
                for i in range(b - a):
                    c = centre[i]
                    lap = edge_w * ((((above[i] - c) + (below[i] - c)) + (left[i] - c)) + (right[i] - c))
                    lap += corner_w * ((((above_l[i] - c) + (above_r[i] - c)) + (below_l[i] - c)) + (below_r[i] - c))
                    out[i] = abs(lap)
        u = b


@row(fastmath={"contract"})
def softmin_weights_row(s, z, tau, rel, p):
    """p[u] = exp(-s[u] / tau_u), the unnormalised softmin weight (eq. 13) of each pixel of a row.

    ``tau`` is float64 (:func:`kernel_tau`). ``rel`` = 0 (the paper-faithful mode): tau_u = tau in depth
    units, as :func:`softmin_row` when tau is a float32 (the same bits), else computed in float64 so that a
    tau beyond float32 (1e-300, 1e300) still gives finite weights. ``rel`` > 0 (the scale-invariant mode):
    tau_u = tau z[u] / rel, relative to the pixel's own depth (``rel`` = ``surfnorm.units.REFERENCE_DEPTH``),
    so the weight depends on the relative smoothness s / z only, not on the unit of depth nor on any other
    pixel. Compiled with FMA contraction, as :func:`softmin_row`.
    """
    tau32 = np.float32(tau)
    if rel > 0.0:
        k = rel / tau
        for u in range(s.shape[0]):
            z_u = np.float64(z[u])
            x = -(np.float64(s[u]) / z_u) * k
            p[u] = exp32(np.float32(x if (z_u > 0.0) & (x == x) else 0.0))  # (never read where z <= 0; s = 0: 1)
    elif np.float64(tau32) == tau:
        for u in range(s.shape[0]):
            p[u] = exp32(-s[u] / tau32)
    else:
        for u in range(s.shape[0]):
            p[u] = exp32(np.float32(-np.float64(s[u]) / tau))


@row(fastmath={"contract"})
def softmin_row(s, tau, p):
    """p[u] = exp(-s[u] / tau), the unnormalised softmin weight (eq. 13) of each pixel of a row.

    Compiled with FMA contraction (only here): the float64 Horner steps of
    :func:`exp32` become fused multiply-adds, twice as fast and at least as
    accurate; this function was checked on every float32 argument in
    [-104.5, 0] to give exactly exp rounded to float32 (benchmarks/exp32_exhaustive.py).
    """
    for u in range(s.shape[0]):
        p[u] = exp32(-s[u] / tau)
