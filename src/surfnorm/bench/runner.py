"""Running the benchmark: which estimates to make, on which frames, with a cache and a timing protocol.

Two stages, each resumable (per-frame results are cached on disk in
``REPORT_DIR/cache``, keyed by frame, method, options, noise and code version):

* accuracy: every (frame, experiment) pair -> e_A, e_p, coverage; may run in
  ``jobs`` processes, one frame per task;
* timing: per frame, every Table III row (registered methods and peers) is
  called once to warm up (compiling, loading caches), then ``repeats`` times
  with one thread (``SLOW_REPEATS`` times when the first timed call took over
  ``SLOW_MS``), the order of the methods rotating from round to round so that
  drift hits all alike; the figure kept is the median. Never in parallel.

Anything that fails at runtime (a method raising, a frame that cannot be read)
is recorded with its reason and reported; the run goes on.
"""

from __future__ import annotations

import hashlib
import json
import time
import zlib
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .. import metrics
from ..errors import InputError, SurfnormError
from ..io._atomic import atomic_write
from ..io.threef2n import LEVELS, find_frames, read_frame
from . import paper

__all__ = ["BenchConfig", "Spec", "run_bench", "experiments", "NOISE_STD", "PEER_LIBRARIES"]

#: Standard deviations of the zero-mean Gaussian noise added to the objects' depth (3F2N depth units;
#: the objects lie 20-30 units from the camera, and neighbouring pixels about 0.02 units apart).
NOISE_STD = (0.0, 0.0001, 0.0002, 0.0005, 0.001, 0.002)
E_P_THRESHOLDS = (5.0, 10.0, 20.0, 30.0)
NOISE_METHODS = ("d2nt_basic", "d2nt_v2", "d2nt_v3")
DLFS = ("1d", "alpha", "beta", "gamma")
PEER_LIBRARIES = ("d2nt", "kornia", "open3d", "opencv")
#: The experiments: Tables II, III, IV, the noise study of Fig. 3, the Fig. 4-style panel.
TABLES = ("table2", "table3", "table4", "noise", "fig4")
#: A slow method (warm call over this many ms) is timed with ``SLOW_REPEATS`` calls only.
SLOW_MS, SLOW_REPEATS = 200.0, 3


@dataclass(frozen=True)
class Spec:
    """One estimate to make on every frame: a surfnorm method (with options) or a peer, maybe on noisy depth."""

    kind: str  # "surfnorm" or "peer"
    method: str
    options: tuple = ()  # sorted (key, value) pairs
    noise_std: float = 0.0

    @property
    def key(self) -> str:
        opts = ",".join(f"{k}={v}" for k, v in self.options)
        return f"{self.kind}:{self.method}[{opts}]@noise={self.noise_std:g}"


@dataclass
class BenchConfig:
    """What ``surfnorm bench`` was asked to do (the CLI maps its options onto this)."""

    root: Path
    out: Path
    methods: list[str] | None = None  # Table III rows among the registered names (+mnr allowed); None = all
    peers: list[str] | None = None  # peer libraries (PEER_LIBRARIES); None = all, [] = none
    levels: tuple[str, ...] = LEVELS
    frames_per_object: int | None = None
    jobs: int = 1
    seed: int = 0
    repeats: int = 7
    noise_std: tuple[float, ...] = NOISE_STD
    panel_frame: str | None = None  # frame of the Fig. 4-style panel; default: the first of the hardest level
    tables: tuple[str, ...] = TABLES  # which experiments to run (all by default)


