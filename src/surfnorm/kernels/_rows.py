"""Helpers shared by the kernels: clamped reads, a row's span of valid pixels, runs of fully valid pixels, exp,
normalise-and-store, orientation, the point cloud.

Private to :mod:`surfnorm.kernels`; every kernel module imports its shared helpers from here and from
no other kernel module's internals.
"""

from __future__ import annotations

import math
from decimal import Decimal, localcontext

import numpy as np

from .._bands import whole
from .._choices import ORIENTATION_TIE
from .._config import as_float64, njit, pixel, row, select

# --- clamped reads and the finite-difference stencil ------------------------------------------------


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
def valid_span(ok_row):
    """(first, last + 1) of the columns where ``ok_row`` is true (or nonzero); (0, 0) where it is nowhere: the
    columns a row kernel works on when only valid pixels get a value (the rest is fill)."""
    W = ok_row.shape[0]
    a = 0
    while a < W and not ok_row[a]:
        a += 1
    if a == W:
        return 0, 0
    b = W
    while not ok_row[b - 1]:
        b -= 1
    return a, b


# --- runs of pixels whose 3x3 neighbourhood is valid ---------------------------------------------


@pixel
def copy_row(src, dst):
    """dst[:] = src, element by element (a slice assignment may allocate, which row functions may not)."""
    for u in range(dst.shape[0]):
        dst[u] = src[u]


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


# --- exp -----------------------------------------------------------------------------------------


# exp for float32 arguments, evaluated in float64 and rounded once, so that it
# is correctly rounded in practice (and vectorises, unlike a call to libm's
# expf, which also misrounds about 1 argument in 10^4 by one ulp).
# exp(x) = 2^k e^r with k = round(x / ln 2), r = x - k ln 2 (ln 2 split in a
# high part with trailing zero bits, so that k * _LN2_HI is exact, and the
# rest), e^r by its Taylor series to r^13 (|r| <= ln2 / 2: truncation 4e-18).
# The constants are computed once, at 40 digits in a local decimal context (the caller's context is untouched).
with localcontext() as _ctx:
    _ctx.prec = 40
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
    e_r = (
        (
            (
                (
                    (
                        (((((((_C13 * r + _C12) * r + _C11) * r + _C10) * r + _C9) * r + _C8) * r + _C7) * r + _C6) * r
                        + _C5
                    )
                    * r
                    + _C4
                )
                * r
                + _C3
            )
            * r
            + _C2
        )
        * r
        + _C1
    ) * r + _C0  # Horner
    two_k = as_float64((np.int64(k) + 1023) << 52)
    y = np.float32(e_r * two_k)
    return y if x_d == x_d else x


# --- normalise and store -------------------------------------------------------------------------


@pixel
def unit_or_fill(n_x, n_y, n_z, ok, fill):
    """The normalisation of every estimator that ends with one: (n / |n|, True) where ``ok`` and n has a
    direction (0 < |n| < inf), else (fill, fill, fill, False).

    Divided outside the selects (no branches), which LLVM keeps branch-free, so that a loop of it vectorises.
    """
    norm = math.sqrt(n_x * n_x + n_y * n_y + n_z * n_z)
    keep = ok & (norm > 0) & (norm < np.inf)
    u_x, u_y, u_z = n_x / norm, n_y / norm, n_z / norm
    return select(keep, u_x, fill), select(keep, u_y, fill), select(keep, u_z, fill), keep


@pixel
def write_unit(out, v, u, n_x, n_y, n_z, fill):
    """:func:`unit_or_fill` stored at (v, u) of ``out`` (H, W, 3); returns whether n had a direction."""
    x, y, z, keep = unit_or_fill(n_x, n_y, n_z, True, fill)
    out[v, u, 0] = x
    out[v, u, 1] = y
    out[v, u, 2] = z
    return keep


@pixel
def store_unit(out_row, u, n_x, n_y, n_z, ok, fill):
    """:func:`unit_or_fill` stored at u of a row ``out_row`` (W, 3); returns whether stored."""
    x, y, z, keep = unit_or_fill(n_x, n_y, n_z, ok, fill)
    out_row[u, 0] = x
    out_row[u, 1] = y
    out_row[u, 2] = z
    return keep


@pixel
def store_unit_flat(out_flat, i, n_x, n_y, n_z, ok, fill):
    """:func:`unit_or_fill` stored at pixel i of a flat run of pixels (x, y, z, x, y, z, ...); returns whether stored.

    LLVM cannot tell that out[u, 0], out[u, 1], out[u, 2] of a 2-D view do not
    overlap (its strides are run-time values), so it vectorises only the flat form.
    """
    x, y, z, keep = unit_or_fill(n_x, n_y, n_z, ok, fill)
    out_flat[3 * i] = x
    out_flat[3 * i + 1] = y
    out_flat[3 * i + 2] = z
    return keep


@pixel
def fill_pixels(out_flat, a, b, fill):
    """Pixels a .. b - 1 of a flat row of normals (x, y, z, x, y, z, ...) set to ``fill``, what every per-pixel rule
    gives a pixel without depth: the row functions write it so (vectorised) and run their rule on the others only,
    for the same values (an invalid region, such as a rendered object's background, costs no per-pixel rule)."""
    for i in range(3 * a, 3 * b):
        out_flat[i] = fill


@pixel
def fill_pixel(out, v, u, fill):
    out[v, u, 0] = fill
    out[v, u, 1] = fill
    out[v, u, 2] = fill


# --- orientation: which way a normal points ------------------------------------------------------


