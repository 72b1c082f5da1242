"""surfnorm.kernels.gradients: FD and DAG gradients (D2NT eq. 10-14); the softmin's exp, tau at any accepted value.

(The gradients are also checked through every D2NT-family method against tests/naive_d2nt.py in test_translate.py.)
"""

from __future__ import annotations

import decimal
import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import surfnorm

from .surfaces import camera, has_normal, scene


def test_softmin_exp_is_correctly_rounded():
    # The kernels' exp(-s / tau) (softmin_row: exp32 in float64, FMA-contracted, rounded once) against exp in
    # float64 rounded to float32, on the arguments the softmin sees and at the edges of the float32 range.
    # (An exhaustive run over all 1.1e9 float32 in [-104.5, 0] found no difference: benchmarks/README.md.)
    from surfnorm.kernels.gradients import softmin_row

    rng = np.random.default_rng(0)
    x = np.concatenate(
        [
            -rng.random(200_000) * 110,
            -rng.random(100_000) * 1e-3,
            -rng.exponential(1.0, 100_000),
            [0.0, -0.0, -1e-45, -87.33655, -103.27893, -103.97208, -104.0, -200.0, 88.0, 88.7228, 89.0, 1e3],
        ]
    )
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


@pytest.mark.slow
def test_importing_the_kernels_leaves_the_decimal_context_alone():
    code = (
        "import decimal; decimal.getcontext().prec = 7; import surfnorm.kernels.gradients; "
        "assert decimal.getcontext().prec == 7, decimal.getcontext().prec"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_exp32_constants_are_ln2_split_exactly():
    from surfnorm.kernels import _rows

    with decimal.localcontext() as ctx:
        ctx.prec = 40
        ln2 = decimal.Decimal(2).ln()
        assert decimal.Decimal(_rows._LN2_HI) + decimal.Decimal(_rows._LN2_LO) - ln2 < decimal.Decimal("1e-26")
    assert _rows._LN2_HI == 0.6931471803691238 and _rows._INV_LN2 == 1.4426950408889634
    assert math.ldexp(_rows._LN2_HI, 32) == int(math.ldexp(_rows._LN2_HI, 32))  # k * LN2_HI exact for |k| < 2^21


# --- tau at any accepted value -------------------------------------------------------------------------------------

SCENE_K = camera(64, 48)


TAUS = [1.0, 0.3, 0.0014, 0.001, 1e-30, 1e-45, 1e-300, 5e-324, 1e30, 1e300, 1.7e308]


@pytest.mark.parametrize("method", ["d2nt_v2", "d2nt_v3"])
@pytest.mark.parametrize("truncate", [True, False])
@pytest.mark.parametrize("tau", TAUS)
def test_every_accepted_tau_gives_unit_normals(method, truncate, tau):
    # tau <= 0.0014 with truncate=True raised OverflowError, 1e-300 ZeroDivisionError
    n = surfnorm.estimate(
        np.full((8, 8), 2.0), [[500, 0, 3.5], [0, 500, 3.5], [0, 0, 1]], method=method, tau=tau, truncate=truncate
    )
    np.testing.assert_array_equal(n[1:-1, 1:-1], np.broadcast_to(np.float32([0, 0, -1]), (6, 6, 3)))
    z = scene()
    n = surfnorm.estimate(z, SCENE_K, method=method, tau=tau, truncate=truncate, fill=np.nan)
    ok = has_normal(n)
    assert ok.mean() > 0.9
    np.testing.assert_allclose(np.linalg.norm(n[ok], axis=-1), 1.0, atol=1e-5)


@pytest.mark.slow
@settings(max_examples=40, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(log_tau=st.floats(-320, 307))
def test_small_tau_truncation_can_not_fire(log_tau):
    """Two regularised softmin weights never differ by more than about 1e8 = e^18.4, so for tau < 1/18.5 the
    truncated softmin equals the plain one: the overflowing threshold e^(1/tau) may be +inf."""
    tau = 10.0**log_tau
    if tau == 0.0:
        return
    z = scene()
    a = surfnorm.estimate(z, SCENE_K, method="d2nt_v2", tau=tau, truncate=True, fill=np.nan)
    assert np.isfinite(a[has_normal(a)]).all()
    if tau < 1 / 18.5:
        np.testing.assert_array_equal(
            a, surfnorm.estimate(z, SCENE_K, method="d2nt_v2", tau=tau, truncate=False, fill=np.nan)
        )


@pytest.mark.parametrize("tau", [0.001, 1e-300, 1e300])
def test_every_accepted_tau_in_the_torch_backend(tau):
    torch = pytest.importorskip("torch")
    from surfnorm import torch as surfnorm_torch

    z = scene()
    for method in ("d2nt_v2", "d2nt_v3"):
        t = surfnorm_torch.estimate(torch.from_numpy(z), torch.tensor(SCENE_K), method=method, tau=tau)[0]
        n = surfnorm.estimate(z, SCENE_K, method=method, tau=tau)
        assert torch.isfinite(t).all()
        np.testing.assert_allclose(t.permute(1, 2, 0).numpy(), n, atol=1e-4)
