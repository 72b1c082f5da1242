"""How the adaptive fit runs a frame: the stride, the row bands on several threads, and what is kept between frames.

Scheduling only: nothing here changes a normal. :func:`choose_stride` picks the fitted pixels' spacing;
:func:`run_bands` hands a frame's rows to the bands of :mod:`surfnorm._bands`, the band on the calling thread
measuring the noise while the others make the integral rows above their own (:class:`surfnorm._bands.Offers`),
weighted by the cost each row took on the last frames of the same size (:class:`Balance`); the rings of integral
rows are kept for the next frame (:func:`release` frees them). The numerics are in
:mod:`surfnorm.kernels.adaptive_fit`, :mod:`surfnorm.kernels._windows` and :mod:`surfnorm.kernels.sensor_noise`.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np

from .._aot import ahead_of_time
from .._bands import Offers, Part, whole
from .._config import njit
from .._constants import MAX_UNREACHED
from ._assembly import CELL, first_fitted_row
from ._spare import Spares
from ._windows import _N_COLUMNS, _N_MOMENTS, integral_positions, prime

__all__ = ["choose_stride", "release", "Balance", "run_bands"]


@ahead_of_time
@njit
def _unreached(valid):
    """(pixels that no valid fitted pixel reaches, valid pixels that are not fitted): see :func:`choose_stride`.

    The valid fitted pixels (even row and column) widened to their 5x5 neighbourhoods, separably: along each
    fitted row (``across``: any within two columns), then down the columns (the fitted rows within two rows of
    a row). Whole rows of bytes at a time, without branches, so that the loops vectorise.
    """
    H, W = valid.shape
    n_rows = (H + 1) // 2
    even = np.zeros(W + 4, np.uint8)  # even[u + 2]: column u is a fitted one; two zeros either side
    even[2 : W + 2 : 2] = 1
    odd = np.ones(W, np.uint8) - even[2 : W + 2]
    fitted = np.zeros(W + 4, np.uint8)
    across = np.zeros((n_rows + 2, W), np.uint8)  # fitted row i at i + 1, with a row of zeros above and below
    for i in range(n_rows):
        row = valid[2 * i]
        for u in range(W):
            fitted[u + 2] = row[u] & even[u + 2]
        out = across[i + 1]
        for u in range(W):
            out[u] = fitted[u] | fitted[u + 1] | fitted[u + 2] | fitted[u + 3] | fitted[u + 4]
    unreached = 0
    others = 0
    for v in range(H):
        row = valid[v]
        i = v // 2
        if v % 2 == 0:  # the pixels of odd columns; fitted rows v - 2, v, v + 2
            up, same, down = across[i], across[i + 1], across[i + 2]
            for u in range(W):
                other = row[u] & odd[u]
                others += other
                unreached += other & ~(up[u] | same[u] | down[u]) & 1
        else:  # every pixel; fitted rows v - 1, v + 1
            up, down = across[i + 1], across[i + 2]
            for u in range(W):
                other = row[u]
                others += other
                unreached += other & ~(up[u] | down[u]) & 1
    return unreached, others


@ahead_of_time
@njit
def _unreached_cells(valid):
    """(pixels that no valid fitted pixel reaches, valid pixels that are not fitted) with ``stride`` ``CELL``: a pixel
    reaches the four corners of its cell (:func:`surfnorm.kernels._assembly.cell_row`). Row by row, branch-free."""
    H, W = valid.shape
    n_cols = (W + CELL - 1) // CELL
    top = np.zeros(n_cols + 1, np.uint8)  # the cell's corners valid: the fitted pixels of the rows above and below
    bottom = np.zeros(n_cols + 1, np.uint8)
    either = np.zeros(W, np.uint8)  # per pixel of a row: any of its cell's corners valid
    not_fitted = np.ones(W, np.uint8)
    not_fitted[::CELL] = 0
    unreached = 0
    others = 0
    for v in range(H):
        if v % CELL == 0:
            t = v
            b = v + CELL
            for j in range(n_cols):
                top[j] = valid[t, CELL * j]
                bottom[j] = valid[b, CELL * j] if b < H else 0
            for u in range(W):
                j = u // CELL
                either[u] = top[j] | top[j + 1] | bottom[j] | bottom[j + 1]
        row = valid[v]
        fitted_row = v % CELL == 0
        for u in range(W):
            other = row[u] & (not_fitted[u] | ~fitted_row & 1)
            others += other
            unreached += other & ~either[u] & 1
    return unreached, others


@ahead_of_time
@njit
def _band_weights(valid, stride, factors):
    """Each row's cost on several threads (see :func:`adaptive_fit`): a quarter of the width, plus its valid
    pixels over ``stride`` on the fitted rows (every ``stride``-th), times its ``factors`` (:class:`Balance`)."""
    H, W = valid.shape
    weights = np.empty(H)
    for v in range(H):
        n = 0
        if v % stride == 0:
            row = valid[v]
            for u in range(W):
                n += row[u]
        weights[v] = (0.25 * W + n / stride) * factors[v]
    return weights


@ahead_of_time
@njit
def _balanced(factors, weights, edges, spent):
    """:meth:`Balance.learn`'s arithmetic, in place on ``factors``: band k (rows edges[k] .. edges[k + 1] - 1)
    took ``spent[k]`` seconds."""
    total = spent.sum() / max(weights.sum(), 1e-300)
    for k in range(spent.shape[0]):
        w = weights[edges[k] : edges[k + 1]].sum()
        if w > 0.0 and spent[k] > 0.0:
            step = math.sqrt(spent[k] / w / total)
            for v in range(edges[k], edges[k + 1]):
                factors[v] *= step
    mean = factors.mean()
    for v in range(factors.shape[0]):
        factors[v] = min(max(factors[v] / mean, 0.25), 4.0)


def choose_stride(valid: np.ndarray) -> int:
    """The default ``stride``: 4 (``CELL``), unless more than MAX_UNREACHED of the valid pixels that are not fitted
    (not on every fourth row and column) have no valid fitted pixel at the corners of their 4x4 cell; then 2,
    unless more than MAX_UNREACHED of the valid pixels that are not fitted (not on an even row and column) have
    no valid fitted pixel in their 5x5 neighbourhood (sparse depth: LiDAR); then 1."""
    H, W = valid.shape
    if H < 2 or W < 2:
        return 1
    valid = np.ascontiguousarray(valid, dtype=np.bool_)
    unreached, others = _unreached_cells(valid)
    if unreached <= MAX_UNREACHED * max(others, 1):
        return CELL
    unreached, others = _unreached(valid)
    return 2 if unreached <= MAX_UNREACHED * max(others, 1) else 1


#: Rings of integral rows kept for the next frame (a 640-pixel row's takes 3.2 MB: mapping its pages in
#: afresh cost about 1 ms a frame); :func:`release` lets them go.
_rings = Spares(64 << 20)


def release() -> None:
    """Free the rings of integral rows kept for the next frame, and forget the bands' balance."""
    _rings.release()
    _balance.forget()


