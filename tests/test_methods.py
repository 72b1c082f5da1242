"""surfnorm.methods: the registry (each name reaches its kernel in one hop), and properties of every registered
method (hypothesis): invalid depth, mirroring and units.

* on random depth with random holes (0, NaN, +-inf, negative, user mask) every output pixel is
  either the fill value or a finite unit vector; every invalid pixel is the fill value; a pixel
  whose whole 3x3 neighbourhood is valid gets a normal;
* the values at invalid pixels are never read: replacing them by anything changes nothing;
* mirroring the image left-right (and the principal point with it) mirrors n_x;
* in the scale-invariant mode, scaling depth by any factor leaves the normals unchanged.

MNR (in ``d2nt_v3`` and any ``+mnr``) gives each pixel the normal of the smoothest of its
4-neighbours and itself: an arg-min. Where two candidates' smoothness ties to within float
rounding (on a plane every |Laplacian| is rounding noise) a rescaled or mirrored image may pick
the other candidate (and an exact tie goes left before right, as in the authors' code). For those
recipes the exact property is asserted for everything before MNR, and for the MNR output that
every pixel either matches or holds one of its own candidates' normals.

Images are small (3..14 pixels a side) and example counts modest so the file runs in seconds;
``derandomize`` makes every run draw the same examples.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import surfnorm
from surfnorm import Intrinsics

SRC = Path(__file__).resolve().parents[1] / "src"
METHODS = list(surfnorm.methods()) + [m + "+mnr" for m in ("cp2tv",) if m in surfnorm.methods()]
HOLE_VALUES = (0.0, np.nan, np.inf, -np.inf, -1.5)
SETTINGS = dict(deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])


@st.composite
def scenes(draw, min_side=3, max_side=14):
    """(depth float32 with holes, user mask, Intrinsics) on a random surface."""
    h = draw(st.integers(min_side, max_side))
    w = draw(st.integers(min_side, max_side))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    kind = draw(st.sampled_from(["noise", "plane", "steps"]))
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    base = draw(st.floats(0.5, 20.0))
    if kind == "noise":
        z = base * (1 + 0.2 * rng.random((h, w)))
    elif kind == "plane":
        z = base * (1 + rng.uniform(-0.03, 0.03) * u + rng.uniform(-0.03, 0.03) * v)
    else:
        z = base * (1 + 0.3 * (rng.random((h, w)) < 0.3)) * (1 + 0.01 * rng.random((h, w)))
    hole_rate = draw(st.sampled_from([0.0, 0.1, 0.3, 0.7]))
    holes = rng.random((h, w)) < hole_rate
    z[holes] = rng.choice(HOLE_VALUES, size=int(holes.sum()))
    mask = rng.random((h, w)) >= draw(st.sampled_from([0.0, 0.1]))
    f = draw(st.floats(5.0, 200.0))
    cam = Intrinsics(f, f * draw(st.floats(0.8, 1.2)), draw(st.floats(-2.0, w + 1.0)), draw(st.floats(-2.0, h + 1.0)))
    return z.astype(np.float32), mask, cam


def mnr_recipe(method: str) -> bool:
    from surfnorm.methods import resolve

    base, refined, _ = resolve(method, {})
    return refined or base.mnr


def auto_weight(z, mask, cam):
    """The weight of adaptive_fit in auto's blend for this frame."""
    import math

    from surfnorm._validate import as_depth, valid_pixels
    from surfnorm.kernels.auto import adaptive_weight
    from surfnorm.kernels.sensor_noise import noise_profile

    zz = as_depth(z, batch=False)
    c = Intrinsics.from_matrix(cam)
    return adaptive_weight(noise_profile(zz, valid_pixels(zz, mask), math.sqrt(c.fx * c.fy)))


