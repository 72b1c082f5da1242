"""The front door: shapes, dtypes, conventions and every input error message."""

from __future__ import annotations

import numpy as np
import pytest

import surfnorm
from surfnorm import InputError

from .surfaces import camera, scene

K = np.array([[100.0, 0, 15.5], [0, 100.0, 11.5], [0, 0, 1]])


def wall(h=24, w=32, d=2.0):
    return np.full((h, w), d, dtype=np.float32)


class TestEstimate:
    def test_shape_dtype_and_facing(self):
        for name in surfnorm.methods():
            n = surfnorm.estimate(wall(), K, method=name)
            assert n.shape == (24, 32, 3) and n.dtype == np.float32
            np.testing.assert_allclose(n[5:-5, 5:-5], np.broadcast_to([0, 0, -1], (14, 22, 3)), atol=1e-6, err_msg=name)

    def test_input_not_modified_and_float64_accepted(self):
        d = wall().astype(np.float64)
        before = d.copy()
        surfnorm.estimate(d, K, method="d2nt_v3")
        np.testing.assert_array_equal(d, before)

    def test_integer_depth_accepted(self):
        d = np.full((24, 32), 2000, dtype=np.uint16)
        n = surfnorm.estimate(d, K, method="d2nt_basic")
        np.testing.assert_allclose(n[3:-3, 3:-3, 2], -1.0, atol=1e-6)

    def test_fill_value_for_invalid_pixels(self):
        d = wall()
        d[10, 10] = np.nan
        d[3, 4] = 0
        d[20, 7] = -1
        n = surfnorm.estimate(d, K, method="d2nt_v3")
        for v, u in [(10, 10), (3, 4), (20, 7)]:
            assert np.all(n[v, u] == 0.0)
        n = surfnorm.estimate(d, K, method="d2nt_basic", fill=np.nan)
        assert np.all(np.isnan(n[10, 10]))
        valid = np.isfinite(d) & (d > 0)
        np.testing.assert_allclose(np.linalg.norm(n[valid], axis=-1), 1.0, atol=1e-6)

    def test_mask_is_honoured(self):
        d = wall()
        mask = np.ones(d.shape, bool)
        mask[:, :5] = False
        n = surfnorm.estimate(d, K, method="d2nt_v2", mask=mask)
        assert np.all(n[:, :5] == 0) and np.all(n[:, 5:, 2] < 0)

    def test_all_invalid_gives_all_fill(self):
        n = surfnorm.estimate(np.zeros((5, 6)), K, method="d2nt_v3")
        assert np.all(n == 0)

    def test_isolated_pixel_has_no_normal(self):
        d = np.zeros((7, 7), np.float32)
        d[3, 3] = 1.0
        assert np.all(surfnorm.estimate(d, K, method="d2nt_basic")[3, 3] == 0)

    def test_batch_equals_frames(self):
        rng = np.random.default_rng(0)
        stack = (2 + rng.random((4, 20, 24))).astype(np.float32)
        Ks = np.stack([K * [[1 + i / 10], [1], [1]] for i in range(4)])
        Ks[:, 2] = [0, 0, 1]
        out = surfnorm.estimate(stack, Ks, method="d2nt_v3", threads=2)
        for i in range(4):
            np.testing.assert_array_equal(out[i], surfnorm.estimate(stack[i], Ks[i], method="d2nt_v3"))
        one_k = surfnorm.estimate(stack, K, method="d2nt_basic")
        np.testing.assert_array_equal(one_k[2], surfnorm.estimate(stack[2], K, method="d2nt_basic"))

    @pytest.mark.parametrize("method", ["d2nt_v3", "cp2tv+mnr", "sda_sne"])
    def test_out_is_written_and_returned(self, method):
        rng = np.random.default_rng(1)
        stack = (2 + rng.random((3, 20, 24))).astype(np.float32)
        stack[1, 5:9, 6:10] = 0  # a hole
        out = np.full(stack.shape + (3,), 7.0, np.float32)  # stale values that must all be overwritten
        assert surfnorm.estimate(stack, K, method=method, threads=2, out=out) is out
        np.testing.assert_array_equal(out, surfnorm.estimate(stack, K, method=method))
        frame = np.full((20, 24, 3), 7.0, np.float32)
        assert surfnorm.estimate(stack[1], K, method=method, out=frame, scale_invariant=True) is frame
        np.testing.assert_array_equal(frame, surfnorm.estimate(stack[1], K, method=method, scale_invariant=True))

    def test_out_reused_for_a_stream_of_batches(self):
        rng = np.random.default_rng(2)
        out = np.empty((4, 20, 24, 3), np.float32)
        for _ in range(3):
            stack = (1 + rng.random((4, 20, 24))).astype(np.float32)
            surfnorm.estimate(stack, K, method="d2nt_v2", threads=2, out=out)
            for i in range(4):
                np.testing.assert_array_equal(out[i], surfnorm.estimate(stack[i], K, method="d2nt_v2"))

    def test_batches_in_a_forked_child(self):
        # The thread pool kept between batch calls must not be inherited by a forked child (its threads are not).
        stack = np.stack([wall(), wall(d=3.0)])
        surfnorm.estimate(stack, K, threads=2)
        ctx = pytest.importorskip("multiprocessing").get_context("fork")
        with ctx.Pool(1) as pool:
            result = pool.apply_async(_batch_z_components, (stack,)).get(timeout=60)
        np.testing.assert_allclose(result, -1.0, atol=1e-6)

    def test_intrinsics_object(self):
        cam = surfnorm.Intrinsics(100, 100, 15.5, 11.5)
        np.testing.assert_array_equal(surfnorm.estimate(wall(), cam), surfnorm.estimate(wall(), K))


