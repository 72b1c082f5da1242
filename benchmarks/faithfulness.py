"""e_A per frame and per level of surfnorm next to the authors' implementations.

    python benchmarks/faithfulness.py [DATASET_DIR] [--border reflect|one-sided]

DATASET_DIR defaults to tests/data/3f2n-sample (the 12 frames, compressed in the repository); the authors'
figures come from the package data (official-3f2n-sample.json).
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from pathlib import Path

import numpy as np

import surfnorm
from surfnorm.io.threef2n import LEVELS, find_frames, read_frame
from surfnorm.metrics import mean_angular_error
from surfnorm.reference import OFFICIAL_KEYS, official_figures


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "dataset", nargs="?", default=str(Path(__file__).resolve().parents[1] / "tests/data/3f2n-sample")
    )
    parser.add_argument("--border", default="reflect", choices=["reflect", "one-sided"])
    args = parser.parse_args()
    registered = surfnorm.methods()
    methods = [m for m in OFFICIAL_KEYS if m in registered]
    per_level = defaultdict(list)
    print("| frame | " + " | ".join(f"{m} (authors)" for m in methods) + " |")
    print("|---|" + "---|" * len(methods))
    for name in find_frames(args.dataset):
        f = read_frame(args.dataset, name)
        ref = official_figures(name)
        cells = []
        for m in methods:
            opts = {"border": args.border} if "border" in registered[m].options else {}
            e = mean_angular_error(surfnorm.estimate(f.depth, f.K, method=m, **opts), f.normals, f.mask)
            r = ref.get(m, float("nan"))
            per_level[m, f.level].append((e, r))
            cells.append(f"{e:.3f} ({r:.3f})")
        print(f"| {name} | " + " | ".join(cells) + " |")
    print()
    print("| level | " + " | ".join(f"{m}: ours / authors / diff" for m in methods) + " |")
    print("|---|" + "---|" * len(methods))
    for level in LEVELS:
        cells = []
        for m in methods:
            pairs = np.array(per_level[m, level])
            if pairs.size:
                o, r = pairs.mean(axis=0)
                cells.append(f"{o:.3f} / {r:.3f} / {o - r:+.4f}")
        if cells:
            print(f"| {level} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
