"""Issue 27 (reliability II): never replace an input, every magnitude, caches that load, hostile files and folders."""

import numpy as np
import pytest
from typer.testing import CliRunner

from surfnorm.cli import app

runner = CliRunner()
CAMERA = ["--fx", "525", "--fy", "525", "--cx", "31.5", "--cy", "23.5"]


def _plane(h=48, w=64):
    v, u = np.mgrid[0:h, 0:w]
    return 1.0 + 0.002 * u + 0.001 * v


def _one_line_exit_2(args, needle=""):
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 2, (args, result.output)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), (args, result.stderr)
    assert needle in lines[0], (args, lines[0])
    return lines[0]


# ---------------------------------------------------------------------------- row 1: never replace an input


@pytest.fixture
def frames(tmp_path, monkeypatch):
    import cv2

    z = np.rint(_plane() * 1000).astype(np.uint16)
    cv2.imwrite(str(tmp_path / "frame.png"), z)
    np.save(tmp_path / "d.npy", _plane().astype(np.float32))
    cv2.imwrite(str(tmp_path / "m.png"), np.full(z.shape, 255, np.uint8))
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.mark.parametrize(
    "args",
    [
        ["frame.png", "frame", "--depth-scale", "1000"],  # frame.png: the png8 picture's name
        ["frame.png", "frame", "--depth-scale", "1000", "--overwrite"],  # --overwrite never replaces an input
        ["d.npy", "d"],  # d.npy: the float32 normals' name
        ["d.npy", "d", "--overwrite", "-f", "npy"],
        ["d.npy", "m", "--mask", "m.png", "--overwrite"],  # the mask is read too
    ],
)
def test_estimate_never_replaces_a_file_it_reads(frames, args):
    before = {p.name: p.read_bytes() for p in frames.iterdir()}
    line = _one_line_exit_2(["estimate", *args, *CAMERA], "output:")
    assert "reads" in line
    assert {p.name: p.read_bytes() for p in frames.iterdir()} == before  # nothing written, nothing replaced


def test_estimate_refuses_an_existing_output_unless_overwrite(frames):
    (frames / "out.png").write_bytes(b"precious")
    line = _one_line_exit_2(["estimate", "d.npy", "out", *CAMERA], "out.png exists")
    assert "--overwrite" in line
    assert (frames / "out.png").read_bytes() == b"precious" and not (frames / "out.npy").exists()
    result = runner.invoke(app, ["estimate", "d.npy", "out", *CAMERA, "--overwrite"])
    assert result.exit_code == 0, result.output
    assert (frames / "out.png").read_bytes() != b"precious" and np.load(frames / "out.npy").shape == (48, 64, 3)


def test_estimate_refuses_an_output_that_links_to_its_input(frames):
    (frames / "link.npy").symlink_to(frames / "d.npy")
    before = (frames / "d.npy").read_bytes()
    _one_line_exit_2(["estimate", "d.npy", "link", "-f", "npy", "--overwrite", *CAMERA], "reads")
    assert (frames / "d.npy").read_bytes() == before


# ---------------------------------------------------------------------------- row 2: depth of any magnitude

K = [[525.0, 0, 31.5], [0, 525.0, 23.5], [0, 0, 1]]
MAGNITUDES = [2.0**-200, 1e-60, 1e-43, 1e-39, 1e39, 1e60, 2.0**200]


def _surface():
    v, u = np.mgrid[0:48, 0:64]
    return 1.0 + 0.002 * u + 0.001 * v + 0.0003 * np.sin(u / 3.0) * np.cos(v / 4.0)


def _method_names():
    import surfnorm

    return list(surfnorm.methods())


@pytest.mark.parametrize("mode", ["faithful", "scale_invariant", "disparity"])
@pytest.mark.parametrize("method", _method_names())
def test_float64_depth_of_any_magnitude_gives_what_it_gives_at_one(method, mode):
    import surfnorm

    kw = {"scale_invariant": True} if mode == "scale_invariant" else {"disparity": True} if mode == "disparity" else {}
    depth = 1.0 / _surface() if mode == "disparity" else _surface()
    ref = surfnorm.estimate(depth, K, method=method, **kw)
    assert not (ref == 0).all(axis=-1).any()
    for s in MAGNITUDES:
        n = surfnorm.estimate(depth * s, K, method=method, **kw)
        filled = (n == 0).all(axis=-1)
        assert not filled.any(), (s, filled.mean())  # never silent fill
        assert np.abs(n - ref).mean() < 2e-3, (s, np.abs(n - ref).max())


