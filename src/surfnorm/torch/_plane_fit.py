"""PlaneSVD, PlanePCA and VectorSVD on tensors (the twins of ``surfnorm.kernels.plane_fit``).

Per pixel p, the moments of the offsets r = q - p of the valid points q of
the window (p included) are summed over shifted views of the float64 point
cloud (one view per window offset, in the NumPy kernel's order), which gives
the 3x3 matrix of each fit:

* VectorSVD: sum r r^T;
* PlanePCA: the scatter matrix S = sum (q - c)(q - c)^T about the centroid c;
* PlaneSVD: M = [Q+, 1]^T [Q+, 1] (4x4), built as [[S + m c c^T, m c], [m c^T, m]].

Their smallest eigenvalue comes from the NumPy kernel's Newton iteration on
the characteristic polynomial (4x4 for PlaneSVD, through the quartic in S and
c), run on all pixels at once (:func:`smallest_root`); the normal is the null
vector of the shifted matrix: the longest cross product of two of its rows,
as there. A batched eigen-solver (``torch.linalg.eigvalsh``) was tried first
and left: it is not more accurate where it matters, and it differs from the
NumPy backend by up to 1.6 per component on windows with one far point (a
silhouette pixel whose window holds one foreground and eight background
points), where the 3x3 problem is so ill-conditioned that rounding picks the
normal; it was also slower on the CPU (0.34 s per 480x640 frame for the
eigenvalues alone). Normals face the camera; the fill value where p is
invalid, fewer than 3 points are valid in its window, or they fix no plane
(the rows' cross products all vanish). Differentiable: the gradient of the
root is that of one Newton step at the root, and the cross products are
polynomials.
"""

from __future__ import annotations

import torch

from .._constants import NEWTON_STEPS, NEWTON_TOL
from .._plane_svd import plane_svd_characteristic
from ._averaging import point_cloud, ring_offsets
from ._ops import Grid, facing_sign

# As surfnorm.kernels.plane_fit: one source, in modules that load no Numba.
_NEWTON_STEPS, _NEWTON_TOL = NEWTON_STEPS, NEWTON_TOL


def window_moments(P, valid, window: int):
    """m and the sums of r and r r^T over the window (``plane_fit.window_moments``), each (B, H, W) float64,
    and whether the valid pixels do not all lie on one image line (``plane_fit.window_spans``)."""
    h = window // 2
    at = ring_offsets(P, valid, h)
    p = P.unbind(1)
    zero = torch.zeros_like(p[0])
    m = s_x = s_y = s_z = s_xx = s_xy = s_xz = s_yy = s_yz = s_zz = zero
    s_u = s_v = s_uu = s_uv = s_vv = zero  # the pixel offsets (small integers: exact in float64)
    for dv in range(-h, h + 1):
        for du in range(-h, h + 1):
            q, ok = at(dv, du)
            w = ok.to(P.dtype)
            r_x, r_y, r_z = ((q_c - p_c) * w for q_c, p_c in zip(q.unbind(1), p))
            m = m + w
            s_x, s_y, s_z = s_x + r_x, s_y + r_y, s_z + r_z
            s_xx, s_xy, s_xz = s_xx + r_x * r_x, s_xy + r_x * r_y, s_xz + r_x * r_z
            s_yy, s_yz, s_zz = s_yy + r_y * r_y, s_yz + r_y * r_z, s_zz + r_z * r_z
            s_u, s_v = s_u + w * du, s_v + w * dv
            s_uu, s_uv, s_vv = s_uu + w * (du * du), s_uv + w * (du * dv), s_vv + w * (dv * dv)
    spread = (m * s_uu - s_u * s_u) * (m * s_vv - s_v * s_v) - (m * s_uv - s_u * s_v) ** 2
    return m, (s_x, s_y, s_z), (s_xx, s_xy, s_xz, s_yy, s_yz, s_zz), spread > 0.0


