"""cross_product (kornia's plain cross-product normals): the kernel against a naive reference, and known answers."""

from __future__ import annotations

import numpy as np
import pytest

import surfnorm
from surfnorm import InputError, Intrinsics


def naive_cross_product(depth, K, mask=None, fill=0.0):
    """The obvious loops: back-project every pixel, take the central differences, cross them, normalise."""
    depth = np.asarray(depth, np.float64)
    H, W = depth.shape
    fx, fy, cx, cy = K[0][0], K[1][1], K[0][2], K[1][2]
    valid = np.isfinite(depth) & (depth > 0)
    if mask is not None:
        valid &= mask
    out = np.full((H, W, 3), fill, np.float32)

    def point(v, u):
        z = depth[v, u]
        return np.array([z * (u - cx) / fx, z * (v - cy) / fy, z])

    for v in range(H):
        for u in range(W):
            if not valid[v, u]:
                continue
            usable = lambda vv, uu: 0 <= vv < H and 0 <= uu < W and valid[vv, uu]
            # central differences; one-sided beside a missing neighbour; none without either
            right, left = (u + 1 if usable(v, u + 1) else u), (u - 1 if usable(v, u - 1) else u)
            down, up = (v + 1 if usable(v + 1, u) else v), (v - 1 if usable(v - 1, u) else v)
            h = point(v, right) - point(v, left)
            d = point(down, u) - point(up, u)
            n = np.cross(d, h)
            norm = np.linalg.norm(n)
            if 0 < norm < np.inf:
                out[v, u] = n / norm
    return out


K = [[60.0, 0, 15.2], [0, 55.0, 11.7], [0, 0, 1]]


def random_scene(seed, h=24, w=31):
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:h, 0:w]
    z = 2.0 + 0.02 * u - 0.01 * v + 0.05 * rng.random((h, w))
    z[rng.random((h, w)) < 0.1] = rng.choice([0.0, np.nan, np.inf, -1.0])
    return z.astype(np.float32), rng.random((h, w)) > 0.05


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("fill", [0.0, np.nan])
def test_matches_the_naive_reference(seed, fill):
    z, mask = random_scene(seed)
    got = surfnorm.estimate(z, K, method="cross_product", mask=mask, fill=fill)
    expected = naive_cross_product(z, K, mask, fill)
    np.testing.assert_allclose(got, expected, atol=2e-6, equal_nan=True)


def test_a_tilted_plane_gets_its_normal_facing_the_camera():
    # the plane n . P = -1 with n = (0.3, -0.2, -0.9) normalised: depth z = -1 / (n . K^-1 [u, v, 1])
    H, W = 20, 26
    n = np.array([0.3, -0.2, -0.9]) / np.linalg.norm([0.3, -0.2, -0.9])
    cam = Intrinsics(50.0, 50.0, 12.5, 9.5)
    v, u = np.mgrid[0:H, 0:W]
    z = -1.0 / (n[0] * (u - cam.cx) / cam.fx + n[1] * (v - cam.cy) / cam.fy + n[2])
    z[7, 9] = 0.0  # a hole: its neighbours take one-sided differences, on a plane the same normal
    got = surfnorm.estimate(z.astype(np.float32), cam, method="cross_product", fill=np.nan)
    assert np.isnan(got[7, 9]).all()
    rest = got[~np.isnan(got[..., 0])]
    assert len(rest) == H * W - 1  # every valid pixel, the border included
    np.testing.assert_allclose(rest, np.broadcast_to(n, rest.shape), atol=1e-4)


def test_a_wall_faces_the_camera_and_a_pixel_without_neighbours_gets_the_fill_value():
    z = np.full((8, 9), 3.0, np.float32)
    z[4, 3] = z[4, 5] = 0.0  # (4, 4) has no horizontal neighbour left
    got = surfnorm.estimate(z, [[40.0, 0, 4.0], [0, 40.0, 3.5], [0, 0, 1]], method="cross_product", fill=-3.0)
    for v, u in ((4, 3), (4, 5), (4, 4)):
        assert (got[v, u] == -3.0).all(), (v, u)
    np.testing.assert_array_equal(got[2, 2], [0.0, 0.0, -1.0])
    np.testing.assert_array_equal(got[0, 0], [0.0, 0.0, -1.0])  # the corner: one-sided both ways


def test_registered_without_a_torch_twin():
    info = surfnorm.methods()["cross_product"]
    assert info.kernel == "surfnorm.kernels.cross_product.cross_product" and info.torch is False
    torch = pytest.importorskip("torch")
    import surfnorm.torch as st

    assert "cross_product" in st.NUMPY_ONLY and "cross_product" not in st.methods()
    with pytest.raises(InputError, match="cross_product.*no torch kernel"):
        st.estimate(torch.ones(1, 1, 4, 4), torch.eye(3), method="cross_product")
