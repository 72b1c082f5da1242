"""Three-Filters-to-Normal (3F2N) and the surface normal estimator of SNE-RoadSeg.

3F2N (Fan et al., "Three-Filters-to-Normal: An Accurate and Ultrafast Surface
Normal Estimator", RA-L 2021). On a plane n . P = d the inverse depth
D = 1/Z is affine in the pixel coordinates, and (eq. 7-9 of the paper)

    n_x = f_x dD/du,    n_y = f_y dD/dv                       (the two gradient filters)

up to the common factor 1/d. The third component follows from each of the
8 neighbours q of p, whose difference vector (dX, dY, dZ) = P_p - P_q lies in
the tangent plane:

    n_z,q = -(n_x dX + n_y dY) / dZ                           (eq. 10)

and the third filter fuses them: n_z = mean or median of the n_z,q (eq. 11).
The method works in float64, as the authors' code does; its gradients use
inverse depth, whose differences cancel badly in float32 (up to 0.04 degrees
of e_A on the 3F2N sample).

Because f_x dX = u_p Z_p - u_q Z_q (with u centred on the principal point),
n_x dX = dD/du (u_p Z_p - u_q Z_q) and the focal lengths drop out of eq. 10;
the kernels use that form. Details of the authors' code that we follow:

* a neighbour with dZ == 0 exactly gives no candidate (no inf, no epsilon);
* the median of an even number of candidates is the mean of the middle two;
* where no candidate is left, or both gradients are exactly 0, the normal is
  (0, 0, -1), the fronto-parallel one;
* with ``border="reflect"`` the image border behaves as OpenCV's
  BORDER_REFLECT_101, as in the authors' code: the gradient across the border
  is 0 and the mirrored neighbour counts as a second candidate. Our default,
  ``"one-sided"``, takes one-sided differences there and leaves out-of-image
  neighbours out.

The raw 3F2N normal points away from the camera (n . P = +1 on a plane); we
flip each normal so that n . P < 0, which changes no folded angular error.

Invalid depth is never read: an invalid neighbour gives no candidate, a
gradient falls back to the one-sided difference beside a gap, and a pixel
with no usable neighbour along an axis gets the fill value.

SNE-RoadSeg's estimator (Fan, Wang, Cai, Liu, "SNE-RoadSeg: Incorporating
Surface Normal Information into Semantic Segmentation for Accurate Freespace
Detection", ECCV 2020, Sec. 3.1) starts like 3F2N (same n_x, n_y, same
neighbour candidates) but fuses differently: the azimuth
phi = arctan(n_y / n_x) is fixed by the gradients, each candidate
n_i = (n_x, n_y, n_z,i) is normalised, the unit vectors are summed to S, and
the polar angle is theta = arctan((S_x cos phi + S_y sin phi) / S_z); the
normal is (sin theta cos phi, sin theta sin phi, cos theta). The authors'
PyTorch code writes n_z,i without the minus sign and negates theta instead,
which is the same thing. It is a road-scene module, and its released code
has road-only steps that we leave out, so that the estimator works on any
scene: it zeroes every row above the principal point (Y <= 0, the sky side
for a road camera), which on the 3F2N objects leaves most pixels without a
normal; it divides Y by f_x where the pinhole model (and its own X) uses
f_y; it zero-pads at the image border; and it flips normals so that n_y <= 0
("up" for a road) where we make them face the camera.
"""

from __future__ import annotations

import math

import numpy as np

from ._config import njit, pixel
from .gradients import stencil, usable
from .translate import write_unit

__all__ = ["three_filters", "sne_roadseg", "THIRD_FILTERS"]

#: The third filter of 3F2N (eq. 11).
THIRD_FILTERS = ("mean", "median")

# The 8 neighbours (dv, du) of a pixel.
_NEIGHBOURS = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