def smallest_root(step, coefficients, active):
    """The smallest eigenvalue by the NumPy kernel's Newton iteration (``plane_fit.smallest_eigenvalue``).

    ``step(*coefficients, lam)`` is one Newton step on the characteristic polynomial, whose
    coefficients are (B, H, W) tensors. From 0, every pixel steps while its step exceeds
    _NEWTON_TOL * lam, at most _NEWTON_STEPS times: the same rule and arithmetic as the NumPy
    kernel, so the same root even where rounding decides it (a window with one far point: the
    polynomial's coefficients cancel badly there, and an eigen-solver lands elsewhere). The
    iteration runs without a graph; the result carries the gradient of the root through one more
    step taken with the graph (at a root, d(step)/dA = -(df/dA) / f', the derivative of the root,
    while the step's value, ~0, is left out).

    On the CPU the pixels still moving are gathered after each step (after two steps about one in
    seven is, on the sample frames, and none after 16), and the loop ends when none is left; on
    another device all _NEWTON_STEPS steps run on every pixel, so that nothing waits for the device.
    """
    with torch.no_grad():
        lam = torch.zeros(active.shape, dtype=torch.float64, device=active.device)
        if lam.device.type == "cpu":
            flat = lam.view(-1)
            idx = active.reshape(-1).nonzero().squeeze(1)
            sub = [c.detach().reshape(-1)[idx] for c in coefficients]
            lam_sub = torch.zeros(idx.shape, dtype=torch.float64)
            for _ in range(_NEWTON_STEPS):
                d = step(*sub, lam_sub)
                moving = d > _NEWTON_TOL * lam_sub  # also stops on NaN
                lam_sub = torch.where(moving, lam_sub + d, lam_sub)
                if not bool(moving.all()):
                    flat[idx] = lam_sub
                    keep = moving.nonzero().squeeze(1)
                    idx, lam_sub, sub = idx[keep], lam_sub[keep], [c[keep] for c in sub]
                    if idx.numel() == 0:
                        break
            flat[idx] = lam_sub
        else:
            moving = active.clone()
            for _ in range(_NEWTON_STEPS):
                d = step(*coefficients, lam)
                moving = moving & (d > _NEWTON_TOL * lam)
                lam = torch.where(moving, lam + d, lam)
    d = step(*coefficients, lam)
    return lam + (d - d.detach())


def newton_step(t_1, t_2, t_3, lam):
    """``plane_fit.newton_step``: one Newton step on det(A - l I) = t_3 - t_2 l + t_1 l^2 - l^3 (0 where the slope is not negative)."""
    f = t_3 + lam * (-t_2 + lam * (t_1 - lam))
    f_prime = -t_2 + lam * (2.0 * t_1 - 3.0 * lam)
    ok = f_prime < 0.0
    return torch.where(ok, -f / torch.where(ok, f_prime, -torch.ones_like(f_prime)), torch.zeros_like(f))


def characteristic(a_00, a_01, a_02, a_11, a_12, a_22):
    """``plane_fit.characteristic``: (t_1, t_2, t_3) of the symmetric 3x3 matrix."""
    t_1 = a_00 + a_11 + a_22
    t_2 = a_00 * a_11 - a_01 * a_01 + a_00 * a_22 - a_02 * a_02 + a_11 * a_22 - a_12 * a_12
    t_3 = a_00 * (a_11 * a_22 - a_12 * a_12) - a_01 * (a_01 * a_22 - a_12 * a_02) + a_02 * (a_01 * a_12 - a_11 * a_02)
    return t_1, t_2, t_3


def plane_svd_step(m, t_1, t_2, t_3, g_0, g_1, g_2, lam):
    """``plane_fit.plane_svd_step``: one Newton step on det(M - l I) at l = lam (0 where the slope is not negative)."""
    d = t_3 + lam * (-t_2 + lam * (t_1 - lam))
    d_prime = -t_2 + lam * (2.0 * t_1 - 3.0 * lam)
    g = g_0 + lam * (g_1 + lam * g_2)
    g_prime = g_1 + 2.0 * lam * g_2
    f = (m - lam) * d - m * lam * g
    f_prime = -d + (m - lam) * d_prime - m * g - m * lam * g_prime
    ok = f_prime < 0.0
    return torch.where(ok, -f / torch.where(ok, f_prime, -torch.ones_like(f_prime)), torch.zeros_like(f))


def _longer(a, b):
    """(x, y, z, squared length) of ``a`` where it is longer than ``b`` (element-wise), else of ``b``."""
    use_a = a[3] > b[3]
    return tuple(torch.where(use_a, p, q) for p, q in zip(a, b))


