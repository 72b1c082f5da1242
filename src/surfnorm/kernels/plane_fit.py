"""Plane fitting on the organised point cloud: PlaneSVD, PlanePCA, VectorSVD.

The energy-minimisation estimators of Table I of Feng et al. (D2NT, ICRA
2023), after the comparisons of Klasing et al. (ICRA 2009) and Jordan &
Mordohai (2014). Each pixel p_i is back-projected to the 3D point
p_i = z K^-1 [u, v, 1]^T (eq. 3); its neighbours Q_i = {q_i1 .. q_ik} are the
valid points of the k x k pixel window around it (``window``, 3 by default),
and Q_i^+ = Q_i with p_i itself. The normal minimises (eq. 1):

* PlaneSVD (Wang et al. 2001; Klasing et al. 2009):
  min || [Q_i^+, 1] b_i ||_2 over b_i = [n_i; d_i] with ||b_i|| = 1, the plane
  n . x + d = 0 with its offset. b_i is the smallest eigenvector of the 4x4
  matrix M = [Q^+, 1]^T [Q^+, 1] (the smallest right singular vector of
  [Q^+, 1]). Writing M with the centroid c and the scatter matrix
  S = sum (q - c)(q - c)^T of the m = |Q^+| points, its characteristic
  polynomial is

      det(M - lambda I) = (m - lambda) det(S - lambda I) - m lambda c^T adj(S - lambda I) c,

  and n_i is the null vector of S - lambda I - (m lambda / (m - lambda)) c c^T
  at its smallest root. Because b is normalised with d in it, the fit is not
  the same as PlanePCA: it depends on where the camera is and on the unit of
  depth; the two agree exactly on planes and nearly on smooth surfaces.
* PlanePCA (Klasing et al. 2009): min || [Q_i^+ - p_bar] n_i || with the
  centroid p_bar; n_i is the smallest eigenvector of S.
* VectorSVD (Jordan & Mordohai 2014): min || [Q_i - 1 p_i^T] n_i ||, the
  smallest right singular vector of the matrix of the vectors q - p_i, i.e.
  the smallest eigenvector of sum (q - p_i)(q - p_i)^T.

The smallest eigenvalue (of the 3x3 matrix, or of the 4x4 one of PlaneSVD
through the quartic above) comes from Newton's method on the characteristic
polynomial started at 0, which rises monotonically to the smallest root
because every root is real and >= 0; on smooth surfaces it converges in 2-4
steps and needs no acos or cos (the trigonometric closed form was 4x slower).
The eigenvector is the null vector of (A - lambda I): the largest cross
product of two of its rows. Arithmetic is float64 (the point offsets q - p are
small differences of large coordinates); the output is float32.

Normals face the camera (n . p_i < 0, :func:`surfnorm.kernels._rows.facing_sign`). Invalid
neighbours are left out (their depth is never read: the point cloud holds 0
there, weighted 0); a pixel gets the fill value when it is invalid itself,
when fewer than 3 points (p_i included) are valid in its window, or when they
fix no plane. A window fixes no plane when its valid pixels lie on one line
of the image (e.g. one row, one column, a diagonal): their rays, and so
their 3D points whatever the depths, lie in one plane through the camera
centre, and every fit returns that plane, seen edge-on (a normal
perpendicular to the viewing ray, 1 % of the pixels of KITTI's sparse LiDAR
depth). The test is exact and free of scale: the 2x2 scatter matrix of the
valid pixels' (u, v) offsets, whose entries are small integers, has
determinant 0. (Points collinear in 3D, which fix no plane either, give a
rank-1 matrix, caught by :func:`null_vector`.)
"""

from __future__ import annotations

import math

import numba.extending
import numpy as np

from .. import _plane_svd
from .._bands import whole
from .._config import njit, pixel
from .._constants import NEWTON_STEPS, NEWTON_TOL
from ._rows import facing_sign, point_cloud

__all__ = ["plane_svd", "plane_pca", "vector_svd"]

# Newton's method on PlaneSVD's characteristic polynomial (shared with the PyTorch backend)
_NEWTON_STEPS, _NEWTON_TOL = NEWTON_STEPS, NEWTON_TOL


