"""adaptive_fit (the sensor-depth estimator) and auto (the default): naive reference, closed-form surfaces."""

from __future__ import annotations

import math

import numpy as np
import pytest

import surfnorm
from surfnorm import InputError
from surfnorm._bands import on_threads
from surfnorm.camera import Intrinsics
from surfnorm.io.threef2n import find_frames, read_frame, sample_root
from surfnorm.kernels.auto import choose
from surfnorm.kernels.sensor_noise import noise_profile

from . import naive_adaptive_fit as naive
from .surfaces import camera, plane, sphere


def angles_deg(a, b):
    """Angle between unit vectors, from their difference (arccos of a dot product near 1 is not
    resolved in float32: 1 ulp below 1 reads as 0.02 degrees)."""
    d = np.linalg.norm(a.astype(np.float64) - b.astype(np.float64), axis=-1)
    return np.degrees(2 * np.arcsin(np.clip(d / 2, 0, 1)))


def scene(seed, H=48, W=64, quantum=0.002, holes=0.1):
    """Two planes meeting at a crease, a sphere in front, quantised depth, random holes."""
    rng = np.random.default_rng(seed)
    K = camera(W, H, fov_deg=60)
    z1, _, _ = plane(K, H, W, [rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), -1], rng.uniform(1, 3))
    z2, _, _ = plane(K, H, W, [rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), -1], rng.uniform(1, 3))
    zs, _, hit = sphere(K, H, W, [rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2), 1.2], 0.3)
    z = np.where(z1 > 0, z1, np.inf)
    z = np.minimum(z, np.where(z2 > 0, z2, np.inf))
    z = np.where(hit, np.minimum(z, zs), z)
    z = np.where(np.isfinite(z), z, 0.0)
    z = np.round(z / quantum) * quantum + rng.normal(0, quantum / 4, z.shape)
    z[rng.random(z.shape) < holes] = 0.0
    return z.astype(np.float32), K


@pytest.mark.parametrize("size", [(48, 64), (120, 160)])  # sampled at step 1 and step 2
@pytest.mark.parametrize("seed", range(6))
def test_noise_profile_matches_naive(seed, size):
    z, K = scene(seed, *size)
    valid = z > 0
    f = math.sqrt(K[0, 0] * K[1, 1])
    got = noise_profile(z, valid, f)
    centres, rho, floor, correlation, floor2 = naive.noise_profile(z.astype(np.float64), valid, f)
    np.testing.assert_allclose(got.depths, centres, rtol=1e-12)
    np.testing.assert_allclose(got.rho, rho, rtol=1e-9, atol=1e-12)
    assert got.floor == pytest.approx(floor, rel=1e-12)
    assert got.floor2 == pytest.approx(floor2, rel=1e-12)
    assert got.correlation == pytest.approx(correlation, rel=1e-9)


@pytest.mark.parametrize("period", [3, 5])
def test_noise_profile_matches_naive_on_sparse_lines(period):
    """Depth on every 3rd or 5th row alone (LiDAR-like lines: sparse, fitted at every pixel), where the depth bins take
    every stencil, not the pixel scale's alone (found along the lines only)."""
    z, K = scene(period, 120, 160, holes=0.0)
    lines = np.zeros_like(z)
    lines[1::period] = z[1::period]
    valid = lines > 0
    f = math.sqrt(K[0, 0] * K[1, 1])
    assert naive.stride_for(valid) == 1
    got = noise_profile(lines, valid, f)
    centres, rho, floor, correlation, floor2 = naive.noise_profile(lines.astype(np.float64), valid, f)
    np.testing.assert_allclose(got.rho, rho, rtol=1e-9, atol=1e-12)
    assert got.floor == pytest.approx(floor, rel=1e-12)
    assert got.correlation == pytest.approx(correlation, rel=1e-9)
    if period == 3:  # stencils across three rows too (gap 3): here the rule shows
        assert not np.array_equal(got.rho, noise_profile(lines, valid, f, sparse=False).rho)


def test_noise_sampling_step_is_a_640x480_frames_on_smaller_frames():
    """Every 5th row and column at 640x480 and below (not denser on smaller frames, so that the measurement's share
    of the call does not grow), at least 3,000 pixels per step squared, about 12,000 samples on larger frames."""
    from surfnorm._constants import noise_step

    known = {(480, 640): 5, (375, 450): 5, (240, 320): 5, (192, 256): 4, (120, 160): 2, (48, 64): 1, (375, 1242): 6}
    known |= {(480, 848): 6, (1080, 1920): 13, (1, 1): 1, (100, 110): 1, (110, 110): 2}
    for (H, W), step in known.items():
        assert noise_step(H, W) == step, (H, W)
    rng = np.random.default_rng(0)
    for H, W in rng.integers(1, 2000, size=(300, 2)):
        step = noise_step(int(H), int(W))
        assert step == naive.sampling_step(int(H), int(W)), (H, W)
        assert H * W >= 3_000 * step * step or step == 1
        assert step >= 5 or H * W < 3_000 * (step + 1) ** 2


