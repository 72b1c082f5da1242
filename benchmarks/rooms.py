"""Simulated rooms through each simulated sensor: the default and the peers on large planes and a grazing floor.

    PYTHONPATH=src python benchmarks/rooms.py
    PYTHONPATH=src python benchmarks/rooms.py --sensors stereo_sgbm,smooth_error --methods auto,opencv_linemod_w5
    PYTHONPATH=src python benchmarks/rooms.py --steps 1,2 --methods auto,d2nt_v3,adaptive_fit
    PYTHONPATH=src python benchmarks/rooms.py --white 0.005,0.01,0.02 --methods auto,d2nt_v3,adaptive_fit

The 3F2N frames of `benchmarks/sensor_sim.py` are objects at a table's distance, seen mostly face on. A robot's
camera sees rooms: walls, and a floor at 60-85 degrees from the line of sight. Three rooms, each a floor, a back wall
and a side wall (camera 0.6-1.2 m above the floor, pitched down 8-25 degrees and turned -15 to 20 degrees; back wall
3-5 m, side wall 1.2-2 m away), 480x640 at f = 525 px, depth in metres, go through each sensor of
`surfnorm.bench.simulate` (seed 0; the sensors' noise at their own scale: `scale=1`). Per sensor and method: e_A in
degrees over the pixels with depth and a normal, by the angle between the line of sight and the surface (the floor
far away is the widest), and over all of them. Every library runs on one thread. ``--steps Q1,Q2``: instead of the
sensors, the exact depth stored in steps of Q millimetres (a renderer's or a dataset's 16-bit PNG: whole millimetres
for Q = 1), no noise. ``--white P1,P2``: instead, the exact depth in float32 with white noise of P percent of depth
(Gaussian, independent from pixel to pixel: a high-end structured-light camera's, a simulation's), seed 0.
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np

H, W, F = 480, 640, 525.0
#: (pitch down, camera height, turn, back wall distance, side wall distance): degrees and metres
ROOMS = ((15.0, 1.0, 0.0, 4.0, 1.5), (25.0, 0.6, 20.0, 3.0, 1.2), (8.0, 1.2, -15.0, 5.0, 2.0))
#: bins of the angle between the line of sight and the surface's normal, degrees
BINS = (0, 45, 60, 70, 75, 80, 90)


def room(pitch: float, height: float, turn: float, back: float, side: float):
    """(depth (H, W), exact normals (H, W, 3) in the camera frame, the angle of each pixel's line of sight to its
    surface's normal in degrees) of a room: the floor ``height`` below the camera, a back wall ``back`` ahead and a
    side wall ``side`` to the right, the camera pitched down by ``pitch`` and turned by ``turn`` (degrees)."""
    K = intrinsics()
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    rays = np.stack([(u - K[0, 2]) / F, (v - K[1, 2]) / F, np.ones_like(u)], axis=-1)  # camera frame, y down
    p, t = math.radians(pitch), math.radians(turn)
    down = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(p), math.sin(p)], [0.0, -math.sin(p), math.cos(p)]])
    round_ = np.array([[math.cos(t), 0.0, math.sin(t)], [0.0, 1.0, 0.0], [-math.sin(t), 0.0, math.cos(t)]])
    R = round_ @ down  # camera to room
    d = rays @ R.T  # each pixel's ray in the room, per unit of depth
    depth = np.full((H, W), np.inf)
    normals = np.zeros((H, W, 3))
    # each plane as (its normal facing the camera, its distance from the camera): n . x = -distance
    for n, dist in ((np.array([0.0, -1.0, 0.0]), height), (np.array([0.0, 0.0, -1.0]), back), ((-1.0, 0, 0), side)):
        n = np.asarray(n, np.float64)
        towards = d @ -n
        hit = np.where(towards > 1e-9, dist / np.where(towards > 1e-9, towards, 1.0), np.inf)
        nearer = hit < depth
        depth = np.where(nearer, hit, depth)
        normals[nearer] = R.T @ n
    depth[~np.isfinite(depth)] = 0.0
    unit = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    view = np.degrees(np.arccos(np.clip(np.abs((unit * normals).sum(-1)), 0.0, 1.0)))
    return depth, normals, view


def _number(text: str) -> float:
    """``text`` as a float; NaN where it is not a number (so that the range test refuses it)."""
    try:
        return float(text)
    except ValueError:
        return float("nan")


def intrinsics() -> np.ndarray:
    return np.array([[F, 0.0, (W - 1) / 2], [0.0, F, (H - 1) / 2], [0.0, 0.0, 1.0]])


def main(argv=None) -> int:
    from surfnorm.bench.peers import single_thread

    single_thread()  # before any peer library is imported
    from surfnorm.bench.sensor import make_entries
    from surfnorm.bench.simulate import SENSORS, frame_seed, sensor_names, simulate
    from surfnorm.camera import Intrinsics
    from surfnorm.errors import SurfnormError
    from surfnorm.metrics import mean_angular_error

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sensors", default=",".join(SENSORS), help="comma-separated; default: every sensor")
    ap.add_argument("--methods", default="auto,d2nt_v3,adaptive_fit,opencv_linemod_w5,opencv_fals_w7,open3d_knn30")
    ap.add_argument("--steps", default=None, help="comma-separated millimetres: the exact depth in such steps instead")
    ap.add_argument("--white", default=None, help="comma-separated percents: the exact depth with such white noise")
    args = ap.parse_args(argv)
    try:
        entries, missing = make_entries(args.methods.split(","))
        if args.steps is not None and args.white is not None:
            raise SurfnormError("--steps, --white: expected one of them, got both")
        if args.steps is not None:
            sensors = [f"{q} mm" for q in args.steps.split(",")]
            wrong = [q for q in args.steps.split(",") if not _number(q) > 0.0]
            if wrong:
                raise SurfnormError(f"--steps: expected millimetres above 0, got {', '.join(wrong)}")
        elif args.white is not None:
            wrong = [p for p in args.white.split(",") if not 0.0 < _number(p) <= 5.0]
            if wrong:
                raise SurfnormError(f"--white: expected percents above 0 and at most 5, got {', '.join(wrong)}")
            sensors = [f"white noise {_number(p):g} %" for p in args.white.split(",")]  # (the seed: 0.01 as 0.010)
        else:
            sensors = sensor_names(args.sensors)
    except SurfnormError as exc:
        print(f"rooms: {exc}", file=sys.stderr)
        return 2
    for name, why in missing.items():
        print(f"(left out: {name}: {why})")
    K = intrinsics()
    cam = Intrinsics.from_matrix(K)
    scenes = [room(*r) for r in ROOMS]
    labels = [f"{a}-{b}" for a, b in zip(BINS[:-1], BINS[1:])] + ["all"]
    for sensor in sensors:
        errors: dict[str, list[list[float]]] = {e.label: [[] for _ in labels] for e in entries}
        weights: list[list[int]] = [[] for _ in labels]
        for k, (depth, normals, view) in enumerate(scenes):
            if args.steps is not None:  # the exact depth in steps of q millimetres
                q = _number(sensor.split()[0]) / 1000.0
                z = np.where(depth > 0, np.round(depth / q) * q, 0.0).astype(np.float32)
            elif args.white is not None:  # the exact depth with white noise of p percent of depth
                p = _number(sensor.split()[2]) / 100.0
                noise = np.random.default_rng(frame_seed(0, f"room{k}", sensor)).standard_normal(depth.shape)
                z = np.where(depth > 0, depth * (1.0 + p * noise), 0.0).astype(np.float32)
            else:
                z = simulate(depth, K, sensor, seed=frame_seed(0, f"room{k}", sensor), normals=normals, scale=1.0)
            valid = z > 0
            parts = [valid & (view >= a) & (view < b) for a, b in zip(BINS[:-1], BINS[1:])] + [valid]
            for i, part in enumerate(parts):
                weights[i].append(int(part.sum()))
            for e in entries:
                n = e.normals(z, cam, valid)
                for i, part in enumerate(parts):
                    errors[e.label][i].append(mean_angular_error(n, normals, part) if part.any() else 0.0)
        print(f"\n### {sensor}: e_A (degrees) by the angle between line of sight and surface, three rooms\n")
        print("| method | " + " | ".join(labels) + " |")
        print("|" + "---|" * (len(labels) + 1))
        for label, per_bin in errors.items():
            cells = []
            for i, values in enumerate(per_bin):
                w = np.array(weights[i], np.float64)
                cells.append(f"{np.dot(values, w) / w.sum():.1f}" if w.sum() >= 200 else "-")
            print(f"| {label} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
