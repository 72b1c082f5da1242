"""The fast D2NT-family, CP2TV and MNR kernels against the slow, obvious reference in naive_d2nt.py.

The kernels sweep the image row by row with a branch-free path where the 3x3
neighbourhood is all valid and the per-pixel rules elsewhere; these tests
check that every method gives the reference's numbers on the shipped 3F2N
frames (all valid: the fast path), on random depth with holes, zeros,
negative and infinite values (mostly the general path), with a mask, with
``border="reflect"``, with non-zero and NaN fill values, and for stacks.
"""

import math

import numpy as np
import pytest

import surfnorm
from surfnorm._validate import valid_pixels
from surfnorm._validate import valid_map
from surfnorm.io.threef2n import find_frames, read_frame, sample_root
from surfnorm.metrics import mean_angular_error

from . import naive_d2nt as naive

# (method, options, reference)
CASES = [
    ("d2nt_basic", {}, lambda z, ok, cam, fill: naive.d2nt_basic(z, ok, cam, fill=fill)),
    ("d2nt_basic", {"border": "reflect"}, lambda z, ok, cam, fill: naive.d2nt_basic(z, ok, cam, border="reflect", fill=fill)),
    ("d2nt_v2", {}, lambda z, ok, cam, fill: naive.d2nt_dag(z, ok, cam, fill=fill)),
    ("d2nt_v2", {"dlf": "alpha", "truncate": False}, lambda z, ok, cam, fill: naive.d2nt_dag(z, ok, cam, dlf="alpha", truncate=False, fill=fill)),
    ("d2nt_v2", {"dlf": "beta", "tau": 0.5}, lambda z, ok, cam, fill: naive.d2nt_dag(z, ok, cam, dlf="beta", tau=0.5, fill=fill)),
    ("d2nt_v2", {"dlf": "gamma", "tau": 2.0}, lambda z, ok, cam, fill: naive.d2nt_dag(z, ok, cam, dlf="gamma", tau=2.0, fill=fill)),
    ("d2nt_v3", {}, lambda z, ok, cam, fill: naive.d2nt_v3(z, ok, cam, fill=fill)),
    ("d2nt_v3", {"dlf": "alpha", "mnr_dlf": "1d"}, lambda z, ok, cam, fill: naive.d2nt_v3(z, ok, cam, dlf="alpha", mnr_dlf="1d", fill=fill)),
    ("d2nt_v3", {"dlf": "beta", "mnr_dlf": "gamma", "truncate": False},
     lambda z, ok, cam, fill: naive.d2nt_v3(z, ok, cam, dlf="beta", mnr_dlf="gamma", truncate=False, fill=fill)),
    ("d2nt_v3+mnr", {}, lambda z, ok, cam, fill: naive.mnr(z, ok, naive.d2nt_v3(z, ok, cam, fill=fill), fill=fill)),
    ("cp2tv", {}, lambda z, ok, cam, fill: naive.cp2tv(z, ok, cam, fill=fill)),
    ("cp2tv", {"border": "reflect"}, lambda z, ok, cam, fill: naive.cp2tv(z, ok, cam, border="reflect", fill=fill)),
    ("cp2tv+mnr", {"mnr_dlf": "beta"}, lambda z, ok, cam, fill: naive.mnr(z, ok, naive.cp2tv(z, ok, cam, fill=fill), dlf="beta", fill=fill)),
    ("d2nt_basic+mnr", {"mnr_dlf": "1d"}, lambda z, ok, cam, fill: naive.mnr(z, ok, naive.d2nt_basic(z, ok, cam, fill=fill), dlf="1d", fill=fill)),
]
IDS = [f"{m}-{'-'.join(f'{k}={v}' for k, v in o.items())}" for m, o, _ in CASES]

# Float32 rounding of the same operations in the same order gives the same bits;
# the tolerance only allows for exp(), which NumPy and the kernels may round
# differently in rare cases (measured: none on these inputs).
ATOL = 1e-6