def _check_config(cfg: BenchConfig, registered: list[str]):
    for name in cfg.methods or []:
        base = name[:-4] if name.endswith("+mnr") else name
        if base not in registered:
            raise InputError(
                f"methods: expected names from {', '.join(registered)} (optionally with +mnr), got {name!r}"
            )
    for lib in cfg.peers or []:
        if lib not in PEER_LIBRARIES:
            raise InputError(f"peers: expected some of {', '.join(PEER_LIBRARIES)}, got {lib!r}")
    for level in cfg.levels:
        if level not in LEVELS:
            raise InputError(f"levels: expected some of {', '.join(LEVELS)}, got {level!r}")
    for table in cfg.tables:
        if table not in TABLES:
            raise InputError(f"tables: expected some of {', '.join(TABLES)}, got {table!r}")
    if not isinstance(cfg.jobs, int) or cfg.jobs < 1:
        raise InputError(f"jobs: expected a positive integer, got {cfg.jobs!r}")
    if not isinstance(cfg.repeats, int) or cfg.repeats < 1:
        raise InputError(f"repeats: expected a positive integer, got {cfg.repeats!r}")
    if cfg.frames_per_object is not None and cfg.frames_per_object < 1:
        raise InputError(f"frames_per_object: expected a positive integer, got {cfg.frames_per_object!r}")
    if any(not np.isfinite(s) or s < 0 for s in cfg.noise_std):
        raise InputError(f"noise_std: expected non-negative numbers, got {cfg.noise_std!r}")
    if not Path(cfg.root).is_dir():
        raise InputError(f"dataset: expected a folder in the 3F2N layout (Easy/<object>/depth/...), got {cfg.root}")


def experiments(cfg: BenchConfig, registered: list[str], peer_names: list[str]) -> dict[str, dict[str, Spec]]:
    """The estimates each table needs, by experiment, as {row label: Spec}. Specs shared by tables are made once."""

    def s(method, noise=0.0, **options):
        return Spec("surfnorm", method, tuple(sorted(options.items())), float(noise))

    out: dict[str, dict] = {"table3": {}, "table2": {}, "table4": {}, "noise": {}, "faithfulness": {}}
    if "table3" in cfg.tables:
        for name in cfg.methods if cfg.methods is not None else registered:
            out["table3"][name] = s(name)
        for name in peer_names:
            out["table3"][name] = Spec("peer", name)
        # the D2NT family as the authors' code computes it (their FD reflects at the image border)
        for name, options in (("d2nt_basic", {"border": "reflect"}), ("d2nt_v2", {}), ("d2nt_v3", {})):
            if name in registered:
                out["faithfulness"][name] = s(name, **options)
    if "table2" in cfg.tables:
        if "d2nt_v2" in registered:
            out["table2"].update({f"D2NT+DAG/{d}": s("d2nt_v2", dlf=d) for d in DLFS})
        if "d2nt_basic" in registered:
            out["table2"].update({f"D2NT+MNR/{d}": s("d2nt_basic+mnr", mnr_dlf=d) for d in DLFS})
        if "d2nt_v3" in registered:
            out["table2"].update({f"D2NT+DAG+MNR/{d}": s("d2nt_v3", mnr_dlf=d) for d in DLFS})
    if "table4" in cfg.tables:
        for paper_name, name in paper.TABLE_IV_METHODS.items():
            if name in registered:
                out["table4"][f"{paper_name}/w/o MNR"] = s(name)
                out["table4"][f"{paper_name}/w/ MNR"] = s(name + "+mnr")
    if "noise" in cfg.tables:
        for name in NOISE_METHODS:
            if name in registered:
                for std in cfg.noise_std:
                    out["noise"][f"{name}/{std:g}"] = s(name, std)
    return out


# ---------------------------------------------------------------------------- frames


def discover(cfg: BenchConfig) -> tuple[list[str], dict[str, str]]:
    """Frame names to evaluate, and {name: reason} for frames that are known to be incomplete.

    A frame is any stem found in an object's ``depth/`` or ``normal/`` folder; one with only
    one of the two is reported as missing the other.
    """
    root = Path(cfg.root)
    names = find_frames(root, levels=cfg.levels, frames_per_object=cfg.frames_per_object)
    problems = {}
    for level in cfg.levels:
        level_dir = root / level
        if not level_dir.is_dir():
            continue
        for obj_dir in sorted(p for p in level_dir.iterdir() if p.is_dir()):
            normal_dir = obj_dir / "normal"
            stems = sorted(p.name[:-4] for p in normal_dir.glob("*.png")) if normal_dir.is_dir() else []
            if cfg.frames_per_object is not None:
                stems = stems[: cfg.frames_per_object]
            for stem in stems:
                name = f"{level}/{obj_dir.name}/{stem}"
                if name not in names:
                    problems[name] = f"missing depth file {obj_dir / 'depth' / (stem + '.bin')}"
    return names, problems


