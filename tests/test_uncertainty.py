"""estimate(..., uncertainty=True): each normal's predicted RMS angular error (surfnorm.kernels.uncertainty).

The analytic check is written independently of the kernel: the covariance of a least-squares plane's parameters
from its design matrix, pushed through the normal's formula by finite differences, checked itself against the
spread of the normals of many noisy fits.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import surfnorm
from surfnorm._constants import KAPPA, RHO_FLOOR
from surfnorm.errors import InputError
from surfnorm.kernels import uncertainty as U
from tests.surfaces import camera

FX = FY = 500.0
CX, CY = 40.0, 30.0


def _normal(g_u, g_v, a, u, v):
    """The unit normal facing the camera of the inverse-depth plane w = a + g_u (u' - u) + g_v (v' - v) at (u, v)."""
    m = -np.array([FX * g_u, FY * g_v, a - g_u * (u - CX) - g_v * (v - CY)])
    return m / np.linalg.norm(m)


def _design(r, u, v):
    """Rows (1, u' - u, v' - v) of the full (2r+1)^2 window centred on (u, v)."""
    d = np.arange(-r, r + 1, dtype=float)
    du, dv = np.meshgrid(d, d)
    return np.stack([np.ones(du.size), du.ravel(), dv.ravel()], 1)


def _analytic_sigma_deg(plane, r, sigma_w, u, v):
    """RMS angle (degrees) of the fitted normal: cov = sigma_w^2 (X^T X)^-1 of (a, g_u, g_v), through the normal
    by central differences: sqrt(trace(J cov J^T)) with J the normal's Jacobian (its change across itself)."""
    X = _design(r, u, v)
    cov = sigma_w**2 * np.linalg.inv(X.T @ X)
    a, g_u, g_v = plane
    p0 = np.array([a, g_u, g_v])
    J = np.empty((3, 3))
    for k in range(3):
        h = np.zeros(3)
        h[k] = 1e-6 * max(abs(p0[k]), 1e-9)
        plus = _normal(p0[1] + h[1], p0[2] + h[2], p0[0] + h[0], u, v)
        minus = _normal(p0[1] - h[1], p0[2] - h[2], p0[0] - h[0], u, v)
        J[:, k] = (plus - minus) / (2 * h[k])
    return math.degrees(math.sqrt(np.trace(J @ cov @ J.T)))


PLANE = (0.5, 2e-4, -1.5e-4)  # w at the pixel, g_u, g_v: a tilted plane about 2 m away
PIXEL = (55.0, 20.0)


def test_the_analytic_formula_matches_the_spread_of_noisy_fits():
    rng = np.random.default_rng(0)
    r, sigma_w = 3, 4e-4
    u, v = PIXEL
    X = _design(r, u, v)
    truth = _normal(PLANE[1], PLANE[2], PLANE[0], u, v)
    w = X @ np.array(PLANE)
    angles = []
    for _ in range(4000):
        p = np.linalg.lstsq(X, w + rng.normal(0, sigma_w, w.size), rcond=None)[0]
        n = _normal(p[1], p[2], p[0], u, v)
        angles.append(math.degrees(math.acos(min(1.0, float(n @ truth)))))
    rms = math.sqrt(np.mean(np.square(angles)))
    assert rms == pytest.approx(_analytic_sigma_deg(PLANE, r, sigma_w, u, v), rel=0.05)


def _one_fit_sigma(r, sigma_w, offset=(0.0, 0.0)):
    """The kernel's sigma (degrees) of the pixel's normal from a fit of the full window of radius r (centre
    ``offset`` from the pixel) whose residual is sigma_w^2, without gains, floor or misfit."""
    u, v = PIXEL
    n = _normal(PLANE[1], PLANE[2], PLANE[0], u, v)
    terms = U.fit_variance(sigma_w**2, (2 * r + 1) ** 2, r, -offset[0], -offset[1], sigma_w**2, 1.0, 0.0, 0.0)
    return math.degrees(math.sqrt(U.angle_variance(*n, 1.0 / PLANE[0], u, v, FX, FY, CX, CY, *terms)))


@pytest.mark.parametrize("r", [1, 2, 4, 8])
@pytest.mark.parametrize("sigma_w", [1e-4, 1e-3])
def test_sigma_of_an_exact_plane_with_known_noise_is_the_analytic_one(r, sigma_w):
    u, v = PIXEL
    assert _one_fit_sigma(r, sigma_w) == pytest.approx(_analytic_sigma_deg(PLANE, r, sigma_w, u, v), rel=0.10)


