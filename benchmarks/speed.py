"""Speed of surfnorm's D2NT family and CP2TV next to the authors' d2nt package, same frames, same process.

    NUMBA_NUM_THREADS=1 python benchmarks/speed.py [--out bench-output] [--repeats 50] [--quick]

(``make bench`` installs d2nt 0.1.3 into .venv and runs this.) Everything is
single-threaded unless said otherwise: NUMBA_NUM_THREADS=1, ``threads=1``,
``cv2.setNumThreads(1)`` for the authors' OpenCV filters. Compilation happens
outside the timed region (one call first). Our time is the public front door
``surfnorm.estimate`` on a float32 (H, W) frame, validation included; theirs
is ``d2nt.depth2normal``. The two are called alternately, so both see the
same machine load, and each figure is the median of ``--repeats`` runs.

Also measured: every other registered estimator on the shipped frames (no peer; the targets of the
issues), ``import surfnorm`` and the first estimate in a fresh process
with a warm compile cache (subprocesses; beside Numba's own floor: its import and
the first call of a one-line cached function), the peak memory of one d2nt_v3 call
(tracemalloc for NumPy arrays, and the growth of the process's peak RSS, which
also sees Numba's own allocations), and the throughput of a stack of 16
frames on 1 and 2 threads, into a new output and into a reused one (``out=``); one
1280x960 frame on 1, 2 and all cores (``threads=N``: row bands, bit-identical) for
the D2NT family, SDA-SNE and the default method; and their time per pixel from
320x240 to 3840x2160 (one thread).

Writes ``speed.md`` (the table printed) and ``speed.json`` (figures, versions,
commit, CPU, thread counts, load average) into ``--out``.
"""

from __future__ import annotations

import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")  # before Numba is imported

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ThreadPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

import surfnorm  # noqa: E402
from surfnorm.io._atomic import atomic_write  # noqa: E402
from surfnorm.io.threef2n import find_frames, read_frame, sample_root  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
# The authors' times per frame in the reference JSON (shipped with the package), on "a 2-core machine like ours".
REFERENCE_MS = json.loads((Path(surfnorm.__file__).parent / "data" / "official-3f2n-sample.json").read_text())["frames"]
# Ours, with the options that compute what the authors' version computes (their FD reflects at the border).
METHODS = {"d2nt_basic": {"border": "reflect"}, "d2nt_v2": {}, "d2nt_v3": {}, "cp2tv": {}}
TARGET_MS = {"d2nt_basic": 1.2, "d2nt_v2": 2.5, "d2nt_v3": 4.0}
# Every other estimator, with the targets of the issues (3F2N median: speed issue; the rest: baselines issue).
BASELINE_TARGET_MS = {
    "3f2n_median": 4.0,
    "3f2n_mean": None,
    "sne_roadseg": None,
    "sda_sne": 20.0,
    "plane_svd": 30.0,
    "plane_pca": 30.0,
    "vector_svd": 30.0,
    "area_weighted": 30.0,
    "angle_weighted": 30.0,
}


