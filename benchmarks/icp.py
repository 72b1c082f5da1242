"""Point-to-plane ICP between frames of an RGB-D sequence with a ground-truth trajectory, the target's normals from
surfnorm, from surfnorm filtered or weighted by its uncertainty, from Open3D and from OpenCV.

    # build the data folder once from the raw files (see "Layout" below), then run the benchmark
    PYTHONPATH=src python benchmarks/icp.py DATA --prepare redwood \\
        --raw RAW
    PYTHONPATH=src python benchmarks/icp.py DATA --out bench-output/icp

Writes OUT/icp.md (the table), OUT/icp.json (every pair, every variant, the settings and versions) and OUT/icp.png
(translation and rotation error per pair and variant).

Layout of the data folder (DATA):

- ``depth/*.png``: 16-bit depth images, ``meta.json``'s ``depth_scale`` units per metre (0 = no depth);
- ``poses.txt``: one line per frame, in order: the depth file's name, then the first three rows of the frame's
  camera-to-world matrix (12 numbers, row-major; camera frame x right, y down, z forward);
- ``K.json``: ``fx``, ``fy``, ``cx``, ``cy`` in pixels (0-based pixel centres);
- ``meta.json``: ``depth_scale``, ``source``, ``licence``.

``--prepare redwood --raw RAW`` makes it from a Redwood-style folder (``RAW/depth/*.png`` in millimetres and
``RAW/trajectory.log``: per frame a line of three integers, then the 4x4 camera-to-world matrix), with the PrimeSense
default intrinsics that Open3D uses for that data (fx = fy = 525, cx = 319.5, cy = 239.5). ``--prepare tum --raw
RAW`` makes it from a TUM RGB-D sequence folder (``depth.txt``, ``depth/``, ``groundtruth.txt``: ``timestamp tx ty tz
qx qy qz qw``, camera-to-world), each depth frame with the pose nearest in time (dropped beyond 20 ms), depth 1/5000
m, and the intrinsics given by ``--fx --fy --cx --cy``.

What runs, for each pair (i, i + k), k in ``--strides``: the source is frame i + k, the target frame i, so that ICP's
answer maps source points into the target's camera frame and is compared with inv(T_i) @ T_{i+k} (T = camera to
world). Before any ICP the script checks that convention: the ground truth's relative pose must leave a smaller
point-to-plane residual than its inverse and the two world-side products on at least 90 % of the pairs, or it stops
(the pairs where it does not are reported: a real sequence's ground truth has errors of its own). A pair whose two
depth frames are identical (a dropped frame sent twice, as TUM RGB-D has) is left out and reported. Both clouds are the
back-projected pixels (0-based pixel centres), thinned by a voxel grid of ``--voxel`` metres that keeps the first
pixel of each voxel in raster order, with that pixel's own normal (no averaging of points or normals). Open3D's
``registration_icp`` with ``TransformationEstimationPointToPlane()`` (L2), identity initial guess, maximum
correspondence distance ``--max-distance``, criteria: relative fitness and RMSE 1e-6, at most 50 iterations. Fitness
and inlier RMSE are Open3D's ``evaluate_registration`` of the result (point to point, unweighted, so that weighted
variants are reported in the same units).

The target normals (a target point without a normal is dropped):

- ``surfnorm``: ``surfnorm.estimate(depth, K)`` (the default method) on the whole image;
- ``surfnorm, sigma <= p70``: the same normals, keeping the target points whose predicted angular error (``sigma``
  from ``surfnorm.estimate(depth, K, uncertainty=True)``) is at most the 70th percentile of the thinned target's;
- ``surfnorm, sigma-weighted``: every point kept, its normal scaled by sqrt(w), w = 1 / (s_z(z)^2 + (l sigma)^2),
  normalised to a largest weight of 1. Open3D's point-to-plane step uses the target normal as given (residual
  (p - q) . n, Jacobian rows (p x n, n)), so a normal of length sqrt(w) makes each Gauss-Newton step weighted least
  squares with weight w: the inverse of the residual's variance, from the depth noise s_z(z) = 1.2 mm + 1.9 mm
  (z - 0.4 m)^2 (a structured-light sensor's axial noise, Nguyen et al. 2012) and the normal's error over a lever of
  l = half a voxel (the typical in-plane distance between a source point and its nearest target point);
- controls for those two: ``surfnorm, random 70 %`` (a seeded random 70 % of the points, the filter's count
  without its choice) and ``surfnorm, depth-weighted`` / ``Open3D KNN 30, depth-weighted`` (the same weights with
  sigma = 0: only the depth noise), which tell what sigma itself adds;
- ``Open3D KNN 30``: ``estimate_normals(KDTreeSearchParamKNN(30))`` on the whole cloud, oriented towards the camera;
- ``Open3D hybrid``: ``estimate_normals(KDTreeSearchParamHybrid(2 * voxel, 30))`` on the thinned cloud (Open3D's
  tutorial pipeline), oriented towards the camera;
- ``OpenCV LINEMOD``: ``cv2.RgbdNormals`` LINEMOD, window 5, where this OpenCV has it (OpenCV 5 or the contrib build).

Needs Open3D and Matplotlib (``pip install open3d matplotlib``).
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

#: ICP's settings (stated in the outputs).
MAX_ITERATIONS = 50
RELATIVE = 1e-6
KEEP_PERCENTILE = 70.0
#: The share of the pairs on which the ground truth's relative pose may lose the convention check (a real
#: sequence's ground truth has errors of its own) before the script stops.
CONVENTION_MISSES = 0.1
LINEMOD_WINDOW = 5
TUM_MAX_DT = 0.02

VARIANTS = (
    "surfnorm",
    "surfnorm, sigma <= p70",
    "surfnorm, sigma-weighted",
    "surfnorm, random 70 %",
    "surfnorm, depth-weighted",
    "Open3D KNN 30",
    "Open3D KNN 30, depth-weighted",
    "Open3D hybrid",
    "OpenCV LINEMOD",
)


# -- poses ---------------------------------------------------------------------------------------------------------


def pose_error(T_est: np.ndarray, T_gt: np.ndarray) -> tuple[float, float]:
    """(translation error in the poses' unit, rotation error in degrees) of ``T_est`` against ``T_gt`` (4x4).

    The error is E = inv(T_gt) @ T_est: its translation's length and its rotation's angle.
    """
    E = np.linalg.inv(T_gt) @ T_est
    cos = np.clip((np.trace(E[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.linalg.norm(E[:3, 3])), float(np.degrees(np.arccos(cos)))


def relative_pose(T_i: np.ndarray, T_j: np.ndarray) -> np.ndarray:
    """The pose of camera j in camera i's frame, from camera-to-world poses: maps points of frame j into frame i."""
    return np.linalg.inv(T_i) @ T_j


def quaternion_matrix(tx, ty, tz, qx, qy, qz, qw) -> np.ndarray:
    """4x4 matrix of a TUM pose line's translation and unit quaternion (x, y, z, w)."""
    q = np.array([qw, qx, qy, qz], dtype=np.float64)
    w, x, y, z = q / np.linalg.norm(q)
    T = np.eye(4)
    T[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    T[:3, 3] = [tx, ty, tz]
    return T


def read_redwood_log(path: Path) -> list[np.ndarray]:
    """Camera-to-world 4x4 matrices of a Redwood ``trajectory.log`` (a line of three integers, then four rows)."""
    rows = [line.split() for line in Path(path).read_text().splitlines() if line.strip()]
    if len(rows) % 5:
        raise ValueError(f"{path}: expected blocks of 5 lines (a header and 4 matrix rows), got {len(rows)} lines")
    return [np.array(rows[b + 1 : b + 5], dtype=np.float64) for b in range(0, len(rows), 5)]


def associate(stamps: np.ndarray, pose_stamps: np.ndarray, max_dt: float = TUM_MAX_DT) -> np.ndarray:
    """Index of the nearest pose time for each stamp, -1 where none is within ``max_dt`` seconds."""
    order = np.argsort(pose_stamps)
    sorted_t = pose_stamps[order]
    right = np.clip(np.searchsorted(sorted_t, stamps), 1, len(sorted_t) - 1)
    left = right - 1
    pick = np.where(np.abs(sorted_t[left] - stamps) <= np.abs(sorted_t[right] - stamps), left, right)
    found = order[pick]
    return np.where(np.abs(pose_stamps[found] - stamps) <= max_dt, found, -1)


# -- the data folder -----------------------------------------------------------------------------------------------


def write_data(out: Path, depth_files, poses, K: dict, depth_scale: float, source: str, licence: str) -> None:
    import shutil

    (out / "depth").mkdir(parents=True, exist_ok=True)
    lines = []
    for src, T in zip(depth_files, poses):
        name = f"depth/{Path(src).name}"
        shutil.copyfile(src, out / name)
        lines.append(" ".join([name] + [repr(float(x)) for x in np.asarray(T)[:3].ravel()]))
    (out / "poses.txt").write_text("\n".join(lines) + "\n")
    (out / "K.json").write_text(json.dumps(K))
    meta = {"depth_scale": depth_scale, "source": source, "licence": licence}
    (out / "meta.json").write_text(json.dumps(meta, indent=1))
    print(f"{out}: {len(lines)} frames")


def prepare_redwood(raw: Path, out: Path) -> None:
    files = sorted((raw / "depth").glob("*.png"))
    poses = read_redwood_log(raw / "trajectory.log")
    if len(files) != len(poses):
        raise SystemExit(f"icp: {len(files)} depth files but {len(poses)} poses in {raw / 'trajectory.log'}")
    K = {"fx": 525.0, "fy": 525.0, "cx": 319.5, "cy": 239.5}
    source = f"Redwood-style folder {raw} (depth in mm, trajectory.log camera-to-world)"
    write_data(out, files, poses, K, 1000.0, source, "see the raw folder's README")


def prepare_tum(raw: Path, out: Path, K: dict) -> None:
    def table(path):
        return [line.split() for line in path.read_text().splitlines() if line.strip() and not line.startswith("#")]

    depth = table(raw / "depth.txt")
    gt = np.array(table(raw / "groundtruth.txt"), dtype=np.float64)
    found = associate(np.array([float(r[0]) for r in depth]), gt[:, 0])
    files = [raw / r[1] for r, f in zip(depth, found) if f >= 0]
    poses = [quaternion_matrix(*gt[f, 1:]) for f in found if f >= 0]
    source = f"TUM RGB-D folder {raw} (groundtruth.txt camera-to-world, nearest pose within {TUM_MAX_DT} s)"
    write_data(out, files, poses, K, 5000.0, source, "CC BY 4.0 (TUM RGB-D)")


def read_data(data: Path):
    """(depths in metres as float32 (N, H, W), camera-to-world poses (N, 4, 4), K dict, meta dict, names)."""
    import cv2

    meta = json.loads((data / "meta.json").read_text())
    K = json.loads((data / "K.json").read_text())
    names, poses = [], []
    for line in (data / "poses.txt").read_text().splitlines():
        if line.strip():
            name, *numbers = line.split()
            names.append(name)
            poses.append(np.vstack([np.array(numbers, dtype=np.float64).reshape(3, 4), [0, 0, 0, 1]]))
    depths = []
    for name in names:
        raw = cv2.imread(str(data / name), cv2.IMREAD_ANYDEPTH)
        if raw is None or raw.dtype != np.uint16:
            raise SystemExit(f"icp: {data / name} is not a 16-bit image")
        depths.append(raw.astype(np.float32) / np.float32(meta["depth_scale"]))
    return np.stack(depths), np.stack(poses), K, meta, names


# -- clouds --------------------------------------------------------------------------------------------------------


def back_project(depth: np.ndarray, K: dict) -> np.ndarray:
    """(H, W, 3) float64 points of a depth image in metres (0-based pixel centres; :func:`surfnorm.points`), zeros
    where there is no depth."""
    import surfnorm

    return surfnorm.points(depth, [[K["fx"], 0.0, K["cx"]], [0.0, K["fy"], K["cy"]], [0.0, 0.0, 1.0]])


def voxel_pick(points: np.ndarray, valid: np.ndarray, voxel: float) -> np.ndarray:
    """Flat pixel indices: the first valid pixel (raster order) of each occupied voxel, in raster order."""
    idx = np.flatnonzero(valid.ravel())
    if voxel <= 0:
        return idx
    keys = np.floor(points.reshape(-1, 3)[idx] / voxel).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return idx[np.sort(first)]


def cloud(points: np.ndarray, normals: np.ndarray | None = None):
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(points, dtype=np.float64)))
    if normals is not None:
        pc.normals = o3d.utility.Vector3dVector(np.ascontiguousarray(normals, dtype=np.float64))
    return pc


