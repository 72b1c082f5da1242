"""MRF-based normal refinement (MNR), Sec. III-C of Feng et al., ICRA 2023 (eq. 16-20).

The MRF energy E (eq. 18) sums a data term Phi (eq. 19) and a smoothness
term Psi (eq. 20), which the local smoothness s_p (eq. 11) weighs. Sec. IV-A simplifies it for real time, and
the authors' code implements that simplification as one rule: each pixel
takes the normal of the pixel among {left, right, up, down, itself} whose
depth is smoothest (smallest |nabla^2 z|). Where p itself is smoothest the
data term wins and its normal stays; near a discontinuity the normal of the
smoothest neighbour replaces it. Ties go in the order left, right, up, down,
self, as in the authors' code.

The DLF defaults to DLF-alpha, as the authors' released code does and as
Table II's best D2NT+MNR row suggests; the text of Sec. IV-A says DLF-beta.
With the 1D DLF, left/right neighbours are scored with the horizontal filter,
up/down with the vertical one, and p with their mean (as in the code).
"""

from __future__ import annotations

import numpy as np

from .._bands import whole
from .._config import njit, pixel, row
from ._rows import box_row, copy_row, fast_row, fill_pixels, segment
from .gradients import dlf_code, laplacian_row

__all__ = ["mnr", "mnr_row", "self_smoothness_row"]


@pixel
def self_smoothness_row(s_h, s_v, one_d, s_self):
    """The score of p itself: the mean of the horizontal and vertical 1D smoothness, or the 3x3 one."""
    if one_d:
        for u in range(s_h.shape[0]):
            s_self[u] = np.float32(0.5) * (s_h[u] + s_v[u])
    else:
        copy_row(s_h, s_self)


@pixel
def challenge(k, s_q, ok, best_s, best, tol):
    """Candidate k (smoothness s_q, ``ok`` if it has a normal) against the best so far: (best_s, best) after it.

    It wins only if smoother by more than ``tol``, so ties (and near-ties, tol > 0) keep the earlier one.
    Written with selects, so that a loop of it vectorises.
    """
    take = ok & (s_q < best_s - tol)
    return (s_q if take else best_s), (k if take else best)


@pixel
def smoothest(s_l, s_r, s_a, s_b, s_c, ok_l, ok_r, ok_a, ok_b, tol):
    """Index of MNR's choice among left, right, up, down (0-3, if ``ok``) and p itself (4), in that order."""
    best_s, best = challenge(0, s_l, ok_l, np.float32(np.inf), 4, tol)
    best_s, best = challenge(1, s_r, ok_r, best_s, best, tol)
    best_s, best = challenge(2, s_a, ok_a, best_s, best, tol)
    best_s, best = challenge(3, s_b, ok_b, best_s, best, tol)
    _, best = challenge(4, s_c, True, best_s, best, tol)
    return best


@pixel
def mnr_pixel(v, H, x, normals, has, scores, tol, fill, out_row):
    """MNR at one pixel of row v, any neighbours missing: the normal of the smoothest of left, right, up, down, self.

    ``normals``, ``has`` and ``scores`` are the rows of :func:`mnr_row`. Candidates are the 4-neighbours that have
    a normal, scored by their precomputed smoothness (s_h for left/right, s_up/s_dn for up/down, s_self
    for p); ties keep the first in that order, as in the authors' code. A
    candidate replaces the best so far only if smoother by more than ``tol``
    (0: strictly smoother; see :func:`mnr_row`). Every candidate is read (at
    clamped columns) before the choice, which then only selects among values
    (see :func:`surfnorm.kernels._rows.clamp`).
    """
    n_up, n_mid, n_dn = normals
    has_up, has_mid, has_dn = has
    s_h, s_up, s_dn, s_self = scores
    W = out_row.shape[0]
    x_l, x_r = max(x - 1, 0), min(x + 1, W - 1)
    ok_l = (x >= 1) & has_mid[x_l]
    ok_r = (x + 1 < W) & has_mid[x_r]
    ok_a = (v >= 1) & has_up[x]
    ok_b = (v + 1 < H) & has_dn[x]
    s_l, s_r, s_a, s_b, s_c = s_h[x_l], s_h[x_r], s_up[x], s_dn[x], s_self[x]
    k = smoothest(s_l, s_r, s_a, s_b, s_c, ok_l, ok_r, ok_a, ok_b, tol)
    keep = has_mid[x]
    for c in range(3):
        n_l, n_r, n_a, n_b, n_c = n_mid[x_l, c], n_mid[x_r, c], n_up[x, c], n_dn[x, c], n_mid[x, c]
        n_k = n_l if k == 0 else n_r if k == 1 else n_a if k == 2 else n_b if k == 3 else n_c
        out_row[x, c] = n_k if keep else fill


