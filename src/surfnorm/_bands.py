"""One frame on several threads: row bands.

A method that declares ``bands=True`` (see :class:`surfnorm.methods.Method`)
takes a keyword ``bands``: a function ``bands(stage, H, weights=None)`` that
calls ``stage(start, stop)`` for row bands that cover rows 0 .. H - 1 and
returns their results in order, on several threads at once (bands of equal
rows, or of equal sums of ``weights``, a cost per row, where the stage gives
them). Each stage of the method
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

import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np

#: Logical cores, read once (``os.cpu_count`` reads a file of the system each time: 5 us, twice a call).
CORES = os.cpu_count() or 1

#: Fewest rows in a band: a band costs a task on the thread pool (tens of microseconds) and the
#: rows that a rolling-buffer kernel primes; below this a frame stays on fewer threads.
MIN_ROWS = 32


# Thread pools for stacks of frames, kept between calls: starting two threads and stopping them costs about
# 0.5 ms (measured), 5 % of a batch of 16 d2nt_basic frames on 2 threads. Only pools of up to one thread per
# core are kept. A forked child forgets them: its copies have no threads behind them.
_pools: dict[int, ThreadPoolExecutor] = {}
_pools_lock = threading.Lock()


def _forget_pools() -> None:
    global _pools_lock
    _pools.clear()
    _pools_lock = threading.Lock()  # another thread may have held it at the fork


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pools)


def map_threads(func, n: int, workers: int) -> None:
    """``func(i)`` for i in range(n) on ``workers`` threads; the first exception is raised here."""
    if workers > CORES:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            list(pool.map(func, range(n)))
        return
    with _pools_lock:
        if workers not in _pools:
            _pools[workers] = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="surfnorm")
        pool = _pools[workers]
    list(pool.map(func, range(n)))


def split_with_caller(func, n: int) -> None:
    """``func(i)`` for i in range(n): i = 0 on the calling thread, the others on a kept pool of n - 1 threads at the
    same time (the caller's caches already hold the frame, and one thread fewer is woken); every call has ended
    when this returns, and the first exception (in the order of i) is raised here."""
    if n - 1 > CORES:
        map_threads(func, n, n)
        return
    with _pools_lock:
        if n - 1 not in _pools:
            _pools[n - 1] = ThreadPoolExecutor(max_workers=n - 1, thread_name_prefix="surfnorm")
        pool = _pools[n - 1]
    futures = [pool.submit(func, i) for i in range(1, n)]
    errors: list[BaseException] = []
    try:
        func(0)
    except BaseException as exc:  # the other calls still run to their end before this one is raised
        errors.append(exc)
    for future in futures:
        try:
            future.result()
        except BaseException as exc:
            errors.append(exc)
    if errors:
        raise errors[0]


def spans(n_rows: int, workers: int, min_rows: int | None = None, weights=None) -> list[tuple[int, int]]:
    """Row bands [start, stop) covering ``n_rows`` rows: at most ``workers``, each at least ``min_rows``
    (default :data:`MIN_ROWS`; one band if there are fewer rows), as equal as possible: in rows, or in the
    sum of ``weights`` (one non-negative number per row: its cost) where given.

    Weights matter where the work is uneven: a LiDAR frame's upper rows are nearly empty, and equal row
    counts gave one thread a third of the work and the other two thirds.
    """
    least = max(1, MIN_ROWS if min_rows is None else min_rows)
    n = max(1, min(workers, n_rows // least))
    if weights is None or n == 1:
        edges = [n_rows * i // n for i in range(n + 1)]
    else:
        cum = np.cumsum(np.asarray(weights, np.float64))
        # band i ends after the first row where the running cost reaches i / n of the total
        edges = [0] + [int(np.searchsorted(cum, cum[-1] * i / n)) + 1 for i in range(1, n)] + [n_rows]
        for i in range(1, n):  # each band at least ``least`` rows, as many as the bands after it need
            edges[i] = min(max(edges[i], edges[i - 1] + least), n_rows - (n - i) * least)
    return [(edges[i], edges[i + 1]) for i in range(n)]


def whole(stage, n_rows: int, weights=None) -> list:
    """``bands`` on one thread: the stage over every row at once (``weights``: see :func:`spans`)."""
    return [stage(0, n_rows)]


def on_threads(workers: int):
    """A ``bands`` function that splits every stage into up to ``workers`` row bands run side by side."""
    if workers <= 1:
        return whole

    def bands(stage, n_rows: int, weights=None) -> list:
        parts = spans(n_rows, workers, weights=weights)
        if len(parts) == 1:
            return [stage(0, n_rows)]
        results = [None] * len(parts)

        def one(i):
            results[i] = stage(*parts[i])

        split_with_caller(one, len(parts))
        return results

    return bands


class Part:
    """A value that the bands of one frame need, made once, by the first thread that takes it (``take``, or
    ``result``, which makes it where nobody has and else waits for it), so that a waiting band's thread may do
    a piece of another band's work (see :class:`Offers`). An error is raised to every thread that asks for the
    result. ``done``: made already (``result`` then returns at once)."""

    def __init__(self, func):
        self._func = func
        self._lock = threading.Lock()
        self._taken = False
        self._done = threading.Event()
        self._value = None
        self._error: BaseException | None = None

    def take(self) -> bool:
        """Run it here unless a thread has taken it already (False then)."""
        with self._lock:
            if self._taken:
                return False
            self._taken = True
        try:
            self._value = self._func()
        except BaseException as exc:  # raised where the result is asked for
            self._error = exc
        finally:
            self._done.set()
        return True

    def finish(self) -> None:
        """Return once nobody runs it: where nobody has taken it, it is taken without being run (``result`` then
        raises); else this waits for its end."""
        with self._lock:
            if not self._taken:
                self._taken = True
                self._error = RuntimeError("a part given up before anybody ran it")
                self._done.set()
                return
        self._done.wait()

    @property
    def done(self) -> bool:
        return self._done.is_set()

    def result(self):
        if not self.take():
            self._done.wait()
        if self._error is not None:
            raise self._error
        return self._value


class Offers:
    """Parts that the band measuring something all bands need (the noise of a frame) hands to the bands waiting
    for it: ``open`` when it starts measuring, ``offer`` parts meanwhile, ``close`` when done; a waiting band
    calls ``help``, which returns once closed, or at once where nobody has started measuring (a ``bands`` that
    runs the bands one after another: nobody else would). A part nobody took is run by its owner
    (:meth:`Part.result`), so nothing ever waits for a thread that is not working on it."""

    def __init__(self):
        self._cond = threading.Condition()
        self._parts: list[Part] = []
        self._open = False
        self._closed = False

    def open(self) -> None:
        with self._cond:
            self._open = True

    def offer(self, part: Part, first: bool = False) -> Part:
        """Hand ``part`` to a waiting band: after the parts offered before it, or before them (``first``: a part the
        measuring band will wait for soonest)."""
        with self._cond:
            self._parts.insert(0 if first else len(self._parts), part)
            self._cond.notify()
        return part

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def help(self, wait: bool = True) -> None:
        """Run the parts offered until the measuring ends (or, not ``wait``: those offered already, then return)."""
        while True:
            with self._cond:
                while wait and not self._parts and self._open and not self._closed:
                    self._cond.wait()
                if not self._parts:
                    return
                part = self._parts.pop(0)
            part.take()
