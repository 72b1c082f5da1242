"""Throughput of the PyTorch backend, every method, next to kornia and Open3D, measured in the same run.

    python benchmarks/bench_torch.py [--batches 1 16 64] [--runs 5] [--methods NAME ...]
                                     [--devices cpu cuda] [--budget 60] [--json out.json]

Frames per second on batches of 480x640 frames (the shipped sample's three
frames, repeated to fill the batch) for every method of
``surfnorm.torch.methods()`` (``auto`` runs ``d2nt_v3`` on these rendered frames, after measuring
their noise) and two peers on the same device:

* kornia's ``depth_to_normals`` (the cross product of finite-difference
  tangents; its normals face away from the camera, ours face it: checked on
  a plane before timing);
* Open3D's tensor normal map, ``t.geometry.Image.create_vertex_map(K)
  .create_normal_map()``, frame by frame (it takes one image at a time), on
  the same device (``CUDA:0`` where Open3D was built with CUDA, else it is
  listed as unavailable there).

CPU: PyTorch's default threads (``--threads`` to set them). Each round times every contender once, in
turn (interleaved), so that load from other processes falls on all of them
alike; the table gives the median over rounds, frames per second from it,
and each contender's speed-up over kornia as the median over rounds of the
two times' ratio. A contender whose first call took longer than ``--budget``
seconds is timed once more and left out of later rounds (SDA-SNE and the
plane fits at batch 64 on a small machine).

CUDA (where present): the same, timed with CUDA events after a warm-up, and
each method's peak GPU memory per frame (``torch.cuda.max_memory_allocated``
over a call, divided by the batch).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

import numpy as np
import torch

import surfnorm.torch as st
from surfnorm.io._atomic import atomic_write
from surfnorm.io.threef2n import find_frames, read_frame, sample_root

KORNIA = "kornia depth_to_normals"
OPEN3D = "Open3D tensor normal map"


def kornia_normals():
    try:
        from kornia.geometry.depth import depth_to_normals
    except ImportError as exc:  # pragma: no cover - kornia is in the "peers" extra
        raise SystemExit("bench_torch.py compares against kornia: pip install kornia (or surfnorm[peers])") from exc
    return depth_to_normals


def open3d_or_reason():
    """The open3d module, or the reason it cannot be used (a string)."""
    try:
        import open3d as o3d
    except Exception as exc:  # ImportError, or a missing system library (libusb)
        return f"{type(exc).__name__}: {exc}"
    return o3d


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


def frames(batch: int):
    """A (batch, 1, 480, 640) float32 depth tensor (the shipped frames, repeated) and their (batch, 3, 3) K."""
    root = sample_root()
    shipped = [read_frame(root, name) for name in find_frames(root)]
    picked = [shipped[i % len(shipped)] for i in range(batch)]
    depth = torch.from_numpy(np.stack([f.depth for f in picked]))[:, None]
    K = torch.from_numpy(np.stack([f.K.matrix for f in picked]))
    return depth, K


def contenders(depth, K, methods, depth_to_normals, o3d, device):
    """name -> zero-argument callable, all on ``device``; and the peers that could not run there, with why."""
    z, Kd = depth.to(device), K.to(device=device, dtype=torch.float32)
    out = {KORNIA: lambda: depth_to_normals(z, Kd)}
    skipped = {}
    if isinstance(o3d, str):
        skipped[OPEN3D] = o3d
    else:
        o3d_device = o3d.core.Device("CPU:0" if device.type == "cpu" else f"CUDA:{device.index or 0}")
        if device.type == "cuda" and not o3d.core.cuda.is_available():
            skipped[OPEN3D] = "this Open3D build has no CUDA"
        else:
            images = [
                o3d.t.geometry.Image(o3d.core.Tensor(depth[i, 0, :, :, None].numpy())).to(o3d_device)
                for i in range(depth.shape[0])
            ]
            Ks = [o3d.core.Tensor(K[i].numpy().astype(np.float64)) for i in range(depth.shape[0])]

            def run_o3d():
                return [img.create_vertex_map(k).create_normal_map() for img, k in zip(images, Ks)]

            out[OPEN3D] = run_o3d
    for m in methods:
        out[f"surfnorm.torch {m}"] = lambda m=m: st.estimate(z, Kd, method=m)
    return out, skipped


def cpu_rounds(fns, runs, budget):
    """Interleaved rounds: {name: [seconds, ...]}. The first call of each is a warm-up, also timed:
    a contender slower than ``budget`` seconds then runs once more only."""
    first = {}
    for name, fn in fns.items():
        t0 = time.perf_counter()
        fn()
        first[name] = time.perf_counter() - t0
    times = {name: [] for name in fns}
    for r in range(runs):
        for name, fn in fns.items():
            if r > 0 and first[name] > budget:
                continue
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
    return times


def cuda_times(fns, runs, batch):
    """{name: ([ms, ...], peak bytes per frame)}, each contender timed alone with CUDA events after a warm-up."""
    out = {}
    for name, fn in fns.items():
        fn()
        torch.cuda.synchronize()
        torch.cuda.reset_peak_memory_stats()
        base = torch.cuda.memory_allocated()
        fn()
        torch.cuda.synchronize()
        peak = (torch.cuda.max_memory_allocated() - base) / batch
        ms = []
        for _ in range(runs):
            start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
            start.record()
            fn()
            end.record()
            torch.cuda.synchronize()
            ms.append(start.elapsed_time(end))
        out[name] = (ms, peak)
    return out


def table(device, batch, fns, runs, budget):
    rows = []
    if device.type == "cpu":
        times = cpu_rounds(fns, runs, budget)
        base = times[KORNIA]
        for name, t in times.items():
            pairs = list(zip(base, t))
            rows.append(
                {
                    "device": str(device),
                    "batch": batch,
                    "contender": name,
                    "runs": len(t),
                    "median_ms": 1e3 * statistics.median(t),
                    "fps": batch / statistics.median(t),
                    "speedup_vs_kornia": statistics.median(b / x for b, x in pairs) if pairs else None,
                }
            )
    else:
        times = cuda_times(fns, runs, batch)
        kornia_ms = statistics.median(times[KORNIA][0])
        for name, (ms, peak) in times.items():
            med = statistics.median(ms)
            rows.append(
                {
                    "device": str(device),
                    "batch": batch,
                    "contender": name,
                    "runs": len(ms),
                    "median_ms": med,
                    "fps": 1e3 * batch / med,
                    "speedup_vs_kornia": kornia_ms / med,
                    "peak_mib_per_frame": peak / 2**20,
                }
            )
    return rows


def print_table(title, rows, skipped):
    print()
    print(title)
    print()
    gpu = "peak_mib_per_frame" in rows[0]
    print(
        "| contender | batch | median ms per batch | frames/s | vs kornia |" + (" peak MiB per frame |" if gpu else "")
    )
    print("|---|---|---|---|---|" + ("---|" if gpu else ""))
    for r in rows:
        ratio = "" if r["speedup_vs_kornia"] is None else f"{r['speedup_vs_kornia']:.2f}x"
        extra = f" {r['peak_mib_per_frame']:.1f} |" if gpu else ""
        print(f"| {r['contender']} | {r['batch']} | {r['median_ms']:.1f} | {r['fps']:.1f} | {ratio} |{extra}")
    for name, why in skipped.items():
        print(f"| {name} | - | not run: {why} | | |" + (" |" if gpu else ""))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 16, 64], help="batch sizes (default 1 16 64)")
    parser.add_argument("--runs", type=int, default=5, help="timed rounds per batch (default 5)")
    parser.add_argument("--methods", nargs="+", default=None, help="torch-backend methods (default: all)")
    parser.add_argument(
        "--devices",
        nargs="+",
        default=["cpu", "cuda"],
        choices=["cpu", "cuda"],
        help="devices to time on (cuda only where present; default both)",
    )
    parser.add_argument(
        "--budget",
        type=float,
        default=60.0,
        help="CPU: a contender whose first call takes longer (s) is timed once (default 60)",
    )
    parser.add_argument(
        "--threads",
        type=int,
        default=None,
        help="CPU: torch.set_num_threads (default: PyTorch's; on a machine shared with other work, "
        "1 avoids OpenMP threads waiting on each other)",
    )
    parser.add_argument("--json", help="also write the figures to this JSON file")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    methods = args.methods or list(st.methods())
    depth_to_normals = kornia_normals()
    o3d = open3d_or_reason()
    agreement = check_agreement(depth_to_normals)
    devices = [torch.device("cpu")] if "cpu" in args.devices else []
    if "cuda" in args.devices and torch.cuda.is_available():
        devices.append(torch.device("cuda"))
    print(
        f"torch {torch.__version__}, {os.cpu_count()} cores, {torch.get_num_threads()} torch threads; "
        f"480x640 frames; kornia sign check on a plane: max diff {agreement:.1e}"
    )
    report = {
        "rows": [],
        "skipped": {},
        "torch": torch.__version__,
        "machine": platform.platform(),
        "cores": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "kornia_sign_check_max_diff": agreement,
    }
    with torch.inference_mode():
        for device in devices:
            name = "CPU" if device.type == "cpu" else f"CUDA {torch.cuda.get_device_name(device)}"
            for batch in args.batches:
                depth, K = frames(batch)
                fns, skipped = contenders(depth, K, methods, depth_to_normals, o3d, device)
                rows = table(device, batch, fns, args.runs, args.budget)
                print_table(
                    f"{name}, batch {batch}, {args.runs} rounds" + (" (interleaved)" if device.type == "cpu" else ""),
                    rows,
                    skipped,
                )
                report["rows"] += rows
                report["skipped"].update({f"{k} on {device}": v for k, v in skipped.items()})
                del fns
    if "cuda" in args.devices and not torch.cuda.is_available():
        print("\nno CUDA device: the GPU tables need one (same command)")
    if args.json:
        import kornia

        report["kornia"] = kornia.__version__
        if not isinstance(o3d, str):
            report["open3d"] = o3d.__version__
        atomic_write(args.json, lambda tmp: tmp.write_text(json.dumps(report, indent=1)))


if __name__ == "__main__":
    main()
