"""Files per second of ``surfnorm convert``: one process, the local ``--jobs 2`` pool, a 2-worker Dask LocalCluster.

    PYTHONPATH=src python benchmarks/bench_convert.py            # 500 frames 480x640, d2nt_v3, 3 rounds
    PYTHONPATH=src python benchmarks/bench_convert.py --files 100 --rounds 1 --shard-sizes 1,default,64

Every timed run is a fresh Python process, so the configurations start alike
(and the local pool forks from a process without Dask's threads, as the CLI
does). Setup in that process (not timed): the kernels are compiled or loaded
from Numba's cache by converting one frame; for the Dask rows the LocalCluster
(2 worker processes, 1 thread each) is started and every worker runs the
estimator once. The cluster's start-up is reported on its own line: a
cluster lives longer than one run.

Timed: one ``surfnorm.convert`` call over all frames (seeded 16-bit PNG depth,
millimetres, with noise and holes; written once) into an empty folder. The
configurations are interleaved round by round (the machine may be shared and
its load changes); the table gives the median files per second and the median
ratio to the single process of the same round. The Dask rows cover every
shard size asked for (``--shard-sizes``; ``default`` is what
``surfnorm.batch.cluster.default_shard_size`` picks for the run).

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
        return subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            cwd=Path(__file__).parent,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


CAMERA = dict(fx=525.0, fy=525.0, cx=319.5, cy=239.5)


def one_run(config: str, inputs: list[Path], out: Path, common: dict) -> dict:
    """Set up, then time one convert call; runs in its own process."""
    from surfnorm.batch import convert

    warm = out.with_name(out.name + "-warm")
    shutil.rmtree(warm, ignore_errors=True)
    convert(inputs[:1], warm, **common)  # compile or load the kernels here
    shutil.rmtree(warm, ignore_errors=True)
    shutil.rmtree(out, ignore_errors=True)
    client = cluster = None
    kw: dict = {}
    extra: dict = {}
    if config == "single":
        kw = dict(jobs=1)
    elif config == "pool":
        kw = dict(jobs=2)
    else:
        import distributed

        import surfnorm
        from surfnorm.camera import Intrinsics

        t0 = time.perf_counter()
        cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0")
        client = distributed.Client(cluster)
        client.wait_for_workers(2)
        extra["cluster_start_s"] = time.perf_counter() - t0
        # every worker reads, estimates and writes once (imports, kernels from Numba's cache)
        from surfnorm.io.depth import read_depth
        from surfnorm.io.normals import write_normals

        z = read_depth(inputs[0], depth_scale=1000.0)
        client.run(read_depth, inputs[0], depth_scale=1000.0)
        client.run(surfnorm.estimate, z, Intrinsics(**CAMERA), method=common["method"])
        warm.mkdir(parents=True, exist_ok=True)
        client.run(write_normals, warm / "n.npy", np.zeros((H, W, 3), np.float32), fmt="npy")
        shutil.rmtree(warm, ignore_errors=True)
        size = config.split(":")[1]
        kw = dict(client=client, shard_size=None if size == "default" else int(size))
    t0 = time.perf_counter()
    summary = convert(inputs, out, **common, **kw)
    dt = time.perf_counter() - t0
    if client is not None:
        client.close()
        cluster.close()
    shutil.rmtree(out, ignore_errors=True)
    assert summary.written == len(inputs), (config, summary.errors[:3])
    return {"config": config, "seconds": dt, "files_per_s": len(inputs) / dt, **extra}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--files", type=int, default=500)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--method", default="d2nt_v3")
    ap.add_argument("--format", dest="fmt", default="npy", choices=("npy", "png16", "png8"))
    ap.add_argument("--shard-sizes", default="default", help="comma-separated; 'default' or numbers")
    ap.add_argument("--workdir", type=Path, default=Path("bench-output/convert"))
    ap.add_argument("--json", type=Path, default=Path("bench-output/bench_convert.json"))
    ap.add_argument("--run", help=argparse.SUPPRESS)  # internal: one timed run in this process
    args = ap.parse_args(argv)

    from surfnorm.batch.cluster import default_shard_size
    from surfnorm.camera import Intrinsics

    common = dict(method=args.method, fmt=args.fmt, depth_scale=1000.0, intrinsics=Intrinsics(**CAMERA))
    inputs = make_inputs(args.workdir / "depth", args.files)
    out = args.workdir / "normals"
    if args.run:
        print(json.dumps(one_run(args.run, inputs, out, common)))
        return

    load_before = os.getloadavg()
    default = default_shard_size(len(inputs), 2)
    sizes = list(dict.fromkeys(default if s == "default" else int(s) for s in args.shard_sizes.split(",")))
    configs = [("1 process", "single"), ("local pool, --jobs 2", "pool")]
    configs += [
        (f"LocalCluster 2 workers, shard {s}" + (" (default)" if s == default else ""), f"cluster:{s}") for s in sizes
    ]
    rates = {name: [] for name, _ in configs}
    ratios = {name: [] for name, _ in configs}
    starts = []
    loads = []
    for r in range(args.rounds):
        base = None
        for name, config in configs:
            cmd = [
                sys.executable,
                __file__,
                "--files",
                str(args.files),
                "--method",
                args.method,
                "--format",
                args.fmt,
                "--workdir",
                str(args.workdir),
                "--run",
                config,
            ]
            done = subprocess.run(cmd, capture_output=True, text=True)
            if done.returncode != 0:
                sys.exit(f"{name} failed:\n{done.stderr[-3000:]}")
            run = json.loads(done.stdout.strip().splitlines()[-1])
            base = run["files_per_s"] if base is None else base
            rates[name].append(run["files_per_s"])
            ratios[name].append(run["files_per_s"] / base)
            if "cluster_start_s" in run:
                starts.append(run["cluster_start_s"])
            loads.append(os.getloadavg()[0])
            print(f"round {r + 1}: {name}: {run['files_per_s']:.2f} files/s (load {loads[-1]:.1f})", file=sys.stderr)

    rows = [(name, statistics.median(rates[name]), statistics.median(ratios[name])) for name, _ in configs]
    print(
        f"\n{len(inputs)} depth frames {W}x{H} 16-bit PNG -> {args.fmt}, method {args.method}; "
        f"median of {args.rounds} interleaved rounds; {os.cpu_count()} CPUs; load average (1 min) "
        f"{load_before[0]:.1f} before, {min(loads):.1f} to {max(loads):.1f} during the runs\n"
    )
    print("| configuration | files/s | vs 1 process |")
    print("|---|---:|---:|")
    for name, rate, ratio in rows:
        print(f"| {name} | {rate:.2f} | {ratio:.2f}x |")
    print(
        f"\nLocalCluster start-up (not in the table): median {statistics.median(starts):.1f} s; "
        f"default shard size for {len(inputs)} files on 2 worker threads: {default}"
    )

    import dask

    import surfnorm

    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(
        json.dumps(
            {
                "files": len(inputs),
                "shape": [H, W],
                "format": args.fmt,
                "method": args.method,
                "rounds": args.rounds,
                "rows": [
                    {
                        "configuration": n,
                        "files_per_s_median": r,
                        "ratio_median": q,
                        "files_per_s": rates[n],
                        "ratios": ratios[n],
                    }
                    for n, r, q in rows
                ],
                "cluster_start_s": starts,
                "default_shard_size": default,
                "load_average": {"before": load_before, "during": loads},
                "machine": {
                    "cpus": os.cpu_count(),
                    "platform": platform.platform(),
                    "python": platform.python_version(),
                },
                "versions": {"surfnorm": surfnorm.__version__, "numpy": np.__version__, "dask": dask.__version__},
                "commit": git_commit(),
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