def _noisy(frame, std: float, seed: int) -> np.ndarray:
    """The frame's depth with seeded zero-mean Gaussian noise of ``std`` added to the object (not the background)."""
    if std == 0.0:
        return frame.depth
    rng = np.random.default_rng([seed, zlib.crc32(frame.name.encode()), int(round(std * 1e9))])
    noise = rng.normal(0.0, std, frame.depth.shape).astype(np.float32)
    return np.where(frame.mask, frame.depth + noise, frame.depth).astype(np.float32)


# ---------------------------------------------------------------------------- cache

#: Sources that only present results: editing them does not invalidate cached per-frame results.
_NOT_IN_RESULTS = {"cli.py", "demo.py", "bench/report.py", "bench/figures.py", "bench/paper.py", "bench/__init__.py"}


def code_version() -> str:
    """A hash of surfnorm's source and the peer libraries' versions: cached results from other code are not reused."""
    from .peers import peer_versions

    h = hashlib.sha256()
    pkg = Path(__file__).resolve().parent.parent
    for path in sorted(pkg.rglob("*.py")):
        if path.relative_to(pkg).as_posix() in _NOT_IN_RESULTS:
            continue
        h.update(path.relative_to(pkg).as_posix().encode())
        h.update(path.read_bytes())
    h.update(json.dumps(peer_versions(), sort_keys=True).encode())
    return h.hexdigest()[:16]


class Cache:
    """Per-frame results on disk, one small JSON file each, written atomically."""

    def __init__(self, folder: Path, version: str, root: Path):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.version = version
        self.root = Path(root)

    def _frame_id(self, frame: str) -> str:
        # The frame's files' sizes and times, so an edited dataset is measured again.
        level, obj, stem = frame.split("/")
        parts = []
        for path in sorted((self.root / level / obj).glob(f"*/{stem}.*")) + [self.root / level / obj / "params.txt"]:
            try:
                st = path.stat()
                parts.append(f"{path.name}:{st.st_size}:{st.st_mtime_ns}")
            except OSError:
                parts.append(f"{path.name}:absent")
        return "|".join(parts)

    def path(self, stage: str, frame: str, key: str) -> Path:
        digest = hashlib.sha256(
            "\n".join([stage, frame, key, self.version, self._frame_id(frame)]).encode()
        ).hexdigest()
        return self.folder / f"{stage}-{digest[:24]}.json"

    def get(self, stage, frame, key):
        path = self.path(stage, frame, key)
        try:
            return json.loads(path.read_text())
        except (OSError, ValueError):
            return None

    def put(self, stage, frame, key, record):
        atomic_write(self.path(stage, frame, key), lambda tmp: tmp.write_text(json.dumps(record)))


# ---------------------------------------------------------------------------- accuracy


def _estimate(spec: Spec, depth, frame, peer_runs):
    if spec.kind == "peer":
        return peer_runs[spec.method](depth, frame.K, frame.mask)
    from .._api import estimate

    return estimate(depth, frame.K, method=spec.method, **dict(spec.options))


def _scores(n, frame) -> dict:
    """e_A, e_p and coverage over the object's pixels, from one angular-error map (as in :mod:`surfnorm.metrics`)."""
    err = metrics.angular_error(n, frame.normals)[frame.mask]
    err = err[np.isfinite(err)]  # pixels without an estimate are left out, as metrics.mean_angular_error does
    e_a = float(err.mean()) if err.size else float("nan")
    e_p = {f"{t:g}": (float((err < t).mean()) if err.size else float("nan")) for t in E_P_THRESHOLDS}
    return {"e_a": e_a, "e_p": e_p, "coverage": metrics.coverage(n, frame.mask)}


def _accuracy_one_frame(root: str, frame_name: str, specs: list[Spec], seed: int, peer_names: list[str]) -> dict:
    """Worker: read one frame, make every spec's estimate, return {'records': [...], 'error': str|None}."""
    from .peers import load_peers

    try:
        frame = read_frame(root, frame_name)
    except (SurfnormError, OSError, ValueError) as exc:
        return {"frame": frame_name, "error": f"{type(exc).__name__}: {exc}", "records": []}
    needed = sorted({s.method for s in specs if s.kind == "peer"})
    peer_runs, _ = load_peers(needed) if needed else ({}, {})
    records = []
    for spec in specs:
        rec = {"frame": frame_name, "level": frame.level, "key": spec.key, **asdict(spec)}
        rec["options"] = dict(spec.options)
        try:
            n = _estimate(spec, _noisy(frame, spec.noise_std, seed), frame, peer_runs)
            rec.update(_scores(n, frame))
        except Exception as exc:  # noqa: BLE001 - any failure of one method is reported, never fatal
            rec["error"] = f"{type(exc).__name__}: {exc}"
        records.append(rec)
    return {"frame": frame_name, "error": None, "records": records}