@pixel
def inverse_depth_gradient(z, valid, v, u, dv, du, reflect):
    """dD/du (or dD/dv) of D = 1/Z at (v, u) in float64: central, one-sided beside a gap.

    Returns (gradient, ok). With ``reflect`` the gradient across the image
    border is 0 (OpenCV BORDER_REFLECT_101), as in the authors' code.
    """
    vb, ub, vf, uf, dist = stencil(valid, v, u, dv, du, reflect)
    grad = (1.0 / np.float64(z[vf, uf]) - 1.0 / np.float64(z[vb, ub])) / max(dist, 1)
    return grad, dist > 0


@pixel
def neighbour_pixel(valid, v, u, dv, du, reflect):
    """The pixel that stands for neighbour (v + dv, u + du), and whether it is usable.

    Outside the image it is the mirror image across the border with
    ``reflect`` (BORDER_REFLECT_101), else unusable; an invalid pixel is unusable.
    """
    H, W = valid.shape
    q_v = v + dv
    q_u = u + du
    if reflect:
        if q_v < 0:
            q_v = -q_v
        elif q_v >= H:
            q_v = 2 * (H - 1) - q_v
        if q_u < 0:
            q_u = -q_u
        elif q_u >= W:
            q_u = 2 * (W - 1) - q_u
    ok = usable(valid, q_v, q_u)
    return q_v, q_u, ok


@pixel
def candidate_nz(z, v, u, q_v, q_u, g_u, g_v, c_x, c_y, zx_p, zy_p, z_p):
    """n_z,q of eq. 10 (times 1/d), and whether it exists (dZ != 0).

    ``zx_p = (u - c_x) Z_p``, ``zy_p = (v - c_y) Z_p``; the focal lengths cancel.
    """
    z_q = np.float64(z[q_v, q_u])
    d_z = z_p - z_q
    nz = -(g_u * (zx_p - (q_u - c_x) * z_q) + g_v * (zy_p - (q_v - c_y) * z_q)) / d_z
    return nz, d_z != 0.0


@pixel
def camera_facing(n_x, n_y, n_z, u_c, v_c, f_x, f_y):
    """(n_x, n_y, n_z) turned, if needed, so that n . P < 0 (P = Z (u_c / f_x, v_c / f_y, 1))."""
    s = 1.0
    if n_x * (u_c / f_x) + n_y * (v_c / f_y) + n_z > 0.0:
        s = -1.0
    return s * n_x, s * n_y, s * n_z


@pixel
def fronto_parallel_fallback(n_x, n_y, n_z, count):
    """The authors' fallbacks: no candidate -> n_x = n_y = 0; then n_x = n_y = 0 -> n_z = -1."""
    if count == 0:
        n_x = 0.0
        n_y = 0.0
    if n_x == 0.0 and n_y == 0.0:
        n_z = -1.0
    return n_x, n_y, n_z


@pixel
def median_nz(z, valid, v, u, g_u, g_v, c_x, c_y, reflect, buf):
    """Median of the candidates n_z,q over the usable neighbours (eq. 11), and their count.

    Candidates are kept sorted in ``buf`` (8 entries) by insertion as they come.
    """
    z_p = np.float64(z[v, u])
    zx_p = (u - c_x) * z_p
    zy_p = (v - c_y) * z_p
    count = 0
    for k in range(8):
        dv, du = _NEIGHBOURS[k]
        q_v, q_u, ok = neighbour_pixel(valid, v, u, dv, du, reflect)
        if ok:
            nz, ok = candidate_nz(z, v, u, q_v, q_u, g_u, g_v, c_x, c_y, zx_p, zy_p, z_p)
            if ok:
                j = count
                while j > 0 and buf[j - 1] > nz:
                    buf[j] = buf[j - 1]
                    j -= 1
                buf[j] = nz
                count += 1
    half = count // 2
    med = np.nan
    if count > 0:
        if count % 2 == 1:
            med = buf[half]
        else:
            med = (buf[half - 1] + buf[half]) / 2.0
    return med, count


