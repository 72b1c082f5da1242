"""Killed runs: `surfnorm convert` (one process, --jobs 2, a 2-worker local Dask cluster) killed with
SIGKILL at random moments leaves no partial output and no process behind, and a rerun completes with
the bytes of a clean run (issue 14, defect 8 and acceptance 4).

Each mode is a chain: a run is killed once a random number of outputs exist (0 included: a kill during
start-up) plus a random delay, the next run resumes the same output folder, and a last run finishes it.
After every kill: each output present is byte-identical to the clean run's (temporary files may stay;
the next run removes them), and every process of the run is gone within 5 s. 10 kills in all; the seed
is fixed, so a failure reproduces (SURFNORM_KILL_VERBOSE=1 with -s prints each kill).
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

import surfnorm
from surfnorm import Intrinsics
from surfnorm.batch import convert

SRC = str(Path(surfnorm.__file__).resolve().parent.parent)
CAM = Intrinsics(300.0, 300.0, 159.5, 119.5)
CAM_ARGS = ["--fx", "300", "--fy", "300", "--cx", "159.5", "--cy", "119.5", "--depth-scale", "1000"]
N_FILES = 60
GRACE_S = 5.0


def _depth_png(path: Path, seed: int, h=240, w=320):
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:h, 0:w]
    z = 1500 + 4 * u + 2 * v + 30 * np.sin(u / 5.0 + seed) + rng.integers(0, 3, (h, w))
    z[rng.random((h, w)) < 0.02] = 0
    assert cv2.imwrite(str(path), z.astype(np.uint16))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """N_FILES depth images and the outputs of a clean run (in this process), by name."""
    root = tmp_path_factory.mktemp("kill")
    folder = root / "in"
    folder.mkdir()
    for i in range(N_FILES):
        _depth_png(folder / f"{i:03d}.png", i)
    clean = root / "clean"
    summary = convert(folder, clean, intrinsics=CAM, depth_scale=1000)
    assert summary.written == N_FILES
    return folder, {p.name: p.read_bytes() for p in clean.iterdir()}


def _session(sid: int) -> list[str]:
    """The processes of session ``sid`` (the run and everything it started), as 'pid command' lines."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_bytes()
            fields = stat.rsplit(b")", 1)[1].split()
            if int(fields[3]) == sid and fields[0] != b"Z":
                command = (entry / "cmdline").read_bytes().replace(b"\0", b" ")[:120].decode(errors="replace")
                found.append(f"{entry.name} {command}")
        except (OSError, IndexError, ValueError):
            continue
    return found


def _outputs(out: Path) -> list[Path]:
    return [p for p in out.iterdir() if not p.name.startswith(".")] if out.is_dir() else []


def _kill_at_random(command, out: Path, rng: random.Random) -> tuple[int, list[str]]:
    """Run ``command`` in its own session, SIGKILL its main process once a random number of outputs exist
    (plus up to 50 ms), and return (outputs at the kill, processes of the run still alive GRACE_S later)."""
    before = len(_outputs(out))
    target = rng.randint(before, before + (N_FILES - before) // 3)  # early enough that the run is still going
    env = {**os.environ, "PYTHONPATH": SRC}
    proc = subprocess.Popen(
        command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and proc.poll() is None and len(_outputs(out)) < target:
            time.sleep(0.002)
        time.sleep(rng.uniform(0.0, 0.05))
        proc.kill()  # SIGKILL of the main process only: it cannot clean up, its children must notice
        proc.wait()
        at_kill = len(_outputs(out))
        deadline = time.monotonic() + GRACE_S
        while _session(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.1)
        left = _session(proc.pid)
        if os.environ.get("SURFNORM_KILL_VERBOSE"):
            print(f"kill at {at_kill} outputs (target {target}), left: {left}")
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)  # never leave them running, whatever the test says
        except ProcessLookupError:
            pass
    return at_kill, left


MODES = {
    "local": ([], 4),
    "jobs2": (["--jobs", "2"], 4),
    "dask": (["--local-cluster", "2"], 2),
}


@pytest.mark.slow
@pytest.mark.parametrize("mode", list(MODES))
def test_killed_at_random_moments_then_rerun_gives_the_clean_bytes(dataset, tmp_path, mode):
    if mode == "dask":
        pytest.importorskip("distributed")
    folder, clean = dataset
    extra, kills = MODES[mode]
    out = tmp_path / "out"
    command = [
        sys.executable,
        "-c",
        "import sys; from surfnorm.cli import app; sys.argv[0] = 'surfnorm'; app()",
        "convert",
        str(folder),
        str(out),
        *CAM_ARGS,
        *extra,
    ]
    rng = random.Random(f"surfnorm-kill-{mode}")
    for trial in range(kills):
        at_kill, left = _kill_at_random(command, out, rng)
        assert at_kill < N_FILES, f"{mode} kill {trial}: the run finished before it could be killed"
        assert left == [], f"{mode} kill {trial} (at {at_kill} outputs): alive {GRACE_S} s after SIGKILL: {left}"
        for p in _outputs(out):  # no partial output: what exists is complete and final
            assert p.read_bytes() == clean[p.name], f"{mode} kill {trial}: {p.name} differs from the clean run"
    rerun = subprocess.run(command, env={**os.environ, "PYTHONPATH": SRC}, capture_output=True, text=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr
    assert sorted(p.name for p in out.iterdir()) == sorted(clean), "missing outputs or temporary files left"
    for name, data in clean.items():
        assert (out / name).read_bytes() == data, name
