"""surfnorm.bench.simulate: seeded sensor depth from exact depth; each effect checked on small scenes."""

from __future__ import annotations

import numpy as np
import pytest

from surfnorm.bench.simulate import SENSORS, Sensor, frame_seed, metres_per_unit, simulate
from surfnorm.errors import InputError

K = [[500.0, 0.0, 31.5], [0.0, 500.0, 23.5], [0.0, 0.0, 1.0]]


def wall(z=10.0, shape=(48, 64)):
    return np.full(shape, z, np.float32)


def step_scene():
    """A near box (depth 8) in front of a far wall (depth 10), in 3F2N-like units."""
    z = wall(10.0)
    z[16:32, 20:40] = 8.0
    return z


@pytest.mark.parametrize("sensor", list(SENSORS))
def test_same_seed_same_output_and_other_seed_differs(sensor):
    z = step_scene()
    a = simulate(z, K, sensor, seed=frame_seed(0, "f", sensor))
    b = simulate(z, K, sensor, seed=frame_seed(0, "f", sensor))
    assert a.dtype == np.float32 and a.shape == z.shape
    assert np.array_equal(a, b)
    if sensor != "exact":
        assert not np.array_equal(a, simulate(z, K, sensor, seed=frame_seed(1, "f", sensor)))


def test_exact_is_the_depth_in_metres_with_the_median_at_the_sensor_distance():
    z = step_scene()
    s = SENSORS["exact"]
    out = simulate(z, K, "exact", seed=0)
    scale = metres_per_unit(z, "exact")
    assert scale == pytest.approx(s.distance_m / np.median(z))
    np.testing.assert_allclose(out, z * scale, rtol=1e-6)
    np.testing.assert_allclose(simulate(z, K, "exact", seed=0, scale=0.5), z * 0.5, rtol=1e-6)


def test_background_outside_the_mask_gets_no_depth():
    z = step_scene()
    mask = z < 9
    out = simulate(z, K, "exact", seed=0, mask=mask)
    assert np.all(out[~mask] == 0) and np.all(out[mask] > 0)


def test_structured_light_depth_falls_on_disparity_terraces():
    # No noise, no edges: a tilted plane's depth takes only values f B / (k q), q = 1/8 pixel
    s = Sensor("sl", "test", "disparity", distance_m=2.0, focal_px=500.0, baseline_m=0.075, disparity_step_px=1 / 8)
    v, u = np.mgrid[0:48, 0:64].astype(np.float32)
    z = 10.0 + 0.05 * u  # a plane tilted about the vertical axis
    out = simulate(z, K, s, seed=0).astype(np.float64)
    d = 500.0 * 0.075 / out  # disparity of the output, pixels of this frame
    np.testing.assert_allclose(d * 8, np.round(d * 8), atol=1e-3)
    # the terraces: fewer distinct depths than pixels, and steps of z^2 / (f B 8) metres
    zm = np.unique(out)
    assert 3 < zm.size < 64
    steps = np.diff(zm)
    np.testing.assert_allclose(steps, zm[:-1] * zm[1:] / (500.0 * 0.075 * 8), rtol=0.02)


def test_metric_noise_is_scaled_to_the_pixel_spacing_of_the_sensor():
    # range noise sigma = a (head-on, on the optical axis) times focal_px / f
    s = Sensor("r", "test", "range", distance_m=2.0, focal_px=250.0, range_noise_m=0.01)
    z = wall(10.0, (200, 200))
    Kc = [[500.0, 0.0, 99.5], [0.0, 500.0, 99.5], [0.0, 0.0, 1.0]]
    out = simulate(z, Kc, s, seed=0)
    centre = out[80:120, 80:120].astype(np.float64)
    assert centre.std() == pytest.approx(0.01 * 250.0 / 500.0, rel=0.15)
    assert np.mean(centre) == pytest.approx(2.0, abs=0.002)


def test_shadow_falls_beside_the_near_box_on_one_side_only():
    s = Sensor("sh", "test", "disparity", distance_m=2.0, focal_px=500.0, baseline_m=0.075, shadow=True)
    z = step_scene()
    out = simulate(z, K, s, seed=0)
    # box at 1.6 m, wall at 2 m: disparities 500 * 0.075 / z = 23.4 and 18.75 px: a 4-5 pixel shadow
    rows = slice(16, 32)
    assert np.all(out[rows, 40:44] == 0) and np.all(out[rows, 45:] > 0)
    assert np.all(out[rows, 20:40] > 0) and np.all(out[rows, :20] > 0)  # the box and the other side are seen