@pixel
def mean_nz(z, valid, v, u, g_u, g_v, c_x, c_y, reflect):
    """Mean of the candidates n_z,q over the usable neighbours (eq. 11), and their count."""
    z_p = np.float64(z[v, u])
    zx_p = (u - c_x) * z_p
    zy_p = (v - c_y) * z_p
    total = 0.0
    count = 0
    for k in range(8):
        dv, du = _NEIGHBOURS[k]
        q_v, q_u, ok = neighbour_pixel(valid, v, u, dv, du, reflect)
        if ok:
            nz, ok = candidate_nz(z, v, u, q_v, q_u, g_u, g_v, c_x, c_y, zx_p, zy_p, z_p)
            if ok:
                total += nz
                count += 1
    return total / max(count, 1), count


@pixel
def fill_pixel(out, v, u, fill):
    out[v, u, 0] = fill
    out[v, u, 1] = fill
    out[v, u, 2] = fill


@pixel
def all_nine_valid(valid, v, u):
    """True if (v, u) and its 8 neighbours lie inside the image and are valid (the fast path)."""
    H, W = valid.shape
    ok = False
    if v >= 1 and v < H - 1 and u >= 1 and u < W - 1:
        ok = (valid[v - 1, u - 1] and valid[v - 1, u] and valid[v - 1, u + 1] and valid[v, u - 1]
              and valid[v, u] and valid[v, u + 1] and valid[v + 1, u - 1] and valid[v + 1, u] and valid[v + 1, u + 1])
    return ok


@pixel
def nz_or_inf(z_q, uq_c, vq_c, g_u, g_v, zx_p, zy_p, z_p):
    """n_z,q of eq. 10 (as :func:`candidate_nz`), +inf where dZ == 0 (no candidate)."""
    d_z = z_p - z_q
    nz = -(g_u * (zx_p - uq_c * z_q) + g_v * (zy_p - vq_c * z_q)) / d_z
    return nz if d_z != 0.0 else np.inf


@pixel
def sort8(a0, a1, a2, a3, a4, a5, a6, a7):
    """The 8 values in ascending order: an optimal 19-comparator sorting network, branch-free min/max."""
    a0, a2 = min(a0, a2), max(a0, a2)
    a1, a3 = min(a1, a3), max(a1, a3)
    a4, a6 = min(a4, a6), max(a4, a6)
    a5, a7 = min(a5, a7), max(a5, a7)
    a0, a4 = min(a0, a4), max(a0, a4)
    a1, a5 = min(a1, a5), max(a1, a5)
    a2, a6 = min(a2, a6), max(a2, a6)
    a3, a7 = min(a3, a7), max(a3, a7)
    a0, a1 = min(a0, a1), max(a0, a1)
    a2, a3 = min(a2, a3), max(a2, a3)
    a4, a5 = min(a4, a5), max(a4, a5)
    a6, a7 = min(a6, a7), max(a6, a7)
    a2, a4 = min(a2, a4), max(a2, a4)
    a3, a5 = min(a3, a5), max(a3, a5)
    a1, a4 = min(a1, a4), max(a1, a4)
    a3, a6 = min(a3, a6), max(a3, a6)
    a1, a2 = min(a1, a2), max(a1, a2)
    a3, a4 = min(a3, a4), max(a3, a4)
    a5, a6 = min(a5, a6), max(a5, a6)
    return a0, a1, a2, a3, a4, a5, a6, a7