@pytest.mark.slow
@pytest.mark.parametrize("method", _method_names())
def test_both_backends_agree_at_any_magnitude(method):
    torch = pytest.importorskip("torch")
    import surfnorm
    import surfnorm.torch as st

    if not surfnorm.methods()[method].torch:  # its registry entry declares no torch twin (tests/test_torch.py)
        pytest.skip(f"{method} has no torch twin (torch=False)")

    for s in (1.0, 1e-60, 1e-39, 1e39, 1e60):
        depth = _surface() * s
        n = surfnorm.estimate(depth, K, method=method)
        t = st.estimate(torch.tensor(depth), torch.tensor(K), method=method)[0].permute(1, 2, 0).numpy()
        assert not (t == 0).all(axis=-1).any(), s
        assert np.abs(n - t).mean() < 2e-3, (s, np.abs(n - t).max())


# ---------------------------------------------------------------------------- row 3: caches that load

# Runs the given calls of surfnorm.estimate in a new process and prints, as JSON, the kernels that Numba compiled
# (its "numba:compile" event fires only where the disk cache had nothing to load) and a checksum of the normals.
_CALLS = r"""
import json, sys
import numpy as np
from numba.core import event
import surfnorm

compiled = []


class Listener(event.Listener):
    def on_start(self, ev):
        compiled.append(ev.data["dispatcher"].py_func.__qualname__)

    def on_end(self, ev):
        pass


event.register("numba:compile", Listener())
K = [[525.0, 0, 31.5], [0, 525.0, 23.5], [0, 0, 1]]
v, u = np.mgrid[0:80, 0:64]
z = 1.0 + 0.002 * u + 0.001 * v + 0.0003 * np.sin(u / 3.0) * np.cos(v / 4.0)
total = 0.0
for method, kw in json.loads(sys.argv[1]):
    for depth in (z, z.astype(np.float32), np.stack([z, z])):
        total += float(np.nansum(surfnorm.estimate(depth, K, method=method, threads=2, **kw)))
for depth in (z, z.astype(np.float32)):
    total += float(np.nansum(surfnorm.refine(surfnorm.estimate(depth, K, method="cp2tv"), depth)))
print(json.dumps({"compiled": compiled, "total": total}))
"""


