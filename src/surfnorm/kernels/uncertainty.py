"""Each normal's predicted RMS angular error, in degrees (ours, not in the paper).

A normal from a least-squares plane fit of inverse depth w = 1/z (``adaptive_fit``, eq. (1)-(2) of
:mod:`surfnorm.kernels.adaptive_fit`) has a covariance that follows from the fit itself. A window of n points
and radius r, whose points scatter by n r (r + 1) / 3 squared pixels along each axis (exactly so for the full
square), fitted with a residual variance s^2 per point, gives the slopes g_u, g_v each the variance::

    var_g = s^2 / (n r (r + 1) / 3)                                                      (1)

and the plane's value a at a pixel offset (o_u, o_v) from the window's centre (the pixel itself for the
centred window, a corner for a quadrant window, one pixel more where a pixel took a neighbour's plane) the
variance s^2 / n + (o_u^2 + o_v^2) var_g, with cov(a, g_u) = o_u var_g and cov(a, g_v) = o_v var_g. The
normal is m / |m| with m = -(f_x g_u, f_y g_v, a - g_u (u - c_x) - g_v (v - c_y)) (eq. (2) there); to first
order its angular error is the part of dm across the normal, over |m| = w / (-n . (x, y, 1)), so::

    sigma^2 = (trace C - n^T C n) / |m|^2,   C = J cov(g_u, g_v, a) J^T                  (2)

with J = d m / d(g_u, g_v, a). For s^2 the fit's own residual per degree of freedom is taken, or the frame's
noise (``rho``, :class:`~surfnorm.kernels.adaptive_fit.NoiseProfile`, as sigma_w = rho / (z f)) where that is
larger: a window whose few points happen to fit well is not trusted beyond the noise the frame shows. Sensor
noise is correlated between neighbours (a matcher's window, a spatial filter, quantisation terraces), which
a residual does not see and a slope does: ``FIT_GAIN`` (a variance factor, the one number set from data:
the simulated sensors of :mod:`surfnorm.bench.simulate`) stands for it.

``d2nt_v3`` takes the gradients of its DAG filter from one pixel's neighbours: its error is that of the 3x3
neighbourhood's plane, the same formulas at r = 1 (a fit of every pixel's 3x3 window, its own residual;
``D2NT_GAIN``). On clean depth that residual is the surface's curvature or a discontinuity inside the window.

A pixel that has a normal always gets a sigma (a normal whose window says nothing, for lack of points, gets
``NO_FIT_DEG``); NaN exactly where the normal is fill.
"""

from __future__ import annotations

import math

import numpy as np

from .._config import njit, pixel

__all__ = ["sigma_from_fits", "neighbourhood_fits", "FIT_GAIN", "D2NT_GAIN", "NO_FIT_DEG"]

#: Variance factor of the adaptive fit's slopes over the independent-noise formula (1).
FIT_GAIN = 4.0
#: Variance factor of the 3x3 fits that stand for ``d2nt_v3``'s gradients.
D2NT_GAIN = 1.0
#: Variance factor of the misfit (a fit's residual beyond the noise), which tilts a plane by about its size over
#: the window's radius, however many points it has.
MISFIT_GAIN = 1.0
#: Misfit's variance factor for ``d2nt_v3``.
D2NT_MISFIT_GAIN = 0.3
#: Weight (on the variance) of the angle between ``d2nt_v3``'s normal and its pixel's best 3x3 plane.
D2NT_DISAGREEMENT = 0.3
#: Added in quadrature to every sigma (degrees).
FLOOR_DEG = 3.0
#: Sigma (degrees) of a normal without a fit to judge it by.
NO_FIT_DEG = 30.0
#: The largest sigma (degrees): a direction known to face the camera, nothing more.
MAX_DEG = 60.0


@pixel
def _terms(s2, n, r, o_u, o_v, noise2, gain, misfit_gain):
    """(var_g, var_a, cov(a, g_u), cov(a, g_v)) of a fit (residual per dof s2, n points, radius r) carried to a
    pixel offset (o_u, o_v) from its window's centre: the noise (the residual, at least ``noise2``, times
    ``gain``) averaged over the n points, and the misfit (the residual beyond ``noise2``, times ``misfit_gain``),
    which the points do not average away."""
    s = gain * max(s2, noise2)
    mis = misfit_gain * max(s2 - noise2, 0.0)
    spread = r * (r + 1.0) / 3.0
    var_g = s / (n * spread) + mis / spread
    return var_g, s / n + mis + (o_u * o_u + o_v * o_v) * var_g, o_u * var_g, o_v * var_g