def raw_normals(method, z, mask, cam, scale_invariant=False):
    """The normals a recipe has before MNR (what MNR chooses from), fill NaN."""
    from surfnorm._validate import as_depth, valid_pixels
    from surfnorm.methods import resolve
    from surfnorm.units import relative_depth

    base, _, options = resolve(method, {"fill": np.nan})
    if base.mnr:  # a recipe whose own run ends in MNR (d2nt_v3, fused): its candidates are d2nt_v2's normals
        base, _, options = resolve(base.name.replace("_v3", "_v2"), {"fill": np.nan})
    options.pop("mnr_dlf", None)
    zz = as_depth(z, batch=False)
    valid = valid_pixels(zz, mask)
    if scale_invariant:
        from surfnorm.units import REFERENCE_DEPTH

        zz = relative_depth(zz, valid)
        valid = valid_pixels(zz, valid)
        if base.relative:  # tau relative to each pixel's depth, as the mode passes it
            options["relative"] = REFERENCE_DEPTH
    return base.run(zz, valid, Intrinsics.from_matrix(cam), np.empty(zz.shape + (3,), np.float32), **options)


def edge_on(n, cam):
    """Pixels whose normal is (nearly) perpendicular to the line of sight: there "facing the camera" does not
    fix the sign (a plane fitted through collinear valid neighbours contains the ray), so either sign is right."""
    H, W = n.shape[:2]
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    ray = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], -1)
    ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
    return np.abs(np.nan_to_num(np.einsum("hwc,hwc->hw", n, ray))) < 1e-3


def assert_same_or_mnr_candidate(method, got, expected, raw, atol, cam=None):
    """got == expected within atol; for an MNR recipe, a pixel may instead hold one of its candidates' raw normals.

    The tolerance is float32 rounding amplified by each method's conditioning (3F2N divides by depth
    differences in float32, plane fits solve small eigenproblems): up to 2e-3 per component (0.1 degree). Where the normal is edge-on
    to the camera (:func:`edge_on`), the sign is compared only up to orientation.
    """
    np.testing.assert_array_equal(np.isnan(got), np.isnan(expected))
    if cam is not None:
        flip = edge_on(expected, Intrinsics.from_matrix(cam)) & (np.nan_to_num((got * expected).sum(-1)) < 0)
        got = np.where(flip[..., None], -got, got)
    if not mnr_recipe(method):
        np.testing.assert_allclose(got, expected, atol=atol, equal_nan=True)
        return
    H, W = got.shape[:2]
    off = np.abs(np.nan_to_num(got - expected)).max(-1) > atol
    for v, u in zip(*np.nonzero(off)):
        candidates = [
            raw[q]
            for q in ((v, u), (v, u - 1), (v, u + 1), (v - 1, u), (v + 1, u))
            if 0 <= q[0] < H and 0 <= q[1] < W and not np.isnan(raw[q]).any()
        ]
        assert any(np.abs(got[v, u] - c).max() <= atol for c in candidates), (v, u, got[v, u], expected[v, u])


def is_fill(n, fill):
    return np.isnan(n).all(-1) if np.isnan(fill) else (n == fill).all(-1)


@pytest.mark.slow
@pytest.mark.parametrize("method", METHODS)
@settings(max_examples=40, **SETTINGS)
@given(scene=scenes(), fill=st.sampled_from([0.0, np.nan, -3.0]))
def test_outputs_are_fill_or_unit_and_invalid_pixels_are_fill(method, scene, fill):
    z, mask, cam = scene
    n = surfnorm.estimate(z, cam, method=method, mask=mask, fill=fill)
    valid = np.isfinite(z) & (z > 0) & mask
    filled = is_fill(n, fill)
    assert filled[~valid].all(), "an invalid pixel got a normal"
    got = ~filled
    assert np.isfinite(n[got]).all()
    np.testing.assert_allclose(np.linalg.norm(n[got].astype(np.float64), axis=-1), 1.0, atol=1e-5)
    # a pixel whose whole 3x3 neighbourhood is valid has support for every estimator
    inner = valid[1:-1, 1:-1].copy()
    for dv in (-1, 0, 1):
        for du in (-1, 0, 1):
            inner &= valid[1 + dv : valid.shape[0] - 1 + dv, 1 + du : valid.shape[1] - 1 + du]
    assert got[1:-1, 1:-1][inner].all(), "a pixel with full support got no normal"