def axial_noise(z: np.ndarray) -> np.ndarray:
    """Standard deviation (m) of a structured-light sensor's depth at ``z`` metres (Nguyen et al. 2012, eq. 1)."""
    return 0.0012 + 0.0019 * (z - 0.4) ** 2


def sigma_weights(sigma_deg: np.ndarray, z: np.ndarray, lever: float) -> np.ndarray:
    """Inverse variance of a point-to-plane residual, normalised to a largest weight of 1."""
    w = 1.0 / (axial_noise(z) ** 2 + (lever * np.radians(sigma_deg)) ** 2)
    return w / w.max()


def point_to_plane_residual(source, target, T: np.ndarray, max_distance: float) -> float:
    """Median |(T p - q) . n_q| over source points whose nearest target point q is within ``max_distance``."""
    import open3d as o3d

    p = np.asarray(source.points) @ T[:3, :3].T + T[:3, 3]
    tree = o3d.geometry.KDTreeFlann(target)
    q = np.asarray(target.points)
    n = np.asarray(target.normals)
    res = []
    for x in p[:: max(1, len(p) // 5000)]:
        k, i, d2 = tree.search_knn_vector_3d(x, 1)
        if k and d2[0] <= max_distance**2:
            res.append(abs((x - q[i[0]]) @ n[i[0]]))
    return float(np.median(res)) if res else float("inf")


# -- normals of the target -----------------------------------------------------------------------------------------


def surfnorm_uncertainty(depth: np.ndarray, K: np.ndarray):
    """(normals, sigma) from surfnorm's uncertainty, or (None, why) where this surfnorm has none."""
    import surfnorm
    from surfnorm.errors import InputError

    try:
        normals, sigma = surfnorm.estimate(depth, K, uncertainty=True)
    except (TypeError, InputError) as exc:
        return None, f"surfnorm.estimate(..., uncertainty=True) refused: {exc}"
    return (np.asarray(normals), np.asarray(sigma)), None


def target_variants(depth: np.ndarray, K: dict, voxel: float):
    """{variant: (points (M, 3), normals (M, 3)) or a string saying why it is not available} for a target frame."""
    import open3d as o3d

    import surfnorm

    Km = np.array([[K["fx"], 0, K["cx"]], [0, K["fy"], K["cy"]], [0, 0, 1]], dtype=np.float64)
    P = back_project(depth, K)
    valid = depth > 0
    pick = voxel_pick(P, valid, voxel)
    pts = P.reshape(-1, 3)[pick]
    out: dict = {}

    def per_pixel(normals: np.ndarray, keep: np.ndarray | None = None):
        n = normals.reshape(-1, 3)[pick].astype(np.float64)
        ok = np.isfinite(n).all(axis=1) & (np.linalg.norm(n, axis=1) > 0.5)
        if keep is not None:
            ok &= keep
        return pts[ok], n[ok]

    out["surfnorm"] = per_pixel(surfnorm.estimate(depth, Km))
    p, n = out["surfnorm"]
    keep = np.random.default_rng(0).random(len(p)) < KEEP_PERCENTILE / 100
    out["surfnorm, random 70 %"] = (p[keep], n[keep])
    out["surfnorm, depth-weighted"] = (p, n * np.sqrt(sigma_weights(np.zeros(len(p)), p[:, 2], voxel / 2))[:, None])

    got, why = surfnorm_uncertainty(depth, Km)
    if got is None:
        out["surfnorm, sigma <= p70"] = out["surfnorm, sigma-weighted"] = why
    else:
        normals, sigma = got
        s = sigma.reshape(-1)[pick].astype(np.float64)
        finite = np.isfinite(s)
        cut = np.percentile(s[finite], KEEP_PERCENTILE)
        out["surfnorm, sigma <= p70"] = per_pixel(normals, finite & (s <= cut))
        p, n = per_pixel(normals, finite)
        w = sigma_weights(s[finite & _has_normal(normals, pick)], p[:, 2], voxel / 2)
        out["surfnorm, sigma-weighted"] = (p, n * np.sqrt(w)[:, None])

    full = cloud(P.reshape(-1, 3)[valid.ravel()])
    full.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(30))
    full.orient_normals_towards_camera_location(np.zeros(3))
    n_full = np.zeros((depth.size, 3))
    n_full[np.flatnonzero(valid.ravel())] = np.asarray(full.normals)
    out["Open3D KNN 30"] = per_pixel(n_full.reshape(depth.shape + (3,)))
    p, n = out["Open3D KNN 30"]
    w = sigma_weights(np.zeros(len(p)), p[:, 2], voxel / 2)
    out["Open3D KNN 30, depth-weighted"] = (p, n * np.sqrt(w)[:, None])

    thin = cloud(pts)
    thin.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
    thin.orient_normals_towards_camera_location(np.zeros(3))
    out["Open3D hybrid"] = (pts, np.asarray(thin.normals).copy())

    from surfnorm.camera import Intrinsics
    from surfnorm.demo import _facing_camera, opencv_rgbd_normals

    opencv, why = opencv_rgbd_normals()
    if opencv is None:
        out["OpenCV LINEMOD"] = why
    else:
        n = opencv(depth, Intrinsics(K["fx"], K["fy"], K["cx"], K["cy"]), "LINEMOD", LINEMOD_WINDOW)
        out["OpenCV LINEMOD"] = per_pixel(_facing_camera(n))
    return out


def _has_normal(normals: np.ndarray, pick: np.ndarray) -> np.ndarray:
    n = normals.reshape(-1, 3)[pick]
    return np.isfinite(n).all(axis=1) & (np.linalg.norm(n, axis=1) > 0.5)


# -- the benchmark -------------------------------------------------------------------------------------------------


def run_icp(source, target, max_distance: float) -> np.ndarray:
    import open3d as o3d

    reg = o3d.pipelines.registration
    result = reg.registration_icp(
        source,
        target,
        max_distance,
        np.eye(4),
        reg.TransformationEstimationPointToPlane(),
        reg.ICPConvergenceCriteria(relative_fitness=RELATIVE, relative_rmse=RELATIVE, max_iteration=MAX_ITERATIONS),
    )
    return np.asarray(result.transformation).copy()


def convention_misses(convention: list[dict]) -> list:
    """The pairs of :func:`check_convention`'s rows on which the ground truth's relative pose does not leave the
    smallest residual of the four conventions; SystemExit where they are more than ``CONVENTION_MISSES`` of all
    (the convention, not the ground truth's own error, is then wrong)."""
    wrong = ("inverse_mm", "world_side_mm", "world_side_inverse_mm")
    bad = [c["pair"] for c in convention if not all(c["gt_mm"] < c[k] for k in wrong)]
    if len(bad) > CONVENTION_MISSES * len(convention):
        raise SystemExit(f"icp: the ground truth's relative pose does not register pairs {bad}: check the convention")
    return bad


def check_convention(depths, poses, K, pairs, voxel, max_distance) -> list[dict]:
    """The ground truth's relative pose against its inverse and the identity, by the point-to-plane residual."""
    import open3d as o3d

    rows = []
    for i, j in pairs:
        Pi, Pj = back_project(depths[i], K), back_project(depths[j], K)
        target = cloud(Pi.reshape(-1, 3)[voxel_pick(Pi, depths[i] > 0, voxel)])
        target.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
        source = cloud(Pj.reshape(-1, 3)[voxel_pick(Pj, depths[j] > 0, voxel)])
        candidates = {
            "gt_mm": relative_pose(poses[i], poses[j]),
            "inverse_mm": relative_pose(poses[j], poses[i]),
            "world_side_mm": poses[i] @ np.linalg.inv(poses[j]),
            "world_side_inverse_mm": poses[j] @ np.linalg.inv(poses[i]),
            "identity_mm": np.eye(4),
        }
        row = {"pair": [i, j]}
        for key, T in candidates.items():
            row[key] = 1e3 * point_to_plane_residual(source, target, T, max_distance)
        rows.append(row)
        print(
            f"convention check {i}->{j}, median |r| (mm): "
            + ", ".join(f"{k[:-3]} {v:.2f}" for k, v in row.items() if k != "pair"),
            flush=True,
        )
    return rows


def benchmark(data: Path, strides, voxel: float, max_distance: float) -> dict:
    import open3d as o3d

    o3d.utility.random.seed(0)
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    depths, poses, K, meta, names = read_data(data)
    pairs = [(i, i + k) for k in strides for i in range(len(depths) - k)]
    # a repeated frame (a sensor's dropped frame sent twice): the same depth under two poses, nothing to register
    repeated = [[i, j] for i, j in pairs if np.array_equal(depths[i], depths[j])]
    pairs = [(i, j) for i, j in pairs if [i, j] not in repeated]
    if not pairs:
        raise SystemExit(f"icp: no pairs with strides {strides} in {len(depths)} frames")
    convention = check_convention(depths, poses, K, pairs, voxel, max_distance)
    bad = convention_misses(convention)
    if bad:  # a real sequence's ground truth has errors of its own (timing, motion blur): kept, and reported
        print(f"icp: the ground truth's relative pose is not the best of the four on pairs {bad}", flush=True)
    targets: dict = {}
    results = []
    for i, j in pairs:
        if i not in targets:
            targets[i] = target_variants(depths[i], K, voxel)
        Pj = back_project(depths[j], K)
        source = cloud(Pj.reshape(-1, 3)[voxel_pick(Pj, depths[j] > 0, voxel)])
        T_gt = relative_pose(poses[i], poses[j])
        gt_t, gt_r = pose_error(np.eye(4), T_gt)
        row = {"pair": [i, j], "stride": j - i, "motion_m": gt_t, "motion_deg": gt_r, "variants": {}}
        for name in VARIANTS:
            got = targets[i][name]
            if isinstance(got, str):
                row["variants"][name] = {"available": False, "why": got}
                continue
            pts, n = got
            target = cloud(pts, n)
            t0 = time.perf_counter()
            T = run_icp(source, target, max_distance)
            seconds = time.perf_counter() - t0
            ev = o3d.pipelines.registration.evaluate_registration(source, cloud(pts), max_distance, T)
            t_err, r_err = pose_error(T, T_gt)
            row["variants"][name] = {
                "available": True,
                "t_err_m": t_err,
                "r_err_deg": r_err,
                "fitness": float(ev.fitness),
                "inlier_rmse_m": float(ev.inlier_rmse),
                "target_points": int(len(pts)),
                "seconds": seconds,
                "transformation": T.tolist(),
            }
        results.append(row)
        print(
            f"{i}->{j}: "
            + ", ".join(
                f"{k} {v['t_err_m'] * 1e3:.1f} mm {v['r_err_deg']:.2f} deg"
                for k, v in row["variants"].items()
                if v["available"]
            ),
            flush=True,
        )
    return {
        "data": str(data),
        "source": meta.get("source"),
        "licence": meta.get("licence"),
        "frames": names,
        "K": K,
        "settings": {
            "strides": list(strides),
            "voxel_m": voxel,
            "max_correspondence_distance_m": max_distance,
            "criteria": {"relative_fitness": RELATIVE, "relative_rmse": RELATIVE, "max_iteration": MAX_ITERATIONS},
            "estimation": "TransformationEstimationPointToPlane() (L2 kernel), identity initial guess",
            "source_frame": "i + k",
            "target_frame": "i",
            "keep_percentile": KEEP_PERCENTILE,
        },
        "convention_check": convention,
        "convention_misses": bad,
        "repeated_frames": repeated,
        "pairs": results,
        "summary": summarise(results),
        "summary_by_stride": {
            str(k): summarise([r for r in results if r["stride"] == k]) for k in sorted({r["stride"] for r in results})
        },
        "versions": versions(),
    }


def summarise(results: list[dict]) -> dict:
    out = {}
    for name in VARIANTS:
        rows = [r["variants"][name] for r in results if r["variants"][name]["available"]]
        if not rows:
            out[name] = {"available": False, "why": results[0]["variants"][name]["why"]}
            continue
        t = np.array([r["t_err_m"] for r in rows])
        a = np.array([r["r_err_deg"] for r in rows])
        out[name] = {
            "available": True,
            "pairs": len(rows),
            "t_median_m": float(np.median(t)),
            "t_mean_m": float(np.mean(t)),
            "r_median_deg": float(np.median(a)),
            "r_mean_deg": float(np.mean(a)),
            "fitness_mean": float(np.mean([r["fitness"] for r in rows])),
            "inlier_rmse_mean_m": float(np.mean([r["inlier_rmse_m"] for r in rows])),
            "target_points_mean": float(np.mean([r["target_points"] for r in rows])),
        }
    return out


def versions() -> dict:
    import open3d as o3d

    import surfnorm

    try:
        commit = subprocess.run(
            ["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = None
    v = {"surfnorm": surfnorm.__version__, "commit": commit, "open3d": o3d.__version__, "numpy": np.__version__}
    try:
        import cv2

        v["opencv"] = cv2.__version__
    except ImportError:
        pass
    v["machine"] = f"{platform.machine()} {platform.processor() or ''}".strip()
    v["python"] = platform.python_version()
    return v


def markdown(report: dict) -> str:
    s = report["settings"]
    lines = [
        f"ICP on {len(report['frames'])} frames ({report['source']}; {report['licence']}), {len(report['pairs'])} "
        f"pairs (strides {s['strides']}), voxel {s['voxel_m'] * 100:g} cm, max correspondence distance "
        f"{s['max_correspondence_distance_m'] * 100:g} cm, point-to-plane (L2), identity initial guess.",
        "",
        "| target normals | pairs | translation error, median / mean (mm) | rotation error, median / mean (deg) "
        "| fitness | inlier RMSE (mm) | target points |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name, r in report["summary"].items():
        if not r["available"]:
            lines.append(f"| {name} | not available: {r['why']} | | | | | |")
            continue
        lines.append(
            f"| {name} | {r['pairs']} | {r['t_median_m'] * 1e3:.2f} / {r['t_mean_m'] * 1e3:.2f} "
            f"| {r['r_median_deg']:.3f} / {r['r_mean_deg']:.3f} | {r['fitness_mean']:.3f} "
            f"| {r['inlier_rmse_mean_m'] * 1e3:.2f} | {r['target_points_mean']:.0f} |"
        )
    lines += ["", "By stride (median translation error mm / median rotation error deg):", ""]
    names = [n for n, r in report["summary"].items() if r["available"]]
    lines.append("| stride | pairs | " + " | ".join(names) + " |")
    lines.append("|---|---:|" + "---:|" * len(names))
    for k, summary in report["summary_by_stride"].items():
        cells = [f"{summary[n]['t_median_m'] * 1e3:.2f} / {summary[n]['r_median_deg']:.3f}" for n in names]
        lines.append(f"| {k} | {summary[names[0]]['pairs']} | " + " | ".join(cells) + " |")
    lines += ["", "Per pair (translation error mm / rotation error deg):", ""]
    names = [n for n, r in report["summary"].items() if r["available"]]
    lines.append("| pair | motion (mm / deg) | " + " | ".join(names) + " |")
    lines.append("|---|---:|" + "---:|" * len(names))
    for row in report["pairs"]:
        cells = [f"{row['variants'][n]['t_err_m'] * 1e3:.2f} / {row['variants'][n]['r_err_deg']:.3f}" for n in names]
        i, j = row["pair"]
        lines.append(
            f"| {i}->{j} | {row['motion_m'] * 1e3:.1f} / {row['motion_deg']:.2f} | " + " | ".join(cells) + " |"
        )
    return "\n".join(lines) + "\n"


#: Up to this many pairs the figure shows every pair's errors as bars; beyond, each variant's sorted errors.
BARS_UP_TO = 30


def figure(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [n for n, r in report["summary"].items() if r["available"]]
    pairs = report["pairs"]
    fig, axes = plt.subplots(2, 1, figsize=(12, 6.5), sharex=True)
    title = "Point-to-plane ICP against the ground truth, by the target's normals"
    if len(pairs) <= BARS_UP_TO:
        labels = [f"{r['pair'][0]}-{r['pair'][1]}" for r in pairs]
        x = np.arange(len(labels))
        width = 0.8 / max(1, len(names))
        for k, name in enumerate(names):
            t = [r["variants"][name]["t_err_m"] * 1e3 for r in pairs]
            a = [r["variants"][name]["r_err_deg"] for r in pairs]
            axes[0].bar(x + (k - (len(names) - 1) / 2) * width, t, width, label=name)
            axes[1].bar(x + (k - (len(names) - 1) / 2) * width, a, width, label=name)
        axes[1].set_xticks(x, labels)
        axes[1].set_xlabel("pair (target-source frame)")
    else:  # too many pairs for bars: each variant's errors sorted, the share of pairs at or below each
        share = 100.0 * np.arange(1, len(pairs) + 1) / len(pairs)
        for name in names:
            style = "-" if name.startswith("surfnorm") else "--"
            t = np.sort([r["variants"][name]["t_err_m"] * 1e3 for r in pairs])
            a = np.sort([r["variants"][name]["r_err_deg"] for r in pairs])
            axes[0].plot(share, t, style, label=name)
            axes[1].plot(share, a, style, label=name)
        axes[0].set_yscale("log")
        axes[1].set_yscale("log")
        axes[1].set_xlabel(f"share of the {len(pairs)} pairs (%), each variant's errors sorted")
        title += " (lower is better)"
    axes[0].set_ylabel("translation error (mm)")
    axes[1].set_ylabel("rotation error (deg)")
    axes[0].legend(fontsize=7, ncol=3)
    axes[0].set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path, help="the data folder (layout in the module's docstring)")
    parser.add_argument("--out", type=Path, default=ROOT / "bench-output" / "icp")
    parser.add_argument("--strides", type=int, nargs="+", default=[1, 2, 3, 4])
    parser.add_argument("--voxel", type=float, default=0.01, help="voxel side in metres (0: every pixel)")
    parser.add_argument("--max-distance", type=float, default=0.05, help="max correspondence distance, metres")
    parser.add_argument("--prepare", choices=["redwood", "tum"], help="build DATA from the raw files in --raw")
    parser.add_argument("--raw", type=Path)
    for name in ("fx", "fy", "cx", "cy"):
        parser.add_argument(f"--{name}", type=float, help="intrinsics for --prepare tum")
    args = parser.parse_args(argv)
    if args.prepare:
        if args.raw is None:
            parser.error("--prepare needs --raw")
        if args.prepare == "redwood":
            prepare_redwood(args.raw, args.data)
        else:
            K = {k: getattr(args, k) for k in ("fx", "fy", "cx", "cy")}
            if None in K.values():
                parser.error("--prepare tum needs --fx --fy --cx --cy")
            prepare_tum(args.raw, args.data, K)
        return 0
    try:
        import matplotlib  # noqa: F401
        import open3d  # noqa: F401
    except ImportError as exc:
        print(f"icp: needs Open3D and Matplotlib (pip install open3d matplotlib): {exc}", file=sys.stderr)
        return 2
    report = benchmark(args.data, args.strides, args.voxel, args.max_distance)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "icp.json").write_text(json.dumps(report, indent=1))
    (args.out / "icp.md").write_text(markdown(report))
    figure(report, args.out / "icp.png")
    print(markdown(report))
    print(f"wrote {args.out / 'icp.md'}, {args.out / 'icp.json'}, {args.out / 'icp.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