def _run_calls(calls, env=None):
    import json
    import os
    import subprocess
    import sys

    env = {**os.environ, "SURFNORM_AOT": "0", **(env or {})}  # the JIT's kernels, not the ahead-of-time ones
    done = subprocess.run(
        [sys.executable, "-c", _CALLS, json.dumps(calls)], capture_output=True, text=True, env=env, timeout=1800
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def _variants():
    import surfnorm

    calls = []
    for name in surfnorm.methods():
        calls += [[name, {}], [name, {"scale_invariant": True}], [name + "+mnr", {}]]
    calls += [["sda_sne", {"base": "3f2n"}], ["sda_sne", {"border": "reflect", "iterations": None}]]
    calls += [["d2nt_v3", {"disparity": True}]]
    return calls


@pytest.mark.slow
def test_every_method_loads_from_the_disk_cache_in_a_new_process():
    calls = _variants()
    _run_calls(calls)  # compiles what no earlier process left in the cache
    second = _run_calls(calls)
    assert second["compiled"] == [], second["compiled"]


@pytest.mark.slow
def test_a_damaged_cache_recompiles_instead_of_failing(tmp_path):
    import math

    calls = [["sda_sne", {}]]
    env = {"NUMBA_CACHE_DIR": str(tmp_path)}
    first = _run_calls(calls, env)
    indexes = list(tmp_path.rglob("*.nbi"))
    assert indexes and first["compiled"]
    for index in indexes:  # damaged index files (a crashed or concurrent writer), and truncated data files
        index.write_bytes(index.read_bytes()[:40] + b"\x00garbage")
    for data in tmp_path.rglob("*.nbc"):
        data.write_bytes(data.read_bytes()[:100])
    second = _run_calls(calls, env)  # recompiles, and repairs the index
    assert math.isclose(second["total"], first["total"], rel_tol=0, abs_tol=1e-6) and second["compiled"]
    third = _run_calls(calls, env)
    assert third["compiled"] == [] and math.isclose(third["total"], first["total"], rel_tol=0, abs_tol=1e-6)


# ---------------------------------------------------------------------------- row 6: a header that lies about its size


@pytest.fixture
def lying_npy(tmp_path):
    import zipfile

    path = tmp_path / "big.npy"
    with open(path, "wb") as fh:  # 1 KB whose header claims (100000, 100000) float32: 37 GiB
        np.lib.format.write_array_header_1_0(fh, {"descr": "<f4", "fortran_order": False, "shape": (100000, 100000)})
        fh.write(b"\0" * 900)
    with zipfile.ZipFile(tmp_path / "big.npz", "w") as archive:
        archive.write(path, "depth.npy")
    return path


@pytest.mark.parametrize("reader", ["depth", "depth_npz", "mask", "normals"])
def test_a_npy_header_that_claims_more_than_the_file_holds_is_a_data_file_error(lying_npy, reader):
    from surfnorm.errors import DataFileError
    from surfnorm.io import read_depth, read_normals
    from surfnorm.io.depth import read_mask

    read = {
        "depth": lambda: read_depth(lying_npy),
        "depth_npz": lambda: read_depth(lying_npy.with_suffix(".npz")),
        "mask": lambda: read_mask(lying_npy),
        "normals": lambda: read_normals(lying_npy),
    }[reader]
    with pytest.raises(
        DataFileError,
        match=r"big\.np[yz]: cannot read as NumPy .*\(truncated or corrupt: .*\(100000, 100000\).*37\.3 GiB",
    ):
        read()


def test_cli_a_lying_npy_header_is_one_line_exit_2(lying_npy, monkeypatch):
    monkeypatch.chdir(lying_npy.parent)
    _one_line_exit_2(["estimate", "big.npy", "out", *CAMERA], "big.npy: cannot read as NumPy")
    np.save(lying_npy.parent / "d.npy", _plane())
    _one_line_exit_2(["estimate", "d.npy", "out", "--mask", "big.npy", *CAMERA], "big.npy: cannot read as NumPy")


# ---------------------------------------------------------------------------- row 7: a window wider than the frame


@pytest.mark.slow
@pytest.mark.parametrize("method", ["plane_pca", "plane_svd", "vector_svd"])
def test_a_window_wider_than_the_frame_is_clipped_to_it(method):
    import surfnorm

    z = _surface()  # 48 x 64: a window of 2 * 64 - 1 = 127 holds the whole frame from any pixel
    widest = surfnorm.estimate(z, K, method=method, window=129)
    assert not (widest == 0).all(axis=-1).any()
    for window in (127, 4001, 1000001):
        assert np.array_equal(surfnorm.estimate(z, K, method=method, window=window), widest), window


@pytest.mark.slow
@pytest.mark.parametrize("method", ["plane_pca", "plane_svd", "vector_svd"])
def test_a_window_wider_than_the_frame_is_clipped_in_torch_too(method):
    torch = pytest.importorskip("torch")
    import surfnorm.torch as st

    z = torch.tensor(_surface())
    widest = st.estimate(z, torch.tensor(K), method=method, window=129)
    assert torch.equal(st.estimate(z, torch.tensor(K), method=method, window=1000001), widest)


# ---------------------------------------------------------------------------- row 8: intrinsics per frame


def test_a_mixed_list_of_intrinsics_per_frame_is_checked_and_used():
    import surfnorm
    from surfnorm import Intrinsics

    stack = np.stack([_surface()] * 3)
    cam = Intrinsics(fx=525.0, fy=525.0, cx=31.5, cy=23.5)
    n = surfnorm.estimate(stack, [cam, K, np.asarray(K)], method="d2nt_basic", threads=2)
    assert np.array_equal(n, surfnorm.estimate(stack, K, method="d2nt_basic"))
    with pytest.raises(surfnorm.InputError, match=r"K\[2\]: expected a 3x3 intrinsic matrix"):
        surfnorm.estimate(stack, [cam, K, np.eye(4)], method="d2nt_basic", threads=2)
    with pytest.raises(surfnorm.InputError, match=r"K\[1\]: expected a 3x3 matrix of real numbers"):
        surfnorm.estimate(stack, [cam, "K", K], method="d2nt_basic", threads=2)
    with pytest.raises(
        surfnorm.InputError,
        match=r"^K: expected a 3x3 matrix, \(3, 3, 3\) matrices or one Intrinsics per frame, got a ragged list$",
    ):
        surfnorm.estimate(stack, [K, [[1, 2], [3]], K], method="d2nt_basic", threads=2)


# ---------------------------------------------------------------------------- row 4: another run's temporaries


def test_cleanup_of_stale_temporaries_leaves_another_live_runs_file_in_flight(tmp_path):
    from surfnorm.batch.tasks import ConvertTask, remove_stale_temporaries
    from surfnorm.io._atomic import atomic_write

    out = tmp_path / "b1.npy"
    task = ConvertTask(tmp_path / "b1.png", out)
    stale = tmp_path / ".b1.npy.k1ll3d_x.tmp.npy"  # as a killed run leaves it: nobody holds it
    stale.write_bytes(b"half")
    seen = []

    def write(tmp):
        tmp.write_bytes(b"first part")
        seen.append(remove_stale_temporaries([task]))  # a second run starting now, into the same folder
        assert tmp.exists()
        with open(tmp, "ab") as fh:
            fh.write(b", second part")

    atomic_write(out, write)
    assert out.read_bytes() == b"first part, second part"
    assert seen == [1] and not stale.exists()  # the killed run's file went, the live one stayed
    assert [p.name for p in tmp_path.iterdir()] == ["b1.npy"]


# ---------------------------------------------------------------------------- row 5: a long but legal name


def test_an_output_whose_temporary_name_would_be_too_long_is_written(tmp_path):
    import cv2

    from surfnorm.io import write_normals

    stem = "s" * 240  # 240.npy is a legal name (244 bytes); ".<name>.<random>.tmp.npy" was not
    n = np.zeros((4, 5, 3), np.float32)
    n[..., 2] = -1
    for fmt, suffix in (("npy", ".npy"), ("png16", ".png"), ("png8", ".png")):
        path = write_normals(tmp_path / (stem + suffix), n, fmt=fmt)
        assert path.exists()
    src = tmp_path / "in"
    src.mkdir()
    cv2.imwrite(str(src / (stem + ".png")), np.rint(_plane() * 1000).astype(np.uint16))
    result = runner.invoke(app, ["convert", str(src), str(tmp_path / "out"), "--depth-scale", "1000", *CAMERA])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "out" / (stem + ".npy")).exists()
    result = runner.invoke(app, ["estimate", str(src / (stem + ".png")), str(tmp_path / ("t" * 240)), *CAMERA])
    assert result.exit_code == 0, result.output
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_a_shortened_temporary_is_still_cleaned_up_when_stale(tmp_path):
    from surfnorm.batch.tasks import ConvertTask, remove_stale_temporaries
    from surfnorm.io._atomic import temporary_affixes

    out = tmp_path / ("s" * 240 + ".npy")
    prefix, suffix = temporary_affixes(out)
    assert len((prefix + "abcd1234" + suffix).encode()) <= 255 and prefix.endswith("~.")
    stale = tmp_path / (prefix + "abcd1234" + suffix)
    stale.write_bytes(b"half")
    assert remove_stale_temporaries([ConvertTask(tmp_path / "x.png", out)]) == 1 and not stale.exists()


