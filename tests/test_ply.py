"""Point clouds: surfnorm.io.write_ply, surfnorm.to_open3d, `surfnorm estimate OUT.ply`, `convert --format ply`.

Every file is read back twice: by Open3D (what users open it with) and by ``read_ply`` below, a reader written
from the PLY specification with NumPy alone, which also checks the header's property names and types.
"""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

import surfnorm
from surfnorm.cli import app
from surfnorm.errors import DataFileError, InputError, MissingDependencyError
from surfnorm.io import read_colors, write_ply


@pytest.fixture(scope="module")
def o3d():
    """Open3D, which make test installs: its absence fails these tests by name (it is never a skip)."""
    try:
        import open3d
    except ImportError:
        pytest.fail("Open3D is not installed: make test installs it (pip install open3d)")
    return open3d


runner = CliRunner()
H, W = 24, 32
K = [[40.0, 0, 15.5], [0, 40.0, 11.5], [0, 0, 1]]
CAMERA = ["--fx", "40", "--fy", "40", "--cx", "15.5", "--cy", "11.5"]
PLY_TYPES = {"float": "<f4", "uchar": "u1"}
XYZN = [("float", n) for n in ("x", "y", "z", "nx", "ny", "nz")]
RGB = [("uchar", n) for n in ("red", "green", "blue")]


def read_ply(path):
    """(header lines, [(type, name)] of the vertex properties, the vertices as a structured array)."""
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    lines = raw[:end].decode("ascii").splitlines()
    assert lines[0] == "ply" and lines[1] == "format binary_little_endian 1.0", lines[:2]
    elements = [ln for ln in lines if ln.startswith("element ")]
    assert len(elements) == 1 and elements[0].startswith("element vertex "), elements
    count = int(elements[0].split()[2])
    props = [tuple(ln.split()[1:]) for ln in lines if ln.startswith("property ")]
    dtype = np.dtype([(name, PLY_TYPES[t]) for t, name in props])
    body = raw[end:]
    assert len(body) == count * dtype.itemsize, (len(body), count, dtype.itemsize)  # nothing more, nothing less
    return lines, props, np.frombuffer(body, dtype=dtype)


def _frame():
    """A curved surface with holes: zero, NaN and negative depth, and a pixel that gets no normal."""
    v, u = np.mgrid[0:H, 0:W]
    depth = 1.5 + 0.01 * u + 0.004 * v + 0.05 * np.sin(u / 5.0)
    depth[3, 4] = 0
    depth[5, 7:10] = np.nan
    depth[10, 20] = -1.0
    depth[0, :] = 0  # a whole row without depth
    return depth


def _rgb():
    return np.random.default_rng(1).integers(0, 256, (H, W, 3), dtype=np.uint8)


def _sigma(normals):
    s = np.random.default_rng(2).uniform(0.0, 30.0, (H, W))
    has = np.isfinite(normals).all(axis=-1) & (normals != 0).any(axis=-1)
    s[~has] = np.nan
    s[7, 3] = np.nan  # a pixel with a normal whose uncertainty is unknown
    return s


def _has(depth, normals):
    with np.errstate(invalid="ignore"):
        return (np.isfinite(depth) & (depth > 0)) & np.isfinite(normals).all(axis=-1) & (normals != 0).any(axis=-1)


@pytest.fixture(scope="module")
def frame():
    depth = _frame()
    normals = surfnorm.estimate(depth, K)
    assert 0 < _has(depth, normals).sum() < H * W - W  # some pixels are left out, most are written
    return depth, normals


OPTIONS = {
    "none": ({}, XYZN),
    "colors": ({"colors": True}, XYZN + RGB),
    "sigma": ({"sigma": True}, XYZN + [("float", "quality")]),
    "colors+sigma": ({"colors": True, "sigma": True}, XYZN + RGB + [("float", "quality")]),
}