@pytest.mark.slow
@pytest.mark.parametrize("stride", [None, 1, 2, 4])
@pytest.mark.parametrize("seed", range(6))
def test_matches_naive_reference(seed, stride):
    z, K = scene(seed, holes=0.05 + 0.05 * seed)
    got = surfnorm.estimate(z, K, method="adaptive_fit", stride=stride)
    assert_like_naive(got, naive.adaptive_fit(z, K, stride=stride))


def assert_like_naive(got, ref):
    """The same pixels have normals (99.5 %), and those agree to 1e-3 degrees (99.5 %: a decision at the noise
    test's threshold may fall the other way under other rounding)."""
    has_got = np.any(got != 0, axis=-1)
    has_ref = np.any(ref != 0, axis=-1)
    assert (has_got == has_ref).mean() >= 0.995
    both = has_got & has_ref
    agree = angles_deg(got[both], ref[both]) < 1e-3
    assert agree.mean() >= 0.995, f"{(~agree).sum()} of {both.sum()} pixels differ"


@pytest.mark.parametrize("stride", [1, 2, 4])
@pytest.mark.parametrize("seed", range(3))
def test_rows_without_depth_match_naive_reference(seed, stride):
    """Rows without a valid pixel (a LiDAR frame's upper part, gaps between its scan bands) add nothing to the
    integral rows and have no fits; the rows around them still fit across them, as in the naive reference, and
    on two threads to the bit."""
    z, K = scene(seed, H=64, holes=0.05)
    z[:12] = 0.0  # the upper rows
    z[30:33] = 0.0  # a gap of three rows: fitted and other rows at either stride
    z[45] = 0.0
    got = surfnorm.estimate(z, K, method="adaptive_fit", stride=stride, threads=1)
    assert not got[:12].any() and not got[30:33].any() and not got[45].any()
    assert_like_naive(got, naive.adaptive_fit(z, K, stride=stride))
    assert np.array_equal(surfnorm.estimate(z, K, method="adaptive_fit", stride=stride, threads=2), got)


@pytest.mark.parametrize("stride", [1, 2, 4])
@pytest.mark.parametrize("seed", range(3))
def test_rows_of_every_density_match_naive_reference(seed, stride):
    """A fitted row with few valid pixels (under half: a LiDAR frame's) works on those alone, a denser one on every
    fitted pixel: with rows of every density from 2 % to all valid, the normals agree with the naive reference,
    which fits pixel by pixel, and on two threads to the bit."""
    z, K = scene(seed, H=64, holes=0.0)
    rng = np.random.default_rng(10 + seed)
    density = rng.uniform(0.02, 1.0, z.shape[0])
    z[rng.random(z.shape) > density[:, None]] = 0.0
    got = surfnorm.estimate(z, K, method="adaptive_fit", stride=stride, threads=1)
    assert_like_naive(got, naive.adaptive_fit(z, K, stride=stride))
    assert np.array_equal(surfnorm.estimate(z, K, method="adaptive_fit", stride=stride, threads=2), got)
    _, sigma = surfnorm.estimate(z, K, method="adaptive_fit", stride=stride, uncertainty=True)
    assert np.array_equal(np.isnan(sigma), ~np.any(got != 0, axis=-1))


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("quantum", [0.0, 0.001])
def test_planes_any_orientation_and_distance(seed, quantum):
    rng = np.random.default_rng(100 + seed)
    H, W = 60, 80
    K = camera(W, H, fov_deg=rng.uniform(40, 90))
    tilt = np.radians(rng.uniform(0, 65))
    az = rng.uniform(0, 2 * np.pi)
    normal = [np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), -np.cos(tilt)]
    distance = rng.uniform(0.3, 20.0) if quantum == 0 else rng.uniform(0.5, 1.5)
    z, n_true, hit = plane(K, H, W, normal, distance)
    if quantum:  # steps of 1 mm: finer than the support at these distances
        z = np.where(hit, np.round(z / quantum) * quantum, 0.0)
    z[rng.random(z.shape) < 0.1] = 0.0
    got = surfnorm.estimate(z.astype(np.float32), K, method="adaptive_fit")
    has = np.any(got != 0, axis=-1) & hit & (z > 0)
    assert has.sum() >= 0.97 * (hit & (z > 0)).sum()
    err = angles_deg(got[has], n_true[has])
    if quantum == 0:
        assert err.max() < 0.01
    else:
        assert err.mean() < 1.0 and np.percentile(err, 99) < 5.0