def seeded_frame(seed=0, h=480, w=640, holes=0.0):
    """A smooth synthetic scene (sphere in front of a tilted wall), optionally with random holes (depth 0)."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    wall = 3.0 + 0.002 * u + 0.001 * v
    r2 = ((u - w / 2) ** 2 + (v - h / 2) ** 2) / (0.3 * h) ** 2
    z = np.where(r2 < 1, 2.0 - 0.5 * np.sqrt(np.clip(1 - r2, 0, 1)), wall) + 1e-4 * rng.standard_normal((h, w))
    z[rng.random((h, w)) < holes] = 0.0
    K = np.array([[525.0, 0, (w - 1) / 2], [0, 525.0, (h - 1) / 2], [0, 0, 1]])
    return z.astype(np.float32), surfnorm.Intrinsics.from_matrix(K)


def inputs():
    frames = [(f.name, f.depth, f.K) for f in (read_frame(sample_root(), n) for n in find_frames(sample_root()))]
    frames.append(("seeded smooth", *seeded_frame(0)))
    frames.append(("seeded, 5% holes", *seeded_frame(1, holes=0.05)))
    return frames


def authors_K(cam):
    # d2nt uses 1-based pixel coordinates: its u0 is our cx + 1.
    return np.array([[cam.fx, 0, cam.cx + 1], [0, cam.fy, cam.cy + 1], [0, 0, 1]])


#: The clock of :func:`interleaved`: wall-clock time; ``benchmarks/threads.py --cpu`` swaps in the thread's CPU time.
CLOCK = time.perf_counter


def interleaved(funcs, repeats):
    """Median seconds of each function, called in turn ``repeats`` times (after one untimed call each)."""
    for f in funcs:
        f()
    times = [[] for _ in funcs]
    for _ in range(repeats):
        for f, t in zip(funcs, times):
            t0 = CLOCK()
            f()
            t.append(CLOCK() - t0)
    return [statistics.median(t) for t in times]


def time_frames(repeats, quick):
    try:
        import cv2
        import d2nt

        cv2.setNumThreads(1)
    except ImportError:
        d2nt = None
    rows = []
    for name, z, cam in inputs()[: 2 if quick else None]:
        for method, options in METHODS.items():
            ours = lambda: surfnorm.estimate(z, cam, method=method, threads=1, **options)  # noqa: E731
            funcs = [ours]
            if d2nt is not None and method.startswith("d2nt"):
                K = authors_K(cam)
                funcs.append(lambda: d2nt.depth2normal(z, K, version=method))
            t = interleaved(funcs, repeats)
            # Ours again, back to back: the caches then hold our frame, where after the authors' call (50 MB of
            # temporaries) they do not; both are reported.
            (alone,) = interleaved([ours], repeats)
            reference = REFERENCE_MS.get(name, {}).get(f"official_{method}_ms")
            rows.append(
                {
                    "frame": name,
                    "method": method,
                    "shape": list(z.shape),
                    "ours_ms": t[0] * 1e3,
                    "reference_authors_ms": reference,
                    "ours_alone_ms": alone * 1e3,
                    "authors_ms": t[1] * 1e3 if len(t) > 1 else None,
                    "ratio": t[1] / t[0] if len(t) > 1 else None,
                    "repeats": repeats,
                }
            )
            print(
                f"  {name:22s} {method:11s} ours {t[0] * 1e3:7.3f} ms (alone {alone * 1e3:7.3f})"
                + (f"  authors {t[1] * 1e3:7.2f} ms  ratio {t[1] / t[0]:5.1f}x" if len(t) > 1 else ""),
                flush=True,
            )
    return rows


_STREAM = None


def stream_kernel():
    """The memory floor's kernel: read each depth, write it into the three float32 channels of ``out``."""
    global _STREAM
    if _STREAM is None:
        import numba

        @numba.njit(nogil=True)
        def stream(z, out):
            for v in range(z.shape[0]):
                for u in range(z.shape[1]):
                    d = z[v, u]
                    out[v, u, 0] = d
                    out[v, u, 1] = d
                    out[v, u, 2] = d

        _STREAM = stream
    return _STREAM


def time_floor(repeats):
    """The memory floor: a kernel that only reads each depth and writes it into three float32 channels of a new
    (H, W, 3) array, as an estimator's input and output traffic; after the authors' call and alone."""
    stream = stream_kernel()
    _, z, cam = inputs()[0]
    floor = lambda: stream(z, np.empty(z.shape + (3,), np.float32))  # noqa: E731
    funcs = [floor]
    try:
        import d2nt

        K = authors_K(cam)
        funcs.append(lambda: d2nt.depth2normal(z, K, version="d2nt_basic"))
    except ImportError:
        pass
    after = interleaved(funcs, repeats)[0]
    (alone,) = interleaved([floor], repeats)
    print(f"  read depth + write 3 channels: {after * 1e3:.3f} ms after the authors' call, {alone * 1e3:.3f} ms alone")
    return {"interleaved_ms": after * 1e3, "alone_ms": alone * 1e3}


