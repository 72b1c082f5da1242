"""e_A of every method and peer on 3F2N frames as real sensors would deliver them (surfnorm.bench.simulate).

    PYTHONPATH=src python benchmarks/sensor_sim.py                       # everything: all methods, peers, sensors
    PYTHONPATH=src python benchmarks/sensor_sim.py --quick               # 1 frame per level, for tuning loops
    PYTHONPATH=src python benchmarks/sensor_sim.py --methods d2nt_v3,plane_pca:window=11,opencv_fals_w7 \\
        --sensors kinect_v1,d435 [--levels Hard] [--frames 2] [--json out.json] [--seed 0]
    PYTHONPATH=src python benchmarks/sensor_sim.py --list                # method, peer and sensor names

ROOT (positional, optional): a folder in the 3F2N layout; default tests/data/3f2n-sample in
the repository when present (12 frames), else the 3 frames shipped in the package.

--methods takes registered names (any with +mnr), options as name:option=value[:option=value], and
peer keys (opencv_fals_w5, ..., open3d_knn30, open3d_normal_map, kornia); default: every registered
method, the variants of surfnorm.bench.sensor.VARIANTS and every peer that imports.

Every library runs on one thread. e_A: mean over frames of the per-frame e_A (folded angle to the
exact normal over the object's pixels where the sensor delivered depth and the method a normal);
coverage beside it. ms: median over frames of one warm call each (noisy: compare within one run).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def main(argv=None) -> int:
    from surfnorm.bench.peers import SENSOR_PEERS, single_thread

    threads = single_thread()  # before any peer library is imported
    from surfnorm.bench.scripts import threef2n_root
    from surfnorm.bench.sensor import make_entries, run_simulated, sim_tables
    from surfnorm.bench.simulate import SENSORS
    from surfnorm.errors import SurfnormError
    from surfnorm.methods import methods

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("root", nargs="?", default=None)
    ap.add_argument("--methods", default=None, help="comma-separated; default: all registered + variants + peers")
    ap.add_argument("--sensors", default=None, help=f"comma-separated among {', '.join(SENSORS)}; default: all")
    ap.add_argument("--levels", default=None, help="comma-separated among Easy, Medium, Hard")
    ap.add_argument("--frames", type=int, default=None, help="at most this many frames per level")
    ap.add_argument("--quick", action="store_true", help="1 frame per level (same as --frames 1)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=None, help="write every per-frame record here")
    ap.add_argument("--list", action="store_true", help="list method, peer and sensor names, and exit")
    args = ap.parse_args(argv)
    if args.list:
        print("methods:", ", ".join(methods()))
        print("peers:", ", ".join(p.name for p in SENSOR_PEERS))
        for s in SENSORS.values():
            print(f"sensor {s.name}: {s.summary}")
        return 0
    root = threef2n_root(args.root, REPO)
    split = lambda s: [x.strip() for x in s.split(",") if x.strip()] if s else None
    try:
        entries, absent = make_entries(split(args.methods))
        t0 = time.perf_counter()
        result = run_simulated(
            root,
            entries,
            split(args.sensors) or list(SENSORS),
            levels=split(args.levels),
            frames_per_level=1 if args.quick else args.frames,
            seed=args.seed,
            progress=lambda msg: print(f"  {msg}", file=sys.stderr, flush=True),
        )
    except (SurfnormError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(
        f"## Simulated sensors on {len(result['frames'])} 3F2N frames ({root.name}), seed {args.seed}, "
        f"one thread, {time.perf_counter() - t0:.0f} s\n"
    )
    print(sim_tables(result))
    for name, why in absent.items():
        print(f"- absent: {name}: {why}")
    if args.json:
        result["threads"] = threads
        Path(args.json).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
