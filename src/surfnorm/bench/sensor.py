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

Time: one thread for every library (:func:`surfnorm.bench.peers.single_thread`),
after a warm-up call; a peer's time is its own library call (its conversion to
unit, camera-facing normals is not timed).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .. import metrics
from ..camera import Intrinsics
from ..errors import InputError

__all__ = ["Entry", "VARIANTS", "make_entries", "parse_name", "run_simulated", "sim_tables"]

#: Variants run beside the registered methods' defaults: (method, options).
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


def _value(text: str):
    for conv in (int, float):
        try:
            return conv(text)
        except ValueError:
            pass
    return {"true": True, "false": False}.get(text.lower(), text)


def parse_name(name: str) -> tuple[str, dict]:
    """``"plane_pca:window=11"`` -> ("plane_pca", {"window": 11})."""
    method, *opts = name.strip().split(":")
    options = {}
    for opt in opts:
        key, eq, value = opt.partition("=")
        if not eq or not key:
            raise InputError(f"methods: expected NAME or NAME:option=value[:option=value], got {name!r}")
        options[key.strip()] = _value(value.strip())
    return method, options


def label_of(method: str, options: dict) -> str:
    return method + "".join(f" {k}={v}" for k, v in options.items())


def _surfnorm_entry(method: str, options: dict) -> Entry:
    from .._api import estimate
    from ..methods import resolve

    resolve(method, dict(options))  # a bad name or option is an InputError now, not on the first frame

    def call(depth, cam, valid, method=method, options=dict(options)):
        return estimate(depth, cam, method=method, **options)

    info_summary = f"surfnorm.estimate(method={method!r}" + "".join(f", {k}={v!r}" for k, v in options.items()) + ")"
    return Entry(label_of(method, options), "surfnorm", info_summary, call)


def _peer_entry(peer, run) -> Entry:
    from .peers import clean

    def call(depth, cam, valid, run=run):
        return run(depth, cam, valid, clean=False)

    return Entry(peer.name, "peer", peer.summary, call, clean)


def make_entries(names: list[str] | None = None) -> tuple[list[Entry], dict[str, str]]:
    """The entries for ``names`` (registered methods, ``name:opt=value`` variants, peer keys), default all.

    Returns (entries, {name: why absent}) - a peer whose library does not import is absent.
    Unknown names are an InputError.
    """
    from ..methods import methods
    from .peers import SENSOR_PEERS, load_peers

    registered = list(methods())
    peer_keys = [p.name for p in SENSOR_PEERS]
    if names is None:
        wanted = [(m, {}) for m in registered] + [(m, o) for m, o in VARIANTS if m in registered]
        wanted_peers = peer_keys
    else:
        wanted, wanted_peers = [], []
        for name in names:
            if name in peer_keys:
                wanted_peers.append(name)
                continue
            method, options = parse_name(name)
            base = method[:-4] if method.endswith("+mnr") else method
            if base not in registered:
                raise InputError(f"methods: expected registered methods ({', '.join(registered)}), optionally with "
                                 f":option=value, or peers ({', '.join(peer_keys)}), got {name!r}")
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


# ---------------------------------------------------------------------------- simulated sensors

def run_simulated(root, entries: list[Entry], sensors: list[str], *, levels=None, frames_per_level: int | None = None,
                  seed: int = 0, progress: Callable[[str], None] | None = None) -> dict:
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
        raise InputError(f"root: expected 3F2N frames (Easy|Medium|Hard/<object>/depth/*.bin) of levels "
                         f"{', '.join(levels)}, found none under {root}")
    progress = progress or (lambda msg: None)
    records, errors, warm = [], [], set()
    for name in names:
        frame = read_frame(root, name)
        for s in sensors:
            z = simulate(frame.depth, frame.K, s, seed=frame_seed(seed, name, s), mask=frame.mask, normals=frame.normals)
            valid = z > 0
            scored = frame.mask & valid
            for e in entries:
                try:
                    if e.label not in warm:
                        e.call(z, frame.K, valid)
                        warm.add(e.label)
                    n, ms = _timed(e, z, frame.K, valid)
                except Exception as exc:  # noqa: BLE001 - one entry failing is reported, never fatal
                    errors.append({"sensor": s, "frame": name, "entry": e.label, "error": f"{type(exc).__name__}: {exc}"})
                    continue
                records.append({"sensor": s, "frame": name, "level": frame.level, "entry": e.label,
                                "e_a": metrics.mean_angular_error(n, frame.normals, scored),
                                "coverage": metrics.coverage(n, scored), "ms": ms,
                                "depth_coverage": float(scored.sum() / max(frame.mask.sum(), 1))})
            progress(f"{name} {s}")
    return {"records": records, "errors": errors, "frames": names, "sensors": list(sensors),
            "entries": [e.label for e in entries], "seed": seed}


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
            out.append(f"| {e} | " + " | ".join(cells) + f" | {fmt(_mean([r['e_a'] for r in rows]))} | "
                       f"{fmt(_mean([r['coverage'] for r in rows]), 3)} | "
                       f"{fmt(float(np.median(ms)) if ms else float('nan'), 1)} |")
        dc = _mean([r["depth_coverage"] for r in sel(sensor=s, entry=entries[0])]) if entries else float("nan")
        out.append(f"\nShare of the objects' pixels with depth from {s}: {fmt(dc, 3)}")
    if result["errors"]:
        out.append("\n### failures\n")
        out += [f"- {e['entry']} on {e['frame']} ({e['sensor']}): {e['error']}" for e in result["errors"]]
    return "\n".join(out) + "\n"
