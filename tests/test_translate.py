"""surfnorm.kernels.translate and surfnorm.kernels.d2nt_v3: D2NT (eq. 9), CP2TV and the fused d2nt_v3.

On surfaces whose normals are known in closed form, then the fast kernels against the slow, obvious reference
in naive_d2nt.py. The kernels sweep the image row by row with a branch-free path where the 3x3 neighbourhood is
all valid and the per-pixel rules elsewhere; the reference comparisons check that every method gives the
reference's numbers on the shipped 3F2N frames (all valid: the fast path), on random depth with holes, zeros,
negative and infinite values (mostly the general path), with a mask, with ``border="reflect"``, with non-zero and
NaN fill values, and for stacks.
"""

import numpy as np
import pytest

import surfnorm
from surfnorm._validate import valid_pixels
from surfnorm.io.threef2n import find_frames, read_frame, sample_root
from surfnorm.kernels.translate import d2nt_normal
from surfnorm.metrics import mean_angular_error

from . import naive_d2nt as naive
from . import surfaces
from .surfaces import holey_depth

METHODS = ["d2nt_basic", "d2nt_v2", "d2nt_v3", "cp2tv"]


def interior(a, k=2):
    return a[k:-k, k:-k]


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("normal", [(0, 0, -1), (0.3, -0.2, -0.9), (-0.6, 0.1, -0.7), (0.1, 0.55, -0.8)])
def test_plane_any_orientation(method, normal):
    K = surfaces.camera(64, 48)
    depth, gt, hit = surfaces.plane(K, 48, 64, normal, distance=3.0)
    assert hit.all()
    n = surfnorm.estimate(depth, K, method=method)
    # Depth of a plane is 1 / (linear in u, v), so finite differences of z are
    # not exact; D2NT with central differences is exact to second order.
    err = surfaces.angle_deg(interior(n), interior(gt))
    assert err.max() < 0.05, (method, err.max())