@pytest.mark.parametrize("stride", [2, None])
def test_on_a_plane_with_white_noise_sigma_is_the_rms_error(stride):
    """End to end: adaptive_fit's normals on a tilted plane with white noise in inverse depth, against the
    plane's exact normals; sigma without its floor predicts their RMS error within 10 % at stride 2. The default
    here, stride 4, spreads the corners' variances over each cell as its planes are, and its bilinear means of
    neighbouring planes (whose windows overlap, so their errors are correlated) are more accurate than that mean
    of variances says: sigma is 1.16 times the RMS error, on the safe side, and not more than 1.25 times."""
    z, K = _noisy_plane(3e-3, shape=(240, 320))
    exact = surfnorm.estimate(_noisy_plane(0.0, shape=(240, 320))[0], K, method="adaptive_fit")
    n, sigma = surfnorm.estimate(z, K, method="adaptive_fit", uncertainty=True, stride=stride)
    inner = (slice(20, -20), slice(20, -20))
    error = np.degrees(np.arccos(np.clip(np.sum(n * exact, -1), -1.0, 1.0)))[inner]
    rms_error = math.sqrt(np.mean(np.square(error.astype(np.float64))))
    rms_sigma = math.sqrt(np.mean(np.square(_core(sigma[inner]))))
    if stride == 2:
        assert rms_sigma == pytest.approx(rms_error, rel=0.10)
    else:
        assert 1.0 <= rms_sigma / rms_error <= 1.25, (rms_sigma, rms_error)


def test_a_quadrant_window_is_less_certain_at_its_corner():
    assert _one_fit_sigma(4, 1e-3, (4.0, 4.0)) > _one_fit_sigma(4, 1e-3)


def _noisy_plane(noise, seed=0, shape=(120, 160)):
    K = camera(shape[1], shape[0])
    H, W = shape
    v, u = np.mgrid[0:H, 0:W].astype(float)
    x, y = (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]
    n = np.array([0.2, -0.3, -1.0])
    n /= np.linalg.norm(n)
    z = -2.0 / (n[0] * x + n[1] * y + n[2])
    w = 1.0 / z + np.random.default_rng(seed).normal(0, noise, z.shape) / z
    return (1.0 / w).astype(np.float32), K


def _core(sigma):
    """sigma without ``FLOOR_DEG`` (added in quadrature to every sigma)."""
    return np.sqrt(np.maximum(np.square(sigma.astype(np.float64)) - U.FLOOR_DEG**2, 0.0))


def test_sigma_grows_with_noise_and_shrinks_with_support():
    quiet, K = _noisy_plane(1e-3)
    loud, _ = _noisy_plane(1e-2)
    s_quiet = surfnorm.estimate(quiet, K, method="adaptive_fit", window=7, max_window=7, uncertainty=True)[1]
    s_loud = surfnorm.estimate(loud, K, method="adaptive_fit", window=7, max_window=7, uncertainty=True)[1]
    assert np.nanmedian(_core(s_loud)) > 5 * np.nanmedian(_core(s_quiet))
    s_wide = surfnorm.estimate(loud, K, method="adaptive_fit", window=21, max_window=21, uncertainty=True)[1]
    assert np.nanmedian(_core(s_wide)) < np.nanmedian(_core(s_loud)) / 5
    assert np.all(s_wide >= U.FLOOR_DEG) and np.all(s_loud >= U.FLOOR_DEG)


def _with_holes(z):
    z = z.copy()
    z[20:30, 40:60] = 0
    z[::7, ::11] = np.nan
    return z


@pytest.mark.parametrize("method", ["auto", "adaptive_fit", "d2nt_v3"])
@pytest.mark.parametrize("fill", [0.0, np.nan])
@pytest.mark.parametrize("noise", [0.0, 1e-2])
def test_sigma_is_nan_exactly_where_the_normal_is_fill(method, fill, noise):
    z, K = _noisy_plane(noise) if noise else _noisy_plane(1e-9)
    if not noise:
        z = _noisy_plane(0.0)[0]
    z = _with_holes(z)
    z[60:, 100:] *= 1.5  # a step
    n, sigma = surfnorm.estimate(z, K, method=method, fill=fill, uncertainty=True)
    is_fill = np.isnan(n).all(-1) if np.isnan(fill) else (n == fill).all(-1)
    assert sigma.dtype == np.float32 and sigma.shape == z.shape
    np.testing.assert_array_equal(np.isnan(sigma), is_fill)
    assert np.all(sigma[~is_fill] >= 0)


@pytest.mark.parametrize("method", ["auto", "adaptive_fit", "d2nt_v3"])
def test_normals_are_the_same_bits_with_and_without_sigma(method):
    z, K = _noisy_plane(5e-3)
    z = _with_holes(z)
    plain = surfnorm.estimate(z, K, method=method)
    n, sigma = surfnorm.estimate(z, K, method=method, uncertainty=True)
    np.testing.assert_array_equal(plain, n)
    n1, sigma1 = surfnorm.estimate(z, K, method=method, uncertainty=True, threads=1)
    np.testing.assert_array_equal(n, n1)
    np.testing.assert_array_equal(sigma, sigma1)


