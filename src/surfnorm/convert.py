"""Batch conversion: many depth files to normal files, in parallel, restartable.

Three layers, each usable alone (``surfnorm.distributed`` runs the same tasks
on a Dask cluster):

* :func:`plan_tasks` turns a folder, a glob pattern or a list of files into
  :class:`ConvertTask` (input, output) pairs with deterministic output names;
* :func:`convert_file` does one task: read, :func:`surfnorm.estimate`, write
  atomically. It is a pure top-level function of picklable arguments, skips an
  output that exists, and never raises for a bad input file: it returns a
  :class:`FileResult` whose status is ``"error"`` and whose message names it;
* :func:`convert` runs the tasks in a local process pool (or on Dask) and
  calls ``progress(result)`` as each file finishes.

A run killed at any moment leaves complete outputs and, at worst, hidden
temporary files (``.<name>.<random>.tmp<suffix>``) that the next run over the
same outputs removes before it starts; outputs that exist are skipped, so
running the same command again finishes the job. Two runs writing into the
same output folder at the same time are not supported.
"""

from __future__ import annotations

import glob as globlib
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from .camera import Intrinsics
from .errors import InputError, SurfnormError
from .methods import DEFAULT_METHOD

__all__ = ["ConvertTask", "ConvertSettings", "FileResult", "ConvertSummary", "plan_tasks", "convert_file", "convert",
           "STATUSES"]

STATUSES = ("written", "skipped", "error")


@dataclass(frozen=True)
class ConvertTask:
    """One depth file and the normal file it becomes."""

    input: Path
    output: Path


@dataclass(frozen=True)
class ConvertSettings:
    """Everything :func:`convert_file` needs besides the task; picklable (plain values only).

    ``intrinsics`` None means: read the 3F2N ``params.txt`` of each file (beside it,
    or in its object folder: ``<object>/depth/<frame>.bin`` -> ``<object>/params.txt``;
    see :func:`surfnorm.io.threef2n.params_for`).
    """

    method: str = DEFAULT_METHOD
    options: dict = field(default_factory=dict)
    fmt: str = "npy"
    depth_scale: float | None = None
    intrinsics: Intrinsics | None = None
    scale_invariant: bool = False
    overwrite: bool = False
    kinect_disparity: bool = False
    byte_order: str | None = None


@dataclass(frozen=True)
class FileResult:
    """What happened to one file: status is "written", "skipped" (output existed) or "error"."""

    input: Path
    output: Path
    status: str
    message: str = ""


@dataclass
class ConvertSummary:
    """The results of a run, in task order."""

    results: list[FileResult]

    def count(self, status: str) -> int:
        return sum(r.status == status for r in self.results)

    @property
    def written(self) -> int:
        return self.count("written")

    @property
    def skipped(self) -> int:
        return self.count("skipped")

    @property
    def errors(self) -> list[FileResult]:
        return [r for r in self.results if r.status == "error"]

    @property
    def ok(self) -> bool:
        """True when no file failed."""
        return not self.errors


# ---------------------------------------------------------------------------- planning

def _output_stem(path: Path) -> str:
    name = path.name
    return name[: -len(".bin.gz")] if name.lower().endswith(".bin.gz") else path.stem


def _is_depth_file(path: Path) -> bool:
    from .io.depth import DEPTH_SUFFIXES, depth_suffix

    return path.is_file() and depth_suffix(path) in DEPTH_SUFFIXES and not path.name.startswith(".")


def _walk(root: Path) -> list[Path]:
    """Depth files under ``root``, recursively, sorted; unreadable folders are errors, not silently skipped."""
    found = []

    def onerror(exc: OSError):
        raise InputError(f"inputs: cannot list the folder {exc.filename} ({exc.strerror or exc})")

    for dirpath, dirnames, filenames in os.walk(root, onerror=onerror):
        dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
        found += [Path(dirpath) / f for f in filenames if _is_depth_file(Path(dirpath) / f)]
    return sorted(found)


def _glob_root(pattern: str) -> Path:
    parts = Path(pattern).parts
    static = []
    for part in parts:
        if globlib.has_magic(part):
            break
        static.append(part)
    return Path(*static) if static else Path(".")


