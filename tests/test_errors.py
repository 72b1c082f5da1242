"""surfnorm.errors as users meet them: a battery of bad input through the library and the CLI, each with its
asserted message (InputError / DataFileError naming the argument or file) or asserted masking."""

from __future__ import annotations

import gzip
import os
import re

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

import surfnorm
from surfnorm import Intrinsics
from surfnorm.batch import plan_tasks
from surfnorm.cli import app
from surfnorm.errors import DataFileError, InputError
from surfnorm.io.depth import read_depth, read_mask
from surfnorm.io.intrinsics import read_intrinsics
from surfnorm.io.normals import read_normals
from surfnorm.io.threef2n import read_frame, read_normal_png, read_params, sample_root
from surfnorm.methods import Method, register

K = np.array([[60.0, 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]])
METHODS = list(surfnorm.methods())


def ramp(h=48, w=64):
    v, u = np.mgrid[0:h, 0:w]
    return (2.0 + 0.01 * u + 0.005 * v).astype(np.float32)


# ---------------------------------------------------------------------------- arrays


@pytest.mark.parametrize(
    "depth, pattern",
    [
        (np.zeros((0, 0)), r"depth: expected at least 3x3 pixels, got shape \(0, 0\)"),
        (np.ones((1, 64)), r"depth: expected at least 3x3 pixels, got shape \(1, 64\)"),
        (np.ones((64, 1)), r"depth: expected at least 3x3 pixels, got shape \(64, 1\)"),
        (np.ones((2, 2)), r"depth: expected at least 3x3 pixels, got shape \(2, 2\)"),
        (np.ones((48, 64, 3)), r"depth: expected one depth channel.*got shape \(48, 64, 3\).*3 channel"),
        (np.ones((48, 64, 1)), r"depth: expected one depth channel.*got shape \(48, 64, 1\)"),
        (
            np.ones((2, 48, 64, 1)),
            r"depth: expected a 2-D array \(H, W\) or a stack \(N, H, W\), got .*shape \(2, 48, 64, 1\)",
        ),
        (np.ones(5), r"depth: expected a 2-D array \(H, W\) or a stack \(N, H, W\), got .*shape \(5,\)"),
        (np.ones((48, 64), dtype=bool), r"depth: expected real-valued depth.*dtype bool.*pass it as mask="),
        (np.ones((48, 64), dtype=complex), r"depth: expected real-valued depth \(float or integer\), got .*complex128"),
        (
            np.ones((48, 64), dtype=object),
            r"depth: expected real-valued depth \(float or integer\), got .*dtype object",
        ),
        (None, r"depth: expected a 2-D array of depth values, got None"),
        (np.zeros((0, 48, 64)), r"depth: expected at least one frame in the stack"),
    ],
    ids=[
        "empty",
        "1xN",
        "Nx1",
        "2x2",
        "HxWx3",
        "HxWx1",
        "4-D",
        "1-D",
        "bool",
        "complex",
        "object",
        "None",
        "empty-stack",
    ],
)
def test_bad_depth_arrays_are_named(depth, pattern):
    with pytest.raises(InputError, match=pattern):
        surfnorm.estimate(depth, K)


@pytest.mark.parametrize("dtype", [np.uint16, np.int32, np.int64, np.float64])
def test_integer_and_float64_depth_is_accepted_and_equals_float32(dtype):
    z = (1000 + 3 * np.arange(48 * 64).reshape(48, 64) % 97).astype(dtype)
    expected = surfnorm.estimate(z.astype(np.float32), K)
    np.testing.assert_array_equal(surfnorm.estimate(z, K), expected)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("bad", [0.0, np.nan, np.inf, -np.inf, -1.0])
def test_all_invalid_depth_gives_only_fill(method, bad):
    z = np.full((16, 20), bad, dtype=np.float32)
    n = surfnorm.estimate(z, K, method=method, fill=np.nan)
    assert n.shape == (16, 20, 3) and np.isnan(n).all()
    assert (surfnorm.estimate(z, K, method=method) == 0).all()


