"""surfnorm.points, to_opengl / from_opengl, to_world and surfnorm.io.normals_to_rgb."""

import numpy as np
import pytest

import surfnorm
from surfnorm import InputError
from surfnorm.io import normals_to_rgb, sample_frame


def naive_points(depth, fx, fy, cx, cy):
    """Back-projection written pixel by pixel from the pinhole model (0-based pixel centres)."""
    H, W = depth.shape
    out = np.zeros((H, W, 3))
    for v in range(H):
        for u in range(W):
            z = float(depth[v, u])
            if np.isfinite(z) and z > 0:
                out[v, u] = [(u - cx) / fx * z, (v - cy) / fy * z, z]
    return out


class TestPoints:
    def test_equals_naive_back_projection(self):
        rng = np.random.default_rng(0)
        depth = rng.uniform(0.5, 4.0, (17, 23))
        depth[3, 4], depth[5, 6], depth[7, 8] = 0.0, np.nan, -1.0
        K = [[300.0, 0, 10.2], [0, 310.0, 7.7], [0, 0, 1]]
        np.testing.assert_allclose(surfnorm.points(depth, K), naive_points(depth, 300.0, 310.0, 10.2, 7.7), rtol=1e-12)

    def test_on_the_sensor_sample_frame(self):
        depth, K = sample_frame("realsense-d435")
        depth = depth[::8, ::8]  # a cheap naive loop; K of the subsampled grid
        K2 = surfnorm.Intrinsics(K.fx / 8, K.fy / 8, K.cx / 8, K.cy / 8)
        np.testing.assert_allclose(
            surfnorm.points(depth, K2), naive_points(depth, K2.fx, K2.fy, K2.cx, K2.cy), rtol=1e-12, atol=0
        )

    def test_pixel_centre_is_zero_based(self):
        P = surfnorm.points(np.full((5, 7), 2.0), [[10.0, 0, 3.0], [0, 10.0, 2.0], [0, 0, 1]])
        assert P[2, 3].tolist() == [0.0, 0.0, 2.0]

    def test_mask_and_fill(self):
        mask = np.ones((4, 4), bool)
        mask[1, 1] = False
        P = surfnorm.points(np.ones((4, 4)), np.eye(3) * [1, 1, 1], mask=mask, fill=np.nan)
        assert np.isnan(P[1, 1]).all() and np.isfinite(P[0, 0]).all()

    def test_normals_are_perpendicular_to_a_plane_of_points(self):
        v, u = np.mgrid[0:48, 0:64].astype(float)
        K = np.array([[200.0, 0, 31.5], [0, 200.0, 23.5], [0, 0, 1]])
        n_true = np.array([0.3, -0.2, -1.0]) / np.linalg.norm([0.3, -0.2, -1.0])
        # plane n.P = -3 in the camera frame: z = -3 / (n . ray)
        rays = np.stack([(u - 31.5) / 200.0, (v - 23.5) / 200.0, np.ones_like(u)], -1)
        depth = -3.0 / (rays @ n_true)
        P = surfnorm.points(depth, K)
        np.testing.assert_allclose(P @ n_true, -3.0, rtol=1e-12)

    @pytest.mark.parametrize(
        "depth, K, needle",
        [
            (np.ones((2, 2, 2)), np.eye(3), "depth"),
            (np.ones((2, 2), bool), np.eye(3), "depth"),
            (np.ones((2, 2)), np.eye(2), "K"),
            (np.ones((2, 2)), [[1.0, 0, 0], [0, -1.0, 0], [0, 0, 1]], "K"),
        ],
    )
    def test_bad_input_names_the_argument(self, depth, K, needle):
        with pytest.raises(InputError, match=needle):
            surfnorm.points(depth, K)


class TestFrames:
    def test_to_opengl_flips_y_and_z_and_round_trips_exactly(self):
        rng = np.random.default_rng(1)
        for dtype in (np.float32, np.float64):
            n = rng.normal(size=(13, 9, 3)).astype(dtype)
            n[0, 0] = 0.0  # the fill value stays
            gl = surfnorm.to_opengl(n)
            assert gl.dtype == dtype
            np.testing.assert_array_equal(gl, n * np.array([1, -1, -1], dtype))
            np.testing.assert_array_equal(surfnorm.from_opengl(gl), n)
            np.testing.assert_array_equal(surfnorm.to_opengl(surfnorm.from_opengl(n)), n)
            assert not np.shares_memory(gl, n)

    def test_facing_camera_means_positive_z_in_opengl(self):
        depth, K = sample_frame("3f2n-easy")
        n = surfnorm.estimate(depth, K, method="d2nt_basic")
        has = np.any(n != 0, axis=-1)
        assert (surfnorm.to_opengl(n)[has][:, 2] > 0).mean() > 0.99

    def test_to_world_rotates_and_keeps_unit_length(self):
        rng = np.random.default_rng(2)
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        R = q * np.sign(np.linalg.det(q))
        n = rng.normal(size=(5, 3))
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        w = surfnorm.to_world(n, R)
        np.testing.assert_allclose(w, np.einsum("ij,kj->ki", R, n), atol=1e-14)
        np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1.0, atol=1e-14)
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = R, [5.0, -2.0, 1.0]  # the translation does not move directions
        np.testing.assert_allclose(surfnorm.to_world(n, pose), w, atol=0)

    @pytest.mark.parametrize(
        "R, message",
        [
            (np.eye(3) * 2, r"R: expected a rotation \(orthonormal, determinant \+1\), got"),
            (np.diag([1.0, 1.0, -1.0]), r"R: expected a rotation \(orthonormal, determinant \+1\), got"),
            (np.eye(2), r"R: expected a finite 3x3 rotation \(or a 4x4 pose\), got shape \(2, 2\)"),
            (np.full((3, 3), np.nan), r"R: expected a finite 3x3 rotation \(or a 4x4 pose\), got"),
        ],
    )
    def test_to_world_refuses_what_is_not_a_rotation(self, R, message):
        with pytest.raises(InputError, match=message):
            surfnorm.to_world(np.zeros((2, 3)), R)

    def test_bad_vectors(self):
        with pytest.raises(InputError, match="normals"):
            surfnorm.to_opengl(np.zeros((4, 2)))


def test_normals_to_rgb_is_the_pictures_colouring():
    depth, K = sample_frame("3f2n-hard")
    n = surfnorm.estimate(depth, K, method="d2nt_basic")
    rgb = normals_to_rgb(n)
    assert rgb.shape == depth.shape + (3,) and rgb.dtype == np.uint8
    has = np.any(n != 0, axis=-1)
    np.testing.assert_array_equal(rgb[has], np.clip(np.rint((1 - n[has]) / 2 * 255), 0, 255).astype(np.uint8))
    assert (rgb[~has] == 255).all()
    with pytest.raises(InputError, match="normals"):
        normals_to_rgb(n[..., :2])
