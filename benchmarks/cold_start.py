"""First-call time of every method in a fresh virtual environment: fresh, cached and precompiled.

    python benchmarks/cold_start.py [--wheel dist/surfnorm-*.whl] [--runs 3] [--methods d2nt_v3 sda_sne]
                                    [--out bench-output]

Builds a wheel of this checkout (or takes ``--wheel``), creates a new virtual
environment (``python -m venv``) and installs the wheel into it with pip (its
dependencies from the configured index). Neither step is timed. Then, for each
method, it times whole processes ``python -c "import surfnorm; surfnorm.estimate(depth, K, method=...)"``
on a 480x640 frame with holes, as a new user would run them, and the default method also on sensor-like
depth (noisy, quantised: its other path):

- fresh: nothing that Numba's JIT compiled anywhere (the package's ``__pycache__/*.nbi|*.nbc`` and the
  user-wide Numba cache are emptied before each run); what the wheel holds (its kernels compiled ahead
  of time, see ``src/surfnorm/_aot.py``) stays, as it does in a new install;
- cached: the same process again, with the cache that the previous run left;
- precompiled: after one ``python -m surfnorm.precompile`` of the timed methods (when the installed
  version has it) from an empty cache, as in an image build; that step is timed too.

Each figure is the median over ``--runs`` processes (the spread is in the JSON). The
default method (``surfnorm.estimate``'s default at run time) is marked. Every process prints a
digest of its normals: a row's fresh, cached and precompiled processes must agree (the AOT code
and the JIT's give the same bits). Writes
``cold-start.md`` and ``cold-start.json`` into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

FIRST_CALL = """
import hashlib, numpy as np, surfnorm
h, w = 480, 640
v, u = np.mgrid[0:h, 0:w]
z = (2.0 + 0.002 * u + 0.001 * v).astype(np.float32)
if {noisy!r}:  # sensor-like depth (noise 5 mm, quantised to 1 mm): auto runs adaptive_fit
    z = np.round((z + np.random.default_rng(0).normal(0, 0.005, z.shape)) * 1000).astype(np.float32) / 1000
