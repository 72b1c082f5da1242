"""Depth gradients z_u = dz/du and z_v = dz/dv: finite differences and the DAG filter.

Equation numbers are those of Feng et al., "D2NT: A High-Performing
Depth-to-Normal Translator", ICRA 2023 (numbered in the order they appear):

* eq. 10  G_h = lambda_l Delta_b + lambda_r Delta_f, G_v likewise (DAG filter)
* eq. 11  s_p = |nabla^2 z_p|, the local smoothness from a discrete Laplace filter (DLF)
* eq. 12  (lambda_l, lambda_r) = M(s_l, s_r), (lambda_u, lambda_d) = M(s_u, s_d)
* eq. 13  softmin M(s_i) = exp(-s_i / tau) / sum_j exp(-s_j / tau)
* eq. 14  truncated softmin: weights 1 and 0 when |s_2 - s_1| > 1

Everything here is a per-pixel ``@njit`` function that the kernels in
``translate.py`` and ``refine.py`` call inside their loops, so that a whole
estimator is a single pass over the image with no temporaries.

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

from ._config import njit, pixel

__all__ = ["DLF_NAMES", "BORDERS", "dlf_code", "fd_gradients", "dag_gradients"]

#: How a finite difference treats the image border (see :func:`stencil`).
BORDERS = ("one-sided", "reflect")

#: The four discrete Laplace filters of Table II, by name.
DLF_NAMES = ("1d", "alpha", "beta", "gamma")

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
def usable(valid, v, u):
    """True if (v, u) lies inside the image and its depth may be used."""
    # Written as plain ifs: Numba compiles a chained ``0 <= v < H and ...`` 20x slower.
    H, W = valid.shape
    if v < 0 or v >= H or u < 0 or u >= W:
        return False
    return valid[v, u]


@pixel
def neighbour_difference(z, valid, v, u, dv, du):
    """z_q - z_p for the neighbour q = p + (dv, du), mirrored to p - (dv, du) if q is missing."""
    diff = np.float32(0.0)
    if usable(valid, v + dv, u + du):
        diff = z[v + dv, u + du] - z[v, u]
    elif usable(valid, v - dv, u - du):
        diff = z[v - dv, u - du] - z[v, u]
    return diff


@pixel
def smoothness(z, valid, v, u, dlf, axis):
    """Local smoothness s_p = |nabla^2 z_p| (eq. 11) of the valid pixel p = (v, u).

    ``dlf`` indexes :data:`DLF_NAMES`. The 1D DLF is [1, -2, 1] along ``axis``
    (0: horizontal, 1: vertical); the 3x3 filters ignore ``axis``.
    """
    if dlf == 0:
        if axis == 0:
            lap = neighbour_difference(z, valid, v, u, 0, -1) + neighbour_difference(z, valid, v, u, 0, 1)
        else:
            lap = neighbour_difference(z, valid, v, u, -1, 0) + neighbour_difference(z, valid, v, u, 1, 0)
        return abs(lap)
    edge = (neighbour_difference(z, valid, v, u, -1, 0) + neighbour_difference(z, valid, v, u, 1, 0)
            + neighbour_difference(z, valid, v, u, 0, -1) + neighbour_difference(z, valid, v, u, 0, 1))
    lap = _DLF_EDGE[dlf] * edge
    if _DLF_CORNER[dlf] != 0:
        corner = (neighbour_difference(z, valid, v, u, -1, -1) + neighbour_difference(z, valid, v, u, -1, 1)
                  + neighbour_difference(z, valid, v, u, 1, -1) + neighbour_difference(z, valid, v, u, 1, 1))
        lap += _DLF_CORNER[dlf] * corner
    return abs(lap)


#: Regulariser of the softmin, as in the authors' code. Where both neighbours
#: are very rough (both exp(-s / tau) far below it), the two weights tend to
#: 1/2 and the DAG gradient falls back to the central difference instead of
#: trusting either side: a one-pixel spike or ridge has no smooth side.
SOFTMIN_EPS = np.float32(1e-8)


@pixel
def truncated_softmin(s_1, s_2, tau, truncate):
    """Weights (lambda_1, lambda_2) of two neighbours with smoothness s_1, s_2.

    softmin (eq. 13) with softness ``tau``, regularised by :data:`SOFTMIN_EPS`;
    with ``truncate`` the smoother side gets weight 1 and the other 0 when
    their softmin weights differ by more than a factor e^(1/tau), i.e. when
    |s_2 - s_1| > 1 (eq. 14).
    """
    p_1 = np.float32(math.exp(-s_1 / tau))
    p_2 = np.float32(math.exp(-s_2 / tau))
    total = SOFTMIN_EPS + p_1 + p_2
    half_eps = np.float32(0.5) * SOFTMIN_EPS
    lambda_1 = (p_1 + half_eps) / total
    lambda_2 = (p_2 + half_eps) / total
    if truncate:
        ratio = np.float32(math.exp(1.0 / tau))
        if lambda_1 / (lambda_2 + SOFTMIN_EPS) > ratio:
            lambda_1, lambda_2 = np.float32(1.0), np.float32(0.0)
        elif lambda_2 / (lambda_1 + SOFTMIN_EPS) > ratio:
            lambda_1, lambda_2 = np.float32(0.0), np.float32(1.0)
    return lambda_1, lambda_2


@pixel
def inside(valid, v, u):
    H, W = valid.shape
    if v < 0 or v >= H or u < 0 or u >= W:
        return False
    return True


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
    vb, ub, vf, uf, dist = v, u, v, u, 0
    if has_b and has_f:
        vb, ub, vf, uf, dist = v - dv, u - du, v + dv, u + du, 2
    elif has_f:
        if reflect and not inside(valid, v - dv, u - du):
            vb, ub, vf, uf, dist = v + dv, u + du, v + dv, u + du, 2
        else:
            vb, ub, vf, uf, dist = v, u, v + dv, u + du, 1
    elif has_b:
        if reflect and not inside(valid, v + dv, u + du):
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
    has_b = usable(valid, v - dv, u - du)
    has_f = usable(valid, v + dv, u + du)
    lambda_b = np.float32(1.0) if has_b else np.float32(0.0)
    lambda_f = np.float32(1.0) if has_f else np.float32(0.0)
    if has_b and has_f:
        s_b = smoothness(z, valid, v - dv, u - du, dlf, axis)
        s_f = smoothness(z, valid, v + dv, u + du, dlf, axis)
        lambda_b, lambda_f = truncated_softmin(s_b, s_f, tau, truncate)
    z_p = z[v, u]
    delta_b = z_p - z[v - dv, u - du] if has_b else np.float32(0.0)
    delta_f = z[v + dv, u + du] - z_p if has_f else np.float32(0.0)
    return lambda_b * delta_b + lambda_f * delta_f, has_b or has_f


@njit
def _fd_map_kernel(z, valid, reflect, out):
    H, W = z.shape
    for v in range(H):
        for u in range(W):
            z_u, ok_u = fd_gradient(z, valid, v, u, 0, 1, reflect)
            z_v, ok_v = fd_gradient(z, valid, v, u, 1, 0, reflect)
            ok = valid[v, u] and ok_u and ok_v
            out[0, v, u] = z_u if ok else np.nan
            out[1, v, u] = z_v if ok else np.nan


@njit
def _dag_map_kernel(z, valid, dlf, tau, truncate, out):
    H, W = z.shape
    for v in range(H):
        for u in range(W):
            ok = False
            if valid[v, u]:
                z_u, ok_u = dag_gradient(z, valid, v, u, 0, 1, dlf, 0, tau, truncate)
                z_v, ok_v = dag_gradient(z, valid, v, u, 1, 0, dlf, 1, tau, truncate)
                ok = ok_u and ok_v
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
    _dag_map_kernel(z, valid, dlf_code(dlf), np.float32(tau), bool(truncate), out)
    return out