def _write(tmp_path, frame, option):
    depth, normals = frame
    flags, _ = OPTIONS[option]
    kwargs = {}
    if flags.get("colors"):
        kwargs["colors"] = _rgb()
    if flags.get("sigma"):
        kwargs["sigma"] = _sigma(normals)
    return write_ply(tmp_path / f"{option}.ply", depth, K, normals, **kwargs), kwargs


# ---------------------------------------------------------------------------- the file


@pytest.mark.parametrize("option", list(OPTIONS))
def test_header_names_and_types_every_property_in_order(tmp_path, frame, option):
    path, _ = _write(tmp_path, frame, option)
    lines, props, vertices = read_ply(path)
    assert props == OPTIONS[option][1]
    assert f"element vertex {_has(*frame).sum()}" in lines
    assert lines[-1] == "end_header" and len(vertices) == _has(*frame).sum()


@pytest.mark.parametrize("option", list(OPTIONS))
def test_open3d_reads_back_the_points_normals_and_colours_bit_for_bit(o3d, tmp_path, frame, option):
    depth, normals = frame
    path, kwargs = _write(tmp_path, frame, option)
    has = _has(depth, normals)
    cloud = o3d.io.read_point_cloud(str(path))
    points = np.asarray(cloud.points)
    assert points.shape == (has.sum(), 3)
    assert np.array_equal(points.astype(np.float32), surfnorm.points(depth, K)[has].astype(np.float32))
    assert np.array_equal(np.asarray(cloud.normals).astype(np.float32), normals[has])
    assert cloud.has_colors() == ("colors" in kwargs)
    if "colors" in kwargs:
        assert np.array_equal(np.rint(np.asarray(cloud.colors) * 255).astype(np.uint8), kwargs["colors"][has])


@pytest.mark.parametrize("option", list(OPTIONS))
def test_every_property_reads_back_bit_for_bit_in_row_major_order(tmp_path, frame, option):
    depth, normals = frame
    path, kwargs = _write(tmp_path, frame, option)
    has = _has(depth, normals)
    _, _, vert = read_ply(path)
    P = surfnorm.points(depth, K)[has].astype(np.float32)  # boolean indexing: row-major order
    for i, (p, n) in enumerate(zip("xyz", ("nx", "ny", "nz"))):
        assert np.array_equal(vert[p], P[:, i]) and np.array_equal(vert[n], normals[has][:, i])
    if "colors" in kwargs:
        for i, c in enumerate(("red", "green", "blue")):
            assert np.array_equal(vert[c], kwargs["colors"][has][:, i])
    if "sigma" in kwargs:
        want = kwargs["sigma"].astype(np.float32)[has]
        assert np.array_equal(vert["quality"].view(np.uint32), want.view(np.uint32))  # NaN included, bit for bit
        assert np.isnan(vert["quality"]).sum() == 1  # the pixel with a normal and no sigma is written


def test_the_order_is_row_major_and_only_pixels_with_depth_and_a_normal_are_written(tmp_path):
    depth = np.full((4, 5), 2.0)
    depth[1, 1] = 0  # no depth, although it has a normal
    normals = np.zeros((4, 5, 3), np.float32)
    normals[..., 2] = -1
    normals[0, 0] = 0  # no normal (the default fill)
    normals[2, 3] = np.nan  # no normal (fill=nan)
    normals[3, 4, 0] = np.inf  # not a normal
    _, _, vert = read_ply(write_ply(tmp_path / "o.ply", depth, K, normals))
    cols = np.rint(vert["x"] * 40 / 2 + 15.5).astype(int)  # u = x fx / z + cx
    rows = np.rint(vert["y"] * 40 / 2 + 11.5).astype(int)
    expected = [(r, c) for r in range(4) for c in range(5) if (r, c) not in {(0, 0), (1, 1), (2, 3), (3, 4)}]
    assert list(zip(rows.tolist(), cols.tolist())) == expected


