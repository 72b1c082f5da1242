"""adaptive_fit's cost per pixel against the window side: constant, from integral images.

    PYTHONPATH=src python benchmarks/adaptive_windows.py [--repeats 7]

On the RealSense D435 frame shipped in the package (1280x720), adaptive_fit with a fixed window of side
3, 5, ..., 31 (``window=w, max_window=w``, so no window grows past w), one thread: median ms of warm calls
and ns per pixel, beside plane_pca (a direct k x k plane fit, O(k^2) per pixel) at the same sides while it
stays under a second per call.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import surfnorm  # noqa: E402
from surfnorm.demo import read_sensor_frame, sensor_root  # noqa: E402


def median_ms(fn, repeats):
    fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1e3 * float(np.median(times))


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args(argv)
    frame = read_sensor_frame(sensor_root())
    z, K = frame.depth, frame.K
    pixels = z.size
    print(f"RealSense D435 frame {z.shape[1]}x{z.shape[0]}, one thread, median of {args.repeats} warm calls")
    print("| window | adaptive_fit ms | ns/pixel | plane_pca ms |")
    print("|---|---|---|---|")
    pca_slow = False
    for w in range(3, 32, 2):
        ms = median_ms(
            lambda: surfnorm.estimate(z, K, method="adaptive_fit", window=w, max_window=w, threads=1), args.repeats
        )
        pca = ""
        if not pca_slow:
            pms = median_ms(lambda: surfnorm.estimate(z, K, method="plane_pca", window=w, threads=1), 3)
            pca = f"{pms:.0f}"
            pca_slow = pms > 1000
        print(f"| {w} | {ms:.1f} | {1e6 * ms / pixels:.0f} | {pca} |", flush=True)


if __name__ == "__main__":
    main()