@pixel
def interior_median_nz(z, v, u, g_u, g_v, c_x, c_y, buf):
    """:func:`median_nz` where all 9 pixels are valid and inside: no checks, a sorting network."""
    z_p = np.float64(z[v, u])
    u_c = u - c_x
    v_c = v - c_y
    zx_p = u_c * z_p
    zy_p = v_c * z_p
    s0, s1, s2, s3, s4, s5, s6, s7 = sort8(
        nz_or_inf(np.float64(z[v - 1, u - 1]), u_c - 1.0, v_c - 1.0, g_u, g_v, zx_p, zy_p, z_p),
        nz_or_inf(np.float64(z[v - 1, u]), u_c, v_c - 1.0, g_u, g_v, zx_p, zy_p, z_p),
        nz_or_inf(np.float64(z[v - 1, u + 1]), u_c + 1.0, v_c - 1.0, g_u, g_v, zx_p, zy_p, z_p),
        nz_or_inf(np.float64(z[v, u - 1]), u_c - 1.0, v_c, g_u, g_v, zx_p, zy_p, z_p),
        nz_or_inf(np.float64(z[v, u + 1]), u_c + 1.0, v_c, g_u, g_v, zx_p, zy_p, z_p),
        nz_or_inf(np.float64(z[v + 1, u - 1]), u_c - 1.0, v_c + 1.0, g_u, g_v, zx_p, zy_p, z_p),
        nz_or_inf(np.float64(z[v + 1, u]), u_c, v_c + 1.0, g_u, g_v, zx_p, zy_p, z_p),
        nz_or_inf(np.float64(z[v + 1, u + 1]), u_c + 1.0, v_c + 1.0, g_u, g_v, zx_p, zy_p, z_p))
    buf[0] = s0
    buf[1] = s1
    buf[2] = s2
    buf[3] = s3
    buf[4] = s4
    buf[5] = s5
    buf[6] = s6
    buf[7] = s7
    count = 8
    while count > 0 and buf[count - 1] == np.inf:  # the dropped candidates (dZ == 0) sort last
        count -= 1
    med = (buf[max(count - 1, 0) // 2] + buf[count // 2]) / 2.0
    return med, count


@pixel
def interior_gradient(z, v, u, dv, du):
    """Central difference of 1/Z / 2 where both neighbours are valid (as :func:`inverse_depth_gradient`)."""
    return (1.0 / np.float64(z[v + dv, u + du]) - 1.0 / np.float64(z[v - dv, u - du])) / 2


@njit
def _tf2n_median_kernel(z, valid, f_x, f_y, c_x, c_y, reflect, fill, out):
    """3F2N with the median filter: gradients of 1/Z -> eq. 10 per neighbour -> median -> unit, one pass."""
    H, W = z.shape
    buf = np.empty(8)
    for v in range(H):
        for u in range(W):
            if all_nine_valid(valid, v, u):
                g_u = interior_gradient(z, v, u, 0, 1)
                g_v = interior_gradient(z, v, u, 1, 0)
                n_z, count = interior_median_nz(z, v, u, g_u, g_v, c_x, c_y, buf)
                n_x, n_y, n_z = fronto_parallel_fallback(f_x * g_u, f_y * g_v, n_z, count)
                n_x, n_y, n_z = camera_facing(n_x, n_y, n_z, u - c_x, v - c_y, f_x, f_y)
                write_unit(out, v, u, n_x, n_y, n_z, fill)
                continue
            ok = False
            if valid[v, u]:
                g_u, ok_u = inverse_depth_gradient(z, valid, v, u, 0, 1, reflect)
                g_v, ok_v = inverse_depth_gradient(z, valid, v, u, 1, 0, reflect)
                if ok_u and ok_v:
                    n_z, count = median_nz(z, valid, v, u, g_u, g_v, c_x, c_y, reflect, buf)
                    n_x, n_y, n_z = fronto_parallel_fallback(f_x * g_u, f_y * g_v, n_z, count)
                    n_x, n_y, n_z = camera_facing(n_x, n_y, n_z, u - c_x, v - c_y, f_x, f_y)
                    ok = write_unit(out, v, u, n_x, n_y, n_z, fill)
            if not ok:
                fill_pixel(out, v, u, fill)


@njit
def _tf2n_mean_kernel(z, valid, f_x, f_y, c_x, c_y, reflect, fill, out):
    """3F2N with the mean filter: gradients of 1/Z -> eq. 10 per neighbour -> mean -> unit, one pass."""
    H, W = z.shape
    for v in range(H):
        for u in range(W):
            ok = False
            if valid[v, u]:
                g_u, ok_u = inverse_depth_gradient(z, valid, v, u, 0, 1, reflect)
                g_v, ok_v = inverse_depth_gradient(z, valid, v, u, 1, 0, reflect)
                if ok_u and ok_v:
                    n_z, count = mean_nz(z, valid, v, u, g_u, g_v, c_x, c_y, reflect)
                    n_x, n_y, n_z = fronto_parallel_fallback(f_x * g_u, f_y * g_v, n_z, count)
                    n_x, n_y, n_z = camera_facing(n_x, n_y, n_z, u - c_x, v - c_y, f_x, f_y)
                    ok = write_unit(out, v, u, n_x, n_y, n_z, fill)
            if not ok:
                fill_pixel(out, v, u, fill)


def _camera(cam):
    return float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy)


def three_filters(z, valid, cam, out, *, third="median", border="one-sided", fill=0.0):
    """3F2N (Fan et al., RA-L 2021, eq. 7-11) with the ``third`` filter "mean" or "median", into ``out``."""
    kernel = _tf2n_median_kernel if third == "median" else _tf2n_mean_kernel
    kernel(z, valid, *_camera(cam), border == "reflect", np.float32(fill), out)
    return out


@njit
def _sne_kernel(z, valid, f_x, f_y, c_x, c_y, reflect, fill, out):
    """SNE-RoadSeg's estimator: 3F2N gradients and candidates, fused through the polar angle theta."""
    H, W = z.shape
    for v in range(H):
        for u in range(W):
            ok = False
            if valid[v, u]:
                g_u, ok_u = inverse_depth_gradient(z, valid, v, u, 0, 1, reflect)
                g_v, ok_v = inverse_depth_gradient(z, valid, v, u, 1, 0, reflect)
                if ok_u and ok_v:
                    n_x = f_x * g_u
                    n_y = f_y * g_v
                    # azimuth phi, as the authors' code: arctan, then + pi (so cos(phi) <= 0)
                    phi = math.atan(n_y / n_x) + math.pi
                    cos_phi = math.cos(phi)
                    sin_phi = math.sin(phi)
                    z_p = np.float64(z[v, u])
                    zx_p = (u - c_x) * z_p
                    zy_p = (v - c_y) * z_p
                    s_x = 0.0
                    s_y = 0.0
                    s_z = 0.0
                    for k in range(8):
                        dv, du = _NEIGHBOURS[k]
                        q_v, q_u, use = neighbour_pixel(valid, v, u, dv, du, reflect)
                        if use:
                            n_z, use = candidate_nz(z, v, u, q_v, q_u, g_u, g_v, c_x, c_y, zx_p, zy_p, z_p)
                            if use:  # sum of the unit candidates n_i / |n_i|
                                norm = math.sqrt(n_x * n_x + n_y * n_y + n_z * n_z)
                                s_x += n_x / norm
                                s_y += n_y / norm
                                s_z += n_z / norm
                    theta = math.atan((s_x * cos_phi + s_y * sin_phi) / s_z)
                    m_x = math.sin(theta) * cos_phi
                    m_y = math.sin(theta) * sin_phi
                    m_z = math.cos(theta)
                    if math.isnan(m_z):  # no azimuth (n_x = n_y = 0) or no candidate: fronto-parallel
                        m_x, m_y, m_z = 0.0, 0.0, -1.0
                    m_x, m_y, m_z = camera_facing(m_x, m_y, m_z, u - c_x, v - c_y, f_x, f_y)
                    ok = write_unit(out, v, u, m_x, m_y, m_z, fill)
            if not ok:
                fill_pixel(out, v, u, fill)


def sne_roadseg(z, valid, cam, out, *, border="one-sided", fill=0.0):
    """SNE-RoadSeg's surface normal estimator (Fan et al., ECCV 2020, Sec. 3.1), into ``out``."""
    _sne_kernel(z, valid, *_camera(cam), border == "reflect", np.float32(fill), out)
    return out
