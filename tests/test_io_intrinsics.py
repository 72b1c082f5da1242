"""Intrinsics files: JSON, YAML, ROS camera_info, OpenCV YAML, 3F2N params.txt, text matrices."""

from __future__ import annotations

import json
import re

import cv2
import numpy as np
import pytest

from surfnorm import Intrinsics
from surfnorm.errors import DataFileError, InputError
from surfnorm.io import read_intrinsics, resolve_intrinsics
from surfnorm.io.threef2n import read_params, sample_root

CAM = Intrinsics(525.0, 520.5, 319.5, 239.25)
K9 = [525.0, 0.0, 319.5, 0.0, 520.5, 239.25, 0.0, 0.0, 1.0]


def write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    "name, text",
    [
        ("a.json", json.dumps({"fx": 525, "fy": 520.5, "cx": 319.5, "cy": 239.25, "width": 640})),
        ("b.json", json.dumps({"K": [K9[0:3], K9[3:6], K9[6:9]]})),
        ("c.json", json.dumps({"camera_matrix": K9})),
        (
            "open3d.json",
            json.dumps({"width": 640, "height": 480, "intrinsic_matrix": list(np.reshape(K9, (3, 3)).T.ravel())}),
        ),
        ("a.yaml", "fx: 525\nfy: 520.5\ncx: 319.5\ncy: 239.25\n"),
        ("b.yml", "K: [525.0, 0.0, 319.5, 0.0, 520.5, 239.25, 0.0, 0.0, 1.0]\n"),
        (
            "ros_calibration.yaml",
            "image_width: 640\nimage_height: 480\ncamera_name: depth\ncamera_matrix:\n  rows: 3\n  cols: 3\n"
            "  data: [525.0, 0.0, 319.5, 0.0, 520.5, 239.25, 0.0, 0.0, 1.0]\ndistortion_model: plumb_bob\n"
            "distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [0, 0, 0, 0, 0]\n",
        ),
        (
            "ros2_camera_info.yaml",
            "header:\n  frame_id: camera\nheight: 480\nwidth: 640\ndistortion_model: plumb_bob\nd: [0.0, 0.0, 0.0, 0.0, 0.0]\n"
            "k: [525.0, 0.0, 319.5, 0.0, 520.5, 239.25, 0.0, 0.0, 1.0]\nr: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n"
            "p: [525.0, 0.0, 319.5, 0.0, 0.0, 520.5, 239.25, 0.0, 0.0, 0.0, 1.0, 0.0]\n",
        ),
        ("K.txt", "525 0 319.5\n0 520.5 239.25\n0 0 1\n"),
        ("intrinsic_depth.txt", "525 0 319.5 0\n0 520.5 239.25 0\n0 0 1 0\n0 0 0 1\n"),
        ("params.txt", "525 520.5 320.5 240.25 100"),
        ("params4.txt", "525 520.5 320.5 240.25"),
    ],
)
def test_every_kind_gives_the_same_camera(tmp_path, name, text):
    assert read_intrinsics(write(tmp_path, name, text)) == CAM


def test_opencv_filestorage_yaml(tmp_path):
    path = tmp_path / "calib.yaml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", np.reshape(K9, (3, 3)))
    fs.release()
    assert "!!opencv-matrix" in path.read_text()
    assert read_intrinsics(path) == CAM
    old = write(
        tmp_path,
        "old.yml",
        "%YAML:1.0\nK: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
        "   data: [ 525., 0., 319.5, 0., 520.5, 239.25, 0., 0., 1. ]\n",
    )
    assert read_intrinsics(old) == CAM
    other = write(
        tmp_path, "other.yml", "%YAML:1.0\nR: !!opencv-matrix\n   rows: 1\n   cols: 1\n   dt: d\n   data: [ 1. ]\n"
    )
    with pytest.raises(
        DataFileError, match=r"other.yml: expected an OpenCV matrix named camera_matrix, K or cameraMatrix"
    ):
        read_intrinsics(other)


def test_3f2n_params_match_the_dataset_reader():
    path = sample_root() / "Easy" / "android" / "params.txt"
    assert read_intrinsics(path) == read_params(path) == Intrinsics(1400, 1380, 319, 259)


