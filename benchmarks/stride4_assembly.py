"""A prototype for the speed clause: ``adaptive_fit``'s planes on every fourth row and column, carried to every pixel.

    PYTHONPATH=src python benchmarks/stride4_assembly.py [SENSOR_DIR] [--sensors kinect_v1,primesense,...] [--rounds 11]

``adaptive_fit`` (stride 2) fits its windows on the pixels of the even rows and columns, a quarter of them, and the
other pixels take the planes of the fitted pixels next to them (``surfnorm.kernels._assembly``). On a 2-core machine
without AVX-512 the default still takes 1.2-1.6x OpenCV LINEMOD's time on 640x480 sensor frames, and fitting a
sixteenth of the pixels is the largest cut of its work in view (``benchmarks/decimated_fit.py``: with one normal per
2x2 block it costs up to 1.19x the error). This measures what the error would be if the windows were fitted on
every fourth row and column only, each with every pixel of the frame in it, and every pixel took the planes of the
four fitted pixels at the corners of its 4x4 cell, each carried to it (w at the pixel, from the plane's slopes):
the mean of those that predict the pixel's own inverse depth within their noise limit, weighted bilinearly by the
pixel's place in the cell (a pixel on a fitted row or column reads only the two fitted pixels on its line), or
where none does the one that predicts it closest; eq. (2) of ``surfnorm.kernels.adaptive_fit`` then gives the normal.

The planes are the kernel's own: ``adaptive_fit`` runs once with a copy of its band kernel that also writes each
fitted pixel's plane (a, g_u, g_v, whether it has one, its noise limit), made from the installed kernel's source,
and checked to give ``adaptive_fit``'s normals to the bit; the planes of the pixels (4 i, 4 j) are those of the
stride-2 fit, so the fits are the same and only what reaches the other pixels differs. As a check of the assembly
written here, the same carrying with the stride-2 planes (the corners 2 apart, plain means as the kernel takes) is
reported too: it reads as the kernel does except at the few pixels where the kernel looks further (its 5x5
fallback). Sparse depth (``choose_stride`` 1: LiDAR) is left out. The carrying is NumPy, slow: its accuracy only.

Times (``--rounds``, on one thread, the noise profile given; dense frames of SENSOR_DIR): the copied kernel at
stride 2 with its normals (``adaptive_fit``), its fits alone (no normal written: the integral rows, the fits, the
widening and the edge test), and the fits alone at stride 4, which the same kernel runs (its integral rows' columns
ordered by their remainder modulo the stride, ``_windows.integral_positions``; checked first: its planes are the
stride-2 planes of the pixels (4 i, 4 j), to the bit). A stride-4 assembly is not written in Numba here: the last columns add stride 2's cost of
writing the normals to the stride-4 fits, and the noise profile to both, for the ratio of one call to another.

Reported: on the frames of SENSOR_DIR (default ../shared/data/sensor-sample beside the repository, skipped where
absent) the plane metric (mean folded angle, coverage) of ``adaptive_fit``, the stride-2 carrying and the stride-4
one; on the 12 3F2N sample frames through each simulated sensor of --sensors (seed 0) the mean e_A of the three over
the pixels where all three have a normal, and the coverage of each (the carried ones have no fallback beyond the
corners of a pixel's cell).
"""

from __future__ import annotations

import argparse
import functools
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent

#: The line of the band kernel before which each fitted row's planes are complete (after the edge test).
_HOOK = "        if few:  # the planes at every fitted pixel again (none where invalid)"
_STORE = """        for c in range(n):
            planes[v // stride, cols[c] // stride, 0] = a[c]
            planes[v // stride, cols[c] // stride, 1] = g_u[c]
            planes[v // stride, cols[c] // stride, 2] = g_v[c]
            planes[v // stride, cols[c] // stride, 3] = 1.0 if valid_row[c] and dof[c] > 0.0 else 0.0
            planes[v // stride, cols[c] // stride, 4] = limit[c]
"""


