"""surfnorm._validate and the checks of every public function: every bad argument of the library's functions is an InputError
(a ValueError) whose message starts with the argument's name, says what was expected and what was received.

One table per function; each row is one case. The counts are asserted at the end, so that a row lost in an
edit shows up.
"""

from __future__ import annotations

import numpy as np
import pytest

import surfnorm
from surfnorm._validate import valid_map, valid_pixels
from surfnorm.camera import Intrinsics
from surfnorm.errors import InputError

from .surfaces import holey_depth

K = np.array([[60.0, 0, 7.5], [0, 60.0, 5.5], [0, 0, 1]])
Z = np.full((12, 16), 2.0, np.float32)
N = np.zeros((12, 16, 3), np.float32)


def _buffer(shape=(12, 16, 3), dtype=np.float32, **flags):
    b = np.zeros(shape, dtype)
    if flags.get("readonly"):
        b.flags.writeable = False
    return b


# (id, keyword arguments of surfnorm.estimate that replace the good ones, argument named first in the message)
ESTIMATE = [
    ("depth-None", dict(depth=None), "depth"),
    ("depth-str", dict(depth="depth.png"), "depth"),
    ("depth-bool", dict(depth=np.ones((12, 16), bool)), "depth"),
    ("depth-complex", dict(depth=np.ones((12, 16), complex)), "depth"),
    ("depth-object", dict(depth=np.array([[1, "a", 2]] * 3, dtype=object)), "depth"),
    ("depth-strings", dict(depth=np.full((12, 16), "2.0")), "depth"),
    ("depth-0d", dict(depth=np.float32(2.0)), "depth"),
    ("depth-1d", dict(depth=np.ones(16)), "depth"),
    ("depth-4d", dict(depth=np.ones((2, 12, 16, 1))), "depth"),
    ("depth-rgb", dict(depth=np.ones((12, 16, 3))), "depth"),
    ("depth-2x2", dict(depth=np.ones((2, 2))), "depth"),
    ("depth-empty", dict(depth=np.ones((0, 16))), "depth"),
    ("depth-empty-stack", dict(depth=np.ones((0, 12, 16))), "depth"),
    ("depth-ragged", dict(depth=[[1.0, 2.0, 3.0], [1.0, 2.0]]), "depth"),
    ("K-None", dict(K=None), "K"),
    ("K-shape", dict(K=np.eye(4)), "K"),
    ("K-vector", dict(K=[60.0, 60.0, 7.5, 5.5]), "K"),
    ("K-strings", dict(K=[["a", "0", "1"]] * 3), "K"),
    ("K-nan", dict(K=np.where(np.eye(3) > 0, np.nan, 0)), "K"),
    ("K-inf-focal", dict(K=[[np.inf, 0, 7.5], [0, 60, 5.5], [0, 0, 1]]), "K"),
    ("K-zero-focal", dict(K=[[0.0, 0, 7.5], [0, 60, 5.5], [0, 0, 1]]), "K"),
    ("K-negative-focal", dict(K=[[60.0, 0, 7.5], [0, -60, 5.5], [0, 0, 1]]), "K"),
    ("K-huge-focal", dict(K=[[1e300, 0, 7.5], [0, 60, 5.5], [0, 0, 1]]), "K"),
    ("K-tiny-focal", dict(K=[[1e-300, 0, 7.5], [0, 60, 5.5], [0, 0, 1]]), "K"),
    ("K-huge-principal-point", dict(K=[[60.0, 0, 7.5], [0, 60, 1e300], [0, 0, 1]]), "K"),
    ("K-skew", dict(K=[[60.0, 1, 7.5], [0, 60, 5.5], [0, 0, 1]]), "K"),
    ("K-last-row", dict(K=[[60.0, 0, 7.5], [0, 60, 5.5], [0, 0, 2]]), "K"),
    ("K-bool", dict(K=np.eye(3, dtype=bool)), "K"),
    ("K-stack-count", dict(depth=np.stack([Z, Z]), K=np.stack([K, K, K])), "K"),
    ("K-list-count", dict(depth=np.stack([Z, Z]), K=[Intrinsics(60, 60, 7.5, 5.5)] * 3), "K"),
    ("mask-shape", dict(mask=np.ones((16, 12), bool)), "mask"),
    ("mask-complex", dict(mask=np.ones((12, 16), complex)), "mask"),
    ("mask-strings", dict(mask=np.full((12, 16), "yes")), "mask"),
    ("mask-nan", dict(mask=np.full((12, 16), np.nan)), "mask"),
    ("method-unknown", dict(method="d2nt_v4"), "method"),
    ("method-not-str", dict(method=3), "method"),
    ("method-mnr-only", dict(method="+mnr"), "method"),
    ("method-case", dict(method="D2NT_V3"), "method"),
    ("option-unknown", dict(method="d2nt_basic", tau=1.0), "options of method"),
    ("option-typo", dict(method="d2nt_v2", taus=1.0), "options of method"),
    ("tau-zero", dict(method="d2nt_v2", tau=0.0), "tau"),
    ("tau-negative", dict(method="d2nt_v2", tau=-1.0), "tau"),
    ("tau-nan", dict(method="d2nt_v2", tau=np.nan), "tau"),
    ("tau-inf", dict(method="d2nt_v3", tau=np.inf), "tau"),
    ("tau-str", dict(method="d2nt_v3", tau="1"), "tau"),
    ("tau-bool", dict(method="d2nt_v3", tau=True), "tau"),
    ("tau-None", dict(method="d2nt_v3", tau=None), "tau"),
    ("dlf-unknown", dict(method="d2nt_v2", dlf="delta"), "dlf"),
    ("dlf-int", dict(method="d2nt_v2", dlf=1), "dlf"),
    ("mnr_dlf-unknown", dict(method="d2nt_v3", mnr_dlf="2d"), "mnr_dlf"),
    ("mnr_dlf-on-mnr-recipe", dict(method="cp2tv+mnr", mnr_dlf="none"), "mnr_dlf"),
    ("truncate-str", dict(method="d2nt_v2", truncate="yes"), "truncate"),
    ("truncate-int", dict(method="d2nt_v2", truncate=1), "truncate"),
    ("border-unknown", dict(method="d2nt_basic", border="wrap"), "border"),
    ("border-None", dict(method="cp2tv", border=None), "border"),
    ("fill-str", dict(fill="nan"), "fill"),
    ("fill-None", dict(fill=None), "fill"),
    ("fill-bool", dict(fill=False), "fill"),
    ("fill-complex", dict(fill=1j), "fill"),
    ("fill-overflows-float32", dict(fill=1e40), "fill"),
    ("fill-underflows-float32", dict(fill=1e-50), "fill"),
    ("window-even", dict(method="plane_pca", window=4), "window"),
    ("window-one", dict(method="plane_svd", window=1), "window"),
    ("window-float", dict(method="vector_svd", window=3.0), "window"),
    ("iterations-negative", dict(method="sda_sne", iterations=-1), "iterations"),
    ("iterations-float", dict(method="sda_sne", iterations=2.5), "iterations"),
    ("base-unknown", dict(method="sda_sne", base="d2nt"), "base"),
    ("threads-zero", dict(depth=np.stack([Z, Z]), threads=0), "threads"),
    ("threads-float", dict(depth=np.stack([Z, Z]), threads=1.5), "threads"),
    ("threads-bool", dict(depth=np.stack([Z, Z]), threads=True), "threads"),
    ("scale_invariant-str", dict(scale_invariant="yes"), "scale_invariant"),
    ("scale_invariant-None", dict(scale_invariant=None), "scale_invariant"),
    ("disparity-int", dict(disparity=1), "disparity"),
    ("out-list", dict(out=[[0.0]]), "out"),
    ("out-float64", dict(out=_buffer(dtype=np.float64)), "out"),
    ("out-shape", dict(out=_buffer(shape=(12, 16))), "out"),
    ("out-non-contiguous", dict(out=np.zeros((12, 32, 3), np.float32)[:, ::2]), "out"),
    ("out-read-only", dict(out=_buffer(readonly=True)), "out"),
]