def time_baselines(repeats, quick):
    """Median ms of every other registered estimator on the shipped frames, one thread (no peer in this table)."""
    rows = []
    frames = inputs()[:3]
    for method in ["3f2n_median", "sda_sne"] if quick else BASELINE_TARGET_MS:
        per_frame = [
            interleaved([lambda: surfnorm.estimate(z, cam, method=method, threads=1)], repeats)[0] * 1e3
            for _, z, cam in frames
        ]
        rows.append(
            {
                "method": method,
                "median_ms": statistics.median(per_frame),
                "per_frame_ms": per_frame,
                "target_ms": BASELINE_TARGET_MS[method],
                "repeats": repeats,
            }
        )
        print(f"  {method:14s} {statistics.median(per_frame):8.2f} ms", flush=True)
    return rows


def subprocess_seconds(code, runs):
    """Median of what ``code`` prints (seconds) over fresh interpreters, and the median wall time of each process.

    One unmeasured run first, with Python's bytecode cache allowed (some machines set PYTHONDONTWRITEBYTECODE):
    "warm cache" means Numba's compile cache and Python's, as for an installed package.
    """
    inner, outer = [], []
    env = {**os.environ, "NUMBA_NUM_THREADS": "1"}
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    for _ in range(runs):
        t0 = time.perf_counter()
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
        outer.append(time.perf_counter() - t0)
        inner.append([float(x) for x in out.stdout.split()])
    return [statistics.median(col) for col in zip(*inner)], statistics.median(outer)


IMPORT_CODE = "import time; t = time.perf_counter(); import surfnorm; print(time.perf_counter() - t)"
FIRST_CALL_CODE = """
import time; t0 = time.perf_counter()
import numpy as np, surfnorm
t1 = time.perf_counter()
z = np.full((480, 640), 2.0, np.float32)
surfnorm.estimate(z, [[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]], method="{method}")
t2 = time.perf_counter()
print(t1 - t0, t2 - t1, t2 - t0)
"""
# Numba's own start-up, the floor under a first estimate: import Numba, then the first call of a one-line
# function loaded from its disk cache (Numba then sets up its typing and target registries, whatever the function).
NUMBA_PROBE = """
import numba


@numba.njit(cache=True, nogil=True)
def probe(x):
    return x[0] + 1.0
"""
NUMBA_FLOOR_CODE = """
import sys, time; sys.path.insert(0, {folder!r})
import numpy as np
t0 = time.perf_counter()
import numba_floor_probe
numba_floor_probe.probe(np.ones(3))
print(time.perf_counter() - t0)
"""


def numba_floor_seconds(runs):
    """Median seconds of Numba's import plus its first cached call, in fresh interpreters (cache warmed first)."""
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        Path(folder, "numba_floor_probe.py").write_text(NUMBA_PROBE)
        code = NUMBA_FLOOR_CODE.format(folder=folder)
        (seconds,), _ = subprocess_seconds(code, runs)  # its warm-up run compiles and writes the cache
    return seconds


