"""``surfnorm demo``: every registered method on the sample frames shipped inside surfnorm."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import metrics
from ._api import estimate
from .io.pictures import error_to_rgb8, normal_to_rgb8, write_rgb8
from .io.threef2n import find_frames, read_frame, sample_root
from .methods import methods
from .reference import official_figures

__all__ = ["demo_methods", "run_demo", "DemoRow"]

#: Table IV of the paper: MNR on other depth-to-normal estimators.
TABLE_IV_COMBOS = ("3f2n_median+mnr", "cp2tv+mnr")


@dataclass
class DemoRow:
    frame: str
    method: str
    e_a: float
    official: float | None
    ms: float


def demo_methods() -> list[str]:
    names = list(methods())
    return names + [c for c in TABLE_IV_COMBOS if c.split("+")[0] in names]


def run_demo(out_dir, *, methods_=None, root=None, progress=None) -> list[DemoRow]:
    """Estimate with every method on every sample frame; write normal and error maps as PNG into ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    root = sample_root() if root is None else Path(root)
    names = list(methods_) if methods_ else demo_methods()
    rows = []
    for frame_name in find_frames(root):
        frame = read_frame(root, frame_name)
        official = official_figures(frame_name)
        stem = frame_name.replace("/", "_")
        write_rgb8(out_dir / f"{stem}_gt.png", normal_to_rgb8(np.where(frame.mask[..., None], frame.normals, 0)))
        for name in names:
            estimate(frame.depth[:8, :8], frame.K, method=name)  # compile or load the kernel outside the timing
            t0 = time.perf_counter()
            n = estimate(frame.depth, frame.K, method=name)
            ms = (time.perf_counter() - t0) * 1e3
            err = metrics.angular_error(n, frame.normals)
            err[~frame.mask] = np.nan
            e_a = metrics.mean_angular_error(n, frame.normals, frame.mask)
            safe = name.replace("+", "_plus_")
            write_rgb8(out_dir / f"{stem}_{safe}_normals.png", normal_to_rgb8(np.where(frame.mask[..., None], n, 0)))
            write_rgb8(out_dir / f"{stem}_{safe}_error.png", error_to_rgb8(err))
            rows.append(DemoRow(frame_name, name, e_a, official.get(name), ms))
            if progress is not None:
                progress()
    return rows
