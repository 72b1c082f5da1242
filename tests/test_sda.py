"""SDA-SNE: naive agreement, closed-form surfaces, iterations, invalid depth, faithfulness to the authors' demo."""

import json
from collections import defaultdict

import numpy as np
import pytest

import surfnorm
from surfnorm.io.threef2n import find_frames, read_frame, sample_root
from surfnorm.kernels import sda
from surfnorm.kernels.sda import MAX_ITERATIONS, sda_gradients
from surfnorm.metrics import mean_angular_error
from surfnorm.reference import official_figures
from surfnorm.units import TIE_TOLERANCE

from . import naive_sda, naive_three_filters, surfaces
from .conftest import SHARED_REFERENCE
from .test_three_filters import assert_agrees, random_depth

H, W = 24, 32


@pytest.mark.parametrize("kind", ["smooth", "discontinuous"])
@pytest.mark.parametrize("holes", [False, True])
@pytest.mark.parametrize("border", ["one-sided", "reflect"])
@pytest.mark.parametrize("iterations", [0, 1, 3, None])
def test_agrees_with_naive_reference(kind, holes, border, iterations):
    K = surfaces.camera(W, H)
    depth, valid = random_depth(kind, holes, seed=10 + 2 * ["smooth", "discontinuous"].index(kind) + holes)
    got = surfnorm.estimate(depth, K, method="sda_sne", border=border, iterations=iterations)
    assert_agrees(got, naive_sda.sda_sne(depth, valid, K, border=border, iterations=iterations), K)
    if holes:
        assert np.all(got[~valid] == 0)


@pytest.mark.parametrize("holes", [False, True])
def test_gradients_and_passes_agree_with_naive_reference(holes):
    depth, valid = random_depth("discontinuous", holes, seed=21)
    z = np.where(valid, depth, 0.0).astype(np.float32).astype(np.float64)
    g_u, g_v, passes = sda_gradients(z, valid, iterations=None)
    n_u, n_v, n_passes = naive_sda.sda(z, valid, iterations=None)
    assert passes == n_passes and 0 < passes < MAX_ITERATIONS
    np.testing.assert_allclose(g_u, n_u, rtol=0, atol=1e-12)
    np.testing.assert_allclose(g_v, n_v, rtol=0, atol=1e-12)
    assert np.isnan(g_u[~valid]).all() and np.isnan(g_v[~valid]).all()


@pytest.mark.parametrize("holes", [False, True])
def test_near_ties_agree_with_naive_reference(holes):
    """The scale-invariant mode's tolerance (tie_tol): on millimetre depth scaled to another unit, full of near-ties."""
    depth, valid = random_depth("discontinuous", holes, seed=33)
    mm = np.rint(np.where(valid, depth, 0.0) * 1000)  # integer millimetres: ramps, exact ties, one-step Laplacians
    z = (mm * 0.0254).astype(np.float32).astype(np.float64)  # the same in inches-and-a-bit, rounded
    for tol in (0.0, TIE_TOLERANCE):
        g_u, g_v, passes = sda_gradients(z, valid, iterations=None, tie_tol=tol)
        n_u, n_v, n_passes = naive_sda.sda(z, valid, iterations=None, tie_tol=tol)
        assert passes == n_passes
        np.testing.assert_allclose(g_u, n_u, rtol=0, atol=1e-12)
        np.testing.assert_allclose(g_v, n_v, rtol=0, atol=1e-12)
    # and the tolerance is what makes the two units agree
    # (z's float32 rounding moves a gradient by a few 1e-5; another choice moves it by 1e-3 and more)
    mm_u = sda_gradients(mm, valid, iterations=None, tie_tol=TIE_TOLERANCE)[0]
    np.testing.assert_allclose(g_u, mm_u * 0.0254, rtol=0, atol=1e-4)
    exact = sda_gradients(z, valid, iterations=None)[0] - sda_gradients(mm, valid, iterations=None)[0] * 0.0254
    assert np.nanmax(np.abs(exact)) > 0.1  # exact comparisons break the ties differently


def test_exact_comparisons_are_a_tolerance_of_zero(monkeypatch):
    """tie_tol 0 runs kernels compiled without the tolerance (tol None); compiled with a float tol of 0.0 they give the same bits."""
    K = surfaces.camera(W, H)
    depth, valid = random_depth("discontinuous", True, seed=33)
    depth = (np.rint(depth * 1000) * 0.0254).astype(np.float32)  # near-ties, as above

    def run():
        z = np.where(valid, depth, 0.0).astype(np.float64)
        return (
            sda_gradients(z, valid, iterations=None),
            [
                surfnorm.estimate(depth, K, method="sda_sne", base=base, border=border, iterations=None)
                for base in ("cp2tv", "3f2n")
                for border in ("one-sided", "reflect")
            ],
        )

    exact = run()
    monkeypatch.setattr(sda, "_kernel_tol", lambda tie_tol: float(tie_tol))
    assert sda._kernel_tol(0.0) == 0.0
    zero = run()
    assert exact[0][2] == zero[0][2] > 0
    for a, b in zip(exact[0][:2] + tuple(exact[1]), zero[0][:2] + tuple(zero[1])):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("border", ["one-sided", "reflect"])