# ---------------------------------------------------------------------------- timing


def _time_one_frame(frame, specs: list[Spec], peer_runs, repeats: int) -> dict[str, dict]:
    """Warm-up call of each spec, then interleaved single-thread calls; {key: {'ms': median, 'calls': n}}."""
    from .._api import estimate

    calls: dict[str, Callable] = {}
    for spec in specs:
        if spec.kind == "peer":
            run = peer_runs[spec.method]
            # the peer's own output, unconverted: its time is its library call
            calls[spec.key] = lambda run=run: run(frame.depth, frame.K, frame.mask, clean=False)
        else:
            opts = dict(spec.options)
            calls[spec.key] = lambda m=spec.method, o=opts: estimate(frame.depth, frame.K, method=m, threads=1, **o)
    times: dict[str, list[float]] = {}
    wanted, errors = {}, {}
    for key, call in calls.items():
        try:
            t0 = time.perf_counter()
            call()
            warm = (time.perf_counter() - t0) * 1e3
            t0 = time.perf_counter()
            call()  # the first call may have compiled; this one tells how slow the method is
            warm = (time.perf_counter() - t0) * 1e3
        except Exception as exc:  # noqa: BLE001
            errors[key] = f"{type(exc).__name__}: {exc}"
            continue
        times[key] = [warm]
        wanted[key] = SLOW_REPEATS if warm > SLOW_MS else repeats
    keys = list(times)
    for r in range(max(wanted.values(), default=0)):
        order = keys[r % len(keys) :] + keys[: r % len(keys)]  # rotate so that no method always goes first
        for key in order:
            if len(times[key]) < wanted[key]:
                t0 = time.perf_counter()
                calls[key]()
                times[key].append((time.perf_counter() - t0) * 1e3)
    out: dict[str, dict] = {k: {"ms": float(np.median(v)), "calls": len(v)} for k, v in times.items()}
    out.update({k: {"error": e} for k, e in errors.items()})
    return out


# ---------------------------------------------------------------------------- the run


class _Clock:
    """Wall time and CPU time (this process and its finished children) since the last lap."""

    def __init__(self):
        self.last = self._now()

    @staticmethod
    def _now():
        import resource

        own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
        return time.perf_counter(), own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime

    def lap(self) -> dict:
        now = self._now()
        out = {"wall_s": round(now[0] - self.last[0], 2), "cpu_s": round(now[1] - self.last[1], 2)}
        self.last = now
        return out


@dataclass
class BenchResult:
    config: dict
    frames: list[str]
    unreadable: dict[str, str]
    experiments: dict[str, dict[str, str]]  # experiment -> {label: spec key}
    accuracy: list[dict]
    timing: list[dict]
    skipped: dict[str, str]
    meta: dict = field(default_factory=dict)


