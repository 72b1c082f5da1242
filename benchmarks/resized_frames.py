"""Real frames as a sensor of 1/K their resolution would give them, resized back: the plane metric.

    PYTHONPATH=src python benchmarks/resized_frames.py [SENSOR_DIR] [--factors 4,5,8] [--interpolation cubic]

Each frame of SENSOR_DIR (default ../shared/data/sensor-sample beside the repository; the layout of
`surfnorm bench --sensor`) keeps every K-th pixel of its depth (starting at K // 2), its own sensor's noise
included, and is resized back to its size by OpenCV (bilinear, or bicubic with ``--interpolation cubic``), with no
depth where the nearest low pixel had none:
a low-resolution time-of-flight camera or phone LiDAR registered to a colour camera, on real scenes. Per factor and
frame: the sensor benchmark's score (the mean folded angle to its reference planes, or e_A against its gt.npy;
sparse frames, under half of whose pixels hold depth (LiDAR: a resize mixes its gaps with depth), are left out) of
the default (with what it decided), its two estimators and OpenCV's peers, one thread each; then the means over the
frames. The 3F2N version of this
family, with exact normals, is `benchmarks/families.py` (`upsampled_linear:K`, `upsampled_cubic:K`).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
METHODS = "auto,d2nt_v3,adaptive_fit,opencv_linemod_w5,opencv_fals_w7"


#: --interpolation: OpenCV's flag for each (looked up where the resize runs: cv2 is imported there)
INTERPOLATIONS = {"linear": "INTER_LINEAR", "cubic": "INTER_CUBIC"}


def resized(depth: np.ndarray, k: int, interpolation: str = "linear") -> np.ndarray:
    """``depth`` (float32, 0 where none) as a sensor of 1/k its resolution gives it, resized back (bilinear or
    bicubic: ``interpolation``); 0 where the nearest low pixel, or the frame itself, had no depth."""
    import cv2

    H, W = depth.shape
    low = np.ascontiguousarray(depth[k // 2 :: k, k // 2 :: k], dtype=np.float32)
    up = cv2.resize(low, (W, H), interpolation=getattr(cv2, INTERPOLATIONS[interpolation]))
    near = cv2.resize(low, (W, H), interpolation=cv2.INTER_NEAREST)
    return np.where((near > 0) & (depth > 0), up, 0.0).astype(np.float32)


def parse_factors(text: str) -> list[int]:
    from surfnorm.errors import InputError

    try:
        factors = [int(x) for x in text.split(",")]
    except ValueError:
        factors = []
    if not factors or any(not 2 <= k <= 16 for k in factors):
        raise InputError(f"--factors: expected whole numbers from 2 to 16, comma-separated, got {text!r}")
    return factors


def main(argv=None) -> int:
    from surfnorm.bench.peers import single_thread

    single_thread()  # before any peer library is imported
    from surfnorm import auto_decision
    from surfnorm.bench.sensor import find_sensor_frames, make_entries, read_sensor_frame, score_frame
    from surfnorm.errors import InputError, SurfnormError

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sensor_dir", nargs="?", default=str(REPO.parent / "shared" / "data" / "sensor-sample"))
    ap.add_argument("--factors", default="4,5,8", help="comma-separated resize factors K (2 to 16)")
    ap.add_argument("--interpolation", default="linear", help="linear (bilinear) or cubic (bicubic)")
    ap.add_argument("--methods", default=METHODS)
    args = ap.parse_args(argv)
    try:
        factors = parse_factors(args.factors)
        if args.interpolation not in INTERPOLATIONS:
            raise InputError(f"--interpolation: expected linear or cubic, got {args.interpolation!r}")
        entries, missing = make_entries(args.methods.split(","))
        frames = [read_sensor_frame(f) for f in find_sensor_frames(args.sensor_dir)]
    except SurfnormError as exc:
        print(f"resized_frames: {exc}", file=sys.stderr)
        return 2
    for name, why in missing.items():
        print(f"(left out: {name}: {why})")
    frames = [f for f in frames if np.mean(f.depth > 0) > 0.5]
    print("| K | frame | `auto` ran | " + " | ".join(e.label for e in entries) + " |")
    print("|---|---|---|" + "---|" * len(entries))
    for k in factors:
        scores = []
        for f in frames:
            depth = resized(f.depth.astype(np.float32), k, args.interpolation)
            got = dataclasses.replace(f, depth=depth)
            row = [score_frame(e.normals(depth, f.K, depth > 0), got)[1] for e in entries]
            scores.append(row)
            d = auto_decision(depth, f.K)
            ran = d.method + (f" ({d.upsampled}x)" if d.upsampled > 1 else "")
            print(f"| {k} | {f.name} | {ran} | " + " | ".join(f"{a:.1f}" for a in row) + " |", flush=True)
        means = np.mean(scores, axis=0)
        print(f"| {k} | mean of {len(frames)} | | " + " | ".join(f"{m:.1f}" for m in means) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