def test_a_stack_gives_each_frames_sigma():
    a, K = _noisy_plane(5e-3, seed=1)
    b, _ = _noisy_plane(0.0)
    n, sigma = surfnorm.estimate(np.stack([a, b]), K, uncertainty=True)
    assert sigma.shape == (2,) + a.shape
    for i, z in enumerate((a, b)):
        n_i, s_i = surfnorm.estimate(z, K, uncertainty=True, threads=1)
        np.testing.assert_array_equal(n[i], n_i)
        np.testing.assert_array_equal(sigma[i], s_i)


@pytest.mark.parametrize("method", ["plane_svd", "d2nt_basic", "d2nt_v3+mnr"])
def test_other_methods_refuse_uncertainty_and_name_those_that_give_it(method):
    z, K = _noisy_plane(0.0)
    with pytest.raises(InputError) as info:
        surfnorm.estimate(z, K, method=method, uncertainty=True)
    assert str(info.value) == (
        f"uncertainty: True is available for the methods auto, adaptive_fit, d2nt_v3, got method={method!r}"
    )


def test_uncertainty_must_be_a_bool():
    z, K = _noisy_plane(0.0)
    with pytest.raises(InputError, match="^uncertainty: expected"):
        surfnorm.estimate(z, K, uncertainty="yes")


def test_torch_refuses_uncertainty_with_a_clear_error():
    torch = pytest.importorskip("torch")
    import surfnorm.torch as st

    z, K = _noisy_plane(0.0)
    with pytest.raises(InputError, match=r"^uncertainty: the torch backend gives no sigma; use surfnorm.estimate"):
        st.estimate(torch.from_numpy(z), torch.from_numpy(K), uncertainty=True)


def test_sigma_ranks_the_errors_on_a_noisy_step():
    """Pixels next to the step and the noisier half must read less certain than the quiet plane's."""
    z, K = _noisy_plane(2e-3)
    loud, _ = _noisy_plane(2e-2, seed=3)
    z[:, 80:] = loud[:, 80:]
    n, sigma = surfnorm.estimate(z, K, method="adaptive_fit", uncertainty=True)
    assert np.nanmedian(_core(sigma[:, 90:150])) > 3 * np.nanmedian(_core(sigma[:, 10:70]))


def test_bench_helpers_against_naive_ones():
    from surfnorm.bench.uncertainty import deciles, spearman

    rng = np.random.default_rng(0)
    s = rng.uniform(1, 10, 1000)
    e = s * rng.uniform(0.5, 1.5, 1000)
    d = deciles(e, s)
    order = np.argsort(s)
    first = order[:100]
    assert d[0]["sigma"] == pytest.approx(s[first].mean())
    assert d[0]["rms_error"] == pytest.approx(math.sqrt(np.mean(e[first] ** 2)))
    ranks = lambda x: np.argsort(np.argsort(x)).astype(float)  # noqa: E731 (no ties here)
    assert spearman(s, e) == pytest.approx(np.corrcoef(ranks(s), ranks(e))[0, 1])
    assert spearman([1, 1, 2, 3], [1, 2, 3, 4]) == pytest.approx(np.corrcoef([0.5, 0.5, 2, 3], [0, 1, 2, 3])[0, 1])


def test_cli_writes_sigma_into_the_ply_and_beside_the_npy(tmp_path):
    from typer.testing import CliRunner

    from surfnorm.cli import app

    z, K = _noisy_plane(5e-3)
    z = _with_holes(z)
    np.save(tmp_path / "d.npy", z)
    k = ["--fx", str(K[0, 0]), "--fy", str(K[1, 1]), "--cx", str(K[0, 2]), "--cy", str(K[1, 2])]
    run = CliRunner().invoke
    res = run(app, ["estimate", str(tmp_path / "d.npy"), str(tmp_path / "n"), "--uncertainty", *k])
    assert res.exit_code == 0, res.output
    n_ref, s_ref = surfnorm.estimate(z, K, uncertainty=True)
    np.testing.assert_array_equal(np.load(tmp_path / "n.npy"), n_ref)
    np.testing.assert_array_equal(np.load(tmp_path / "n.sigma.npy"), s_ref)
    res = run(app, ["estimate", str(tmp_path / "d.npy"), str(tmp_path / "n.ply"), "--uncertainty", *k])
    assert res.exit_code == 0, res.output
    body = (tmp_path / "n.ply").read_bytes()
    header, data = body.split(b"end_header\n", 1)
    assert b"property float quality" in header
    rows = np.frombuffer(data, np.dtype([(c, "<f4") for c in ("x", "y", "z", "nx", "ny", "nz", "quality")]))
    has = ~np.isnan(s_ref)
    np.testing.assert_array_equal(rows["quality"], s_ref[has])
    res = run(app, ["estimate", str(tmp_path / "d.npy"), str(tmp_path / "m"), "--uncertainty", "-m", "plane_svd", *k])
    assert res.exit_code == 2 and res.output.count("\n") == 1
    assert "uncertainty: True is available for the methods auto, adaptive_fit, d2nt_v3" in res.output


