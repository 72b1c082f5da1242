"""PlaneSVD's characteristic polynomial, written once for both backends.

:func:`plane_svd_characteristic` is plain arithmetic (additions and multiplications, in a fixed order), so the
same function runs on floats inside the Numba kernels (:mod:`surfnorm.kernels.plane_fit` compiles it, inlined)
and on tensors in :mod:`surfnorm.torch._plane_fit`. Loads no Numba (:mod:`surfnorm.kernels.plane_fit` registers
:func:`quadratic_form`, which it calls, with Numba).
"""

from __future__ import annotations


def quadratic_form(a_00, a_01, a_02, a_11, a_12, a_22, c_x, c_y, c_z):
    """c^T A c for the symmetric 3x3 matrix A (its upper triangle a_ij)."""
    return (
        a_00 * c_x * c_x
        + a_11 * c_y * c_y
        + a_22 * c_z * c_z
        + 2.0 * (a_01 * c_x * c_y + a_02 * c_x * c_z + a_12 * c_y * c_z)
    )


def plane_svd_characteristic(c_x, c_y, c_z, s_00, s_01, s_02, s_11, s_12, s_22):
    """(t_1, t_2, t_3, g_0, g_1, g_2) of det(M - l I) = (m - l) D(l) - m l G(l) (see :func:`plane_svd_lambda`)."""
    t_1 = s_00 + s_11 + s_22
    t_2 = s_00 * s_11 - s_01 * s_01 + s_00 * s_22 - s_02 * s_02 + s_11 * s_22 - s_12 * s_12
    a_00, a_11, a_22 = s_11 * s_22 - s_12 * s_12, s_00 * s_22 - s_02 * s_02, s_00 * s_11 - s_01 * s_01  # adj(S)
    a_01, a_02, a_12 = s_02 * s_12 - s_01 * s_22, s_01 * s_12 - s_02 * s_11, s_01 * s_02 - s_00 * s_12
    t_3 = s_00 * a_00 + s_01 * a_01 + s_02 * a_02
    g_0 = quadratic_form(a_00, a_01, a_02, a_11, a_12, a_22, c_x, c_y, c_z)
    c_c = c_x * c_x + c_y * c_y + c_z * c_z
    c_s_c = quadratic_form(s_00, s_01, s_02, s_11, s_12, s_22, c_x, c_y, c_z)
    g_1 = c_s_c - t_1 * c_c
    g_2 = c_c
    return t_1, t_2, t_3, g_0, g_1, g_2
