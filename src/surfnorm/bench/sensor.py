"""The sensor benchmark: surfnorm's methods next to OpenCV, Open3D and kornia on depth as sensors deliver it.

Two sources of frames, one set of entries (what is estimated) and one timing protocol:

* :func:`run_simulated`: 3F2N frames (exact normals) turned into sensor depth by
  :mod:`surfnorm.bench.simulate`; e_A and coverage per sensor model and level.
  ``python benchmarks/sensor_sim.py`` prints its tables.
* :func:`run_folder`: real frames in the layout of the sensor sample (one folder
  per frame: ``depth.npy`` in metres, ``K.json``, and ``planes.npz`` or ``gt.npy``);
  the plane metric (:func:`surfnorm.metrics.plane_error`) or e_A against ``gt.npy``,
  and time. ``surfnorm bench --sensor DIR --out R`` writes its report.

Entries are every registered method (:func:`surfnorm.methods`, so a new one
appears here once registered) with its defaults, a few variants
(:data:`VARIANTS`), and the peers of :data:`surfnorm.bench.peers.SENSOR_PEERS`;
a peer whose library does not import is reported as absent, not as a failure.
A method name may carry options: ``plane_pca:window=11``.

Time: one thread for every library (:func:`surfnorm.bench.peers.single_thread`,
and ``threads=1`` for surfnorm, unless an entry names ``threads``: see
:data:`VARIANTS`), after a warm-up call; a peer's time is its own library call (its conversion to
unit, camera-facing normals is not timed).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .. import metrics
from ..camera import Intrinsics
from ..errors import InputError
from ..methods import DEFAULT_METHOD, parse_method

__all__ = [
    "Entry",
    "VARIANTS",
    "make_entries",
    "linemod_entry",
    "alternating_medians",
    "parse_name",
    "run_simulated",
    "sim_tables",
    "SensorFrame",
    "find_sensor_frames",
    "read_sensor_frame",
    "score_frame",
    "run_folder",
    "write_folder_report",
    "sensor_bench",
]

#: Variants run beside the registered methods' defaults: (method, options). ``threads`` is ``estimate``'s
#: (default 1 in the benchmark, "all": every core); on a machine with several cores the default method
#: is also run as a user calls it, on every core.
VARIANTS = (("plane_pca", {"window": 11}),)


@dataclass
class Entry:
    """One row of the benchmark: a label, and ``call(depth, cam, valid) -> raw`` with ``finish(raw) -> normals``.

    ``call`` is what is timed; ``finish`` turns its output into unit, camera-facing normals (zeros where none).
    """

    label: str
    kind: str  # "surfnorm" or "peer"
    summary: str
    call: Callable
    finish: Callable = field(default=lambda n: n)

    def normals(self, depth, cam, valid) -> np.ndarray:
        return self.finish(self.call(depth, cam, valid))


def parse_name(name: str) -> tuple[str, dict]:
    """``"plane_pca:window=11"`` -> ("plane_pca", {"window": 11}): :func:`surfnorm.methods.parse_method`, the
    parser of ``surfnorm estimate -m``."""
    return parse_method(name)


def label_of(method: str, options: dict) -> str:
    return method + "".join(f" {k}={v}" for k, v in options.items())


def _threads(value) -> int:
    """An entry's ``threads``: a positive integer, or "all" (every core, as ``estimate``'s default)."""
    if value == "all":
        return os.cpu_count() or 1
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise InputError(f"methods: expected threads=N (a positive integer) or threads=all, got threads={value!r}")
    return value


def _surfnorm_entry(method: str, options: dict) -> Entry:
    """``estimate`` on one thread, unless the options hold ``threads`` (N or "all": one frame in row bands)."""
    from .._api import estimate
    from ..methods import resolve

    options = dict(options)
    threads = _threads(options.pop("threads", 1))
    resolve(method, dict(options))  # a bad name or option is an InputError now, not on the first frame

    def call(depth, cam, valid, method=method, options=options):
        return estimate(depth, cam, method=method, threads=threads, **options)

    shown = dict(options, threads=threads) if threads != 1 else options
    info_summary = f"surfnorm.estimate(method={method!r}" + "".join(f", {k}={v!r}" for k, v in shown.items()) + ")"
    return Entry(label_of(method, shown), "surfnorm", info_summary, call)


def _peer_entry(peer, run) -> Entry:
    from .peers import clean

    def call(depth, cam, valid, run=run):
        return run(depth, cam, valid, clean=False)

    return Entry(peer.name, "peer", peer.summary, call, clean)


def make_entries(
    names: list[str] | None = None, *, peer_libraries: list[str] | None = None
) -> tuple[list[Entry], dict[str, str]]:
    """The entries for ``names`` (registered methods, ``name:opt=value`` variants, peer keys), default all.

    ``peer_libraries`` (opencv, open3d, kornia; default all) limits the default peers.
    Returns (entries, {name: why absent}) - a peer whose library does not import is absent.
    Unknown names are an InputError.
    """
    from ..methods import methods
    from .peers import SENSOR_PEERS, load_peers

    registered = list(methods())
    peer_keys = [p.name for p in SENSOR_PEERS]
    if names is None:
        wanted: list = [(m, {}) for m in registered] + [(m, o) for m, o in VARIANTS if m in registered]
        if (os.cpu_count() or 1) > 1:  # the default call as a user makes it: one frame on every core
            wanted.append((DEFAULT_METHOD, {"threads": "all"}))
        libs = {p.library for p in SENSOR_PEERS}
        for lib in peer_libraries or []:
            if lib not in libs:
                raise InputError(f"peers: expected some of {', '.join(sorted(libs))}, got {lib!r}")
        wanted_peers = [p.name for p in SENSOR_PEERS if peer_libraries is None or p.library in peer_libraries]
    else:
        wanted, wanted_peers = [], []
        for name in names:
            if name in peer_keys:
                wanted_peers.append(name)
                continue
            method, options = parse_name(name)
            base = method[:-4] if method.endswith("+mnr") else method
            if base not in registered:
                raise InputError(
                    f"methods: expected registered methods ({', '.join(registered)}), optionally with "
                    f":option=value, or peers ({', '.join(peer_keys)}), got {name!r}"
                )
            wanted.append((method, options))
    entries = [_surfnorm_entry(m, o) for m, o in wanted]
    runs, absent = load_peers(wanted_peers, table=SENSOR_PEERS) if wanted_peers else ({}, {})
    by_name = {p.name: p for p in SENSOR_PEERS}
    entries += [_peer_entry(by_name[n], runs[n]) for n in wanted_peers if n in runs]
    return entries, absent


def _timed(entry: Entry, depth, cam, valid) -> tuple[np.ndarray, float]:
    t0 = time.perf_counter()
    raw = entry.call(depth, cam, valid)
    ms = (time.perf_counter() - t0) * 1e3
    return entry.finish(raw), ms


def linemod_entry(script: str) -> Entry | None:
    """OpenCV's LINEMOD (window 5, the sensor benchmark's most accurate peer) for a benchmark ``script`` to time the
    default against; None after one line on standard error that names ``script`` and why the peer is absent (the
    script then exits 2)."""
    import sys

    entries, absent = make_entries(["opencv_linemod_w5"])
    if entries and not absent:
        return entries[0]
    why = "; ".join(f"{k}: {v}" for k, v in absent.items()) or "no entry made"
    print(
        f"{script}: OpenCV's RgbdNormals is needed (pip install opencv-contrib-python-headless), got {why}",
        file=sys.stderr,
    )
    return None


def alternating_medians(calls: dict[str, Callable[[], object]], rounds: int, *, warm_up: int = 2) -> dict[str, float]:
    """The median milliseconds of each of ``calls`` (name: a call without arguments) over ``rounds`` rounds, each
    call once per round, in the order given on even rounds and the reverse on odd ones (so that no call always
    follows the same one), after ``warm_up`` untimed calls of each. For the same-run ratios of the benchmark scripts.
    """
    for call in calls.values():
        for _ in range(warm_up):
            call()
    times: dict[str, list[float]] = {name: [] for name in calls}
    names = list(calls)
    for r in range(rounds):
        for name in names if r % 2 == 0 else names[::-1]:
            t0 = time.perf_counter()
            calls[name]()
            times[name].append(time.perf_counter() - t0)
    return {name: float(np.median(t)) * 1e3 for name, t in times.items()}


# ---------------------------------------------------------------------------- simulated sensors


def run_simulated(
    root,
    entries: list[Entry],
    sensors: list[str],
    *,
    levels=None,
    frames_per_level: int | None = None,
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
) -> dict:
    """e_A, coverage and time of every entry on the 3F2N frames under ``root`` as each sensor would see them.

    Per (sensor, frame, entry): e_A over the object's pixels where the sensor delivered depth and the
    entry a normal, the coverage of those pixels, and the time of one call (after one warm-up call of
    each entry, on the first frame, not counted). Returns {"records": [...], "errors": [...], "frames": [...]}.
    """
    from ..io.threef2n import LEVELS, find_frames, read_frame
    from .simulate import SENSORS, frame_seed, simulate

    for s in sensors:
        if s not in SENSORS:
            raise InputError(f"sensors: expected some of {', '.join(SENSORS)}, got {s!r}")
    levels = tuple(levels or LEVELS)
    names = find_frames(root, levels=levels)
    if frames_per_level is not None:
        picked = []
        for lv in levels:
            picked += [n for n in names if n.startswith(lv + "/")][:frames_per_level]
        names = picked
    if not names:
        raise InputError(
            f"root: expected 3F2N frames (Easy|Medium|Hard/<object>/depth/*.bin) of levels "
            f"{', '.join(levels)}, found none under {root}"
        )
    progress = progress or (lambda msg: None)
    records, errors, warm = [], [], set()
    for name in names:
        frame = read_frame(root, name)
        for s in sensors:
            z = simulate(
                frame.depth, frame.K, s, seed=frame_seed(seed, name, s), mask=frame.mask, normals=frame.normals
            )
            valid = z > 0
            scored = frame.mask & valid
            for e in entries:
                try:
                    if e.label not in warm:
                        e.call(z, frame.K, valid)
                        warm.add(e.label)
                    n, ms = _timed(e, z, frame.K, valid)
                except Exception as exc:  # noqa: BLE001 - one entry failing is reported, never fatal
                    errors.append(
                        {"sensor": s, "frame": name, "entry": e.label, "error": f"{type(exc).__name__}: {exc}"}
                    )
                    continue
                records.append(
                    {
                        "sensor": s,
                        "frame": name,
                        "level": frame.level,
                        "entry": e.label,
                        "e_a": metrics.mean_angular_error(n, frame.normals, scored),
                        "coverage": metrics.coverage(n, scored),
                        "ms": ms,
                        "depth_coverage": float(scored.sum() / max(frame.mask.sum(), 1)),
                    }
                )
            progress(f"{name} {s}")
    return {
        "records": records,
        "errors": errors,
        "frames": names,
        "sensors": list(sensors),
        "entries": [e.label for e in entries],
        "seed": seed,
    }


def _mean(values):
    values = [v for v in values if v is not None and np.isfinite(v)]
    return float(np.mean(values)) if values else float("nan")


def sim_tables(result: dict) -> str:
    """Markdown: one table per sensor (e_A per level, all frames, coverage, ms) and a summary (e_A per sensor)."""
    from ..io.threef2n import LEVELS

    recs = result["records"]
    levels = [lv for lv in LEVELS if any(r["level"] == lv for r in recs)]
    entries, sensors = result["entries"], result["sensors"]
    out = []

    def sel(**kw):
        return [r for r in recs if all(r[k] == v for k, v in kw.items())]

    def fmt(v, d=2):
        return "-" if not np.isfinite(v) else f"{v:.{d}f}"

    # summary first: the figure tuning looks at
    out.append("### e_A (degrees, mean over frames) per sensor model; ms = median time per frame\n")
    out.append("| method | " + " | ".join(sensors) + " | ms |")
    out.append("|---|" + "---|" * (len(sensors) + 1))
    for e in entries:
        cells = [fmt(_mean([r["e_a"] for r in sel(entry=e, sensor=s)])) for s in sensors]
        ms = [r["ms"] for r in sel(entry=e)]
        out.append(f"| {e} | " + " | ".join(cells) + f" | {fmt(float(np.median(ms)) if ms else float('nan'), 1)} |")
    for s in sensors:
        out.append(f"\n### {s}: e_A (degrees) per level, coverage of the pixels with depth, ms per frame\n")
        out.append("| method | " + " | ".join(levels) + " | all | coverage | ms |")
        out.append("|---|" + "---|" * (len(levels) + 3))
        for e in entries:
            rows = sel(entry=e, sensor=s)
            cells = [fmt(_mean([r["e_a"] for r in rows if r["level"] == lv])) for lv in levels]
            ms = [r["ms"] for r in rows]
            out.append(
                f"| {e} | " + " | ".join(cells) + f" | {fmt(_mean([r['e_a'] for r in rows]))} | "
                f"{fmt(_mean([r['coverage'] for r in rows]), 3)} | "
                f"{fmt(float(np.median(ms)) if ms else float('nan'), 1)} |"
            )
        dc = _mean([r["depth_coverage"] for r in sel(sensor=s, entry=entries[0])]) if entries else float("nan")
        out.append(f"\nShare of the objects' pixels with depth from {s}: {fmt(dc, 3)}")
    if result["errors"]:
        out.append("\n### failures\n")
        out += [f"- {e['entry']} on {e['frame']} ({e['sensor']}): {e['error']}" for e in result["errors"]]
    return "\n".join(out) + "\n"


# ---------------------------------------------------------------------------- real frames (a folder)

#: A method whose warm call takes longer than this (ms) is timed with SLOW_REPEATS calls only.
SLOW_MS, SLOW_REPEATS = 200.0, 3


@dataclass
class SensorFrame:
    """One frame of a sensor folder: depth (metres, 0 = none), intrinsics, and its reference.

    ``planes``: (normals (P, 3), masks (P, H, W)) for real frames; ``gt``: normals (H, W, 3) for rendered ones.
    """

    name: str
    depth: np.ndarray
    K: Intrinsics
    planes: tuple[np.ndarray, np.ndarray] | None = None
    gt: np.ndarray | None = None


def find_sensor_frames(root) -> list[Path]:
    """The frame folders under ``root`` (sub-folders holding ``depth.npy``; ``root`` itself if it holds one).

    Raises InputError when ``root`` is not a folder or holds no frame.
    """
    root = Path(root)
    if not root.is_dir():
        raise InputError(
            f"sensor dataset: expected a folder of frame folders (depth.npy, K.json, planes.npz or gt.npy), got {root}"
        )
    if (root / "depth.npy").is_file():
        return [root]
    found = sorted(p for p in root.iterdir() if p.is_dir() and (p / "depth.npy").is_file())
    if not found:
        raise InputError(
            f"sensor dataset: expected frame folders holding depth.npy, K.json and planes.npz or gt.npy, "
            f"found none in {root}"
        )
    return found


def _load_npy(path: Path, what: str) -> np.ndarray:
    from ..errors import DataFileError

    try:
        return np.load(path, allow_pickle=False)
    except FileNotFoundError as exc:
        raise DataFileError(f"{path}: missing ({what})") from exc
    except (OSError, ValueError, EOFError) as exc:
        raise DataFileError(f"{path}: cannot read as a NumPy .npy file ({what}): {exc}") from exc


def read_sensor_frame(folder) -> SensorFrame:
    """Read one frame folder of the sensor-sample layout; a bad file is a DataFileError naming it."""
    import zipfile

    from ..errors import DataFileError
    from ..io.intrinsics import read_intrinsics

    folder = Path(folder)
    depth = _load_npy(folder / "depth.npy", "depth in metres, (H, W) float")
    if depth.ndim != 2 or not (np.issubdtype(depth.dtype, np.floating) or np.issubdtype(depth.dtype, np.integer)):
        raise DataFileError(
            f"{folder / 'depth.npy'}: expected (H, W) float depth in metres, got shape {depth.shape} dtype {depth.dtype}"
        )
    depth = np.nan_to_num(depth.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    if not np.any(depth > 0):
        raise DataFileError(f"{folder / 'depth.npy'}: expected some valid (positive) depth, got none")
    K = read_intrinsics(folder / "K.json")
    H, W = depth.shape
    planes = gt = None
    if (folder / "planes.npz").is_file():
        path = folder / "planes.npz"
        try:
            with np.load(path, allow_pickle=False) as z:
                normals, masks = np.asarray(z["normals"], np.float64), np.asarray(z["masks"]).astype(bool)
        except KeyError as exc:
            raise DataFileError(
                f"{path}: expected arrays 'normals' (P, 3) and 'masks' (P, H, W), missing {exc}"
            ) from exc
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise DataFileError(f"{path}: cannot read as a NumPy .npz file: {exc}") from exc
        if normals.ndim != 2 or normals.shape[1] != 3 or masks.shape != (normals.shape[0], H, W):
            raise DataFileError(
                f"{path}: expected normals (P, 3) and masks (P, {H}, {W}) to match depth.npy, "
                f"got {normals.shape} and {masks.shape}"
            )
        planes = (normals, masks)
    elif (folder / "gt.npy").is_file():
        gt = _load_npy(folder / "gt.npy", "ground-truth normals (H, W, 3)")
        if gt.shape != (H, W, 3):
            raise DataFileError(
                f"{folder / 'gt.npy'}: expected normals of shape {(H, W, 3)} to match depth.npy, got {gt.shape}"
            )
        gt = gt.astype(np.float32)
    else:
        raise DataFileError(
            f"{folder}: expected a reference, planes.npz (real frames) or gt.npy (rendered), found neither"
        )
    return SensorFrame(folder.name, depth, K, planes, gt)


def score_frame(n: np.ndarray, frame: SensorFrame) -> tuple[str, float, float]:
    """(metric, mean angle in degrees, coverage): the plane metric, or e_A against gt.npy over valid depth."""
    if frame.planes is not None:
        mean, cov = metrics.plane_error(n, *frame.planes)
        return "planes", mean, cov
    assert frame.gt is not None  # a frame holds planes.npz or gt.npy (read_sensor_frame)
    sq = np.einsum("hwc,hwc->hw", frame.gt.astype(np.float64), frame.gt.astype(np.float64))
    where = (frame.depth > 0) & np.isfinite(sq) & (sq > 0)
    return "gt", metrics.mean_angular_error(n, frame.gt, where), metrics.coverage(n, where)


def run_folder(
    root, entries: list[Entry], *, repeats: int = 5, progress: Callable[[str, int, int], None] | None = None
) -> dict:
    """The sensor benchmark on every frame folder under ``root``.

    Per frame and entry: the metric of its normals (from the warm-up call), then ``repeats`` timed
    calls (``SLOW_REPEATS`` for entries slower than ``SLOW_MS``), the entries' order rotating from
    round to round; the median is kept. A frame that cannot be read is a DataFileError (the whole
    run stops: a benchmark over a partial folder would be misread); an entry that raises is recorded.
    """
    if not isinstance(repeats, int) or isinstance(repeats, bool) or repeats < 1:
        raise InputError(f"repeats: expected a positive integer, got {repeats!r}")
    folders = find_sensor_frames(root)
    frames = [read_sensor_frame(f) for f in folders]  # all read first: a bad file fails before hours of work
    progress = progress or (lambda stage, done, total: None)
    records, errors, decisions = [], [], {}
    for i, frame in enumerate(frames):
        valid = frame.depth > 0
        decisions[frame.name] = _decision(frame)
        times, scores = {}, {}
        for e in entries:
            try:
                e.call(frame.depth, frame.K, valid)  # warm-up (compiling, caches)
                n, ms = _timed(e, frame.depth, frame.K, valid)
            except Exception as exc:  # noqa: BLE001 - reported, never fatal
                errors.append({"frame": frame.name, "entry": e.label, "error": f"{type(exc).__name__}: {exc}"})
                continue
            scores[e.label] = score_frame(n, frame)
            times[e.label] = [ms]
        live = [e for e in entries if e.label in times]
        want = {e.label: SLOW_REPEATS if times[e.label][0] > SLOW_MS else repeats for e in live}
        for r in range(max(want.values(), default=0) - 1):
            k = r % max(len(live), 1)
            for e in live[k:] + live[:k]:
                if len(times[e.label]) < want[e.label]:
                    t0 = time.perf_counter()
                    e.call(frame.depth, frame.K, valid)
                    times[e.label].append((time.perf_counter() - t0) * 1e3)
        for e in live:
            metric, angle, cov = scores[e.label]
            records.append(
                {
                    "frame": frame.name,
                    "entry": e.label,
                    "kind": e.kind,
                    "metric": metric,
                    "angle": angle,
                    "coverage": cov,
                    "ms": float(np.median(times[e.label])),
                    "calls": len(times[e.label]),
                    "size": list(frame.depth.shape),
                }
            )
        progress("frames", i + 1, len(frames))
    return {
        "root": str(root),
        "frames": [f.name for f in frames],
        "entries": [e.label for e in entries],
        "summaries": {e.label: e.summary for e in entries},
        "records": records,
        "errors": errors,
        "repeats": repeats,
        "decisions": decisions,
    }


def _decision(frame: SensorFrame) -> dict:
    """What the default method (auto) runs on the frame, and the measurements behind it (surfnorm.auto_decision)."""
    from .._api import auto_decision

    return auto_decision(frame.depth, frame.K)._asdict()


def _fmt(v, d=1) -> str:
    return "-" if v is None or not np.isfinite(v) else f"{v:.{d}f}"


def folder_markdown(result: dict) -> str:
    """The report: angle (ms) per frame and entry, the medians over frames, coverage, what was absent or failed."""
    frames, entries, recs = result["frames"], result["entries"], result["records"]
    get = {(r["frame"], r["entry"]): r for r in recs}
    best = {}
    for f in frames:
        vals = [(get[(f, e)]["angle"], e) for e in entries if (f, e) in get and np.isfinite(get[(f, e)]["angle"])]
        best[f] = min(vals)[1] if vals else None
    metric = {f: next((get[(f, e)]["metric"] for e in entries if (f, e) in get), "") for f in frames}
    out = [
        "# Sensor benchmark",
        "",
        f"Frames: {len(frames)} in {result['root']}. Cells: mean folded angle in degrees to the reference planes "
        "(plane metric) or to the ground truth (e_A, frames marked *), and in brackets the median time of a warm "
        f"call in ms at one thread, or on N threads where an entry says threads=N ({result['repeats']} calls, "
        f"{SLOW_REPEATS} for calls over {SLOW_MS:g} ms). "
        "Best angle per frame in bold. Medians over frames in the last columns.",
        "",
        "## Angle (ms)",
        "",
    ]
    head = [f + ("*" if metric[f] == "gt" else "") for f in frames]
    out.append("| method | " + " | ".join(head) + " | median angle | median ms |")
    out.append("|---|" + "---|" * (len(frames) + 2))
    for e in entries:
        cells, angles, times = [], [], []
        for f in frames:
            r = get.get((f, e))
            if r is None:
                cells.append("failed")
                continue
            a = _fmt(r["angle"])
            cells.append((f"**{a}**" if best[f] == e else a) + f" ({_fmt(r['ms'], 0 if r['ms'] >= 10 else 1)})")
            angles.append(r["angle"])
            times.append(r["ms"])
        out.append(
            f"| {e} | " + " | ".join(cells) + f" | {_fmt(float(np.median(angles)) if angles else None)} | "
            f"{_fmt(float(np.median(times)) if times else None)} |"
        )
    out += ["", "## Coverage (share of the reference pixels that received a normal)", ""]
    out.append("| method | " + " | ".join(head) + " | min |")
    out.append("|---|" + "---|" * (len(frames) + 1))
    for e in entries:
        covs = [get[(f, e)]["coverage"] if (f, e) in get else None for f in frames]
        ok = [c for c in covs if c is not None and np.isfinite(c)]
        out.append(f"| {e} | " + " | ".join(_fmt(c, 3) for c in covs) + f" | {_fmt(min(ok) if ok else None, 3)} |")
    if result.get("decisions"):
        out += [
            "",
            "## What the default ran",
            "",
            "`auto` decides per frame on its noise reading (point spacings z / f): the largest of the noise floor, "
            "the smooth noise and the terraces' quantisation noise, at least 0.20 where the depth is terraced in "
            "full, and at least 0.10 + 0.10 s where its error is small and smooth over a few pixels (s, the smooth "
            "error's share, from 0 to 1: the noise rho over the floor, 1 for white noise); `d2nt_v3` at or below "
            "0.10, `adaptive_fit` at or above 0.20, their blend between "
            "(`surfnorm.auto_decision`); grid: the step of the grid the depth is stored on (whole millimetres and "
            "the like; 0 for float depth), from which (0.05 to 0.10) `adaptive_fit`'s weight is at least its share; "
            "white noise: how far the error is white noise however small (as much at the pixel scale as at stride "
            "2, rho about the floor: 0 to 1), and `adaptive_fit`'s weight at least that share plus the smooth error's; "
            "checked: `adaptive_fit`'s normals checked against `d2nt_v3`'s pixel by "
            "pixel (at low noise, and on quantised depth where its step is small); upsampled: the factor by which the depth was resized "
            "from a lower resolution, where `adaptive_fit`'s weight is under 1 or the noise is correlated (at least 3) "
            "and one was found (`adaptive_fit` alone then, with windows of at least 2 K + 1 pixels, 2 ceil(1.5 K) + 1 "
            "where its weight is 1), 1 elsewhere; "
            "correlation: of the noise between neighbouring pixels (1: independent).",
            "",
            "| frame | ran | adaptive_fit's weight | reading | floor | smooth | terraced | step | quantisation "
            "| grid | checked | upsampled | correlation | smooth error | white noise |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for f in frames:
            d = result["decisions"].get(f)
            if d is None:
                continue
            nums = [_fmt(d[k], 3) for k in ("weight", "reading", "floor", "smooth", "terraced", "step", "quantisation")]
            checked = "yes" if d.get("checked") else "no"
            out.append(
                f"| {f} | {d['method']} | " + " | ".join(nums) + f" | {_fmt(d.get('grid'), 3)} | {checked} "
                f"| {d.get('upsampled', 1):g} "
                f"| {_fmt(d.get('correlation'), 2)} | {_fmt(d.get('smooth_error'), 2)} | {_fmt(d.get('white_noise'), 2)} |"
            )
    out += ["", "## Entries", ""] + [f"- {e}: {result['summaries'][e]}" for e in entries]
    if result.get("absent"):
        out += ["", "## Absent peers (library not installed)", ""]
        out += [f"- {k}: {v}" for k, v in result["absent"].items()]
    if result["errors"]:
        out += ["", "## Failures", ""] + [f"- {x['entry']} on {x['frame']}: {x['error']}" for x in result["errors"]]
    if result.get("meta"):
        out += ["", "## Run", ""] + [f"- {k}: {v}" for k, v in result["meta"].items()]
    return "\n".join(out) + "\n"


def folder_figure(path, result: dict) -> Path:
    """Per frame, angle against time (log scale) of every entry: surfnorm's methods and the peers in two colours."""
    from .figures import _plt, _save

    plt = _plt()
    frames = result["frames"]
    cols = min(4, len(frames))
    rows = -(-len(frames) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.6 * rows), squeeze=False)
    for ax, f in zip(axes.flat, frames):
        for r in (r for r in result["records"] if r["frame"] == f and np.isfinite(r["angle"]) and r["ms"] > 0):
            color = "tab:blue" if r["kind"] == "surfnorm" else "tab:orange"
            ax.scatter(r["ms"], r["angle"], s=14, color=color)
            ax.annotate(r["entry"], (r["ms"], r["angle"]), fontsize=5, xytext=(2, 2), textcoords="offset points")
        ax.set_xscale("log")
        ax.set_title(f, fontsize=9)
        ax.set_xlabel("ms (one thread unless the entry says threads=N)", fontsize=8)
        ax.set_ylabel("angle (deg)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(frames) :]:
        ax.axis("off")
    fig.suptitle("Sensor benchmark: angle vs time per frame (blue: surfnorm, orange: peers)", fontsize=10)
    fig.tight_layout()
    return _save(fig, Path(path))


def write_folder_report(result: dict, out_dir) -> dict[str, Path]:
    """report.md, results.json and sensor.png in ``out_dir``, each written atomically."""
    import json

    from ..io._atomic import atomic_write

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    text = folder_markdown(result)
    sigma = result.get("uncertainty")
    if sigma is not None:
        from .uncertainty import figure, markdown

        text = text.rstrip("\n") + "\n\n" + markdown(sigma["calibration"], sigma["sparsification"])

    def finite(obj):
        if isinstance(obj, float):
            return obj if np.isfinite(obj) else None
        if isinstance(obj, dict):
            return {k: finite(v) for k, v in obj.items()}
        if isinstance(obj, list):
            return [finite(v) for v in obj]
        return obj

    return {
        "report": atomic_write(out_dir / "report.md", lambda tmp: tmp.write_text(text)),
        "results": atomic_write(
            out_dir / "results.json", lambda tmp: tmp.write_text(json.dumps(finite(result), indent=1))
        ),
        "figure": folder_figure(out_dir / "sensor.png", result),
        **(
            {"uncertainty": figure(out_dir / "uncertainty.png", sigma["calibration"], sigma["sparsification"])}
            if sigma is not None
            else {}
        ),
    }


def sensor_bench(
    root,
    out,
    *,
    names: list[str] | None = None,
    peer_libraries: list[str] | None = None,
    repeats: int = 5,
    progress=None,
    uncertainty: bool = True,
    calibration_root=None,
) -> tuple[dict, dict[str, Path]]:
    """``surfnorm bench --sensor ROOT --out OUT``: one thread everywhere (and the default method also on every
    core), every entry, the report. With ``uncertainty``, also the default's sigma: its calibration on the
    simulated sensors over the 3F2N frames under ``calibration_root`` (default: those shipped in the package)
    and its sparsification on the frames under ``root`` (:mod:`surfnorm.bench.uncertainty`), in the report
    and in uncertainty.png. Returns (result, paths)."""
    import platform

    from .peers import peer_versions, single_thread

    find_sensor_frames(root)  # a bad folder fails before any library is imported
    if uncertainty:
        from .uncertainty import calibration_frames

        calibration_frames(calibration_root)  # and a dataset without frames before hours of work
    threads = single_thread()
    entries, absent = make_entries(names, peer_libraries=peer_libraries)
    result = run_folder(root, entries, repeats=repeats, progress=progress)
    result["absent"] = absent
    if uncertainty:
        from .uncertainty import calibration, sparsification

        result["uncertainty"] = {
            "calibration": calibration(calibration_root),
            "sparsification": sparsification([read_sensor_frame(f) for f in find_sensor_frames(root)]),
        }
    result["meta"] = {
        "threads": threads,
        "versions": peer_versions(),
        "python": platform.python_version(),
        "machine": platform.machine(),
        "cpus": __import__("os").cpu_count(),
    }
    return result, write_folder_report(result, out)
