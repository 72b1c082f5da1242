"""The tasks of a batch conversion: planning them, and converting one file.

* :func:`plan_tasks` turns a folder, a glob pattern or a list of files into
  :class:`ConvertTask` (input, output) pairs with deterministic output names;
* :func:`convert_file` does one task: read, :func:`surfnorm.estimate`, write
  atomically. It is a pure top-level function of picklable arguments, skips an
  output that exists, and never raises for a bad input file: it returns a
  :class:`FileResult` whose status is ``"error"`` and whose message names it;
* :func:`remove_stale_temporaries` removes what a killed run left behind.

:mod:`surfnorm.batch.run` runs the tasks in a process pool, :mod:`surfnorm.batch.cluster` on Dask.
"""

from __future__ import annotations

import glob as globlib
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import numpy as np

from ..camera import Intrinsics
from ..errors import InputError, SurfnormError
from ..methods import DEFAULT_METHOD

__all__ = [
    "ConvertTask",
    "ConvertSettings",
    "FileResult",
    "ConvertSummary",
    "plan_tasks",
    "convert_file",
    "remove_stale_temporaries",
    "one_thread_per_frame",
    "STATUSES",
]

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
    sun_rgbd: bool = False


@dataclass(frozen=True)
class FileResult:
    """What happened to one file: status is "written", "skipped" (output existed) or "error"."""

    input: Path
    output: Path
    status: str
    message: str = ""

    @classmethod
    def error(cls, task: ConvertTask, why: str) -> FileResult:
        """Status "error" for ``task``, the message ``why`` after the input's name."""
        return cls(task.input, task.output, "error", f"{task.input}: {why}")


@dataclass
class ConvertSummary:
    """The results of a run, in task order."""

    results: list[FileResult]

    def count(self, status: str) -> int:
        """The number of files whose status is ``status`` (``"written"``, ``"skipped"`` or ``"error"``)."""
        return sum(r.status == status for r in self.results)

    @property
    def written(self) -> int:
        """The number of files written."""
        return self.count("written")

    @property
    def skipped(self) -> int:
        """The number of files skipped because their output existed."""
        return self.count("skipped")

    @property
    def errors(self) -> list[FileResult]:
        """The files that failed, each with its error message."""
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
    """A depth file's name (not hidden), and a file or a symbolic link.

    A dangling link or a loop becomes a task that fails by name ("cannot read depth file (No such file or
    directory)"), not an input silently dropped.
    """
    from ..io.depth import DEPTH_SUFFIXES, depth_suffix

    if path.name.startswith(".") or depth_suffix(path) not in DEPTH_SUFFIXES:
        return False
    return path.is_symlink() or path.is_file()


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
        raise InputError(
            f"inputs: expected a depth file, a folder or a glob pattern, got {text!r}, which does not exist"
        )
    try:
        items = list(inputs)
    except TypeError as exc:
        raise InputError(
            f"inputs: expected a path, a glob pattern or a list of files, got {type(inputs).__name__}"
        ) from exc
    out = []
    for item in items:
        if not isinstance(item, (str, os.PathLike)):
            raise InputError(f"inputs: expected paths in the list, got {type(item).__name__} {item!r}")
        out.append((Path(item), Path(item).parent))
    return out


