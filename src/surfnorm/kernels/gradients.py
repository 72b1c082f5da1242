"""Depth gradients z_u = dz/du and z_v = dz/dv: finite differences and the DAG filter.

Equation numbers are those of Feng et al., "D2NT: A High-Performing
Depth-to-Normal Translator", ICRA 2023 (numbered in the order they appear):

* eq. 10  G_h = lambda_l Delta_b + lambda_r Delta_f, G_v likewise (DAG filter)
* eq. 11  s_p = |nabla^2 z_p|, the local smoothness from a discrete Laplace filter (DLF)
* eq. 12  (lambda_l, lambda_r) = M(s_l, s_r), (lambda_u, lambda_d) = M(s_u, s_d)
* eq. 13  softmin M(s_i) = exp(-s_i / tau) / sum_j exp(-s_j / tau)
* eq. 14  truncated softmin: weights 1 and 0 when |s_2 - s_1| > 1

The per-pixel ``@pixel`` functions below are the readable statement of the
rules (and the general path of the kernels, used near the image border and
near missing depth). The kernels in ``translate.py`` and ``mnr.py`` sweep the
image row by row: each pixel's smoothness and softmin weight exp(-s/tau) is
computed once into a small row buffer (not once per neighbour that uses it),
and inside runs of pixels whose 3x3 neighbourhood is all valid a branch-free
loop (:func:`fast_row`, :func:`segment`) does the same arithmetic without any
validity or bounds checks, so that LLVM can vectorise it. The row-level
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
from decimal import Decimal, getcontext

import numpy as np

from .._choices import BORDERS, DLF_NAMES
from .._config import as_float64, njit, pixel, row

__all__ = ["DLF_NAMES", "BORDERS", "dlf_code", "fd_gradients", "dag_gradients", "valid_map", "softmin_ratio",
           "kernel_tau"]

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
def clamp(i, n):
    """i clamped to 0 .. n - 1: an index that is always safe to read.

    The per-pixel helpers are written in one way for speed: first the calls
    to other helpers that take arrays, then every array read, unconditional,
    at clamped indices, and only then the choices, as scalar tests among the
    values read. Written otherwise (an array read inside an ``if``, or before
    a nested helper call), a helper inlined into a kernel makes Numba keep
    atomic reference-count updates of the arrays on every pixel, which its
    pruning pass does not remove: measured 120-220 ns instead of 4-8 ns per
    pixel for the smoothness, on every pixel next to a hole or the image border.
    """
    return min(max(i, 0), n - 1)


@pixel
def usable(valid, v, u):
    """True if (v, u) lies inside the image and its depth may be used."""
    H, W = valid.shape
    v_c, u_c = clamp(v, H), clamp(u, W)
    return (v == v_c) & (u == u_c) & valid[v_c, u_c]


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


# exp for float32 arguments, evaluated in float64 and rounded once, so that it
# is correctly rounded in practice (and vectorises, unlike a call to libm's
# expf, which also misrounds about 1 argument in 10^4 by one ulp).
# exp(x) = 2^k e^r with k = round(x / ln 2), r = x - k ln 2 (ln 2 split in a
# high part with trailing zero bits, so that k * _LN2_HI is exact, and the
# rest), e^r by its Taylor series to r^13 (|r| <= ln2 / 2: truncation 4e-18).
getcontext().prec = 40
_LN2 = Decimal(2).ln()
_LN2_HI = math.ldexp(math.floor(math.ldexp(float(_LN2), 32)), -32)
_LN2_LO = float(_LN2 - Decimal(_LN2_HI))
_INV_LN2 = float(1 / _LN2)
_C0, _C1, _C2, _C3, _C4, _C5, _C6, _C7, _C8, _C9, _C10, _C11, _C12, _C13 = (1.0 / math.factorial(k) for k in range(14))
_EXP_LO, _EXP_HI = -104.0, 89.0  # exp(-104) < 2^-150 rounds to 0 in float32; exp(89) overflows to inf


@pixel
def exp32(x):
    """exp(x) of a float32, as a float32 (see the note above)."""
    x_d = np.float64(x)
    x_c = x_d if x_d > _EXP_LO else _EXP_LO  # NaN -> _EXP_LO, put back below
    x_c = x_c if x_c < _EXP_HI else _EXP_HI
    k = math.floor(x_c * _INV_LN2 + 0.5)
    r = (x_c - k * _LN2_HI) - k * _LN2_LO
    e_r = ((((((((((((_C13 * r + _C12) * r + _C11) * r + _C10) * r + _C9) * r + _C8) * r + _C7) * r + _C6)
                * r + _C5) * r + _C4) * r + _C3) * r + _C2) * r + _C1) * r + _C0  # Horner
    two_k = as_float64((np.int64(k) + 1023) << 52)
    y = np.float32(e_r * two_k)
    return y if x_d == x_d else x


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
def truncated_softmin(s_1, s_2, tau, truncate):
    """Weights (lambda_1, lambda_2) of two neighbours with smoothness s_1, s_2 (eq. 13-14).

    softmin with softness ``tau``, regularised by :data:`SOFTMIN_EPS`; with
    ``truncate`` the smoother side gets weight 1 and the other 0 when their
    softmin weights differ by more than a factor e^(1/tau), i.e. when
    |s_2 - s_1| > 1 (eq. 14).
    """
    inv = 1.0 / np.float64(tau)
    ratio = np.float32(math.exp(inv)) if truncate and inv < _EXP32_MAX_ARG else np.float32(np.inf)
    return softmin_pair(exp32(scaled_smoothness(s_1, tau)), exp32(scaled_smoothness(s_2, tau)), ratio)


@pixel
def scaled_smoothness(s, tau):
    """-s / tau rounded to float32, computed in float64 (``tau`` float64, see :func:`kernel_tau`).

    For a tau that is a float32 this is exactly the float32 quotient (a float64 quotient of two float32
    values rounds to the same float32); for any other positive tau it is the correctly rounded value,
    never NaN (s = 0 gives -0) and -inf where s / tau overflows (exp gives 0).
    """
    return np.float32(-np.float64(s) / np.float64(tau))


@pixel
def copy_row(src, dst):
    """dst[:] = src, element by element (a slice assignment may allocate, which row functions may not)."""
    for u in range(dst.shape[0]):
        dst[u] = src[u]


@pixel
def inside(valid, v, u):
    """True if (v, u) lies inside the image."""
    H, W = valid.shape
    return (v >= 0) & (v < H) & (u >= 0) & (u < W)


@pixel
def stencil(valid, v, u, dv, du, reflect):
    """The two samples of a difference along (dv, du) at p = (v, u), and their distance.

    Central (p - d, p + d, 2) when both neighbours are usable, else one-sided
    (p, p + d, 1) or (p - d, p, 1); distance 0 when neither is. With
    ``reflect``, a neighbour outside the image is the mirror image of the one
    inside (OpenCV's BORDER_REFLECT_101, as the authors' code), which makes
    the central difference there zero.
    """
    has_b = usable(valid, v - dv, u - du)
    has_f = usable(valid, v + dv, u + du)
    mirror_b = reflect & (not inside(valid, v - dv, u - du))  # the missing neighbour is outside the image: mirror it
    mirror_f = reflect & (not inside(valid, v + dv, u + du))
    vb, ub, vf, uf, dist = v, u, v, u, 0
    if has_b & has_f:
        vb, ub, vf, uf, dist = v - dv, u - du, v + dv, u + du, 2
    elif has_f:
        if mirror_b:
            vb, ub, vf, uf, dist = v + dv, u + du, v + dv, u + du, 2
        else:
            vb, ub, vf, uf, dist = v, u, v + dv, u + du, 1
    elif has_b:
        if mirror_f:
            vb, ub, vf, uf, dist = v - dv, u - du, v - dv, u - du, 2
        else:
            vb, ub, vf, uf, dist = v - dv, u - du, v, u, 1
    # (one return statement: Numba compiles several tuple returns in a hot helper far slower)
    return vb, ub, vf, uf, dist


@pixel
def fd_gradient(z, valid, v, u, dv, du, reflect):
    """Finite-difference gradient along (dv, du): Delta = [-1, 0, 1] / 2, one-sided at gaps.

    Returns (gradient, ok); ok is False when neither neighbour is usable.
    """
    vb, ub, vf, uf, dist = stencil(valid, v, u, dv, du, reflect)
    return (z[vf, uf] - z[vb, ub]) / np.float32(max(dist, 1)), dist > 0


@pixel
def dag_gradient(z, valid, v, u, dv, du, dlf, axis, tau, truncate):
    """DAG gradient along (dv, du): lambda_b Delta_b z + lambda_f Delta_f z (eq. 10, 12-14).

    The backward and forward differences are weighted by the (truncated)
    softmin of the smoothness of the backward and forward neighbours, so the
    side that lies on the same smooth surface as p dominates. One-sided where
    only one neighbour is usable. Returns (gradient, ok).
    """
    H, W = z.shape
    v_b, u_b, v_f, u_f = clamp(v - dv, H), clamp(u - du, W), clamp(v + dv, H), clamp(u + du, W)
    has_b = usable(valid, v - dv, u - du)
    has_f = usable(valid, v + dv, u + du)
    s_b = smoothness(z, valid, v_b, u_b, dlf, axis)  # taken always (see clamp), used only with both neighbours
    s_f = smoothness(z, valid, v_f, u_f, dlf, axis)
    lambda_b, lambda_f = truncated_softmin(s_b, s_f, tau, truncate)
    if not (has_b & has_f):
        lambda_b = np.float32(1.0) if has_b else np.float32(0.0)
        lambda_f = np.float32(1.0) if has_f else np.float32(0.0)
    z_p, z_b, z_f = z[v, u], z[v_b, u_b], z[v_f, u_f]
    delta_b = (z_p - z_b) if has_b else np.float32(0.0)
    delta_f = (z_f - z_p) if has_f else np.float32(0.0)
    return lambda_b * delta_b + lambda_f * delta_f, has_b | has_f


@njit
def _fd_map_kernel(z, valid, reflect, out):
    H, W = z.shape
    for v in range(H):
        for u in range(W):
            z_u, ok_u = fd_gradient(z, valid, v, u, 0, 1, reflect)
            z_v, ok_v = fd_gradient(z, valid, v, u, 1, 0, reflect)
            ok = valid[v, u] & ok_u & ok_v
            out[0, v, u] = z_u if ok else np.nan
            out[1, v, u] = z_v if ok else np.nan


@njit
def _dag_map_kernel(z, valid, dlf, tau, truncate, out):
    H, W = z.shape
    for v in range(H):
        for u in range(W):
            z_u, ok_u = dag_gradient(z, valid, v, u, 0, 1, dlf, 0, tau, truncate)
            z_v, ok_v = dag_gradient(z, valid, v, u, 1, 0, dlf, 1, tau, truncate)
            ok = valid[v, u] & ok_u & ok_v
            out[0, v, u] = z_u if ok else np.nan
            out[1, v, u] = z_v if ok else np.nan


def fd_gradients(z: np.ndarray, valid: np.ndarray, *, border: str = "one-sided") -> np.ndarray:
    """Finite-difference depth gradients, shape (2, H, W): (z_u, z_v), NaN where undefined."""
    out = np.empty((2,) + z.shape, dtype=np.float32)
    _fd_map_kernel(z, valid, border == "reflect", out)
    return out


def dag_gradients(z: np.ndarray, valid: np.ndarray, *, dlf: str = "1d", tau: float = 1.0, truncate: bool = True) -> np.ndarray:
    """DAG depth gradients (eq. 10-14), shape (2, H, W): (z_u, z_v), NaN where undefined."""
    out = np.empty((2,) + z.shape, dtype=np.float32)
    _dag_map_kernel(z, valid, dlf_code(dlf), kernel_tau(tau), bool(truncate), out)
    return out


# ---------------------------------------------------------------------------
# Validity and the row machinery of the fast kernels.


@njit
def _valid_kernel(z, out):
    H, W = z.shape
    for v in range(H):
        for u in range(W):
            d = z[v, u]
            out[v, u] = (d > 0) & (d < np.inf)  # finite and positive (NaN fails both)


@njit
def _valid_masked_kernel(z, mask, out):
    H, W = z.shape
    for v in range(H):
        for u in range(W):
            d = z[v, u]
            out[v, u] = (d > 0) & (d < np.inf) & mask[v, u]


def valid_map(z: np.ndarray, mask: np.ndarray | None, out: np.ndarray | None = None) -> np.ndarray:
    """Pixels whose depth may be used (finite, positive, in ``mask``): one pass, one allocation (none with ``out``).

    Same result as :func:`surfnorm._validate.valid_pixels` (NumPy, three passes).
    """
    if out is None:
        out = np.empty(z.shape, dtype=np.bool_)
    if mask is None:
        _valid_kernel(z, out)
    else:
        _valid_masked_kernel(z, mask, out)
    return out


@pixel
def box_row(up, mid, dn, interior, col, runs):
    """Runs of columns where up, mid and dn are all True at u - 1, u and u + 1; returns their number.

    Applied to the rows v - 1, v, v + 1 of a validity map: the runs [a, b)
    (``runs[k, 0]``, ``runs[k, 1]``) of pixels whose 3x3 neighbourhood lies in
    the image and is all valid, where the kernels use a branch-free loop.
    None unless ``interior`` (row v has rows above and below). ``col`` is
    scratch of length W; ``runs`` has room for W // 2 + 1 runs. Computed once
    per row and shared by every stage that sweeps it (scanning a row for runs
    in every stage cost as much as the stages themselves).
    """
    W = col.shape[0]
    n = 0
    if interior:
        # The usual case, a row without holes, found with one AND over the bytes (0 or 1) of the
        # three rows (as uint8, which LLVM vectorises; as bool it did not).
        up_b, mid_b, dn_b = up.view(np.uint8), mid.view(np.uint8), dn.view(np.uint8)
        every = np.uint8(1)
        for u in range(W):
            every &= up_b[u] & mid_b[u] & dn_b[u]
        if every == 1:  # one run over the whole row
            runs[0, 0] = 1
            runs[0, 1] = W - 1
            n = 1
        else:
            for u in range(W):
                col[u] = up[u] & mid[u] & dn[u]
            u = 1
            while u < W - 1:
                if col[u - 1] and col[u] and col[u + 1]:
                    runs[n, 0] = u
                    while u < W - 1 and col[u - 1] and col[u] and col[u + 1]:
                        u += 1
                    runs[n, 1] = u
                    n += 1
                else:
                    u += 1
    return n


@row
def fast_row(valid, v, col, runs):
    """:func:`box_row` of the validity map around row v."""
    H = valid.shape[0]
    return box_row(valid[max(v - 1, 0)], valid[v], valid[min(v + 1, H - 1)], v >= 1 and v < H - 1, col, runs)


@pixel
def segment(runs, n_runs, k, W):
    """Fast run k = [a, b) of a row, k = 0 .. n_runs; the last one, k = n_runs, is empty at the end (a = b = W).

    A sweep over a row handles pixels [previous b, a) by the per-pixel rule,
    then the run [a, b) by a branch-free loop.
    """
    a, b = W, W
    if k < n_runs:
        a, b = runs[k, 0], runs[k, 1]
    return a, b


@row
def laplacian_row(z, valid, r, runs, n_runs, dlf, axis, s):
    """s[u] = smoothness |nabla^2 z| (eq. 11) of every valid pixel of row r (0 where invalid).

    Branch-free inside the fast runs of row r (all neighbours valid, so no
    mirroring), the per-pixel rule :func:`smoothness` elsewhere; the same sums
    in the same order.
    """
    H, W = z.shape
    up, mid, dn = z[max(r - 1, 0)], z[r], z[min(r + 1, H - 1)]
    edge_w, corner_w = _DLF_EDGE[dlf], _DLF_CORNER[dlf]
    u = 0
    for k in range(n_runs + 1):
        a, b = segment(runs, n_runs, k, W)
        for x in range(u, a):
            s_x = smoothness(z, valid, r, x, dlf, axis)
            s[x] = s_x if valid[r, x] else np.float32(0.0)
        if b > a:
            # Views shifted so that the loop index starts at 0: Numba's negative-index
            # handling otherwise hides the address pattern and LLVM does not vectorise.
            out, left, centre, right, above, below = s[a:b], mid[a - 1:b - 1], mid[a:b], mid[a + 1:b + 1], up[a:b], dn[a:b]
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
                above_l, above_r, below_l, below_r = up[a - 1:b - 1], up[a + 1:b + 1], dn[a - 1:b - 1], dn[a + 1:b + 1]
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
