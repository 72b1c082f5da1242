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
flip each normal so that n . P < 0, which changes no folded angular error;
an edge-on normal (n . P = 0 up to rounding) is oriented by the fixed rule of
:func:`surfnorm.kernels._rows.facing_sign`, not by the rounding.

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

from .._bands import whole
from .._config import njit, pixel
from ._rows import camera_facing, facing_sign, fill_pixel, fill_pixels, stencil, usable, write_unit

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
def fronto_parallel_fallback(n_x, n_y, n_z, count):
    """The authors' fallbacks: no candidate -> n_x = n_y = 0; then n_x = n_y = 0 -> n_z = -1."""
    if count == 0:
        n_x = 0.0
        n_y = 0.0
    if n_x == 0.0 and n_y == 0.0:
        n_z = -1.0
    return n_x, n_y, n_z


@pixel
def neighbour_nz(z, valid, v, u, k, g_u, g_v, c_x, c_y, reflect, zx_p, zy_p, z_p):
    """The candidate n_z,q of neighbour k of ``_NEIGHBOURS`` (:func:`candidate_nz`), and whether it exists:
    the neighbour is usable (:func:`neighbour_pixel`) and dZ != 0."""
    dv, du = _NEIGHBOURS[k]
    q_v, q_u, ok = neighbour_pixel(valid, v, u, dv, du, reflect)
    if not ok:
        return 0.0, False
    return candidate_nz(z, v, u, q_v, q_u, g_u, g_v, c_x, c_y, zx_p, zy_p, z_p)


@pixel
def third_nz(z, valid, v, u, g_u, g_v, c_x, c_y, reflect, median, buf):
    """n_z of eq. 11 from the candidates n_z,q of the usable neighbours, and their count.

    The median (``median``: NaN without candidates) or the mean (0 without).
    Candidates are collected in ``buf`` (8 entries), kept sorted by insertion
    as they come for the median; the mean adds them in neighbour order.
    """
    z_p = np.float64(z[v, u])
    zx_p = (u - c_x) * z_p
    zy_p = (v - c_y) * z_p
    count = 0
    for k in range(8):
        nz, ok = neighbour_nz(z, valid, v, u, k, g_u, g_v, c_x, c_y, reflect, zx_p, zy_p, z_p)
        if ok:
            j = count
            while median and j > 0 and buf[j - 1] > nz:
                buf[j] = buf[j - 1]
                j -= 1
            buf[j] = nz
            count += 1
    if not median:
        total = 0.0
        for i in range(count):
            total += buf[i]
        return total / max(count, 1), count
    half = count // 2
    med = np.nan
    if count > 0:
        if count % 2 == 1:
            med = buf[half]
        else:
            med = (buf[half - 1] + buf[half]) / 2.0
    return med, count


# ---- fast path: runs of pixels whose 3x3 neighbourhood is inside the image and valid --------------
#
# Written without branches so that LLVM vectorises the loop over a run (8 pixels per AVX-512
# instruction): the normals of a run go to three row buffers (an interleaved (H, W, 3) store would
# stop the vectoriser) and are copied into ``out`` afterwards. Differences of depth and of inverse
# depth, where precision is lost, are float64; the 8 quotients of eq. 10 are taken in float32 (3x
# cheaper than float64 division, and the normal is stored in float32 anyway).


@pixel
def all_nine_valid(valid, v, u):
    """True if (v, u) and its 8 neighbours lie inside the image and are valid."""
    H, W = valid.shape
    ok = False
    if v >= 1 and v < H - 1 and u >= 1 and u < W - 1:
        ok = (
            valid[v - 1, u - 1]
            & valid[v - 1, u]
            & valid[v - 1, u + 1]
            & valid[v, u - 1]
            & valid[v, u]
            & valid[v, u + 1]
            & valid[v + 1, u - 1]
            & valid[v + 1, u]
            & valid[v + 1, u + 1]
        )
    return ok