# ---------------------------------------------------------------------------- row 10: hostile folders


@pytest.mark.parametrize("as_glob", [False, True])
def test_convert_names_every_input_it_could_not_read(tmp_path, as_glob):
    import cv2

    src = tmp_path / "in"
    src.mkdir()
    cv2.imwrite(str(src / "a.png"), np.rint(_plane() * 1000).astype(np.uint16))
    (src / "b.png").symlink_to(src / "gone.png")  # dangling
    (src / "c.png").symlink_to(src / "c.png")  # a loop
    inputs = str(src / "*.png") if as_glob else str(src)
    result = runner.invoke(app, ["convert", inputs, str(tmp_path / "out"), "--depth-scale", "1000", *CAMERA])
    assert result.exit_code == 1, result.output
    assert "1 written, 0 skipped (output existed), 2 failed" in result.output.replace("\n", " "), result.output
    assert "b.png: cannot read depth file (No such file or directory)" in result.stderr
    assert "c.png: cannot read depth file (Too many levels of symbolic links)" in result.stderr


# ---------------------------------------------------------------------------- row 11: the system's reason, our names


def test_an_output_in_a_missing_folder_names_the_output_not_the_temporary(frames):
    line = _one_line_exit_2(["estimate", "d.npy", "/no/such/dir/o", *CAMERA], "cannot write /no/such/dir/o.npy")
    assert "(No such file or directory)" in line and ".tmp" not in line


