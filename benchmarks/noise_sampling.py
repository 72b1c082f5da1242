"""The noise measurement's sampling on frames under 300,000 pixels: the shipped step against the denser one before it.

    PYTHONPATH=src python benchmarks/noise_sampling.py SENSOR_DIR [--rounds 21] [--json out.json]

``surfnorm._constants.noise_step`` samples every 5th row and column of a frame of up to 640x480 pixels (a 640x480
frame's own step; at least 3,000 samples) and about 12,000 pixels of a larger one. Before, every frame got about
12,000 samples: every 4th row and column at 450x375, every 3rd at 320x240. On frames of 300,000 pixels or more the
two rules give the same step (the same normals, to the bit). For smaller frames this compares them, the earlier
rule patched in for the comparison (``surfnorm.kernels.sensor_noise.noise_step``):

1. real frames: each frame of SENSOR_DIR (the layout of ``surfnorm bench --sensor``) under 300,000 pixels whole,
   larger ones cropped (320x240 about the centre and at the top-left and bottom-right corners, 512x424 about the
   centre; the principal point moves with the crop; reference planes with under 200 pixels in a crop left out):
   the default's angle (the sensor benchmark's metric) with each rule, and OpenCV LINEMOD's (window 5);
2. the simulated sensors: the 12 3F2N frames of tests/data/3f2n-sample through each (seed 0), cropped to 320x240
   about the centre: the default's mean e_A with each rule, and its sigma's calibration (deciles of pixels by
   sigma whose RMS error over mean sigma lies in 0.67-1.5, as ``surfnorm bench``'s; the two frames of
   ``surfnorm.bench.uncertainty.SKIP`` left out of it);
3. clean depth: the 3F2N frames' exact depth in the same crops as 1: what ``auto`` decides with each rule;
4. speed: on the real frames and crops of 1, the default call (every core) with each rule and LINEMOD (one
   thread), alternating; medians of --rounds calls and their ratios.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import warnings
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
SMALL = 300_000  # pixels: below this the two rules differ


def dense_step(H: int, W: int) -> int:
    """The earlier rule: about 12,000 samples on every frame."""
    return max(1, round(math.sqrt(H * W / 12_000)))


def crops(H: int, W: int) -> list[tuple[str, int, int, int, int]]:
    if H * W < SMALL:
        return [("whole", 0, 0, H, W)]
    out = []
    if H >= 424 and W >= 512:
        out.append(("512x424", (H - 424) // 2, (W - 512) // 2, 424, 512))
    if H >= 240 and W >= 320:
        out += [
            ("320x240", (H - 240) // 2, (W - 320) // 2, 240, 320),
            ("320x240 top-left", 0, 0, 240, 320),
            ("320x240 bottom-right", H - 240, W - 320, 240, 320),
        ]
    return out


def cropped(z, K, v0, u0, h, w):
    from surfnorm.camera import Intrinsics

    return np.ascontiguousarray(z[v0 : v0 + h, u0 : u0 + w]), Intrinsics(K.fx, K.fy, K.cx - u0, K.cy - v0)


def main(argv=None) -> int:
    from surfnorm.bench.peers import single_thread

    single_thread()  # LINEMOD on one thread; surfnorm's own calls use every core
    import surfnorm
    import surfnorm.kernels.sensor_noise as noise
    from surfnorm.bench.scripts import threef2n_root
    from surfnorm.bench.sensor import (
        SensorFrame,
        alternating_medians,
        find_sensor_frames,
        linemod_entry,
        read_sensor_frame,
        score_frame,
    )
    from surfnorm.bench.simulate import SENSORS, frame_seed, simulate
    from surfnorm.bench.uncertainty import SKIP, deciles
    from surfnorm.io.threef2n import find_frames, read_frame
    from surfnorm.metrics import angular_error

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sensor_dir")
    ap.add_argument("--rounds", type=int, default=21)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    linemod = linemod_entry("noise_sampling")
    if linemod is None:
        return 2
    rules = {"shipped": noise.noise_step, "dense": dense_step}

    def under(rule, func, *a, **k):
        noise.noise_step = rules[rule]
        try:
            return func(*a, **k)
        finally:
            noise.noise_step = rules["shipped"]

    warnings.simplefilter("ignore", surfnorm.IntrinsicsWarning)  # crops move the principal point off centre
    result: dict = {"real": {}, "simulated": {}, "clean": {}, "speed": {}}
    cases = []
    for folder in find_sensor_frames(args.sensor_dir):
        fr = read_sensor_frame(folder)
        for tag, v0, u0, h, w in crops(*fr.depth.shape):
            z, K = cropped(fr.depth, fr.K, v0, u0, h, w)
            if fr.planes is not None:
                normals, masks = fr.planes
                masks = masks[:, v0 : v0 + h, u0 : u0 + w]
                keep = masks.sum(axis=(1, 2)) >= 200
                if not keep.any():
                    continue
                ref = SensorFrame(fr.name, z, K, planes=(normals[keep], masks[keep]))
            else:
                assert fr.gt is not None
                ref = SensorFrame(fr.name, z, K, gt=fr.gt[v0 : v0 + h, u0 : u0 + w])
            name = f"{fr.name} ({tag})"
            cases.append((name, z, K))
            row = {rule: score_frame(under(rule, surfnorm.estimate, z, K), ref)[1] for rule in rules}
            row["linemod"] = score_frame(linemod.call(z, K, z > 0), ref)[1]
            result["real"][name] = row
    print("| real frame (crop) | default, shipped step | default, dense step | LINEMOD w5 |")
    print("|---|---|---|---|")
    for name, row in result["real"].items():
        print(f"| {name} | {row['shipped']:.2f} | {row['dense']:.2f} | {row['linemod']:.2f} |")
    moved = np.array([row["shipped"] - row["dense"] for row in result["real"].values()])
    if moved.size:
        print(
            f"\nshipped - dense: mean {moved.mean():+.3f}, median {np.median(moved):+.3f}, "
            f"from {moved.min():+.3f} to {moved.max():+.3f} degrees over {moved.size} frames and crops\n"
        )

    root = threef2n_root(None, REPO)
    names = find_frames(root)
    frames = [read_frame(root, n) for n in names]
    print("| simulated sensor (320x240 crops) | e_A shipped | e_A dense | calibration shipped | calibration dense |")
    print("|---|---|---|---|---|")
    for sensor in SENSORS:
        errors: dict[str, list] = {rule: [] for rule in rules}
        pooled: dict[str, tuple[list, list]] = {rule: ([], []) for rule in rules}
        for name, fr in zip(names, frames):
            depth = simulate(fr.depth, fr.K, sensor, seed=frame_seed(0, name, sensor), mask=fr.mask, normals=fr.normals)
            H, W = depth.shape
            v0, u0 = (H - 240) // 2, (W - 320) // 2
            z, K = cropped(depth, fr.K, v0, u0, 240, 320)
            gt = fr.normals[v0 : v0 + 240, u0 : u0 + 320]
            m = fr.mask[v0 : v0 + 240, u0 : u0 + 320] & (z > 0)
            if m.sum() < 500:
                continue
            for rule in rules:
                n, sigma = under(rule, surfnorm.estimate, z, K, uncertainty=True)
                err = angular_error(n, gt)
                errors[rule].append(float(np.nanmean(err[m])))
                if not any(name.startswith(s + "/") for s in SKIP):
                    mm = m & np.isfinite(sigma)
                    pooled[rule][0].append(err[mm])
                    pooled[rule][1].append(sigma[mm].astype(np.float64))
        row = {}
        for rule in rules:
            d = deciles(np.concatenate(pooled[rule][0]), np.concatenate(pooled[rule][1]))
            row[rule] = {"e_A": float(np.mean(errors[rule])), "within": sum(0.67 <= x["ratio"] <= 1.5 for x in d)}
        result["simulated"][sensor] = row
        print(
            f"| {sensor} | {row['shipped']['e_A']:.3f} | {row['dense']['e_A']:.3f} | "
            f"{row['shipped']['within']}/10 | {row['dense']['within']}/10 |",
            flush=True,
        )

    for name, fr in zip(names, frames):
        for tag, v0, u0, h, w in crops(*fr.depth.shape):
            z, K = cropped(fr.depth, fr.K, v0, u0, h, w)
            if (z > 0).sum() >= 1000:
                result["clean"][f"{name} ({tag})"] = {
                    rule: under(rule, surfnorm.auto_decision, z, K).method for rule in rules
                }
    off = {k: v for k, v in result["clean"].items() if set(v.values()) != {"d2nt_v3"}}
    print(f"\nclean 3F2N crops: {len(result['clean'])}, decided other than d2nt_v3 with either rule: {off or 'none'}\n")

    print("| frame (crop) | ms shipped | ms dense | ms LINEMOD | shipped / LINEMOD | dense / LINEMOD |")
    print("|---|---|---|---|---|---|")
    for name, z, K in cases:
        valid = z > 0
        calls = {
            "shipped": lambda z=z, K=K: surfnorm.estimate(z, K),
            "dense": lambda z=z, K=K: under("dense", surfnorm.estimate, z, K),
            "linemod": lambda z=z, K=K, valid=valid: linemod.call(z, K, valid),
        }
        ms = alternating_medians(calls, args.rounds)
        result["speed"][name] = ms
        print(
            f"| {name} | {ms['shipped']:.2f} | {ms['dense']:.2f} | {ms['linemod']:.2f} "
            f"| {ms['shipped'] / ms['linemod']:.2f} | {ms['dense'] / ms['linemod']:.2f} |",
            flush=True,
        )
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