@pixel
def pixel_spread(m, s_u, s_v, s_uu, s_uv, s_vv):
    """m^2 det of the scatter matrix of the valid pixels' offsets (d_u, d_v) in a window: 0 exactly when they
    lie on one image line (the sums are small integers, so this is exact in float64)."""
    return (m * s_uu - s_u * s_u) * (m * s_vv - s_v * s_v) - (m * s_uv - s_u * s_v) * (m * s_uv - s_u * s_v)


@pixel
def window_spans(valid, v, u, h):
    """True if the valid pixels of the window of half-width h around (v, u) do not all lie on one image line."""
    m = s_u = s_v = s_uu = s_uv = s_vv = 0.0
    for q_v in range(v - h, v + h + 1):
        for q_u in range(u - h, u + h + 1):
            w = 1.0 if valid[q_v, q_u] else 0.0
            d_v, d_u = np.float64(q_v - v), np.float64(q_u - u)
            m += w
            s_u += w * d_u
            s_v += w * d_v
            s_uu += w * d_u * d_u
            s_uv += w * d_u * d_v
            s_vv += w * d_v * d_v
    return pixel_spread(m, s_u, s_v, s_uu, s_uv, s_vv) > 0.0


@pixel
def window_moments(P, valid, v, u, h):
    """Moments of the offsets r = q - p of the valid points q in the window of half-width h around p.

    (v, u) index the padded cloud (border >= h). Returns (m, sum r_x, sum r_y, sum r_z,
    sum r_x r_x, r_x r_y, r_x r_z, r_y r_y, r_y r_z, r_z r_z); m counts p itself (whose offset is 0).
    Invalid points are weighted 0 rather than branched around (several times faster).
    """
    p_x, p_y, p_z = P[0, v, u], P[1, v, u], P[2, v, u]
    m = 0.0
    s_x = s_y = s_z = 0.0
    s_xx = s_xy = s_xz = s_yy = s_yz = s_zz = 0.0
    for q_v in range(v - h, v + h + 1):
        for q_u in range(u - h, u + h + 1):
            w = 1.0 if valid[q_v, q_u] else 0.0
            m, s_x, s_y, s_z, s_xx, s_xy, s_xz, s_yy, s_yz, s_zz = add_offset(
                m,
                s_x,
                s_y,
                s_z,
                s_xx,
                s_xy,
                s_xz,
                s_yy,
                s_yz,
                s_zz,
                (P[0, q_v, q_u] - p_x) * w,
                (P[1, q_v, q_u] - p_y) * w,
                (P[2, q_v, q_u] - p_z) * w,
                w,
            )
    return m, s_x, s_y, s_z, s_xx, s_xy, s_xz, s_yy, s_yz, s_zz


@pixel
def add_offset(m, s_x, s_y, s_z, s_xx, s_xy, s_xz, s_yy, s_yz, s_zz, r_x, r_y, r_z, w):
    """The moments with one more offset r (already weighted by w): count, sums, sums of products."""
    return (
        m + w,
        s_x + r_x,
        s_y + r_y,
        s_z + r_z,
        s_xx + r_x * r_x,
        s_xy + r_x * r_y,
        s_xz + r_x * r_z,
        s_yy + r_y * r_y,
        s_yz + r_y * r_z,
        s_zz + r_z * r_z,
    )


@pixel
def characteristic(a_00, a_01, a_02, a_11, a_12, a_22):
    """(t_1, t_2, t_3): det(A - l I) = t_3 - t_2 l + t_1 l^2 - l^3 for the symmetric 3x3 matrix A."""
    t_1 = a_00 + a_11 + a_22
    t_2 = a_00 * a_11 - a_01 * a_01 + a_00 * a_22 - a_02 * a_02 + a_11 * a_22 - a_12 * a_12
    t_3 = a_00 * (a_11 * a_22 - a_12 * a_12) - a_01 * (a_01 * a_22 - a_12 * a_02) + a_02 * (a_01 * a_12 - a_11 * a_02)
    return t_1, t_2, t_3


@pixel
def newton_step(t_1, t_2, t_3, lam):
    """One Newton step on det(A - l I) at l = lam (0 where the slope is not negative)."""
    f = t_3 + lam * (-t_2 + lam * (t_1 - lam))
    f_prime = -t_2 + lam * (2.0 * t_1 - 3.0 * lam)
    return -f / f_prime if f_prime < 0.0 else 0.0