@pytest.mark.slow
@pytest.mark.parametrize("method", METHODS)
@settings(max_examples=30, **SETTINGS)
@given(scene=scenes(), garbage=st.sampled_from([0.0, np.nan, 1e-3, 7.0, 1e6, -5.0]))
def test_invalid_values_are_never_read(method, scene, garbage):
    z, mask, cam = scene
    valid = np.isfinite(z) & (z > 0) & mask
    other = z.copy()
    other[~valid] = garbage  # masked-out pixels get anything, holes stay holes or become masked garbage
    expected = surfnorm.estimate(z, cam, method=method, mask=valid, fill=np.nan)
    np.testing.assert_array_equal(surfnorm.estimate(other, cam, method=method, mask=valid, fill=np.nan), expected)


@pytest.mark.slow
@pytest.mark.parametrize("method", METHODS)
@settings(max_examples=30, **SETTINGS)
@given(scene=scenes())
def test_mirroring_mirrors_n_x(method, scene):
    z, mask, cam = scene
    w = z.shape[1]
    n = surfnorm.estimate(z, cam, method=method, mask=mask, fill=np.nan)
    m = surfnorm.estimate(z[:, ::-1], cam.flipped_lr(w), method=method, mask=mask[:, ::-1], fill=np.nan)[:, ::-1]
    flip = np.float32([-1, 1, 1])
    if method == "auto":
        # auto is d2nt_v3, adaptive_fit, or their weighted mean, at a weight from the frame's noise floor: the weight
        # must not change under mirroring. Where it is 0 or 1 auto is that method, compared as such below; between,
        # MNR's near-ties inside d2nt_v3 may go to the other neighbour in the mirrored frame, which the mean cannot
        # show as a candidate, and each part's own case checks it.
        t = auto_weight(z, mask, cam)
        assert auto_weight(z[:, ::-1], mask[:, ::-1], cam.flipped_lr(w)) == pytest.approx(t, abs=1e-9)
        if 0.0 < t < 1.0:
            return
        method = "d2nt_v3" if t == 0.0 else "adaptive_fit"
    if method == "adaptive_fit":
        # stride s fits every s-th column from the first: mirrored, they are the fitted columns again only where
        # s divides w - 1; elsewhere the mirrored frame's fitted columns take the planes of their neighbours
        # instead (the same normals to within that interpolation, not to the bit); and the choice of stride counts
        # the pixels that no fitted one reaches, which differ between the two (one may take 4, the other 2 or 1)
        from surfnorm.kernels._schedule import choose_stride

        valid = np.isfinite(z) & (z > 0) & (np.ones(z.shape, bool) if mask is None else mask)
        strides = {choose_stride(valid), choose_stride(valid[:, ::-1].copy())}
        if len(strides) > 1 or any((w - 1) % s for s in strides):
            n = surfnorm.estimate(z, cam, method=method, mask=mask, fill=np.nan, stride=1)
            m = surfnorm.estimate(
                z[:, ::-1], cam.flipped_lr(w), method=method, mask=mask[:, ::-1], fill=np.nan, stride=1
            )
            m = m[:, ::-1]
    if method == "adaptive_fit":
        # Its choices (the noise test, the quadrant of the edge test) compare window sums that the mirrored frame
        # accumulates from the other side, so a fit within rounding of its limit may go either way: on the random
        # scenes here (pure noise, every fit near its limit) one pixel in 100 did. All others must agree.
        np.testing.assert_array_equal(np.isnan(m), np.isnan(n))
        off = np.abs(np.nan_to_num(m * flip - n)).max(-1) > 2e-5
        assert off.sum() <= max(1, 0.02 * (~np.isnan(n[..., 0])).sum()), np.argwhere(off)
        return
    assert_same_or_mnr_candidate(method, m * flip, n, raw_normals(method, z, mask, cam), 2e-5, cam)
    if mnr_recipe(method):  # before MNR, exactly equivariant
        raw_m = raw_normals(method, z[:, ::-1], mask[:, ::-1], cam.flipped_lr(w))[:, ::-1]
        np.testing.assert_allclose(raw_m * flip, raw_normals(method, z, mask, cam), atol=2e-5, equal_nan=True)


