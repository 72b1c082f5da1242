"""D2NT with DAG gradients and MNR (``d2nt_v3``), fused into one sweep over the rows.

The recipe is DAG gradients (eq. 10-14, :mod:`.gradients`) -> D2NT's eq. 9
(:mod:`.translate`) -> MNR (Sec. III-C and IV-A, :mod:`.mnr`); run as three
whole-frame stages it would write the unrefined normals to a full-size
temporary and read it back. Here the unrefined normals of a row are estimated
just before the row below them is refined, and live only in a rolling buffer
of three rows. The same arithmetic as the three stages; tests/test_translate.py checks it against the
naive reference of the three (tests/naive_d2nt.py).
"""

from __future__ import annotations

import numpy as np

from .._aot import ahead_of_time
from .._bands import whole
from .._config import njit, row
from ._rows import centred_columns, copy_row
from .gradients import dlf_code, kernel_tau, laplacian_row, softmin_ratio, softmin_weights_row
from .mnr import mnr_row, self_smoothness_row
from .translate import dag_row, prepare_dag_row

__all__ = ["d2nt_v3"]


@row
def v3_estimate_row(z, valid, q, cam, c_y, dag, mnr_dlf, fill, fill_counts, slots, scratch):
    """d2nt_v3, step 1 for row q: the row data of row q + 1, then the unrefined normals of row q.

    Rows live in rolling slots: row data (fast runs, softmin weights, MNR smoothness) of row r in slot r % 4,
    unrefined normals of row r in slot r % 3 (see :func:`_d2nt_v3_kernel`).

    Parameters
    ----------
    z, valid : ndarray, shape (H, W)
        Validated depth (float32) and its validity (bool).
    q : int
        The row to estimate.
    cam : (f_x, f_y, u_c)
        Focal lengths (float32), and u - c_x of every column (ndarray of float32, shape (W,)).
    c_y : float32
        Principal point's row.
    dag : (dlf, tau, rel, ratio)
        The DAG filter's DLF index, softness, relative mode and truncation ratio (see :func:`.translate.dag_row`).
    mnr_dlf : int
        Index of MNR's DLF (0: the 1D filters, horizontal for left/right, vertical for up/down).
    fill : float32
        Value written where there is no normal.
    fill_counts : bool
        Whether a pixel holding ``fill`` counts as having a normal for MNR (``fill`` finite and non-zero).
    slots : (runs, n_runs, p_v, sm_v, raw, has)
        The rolling slots: the rows' fast runs and their counts (int64 (4, W // 2 + 1, 2), int64 (4,)); the rows'
        softmin weights with the vertical (or 3x3) smoothness and their MNR smoothness (vertical, or 3x3), float32
        (4, W) each; the unrefined normals, float32 (3, W, 3), and whether each exists (for MNR), bool (3, W).
    scratch : (col, s, p_h, ok_row)
        Scratch: bool (W,); the smoothness and row q's weights with the horizontal smoothness, float32 (W,) each;
        which pixels of row q got a normal, bool (W,).
    """
    dlf, tau, rel, ratio = dag
    runs, n_runs, p_v, sm_v, raw, has = slots
    col, s, p_h, ok_row = scratch
    H, W = z.shape
    if q + 1 < H:
        j = (q + 1) % 4
        n_runs[j] = prepare_dag_row(z, valid, q + 1, dlf, tau, rel, col, runs[j], s, p_v[j])
        laplacian_row(z, valid, q + 1, runs[j], n_runs[j], mnr_dlf, np.int64(1), sm_v[j])
    if q < H:
        j = q % 4
        if dlf == 0:
            laplacian_row(z, valid, q, runs[j], n_runs[j], np.int64(0), np.int64(0), s)
            softmin_weights_row(s, z[q], tau, rel, p_h)
        else:
            copy_row(p_v[j], p_h)
        weights = (p_h, p_v[(q - 1) % 4], p_v[(q + 1) % 4])
        dag_row(z, valid, q, runs[j], n_runs[j], weights, cam, np.float32(q - c_y), ratio, fill, raw[q % 3], ok_row)
        has_q, valid_q = has[q % 3], valid[q]
        for u in range(W):
            has_q[u] = ok_row[u] | (valid_q[u] & fill_counts)


@row
def v3_refine_row(z, valid, v, mnr_dlf, tie_tol, fill, slots, scratch, out_row):
    """d2nt_v3, step 2 for row v: MNR of its unrefined normals into the output row.

    ``z``, ``valid``, ``mnr_dlf``, ``fill``: as in :func:`v3_estimate_row`, which fills the ``slots``.

    Parameters
    ----------
    v : int
        The row to refine.
    tie_tol : float32
        MNR's relative near-tie tolerance (0: exact).
    slots : (runs, n_runs, p_v, sm_v, raw, has)
        The slots of :func:`v3_estimate_row`.
    scratch : (sm_h, s_self, col, mruns, choice)
        Scratch: row v's smoothness scoring left/right and the score of p itself, float32 (W,) each; the scratch
        of :func:`surfnorm.kernels.mnr.mnr_row`.
    out_row : ndarray of float32, shape (W, 3)
        Row v of the output.
    """
    runs, n_runs, _, sm_v, raw, has = slots
    sm_h, s_self, col, mruns, choice = scratch
    H = z.shape[0]
    j = v % 4
    if mnr_dlf == 0:
        laplacian_row(z, valid, v, runs[j], n_runs[j], np.int64(0), np.int64(0), sm_h)
    else:
        copy_row(sm_v[j], sm_h)
    self_smoothness_row(sm_h, sm_v[j], mnr_dlf == 0, s_self)
    rows = (raw[(v - 1) % 3], raw[v % 3], raw[(v + 1) % 3])
    has_rows = (has[(v - 1) % 3], has[v % 3], has[(v + 1) % 3])
    scores = (sm_h, sm_v[(v - 1) % 4], sm_v[(v + 1) % 4], s_self)
    mnr_row(v, H, rows, has_rows, scores, z[v], tie_tol, fill, (col, mruns, choice), out_row)