@pixel
def smallest_eigenvalue(a_00, a_01, a_02, a_11, a_12, a_22):
    """Smallest eigenvalue of the symmetric positive semi-definite 3x3 matrix A.

    Newton's method on the characteristic polynomial f(l) = det(A - l I) = t_3 - t_2 l + t_1 l^2 - l^3,
    from l = 0: all roots are real and >= 0, so f > 0 and f' < 0 left of the smallest root and
    every step is positive and lands short of it (monotone convergence, quadratic once close).
    Cheaper than the trigonometric closed form (no acos, cos) and as accurate.
    """
    t_1, t_2, t_3 = characteristic(a_00, a_01, a_02, a_11, a_12, a_22)
    lam = 0.0
    for _ in range(_NEWTON_STEPS):
        step = newton_step(t_1, t_2, t_3, lam)
        if not step > _NEWTON_TOL * lam:  # converged, or rounding says so (also stops on NaN)
            break
        lam += step
    return lam


@pixel
def null_vector(b_00, b_01, b_02, b_11, b_12, b_22):
    """Unit null vector of the (near-)singular symmetric 3x3 matrix B: the longest cross product of two rows.

    Returns (n_x, n_y, n_z, ok); ok is False when B has rank below 2 (no unique direction).
    """
    # rows (b_00, b_01, b_02), (b_01, b_11, b_12), (b_02, b_12, b_22)
    x_a, y_a, z_a = b_01 * b_12 - b_02 * b_11, b_02 * b_01 - b_00 * b_12, b_00 * b_11 - b_01 * b_01  # row0 x row1
    x_b, y_b, z_b = b_01 * b_22 - b_02 * b_12, b_02 * b_02 - b_00 * b_22, b_00 * b_12 - b_01 * b_02  # row0 x row2
    x_c, y_c, z_c = b_11 * b_22 - b_12 * b_12, b_12 * b_02 - b_01 * b_22, b_01 * b_12 - b_11 * b_02  # row1 x row2
    l_a = x_a * x_a + y_a * y_a + z_a * z_a
    l_b = x_b * x_b + y_b * y_b + z_b * z_b
    l_c = x_c * x_c + y_c * y_c + z_c * z_c
    # selects, not branches, so that loops of this vectorise
    use_b = l_b > l_a
    n_x, n_y, n_z, l = (
        (x_b if use_b else x_a),
        (y_b if use_b else y_a),
        (z_b if use_b else z_a),
        (l_b if use_b else l_a),
    )
    use_c = l_c > l
    n_x, n_y, n_z, l = (x_c if use_c else n_x), (y_c if use_c else n_y), (z_c if use_c else n_z), (l_c if use_c else l)
    ok = (l > 0.0) & (l < np.inf)  # positive and finite (false for NaN)
    norm = math.sqrt(l) if ok else 1.0
    return n_x / norm, n_y / norm, n_z / norm, ok


@pixel
def write_facing(out, v, u, n_x, n_y, n_z, ok, p_x, p_y, p_z, fill):
    """Store the unit normal at (v, u), turned to face the camera (:func:`surfnorm.kernels._rows.facing_sign`), or the fill value."""
    if ok:
        sign = facing_sign(n_x, n_y, n_z, p_x, p_y, p_z)
        out[v, u, 0] = sign * n_x
        out[v, u, 1] = sign * n_y
        out[v, u, 2] = sign * n_z
    else:
        out[v, u, 0] = fill
        out[v, u, 1] = fill
        out[v, u, 2] = fill


@pixel
def scatter(m, s_x, s_y, s_z, s_xx, s_xy, s_xz, s_yy, s_yz, s_zz):
    """S = sum (q - c)(q - c)^T about the centroid c, from the moments of the offsets r = q - p."""
    return (
        s_xx - s_x * s_x / m,
        s_xy - s_x * s_y / m,
        s_xz - s_x * s_z / m,
        s_yy - s_y * s_y / m,
        s_yz - s_y * s_z / m,
        s_zz - s_z * s_z / m,
    )


#: (t_1, t_2, t_3, g_0, g_1, g_2) of det(M - l I) = (m - l) D(l) - m l G(l) (see :func:`plane_svd_lambda`): the
#: arithmetic of :func:`surfnorm._plane_svd.plane_svd_characteristic`, which the PyTorch backend runs on tensors.
#: Its helper quadratic_form is registered with Numba as it is (inlined where it is called), so that the compiled
#: plane_svd_characteristic calls it and Python code still gets the plain function.
numba.extending.register_jitable(inline="always")(_plane_svd.quadratic_form)
plane_svd_characteristic = pixel(_plane_svd.plane_svd_characteristic)


