"""Intrinsics files: JSON, YAML, ROS camera_info, OpenCV YAML, 3F2N params.txt, text matrices."""

from __future__ import annotations

import json

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
        ("open3d.json", json.dumps({"width": 640, "height": 480, "intrinsic_matrix": list(np.reshape(K9, (3, 3)).T.ravel())})),
        ("a.yaml", "fx: 525\nfy: 520.5\ncx: 319.5\ncy: 239.25\n"),
        ("b.yml", "K: [525.0, 0.0, 319.5, 0.0, 520.5, 239.25, 0.0, 0.0, 1.0]\n"),
        ("ros_calibration.yaml",
         "image_width: 640\nimage_height: 480\ncamera_name: depth\ncamera_matrix:\n  rows: 3\n  cols: 3\n"
         "  data: [525.0, 0.0, 319.5, 0.0, 520.5, 239.25, 0.0, 0.0, 1.0]\ndistortion_model: plumb_bob\n"
         "distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [0, 0, 0, 0, 0]\n"),
        ("ros2_camera_info.yaml",
         "header:\n  frame_id: camera\nheight: 480\nwidth: 640\ndistortion_model: plumb_bob\nd: [0.0, 0.0, 0.0, 0.0, 0.0]\n"
         "k: [525.0, 0.0, 319.5, 0.0, 520.5, 239.25, 0.0, 0.0, 1.0]\nr: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n"
         "p: [525.0, 0.0, 319.5, 0.0, 0.0, 520.5, 239.25, 0.0, 0.0, 0.0, 1.0, 0.0]\n"),
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
    old = write(tmp_path, "old.yml", "%YAML:1.0\nK: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
                "   data: [ 525., 0., 319.5, 0., 520.5, 239.25, 0., 0., 1. ]\n")
    assert read_intrinsics(old) == CAM
    other = write(tmp_path, "other.yml", "%YAML:1.0\nR: !!opencv-matrix\n   rows: 1\n   cols: 1\n   dt: d\n   data: [ 1. ]\n")
    with pytest.raises(DataFileError, match=r"other.yml: expected an OpenCV matrix named camera_matrix, K or cameraMatrix"):
        read_intrinsics(other)


def test_3f2n_params_match_the_dataset_reader():
    path = sample_root() / "Easy" / "android" / "params.txt"
    assert read_intrinsics(path) == read_params(path) == Intrinsics(1400, 1380, 319, 259)


@pytest.mark.parametrize(
    "name, text, pattern",
    [
        ("bad.json", "{fx: 1", r"bad.json: cannot parse as JSON \(Expecting property name"),
        ("partial.json", '{"fx": 1, "fy": 2}', r"partial.json: expected all of fx, fy, cx, cy, got fx, fy without cx, cy"),
        ("other.json", '{"focal": 1}', r"other.json: expected fx, fy, cx, cy, or a 3x3 matrix K .*got keys focal"),
        ("list.json", "[1, 2, 3]", r"list.json: expected a mapping with fx, fy, cx, cy.*got list"),
        ("nan.json", '{"fx": NaN, "fy": 1, "cx": 0, "cy": 0}', r"nan.json: intrinsics.fx: expected a finite number, got nan"),
        ("zero.json", '{"fx": 0, "fy": 1, "cx": 0, "cy": 0}', r"zero.json: intrinsics.fx: expected a positive focal length"),
        ("text.json", '{"fx": "a", "fy": 1, "cx": 0, "cy": 0}', r"text.json: expected numbers for fx, fy, cx, cy"),
        ("k8.json", '{"K": [1, 0, 0, 0, 1, 0, 0, 0]}', r"k8.json: expected 9 numbers \(a 3x3 matrix\) for 'K', got 8"),
        ("kneg.json", json.dumps({"K": [-5, 0, 1, 0, 5, 1, 0, 0, 1]}), r"kneg.json: K: expected positive focal lengths.*fx=-5"),
        ("kinf.json", '{"K": [Infinity, 0, 1, 0, 5, 1, 0, 0, 1]}', r"kinf.json: K: expected finite entries"),
        ("skew.json", json.dumps({"K": [5, 1, 1, 0, 5, 1, 0, 0, 1]}), r"skew.json: K: expected \[\[fx, 0, cx\], \[0, fy, cy\], \[0, 0, 1\]\] \(no skew\)"),
        ("bad.yaml", "fx: [1\n", r"bad.yaml: cannot parse as YAML"),
        ("empty.yaml", "", r"empty.yaml: expected a mapping with fx, fy, cx, cy.*got NoneType"),
        ("few.txt", "1 2 3", r"few.txt: expected 4 or 5 numbers \(3F2N 'fx fy u0 v0 count'\), 9 \(a 3x3 K\) or 16 \(a 4x4 matrix\), got 3 numbers"),
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
    with pytest.raises(InputError, match=r"intrinsics: expected a file/matrix or --fx --fy --cx --cy, not both \(got fx too\)"):
        resolve_intrinsics(CAM, fx=1)