@pixel
def run_end(valid, v, u):
    """The first pixel after u in row v that is not inside a fully valid 3x3 neighbourhood."""
    W = valid.shape[1]
    end = u + 1
    while end < W and all_nine_valid(valid, v, end):
        end += 1
    return end


@pixel
def invalid_end(valid_row, u):
    """The first pixel from u on in ``valid_row`` that holds depth (its length where none does)."""
    end = u
    while end < valid_row.shape[0] and not valid_row[end]:
        end += 1
    return end


@pixel
def interior_gradients(z_l, z_r, z_a, z_b):
    """dD/du, dD/dv of D = 1/Z from the 4 neighbours: (1/z_r - 1/z_l) / 2 as (z_l - z_r) / (2 z_l z_r),
    both with one division (the products of two float32 depths are exact in float64)."""
    lr = z_l * z_r
    ab = z_a * z_b
    inv = 0.5 / (lr * ab)
    return ((z_l - z_r) * ab) * inv, ((z_a - z_b) * lr) * inv


@pixel
def nz_or_inf(z_q, uq_c, vq_c, g_u, g_v, zx_p, zy_p, z_p):
    """n_z,q of eq. 10 as float32 (numerator and dZ in float64), +inf where dZ == 0 (no candidate)."""
    d_z = z_p - z_q
    num = -(g_u * (zx_p - uq_c * z_q) + g_v * (zy_p - vq_c * z_q))
    nz = np.float32(num) / np.float32(d_z)
    return nz if d_z != 0.0 else np.float32(np.inf)


@pixel
def interior_candidates(z, v, u, g_u, g_v, u_c, v_c):
    """The 8 candidates n_z,q (eq. 10) of an interior pixel, +inf where dZ == 0."""
    z_p = np.float64(z[v, u])
    zx_p = u_c * z_p
    zy_p = v_c * z_p
    return (
        nz_or_inf(np.float64(z[v - 1, u - 1]), u_c - 1.0, v_c - 1.0, g_u, g_v, zx_p, zy_p, z_p),
        nz_or_inf(np.float64(z[v - 1, u]), u_c, v_c - 1.0, g_u, g_v, zx_p, zy_p, z_p),
        nz_or_inf(np.float64(z[v - 1, u + 1]), u_c + 1.0, v_c - 1.0, g_u, g_v, zx_p, zy_p, z_p),
        nz_or_inf(np.float64(z[v, u - 1]), u_c - 1.0, v_c, g_u, g_v, zx_p, zy_p, z_p),
        nz_or_inf(np.float64(z[v, u + 1]), u_c + 1.0, v_c, g_u, g_v, zx_p, zy_p, z_p),
        nz_or_inf(np.float64(z[v + 1, u - 1]), u_c - 1.0, v_c + 1.0, g_u, g_v, zx_p, zy_p, z_p),
        nz_or_inf(np.float64(z[v + 1, u]), u_c, v_c + 1.0, g_u, g_v, zx_p, zy_p, z_p),
        nz_or_inf(np.float64(z[v + 1, u + 1]), u_c + 1.0, v_c + 1.0, g_u, g_v, zx_p, zy_p, z_p),
    )


@pixel
def count_finite8(a0, a1, a2, a3, a4, a5, a6, a7):
    """How many of the 8 candidates exist (are not +inf)."""
    inf = np.float32(np.inf)
    return (
        (np.int64(a0 != inf) + np.int64(a1 != inf))
        + (np.int64(a2 != inf) + np.int64(a3 != inf))
        + ((np.int64(a4 != inf) + np.int64(a5 != inf)) + (np.int64(a6 != inf) + np.int64(a7 != inf)))
    )


@pixel
def sort8(a0, a1, a2, a3, a4, a5, a6, a7):
    """The 8 values in ascending order: an optimal 19-comparator sorting network of min/max."""
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
def median_of_sorted(s0, s1, s2, s3, s4, count):
    """Median of the first ``count`` of sorted values (the rest are +inf): the middle one, or the
    mean of the middle two for an even count (as numpy); NaN-free garbage for count 0 (not used)."""
    lo = s0 if count <= 2 else (s1 if count <= 4 else (s2 if count <= 6 else s3))
    hi = s0 if count <= 1 else (s1 if count <= 3 else (s2 if count <= 5 else (s3 if count <= 7 else s4)))
    return (np.float64(lo) + np.float64(hi)) / 2.0