@pixel
def plane_svd_step(m, t_1, t_2, t_3, g_0, g_1, g_2, lam):
    """One Newton step on det(M - l I) at l = lam (0 where the slope is not negative)."""
    d = t_3 + lam * (-t_2 + lam * (t_1 - lam))
    d_prime = -t_2 + lam * (2.0 * t_1 - 3.0 * lam)
    g = g_0 + lam * (g_1 + lam * g_2)
    g_prime = g_1 + 2.0 * lam * g_2
    f = (m - lam) * d - m * lam * g
    f_prime = -d + (m - lam) * d_prime - m * g - m * lam * g_prime
    return -f / f_prime if f_prime < 0.0 else 0.0


@pixel
def plane_svd_lambda(m, c_x, c_y, c_z, s_00, s_01, s_02, s_11, s_12, s_22):
    """Smallest eigenvalue of M = [Q^+, 1]^T [Q^+, 1] by Newton's method on its characteristic polynomial.

    f(l) = (m - l) D(l) - m l G(l) with D(l) = det(S - l I) = t_3 - t_2 l + t_1 l^2 - l^3 and
    G(l) = c^T adj(S - l I) c = g_0 + g_1 l + g_2 l^2. From l = 0 (f(0) = m det S >= 0) Newton's
    steps are positive and never pass the smallest root.
    """
    t_1, t_2, t_3, g_0, g_1, g_2 = plane_svd_characteristic(c_x, c_y, c_z, s_00, s_01, s_02, s_11, s_12, s_22)
    lam = 0.0
    for _ in range(_NEWTON_STEPS):
        step = plane_svd_step(m, t_1, t_2, t_3, g_0, g_1, g_2, lam)
        if not step > _NEWTON_TOL * lam:  # converged, or rounding says so (also stops on NaN)
            break
        lam += step
    return lam


_PLANE_PCA, _PLANE_SVD, _VECTOR_SVD = 0, 1, 2  # ``kind`` of the fit kernels


@pixel
def relative_moments(rel, p_x, p_y, p_z, s_x, s_y, s_z, s_xx, s_xy, s_xz, s_yy, s_yz, s_zz):
    """The window's point and moments in units of p_z / rel (``rel`` > 0: PlaneSVD in the scale-invariant mode),
    unchanged for rel = 0. PlaneSVD's fit mixes the normal with the offset d (a length), so its result depends on
    the unit of depth; measured relative to the pixel's own depth it does not, and no other pixel matters."""
    l = rel / p_z if rel > 0.0 else 1.0
    l2 = l * l
    return (
        p_x * l,
        p_y * l,
        p_z * l,
        s_x * l,
        s_y * l,
        s_z * l,
        s_xx * l2,
        s_xy * l2,
        s_xz * l2,
        s_yy * l2,
        s_yz * l2,
        s_zz * l2,
    )