def test_fill_nan_and_fill_zero_give_the_same_file(tmp_path):
    depth = _frame()
    a = write_ply(tmp_path / "a.ply", depth, K, surfnorm.estimate(depth, K))
    b = write_ply(tmp_path / "b.ply", depth, K, surfnorm.estimate(depth, K, fill=np.nan))
    assert a.read_bytes() == b.read_bytes()


def test_sigma_does_not_change_which_vertices_are_written(tmp_path, frame):
    _, _, plain = read_ply(_write(tmp_path, frame, "none")[0])
    _, _, with_sigma = read_ply(_write(tmp_path, frame, "sigma")[0])
    for name in ("x", "y", "z", "nx", "ny", "nz"):
        assert np.array_equal(plain[name], with_sigma[name])


def test_float_colours_in_0_1_are_rounded_to_bytes(tmp_path, frame):
    depth, normals = frame
    rgb = _rgb()
    a = write_ply(tmp_path / "a.ply", depth, K, normals, colors=rgb)
    b = write_ply(tmp_path / "b.ply", depth, K, normals, colors=rgb / 255.0)
    assert a.read_bytes() == b.read_bytes()
    half = np.full((H, W, 3), 0.5, np.float32)  # 127.5 rounds half to even: 128
    _, _, vert = read_ply(write_ply(tmp_path / "c.ply", depth, K, normals, colors=half))
    assert set(vert["red"].tolist()) == {128}


def test_the_same_arguments_give_the_same_bytes(tmp_path, frame):
    a, _ = _write(tmp_path, frame, "colors+sigma")
    first = a.read_bytes()
    b, _ = _write(tmp_path, frame, "colors+sigma")
    assert b.read_bytes() == first


