"""AreaWeighted and AngleWeighted (surfnorm.kernels.averaging) against naive references and closed-form surfaces."""

from __future__ import annotations

import numpy as np
import pytest

import surfnorm
from surfnorm import _api
from surfnorm.errors import InputError
from surfnorm.kernels.averaging import RING

from . import surfaces
from .naive_averaging import averaging as naive_averaging
from .naive_plane_fit import points
from .test_plane_fit import H, K, W, angle, errors_by_resolution, rough_depth, smooth_depth

METHODS = {"area_weighted": "area", "angle_weighted": "angle"}


def compare(depth, method, mask=None, fill=0.0):
    ours = surfnorm.estimate(depth, K, method=method, mask=mask, fill=fill)
    ref = naive_averaging(depth, K, METHODS[method], mask=mask, fill=fill)
    has_ref = np.any(ref != fill, axis=-1) if np.isfinite(fill) else np.all(np.isfinite(ref), axis=-1)
    has_ours = np.any(ours != fill, axis=-1) if np.isfinite(fill) else np.all(np.isfinite(ours), axis=-1)
    assert np.array_equal(has_ref, has_ours)
    return ours, ref, angle(ours[has_ref], ref[has_ref])


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("seed", [0, 1])
def test_agrees_with_naive_on_smooth_depth(method, seed):
    ours, ref, err = compare(smooth_depth(seed), method)
    assert err.max() < 1e-3  # degrees; float32 output
    assert np.all(ours[..., 2] < 0)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("seed", [2, 3])
def test_agrees_with_naive_on_steps_and_holes(method, seed):
    depth, mask = rough_depth(seed)
    ours, ref, err = compare(depth, method, mask=mask, fill=np.nan)
    assert err.max() < 1e-3
    invalid = ~(np.isfinite(depth) & (depth > 0) & mask)
    assert np.all(np.isnan(ours[invalid]))


@pytest.mark.parametrize("method", METHODS)
def test_every_normal_faces_the_camera(method):
    # Triangle normals of a counter-clockwise ring face the camera whatever the depth does.
    depth, mask = rough_depth(7)
    depth = np.where(np.isfinite(depth), depth, 0.0) * np.random.default_rng(7).uniform(0.5, 1.5, depth.shape)
    out = surfnorm.estimate(depth, K, method=method, mask=mask)
    P = points(np.asarray(depth, dtype=np.float32), K)
    has = np.any(out != 0, axis=-1)
    assert np.all(np.einsum("hwc,hwc->hw", out, P)[has] < 0)


def test_ring_is_counter_clockwise_on_screen():
    assert len(set(RING)) == 8 and (0, 0) not in RING
    # screen coordinates (x right, y up) = (du, -dv): angles increase by 45 degrees
    angles = [np.degrees(np.arctan2(-dv, du)) % 360 for dv, du in RING]
    assert angles == [0, 45, 90, 135, 180, 225, 270, 315]


@pytest.mark.parametrize("method", METHODS)
def test_triangle_needs_both_neighbours(method):
    depth = np.zeros((H, W))
    depth[5, 5] = 2.0
    depth[5, 6] = 2.0  # right neighbour only: no triangle
    out = surfnorm.estimate(depth, K, method=method, fill=np.nan)
    assert np.all(np.isnan(out))
    depth[4, 5] = 2.0  # up: still no consecutive pair at (5, 5) (right, up-right, up)
    out = surfnorm.estimate(depth, K, method=method, fill=np.nan)
    assert np.all(np.isnan(out[5, 5]))
    depth[4, 6] = 2.0  # up-right: two triangles (right, up-right), (up-right, up)
    out = surfnorm.estimate(depth, K, method=method, fill=np.nan)
    np.testing.assert_allclose(out[5, 5], [0, 0, -1], atol=1e-6)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize(
    "normal", [(0, 0, -1), (0.3, -0.2, -0.9), (-0.7, 0.1, -0.5), (0.0, 0.8, -0.3), (0.5, 0.5, -0.2)]
)
def test_exact_on_planes(method, normal):
    depth, n_true, hit = surfaces.plane(K, H, W, normal, 2.0)
    out = surfnorm.estimate(depth, K, method=method)
    assert angle(out[hit], n_true[hit]).max() < 2e-3  # float32 depth and output
    assert np.all(out[~hit] == 0.0)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("surface", ["sphere", "cylinder"])
def test_error_falls_with_resolution(method, surface):
    errors = errors_by_resolution(method, surface)
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 0.5 * errors[0]
    assert errors[2] < 0.5


def test_area_and_angle_weights_differ():
    depth, mask = rough_depth(8)
    a = surfnorm.estimate(depth, K, method="area_weighted", mask=mask)
    b = surfnorm.estimate(depth, K, method="angle_weighted", mask=mask)
    assert np.nanmax(angle(a, b)) > 1.0


@pytest.mark.parametrize("method", METHODS)
def test_mnr(method):
    depth, mask = rough_depth(6)
    refined = surfnorm.estimate(depth, K, method=method + "+mnr", mask=mask)
    raw = surfnorm.estimate(depth, K, method=method, mask=mask)
    assert np.array_equal(refined, _api.refine(raw, depth, mask=mask))


def test_registered_with_category_and_reference():
    info = surfnorm.methods()
    for method in METHODS:
        assert info[method].category == "averaging"
        assert info[method].options == {"fill": 0.0}
    assert "Klasing" in info["area_weighted"].reference
    assert "Jin" in info["angle_weighted"].reference


def test_window_option_is_refused():
    with pytest.raises(
        InputError, match=r"options of method 'angle_weighted': expected some of fill, got unknown option\(s\) window"
    ):
        surfnorm.estimate(smooth_depth(0), K, method="angle_weighted", window=5)


def test_bad_fill_is_refused():
    with pytest.raises(InputError, match=r"fill: expected a number .*, got 'zero'"):
        surfnorm.estimate(smooth_depth(0), K, method="area_weighted", fill="zero")


def test_angle_polynomial_matches_arctan2():
    from surfnorm.kernels.averaging import angle_from

    rng = np.random.default_rng(0)
    s = np.abs(rng.normal(size=4000)) * 10.0 ** rng.uniform(-8, 8, 4000)
    c = rng.normal(size=4000) * 10.0 ** rng.uniform(-8, 8, 4000)
    edge = [(0.0, 1.0), (0.0, -1.0), (1.0, 0.0), (1.0, 1.0), (1.0, -1.0), (np.tan(np.pi / 8), 1.0), (3.0, -1e-300)]
    s = np.r_[s, [a for a, _ in edge]]
    c = np.r_[c, [b for _, b in edge]]
    got = np.array([angle_from(a, b) for a, b in zip(s, c)])
    assert np.abs(got - np.arctan2(s, c)).max() < 1e-12
    assert angle_from(0.0, 0.0) == 0.0  # no triangle: a finite weight that multiplies a zero normal
