"""Batch conversion: planning, one file, many files, the CLI, and issue 6 acceptance 3 (200 PNGs, kill and restart)."""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import time
import types
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

import surfnorm
from surfnorm import Intrinsics
from surfnorm.batch import ConvertSettings, ConvertTask, FileResult, convert, convert_file, plan_tasks
from surfnorm.cli import app
from surfnorm.errors import InputError
from surfnorm.io import read_depth, read_normals

CAM = Intrinsics(60.0, 60.0, 31.5, 23.5)
CAM_ARGS = ["--fx", "60", "--fy", "60", "--cx", "31.5", "--cy", "23.5"]
SRC = str(Path(surfnorm.__file__).resolve().parent.parent)


def depth_png(path: Path, seed: int, h=48, w=64):
    """A 16-bit millimetre depth image of a tilted, bumpy surface with a few holes."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:h, 0:w]
    z = 1500 + 4 * u + 2 * v + 30 * np.sin(u / 5.0 + seed) + rng.integers(0, 3, (h, w))
    z[rng.random((h, w)) < 0.02] = 0
    assert cv2.imwrite(str(path), z.astype(np.uint16))
    return path


def corrupt(path: Path, how: int):
    data = path.read_bytes()
    if how == 0:
        path.write_bytes(data[: len(data) // 2])  # truncated
    elif how == 1:
        path.write_bytes(b"")  # empty
    elif how == 2:
        path.write_bytes(data[:40] + b"\x00" * 200 + data[240:])  # damaged chunk
    elif how == 3:
        cv2.imwrite(str(path), np.zeros((48, 64, 3), np.uint8))  # a colour picture, not depth
    else:
        path.write_bytes(b"not a png at all")


def temporaries(folder: Path):
    return sorted(p.name for p in folder.rglob(".*") if ".tmp" in p.name)


def expected_normals(path, **kw):
    return surfnorm.estimate(read_depth(path, depth_scale=1000), CAM, **kw)


def cli(*args):
    result = CliRunner().invoke(app, [str(a) for a in args])
    assert "Traceback" not in result.output, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    return result


# ---------------------------------------------------------------------------- planning


def test_plan_folder_is_recursive_deterministic_and_keeps_subfolders(tmp_path):
    for rel in ("b.png", "a.npy", "sub/c.tif", "sub/deeper/d.bin.gz", "notes.txt", ".hidden.png", ".git/x.png"):
        p = tmp_path / "in" / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(b"x")
    tasks = plan_tasks(tmp_path / "in", tmp_path / "out", "png16")
    assert [(t.input.relative_to(tmp_path), t.output.relative_to(tmp_path)) for t in tasks] == [
        (Path("in/a.npy"), Path("out/a.png")),
        (Path("in/b.png"), Path("out/b.png")),
        (Path("in/sub/c.tif"), Path("out/sub/c.png")),
        (Path("in/sub/deeper/d.bin.gz"), Path("out/sub/deeper/d.png")),
    ]
    assert plan_tasks(str(tmp_path / "in"), tmp_path / "out", "png16") == tasks


def test_plan_glob_and_list(tmp_path):
    for rel in ("s1/depth/0001.png", "s1/depth/0002.png", "s2/depth/0001.png", "s2/rgb/0001.png"):
        p = tmp_path / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(b"x")
    tasks = plan_tasks(str(tmp_path / "s*" / "depth" / "*.png"), tmp_path / "out")
    assert [t.output.relative_to(tmp_path / "out") for t in tasks] == [
        Path("s1/depth/0001.npy"),
        Path("s1/depth/0002.npy"),
        Path("s2/depth/0001.npy"),
    ]
    listed = plan_tasks([tmp_path / "s1/depth/0002.png", str(tmp_path / "s1/depth/0001.png")], tmp_path / "out")
    assert [t.output.name for t in listed] == ["0002.npy", "0001.npy"]
    with pytest.raises(InputError, match=r"inputs: .*0001.png and .*0001.png would both be written to .*0001.npy"):
        plan_tasks([tmp_path / "s1/depth/0001.png", tmp_path / "s2/depth/0001.png"], tmp_path / "out")


def test_plan_errors(tmp_path):
    (tmp_path / "a.npy").write_bytes(b"x")
    with pytest.raises(InputError, match=r"output_dir: writing .*a.npy would replace its input"):
        plan_tasks([tmp_path / "a.npy"], tmp_path, "npy")
    with pytest.raises(
        InputError,
        match=r"output_dir: expected a folder other than the input folder .*, got .*; "
        r"its outputs would be read as inputs by the next run",
    ):
        plan_tasks(tmp_path, tmp_path, "png16")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match=r"inputs: expected at least one depth file, found none in .*empty"):
        plan_tasks(tmp_path / "empty", tmp_path / "out")
    with pytest.raises(
        InputError,
        match=r"inputs: expected a depth file, a folder or a glob pattern, got '.*nope', which does not exist",
    ):
        plan_tasks(tmp_path / "nope", tmp_path / "out")
    with pytest.raises(InputError, match=r"inputs: expected paths in the list, got int 3"):
        plan_tasks([3], tmp_path / "out")
    with pytest.raises(InputError, match=r"fmt: expected one of 'npy', 'png16', 'png8', 'ply', got 'exr'"):
        plan_tasks(tmp_path, tmp_path / "out", "exr")


def test_outputs_inside_the_input_folder_are_not_inputs(tmp_path):
    depth_png(tmp_path / "a.png", 0)
    summary = convert(tmp_path, tmp_path / "normals", intrinsics=CAM, depth_scale=1000)
    assert summary.written == 1
    again = convert(tmp_path, tmp_path / "normals", intrinsics=CAM, depth_scale=1000)
    assert [r.status for r in again.results] == ["skipped"]


def test_unlistable_input_folder_and_unwritable_output(tmp_path, monkeypatch):
    mod = sys.modules["surfnorm.batch.tasks"]

    depth_png(tmp_path / "a.png", 0)
    real = os.access
    monkeypatch.setattr(mod.os, "access", lambda p, mode: False if str(p).startswith(str(tmp_path)) else real(p, mode))
    with pytest.raises(InputError, match=r"inputs: cannot list the folder .* \(Permission denied\)"):
        plan_tasks(tmp_path, tmp_path / "out")
    with pytest.raises(InputError, match=r"output_dir: cannot write into .*out \(Permission denied\)"):
        convert([tmp_path / "a.png"], tmp_path / "out", intrinsics=CAM)


# ---------------------------------------------------------------------------- one file


def test_convert_file_statuses_and_determinism(tmp_path):
    src = depth_png(tmp_path / "d.png", 1)
    settings = ConvertSettings(fmt="png16", depth_scale=1000.0, intrinsics=CAM)
    pickle.loads(pickle.dumps(settings))  # goes to worker processes and Dask
    a = convert_file(ConvertTask(src, tmp_path / "a" / "d.png"), settings)
    b = convert_file(ConvertTask(src, tmp_path / "b" / "d.png"), settings)
    assert (a.status, b.status) == ("written", "written")
    assert (tmp_path / "a/d.png").read_bytes() == (tmp_path / "b/d.png").read_bytes()
    assert convert_file(ConvertTask(src, tmp_path / "a" / "d.png"), settings) == FileResult(
        src, tmp_path / "a/d.png", "skipped", "output exists"
    )
    again = convert_file(
        ConvertTask(src, tmp_path / "a" / "d.png"), ConvertSettings(**{**settings.__dict__, "overwrite": True})
    )
    assert again.status == "written"
    back = read_normals(tmp_path / "a/d.png", fill=0.0)
    n = expected_normals(src)
    assert np.abs(back - n).max() < 4e-5


@pytest.mark.parametrize("how", range(5))
def test_convert_file_never_raises_for_a_bad_file(tmp_path, how):
    src = depth_png(tmp_path / "bad.png", 0)
    corrupt(src, how)
    result = convert_file(ConvertTask(src, tmp_path / "out.npy"), ConvertSettings(intrinsics=CAM))
    assert result.status == "error" and str(src) in result.message
    assert not (tmp_path / "out.npy").exists() and temporaries(tmp_path) == []


def test_convert_file_other_errors_are_named(tmp_path):
    src = depth_png(tmp_path / "d.png", 0)
    (tmp_path / "taken.npy").mkdir()
    r = convert_file(ConvertTask(src, tmp_path / "taken.npy"), ConvertSettings(intrinsics=CAM))
    assert r.status == "error" and r.message == f"{src}: output {tmp_path / 'taken.npy'} exists and is a folder"
    r = convert_file(ConvertTask(tmp_path / "gone.png", tmp_path / "o.npy"), ConvertSettings(intrinsics=CAM))
    assert r.status == "error" and "gone.png: cannot read depth file (No such file or directory)" in r.message
    r = convert_file(ConvertTask(src, tmp_path / "o.npy"), ConvertSettings(intrinsics=None))
    assert r.status == "error" and "intrinsics: none given and no 3F2N params.txt beside" in r.message
    (tmp_path / "afile").write_text("x")
    r = convert_file(ConvertTask(src, tmp_path / "afile" / "o.npy"), ConvertSettings(intrinsics=CAM))
    assert r.status == "error" and r.message.startswith(f"{src}: cannot write")
    z = np.zeros((8, 8), np.float32)
    np.save(tmp_path / "zeros.npy", z)
    r = convert_file(ConvertTask(tmp_path / "zeros.npy", tmp_path / "z_out.npy"), ConvertSettings(intrinsics=CAM))
    assert r.status == "written" and r.message == "no valid depth: every pixel holds the fill value"


def test_3f2n_files_use_their_params(tmp_path):
    from surfnorm.io.threef2n import read_frame, sample_root

    summary = convert(str(sample_root() / "Easy" / "*" / "depth" / "*"), tmp_path, method="d2nt_v2")
    assert summary.written == 1 and summary.ok
    frame = read_frame(sample_root(), "Easy/android/000001")
    np.testing.assert_array_equal(
        np.load(tmp_path / "android/depth/000001.npy"), surfnorm.estimate(frame.depth, frame.K, method="d2nt_v2")
    )


def test_convert_arguments_are_checked_once(tmp_path):
    depth_png(tmp_path / "d.png", 0)
    with pytest.raises(InputError, match=r"method: expected one of"):
        convert(tmp_path, tmp_path / "o", method="nope", intrinsics=CAM)
    with pytest.raises(InputError, match=r"options of method 'd2nt_v2': .*unknown option\(s\) tua"):
        convert(tmp_path, tmp_path / "o", method="d2nt_v2", intrinsics=CAM, tua=2.0)
    with pytest.raises(InputError, match=r"jobs: expected a positive integer, got 0"):
        convert(tmp_path, tmp_path / "o", intrinsics=CAM, jobs=0)
    with pytest.raises(InputError, match=r"depth_scale: expected a positive finite number, got -1"):
        convert(tmp_path, tmp_path / "o", intrinsics=CAM, depth_scale=-1)
    with pytest.raises(
        InputError,
        match=r"intrinsics: expected --intrinsics FILE or --fx --fy --cx --cy \(no 3F2N params.txt beside .*d.png\)",
    ):
        convert(tmp_path, tmp_path / "o")
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match=r"output_dir: expected a folder, got the file .*file"):
        convert(tmp_path, tmp_path / "file", intrinsics=CAM)


def test_options_reach_the_estimator(tmp_path):
    src = depth_png(tmp_path / "d.png", 2)
    convert(
        [src],
        tmp_path / "o",
        method="d2nt_v2",
        intrinsics=CAM.matrix,
        depth_scale=1000,
        dlf="gamma",
        fill=np.nan,
        scale_invariant=True,
    )
    np.testing.assert_array_equal(
        np.load(tmp_path / "o/d.npy"),
        expected_normals(src, method="d2nt_v2", dlf="gamma", fill=np.nan, scale_invariant=True),
    )


def test_front_door_function():
    assert surfnorm.convert is convert and callable(surfnorm.convert)


def test_dask_client_is_handed_the_tasks(tmp_path, monkeypatch):
    srcs = [depth_png(tmp_path / f"{i}.png", i) for i in range(3)]
    calls = []

    def run_on_dask(tasks, settings, client, on_result, *, shard_size=None):
        calls.append((list(tasks), settings, client, shard_size))
        for t in tasks[:2]:  # the fake cluster loses the last task
            on_result(convert_file(t, settings))

    monkeypatch.setitem(sys.modules, "surfnorm.batch.cluster", types.SimpleNamespace(run_on_dask=run_on_dask))
    seen = []
    client = types.SimpleNamespace(submit=lambda *a, **k: None, nthreads=lambda: {})  # what convert checks a client has
    summary = convert(
        srcs, tmp_path / "o", intrinsics=CAM, depth_scale=1000, client=client, progress=seen.append, shard_size=5
    )
    assert calls[0][2] is client and len(calls[0][0]) == 3 and calls[0][1].depth_scale == 1000
    assert calls[0][3] == 5
    assert [r.status for r in summary.results] == ["written", "written", "error"]
    assert summary.errors[0].message.endswith("2.png: no result from the Dask cluster")
    assert len(seen) == 2


# ---------------------------------------------------------------------------- acceptance 3


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    """200 generated 16-bit PNGs, 5 of them corrupt."""
    folder = tmp_path_factory.mktemp("batch")
    bad = {17: 0, 58: 1, 99: 2, 140: 3, 181: 4}
    for i in range(200):
        p = depth_png(folder / f"frame_{i:03d}.png", i)
        if i in bad:
            corrupt(p, bad[i])
    return folder, sorted(folder / f"frame_{i:03d}.png" for i in bad)


@pytest.mark.slow
def test_200_pngs_with_5_corrupt(batch, tmp_path):
    folder, bad = batch
    out = tmp_path / "out"
    result = cli("convert", folder, out, *CAM_ARGS, "--depth-scale", "1000", "--jobs", "2")
    assert result.exit_code == 1, result.output
    text = result.output.replace("\n", " ")
    assert "195 written, 0 skipped (output existed), 5 failed" in text
    for p in bad:
        assert f"error: {p}" in text.replace(" ", "").replace("error:", "error: ") or str(p) in text
        assert not (out / (p.stem + ".npy")).exists()
    outputs = sorted(out.iterdir())
    assert len(outputs) == 195 and temporaries(out) == []
    for o in outputs:
        np.testing.assert_array_equal(np.load(o), expected_normals(folder / (o.stem + ".png")))
    # the library reports the same, in order, with the bad files named
    summary = convert(folder, tmp_path / "lib", intrinsics=CAM, depth_scale=1000, jobs=2)
    assert summary.written == 195 and [Path(r.input) for r in summary.errors] == bad
    assert all(str(r.input) in r.message for r in summary.errors)
    # a re-run skips the 195 and names the 5 again
    again = cli("convert", folder, out, *CAM_ARGS, "--depth-scale", "1000")
    assert again.exit_code == 1 and "0 written, 195 skipped (output existed), 5 failed" in again.output.replace(
        "\n", " "
    )


def _interrupt(command, env, out: Path, at_least: int, sig) -> subprocess.CompletedProcess:
    """Start the CLI, send ``sig`` to it and its workers once ``at_least`` outputs exist, wait for it.

    The CLI gets Ctrl-C's default action even where this process ignores it (a shell's background job does, and
    Python then installs no KeyboardInterrupt handler: the CLI ran to its end), and runs at a lower priority than
    this process, so that its workers, busy on every core, cannot keep this watcher from seeing the outputs.
    """

    def child():
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        os.nice(10)

    proc = subprocess.Popen(
        command,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=child,
    )
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if out.is_dir() and sum(1 for p in out.iterdir() if not p.name.startswith(".")) >= at_least:
                break
            time.sleep(0.005)
        os.killpg(proc.pid, sig)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    return subprocess.CompletedProcess(command, proc.returncode, stdout, stderr)


@pytest.mark.slow
def test_interrupted_and_killed_mid_run_then_restarted_finishes_every_output(tmp_path):
    folder = tmp_path / "in"
    folder.mkdir()
    for i in range(300):
        depth_png(folder / f"{i:03d}.png", i)
    out = tmp_path / "out"
    command = [
        sys.executable,
        "-c",
        "import sys; from surfnorm.cli import app; sys.argv[0] = 'surfnorm'; app()",
        "convert",
        str(folder),
        str(out),
        *CAM_ARGS,
        "--depth-scale",
        "1000",
        "--jobs",
        "2",
        "--format",
        "png16",
    ]
    env = {**os.environ, "PYTHONPATH": SRC}

    def finished():
        return [p for p in out.iterdir() if not p.name.startswith(".")]

    # Ctrl-C: stops promptly with a one-line message, exit 130
    first = _interrupt(command, env, out, 10, signal.SIGINT)
    assert first.returncode == 130, first.stderr
    assert "interrupted: finished outputs are complete; run the same command again" in first.stderr
    assert "Traceback" not in first.stderr + first.stdout
    after_int = len(finished())
    assert 10 <= after_int < 300
    # kill -9 of the CLI and its workers at once
    second = _interrupt(command, env, out, after_int + 10, signal.SIGKILL)
    assert second.returncode == -signal.SIGKILL, "the run finished before it could be killed"
    done_before = finished()
    assert after_int + 10 <= len(done_before) < 300
    (out / ".123.png.abc_12.tmp.png").write_bytes(b"half a png")  # as a kill during a write leaves it
    rerun = subprocess.run(command, env=env, capture_output=True, text=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr
    assert "Traceback" not in rerun.stderr + rerun.stdout
    assert f"{300 - len(done_before)} written, {len(done_before)} skipped" in rerun.stdout.replace("\n", " ")
    assert temporaries(out) == []
    outputs = sorted(out.iterdir())
    assert len(outputs) == 300
    for o in outputs[::7] + done_before:  # every output decodes and equals a fresh estimate
        n = read_normals(o, fill=0.0)
        assert np.abs(n - expected_normals(folder / o.name)).max() < 4e-5


# ---------------------------------------------------------------------------- CLI happy paths


def test_cli_estimate_writes_what_the_library_computes(tmp_path):
    import json

    src = depth_png(tmp_path / "d.png", 4)
    (tmp_path / "cam.json").write_text(json.dumps({"fx": 60, "fy": 60, "cx": 31.5, "cy": 23.5}))
    mask = (np.arange(48 * 64).reshape(48, 64) % 5 != 0).astype(np.uint8) * 255
    cv2.imwrite(str(tmp_path / "mask.png"), mask)
    r = cli(
        "estimate",
        src,
        tmp_path / "n",
        "--intrinsics",
        tmp_path / "cam.json",
        "--depth-scale",
        "1000",
        "--mask",
        tmp_path / "mask.png",
        "--scale-invariant",
        "--method",
        "d2nt_v2",
    )
    assert r.exit_code == 0, r.output
    expected = expected_normals(src, method="d2nt_v2", mask=mask > 0, scale_invariant=True)
    np.testing.assert_array_equal(np.load(tmp_path / "n.npy"), expected)
    assert cv2.imread(str(tmp_path / "n.png")).dtype == np.uint8
    r = cli("estimate", src, tmp_path / "m", *CAM_ARGS, "--depth-scale", "1000", "--format", "png16")
    assert r.exit_code == 0 and not (tmp_path / "m.npy").exists()
    assert np.abs(read_normals(tmp_path / "m.png") - expected_normals(src)).max() < 4e-5


def test_cli_estimate_disparity(tmp_path):
    d = np.full((20, 30), 12.5, np.float32)
    d[5, 5] = 0
    np.save(tmp_path / "disp.npy", d)
    r = cli("estimate", tmp_path / "disp.npy", tmp_path / "n", *CAM_ARGS, "--disparity", "--format", "npy")
    assert r.exit_code == 0, r.output
    n = np.load(tmp_path / "n.npy")
    assert (n[5, 5] == 0).all() and np.allclose(n[10, 15], [0, 0, -1], atol=1e-6)


def test_cli_convert_with_intrinsics_file_and_png8(tmp_path):
    import json

    (tmp_path / "in").mkdir()
    for i in range(3):
        depth_png(tmp_path / "in" / f"{i}.png", i)
    (tmp_path / "cam.json").write_text(json.dumps({"K": CAM.matrix.tolist()}))
    r = cli(
        "convert", tmp_path / "in", tmp_path / "out", "-k", tmp_path / "cam.json", "--depth-scale", "1000", "-f", "png8"
    )
    assert r.exit_code == 0, r.output
    assert "3 written, 0 skipped (output existed), 0 failed" in r.output.replace("\n", " ")
    pic = cv2.imread(str(tmp_path / "out" / "1.png"), cv2.IMREAD_UNCHANGED)
    assert pic.dtype == np.uint8 and pic.shape == (48, 64, 3)
