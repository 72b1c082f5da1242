"""`surfnorm demo` on the RealSense D435 frame shipped inside surfnorm (present in every clone)."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

import surfnorm
from surfnorm import demo
from surfnorm.cli import app
from surfnorm.demo import default_label, read_sensor_frame, run_sensor_demo, sensor_root

SENSOR_SAMPLE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "sensor-sample" / "d435_080"
HAS_RGBD_NORMALS = hasattr(cv2, "RgbdNormals") and hasattr(cv2, "depthTo3d")


def test_shipped_frame_files_and_notice():
    root = sensor_root()
    assert sorted(p.name for p in root.iterdir()) == ["K.json", "NOTICE", "depth.png", "meta.json", "planes.npz"]
    assert sum(p.stat().st_size for p in root.iterdir()) < 1_000_000
    notice = (root / "NOTICE").read_text()
    assert "Shreeyak/cleargrasp" in notice and "000000080-opaque-depth-img.exr" in notice
    assert "Apache License, Version 2.0" in notice and "http://www.apache.org/licenses/LICENSE-2.0" in notice
    assert "cleargrasp" in json.loads((root / "meta.json").read_text())["source"]
    # the NYU and KITTI frames of the sensor sample may not ship
    assert not [p for p in sensor_root().parent.rglob("*") if "nyu" in p.name.lower() or "kitti" in p.name.lower()]


def test_shipped_frame_reads():
    frame = read_sensor_frame()
    assert frame.depth.shape == (720, 1280) and frame.depth.dtype == np.float32
    valid = frame.depth > 0
    assert 0.85 < valid.mean() < 0.95 and 0.4 < np.median(frame.depth[valid]) < 0.8  # metres, holes are 0
    assert (frame.K.fx, frame.K.fy, frame.K.cx, frame.K.cy) == (921.0, 921.0, 642.0, 359.0)
    P = frame.plane_normals.shape[0]
    assert frame.plane_masks.shape == (P, 720, 1280) and P >= 2
    np.testing.assert_allclose(np.linalg.norm(frame.plane_normals, axis=1), 1.0, atol=1e-6)
    assert (frame.plane_normals[:, 2] < 0).all()  # facing the camera
    assert not (frame.plane_masks & ~valid).any()  # reference pixels have depth


def test_shipped_frame_equals_the_published_depth():
    """The 0.1 mm PNG rounded to float16 gives ClearGrasp's EXR values back exactly."""
    if not (SENSOR_SAMPLE / "depth.npy").is_file():
        pytest.skip(f"the sensor sample is not at {SENSOR_SAMPLE}")
    frame = read_sensor_frame()
    np.testing.assert_array_equal(frame.depth, np.load(SENSOR_SAMPLE / "depth.npy"))
    with np.load(SENSOR_SAMPLE / "planes.npz") as planes:
        np.testing.assert_array_equal(frame.plane_normals, planes["normals"])
        np.testing.assert_array_equal(frame.plane_masks, planes["masks"])


def test_sensor_demo_default_beside_opencv(tmp_path):
    rows, skipped, picture = run_sensor_demo(tmp_path, repeats=1)
    frame = read_sensor_frame()
    by_name = {r.estimator: r for r in rows}
    default = rows[0]
    assert default.estimator == default_label()
    # the table's figure is the plane metric of what surfnorm.estimate(depth, K) returns
    expected = surfnorm.metrics.plane_error(surfnorm.estimate(frame.depth, frame.K), frame.plane_normals, frame.plane_masks)
    assert default.plane_error == pytest.approx(expected[0], abs=1e-5) and default.coverage == expected[1]
    assert 0 < default.plane_error < 45 and default.coverage > 0.9 and default.ms > 0
    if HAS_RGBD_NORMALS:
        assert skipped is None
        # the sensor sample's README: FALS w7 15.1, LINEMOD w5 13.8 degrees on this frame
        assert by_name["OpenCV RgbdNormals FALS w7"].plane_error == pytest.approx(15.1, abs=0.05)
        assert by_name["OpenCV RgbdNormals LINEMOD w5"].plane_error == pytest.approx(13.8, abs=0.05)
        assert by_name["OpenCV RgbdNormals LINEMOD w5"].coverage < 1.0  # LINEMOD leaves some plane pixels empty
    else:
        assert "cv2.RgbdNormals" in skipped and len(rows) == 1
    side = cv2.imread(str(picture), cv2.IMREAD_COLOR)
    assert picture.name == "realsense-d435_normals.png"
    assert side.shape[1] >= len(rows) * 640 and side.shape[0] == 360 + 36
    assert len(list(tmp_path.glob("realsense-d435_*_normals.png"))) == len(rows)


def test_sensor_demo_without_opencv_contrib(tmp_path, monkeypatch):
    """An OpenCV without cv2.RgbdNormals (4.x): the peers are skipped with the reason, the rest runs."""
    monkeypatch.delattr(cv2, "RgbdNormals", raising=False)
    rows, skipped, picture = run_sensor_demo(tmp_path, repeats=1)
    assert [r.estimator for r in rows] == [default_label()]
    assert "has no cv2.RgbdNormals" in skipped and "opencv-python-headless>=5" in skipped
    assert cv2.imread(str(picture)).shape == (360 + 36, 640, 3)


def test_sensor_demo_follows_the_default(tmp_path, monkeypatch):
    """The demo calls estimate(depth, K) with no method, so it shows whatever the default is."""
    calls = []
    real = demo.estimate

    def spy(depth, K, **kwargs):
        calls.append(kwargs)
        return real(depth, K, **kwargs)

    monkeypatch.setattr(demo, "estimate", spy)
    run_sensor_demo(tmp_path, peers=False, repeats=1)
    assert calls and all("method" not in c for c in calls)


def test_cli_demo_prints_the_sensor_table(tmp_path, monkeypatch):
    monkeypatch.setattr(demo, "demo_methods", lambda: ["d2nt_basic"])  # the 3F2N part, kept short
    monkeypatch.delattr(cv2, "RgbdNormals", raising=False)
    result = CliRunner().invoke(app, ["demo", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    assert "RealSense D435" in result.output and default_label() in result.output
    assert "OpenCV RgbdNormals skipped" in result.output
    assert (tmp_path / "out" / "realsense-d435_normals.png").is_file()
