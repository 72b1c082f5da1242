"""Make a frame folder for the sensor benchmark (`surfnorm bench --sensor DIR`) from a depth file or a stereo pair.

    # a depth file as a camera wrote it (any file surfnorm.io.read_depth reads), with its intrinsics
    PYTHONPATH=src python benchmarks/sensor_folder.py depth OUT/tum_fr2 1_depth.png --depth-scale 5000 \\
        --fx 520.9 --fy 521.0 --cx 325.1 --cy 249.7 --source "TUM RGB-D fr2 desk, CC BY 4.0"
    # NYU Depth v2's raw Kinect disparity (a little-endian 16-bit PGM, as libfreenect writes it)
    PYTHONPATH=src python benchmarks/sensor_folder.py depth OUT/nyu_raw d-1.pgm --kinect-disparity --byte-order little \\
        --fx 582.62 --fy 582.69 --cx 313.04 --cy 238.44 --source "NYU Depth v2 raw, research use"
    # OpenCV's SGBM on a rectified pair with ground-truth disparity (reference planes from the ground truth)
    PYTHONPATH=src python benchmarks/sensor_folder.py stereo OUT/mb2003_teddy im2.png im6.png disp2.png \\
        --gt-scale 4 --fx 450 --baseline 0.16 --source "Middlebury 2003 Teddy (quarter size)"
    # Middlebury 2014 or later: ground truth in PFM (inf unknown), depth f B / (d + doffs) with calib.txt's doffs
    PYTHONPATH=src python benchmarks/sensor_folder.py stereo OUT/mb2014q_motorcycle im0.png im1.png disp0GT.pfm \\
        --fx 999.421 --cx 294.182 --cy 252.932 --baseline 0.193001 --doffs 32.778 \\
        --source "Middlebury 2014 Motorcycle (trainingQ)"
    # the same pair through OpenCV's block matcher (another stereo family)
    PYTHONPATH=src python benchmarks/sensor_folder.py stereo OUT/mb2003_teddy_bm9 im2.png im6.png disp2.png \\
        --gt-scale 4 --fx 450 --baseline 0.16 --matcher bm --source "Middlebury 2003 Teddy (quarter size)"

The folder gets the layout of the benchmark's frames: the input file(s) as given (raw.*, or raw_left.*,
raw_right.*, raw_gt.*), depth.npy (float32 metres, 0 where invalid), K.json (fx, fy, cx, cy; 0-based pixel
centres; cx, cy default to the image centre), planes.npz (reference planes) and meta.json (where it came from, and
how the planes were found).

Reference planes: RANSAC on the back-projected valid points (Open3D's segment_plane, distance threshold
max(4 mm, 1.2 % of the median depth), 1000 iterations, seed 0), at most 5 planes, each cut to its largest
4-connected piece after a 5x5 erosion and kept if it has at least 2000 pixels, with its normal from an SVD of the
piece's points, facing the camera. For a stereo pair they are found on the ground truth's depth and kept where
SGBM gave depth, so that coverage measures the estimators, not the matcher. The ground truth is any image OpenCV
reads (its values divided by ``--gt-scale``), or a PFM file (surfnorm.io.read_depth: Middlebury 2014 and later,
SceneFlow, ETH3D); 0, negative and non-finite values are unknown. Open3D's RANSAC is not bit-stable
across runs on every frame: keep the planes.npz a run wrote as the reference.

SGBM (the default matcher): 5x5 blocks, P1 = 8 * 3 * 25, P2 = 32 * 3 * 25, disp12MaxDiff 1, uniqueness 10, speckle
window 100 and range 2, numDisparities the multiple of 16 above the ground truth's largest disparity + 8; depth f B / d.
``--matcher bm``: OpenCV's block matcher on the grey images instead (9x9 blocks, uniqueness 10, the same speckle
filter and disparity range), a second family of stereo error: fronto-parallel patches the size of a block.

Needs Open3D (``pip install open3d``; on Debian also ``apt-get install libusb-1.0-0``).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import cv2
import numpy as np

# the matchers (and their default blocks) and depth from disparity, shared with sensor_variants.py
from surfnorm.bench.processing import BLOCKS, stereo_depth, stereo_disparity

MAX_PLANES = 5
MIN_PIXELS = 2000


def reference_planes(depth: np.ndarray, fx: float, fy: float, cx: float, cy: float):
    """(normals (P, 3), masks (P, H, W), RANSAC threshold in metres) of ``depth`` (metres, 0 = invalid)."""
    import open3d as o3d

    o3d.utility.random.seed(0)
    H, W = depth.shape
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    z = depth.astype(np.float64)
    # written out, not surfnorm.points (whose rounding differs in the last bit): RANSAC turns a last-bit change
    # into other planes on some frames, and these are the expressions the stored reference planes were made with
    points = np.stack([(u - cx) * z / fx, (v - cy) * z / fy, z], axis=-1)
    valid = depth > 0
    threshold = max(0.004, 0.012 * float(np.median(depth[valid])))
    remaining = np.flatnonzero(valid.ravel())
    flat = points.reshape(-1, 3)
    normals, masks = [], []
    for _ in range(MAX_PLANES):
        if remaining.size < 3 * MIN_PIXELS // 2:
            break
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(flat[remaining]))
        _, inliers = cloud.segment_plane(distance_threshold=threshold, ransac_n=3, num_iterations=1000)
        inliers = np.asarray(inliers, dtype=np.int64)
        if inliers.size < MIN_PIXELS:
            break
        hit = np.zeros(H * W, np.uint8)
        hit[remaining[inliers]] = 1
        remaining = np.delete(remaining, inliers)
        hit = cv2.erode(hit.reshape(H, W), np.ones((5, 5), np.uint8))
        n, labels, stats, _ = cv2.connectedComponentsWithStats(hit, connectivity=4)
        if n <= 1:
            continue
        piece = labels == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        if piece.sum() < MIN_PIXELS:
            continue
        q = points[piece]
        normal = np.linalg.svd(q - q.mean(axis=0), full_matrices=False)[2][2]
        normals.append(-normal if normal @ q.mean(axis=0) > 0 else normal)
        masks.append(piece)
    if not normals:
        return np.zeros((0, 3)), np.zeros((0, H, W), bool), threshold
    return np.array(normals), np.array(masks), threshold


def write(out: Path, depth, K: dict, planes_from, raw: dict, meta: dict) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for name, src in raw.items():
        shutil.copyfile(src, out / name)
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float32)
    np.save(out / "depth.npy", depth)
    (out / "K.json").write_text(json.dumps(K))
    normals, masks, threshold = reference_planes(planes_from, **K)
    masks &= (depth > 0)[None]
    np.savez_compressed(out / "planes.npz", normals=normals, masks=masks)
    meta["planes.npz"] = (
        f"RANSAC (Open3D segment_plane, seed 0, threshold {threshold * 1000:.1f} mm), at most {MAX_PLANES} planes, "
        f"largest 4-connected piece after a 5x5 erosion, at least {MIN_PIXELS} px, SVD normal facing the camera"
    )
    (out / "meta.json").write_text(json.dumps(meta, indent=1))
    print(f"{out}: {depth.shape[1]}x{depth.shape[0]}, {masks.shape[0]} planes {masks.sum(axis=(1, 2)).tolist()}")


def main(argv=None) -> int:
    from surfnorm.io.depth import PGM_BYTE_ORDERS

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="kind", required=True)
    d = sub.add_parser("depth", help="a depth file and its intrinsics")
    d.add_argument("out", type=Path)
    d.add_argument("depth", type=Path)
    d.add_argument("--depth-scale", type=float, default=None, help="stored units per metre (1000 mm, 5000 TUM)")
    d.add_argument("--kinect-disparity", action="store_true", help="NYU raw PGM: Kinect disparity")
    d.add_argument(
        "--byte-order", choices=PGM_BYTE_ORDERS, default=None, help="16-bit PGM samples' order (NYU raw: little)"
    )
    d.add_argument("--sun-rgbd", action="store_true", help="SUN RGB-D's PNG: millimetres with rotated bits")
    s = sub.add_parser("stereo", help="a rectified pair and its ground-truth disparity")
    s.add_argument("out", type=Path)
    s.add_argument("left", type=Path)
    s.add_argument("right", type=Path)
    s.add_argument("gt", type=Path)
    s.add_argument("--gt-scale", type=float, default=1.0, help="stored ground-truth units per pixel of disparity")
    s.add_argument("--baseline", type=float, required=True, help="metres")
    s.add_argument(
        "--doffs", type=float, default=0.0, help="x offset of the principal points, pixels: depth f B / (d + doffs)"
    )
    s.add_argument("--matcher", choices=sorted(BLOCKS), default="sgbm", help="OpenCV's SGBM (default) or block matcher")
    s.add_argument("--block", type=int, default=None, help="the matcher's block side (default: SGBM 5, BM 9)")
    for p in (d, s):
        p.add_argument("--fx", type=float, required=True)
        p.add_argument("--fy", type=float, default=None, help="default: fx")
        p.add_argument("--cx", type=float, default=None, help="default: the image centre")
        p.add_argument("--cy", type=float, default=None, help="default: the image centre")
        p.add_argument("--source", required=True, help="where the file(s) come from, and their licence")
    args = ap.parse_args(argv)

    def intrinsics(H, W):
        return dict(
            fx=args.fx,
            fy=args.fy if args.fy is not None else args.fx,
            cx=args.cx if args.cx is not None else (W - 1) / 2,
            cy=args.cy if args.cy is not None else (H - 1) / 2,
        )

    if args.kind == "depth":
        from surfnorm.io.depth import read_depth

        depth = read_depth(
            args.depth,
            depth_scale=args.depth_scale,
            kinect_disparity=args.kinect_disparity,
            byte_order=args.byte_order,
            sun_rgbd=args.sun_rgbd,
        )
        K = intrinsics(*depth.shape)
        raw = {"raw" + args.depth.suffix: args.depth}
        write(args.out, depth, K, depth, raw, {"source": args.source, "depth": "as read by surfnorm.io.read_depth"})
        return 0
    least = 5 if args.matcher == "bm" else 1
    if args.block is not None and (args.block < least or args.block % 2 == 0):
        print(
            f"error: --block: expected an odd side of at least {least} for {args.matcher}, got {args.block}",
            file=sys.stderr,
        )
        return 2
    left, right = (cv2.imread(str(p), cv2.IMREAD_COLOR) for p in (args.left, args.right))
    if args.gt.suffix.lower() == ".pfm":
        from surfnorm.errors import DataFileError
        from surfnorm.io.depth import read_depth

        try:
            gt = read_depth(args.gt)
        except DataFileError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    else:
        gt = cv2.imread(str(args.gt), cv2.IMREAD_UNCHANGED)
    if left is None or right is None or gt is None:
        print("error: could not read the pair or the ground truth", file=sys.stderr)
        return 2
    gt = (gt[..., 0] if gt.ndim == 3 else gt).astype(np.float64)
    gt = np.where(np.isfinite(gt) & (gt > 0), gt, 0.0) / args.gt_scale
    K = intrinsics(*gt.shape)
    block = BLOCKS[args.matcher] if args.block is None else args.block
    largest = float(gt.max())
    disparity = stereo_disparity(left, right, largest, args.matcher, block)
    depth = stereo_depth(disparity, K["fx"], args.baseline, args.doffs)
    gt_depth = stereo_depth(gt, K["fx"], args.baseline, args.doffs)
    raw = {f"raw_{k}{p.suffix}": p for k, p in (("left", args.left), ("right", args.right), ("gt", args.gt))}
    name = {"sgbm": "SGBM", "bm": "StereoBM"}[args.matcher]
    formula = f"f B / (d + {args.doffs:g})" if args.doffs else "f B / d"
    depth_text = f"OpenCV {name}, {block}x{block} blocks (benchmarks/sensor_folder.py), {formula}"
    # what made the depth, for a later matcher on the same pair (sensor_variants.py's WLS variant)
    stereo = {
        "matcher": args.matcher,
        "block": block,
        "largest": largest,
        "baseline": args.baseline,
        "doffs": args.doffs,
    }
    meta = {"source": args.source, "depth": depth_text, "K": K, "stereo": stereo}
    write(args.out, depth, K, gt_depth, raw, meta)
    np.save(args.out / "gt_depth.npy", gt_depth)
    return 0


if __name__ == "__main__":
    sys.exit(main())
