"""SDA-SNE's fused sweeps (see surfnorm.kernels.sda._sda_sweep): the bits of the stages run one by one, wherever
the stop test fires within a sweep and however the rows are split into bands."""

import numpy as np
import pytest

from surfnorm._bands import on_threads, whole
from surfnorm.camera import Intrinsics
from surfnorm.kernels import sda

from . import naive_sda
from .test_bands import interleaved_bands
from .test_three_filters import random_depth

# Two frames of test_three_filters one above the other (48 x 32, with holes), whose dynamic programming moves no
# pixel in its 7th, 8th and 9th pass (iterations=None): the first, second and third pass of a sweep of three.
STOPS = {7: ("discontinuous", 2), 8: ("discontinuous", 0), 9: ("smooth", 0)}

# Bands of one row are too short to fuse: the stages run one by one, each pass's stop test before the next.
ONE_BY_ONE = interleaved_bands([(r, r + 1) for r in range(48)])
FUSED = {
    "one band": whole,
    "two bands": interleaved_bands([(0, 20), (20, 10**6)]),
    "three bands": interleaved_bands([(0, 16), (16, 32), (32, 10**6)]),
    "threads": on_threads(2),
}


def stacked(kind, seed):
    d1, v1 = random_depth(kind, True, seed)
    d2, v2 = random_depth(kind, True, seed + 100)
    return np.vstack([np.where(v1, d1, 0.0), np.where(v2, d2, 0.0)]), np.vstack([v1, v2])


def run(z, valid, iterations, bands, **kwargs):
    result, passes, _ = sda._run_sda(z, valid, iterations, "one-sided", 0.0, bands, **kwargs)
    return [a.copy() for a in result], passes


@pytest.mark.slow
@pytest.mark.parametrize("stop", sorted(STOPS))
@pytest.mark.parametrize("iterations", [None, 3, 6, 7, 8, 9, 12])
def test_fused_sweeps_give_the_bits_of_the_stages_one_by_one(stop, iterations):
    z, valid = stacked(*STOPS[stop])
    (g_u, g_v, e_u, e_v), passes = run(z, valid, iterations, ONE_BY_ONE)
    assert passes == (stop - 1 if iterations is None else min(stop - 1, iterations))
    n_u, n_v, n_passes = naive_sda.sda(z, valid, iterations=iterations)
    assert passes == n_passes
    np.testing.assert_allclose(np.where(e_u < np.inf, g_u, np.nan)[3:-3, 3:-3], n_u, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.where(e_v < np.inf, g_v, np.nan)[3:-3, 3:-3], n_v, rtol=0, atol=1e-12)
    for name, bands in FUSED.items():
        got, got_passes = run(z, valid, iterations, bands)
        assert got_passes == passes, name
        for a, b in zip(got, (g_u, g_v, e_u, e_v)):
            np.testing.assert_array_equal(a.view(np.uint64), b.view(np.uint64), err_msg=name)


@pytest.mark.parametrize("stop", sorted(STOPS))
@pytest.mark.parametrize("base", ["cp2tv", "3f2n"])
def test_fused_normals_give_the_bits_of_the_stages_one_by_one(stop, base):
    """The normals come from the sweep's last pass, or after it from the set that holds the result."""
    z, valid = stacked(*STOPS[stop])
    z = z.astype(np.float32)
    cam = Intrinsics.from_matrix([[40.0, 0, 15.3], [0, 41.0, 23.9], [0, 0, 1]])
    for iterations in (3, stop - 1, stop, stop + 1, None):
        want = sda.sda_sne(z, valid, cam, np.empty(z.shape + (3,), np.float32), iterations=iterations, base=base)
        ref = sda.sda_sne(
            z, valid, cam, np.empty(z.shape + (3,), np.float32), iterations=iterations, base=base, bands=ONE_BY_ONE
        )
        np.testing.assert_array_equal(want.view(np.uint32), ref.view(np.uint32), err_msg=f"{iterations}")
        for name, bands in FUSED.items():
            out = np.full(z.shape + (3,), np.nan, np.float32)
            got = sda.sda_sne(z, valid, cam, out, iterations=iterations, base=base, bands=bands)
            np.testing.assert_array_equal(got.view(np.uint32), ref.view(np.uint32), err_msg=f"{name} {iterations}")


def test_a_frame_without_valid_depth_stops_at_the_first_pass(monkeypatch):
    """No pixel moves in the first pass of the first sweep: its result (the initial gradients) is overwritten by
    the third pass, so the stages run again one by one."""
    z, valid = np.zeros((40, 30)), np.zeros((40, 30), bool)
    stages = []
    real = sda._sda_sweep

    def spy(*args):
        stages.append(tuple(args[-6:-4]))  # j0, j1
        real(*args)

    monkeypatch.setattr(sda, "_sda_sweep", spy)
    for name, bands in FUSED.items():
        stages.clear()
        (g_u, g_v, e_u, e_v), passes = run(z, valid, 3, bands)
        assert passes == 0 and np.isinf(e_u).all() and np.isinf(e_v).all(), name
        assert (0, 6) in stages and (0, 1) in stages and (3, 4) in stages, name  # fused, then load, ..., a pass