@pixel
def fit_normal(kind, p_x, p_y, p_z, m, s_x, s_y, s_z, s_xx, s_xy, s_xz, s_yy, s_yz, s_zz, rel):
    """The normal of one window from its moments: PlanePCA, VectorSVD or PlaneSVD (``kind``); returns (n, ok).

    ``rel``: see :func:`relative_moments` (PlaneSVD only; the other two fits do not depend on the unit)."""
    n_x = n_y = n_z = 0.0
    if kind == _PLANE_SVD:
        p_x, p_y, p_z, s_x, s_y, s_z, s_xx, s_xy, s_xz, s_yy, s_yz, s_zz = relative_moments(
            rel, p_x, p_y, p_z, s_x, s_y, s_z, s_xx, s_xy, s_xz, s_yy, s_yz, s_zz
        )
    ok = False
    if kind == _VECTOR_SVD:  # the matrix of the offsets q - p themselves
        sigma = smallest_eigenvalue(s_xx, s_xy, s_xz, s_yy, s_yz, s_zz)
        n_x, n_y, n_z, ok = null_vector(s_xx - sigma, s_xy, s_xz, s_yy - sigma, s_yz, s_zz - sigma)
    else:
        s_00, s_01, s_02, s_11, s_12, s_22 = scatter(m, s_x, s_y, s_z, s_xx, s_xy, s_xz, s_yy, s_yz, s_zz)
        if kind == _PLANE_PCA:  # the covariance about the centroid
            sigma = smallest_eigenvalue(s_00, s_01, s_02, s_11, s_12, s_22)
            n_x, n_y, n_z, ok = null_vector(s_00 - sigma, s_01, s_02, s_11 - sigma, s_12, s_22 - sigma)
        else:  # PlaneSVD: [Q+, 1] with the offset inside the normalisation
            c_x = p_x + s_x / m  # centroid
            c_y = p_y + s_y / m
            c_z = p_z + s_z / m
            lam = plane_svd_lambda(m, c_x, c_y, c_z, s_00, s_01, s_02, s_11, s_12, s_22)
            mu = m * lam / (m - lam)
            n_x, n_y, n_z, ok = null_vector(
                s_00 - lam - mu * c_x * c_x,
                s_01 - mu * c_x * c_y,
                s_02 - mu * c_x * c_z,
                s_11 - lam - mu * c_y * c_y,
                s_12 - mu * c_y * c_z,
                s_22 - lam - mu * c_z * c_z,
            )
    return n_x, n_y, n_z, ok


@njit
def _window_fit_kernel(P, valid, h, kind, rel, fill, out, v0, v1):
    """PlanePCA, PlaneSVD or VectorSVD (``kind``) over any window, pixel by pixel (the 3x3 one has a tiled path).

    Rows v0 .. v1 - 1 (halo: h rows of the cloud)."""
    H, W = out.shape[:2]
    for o_v in range(v0, v1):
        for o_u in range(W):
            v, u = o_v + h, o_u + h  # p in the padded cloud
            ok = False
            n_x = n_y = n_z = 0.0
            if valid[v, u]:
                m, s_x, s_y, s_z, s_xx, s_xy, s_xz, s_yy, s_yz, s_zz = window_moments(P, valid, v, u, h)
                if m >= 3 and window_spans(valid, v, u, h):  # p and two other points, not on one image line
                    n_x, n_y, n_z, ok = fit_normal(
                        kind,
                        P[0, v, u],
                        P[1, v, u],
                        P[2, v, u],
                        m,
                        s_x,
                        s_y,
                        s_z,
                        s_xx,
                        s_xy,
                        s_xz,
                        s_yy,
                        s_yz,
                        s_zz,
                        rel,
                    )
            write_facing(out, o_v, o_u, n_x, n_y, n_z, ok, P[0, v, u], P[1, v, u], P[2, v, u], fill)


# ---- fast path for the 3x3 window: column tiles with a constant row pitch -------------------------
#
# LLVM vectorises a loop over pixels only if it can rule out (at run time) that its stores overwrite
# its loads; every pair of arrays, or of rows of a 2-D array (their distance is a run-time stride),
# costs one such check, and past a handful it gives up. So the cloud is laid out in column tiles of
# _TILE pixels whose rows have the constant pitch _PITCH: P_t[t, v, k, :] holds x, y, z and the
# weight w (1.0 valid, 0.0 not) of padded row v, columns c0 - 1 .. c0 + _TILE of tile t. The three
# rows around a pixel are then one block with offsets known at compile time, and so is the
# per-row scratch ``work`` (moments, polynomial coefficients, eigenvalue): each loop has one load
# and one store block. A row of a tile is swept three times: moments -> coefficients (vectorised),
# Newton steps on all pixels at once with a mask (vectorised, until none moves), null vector ->
# output (vectorised). Each pixel does the same operations in the same order as the per-pixel
# kernels above (same sums, same Newton steps, same stopping rule), so the results are the same bits.

_TILE = 128
_PITCH = 136  # >= _TILE + 2, a multiple of 8
# rows of ``work``
_M, _SX, _SY, _SZ, _S00, _S01, _S02, _S11, _S12, _S22 = 0, 1, 2, 3, 4, 5, 6, 7, 8, 9
_T1, _T2, _T3, _G0, _G1, _G2, _LAM, _ACT, _SPANS = 10, 11, 12, 13, 14, 15, 16, 17, 18
_WORK_ROWS = 19


