"""Speed of the PyTorch backend against kornia's depth_to_normals, measured in the same run.

    python benchmarks/bench_torch.py [--runs 30] [--methods d2nt_basic ...] [--json out.json]

CPU: one 480x640 frame (Medium/Trex from the sample shipped in the package),
with one thread (``torch.set_num_threads(1)``) and with PyTorch's default
threads. Each round times every contender once, in turn (interleaved), so
that load from other processes falls on all of them alike; the table gives
medians over ``--runs`` rounds and each method's speed-up over kornia in the
same rounds. kornia's normals face away from the camera (ours face it); the
benchmark times both as they come and checks that they agree up to that sign
on a plane.

GPU (only where CUDA is present): frames per second on a batch of 16 frames
of 480x640 for each method and for kornia, timed with CUDA events after a
warm-up.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

import torch

import surfnorm.torch as st
from surfnorm.io._atomic import atomic_write
from surfnorm.io.threef2n import read_frame, sample_root

FRAME = "Medium/Trex/000001"


def kornia_normals():
    try:
        from kornia.geometry.depth import depth_to_normals
    except ImportError as exc:  # pragma: no cover - kornia is in the "peers" extra
        raise SystemExit("bench_torch.py compares against kornia: pip install kornia (or surfnorm[peers])") from exc
    return depth_to_normals


def check_agreement(depth_to_normals):
    """On a tilted plane, kornia's normals are ours with the opposite sign (away from the camera)."""
    H, W = 48, 64
    K = torch.tensor([[60.0, 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]])
    v, u = torch.meshgrid(torch.arange(H, dtype=torch.float32), torch.arange(W, dtype=torch.float32), indexing="ij")
    n = torch.tensor([0.2, -0.3, -1.0])
    n = n / n.norm()
    rays = torch.stack(((u - 31.5) / 60.0, (v - 23.5) / 60.0, torch.ones_like(u)))
    depth = (-2.0 / torch.einsum("c,chw->hw", n, rays))[None, None]
    ours = st.estimate(depth, K, method="d2nt_basic")[0, :, 2:-2, 2:-2]
    theirs = depth_to_normals(depth, K[None])[0, :, 2:-2, 2:-2]
    err = (ours + theirs).abs().max().item()
    if err > 1e-4:
        raise SystemExit(f"kornia's normals are not ours with the opposite sign on a plane (max diff {err:.2e})")
    return err


def cpu_rounds(contenders, runs, warmup=3):
    for fn in contenders.values():
        for _ in range(warmup):
            fn()
    times = {name: [] for name in contenders}
    for _ in range(runs):
        for name, fn in contenders.items():
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
    return times


def cpu_table(depth, K, methods, runs, depth_to_normals):
    z = torch.from_numpy(depth)[None, None]
    Kt = torch.from_numpy(K).float()
    contenders = {"kornia depth_to_normals": lambda: depth_to_normals(z, Kt[None])}
    for m in methods:
        contenders[f"surfnorm.torch {m}"] = (lambda m=m: st.estimate(z, Kt, method=m))
    rows = []
    default_threads = torch.get_num_threads()
    for threads in (1, default_threads):
        torch.set_num_threads(threads)
        times = cpu_rounds(contenders, runs)
        base = times["kornia depth_to_normals"]
        for name, t in times.items():
            # speed-up in the same rounds: median over rounds of kornia's time / this contender's time
            ratio = statistics.median(b / x for b, x in zip(base, t))
            rows.append({"threads": threads, "contender": name, "median_ms": 1e3 * statistics.median(t),
                         "min_ms": 1e3 * min(t), "speedup_vs_kornia": ratio, "runs": len(t)})
    torch.set_num_threads(default_threads)
    return rows


def gpu_table(depth, K, methods, runs, depth_to_normals, batch=16):
    z = torch.from_numpy(depth)[None, None].repeat(batch, 1, 1, 1).cuda()
    Kt = torch.from_numpy(K).float().cuda()
    Kb = Kt[None].repeat(batch, 1, 1)
    contenders = {"kornia depth_to_normals": lambda: depth_to_normals(z, Kb)}
    for m in methods:
        contenders[f"surfnorm.torch {m}"] = (lambda m=m: st.estimate(z, Kt, method=m))
    rows = []
    for name, fn in contenders.items():
        for _ in range(3):
            fn()
        torch.cuda.synchronize()
        ms = []
        for _ in range(runs):
            start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
            start.record()
            fn()
            end.record()
            torch.cuda.synchronize()
            ms.append(start.elapsed_time(end))
        med = statistics.median(ms)
        rows.append({"contender": name, "batch": batch, "median_ms": med, "fps": 1e3 * batch / med, "runs": runs})
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=30, help="interleaved rounds (default 30)")
    parser.add_argument("--methods", nargs="+", default=["d2nt_basic"], help="torch-backend methods to time")
    parser.add_argument("--json", help="also write the figures to this JSON file")
    args = parser.parse_args()
    depth_to_normals = kornia_normals()
    frame = read_frame(sample_root(), FRAME)
    depth, K = frame.depth, frame.K.matrix
    agreement = check_agreement(depth_to_normals)
    rows = cpu_table(depth, K, args.methods, args.runs, depth_to_normals)
    print(f"CPU, one {depth.shape[0]}x{depth.shape[1]} frame ({FRAME}), {args.runs} interleaved rounds, "
          f"torch {torch.__version__}, {os.cpu_count()} cores")
    print()
    print("| threads | contender | median ms | min ms | speed-up vs kornia (same rounds) |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['threads']} | {r['contender']} | {r['median_ms']:.1f} | {r['min_ms']:.1f} | {r['speedup_vs_kornia']:.2f}x |")
    gpu_rows = []
    if torch.cuda.is_available():
        gpu_rows = gpu_table(depth, K, args.methods, args.runs, depth_to_normals)
        print()
        print(f"GPU {torch.cuda.get_device_name()}, batch of 16 frames of 480x640")
        print()
        print("| contender | median ms per batch | frames per second |")
        print("|---|---|---|")
        for r in gpu_rows:
            print(f"| {r['contender']} | {r['median_ms']:.2f} | {r['fps']:.0f} |")
    if args.json:
        import kornia

        report = {"cpu": rows, "gpu": gpu_rows, "torch": torch.__version__, "kornia": kornia.__version__,
                  "machine": platform.platform(), "cores": os.cpu_count(), "frame": FRAME,
                  "kornia_sign_check_max_diff": agreement}
        atomic_write(args.json, lambda tmp: tmp.write_text(json.dumps(report, indent=1)))


if __name__ == "__main__":
    main()