def _naive_spread(has, var, floor):
    """sigma from the fitted pixels' variances (stride 2), written from the docstring: a fitted pixel its own; a
    pixel on an even row the mean of its left and right fitted neighbours (or its own), on an odd row of those
    above and below (or the four diagonal ones); else the mean over the fitted pixels of its 5x5 neighbourhood."""
    H, W = has.shape
    out = np.full((H, W), np.nan)
    for v in range(H):
        for u in range(W):
            if not has[v, u]:
                continue
            rows = [v] if v % 2 == 0 else [v - 1, v + 1]
            cols = [u] if u % 2 == 0 else [u - 1, u + 1]
            near = [var[y // 2, x // 2] for y in rows for x in cols if 0 <= y < H and 0 <= x < W]
            near = [x for x in near if not np.isnan(x)]
            if not near:
                near = [
                    var[y // 2, x // 2]
                    for y in range(v - 2, v + 3)
                    for x in range(u - 2, u + 3)
                    if 0 <= y < H and 0 <= x < W and y % 2 == 0 and x % 2 == 0 and not np.isnan(var[y // 2, x // 2])
                ]
            if not near:
                out[v, u] = U.NO_FIT_DEG
                continue
            out[v, u] = min(math.sqrt(math.degrees(1.0) ** 2 * np.mean(near) + floor**2), U.MAX_DEG)
    return out


def _naive_spread_cells(has, var, floor):
    """sigma from the fitted pixels' variances (stride 4), written from the docstring: the mean of the variances of
    the pixel's 4x4 cell's corners of weight above 0 that have one, weighted bilinearly by its place in the cell (a
    fitted pixel its own); where none of those has one, the plain mean of the four corners' that have one."""
    H, W = has.shape
    out = np.full((H, W), np.nan)
    for v in range(H):
        for u in range(W):
            if not has[v, u]:
                continue
            fv, fu = (v % 4) / 4, (u % 4) / 4
            corners = []
            for di, wv in ((0, 1 - fv), (1, fv)):
                for dj, wu in ((0, 1 - fu), (1, fu)):
                    i, j = v // 4 + di, u // 4 + dj
                    if i < var.shape[0] and j < var.shape[1] and not np.isnan(var[i, j]):
                        corners.append((wv * wu, var[i, j]))
            weighted = [(w, x) for w, x in corners if w > 0]
            if weighted:
                mean = sum(w * x for w, x in weighted) / sum(w for w, _ in weighted)
            elif corners:
                mean = np.mean([x for _, x in corners])
            else:
                out[v, u] = U.NO_FIT_DEG
                continue
            out[v, u] = min(math.sqrt(math.degrees(1.0) ** 2 * mean + floor**2), U.MAX_DEG)
    return out


@pytest.mark.parametrize(
    "stride,shape", [(2, (9, 11)), (2, (10, 12)), (2, (7, 6)), (4, (9, 11)), (4, (10, 12)), (4, (7, 6)), (4, (13, 17))]
)
def test_spread_against_a_naive_reference(stride, shape):
    rng = np.random.default_rng(sum(shape))
    H, W = shape
    var = rng.uniform(0, 0.01, ((H + stride - 1) // stride, (W + stride - 1) // stride))
    var[rng.random(var.shape) < 0.4] = np.nan
    has = rng.random(shape) < 0.8
    normals = np.zeros(shape + (3,), np.float32)
    normals[has] = (0.0, 0.6, -0.8)
    naive = _naive_spread if stride == 2 else _naive_spread_cells
    out = U.sigma_from_fits(np.ones(shape, bool), normals, var, stride, floor=1.5)
    np.testing.assert_allclose(out, naive(has, var, 1.5), rtol=1e-6)
    out_bands = U.sigma_from_fits(
        np.ones(shape, bool), normals, var, stride, floor=1.5, bands=lambda f, n: [f(0, 3), f(3, n)]
    )
    np.testing.assert_array_equal(out, out_bands)


def _lstsq_fit3(z, valid, v, u, cam):
    """The least-squares plane of w = 1/z over the valid pixels of the 3x3 window centred on (v, u), offsets as
    coordinates: (rss / dof, n, g_u, g_v, a, unit normal at the centre), or None (fewer than 4 points, a line, or
    a centre outside the frame)."""
    fx, fy, cx, cy = cam
    H, W = z.shape
    if not (0 <= v < H and 0 <= u < W):
        return None
    pts = [
        (dx, dy, 1.0 / float(z[v + dy, u + dx]))
        for dy in (-1, 0, 1)
        for dx in (-1, 0, 1)
        if 0 <= v + dy < H and 0 <= u + dx < W and valid[v + dy, u + dx]
    ]
    X = np.array([[1.0, dx, dy] for dx, dy, _ in pts]).reshape(-1, 3)
    if len(pts) < 4 or np.linalg.matrix_rank(X) < 3:
        return None
    w = np.array([p[2] for p in pts])
    (a, g_u, g_v), *_ = np.linalg.lstsq(X, w, rcond=None)
    rss = float(np.sum((X @ (a, g_u, g_v) - w) ** 2))
    m = np.array([fx * g_u, fy * g_v, a - g_u * (u - cx) - g_v * (v - cy)])  # eq. (2), up to its sign
    return rss / (len(pts) - 3), len(pts), g_u, g_v, a, m / np.linalg.norm(m)


def _fit_rows(z, valid, cam, c0=None, c1=None):
    """Every row's :func:`U._fits3_row` (H, 8, W + 2), each from a ring of three input rows, as the kernel runs them."""
    H, W = z.shape
    c0, c1 = (0, W) if c0 is None else (c0, c1)
    inputs = np.zeros((3, 3, W + 2))
    col = np.empty((6, W + 2))
    fits = np.zeros((H, 8, W + 2))
    U._inputs_row(z, valid, -1, 0, W, inputs[2])
    U._inputs_row(z, valid, 0, 0, W, inputs[0])
    for v in range(H):
        U._inputs_row(z, valid, v + 1, 0, W, inputs[(v + 1) % 3])
        U._fits3_row(inputs, v, H, (FX, FY, CX, CY), c0, c1, col, fits[v])
    return fits


def test_centred_3x3_fits_against_least_squares():
    rng = np.random.default_rng(7)
    H, W = 8, 9
    z = rng.uniform(1.0, 2.0, (H, W))
    valid = rng.random((H, W)) < 0.75
    fits = _fit_rows(z, valid, (FX, FY, CX, CY))
    for v in range(H):
        for u in range(W):
            want = _lstsq_fit3(z, valid, v, u, (FX, FY, CX, CY))
            if want is None:
                assert fits[v, 0, u + 1] == np.inf
                continue
            q, n, g_u, g_v, a, m = want
            np.testing.assert_allclose(fits[v, 1:5, u + 1], [n, g_u, g_v, a], rtol=1e-9, atol=1e-12)
            assert fits[v, 0, u + 1] == pytest.approx(q, rel=1e-6, abs=1e-15)
            np.testing.assert_allclose(fits[v, 5:, u + 1], m, rtol=1e-9, atol=1e-12)
    # the pad columns have no fit, nor the columns outside those asked for
    assert np.all(fits[:, 0, [0, W + 1]] == np.inf)
    part = _fit_rows(z, valid, (FX, FY, CX, CY), 2, 6)
    np.testing.assert_array_equal(part[:, :, 3:7], fits[:, :, 3:7])
    assert np.all(part[:, 0, :3] == np.inf) and np.all(part[:, 0, 7:] == np.inf)


def _naive_d2nt_sigma(z, valid, normals, cam, noise, fill):
    """d2nt_v3's sigma pixel by pixel, as the module's docstring says, from least-squares fits (the variance
    formulas themselves are checked against the analytic ones above)."""
    fx, fy, cx, cy = cam
    f = math.sqrt(fx * fy)
    z0, inv_step, rho_t = noise
    H, W = z.shape
    fit = {}
    for v in range(-1, H + 1):
        for u in range(-1, W + 1):
            fit[v, u] = _lstsq_fit3(z, valid, v, u, cam)
    out = np.full((H, W), np.nan)
    for v in range(H):
        for u in range(W):
            n = normals[v, u].astype(float)
            if not valid[v, u] or not np.all(np.isfinite(n)) or np.all(n == fill):
                continue
            # the window centred on the pixel, or one with it at a corner: the smallest residual, the first of equals
            best = None
            for dv, du in ((0, 0), (-1, -1), (-1, 1), (1, -1), (1, 1)):
                got = fit[v + dv, u + du]
                if got is not None and (best is None or got[0] < best[0][0]):
                    best = (got, v + dv, u + du)
            if best is None:
                out[v, u] = U.NO_FIT_DEG
                continue
            (q, count, g_u, g_v, a, _), bv, bu = best
            o_u, o_v = float(u - bu), float(v - bv)
            zp = float(z[v, u])
            rho = rho_t[min(max(int((zp - z0) * inv_step), 0), len(rho_t) - 1)]
            noise2 = (rho / (zp * f)) ** 2
            gains = (U.D2NT_GAIN, U.D2NT_MISFIT_GAIN, U.MISFIT_SIGNIFICANCE)
            var_g, var_a, c_u, c_v = U.fit_variance(q, count, 1.0, o_u, o_v, noise2, *gains)
            var = U.angle_variance(*n, zp, u, v, fx, fy, cx, cy, var_g, var_a, c_u, c_v)
            # the best plane's own normal at the pixel, against d2nt_v3's
            m = np.array([fx * g_u, fy * g_v, a + g_u * o_u + g_v * o_v - g_u * (u - cx) - g_v * (v - cy)])
            m /= np.linalg.norm(m)
            var += U.D2NT_DISAGREEMENT * max(1.0 - float(n @ m) ** 2, 0.0)
            # the turn to the planes of the neighbours' windows that pass the noise test
            limit = (KAPPA * max(rho, RHO_FLOOR)) ** 2 / (zp * f) ** 2
            turns = [
                max(1.0 - float(m @ fit[y, x][5]) ** 2, 0.0)
                for y in (v - 1, v, v + 1)
                for x in (u - 1, u, u + 1)
                if (y, x) != (v, u) and fit[y, x] is not None and fit[y, x][0] <= limit
            ]
            var += U.D2NT_TURN * (np.mean(turns) if turns else 0.0)
            out[v, u] = min(math.sqrt(math.degrees(1.0) ** 2 * var + U.FLOOR_DEG**2), U.MAX_DEG)
    return out


def _test_frame(fill, noise=2e-3, seed=11):
    """A tilted plane with noise, holes, an empty row, a row whose depth starts and ends inside the frame, and a
    step; d2nt_v3's normals (one valid pixel without a normal, at (2, 5)); K."""
    rng = np.random.default_rng(seed)
    H, W = 12, 15
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    z = (1.5 + 0.01 * u + 0.004 * v + rng.normal(0.0, noise, (H, W))) * (rng.random((H, W)) < 0.85)
    z[4] = 0.0
    z[7, :3] = z[7, 11:] = 0.0
    z[9:, 9:] *= 1.2  # a step
    z = z.astype(np.float32)
    K = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1.0]])
    normals = surfnorm.estimate(z, K, method="d2nt_v3", fill=fill)
    normals[2, 5] = fill
    return z, normals, K


def _check_sigma(got, want, z, normals, fill, banded, atol=1e-6):
    """``got`` as ``want`` (to ``atol`` degrees), NaN exactly where there is no normal, and the same bits with rows
    on two threads."""
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=atol)
    has = (z > 0) & np.isfinite(normals).all(-1) & ~(normals == fill).all(-1)
    assert has.sum() > 100 and not has[2, 5]
    np.testing.assert_array_equal(np.isnan(got), ~has)
    two = lambda stage, n: [stage(0, 5), stage(5, n)]  # noqa: E731  rows split anywhere
    np.testing.assert_array_equal(banded(two), got)


@pytest.mark.parametrize("fill", [0.0, np.nan])
def test_d2nt_sigma_against_a_naive_reference(fill):
    z, normals, K = _test_frame(fill)
    valid = z > 0
    rng = np.random.default_rng(12)
    noise = (1.4, 20.0, rng.uniform(1e-4, 3e-3, 8))  # the frame's rho at 1.4 + k / 20 m
    want = _naive_d2nt_sigma(z, valid, normals, (FX, FY, CX, CY), noise, fill)
    cam = surfnorm.Intrinsics.from_matrix(K)
    got = U.d2nt_sigma(z, valid, cam, normals, noise, fill=fill)

    def banded(bands):
        return U.d2nt_sigma(z, valid, cam, normals, noise, fill=fill, bands=bands)

    _check_sigma(got, want, z, normals, fill, banded)


def _naive_clean_sigma(z, normals, fill):
    """The clean model pixel by pixel, as the module's docstring says."""
    H, W = z.shape
    f = math.sqrt(FX * FY)
    valid = z > 0
    n = normals.astype(np.float64)
    has = valid & np.isfinite(n).all(-1) & ~(n == fill).all(-1)
    w = np.where(valid, 1.0 / np.where(valid, z, 1.0), 0.0)

    def pairs(y, x):  # (squared sines, count) of pixel (y, x)'s pairs with its right and lower neighbours
        out = []
        for q in ((y, x + 1), (y + 1, x)):
            if 0 <= q[0] < H and 0 <= q[1] < W and has[y, x] and has[q]:
                out.append(1.0 - float(n[y, x] @ n[q]) ** 2)
        return out

    sigma = np.full((H, W), np.nan)
    for v in range(H):
        for u in range(W):
            if not has[v, u]:
                continue
            bend = 0.0
            for a, b in (((v - 1, u), (v + 1, u)), ((v, u - 1), (v, u + 1))):
                if not all(0 <= p[0] < H and 0 <= p[1] < W for p in (a, b)):
                    continue  # a line that leaves the frame says nothing
                if valid[a] and valid[b]:
                    bend = max(bend, abs(w[a] - 2.0 * w[v, u] + w[b]) / w[v, u])
                else:
                    bend = max(bend, 1.0)  # a discontinuity
            sines = [
                t
                for y in range(v - 2, v + 3)
                for x in range(u - 2, u + 3)
                if 0 <= y < H and 0 <= x < W
                for t in pairs(y, x)
            ]
            turn = np.mean(sines) if sines else 0.0
            var = (U.CLEAN_BEND * f * bend) ** 2 + U.CLEAN_TURN * turn
            sigma[v, u] = min(math.sqrt(math.degrees(1.0) ** 2 * var + U.CLEAN_FLOOR_DEG**2), U.CLEAN_MAX_DEG)
    return sigma


@pytest.mark.parametrize("fill", [0.0, np.nan])
@pytest.mark.parametrize("noise", [0.0, 2e-4])
def test_clean_sigma_against_a_naive_reference(fill, noise):
    z, normals, K = _test_frame(fill, noise)
    valid = z > 0
    want = _naive_clean_sigma(z, normals, fill)
    cam = surfnorm.Intrinsics.from_matrix(K)
    got = U.d2nt_sigma(z, valid, cam, normals, None, clean=True, fill=fill)

    def banded(bands):
        return U.d2nt_sigma(z, valid, cam, normals, None, clean=True, fill=fill, bands=bands)

    _check_sigma(got, want, z, normals, fill, banded, atol=1e-3)  # the kernel works in float32
    # every term shows: the floor on the plane, the bend, the turn and the cap at the step and the holes
    assert np.nanmin(got) < U.CLEAN_FLOOR_DEG + 0.5 and np.nanmax(got) == pytest.approx(U.CLEAN_MAX_DEG)
    assert np.sum((got > U.CLEAN_FLOOR_DEG + 0.5) & (got < U.CLEAN_MAX_DEG - 0.5)) >= 5


def _roof(tilt_deg, shape=(60, 80)):
    """Depth of two planes meeting at a ridge down the middle column, each tilted ``tilt_deg`` about the vertical
    axis (towards and away from the camera), 2 m away."""
    H, W = shape
    K = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1.0]])
    u = np.arange(W, dtype=float)[None, :].repeat(H, 0)
    x = (u - CX) / FX  # the ray's slope; the planes z = 2 + k |X - X_ridge| through the ridge at u = W / 2
    k = math.tan(math.radians(tilt_deg))
    x0 = (W / 2 - CX) / FX * 2.0
    z = np.where(u < W / 2, (2.0 + k * x0) / (1.0 + k * x), (2.0 - k * x0) / (1.0 - k * x))
    return z.astype(np.float32), K