@njit
def _tiled_cloud_kernel(z, valid, f_x, f_y, c_x, c_y, P_t, v0, v1):
    """The point cloud of eq. 3 (as :func:`_point_cloud_kernel`, same arithmetic) in the tiled layout.

    Image rows v0 .. v1 - 1 (the first band also writes the top padded row, the last the bottom one)."""
    H, W = z.shape
    n_tiles = P_t.shape[0]
    x_ray = np.empty(W + 2)
    for j in range(W + 2):
        x_ray[j] = (j - 1 - c_x) / f_x
    for t in range(n_tiles):
        c0 = t * _TILE
        n = min(W - c0, _TILE) + 2  # padded columns c0 - 1 .. c0 + n - 2 of the image
        for pv in range(v0 + 1 if v0 > 0 else 0, v1 + 1 if v1 < H else H + 2):
            row = P_t[t, pv]
            v = pv - 1
            row[:, :] = 0.0
            if v < 0 or v >= H:
                continue
            y_ray = (v - c_y) / f_y
            for j in range(n):
                u = c0 - 1 + j
                if u >= 0 and u < W and valid[v, u]:
                    d = np.float64(z[v, u])
                    row[0, j] = d * x_ray[c0 + j]
                    row[1, j] = d * y_ray
                    row[2, j] = d
                    row[3, j] = 1.0


@pixel
def tile_moments(R, i):
    """window_moments of pixel i of a tile row: R is the flat block of the three padded rows around it."""
    c = 4 * _PITCH + i + 1  # the pixel itself: row 1, padded column i + 1
    p_x, p_y, p_z = R[c], R[c + _PITCH], R[c + 2 * _PITCH]
    m = 0.0
    s_x = s_y = s_z = 0.0
    s_xx = s_xy = s_xz = s_yy = s_yz = s_zz = 0.0
    s_u = s_v = s_uu = s_uv = s_vv = 0.0  # the pixel offsets, for pixel_spread
    for r in range(3):
        for d_u in range(3):
            q = 4 * r * _PITCH + i + d_u
            w = R[q + 3 * _PITCH]
            m, s_x, s_y, s_z, s_xx, s_xy, s_xz, s_yy, s_yz, s_zz = add_offset(
                m,
                s_x,
                s_y,
                s_z,
                s_xx,
                s_xy,
                s_xz,
                s_yy,
                s_yz,
                s_zz,
                (R[q] - p_x) * w,
                (R[q + _PITCH] - p_y) * w,
                (R[q + 2 * _PITCH] - p_z) * w,
                w,
            )
            o_u, o_v = np.float64(d_u - 1), np.float64(r - 1)
            s_u += w * o_u
            s_v += w * o_v
            s_uu += w * (o_u * o_u)
            s_uv += w * (o_u * o_v)
            s_vv += w * (o_v * o_v)
    spans = pixel_spread(m, s_u, s_v, s_uu, s_uv, s_vv) > 0.0
    return m, s_x, s_y, s_z, s_xx, s_xy, s_xz, s_yy, s_yz, s_zz, p_x, p_y, p_z, R[c + 3 * _PITCH], spans


