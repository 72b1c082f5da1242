"""Scale-invariant mode: integer millimetres vs the same depth in metres (float32), per method.

    PYTHONPATH=src python benchmarks/unit_ties.py [--methods a,b] [--frames test,sample]

For each method, the share of pixels whose normals differ by more than 2e-3 (any component)
between ``estimate(mm, scale_invariant=True)`` and ``estimate(float32(mm / 1000), scale_invariant=True)``,
and the largest difference. "test" is the frame of tests/test_units.py (a noisy sphere before a wall,
rint to 1 mm, holes); "sample" are the 12 frames of the 3F2N sample taken as metres,
mm = rint(depth * 1000), background passed as invalid (mask).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import surfnorm
from surfnorm.io.threef2n import find_frames, read_frame

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def compare(mm, metres, K, method, mask=None):
    a = surfnorm.estimate(mm, K, method=method, scale_invariant=True, fill=np.nan, mask=mask)
    b = surfnorm.estimate(metres, K, method=method, scale_invariant=True, fill=np.nan, mask=mask)
    d = np.abs(np.nan_to_num(b - a)).max(-1)
    have = ~np.isnan(a[..., 0]) | ~np.isnan(b[..., 0])
    return int((d > 2e-3).sum()), int(have.sum()), float(d.max())


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--methods", default=None)
    ap.add_argument("--frames", default="test,sample")
    ap.add_argument("--root", default=str(Path(__file__).resolve().parents[1] / "tests" / "data" / "3f2n-sample"))
    args = ap.parse_args(argv)
    names = args.methods.split(",") if args.methods else list(surfnorm.methods()) + ["cp2tv+mnr"]
    frames = []
    if "test" in args.frames:
        from tests.test_units import K, sensor_millimetres

        mm = sensor_millimetres()
        frames.append(("test", mm, (mm / 1000.0).astype(np.float32), K, None))
    if "sample" in args.frames:
        for n in find_frames(args.root):
            f = read_frame(args.root, n)
            mm = np.rint(f.depth.astype(np.float64) * 1000).astype(np.float32)  # integers, exact in float32
            frames.append((f.name, mm, (mm.astype(np.float64) / 1000).astype(np.float32), f.K, f.mask))
    print(
        "| method | test frame: differing / with normal (max diff) | 12 sample frames: differing / with normal (max diff) |"
    )
    print("|---|---|---|")
    for name in names:
        cells = {}
        for fname, mm, metres, K, mask in frames:
            off, have, mx = compare(mm, metres, K, name, mask)
            key = "test" if fname == "test" else "sample"
            o, h, m = cells.get(key, (0, 0, 0.0))
            cells[key] = (o + off, h + have, max(m, mx))
        fmt = lambda c: f"{c[0]}/{c[1]} = {100 * c[0] / max(c[1], 1):.3f} % ({c[2]:.2g})" if c else "-"
        print(f"| {name} | {fmt(cells.get('test'))} | {fmt(cells.get('sample'))} |", flush=True)


if __name__ == "__main__":
    main()