@pytest.mark.parametrize("method", ["d2nt_v3", "auto"])
def test_clean_sigma_grows_where_planes_turn(method):
    # a clean roof: the faces' pixels away from the ridge see flat depth and parallel normals (sigma the floor);
    # the pixels beside the ridge see the depth bend and the normals turn, by more on a sharper ridge
    soft, K = _roof(5.0)
    sharp, _ = _roof(20.0)
    s_soft = surfnorm.estimate(soft, K, method=method, uncertainty=True)[1]
    s_sharp = surfnorm.estimate(sharp, K, method=method, uncertainty=True)[1]
    face = np.s_[10:50, 10:30]
    ridge = np.s_[10:50, 39:41]
    assert np.allclose(s_soft[face], U.CLEAN_FLOOR_DEG, atol=0.01)
    assert np.nanmedian(s_soft[ridge]) > U.CLEAN_FLOOR_DEG + 0.3
    assert np.nanmedian(s_sharp[ridge]) > np.nanmedian(s_soft[ridge]) + 1.0
    # the clean model, as d2nt_sigma gives it
    valid = soft > 0
    normals = surfnorm.estimate(soft, K, method=method)
    cam = surfnorm.Intrinsics.from_matrix(K)
    np.testing.assert_array_equal(s_soft, U.d2nt_sigma(soft, valid, cam, normals, None, clean=True))