def check(ours, ref, what):
    assert ours.shape == ref.shape and ours.dtype == np.float32
    np.testing.assert_allclose(ours, ref, rtol=0, atol=ATOL, err_msg=what)


@pytest.fixture(scope="module")
def frames():
    return [read_frame(sample_root(), name) for name in find_frames(sample_root())]


@pytest.mark.parametrize("method, options, reference", CASES, ids=IDS)
def test_shipped_frames_equal_naive(frames, method, options, reference):
    assert len(frames) == 3
    for f in frames:
        ok = valid_pixels(f.depth, None)
        check(surfnorm.estimate(f.depth, f.K, method=method, **options), reference(f.depth, ok, f.K, 0.0),
              f"{f.name} {method} {options}")


def holey_depth(seed, h=41, w=53):
    """A tilted plane with a step, noise, a spike, and holes of every kind (NaN, 0, < 0, inf), some in runs."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:h, 0:w]
    z = 2.0 + 0.01 * u + 0.02 * v + 0.3 * (u > w // 2) + 0.003 * rng.standard_normal((h, w))
    z[h // 3, w // 3] += 1.0
    holes = rng.random((h, w))
    z[holes < 0.04] = np.nan
    z[(holes >= 0.04) & (holes < 0.07)] = 0.0
    z[(holes >= 0.07) & (holes < 0.08)] = -1.0
    z[(holes >= 0.08) & (holes < 0.085)] = np.inf
    z[5:9, 10:30] = np.nan  # a large hole
    z[:, 0] = np.where(rng.random(h) < 0.5, 0.0, z[:, 0])  # gaps on the image border
    return z.astype(np.float32)


CAM = surfnorm.Intrinsics(60.0, 64.0, 25.5, 19.0)


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("method, options, reference", CASES, ids=IDS)
def test_holes_and_fill_values_equal_naive(seed, method, options, reference):
    z = holey_depth(seed)
    ok = valid_pixels(z, None)
    for fill in (0.0, np.nan, 0.5):  # a non-zero finite fill counts as a normal for MNR
        check(surfnorm.estimate(z, CAM, method=method, fill=fill, **options), reference(z, ok, CAM, fill),
              f"seed {seed} fill {fill}")


@pytest.mark.parametrize("method, options, reference", CASES[::3], ids=IDS[::3])
def test_mask_equals_naive(method, options, reference):
    z = holey_depth(3)
    mask = np.ones(z.shape, bool)
    mask[20:30, 35:45] = False
    mask[::7, :] = False
    check(surfnorm.estimate(z, CAM, method=method, mask=mask, **options), reference(z, valid_pixels(z, mask), CAM, 0.0),
          "mask")


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
    from surfnorm.kernels.mnr import mnr
    from surfnorm.kernels.d2nt_v3 import d2nt_v3

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
            check(mnr(z, ok, raw, np.empty_like(raw), dlf=dlf, tie_tol=tie_tol),
                  naive.mnr(z, ok, raw, dlf=dlf, tie_tol=tie_tol), f"mnr {dlf} {tie_tol}")
        check(d2nt_v3(z, ok, cam, np.empty(z.shape + (3,), np.float32), tie_tol=tie_tol),
              naive.d2nt_v3(z, ok, cam, tie_tol=tie_tol), f"d2nt_v3 {tie_tol}")
    # and the tolerance changes choices (otherwise the comparison above would prove nothing)
    assert not np.array_equal(naive.mnr(z, ok, raw, tie_tol=1e-3), naive.mnr(z, ok, raw))


@pytest.mark.parametrize("method", ["d2nt_basic", "d2nt_v2", "d2nt_v3", "cp2tv", "cp2tv+mnr"])
def test_stack_equals_frames(method):
    z = np.stack([holey_depth(s, 30, 37) for s in range(5)])
    mask = np.ones(z.shape[1:], bool)
    mask[3:6, 4:20] = False
    Ks = [surfnorm.Intrinsics(60.0 + i, 64.0, 18.0, 14.5) for i in range(5)]
    for threads in (1, 2):
        stack = surfnorm.estimate(z, Ks, method=method, mask=mask, threads=threads)
        for i in range(5):
            np.testing.assert_array_equal(stack[i], surfnorm.estimate(z[i], Ks[i], method=method, mask=mask))


def test_valid_map_equals_numpy_rule():
    z = holey_depth(7)
    z[0, :4] = [-0.0, np.float32(1e-45), -np.inf, np.float32(3e38)]
    mask = np.random.default_rng(7).random(z.shape) < 0.8
    np.testing.assert_array_equal(valid_map(z, None), valid_pixels(z, None))
    np.testing.assert_array_equal(valid_map(z, mask), valid_pixels(z, mask))


def test_softmin_exp_is_correctly_rounded():
    # The kernels' exp(-s / tau) (softmin_row: exp32 in float64, FMA-contracted, rounded once) against exp in
    # float64 rounded to float32, on the arguments the softmin sees and at the edges of the float32 range.
    # (An exhaustive run over all 1.1e9 float32 in [-104.5, 0] found no difference: benchmarks/README.md.)
    from surfnorm.kernels.gradients import softmin_row

    rng = np.random.default_rng(0)
    x = np.concatenate([-rng.random(200_000) * 110, -rng.random(100_000) * 1e-3, -rng.exponential(1.0, 100_000),
                        [0.0, -0.0, -1e-45, -87.33655, -103.27893, -103.97208, -104.0, -200.0, 88.0, 88.7228, 89.0, 1e3]])
    x = x.astype(np.float32)
    for tau in (1.0, 0.37):
        out = np.empty_like(x)
        softmin_row(-x * np.float32(tau), np.float32(tau), out)
        with np.errstate(over="ignore"):
            expected = np.exp(((-x * np.float32(tau)) * np.float32(-1) / np.float32(tau)).astype(np.float64))
            expected = expected.astype(np.float32)
        np.testing.assert_array_equal(out, expected)
    out = np.empty(3, np.float32)
    softmin_row(np.array([np.nan, np.inf, -np.inf], np.float32), np.float32(1.0), out)
    assert math.isnan(out[0]) and out[1] == 0.0 and out[2] == np.inf


def test_authors_package_agrees(frames):
    """The authors' d2nt 0.1.3 (CI installs it: pip install --no-deps d2nt==0.1.3, beside opencv-python-headless)."""
    d2nt = pytest.importorskip("d2nt")
    for f in frames:
        # The authors' pixel coordinates are 1-based: their u0 is our cx + 1.
        K = np.array([[f.K.fx, 0, f.K.cx + 1], [0, f.K.fy, f.K.cy + 1], [0, 0, 1]])
        for version, options in (("d2nt_basic", {"border": "reflect"}), ("d2nt_v2", {}), ("d2nt_v3", {})):
            theirs = d2nt.depth2normal(f.depth, K, version=version)
            ours = surfnorm.estimate(f.depth, f.K, method=version, **options)
            close = np.all(np.abs(ours - theirs) <= 1e-5, axis=-1)
            if version != "d2nt_v3":
                assert close.all(), (f.name, version, np.abs(ours - theirs).max())
            else:
                # MNR picks the argmin of |Laplacian|; the authors' filter2D sums the Laplacian in another
                # order, so near-ties on smooth surfaces go the other way at about 1% of pixels.
                assert close.mean() > 0.98, (f.name, close.mean())
                e_ours = mean_angular_error(ours, f.normals, f.mask)
                e_theirs = mean_angular_error(theirs, f.normals, f.mask)
                assert abs(e_ours - e_theirs) < 0.002, (f.name, e_ours, e_theirs)