def _kernel_copy(*, planes: bool = True, normals: bool = True):
    """A copy of ``_adaptive_fit_kernel`` compiled from the installed module's source (not cached), with an argument
    ``planes`` ((H / stride, W / stride, 5) float64) that it fills where ``planes``, and without writing any normal
    (no assembly: the fits alone, for their time) where not ``normals``."""
    import re

    import surfnorm.kernels.adaptive_fit as af
    from surfnorm._config import njit

    source = Path(af.__file__).read_text()
    start = source.index("def _adaptive_fit_kernel(")
    end = source.index("\n#: ``info`` of :func:`_adaptive_fit_kernel`")
    body = source[start:end]
    if body.count(_HOOK) != 1:
        raise RuntimeError("stride4_assembly: the band kernel changed; its hook line was not found once")
    body = body.replace("stride, info, gains, has):", "stride, info, gains, has, planes):", 1)
    if planes:
        body = body.replace(_HOOK, _STORE + _HOOK, 1)
    if not normals:  # every call that writes normals (row_done, emit_row: one line each) becomes a no-op
        body, n = re.subn(r"\n( +)(row_done|emit_row)\([^\n]*\)\n", r"\n\1pass\n", body)
        if n < 3:
            raise RuntimeError("stride4_assembly: the band kernel changed; its calls that write normals were not found")
    namespace = dict(vars(af))
    exec(compile(body, "<stride4_assembly kernel>", "exec"), namespace)
    return njit(noalias=True, cache=False)(namespace["_adaptive_fit_kernel"])


@functools.lru_cache(maxsize=None)
def _kernel(planes: bool, normals: bool):
    return _kernel_copy(planes=planes, normals=normals)