@pytest.mark.parametrize(
    "name, text, pattern",
    [
        ("bad.json", "{fx: 1", r"bad.json: cannot parse as JSON \(Expecting property name"),
        (
            "partial.json",
            '{"fx": 1, "fy": 2}',
            r"partial.json: expected all of fx, fy, cx, cy, got fx, fy without cx, cy",
        ),
        ("other.json", '{"focal": 1}', r"other.json: expected fx, fy, cx, cy, or a 3x3 matrix K .*got keys focal"),
        ("list.json", "[1, 2, 3]", r"list.json: expected a mapping with fx, fy, cx, cy.*got list"),
        (
            "nan.json",
            '{"fx": NaN, "fy": 1, "cx": 0, "cy": 0}',
            r"nan.json: intrinsics.fx: expected a finite number, got nan",
        ),
        (
            "zero.json",
            '{"fx": 0, "fy": 1, "cx": 0, "cy": 0}',
            r"zero.json: intrinsics.fx: expected a positive focal length",
        ),
        ("text.json", '{"fx": "a", "fy": 1, "cx": 0, "cy": 0}', r"text.json: expected numbers for fx, fy, cx, cy"),
        ("k8.json", '{"K": [1, 0, 0, 0, 1, 0, 0, 0]}', r"k8.json: expected 9 numbers \(a 3x3 matrix\) for 'K', got 8"),
        (
            "kneg.json",
            json.dumps({"K": [-5, 0, 1, 0, 5, 1, 0, 0, 1]}),
            r"kneg.json: K: expected positive focal lengths.*fx=-5",
        ),
        ("kinf.json", '{"K": [Infinity, 0, 1, 0, 5, 1, 0, 0, 1]}', r"kinf.json: K: expected finite entries"),
        (
            "skew.json",
            json.dumps({"K": [5, 1, 1, 0, 5, 1, 0, 0, 1]}),
            r"skew.json: K: expected \[\[fx, 0, cx\], \[0, fy, cy\], \[0, 0, 1\]\] \(no skew\)",
        ),
        ("bad.yaml", "fx: [1\n", r"bad.yaml: cannot parse as YAML"),
        ("empty.yaml", "", r"empty.yaml: expected a mapping with fx, fy, cx, cy.*got NoneType"),
        (
            "few.txt",
            "1 2 3",
            r"few.txt: expected 4 or 5 numbers \(3F2N 'fx fy u0 v0 count'\), 9 \(a 3x3 K\) or 16 \(a 4x4 matrix\), got 3 numbers",
        ),
        ("words.txt", "fx=1", r"words.txt: expected whitespace-separated numbers"),
        ("zero.txt", "0 1 2 3 4", r"zero.txt: intrinsics.fx: expected a positive focal length"),
        ("cam.ini", "[camera]", r"cam.ini: unknown intrinsics file type '.ini'; expected .json, .yaml, .yml or .txt"),
    ],
)
def test_bad_intrinsics_files_are_named(tmp_path, name, text, pattern):
    with pytest.raises(DataFileError, match=pattern):
        read_intrinsics(write(tmp_path, name, text))


def test_missing_binary_and_directory(tmp_path):
    with pytest.raises(DataFileError, match=r"none.json: cannot read intrinsics file \(No such file or directory\)"):
        read_intrinsics(tmp_path / "none.json")
    (tmp_path / "bin.txt").write_bytes(b"\xff\xfe\x00\x81")
    with pytest.raises(DataFileError, match=r"bin.txt: expected a text intrinsics file, got binary data"):
        read_intrinsics(tmp_path / "bin.txt")
    with pytest.raises(DataFileError, match=r"expected an intrinsics file, got a directory"):
        read_intrinsics(tmp_path)


def test_resolve_intrinsics_sources(tmp_path):
    assert resolve_intrinsics() is None
    assert resolve_intrinsics(fx=525, fy=520.5, cx=319.5, cy=239.25) == CAM
    assert resolve_intrinsics(np.reshape(K9, (3, 3))) == CAM
    assert resolve_intrinsics(CAM) is CAM
    assert resolve_intrinsics({"fx": 525, "fy": 520.5, "cx": 319.5, "cy": 239.25}) == CAM
    assert resolve_intrinsics(str(write(tmp_path, "k.json", json.dumps({"K": K9})))) == CAM
    with pytest.raises(InputError, match=r"intrinsics: expected all of fx, fy, cx, cy, got fx, cy without fy, cx"):
        resolve_intrinsics(fx=1, cy=2)
    with pytest.raises(
        InputError, match=r"intrinsics: expected a file/matrix or --fx --fy --cx --cy, not both \(got fx too\)"
    ):
        resolve_intrinsics(CAM, fx=1)


# ---------------------------------------------------------------------------- issue 14: hostile files

OPENCV = "%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: {dt}\n   data: [ {data} ]\n"
NINE = "525., 0., 319.5, 0., 520.5, 239.25, 0., 0., 1."


def _alias_bomb(levels=10):
    lines = ['a0: &a0 ["x", "x", "x", "x", "x", "x", "x", "x", "x"]']
    for i in range(1, levels):
        lines.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]")
    return "\n".join(lines) + f"\nK: *a{levels - 1}\n"