@pixel
def finish(n_x, n_y, n_z, count, u_c, v_c, f_x, f_y):
    """The authors' fallbacks, then turn to face the camera and scale to unit length (no branches)."""
    n_x = n_x if count > 0 else 0.0
    n_y = n_y if count > 0 else 0.0
    n_z = -1.0 if (n_x == 0.0) & (n_y == 0.0) else n_z
    # facing the camera (surfnorm.kernels._rows.facing_sign), with P = Z (u_c / f_x, v_c / f_y, 1) multiplied by f_x f_y / Z > 0
    scale = facing_sign(n_x, n_y, n_z, u_c * f_y, v_c * f_x, f_x * f_y) / math.sqrt(n_x * n_x + n_y * n_y + n_z * n_z)
    return n_x * scale, n_y * scale, n_z * scale


@pixel
def interior_pixel(z, v, u, u_c, v_c):
    """An interior pixel's (g_u, g_v) (:func:`interior_gradients`), its 8 candidates n_z,q
    (:func:`interior_candidates`) and how many of them exist (:func:`count_finite8`)."""
    g_u, g_v = interior_gradients(
        np.float64(z[v, u - 1]), np.float64(z[v, u + 1]), np.float64(z[v - 1, u]), np.float64(z[v + 1, u])
    )
    a0, a1, a2, a3, a4, a5, a6, a7 = interior_candidates(z, v, u, g_u, g_v, u_c, v_c)
    return g_u, g_v, (a0, a1, a2, a3, a4, a5, a6, a7), count_finite8(a0, a1, a2, a3, a4, a5, a6, a7)


@pixel
def store_run(out, v, u0, u1, rows):
    for u in range(u0, u1):
        out[v, u, 0] = rows[0, u]
        out[v, u, 1] = rows[1, u]
        out[v, u, 2] = rows[2, u]


@pixel
def median_run(z, v, u0, u1, f_x, f_y, c_x, c_y, rows):
    """3F2N-median normals of pixels u0..u1-1 of row v (all fully valid neighbourhoods) into ``rows``."""
    v_c = v - c_y
    for u in range(u0, u1):
        u_c = u - c_x
        g_u, g_v, candidates, count = interior_pixel(z, v, u, u_c, v_c)
        a0, a1, a2, a3, a4, a5, a6, a7 = candidates
        s0, s1, s2, s3, s4, s5, s6, s7 = sort8(a0, a1, a2, a3, a4, a5, a6, a7)
        n_x, n_y, n_z = finish(
            f_x * g_u, f_y * g_v, median_of_sorted(s0, s1, s2, s3, s4, count), count, u_c, v_c, f_x, f_y
        )
        rows[0, u] = n_x
        rows[1, u] = n_y
        rows[2, u] = n_z