def _run(z, cam, stride: int, *, planes: bool, normals: bool, profile=None):
    """One band of the copied kernel over ``z``; returns (normals, planes)."""
    from surfnorm._bands import whole
    from surfnorm.kernels import _schedule
    from surfnorm.kernels.adaptive_fit import FitPlan

    out = np.empty(z.shape + (3,), np.float32)
    frame = FitPlan(z, z > 0, cam, out, stride=stride, profile=profile)
    shape = ((z.shape[0] + stride - 1) // stride, (z.shape[1] + stride - 1) // stride, 5) if planes else (1, 1, 5)
    fitted = np.zeros(shape)
    kernel = _kernel(planes, normals)

    def fit(v0, v1, work, tables):
        kernel(z, frame.valid, tables, frame.steps, frame.cam, frame.options, work, out, v0, v1, stride, frame.info,
               frame.gains, frame.has, fitted)  # fmt: skip

    frame.fit = fit
    _schedule.run_bands(frame, whole)
    return out, fitted


def fitted_planes(z: np.ndarray, cam) -> tuple[np.ndarray, np.ndarray, int]:
    """``adaptive_fit``'s normals of ``z`` (one band, its defaults), its fitted pixels' planes and its stride."""
    import surfnorm
    from surfnorm.kernels._schedule import choose_stride

    z = np.ascontiguousarray(z, np.float32)
    stride = choose_stride(z > 0)
    out, planes = _run(z, cam, stride, planes=True, normals=True)
    if not np.array_equal(out, surfnorm.estimate(z, cam, method="adaptive_fit", threads=1), equal_nan=True):
        raise RuntimeError("stride4_assembly: the copied kernel's normals differ from adaptive_fit's")
    return out, planes, stride


def fit_times(z: np.ndarray, cam, rounds: int) -> dict[str, float]:
    """Median ms on one thread, the noise profile given: ``adaptive_fit`` (the copied kernel at stride 2, its normals
    included), its fits alone (no normal written) at stride 2 and at stride 4; checked first that the stride-4 fits
    are the stride-2 fits of the pixels (4 i, 4 j), to the bit."""
    import math
    import time

    from surfnorm.kernels.sensor_noise import noise_profile

    z = np.ascontiguousarray(z, np.float32)
    profile = noise_profile(z, z > 0, math.sqrt(cam.fx * cam.fy))
    two = _run(z, cam, 2, planes=True, normals=True, profile=profile)[1]
    four = _run(z, cam, 4, planes=True, normals=False, profile=profile)[1]
    ok = two[::2, ::2, 3] > 0.0  # (a pixel without a plane holds what its row's scratch held)
    if not (np.array_equal(ok, four[..., 3] > 0.0) and np.array_equal(two[::2, ::2][ok], four[ok])):
        raise RuntimeError("stride4_assembly: the stride-4 fits differ from the stride-2 fits of the same pixels")
    calls = {
        "stride 2": lambda: _run(z, cam, 2, planes=False, normals=True, profile=profile),
        "stride 2, fits alone": lambda: _run(z, cam, 2, planes=False, normals=False, profile=profile),
        "stride 4, fits alone": lambda: _run(z, cam, 4, planes=False, normals=False, profile=profile),
    }
    times: dict[str, list] = {k: [] for k in calls}
    for call in calls.values():
        call()
    for r in range(rounds):
        for k in list(calls) if r % 2 == 0 else list(calls)[::-1]:
            t0 = time.perf_counter()
            calls[k]()
            times[k].append(time.perf_counter() - t0)
    ms = {k: 1e3 * float(np.median(v)) for k, v in times.items()}
    t0 = time.perf_counter()
    for _ in range(rounds):
        noise_profile(z, z > 0, math.sqrt(cam.fx * cam.fy))
    ms["noise profile"] = 1e3 * (time.perf_counter() - t0) / rounds
    return ms


def carried(z: np.ndarray, planes: np.ndarray, step: int, cam, *, bilinear: bool) -> np.ndarray:
    """Every pixel's normal from the planes of the fitted pixels (step i, step j) at the corners of its cell (see the
    module docstring); ``bilinear``: weighted by the pixel's place in the cell, else plain means (of the corners
    whose weight is not 0). Zeros where a pixel has no depth or no corner with a plane."""
    H, W = z.shape
    v, u = np.mgrid[0:H, 0:W]
    valid = z > 0
    w_p = np.where(valid, 1.0 / np.where(valid, z, 1.0), 0.0)
    i0, j0 = v // step, u // step
    total, weights = np.zeros((H, W, 3)), np.zeros((H, W))
    closest, closest_plane = np.full((H, W), np.inf), np.zeros((H, W, 3))
    for di in (0, 1):
        for dj in (0, 1):
            i, j = i0 + di, j0 + dj
            inside = (i < planes.shape[0]) & (j < planes.shape[1])
            p = planes[np.minimum(i, planes.shape[0] - 1), np.minimum(j, planes.shape[1] - 1)]
            du, dv = u - step * j, v - step * i
            weight = np.where(inside, (1.0 - np.abs(du) / step) * (1.0 - np.abs(dv) / step), 0.0)
            if not bilinear:
                weight = (weight > 0.0).astype(np.float64)
            has = inside & (p[..., 3] > 0.0) & (weight > 0.0)
            w_there = p[..., 0] + p[..., 1] * du + p[..., 2] * dv
            error = np.where(has, (w_there - w_p) ** 2, np.inf)
            plane = np.stack([w_there, p[..., 1], p[..., 2]], axis=-1)
            passes = has & (error <= p[..., 4])
            total += np.where(passes[..., None], weight[..., None] * plane, 0.0)
            weights += np.where(passes, weight, 0.0)
            closer = error < closest
            closest = np.where(closer, error, closest)
            closest_plane = np.where(closer[..., None], plane, closest_plane)
    found = weights > 0.0
    plane = np.where(found[..., None], total / np.where(found, weights, 1.0)[..., None], closest_plane)
    a = np.where(plane[..., 0] > 0.0, plane[..., 0], w_p)  # a plane behind the camera: the pixel's own w
    nx, ny = cam.fx * plane[..., 1], cam.fy * plane[..., 2]
    nz = a - plane[..., 1] * (u - cam.cx) - plane[..., 2] * (v - cam.cy)
    norm = np.sqrt(nx * nx + ny * ny + nz * nz)
    n = -np.stack([nx, ny, nz], axis=-1) / np.where(norm > 0.0, norm, 1.0)[..., None]
    n[~(valid & (found | (closest < np.inf)))] = 0.0
    return n.astype(np.float32)


def variants(z: np.ndarray, cam) -> dict[str, np.ndarray] | None:
    """``adaptive_fit``, the stride-2 carrying and the stride-4 one; None for sparse depth."""
    normals, planes, stride = fitted_planes(z, cam)
    if stride != 2:
        return None
    return {
        "adaptive_fit": normals,
        "carried, stride 2": carried(z, planes, 2, cam, bilinear=False),
        "carried, stride 4": carried(z, planes[::2, ::2], 4, cam, bilinear=True),
    }


def main(argv=None) -> int:
    from surfnorm.bench.peers import steady_allocator

    steady_allocator()  # the timed calls allocate their output: from memory the process kept, not fresh pages
    from surfnorm.bench.sensor import find_sensor_frames, read_sensor_frame, score_frame
    from surfnorm.bench.simulate import frame_seed, sensor_names, simulate
    from surfnorm.camera import Intrinsics
    from surfnorm.errors import InputError
    from surfnorm.io.threef2n import find_frames, read_frame, sample_root
    from surfnorm.kernels._schedule import choose_stride
    from surfnorm.metrics import coverage, mean_angular_error

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sensor_dir", nargs="?", default=str(REPO.parent / "shared" / "data" / "sensor-sample"))
    ap.add_argument("--sensors", default="kinect_v1,primesense,d435,kinect_v1_raw,stereo_sgbm,post_filtered,tof")
    ap.add_argument("--rounds", type=int, default=11, help="timed calls of each kernel per frame (0: no times)")
    args = ap.parse_args(argv)
    try:
        sensors = sensor_names(args.sensors)
    except InputError as exc:
        print(f"stride4_assembly: {exc}", file=sys.stderr)
        return 2
    names = ("adaptive_fit", "carried, stride 2", "carried, stride 4")
    folders = find_sensor_frames(args.sensor_dir) if Path(args.sensor_dir).is_dir() else []
    rows = ["| frame | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    for folder in folders:
        f = read_sensor_frame(folder)
        got = variants(f.depth, f.K)
        if got is None:
            rows.append(f"| {f.name} | sparse: left out | | |")
            continue
        cells = [f"{score_frame(got[k], f)[1]:.2f} ({score_frame(got[k], f)[2]:.3f})" for k in names]
        rows.append(f"| {f.name} | " + " | ".join(cells) + " |")
    if folders:
        print("\n".join(rows) + "\n")
    if folders and args.rounds > 0:
        rows = [
            "| frame | stride 2 | its fits alone | stride 4, fits alone | stride 4 with stride 2's normals' cost "
            "| noise profile | one call at stride 4 over one at stride 2 |",
            "|---" * 7 + "|",
        ]
        for folder in folders:
            f = read_sensor_frame(folder)
            if choose_stride(f.depth > 0) != 2:
                continue
            ms = fit_times(f.depth, f.K, args.rounds)
            normals = ms["stride 2"] - ms["stride 2, fits alone"]
            four = ms["stride 4, fits alone"] + normals
            ratio = (four + ms["noise profile"]) / (ms["stride 2"] + ms["noise profile"])
            rows.append(
                f"| {f.name} | {ms['stride 2']:.1f} | {ms['stride 2, fits alone']:.1f} | "
                f"{ms['stride 4, fits alone']:.1f} | {four:.1f} | {ms['noise profile']:.1f} | {ratio:.2f} |"
            )
        print("\n".join(rows) + "\n")
    root = REPO / "tests" / "data" / "3f2n-sample"
    root = root if root.is_dir() else Path(sample_root())
    frames = find_frames(root)
    rows = [
        "| simulated sensor | " + " | ".join(names) + " | coverage |",
        "|---" * (len(names) + 2) + "|",
    ]
    for s in sensors:
        errors: dict[str, list] = {k: [] for k in names}
        covered: dict[str, list] = {k: [] for k in names}
        for name in frames:
            f = read_frame(root, name)
            z = simulate(f.depth, f.K, s, seed=frame_seed(0, name, s), mask=f.mask, normals=f.normals)
            got = variants(z, Intrinsics.from_matrix(f.K))
            if got is None:
                continue
            m = (z > 0) & f.mask
            every = m.copy()  # e_A over the pixels where all three have a normal (a pixel left out is not an error)
            for k in names:
                every &= np.any(got[k] != 0.0, axis=-1)
                covered[k].append(coverage(got[k], m))
            for k in names:
                errors[k].append(mean_angular_error(got[k], f.normals, every))
        if not errors[names[0]]:
            rows.append(f"| {s} | sparse: left out | | | |")
            continue
        e = {k: float(np.mean(v)) for k, v in errors.items()}
        c = " / ".join(f"{np.mean(covered[k]):.4f}" for k in names)
        rows.append(f"| {s} | " + " | ".join(f"{e[k]:.2f} ({e[k] / e[names[0]]:.3f})" for k in names) + f" | {c} |")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