def _batch_z_components(stack):
    return surfnorm.estimate(stack, K, method="d2nt_basic", threads=2)[:, 5:-5, 5:-5, 2]


BAD_DEPTH = [
    (
        np.zeros((4, 5, 6, 2)),
        "depth: expected a 2-D array (H, W) or a stack (N, H, W), got an array of shape (4, 5, 6, 2)",
    ),
    (np.zeros(7), "depth: expected a 2-D array (H, W) or a stack (N, H, W), got an array of shape (7,)"),
    (np.zeros((0, 0)), "depth: expected at least 3x3 pixels, got shape (0, 0)"),
    (np.zeros((2, 2)), "depth: expected at least 3x3 pixels, got shape (2, 2)"),
    (np.zeros((1, 9)), "depth: expected at least 3x3 pixels, got shape (1, 9)"),
    (
        np.zeros((4, 4), bool),
        "depth: expected real-valued depth (float or integer), got an array of shape (4, 4) and dtype bool",
    ),
    (
        np.zeros((4, 4), complex),
        "depth: expected real-valued depth (float or integer), got an array of shape (4, 4) and dtype complex128",
    ),
    (
        np.array([["a", "b", "c"]] * 3),
        "depth: expected real-valued depth (float or integer), got an array of shape (3, 3) and dtype <U1",
    ),
    (
        np.empty((3, 3), object),
        "depth: expected real-valued depth (float or integer), got an array of shape (3, 3) and dtype object",
    ),
    (None, "depth: expected a 2-D array of depth values, got None"),
]


@pytest.mark.parametrize("depth, message", BAD_DEPTH)
def test_bad_depth(depth, message):
    with pytest.raises(InputError) as info:
        surfnorm.estimate(depth, K)
    assert str(info.value).startswith(message)
    assert isinstance(info.value, ValueError)


BAD_K = [
    (np.eye(2), "K: expected a 3x3 intrinsic matrix, got shape (2, 2)"),
    ([[0.0, 0, 1], [0, 100, 1], [0, 0, 1]], "K: expected positive focal lengths K[0,0] and K[1,1], got fx=0, fy=100"),
    ([[100.0, 0, 1], [0, -5, 1], [0, 0, 1]], "K: expected positive focal lengths K[0,0] and K[1,1], got fx=100, fy=-5"),
    ([[np.nan, 0, 1], [0, 100, 1], [0, 0, 1]], "K: expected finite entries"),
    ([[100, 0, np.inf], [0, 100, 1], [0, 0, 1]], "K: expected finite entries"),
    ([[100.0, 2, 1], [0, 100, 1], [0, 0, 1]], "K: expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)"),
    (np.full((3, 3), "x"), "K: expected a 3x3 matrix of real numbers, got dtype <U1"),
]


