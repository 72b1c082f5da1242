"""Your own camera: the sample frames, the sensor recipes (stand-in objects), and IntrinsicsWarning."""

import json
import warnings
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

import surfnorm
from surfnorm import InputError, Intrinsics, IntrinsicsWarning
from surfnorm.io import read_depth, read_intrinsics, sample_frame, sample_frames, write_sample
from surfnorm.io.threef2n import read_frame, sample_root

SENSOR_SAMPLE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "sensor-sample"
README_K = np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]])


# ---------------------------------------------------------------------------- sample frames


def test_sample_frames_are_data():
    names = list(sample_frames())
    assert names == ["realsense-d435", "3f2n-easy", "3f2n-medium", "3f2n-hard"]
    for name in names:
        depth, K = sample_frame(name)
        assert depth.dtype == np.float32 and depth.ndim == 2
        assert (K.width, K.height) == (depth.shape[1], depth.shape[0])
        assert np.all(np.isfinite(depth)) and (depth >= 0).all() and (depth > 0).mean() > 0.05


def test_sample_frame_d435_is_the_demo_frame_in_metres():
    from surfnorm.demo import read_sensor_frame

    depth, K = sample_frame("realsense-d435")
    frame = read_sensor_frame()
    np.testing.assert_array_equal(depth, frame.depth)
    assert K == frame.K and depth.shape == (720, 1280)
    assert 0.2 < np.median(depth[depth > 0]) < 3.0  # metres, a table-top scene


def test_sample_frame_3f2n_is_the_foreground_of_the_dataset_frame():
    depth, K = sample_frame("3f2n-medium")
    frame = read_frame(sample_root(), "Medium/Trex/000001")
    np.testing.assert_array_equal(depth[frame.mask], frame.depth[frame.mask])
    assert (depth[~frame.mask] == 0).all() and K == frame.K


def test_sample_frame_unknown_name():
    with pytest.raises(InputError, match="name: expected one of realsense-d435"):
        sample_frame("kinect")


def test_write_sample_round_trips_in_millimetres(tmp_path):
    png, js = write_sample("realsense-d435", tmp_path / "frame.png")
    depth, K = sample_frame("realsense-d435")
    back = read_depth(png, depth_scale=1000)
    assert np.abs(back - depth).max() <= 0.0005 + 1e-7
    assert read_intrinsics(js) == K and read_intrinsics(js).width == 1280
    with pytest.raises(InputError, match=r"^path: expected a file name ending in .png, got '.*frame.npy'$"):
        write_sample("3f2n-easy", tmp_path / "frame.npy")
    for bad in (0, -1000.0, "1000", float("nan")):
        with pytest.raises(InputError, match="depth_scale: expected a positive finite number"):
            write_sample("3f2n-easy", tmp_path / "frame.png", depth_scale=bad)
    with pytest.raises(InputError, match="depth_scale: expected at most"):
        write_sample("realsense-d435", tmp_path / "frame.png", depth_scale=1e6)


# ---------------------------------------------------------------------------- recipes


def test_from_realsense_reads_rs_intrinsics():
    # a stand-in of pyrealsense2.intrinsics: the attributes librealsense's Python binding has
    intr = SimpleNamespace(width=848, height=480, ppx=421.7, ppy=238.2, fx=427.1, fy=427.1, model=None, coeffs=[0] * 5)
    K = Intrinsics.from_realsense(intr)
    assert (K.fx, K.fy, K.cx, K.cy, K.width, K.height) == (427.1, 427.1, 421.7, 238.2, 848, 480)
    with pytest.raises(InputError, match="intr: expected pyrealsense2 intrinsics .* without ppx, ppy"):
        Intrinsics.from_realsense(SimpleNamespace(fx=1.0, fy=1.0, width=2, height=2))


def test_realsense_depth_scale_is_the_inverse_of_ours(tmp_path):
    raw = np.array([[0, 1000], [2500, 65535]], np.uint16)  # what get_data() gives
    rs_scale = 0.001  # depth_sensor.get_depth_scale(): metres per unit
    cv2.imwrite(str(tmp_path / "d.png"), raw)
    np.testing.assert_allclose(read_depth(tmp_path / "d.png", depth_scale=1 / rs_scale), raw * rs_scale, rtol=1e-6)