MEMORY_CODE = """
import tracemalloc, numpy as np, surfnorm
from surfnorm.io.threef2n import read_frame, sample_root
def status(key):
    return next(int(line.split()[1]) * 1024 for line in open("/proc/self/status") if line.startswith(key))
f = read_frame(sample_root(), "Easy/android/000001")
surfnorm.estimate(f.depth[:40, :40].copy(), f.K, method="{method}")  # load the kernels
z = f.depth
with open("/proc/self/clear_refs", "w") as fh:  # reset the peak RSS (VmHWM) to the current RSS
    fh.write("5")
before = status("VmRSS:")
tracemalloc.start()
n = surfnorm.estimate(z, f.K, method="{method}")
peak = tracemalloc.get_traced_memory()[1]
tracemalloc.stop()
print(peak, status("VmHWM:") - before, n.nbytes)
"""
AUTHORS_MEMORY_CODE = """
import tracemalloc, numpy as np, d2nt
from surfnorm.io.threef2n import read_frame, sample_root
f = read_frame(sample_root(), "Easy/android/000001")
K = np.array([[f.K.fx, 0, f.K.cx + 1], [0, f.K.fy, f.K.cy + 1], [0, 0, 1]])
d2nt.depth2normal(f.depth[:40, :40].copy(), K, version="d2nt_v3")
tracemalloc.start()
n = d2nt.depth2normal(f.depth, K, version="d2nt_v3")
print(tracemalloc.get_traced_memory()[1], 0, n.nbytes)
"""


def _batch_row(method, t1, t2, r1, r2, repeats):
    """One row of the batch table (seconds for 16 frames: a new output on 1 and 2 threads, then into ``out=``),
    printed as it is made."""
    print(
        f"  batch of 16 {method:11s} new output: 1 thread {t1 * 1e3:6.1f} ms, 2 threads {t2 * 1e3:6.1f} ms, "
        f"{t1 / t2:4.2f}x | out=: {r1 * 1e3:6.1f} ms, {r2 * 1e3:6.1f} ms, {r1 / r2:4.2f}x",
        flush=True,
    )
    return {
        "method": method,
        "frames": 16,
        "one_thread_ms": t1 * 1e3,
        "two_threads_ms": t2 * 1e3,
        "speed_up": t1 / t2,
        "frames_per_s_2_threads": 16 / t2,
        "out_one_thread_ms": r1 * 1e3,
        "out_two_threads_ms": r2 * 1e3,
        "out_speed_up": r1 / r2,
        "out_frames_per_s_2_threads": 16 / r2,
        "repeats": repeats,
    }


def time_batches(repeats, quick):
    """A stack of 16 frames on 1 and 2 threads, into a new output per call and into a reused one (``out=``).

    A new 59 MB output is memory that the system zeroes on first touch; that
    part does not get faster with a second thread, so both are reported.
    """
    frames = inputs()[:3]
    stack = np.stack([frames[i % 3][1] for i in range(16)])
    cams = [frames[i % 3][2] for i in range(16)]
    buffer = np.zeros(stack.shape + (3,), np.float32)
    rows = []
    # The memory floor on the same stack: what reading the frames and writing their outputs alone gains
    # from a second thread on this machine (no estimator can scale better where it streams memory).
    stream = stream_kernel()
    pool = ThreadPoolExecutor(2)

    def floor(threads, out):
        target = np.empty(stack.shape + (3,), np.float32) if out is None else out
        if threads == 1:
            for i in range(16):
                stream(stack[i], target[i])
        else:
            list(pool.map(lambda i: stream(stack[i], target[i]), range(16)))

    t1, t2, r1, r2 = interleaved(
        [lambda: floor(1, None), lambda: floor(2, None), lambda: floor(1, buffer), lambda: floor(2, buffer)], repeats
    )
    pool.shutdown()
    rows.append(_batch_row("memory floor", t1, t2, r1, r2, repeats))
    for method in ["d2nt_v3"] if quick else ["d2nt_basic", "d2nt_v2", "d2nt_v3", "cp2tv"]:
        options = METHODS[method]
        t1, t2, r1, r2 = interleaved(
            [
                lambda: surfnorm.estimate(stack, cams, method=method, threads=1, **options),
                lambda: surfnorm.estimate(stack, cams, method=method, threads=2, **options),
                lambda: surfnorm.estimate(stack, cams, method=method, threads=1, out=buffer, **options),
                lambda: surfnorm.estimate(stack, cams, method=method, threads=2, out=buffer, **options),
            ],
            repeats,
        )
        rows.append(_batch_row(method, t1, t2, r1, r2, repeats))
    return rows


