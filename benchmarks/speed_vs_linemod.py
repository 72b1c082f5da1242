"""The default call's time against OpenCV's LINEMOD (window 5) on frames beyond the sensor benchmark's eight.

    PYTHONPATH=src python benchmarks/speed_vs_linemod.py [SENSOR_DIR] [--rounds 9] [--json out.json]

1. The 3F2N frames of tests/data/3f2n-sample (12) as each simulated sensor delivers them
   (surfnorm.bench.simulate, seed 0; 480x640).
2. The frames of SENSOR_DIR (default ../shared/data/sensor-sample beside the repository, skipped where absent;
   the layout of `surfnorm bench --sensor`) cropped about their centre to the sizes of other cameras: 512x424
   (Kinect v2), 848x480 (RealSense), 320x240; the principal point moves with the crop.

Per frame: `surfnorm.estimate(depth, K)` as a user calls it (every core) and LINEMOD on one thread (as the sensor
benchmark runs it), called alternately, each the median of --rounds calls after two warm-up calls; the ratio of
the two medians. Per sensor or size: the median ratio and the range. Needs OpenCV with `RgbdNormals`
(`pip install opencv-contrib-python-headless`). Timings are never asserted in tests.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
SIZES = ((424, 512), (480, 848), (240, 320))


def _ratio(entries, z, K, rounds: int) -> tuple[float, float, float]:
    from surfnorm.bench.sensor import alternating_medians

    valid = z > 0
    ms = alternating_medians({e.label: (lambda e=e: e.call(z, K, valid)) for e in entries}, rounds)
    ours, theirs = (ms[e.label] for e in entries)
    return ours / theirs, ours, theirs


def main(argv=None) -> int:
    from surfnorm.bench.peers import single_thread

    single_thread()  # LINEMOD on one thread, as in the sensor benchmark; surfnorm's entry names its threads
    import numpy as np

    from surfnorm.bench.scripts import threef2n_root
    from surfnorm.bench.sensor import find_sensor_frames, linemod_entry, make_entries, read_sensor_frame
    from surfnorm.bench.simulate import SENSORS, frame_seed, simulate
    from surfnorm.camera import Intrinsics
    from surfnorm.io.threef2n import find_frames, read_frame

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sensor_dir", nargs="?", default=str(REPO.parent / "shared" / "data" / "sensor-sample"))
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--json", default=None, help="write every per-frame record here")
    args = ap.parse_args(argv)
    linemod = linemod_entry("speed_vs_linemod")
    if linemod is None:
        return 2
    entries = make_entries(["auto:threads=all"])[0] + [linemod]
    records = []
    root = threef2n_root(None, REPO)
    names = find_frames(root)
    rows = [
        "| frames | n | median ratio | range | median ms, `auto` | median ms, LINEMOD |",
        "|---|---|---|---|---|---|",
    ]

    def row(label, got):
        r = np.array([g[:3] for g in got])
        rows.append(
            f"| {label} | {len(got)} | {np.median(r[:, 0]):.2f} | {r[:, 0].min():.2f}-{r[:, 0].max():.2f} "
            f"| {np.median(r[:, 1]):.1f} | {np.median(r[:, 2]):.1f} |"
        )

    for s in SENSORS:
        got = []
        for name in names:
            f = read_frame(root, name)
            z = simulate(f.depth, f.K, s, seed=frame_seed(0, name, s), mask=f.mask, normals=f.normals)
            got.append(_ratio(entries, z, f.K, args.rounds))
            records.append({"set": f"simulated {s}", "frame": name, "ratio": got[-1][0], "ms": got[-1][1:]})
        row(f"3F2N as {s} (480x640)", got)
    folders = find_sensor_frames(args.sensor_dir) if Path(args.sensor_dir).is_dir() else []
    for h, w in SIZES:
        got = []
        for folder in folders:
            f = read_sensor_frame(folder)
            if f.depth.shape[0] < h or f.depth.shape[1] < w:
                continue
            v0, u0 = (f.depth.shape[0] - h) // 2, (f.depth.shape[1] - w) // 2
            z = np.ascontiguousarray(f.depth[v0 : v0 + h, u0 : u0 + w])
            K = Intrinsics(f.K.fx, f.K.fy, f.K.cx - u0, f.K.cy - v0)
            got.append(_ratio(entries, z, K, args.rounds))
            records.append({"set": f"crop {w}x{h}", "frame": folder.name, "ratio": got[-1][0], "ms": got[-1][1:]})
        if got:
            row(f"sensor frames cropped to {w}x{h}", got)
    print("\n".join(rows))
    if args.json:
        Path(args.json).write_text(json.dumps(records, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
