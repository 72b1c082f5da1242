"""``surfnorm bench``: the D2NT paper's tables and figures, regenerated on any data in the 3F2N layout.

::

    from surfnorm.bench import BenchConfig, run_bench, write_report
    result = run_bench(BenchConfig(root=sample_root(), out=Path("bench-output")))
    write_report(result, "bench-output")

Modules: :mod:`.runner` (what runs, cache, timing protocol), :mod:`.peers`
(other libraries), :mod:`.paper` (the paper's numbers, as data), :mod:`.report`
(report.md, results.json), :mod:`.figures` (PNG).
"""

from __future__ import annotations

from .report import write_report
from .runner import BenchConfig, BenchResult, run_bench

__all__ = ["BenchConfig", "BenchResult", "run_bench", "write_report"]