def test_3f2n_base_agrees_with_naive_reference(border):
    """The demo's SDA + 3F2N: SDA on inverse depth, then 3F2N's median on those gradients."""
    K = surfaces.camera(W, H)
    depth, valid = random_depth("discontinuous", True, seed=7)
    got = surfnorm.estimate(depth, K, method="sda_sne", base="3f2n", border=border)
    inv = np.where(valid, 1.0 / depth.astype(np.float32).astype(np.float64), 0.0)
    g_u, g_v, _ = naive_sda.sda(inv, valid, iterations=3, border=border)
    expected = naive_three_filters.three_f2n(depth, valid, K, third="median", border=border, gradients=(g_u, g_v))
    assert_agrees(got, expected, K)


def test_invalid_depth_is_never_read():
    K = surfaces.camera(W, H)
    depth, valid = random_depth("discontinuous", True, seed=4)
    results = []
    for garbage in (np.nan, 0.0, -5.0, np.inf, 1e30, 2.0):
        z = np.where(valid, depth, garbage)
        mask = valid if garbage in (1e30, 2.0) else None
        for base in ("cp2tv", "3f2n"):
            results.append(
                surfnorm.estimate(z, K, method="sda_sne", mask=mask, base=base, iterations=None, fill=np.nan)
            )
    for i, r in enumerate(results[2:]):
        np.testing.assert_array_equal(r, results[i % 2])
    assert np.all(np.isnan(results[0][~valid]))


def test_exact_on_walls_and_steps():
    """A fronto-parallel wall has zero gradients; at a step SDA takes the one-sided gradient of the same wall."""
    K = surfaces.camera(64, 48)
    depth, n_true, _ = surfaces.step(K, 48, 64)
    for iterations in (3, None):
        n = surfnorm.estimate(depth, K, method="sda_sne", iterations=iterations)
        np.testing.assert_array_equal(n, n_true.astype(np.float32))
    # the central difference (3F2N, D2NT with FD) bends the normals next to the step
    assert np.abs(surfnorm.estimate(depth, K, method="3f2n_median") - n_true).max() > 0.1


@pytest.mark.parametrize("surface", ["plane", "sphere", "cylinder"])
def test_error_falls_with_resolution(surface):
    errors = []
    for width in (32, 64, 128):
        height = width * 3 // 4
        K = surfaces.camera(width, height)
        if surface == "plane":
            depth, n_true, hit = surfaces.plane(K, height, width, (0.3, -0.2, -1), 2.0)
        else:
            make = surfaces.sphere if surface == "sphere" else surfaces.cylinder
            depth, n_true, hit = make(K, height, width, (0.0, 0.0, 3.0), 1.0)
        inner = hit.copy()  # one pixel away from the silhouette
        inner[1:-1, 1:-1] &= hit[:-2, 1:-1] & hit[2:, 1:-1] & hit[1:-1, :-2] & hit[1:-1, 2:]
        inner[[0, -1], :] = inner[:, [0, -1]] = False
        n = surfnorm.estimate(depth, K, method="sda_sne", mask=hit)
        errors.append(surfaces.angle_deg(n[inner], n_true[inner]).mean())
    assert errors[1] < 0.75 * errors[0] and errors[2] < 0.75 * errors[1], errors


def test_more_passes_until_stable():
    depth, valid = random_depth("discontinuous", False, seed=2)
    z = depth.astype(np.float32).astype(np.float64)
    _, _, stable = sda_gradients(z, valid, iterations=None)
    assert stable > 3
    assert [sda_gradients(z, valid, iterations=i)[2] for i in (0, 1, 3, stable + 5)] == [0, 1, 3, stable]
    g_stable = sda_gradients(z, valid, iterations=None)[:2]
    g_more = sda_gradients(z, valid, iterations=stable + 5)[:2]
    np.testing.assert_array_equal(g_stable, g_more)


def test_registered_with_category_reference_and_options():
    info = surfnorm.methods()["sda_sne"]
    assert info.category == "energy minimisation" and "3DV 2022" in info.reference
    assert info.options == {"fill": 0.0, "iterations": 3, "base": "cp2tv", "border": "one-sided"}


@pytest.mark.parametrize("value", [-1, 1.5, True, "3", np.float64(2.0)])
def test_bad_iterations_are_named(value):
    with pytest.raises(
        ValueError,
        match=r"iterations: expected a non-negative integer number of passes, or None to run until stable, got ",
    ):
        surfnorm.estimate(np.ones((4, 4)), surfaces.camera(4, 4), method="sda_sne", iterations=value)


def test_bad_base_is_named():
    with pytest.raises(ValueError, match=r"base: expected one of 'cp2tv', '3f2n', got 'd2nt'"):
        surfnorm.estimate(np.ones((4, 4)), surfaces.camera(4, 4), method="sda_sne", base="d2nt")


def test_with_mnr():
    K = surfaces.camera(W, H)
    depth, valid = random_depth("discontinuous", True, seed=9)
    n = surfnorm.estimate(depth, K, method="sda_sne+mnr")
    assert np.all(n[~valid] == 0) and np.allclose(np.linalg.norm(n[valid], axis=-1), 1, atol=1e-6)