class Balance:
    """Per-row cost factors of one frame on several threads, learnt from the time its bands took, by frame size.

    The band weights (valid pixels per row) miss where the work really lies (planes that widen their
    windows, edges that try the quadrants, the noise measured by the first band, the rows a later band makes
    before its own): at 640x480 the band that finished first waited 0.3-0.5 ms for the other. After a frame,
    each band's rows are weighed by how long the band took for its weight against the mean (square root of
    the ratio: a damped step, factors kept within 1/4 and 4), so the next frame of the same size (a camera's
    stream) splits closer to equal times. The bands give the same bits whatever the split (see
    :mod:`surfnorm._bands`): only the time moves. Kept for the last ``KEEP`` frame sizes.
    """

    KEEP = 8

    def __init__(self):
        self._lock = threading.Lock()
        self._factors: dict = {}

    def factors(self, key):
        with self._lock:
            return self._factors.get(key)

    def learn(self, key, weights: np.ndarray, spent: list) -> None:
        """From the row ``weights`` the bands were split by (factors included) and ``spent``: (first row, end row,
        seconds from the start of the bands to the band's end) of each band."""
        if len(spent) < 2:
            return
        old = self.factors(key)
        factors = np.ones(weights.shape[0]) if old is None else old.copy()
        spent = sorted(spent)
        edges = np.array([v0 for v0, _, _ in spent] + [spent[-1][1]], np.int64)
        _balanced(factors, weights, edges, np.array([t for _, _, t in spent]))
        with self._lock:
            self._factors.pop(key, None)
            if len(self._factors) >= self.KEEP:
                self._factors.pop(next(iter(self._factors)))
            self._factors[key] = factors

    def forget(self) -> None:
        with self._lock:
            self._factors.clear()