# (id, keyword arguments of surfnorm.refine, argument named)
REFINE = [
    ("normals-int", dict(normals=np.zeros((12, 16, 3), int)), "normals"),
    ("normals-shape", dict(normals=np.zeros((12, 16, 2), np.float32)), "normals"),
    ("normals-other-size", dict(normals=np.zeros((16, 12, 3), np.float32)), "normals"),
    ("depth-stack", dict(depth=np.stack([Z, Z])), "depth"),
    ("depth-None", dict(depth=None), "depth"),
    ("mask-shape", dict(mask=np.ones((3, 3), bool)), "mask"),
    ("dlf-unknown", dict(dlf="laplace"), "dlf"),
    ("fill-str", dict(fill="0"), "fill"),
    ("fill-overflows-float32", dict(fill=-1e39), "fill"),
]

# (id, arguments of Intrinsics, argument named)
INTRINSICS = [
    ("fx-str", ("60", 60, 7.5, 5.5), "intrinsics.fx"),
    ("fy-bool", (60, True, 7.5, 5.5), "intrinsics.fy"),
    ("cx-None", (60, 60, None, 5.5), "intrinsics.cx"),
    ("cy-nan", (60, 60, 7.5, float("nan")), "intrinsics.cy"),
    ("fx-zero", (0, 60, 7.5, 5.5), "intrinsics.fx"),
    ("fy-huge", (60, 1e300, 7.5, 5.5), "intrinsics.fy"),
    ("fx-tiny", (1e-9, 60, 7.5, 5.5), "intrinsics.fx"),
    ("cx-huge", (60, 60, -1e9, 5.5), "intrinsics.cx"),
]


