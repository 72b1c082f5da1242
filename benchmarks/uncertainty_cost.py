"""What ``uncertainty=True`` costs on top of the estimate: same-run medians, calls alternating.

    python benchmarks/uncertainty_cost.py FOLDER [FOLDER ...] [--repeats 41] [--threads N]

Each FOLDER is a frame in the sensor sample's layout (``depth.npy`` in metres, ``K.json``) or a 3F2N frame
(``Easy/torus/000001`` under ``tests/data/3f2n-sample``, given as ROOT::NAME). For each frame: the default
method's median time without and with sigma, over calls that alternate between the two (so that the machine's
drift falls on both), and their ratio.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import surfnorm


def load(spec: str):
    """(name, depth, K) of a sensor-sample folder, or of ROOT::NAME for a 3F2N frame (its object pixels)."""
    if "::" in spec:
        from surfnorm.io.threef2n import read_frame

        root, name = spec.split("::", 1)
        fr = read_frame(root, name)
        return name, np.where(fr.mask, fr.depth, 0).astype(np.float32), fr.K
    from surfnorm.bench.sensor import read_sensor_frame

    fr = read_sensor_frame(Path(spec))
    return fr.name, fr.depth, fr.K


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("frames", nargs="+")
    parser.add_argument("--repeats", type=int, default=41)
    parser.add_argument("--threads", type=int, default=None, help="estimate's threads (default: every core)")
    args = parser.parse_args(argv)
    print("| frame | size | default, ms | with sigma, ms | ratio |")
    print("|---|---|---|---|---|")
    for spec in args.frames:
        name, depth, K = load(spec)
        options = {} if args.threads is None else {"threads": args.threads}
        calls = {
            "plain": lambda: surfnorm.estimate(depth, K, **options),
            "sigma": lambda: surfnorm.estimate(depth, K, uncertainty=True, **options),
        }
        times: dict[str, list[float]] = {k: [] for k in calls}
        for fn in calls.values():
            fn()
        for r in range(args.repeats):
            order = list(calls) if r % 2 == 0 else list(calls)[::-1]
            for k in order:
                t0 = time.perf_counter()
                calls[k]()
                times[k].append((time.perf_counter() - t0) * 1e3)
        plain, sigma = float(np.median(times["plain"])), float(np.median(times["sigma"]))
        h, w = depth.shape
        print(f"| {name} | {w}x{h} | {plain:.2f} | {sigma:.2f} | {sigma / plain:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
