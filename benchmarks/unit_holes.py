"""Scale-invariant mode: metres vs millimetres with and without holes, and how far a hole reaches.

    python benchmarks/unit_holes.py [DATA] [--methods a,b] [--seed 0]

DATA is a folder in the 3F2N layout (default: the 12-frame sample in the repository, tests/data/3f2n-sample,
else the 3 frames shipped in the package). The frames' depth unit is read as centimetres (``--factors 10``: 0.1 to
4 m, a depth sensor's range) and as metres (``1000``: up to 400 m): mm = rint(factor z) (integer millimetres, as a
sensor gives them) against metres = float32(mm / 1000), both with ``scale_invariant=True`` and the frame's object
mask. "holes": the same random holes (NaN) in both: 12 squares of 4 to 16 pixels and 1 % single pixels.

Table 1, per method: pixels whose normals differ by more than 1e-4 (any component) between the units, as a share of
the pixels with a normal in either, without and with holes; and 180-degree flips (normals more than 90 degrees
apart) in both runs. Table 2, per method: pixels farther than 10 px (Chebyshev) from a 10x10 hole whose normal
changes by more than 1e-4 when the hole is punched into the frame (same unit), summed over the frames.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

import surfnorm
from surfnorm.io.threef2n import find_frames, read_frame, sample_root

BESIDE = Path(__file__).resolve().parents[1] / "tests" / "data" / "3f2n-sample"


def random_holes(shape, rng):
    holes = rng.random(shape) < 0.01
    for _ in range(12):
        s = int(rng.integers(4, 17))
        v, u = int(rng.integers(0, shape[0] - s)), int(rng.integers(0, shape[1] - s))
        holes[v : v + s, u : u + s] = True
    return holes


def compare(a, b):
    """(differing > 1e-4, flips > 90 degrees, pixels with a normal in either)."""
    have = ~np.isnan(a[..., 0]) | ~np.isnan(b[..., 0])
    d = np.abs(np.nan_to_num(b - a, nan=2.0)).max(-1)
    dots = np.einsum("hwc,hwc->hw", np.nan_to_num(a), np.nan_to_num(b))
    both = ~np.isnan(a[..., 0]) & ~np.isnan(b[..., 0])
    return int((have & (d > 1e-4)).sum()), int((both & (dots < 0)).sum()), int(have.sum())


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("root", nargs="?", default=str(BESIDE if BESIDE.is_dir() else sample_root()))
    ap.add_argument("--methods", default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--factors", default="10,1000", help="millimetres per depth unit of the frames, comma-separated")
    args = ap.parse_args(argv)
    names = args.methods.split(",") if args.methods else list(surfnorm.methods()) + ["cp2tv+mnr", "3f2n_median+mnr"]
    for factor in (float(x) for x in args.factors.split(",")):
        table(args, names, factor)


def table(args, names, factor):
    rng = np.random.default_rng(args.seed)
    frames = []
    for n in find_frames(args.root):
        f = read_frame(args.root, n)
        mm = np.rint(f.depth.astype(np.float64) * factor).astype(np.float32)
        holes = random_holes(mm.shape, rng)
        H, W = mm.shape
        ys, xs = np.nonzero(f.mask)
        v, u = int(np.median(ys)), int(np.median(xs))  # a 10x10 hole in the object
        square = np.zeros(mm.shape, bool)
        square[v : v + 10, u : u + 10] = True
        frames.append((f, mm, holes, square))
    depths = np.concatenate([mm[f.mask] for f, mm, _, _ in frames]) / 1000
    print(
        f"\n{len(frames)} frames from {args.root}, depth unit = {factor:g} mm "
        f"(object depth {depths.min():.2f} to {depths.max():.2f} m, median {np.median(depths):.2f} m)\n"
    )
    print("| method | differing > 1e-4, no holes | with holes | 180-degree flips | far changes from one 10x10 hole |")
    print("|---|---|---|---|---|")
    for name in names:
        cells = np.zeros((2, 3), np.int64)
        far_changes, far_total = 0, 0
        for f, mm, holes, square in frames:
            for row, hole in enumerate((None, holes)):
                a_in, b_in = mm, (mm.astype(np.float64) / 1000).astype(np.float32)
                if hole is not None:
                    a_in, b_in = np.where(hole, np.nan, a_in), np.where(hole, np.nan, b_in)
                a = surfnorm.estimate(a_in, f.K, method=name, mask=f.mask, scale_invariant=True, fill=np.nan)
                b = surfnorm.estimate(b_in, f.K, method=name, mask=f.mask, scale_invariant=True, fill=np.nan)
                cells[row] += compare(a, b)
            plain = surfnorm.estimate(mm, f.K, method=name, mask=f.mask, scale_invariant=True, fill=np.nan)
            holed = surfnorm.estimate(
                np.where(square, np.nan, mm), f.K, method=name, mask=f.mask, scale_invariant=True, fill=np.nan
            )
            far = cv2.dilate(square.astype(np.uint8), np.ones((21, 21), np.uint8)) == 0
            d = np.abs(np.nan_to_num(holed - plain, nan=2.0)).max(-1)
            have = ~np.isnan(plain[..., 0]) | ~np.isnan(holed[..., 0])
            far_changes += int((far & have & (d > 1e-4)).sum())
            far_total += int((far & ~np.isnan(plain[..., 0])).sum())
        share = lambda c: f"{c[0]}/{c[2]} = {100 * c[0] / max(c[2], 1):.4f} %"
        print(
            f"| {name} | {share(cells[0])} | {share(cells[1])} | {cells[0, 1] + cells[1, 1]} | "
            f"{far_changes}/{far_total} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
