"""surfnorm.batch.cluster: convert on a Dask cluster (issue 8).

One LocalCluster of 2 single-threaded worker processes serves the module. The
tests that need a worker to misbehave (die mid-write, wait for the client)
install a worker plugin that wraps ``surfnorm.batch.tasks.convert_file`` in the
worker processes only; the client's own process and the code under test are
not patched.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

import surfnorm
from surfnorm.batch import ConvertSettings, convert, plan_tasks
from surfnorm.camera import Intrinsics
from surfnorm.errors import InputError, MissingDependencyError

try:
    import distributed
except ImportError:  # pragma: no cover - the shared venv has it
    distributed = None

needs_dask = pytest.mark.skipif(
    distributed is None, reason='dask.distributed is not installed (pip install "surfnorm[dask]")'
)

H, W = 48, 64
N_FILES = 100
CAM = Intrinsics(fx=55.0, fy=55.0, cx=(W - 1) / 2, cy=(H - 1) / 2)
OPTIONS = dict(method="d2nt_v3", fmt="npy", depth_scale=1000.0, intrinsics=CAM)


def depth_mm(seed: int) -> np.ndarray:
    """A tilted plane with a spherical bump, sensor-like noise and holes, as uint16 millimetres."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    z = 1.5 + 0.004 * (u - W / 2) * rng.uniform(0.5, 1.5) + 0.003 * (v - H / 2)
    bump = 0.25 - ((u - rng.uniform(20, 44)) ** 2 + (v - rng.uniform(15, 33)) ** 2) / 400.0
    z = z - np.sqrt(np.clip(bump, 0, None)) * 0.3
    z = z + rng.normal(0, 0.002, z.shape)
    mm = np.rint(z * 1000).astype(np.uint16)
    mm[rng.random(z.shape) < 0.02] = 0  # dropouts
    return mm


def write_inputs(folder: Path, n: int) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i in range(n):
        p = folder / f"d{i:03d}.png"
        assert cv2.imwrite(str(p), depth_mm(i))
        paths.append(p)
    return paths


def listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def expected_names(inputs) -> list[str]:
    return sorted(f"{p.stem}.npy" for p in inputs)


# --- worker-side misbehaviour, installed with a WorkerPlugin ---------------------------------------


class PatchConvertFile(distributed.WorkerPlugin if distributed is not None else object):
    """Worker plugin: wrap ``surfnorm.batch.tasks.convert_file`` in each worker process with ``wrapper(real, task, settings)``."""

    name = "surfnorm-test-patch"

    def __init__(self, wrapper, **params):
        self.wrapper = wrapper
        self.params = params

    def setup(self, worker):
        import functools
        import importlib

        convert = importlib.import_module("surfnorm.batch.tasks")

        real = getattr(convert.convert_file, "__wrapped_real__", convert.convert_file)
        patched = functools.partial(self.wrapper, real, **self.params)
        patched.__wrapped_real__ = real
        convert.convert_file = patched

    def teardown(self, worker):
        import importlib

        convert = importlib.import_module("surfnorm.batch.tasks")

        convert.convert_file = getattr(convert.convert_file, "__wrapped_real__", convert.convert_file)


def die_mid_write(real, task, settings, *, victim, marker=None):
    """Kill this worker process halfway through writing ``victim`` (once if ``marker``, else every time)."""
    if task.input.name == victim and (marker is None or not Path(marker).exists()):
        from surfnorm.io._atomic import atomic_write

        if marker is not None:
            Path(marker).touch()

        def half_write(tmp):
            tmp.write_bytes(b"\x93NUMPY half of a file")
            os._exit(1)  # no finally, no cleanup: as if killed by the OOM killer

        atomic_write(task.output, half_write)
    return real(task, settings)


def wait_for_marker(real, task, settings, *, victim, marker, seconds):
    """Hold ``victim`` until the client has seen a result (``marker`` exists); note whether it had to give up."""
    if task.input.name == victim:
        deadline = time.monotonic() + seconds
        while not Path(marker).exists() and time.monotonic() < deadline:
            time.sleep(0.01)
        if not Path(marker).exists():
            Path(marker + ".timeout").touch()
    return real(task, settings)


# --- fixtures ---------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def client():
    if distributed is None:  # pragma: no cover
        pytest.skip('dask.distributed is not installed (pip install "surfnorm[dask]")')
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0")
    c = distributed.Client(cluster)
    yield c
    c.close()
    cluster.close()


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    return write_inputs(tmp_path_factory.mktemp("depth"), N_FILES)