def test_plane_exact_for_d2nt_with_exact_gradients():
    # Eq. 9 with the true gradients of a plane gives its normal to float precision.
    K = surfaces.camera(64, 48)
    normal = np.array([0.3, -0.2, -0.9]) / np.linalg.norm([0.3, -0.2, -0.9])
    d = 3.0
    v, u = np.mgrid[0:48, 0:64].astype(np.float64)
    uc, vc = u - K[0, 2], v - K[1, 2]
    denom = normal[0] * uc / K[0, 0] + normal[1] * vc / K[1, 1] + normal[2]
    z = -d / denom
    z_u = d * normal[0] / K[0, 0] / denom**2
    z_v = d * normal[1] / K[1, 1] / denom**2
    n = np.stack(d2nt_normal.py_func(z, z_u, z_v, K[0, 0], K[1, 1], uc, vc), axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    np.testing.assert_allclose(n, np.broadcast_to(normal, n.shape), atol=1e-12)


def test_d2nt_equals_cross_product_of_tangents():
    """Paper's claim: eq. 9 is the normalised cross product of the back-projected tangent vectors."""
    rng = np.random.default_rng(1)
    fx, fy, cx, cy = 500.0, 480.0, 31.5, 23.5
    for _ in range(50):
        u, v = rng.uniform(0, 64), rng.uniform(0, 48)
        a, b, c, e = rng.normal(size=4) * [1e-2, 1e-2, 1e-4, 1e-4]
        z = 2 + a * u + b * v + c * u * u + e * u * v  # any smooth depth
        z_u = a + 2 * c * u + e * v
        z_v = b + e * u
        # P(u, v) = z(u, v) * [(u - cx) / fx, (v - cy) / fy, 1]; its partial derivatives:
        t_u = np.array([(z_u * (u - cx) + z) / fx, z_u * (v - cy) / fy, z_u])
        t_v = np.array([z_v * (u - cx) / fx, (z_v * (v - cy) + z) / fy, z_v])
        cross = np.cross(t_v, t_u)
        n = np.array(d2nt_normal.py_func(z, z_u, z_v, fx, fy, u - cx, v - cy))
        np.testing.assert_allclose(n / np.linalg.norm(n), cross / np.linalg.norm(cross), atol=1e-12)
        assert n[2] < 0  # faces the camera (the point is in front, n . P < 0)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("shape", ["sphere", "cylinder"])
def test_error_falls_with_resolution(method, shape):
    errors = []
    for w in (64, 128, 256):
        h = w * 3 // 4
        K = surfaces.camera(w, h)
        if shape == "sphere":
            depth, gt, hit = surfaces.sphere(K, h, w, centre=(0, 0, 4.0), radius=1.5)
        else:
            depth, gt, hit = surfaces.cylinder(K, h, w, centre=(0, 0, 4.0), radius=1.5)
        n = surfnorm.estimate(depth, K, method=method, mask=hit)
        # evaluate away from the silhouette: pixels whose 5x5 neighbourhood is on the surface
        inner = hit.copy()
        for dv in range(-2, 3):
            for du in range(-2, 3):
                inner &= np.roll(np.roll(hit, dv, 0), du, 1)
        errors.append(float(np.mean(surfaces.angle_deg(n[inner], gt[inner]))))
    assert errors[0] > errors[1] > errors[2], errors
    if method == "d2nt_v3":
        # MNR copies a neighbour's normal: first order, the error halves per doubling
        assert errors[2] < errors[0] / 3, errors
    else:
        # central differences: second order, the error quarters per doubling
        assert errors[2] < errors[0] / 4 and errors[2] < 0.05, errors


@pytest.mark.parametrize("method", METHODS)
def test_step_edge(method):
    K = surfaces.camera(64, 48)
    # 3F2N-like depth units (tens to hundreds): the DAG thresholds (eq. 14) are absolute
    depth, gt, _ = surfaces.step(K, 48, 64, near=20.0, far=30.0, column=32)
    n = surfnorm.estimate(depth, K, method=method)
    far_from_edge = np.ones((48, 64), bool)
    far_from_edge[:, 30:34] = False
    err = surfaces.angle_deg(n, gt)
    assert err[2:-2][far_from_edge[2:-2]].max() < 1e-4
    if method in ("d2nt_v2", "d2nt_v3"):
        # DAG picks the side on the same wall: the pixels next to the edge are right too
        assert err[2:-2, 31:33].max() < 1e-4
    else:
        # finite differences straddle the edge: the pixels beside it are wrong
        assert err[2:-2, 31:33].min() > 10


def test_v3_is_v2_refined():
    rng = np.random.default_rng(3)
    depth = (3 + np.cumsum(rng.normal(size=(30, 40)), axis=1) * 0.01).astype(np.float32)
    depth[:, 20:] += 0.5
    K = surfaces.camera(40, 30)
    v2 = surfnorm.estimate(depth, K, method="d2nt_v2")
    np.testing.assert_array_equal(surfnorm.estimate(depth, K, method="d2nt_v3"), surfnorm.refine(v2, depth))
    np.testing.assert_array_equal(
        surfnorm.estimate(depth, K, method="d2nt_v2+mnr", mnr_dlf="beta"), surfnorm.refine(v2, depth, dlf="beta")
    )


def test_mirroring_flips_n_x():
    rng = np.random.default_rng(5)
    depth = (3 + rng.random((30, 40)) * 0.2).astype(np.float32)
    K = np.array([[60.0, 0, 17.3], [0, 61.0, 14.2], [0, 0, 1]])
    Km = K.copy()
    Km[0, 2] = 40 - 1 - K[0, 2]
    for method in ("d2nt_basic", "cp2tv"):
        n = surfnorm.estimate(depth, K, method=method)
        m = surfnorm.estimate(depth[:, ::-1], Km, method=method)[:, ::-1]
        np.testing.assert_allclose(m[..., 0], -n[..., 0], atol=1e-5)
        np.testing.assert_allclose(m[..., 1:], n[..., 1:], atol=1e-5)


def test_dag_threshold_is_in_depth_units():
    """Eq. 14 truncates when |s_2 - s_1| > 1 in depth units: a step of 1 unit is not truncated,
    the same step scaled by 10 is (this is why issue 6 adds a scale-invariant mode)."""
    K = surfaces.camera(64, 48)
    small, gt, _ = surfaces.step(K, 48, 64, near=2.0, far=3.0, column=32)
    edge_small = surfaces.angle_deg(surfnorm.estimate(small, K, method="d2nt_v2"), gt)[10, 31]
    edge_large = surfaces.angle_deg(surfnorm.estimate(small * 10, K, method="d2nt_v2"), gt)[10, 31]
    assert edge_small > 45 and edge_large < 1e-4


# --- the fast kernels against the naive reference (tests/naive_d2nt.py) ---------------------------------

# (method, options, reference)
CASES = [
    ("d2nt_basic", {}, lambda z, ok, cam, fill: naive.d2nt_basic(z, ok, cam, fill=fill)),
    (
        "d2nt_basic",
        {"border": "reflect"},
        lambda z, ok, cam, fill: naive.d2nt_basic(z, ok, cam, border="reflect", fill=fill),
    ),
    ("d2nt_v2", {}, lambda z, ok, cam, fill: naive.d2nt_dag(z, ok, cam, fill=fill)),
    (
        "d2nt_v2",
        {"dlf": "alpha", "truncate": False},
        lambda z, ok, cam, fill: naive.d2nt_dag(z, ok, cam, dlf="alpha", truncate=False, fill=fill),
    ),
    (
        "d2nt_v2",
        {"dlf": "beta", "tau": 0.5},
        lambda z, ok, cam, fill: naive.d2nt_dag(z, ok, cam, dlf="beta", tau=0.5, fill=fill),
    ),
    (
        "d2nt_v2",
        {"dlf": "gamma", "tau": 2.0},
        lambda z, ok, cam, fill: naive.d2nt_dag(z, ok, cam, dlf="gamma", tau=2.0, fill=fill),
    ),
    ("d2nt_v3", {}, lambda z, ok, cam, fill: naive.d2nt_v3(z, ok, cam, fill=fill)),
    (
        "d2nt_v3",
        {"dlf": "alpha", "mnr_dlf": "1d"},
        lambda z, ok, cam, fill: naive.d2nt_v3(z, ok, cam, dlf="alpha", mnr_dlf="1d", fill=fill),
    ),
    (
        "d2nt_v3",
        {"dlf": "beta", "mnr_dlf": "gamma", "truncate": False},
        lambda z, ok, cam, fill: naive.d2nt_v3(z, ok, cam, dlf="beta", mnr_dlf="gamma", truncate=False, fill=fill),
    ),
    ("d2nt_v3+mnr", {}, lambda z, ok, cam, fill: naive.mnr(z, ok, naive.d2nt_v3(z, ok, cam, fill=fill), fill=fill)),
    ("cp2tv", {}, lambda z, ok, cam, fill: naive.cp2tv(z, ok, cam, fill=fill)),
    ("cp2tv", {"border": "reflect"}, lambda z, ok, cam, fill: naive.cp2tv(z, ok, cam, border="reflect", fill=fill)),
    (
        "cp2tv+mnr",
        {"mnr_dlf": "beta"},
        lambda z, ok, cam, fill: naive.mnr(z, ok, naive.cp2tv(z, ok, cam, fill=fill), dlf="beta", fill=fill),
    ),
    (
        "d2nt_basic+mnr",
        {"mnr_dlf": "1d"},
        lambda z, ok, cam, fill: naive.mnr(z, ok, naive.d2nt_basic(z, ok, cam, fill=fill), dlf="1d", fill=fill),
    ),
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
        check(
            surfnorm.estimate(f.depth, f.K, method=method, **options),
            reference(f.depth, ok, f.K, 0.0),
            f"{f.name} {method} {options}",
        )


CAM = surfnorm.Intrinsics(60.0, 64.0, 25.5, 19.0)


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("method, options, reference", CASES, ids=IDS)
def test_holes_and_fill_values_equal_naive(seed, method, options, reference):
    z = holey_depth(seed)
    ok = valid_pixels(z, None)
    for fill in (0.0, np.nan, 0.5):  # a non-zero finite fill counts as a normal for MNR
        check(
            surfnorm.estimate(z, CAM, method=method, fill=fill, **options),
            reference(z, ok, CAM, fill),
            f"seed {seed} fill {fill}",
        )


@pytest.mark.parametrize("method, options, reference", CASES[::3], ids=IDS[::3])
def test_mask_equals_naive(method, options, reference):
    z = holey_depth(3)
    mask = np.ones(z.shape, bool)
    mask[20:30, 35:45] = False
    mask[::7, :] = False
    check(
        surfnorm.estimate(z, CAM, method=method, mask=mask, **options),
        reference(z, valid_pixels(z, mask), CAM, 0.0),
        "mask",
    )


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