@row
def mnr_row(v, H, normals, has, scores, z_row, tie_tol, fill, scratch, out_row):
    """MNR of row v (Sec. IV-A's rule): each pixel with a normal takes the normal of the smoothest of
    [left, right, up, down, itself].

    Strict ``<`` in that order keeps the first candidate on ties, as ``argmin`` in the authors' code. With
    ``tie_tol`` > 0 (the scale-invariant mode) a candidate must be smoother than the best so far by more than
    tie_tol * z_p, so near-ties also keep the first (see :mod:`surfnorm.units`, "Ties"); 0 subtracts nothing,
    bit for bit the exact rule. A branch-free loop where all four neighbours have normals, the per-pixel rule
    :func:`mnr_pixel` elsewhere.

    Parameters
    ----------
    v, H : int
        The row, and the number of rows.
    normals : (n_up, n_mid, n_dn), ndarrays of float32, shape (W, 3)
        Unrefined normals of rows v - 1, v, v + 1 (rows outside the image: any row, never chosen).
    has : (has_up, has_mid, has_dn), ndarrays of bool, shape (W,)
        Whether those pixels have a normal.
    scores : (s_h, s_up, s_dn, s_self), ndarrays of float32, shape (W,)
        Smoothness s_p (eq. 11) of row v that scores the left and right candidates, that of rows v - 1 and
        v + 1 that scores the up and down candidates, and the score of p itself (:func:`self_smoothness_row`).
    z_row : ndarray of float32, shape (W,)
        Depth of row v (for ``tie_tol``).
    tie_tol : float32
        Relative near-tie tolerance; 0 in the paper-faithful mode.
    fill : float32
        Value written where p has no normal.
    scratch : (col, runs, choice), ndarrays
        Scratch: bool (W,), int64 (W // 2 + 1, 2), and int32 (3 W,) for each pixel's choice, three times.
    out_row : ndarray of float32, shape (W, 3)
        Row v of the refined output (must not alias ``n_mid``).
    """
    n_up, n_mid, n_dn = normals
    has_up, has_mid, has_dn = has
    s_h, s_up, s_dn, s_self = scores
    col, runs, choice = scratch
    W = out_row.shape[0]
    n_runs = box_row(has_up, has_mid, has_dn, v >= 1 and v < H - 1, col, runs)
    up_flat, mid_flat, dn_flat, out_flat = (
        n_up.reshape(3 * W),
        n_mid.reshape(3 * W),
        n_dn.reshape(3 * W),
        out_row.reshape(3 * W),
    )
    u = 0
    for k in range(n_runs + 1):
        a, b = segment(runs, n_runs, k, W)
        fill_pixels(out_flat, u, a, fill)  # pixels without a normal (the rule's value for them)
        for x in range(u, a):
            if has_mid[x]:
                mnr_pixel(v, H, x, normals, has, scores, tie_tol * z_row[x], fill, out_row)
        if b > a:  # all four neighbours have normals: branch-free argmin (views start at a: see laplacian_row)
            s_l, s_r, s_a, s_b, s_c = s_h[a - 1 : b - 1], s_h[a + 1 : b + 1], s_up[a:b], s_dn[a:b], s_self[a:b]
            z_p = z_row[a:b]
            n_l, n_r = mid_flat[3 * (a - 1) : 3 * (b - 1)], mid_flat[3 * (a + 1) : 3 * (b + 1)]
            n_a, n_b, n_c = up_flat[3 * a : 3 * b], dn_flat[3 * a : 3 * b], mid_flat[3 * a : 3 * b]
            run_out = out_flat[3 * a : 3 * b]
            run_choice = choice[3 * a : 3 * b]
            for i in range(b - a):
                best = smoothest(s_l[i], s_r[i], s_a[i], s_b[i], s_c[i], True, True, True, True, tie_tol * z_p[i])
                run_choice[3 * i] = best
                run_choice[3 * i + 1] = best
                run_choice[3 * i + 2] = best
            # Then copy the chosen normals, one float at a time: all five candidates loaded, then selected.
            # (A load inside a branch, a loop not starting at 0, or more arrays per loop, and LLVM does not
            # vectorise: "cannot identify array bounds" / "too many SCEV assumptions".)
            for j in range(3 * (b - a)):
                best = run_choice[j]
                l_j, r_j, a_j, b_j, c_j = n_l[j], n_r[j], n_a[j], n_b[j], n_c[j]
                run_out[j] = l_j if best == 0 else r_j if best == 1 else a_j if best == 2 else b_j if best == 3 else c_j
        u = b