@pytest.fixture(scope="module")
def local_outputs(inputs, tmp_path_factory):
    """The local path's outputs: the reference every cluster run must match byte for byte."""
    out = tmp_path_factory.mktemp("local")
    results = convert(inputs, out, **OPTIONS).results
    assert sorted(r.status for r in results) == ["written"] * N_FILES
    return out


@pytest.fixture
def patched(client):
    installed = []

    def install(wrapper, **params):
        plugin = PatchConvertFile(wrapper, **params)
        client.register_plugin(plugin, name=PatchConvertFile.name)
        installed.append(plugin)

    allowed = client.run_on_scheduler(_get_allowed_failures)
    yield install
    if installed:
        client.unregister_worker_plugin(PatchConvertFile.name)
    client.run_on_scheduler(_set_allowed_failures, allowed)


def _get_allowed_failures(dask_scheduler=None):
    return dask_scheduler.allowed_failures


def _set_allowed_failures(n, dask_scheduler=None):
    dask_scheduler.allowed_failures = n


def assert_same_bytes(out: Path, reference: Path, inputs):
    assert listing(out) == expected_names(inputs)  # nothing extra: no temporaries, no duplicates
    for name in expected_names(inputs):
        assert (out / name).read_bytes() == (reference / name).read_bytes(), name


# --- acceptance 1: a 2-worker LocalCluster writes what the local path writes ----------------------


@pytest.mark.slow
@needs_dask
def test_cluster_outputs_identical_to_local(client, inputs, local_outputs, tmp_path):
    seen = []
    results = convert(inputs, tmp_path, client=client, progress=seen.append, **OPTIONS).results
    assert_same_bytes(tmp_path, local_outputs, inputs)
    assert sorted(r.status for r in results) == ["written"] * N_FILES
    assert sorted(r.input.name for r in seen) == sorted(p.name for p in inputs)  # every file reported once


@needs_dask
def test_rerun_skips_finished_outputs(client, inputs, local_outputs, tmp_path):
    convert(inputs[:30], tmp_path, client=client, **OPTIONS)
    before = {p.name: p.stat().st_mtime_ns for p in tmp_path.iterdir()}
    results = convert(inputs, tmp_path, client=client, shard_size=7, **OPTIONS).results
    status = {r.input.name: r.status for r in results}
    assert [status[p.name] for p in inputs] == ["skipped"] * 30 + ["written"] * 70
    assert {n: (tmp_path / n).stat().st_mtime_ns for n in before} == before  # not rewritten
    assert_same_bytes(tmp_path, local_outputs, inputs)


@needs_dask
def test_bad_input_is_one_error_and_the_rest_go_on(client, inputs, local_outputs, tmp_path):
    corrupt = tmp_path / "in" / "d999.png"
    corrupt.parent.mkdir()
    corrupt.write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    out = tmp_path / "out"
    results = convert([*inputs[:20], corrupt], out, client=client, shard_size=4, **OPTIONS).results
    errors = [r for r in results if r.status == "error"]
    assert [r.input for r in errors] == [corrupt]
    assert "d999.png" in errors[0].message
    assert_same_bytes(out, local_outputs, inputs[:20])


@needs_dask
def test_results_stream_back_as_shards_finish(client, inputs, patched, tmp_path):
    """The last file waits until the client has handled a result: a run that gathered everything at the end would stall."""
    marker = str(tmp_path / "client-saw-a-result")
    patched(wait_for_marker, victim=inputs[-1].name, marker=marker, seconds=20.0)
    seen = []

    def progress(result):
        seen.append(result)
        Path(marker).touch()

    t0 = time.monotonic()
    run_on = tmp_path / "out"
    convert(inputs, run_on, client=client, shard_size=10, progress=progress, **OPTIONS)
    assert not Path(marker + ".timeout").exists()  # the client saw a result while the last file was still waiting
    assert time.monotonic() - t0 < 20.0
    assert sorted(r.input.name for r in seen) == sorted(p.name for p in inputs)


# --- acceptance 2: a worker killed mid-shard loses nothing -----------------------------------------