@pixel
def median_span(z, v, a, b, f_x, f_y, c_x, c_y, rows):
    """:func:`median_run` over pixels a..b-1 of row v, written on views that start at the span, so
    that the loop index starts at 0 and LLVM vectorises it wherever the span starts."""
    up, mid, dn = z[v - 1, a - 1 : b + 1], z[v, a - 1 : b + 1], z[v + 1, a - 1 : b + 1]  # 1-D, so contiguous
    rows_x, rows_y, rows_z = rows[0, a:b], rows[1, a:b], rows[2, a:b]
    v_c = v - c_y
    for i in range(b - a):
        u_c = (a + i) - c_x
        g_u, g_v = interior_gradients(
            np.float64(mid[i]), np.float64(mid[i + 2]), np.float64(up[i + 1]), np.float64(dn[i + 1])
        )
        # interior_candidates, on the row views
        z_p = np.float64(mid[i + 1])
        zx_p = u_c * z_p
        zy_p = v_c * z_p
        a0 = nz_or_inf(np.float64(up[i]), u_c - 1.0, v_c - 1.0, g_u, g_v, zx_p, zy_p, z_p)
        a1 = nz_or_inf(np.float64(up[i + 1]), u_c, v_c - 1.0, g_u, g_v, zx_p, zy_p, z_p)
        a2 = nz_or_inf(np.float64(up[i + 2]), u_c + 1.0, v_c - 1.0, g_u, g_v, zx_p, zy_p, z_p)
        a3 = nz_or_inf(np.float64(mid[i]), u_c - 1.0, v_c, g_u, g_v, zx_p, zy_p, z_p)
        a4 = nz_or_inf(np.float64(mid[i + 2]), u_c + 1.0, v_c, g_u, g_v, zx_p, zy_p, z_p)
        a5 = nz_or_inf(np.float64(dn[i]), u_c - 1.0, v_c + 1.0, g_u, g_v, zx_p, zy_p, z_p)
        a6 = nz_or_inf(np.float64(dn[i + 1]), u_c, v_c + 1.0, g_u, g_v, zx_p, zy_p, z_p)
        a7 = nz_or_inf(np.float64(dn[i + 2]), u_c + 1.0, v_c + 1.0, g_u, g_v, zx_p, zy_p, z_p)
        count = count_finite8(a0, a1, a2, a3, a4, a5, a6, a7)
        s0, s1, s2, s3, s4, s5, s6, s7 = sort8(a0, a1, a2, a3, a4, a5, a6, a7)
        n_x, n_y, n_z = finish(
            f_x * g_u, f_y * g_v, median_of_sorted(s0, s1, s2, s3, s4, count), count, u_c, v_c, f_x, f_y
        )
        rows_x[i] = n_x
        rows_y[i] = n_y
        rows_z[i] = n_z


#: Flat spans shorter than this are computed like any other pixels (not worth a separate loop).
_MIN_FLAT_SPAN = 16


@pixel
def equal_neighbours(z, v, a, b):
    """How many pixels a..b-1 of row v have the depth of their right neighbour (a cheap bound on
    :func:`flat_pixels`: a flat span of n pixels holds n + 1 such pairs)."""
    mid = z[v, a - 1 : b + 1]
    count = 0
    for i in range(b - a):
        count += np.int64(mid[i + 1] == mid[i + 2])
    return count


@pixel
def flat_pixels(z, v, a, b, flat):
    """flat[i] = the 8 neighbours of pixel (v, a + i) have exactly its depth.

    Such a pixel has no candidate (every dZ is 0), so its 3F2N normal is the authors' fallback
    (0, 0, -1), whatever the rest of the arithmetic would give.
    """
    up, mid, dn = z[v - 1, a - 1 : b + 1], z[v, a - 1 : b + 1], z[v + 1, a - 1 : b + 1]
    for i in range(b - a):
        c = mid[i + 1]
        flat[i] = (
            (up[i] == c)
            & (up[i + 1] == c)
            & (up[i + 2] == c)
            & (mid[i] == c)
            & (mid[i + 2] == c)
            & (dn[i] == c)
            & (dn[i + 1] == c)
            & (dn[i + 2] == c)
        )


@pixel
def median_run_split(z, v, a, b, f_x, f_y, c_x, c_y, rows, flat, fronto, out):
    """3F2N-median normals of pixels a..b-1 of row v (all fully valid neighbourhoods) into ``out``.

    Long spans of flat pixels (:func:`flat_pixels`) get (0, 0, -1) directly (``fronto`` holds that
    normal for a whole row, x, y, z, x, y, z, ...): the same numbers, without the arithmetic (e.g. on
    a constant background). The rest goes through :func:`median_span` and :func:`store_run`.
    """
    if equal_neighbours(z, v, a, b) <= _MIN_FLAT_SPAN:
        median_run(z, v, a, b, f_x, f_y, c_x, c_y, rows)
        store_run(out, v, a, b, rows)
        return
    flat_pixels(z, v, a, b, flat)
    out_flat = out[v].reshape(3 * out.shape[1])
    i = a
    while i < b:
        s = i  # find the next flat span [s, e) of at least _MIN_FLAT_SPAN pixels
        e = b
        while s < b:
            if flat[s - a]:
                e = s
                while e < b and flat[e - a]:
                    e += 1
                if e - s >= _MIN_FLAT_SPAN:
                    break
                s = e
            else:
                s += 1
        if s >= b:
            s = b
            e = b
        if s > i:
            median_span(z, v, i, s, f_x, f_y, c_x, c_y, rows)
            store_run(out, v, i, s, rows)
        out_flat[3 * s : 3 * e] = fronto[3 * s : 3 * e]
        i = e


