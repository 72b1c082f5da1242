"""Batch conversion: many depth files to normal files, in parallel, restartable.

:func:`convert` plans the tasks (:mod:`surfnorm.batch.tasks`), removes what a
killed run left, and runs them in a local process pool, or on a Dask cluster
(:mod:`surfnorm.batch.cluster`), calling ``progress(result)`` as each file
finishes.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable

from ..errors import InputError
from ..methods import DEFAULT_METHOD
from .tasks import (
    ConvertSettings,
    ConvertSummary,
    FileResult,
    convert_file,
    one_thread_per_frame,
    plan_tasks,
    remove_stale_temporaries,
)

__all__ = ["convert"]


def _check_output_dir(output_dir: Path):
    if output_dir.exists() and not output_dir.is_dir():
        raise InputError(f"output_dir: expected a folder, got the file {output_dir}")
    try:
        output_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"output_dir: cannot create the folder {output_dir} ({exc.strerror or exc})") from exc
    if not os.access(output_dir, os.W_OK | os.X_OK):
        raise InputError(f"output_dir: cannot write into {output_dir} (Permission denied)")


def _settings(given: ConvertSettings) -> ConvertSettings:
    """``given`` (the arguments of :func:`convert` as passed) checked, with its intrinsics resolved."""
    from dataclasses import replace

    from .._validate import check_bool, check_choice, check_positive
    from ..io.depth import _check_raw_options
    from ..io.intrinsics import resolve_intrinsics
    from ..io.normals import OUTPUT_FORMATS
    from ..methods import resolve

    resolve(given.method, given.options)  # a wrong method or option fails once, here, not once per file
    check_choice("fmt", given.fmt, OUTPUT_FORMATS)
    depth_scale = given.depth_scale
    if depth_scale is not None:
        depth_scale = check_positive("depth_scale", depth_scale)
    # files of any type: byte_order applies to the .pgm ones among the inputs
    raw = _check_raw_options(None, depth_scale, given.kinect_disparity, given.byte_order, given.sun_rgbd)
    return replace(
        given,
        depth_scale=depth_scale,
        intrinsics=resolve_intrinsics(given.intrinsics),
        scale_invariant=check_bool("scale_invariant", given.scale_invariant),
        overwrite=check_bool("overwrite", given.overwrite),
        kinect_disparity=raw[0],
        sun_rgbd=raw[1],
    )


def _alive(pid: int) -> bool:
    """Whether process ``pid`` is running (a zombie, dead but not yet reaped, counts as dead)."""
    try:
        os.kill(pid, 0)
    except OSError:  # gone, or (PermissionError) the number now belongs to another user's process
        return False
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            return fh.read().rsplit(b")", 1)[1].split()[0] != b"Z"
    except (OSError, IndexError):
        return True


def _die_with(main_pid: int, poll_s: float = 0.5):
    """End this worker process when ``main_pid`` (the process running :func:`convert`) dies, even by SIGKILL.

    Linux: the kernel sends SIGKILL when the worker's parent dies (``prctl(PR_SET_PDEATHSIG)``); the
    parent is ``main_pid`` itself, or the forkserver, which lives as long as the workers do (each
    holds a copy of its lifeline), so on every system a daemon thread also checks twice a second
    that ``main_pid`` is alive. A worker that outlived the run would hold memory and a CPU (and keep
    multiprocessing's resource tracker and forkserver alive) for nothing.
    """
    import signal
    import sys
    import threading
    import time

    if sys.platform.startswith("linux"):
        try:
            import ctypes

            PR_SET_PDEATHSIG = 1
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        except (OSError, AttributeError):  # pragma: no cover - no prctl: the watchdog remains
            pass
    if not _alive(main_pid):  # it died before prctl took effect
        os._exit(1)

    def watch():
        while _alive(main_pid):
            time.sleep(poll_s)
        os._exit(1)

    threading.Thread(target=watch, name="surfnorm-main-watchdog", daemon=True).start()


def _worker_init(main_pid: int | None = None):
    """Set up a worker process.

    Workers ignore Ctrl-C (the parent handles it for the whole pool, see :func:`convert`), die with
    ``main_pid``, and run one frame on one thread.
    """
    import signal

    one_thread_per_frame()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if main_pid is not None:
        _die_with(main_pid)


def _pool_context():
    """The start method of the worker processes.

    fork when this process has one thread (fast, and scripts need no ``if __name__ == "__main__"``);
    otherwise forkserver, because fork() would copy other threads' held locks (e.g. Rich's refresh thread).
    """
    import multiprocessing
    import threading

    methods = multiprocessing.get_all_start_methods()
    if "fork" in methods and threading.active_count() == 1:
        return multiprocessing.get_context("fork")
    return multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")


def _run_in_processes(tasks, settings, jobs: int, done) -> None:
    """:func:`convert`'s tasks on a pool of ``jobs`` processes.

    ``done(i, result)`` for each as it finishes (a worker that died gives an error result). Ctrl-C or an error in
    ``done`` stops the workers at once.
    """
    from concurrent.futures import ProcessPoolExecutor, as_completed

    pool = ProcessPoolExecutor(
        max_workers=min(jobs, len(tasks)),
        mp_context=_pool_context(),
        initializer=_worker_init,
        initargs=(os.getpid(),),
    )
    try:
        futures = {pool.submit(convert_file, t, settings): i for i, t in enumerate(tasks)}
        for fut in as_completed(futures):
            i = futures[fut]
            try:
                result = fut.result()
            except Exception as exc:  # noqa: BLE001 - a worker that died (e.g. out of memory)
                result = FileResult.error(tasks[i], f"worker failed ({type(exc).__name__}: {exc})")
            done(i, result)
    except BaseException:
        # Ctrl-C or an error in a callback: stop now instead of finishing the queue. A file being
        # written is left as a temporary that the next run removes; finished outputs are complete.
        workers = list((getattr(pool, "_processes", None) or {}).values())  # (shutdown forgets them)
        pool.shutdown(wait=False, cancel_futures=True)
        for process in workers:
            process.terminate()
        raise
    pool.shutdown(wait=True)


def convert(
    inputs,
    output_dir,
    *,
    method: str = DEFAULT_METHOD,
    fmt: str = "npy",
    depth_scale: float | None = None,
    intrinsics=None,
    jobs: int = 1,
    client=None,
    shard_size: int | None = None,
    overwrite: bool = False,
    progress: Callable[[FileResult], None] | None = None,
    scale_invariant: bool = False,
    kinect_disparity: bool = False,
    byte_order: str | None = None,
    sun_rgbd: bool = False,
    **options,
) -> ConvertSummary:
    """Convert depth files to normal files; see :func:`plan_tasks` for ``inputs`` and the output names.

    Parameters
    ----------
    inputs : folder, glob pattern or list of depth files
    output_dir : str or Path
        Created if missing.
    method, scale_invariant, **options
        As in :func:`surfnorm.estimate` (e.g. ``dlf="alpha"``, ``fill=nan``).
    fmt : {"npy", "png16", "png8", "ply"}
        Output format: a normal map (see :mod:`surfnorm.io.normals`), or ``"ply"``, a PLY point cloud of the
        pixels that have a normal (:func:`surfnorm.io.write_ply`).
    depth_scale : float, optional
        Divide the stored depth by this (1000 for millimetre PNG, 5000 for TUM).
    intrinsics : Intrinsics, 3x3 matrix, dict or path of an intrinsics file, optional
        The camera of every file (see :func:`surfnorm.io.read_intrinsics`);
        None reads each 3F2N file's ``params.txt``.
    jobs : int
        Processes (1: in this process).
    client : dask.distributed.Client, optional
        Run the tasks on this cluster with ``surfnorm.batch.cluster.run_on_dask`` instead.
    shard_size : int, optional
        With ``client``: files per Dask task (see ``surfnorm.batch.cluster.default_shard_size``).
    overwrite : bool
        Replace outputs that exist instead of skipping them.
    progress : callable, optional
        Called with each :class:`FileResult` as its file finishes (in this process).
    kinect_disparity, byte_order, sun_rgbd
        How raw sensor files are stored, as in :func:`surfnorm.io.read_depth`
        (Kinect v1 disparity; little-endian 16-bit PGM such as NYU Depth v2's raw
        frames; SUN RGB-D's rotated millimetres; ``byte_order`` applies to the
        ``.pgm`` files among the inputs).

    Returns
    -------
    ConvertSummary
        Per-file results in task order; failed files are in ``.errors``, they do not raise.

    Raises
    ------
    InputError
        Bad arguments, no input files, an output folder that is a file or not writable.

    Examples
    --------
    >>> import tempfile, surfnorm
    >>> from surfnorm.io import sample_root
    >>> depth_files, out = str(sample_root() / "*" / "*" / "depth" / "*.bin.gz"), tempfile.TemporaryDirectory()
    >>> summary = surfnorm.convert(depth_files, out.name, method="d2nt_basic")   # each file's params.txt
    >>> summary.written, summary.skipped, summary.errors
    (3, 0, [])
    >>> surfnorm.convert(depth_files, out.name, method="d2nt_basic").skipped   # a re-run skips finished outputs
    3
    >>> out.cleanup()
    """
    given = (method, dict(options), fmt, depth_scale, intrinsics, scale_invariant, overwrite)
    settings = _settings(ConvertSettings(*given, kinect_disparity, byte_order, sun_rgbd))
    if client is not None and not (
        callable(getattr(client, "submit", None)) and callable(getattr(client, "nthreads", None))
    ):
        try:
            import distributed  # noqa: F401
        except ImportError:
            pass  # without Dask, run_on_dask's message (how to install it) is the useful one
        else:
            raise InputError(f"client: expected a dask.distributed.Client, got {type(client).__name__} {client!r:.60}")
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise InputError(f"jobs: expected a positive integer, got {jobs!r}")
    output_dir = Path(output_dir)
    _check_output_dir(output_dir)
    tasks = plan_tasks(inputs, output_dir, fmt)
    if settings.intrinsics is None:
        from ..io.threef2n import params_for

        missing = [t.input for t in tasks if params_for(t.input) is None]
        if missing:
            raise InputError(
                f"intrinsics: expected --intrinsics FILE or --fx --fy --cx --cy "
                f"(no 3F2N params.txt beside {missing[0]}{' and %d more' % (len(missing) - 1) if len(missing) > 1 else ''})"
            )
    remove_stale_temporaries(tasks)
    results: dict[int, FileResult] = {}

    def done(i: int, result: FileResult):
        results[i] = result
        if progress is not None:
            progress(result)

    if client is not None:
        from .cluster import run_on_dask

        index = {(t.input, t.output): i for i, t in enumerate(tasks)}

        def on_result(r: FileResult):
            i = index.get((Path(r.input), Path(r.output)))
            if i is not None and i not in results:
                done(i, r)

        run_on_dask(tasks, settings, client, on_result, shard_size=shard_size)
        for i, t in enumerate(tasks):  # a task the cluster never answered is an error, not a silent gap
            results.setdefault(i, FileResult.error(t, "no result from the Dask cluster"))
    elif jobs == 1 or len(tasks) == 1:
        for i, t in enumerate(tasks):
            done(i, convert_file(t, settings))
    else:
        _run_in_processes(tasks, settings, jobs, done)
    return ConvertSummary([results[i] for i in range(len(tasks))])