@pytest.mark.slow
@needs_dask
def test_worker_killed_mid_write_loses_nothing(client, inputs, local_outputs, patched, tmp_path):
    marker = tmp_path / "killed-once"
    out = tmp_path / "out"
    # shard 4 is d040..d049: the worker writes d040 and d041, then dies halfway through writing d042
    patched(die_mid_write, victim="d042.png", marker=str(marker))
    results = convert(inputs, out, client=client, shard_size=10, **OPTIONS).results
    assert marker.exists()  # a worker really died
    status = {r.input.name: r.status for r in results}
    assert len(results) == N_FILES and len(status) == N_FILES
    assert "error" not in status.values()
    # the retried shard found the two files the dead attempt had finished, and did not redo them
    assert status["d040.png"] == status["d041.png"] == "skipped"
    assert status["d042.png"] == "written"
    assert_same_bytes(out, local_outputs, inputs)  # no half file, no temporary left, nothing extra
    # the nanny restarted the worker
    client.wait_for_workers(2, timeout=30)


@pytest.mark.slow
@needs_dask
def test_file_that_kills_every_worker_is_one_error(client, inputs, local_outputs, patched, tmp_path):
    client.run_on_scheduler(_set_allowed_failures, 0)  # give up on a task after one worker death (default 3)
    out = tmp_path / "out"
    patched(die_mid_write, victim="d013.png")
    few = inputs[:20]
    results = convert(few, out, client=client, shard_size=5, **OPTIONS).results
    errors = [r for r in results if r.status == "error"]
    assert [r.input.name for r in errors] == ["d013.png"]
    assert "worker process died" in errors[0].message and "d013.png" in errors[0].message
    rest = [p for p in few if p.name != "d013.png"]
    assert_same_bytes(out, local_outputs, rest)  # d013's temporaries were swept too
    client.wait_for_workers(2, timeout=30)


def raise_on(real, task, settings, *, victim):
    """An exception that escapes convert_file, as a worker without surfnorm's dependencies would raise."""
    if task.input.name == victim:
        raise RuntimeError("simulated failure outside convert_file")
    return real(task, settings)


@pytest.mark.slow
@needs_dask
def test_exception_escaping_convert_file_is_that_files_error(client, inputs, local_outputs, patched, tmp_path):
    patched(raise_on, victim="d006.png")
    out = tmp_path / "out"
    results = convert(inputs[:10], out, client=client, shard_size=5, **OPTIONS).results
    status = [r.status for r in results]
    # the shard d005..d009 raised after writing d005; its files were run again one per task
    assert status == ["written"] * 5 + ["skipped", "error"] + ["written"] * 3
    assert (
        results[6].message == f"{inputs[6]}: failed on a worker: RuntimeError: simulated failure outside convert_file"
    )
    rest = [p for p in inputs[:10] if p.name != "d006.png"]
    assert_same_bytes(out, local_outputs, rest)


# --- shard size, temporaries, errors ---------------------------------------------------------------


def test_default_shard_size():
    from surfnorm.batch.cluster import MAX_SHARD, MIN_SHARD, default_shard_size

    assert default_shard_size(100, 2) == 13  # ceil(100 / (4 shards x 2 threads))
    assert default_shard_size(10, 2) == MIN_SHARD
    assert default_shard_size(10**6, 64) == MAX_SHARD
    assert default_shard_size(1000, 0) == MAX_SHARD  # an adaptive cluster may start with no workers


@pytest.mark.parametrize("bad", [0, -3, 2.5, True, "8"])
def test_bad_shard_size(bad):
    from surfnorm.batch.cluster import run_on_dask

    with pytest.raises(InputError, match=r"shard_size: expected a positive whole number, got"):
        run_on_dask([], ConvertSettings(), client=None, on_result=print, shard_size=bad)


def test_missing_dask_says_how_to_install(monkeypatch, inputs, tmp_path):
    from surfnorm.batch.cluster import cluster_client, run_on_dask

    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    hint = r'pip install "surfnorm\[dask\]"'
    tasks = plan_tasks(inputs[:3], tmp_path, "npy")
    with pytest.raises(MissingDependencyError, match=hint) as info:
        run_on_dask(tasks, ConvertSettings(), client=object(), on_result=print)
    assert isinstance(info.value, ImportError)
    with pytest.raises(MissingDependencyError, match=hint):
        convert(inputs[:3], tmp_path / "out", client=object(), **OPTIONS)
    assert listing(tmp_path / "out") == []  # nothing was converted on the side
    with pytest.raises(MissingDependencyError, match=hint):
        with cluster_client(local_workers=2):
            pass


def test_import_surfnorm_does_not_import_dask():
    code = "import sys, surfnorm, surfnorm.batch; print(sorted(m for m in ('dask', 'distributed') if m in sys.modules))"
    env = dict(os.environ, PYTHONPATH=str(Path(surfnorm.__file__).parents[1]))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert out.stdout.strip() == "[]"