_FULL_DISK = r"""
import resource, signal, sys
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write beyond the limit fails with EFBIG, as a full disk's ENOSPC
resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))
from surfnorm.cli import app
sys.argv = ["surfnorm", *sys.argv[1:]]
app()
"""


@pytest.mark.slow
@pytest.mark.parametrize("fmt", ["npy", "png16"])
def test_a_write_that_the_system_refuses_is_one_line_with_its_reason(tmp_path, fmt):
    import subprocess
    import sys

    v, u = np.mgrid[0:480, 0:640]
    np.save(tmp_path / "d.npy", (1.0 + 0.001 * u + 0.01 * np.sin(v / 7.0)).astype(np.float32))
    camera = ["--fx", "500", "--fy", "500", "--cx", "319.5", "--cy", "239.5"]  # the 640x480 frame's own
    args = ["estimate", "d.npy", "o", "-f", fmt, "-m", "d2nt_basic", *camera]
    done = subprocess.run([sys.executable, "-c", _FULL_DISK, *args], cwd=tmp_path, capture_output=True, text=True)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), done.stderr
    assert f"cannot write o.{'npy' if fmt == 'npy' else 'png'} (File too large)" in lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.npy"]  # no output, no temporary


# ---------------------------------------------------------------------------- row 9: only our one line