@njit
def _mnr_kernel(z, valid, has_normal, normals, dlf, tie_tol, fill, out, v0, v1):
    """MNR of rows v0 .. v1 - 1 of a normal map, row by row; smoothness computed once per pixel into rolling rows.

    Halo: row v reads the normals of rows v - 1 .. v + 1 and the smoothness of rows v - 1 .. v + 1 (each from
    its 3x3 neighbourhood of depth), so a band starting at v0 > 0 first prepares row v0 - 1.
    """
    H, W = z.shape
    col = np.empty(W, np.bool_)
    runs, n_runs = np.empty((3, W // 2 + 1, 2), np.int64), np.zeros(3, np.int64)
    mruns, choice = np.empty((W // 2 + 1, 2), np.int64), np.empty(3 * W, np.int32)
    s_v = np.empty((3, W), np.float32)
    s_h, s_self = np.empty(W, np.float32), np.empty(W, np.float32)
    for r in range(max(v0 - 1, 0), v0 + 1):
        n_runs[r % 3] = fast_row(valid, r, col, runs[r % 3])
        laplacian_row(z, valid, r, runs[r % 3], n_runs[r % 3], dlf, np.int64(1), s_v[r % 3])
    for v in range(v0, v1):
        if v + 1 < H:
            j = (v + 1) % 3
            n_runs[j] = fast_row(valid, v + 1, col, runs[j])
            laplacian_row(z, valid, v + 1, runs[j], n_runs[j], dlf, np.int64(1), s_v[j])
        j = v % 3
        if dlf == 0:
            laplacian_row(z, valid, v, runs[j], n_runs[j], np.int64(0), np.int64(0), s_h)
        else:
            s_h[:] = s_v[j]
        self_smoothness_row(s_h, s_v[j], dlf == 0, s_self)
        up, dn = max(v - 1, 0), min(v + 1, H - 1)
        rows = (normals[up], normals[v], normals[dn])
        has_rows = (has_normal[up], has_normal[v], has_normal[dn])
        scores = (s_h, s_v[(v - 1) % 3], s_v[(v + 1) % 3], s_self)
        mnr_row(v, H, rows, has_rows, scores, z[v], tie_tol, fill, (col, mruns, choice), out[v])


def has_normal_map(normals: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Pixels with usable depth and a finite, non-zero normal."""
    with np.errstate(invalid="ignore", over="ignore"):
        sq = np.einsum("hwc,hwc->hw", normals, normals)
        return np.ascontiguousarray(valid & np.isfinite(sq) & (sq > 0))


def mnr(z, valid, normals, out, *, dlf="alpha", fill=0.0, tie_tol=0.0, bands=whole):
    """MNR on ``normals`` (H, W, 3) guided by depth ``z``, into ``out`` (must not alias ``normals``).

    ``tie_tol``: relative near-tie tolerance of the scale-invariant mode (see :func:`mnr_row`).
    ``bands``: how rows are split over threads (see :mod:`surfnorm._bands`); two stages.
    """
    has_normal = np.empty(valid.shape, np.bool_)

    def has(a, b):
        has_normal[a:b] = has_normal_map(normals[a:b], valid[a:b])

    bands(has, z.shape[0])
    args = (dlf_code(dlf), np.float32(tie_tol), np.float32(fill))
    bands(lambda a, b: _mnr_kernel(z, valid, has_normal, normals, *args, out, a, b), z.shape[0])
    return out
