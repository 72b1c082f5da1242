"""The seeded sensor noise model."""

from __future__ import annotations

import numpy as np
import pytest

import surfnorm
from surfnorm.errors import InputError
from surfnorm.noise import SensorNoise, add_noise
from tests.surfaces import camera, step


def test_same_seed_same_output_other_seed_other_output():
    z = np.full((40, 50), 2.0)
    a = add_noise(z, seed=3)
    np.testing.assert_array_equal(a, add_noise(z, seed=3))
    assert not np.array_equal(a, add_noise(z, seed=4))
    np.testing.assert_array_equal(add_noise(z, seed=np.random.default_rng(3)), a)
    assert a.dtype == np.float32 and a.shape == z.shape


def test_axial_noise_grows_as_a_plus_b_z_squared():
    model = SensorNoise(quantum=0.0, edge_dropout=0.0)
    for depth in (0.5, 2.0, 4.0):
        z = np.full((200, 200), depth)
        sd = float(np.std(add_noise(z, model, seed=1).astype(np.float64) - depth))
        expected = 0.0012 + 0.0019 * depth**2
        assert abs(sd - expected) < 0.05 * expected, (depth, sd, expected)


def test_quantisation_to_the_quantum():
    z = np.random.default_rng(0).uniform(0.5, 3.0, (30, 30))
    q = add_noise(z, SensorNoise(a=0.0, b=0.0, quantum=0.001, edge_dropout=0.0), seed=0).astype(np.float64)
    np.testing.assert_allclose(q * 1000, np.rint(q * 1000), atol=2e-3)
    assert np.abs(q - z).max() <= 0.0005 + 1e-6


def test_dropouts_only_at_depth_edges():
    K = camera(64, 48)
    z, _, _ = step(K, 48, 64, near=2.0, far=3.0, column=32)
    noisy = add_noise(z, SensorNoise(a=0, b=0, quantum=0, edge_dropout=1.0, edge_width=2), seed=0)
    holes = noisy == 0
    assert holes[:, 30:34].all()  # 2 pixels each side of the step
    assert not holes[:, :30].any() and not holes[:, 34:].any()
    some = add_noise(z, SensorNoise(a=0, b=0, quantum=0, edge_dropout=0.5, edge_width=1), seed=0) == 0
    assert 0.3 < some[:, 31:33].mean() < 0.7 and not some[:, :31].any()


def test_random_dropouts_and_invalid_input_kept():
    z = np.full((100, 100), 1.0)
    z[0, 0], z[0, 1], z[0, 2] = 0.0, np.nan, -1.0
    out = add_noise(z, SensorNoise(dropout=0.2, edge_dropout=0.0), seed=0)
    assert out[0, 0] == 0 and np.isnan(out[0, 1]) and out[0, 2] == -1
    assert 0.17 < (out[1:] == 0).mean() < 0.23
    assert (out[out > 0] > 0.9).all()


def test_unit_conversion_gives_the_same_sensor_in_millimetres():
    z = np.random.default_rng(1).uniform(0.5, 3.0, (20, 20))
    metres = add_noise(z, SensorNoise(edge_dropout=0.0), seed=5).astype(np.float64)
    mm = add_noise(z * 1000, SensorNoise(edge_dropout=0.0).in_unit(1000), seed=5).astype(np.float64)
    np.testing.assert_allclose(mm, metres * 1000, atol=1e-3)


def test_noisy_depth_feeds_every_estimator():
    K = camera(64, 48)
    z = 2.0 + 0.1 * np.mgrid[0:48, 0:64][1] / 64
    noisy = add_noise(z, SensorNoise(dropout=0.05), seed=0)
    for method in surfnorm.methods():
        n = surfnorm.estimate(noisy, K, method=method, fill=np.nan)
        assert np.isnan(n[noisy == 0]).all()
        ok = ~np.isnan(n[..., 0])
        np.testing.assert_allclose(np.linalg.norm(n[ok], axis=-1), 1, atol=1e-5)


@pytest.mark.parametrize(
    "kwargs, pattern",
    [
        (dict(a=-1.0), r"a: expected a finite number >= 0, got -1.0"),
        (dict(b=float("nan")), r"b: expected a finite number >= 0, got nan"),
        (dict(dropout=1.5), r"dropout: expected a number <= 1.0, got 1.5"),
        (dict(edge_width=1.5), r"edge_width: expected an integer >= 0, got 1.5"),
        (dict(quantum="1mm"), r"quantum: expected a finite number >= 0, got '1mm'"),
    ],
)
def test_bad_parameters_are_named(kwargs, pattern):
    with pytest.raises(InputError, match=pattern):
        SensorNoise(**kwargs)


def test_bad_calls_are_named():
    with pytest.raises(InputError, match=r"seed: expected an integer or a numpy Generator, got None"):
        add_noise(np.ones((4, 4)), seed=None)
    with pytest.raises(InputError, match=r"model: expected a SensorNoise, got dict"):
        add_noise(np.ones((4, 4)), {}, seed=0)
    with pytest.raises(InputError, match=r"depth: expected a 2-D array \(H, W\)"):
        add_noise(np.ones((2, 4, 4)), seed=0)
    with pytest.raises(InputError, match=r"per_metre: expected a positive number, got 0"):
        SensorNoise().in_unit(0)
