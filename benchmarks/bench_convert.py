"""Files per second of ``surfnorm convert``: one process, the local ``--jobs 2`` pool, a 2-worker Dask LocalCluster.

    PYTHONPATH=src python benchmarks/bench_convert.py            # 500 frames 480x640, 3 rounds
    PYTHONPATH=src python benchmarks/bench_convert.py --files 100 --rounds 1 --shard-sizes 1,8,64

Setup (not timed): seeded 16-bit PNG depth frames (millimetres, holes, noise)
are written once; the kernels are compiled in this process; the LocalCluster
(2 worker processes, 1 thread each) is started and every worker converts one
frame so that it has loaded the compiled kernels. The cluster's start-up time
is reported on its own line: a cluster lives longer than one run. The local
pool is started inside each timed call, as ``convert --jobs 2`` does.

Timed: one ``surfnorm.convert`` call over all frames into an empty folder; the
configurations are interleaved round by round (the machine may be shared and
its load changes), and the table gives the median files per second and the
ratio to the single process of the same round. The Dask rows include every
shard size asked for (``--shard-sizes``; ``default`` is what
``surfnorm.distributed.default_shard_size`` picks for this run).

Writes a Markdown table to stdout and JSON (figures, versions, commit, load)
to ``bench-output/bench_convert.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

H, W = 480, 640


def depth_mm(seed: int) -> np.ndarray:
    """A tilted floor and a wall with a spherical object, axial noise growing with depth, dropouts; uint16 mm."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    z = 2.0 + 0.002 * (u - W / 2) * rng.uniform(0.5, 1.5) + 0.0015 * (v - H / 2)
    cu, cv, r = rng.uniform(200, 440), rng.uniform(150, 330), rng.uniform(60, 120)
    d2 = ((u - cu) ** 2 + (v - cv) ** 2) / r**2
    z = z - 0.4 * np.sqrt(np.clip(1 - d2, 0, None))
    z = z + rng.normal(0, 1, z.shape) * 0.0012 * z**2
    mm = np.rint(z * 1000).astype(np.uint16)
    mm[rng.random(z.shape) < 0.01] = 0
    return mm


def make_inputs(folder: Path, n: int) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / f"{i:05d}.png" for i in range(n)]
    for i, p in enumerate(paths):
        if not p.exists():
            assert cv2.imwrite(str(p), depth_mm(i))
    return paths


def git_commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              cwd=Path(__file__).parent, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--files", type=int, default=500)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--method", default="d2nt_v3")
    ap.add_argument("--format", dest="fmt", default="npy", choices=("npy", "png16", "png8"))
    ap.add_argument("--shard-sizes", default="default", help="comma-separated; 'default' or numbers")
    ap.add_argument("--workdir", type=Path, default=Path("bench-output/convert"))
    ap.add_argument("--json", type=Path, default=Path("bench-output/bench_convert.json"))
    args = ap.parse_args(argv)

    import distributed

    import surfnorm
    from surfnorm.camera import Intrinsics
    from surfnorm.convert import convert
    from surfnorm.distributed import default_shard_size

    cam = Intrinsics(fx=525.0, fy=525.0, cx=319.5, cy=239.5)
    common = dict(method=args.method, fmt=args.fmt, depth_scale=1000.0, intrinsics=cam)
    inputs = make_inputs(args.workdir / "depth", args.files)
    out = args.workdir / "normals"
    load_before = os.getloadavg()

    # setup: compile here, start the cluster, warm its workers
    warm = args.workdir / "warm"
    shutil.rmtree(warm, ignore_errors=True)
    convert(inputs[:1], warm, **common)
    t0 = time.perf_counter()
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0")
    client = distributed.Client(cluster)
    cluster_start = time.perf_counter() - t0
    shutil.rmtree(warm, ignore_errors=True)
    convert(inputs[:2], warm, client=client, shard_size=1, **common)
    shutil.rmtree(warm, ignore_errors=True)

    sizes = []
    for s in args.shard_sizes.split(","):
        sizes.append(default_shard_size(len(inputs), 2) if s == "default" else int(s))
    configs = [("1 process", dict(jobs=1)), ("local pool, --jobs 2", dict(jobs=2))]
    configs += [(f"LocalCluster 2 workers, shard {s}", dict(client=client, shard_size=s)) for s in dict.fromkeys(sizes)]

    rates = {name: [] for name, _ in configs}
    ratios = {name: [] for name, _ in configs}
    for r in range(args.rounds):
        base = None
        for name, kw in configs:
            shutil.rmtree(out, ignore_errors=True)
            t0 = time.perf_counter()
            summary = convert(inputs, out, **common, **kw)
            dt = time.perf_counter() - t0
            assert summary.written == len(inputs), (name, summary.errors[:3])
            rate = len(inputs) / dt
            base = rate if base is None else base
            rates[name].append(rate)
            ratios[name].append(rate / base)
            print(f"round {r + 1}: {name}: {rate:.1f} files/s", file=sys.stderr)
    shutil.rmtree(out, ignore_errors=True)
    client.close()
    cluster.close()
    load_after = os.getloadavg()

    rows = [(name, statistics.median(rates[name]), statistics.median(ratios[name])) for name, _ in configs]
    print(f"\n{len(inputs)} depth frames {W}x{H} 16-bit PNG -> {args.fmt}, method {args.method}; "
          f"median of {args.rounds} interleaved rounds; {os.cpu_count()} CPUs; "
          f"load average {load_before[0]:.1f} before, {load_after[0]:.1f} after\n")
    print("| configuration | files/s | vs 1 process |")
    print("|---|---:|---:|")
    for name, rate, ratio in rows:
        print(f"| {name} | {rate:.1f} | {ratio:.2f}x |")
    print(f"\nLocalCluster start-up (not in the table): {cluster_start:.1f} s; "
          f"default shard size for {len(inputs)} files on 2 threads: {default_shard_size(len(inputs), 2)}")

    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({
        "files": len(inputs), "shape": [H, W], "format": args.fmt, "method": args.method, "rounds": args.rounds,
        "rows": [{"configuration": n, "files_per_s_median": r, "ratio_median": q, "files_per_s": rates[n]}
                 for n, r, q in rows],
        "cluster_start_s": cluster_start, "default_shard_size": default_shard_size(len(inputs), 2),
        "load_average": {"before": load_before, "after": load_after},
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
        "versions": {"surfnorm": surfnorm.__version__, "numpy": np.__version__, "dask": distributed.__version__},
        "commit": git_commit(),
    }, indent=2))


if __name__ == "__main__":
    main()