def null_vector(b_00, b_01, b_02, b_11, b_12, b_22):
    """``plane_fit.null_vector``: the longest cross product of two rows of B, unit; and whether B has rank 2."""
    x_a, y_a, z_a = b_01 * b_12 - b_02 * b_11, b_02 * b_01 - b_00 * b_12, b_00 * b_11 - b_01 * b_01  # row0 x row1
    x_b, y_b, z_b = b_01 * b_22 - b_02 * b_12, b_02 * b_02 - b_00 * b_22, b_00 * b_12 - b_01 * b_02  # row0 x row2
    x_c, y_c, z_c = b_11 * b_22 - b_12 * b_12, b_12 * b_02 - b_01 * b_22, b_01 * b_12 - b_11 * b_02  # row1 x row2
    l_a = x_a * x_a + y_a * y_a + z_a * z_a
    l_b = x_b * x_b + y_b * y_b + z_b * z_b
    l_c = x_c * x_c + y_c * y_c + z_c * z_c
    n_x, n_y, n_z, l = _longer((x_b, y_b, z_b, l_b), (x_a, y_a, z_a, l_a))
    n_x, n_y, n_z, l = _longer((x_c, y_c, z_c, l_c), (n_x, n_y, n_z, l))
    ok = (l > 0.0) & (l < float("inf"))
    norm = torch.sqrt(torch.where(ok, l, torch.ones_like(l)))
    return n_x / norm, n_y / norm, n_z / norm, ok


def _fit(kind: str, g: Grid, cam, window: int, fill: float):
    P = point_cloud(g, cam)
    window = min(window, 2 * max(g.valid.shape[-2:]) - 1)  # wider holds no more pixels (as the NumPy kernel)
    m, (s_x, s_y, s_z), R, spans = window_moments(P, g.valid, window)
    active = g.valid & (m >= 3) & spans  # p and at least two other points, not all on one image line
    m_safe = torch.where(active, m, torch.ones_like(m))
    p_x, p_y, p_z = P.unbind(1)
    if kind == "vector_svd":  # the matrix of the offsets q - p themselves
        S = R
    else:  # the scatter about the centroid (plane_fit.scatter)
        s_xx, s_xy, s_xz, s_yy, s_yz, s_zz = R
        S = (
            s_xx - s_x * s_x / m_safe,
            s_xy - s_x * s_y / m_safe,
            s_xz - s_x * s_z / m_safe,
            s_yy - s_y * s_y / m_safe,
            s_yz - s_y * s_z / m_safe,
            s_zz - s_z * s_z / m_safe,
        )
    if kind == "plane_svd":
        c = (p_x + s_x / m_safe, p_y + s_y / m_safe, p_z + s_z / m_safe)  # centroid
        coefficients = plane_svd_characteristic(*c, *S)
        lam = smallest_root(plane_svd_step, (m_safe,) + coefficients, active)
        mu = m_safe * lam / (m_safe - lam)
        s_00, s_01, s_02, s_11, s_12, s_22 = S
        c_x, c_y, c_z = c
        n_x, n_y, n_z, ok = null_vector(
            s_00 - lam - mu * c_x * c_x,
            s_01 - mu * c_x * c_y,
            s_02 - mu * c_x * c_z,
            s_11 - lam - mu * c_y * c_y,
            s_12 - mu * c_y * c_z,
            s_22 - lam - mu * c_z * c_z,
        )
    else:
        t = characteristic(*S)
        lam = smallest_root(newton_step, t, active)
        s_00, s_01, s_02, s_11, s_12, s_22 = S
        n_x, n_y, n_z, ok = null_vector(s_00 - lam, s_01, s_02, s_11 - lam, s_12, s_22 - lam)
    ok = ok & active
    sign = facing_sign(n_x, n_y, n_z, p_x, p_y, p_z)  # surfnorm.kernels._rows.facing_sign's rule
    n = torch.stack((sign * n_x, sign * n_y, sign * n_z), dim=1)
    return torch.where(ok.unsqueeze(1), n, torch.full_like(n, fill)).to(g.z.dtype)


def plane_svd(g: Grid, cam, *, window: int, fill: float):
    """PlaneSVD (Table I): smallest right singular vector b = [n; d] of [Q^+, 1] over a window x window patch."""
    return _fit("plane_svd", g, cam, window, fill)


def plane_pca(g: Grid, cam, *, window: int, fill: float):
    """PlanePCA (Table I): smallest eigenvector of the covariance of Q^+ about its centroid."""
    return _fit("plane_pca", g, cam, window, fill)


def vector_svd(g: Grid, cam, *, window: int, fill: float):
    """VectorSVD (Table I): smallest right singular vector of the matrix of the vectors q - p."""
    return _fit("vector_svd", g, cam, window, fill)