def default_method():
    """``surfnorm.estimate``'s default method at run time."""
    import inspect

    return inspect.signature(surfnorm.estimate).parameters["method"].default


def scaling_methods():
    """The D2NT family, SDA-SNE and the default method (in that order, once each)."""
    return list(dict.fromkeys(["d2nt_basic", "d2nt_v2", "d2nt_v3", "sda_sne", default_method()]))


def thread_counts():
    return sorted({1, 2, os.cpu_count() or 1})


def time_frame_threads(repeats, quick):
    """One 1280x960 frame (5 % holes) on 1, 2 and all cores (row bands), interleaved; and whether the bits agree."""
    z, cam = seeded_frame(2, h=960, w=1280, holes=0.05)
    rows = []
    counts = thread_counts()
    for method in ["d2nt_v3", "sda_sne"] if quick else scaling_methods():
        out = {n: np.empty(z.shape + (3,), np.float32) for n in counts}
        funcs = [lambda n=n: surfnorm.estimate(z, cam, method=method, threads=n, out=out[n]) for n in counts]
        times = interleaved(funcs, repeats)
        same = all(np.array_equal(out[n].view(np.uint32), out[1].view(np.uint32)) for n in counts)
        row = {
            "method": method,
            "shape": list(z.shape),
            "threads": counts,
            "ms": [t * 1e3 for t in times],
            "speed_up": [times[0] / t for t in times],
            "bit_identical": same,
            "repeats": repeats,
        }
        rows.append(row)
        print(
            f"  {method:11s} "
            + ", ".join(f"{n} thread(s) {t * 1e3:7.2f} ms ({times[0] / t:4.2f}x)" for n, t in zip(counts, times))
            + f"; bit-identical: {same}",
            flush=True,
        )
    return rows


SIZES = [(240, 320), (480, 640), (720, 1280), (960, 1280), (1536, 2048), (2160, 3840)]


def time_per_pixel(repeats, quick):
    """ns per pixel on one thread from 320x240 to 3840x2160 (same scene, 5 % holes), into a reused output
    and into a new one; the ratio to 640x480 shows a cache cliff if there is one."""
    rows = []
    frames = {hw: seeded_frame(3, h=hw[0], w=hw[1], holes=0.05) for hw in (SIZES[:3] if quick else SIZES)}
    for method in ["d2nt_v3"] if quick else scaling_methods():
        for (h, w), (z, cam) in frames.items():
            n = max(3, int(repeats * 640 * 480 / (h * w)))
            buffer = np.empty((h, w, 3), np.float32)
            reused, new = interleaved(
                [
                    lambda: surfnorm.estimate(z, cam, method=method, threads=1, out=buffer),
                    lambda: surfnorm.estimate(z, cam, method=method, threads=1),
                ],
                n,
            )
            rows.append(
                {
                    "method": method,
                    "shape": [h, w],
                    "ns_per_pixel": reused * 1e9 / (h * w),
                    "new_output_ns_per_pixel": new * 1e9 / (h * w),
                    "repeats": n,
                }
            )
        base = next(r for r in rows if r["method"] == method and r["shape"] == [480, 640])
        for r in rows:
            if r["method"] == method:
                r["vs_640x480"] = r["ns_per_pixel"] / base["ns_per_pixel"]
                r["new_output_vs_640x480"] = r["new_output_ns_per_pixel"] / base["new_output_ns_per_pixel"]
        print(
            f"  {method:11s} ns/pixel (out=; new output): "
            + ", ".join(
                f"{r['shape'][1]}x{r['shape'][0]} {r['ns_per_pixel']:.2f}; {r['new_output_ns_per_pixel']:.2f}"
                for r in rows
                if r["method"] == method
            ),
            flush=True,
        )
    return rows


