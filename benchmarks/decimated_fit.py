"""What the default would give if it fitted a quarter of the pixels: the speed that acceptance asks of it on 2 cores.

    PYTHONPATH=src python benchmarks/decimated_fit.py [SENSOR_DIR] [--sensors kinect_v1,primesense,...] [--rounds 9]

The default call (`surfnorm.estimate(depth, K)`, every core) against the same call on a half-size frame, whose
normals are then repeated over each 2x2 block of the frame:

- ``decimated``: every other row and column, the pixels (2 i, 2 j), with fx / 2, fy / 2, cx / 2, cy / 2 (0-based
  pixel centres: the pixel u = 2 i of the frame is the pixel i of the half-size one exactly);
- ``binned``: each 2x2 block's depth from the mean inverse depth of its valid pixels (where at least 2 of the 4
  are), with the principal point at (c - 0.5) / 2 (a block's centre is its pixels' mean);

measured
1. on the frames of SENSOR_DIR (default ../shared/data/sensor-sample beside the repository, skipped where absent;
   the layout of `surfnorm bench --sensor`): the plane metric of each (mean folded angle, and the coverage of the
   two half-size ones), and the same-run median times of each and of OpenCV's LINEMOD w5 on one thread (as the
   sensor benchmark runs it), called alternately, as ratios to LINEMOD's;
2. on the 12 3F2N sample frames as each simulated sensor of --sensors delivers them (seed 0): the mean e_A of each.

A pixel without depth gets no normal. This bounds the idea; it is not a method: the repeat gives each 2x2 block one
normal, where a fit on every fourth row and column would keep every pixel in its windows and carry the planes to the
pixels between them, each to the side of an edge that it lies on, as ``adaptive_fit``'s stride 2 does. The
half-size calls' times include NumPy's resampling. Needs OpenCV with `RgbdNormals`
(`pip install opencv-contrib-python-headless`). Timings are never asserted in tests.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent


def decimated(z: np.ndarray, K) -> np.ndarray:
    """The default's normals (every core) of every other row and column of ``z`` (intrinsics ``K`` halved), repeated
    2x2; fill (0) where ``z`` has no depth."""
    import surfnorm
    from surfnorm.camera import Intrinsics

    half = Intrinsics(K.fx / 2, K.fy / 2, K.cx / 2, K.cy / 2)
    return _repeated(surfnorm.estimate(np.ascontiguousarray(z[::2, ::2]), half), z)


def binned(z: np.ndarray, K) -> np.ndarray:
    """The default's normals (every core) of ``z`` binned 2x2 (each block's depth from the mean inverse depth of its
    valid pixels, where at least 2 of its 4 are; a last odd row or column dropped), repeated 2x2; fill (0) where
    ``z`` has no depth and on a dropped row or column."""
    import surfnorm
    from surfnorm.camera import Intrinsics

    H, W = (z.shape[0] // 2) * 2, (z.shape[1] // 2) * 2
    valid = z[:H, :W] > 0
    w = np.where(valid, 1.0 / np.where(valid, z[:H, :W], 1.0), 0.0)
    count = valid.reshape(H // 2, 2, W // 2, 2).sum(axis=(1, 3))
    total = w.reshape(H // 2, 2, W // 2, 2).sum(axis=(1, 3))
    coarse = np.where(count >= 2, np.maximum(count, 1) / np.where(count >= 2, total, 1.0), 0.0).astype(np.float32)
    # a block's centre is the mean of its pixels' (0-based): u = 2 i + 0.5
    half = Intrinsics(K.fx / 2, K.fy / 2, (K.cx - 0.5) / 2, (K.cy - 0.5) / 2)
    return _repeated(surfnorm.estimate(coarse, half), z)


def _repeated(n: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Half-size normals ``n`` repeated over 2x2 blocks to the shape of ``z``; 0 where ``z`` has no depth (and
    beyond ``n``'s blocks)."""
    H, W = z.shape
    full = np.zeros((H, W, 3), np.float32)
    full[: 2 * n.shape[0], : 2 * n.shape[1]] = np.repeat(np.repeat(n, 2, axis=0), 2, axis=1)[:H, :W]
    full[~(z > 0)] = 0.0
    return full