@pytest.mark.parametrize("K_, message", BAD_K)
def test_bad_K(K_, message):
    with pytest.raises(InputError) as info:
        surfnorm.estimate(wall(), K_)
    assert str(info.value).startswith(message)


def test_bad_K_stack():
    with pytest.raises(
        InputError, match=r"K: expected shape \(3, 3\) or \(2, 3, 3\) for 2 frames, got shape \(3, 3, 3\)"
    ):
        surfnorm.estimate(np.ones((2, 5, 5)), np.stack([K] * 3))


def test_bad_intrinsics_object():
    with pytest.raises(InputError, match=r"intrinsics.fx: expected a positive focal length in pixels, got -1.0"):
        surfnorm.Intrinsics(-1, 1, 0, 0)
    with pytest.raises(InputError, match=r"intrinsics.cy: expected a finite number, got nan"):
        surfnorm.Intrinsics(1, 1, 0, float("nan"))


def test_bad_mask():
    with pytest.raises(InputError, match=r"mask: expected shape \(24, 32\) to match depth, got shape \(24, 31\)"):
        surfnorm.estimate(wall(), K, mask=np.ones((24, 31), bool))
    with pytest.raises(
        InputError,
        match=r"mask: expected a boolean array \(True where depth is usable\), got an array of shape \(24, 32\) and dtype <U1",
    ):
        surfnorm.estimate(wall(), K, mask=np.full((24, 32), "y"))


def test_bad_out():
    shape = (24, 32, 3)
    read_only = np.empty(shape, np.float32)
    read_only.flags.writeable = False
    depth_and_room = np.ones((4, 24, 32), np.float32)  # depth in plane 0, and room that a wrong out= could reuse
    cases = [
        ([], r"out: expected a float32 NumPy array of shape \(24, 32, 3\) to write the normals into, got list"),
        (
            np.empty(shape),
            r"out: expected a float32 array of shape \(24, 32, 3\), got an array of shape \(24, 32, 3\) and dtype float64",
        ),
        (
            np.empty((2,) + shape, np.float32),
            r"out: expected a float32 array of shape \(24, 32, 3\), got an array of shape \(2, 24, 32, 3\)",
        ),
        (
            np.empty((24, 32, 4), np.float32)[..., :3],
            r"out: expected a C-contiguous array \(written in place\), got a non-contiguous view",
        ),
        (read_only, r"out: expected a writeable array, got a read-only one"),
        (
            depth_and_room.reshape(-1)[: 24 * 32 * 3].reshape(shape),
            r"out: expected an array apart from depth, got one that shares memory with it",
        ),
    ]
    for out, message in cases:
        with pytest.raises(InputError, match=message):
            surfnorm.estimate(depth_and_room[0], K, out=out)
    with pytest.raises(
        InputError,
        match=r"out: expected a float32 array of shape \(2, 24, 32, 3\), got an array of shape \(24, 32, 3\)",
    ):
        surfnorm.estimate(np.stack([wall(), wall()]), K, out=np.empty(shape, np.float32))


def test_unknown_method_and_options():
    with pytest.raises(
        InputError, match=r"method: expected one of d2nt_basic, .* \(optionally followed by '\+mnr'\), got 'd2nt_v9'"
    ):
        surfnorm.estimate(wall(), K, method="d2nt_v9")
    with pytest.raises(InputError, match=r"method: expected a method name \(str\), got int 3"):
        surfnorm.estimate(wall(), K, method=3)
    with pytest.raises(
        InputError, match=r"options of method 'd2nt_basic': expected some of border, fill, got unknown option\(s\) dlf"
    ):
        surfnorm.estimate(wall(), K, method="d2nt_basic", dlf="alpha")
    with pytest.raises(InputError, match=r"dlf: expected one of '1d', 'alpha', 'beta', 'gamma', got 'delta'"):
        surfnorm.estimate(wall(), K, method="d2nt_v2", dlf="delta")
    with pytest.raises(InputError, match=r"tau: expected a positive finite number, got 0"):
        surfnorm.estimate(wall(), K, method="d2nt_v2", tau=0)
    with pytest.raises(InputError, match=r"truncate: expected True or False, got 'yes'"):
        surfnorm.estimate(wall(), K, method="d2nt_v2", truncate="yes")
    with pytest.raises(InputError, match=r"mnr_dlf: expected one of '1d', 'alpha', 'beta', 'gamma', got 'x'"):
        surfnorm.estimate(wall(), K, method="cp2tv+mnr", mnr_dlf="x")
    with pytest.raises(InputError, match=r"border: expected one of 'one-sided', 'reflect', got 'wrap'"):
        surfnorm.estimate(wall(), K, method="d2nt_basic", border="wrap")
    with pytest.raises(InputError, match=r"fill: expected a number"):
        surfnorm.estimate(wall(), K, method="d2nt_basic", fill="zero")
    with pytest.raises(InputError, match=r"threads: expected a positive integer, got 0"):
        surfnorm.estimate(np.ones((2, 5, 5)), K, threads=0)