def machine():
    cpu = (
        next(
            (line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name")),
            platform.processor(),
        )
        if os.path.exists("/proc/cpuinfo")
        else platform.processor()
    )
    import numba

    versions = {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": numba.__version__,
        "surfnorm": surfnorm.__version__,
    }
    for mod in ("llvmlite", "cv2", "d2nt"):
        try:
            versions[mod] = __import__(mod).__version__
        except ImportError:
            versions[mod] = None
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True).stdout.strip()
        dirty = bool(
            subprocess.run(
                ["git", "status", "--porcelain", "--untracked-files=no"], cwd=REPO, capture_output=True, text=True
            ).stdout.strip()
        )
    except OSError:
        commit, dirty = None, None
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "numba_threads": int(os.environ["NUMBA_NUM_THREADS"]),
        "versions": versions,
        "commit": commit,
        "uncommitted_changes": dirty,
        "platform": platform.platform(),
    }


def markdown(record):
    lines = [
        f"# surfnorm speed ({record['machine']['cpu']}, {record['machine']['cores']} cores, single thread)",
        "",
        f"Commit {record['machine']['commit']}; load average {record['load_before']} before, "
        f"{record['load_after']} after. Medians of {record['repeats']} interleaved runs.",
        "",
        "Ours interleaved with the authors' calls (our frame no longer in the caches), and ours alone (back to back).",
        "",
        "| frame (480x640) | method | ours, interleaved (ms) | ours alone (ms) | authors' d2nt 0.1.3 (ms) | ratio |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for r in record["frames"]:
        theirs = f"{r['authors_ms']:.2f}" if r["authors_ms"] else "-"
        ratio = f"{r['ratio']:.1f}x" if r["ratio"] else "-"
        lines.append(
            f"| {r['frame']} | {r['method']} | {r['ours_ms']:.3f} | {r['ours_alone_ms']:.3f} | {theirs} | {ratio} |"
        )
    lines += [
        "",
        "| method | shipped frames: median ours, interleaved (ms) | alone (ms) | target (ms) | median ratio "
        "| all frames: median ratio | ours at the reference machine's pace (ms) |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for method in METHODS:
        rs = [r for r in record["frames"] if r["method"] == method]
        shipped = [r for r in rs if not r["frame"].startswith("seeded")] or rs
        ratio = [
            f"{statistics.median(x):.1f}x" if x else "-"
            for x in ([r["ratio"] for r in shipped if r["ratio"]], [r["ratio"] for r in rs if r["ratio"]])
        ]
        paced = [
            r["reference_authors_ms"] / r["ratio"] for r in shipped if r.get("reference_authors_ms") and r["ratio"]
        ]
        lines.append(
            f"| {method} | {statistics.median(r['ours_ms'] for r in shipped):.3f} | "
            f"{statistics.median(r['ours_alone_ms'] for r in shipped):.3f} | "
            f"{TARGET_MS.get(method, '-')} | {ratio[0]} | {ratio[1]} | "
            f"{f'{statistics.median(paced):.2f}' if paced else '-'} |"
        )
    lines += [
        "",
        "The last column divides the authors' time on each frame in the reference JSON (measured on \"a 2-core "
        "machine like ours\") by this run's ratio: our time at that machine's pace, as this VM's speed drifts.",
    ]
    f = record["floor"]
    lines += [
        "",
        f"Memory floor on this machine: reading a 480x640 float32 depth and writing it into a new (480, 640, 3) "
        f"float32 array takes {f['interleaved_ms']:.3f} ms after the authors' call, {f['alone_ms']:.3f} ms alone.",
    ]
    lines += [
        "",
        "| every other estimator (480x640, shipped frames) | median ours (ms) | target (ms) |",
        "|---|---:|---:|",
    ]
    for b in record["baselines"]:
        lines.append(f"| {b['method']} | {b['median_ms']:.2f} | {b['target_ms'] or '-'} |")
    s = record["startup"]
    lines += [
        "",
        "| start-up and memory | measured | target |",
        "|---|---:|---:|",
        f"| `import surfnorm` (in-process, median of fresh interpreters) | {s['import_s']:.3f} s | 0.3 s |",
        f"| `python -c 'import surfnorm'` wall time, interpreter included | {s['import_process_s']:.3f} s | |",
        f"| first d2nt_v3 estimate, fresh process, warm cache (after the import) | {s['first_call_s']:.3f} s | 0.5 s |",
        f"| the Numba floor under it: import Numba + first call of a one-line cached function | "
        f"{s['numba_floor_s']:.3f} s | |",
        f"| import + first estimate | {s['import_and_first_s']:.3f} s | |",
    ]
    m = record["memory"]
    out_mb = m["output_bytes"] / 2**20
    lines += [
        f"| peak memory of one d2nt_v3 call, NumPy (tracemalloc) | {m['tracemalloc_peak_bytes'] / 2**20:.2f} MiB "
        f"= {m['tracemalloc_peak_bytes'] / m['output_bytes']:.2f}x output ({out_mb:.2f} MiB) | 3x |",
        f"| peak RSS growth of that call (all allocations, Numba's included) | {m['rss_growth_bytes'] / 2**20:.2f} MiB "
        f"= {m['rss_growth_bytes'] / m['output_bytes']:.2f}x output | 3x |",
    ]
    if m.get("authors_tracemalloc_peak_bytes"):
        lines.append(
            f"| authors' d2nt_v3, NumPy peak (tracemalloc) | {m['authors_tracemalloc_peak_bytes'] / 2**20:.2f} MiB "
            f"= {m['authors_tracemalloc_peak_bytes'] / m['output_bytes']:.1f}x output | |"
        )
    lines += [
        "",
        "| batch of 16 (N, 480, 640) | new output: 1 thread (ms) | 2 threads (ms) | speed-up "
        "| `out=` reused: 1 thread (ms) | 2 threads (ms) | speed-up | target |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for b in record["batch"]:
        lines.append(
            f"| {b['method']} | {b['one_thread_ms']:.1f} | {b['two_threads_ms']:.1f} | {b['speed_up']:.2f}x "
            f"| {b['out_one_thread_ms']:.1f} | {b['out_two_threads_ms']:.1f} | {b['out_speed_up']:.2f}x "
            f"| {'1.7x' if b['method'] != 'memory floor' else '(bound)'} |"
        )
    if record.get("frame_threads"):
        counts = record["frame_threads"][0]["threads"]
        lines += [
            "",
            f"One 1280x960 frame split into row bands (`threads=N`, reused `out=`), default method "
            f"{record['default_method']}; target for d2nt_v3 and sda_sne: 1.7x on 2 threads",
            "",
            "| method | "
            + " | ".join(f"{n} thread(s) (ms)" for n in counts)
            + " | "
            + " | ".join(f"speed-up {n}" for n in counts[1:])
            + " | bit-identical |",
            "|---|" + "---:|" * (2 * len(counts) - 1) + "---|",
        ]
        for r in record["frame_threads"]:
            lines.append(
                f"| {r['method']} | "
                + " | ".join(f"{t:.2f}" for t in r["ms"])
                + " | "
                + " | ".join(f"{x:.2f}x" for x in r["speed_up"][1:])
                + f" | {r['bit_identical']} |"
            )
    if record.get("per_pixel"):
        sizes = list(dict.fromkeys(tuple(r["shape"]) for r in record["per_pixel"]))
        lines += [
            "",
            "Time per pixel on one thread (ns), reused `out=` / new output; in brackets the ratio to 640x480 "
            "(target for the D2NT family: within 1.5x up to 3840x2160)",
            "",
            "| method | " + " | ".join(f"{w}x{h}" for h, w in sizes) + " |",
            "|---|" + "---:|" * len(sizes),
        ]
        for method in dict.fromkeys(r["method"] for r in record["per_pixel"]):
            rs = {tuple(r["shape"]): r for r in record["per_pixel"] if r["method"] == method}
            lines.append(
                f"| {method} | "
                + " | ".join(
                    f"{rs[hw]['ns_per_pixel']:.2f} ({rs[hw]['vs_640x480']:.2f}x) / {rs[hw]['new_output_ns_per_pixel']:.2f} "
                    f"({rs[hw]['new_output_vs_640x480']:.2f}x)"
                    for hw in sizes
                )
                + " |"
            )
    return "\n".join(lines) + "\n"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="bench-output")
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument("--quick", action="store_true", help="two frames, fewer runs (a smoke test, not a measurement)")
    args = parser.parse_args()
    repeats = 5 if args.quick else args.repeats
    load_before = [round(x, 2) for x in os.getloadavg()]
    print("single frames (interleaved with the authors' package):", flush=True)
    frames = time_frames(repeats, args.quick)
    print("memory floor:", flush=True)
    floor = time_floor(repeats)
    print("every other estimator:", flush=True)
    baselines = time_baselines(max(10, repeats // 2), args.quick)
    print("start-up (fresh interpreters):", flush=True)
    (imp,), imp_wall = subprocess_seconds(IMPORT_CODE, 3 if args.quick else 9)
    (t_imp, t_first, t_both), _ = subprocess_seconds(FIRST_CALL_CODE.format(method="d2nt_v3"), 3 if args.quick else 9)
    numba_floor = numba_floor_seconds(3 if args.quick else 9)
    print(
        f"  import {imp:.3f} s (process {imp_wall:.3f} s); first d2nt_v3 {t_first:.3f} s; both {t_both:.3f} s; "
        f"Numba floor {numba_floor:.3f} s"
    )
    (peak, rss, nbytes), _ = subprocess_seconds(MEMORY_CODE.format(method="d2nt_v3"), 1)
    memory = {"tracemalloc_peak_bytes": peak, "rss_growth_bytes": rss, "output_bytes": nbytes}
    try:
        import d2nt  # noqa: F401

        (a_peak, _, _), _ = subprocess_seconds(AUTHORS_MEMORY_CODE, 1)
        memory["authors_tracemalloc_peak_bytes"] = a_peak
    except ImportError:
        pass
    print(f"  memory: {memory}", flush=True)
    print("batches:", flush=True)
    batch = time_batches(max(10, repeats // 3) if not args.quick else 3, args.quick)
    print("one frame on several threads:", flush=True)
    frame_threads = time_frame_threads(max(10, repeats // 3) if not args.quick else 3, args.quick)
    print("time per pixel against frame size:", flush=True)
    per_pixel = time_per_pixel(max(10, repeats // 3) if not args.quick else 3, args.quick)
    record = {
        "about": __doc__.splitlines()[0],
        "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "machine": machine(),
        "repeats": repeats,
        "load_before": load_before,
        "load_after": [round(x, 2) for x in os.getloadavg()],
        "frames": frames,
        "floor": floor,
        "baselines": baselines,
        "startup": {
            "import_s": imp,
            "import_process_s": imp_wall,
            "first_call_s": t_first,
            "import_and_first_s": t_both,
            "numba_floor_s": numba_floor,
        },
        "memory": memory,
        "batch": batch,
        "default_method": default_method(),
        "frame_threads": frame_threads,
        "per_pixel": per_pixel,
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    table = markdown(record)
    atomic_write(out / "speed.md", lambda p: p.write_text(table))
    atomic_write(out / "speed.json", lambda p: p.write_text(json.dumps(record, indent=1) + "\n"))
    print()
    print(table)


if __name__ == "__main__":
    main()