@pixel
def facing_sign(n_x, n_y, n_z, p_x, p_y, p_z):
    """+1.0 or -1.0: the factor that turns (n_x, n_y, n_z) to face the camera from the point (p_x, p_y, p_z).

    Any positive multiple of n or of P gives the same answer. Float64, no branches (selects only).

    Which way a normal points: one rule, used wherever an estimator has to choose the sign.

    3F2N (and SNE-RoadSeg and SDA-SNE's 3F2N base, which share its last step) and
    the plane fits find a normal up to its sign and turn it to face the camera,
    n . P < 0 with P the pixel's 3D point. Where the normal is (nearly)
    perpendicular to the viewing ray, n . P is a difference of nearly equal
    terms and its sign is decided by rounding: integer depth gives exact ties
    (n . P = 0 in exact arithmetic), and the NumPy and PyTorch backends, or the
    same depth in metres and in millimetres, rounded them to opposite signs
    (a 180-degree difference on 0.1-0.3 % of the pixels of sensor frames).

    The rule, :func:`facing_sign` here and ``surfnorm.torch._ops.facing_sign``:

    1. if |n . P| > t |n| |P| (t = :data:`ORIENTATION_TIE` = 1e-3, i.e. the normal is
       more than 0.06 degrees away from edge-on): the sign that makes n . P < 0;
    2. else (edge-on, both signs face the camera equally little) the first of
       n_z, n_y, n_x (in that order) whose magnitude exceeds t |n| is made
       negative: towards the camera along the optical axis, else "up", else "left".

    Scale-free (both tests are relative), so the same in every unit of depth. t
    is far above the rounding of n . P (float32 candidates in 3F2N: about 1e-7
    relative; float64 elsewhere), and above what the float32 rounding of depth
    in another unit does to an exact tie of integer depth: 3F2N's mean of
    candidates, which divide by 1 mm steps, moves such a normal up to 1e-4 away
    from edge-on (measured on the 3F2N sample read as centimetres, mm against
    float32 metres; with t = 1e-5 that flipped 15 pixels). So exact and rounded
    ties fall in the band the same way; a normal at the band's edge itself can
    still go either way, as at any rule's boundary (a sign cannot be chosen
    continuously for all directions). The folded angular error of the
    benchmarks is unchanged by the sign: on the 12 frames of the 3F2N sample the
    rule turns only edge-on normals around (measured with
    ``benchmarks/orientation_ties.py``).
    """
    d = n_x * p_x + n_y * p_y + n_z * p_z
    t2 = ORIENTATION_TIE * ORIENTATION_TIE * (n_x * n_x + n_y * n_y + n_z * n_z)
    edge_on = d * d <= t2 * (p_x * p_x + p_y * p_y + p_z * p_z)
    key = n_z if n_z * n_z > t2 else (n_y if n_y * n_y > t2 else n_x)
    key = key if edge_on else d
    return -1.0 if key > 0.0 else 1.0


@pixel
def camera_facing(n_x, n_y, n_z, u_c, v_c, f_x, f_y):
    """(n_x, n_y, n_z) turned, if needed, to face the camera (:func:`facing_sign`).

    P = Z (u_c / f_x, v_c / f_y, 1) enters as its positive multiple P f_x f_y / Z.
    """
    s = facing_sign(n_x, n_y, n_z, u_c * f_y, v_c * f_x, f_x * f_y)
    return s * n_x, s * n_y, s * n_z


# --- pixel coordinates and the organised point cloud ----------------------------------------------


@pixel
def centred_columns(W, c_x):
    """u - c_x for every column, as float32 (one array instead of one conversion per pixel)."""
    u_c = np.empty(W, dtype=np.float32)
    for u in range(W):
        u_c[u] = np.float32(u - c_x)
    return u_c


@njit
def _point_cloud_kernel(z, valid, f_x, f_y, c_x, c_y, pad, P, P_valid, v0, v1):
    """P[:, v + pad, u + pad] = z K^-1 [u, v, 1]^T (eq. 3) in float64, in a border of ``pad`` invalid pixels.

    Where depth is invalid (and in the border) P is 0 and P_valid False; z is not read there. Image rows
    v0 .. v1 - 1 (the first band also writes the top border, the last the bottom one).
    """
    H, W = z.shape
    r0 = v0 + pad if v0 > 0 else 0
    r1 = v1 + pad if v1 < H else H + 2 * pad
    P[:, r0:r1, :] = 0.0
    P_valid[r0:r1, :] = False
    for v in range(v0, v1):
        y_ray = (v - c_y) / f_y
        for u in range(W):
            if valid[v, u]:
                d = np.float64(z[v, u])
                P[0, v + pad, u + pad] = d * ((u - c_x) / f_x)
                P[1, v + pad, u + pad] = d * y_ray
                P[2, v + pad, u + pad] = d
                P_valid[v + pad, u + pad] = True


def point_cloud(z, valid, cam, pad=0, bands=whole):
    """The organised point cloud of validated depth ``z``: P (3, H + 2 pad, W + 2 pad), P_valid (H + 2 pad, W + 2 pad).

    P holds x, y, z planes (contiguous rows, so that row loops vectorise) in float64; it is zero
    where depth is invalid and in the border of ``pad`` pixels, which lets the kernels visit a
    neighbourhood without bounds checks.
    """
    H, W = z.shape
    P = np.empty((3, H + 2 * pad, W + 2 * pad), dtype=np.float64)
    P_valid = np.empty((H + 2 * pad, W + 2 * pad), dtype=np.bool_)
    f = (float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy))
    bands(lambda a, b: _point_cloud_kernel(z, valid, *f, pad, P, P_valid, a, b), H)
    return P, P_valid