@needs_dask
def test_cluster_client_refuses_both_or_neither():
    from surfnorm.batch.cluster import cluster_client

    with pytest.raises(InputError, match="expected exactly one of address= and local_workers="):
        with cluster_client():
            pass
    with pytest.raises(InputError, match="expected exactly one of address= and local_workers="):
        with cluster_client("tcp://127.0.0.1:8786", local_workers=2):
            pass
    with pytest.raises(InputError, match="local_workers: expected a positive whole number, got 0"):
        with cluster_client(local_workers=0):
            pass


@pytest.mark.slow
@needs_dask
def test_cluster_client_unreachable_address():
    from surfnorm.batch.cluster import cluster_client

    with pytest.raises(ConnectionError, match=r"cluster address 'tcp://127.0.0.1:9': no Dask scheduler answered there"):
        with cluster_client("tcp://127.0.0.1:9", timeout=1.0):
            pass


# --- the command line -------------------------------------------------------------------------------


def cli(*args):
    from typer.testing import CliRunner

    from surfnorm.cli import app

    result = CliRunner().invoke(app, [str(a) for a in args])
    assert "Traceback" not in result.output, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    return result


# the same method as OPTIONS (the local reference), named: the default would decide per frame
CAMERA_FLAGS = [
    "--depth-scale",
    "1000",
    "--fx",
    CAM.fx,
    "--fy",
    CAM.fy,
    "--cx",
    CAM.cx,
    "--cy",
    CAM.cy,
    "-m",
    "d2nt_v3",
]


@needs_dask
def test_cli_cluster_address(client, inputs, local_outputs, tmp_path):
    out = tmp_path / "out"
    result = cli(
        "convert",
        inputs[0].parent / "d00*.png",
        out,
        *CAMERA_FLAGS,
        "--cluster",
        client.scheduler.address,
        "--shard-size",
        3,
    )
    assert result.exit_code == 0, result.output
    assert "10 written, 0 skipped (output existed), 0 failed" in result.stdout
    assert_same_bytes(out, local_outputs, inputs[:10])


@pytest.mark.slow
@needs_dask
def test_cli_local_cluster(inputs, local_outputs, tmp_path):
    out = tmp_path / "out"
    result = cli("convert", inputs[0].parent / "d01*.png", out, *CAMERA_FLAGS, "--local-cluster", 1)
    assert result.exit_code == 0, result.output
    assert_same_bytes(out, local_outputs, inputs[10:20])


@pytest.mark.parametrize(
    "args, message",
    [
        (
            ["--cluster", "tcp://127.0.0.1:9", "--local-cluster", 2],
            "--cluster and --local-cluster: expected one of them, got both",
        ),
        (["--local-cluster", 2, "--jobs", 2], "--jobs: a local process pool and a Dask cluster are alternatives"),
        (["--shard-size", 8], "--shard-size: applies to a Dask run; add --cluster ADDRESS or --local-cluster N"),
        (["--local-cluster", 2, "--shard-size", 0], "--shard-size: expected a positive integer, got 0"),
        (["--local-cluster", 0], "local_workers: expected a positive whole number, got 0"),
    ],
)
def test_cli_usage_errors(inputs, tmp_path, args, message):
    result = cli("convert", inputs[0], tmp_path / "out", *CAMERA_FLAGS, *args)
    assert result.exit_code == 2
    assert message in " ".join(result.stderr.split())


@pytest.mark.slow
@needs_dask
def test_cli_unreachable_cluster(inputs, tmp_path):
    import dask

    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        result = cli("convert", inputs[0], tmp_path / "out", *CAMERA_FLAGS, "--cluster", "tcp://127.0.0.1:9")
    assert result.exit_code == 2
    assert "cluster address 'tcp://127.0.0.1:9': no Dask scheduler answered there" in " ".join(result.stderr.split())


@pytest.mark.slow
def test_cli_without_dask_says_how_to_install(monkeypatch, inputs, tmp_path):
    monkeypatch.setitem(sys.modules, "distributed", None)
    for option in (["--cluster", "tcp://127.0.0.1:8786"], ["--local-cluster", 2]):
        result = cli("convert", inputs[0], tmp_path / "out", *CAMERA_FLAGS, *option)
        assert result.exit_code == 2
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and 'pip install "surfnorm[dask]"' in lines[0], result.stderr