@pixel
def mean_run(z, v, u0, u1, f_x, f_y, c_x, c_y, rows):
    """3F2N-mean normals of pixels u0..u1-1 of row v (all fully valid neighbourhoods) into ``rows``."""
    v_c = v - c_y
    zero = np.float32(0.0)
    inf = np.float32(np.inf)
    for u in range(u0, u1):
        u_c = u - c_x
        g_u, g_v, candidates, count = interior_pixel(z, v, u, u_c, v_c)
        a0, a1, a2, a3, a4, a5, a6, a7 = candidates
        total = (
            (np.float64(a0 if a0 != inf else zero) + np.float64(a1 if a1 != inf else zero))
            + (np.float64(a2 if a2 != inf else zero) + np.float64(a3 if a3 != inf else zero))
            + (
                (np.float64(a4 if a4 != inf else zero) + np.float64(a5 if a5 != inf else zero))
                + (np.float64(a6 if a6 != inf else zero) + np.float64(a7 if a7 != inf else zero))
            )
        )
        n_x, n_y, n_z = finish(f_x * g_u, f_y * g_v, total / max(count, 1), count, u_c, v_c, f_x, f_y)
        rows[0, u] = n_x
        rows[1, u] = n_y
        rows[2, u] = n_z


@pixel
def gradient_normal(z, valid, v, u, g_u, g_v, f_x, f_y, c_x, c_y, reflect, median, buf, fill, out):
    """3F2N's unit normal at (v, u) from its gradients of inverse depth (g_u, g_v), any neighbours missing:
    n_z by :func:`third_nz`, :func:`fronto_parallel_fallback`, the camera-facing sign, into ``out``.
    Returns whether it got one (``out`` is left as it was where not)."""
    n_z, count = third_nz(z, valid, v, u, g_u, g_v, c_x, c_y, reflect, median, buf)
    n_x, n_y, n_z = fronto_parallel_fallback(f_x * g_u, f_y * g_v, n_z, count)
    n_x, n_y, n_z = camera_facing(n_x, n_y, n_z, u - c_x, v - c_y, f_x, f_y)
    return write_unit(out, v, u, n_x, n_y, n_z, fill)


@pixel
def generic_pixel(z, valid, v, u, f_x, f_y, c_x, c_y, reflect, fill, median, buf, out):
    """3F2N at a pixel next to the image border or to invalid depth (checks every neighbour)."""
    ok = False
    if valid[v, u]:
        g_u, ok_u = inverse_depth_gradient(z, valid, v, u, 0, 1, reflect)
        g_v, ok_v = inverse_depth_gradient(z, valid, v, u, 1, 0, reflect)
        if ok_u and ok_v:
            ok = gradient_normal(z, valid, v, u, g_u, g_v, f_x, f_y, c_x, c_y, reflect, median, buf, fill, out)
    if not ok:
        fill_pixel(out, v, u, fill)


@pixel
def row_is_dense(rows_valid, v):
    """True if rows v - 1, v, v + 1 exist and hold only valid depth."""
    H = rows_valid.shape[0]
    ok = False
    if v >= 1 and v < H - 1:
        ok = rows_valid[v - 1] and rows_valid[v] and rows_valid[v + 1]
    return ok