@pixel
def tile_prepare(R, n, kind, rel, work):
    """Sweep 1: moments, scatter matrix, coefficients of the characteristic polynomial, start of Newton."""
    for i in range(n):
        m, s_x, s_y, s_z, s_xx, s_xy, s_xz, s_yy, s_yz, s_zz, p_x, p_y, p_z, w_p, spans = tile_moments(R, i)
        if kind == _PLANE_SVD:
            p_x, p_y, p_z, s_x, s_y, s_z, s_xx, s_xy, s_xz, s_yy, s_yz, s_zz = relative_moments(
                rel, p_x, p_y, p_z, s_x, s_y, s_z, s_xx, s_xy, s_xz, s_yy, s_yz, s_zz
            )
        if kind == _VECTOR_SVD:  # the matrix of the offsets q - p themselves
            s_00, s_01, s_02, s_11, s_12, s_22 = s_xx, s_xy, s_xz, s_yy, s_yz, s_zz
        else:
            s_00, s_01, s_02, s_11, s_12, s_22 = scatter(m, s_x, s_y, s_z, s_xx, s_xy, s_xz, s_yy, s_yz, s_zz)
        if kind == _PLANE_SVD:
            c_x = p_x + s_x / m  # centroid
            c_y = p_y + s_y / m
            c_z = p_z + s_z / m
            t_1, t_2, t_3, g_0, g_1, g_2 = plane_svd_characteristic(c_x, c_y, c_z, s_00, s_01, s_02, s_11, s_12, s_22)
            work[_G0 * _PITCH + i] = g_0
            work[_G1 * _PITCH + i] = g_1
            work[_G2 * _PITCH + i] = g_2
        else:
            t_1, t_2, t_3 = characteristic(s_00, s_01, s_02, s_11, s_12, s_22)
        work[_M * _PITCH + i] = m
        work[_SX * _PITCH + i] = s_x
        work[_SY * _PITCH + i] = s_y
        work[_SZ * _PITCH + i] = s_z
        work[_S00 * _PITCH + i] = s_00
        work[_S01 * _PITCH + i] = s_01
        work[_S02 * _PITCH + i] = s_02
        work[_S11 * _PITCH + i] = s_11
        work[_S12 * _PITCH + i] = s_12
        work[_S22 * _PITCH + i] = s_22
        work[_T1 * _PITCH + i] = t_1
        work[_T2 * _PITCH + i] = t_2
        work[_T3 * _PITCH + i] = t_3
        work[_LAM * _PITCH + i] = 0.0
        work[_ACT * _PITCH + i] = 1.0 if (w_p != 0.0) & (m >= 3) & spans else 0.0
        work[_SPANS * _PITCH + i] = 1.0 if spans else 0.0


@pixel
def tile_newton(n, kind, work):
    """Sweep 2: Newton steps from 0 for every pixel still moving, with the per-pixel stopping rule."""
    for _ in range(_NEWTON_STEPS):
        moving = 0
        for i in range(n):
            lam = work[_LAM * _PITCH + i]
            if kind == _PLANE_SVD:
                step = plane_svd_step(
                    work[_M * _PITCH + i],
                    work[_T1 * _PITCH + i],
                    work[_T2 * _PITCH + i],
                    work[_T3 * _PITCH + i],
                    work[_G0 * _PITCH + i],
                    work[_G1 * _PITCH + i],
                    work[_G2 * _PITCH + i],
                    lam,
                )
            else:
                step = newton_step(work[_T1 * _PITCH + i], work[_T2 * _PITCH + i], work[_T3 * _PITCH + i], lam)
            go = (work[_ACT * _PITCH + i] != 0.0) & (step > _NEWTON_TOL * lam)
            work[_LAM * _PITCH + i] = lam + step if go else lam
            work[_ACT * _PITCH + i] = 1.0 if go else 0.0
            moving += np.int64(go)
        if moving == 0:
            break


@pixel
def tile_finish(R, n, kind, rel, fill, work, out_flat):
    """Sweep 3: the normal (null vector of the shifted matrix), facing the camera, or the fill value."""
    for i in range(n):
        c = 4 * _PITCH + i + 1
        p_x, p_y, p_z, w_p = R[c], R[c + _PITCH], R[c + 2 * _PITCH], R[c + 3 * _PITCH]
        m = work[_M * _PITCH + i]
        lam = work[_LAM * _PITCH + i]
        s_00, s_01, s_02 = work[_S00 * _PITCH + i], work[_S01 * _PITCH + i], work[_S02 * _PITCH + i]
        s_11, s_12, s_22 = work[_S11 * _PITCH + i], work[_S12 * _PITCH + i], work[_S22 * _PITCH + i]
        if kind == _PLANE_SVD:
            l = rel / p_z if rel > 0.0 else 1.0  # as relative_moments (the sums in work are already scaled)
            c_x = p_x * l + work[_SX * _PITCH + i] / m  # centroid
            c_y = p_y * l + work[_SY * _PITCH + i] / m
            c_z = p_z * l + work[_SZ * _PITCH + i] / m
            mu = m * lam / (m - lam)
            n_x, n_y, n_z, ok = null_vector(
                s_00 - lam - mu * c_x * c_x,
                s_01 - mu * c_x * c_y,
                s_02 - mu * c_x * c_z,
                s_11 - lam - mu * c_y * c_y,
                s_12 - mu * c_y * c_z,
                s_22 - lam - mu * c_z * c_z,
            )
        else:
            n_x, n_y, n_z, ok = null_vector(s_00 - lam, s_01, s_02, s_11 - lam, s_12, s_22 - lam)
        ok = ok & (w_p != 0.0) & (m >= 3) & (work[_SPANS * _PITCH + i] != 0.0)
        sign = facing_sign(n_x, n_y, n_z, p_x, p_y, p_z)
        n_x = sign * n_x
        n_y = sign * n_y
        n_z = sign * n_z
        out_flat[3 * i] = np.float32(n_x) if ok else fill
        out_flat[3 * i + 1] = np.float32(n_y) if ok else fill
        out_flat[3 * i + 2] = np.float32(n_z) if ok else fill