def test_refine_errors_and_identity_on_plane():
    n = surfnorm.estimate(wall(), K, method="d2nt_basic")
    np.testing.assert_array_equal(surfnorm.refine(n, wall()), n)
    with pytest.raises(InputError, match=r"normals: expected shape \(24, 32, 3\) to match depth, got shape \(24, 32\)"):
        surfnorm.refine(n[..., 0], wall())
    with pytest.raises(
        InputError,
        match=r"normals: expected a float array of shape \(24, 32, 3\), got an array of shape \(24, 32, 3\) and dtype int64",
    ):
        surfnorm.refine(n.astype(np.int64), wall())
    with pytest.raises(InputError, match=r"dlf: expected one of"):
        surfnorm.refine(n, wall(), dlf="sobel")
    with pytest.raises(InputError, match=r"depth: expected a 2-D array \(H, W\), got an array of shape \(1, 24, 32\)"):
        surfnorm.refine(n, wall()[None])


def test_methods_registry():
    info = surfnorm.methods()
    assert {"d2nt_basic", "d2nt_v2", "d2nt_v3", "cp2tv"} <= set(info)
    for m in info.values():
        assert m.category in ("energy minimisation", "averaging", "depth-to-normal", "automatic")
        assert m.reference and "fill" in m.options
    assert info["d2nt_v3"].options["dlf"] == "1d" and info["d2nt_v3"].options["mnr_dlf"] == "alpha"


# --- masked arrays -------------------------------------------------------------------------------------------------

SCENE_K = camera(64, 48)


@pytest.mark.parametrize("method", ["d2nt_v3", "3f2n_median", "plane_pca", "sda_sne", "angle_weighted+mnr"])
def test_masked_arrays_mask_pixels(method):
    z = scene()
    rng = np.random.default_rng(0)
    hidden = rng.random(z.shape) < 0.1
    garbage = np.where(hidden, rng.uniform(0.1, 50, z.shape), z).astype(np.float32)
    expected = surfnorm.estimate(z, SCENE_K, method=method, mask=~hidden)
    np.testing.assert_array_equal(
        surfnorm.estimate(np.ma.masked_array(garbage, hidden), SCENE_K, method=method), expected
    )
    # the mask argument as a masked array: masked entries are unusable; both masks combine
    other = rng.random(z.shape) < 0.05
    m = np.ma.masked_array(np.ones(z.shape, bool), other)
    np.testing.assert_array_equal(
        surfnorm.estimate(np.ma.masked_array(garbage, hidden), SCENE_K, method=method, mask=m),
        surfnorm.estimate(z, SCENE_K, method=method, mask=~hidden & ~other),
    )
    stack = surfnorm.estimate(
        np.ma.masked_array(np.stack([garbage, garbage]), np.stack([hidden, hidden])), SCENE_K, method=method
    )
    np.testing.assert_array_equal(stack[1], expected)


def test_refine_honours_masked_arrays():
    z = scene()
    hidden = np.zeros(z.shape, bool)
    hidden[10:20, 10:20] = True
    raw = surfnorm.estimate(z, SCENE_K, method="cp2tv")
    expected = surfnorm.refine(raw, z, mask=~hidden)
    np.testing.assert_array_equal(surfnorm.refine(raw, np.ma.masked_array(np.where(hidden, 9.0, z), hidden)), expected)
    masked_normals = np.ma.masked_array(raw, np.repeat(hidden[..., None], 3, -1))
    got = surfnorm.refine(masked_normals, z)
    np.testing.assert_array_equal(got, surfnorm.refine(np.where(hidden[..., None], np.nan, raw), z))