def test_a_masked_array_leaves_its_masked_pixels_out(tmp_path, frame):
    depth, normals = frame
    masked = np.ma.masked_array(depth, mask=np.zeros(depth.shape, bool))
    masked[:, : W // 2] = np.ma.masked
    _, _, vert = read_ply(write_ply(tmp_path / "m.ply", masked, K, normals))
    has = _has(depth, normals)
    has[:, : W // 2] = False
    assert np.array_equal(vert["x"], surfnorm.points(depth, K)[has][:, 0].astype(np.float32))


@pytest.mark.parametrize("what", ["no depth", "no normals"])
def test_a_frame_without_any_point_is_a_valid_empty_ply(o3d, tmp_path, frame, what):
    depth, normals = frame
    if what == "no depth":
        depth = np.zeros_like(depth)
    else:
        normals = np.zeros_like(normals)
    path = write_ply(tmp_path / "empty.ply", depth, K, normals, colors=_rgb(), sigma=_sigma(frame[1]))
    lines, props, vert = read_ply(path)
    assert "element vertex 0" in lines and len(vert) == 0
    assert props == OPTIONS["colors+sigma"][1]
    assert path.read_bytes().endswith(b"end_header\n")
    cloud = o3d.io.read_point_cloud(str(path))  # Open3D warns "number of vertex <= 0" and returns an empty cloud
    assert len(cloud.points) == 0


def test_a_frame_of_any_shape_is_written(tmp_path):
    depth = np.full((1, 3), 2.0)
    normals = np.tile(np.array([0, 0, -1], np.float32), (1, 3, 1))
    _, _, vert = read_ply(write_ply(tmp_path / "row.ply", depth, surfnorm.Intrinsics(10.0, 10.0, 1.0, 0.0), normals))
    assert np.array_equal(vert["x"], np.array([-0.2, 0.0, 0.2], np.float32))
    assert vert["z"].tolist() == [2.0, 2.0, 2.0]


# ---------------------------------------------------------------------------- refusals


def _bad(name):
    depth, normals = _frame(), np.zeros((H, W, 3), np.float32)
    normals[..., 2] = -1
    args = {"depth": depth, "K": K, "normals": normals}
    cases = {
        "stack": ({"depth": np.stack([depth, depth])}, "depth: expected one frame, a 2-D array (H, W), got a stack of shape (2, 24, 32); write each frame on its own (depth[i])"),
        "depth 1-D": ({"depth": depth.ravel()}, "depth: expected a 2-D array (H, W) of real depth values, got shape (768,) and dtype float64"),
        "depth bool": ({"depth": depth > 1}, "depth: expected a 2-D array (H, W) of real depth values, got shape (24, 32) and dtype bool"),
        "K": ({"K": np.eye(2)}, "K: expected a 3x3 intrinsic matrix, got shape (2, 2)"),
        "normals shape": ({"normals": normals[:, :-1]}, "normals: expected a float array of shape (24, 32, 3) (depth's (H, W) and 3), got shape (24, 31, 3) and dtype float32"),
        "normals int": ({"normals": normals.astype(np.int8)}, "normals: expected a float array of shape (24, 32, 3) (depth's (H, W) and 3), got shape (24, 32, 3) and dtype int8"),
        "normals stack": ({"normals": normals[None]}, "normals: expected a float array of shape (24, 32, 3) (depth's (H, W) and 3), got shape (1, 24, 32, 3) and dtype float32; one frame, not a stack: pass normals[i]"),
        "colors RGBA": ({"colors": np.zeros((H, W, 4), np.uint8)}, "colors: expected RGB of shape (24, 32, 3) (depth's (H, W) and 3), uint8 0-255 or float 0-1, got shape (24, 32, 4) and dtype uint8"),
        "colors uint16": ({"colors": np.zeros((H, W, 3), np.uint16)}, "colors: expected RGB of shape (24, 32, 3) (depth's (H, W) and 3), uint8 0-255 or float 0-1, got shape (24, 32, 3) and dtype uint16"),
        "colors grey": ({"colors": np.zeros((H, W), np.uint8)}, "colors: expected RGB of shape (24, 32, 3) (depth's (H, W) and 3), uint8 0-255 or float 0-1, got shape (24, 32) and dtype uint8"),
        "colors 0-255 floats": ({"colors": np.full((H, W, 3), 200.0)}, "colors: expected float values in [0, 1], got 200.0 at pixel (row 0, column 0) and 2304 such value(s) in all"),
        "colors NaN": ({"colors": np.where(np.arange(W)[None, :, None] == 5, np.nan, np.full((H, W, 3), 0.5))}, "colors: expected float values in [0, 1], got nan at pixel (row 0, column 5) and 72 such value(s) in all"),
        "sigma shape": ({"sigma": np.zeros((H, W, 1))}, "sigma: expected real values of shape (24, 32) (depth's (H, W)), degrees, got shape (24, 32, 1) and dtype float64"),
        "sigma negative": ({"sigma": np.where(np.arange(H)[:, None] == 2, -1.0, np.zeros((H, W)))}, "sigma: expected finite values >= 0 (degrees; NaN where there is none), got -1.0 at pixel (row 2, column 0) and 32 such value(s) in all"),
        "sigma inf": ({"sigma": np.where(np.arange(W)[None, :] == 9, np.inf, np.zeros((H, W)))}, "sigma: expected finite values >= 0 (degrees; NaN where there is none), got inf at pixel (row 0, column 9) and 24 such value(s) in all"),
        "depth beyond float32": ({"depth": np.where(np.arange(W)[None, :] == 1, 1e39, depth)}, "depth: expected points within float32's range (the type of the PLY's coordinates), got (-3.625e+38, -2.875e+38, 1e+39) at pixel (row 0, column 1)"),
    }  # fmt: skip
    change, message = cases[name]
    return {**args, **change}, message


@pytest.mark.parametrize(
    "name",
    ["stack", "depth 1-D", "depth bool", "K", "normals shape", "normals int", "normals stack", "colors RGBA",
     "colors uint16", "colors grey", "colors 0-255 floats", "colors NaN", "sigma shape", "sigma negative",
     "sigma inf", "depth beyond float32"],
)  # fmt: skip
def test_a_bad_argument_is_an_input_error_naming_it_and_nothing_is_written(o3d, tmp_path, name):
    kwargs, message = _bad(name)
    out = tmp_path / "o.ply"
    out.write_bytes(b"before")
    depth, K_, normals = kwargs.pop("depth"), kwargs.pop("K"), kwargs.pop("normals")
    with pytest.raises(InputError) as err:
        write_ply(out, depth, K_, normals, **kwargs)
    assert str(err.value) == message
    assert out.read_bytes() == b"before" and sorted(p.name for p in tmp_path.iterdir()) == ["o.ply"]
    if "sigma" not in kwargs:  # to_open3d checks the same arguments with the same messages
        with pytest.raises(InputError) as err:
            surfnorm.to_open3d(depth, K_, normals, **kwargs)
        assert str(err.value) == message


def test_a_path_that_is_not_a_path_is_an_input_error(frame):
    with pytest.raises(InputError, match=re.escape("path: expected a file path (str or os.PathLike), got int 3")):
        write_ply(3, *frame[:1], K, frame[1])


def test_a_missing_folder_is_a_data_file_error_naming_the_output(tmp_path, frame):
    with pytest.raises(DataFileError) as err:
        write_ply(tmp_path / "no" / "o.ply", frame[0], K, frame[1])
    assert str(err.value) == f"cannot write {tmp_path / 'no' / 'o.ply'} (No such file or directory)"


_FULL_DISK = r"""
import resource, signal, sys
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write beyond the limit fails with EFBIG, as a full disk's ENOSPC
resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))
import numpy as np
from surfnorm.io import write_ply
depth = np.full((480, 640), 2.0)
normals = np.zeros((480, 640, 3), np.float32)
normals[..., 2] = -1
try:
    write_ply("o.ply", depth, [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]], normals)
except Exception as exc:
    print(type(exc).__name__, exc)
"""


def test_a_write_that_the_system_refuses_leaves_nothing_behind(tmp_path):
    done = subprocess.run([sys.executable, "-c", _FULL_DISK], cwd=tmp_path, capture_output=True, text=True)
    assert done.stdout.strip() == "DataFileError cannot write o.ply (File too large)", done.stderr
    assert list(tmp_path.iterdir()) == []  # no truncated o.ply, no temporary file


# ---------------------------------------------------------------------------- to_open3d


def test_to_open3d_has_the_pixels_of_the_file_in_float64(o3d, tmp_path, frame):
    depth, normals = frame
    rgb = _rgb()
    cloud = surfnorm.to_open3d(depth, K, normals, colors=rgb)
    has = _has(depth, normals)
    assert np.array_equal(np.asarray(cloud.points), surfnorm.points(depth, K)[has])  # not rounded to float32
    assert np.array_equal(np.asarray(cloud.normals), normals[has].astype(np.float64))
    assert np.array_equal(np.asarray(cloud.colors), rgb[has] / 255.0)
    _, _, vert = read_ply(write_ply(tmp_path / "o.ply", depth, K, normals, colors=rgb))
    assert np.array_equal(np.asarray(cloud.points).astype(np.float32)[:, 2], vert["z"])


def test_to_open3d_keeps_float_colours_as_given_and_adds_none_without(o3d, frame):
    depth, normals = frame
    rgb = np.random.default_rng(3).uniform(0, 1, (H, W, 3))
    has = _has(depth, normals)
    assert np.array_equal(np.asarray(surfnorm.to_open3d(depth, K, normals, rgb).colors), rgb[has])
    assert not surfnorm.to_open3d(depth, K, normals).has_colors()


def test_to_open3d_without_open3d_names_the_extra(monkeypatch, frame):
    monkeypatch.setitem(sys.modules, "open3d", None)  # import open3d raises ImportError
    with pytest.raises(MissingDependencyError) as err:
        surfnorm.to_open3d(*frame[:1], K, frame[1])
    assert str(err.value) == (
        'to_open3d needs Open3D, which is not installed: pip install "surfnorm[open3d]" (or pip install open3d)'
    )


# ---------------------------------------------------------------------------- surfnorm.convert


def test_convert_writes_one_ply_per_frame_as_write_ply_does(tmp_path):
    scans = tmp_path / "scans"
    scans.mkdir()
    depths = {"a": _frame(), "b": np.nan_to_num(_frame()) + 0.5}
    for name, z in depths.items():
        np.save(scans / f"{name}.npy", z.astype(np.float32))
    summary = surfnorm.convert(scans, tmp_path / "out", intrinsics=K, fmt="ply", method="d2nt_basic")
    assert summary.written == 2 and summary.ok
    for name, z in depths.items():
        z32 = z.astype(np.float32)
        want = write_ply(tmp_path / f"{name}.ply", z32, K, surfnorm.estimate(z32, K, method="d2nt_basic"))
        assert (tmp_path / "out" / f"{name}.ply").read_bytes() == want.read_bytes()


# ---------------------------------------------------------------------------- the command line


@pytest.fixture
def files(tmp_path, monkeypatch):
    import cv2

    depth = np.nan_to_num(_frame()).astype(np.float32)
    np.save(tmp_path / "d.npy", depth)
    rgb = _rgb()
    cv2.imwrite(str(tmp_path / "rgb.png"), rgb[:, :, ::-1])  # OpenCV writes BGR
    cv2.imwrite(str(tmp_path / "small.png"), rgb[:-1, :, ::-1])
    monkeypatch.chdir(tmp_path)
    return tmp_path, depth, rgb


def _one_line_exit_2(args):
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 2, (args, result.output)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), (args, result.stderr)
    return lines[0].removeprefix("error: ")


def _ok(args):
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, (args, result.output)
    return result.stdout


@pytest.mark.parametrize("args", [["out.ply"], ["out", "--format", "ply"], ["out.ply", "-f", "ply"]])
def test_cli_estimate_writes_the_ply_of_write_ply(files, args):
    folder, depth, _ = files
    assert _ok(["estimate", "d.npy", *args, *CAMERA]).strip() == "wrote out.ply"
    want = write_ply(folder / "want.ply", depth, K, surfnorm.estimate(depth, K))
    assert (folder / "out.ply").read_bytes() == want.read_bytes()
    assert sorted(p.name for p in folder.iterdir()) == ["d.npy", "out.ply", "rgb.png", "small.png", "want.ply"]


def test_cli_estimate_color_adds_the_images_rgb(files):
    folder, depth, rgb = files
    _ok(["estimate", "d.npy", "c.ply", "--color", "rgb.png", *CAMERA])
    normals = surfnorm.estimate(depth, K)
    assert (folder / "c.ply").read_bytes() == write_ply(folder / "w.ply", depth, K, normals, colors=rgb).read_bytes()
    _, props, vert = read_ply(folder / "c.ply")
    assert props == XYZN + RGB
    assert np.array_equal(vert["red"], rgb[_has(depth, normals)][:, 0])  # red is red: BGR was turned to RGB
    assert np.array_equal(read_colors(folder / "rgb.png"), rgb)


def test_cli_color_of_another_size_is_one_line_exit_2(files):
    line = _one_line_exit_2(["estimate", "d.npy", "c.ply", "--color", "small.png", *CAMERA])
    assert line == (
        "--color: small.png is 32x23 pixels and the depth 32x24; expected a colour image registered to the depth "
        "frame, of its size"
    )
    assert not (files[0] / "c.ply").exists()


def test_cli_color_that_is_not_an_image_is_one_line_exit_2(files):
    (files[0] / "bad.png").write_bytes(b"not a picture")
    line = _one_line_exit_2(["estimate", "d.npy", "c.ply", "--color", "bad.png", *CAMERA])
    assert line == "bad.png: cannot decode as a colour image (empty, truncated or corrupt)"


@pytest.mark.parametrize(
    "args, message",
    [
        (["c", "--color", "rgb.png"], "--color: adds colours to a PLY point cloud; expected an OUTPUT ending in .ply, got c"),
        (["c", "-f", "npy", "--color", "rgb.png"], "--color: adds colours to a PLY point cloud; expected an OUTPUT ending in .ply, got c"),
        (["c.ply", "-f", "png16"], "--format: c.ply names a PLY point cloud, got --format png16; drop --format, or give a prefix"),
        (["c.ply", "--disparity"], "--disparity: a PLY output back-projects depth to points; expected depth, not disparity"),
        (["c", "-f", "obj"], "--format: expected one of npy, png16, png8, ply, got 'obj'"),
    ],
)  # fmt: skip
def test_cli_ply_usage_errors_are_one_line_exit_2(files, args, message):
    assert _one_line_exit_2(["estimate", "d.npy", *args, *CAMERA]) == message
    assert sorted(p.name for p in files[0].iterdir()) == ["d.npy", "rgb.png", "small.png"]


def test_cli_refuses_an_existing_ply_unless_overwrite(files):
    folder = files[0]
    (folder / "out.ply").write_bytes(b"keep")
    line = _one_line_exit_2(["estimate", "d.npy", "out.ply", *CAMERA])
    assert line == "output: out.ply exists; pass --overwrite to replace it, or choose another output name"
    assert (folder / "out.ply").read_bytes() == b"keep"
    _ok(["estimate", "d.npy", "out.ply", "--overwrite", *CAMERA])
    assert read_ply(folder / "out.ply")[1] == XYZN


def test_cli_never_writes_over_the_colour_image(files):
    folder = files[0]
    (folder / "rgb.ply").write_bytes((folder / "rgb.png").read_bytes())  # a PNG named .ply
    line = _one_line_exit_2(["estimate", "d.npy", "rgb.ply", "--color", "rgb.ply", "--overwrite", *CAMERA])
    assert line == (
        "output: expected a path other than the files this command reads, got rgb.ply, which is rgb.ply; "
        "choose another output name"
    )
    assert (folder / "rgb.ply").read_bytes() == (folder / "rgb.png").read_bytes()


def test_cli_convert_format_ply_writes_one_ply_per_frame_and_skips_them_on_a_rerun(files):
    folder, depth, _ = files
    (folder / "scans").mkdir()
    np.save(folder / "scans" / "a.npy", depth)
    np.save(folder / "scans" / "b.npy", depth + 0.25)
    out = _ok(["convert", "scans", "plys", "--format", "ply", *CAMERA])
    assert out.strip() == "2 written, 0 skipped (output existed), 0 failed -> plys"
    assert sorted(p.name for p in (folder / "plys").iterdir()) == ["a.ply", "b.ply"]
    for name, z in (("a", depth), ("b", depth + 0.25)):
        want = write_ply(folder / "want.ply", z, K, surfnorm.estimate(z, K))
        assert (folder / "plys" / f"{name}.ply").read_bytes() == want.read_bytes()
    (folder / "plys" / "a.ply").write_bytes(b"old")
    assert _ok(["convert", "scans", "plys", "-f", "ply", *CAMERA]).strip().startswith("0 written, 2 skipped")
    assert (folder / "plys" / "a.ply").read_bytes() == b"old"
    assert _ok(["convert", "scans", "plys", "-f", "ply", "--overwrite", *CAMERA]).strip().startswith("2 written")
    assert read_ply(folder / "plys" / "a.ply")[1] == XYZN