# (file name, content, words of the message after the file name). 24 cases.
HOSTILE = [
    (
        "ocv_8.yaml",
        OPENCV.format(rows=3, cols=3, dt="d", data=NINE.rsplit(",", 1)[0]),
        r"expected 9 numbers \(a 3x3 matrix\) in camera_matrix.data, got 8 values",
    ),
    ("ocv_10.yaml", OPENCV.format(rows=3, cols=3, dt="d", data=NINE + ", 1."), r"in camera_matrix.data, got 10 values"),
    (
        "ocv_rows.yaml",
        OPENCV.format(rows=-3, cols=3, dt="d", data=NINE),
        r"expected rows: 3 and cols: 3 for 'camera_matrix', got rows: -3",
    ),
    (
        "ocv_rows_huge.yaml",
        OPENCV.format(rows=100000, cols=100000, dt="d", data=NINE),
        r"got rows: 100000, cols: 100000",
    ),
    ("ocv_rows_text.yaml", OPENCV.format(rows="three", cols=3, dt="d", data=NINE), r"got rows: not an integer"),
    (
        "ocv_dt.yaml",
        OPENCV.format(rows=3, cols=3, dt="q", data=NINE),
        r"expected camera_matrix.dt to be one of u, c, w, s, i, f, d, h, got 'q'",
    ),
    ("ocv_dt_none.yaml", OPENCV.format(rows=3, cols=3, dt=7, data=NINE), r"expected camera_matrix.dt to be one of"),
    (
        "ocv_text.yaml",
        OPENCV.format(rows=3, cols=3, dt="d", data=NINE.replace("525.", "abc")),
        r"expected numbers in camera_matrix.data",
    ),
    ("ocv_scalar.yaml", "%YAML:1.0\ncamera_matrix: 5\n", r"expected 'camera_matrix' to be an opencv-matrix"),
    ("ocv_unterminated.yaml", "%YAML:1.0\ncamera_matrix: [[[\n", r"cannot parse as OpenCV YAML \(line 2"),
    (
        "ocv_deep.yaml",
        "%YAML:1.0\ncamera_matrix: " + "[" * 100_000 + "]" * 100_000 + "\n",
        r"expected lists and mappings at most 16 deep",
    ),
    ("unterminated.yaml", "K: [[[\n", r"cannot parse as YAML"),
    ("deep.json", "[" * 100_000 + "]" * 100_000, r"expected lists and mappings at most 16 deep"),
    ("deep_k.json", '{"K": ' + "[" * 100_000 + "]" * 100_000 + "}", r"expected lists and mappings at most 16 deep"),
    ("deep17.json", '{"K": ' + "[" * 17 + "]" * 17 + "}", r"expected lists and mappings at most 16 deep"),
    ("deep.yaml", "K: " + "[" * 5000 + "]" * 5000 + "\n", r"line 1: expected lists and mappings at most 16 deep"),
    ("deep_block.yaml", "".join(" " * i + f"k{i}:\n" for i in range(40)) + " " * 40 + "x: 1\n", r"at most 16 deep"),
    ("bomb.yaml", _alias_bomb(), r"line 2: expected plain values, got the YAML alias \*a0"),
    (
        "true.json",
        '{"fx": true, "fy": 500, "cx": 1, "cy": 1}',
        r"expected numbers for fx, fy, cx, cy, got fx: true \(a boolean\)",
    ),
    ("string.json", '{"fx": 500, "fy": "500", "cx": 1, "cy": 1}', r"got fy: '500' \(a string\)"),
    (
        "k_bool.json",
        '{"K": [[true, 0, 1], [0, 1, 1], [0, 0, 1]]}',
        r"expected numbers for 'K', got true \(a boolean\) at K\[0\]\[0\]",
    ),
    (
        "k_str.yaml",
        'K: ["525", 0, 1, 0, 5, 1, 0, 0, 1]\n',
        r"expected numbers for 'K', got '525' \(a string\) at K\[0\]",
    ),
    ("k_map.yaml", "K: {a: 1}\n", r"expected numbers for 'K', got a mapping of 1"),
    (
        "ros_rows.yaml",
        "camera_matrix: {rows: 30, cols: 3, data: [1, 0, 1, 0, 1, 1, 0, 0, 1]}\n",
        r"expected rows: 3 and cols: 3 for 'camera_matrix', got rows: 30",
    ),
]


@pytest.mark.slow
@pytest.mark.parametrize("name, text, pattern", HOSTILE, ids=[h[0] for h in HOSTILE])
def test_hostile_intrinsics_files_are_named_with_bounded_memory(tmp_path, name, text, pattern):
    import tracemalloc

    path = write(tmp_path, name, text)
    tracemalloc.start()
    try:
        with pytest.raises(DataFileError, match=re.escape(str(path)) + ": .*" + pattern):
            read_intrinsics(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 16 * 2**20 + 4 * len(text), f"{peak / 2**20:.0f} MiB to refuse a {len(text)} byte file"


def test_an_oversized_file_is_not_read(tmp_path):
    path = tmp_path / "huge.json"
    path.write_text('{"fx": 1, "pad": "' + "x" * (1 << 20) + '"}')
    with pytest.raises(DataFileError, match=r"huge.json: expected an intrinsics file of at most 1048576 bytes"):
        read_intrinsics(path)


def test_the_cli_says_the_same_in_one_line(tmp_path):
    from typer.testing import CliRunner

    from surfnorm.cli import app

    depth = sample_root() / "Easy" / "android" / "depth" / "000001.bin.gz"
    for name, text, pattern in HOSTILE[::4]:
        path = write(tmp_path, name, text)
        result = CliRunner().invoke(app, ["estimate", str(depth), str(tmp_path / "o"), "-k", str(path)])
        lines = result.stderr.strip().splitlines()
        assert result.exit_code == 2 and len(lines) == 1 and re.search(pattern, lines[0]), result.output
