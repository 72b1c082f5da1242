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
from surfnorm.demo import (
    CONTACT_SHEET,
    default_label,
    read_sensor_frame,
    run_demo,
    run_sensor_demo,
    sensor_root,
    write_contact_sheet,
)

SENSOR_SAMPLE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "sensor-sample" / "d435_080"
HAS_RGBD_NORMALS = hasattr(cv2, "RgbdNormals") and hasattr(cv2, "depthTo3d")


def test_shipped_frame_files_and_notice():
    root = sensor_root()
    assert sorted(p.name for p in root.iterdir()) == [
        "K.json",
        "LICENSE",
        "NOTICE",
        "depth.png",
        "meta.json",
        "planes.npz",
    ]
    assert sum(p.stat().st_size for p in root.iterdir()) < 1_000_000
    # the License's full text beside the frame: its title, all nine sections, the end of the terms, the appendix
    license_text = (root / "LICENSE").read_text()
    assert license_text.lstrip().startswith("Apache License\n") and "Version 2.0, January 2004" in license_text
    assert all(f"   {k}. " in license_text for k in range(1, 10)) and "END OF TERMS AND CONDITIONS" in license_text
    assert "APPENDIX: How to apply the Apache License to your work." in license_text
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


@pytest.mark.slow
def test_sensor_demo_default_beside_opencv(tmp_path):
    rows, skipped, picture = run_sensor_demo(tmp_path, repeats=1)
    frame = read_sensor_frame()
    by_name = {r.estimator: r for r in rows}
    default = rows[0]
    assert default.estimator == default_label()
    # the table's figure is the plane metric of what surfnorm.estimate(depth, K) returns
    expected = surfnorm.metrics.plane_error(
        surfnorm.estimate(frame.depth, frame.K), frame.plane_normals, frame.plane_masks
    )
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


@pytest.mark.slow
def test_cli_demo_prints_the_sensor_table(tmp_path, monkeypatch):
    monkeypatch.setattr(demo, "demo_methods", lambda: ["d2nt_basic"])  # the 3F2N part, kept short
    monkeypatch.delattr(cv2, "RgbdNormals", raising=False)
    result = CliRunner().invoke(app, ["demo", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    assert "RealSense D435" in result.output and default_label() in result.output
    assert "OpenCV RgbdNormals skipped" in result.output
    assert (tmp_path / "out" / "realsense-d435_normals.png").is_file()
    # the contact sheet, and the line that says where it is
    assert f"contact sheet (every frame and method on one picture): {tmp_path / 'out' / CONTACT_SHEET}" in result.output
    assert cv2.imread(str(tmp_path / "out" / CONTACT_SHEET)) is not None


def _rgb(path):
    return cv2.imread(str(path), cv2.IMREAD_COLOR)[:, :, ::-1]


@pytest.mark.slow
def test_contact_sheet_shows_every_frame_and_method(tmp_path):
    """One PNG beside the per-method files: each tile is that file at half size, each error tile's caption
    carries e_A (and the authors' figure), and the colour scale spans the error maps' 0 to 30 degrees."""
    from matplotlib import colormaps

    names = ["d2nt_basic", "cp2tv"]
    rows = run_demo(tmp_path, methods_=names)
    written = _rgb(tmp_path / CONTACT_SHEET)
    sheet = write_contact_sheet(tmp_path, rows)  # the same picture again, now with its layout
    assert sheet.path == tmp_path / CONTACT_SHEET
    np.testing.assert_array_equal(_rgb(sheet.path), written)
    frames = list(dict.fromkeys(r.frame for r in rows))
    assert len(frames) == 3 and len(rows) == 3 * len(names)
    expected = {(f, "", k) for f in frames for k in ("depth", "gt")}
    expected |= {(f, m, k) for f in frames for m in names for k in ("normals", "error")}
    assert set(sheet.tiles) == expected == set(sheet.captions)
    boxes = list(sheet.tiles.values()) + [sheet.scale]
    for i, (t, l, h, w) in enumerate(boxes):  # inside the picture, and no two overlap
        assert 0 <= t and t + h <= written.shape[0] and 0 <= l and l + w <= written.shape[1]
        for t2, l2, h2, w2 in boxes[i + 1 :]:
            assert t + h <= t2 or t2 + h2 <= t or l + w <= l2 or l2 + w2 <= l
    for (frame, method, kind), (t, l, h, w) in sheet.tiles.items():
        stem = frame.replace("/", "_")
        file = f"{stem}_{kind}.png" if not method else f"{stem}_{method}_{kind}.png"
        full = _rgb(tmp_path / file)
        assert (h, w) == (full.shape[0] // 2, full.shape[1] // 2)
        np.testing.assert_array_equal(
            written[t : t + h, l : l + w], cv2.resize(full, (w, h), interpolation=cv2.INTER_AREA)
        )
        assert (written[t : t + h, l : l + w] != 255).any()  # not an empty tile
    for r in rows:
        caption = sheet.captions[(r.frame, r.method, "error")]
        assert f"e_A {r.e_a:.3f} deg" in caption
        assert ("authors'" in caption) == (r.official is not None)
        assert r.official is None or f"[authors' {r.official:.3f}]" in caption
        assert sheet.captions[(r.frame, r.method, "normals")] == f"{r.method} normals"
    assert any(r.official is not None for r in rows)
    t, l, h, w = sheet.scale  # the bar: inferno from 0 (left) to 30 degrees (right), as the error maps
    for x, value in ((l, 0.0), (l + w - 1, 1.0)):
        np.testing.assert_array_equal(written[t + h // 2, x], np.rint(np.array(colormaps["inferno"](value)[:3]) * 255))
