"""One frame on several threads: row bands.

A method that declares ``bands=True`` (see :class:`surfnorm.methods.Method`)
takes a keyword ``bands``: a function ``bands(stage, H)`` that calls
``stage(start, stop)`` for row bands that cover rows 0 .. H - 1 and returns
their results in order, on several threads at once. Each stage of the method
(a Numba kernel that releases the GIL) is written to compute rows
``start .. stop - 1`` of the *whole* frame: it reads the rows around the band
that it needs (its halo: one row for a 3x3 stencil, three for d2nt_v3's DAG
gradients followed by MNR, half the window for the plane fits) from the whole
frame, exactly as when it sweeps every row, and writes only its own rows. So a
band gives the same bits as one sweep, whatever the split, and no row is
computed twice except the rows that a rolling-buffer kernel primes before its
first row. A method of several stages (SDA-SNE's passes, the plane fits' point
cloud then fit, MNR after another method) calls ``bands`` once per stage: the
call returns when every band is done, the barrier between stages.

Cropping each band with a halo and shifting the principal point instead would
not give the same bits: the kernels compute ``v - c_y`` in floating point,
and ``(v - o) - (c_y - o)`` rounds differently from ``v - c_y`` for most
calibrated ``c_y``.
"""

from __future__ import annotations

#: Fewest rows in a band: a band costs a task on the thread pool (tens of microseconds) and the
#: rows that a rolling-buffer kernel primes; below this a frame stays on fewer threads.
MIN_ROWS = 32


def spans(n_rows: int, workers: int, min_rows: int | None = None) -> list[tuple[int, int]]:
    """Row bands [start, stop) covering ``n_rows`` rows: at most ``workers``, each at least ``min_rows``
    (default :data:`MIN_ROWS`; one band if there are fewer rows), as equal as possible."""
    n = max(1, min(workers, n_rows // max(1, MIN_ROWS if min_rows is None else min_rows)))
    edges = [n_rows * i // n for i in range(n + 1)]
    return [(edges[i], edges[i + 1]) for i in range(n)]


def whole(stage, n_rows: int) -> list:
    """``bands`` on one thread: the stage over every row at once."""
    return [stage(0, n_rows)]


def on_threads(workers: int):
    """A ``bands`` function that splits every stage into up to ``workers`` row bands run side by side."""
    if workers <= 1:
        return whole

    def bands(stage, n_rows: int) -> list:
        parts = spans(n_rows, workers)
        if len(parts) == 1:
            return [stage(0, n_rows)]
        from ._api import _map

        results = [None] * len(parts)

        def one(i):
            results[i] = stage(*parts[i])

        _map(one, len(parts), len(parts))
        return results

    return bands
