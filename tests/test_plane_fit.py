"""PlaneSVD, PlanePCA, VectorSVD (surfnorm.kernels.plane_fit) against naive references and closed-form surfaces."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import surfnorm
from surfnorm import _api
from surfnorm.errors import InputError

from . import surfaces
from .naive_plane_fit import plane_fit as naive_plane_fit
from .naive_plane_fit import points
from .surfaces import camera

METHODS = ("plane_svd", "plane_pca", "vector_svd")
H, W = 24, 32
K = surfaces.camera(W, H)


def angle(a, b):
    """Angle in degrees, accurate near 0 (atan2 of |a x b| and a . b, float64)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.einsum("...c,...c->...", a, b)))


def smooth_depth(seed):
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    a, b, c = rng.uniform(0.5, 2, 3)
    return 2.0 + 0.3 * np.sin(u / (3 * a) + c) * np.cos(v / (4 * b)) + 0.02 * u - 0.01 * v


def rough_depth(seed):
    """Smooth depth with steps, holes (0, NaN, -1, inf) and a user mask."""
    rng = np.random.default_rng(seed)
    depth = smooth_depth(seed)
    depth[:, W // 3 :] += 0.7  # a depth step
    depth[H // 2 :, : W // 2] -= 0.4  # another
    depth += rng.normal(0, 0.002, depth.shape)  # sensor noise
    holes = rng.random(depth.shape) < 0.12
    depth[holes] = rng.choice([0.0, np.nan, -1.0, np.inf], size=holes.sum())
    mask = rng.random(depth.shape) > 0.05
    return depth, mask


def compare(depth, method, mask=None, window=3, fill=0.0, min_gap=1e-6):
    ours = surfnorm.estimate(depth, K, method=method, mask=mask, window=window, fill=fill)
    ref, gap = naive_plane_fit(depth, K, method, window=window, mask=mask, fill=fill)
    has_ref = np.any(ref != fill, axis=-1) if np.isfinite(fill) else np.all(np.isfinite(ref), axis=-1)
    has_ours = np.any(ours != fill, axis=-1) if np.isfinite(fill) else np.all(np.isfinite(ours), axis=-1)
    # Both give a normal in the same places, except where the naive rank test and ours disagree on
    # a (nearly) degenerate neighbourhood.
    assert np.array_equal(has_ref, has_ours) or np.all(gap[has_ref != has_ours] < min_gap)
    well_posed = has_ref & has_ours & (gap > min_gap)
    assert well_posed.sum() > 0.8 * has_ref.sum()
    # Where all points lie on a plane through the camera centre (e.g. one image column) the fitted
    # plane is seen edge-on, n . p = 0, and "facing the camera" cannot choose the sign.
    rays = points(np.asarray(depth, dtype=np.float32), K)
    edge_on = np.abs(np.einsum("hwc,hwc->hw", ref, rays)) < 1e-6 * np.linalg.norm(rays, axis=-1)
    aligned = np.where((edge_on & (np.einsum("hwc,hwc->hw", ref, ours) < 0))[..., None], -ref, ref)
    err = angle(ours[well_posed], aligned[well_posed])
    return ours, ref, err


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("seed", [0, 1])
def test_agrees_with_naive_on_smooth_depth(method, seed):
    ours, ref, err = compare(smooth_depth(seed), method)
    assert err.max() < 1e-3  # degrees; float32 output
    assert np.all(ours[..., 2] < 0)  # facing the camera everywhere


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("seed", [2, 3])
def test_agrees_with_naive_on_steps_and_holes(method, seed):
    depth, mask = rough_depth(seed)
    ours, ref, err = compare(depth, method, mask=mask)
    assert err.max() < 1e-3
    invalid = ~(np.isfinite(depth) & (depth > 0) & mask)
    assert np.all(ours[invalid] == 0.0)


@pytest.mark.parametrize("method", METHODS)
def test_window_five_agrees_with_naive(method):
    depth, mask = rough_depth(4)
    ours, ref, err = compare(depth, method, mask=mask, window=5)
    assert err.max() < 1e-3
    three = surfnorm.estimate(depth, K, method=method, mask=mask)
    assert not np.allclose(ours, three)  # the option is used


@pytest.mark.parametrize("method", METHODS)
def test_fill_value_where_support_is_too_small(method):
    depth = np.full((H, W), 2.0)
    depth[::2, :] = 0.0  # every other row missing
    depth[:, ::2] = 0.0  # and every other column: each valid pixel has no valid neighbour
    out = surfnorm.estimate(depth, K, method=method, fill=np.nan)
    assert np.all(np.isnan(out))
    # two neighbours on a line: a plane fit needs 3 points not on a line
    depth = np.zeros((H, W))
    depth[5, 3:6] = [2.0, 2.0, 2.0]
    out = surfnorm.estimate(depth, K, method=method, fill=np.nan)
    assert np.all(np.isnan(out))
    depth[6, 4] = 2.0  # a third, off the line
    out = surfnorm.estimate(depth, K, method=method, fill=np.nan)
    assert np.all(np.isfinite(out[5, 3:6]))


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize(
    "normal", [(0, 0, -1), (0.3, -0.2, -0.9), (-0.7, 0.1, -0.5), (0.0, 0.8, -0.3), (0.5, 0.5, -0.2)]
)
@pytest.mark.parametrize("window", [3, 5])
def test_exact_on_planes(method, normal, window):
    depth, n_true, hit = surfaces.plane(K, H, W, normal, 2.0)
    out = surfnorm.estimate(depth, K, method=method, window=window)
    # Exact but for float32 depth and output: far below any discretisation error
    assert angle(out[hit], n_true[hit]).max() < 2e-3
    assert np.all(out[~hit] == 0.0)


def errors_by_resolution(method, surface):
    """Mean angular error on a sphere or cylinder of fixed size seen at 24x32, 48x64 and 96x128 pixels."""
    errors = []
    for scale in (1, 2, 4):
        h, w = 24 * scale, 32 * scale
        Ks = surfaces.camera(w, h)
        depth, n_true, hit = getattr(surfaces, surface)(Ks, h, w, (0.1, -0.05, 3.0), 1.0)
        out = surfnorm.estimate(depth, Ks, method=method)
        errors.append(angle(out[hit], n_true[hit]).mean())
    return errors


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("surface", ["sphere", "cylinder"])
def test_error_falls_with_resolution(method, surface):
    errors = errors_by_resolution(method, surface)
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 0.5 * errors[0]
    assert errors[2] < 0.5  # degrees


def test_plane_svd_differs_from_plane_pca_only_where_curved():
    # On a plane they agree exactly; at a depth step (far from planar) the offset in b = [n; d]
    # makes PlaneSVD differ from PlanePCA.
    depth, _, _ = surfaces.plane(K, H, W, (0.3, -0.2, -0.9), 2.0)
    a = surfnorm.estimate(depth, K, method="plane_svd")
    b = surfnorm.estimate(depth, K, method="plane_pca")
    assert angle(a, b).max() < 2e-3
    depth, mask = rough_depth(5)
    a = surfnorm.estimate(depth, K, method="plane_svd", mask=mask)
    b = surfnorm.estimate(depth, K, method="plane_pca", mask=mask)
    assert np.nanmax(angle(a, b)) > 1.0


@pytest.mark.parametrize("method", METHODS)
def test_mnr_and_batches(method):
    depth, mask = rough_depth(6)
    refined = surfnorm.estimate(depth, K, method=method + "+mnr", mask=mask, window=5)
    raw = surfnorm.estimate(depth, K, method=method, mask=mask, window=5)
    assert refined.shape == (H, W, 3) and refined.dtype == np.float32
    # (surfnorm.refine is shadowed by the submodule surfnorm.refine once that is imported: use _api's)
    assert np.array_equal(refined, _api.refine(raw, depth, mask=mask))
    stack = surfnorm.estimate(
        np.stack([depth, depth[::-1]]), K, method=method, mask=np.stack([mask, mask[::-1]]), window=5, threads=2
    )
    assert np.array_equal(stack[0], raw)


def test_registered_with_category_and_reference():
    info = surfnorm.methods()
    for method in METHODS:
        assert info[method].category == "energy minimisation"
        assert info[method].options == {"fill": 0.0, "window": 3}
    assert "Wang" in info["plane_svd"].reference
    assert "Klasing" in info["plane_pca"].reference
    assert "Jordan" in info["vector_svd"].reference


@pytest.mark.parametrize("window", [4, 1, 0, -3, 3.0, "3", True, None])
def test_bad_window_is_refused(window):
    depth = smooth_depth(0)
    with pytest.raises(InputError, match=rf"window: expected an odd integer >= 3 .*, got {window!r}"):
        surfnorm.estimate(depth, K, method="plane_pca", window=window)


def test_averaging_option_on_plane_fit_is_refused():
    with pytest.raises(
        InputError, match=r"options of method 'plane_svd': expected some of fill, window, got unknown option\(s\) dlf"
    ):
        surfnorm.estimate(smooth_depth(0), K, method="plane_svd", dlf="1d")


def test_newton_eigenvalue_matches_eigvalsh():
    from surfnorm.kernels.plane_fit import smallest_eigenvalue

    rng = np.random.default_rng(1)
    for _ in range(300):
        # scatter matrices of 3..9 points, from round clouds to nearly flat and nearly collinear ones
        pts = rng.normal(size=(rng.integers(3, 10), 3)) * rng.uniform(1e-4, 1.0, 3)
        A = (pts - pts.mean(axis=0)).T @ (pts - pts.mean(axis=0))
        got = smallest_eigenvalue(A[0, 0], A[0, 1], A[0, 2], A[1, 1], A[1, 2], A[2, 2])
        assert abs(got - np.linalg.eigvalsh(A)[0]) <= 1e-12 * np.linalg.eigvalsh(A)[2]


def test_plane_svd_eigenvalue_is_smallest_of_the_4x4():
    from surfnorm.kernels.plane_fit import plane_svd_lambda

    rng = np.random.default_rng(2)
    for _ in range(300):
        pts = rng.normal(size=(rng.integers(3, 10), 3)) * rng.uniform(1e-3, 1.0, 3) + rng.uniform(-3, 3, 3)
        A = np.hstack([pts, np.ones((len(pts), 1))])
        c = pts.mean(axis=0)
        S = (pts - c).T @ (pts - c)
        got = plane_svd_lambda(float(len(pts)), *c, S[0, 0], S[0, 1], S[0, 2], S[1, 1], S[1, 2], S[2, 2])
        lam = np.linalg.eigvalsh(A.T @ A)
        assert abs(got - lam[0]) <= 1e-10 * lam[3]


# --- degenerate windows --------------------------------------------------------------------------------------------

PLANE_FITS = ("plane_svd", "plane_pca", "vector_svd")


@pytest.mark.parametrize("method", PLANE_FITS)
def test_plane_fit_of_one_image_row_gets_the_fill_value(method):
    z = np.zeros((3, 3), np.float32)
    z[1] = [2.0, 2.1, 2.3]  # was (0, -1, 0) for plane_pca: the plane of the row's rays, edge-on
    n = surfnorm.estimate(z, [[500, 0, 1], [0, 500, 1], [0, 0, 1]], method=method, fill=np.nan)
    assert np.isnan(n).all()


@st.composite
def line_windows(draw):
    """A frame whose valid pixels lie on one image line (row, column or diagonal), random depths."""
    h, w = draw(st.integers(3, 12)), draw(st.integers(3, 12))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    z = np.zeros((h, w), np.float32)
    kind = draw(st.sampled_from(["row", "column", "diagonal", "anti-diagonal"]))
    k = min(h, w)
    idx = {
        "row": (np.full(w, draw(st.integers(0, h - 1))), np.arange(w)),
        "column": (np.arange(h), np.full(h, draw(st.integers(0, w - 1)))),
        "diagonal": (np.arange(k), np.arange(k)),
        "anti-diagonal": (np.arange(k), k - 1 - np.arange(k)),
    }[kind]
    z[idx] = rng.uniform(0.5, 5.0, len(idx[0]))
    return z, draw(st.sampled_from([3, 5]))


@settings(max_examples=80, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(frame=line_windows())
def test_plane_fits_fill_windows_whose_pixels_lie_on_one_line(frame):
    z, window = frame
    cam = camera(z.shape[1], z.shape[0])
    for method in PLANE_FITS:
        assert np.isnan(surfnorm.estimate(z, cam, method=method, window=window, fill=np.nan)).all(), method


@pytest.mark.parametrize("method", PLANE_FITS)
def test_plane_fit_with_one_pixel_off_the_line_fits(method):
    z = np.zeros((5, 5), np.float32)
    z[2] = 2.0
    z[1, 2] = 2.0  # now the window around (2, 2) spans a plane: the fronto-parallel wall
    n = surfnorm.estimate(z, camera(5, 5), method=method, fill=np.nan)
    np.testing.assert_allclose(n[2, 2], [0, 0, -1], atol=1e-6)