def test_clean_sigma_is_capped_and_noisy_sigma_is_not():
    z, K = _noisy_plane(0.0)
    z = z.copy()
    z[:, ::2] *= 1.3  # every window of every pixel straddles a discontinuity: the largest misfit there is
    clean = surfnorm.estimate(z, K, method="d2nt_v3", uncertainty=True)[1]
    assert np.nanmax(clean) == pytest.approx(U.CLEAN_MAX_DEG)
    loud, _ = _noisy_plane(3e-2)
    noisy = surfnorm.estimate(loud, K, method="d2nt_v3", uncertainty=True)[1]
    assert np.nanmax(noisy) > U.CLEAN_MAX_DEG


def test_cli_refuses_an_existing_sigma_file_without_overwrite(tmp_path):
    from typer.testing import CliRunner

    from surfnorm.cli import app

    z, K = _noisy_plane(5e-3)
    np.save(tmp_path / "d.npy", z)
    (tmp_path / "n.sigma.npy").write_bytes(b"keep")
    k = ["--fx", str(K[0, 0]), "--fy", str(K[1, 1]), "--cx", str(K[0, 2]), "--cy", str(K[1, 2])]
    res = CliRunner().invoke(app, ["estimate", str(tmp_path / "d.npy"), str(tmp_path / "n"), "--uncertainty", *k])
    assert res.exit_code == 2 and res.output.count("\n") == 1
    assert "n.sigma.npy" in res.output and "--overwrite" in res.output
    assert (tmp_path / "n.sigma.npy").read_bytes() == b"keep"
    assert not (tmp_path / "n.npy").exists()
    res = CliRunner().invoke(
        app, ["estimate", str(tmp_path / "d.npy"), str(tmp_path / "n"), "--uncertainty", "--overwrite", *k]
    )
    assert res.exit_code == 0, res.output
    assert np.load(tmp_path / "n.sigma.npy").shape == z.shape