z[::7, ::11] = 0.0
K = [[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]]
n = surfnorm.estimate(z, K, method={method!r})
assert n.shape == (h, w, 3)
print(hashlib.sha256(n.tobytes()).hexdigest())
"""

#: The default method's row on sensor depth (its other path), beside every method on clean depth.
SENSOR = " (sensor depth)"

LIST = (
    "import inspect, json, surfnorm; print(json.dumps([list(surfnorm.methods()), "
    "inspect.signature(surfnorm.estimate).parameters['method'].default]))"
)


def build_wheel(dest: Path) -> Path:
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(dest), str(REPO)], check=True)
    return next(dest.glob("surfnorm-*.whl"))


def make_venv(root: Path, wheel: Path) -> Path:
    subprocess.run([sys.executable, "-m", "venv", str(root)], check=True)
    py = root / "bin" / "python"
    subprocess.run([str(py), "-m", "pip", "install", "-q", str(wheel)], check=True)
    return py


def package_dir(py: Path) -> Path:
    out = subprocess.run(
        [str(py), "-c", "import surfnorm, os; print(os.path.dirname(surfnorm.__file__))"],
        check=True,
        capture_output=True,
        text=True,
    )
    return Path(out.stdout.strip())


def clear_caches(pkg: Path, user_cache: Path) -> None:
    for path in list(pkg.rglob("*.nbi")) + list(pkg.rglob("*.nbc")):
        path.unlink()
    shutil.rmtree(user_cache, ignore_errors=True)
    user_cache.mkdir(parents=True)


DIGESTS: dict[str, set] = {}


def timed(cmd, env, row=None) -> tuple[float, float]:
    """(wall, CPU) seconds of one process: CPU time (user + system) is what compilation costs, and on a
    shared machine it moves less with the load than the wall-clock time does. The digest of the normals that a
    first call printed goes into DIGESTS[row] (one digest per row: the same bits however the kernels came)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run(cmd, check=True, env=env, stdout=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if row is not None and done.stdout.strip():
        DIGESTS.setdefault(row, set()).add(done.stdout.split()[-1])
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def fmt(runs) -> str:
    """Median wall and CPU seconds of (wall, cpu) pairs: "wall (cpu)"."""
    if not runs:
        return "-"
    return f"{statistics.median(w for w, _ in runs):.2f} ({statistics.median(c for _, c in runs):.2f})"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--wheel", type=Path, help="the wheel to install (default: build one of this checkout)")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--methods", nargs="*", help="methods to time (default: every registered one)")
    ap.add_argument("--out", type=Path, default=REPO / "bench-output")
    ap.add_argument("--label", default="", help="a name for this build in the table (e.g. before, after)")
    args = ap.parse_args(argv)

    with tempfile.TemporaryDirectory(prefix="surfnorm-cold-") as tmp:
        tmp = Path(tmp)
        wheel = args.wheel or build_wheel(tmp / "dist")
        py = make_venv(tmp / "venv", wheel)
        pkg = package_dir(py)
        user_cache = tmp / "numba-cache"
        # A new user's environment: no NUMBA_CACHE_DIR of ours unless the package directory is read-only
        # (then Numba falls back to its user-wide cache, pointed here so that it can be emptied).
        env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
        env["NUMBA_CACHE_DIR"] = str(user_cache)
        names, default = json.loads(
            subprocess.run([str(py), "-c", LIST], check=True, capture_output=True, text=True, env=env).stdout
        )
        has_precompile = (
            subprocess.run([str(py), "-c", "import surfnorm.precompile"], env=env, capture_output=True).returncode == 0
        )
        methods = args.methods or names
        rows = {}
        labels = [n for m in methods for n in ([m, m + SENSOR] if m == default else [m])]

        def first_call(label):
            method = label.removesuffix(SENSOR)
            return [str(py), "-c", FIRST_CALL.format(method=method, noisy=label.endswith(SENSOR))]

        for name in labels:
            rows[name] = {"fresh_s": [], "cached_s": [], "precompiled_s": []}
            for _ in range(args.runs):
                clear_caches(pkg, user_cache)
                rows[name]["fresh_s"].append(timed(first_call(name), env, name))
                rows[name]["cached_s"].append(timed(first_call(name), env, name))
            print(f"{name:16s} " + "  ".join(f"{k[:-2]} {fmt(v)} s" for k, v in rows[name].items() if v), flush=True)
        # Precompiled: one `python -m surfnorm.precompile` (every method and variant, as in an image build) from
        # an empty cache, then the first call of each method.
        precompile_step = []
        for _ in range(args.runs if has_precompile else 0):
            clear_caches(pkg, user_cache)
            precompile_step.append(timed([str(py), "-m", "surfnorm.precompile", "--quiet", *methods], env))
            for name in labels:
                rows[name]["precompiled_s"].append(timed(first_call(name), env, name))
        if precompile_step:
            print(f"python -m surfnorm.precompile (these methods): {fmt(precompile_step)} s", flush=True)
        clear_caches(pkg, user_cache)

    lines = [
        f"First call in a new virtual environment ({args.label or wheel.name}), whole process, "
        f"median of {args.runs} runs, seconds of wall-clock time (CPU time); default method: {default}; "
        f"load average at the end {' '.join(f'{x:.1f}' for x in os.getloadavg())}",
        "",
        "| method | fresh | cached | precompiled | same bits in every run |",
        "|---|---|---|---|---|",
    ]
    for name, r in rows.items():
        mark = " (default)" if name.removesuffix(SENSOR) == default else ""
        same = "yes" if len(DIGESTS.get(name, ())) == 1 else f"NO ({len(DIGESTS.get(name, ()))} digests)"
        lines.append(
            f"| {name}{mark} | {fmt(r['fresh_s'])} | {fmt(r['cached_s'])} | {fmt(r['precompiled_s'])} | {same} |"
        )
    if precompile_step:
        lines += [
            "",
            f"`python -m surfnorm.precompile {' '.join(methods)}` from an empty cache: {fmt(precompile_step)}",
        ]
    table = "\n".join(lines)
    print(table)
    args.out.mkdir(parents=True, exist_ok=True)
    stem = "cold-start" + (f"-{args.label}" if args.label else "")
    (args.out / f"{stem}.md").write_text(table + "\n")
    (args.out / f"{stem}.json").write_text(
        json.dumps(
            {
                "label": args.label,
                "wheel": wheel.name,
                "default": default,
                "runs": args.runs,
                "methods": rows,
                "digests": {k: sorted(v) for k, v in DIGESTS.items()},
                "precompile_step_s": precompile_step,
                "python": sys.version.split()[0],
                "machine": platform.processor() or platform.machine(),
                "cpus": os.cpu_count(),
                "loadavg": os.getloadavg(),
            },
            indent=1,
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