# Passes the authors' demo makes until its stop test fires (the pass that finds nothing to change is not
# counted), as measured with the demo on the 12 frames; planar scenes (cube 228, room 162) take longest.
DEMO_PASSES = {
    "Easy/android": 18,
    "Easy/cube": 228,
    "Easy/torus": 6,
    "Easy/torusknot": 9,
    "Medium/Trex": 8,
    "Medium/bunny": 7,
    "Medium/chair": 8,
    "Medium/penguin": 9,
    "Hard/batman": 16,
    "Hard/room": 162,
    "Hard/temple": 12,
    "Hard/tree": 10,
}
#: The converged variant is checked only on frames that stabilise within this many passes (all but cube and
#: room), to keep the suite fast; their per-level figures are covered by the report's table.
FAST_CONVERGING = 30


@pytest.mark.parametrize("frame_name", find_frames(sample_root()))
def test_faithful_on_shipped_frames(frame_name):
    """The authors' demo (float64, BORDER_REFLECT_101), 3 passes and until stable: e_A agrees to 1e-3 degrees."""
    f = read_frame(sample_root(), frame_name)
    official = official_figures(frame_name)
    n = surfnorm.estimate(f.depth, f.K, method="sda_sne", border="reflect")
    assert abs(mean_angular_error(n, f.normals, f.mask) - official["sda_sne"]) < 1e-3
    n = surfnorm.estimate(f.depth, f.K, method="sda_sne", border="reflect", iterations=None)
    assert abs(mean_angular_error(n, f.normals, f.mask) - official["sda_sne_converged"]) < 1e-3
    z = f.depth.astype(np.float64)
    passes = sda_gradients(z, np.ones(z.shape, dtype=bool), iterations=None, border="reflect")[2]
    assert passes == DEMO_PASSES[frame_name.rsplit("/", 1)[0]]


@pytest.mark.slow
def test_faithful_on_all_twelve_frames(shared_sample):
    with open(SHARED_REFERENCE) as fh:
        ref = json.load(fh)["frames"]
    ours, theirs = defaultdict(list), defaultdict(list)
    for name in find_frames(shared_sample):
        f = read_frame(shared_sample, name)
        n = surfnorm.estimate(f.depth, f.K, method="sda_sne", border="reflect")
        e_a, r = mean_angular_error(n, f.normals, f.mask), ref[name]["official_sda_sne_3iter"]
        assert abs(e_a - r) < 1e-3, (name, e_a, r)
        ours[f.level].append(e_a)
        theirs[f.level].append(r)
        obj = name.rsplit("/", 1)[0]
        if DEMO_PASSES[obj] <= FAST_CONVERGING:
            n = surfnorm.estimate(f.depth, f.K, method="sda_sne", border="reflect", iterations=None)
            e_a, r = mean_angular_error(n, f.normals, f.mask), ref[name]["official_sda_sne_converged"]
            assert abs(e_a - r) < 1e-3, (name, e_a, r)
    assert len(ours) == 3
    for level in ours:
        assert abs(np.mean(ours[level]) - np.mean(theirs[level])) < 1e-3, level


def _poison(value, code):
    """Overwrite every kept working array (its inner part and its margin) with ``value`` / ``code``."""
    for sets in sda._working._sets.values():
        for arrays in sets:
            for a in arrays:
                a.fill(value if a.dtype.kind == "f" else code if a.dtype.kind in "iu" else bool(code % 2))


@pytest.mark.parametrize("threads", [1, 2])
def test_working_arrays_kept_for_the_next_frame_give_the_same_bits(threads):
    """sda_sne keeps a frame's working arrays for the next frame of the same size: whatever they hold (another
    frame's values, or any value at all), the normals are the same bits."""
    rng = np.random.default_rng(7)
    K = [[60.0, 0, 31.5], [0, 60.0, 39.5], [0, 0, 1]]
    frames = []
    for holes in (0.0, 0.2, 0.05):
        z = rng.uniform(1.0, 3.0, (80, 64)).astype(np.float32)
        z[rng.random(z.shape) < holes] = 0.0
        frames.append(z)
    for kwargs in ({}, {"base": "3f2n"}, {"scale_invariant": True}):
        sda.release()
        runs = {}
        for i, z in enumerate(frames):  # each frame after another's arrays
            runs[i] = [surfnorm.estimate(z, K, method="sda_sne", threads=threads, **kwargs)]
        assert sda._working._sets, "the working arrays were kept"
        for value, code in ((np.nan, 5), (-1e300, 3), (0.0, 0)):
            for i, z in enumerate(frames):
                _poison(value, code)
                runs[i].append(surfnorm.estimate(z, K, method="sda_sne", threads=threads, **kwargs))
        sda.release()
        for i, z in enumerate(frames):
            runs[i].append(surfnorm.estimate(z, K, method="sda_sne", threads=threads, **kwargs))  # new arrays
            for other in runs[i][1:]:
                np.testing.assert_array_equal(other.view(np.uint32), runs[i][0].view(np.uint32))
    sda.release()
