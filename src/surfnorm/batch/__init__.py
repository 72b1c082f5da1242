"""Batch conversion: many depth files to normal files, in parallel, restartable.

Three layers, each usable alone (:mod:`surfnorm.batch.cluster` runs the same tasks
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
same outputs removes before it starts (only those that no live run holds: a
writer keeps its temporary file locked); outputs that exist are skipped, so
running the same command again finishes the job. Two runs writing into the
same output folder at the same time leave each other's files in flight alone
(a file both convert is written twice, with the same bytes).
"""

from __future__ import annotations

from .run import convert
from .tasks import STATUSES, ConvertSettings, ConvertSummary, ConvertTask, FileResult, convert_file, plan_tasks

__all__ = ["convert", "plan_tasks", "convert_file", "STATUSES"]  # the functions, then the types
__all__ += ["ConvertTask", "ConvertSettings", "FileResult", "ConvertSummary"]