@pixel
def interior_run(median, z, v, a, b, f_x, f_y, c_x, c_y, rows, flat, fronto, out):
    """Pixels [a, b) of row v, whose 3x3 neighbourhoods are all valid: the median or the mean path."""
    if median:
        median_run_split(z, v, a, b, f_x, f_y, c_x, c_y, rows, flat, fronto, out)
    else:
        mean_run(z, v, a, b, f_x, f_y, c_x, c_y, rows)
        store_run(out, v, a, b, rows)


@njit
def _tf2n_kernel(z, valid, rows_valid, median, f_x, f_y, c_x, c_y, reflect, fill, out, v0, v1):
    """3F2N: gradients of 1/Z -> eq. 10 per neighbour -> median (or mean) -> unit, one pass over rows v0 .. v1 - 1.

    ``rows_valid[v]``: row v holds only valid depth. Between such rows the interior of a row is one
    run, whose loop starts at the constant 1 (a run starting elsewhere is not vectorised by LLVM).
    """
    H, W = z.shape
    rows = np.empty((3, W), dtype=np.float32)  # a run's normals, component by component
    flat = np.empty(W, dtype=np.bool_)
    fronto = np.zeros(3 * W, dtype=np.float32)  # (0, 0, -1) for a whole row
    fronto[2::3] = -1.0
    buf = np.empty(8)
    for v in range(v0, v1):  # halo: 1 row (3x3 neighbourhoods)
        if row_is_dense(rows_valid, v):
            interior_run(median, z, v, 1, W - 1, f_x, f_y, c_x, c_y, rows, flat, fronto, out)
            generic_pixel(z, valid, v, 0, f_x, f_y, c_x, c_y, reflect, fill, median, buf, out)
            generic_pixel(z, valid, v, W - 1, f_x, f_y, c_x, c_y, reflect, fill, median, buf, out)
            continue
        u = 0
        valid_v, out_v = valid[v], out[v].reshape(-1)
        while u < W:
            end = invalid_end(valid_v, u)
            if end > u:  # no depth here: what generic_pixel gives such pixels, for the whole stretch at once
                fill_pixels(out_v, u, end, fill)
                u = end
            elif all_nine_valid(valid, v, u):
                end = run_end(valid, v, u)
                interior_run(median, z, v, u, end, f_x, f_y, c_x, c_y, rows, flat, fronto, out)
                u = end
            else:
                generic_pixel(z, valid, v, u, f_x, f_y, c_x, c_y, reflect, fill, median, buf, out)
                u += 1


def _camera(cam):
    return float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy)


def three_filters(z, valid, cam, out, *, third="median", border="one-sided", fill=0.0, bands=whole):
    """3F2N (Fan et al., RA-L 2021, eq. 7-11) with the ``third`` filter "mean" or "median", into ``out``.

    ``bands``: how rows are split over threads (see :mod:`surfnorm._bands`)."""
    rows_valid = np.empty(z.shape[0], np.bool_)

    def dense(a, b):
        rows_valid[a:b] = valid[a:b].all(axis=1)

    bands(dense, z.shape[0])
    args = (third == "median", *_camera(cam), border == "reflect", np.float32(fill))
    bands(lambda a, b: _tf2n_kernel(z, valid, rows_valid, *args, out, a, b), z.shape[0])
    return out


@njit
def _sne_kernel(z, valid, f_x, f_y, c_x, c_y, reflect, fill, out, v0, v1):
    """SNE-RoadSeg's estimator: 3F2N gradients and candidates, fused through the polar angle theta (rows v0 .. v1 - 1)."""
    H, W = z.shape
    for v in range(v0, v1):
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


def sne_roadseg(z, valid, cam, out, *, border="one-sided", fill=0.0, bands=whole):
    """SNE-RoadSeg's surface normal estimator (Fan et al., ECCV 2020, Sec. 3.1), into ``out``."""
    args = (*_camera(cam), border == "reflect", np.float32(fill))
    bands(lambda a, b: _sne_kernel(z, valid, *args, out, a, b), z.shape[0])
    return out