def _sources(inputs) -> list[tuple[Path, Path]]:
    """(file, the folder its output name is relative to) for every input file."""
    if isinstance(inputs, (str, os.PathLike)):
        text = os.fspath(inputs)
        path = Path(text)
        if path.is_dir():
            if not os.access(path, os.R_OK | os.X_OK):
                raise InputError(f"inputs: cannot list the folder {path} (Permission denied)")
            return [(f, path) for f in _walk(path)]
        if path.exists():
            return [(path, path.parent)]
        if globlib.has_magic(text):
            root = _glob_root(text)
            files = sorted(Path(p) for p in globlib.glob(text, recursive=True))
            return [(f, root) for f in files if _is_depth_file(f)]
        raise InputError(f"inputs: expected a depth file, a folder or a glob pattern, got {text!r}, which does not exist")
    try:
        items = list(inputs)
    except TypeError as exc:
        raise InputError(f"inputs: expected a path, a glob pattern or a list of files, got {type(inputs).__name__}") from exc
    out = []
    for item in items:
        if not isinstance(item, (str, os.PathLike)):
            raise InputError(f"inputs: expected paths in the list, got {type(item).__name__} {item!r}")
        out.append((Path(item), Path(item).parent))
    return out


def plan_tasks(inputs, output_dir, fmt: str = "npy") -> list[ConvertTask]:
    """Pair every input depth file with its output file, in a deterministic order.

    Parameters
    ----------
    inputs : str, Path or list of paths
        A folder (every depth file under it, recursively, sub-folders kept in
        the output), a glob pattern (``"scans/*/depth/*.png"``; the part before
        the first wildcard is the root whose sub-folders are kept) or a list of
        files (outputs side by side in ``output_dir``). A listed file that does
        not exist becomes a task too, and fails by name when run.
    output_dir : str or Path
        Folder of the outputs, ``<relative folder>/<stem>.npy`` or ``.png``
        (``000001.bin.gz`` -> ``000001.npy``).
    fmt : {"npy", "png16", "png8"}

    Raises
    ------
    InputError
        No depth file found, a folder that cannot be listed, two inputs that
        would write the same output, or an output that would replace its input.
    """
    from ._validate import check_choice
    from .io.normals import FORMAT_SUFFIX, NORMAL_FORMATS

    check_choice("fmt", fmt, NORMAL_FORMATS)
    output_dir = Path(output_dir)
    out_root = output_dir.resolve()
    sources = _sources(inputs)
    if isinstance(inputs, (str, os.PathLike)) and not Path(inputs).is_file():
        roots = {r.resolve() for _, r in sources} or {Path(os.fspath(inputs)).resolve()}
        if out_root in roots:
            raise InputError(f"output_dir: expected a folder other than the input folder {os.fspath(inputs)}, got {output_dir}; "
                             "its outputs would be read as inputs by the next run")
        # outputs of an earlier run inside the input folder (e.g. convert data data/normals) are not inputs
        sources = [(f, r) for f, r in sources if out_root not in f.resolve().parents]
    if not sources:
        raise InputError(f"inputs: expected at least one depth file, found none in {os.fspath(inputs) if isinstance(inputs, (str, os.PathLike)) else 'the list'}")
    tasks, seen = [], {}
    for file, root in sources:
        try:
            rel = file.parent.relative_to(root)
        except ValueError:
            rel = Path()
        out = output_dir / rel / (_output_stem(file) + FORMAT_SUFFIX[fmt])
        if out in seen:
            raise InputError(f"inputs: {seen[out]} and {file} would both be written to {out}; "
                             "convert them into different output folders")
        if out.resolve() == file.resolve():
            raise InputError(f"output_dir: writing {out} would replace its input; choose another output folder")
        seen[out] = file
        tasks.append(ConvertTask(file, out))
    return tasks


# ---------------------------------------------------------------------------- one file

# Threads per frame (see surfnorm.estimate): all cores in the calling process; 1 in a worker of a pool
# (processes here, or Dask), which already runs frames side by side.
_frame_threads: int | None = None


def _convert(task: ConvertTask, settings: ConvertSettings) -> str:
    from ._api import estimate
    from .io.depth import depth_suffix, read_depth
    from .io.normals import write_normals
    from .io.threef2n import params_for, read_params

    cam = settings.intrinsics
    if cam is None:
        params = params_for(task.input)
        if params is None:
            raise InputError(f"intrinsics: none given and no 3F2N params.txt beside {task.input} or in the folder above it")
        cam = read_params(params)
    byte_order = settings.byte_order if depth_suffix(task.input) == ".pgm" else None  # other files in the folder
    depth = read_depth(task.input, depth_scale=settings.depth_scale, kinect_disparity=settings.kinect_disparity,
                       byte_order=byte_order)
    normals = estimate(depth, cam, method=settings.method, scale_invariant=settings.scale_invariant,
                       threads=_frame_threads, **settings.options)
    task.output.parent.mkdir(parents=True, exist_ok=True)
    write_normals(task.output, normals, fmt=settings.fmt)
    with np.errstate(invalid="ignore"):
        any_valid = bool((np.isfinite(depth) & (depth > 0)).any())
    return "" if any_valid else "no valid depth: every pixel holds the fill value"