@njit
def _tiled_fit_kernel(P_t, kind, rel, fill, out, v0, v1):
    """PlanePCA, PlaneSVD or VectorSVD (``kind``) over the 3x3 window, from the tiled cloud; rows v0 .. v1 - 1."""
    H, W = out.shape[:2]
    n_tiles = P_t.shape[0]
    flat = P_t.reshape(P_t.size)
    tile_size = (H + 2) * 4 * _PITCH
    work = np.empty(_WORK_ROWS * _PITCH)
    for t in range(n_tiles):
        c0 = t * _TILE
        n = min(W - c0, _TILE)
        for o_v in range(v0, v1):
            start = t * tile_size + o_v * 4 * _PITCH  # padded rows o_v .. o_v + 2
            R = flat[start : start + 12 * _PITCH]
            tile_prepare(R, n, kind, rel, work)
            tile_newton(n, kind, work)
            out_flat = out[o_v].reshape(3 * W)[3 * c0 : 3 * (c0 + n)]
            tile_finish(R, n, kind, rel, fill, work, out_flat)


def tiled_cloud(z, valid, cam, bands=whole):
    """The cloud of :func:`point_cloud` (pad 1) in the tiled layout of the 3x3 fast path, with weights."""
    H, W = z.shape
    P_t = np.empty((-(-W // _TILE), H + 2, 4, _PITCH), dtype=np.float64)
    f = (float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy))
    bands(lambda a, b: _tiled_cloud_kernel(z, valid, *f, P_t, a, b), H)
    return P_t


def _run_fit(kind, z, valid, cam, out, window, fill, relative=0.0, bands=whole):
    # Two stages (the cloud, then the fits, which read the cloud's rows around theirs), each in row bands.
    H, fill32, rel = z.shape[0], np.float32(fill), float(relative)
    if int(window) == 3 and out.flags.c_contiguous:
        P_t = tiled_cloud(z, valid, cam, bands)
        bands(lambda a, b: _tiled_fit_kernel(P_t, kind, rel, fill32, out, a, b), H)
        return out
    # A window wider than the frame holds no more pixels than one of half-width max(H, W) - 1 (every pixel of
    # the frame from any pixel), so it is clipped to that: the same normals, at a cost bounded by the frame
    # (window=4001 on a 48x64 frame took 145 s and 534 MB; window=1000001 asked for 21.8 TiB).
    h = min(int(window) // 2, max(z.shape) - 1)
    P, P_valid = point_cloud(z, valid, cam, pad=h, bands=bands)
    bands(lambda a, b: _window_fit_kernel(P, P_valid, h, kind, rel, fill32, out, a, b), H)
    return out


def plane_svd(z, valid, cam, out, *, window=3, fill=0.0, relative=0.0, bands=whole):
    """PlaneSVD (Table I): smallest right singular vector b = [n; d] of [Q^+, 1] over a window x window patch.

    ``relative`` > 0 (the scale-invariant mode): each window's points in units of its pixel's depth / relative
    (:func:`relative_moments`), so that the fit does not depend on the unit of depth.
    ``bands``: how rows are split over threads (see :mod:`surfnorm._bands`)."""
    return _run_fit(_PLANE_SVD, z, valid, cam, out, window, fill, relative, bands)


def plane_pca(z, valid, cam, out, *, window=3, fill=0.0, bands=whole):
    """PlanePCA (Table I): smallest eigenvector of the covariance of Q^+ about its centroid."""
    return _run_fit(_PLANE_PCA, z, valid, cam, out, window, fill, bands=bands)


def vector_svd(z, valid, cam, out, *, window=3, fill=0.0, bands=whole):
    """VectorSVD (Table I): smallest right singular vector of the matrix of the vectors q - p."""
    return _run_fit(_VECTOR_SVD, z, valid, cam, out, window, fill, bands=bands)