@pytest.mark.parametrize("key", ["k", "K"])
def test_from_camera_info_ros1_and_ros2(key):
    msg = SimpleNamespace(width=640, height=480, **{key: (570.3, 0.0, 319.5, 0.0, 570.3, 239.5, 0.0, 0.0, 1.0)})
    K = Intrinsics.from_camera_info(msg)
    assert K == Intrinsics(570.3, 570.3, 319.5, 239.5) and (K.width, K.height) == (640, 480)
    assert K.matrix[0, 2] == 319.5


def test_from_camera_info_errors_name_the_field():
    with pytest.raises(InputError, match="msg: expected a sensor_msgs/CameraInfo"):
        Intrinsics.from_camera_info(SimpleNamespace(width=1, height=1))
    with pytest.raises(InputError, match="msg.k: expected 9 numbers"):
        Intrinsics.from_camera_info(SimpleNamespace(k=[1.0, 2.0], width=1, height=1))
    uncalibrated = SimpleNamespace(k=[5.0, 0, 1, 0, 5.0, 1, 0, 0, 1], width=0, height=0)
    assert Intrinsics.from_camera_info(uncalibrated).width is None


@pytest.mark.parametrize(
    "sensor, scale",
    [("kitti", 256.0), ("tum", 5000.0), ("azure-kinect", 1000.0), ("realsense", 1000.0)],
)
def test_sixteen_bit_png_of_each_sensor_reads_in_metres(tmp_path, sensor, scale):
    metres = np.array([[0.0, 1.25], [3.5, 12.0]])
    png = tmp_path / f"{sensor}.png"
    cv2.imwrite(str(png), np.rint(metres * scale).astype(np.uint16))
    np.testing.assert_allclose(read_depth(png, depth_scale=scale), metres, atol=0.5 / scale)


def test_nyu_raw_disparity_recipe(tmp_path):
    d = np.array([[2047, 700], [800, 900]], np.uint16)  # raw 11-bit disparity; 2047: no reading
    pgm = tmp_path / "d-1.pgm"
    cv2.imwrite(str(pgm), d.byteswap())  # NYU's dumps are little-endian; OpenCV writes big-endian
    z = read_depth(pgm, kinect_disparity=True, byte_order="little")
    np.testing.assert_allclose(z, np.where(d == 2047, 0.0, 351.3 / (1092.5 - d.astype(float))), rtol=1e-5)


def test_ros_camera_info_yaml_keeps_the_image_size(tmp_path):
    pytest.importorskip("yaml")
    path = tmp_path / "camera_info.yaml"
    path.write_text(
        "image_width: 640\nimage_height: 480\ncamera_name: c\n"
        "camera_matrix:\n  rows: 3\n  cols: 3\n  data: [525.0, 0, 319.5, 0, 525.0, 239.5, 0, 0, 1]\n"
    )
    K = read_intrinsics(path)
    assert (K.width, K.height) == (640, 480)
    with pytest.warns(IntrinsicsWarning, match="for a 640x480 image, but the frame is 1280x720"):
        surfnorm.estimate(np.ones((720, 1280)), K, method="d2nt_basic")


# ---------------------------------------------------------------------------- IntrinsicsWarning


def test_warning_for_the_readme_intrinsics_on_a_1280x720_frame():
    depth, _ = sample_frame("realsense-d435")
    with pytest.warns(IntrinsicsWarning, match="centre of a 640x480 image") as caught:
        surfnorm.estimate(depth, README_K, method="d2nt_basic")
    assert caught[0].filename == __file__  # points at the caller's line
    assert issubclass(IntrinsicsWarning, UserWarning)