def main(argv=None) -> int:
    from surfnorm.bench.peers import single_thread

    single_thread()  # LINEMOD on one thread, as in the sensor benchmark; the default on every core, as a user calls it
    import surfnorm
    from surfnorm.bench.scripts import threef2n_root
    from surfnorm.bench.sensor import (
        alternating_medians,
        find_sensor_frames,
        linemod_entry,
        read_sensor_frame,
        score_frame,
    )
    from surfnorm.bench.simulate import frame_seed, sensor_names, simulate
    from surfnorm.camera import Intrinsics
    from surfnorm.errors import InputError
    from surfnorm.io.threef2n import find_frames, read_frame
    from surfnorm.metrics import mean_angular_error

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sensor_dir", nargs="?", default=str(REPO.parent / "shared" / "data" / "sensor-sample"))
    ap.add_argument("--sensors", default="kinect_v1,primesense,d435,kinect_v1_raw,post_filtered,tof")
    ap.add_argument("--rounds", type=int, default=9)
    args = ap.parse_args(argv)
    try:
        sensors = sensor_names(args.sensors)
    except InputError as exc:
        print(f"decimated_fit: {exc}", file=sys.stderr)
        return 2
    linemod = linemod_entry("decimated_fit")
    if linemod is None:
        return 2

    folders = find_sensor_frames(args.sensor_dir) if Path(args.sensor_dir).is_dir() else []
    variants = {"default": lambda z, K: surfnorm.estimate(z, K), "decimated": decimated, "binned": binned}
    rows = [
        "| frame | size | default: angle (ms) | decimated: angle, coverage (ms) | binned: angle, coverage (ms) "
        "| LINEMOD (ms) | ratios to LINEMOD |",
        "|---|---|---|---|---|---|---|",
    ]
    for folder in folders:
        f = read_sensor_frame(folder)
        z, K, valid = f.depth, f.K, f.depth > 0
        calls = {name: (lambda run=run: run(z, K)) for name, run in variants.items()}
        calls["linemod"] = lambda: linemod.call(z, K, valid)
        ms = alternating_medians(calls, args.rounds)
        cells = []
        for name, run in variants.items():
            _, angle, cover = score_frame(run(z, K), f)
            cells.append(
                f"{angle:.2f} ({ms[name]:.1f})" if name == "default" else f"{angle:.2f}, {cover:.3f} ({ms[name]:.1f})"
            )
        ratios = ", ".join(f"{ms[name] / ms['linemod']:.2f}" for name in variants)
        rows.append(f"| {f.name} | {z.shape[1]}x{z.shape[0]} | {' | '.join(cells)} | {ms['linemod']:.1f} | {ratios} |")
    if folders:
        print("\n".join(rows) + "\n")

    root = threef2n_root(None, REPO)
    names = find_frames(root)
    rows = ["| simulated sensor | default e_A | decimated e_A (ratio) | binned e_A (ratio) |", "|---|---|---|---|"]
    for s in sensors:
        errors: dict[str, list] = {name: [] for name in variants}
        for name in names:
            f = read_frame(root, name)
            z = simulate(f.depth, f.K, s, seed=frame_seed(0, name, s), mask=f.mask, normals=f.normals)
            K = Intrinsics.from_matrix(f.K)
            m = (z > 0) & f.mask
            for variant, run in variants.items():
                errors[variant].append(mean_angular_error(run(z, K), f.normals, m))
        e = {name: float(np.mean(v)) for name, v in errors.items()}
        rows.append(
            f"| {s} | {e['default']:.2f} | {e['decimated']:.2f} ({e['decimated'] / e['default']:.3f}) "
            f"| {e['binned']:.2f} ({e['binned'] / e['default']:.3f}) |"
        )
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