def test_the_noise_correlation_leaves_the_curvature_out():
    """White noise on a strongly curved surface: the stride-2 over stride-1 mean square alone reads curvature as
    correlation (well above 1); NoiseProfile.correlation, with the curvature solved for from the three strides,
    stays near 1. Noise smoothed over a few pixels on a plane reads well above 1 either way."""
    import cv2

    from surfnorm.kernels import sensor_noise as S

    rng = np.random.default_rng(3)
    H, W, f = 240, 320, 300.0
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    r2 = ((u - W / 2) ** 2 + (v - H / 2) ** 2) / (W / 2) ** 2
    w_bowl = 0.5 + 0.25 * r2  # inverse depth, curved
    noise = 2e-5 * rng.standard_normal((H, W))
    z = (1.0 / (w_bowl + noise)).astype(np.float32)
    valid = np.ones_like(z, bool)
    _, _, xs, _, _, _, _ = S._samples(z, valid, f)
    raw = float(np.mean(xs[1] ** 2) / np.mean(xs[0] ** 2))
    got = S.noise_profile(z, valid, f).correlation
    assert raw > 1.5 and abs(got - 1.0) < 0.15, (raw, got)
    smooth = cv2.GaussianBlur(rng.standard_normal((H, W)), (0, 0), 1.5) * 1e-4
    z = (1.0 / (0.5 + smooth)).astype(np.float32)
    assert S.noise_profile(z, valid, f).correlation > 2.0


@pytest.mark.parametrize("stride", [1, 2, 4])
@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("fill", [0.0, np.nan])
def test_the_fit_records_which_pixels_hold_a_normal(stride, threads, fill):
    from surfnorm._bands import on_threads
    from surfnorm.camera import Intrinsics
    from surfnorm.kernels.adaptive_fit import adaptive_fit

    z, K = _noisy_plane(1e-2)
    z = _with_holes(z)
    z[60:, 100:] *= 1.5  # a step
    z[40:44, :] = 0.0  # rows without depth
    z[::3, 5] = 0.0
    valid = np.isfinite(z) & (z > 0)
    z = np.where(valid, z, 0.0).astype(np.float32)
    out = np.full(z.shape + (3,), 7.0, np.float32)
    record: dict = {}
    adaptive_fit(
        z, valid, Intrinsics.from_matrix(K), out, fill=fill, stride=stride, record=record, bands=on_threads(threads)
    )
    is_fill = np.isnan(out).all(-1) if np.isnan(fill) else (out == fill).all(-1)
    assert is_fill.any() and (~is_fill).any()
    np.testing.assert_array_equal(record["has"], valid & ~is_fill & np.isfinite(out).all(-1))