def run_bench(cfg: BenchConfig, *, progress: Callable[[str, int, int], None] | None = None) -> BenchResult:
    """Run the benchmark described by ``cfg``; see :mod:`surfnorm.bench.report` for the files it leads to.

    ``progress(stage, done, total)`` is called as work finishes.
    """
    from ..methods import methods
    from .peers import PEERS, load_peers, single_thread

    registered = list(methods())
    _check_config(cfg, registered)
    progress = progress or (lambda stage, done, total: None)
    threads = single_thread()  # before the peers import, so that OpenMP in them reads it
    libs = PEER_LIBRARIES if cfg.peers is None else cfg.peers
    wanted_peers = [p.name for p in PEERS if p.library in libs]
    peer_runs, skipped = load_peers(wanted_peers)
    peer_names = [n for n in wanted_peers if n in peer_runs]
    exps = experiments(cfg, registered, peer_names)
    specs = list(dict.fromkeys(s for table in exps.values() for s in table.values()))
    needs = {
        "table2": ("d2nt_basic", "d2nt_v2", "d2nt_v3"),
        "table4": tuple(paper.TABLE_IV_METHODS.values()),
        "noise": NOISE_METHODS,
    }
    for table, names in needs.items():
        for name in names:
            if table in cfg.tables and name not in registered:
                skipped.setdefault(name, f"not registered in surfnorm.methods() (needed by {table})")

    frames, unreadable = discover(cfg)
    if not frames:
        found = f"; only frames without depth: {', '.join(list(unreadable)[:3])}" if unreadable else ""
        raise InputError(
            f"dataset: expected frames in the 3F2N layout ({'|'.join(cfg.levels)}/<object>/depth/<frame>.bin), "
            f"found none in {cfg.root}{found}"
        )
    cache = Cache(Path(cfg.out) / "cache", code_version(), cfg.root)

    # accuracy: what is not cached yet, one task per frame
    accuracy: list = []
    todo: dict = {}
    for name in frames:
        for spec in specs:
            rec = cache.get("accuracy", name, spec.key)
            if rec is None:
                todo.setdefault(name, []).append(spec)
            else:
                accuracy.append(rec)
    stages = {}
    clock = _Clock()
    total, done = len(frames), len(frames) - len(todo)
    progress("accuracy", done, total)

    def absorb(result):
        nonlocal done
        if result["error"] is not None:
            unreadable[result["frame"]] = result["error"]
        for rec in result["records"]:
            cache.put("accuracy", rec["frame"], rec["key"], rec)
            accuracy.append(rec)
        done += 1
        progress("accuracy", done, total)

    if cfg.jobs > 1 and len(todo) > 1:
        import multiprocessing

        ctx = multiprocessing.get_context("spawn")  # numba and OpenMP do not survive fork well
        with ProcessPoolExecutor(max_workers=min(cfg.jobs, len(todo)), mp_context=ctx) as pool:
            futures = {
                pool.submit(_accuracy_one_frame, str(cfg.root), n, s, cfg.seed, peer_names): n for n, s in todo.items()
            }
            for fut in as_completed(futures):
                try:
                    absorb(fut.result())
                except Exception as exc:  # noqa: BLE001 - a worker that died (e.g. a crash in a peer library)
                    skipped[f"frame {futures[fut]}"] = f"accuracy worker failed: {type(exc).__name__}: {exc}"
                    absorb({"frame": futures[fut], "error": None, "records": []})
    else:
        for name, s in todo.items():
            absorb(_accuracy_one_frame(str(cfg.root), name, s, cfg.seed, peer_names))

    stages["accuracy"] = clock.lap()
    # timing: Table III rows, one frame at a time, in this process only
    timed = list(exps["table3"].values())
    timing = []
    readable = [n for n in frames if n not in unreadable]
    progress("timing", 0, len(readable))
    for i, name in enumerate(readable):
        recs = {s.key: cache.get("timing", name, f"{s.key}#{cfg.repeats}") for s in timed}
        missing = [s for s in timed if recs[s.key] is None]
        if missing:
            try:
                frame = read_frame(cfg.root, name)
            except (SurfnormError, OSError, ValueError) as exc:
                unreadable[name] = f"{type(exc).__name__}: {exc}"
                continue
            for key, rec in _time_one_frame(frame, missing, peer_runs, cfg.repeats).items():
                rec = {"frame": name, "level": frame.level, "key": key, **rec}
                cache.put("timing", name, f"{key}#{cfg.repeats}", rec)
                recs[key] = rec
        timing += [recs[s.key] for s in timed]
        progress("timing", i + 1, len(readable))

    stages["timing"] = clock.lap()
    for rec in accuracy + timing:
        if "error" in rec:
            skipped.setdefault(rec["key"], f"failed on {rec['frame']}: {rec['error']}")
    config = {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(cfg).items()}
    return BenchResult(
        config=config,
        frames=frames,
        unreadable=dict(sorted(unreadable.items())),
        experiments={e: {label: spec.key for label, spec in t.items()} for e, t in exps.items()},
        accuracy=sorted(accuracy, key=lambda r: (r["frame"], r["key"])),
        timing=sorted(timing, key=lambda r: (r["frame"], r["key"])),
        skipped=skipped,
        meta={"threads": threads, "code_version": cache.version, "jobs": cfg.jobs, "stages": stages},
    )