def convert_file(task: ConvertTask, settings: ConvertSettings) -> FileResult:
    """Convert one depth file; never raises for a bad input (status "error", message naming the file).

    The output is skipped when it exists (unless ``settings.overwrite``),
    written atomically otherwise; the same input and settings give the same bytes.
    """
    try:
        if task.output.exists() and not settings.overwrite:
            if task.output.is_dir():
                return FileResult(task.input, task.output, "error", f"{task.input}: output {task.output} exists and is a folder")
            return FileResult(task.input, task.output, "skipped", "output exists")
        return FileResult(task.input, task.output, "written", _convert(task, settings))
    except (SurfnormError, ValueError) as exc:
        message = str(exc)
        if str(task.input) not in message:
            message = f"{task.input}: {message}"
        return FileResult(task.input, task.output, "error", message)
    except OSError as exc:
        where = exc.filename if exc.filename else task.output
        return FileResult(task.input, task.output, "error", f"{task.input}: cannot write {where} ({exc.strerror or exc})")
    except Exception as exc:  # noqa: BLE001 - a bad file must not stop the other thousand
        return FileResult(task.input, task.output, "error", f"{task.input}: unexpected {type(exc).__name__}: {exc}")


# ---------------------------------------------------------------------------- many files

#: The name atomic_write gives its temporary file: ".<name>.<random>.tmp<suffix>".
_TEMPORARY = re.compile(r"^\.(?P<name>.+)\.[A-Za-z0-9_]+\.tmp(\.[A-Za-z0-9]+)?$")


def _remove_stale_temporaries(tasks: Iterable[ConvertTask]) -> int:
    """Remove the temporary files an interrupted run left beside the planned outputs; returns how many."""
    removed = 0
    by_dir: dict[Path, set[str]] = {}
    for t in tasks:
        by_dir.setdefault(t.output.parent, set()).add(t.output.name)
    for folder, names in by_dir.items():
        if not folder.is_dir():
            continue
        for entry in folder.iterdir():
            match = _TEMPORARY.match(entry.name)
            if match and match["name"] in names and entry.is_file():
                entry.unlink(missing_ok=True)
                removed += 1
    return removed


def _check_output_dir(output_dir: Path):
    if output_dir.exists() and not output_dir.is_dir():
        raise InputError(f"output_dir: expected a folder, got the file {output_dir}")
    try:
        output_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"output_dir: cannot create the folder {output_dir} ({exc.strerror or exc})") from exc
    if not os.access(output_dir, os.W_OK | os.X_OK):
        raise InputError(f"output_dir: cannot write into {output_dir} (Permission denied)")


def _settings(method, fmt, depth_scale, intrinsics, scale_invariant, overwrite, options, kinect_disparity=False,
              byte_order=None) -> ConvertSettings:
    from ._validate import check_bool, check_choice, check_positive
    from .io.depth import PGM_BYTE_ORDERS
    from .io.intrinsics import resolve_intrinsics
    from .io.normals import NORMAL_FORMATS
    from .methods import resolve

    resolve(method, dict(options))  # a wrong method or option fails once, here, not once per file
    check_choice("fmt", fmt, NORMAL_FORMATS)
    if depth_scale is not None:
        depth_scale = check_positive("depth_scale", depth_scale)
    kinect_disparity = check_bool("kinect_disparity", kinect_disparity)
    if byte_order is not None:
        check_choice("byte_order", byte_order, PGM_BYTE_ORDERS)
    if kinect_disparity and depth_scale is not None:
        raise InputError(f"depth_scale: expected None with kinect_disparity=True (the conversion gives metres), got {depth_scale!r}")
    return ConvertSettings(method, dict(options), fmt, depth_scale, resolve_intrinsics(intrinsics),
                           check_bool("scale_invariant", scale_invariant), check_bool("overwrite", overwrite),
                           kinect_disparity, byte_order)


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
    """Workers ignore Ctrl-C (the parent handles it for the whole pool, see :func:`convert`), die with
    ``main_pid``, and run one frame on one thread."""
    import signal

    global _frame_threads
    _frame_threads = 1
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if main_pid is not None:
        _die_with(main_pid)


def _pool_context():
    """fork when this process has one thread (fast, and scripts need no ``if __name__ == "__main__"``);
    otherwise forkserver, because fork() would copy other threads' held locks (e.g. Rich's refresh thread)."""
    import multiprocessing
    import threading

    methods = multiprocessing.get_all_start_methods()
    if "fork" in methods and threading.active_count() == 1:
        return multiprocessing.get_context("fork")
    return multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")