@pytest.mark.slow
@pytest.mark.parametrize("method", METHODS)
@settings(max_examples=30, **SETTINGS)
@given(scene=scenes(), factor=st.floats(1e-3, 1e3))
def test_scale_invariant_mode_ignores_the_unit(method, scene, factor):
    z, mask, cam = scene
    n = surfnorm.estimate(z, cam, method=method, mask=mask, scale_invariant=True, fill=np.nan)
    scaled = (z.astype(np.float64) * factor).astype(np.float32)
    m = surfnorm.estimate(scaled, cam, method=method, mask=mask, scale_invariant=True, fill=np.nan)
    assert_same_or_mnr_candidate(method, m, n, raw_normals(method, z, mask, cam, True), 2e-3, cam)
    if mnr_recipe(method):  # before MNR, the same to float precision
        np.testing.assert_allclose(
            raw_normals(method, scaled, mask, cam, True),
            raw_normals(method, z, mask, cam, True),
            atol=1e-3,
            equal_nan=True,
        )


@pytest.mark.slow
@pytest.mark.parametrize("method", METHODS)
@settings(max_examples=15, **SETTINGS)
@given(scene=scenes(), power=st.integers(-20, 20))
def test_scale_invariant_mode_is_exact_for_powers_of_two(method, scene, power):
    z, mask, cam = scene
    n = surfnorm.estimate(z, cam, method=method, mask=mask, scale_invariant=True)
    m = surfnorm.estimate(z * np.float32(2.0**power), cam, method=method, mask=mask, scale_invariant=True)
    np.testing.assert_array_equal(m, n)


# --- the registry: one hop from a name to its kernel ----------------------------------------------------------------


def test_every_method_names_where_its_kernel_lives():
    import importlib

    for name, info in surfnorm.methods().items():
        module, _, function = info.kernel.rpartition(".")
        assert module.startswith("surfnorm.kernels."), (name, info.kernel)
        assert callable(getattr(importlib.import_module(module), function)), (name, info.kernel)


@pytest.mark.parametrize("name", list(surfnorm.methods()))
def test_each_run_calls_the_kernel_it_names(name, monkeypatch):
    """The run function of each entry calls exactly the function that ``kernel`` names (a spy replaces it)."""
    import importlib

    from surfnorm.methods import _REGISTRY

    module, _, function = _REGISTRY[name].kernel.rpartition(".")
    mod = importlib.import_module(module)
    real, calls = getattr(mod, function), []

    def spy(*args, **kwargs):
        calls.append(kwargs)
        return real(*args, **kwargs)

    monkeypatch.setattr(mod, function, spy)
    v, u = np.mgrid[0:24, 0:32]
    z = (2.0 + 0.01 * u + 0.005 * v).astype(np.float32)
    surfnorm.estimate(z, [[40.0, 0, 15.5], [0, 40.0, 11.5], [0, 0, 1]], method=name, threads=1)
    assert len(calls) == 1, f"{name}: {module}.{function} called {len(calls)} times"


def test_the_registry_is_filled_without_importing_a_kernel():
    code = (
        "import sys, surfnorm; names = list(surfnorm.methods()); "
        "assert len(names) >= 14 and not any(m.startswith('surfnorm.kernels') for m in sys.modules), sorted(sys.modules)"
    )
    subprocess.run([sys.executable, "-c", code], check=True, env={**os.environ, "PYTHONPATH": str(SRC)})