@pytest.mark.parametrize("method", METHODS)
def test_each_kind_of_invalid_pixel_is_masked(method):
    z = ramp()
    holes = {(10, 10): 0.0, (10, 30): np.nan, (20, 20): np.inf, (30, 40): -np.inf, (40, 50): -2.0}
    for (v, u), value in holes.items():
        z[v, u] = value
    mask = np.ones(z.shape, bool)
    mask[5, 5] = False
    n = surfnorm.estimate(z, K, method=method, mask=mask, fill=np.nan)
    for v, u in list(holes) + [(5, 5)]:
        assert np.isnan(n[v, u]).all(), (v, u)
    rest = ~np.isnan(n[..., 0])
    assert rest.sum() == z.size - len(holes) - 1
    assert np.allclose(np.linalg.norm(n[rest], axis=-1), 1, atol=1e-5)


@pytest.mark.parametrize(
    "K_bad, pattern",
    [
        ([[np.nan, 0, 31.5], [0, 60, 23.5], [0, 0, 1]], r"K: expected finite entries"),
        ([[60, 0, np.inf], [0, 60, 23.5], [0, 0, 1]], r"K: expected finite entries"),
        ([[0, 0, 31.5], [0, 60, 23.5], [0, 0, 1]], r"K: expected positive focal lengths.*fx=0"),
        ([[60, 0, 31.5], [0, -60, 23.5], [0, 0, 1]], r"K: expected positive focal lengths.*fy=-60"),
        (np.eye(4), r"K: expected a 3x3 intrinsic matrix, got shape \(4, 4\)"),
    ],
    ids=["nan-fx", "inf-cx", "zero-fx", "negative-fy", "4x4"],
)
def test_bad_intrinsics_are_named(K_bad, pattern):
    with pytest.raises(InputError, match=pattern):
        surfnorm.estimate(ramp(), K_bad)


def test_intrinsics_object_refuses_bad_values():
    with pytest.raises(InputError, match=r"intrinsics.fx: expected a positive focal length in pixels, got 0.0"):
        surfnorm.Intrinsics(0.0, 1.0, 0.0, 0.0)
    with pytest.raises(InputError, match=r"intrinsics.cy: expected a finite number, got nan"):
        surfnorm.Intrinsics(1.0, 1.0, 0.0, float("nan"))


def test_mask_of_another_shape_is_named():
    with pytest.raises(InputError, match=r"mask: expected shape \(48, 64\) to match depth, got shape \(64, 48\)"):
        surfnorm.estimate(ramp(), K, mask=np.ones((64, 48), bool))
    with pytest.raises(InputError, match=r"mask: expected a boolean array.*complex"):
        surfnorm.estimate(ramp(), K, mask=np.ones((48, 64), complex))


def test_bad_mode_flags_are_named():
    with pytest.raises(InputError, match=r"scale_invariant: expected True or False, got 'yes'"):
        surfnorm.estimate(ramp(), K, scale_invariant="yes")
    with pytest.raises(InputError, match=r"disparity: expected True or False, got 1"):
        surfnorm.estimate(ramp(), K, disparity=1)


# ---------------------------------------------------------------------------- files


def png16(path, z):
    assert cv2.imwrite(str(path), z.astype(np.uint16))
    return path