@pytest.mark.slow
@pytest.mark.parametrize("suffix", [".png", ".tif", ".pgm", "mask"])
def test_a_truncated_image_is_only_our_one_line_on_stderr(tmp_path, suffix):
    import subprocess
    import sys

    import cv2

    z = np.rint(_plane() * 1000).astype(np.uint16)
    ext = ".png" if suffix == "mask" else suffix
    cv2.imwrite(str(tmp_path / ("full" + ext)), z.astype(np.float32) if ext == ".tif" else z)
    raw = (tmp_path / ("full" + ext)).read_bytes()
    (tmp_path / ("cut" + ext)).write_bytes(raw[: len(raw) // 2])
    args = ["full.png", "o", "--mask", "cut.png"] if suffix == "mask" else ["cut" + ext, "o"]
    command = [sys.executable, "-m", "surfnorm.cli", "estimate", *args, *CAMERA]  # OpenCV writes to fd 2 itself
    done = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        f"error: cut{ext}: cannot decode as an image (empty, truncated or corrupt)"
    ]
    assert done.stdout == ""


# ---------------------------------------------------------------------------- row 12: small contracts


def test_scale_invariant_help_says_what_the_code_does():
    import typer

    group = typer.main.get_command(app)
    for command in ("estimate", "convert"):
        (option,) = [p for p in group.commands[command].params if p.name == "scale_invariant"]
        assert "median" not in option.help and "relative to each pixel's own depth" in option.help, option.help


def test_timedelta_depth_and_intrinsics_are_refused():
    import surfnorm
    from surfnorm import Intrinsics

    depth = np.full((8, 8), 5, dtype="timedelta64[ms]")
    with pytest.raises(surfnorm.InputError, match=r"depth: expected real-valued depth .*timedelta64"):
        surfnorm.estimate(depth, K)
    with pytest.raises(surfnorm.InputError, match="mask: expected a boolean array"):
        surfnorm.estimate(np.ones((8, 8)), K, mask=depth)
    with pytest.raises(surfnorm.InputError, match="K: expected a 3x3 matrix of real numbers"):
        Intrinsics.from_matrix(np.asarray(K).astype("timedelta64[s]"))


def test_timedelta_depth_files_are_refused(tmp_path):
    from surfnorm.errors import DataFileError
    from surfnorm.io import read_depth
    from surfnorm.io.depth import read_mask

    np.save(tmp_path / "t.npy", np.full((8, 8), 5, dtype="timedelta64[ms]"))
    with pytest.raises(DataFileError, match=r"t\.npy: expected real-valued depth"):
        read_depth(tmp_path / "t.npy")
    with pytest.raises(DataFileError, match=r"t\.npy: expected a 2-D mask"):
        read_mask(tmp_path / "t.npy")


def test_numpy_integers_are_accepted_for_threads_as_for_window():
    import surfnorm

    z = np.stack([_surface()] * 2)
    ref = surfnorm.estimate(z, K, method="plane_pca", window=5, threads=1)
    assert np.array_equal(surfnorm.estimate(z, K, method="plane_pca", window=np.int64(5), threads=np.int64(2)), ref)
    with pytest.raises(surfnorm.InputError, match="threads: expected a positive integer"):
        surfnorm.estimate(z, K, threads=np.float64(2))


@pytest.mark.parametrize(
    "name, text",
    [
        ("k.yaml", "fx: 525\nfy: 525\ncx: 31.5\ncy: 23.5\nfx: 600\n"),
        ("k.json", '{"fx": 525, "fy": 525, "cx": 31.5, "cy": 23.5, "fx": 600}'),
    ],
)
def test_an_intrinsics_key_given_twice_is_an_error(tmp_path, name, text):
    from surfnorm.errors import DataFileError
    from surfnorm.io import read_intrinsics

    (tmp_path / name).write_text(text)
    with pytest.raises(DataFileError, match=r"expected each key once, got 'fx' twice"):
        read_intrinsics(tmp_path / name)


def test_utf8_bom_json_intrinsics_are_read(tmp_path):
    from surfnorm.io import read_intrinsics

    (tmp_path / "k.json").write_bytes(b"\xef\xbb\xbf" + b'{"fx": 525, "fy": 526, "cx": 31.5, "cy": 23.5}')
    cam = read_intrinsics(tmp_path / "k.json")
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (525.0, 526.0, 31.5, 23.5)


def test_a_masked_output_array_is_refused():
    import surfnorm

    out = np.ma.masked_all((48, 64, 3), np.float32)
    with pytest.raises(surfnorm.InputError, match="out: expected a plain NumPy array .* masked array"):
        surfnorm.estimate(_surface(), K, method="d2nt_basic", out=out)


def test_a_stack_of_narrow_frames_is_read_as_a_stack_as_one_narrow_frame_is_a_frame():
    import surfnorm

    frame = np.tile(np.linspace(1.0, 1.1, 3), (100, 1))  # 100 rows, 3 columns: one frame
    one = surfnorm.estimate(frame, K, method="d2nt_basic")
    both = surfnorm.estimate(np.stack([frame, frame]), K, method="d2nt_basic")  # (2, 100, 3): two such frames
    assert both.shape == (2, 100, 3, 3) and np.array_equal(both[1], one)
    with pytest.raises(surfnorm.InputError, match="looks like an image with 3 channel"):
        surfnorm.estimate(np.ones((48, 64, 3)), K)  # a colour picture is still refused


# ---------------------------------------------------------------------------- the principles' other cases


@pytest.mark.parametrize("name", ["a.bin", "a.bin.gz"])
def test_a_bin_shape_larger_than_the_file_is_a_data_file_error_before_allocating(tmp_path, name):
    import gzip

    from surfnorm.errors import DataFileError
    from surfnorm.io import read_depth

    raw = np.ones((48, 64), np.float32).tobytes()
    (tmp_path / name).write_bytes(gzip.compress(raw) if name.endswith(".gz") else raw)
    with pytest.raises(
        DataFileError, match=r"expected 40000000000 bytes of float32 depth \(100000x100000\), got 12288"
    ):
        read_depth(tmp_path / name, shape=(100000, 100000))
    assert read_depth(tmp_path / name, shape=(48, 64)).shape == (48, 64)


def test_refine_takes_depth_of_any_magnitude():
    import surfnorm

    z = _surface()
    noisy = surfnorm.estimate(z, K, method="d2nt_basic")
    noisy[10, 10] = [0.6, 0.0, -0.8]
    ref = surfnorm.refine(noisy, z)
    for s in (2.0**-200, 2.0**200):
        assert np.array_equal(surfnorm.refine(noisy, z * s), ref), s


def test_a_depth_scale_that_float32_cannot_hold_is_an_input_error(tmp_path):
    import cv2

    from surfnorm.errors import InputError
    from surfnorm.io import read_depth

    cv2.imwrite(str(tmp_path / "d.png"), np.rint(_plane() * 1000).astype(np.uint16))
    for scale in (1e-40, 1e45):
        with pytest.raises(InputError, match=r"depth_scale: expected a scale that keeps depth"):
            read_depth(tmp_path / "d.png", depth_scale=scale)
    assert np.allclose(read_depth(tmp_path / "d.png", depth_scale=1000), _plane(), atol=1e-3)
