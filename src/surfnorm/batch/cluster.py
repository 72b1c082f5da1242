"""Run ``convert`` on a Dask cluster: shards of files, streamed results, nothing lost when a worker dies.

``surfnorm.convert(..., client=client)`` and ``surfnorm convert ... --cluster
ADDRESS`` / ``--local-cluster N`` come here. Dask is an optional extra
(``pip install "surfnorm[dask]"``); this module is imported only when a
cluster is asked for, and ``import surfnorm`` never imports it.

How the work is cut
-------------------
The files are cut into shards of ``shard_size`` consecutive tasks; each shard
is one Dask task that calls :func:`surfnorm.batch.tasks.convert_file` on its files
in turn, on whichever worker the scheduler picks. Results come back shard by
shard as shards finish (``as_completed``), and every file's result goes to the
same ``on_result`` callback as on the local path, so the progress bar moves
as work completes. See :func:`default_shard_size` for the trade-off.

Why a dead worker loses nothing
-------------------------------
* When a worker process dies (killed, out of memory, a crash in a native
  library) the scheduler reschedules the shards it was running or holding on
  the other workers (and on the worker the nanny restarts). Dask allows a
  task ``distributed.scheduler.allowed-failures`` such deaths (default 3)
  before it gives up with ``KilledWorker``; when it does, the shard's files are
  tried again one file per task, one such task at a time, so that a single
  file that kills every worker that reads it (a frame too large for the
  worker's memory, a file that crashes a native decoder) ends up as one error
  naming that file, and the rest of its shard is converted.
* A retried shard is idempotent, by three properties of ``convert_file``:
  (1) outputs are written to a temporary file and renamed over the target, so
  an output path holds either nothing or a complete file; (2) an output that
  already exists is skipped, so the files the dead attempt finished are not
  redone; (3) the bytes written are a deterministic function of the input
  and the settings, so even when two attempts of one shard overlap (a worker
  the scheduler gave up on that is still running), both renames put the same
  bytes in place: no file is ever written twice with different content.
* A process killed between creating its temporary file and the rename leaves
  that temporary file behind (its cleanup never runs). When all shards are
  done, the temporary files beside the planned outputs are removed, as
  :func:`surfnorm.batch.run.convert` does before a run.

Inputs are read and outputs written by the workers, and the client plans the
tasks (lists input folders, creates the output folder, sweeps temporaries):
the paths must name the same files on every worker and on the machine that
runs ``convert`` (a shared filesystem, e.g. from a cluster's login node).
"""

from __future__ import annotations

import math
import uuid
from collections import deque
from contextlib import contextmanager
from typing import Callable, Iterator, Sequence

from ..errors import InputError, MissingDependencyError
from . import tasks as tasks_module
from .tasks import FileResult, remove_stale_temporaries

__all__ = ["run_on_dask", "default_shard_size", "cluster_client", "INSTALL_HINT"]

INSTALL_HINT = 'pip install "surfnorm[dask]"'

#: Shards per worker thread that the default aims for: enough that the end of
#: the run stays balanced (no worker finishing a long shard while the others
#: idle) and that the progress bar moves.
SHARDS_PER_THREAD = 4
#: Smallest default shard: a Dask task costs the scheduler about a millisecond
#: plus a network round trip; 8 files of even a small frame take longer.
MIN_SHARD = 8
#: Largest default shard: progress arrives at least every 64 files per thread,
#: and a million files make about 16,000 tasks, which a scheduler handles well.
MAX_SHARD = 64


def _require_distributed():
    """Import ``distributed`` or say how to install it."""
    try:
        import distributed
    except ImportError as exc:
        raise MissingDependencyError(
            f"running on a Dask cluster needs dask.distributed, which is not installed; install it with: {INSTALL_HINT}"
        ) from exc
    return distributed


def default_shard_size(n_tasks: int, n_threads: int) -> int:
    """The shard size used when none is given: ``SHARDS_PER_THREAD`` shards per worker thread, within [8, 64].

    The trade-off: every Dask task costs the scheduler about a millisecond and
    a round trip, so shards of many files make scheduling negligible next to
    the work (one 480x640 frame takes tens to hundreds of milliseconds to read,
    estimate and write). Small shards balance the end of the run, move the
    progress bar more often, and put fewer files on a worker that may die; a
    dead worker costs little either way: its shard is retried elsewhere and
    skips the files it had finished, so only the file being written is redone.
    ``n_threads`` is the cluster's worker threads when the run starts (an
    adaptive cluster may have none yet: then shards are ``MAX_SHARD`` long).
    """
    per_thread = math.ceil(n_tasks / (SHARDS_PER_THREAD * max(1, n_threads)))
    return max(MIN_SHARD, min(MAX_SHARD, per_thread))


def _convert_shard(tasks, settings):
    """One Dask task: convert ``tasks`` in order."""
    tasks_module.one_thread_per_frame()  # the cluster's threads already run shards side by side
    return [tasks_module.convert_file(task, settings) for task in tasks]