@pytest.fixture
def files(tmp_path):
    z = (1000 + np.arange(48 * 64).reshape(48, 64) % 50).astype(np.uint16)
    good_png = png16(tmp_path / "good.png", z)
    data = good_png.read_bytes()
    (tmp_path / "truncated.png").write_bytes(data[: len(data) // 2])
    corrupt = bytearray(data)
    corrupt[60:90] = b"\x00" * 30
    (tmp_path / "corrupt.png").write_bytes(bytes(corrupt))
    assert cv2.imwrite(str(tmp_path / "good.tif"), z.astype(np.float32) / 1000)
    tif = (tmp_path / "good.tif").read_bytes()
    (tmp_path / "truncated.tif").write_bytes(tif[: len(tif) // 3])
    (tmp_path / "garbage.tif").write_bytes(b"II*\x00" + os.urandom(64))
    np.save(tmp_path / "good.npy", z.astype(np.float32))
    npy = (tmp_path / "good.npy").read_bytes()
    (tmp_path / "truncated.npy").write_bytes(npy[: len(npy) // 2])
    (tmp_path / "corrupt.npy").write_bytes(b"\x93NUMPY garbage")
    np.savez(tmp_path / "two.npz", a=z, b=z)
    (tmp_path / "truncated.npz").write_bytes((tmp_path / "two.npz").read_bytes()[:100])
    raw = np.full((480, 640), 2.0, "<f4").tobytes()
    (tmp_path / "short.bin").write_bytes(raw[:1000])
    (tmp_path / "truncated.bin.gz").write_bytes(gzip.compress(raw)[:500])
    (tmp_path / "corrupt.bin.gz").write_bytes(b"\x1f\x8b\x08\x00" + b"\xff" * 40)
    (tmp_path / "notgzip.bin.gz").write_bytes(b"plain text")
    (tmp_path / "empty.png").write_bytes(b"")
    cv2.imwrite(str(tmp_path / "colour.png"), np.zeros((8, 8, 3), np.uint8))
    cv2.imwrite(str(tmp_path / "eight.png"), np.zeros((8, 8), np.uint8))
    return tmp_path


@pytest.mark.parametrize(
    "name, pattern",
    [
        ("truncated.png", r"truncated.png: cannot decode as an image \(empty, truncated or corrupt\)"),
        ("corrupt.png", r"corrupt.png: cannot decode as an image"),
        ("empty.png", r"empty.png: cannot decode as an image"),
        ("truncated.tif", r"truncated.tif: cannot decode as an image"),
        ("garbage.tif", r"garbage.tif: cannot decode as an image"),
        ("truncated.npy", r"truncated.npy: cannot read as NumPy .npy depth \(truncated or corrupt"),
        ("corrupt.npy", r"corrupt.npy: cannot read as NumPy .npy depth"),
        (
            "two.npz",
            r"two.npz: expected an array named 'depth' or a single array in the .npz archive, got 2 arrays \(a, b\)",
        ),
        ("truncated.npz", r"truncated.npz: cannot read as NumPy .npz depth"),
        ("short.bin", r"short.bin: expected 1228800 bytes of float32 depth \(480x640\), got 1000"),
        ("truncated.bin.gz", r"truncated.bin.gz: truncated or corrupt gzip stream"),
        ("corrupt.bin.gz", r"corrupt.bin.gz: truncated or corrupt gzip stream"),
        ("notgzip.bin.gz", r"notgzip.bin.gz: truncated or corrupt gzip stream"),
        ("colour.png", r"colour.png: expected a single-channel depth image, got 3 channels"),
        ("eight.png", r"eight.png: expected 16-bit integer or 32-bit float depth, got an 8-bit image"),
        ("missing.png", r"missing.png: cannot read depth file \(No such file or directory\)"),
        ("missing.npy", r"missing.npy: cannot read depth file \(No such file or directory\)"),
        ("missing.bin", r"missing.bin: cannot read depth file \(No such file or directory\)"),
        ("depth.jpg", r"depth.jpg: unknown depth file type '.jpg'; expected one of .bin, .bin.gz"),
    ],
)
def test_bad_depth_files_are_named(files, name, pattern):
    with pytest.raises(DataFileError, match=pattern):
        read_depth(files / name)


def test_a_directory_is_not_a_depth_file(files):
    with pytest.raises(DataFileError, match=r"expected a depth file, got a directory"):
        read_depth(files)


def test_good_files_read(files):
    z = read_depth(files / "good.png", depth_scale=1000)
    assert z.dtype == np.float32 and z.shape == (48, 64) and abs(z[0, 0] - 1.0) < 1e-6
    np.testing.assert_array_equal(
        read_depth(files / "good.tif"), (np.asarray(read_depth(files / "good.png")) / 1000).astype(np.float32)
    )
    np.testing.assert_array_equal(read_depth(files / "good.npy"), read_depth(files / "good.png"))


def _deny(monkeypatch, path):
    """Make reading ``path`` fail as a directory without permission does for a normal user.

    The tests run as root in CI containers, where chmod does not stop reading; there
    the operating system's refusal is simulated at the one call the readers make.
    """
    from pathlib import Path

    real = Path.read_bytes

    def read_bytes(self):
        if str(self).startswith(str(path)):
            raise PermissionError(13, "Permission denied", str(self))
        return real(self)

    monkeypatch.setattr(Path, "read_bytes", read_bytes)


def test_directory_without_permission(files, monkeypatch):
    locked = files / "locked"
    locked.mkdir()
    png16(locked / "d.png", np.full((8, 8), 1000))
    locked.chmod(0)
    try:
        if os.geteuid() == 0:
            _deny(monkeypatch, locked)
        with pytest.raises(DataFileError, match=r"d.png: cannot read depth file \(Permission denied\)"):
            read_depth(locked / "d.png")
    finally:
        locked.chmod(0o755)


# ---------------------------------------------------------------------------- CLI


def run_cli(*args):
    result = CliRunner().invoke(app, [str(a) for a in args])
    assert "Traceback" not in result.output, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    return result


CAM = ["--fx", 60, "--fy", 60, "--cx", 31.5, "--cy", 23.5]


@pytest.mark.parametrize(
    "args, pattern",
    [
        (["truncated.png", "out"] + CAM, r"truncated.png: cannot decode as an image"),
        (["corrupt.npy", "out"] + CAM, r"corrupt.npy: cannot read as NumPy"),
        (["truncated.bin.gz", "out"] + CAM, r"truncated or corrupt gzip stream"),
        (["good.png", "out"], r"intrinsics: expected --intrinsics FILE or all of --fx --fy --cx --cy"),
        (["good.png", "out", "--fx", 60], r"intrinsics: expected all of fx, fy, cx, cy, got fx without fy, cx, cy"),
        (
            ["good.png", "out", "--fx", 0, "--fy", 60, "--cx", 1, "--cy", 1],
            r"intrinsics.fx: expected a positive focal length",
        ),
        (
            ["good.png", "out", "--fx", "nan", "--fy", 60, "--cx", 1, "--cy", 1],
            r"intrinsics.fx: expected a finite number",
        ),
        (["good.png", "out", "--intrinsics", "missing.json"], r"missing.json: cannot read intrinsics file"),
        (["good.png", "out", "--depth-scale", 0] + CAM, r"depth_scale: expected a positive finite number, got 0.0"),
        (["good.png", "out", "--method", "nope"] + CAM, r"method: expected one of .*got 'nope'"),
        (["good.png", "out", "--format", "jpg"] + CAM, r"--format: expected one of npy, png16, png8, ply, got 'jpg'"),
        (["good.png", "out", "--mask", "truncated.png"] + CAM, r"truncated.png: cannot decode as an image"),
        (
            ["good.png", "out", "--mask", "colour.png"] + CAM,
            r"mask: expected shape \(48, 64\) to match depth, got shape \(8, 8\)",
        ),
        (["good.png", "."] + CAM, r"output: expected a file prefix, got the directory"),
    ],
)
def test_cli_estimate_usage_errors_exit_2_without_traceback(files, args, pattern, monkeypatch):
    monkeypatch.chdir(files)
    result = run_cli("estimate", *args)
    assert result.exit_code == 2, result.output
    assert re.search(pattern, result.output.replace("\n", " ")), result.output


def test_cli_convert_usage_errors_exit_2(files, monkeypatch):
    monkeypatch.chdir(files)
    (files / "afile").write_text("x")
    cases = [
        (["good.png", "afile"] + CAM, r"output_dir: expected a folder, got the file afile"),
        (
            ["nothing-here/", "out"] + CAM,
            r"inputs: expected a depth file, a folder or a glob pattern, got 'nothing-here/'",
        ),
        (["nothing*.png", "out"] + CAM, r"inputs: expected at least one depth file, found none in nothing\*.png"),
        (["good.png", "out", "--jobs", 0] + CAM, r"--jobs: expected a positive integer, got 0"),
        (["good.png", "out"], r"intrinsics: expected --intrinsics FILE or --fx --fy --cx --cy"),
        (["good.png", "out", "--format", "tiff"] + CAM, r"--format: expected one of npy, png16, png8, ply, got 'tiff'"),
    ]
    for args, pattern in cases:
        result = run_cli("convert", *args)
        assert result.exit_code == 2, (args, result.output)
        assert re.search(pattern, result.output.replace("\n", " ")), (args, result.output)


def test_cli_typer_usage_errors_exit_2(files):
    result = run_cli("convert", files / "good.png", files / "o", "--jobs", "x")
    assert result.exit_code == 2
    assert run_cli("convert").exit_code == 2
    assert run_cli("estimate", files / "good.png").exit_code == 2


# ---------------------------------------------------------------------------- issue 14: readers' arguments and files

from pathlib import Path  # noqa: E402

# (reader, positional argument, keyword arguments, message). 13 cases.
READER_ARGUMENTS = [
    (read_depth, None, {}, r"path: expected a file path \(str or os.PathLike\), got NoneType None"),
    (read_depth, 3, {}, r"path: expected a file path \(str or os.PathLike\), got int 3"),
    (read_depth, 2.5, {}, r"path: expected a file path .*got float 2.5"),
    (read_depth, ["a.png"], {}, r"path: expected a file path .*got list"),
    (read_depth, "", {}, r"path: expected a file path, got an empty one"),
    (read_mask, None, {}, r"path: expected a file path \(str or os.PathLike\), got NoneType None"),
    (read_mask, 7, {}, r"path: expected a file path .*got int 7"),
    (
        read_depth,
        "x.bin",
        {"shape": (-480, -640)},
        r"shape: expected \(rows, cols\), two positive integers, got \(-480, -640\)",
    ),
    (
        read_depth,
        "x.bin",
        {"shape": (0, 640)},
        r"shape: expected \(rows, cols\), two positive integers, got \(0, 640\)",
    ),
    (read_depth, "x.bin", {"shape": (480,)}, r"shape: expected \(rows, cols\), two positive integers, got \(480,\)"),
    (read_depth, "x.bin", {"shape": (480.5, 640)}, r"shape: expected \(rows, cols\).*got \(480.5, 640\)"),
    (read_depth, "x.bin", {"shape": (True, 640)}, r"shape: expected \(rows, cols\).*got \(True, 640\)"),
    (read_depth, "x.bin", {"shape": "ab"}, r"shape: expected \(rows, cols\).*got 'ab'"),
]


@pytest.mark.parametrize("reader, arg, kwargs, pattern", READER_ARGUMENTS)
def test_reader_arguments_are_input_errors_naming_them(reader, arg, kwargs, pattern):
    with pytest.raises(InputError, match=pattern):
        reader(arg, **kwargs)


def test_a_bytes_path_reads_like_a_str_path(files):
    np.testing.assert_array_equal(read_depth(os.fsencode(files / "good.png")), read_depth(files / "good.png"))
    np.testing.assert_array_equal(read_mask(os.fsencode(files / "good.png")), read_mask(files / "good.png"))


# (array saved as mask.npy, words of the message). 6 cases.
BAD_MASKS = [
    (np.zeros((4, 4), dtype=[("a", "<i4"), ("b", "<f4")]), r"dtype \[\('a', '<i4'\), \('b', '<f4'\)\]"),
    (np.full((4, 4), "yes"), r"dtype <U3"),
    (np.full((4, 4), b"1"), r"dtype \|S1"),
    (np.ones((4, 4), np.complex64), r"dtype complex64"),
    (np.ones((4, 4), "M8[s]"), r"dtype datetime64\[s\]"),
    (np.ones((4, 4, 2), bool), r"shape \(4, 4, 2\)"),
]


@pytest.mark.parametrize("arr, pattern", BAD_MASKS, ids=["record", "str", "bytes", "complex", "datetime", "3-D"])
def test_bad_mask_files_are_named(tmp_path, arr, pattern):
    np.save(tmp_path / "mask.npy", arr)
    with pytest.raises(DataFileError, match=r"mask.npy: expected a 2-D mask, got an array of " + ".*" + pattern):
        read_mask(tmp_path / "mask.npy")


@pytest.mark.slow
def test_gzip_bomb_is_refused_while_decompressing(tmp_path):
    import tracemalloc

    bomb = tmp_path / "bomb.bin.gz"
    with gzip.open(bomb, "wb", compresslevel=9) as fh:  # 256 MiB of zeros in about 255 KB
        block = bytes(1 << 20)
        for _ in range(256):
            fh.write(block)
    assert bomb.stat().st_size < 300_000
    tracemalloc.start()
    try:
        with pytest.raises(
            DataFileError,
            match=r"bomb.bin.gz: expected 1228800 bytes of float32 depth \(480x640\) once decompressed, got more",
        ):
            read_depth(bomb)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 8 * 2**20, f"peak {peak / 2**20:.0f} MiB while refusing the file"  # one frame is 1.2 MiB


def test_a_gzip_frame_of_the_right_size_still_reads(tmp_path):
    z = np.arange(12, dtype="<f4").reshape(3, 4)
    (tmp_path / "z.bin.gz").write_bytes(gzip.compress(z.tobytes()))
    np.testing.assert_array_equal(read_depth(tmp_path / "z.bin.gz", shape=(3, 4)), z)
    with pytest.raises(DataFileError, match=r"z.bin.gz: expected 1228800 bytes of float32 depth \(480x640\), got 48"):
        read_depth(tmp_path / "z.bin.gz")
    (tmp_path / "z.bin").write_bytes(z.tobytes() + b"1234")
    with pytest.raises(DataFileError, match=r"z.bin: expected 48 bytes of float32 depth \(3x4\), got 52"):
        read_depth(tmp_path / "z.bin", shape=(3, 4))


@pytest.mark.parametrize("client", ["x", 3, object()])
def test_convert_client_must_be_a_dask_client(files, client):
    with pytest.raises(InputError, match=r"client: expected a dask.distributed.Client, got "):
        surfnorm.convert(files / "good.png", files / "out", intrinsics=K, client=client)


@pytest.mark.parametrize("umask", [0o022, 0o027, 0o002, 0o077])
def test_outputs_get_the_mode_of_an_ordinary_write(tmp_path, umask):
    from surfnorm.io.normals import write_normals
    from surfnorm.io.pictures import write_rgb8

    n = np.zeros((4, 4, 3), np.float32)
    n[..., 2] = -1
    old = os.umask(umask)
    try:
        (tmp_path / "plain").write_bytes(b"x")  # what open(..., "w") gives
        written = [
            write_normals(tmp_path / "n.npy", n),
            write_normals(tmp_path / "n.png", n, fmt="png16"),
            write_rgb8(tmp_path / "p.png", np.zeros((4, 4, 3), np.uint8)),
        ]
    finally:
        os.umask(old)
    plain = (tmp_path / "plain").stat().st_mode & 0o777
    assert plain == 0o666 & ~umask
    for p in written:
        assert Path(p).stat().st_mode & 0o777 == plain, p
    # replacing a file keeps its mode, as writing into it would
    (tmp_path / "n.npy").chmod(0o640)
    write_normals(tmp_path / "n.npy", n)
    assert (tmp_path / "n.npy").stat().st_mode & 0o777 == 0o640


# --- error paths that the other module tests do not reach -----------------------------------------------------


def test_intrinsics_need_real_numbers():
    with pytest.raises(InputError, match=r"intrinsics.fx: expected a real number, got str 'a'"):
        Intrinsics("a", 1, 1, 1)


def test_registry_refuses_bad_names_and_categories():
    with pytest.raises(ValueError, match=r"method name 'x\+mnr' may not contain '\+mnr'"):
        register(Method("x+mnr", "averaging", "ref", "summary", lambda *a, **k: None))
    with pytest.raises(ValueError, match=r"category of 'x': expected one of"):
        register(Method("x", "magic", "ref", "summary", lambda *a, **k: None))


def test_one_intrinsics_per_frame():
    with pytest.raises(InputError, match=r"K: expected one intrinsics for all 2 frames or one per frame, got 3"):
        surfnorm.estimate(np.ones((2, 5, 5)), [Intrinsics(1, 1, 1, 1)] * 3)


def test_depth_and_mask_files(tmp_path):
    np.save(tmp_path / "d.npy", np.zeros((4, 4, 2)))
    with pytest.raises(DataFileError, match=r"d.npy: expected a 2-D depth image, got an array of shape \(4, 4, 2\)"):
        read_depth(tmp_path / "d.npy")
    one = np.arange(12.0).reshape(3, 4, 1)  # one channel: (H, W, 1), as some datasets save depth
    np.save(tmp_path / "one.npy", one)
    np.testing.assert_array_equal(read_depth(tmp_path / "one.npy"), one[..., 0].astype(np.float32))
    np.save(tmp_path / "first.npy", np.zeros((1, 4, 4)))
    with pytest.raises(
        DataFileError, match=r"first.npy: expected a 2-D depth image, got an array of shape \(1, 4, 4\)"
    ):
        read_depth(tmp_path / "first.npy")
    with pytest.raises(DataFileError, match=r"missing.png: cannot read mask file"):
        read_mask(tmp_path / "missing.png")
    np.save(tmp_path / "m1.npy", np.eye(4)[..., None])
    np.testing.assert_array_equal(read_mask(tmp_path / "m1.npy"), np.eye(4, dtype=bool))  # (H, W, 1) as (H, W)
    np.save(tmp_path / "m.npy", np.zeros((4, 4, 2), bool))
    with pytest.raises(DataFileError, match=r"m.npy: expected a 2-D mask, got an array of shape \(4, 4, 2\)"):
        read_mask(tmp_path / "m.npy")
    np.savez(tmp_path / "two.npz", a=np.ones((2, 2)), b=np.ones((2, 2)))
    with pytest.raises(
        DataFileError,
        match=r"two.npz: expected an array named 'mask' or a single array in the .npz "
        r"archive, got 2 arrays \(a, b\)",
    ):
        read_mask(tmp_path / "two.npz")
    (tmp_path / "cut.npy").write_bytes((tmp_path / "m.npy").read_bytes()[:60])
    with pytest.raises(DataFileError, match=r"cut.npy: cannot read as NumPy .npy mask \(truncated or corrupt"):
        read_mask(tmp_path / "cut.npy")
    with pytest.raises(DataFileError, match=r"missing.npy: cannot read mask file"):
        read_mask(tmp_path / "missing.npy")
    (tmp_path / "bad.png").write_bytes(b"\x89PNG not an image")
    with pytest.raises(DataFileError, match=r"bad.png: cannot decode as an image \(empty, truncated or corrupt\)"):
        read_mask(tmp_path / "bad.png")
    np.savez(tmp_path / "named.npz", other=np.zeros((2, 2)), mask=np.eye(2))
    np.testing.assert_array_equal(read_mask(tmp_path / "named.npz"), np.eye(2, dtype=bool))


def test_normal_files(tmp_path):
    (tmp_path / "n.png").write_bytes(b"\x89PNG not really")
    with pytest.raises(DataFileError, match=r"n.png: cannot decode as PNG \(empty, truncated or corrupt\)"):
        read_normals(tmp_path / "n.png")


def test_3f2n_layout_errors(tmp_path):
    with pytest.raises(DataFileError, match=r"params.txt: cannot read 3F2N params.txt"):
        read_params(tmp_path / "params.txt")
    with pytest.raises(DataFileError, match=r"gt.png: cannot read as an image \(missing, truncated or not a PNG\)"):
        read_normal_png(tmp_path / "gt.png")
    cv2.imwrite(str(tmp_path / "gt8.png"), np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(DataFileError, match=r"gt8.png: expected a 16-bit RGB PNG, got shape \(4, 4, 3\) dtype uint8"):
        read_normal_png(tmp_path / "gt8.png")
    # a frame whose ground truth has another size than its depth
    src = sample_root() / "Easy" / "android"
    obj = tmp_path / "Easy" / "android"
    (obj / "depth").mkdir(parents=True)
    (obj / "normal").mkdir()
    (obj / "depth" / "000001.bin.gz").write_bytes((src / "depth" / "000001.bin.gz").read_bytes())
    (obj / "params.txt").write_text((src / "params.txt").read_text())
    cv2.imwrite(str(obj / "normal" / "000001.png"), np.zeros((4, 4, 3), np.uint16))
    with pytest.raises(DataFileError, match=r"expected \(480, 640\) pixels to match depth, got \(4, 4\)"):
        read_frame(tmp_path, "Easy/android/000001")


def test_intrinsics_files(tmp_path):
    with pytest.raises(DataFileError, match=r"expected an intrinsics file, got a directory"):
        read_intrinsics(tmp_path)
    (tmp_path / "k.yaml").write_text("fx: [1, 2\n")
    with pytest.raises(DataFileError, match=r"k.yaml: cannot parse as YAML"):
        read_intrinsics(tmp_path / "k.yaml")


def test_convert_inputs_and_output_dir(tmp_path):
    with pytest.raises(InputError, match=r"inputs: expected a path, a glob pattern or a list of files, got int"):
        plan_tasks(123, tmp_path / "out")
    (tmp_path / "blocker").write_text("a file")
    np.save(tmp_path / "d.npy", np.ones((8, 8), np.float32))
    with pytest.raises(InputError, match=r"output_dir: (cannot create the folder|expected a folder)"):
        surfnorm.convert([tmp_path / "d.npy"], tmp_path / "blocker" / "out", intrinsics=Intrinsics(5, 5, 3.5, 3.5))


def test_torch_intrinsics_tensors():
    torch = pytest.importorskip("torch")
    import surfnorm.torch as st

    depth = torch.ones(5, 5)
    with pytest.raises(InputError, match=r"K: expected shape \(3, 3\) or \(1, 3, 3\) for 1 frame\(s\)"):
        st.estimate(depth, torch.eye(2))
    with pytest.raises(InputError, match=r"K: expected a real \(3, 3\) or \(1, 3, 3\) intrinsic matrix"):
        st.estimate(depth, torch.eye(3, dtype=torch.complex64))