def _estimate(**changes):
    kw = dict(depth=Z, K=K)
    kw.update(changes)
    depth, cam = kw.pop("depth"), kw.pop("K")
    return surfnorm.estimate(depth, cam, **kw)


def _refine(**changes):
    kw = dict(normals=N, depth=Z)
    kw.update(changes)
    return surfnorm._api.refine(kw.pop("normals"), kw.pop("depth"), **kw)


def _assert_named(exc, name):
    message = str(exc.value)
    assert message.startswith(name), message
    assert "expected" in message and "got" in message, message
    assert "\n" not in message, message


@pytest.mark.parametrize("changes, name", [c[1:] for c in ESTIMATE], ids=[c[0] for c in ESTIMATE])
def test_estimate_refuses_bad_arguments_by_name(changes, name):
    with pytest.raises(InputError) as exc:
        _estimate(**changes)
    _assert_named(exc, name)


@pytest.mark.parametrize("changes, name", [c[1:] for c in REFINE], ids=[c[0] for c in REFINE])
def test_refine_refuses_bad_arguments_by_name(changes, name):
    with pytest.raises(InputError) as exc:
        _refine(**changes)
    _assert_named(exc, name)


@pytest.mark.parametrize("args, name", [c[1:] for c in INTRINSICS], ids=[c[0] for c in INTRINSICS])
def test_intrinsics_refuse_bad_values_by_name(args, name):
    with pytest.raises(InputError) as exc:
        Intrinsics(*args)
    _assert_named(exc, name)


TORCH = [
    ("depth-None", dict(depth=None), "depth"),
    ("depth-3d", dict(depth=np.ones((2, 12, 16), np.float32)), "depth"),
    ("depth-bool", dict(depth=np.ones((12, 16), bool)), "depth"),
    ("depth-2x2", dict(depth=np.ones((2, 2), np.float32)), "depth"),
    ("K-shape", dict(K=np.eye(4)), "K"),
    ("K-huge-focal", dict(K=[[1e300, 0, 7.5], [0, 60, 5.5], [0, 0, 1]]), "K"),
    ("mask-shape", dict(mask=np.ones((3, 3), bool)), "mask"),
    ("method-unknown", dict(method="d2nt_v4"), "method"),
    ("window-wider-than-max_window", dict(method="adaptive_fit", window=9, max_window=5), "window"),
    ("tau-zero", dict(method="d2nt_v2", tau=0.0), "tau"),
    ("dlf-unknown", dict(method="d2nt_v3", dlf="x"), "dlf"),
    ("fill-overflows-float32", dict(fill=1e40), "fill"),
    ("option-unknown", dict(method="cp2tv", window=3), "options of method"),
]


@pytest.mark.parametrize("changes, name", [c[1:] for c in TORCH], ids=[c[0] for c in TORCH])
def test_torch_estimate_refuses_bad_arguments_by_name(changes, name):
    torch = pytest.importorskip("torch")
    import surfnorm.torch

    kw = dict(depth=torch.from_numpy(Z), K=K)
    kw.update(
        {
            k: (torch.from_numpy(v) if isinstance(v, np.ndarray) and k in ("depth", "mask") else v)
            for k, v in changes.items()
        }
    )
    with pytest.raises(InputError) as exc:
        surfnorm.torch.estimate(kw.pop("depth"), kw.pop("K"), **kw)
    _assert_named(exc, name)


def test_the_battery_counts():
    assert (len(ESTIMATE), len(REFINE), len(INTRINSICS), len(TORCH)) == (78, 9, 8, 13)  # 108 cases


# --- validity: valid_map (one Numba pass) and valid_pixels (NumPy) agree -----------------------------------------


def test_valid_map_equals_numpy_rule():
    z = holey_depth(7)
    z[0, :4] = [-0.0, np.float32(1e-45), -np.inf, np.float32(3e38)]
    mask = np.random.default_rng(7).random(z.shape) < 0.8
    np.testing.assert_array_equal(valid_map(z, None), valid_pixels(z, None))
    np.testing.assert_array_equal(valid_map(z, mask), valid_pixels(z, mask))