def _resolved(path: Path) -> Path:
    """``path.resolve()``, or its absolute path where links loop (a loop fails by name when its task runs)."""
    try:
        return path.resolve()
    except (RuntimeError, OSError):
        return path.absolute()


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
        Folder of the outputs, ``<relative folder>/<stem>.npy``, ``.png`` or ``.ply``
        (``000001.bin.gz`` -> ``000001.npy``).
    fmt : {"npy", "png16", "png8", "ply"}

    Raises
    ------
    InputError
        No depth file found, a folder that cannot be listed, two inputs that
        would write the same output, or an output that would replace its input.
    """
    from .._validate import check_choice
    from ..io.normals import FORMAT_SUFFIX, OUTPUT_FORMATS

    check_choice("fmt", fmt, OUTPUT_FORMATS)
    output_dir = Path(output_dir)
    out_root = output_dir.resolve()
    sources = _sources(inputs)
    if isinstance(inputs, (str, os.PathLike)) and not Path(inputs).is_file():
        roots = {r.resolve() for _, r in sources} or {Path(os.fspath(inputs)).resolve()}
        if out_root in roots:
            raise InputError(
                f"output_dir: expected a folder other than the input folder {os.fspath(inputs)}, got {output_dir}; "
                "its outputs would be read as inputs by the next run"
            )
        # outputs of an earlier run inside the input folder (e.g. convert data data/normals) are not inputs
        sources = [(f, r) for f, r in sources if out_root not in _resolved(f).parents]
    if not sources:
        raise InputError(
            f"inputs: expected at least one depth file, found none in {os.fspath(inputs) if isinstance(inputs, (str, os.PathLike)) else 'the list'}"
        )
    tasks: list = []
    seen: dict = {}
    for file, root in sources:
        try:
            rel = file.parent.relative_to(root)
        except ValueError:
            rel = Path()
        out = output_dir / rel / (_output_stem(file) + FORMAT_SUFFIX[fmt])
        if out in seen:
            raise InputError(
                f"inputs: {seen[out]} and {file} would both be written to {out}; "
                "convert them into different output folders"
            )
        if _resolved(out) == _resolved(file):
            raise InputError(f"output_dir: writing {out} would replace its input; choose another output folder")
        seen[out] = file
        tasks.append(ConvertTask(file, out))
    return tasks


# ---------------------------------------------------------------------------- one file

# Threads per frame (see surfnorm.estimate): all cores in the calling process; 1 in a worker of a pool
# (processes here, or Dask), which already runs frames side by side.
_frame_threads: int | None = None


def one_thread_per_frame() -> None:
    """Run each frame on one thread, in a worker of a pool (processes, or Dask).

    The pool already runs frames side by side.
    """
    global _frame_threads
    _frame_threads = 1


def _convert(task: ConvertTask, settings: ConvertSettings) -> str:
    from .._api import estimate
    from ..io.depth import depth_suffix, read_depth
    from ..io.normals import write_normals
    from ..io.ply import write_ply
    from ..io.threef2n import params_for, read_params

    cam = settings.intrinsics
    if cam is None:
        params = params_for(task.input)
        if params is None:
            raise InputError(
                f"intrinsics: none given and no 3F2N params.txt beside {task.input} or in the folder above it"
            )
        cam = read_params(params)
    byte_order = settings.byte_order if depth_suffix(task.input) == ".pgm" else None  # other files in the folder
    depth = read_depth(
        task.input,
        depth_scale=settings.depth_scale,
        kinect_disparity=settings.kinect_disparity,
        byte_order=byte_order,
        sun_rgbd=settings.sun_rgbd,
    )
    normals = estimate(
        depth,
        cam,
        method=settings.method,
        scale_invariant=settings.scale_invariant,
        threads=_frame_threads,
        **settings.options,
    )
    task.output.parent.mkdir(parents=True, exist_ok=True)
    if settings.fmt == "ply":
        write_ply(task.output, depth, cam, normals)  # the points of the pixels that have a normal
    else:
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
                return FileResult.error(task, f"output {task.output} exists and is a folder")
            return FileResult(task.input, task.output, "skipped", "output exists")
        return FileResult(task.input, task.output, "written", _convert(task, settings))
    except (SurfnormError, ValueError) as exc:
        message = str(exc)
        if str(task.input) not in message:
            message = f"{task.input}: {message}"
        return FileResult(task.input, task.output, "error", message)
    except OSError as exc:
        where = exc.filename if exc.filename else task.output
        return FileResult.error(task, f"cannot write {where} ({exc.strerror or exc})")
    except Exception as exc:  # noqa: BLE001 - a bad file must not stop the other thousand
        return FileResult.error(task, f"unexpected {type(exc).__name__}: {exc}")


# ---------------------------------------------------------------------------- many files

#: The name atomic_write gives its temporary file: ".<name>.<random>.tmp<suffix>" (<name> shortened, ending
#: with "~", where the whole would be too long for the filesystem).
_TEMPORARY = re.compile(r"^\.(?P<name>.+)\.[A-Za-z0-9_]+\.tmp(\.[A-Za-z0-9]+)?$")


def _temporary_of(name: str, outputs: set[str]) -> bool:
    """Whether ``name`` (the <name> part of a temporary file) is that of one of ``outputs``, whole or shortened."""
    from ..io._atomic import TRUNCATED

    if name in outputs:
        return True
    stem = name[: -len(TRUNCATED)]
    return name.endswith(TRUNCATED) and any(o.startswith(stem) for o in outputs)


def remove_stale_temporaries(tasks: Iterable[ConvertTask]) -> int:
    """Remove the temporary files an interrupted run left beside the planned outputs; returns how many.

    Only those that no live writer holds: another run writing into the same folder keeps its files in flight
    locked (see :func:`surfnorm.io._atomic.remove_if_stale`), and they are left alone.
    """
    from ..io._atomic import remove_if_stale

    removed = 0
    by_dir: dict[Path, set[str]] = {}
    for t in tasks:
        by_dir.setdefault(t.output.parent, set()).add(t.output.name)
    for folder, names in by_dir.items():
        if not folder.is_dir():
            continue
        for entry in folder.iterdir():
            match = _TEMPORARY.match(entry.name)
            if match and _temporary_of(match["name"], names) and entry.is_file() and remove_if_stale(entry):
                removed += 1
    return removed