def convert(inputs, output_dir, *, method: str = DEFAULT_METHOD, fmt: str = "npy", depth_scale: float | None = None,
            intrinsics=None, jobs: int = 1, client=None, shard_size: int | None = None, overwrite: bool = False,
            progress: Callable[[FileResult], None] | None = None, scale_invariant: bool = False,
            kinect_disparity: bool = False, byte_order: str | None = None, **options) -> ConvertSummary:
    """Convert depth files to normal files; see :func:`plan_tasks` for ``inputs`` and the output names.

    Parameters
    ----------
    inputs : folder, glob pattern or list of depth files
    output_dir : str or Path
        Created if missing.
    method, scale_invariant, **options
        As in :func:`surfnorm.estimate` (e.g. ``dlf="alpha"``, ``fill=nan``).
    fmt : {"npy", "png16", "png8"}
        Output format, see :mod:`surfnorm.io.normals`.
    depth_scale : float, optional
        Divide the stored depth by this (1000 for millimetre PNG, 5000 for TUM).
    intrinsics : Intrinsics, 3x3 matrix, dict or path of an intrinsics file, optional
        The camera of every file (see :func:`surfnorm.io.read_intrinsics`);
        None reads each 3F2N file's ``params.txt``.
    jobs : int
        Processes (1: in this process).
    client : dask.distributed.Client, optional
        Run the tasks on this cluster with ``surfnorm.distributed.run_on_dask`` instead.
    shard_size : int, optional
        With ``client``: files per Dask task (see ``surfnorm.distributed.default_shard_size``).
    overwrite : bool
        Replace outputs that exist instead of skipping them.
    progress : callable, optional
        Called with each :class:`FileResult` as its file finishes (in this process).
    kinect_disparity, byte_order
        How raw sensor files are stored, as in :func:`surfnorm.io.read_depth`
        (Kinect v1 disparity; little-endian 16-bit PGM such as NYU Depth v2's raw
        frames; ``byte_order`` applies to the ``.pgm`` files among the inputs).

    Returns
    -------
    ConvertSummary
        Per-file results in task order; failed files are in ``.errors``, they do not raise.

    Raises
    ------
    InputError
        Bad arguments, no input files, an output folder that is a file or not writable.
    """
    settings = _settings(method, fmt, depth_scale, intrinsics, scale_invariant, overwrite, options, kinect_disparity,
                         byte_order)
    if client is not None and not (callable(getattr(client, "submit", None)) and callable(getattr(client, "nthreads", None))):
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
        from .io.threef2n import params_for

        missing = [t.input for t in tasks if params_for(t.input) is None]
        if missing:
            raise InputError(f"intrinsics: expected --intrinsics FILE or --fx --fy --cx --cy "
                             f"(no 3F2N params.txt beside {missing[0]}{' and %d more' % (len(missing) - 1) if len(missing) > 1 else ''})")
    _remove_stale_temporaries(tasks)
    results: dict[int, FileResult] = {}

    def done(i: int, result: FileResult):
        results[i] = result
        if progress is not None:
            progress(result)

    if client is not None:
        from .distributed import run_on_dask

        index = {(t.input, t.output): i for i, t in enumerate(tasks)}

        def on_result(r: FileResult):
            i = index.get((Path(r.input), Path(r.output)))
            if i is not None and i not in results:
                done(i, r)

        run_on_dask(tasks, settings, client, on_result, shard_size=shard_size)
        for i, t in enumerate(tasks):  # a task the cluster never answered is an error, not a silent gap
            results.setdefault(i, FileResult(t.input, t.output, "error", f"{t.input}: no result from the Dask cluster"))
    elif jobs == 1 or len(tasks) == 1:
        for i, t in enumerate(tasks):
            done(i, convert_file(t, settings))
    else:
        from concurrent.futures import ProcessPoolExecutor, as_completed

        pool = ProcessPoolExecutor(max_workers=min(jobs, len(tasks)), mp_context=_pool_context(), initializer=_worker_init,
                                   initargs=(os.getpid(),))
        try:
            futures = {pool.submit(convert_file, t, settings): i for i, t in enumerate(tasks)}
            for fut in as_completed(futures):
                i = futures[fut]
                try:
                    result = fut.result()
                except Exception as exc:  # noqa: BLE001 - a worker that died (e.g. out of memory)
                    t = tasks[i]
                    result = FileResult(t.input, t.output, "error", f"{t.input}: worker failed ({type(exc).__name__}: {exc})")
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
    return ConvertSummary([results[i] for i in range(len(tasks))])