@pixel
def _angle(n0, n1, n2, zp, u, v, fx, fy, cx, cy, var_g, var_a, c_u, c_v):
    """Eq. (2) in degrees at pixel (u, v) with unit normal (n0, n1, n2) and depth ``zp``."""
    du = u - cx
    dv = v - cy
    facing = -(n0 * du / fx + n1 * dv / fy + n2)
    if not facing > 1e-6:
        return 90.0
    m = 1.0 / (zp * facing)
    trace = var_g * (fx * fx + du * du + fy * fy + dv * dv) + var_a - 2.0 * (c_u * du + c_v * dv)
    p_u = n0 * fx - n2 * du  # n . J_gu
    p_v = n1 * fy - n2 * dv  # n . J_gv
    along = var_g * (p_u * p_u + p_v * p_v) + var_a * n2 * n2 + 2.0 * n2 * (c_u * p_u + c_v * p_v)
    return min(math.degrees(math.sqrt(max(trace - along, 0.0)) / m), MAX_DEG)


@njit(nogil=True)
def _sigma_kernel(
    z,
    valid,
    normals,
    fill,
    fits,
    stride,
    cam,
    rho_z0,
    rho_inv_step,
    rho_t,
    gain,
    misfit_gain,
    disagreement,
    floor,
    no_fit,
    out,
):
    H, W = z.shape
    Hf, Wf = fits.shape[0], fits.shape[1]
    fx, fy, cx, cy = cam
    f = math.sqrt(fx * fy)
    n_t = rho_t.shape[0]
    for v in range(H):
        for u in range(W):
            n0, n1, n2 = normals[v, u, 0], normals[v, u, 1], normals[v, u, 2]
            is_fill = n0 == fill and n1 == fill and n2 == fill
            if not valid[v, u] or is_fill or not (math.isfinite(n0) and math.isfinite(n1) and math.isfinite(n2)):
                out[v, u] = np.nan
                continue
            # the fitted pixels whose planes this pixel may have taken: itself, or the nearest ones
            s_g = s_a = s_u = s_v = 0.0
            k = 0
            for reach in (stride - 1, stride):
                lo_v = max((v - reach + stride - 1) // stride, 0)
                hi_v = min((v + reach) // stride, Hf - 1)
                lo_u = max((u - reach + stride - 1) // stride, 0)
                hi_u = min((u + reach) // stride, Wf - 1)
                for i in range(lo_v, hi_v + 1):
                    for j in range(lo_u, hi_u + 1):
                        s2 = fits[i, j, 0]
                        if not s2 == s2:
                            continue
                        vf, uf = i * stride, j * stride
                        zf = z[vf, uf]
                        t = min(max(int((zf - rho_z0) * rho_inv_step), 0), n_t - 1)
                        noise = rho_t[t] / (zf * f)
                        o_u = (u - uf) - fits[i, j, 3]
                        o_v = (v - vf) - fits[i, j, 4]
                        g, a, c_u, c_v = _terms(
                            s2, fits[i, j, 1], fits[i, j, 2], o_u, o_v, noise * noise, gain, misfit_gain
                        )
                        s_g += g
                        s_a += a
                        s_u += c_u
                        s_v += c_v
                        k += 1
                if k > 0 or stride == 1:
                    break
            if k == 0:
                out[v, u] = no_fit
                continue
            inv = 1.0 / k
            sigma = _angle(n0, n1, n2, z[v, u], u, v, fx, fy, cx, cy, s_g * inv, s_a * inv, s_u * inv, s_v * inv)
            if fits.shape[2] > 5 and fits[v, u, 0] == fits[v, u, 0]:
                # a normal not taken from this plane (d2nt_v3): how far it is from it counts as error too
                g_u, g_v, a = fits[v, u, 5], fits[v, u, 6], fits[v, u, 7]
                m0, m1, m2 = fx * g_u, fy * g_v, a - g_u * (u - cx) - g_v * (v - cy)
                m_norm = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
                if m_norm > 0.0:
                    c = -(n0 * m0 + n1 * m1 + n2 * m2) / m_norm
                    off = math.degrees(math.acos(min(max(c, -1.0), 1.0)))
                    sigma = min(math.sqrt(sigma * sigma + disagreement * off * off), MAX_DEG)
            out[v, u] = min(math.sqrt(sigma * sigma + floor * floor), MAX_DEG)


def sigma_from_fits(
    z, valid, cam, normals, fits, stride, profile, *, gain, misfit_gain, disagreement=0.0, fill=0.0, out=None
) -> np.ndarray:
    """Each normal's sigma (degrees; NaN where it is ``fill`` or not finite) from the fits its planes came from.

    ``fits``: (H / stride, W / stride, 5) as ``info`` of the adaptive fit's kernel (residual per dof, points,
    radius, window offset), NaN where a fitted pixel has no fit; ``profile``: the frame's noise profile (for the
    residual's floor); ``gain``: the variance factor (``FIT_GAIN`` or ``D2NT_GAIN``).
    """
    from .adaptive_fit import radius_table

    z0, inv_step, _, rho_t = radius_table(profile.depths, profile.rho)
    if out is None:
        out = np.empty(z.shape, np.float32)
    _sigma_kernel(
        z,
        valid,
        normals,
        np.float32(fill),
        fits,
        int(stride),
        (float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy)),
        float(z0),
        float(inv_step),
        rho_t,
        float(gain),
        float(misfit_gain),
        float(disagreement),
        float(FLOOR_DEG),
        float(NO_FIT_DEG),
        out,
    )
    return out


@pixel
def _fit3(z, valid, v, u):
    """(rss / dof, n, g_u, g_v, w at (v, u)) of the least-squares plane of w = 1/z over the valid pixels of the
    3x3 window centred on (v, u); (inf, 0, 0, 0, 0) where fewer than 4 points or points on a line."""
    H, W = z.shape
    n = s_x = s_y = s_xx = s_xy = s_yy = s_w = s_xw = s_yw = s_ww = 0.0
    for dy in range(-1, 2):
        y = v + dy
        if y < 0 or y >= H:
            continue
        for dx in range(-1, 2):
            x = u + dx
            if x < 0 or x >= W or not valid[y, x]:
                continue
            w = 1.0 / z[y, x]
            n += 1.0
            s_x += dx
            s_y += dy
            s_xx += dx * dx
            s_xy += dx * dy
            s_yy += dy * dy
            s_w += w
            s_xw += dx * w
            s_yw += dy * w
            s_ww += w * w
    if n < 4.0:
        return np.inf, 0.0, 0.0, 0.0, 0.0
    mx, my, mw = s_x / n, s_y / n, s_w / n
    cxx = s_xx - s_x * mx
    cxy = s_xy - s_x * my
    cyy = s_yy - s_y * my
    cxw = s_xw - s_x * mw
    cyw = s_yw - s_y * mw
    cww = s_ww - s_w * mw
    det = cxx * cyy - cxy * cxy
    if not det > 1e-6 * cxx * cyy:
        return np.inf, 0.0, 0.0, 0.0, 0.0
    g_x = (cyy * cxw - cxy * cyw) / det
    g_y = (cxx * cyw - cxy * cxw) / det
    return max(cww - g_x * cxw - g_y * cyw, 0.0) / (n - 3.0), n, g_x, g_y, mw - g_x * mx - g_y * my


@njit(nogil=True)
def _fits3(z, valid, out):
    """Each valid pixel's best 3x3 plane of inverse depth: of the window centred on it and the four with it at a
    corner, the one with the smallest residual per dof (a pixel beside a discontinuity is judged by its own
    side, as DAG takes its gradient from the smoother side): (rss / dof, n, 1, offset u, offset v, g_u, g_v, w at
    the pixel) into ``out`` (H, W, 8); NaN where no window has a plane."""
    H, W = z.shape
    for v in range(H):
        for u in range(W):
            out[v, u, 0] = np.nan
            if not valid[v, u]:
                continue
            best, n_best, g_u, g_v, a = _fit3(z, valid, v, u)
            o_u = o_v = 0.0
            for dv in (-1, 1):
                for du in (-1, 1):
                    s2, n, gu_k, gv_k, a_k = _fit3(z, valid, v + dv, u + du)
                    if s2 < best:
                        best, n_best, o_u, o_v = s2, n, float(du), float(dv)
                        g_u, g_v, a = gu_k, gv_k, a_k - gu_k * du - gv_k * dv
            if n_best > 0.0:
                out[v, u, 0] = best
                out[v, u, 1] = n_best
                out[v, u, 2] = 1.0
                out[v, u, 3] = o_u
                out[v, u, 4] = o_v
                out[v, u, 5] = g_u
                out[v, u, 6] = g_v
                out[v, u, 7] = a


def neighbourhood_fits(z, valid) -> np.ndarray:
    """Every valid pixel's best 3x3 plane fit of inverse depth, as ``fits`` of :func:`sigma_from_fits` (stride 1),
    with the plane itself at the pixel (g_u, g_v, w) in channels 5-7."""
    out = np.empty(z.shape + (8,), np.float32)
    _fits3(z, valid, out)
    return out