def _shards(tasks: Sequence, size: int) -> list[list]:
    return [list(tasks[i : i + size]) for i in range(0, len(tasks), size)]


def run_on_dask(tasks, settings, client, on_result: Callable, *, shard_size: int | None = None) -> list:
    """Convert ``tasks`` on the Dask cluster behind ``client``; return their results in task order.

    Parameters
    ----------
    tasks : sequence of ConvertTask
        From :func:`surfnorm.batch.tasks.plan_tasks`; the paths must be visible to
        every worker.
    settings : ConvertSettings
        Sent to the workers with every shard.
    client : distributed.Client
        Connected to the scheduler that runs the work.
    on_result : callable
        Called in this process with each file's ``FileResult`` as its shard
        finishes (the progress callback of the local path).
    shard_size : int, optional
        Files per Dask task; :func:`default_shard_size` when omitted.

    Returns
    -------
    list of FileResult
        One per task, in the order of ``tasks``. A file that kept killing
        workers, or whose conversion raised an exception that escaped
        ``convert_file``, is an ``"error"`` result saying so.
    """
    distributed = _require_distributed()
    from .._validate import check_positive_int

    tasks = list(tasks)
    if shard_size is None:
        shard_size = default_shard_size(len(tasks), sum(client.nthreads().values()))
    else:
        shard_size = check_positive_int("shard_size", shard_size)
    if not tasks:
        return []

    run_id = uuid.uuid4().hex[:12]
    position = {id(task): i for i, task in enumerate(tasks)}
    results: list = [None] * len(tasks)
    shard_of = {}  # future key -> its tasks
    suspects: deque = deque()  # files of shards that kept killing workers, to be tried one at a time
    lane = None  # key of the one suspect in flight
    counter = 0

    def submit(shard):
        nonlocal counter
        counter += 1
        future = client.submit(_convert_shard, shard, settings, key=f"surfnorm-convert-{run_id}-{counter}", pure=False)
        shard_of[future.key] = shard
        return future

    pending = distributed.as_completed([submit(shard) for shard in _shards(tasks, shard_size)])
    for future in pending:
        shard = shard_of.pop(future.key)
        alone = future.key == lane
        if alone:
            lane = None
        try:
            shard_results = future.result()
        except distributed.KilledWorker as exc:
            if not alone:
                # Workers died each time they ran this shard: one of its files may crash or exhaust
                # every worker. Try its files one task at a time, never two suspects together, so
                # that a file is blamed only for deaths while it ran as the only suspect.
                suspects.extend(shard)
                shard_results = []
            else:
                why = "the worker process died each time it converted this file (out of memory, or a crash in a native library?)"
                shard_results = [FileResult.error(shard[0], f"{why}: {exc}")]
        except Exception as exc:
            if future.status != "error":  # cancelled, or the client lost the scheduler: not the files' fault
                raise
            if len(shard) > 1:
                # convert_file returns its errors, so this one escaped it (a worker that cannot import
                # a dependency, say): run the files one per task so each gets its own result
                for task in shard:
                    pending.add(submit([task]))
                shard_results = []
            else:
                shard_results = [FileResult.error(shard[0], f"failed on a worker: {type(exc).__name__}: {exc}")]
        finally:
            future.release()
        for task, result in zip(shard, shard_results):
            results[position[id(task)]] = result
            on_result(result)
        if lane is None and suspects:
            suspect = submit([suspects.popleft()])
            lane = suspect.key
            pending.add(suspect)
    # A worker killed between creating a temporary file and renaming it left that file behind; the
    # outputs are complete now, so what remains beside them is debris of dead attempts.
    remove_stale_temporaries(tasks)
    return results


@contextmanager
def cluster_client(
    address: str | None = None, *, local_workers: int | None = None, timeout: float | None = None
) -> Iterator:
    """A ``distributed.Client`` for the CLI: to the scheduler at ``address``, or to a new LocalCluster.

    ``local_workers`` starts a LocalCluster of that many single-threaded worker
    processes on this machine (closed again on exit). Exactly one of the two
    must be given.
    """
    from .._validate import check_positive_int

    distributed = _require_distributed()
    if (address is None) == (local_workers is None):
        raise InputError(
            f"cluster_client: expected exactly one of address= and local_workers=, got address={address!r}, local_workers={local_workers!r}"
        )
    cluster = None
    if address is not None:
        try:
            kwargs = {} if timeout is None else {"timeout": timeout}  # else distributed.comm.timeouts.connect
            client = distributed.Client(address, **kwargs)
        except (OSError, TimeoutError) as exc:
            raise ConnectionError(f"cluster address {address!r}: no Dask scheduler answered there ({exc})") from exc
        except (ValueError, TypeError) as exc:  # distributed's own words for a malformed address
            raise InputError(
                f"cluster address: expected a Dask scheduler address such as tcp://host:8786, got {address!r} ({exc})"
            ) from exc
    else:
        n = check_positive_int("local_workers", local_workers)
        # ":0": any free port for the scheduler's HTTP server (8787 may be another cluster's)
        cluster = distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0")
        client = distributed.Client(cluster)
    try:
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
