"""Real frames as a sensor of 1/K their resolution would give them, resized back: the plane metric.

    PYTHONPATH=src python benchmarks/resized_frames.py [SENSOR_DIR] [--factors 4,5,8] [--interpolation cubic]
    PYTHONPATH=src python benchmarks/resized_frames.py SENSOR_DIR --enlarge --factors 4.5,7.5

Each frame of SENSOR_DIR (default ../shared/data/sensor-sample beside the repository; the layout of
`surfnorm bench --sensor`) keeps every K-th pixel of its depth (starting at K // 2; K may be halfway between whole
numbers, 7.5: then the pixel nearest each sample's centre), its own sensor's noise included, and is resized back to
its size by OpenCV (bilinear, or bicubic with ``--interpolation cubic``), with no depth where the nearest low pixel
had none:
a low-resolution time-of-flight camera or phone LiDAR registered to a colour camera, on real scenes. Per factor and
frame: the sensor benchmark's score (the mean folded angle to its reference planes, or e_A against its gt.npy;
sparse frames, under half of whose pixels hold depth (LiDAR: a resize mixes its gaps with depth), are left out) of
the default (with what it decided), its two estimators and OpenCV's peers, one thread each; then the means over the
frames. The 3F2N version of this
family, with exact normals, is `benchmarks/families.py` (`upsampled_linear:K`, `upsampled_cubic:K`).

With ``--enlarge`` each frame is instead resized K times larger, its own depth taken as the low-resolution sensor's (a
phone's 256x192 depth brought to its 1920x1440 colour: 7.5x), with its reference (planes' masks, or gt.npy's
normals) resized to the nearest pixel and its intrinsics for the smaller pixels; frames that would exceed
``ENLARGED_MAX`` pixels along a side are left out.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
METHODS = "auto,d2nt_v3,adaptive_fit,opencv_linemod_w5,opencv_fals_w7"


#: --interpolation: OpenCV's flag for each (looked up where the resize runs: cv2 is imported there)
INTERPOLATIONS = {"linear": "INTER_LINEAR", "cubic": "INTER_CUBIC"}


def resized(depth: np.ndarray, k: float, interpolation: str = "linear") -> np.ndarray:
    """``depth`` (float32, 0 where none) as a sensor of 1/k its resolution gives it (:func:`_sampled`), resized back
    (bilinear or bicubic: ``interpolation``); 0 where the nearest low pixel, or the frame itself, had no depth."""
    import cv2

    H, W = depth.shape
    rows, cols = (_sampled(n, k) for n in (H, W))
    low = np.ascontiguousarray(depth[np.ix_(rows, cols)], dtype=np.float32)
    up = cv2.resize(low, (W, H), interpolation=getattr(cv2, INTERPOLATIONS[interpolation]))
    near = cv2.resize(low, (W, H), interpolation=cv2.INTER_NEAREST)
    return np.where((near > 0) & (depth > 0), up, 0.0).astype(np.float32)


#: --enlarge: the most pixels along a side of an enlarged frame (a phone's colour camera: 1920).
ENLARGED_MAX = 2048


def enlarged(frame, k: float, interpolation: str = "linear"):
    """The sensor frame ``frame`` resized k times larger (``round(k W)`` x ``round(k H)``): its depth by OpenCV
    (bilinear or bicubic), 0 where the nearest pixel had none; its reference planes' masks or ground-truth normals to
    the nearest pixel; its intrinsics for the smaller pixels (pixel i's centre at (i + 0.5) s - 0.5, s the actual
    ratio of the sides)."""
    import cv2

    from surfnorm.camera import Intrinsics

    H, W = frame.depth.shape
    size = (round(k * W), round(k * H))
    sx, sy = size[0] / W, size[1] / H
    depth = frame.depth.astype(np.float32)
    up = cv2.resize(depth, size, interpolation=getattr(cv2, INTERPOLATIONS[interpolation]))
    near = cv2.resize(depth, size, interpolation=cv2.INTER_NEAREST)
    up = np.where((near > 0) & (up > 0), up, 0.0).astype(np.float32)
    c = frame.K
    K = Intrinsics(c.fx * sx, c.fy * sy, (c.cx + 0.5) * sx - 0.5, (c.cy + 0.5) * sy - 0.5)
    planes = gt = None
    if frame.planes is not None:
        normals, masks = frame.planes
        masks = np.stack([cv2.resize(m.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0 for m in masks])
        planes = (normals, masks)
    if frame.gt is not None:
        gt = cv2.resize(frame.gt.astype(np.float32), size, interpolation=cv2.INTER_NEAREST)
    return dataclasses.replace(frame, depth=up, K=K, planes=planes, gt=gt)


def _sampled(n: int, k: float) -> np.ndarray:
    """The pixels of a side of n that the sensor of 1/k the resolution keeps: floor((i + 0.5) k), the nearest to its
    pixel i's centre (i k + k // 2 for a whole k; as benchmarks/families.py's ``sampled``)."""
    centres = (np.arange(math.ceil(n / k) + 1) + 0.5) * k
    return np.floor(centres[centres < n]).astype(np.int64)


def parse_factors(text: str) -> list[float]:
    from surfnorm.errors import InputError

    try:
        factors = [float(x) for x in text.split(",")]
    except ValueError:
        factors = []
    if not factors or any(not (2 <= k <= 16 and (2 * k).is_integer()) for k in factors):
        raise InputError(
            f"--factors: expected numbers from 2 to 16, whole or halfway (7.5), comma-separated, got {text!r}"
        )
    return [int(k) if k.is_integer() else k for k in factors]


def main(argv=None) -> int:
    from surfnorm.bench.peers import single_thread

    single_thread()  # before any peer library is imported
    from surfnorm import auto_decision
    from surfnorm.bench.sensor import find_sensor_frames, make_entries, read_sensor_frame, score_frame
    from surfnorm.errors import InputError, SurfnormError

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sensor_dir", nargs="?", default=str(REPO.parent / "shared" / "data" / "sensor-sample"))
    ap.add_argument(
        "--factors", default="4,5,8", help="comma-separated resize factors K (2 to 16, whole or halfway: 7.5)"
    )
    ap.add_argument("--interpolation", default="linear", help="linear (bilinear) or cubic (bicubic)")
    ap.add_argument("--methods", default=METHODS)
    ap.add_argument("--enlarge", action="store_true", help="resize each frame K times larger instead")
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
    if args.enlarge:
        big = [f.name for f in frames if max(f.depth.shape) * max(factors) > ENLARGED_MAX]
        if big:
            print(f"(left out: {', '.join(big)}: over {ENLARGED_MAX} pixels along a side when enlarged)")
        frames = [f for f in frames if f.name not in big]
    if not frames:
        print(f"resized_frames: {args.sensor_dir}: no frame to resize (dense, and small enough)", file=sys.stderr)
        return 2
    print("| K | frame | `auto` ran | " + " | ".join(e.label for e in entries) + " |")
    print("|---|---|---|" + "---|" * len(entries))
    for k in factors:
        scores = []
        for f in frames:
            if args.enlarge:
                got = enlarged(f, k, args.interpolation)
            else:
                got = dataclasses.replace(f, depth=resized(f.depth.astype(np.float32), k, args.interpolation))
            depth = got.depth
            row = [score_frame(e.normals(depth, got.K, depth > 0), got)[1] for e in entries]
            scores.append(row)
            d = auto_decision(depth, got.K)
            ran = d.method + (f" ({d.upsampled:g}x)" if d.upsampled > 1 else "")
            print(f"| {k:g} | {f.name} | {ran} | " + " | ".join(f"{a:.1f}" for a in row) + " |", flush=True)
        means = np.mean(scores, axis=0)
        print(f"| {k:g} | mean of {len(frames)} | | " + " | ".join(f"{m:.1f}" for m in means) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
