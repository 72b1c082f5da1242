"""surfnorm.kernels.mnr: MNR (D2NT Sec. III-C and IV-A, eq. 16-20) against the naive reference, on any normal map."""

import numpy as np

import surfnorm
from surfnorm._validate import valid_pixels

from . import naive_d2nt as naive
from .surfaces import holey_depth

ATOL = 1e-6  # see test_translate.py


def check(ours, ref, what):
    assert ours.shape == ref.shape and ours.dtype == np.float32
    np.testing.assert_allclose(ours, ref, rtol=0, atol=ATOL, err_msg=what)


def test_refine_equals_naive_mnr_on_any_normals():
    rng = np.random.default_rng(5)
    z = holey_depth(5)
    n = rng.standard_normal(z.shape + (3,)).astype(np.float32)
    n[rng.random(z.shape) < 0.1] = 0.0  # normals missing
    n[rng.random(z.shape) < 0.05] = np.nan
    ok = valid_pixels(z, None)
    for dlf in ("1d", "alpha", "beta", "gamma"):
        check(surfnorm.refine(n, z, dlf=dlf), naive.mnr(z, ok, n, dlf=dlf), dlf)


def test_mnr_near_tie_tolerance_equals_naive():
    """The scale-invariant mode's MNR rule (a candidate must be smoother by more than tie_tol * z): kernel = reference."""
    from surfnorm.kernels.d2nt_v3 import d2nt_v3
    from surfnorm.kernels.mnr import mnr

    rng = np.random.default_rng(7)
    v, u = np.mgrid[0:41, 0:53]
    # integer steps (exact ties of the smoothness), then a unit change that makes them near-ties
    z = (1500 + 3 * u + 2 * v + rng.integers(0, 3, (41, 53)) + 40 * (u > 30)).astype(np.float32) / np.float32(15)
    z[rng.random(z.shape) < 0.05] = 0.0
    ok = valid_pixels(z, None)
    cam = surfnorm.Intrinsics(60.0, 64.0, 25.5, 19.0)
    raw = naive.d2nt_dag(z, ok, cam)
    for tie_tol in (0.0, 1.5e-6, 1e-3):
        for dlf in ("1d", "alpha"):
            check(
                mnr(z, ok, raw, np.empty_like(raw), dlf=dlf, tie_tol=tie_tol),
                naive.mnr(z, ok, raw, dlf=dlf, tie_tol=tie_tol),
                f"mnr {dlf} {tie_tol}",
            )
        check(
            d2nt_v3(z, ok, cam, np.empty(z.shape + (3,), np.float32), tie_tol=tie_tol),
            naive.d2nt_v3(z, ok, cam, tie_tol=tie_tol),
            f"d2nt_v3 {tie_tol}",
        )
    # and the tolerance changes choices (otherwise the comparison above would prove nothing)
    assert not np.array_equal(naive.mnr(z, ok, raw, tie_tol=1e-3), naive.mnr(z, ok, raw))
