"""What the repository's benchmark scripts (``benchmarks/*.py``) share: where they read the 3F2N frames, and their
methods and peers with the script's own list, refused in one line.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from .sensor import Entry

__all__ = ["threef2n_root", "script_entries"]

T = TypeVar("T")


def threef2n_root(root, checkout) -> Path:
    """The 3F2N frames a benchmark script reads: ``root`` where given; else the checkout's ``tests/data/3f2n-sample``
    (the 12 sample frames) where the repository folder ``checkout`` has it; else the frames shipped in the package
    (:func:`surfnorm.io.threef2n.sample_root`, one per level)."""
    from ..io.threef2n import sample_root

    if root:
        return Path(root)
    shipped = Path(checkout) / "tests" / "data" / "3f2n-sample"
    return shipped if shipped.is_dir() else Path(sample_root())


def script_entries(script: str, methods: str, parse: Callable[[], T]) -> tuple[T, list[Entry]] | None:
    """``parse()`` (the script's own list: its families, its matchers) and the entries of the comma-separated
    ``methods`` (:func:`surfnorm.bench.sensor.make_entries`), the peers that are absent printed one line each; None
    after one line on standard error, ``"<script>: <why>"``, where either is refused (the script then exits 2)."""
    from ..errors import SurfnormError
    from .sensor import make_entries

    try:
        parsed = parse()
        entries, missing = make_entries(methods.split(","))
    except SurfnormError as exc:
        print(f"{script}: {exc}", file=sys.stderr)
        return None
    for name, why in missing.items():
        print(f"(left out: {name}: {why})")
    return parsed, entries