_balance = Balance()


def run_bands(frame, bands, tables=None) -> bool:
    """The rows of a frame on ``bands`` (:mod:`surfnorm._bands`); True when every band ran.

    ``frame`` is a :class:`surfnorm.kernels.adaptive_fit.FitPlan`: its depth ``z`` and ``valid``, ``stride``,
    ``r_max`` and ``key`` (the frame's kind for :class:`Balance`), and its three steps. ``frame.measure(offers)``
    returns the frame's noise profile and ``tables(profile)`` (default ``frame.tables``) the tables a band's fit
    needs (None: the frame is not for this method, and nothing is fitted); the band on the calling thread runs
    them once, while the others make the integral rows above their own rows, which do not depend on them, and
    then take its first integral rows and parts of its measuring (``offers``: :class:`surfnorm._bands.Offers`).
    ``frame.fit(v0, v1, work, tables)`` fits rows v0 .. v1 - 1 with ``work`` = (ring, cols, pos, w_scratch, made):
    a ring of 4 r_max + 3 integral rows primed up to row ``made`` (:func:`surfnorm.kernels._windows.prime`).
    """
    z, valid, stride, r_max, key = frame.z, frame.valid, frame.stride, frame.r_max, frame.key
    measure, plan, fit = frame.measure, frame.tables if tables is None else tables, frame.fit
    H, W = z.shape
    # bands waiting for the noise take parts of its measuring (Offers.help) until it is done
    offers = None if bands is whole else Offers()

    def measured():
        if offers is not None:
            offers.open()
        try:
            p = measure(offers)
        finally:
            if offers is not None:
                offers.close()
        return plan(p)

    tables = Part(measured)
    shape = (4 * r_max + 3, _N_MOMENTS, W + 1)
    spent: list = []

    def rows(v0, v1):
        kept = _rings.take(shape)
        ring = kept[0] if kept is not None else np.empty(shape)
        primed = None
        try:
            v_first = first_fitted_row(v0, stride)
            upto = min(H, v_first + 2 * r_max + 1)
            first_read = v_first - 2 * r_max  # the first integral row that the band's windows read
            pos, w_scratch = integral_positions(W, stride), np.empty(W)
            cols = np.empty((_N_COLUMNS, W))

            def primer():
                # in two halves, so that a band stops early where the frame turns out not to be for this method
                made = prime(z, valid, ring, cols, pos, w_scratch, 0, upto // 2, first_read)
                if not (tables.done and tables.result() is None):
                    made = prime(z, valid, ring, cols, pos, w_scratch, made, upto, first_read)
                return made

            if v0 > 0:
                if offers is not None:  # the measuring's first parts, which it waits for, before this band's own rows
                    offers.help(wait=False)
                made = primer()
                if offers is not None:
                    offers.help()
            elif offers is None:
                tables.result()
                made = primer()
            else:  # the calling thread's band measures the noise; a waiting band may make its first integral rows
                primed = offers.offer(Part(primer))
                tables.result()
                made = primed.result()
            got = tables.result()
            if got is None:
                return False
            fit(v0, v1, (ring, cols, pos, w_scratch, made), got)
            return True
        finally:
            if v0 == 0 and offers is not None:  # never leave the other bands waiting for it
                offers.close()
            if primed is not None:
                primed.finish()  # nobody writes the ring once it is given back
            _rings.give(shape, (ring,))
            spent.append((v0, v1, time.perf_counter() - start))

    # A row costs its integral row and bookkeeping (every pixel) and its fits (its valid pixels on the fitted
    # columns, on the fitted rows only): sparse rows (a LiDAR frame's upper part) are cheap, so bands of equal
    # cost, not of equal rows.
    # Then each band's rows weigh what the bands took on the last frames of this size (Balance).
    if bands is whole:
        weights = None
    else:
        factors = _balance.factors(key)
        weights = _band_weights(valid, stride, np.ones(H) if factors is None else factors)
    start = time.perf_counter()
    done = bands(rows, H, weights=weights)
    if weights is not None and all(done):
        _balance.learn(key, weights, spent)
    return all(done)