def test_flying_pixels_lie_between_the_two_sides_and_dropouts_only_at_edges():
    s = Sensor("fl", "test", "range", distance_m=2.0, focal_px=500.0, flying=1.0, edge_dropout=0.0)
    z = step_scene()
    out = simulate(z, K, s, seed=0).astype(np.float64)
    scale = 2.0 / np.median(z)
    near, far = 8.0 * scale, 10.0 * scale
    moved = np.abs(out - z * scale) > 1e-6
    assert moved.any()
    # only pixels of the box's rim moved, each to a depth between the box and the wall
    rim = np.zeros_like(moved)
    rim[16:32, 20:40] = True
    rim[17:31, 21:39] = False
    assert np.all(moved <= rim)
    assert np.all((out[moved] >= near - 1e-6) & (out[moved] <= far + 1e-6))
    d = Sensor("dr", "test", "range", distance_m=2.0, focal_px=500.0, edge_dropout=1.0)
    lost = simulate(z, K, d, seed=0) == 0
    assert lost.any() and np.all(lost <= rim)


def test_lidar_keeps_about_a_fifth_of_the_pixels_along_scanlines():
    z = wall(10.0, (300, 400))
    Kc = [[500.0, 0.0, 199.5], [0.0, 500.0, 149.5], [0.0, 0.0, 1.0]]
    out = simulate(z, Kc, "lidar", seed=3)
    valid = out > 0
    assert 0.17 < valid.mean() < 0.23
    # range noise of 1.5 cm scaled by 721 / 500 (plus 1/256 m steps) around 14 m
    err = out[valid] - 14.0
    assert abs(np.median(err)) < 0.01 and 0.015 < err.std() < 0.03


def test_bad_input_names_the_argument():
    with pytest.raises(InputError, match="sensor: expected one of kinect_v1"):
        simulate(wall(), K, "kinect_v9", seed=0)
    with pytest.raises(InputError, match="depth: expected some valid"):
        simulate(np.zeros((8, 8), np.float32), K, "tof", seed=0)
    with pytest.raises(InputError, match="normals: expected shape"):
        simulate(wall(), K, "tof", seed=0, normals=np.zeros((4, 4, 3)))
    with pytest.raises(InputError, match="scale: expected a positive"):
        simulate(wall(), K, "tof", seed=0, scale=-1.0)


def test_sensor_names_skip_empty_items_and_name_every_unknown_one():
    from surfnorm.bench.simulate import SENSORS, sensor_names

    assert sensor_names("kinect_v1,,tof,") == ["kinect_v1", "tof"]
    with pytest.raises(InputError) as info:
        sensor_names("kinect_v1,sonar,kinect_v9")
    assert str(info.value) == f"--sensors: expected some of {', '.join(SENSORS)}, got sonar, kinect_v9"


def test_the_stereo_preset_through_other_matchers():
    """The matcher's block and kind (benchmarks/stereo_matchers.py): the preset's own (5x5 SGBM) to the bit when named;
    another block, or OpenCV's block matcher, another disparity from the same pair, as dense and at the same depth."""
    from dataclasses import replace

    v, u = np.mgrid[0:96, 0:128].astype(np.float32)
    z = 10.0 + 0.02 * u + 0.01 * v  # a tilted plane
    preset = SENSORS["stereo_sgbm"]
    Kw = [[500.0, 0.0, 63.5], [0.0, 500.0, 47.5], [0.0, 0.0, 1.0]]
    seed = frame_seed(0, "plane", "stereo_sgbm")
    base = simulate(z, Kw, "stereo_sgbm", seed=seed)
    assert preset.matcher_block == 5 and preset.matcher_kind == "sgbm"
    np.testing.assert_array_equal(simulate(z, Kw, replace(preset, matcher_block=5), seed=seed), base)
    wide = simulate(z, Kw, replace(preset, matcher_block=9), seed=seed)
    bm = simulate(z, Kw, replace(preset, matcher_kind="bm", matcher_block=9), seed=seed)
    inner = np.s_[16:-16, 56:-8]  # away from the left border that the matchers leave empty (disparities to 48)
    for other in (wide, bm):
        assert (other[inner] > 0).mean() > 0.9 and not np.array_equal(other, base)
        np.testing.assert_allclose(np.median(other[inner]), np.median(base[inner]), rtol=0.02)
    assert not np.array_equal(wide, bm)
    with pytest.raises(InputError, match="matcher_kind: expected 'sgbm' or 'bm', got 'census'"):
        replace(preset, matcher_kind="census")
    for kind, block in (("sgbm", 4), ("bm", 3), ("sgbm", 5.0)):
        with pytest.raises(InputError, match=f"matcher_block: expected an odd number of pixels .* got {block!r}"):
            replace(preset, matcher_kind=kind, matcher_block=block)
