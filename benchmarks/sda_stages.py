"""SDA-SNE per stage, this checkout against an earlier revision, interleaved in one process.

    NUMBA_NUM_THREADS=1 PYTHONPATH=src python benchmarks/sda_stages.py [--old REV] [--runs N] [--cpu]

The old ``sda.py`` (default: 6a2f4c0, before the speed work) is taken with ``git show`` into a
temporary directory and imported beside the current one; both run the same stages on the 12 frames
of the 3F2N sample (tests/data/3f2n-sample, all pixels valid, the defaults: 3 iterations, CP2TV), alternately,
after a warm-up. Prints medians in ms per stage and of the whole ``sda_sne`` call, and of
``surfnorm.estimate(z, K, method="sda_sne")``. ``--cpu`` times with the thread's CPU clock, steadier
than the wall clock on a shared machine. Also checks that both give the same bits.
"""

import argparse
import inspect
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import surfnorm  # noqa: E402
from surfnorm._validate import valid_map  # noqa: E402
from surfnorm.io.threef2n import find_frames, read_frame  # noqa: E402
from surfnorm.kernels import sda as new  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "tests" / "data" / "3f2n-sample"
STAGES = ["alloc", "laplacians", "init", "step 1", "step 2", "step 3", "cp2tv"]


def load_old(rev):
    text = subprocess.run(
        ["git", "show", f"{rev}:src/surfnorm/sda.py"], cwd=ROOT, check=True, capture_output=True, text=True
    ).stdout
    text = (
        text.replace("from ._config import", "from surfnorm._config import")
        .replace("from .three_filters import", "from surfnorm.kernels.three_filters import")
        .replace("from ._choices import", "from surfnorm._choices import")
    )
    folder = tempfile.mkdtemp(prefix="sda-old-")
    Path(folder, "sda_old.py").write_text(text)
    sys.path.insert(0, folder)
    import sda_old

    return sda_old


def stages(mod, z, valid, cam, clock):
    """The stages of ``sda_sne`` (defaults), as ``_run_sda`` and ``sda_sne`` call them."""
    P = mod._P
    t = [clock()]
    shape = (z.shape[0] + 2 * P, z.shape[1] + 2 * P)
    inner = (slice(P, -P), slice(P, -P))
    s = np.zeros(shape)
    s[inner] = np.where(valid, z.astype(np.float64), 0.0)
    ok = np.zeros(shape, dtype=np.bool_)
    ok[inner] = valid
    a_u, a_v = mod._padded(shape, np.float64, np.inf), mod._padded(shape, np.float64, np.inf)
    con = mod._padded(shape, np.uint8, 0)
    sets = [
        [
            mod._padded(shape, np.float64, 0.0),
            mod._padded(shape, np.float64, 0.0),
            mod._padded(shape, np.float64, np.inf),
            mod._padded(shape, np.float64, np.inf),
            mod._padded(shape, np.int8, -1),
            mod._padded(shape, np.int8, -1),
        ]
        for _ in range(2)
    ]
    l_u, l_v = np.ones(shape), np.ones(shape)
    t.append(clock())
    # Kernels since the scale-invariant near-tie tolerance take it after these arguments (None: exact, the default).
    tol = (None,) if "tol" in inspect.signature(mod._sda_step.py_func).parameters else ()
    # Kernels since the row bands (one frame on several threads) take the rows to compute; here all of them.
    banded = "v0" in inspect.signature(mod._sda_step.py_func).parameters
    rows, padded_rows = ((0, z.shape[0]), (1, shape[0] - 1)) if banded else ((), ())
    mod._sda_laplacians(s, ok, *tol, l_u, l_v, a_u, a_v, *padded_rows)
    t.append(clock())
    mod._sda_init(s, ok, False, *tol, l_u, l_v, a_u, a_v, con, *sets[0], *rows)
    t.append(clock())
    cur = 0
    for i in range(1, 4):
        mod._sda_step(s, ok, 1.0 / (i + 1), *tol, a_u, a_v, con, *sets[cur], *sets[1 - cur], *rows)
        cur = 1 - cur
        t.append(clock())
    out = np.empty(z.shape + (3,), np.float32)
    (getattr(mod, "_gradients_to_normals_kernel", None) or mod._cp2tv_kernel)(
        s, *sets[cur][:4], cam.fx, cam.fy, cam.cx, cam.cy, np.float32(0), out, *rows
    )
    t.append(clock())
    return np.diff(t) * 1e3


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--old", default="6a2f4c0")
    parser.add_argument("--runs", type=int, default=30)
    parser.add_argument("--cpu", action="store_true")
    args = parser.parse_args()
    clock = time.thread_time if args.cpu else time.perf_counter
    old = load_old(args.old)
    frames = [read_frame(SAMPLE, name) for name in find_frames(SAMPLE)]
    valid = [valid_map(f.depth, None) for f in frames]
    mods = {"old": old, "new": new}

    def call(mod, f, v):
        out = np.empty(f.depth.shape + (3,), np.float32)
        return mod.sda_sne(f.depth, v, f.K, out)

    for f, v in zip(frames, valid):  # compile, and compare the bits
        assert np.array_equal(call(old, f, v), call(new, f, v)), f.name
    whole = {k: [] for k in ["old", "new", "estimate"]}
    per_stage = {"old": [], "new": []}
    for _ in range(args.runs):
        for f, v in zip(frames, valid):
            for key, mod in mods.items():
                t0 = clock()
                call(mod, f, v)
                whole[key].append(clock() - t0)
                per_stage[key].append(stages(mod, f.depth, v, f.K, clock))
            t0 = clock()
            surfnorm.estimate(f.depth, f.K, method="sda_sne")
            whole["estimate"].append(clock() - t0)
    print(
        f"{len(frames)} frames x {args.runs} runs, {'CPU' if args.cpu else 'wall'} clock, medians in ms, "
        f"load average {os.getloadavg()[0]:.1f}"
    )
    for key in ("old", "new"):
        m = np.median(np.array(per_stage[key]), axis=0)
        print(
            f"{key:4s} "
            + "  ".join(f"{n} {x:.2f}" for n, x in zip(STAGES, m))
            + f"  | sda_sne {np.median(whole[key]) * 1e3:.2f}"
        )
    print(
        f"surfnorm.estimate(z, K, method='sda_sne'): {np.median(whole['estimate']) * 1e3:.2f}; "
        f"old / new sda_sne: {np.median(whole['old']) / np.median(whole['new']):.2f}"
    )


if __name__ == "__main__":
    main()