def test_warning_for_a_principal_point_outside_the_frame_and_for_stacks():
    K = [[500.0, 0, 719.5], [0, 500.0, 539.5], [0, 0, 1]]  # 1440x1080 intrinsics on a 640x480 frame
    with pytest.warns(IntrinsicsWarning, match=r"principal point \(719.5, 539.5\) lies outside the 640x480 frame"):
        surfnorm.estimate(np.ones((480, 640)), K, method="d2nt_basic")
    with pytest.warns(IntrinsicsWarning, match="K: "):
        surfnorm.estimate(np.ones((2, 480, 640)), K, method="d2nt_basic")
    with pytest.warns(IntrinsicsWarning, match=r"K\[1\]: "):
        surfnorm.estimate(np.ones((2, 480, 640)), [Intrinsics(500.0, 500.0, 319.5, 239.5), K], method="d2nt_basic")


def test_warning_can_be_silenced_by_the_usual_means():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", category=IntrinsicsWarning)
        surfnorm.estimate(np.ones((720, 1280)), README_K, method="d2nt_basic")


def test_no_warning_for_the_shipped_frames_with_their_own_intrinsics():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for name in sample_frames():
            depth, K = sample_frame(name)
            K.check_frame(depth.shape)
            surfnorm.estimate(depth[:64, :64], Intrinsics(K.fx, K.fy, 31.5, 31.5), method="d2nt_basic")


def test_no_warning_for_the_3f2n_frames_with_their_own_intrinsics():
    """The dataset's renders have principal points up to 37 % of the height off centre on one axis."""
    from surfnorm.io.threef2n import find_frames, read_frame

    from .conftest import SAMPLE

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for name in find_frames(SAMPLE):
            frame = read_frame(SAMPLE, name)
            frame.K.check_frame(frame.depth.shape)


@pytest.mark.skipif(not SENSOR_SAMPLE.is_dir(), reason="the sensor sample is not beside the repository")
def test_no_warning_for_any_frame_of_the_sensor_sample():
    frames = sorted(p for p in SENSOR_SAMPLE.iterdir() if (p / "K.json").is_file())
    assert len(frames) >= 8
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for folder in frames:
            depth = np.load(folder / "depth.npy")
            K = Intrinsics(**json.loads((folder / "K.json").read_text()))
            K.check_frame(depth.shape)
            surfnorm.estimate(depth, K, method="d2nt_basic")


def test_opencv_calibration_yaml_keeps_the_image_size(tmp_path):
    path = tmp_path / "calib.yml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 1280)
    fs.write("image_height", 720)
    fs.write("camera_matrix", np.array([[921.0, 0, 642.0], [0, 921.0, 359.0], [0, 0, 1]]))
    fs.release()
    K = read_intrinsics(path)
    assert (K.fx, K.cx, K.width, K.height) == (921.0, 642.0, 1280, 720)
    with pytest.warns(IntrinsicsWarning, match="for a 1280x720 image, but the frame is 640x480"):
        K.check_frame((480, 640))


def test_the_torch_backend_warns_alike_for_intrinsics_it_can_read():
    torch = pytest.importorskip("torch")
    import surfnorm.torch

    depth = torch.ones(48, 64, dtype=torch.float64) * 2
    with pytest.warns(IntrinsicsWarning, match="outside the 64x48 frame") as caught:
        surfnorm.torch.estimate(depth, [[60.0, 0, 100.5], [0, 60.0, 23.5], [0, 0, 1]], method="d2nt_basic")
    assert caught[0].filename == __file__
    with pytest.warns(IntrinsicsWarning, match="for a 640x480 image"):
        surfnorm.torch.estimate(depth, Intrinsics(60.0, 60.0, 31.5, 23.5, 640, 480), method="d2nt_basic")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        surfnorm.torch.estimate(depth, Intrinsics(60.0, 60.0, 31.5, 23.5, 64, 48), method="d2nt_basic")
        surfnorm.torch.estimate(
            depth, torch.tensor([[60.0, 0, 100.5], [0, 60.0, 23.5], [0, 0, 1]]), method="d2nt_basic"
        )


def test_an_image_size_needs_both_width_and_height():
    with pytest.raises(
        InputError, match=r"^intrinsics.width, height: expected both or neither, got width=640, height=None$"
    ):
        Intrinsics(500.0, 500.0, 319.5, 239.5, 640, None)