def test_step_edges_keep_their_side():
    """Two fronto-parallel planes 10 cm apart: no normal is bent by the other side of the step."""
    H, W = 40, 60
    K = camera(W, H)
    z = np.full((H, W), 1.0)
    z[:, W // 2 :] = 1.1
    rng = np.random.default_rng(0)
    z = np.round((z + rng.normal(0, 0.0005, z.shape)) / 0.001) * 0.001
    got = surfnorm.estimate(z.astype(np.float32), K, method="adaptive_fit")
    err = angles_deg(got, np.broadcast_to([0.0, 0.0, -1.0], got.shape))
    assert np.percentile(err, 95) < 3.0
    assert err[:, W // 2 - 3 : W // 2 + 3].mean() < 5.0


def test_sparse_depth_gets_normals():
    """LiDAR-like: 20 % of the pixels of a tilted plane; every valid pixel gets a close normal."""
    H, W = 60, 80
    K = camera(W, H)
    z, n_true, hit = plane(K, H, W, [0.3, -0.4, -1.0], 5.0)
    rng = np.random.default_rng(1)
    z = np.where(rng.random(z.shape) < 0.2, z, 0.0)
    got = surfnorm.estimate(z.astype(np.float32), K, method="adaptive_fit")
    has = z > 0
    assert np.all(np.any(got[has] != 0, axis=-1))
    assert angles_deg(got[has], n_true[has]).max() < 0.01


def test_unit_free():
    z, K = scene(3)
    m = surfnorm.estimate(z, K, method="adaptive_fit")
    mm = surfnorm.estimate(z * np.float32(1000), K, method="adaptive_fit")
    has = np.any(m != 0, axis=-1)
    assert np.array_equal(has, np.any(mm != 0, axis=-1))
    assert (angles_deg(m[has], mm[has]) < 1e-3).mean() > 0.995


def test_fixed_window_option_and_validation():
    z, K = scene(1, holes=0.0)
    a = surfnorm.estimate(z, K, method="adaptive_fit", window=5)
    assert a.shape == z.shape + (3,)
    with pytest.raises(InputError, match="window"):
        surfnorm.estimate(z, K, method="adaptive_fit", window=4)
    with pytest.raises(InputError, match="max_window"):
        surfnorm.estimate(z, K, method="adaptive_fit", max_window=2)


def test_auto_chooses_from_the_depth():
    H, W = 60, 80
    K = camera(W, H)
    zs, _, hit = sphere(K, H, W, [0.0, 0.0, 2.0], 0.8)
    clean = np.where(hit, zs, 0.0).astype(np.float32)
    cam = Intrinsics.from_matrix(K)
    assert choose(clean, clean > 0, cam) == "d2nt_v3"
    np.testing.assert_array_equal(surfnorm.estimate(clean, K), surfnorm.estimate(clean, K, method="d2nt_v3"))
    spacing = 2.0 / K[0, 0]  # distance between neighbouring pixels' points at the sphere
    noisy = zs + np.random.default_rng(0).normal(0, 0.3 * spacing, zs.shape)
    sensor = np.where(hit, np.round(noisy / spacing) * spacing, 0.0).astype(np.float32)  # steps of one spacing
    assert choose(sensor, sensor > 0, cam) == "adaptive_fit"
    np.testing.assert_array_equal(surfnorm.estimate(sensor, K), surfnorm.estimate(sensor, K, method="adaptive_fit"))
    sparse = np.where(np.random.default_rng(0).random(clean.shape) < 0.1, clean, 0).astype(np.float32)
    assert choose(sparse, sparse > 0, cam) == "adaptive_fit"


def test_default_is_auto():
    assert "auto" in surfnorm.methods() and "adaptive_fit" in surfnorm.methods()
    import inspect

    assert inspect.signature(surfnorm.estimate).parameters["method"].default == "auto"


def test_auto_tau_is_checked():
    z, K = scene(2)
    with pytest.raises(InputError, match=r"^tau: expected a positive"):
        surfnorm.estimate(z, K, tau=0.0)
    with pytest.raises(InputError, match=r"options of method 'auto'.*unknown option\(s\) window"):
        surfnorm.estimate(z, K, window=5)


def test_auto_blends_between_the_floors_so_that_its_output_moves_continuously():
    """Between CLEAN_FLOOR and NOISY_FLOOR auto is the normalised weighted mean of both estimators' normals."""
    from surfnorm.kernels.auto import CLEAN_FLOOR, NOISY_FLOOR, adaptive_weight
    from surfnorm.kernels.sensor_noise import NoiseProfile

    def white(floor):  # noise read by its floor alone: rho as large as it, no floor2 (no smooth error, no white share)
        return NoiseProfile(np.ones(1), np.full(1, floor), floor)

    assert adaptive_weight(white(CLEAN_FLOOR)) == 0.0
    assert adaptive_weight(white(NOISY_FLOOR)) == 1.0
    assert adaptive_weight(white(float("nan"))) == 1.0
    mid = 0.5 * (CLEAN_FLOOR + NOISY_FLOOR)
    assert adaptive_weight(white(mid)) == pytest.approx(0.5)
    # a sphere with noise that puts adaptive_fit's weight strictly between 0 and 1 (its floor in the band, or the white
    # noise's share under 1)
    H, W = 60, 80
    K = camera(W, H)
    cam = Intrinsics.from_matrix(K)
    zs, _, hit = sphere(K, H, W, [0.0, 0.0, 2.0], 0.8)
    spacing = 2.0 / K[0, 0]
    rng = np.random.default_rng(1)
    for sigma in (0.02, 0.05, 0.08, 0.12, 0.2):
        z = np.where(hit, zs + rng.normal(0, sigma * spacing, zs.shape), 0.0).astype(np.float32)
        if choose(z, z > 0, cam) == "blend":
            break
    else:
        pytest.fail("no noise level put the floor inside the band")

    t = adaptive_weight(noise_profile(z, z > 0, float(K[0, 0])))
    a = surfnorm.estimate(z, K, method="d2nt_v3", fill=np.nan)
    b = surfnorm.estimate(z, K, method="adaptive_fit", fill=np.nan)
    expected = (1 - t) * a + t * b
    expected /= np.linalg.norm(expected, axis=-1, keepdims=True)
    # at low noise adaptive_fit's normals are checked against d2nt_v3's: the few pixels where they differ by more than
    # the noise explains take d2nt_v3's alone (blended with itself)
    from surfnorm.kernels.auto import auto

    record: dict = {}
    auto(z, z > 0, cam, np.empty(z.shape + (3,), np.float32), fill=np.nan, record=record)
    took = record.get("took_d2nt", np.zeros(z.shape, bool))
    assert took.sum() <= 0.01 * np.count_nonzero(z)
    expected = np.where(took[..., None], a, expected)
    np.testing.assert_allclose(surfnorm.estimate(z, K, fill=np.nan), expected, atol=1e-6, equal_nan=True)


def test_blend_matches_the_naive_one_pixel_by_pixel():
    """auto.blend against a pixel-by-pixel reference on random normal maps: holes in either, pairs that cancel
    (opposite directions), weights on both sides of 0.5 and at it, fills 0, -3 and NaN; the same float32 values."""
    from surfnorm.kernels.auto import blend

    rng = np.random.default_rng(7)
    for k in range(40):
        H, W = rng.integers(1, 30, 2)
        a = rng.normal(size=(H, W, 3)).astype(np.float32)
        b = rng.normal(size=(H, W, 3)).astype(np.float32)
        a /= np.linalg.norm(a, axis=-1, keepdims=True)
        b /= np.linalg.norm(b, axis=-1, keepdims=True)
        opposite = rng.random((H, W)) < 0.15
        b[opposite] = -a[opposite]
        a[rng.random((H, W)) < 0.2] = np.nan
        b[rng.random((H, W)) < 0.2] = np.nan
        t = (0.3, 0.5, 0.8, float(rng.random()))[k % 4]
        fill = (0.0, -3.0, np.nan)[k % 3]
        got = blend(a, b, t, fill, np.empty_like(a))
        np.testing.assert_array_equal(got, naive.blend(a, b, t, fill), err_msg=f"case {k}, t={t}")
    # in row bands on threads (of at least MIN_ROWS rows: two of a frame of 96), in place: the same bits
    a, b = (rng.normal(size=(96, 7, 3)).astype(np.float32) for _ in range(2))
    a /= np.linalg.norm(a, axis=-1, keepdims=True)
    b /= np.linalg.norm(b, axis=-1, keepdims=True)
    a[rng.random((96, 7)) < 0.2] = np.nan
    b[rng.random((96, 7)) < 0.2] = np.nan
    banded = b.copy()
    blend(a, banded, t, fill, banded, on_threads(2))
    np.testing.assert_array_equal(banded, naive.blend(a, b, t, fill))


def test_window_ties_go_the_same_way_in_every_unit():
    """Integer-millimetre steps make mirror-image windows tie, and planes fitted exactly leave residuals of rounding;
    rounding in float32 metres must not decide them. On the shipped frames read with 1 mm steps (0.1 to 4 m), 8 of
    137,963 pixels moved by more than 1e-4 (some by 20 degrees) before ties had a margin (surfnorm.kernels.adaptive_fit.TIE);
    benchmarks/unit_holes.py has the 12-frame table."""
    differing = total = 0
    for name in find_frames(sample_root()):
        f = read_frame(sample_root(), name)
        mm = np.rint(f.depth.astype(np.float64) * 10).astype(np.float32)
        a = surfnorm.estimate(mm, f.K, method="adaptive_fit", mask=f.mask, scale_invariant=True, fill=np.nan)
        b = surfnorm.estimate(
            (mm.astype(np.float64) / 1000).astype(np.float32),
            f.K,
            method="adaptive_fit",
            mask=f.mask,
            scale_invariant=True,
            fill=np.nan,
        )
        have = ~np.isnan(a[..., 0]) | ~np.isnan(b[..., 0])
        differing += int((have & (np.abs(np.nan_to_num(b - a, nan=2.0)).max(-1) > 1e-4)).sum())
        total += int(have.sum())
    assert differing <= 1e-5 * total, (differing, total)


@pytest.mark.parametrize("W", [50, 51])
@pytest.mark.parametrize("stride", [1, 2, 4])
@pytest.mark.parametrize("r", [1, 2, 4, 15, 40])
def test_row_window_sums_are_the_box_formula_where_picked(r, stride, W):
    """box_row, box_row_sparse and coordinate_sums (the row path of the window sums) give, for every picked
    fitted pixel (column u = stride i, or the columns of a compacted row), exactly (bottom - top at column
    u + r + 1) - (bottom - top at column u - r), clipped, with the integral columns where integral_positions
    places them; box_row keeps src elsewhere unless ``first``, and coordinate_sums fills only windows that are not
    the full square. The kernel's outputs rest on these bits (the windows' fits and every decision made from
    them)."""
    from surfnorm.kernels._windows import (
        _BOXED,
        _COORDS,
        box_row,
        box_row_sparse,
        coordinate_sums,
        integral_positions,
    )

    rng = np.random.default_rng(r)
    n_fit = (W + stride - 1) // stride
    by_column = rng.normal(0, 1e3, (2, 10, W + 1))
    pos = integral_positions(W, stride)
    assert sorted(pos) == list(range(W + 1))
    top, bottom = np.empty_like(by_column[0]), np.empty_like(by_column[1])
    top[:, pos], bottom[:, pos] = by_column  # column u of the integral row at pos[u]
    pick = rng.random(n_fit) < 0.6
    u = stride * np.arange(n_fit)
    u0, u1 = np.clip(u - r, 0, W), np.clip(u + r + 1, 0, W)
    t, b = by_column
    box = (b[:, u1] - t[:, u1]) - (b[:, u0] - t[:, u0])  # (10, n_fit), same operations in NumPy
    src = rng.normal(size=(len(_BOXED), n_fit))
    for first in (False, True):
        dst = np.full((len(_BOXED), n_fit), np.nan)
        box_row(top, bottom, r, stride, pos, pick, first, src, dst)
        np.testing.assert_array_equal(dst[:, pick], box[list(_BOXED)][:, pick])
        if not first:
            np.testing.assert_array_equal(dst[:, ~pick], src[:, ~pick])
    # the pixel-by-pixel path, at the fitted columns and at a compacted row's (some of them, in their order): the
    # same sums where picked, the rest kept
    few = np.flatnonzero(rng.random(n_fit) < 0.3)
    for k in (np.arange(n_fit), few):
        cols = u[k]
        in_place = src[:, k].copy()
        box_row_sparse(top, bottom, r, cols, pos, pick[k], in_place)
        np.testing.assert_array_equal(in_place[:, pick[k]], box[list(_BOXED)][:, k][:, pick[k]])
        np.testing.assert_array_equal(in_place[:, ~pick[k]], src[:, k][:, ~pick[k]])
        counts = np.where(rng.random(k.size) < 0.5, float((2 * r + 1) ** 2), box[0, k])
        coords = np.full((len(_COORDS), k.size), np.nan)
        coordinate_sums(top, bottom, r, cols, pos, pick[k], counts, coords)
        fill = pick[k] & (counts != (2 * r + 1) ** 2)
        np.testing.assert_array_equal(coords[:, fill], box[list(_COORDS)][:, k][:, fill])
        assert np.isnan(coords[:, ~fill]).all()


def test_stride_follows_the_density_of_the_depth():
    """Every fourth row and column is fitted where the pixels between have a fitted pixel at a corner of their cell
    (dense depth), every other one where they have one near them (depth with many holes), every pixel where many
    do not (LiDAR scanlines); the rule agrees with the naive one on random masks."""
    from surfnorm.kernels._schedule import choose_stride

    rng = np.random.default_rng(3)
    dense = rng.random((60, 80)) > 0.2
    assert choose_stride(dense) == 4
    holey = np.ones((60, 80), bool)
    holey[::4, ::4] = False  # no cell has a valid corner; every pixel has valid pixels of even rows and columns near
    assert choose_stride(holey) == 2
    scanlines = np.zeros((60, 80), bool)
    scanlines[1::2] = rng.random((30, 80)) > 0.2  # valid only on the odd rows: none of them is reachable
    assert choose_stride(scanlines) == 1
    for holes in (0.1, 0.3, 0.35, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9):
        for shape in ((7, 9), (8, 9), (31, 40), (33, 45)):
            valid = rng.random(shape) > holes
            assert choose_stride(valid) == naive.stride_for(valid), (holes, shape)
    assert choose_stride(np.ones((1, 5), bool)) == choose_stride(np.ones((5, 1), bool)) == 1


@pytest.mark.parametrize("stride", [1, 2, 4])
def test_integral_rows_are_the_sums_above_and_left_and_a_band_below_makes_the_same_bits(stride):
    """Integral row i holds, at column u (where integral_positions places it), the sums over the valid pixels of
    rows < i and columns < u of the ten moments; a band that sums only the columns of the rows above the ones
    it reads (make_rows' first_read) then makes those rows to the bit of a sweep from row 0."""
    from surfnorm.kernels._windows import _N_COLUMNS, _N_MOMENTS, integral_positions, make_rows

    rng = np.random.default_rng(stride)
    H, W = 23, 17
    z = rng.uniform(0.5, 4.0, (H, W)).astype(np.float32)
    valid = rng.random((H, W)) > 0.25
    pos = integral_positions(W, stride)
    L = 7
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    x, y = x - 0.5 * W, y - 0.5 * H
    w = np.where(valid, 1.0 / z.astype(np.float64), 0.0)
    m = valid * np.stack((np.ones_like(x), x, y, x * x, x * y, y * y, w, x * w, y * w, w * w))
    sums = np.zeros((_N_MOMENTS, H + 1, W + 1))
    sums[:, 1:, 1:] = m.cumsum(1).cumsum(2)
    for first_read in (0, 5, 11):
        ring = np.full((L, _N_MOMENTS, W + 1), np.nan)
        cols = np.full((_N_COLUMNS, W), np.nan)
        assert make_rows(z, valid, ring, cols, pos, np.empty(W), 0, H, first_read) == H
        sweep = np.full_like(ring, np.nan)
        make_rows(z, valid, sweep, np.empty_like(cols), pos, np.empty(W), 0, H, 0)
        for i in range(max(first_read, H + 1 - L), H + 1):
            np.testing.assert_array_equal(ring[i % L], sweep[i % L])
            np.testing.assert_allclose(ring[i % L][:, pos], sums[:, i], rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("stride", [1, 2, 4])
def test_a_band_writes_its_own_rows_only(stride):
    """Bands split a frame between threads: each writes its rows and nothing else, and together they give the
    whole frame's bits (odd band ends: a band reads the fitted row below it, and must not write it)."""
    from surfnorm.kernels.adaptive_fit import adaptive_fit

    z, K = scene(2, holes=0.1)
    valid = z > 0
    cam = Intrinsics.from_matrix(K)
    whole = adaptive_fit(z, valid, cam, np.empty(z.shape + (3,), np.float32), stride=stride)
    H = z.shape[0]
    out = np.full(z.shape + (3,), 7.0, np.float32)
    for v0, v1 in ((0, 17), (17, 30), (30, 33), (33, H)):

        def one_band(stage, n_rows, weights=None, v0=v0, v1=v1):
            return [stage(v0, v1)]

        part = np.full(z.shape + (3,), 7.0, np.float32)
        adaptive_fit(z, valid, cam, part, stride=stride, bands=one_band)
        assert (part[:v0] == 7.0).all() and (part[v1:] == 7.0).all(), (v0, v1)
        out[v0:v1] = part[v0:v1]
    np.testing.assert_array_equal(out, whole)


@pytest.mark.parametrize("stride", [1, 2, 4])
def test_each_side_of_a_step_keeps_its_plane(stride):
    """Two tilted planes meeting at a depth step off the fitted grid, and a hole: every pixel with depth gets its own
    plane's normal (the fitted pixels across the step fail the noise test there), on one thread and on several to the
    bit, and the hole gets none."""
    H, W = 61, 83
    cam = Intrinsics(300.0, 310.0, 47.3, 25.8)
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    ray = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], axis=-1)
    n_a, n_b = np.array([0.3, -0.4, -1.0]), np.array([-0.5, 0.2, -1.0])
    n_a, n_b = n_a / np.linalg.norm(n_a), n_b / np.linalg.norm(n_b)
    right = u >= 41  # not a fitted column of stride 2 or 4
    z = np.where(right, -3.0 / (ray @ n_b), -2.0 / (ray @ n_a)).astype(np.float32)
    z[10:14, 20:30] = 0.0
    truth = np.where(right[..., None], n_b, n_a)
    n = surfnorm.estimate(z, cam, method="adaptive_fit", stride=stride, threads=1)
    assert np.all(n[10:14, 20:30] == 0.0)
    has = z > 0
    assert np.all(np.any(n[has] != 0.0, axis=-1))
    assert angles_deg(n[has], truth[has]).max() < 0.05  # float32 depth: 0.015 degrees
    assert np.array_equal(surfnorm.estimate(z, cam, method="adaptive_fit", stride=stride, threads=3), n)


@pytest.mark.parametrize("stride", [0, 3, 1.0, True, "2"])
def test_stride_checked(stride):
    z, K = scene(0)
    with pytest.raises(InputError, match=r"stride: expected 1, 2, 4 or None, got"):
        surfnorm.estimate(z, K, method="adaptive_fit", stride=stride)


def test_a_fixed_window_wider_than_max_window_is_refused():
    z, K = scene(1, holes=0.0)
    with pytest.raises(InputError, match=r"window: expected at most max_window \(5\), got 9"):
        surfnorm.estimate(z, K, method="adaptive_fit", window=9, max_window=5)
    assert surfnorm.estimate(z, K, method="adaptive_fit", window=5, max_window=5).shape == z.shape + (3,)


def test_depth_range_from_the_bits_is_the_plain_one():
    """The noise profile's depth range from float32 bits (vectorised integer minima) equals the plain loop's,
    with NaN, infinities, negatives and zeros where the validity says so, and without any valid pixel."""
    from surfnorm._validate import valid_map
    from surfnorm.kernels.sensor_noise import _depth_range, depth_range

    rng = np.random.default_rng(7)
    for shape in ((1, 1), (5, 7), (48, 64)):
        z = rng.lognormal(0.0, 2.0, shape).astype(np.float32)
        z[rng.random(shape) < 0.2] = rng.choice(np.array([0.0, -1.0, np.nan, np.inf], np.float32))
        for valid in (valid_map(z, None), rng.random(shape) < 0.5, np.zeros(shape, bool)):
            valid &= np.isfinite(z) & (z > 0)
            assert depth_range(z, valid) == _depth_range(z, valid)
    assert depth_range(np.zeros((3, 4), np.float32), np.zeros((3, 4), bool)) == (np.inf, 0.0)


@pytest.mark.parametrize("size", [(120, 96), (131, 77), (383, 434)])  # sampled at step 1, 1 and 5; odd rows
def test_noise_samples_split_between_two_threads_are_those_of_one_sweep(size, monkeypatch):
    """With a waiting band (``offers``), the lower half of the sampled rows is swept on its thread and its samples
    moved up behind the upper half's: the same arrays, in the same order, as one sweep on one thread."""
    import threading

    from surfnorm._bands import Offers
    from surfnorm.kernels import sensor_noise as S

    z, K = scene(5, *size, holes=0.05)
    valid = z > 0
    f = math.sqrt(K[0, 0] * K[1, 1])
    one = S._samples(z, valid, f)
    swept = []
    sweep = S._second_differences
    helper_started = threading.Event()

    def recorded(*args):
        swept.append((threading.get_ident(), args[7]))
        if threading.get_ident() == helper.ident:
            helper_started.set()
        else:  # the measuring thread waits for the helper to take its half (else it would sweep both itself)
            assert helper_started.wait(5)
        return sweep(*args)

    monkeypatch.setattr(S, "_second_differences", recorded)
    offers = Offers()
    offers.open()
    helper = threading.Thread(target=offers.help)
    helper.start()
    try:
        two = S._samples(z, valid, f, offers=offers)
    finally:
        offers.close()
        helper.join(timeout=5)
    H = size[0]
    assert sorted(rows for _, rows in swept) == [(0, swept[0][1][1]), (swept[0][1][1], H)]  # two halves
    assert {thread for thread, _ in swept} == {threading.get_ident(), helper.ident}  # one of them on the helper
    assert one[:2] == two[:2] and one[5] == two[5]
    for a, b in zip(one[2:5] + one[6:], two[2:5] + two[6:]):
        assert a.dtype == b.dtype
        np.testing.assert_array_equal(a, b)


def test_noise_measured_by_one_band_while_the_others_make_their_rows():
    """The profile given, measured here, or measured by the first band that needs it (while the others make
    the integral rows above their own) gives the same bits on one band and on several; tables declined once the
    noise is known (auto's decision) write nothing."""
    from surfnorm._bands import Part, on_threads
    from surfnorm.kernels._schedule import run_bands
    from surfnorm.kernels.adaptive_fit import FitPlan, adaptive_fit
    from surfnorm.kernels.sensor_noise import noise_profile

    z, K = scene(4, H=120, W=96, holes=0.1)  # 120 rows: up to three bands of 40
    z = z.astype(np.float32)
    valid = z > 0
    cam = Intrinsics.from_matrix(K)
    f = np.sqrt(cam.fx * cam.fy)
    ref = adaptive_fit(z, valid, cam, np.empty(z.shape + (3,), np.float32))
    for bands in (on_threads(1), on_threads(2), on_threads(3)):
        for profile in (None, noise_profile(z, valid, f), Part(lambda: noise_profile(z, valid, f)).result):
            got = adaptive_fit(z, valid, cam, np.empty(z.shape + (3,), np.float32), profile=profile, bands=bands)
            np.testing.assert_array_equal(got, ref)
        # a frame decided against once its noise is known (auto on clean depth): nothing written
        out = np.full(z.shape + (3,), 7.0, np.float32)
        frame = FitPlan(z, valid, cam, out)
        decline = lambda p: frame.tables(p, fit=False)  # noqa: E731
        assert not run_bands(frame, bands, tables=decline)
        assert (out == 7.0).all()


def test_bands_balanced_by_their_times_give_the_same_bits():
    """Balance moves band edges toward equal times from frame to frame; whatever the split, the same bits."""
    from surfnorm._bands import on_threads
    from surfnorm.kernels._schedule import Balance, _balance, choose_stride
    from surfnorm.kernels.adaptive_fit import adaptive_fit

    balance = Balance()
    weights = np.ones(100)
    balance.learn("k", weights, [(0, 50, 3.0), (50, 100, 1.0)])  # the first band took three times as long
    factors = balance.factors("k")
    assert factors[:50].mean() > factors[50:].mean() and np.isclose(factors.mean(), 1.0)
    assert balance.factors("other") is None
    used = weights * factors
    # times in proportion to the weights the bands were split by: the factors hold
    balance.learn("k", used, [(0, 40, used[:40].sum()), (40, 100, used[40:].sum())])
    np.testing.assert_allclose(balance.factors("k"), factors)

    z, K = scene(5, H=128, W=96, holes=0.1)
    z = z.astype(np.float32)
    valid = z > 0
    cam = Intrinsics.from_matrix(K)
    ref = adaptive_fit(z, valid, cam, np.empty(z.shape + (3,), np.float32))
    _balance.forget()
    for _ in range(4):  # the factors learnt from each frame move the next frame's band edges
        got = adaptive_fit(z, valid, cam, np.empty(z.shape + (3,), np.float32), bands=on_threads(2))
        np.testing.assert_array_equal(got, ref)
    assert _balance.factors((z.shape, choose_stride(valid), 31, None)) is not None


def test_kappa_gain_doubles_kappa_for_correlated_noise_not_for_fine_geometry():
    """kappa_gain: 1 for noise independent from pixel to pixel (correlation up to 2), 2 from correlation 3 on where
    rho is noise (median 1.5 point spacings and less), none where rho is 2.5 or more (fine geometry) or the depth is
    clean (auto's weight), linear between; 1 where the correlation is not a number."""
    from surfnorm.kernels.sensor_noise import NoiseProfile, kappa_gain

    def gain(correlation, rho):
        return kappa_gain(NoiseProfile(np.ones(3), np.full(3, rho), 0.5, correlation=correlation))

    assert gain(1.0, 0.5) == gain(2.0, 0.5) == 1.0
    assert gain(3.0, 0.5) == gain(11.0, 1.5) == 2.0
    assert gain(2.5, 0.5) == pytest.approx(1.5)
    assert gain(4.0, 2.0) == pytest.approx(1.5)
    assert gain(4.0, 2.5) == gain(4.0, 9.0) == 1.0
    assert gain(float("nan"), 0.5) == 1.0
    # clean depth (no noise floor, no smooth noise, no terraces: auto's weight 0) reads any correlation without noise
    clean = NoiseProfile(np.ones(3), np.full(3, 0.1), 0.0, correlation=11.0)
    assert kappa_gain(clean) == 1.0
    assert kappa_gain(clean._replace(floor=0.15)) == pytest.approx(1.5)  # half-way between clean and sensor
    # the median of the bins' rho: one loud bin does not switch it off
    assert kappa_gain(NoiseProfile(np.ones(3), np.array([0.5, 0.5, 9.0]), 0.5, correlation=4.0)) == 2.0


def smooth_error_plane(seed, H=120, W=160):
    """A tilted plane through the smooth-error preset (disparity error correlated over about 2 pixels): its exact
    normal, the simulated depth and K."""
    from surfnorm.bench.simulate import simulate

    K = camera(W, H, fov_deg=60)
    z, n, _ = plane(K, H, W, [0.3, -0.4, -1.0], 2.0)
    return n, simulate(z, K, "smooth_error", seed=seed, scale=1.0), K


@pytest.mark.parametrize("seed", range(3))
def test_correlated_noise_gets_the_wider_noise_test(seed):
    """On noise correlated across pixels the fit runs with kappa times kappa_gain (the same bits as asking for that
    kappa with the gain off), and its normals are closer to the plane's than with the gain off."""
    from surfnorm.kernels.adaptive_fit import KAPPA, adaptive_fit
    from surfnorm.kernels.sensor_noise import kappa_gain

    n, z, K = smooth_error_plane(seed)
    valid = z > 0
    cam = Intrinsics.from_matrix(K)
    p = noise_profile(z, valid, math.sqrt(cam.fx * cam.fy))
    assert kappa_gain(p) == 2.0

    def fit(profile, **kw):
        return adaptive_fit(z, valid, cam, np.empty(z.shape + (3,), np.float32), profile=profile, **kw)

    got = fit(p)
    off = p._replace(correlation=1.0)
    np.testing.assert_array_equal(got, fit(off, kappa=KAPPA * kappa_gain(p)))
    plain = fit(off)
    assert not np.array_equal(got, plain)
    err_got, err_plain = (angles_deg(x[valid], np.broadcast_to(n, x.shape)[valid]).mean() for x in (got, plain))
    assert err_got < 0.8 * err_plain, (err_got, err_plain)
