"""adaptive_fit's cost per pixel against the window side: constant, from integral images.

    PYTHONPATH=src python benchmarks/adaptive_windows.py [--repeats 7]

Three depth maps of 1280x720 pixels with the intrinsics of the RealSense D435 frame shipped in the package,
one thread, ``adaptive_fit`` with a fixed window of side w = 3, 5, ..., 31 (``window=w, max_window=w``, so no
window grows past w); median ms of warm calls:

- ``plane``: a tilted plane quantised in 1 mm steps, as a sensor delivers it. Every window passes the noise test,
  so this is the cost of the window sums and fits alone: it should not grow with w.
- ``D435``: the shipped frame. Where a window's fit fails the noise test (it spans an edge or a curved surface),
  the edge test fits the four quadrant windows instead: a constant cost per such pixel too, but the wider the
  window, the more pixels' windows span an edge, so this column grows with w by the share of such pixels.
- ``D435, no edge test``: the same frame with the edge test switched off (``kappa`` so large that every fit
  passes: not a setting for use, a measurement), which separates the two.

Beside them ``plane_pca`` (a direct k x k plane fit, O(k^2) per pixel) on the frame at the same sides while it
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
from surfnorm.kernels.adaptive_fit import adaptive_fit  # noqa: E402


def median_ms(fn, repeats):
    fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1e3 * float(np.median(times))


def quantised_plane(shape, K, step=1e-3):
    """Depth of the plane 0.2 x - 0.3 y - 0.93 z + 1 = 0 (normal tilted 22 degrees from the optical axis, about
    1 m away) seen through K, rounded to ``step``."""
    v, u = np.mgrid[0 : shape[0], 0 : shape[1]].astype(np.float64)
    n = np.array([0.2, -0.3, -0.93])
    n /= np.linalg.norm(n)
    ray = n[0] * (u - K.cx) / K.fx + n[1] * (v - K.cy) / K.fy + n[2]
    return (np.round(-1.0 / ray / step) * step).astype(np.float32)


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args(argv)
    frame = read_sensor_frame(sensor_root())
    z, K = np.ascontiguousarray(frame.depth, np.float32), frame.K
    plane = quantised_plane(z.shape, K)
    valid = (z > 0) & np.isfinite(z)
    out = np.empty(z.shape + (3,), np.float32)
    pixels = z.size
    print(f"{z.shape[1]}x{z.shape[0]} pixels, one thread, median of {args.repeats} warm calls, ms (ns per pixel)")
    print("| window | plane | D435 | D435, no edge test | plane_pca on D435 |")
    print("|---|---|---|---|---|")
    pca_slow = False
    for w in range(3, 32, 2):
        cells = []
        for depth in (plane, z):
            ms = median_ms(
                lambda d=depth: surfnorm.estimate(d, K, method="adaptive_fit", window=w, max_window=w, threads=1),
                args.repeats,
            )
            cells.append(f"{ms:.1f} ({1e6 * ms / pixels:.0f})")
        ms = median_ms(lambda: adaptive_fit(z, valid, K, out, window=w, max_window=w, kappa=1e300), args.repeats)
        cells.append(f"{ms:.1f} ({1e6 * ms / pixels:.0f})")
        pca = ""
        if not pca_slow:
            pms = median_ms(lambda: surfnorm.estimate(z, K, method="plane_pca", window=w, threads=1), 3)
            pca = f"{pms:.0f}"
            pca_slow = pms > 1000
        print(f"| {w} | " + " | ".join(cells) + f" | {pca} |", flush=True)


if __name__ == "__main__":
    main()