@ahead_of_time
@njit
def _d2nt_v3_kernel(z, valid, f_x, f_y, c_x, c_y, dlf, tau, rel, ratio, mnr_dlf, tie_tol, fill, out, v0, v1):
    """D2NT with DAG gradients, then MNR (eq. 9-20), fused into one sweep over rows v0 .. v1 - 1 of out.

    The unrefined normals live only in a rolling buffer of 3 rows: row v + 1
    is estimated just before row v is refined (MNR looks one row up and down).
    Row data (fast runs, softmin weights, MNR smoothness) use 4 slots, rows
    v - 1 .. v + 2. Halo: refining row v0 needs the unrefined normals of row
    v0 - 1, which need the weights of row v0 - 2 (3 rows of depth above the
    band); a band starting at v0 > 0 primes rows q0 - 1 and q0 = v0 - 1.
    """
    H, W = z.shape
    u_c = centred_columns(W, c_x)
    col, ok_row = np.empty(W, np.bool_), np.empty(W, np.bool_)
    runs, n_runs = np.empty((4, W // 2 + 1, 2), np.int64), np.zeros(4, np.int64)
    mruns, choice = np.empty((W // 2 + 1, 2), np.int64), np.empty(3 * W, np.int32)
    p_v, sm_v = np.empty((4, W), np.float32), np.empty((4, W), np.float32)
    s, p_h, sm_h, s_self = (
        np.empty(W, np.float32),
        np.empty(W, np.float32),
        np.empty(W, np.float32),
        np.empty(W, np.float32),
    )
    raw, has = np.empty((3, W, 3), np.float32), np.empty((3, W), np.bool_)
    # A pixel whose normal failed holds `fill`; MNR treats it as having a normal when fill is non-zero and finite
    # (as when MNR runs on a finished map): fill_counts.
    fill_sq = fill * fill + fill * fill + fill * fill
    fill_counts = (fill_sq > 0) & (fill_sq < np.inf)
    cam, dag, slots = (f_x, f_y, u_c), (dlf, tau, rel, ratio), (runs, n_runs, p_v, sm_v, raw, has)
    estimate_scratch, refine_scratch = (col, s, p_h, ok_row), (sm_h, s_self, col, mruns, choice)
    q0 = max(v0 - 1, 0)  # the first row estimated
    if q0 > 0:
        j = (q0 - 1) % 4
        n_runs[j] = prepare_dag_row(z, valid, q0 - 1, dlf, tau, rel, col, runs[j], s, p_v[j])
    j = q0 % 4
    n_runs[j] = prepare_dag_row(z, valid, q0, dlf, tau, rel, col, runs[j], s, p_v[j])
    laplacian_row(z, valid, q0, runs[j], n_runs[j], mnr_dlf, np.int64(1), sm_v[j])
    for r in range(q0 - 1, v1):
        # estimate row q = r + 1 (needs the weights of rows q - 1 .. q + 1), then refine row v = r
        v3_estimate_row(z, valid, r + 1, cam, c_y, dag, mnr_dlf, fill, fill_counts, slots, estimate_scratch)
        if r >= v0:
            v3_refine_row(z, valid, r, mnr_dlf, tie_tol, fill, slots, refine_scratch, out[r])


def d2nt_v3(
    z,
    valid,
    cam,
    out,
    *,
    dlf="1d",
    tau=1.0,
    truncate=True,
    mnr_dlf="alpha",
    fill=0.0,
    tie_tol=0.0,
    relative=0.0,
    bands=whole,
):
    """D2NT with DAG gradients and MNR (``d2nt_v3``) in one sweep, into ``out`` (H, W, 3).

    ``tie_tol``: MNR's relative near-tie tolerance of the scale-invariant mode (see :func:`surfnorm.kernels.mnr.mnr_row`);
    ``relative``: DAG's tau relative to each pixel's depth in that mode (see :func:`d2nt`).
    ``bands``: how rows are split over threads (see :mod:`surfnorm._bands`).
    """
    f = (np.float32(cam.fx), np.float32(cam.fy), np.float32(cam.cx), np.float32(cam.cy))
    args = (
        dlf_code(dlf),
        kernel_tau(tau),
        float(relative),
        softmin_ratio(tau, truncate),
        dlf_code(mnr_dlf),
        np.float32(tie_tol),
        np.float32(fill),
    )
    bands(lambda a, b: _d2nt_v3_kernel(z, valid, *f, *args, out, a, b), z.shape[0])
    return out
