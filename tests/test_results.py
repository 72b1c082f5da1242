"""Results made in the memory of earlier ones (surfnorm._results): never while anything still uses it."""

from __future__ import annotations

import gc
import io
import pickle
import threading

import numpy as np
import pytest

import surfnorm
from surfnorm import _results

K = [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]]


def frame(seed=0, H=480, W=640):
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:H, 0:W]
    z = 2.0 + 0.001 * u + 0.0005 * v + rng.normal(0, 0.002, (H, W))
    z[:, W // 2 :] += 0.5
    return z.astype(np.float32)


@pytest.fixture(autouse=True)
def empty_pool():
    # results that earlier tests left in reference cycles go back to the pool when collected: collect them first, so
    # that a collection inside a test cannot put a block into the pool that the test did not free
    gc.collect()
    _results.release()
    yield
    _results.release()


def test_a_freed_result_is_taken_by_the_next_result_of_its_size():
    z = frame()
    first = surfnorm.estimate(z, K)
    expected = first.copy()
    address = first.ctypes.data
    del first
    gc.collect()
    assert _results.kept_bytes() == expected.nbytes
    again = surfnorm.estimate(z, K)
    assert again.ctypes.data == address
    np.testing.assert_array_equal(again, expected)
    assert _results.kept_bytes() == 0


@pytest.mark.parametrize(
    "derive",
    [
        lambda r: r[..., 0],  # a view
        lambda r: r.reshape(-1),
        lambda r: r[::2, ::3].T,
        lambda r: memoryview(r),
        lambda r: np.asarray(r),
        lambda r: [r],  # the result itself, elsewhere
    ],
    ids=["view", "reshape", "strided", "memoryview", "asarray", "list"],
)
def test_memory_still_in_use_is_never_handed_out(derive):
    z = frame()
    result = surfnorm.estimate(z, K)
    kept = derive(result)
    expected = result.copy()
    del result
    gc.collect()
    assert _results.kept_bytes() == 0
    others = [surfnorm.estimate(frame(seed), K) for seed in (1, 2, 3)]
    held = np.asarray(kept[0] if isinstance(kept, list) else kept)
    for other in others:
        assert not np.shares_memory(other, held)
    np.testing.assert_array_equal(np.asarray(held).reshape(-1), np.asarray(derive(expected)).reshape(-1))
    del kept, held
    gc.collect()
    assert _results.kept_bytes() == expected.nbytes  # now it is free


def test_results_are_plain_writable_arrays():
    z = frame()
    n, sigma = surfnorm.estimate(z, K, uncertainty=True)
    for a, shape in ((n, z.shape + (3,)), (sigma, z.shape)):
        assert a.shape == shape and a.dtype == np.float32
        assert a.flags.c_contiguous and a.flags.writeable and a.flags.aligned
        copy = pickle.loads(pickle.dumps(a))
        np.testing.assert_array_equal(copy, a)
        buf = io.BytesIO()
        np.save(buf, a)
        buf.seek(0)
        np.testing.assert_array_equal(np.load(buf), a)
    n[0, 0] = 7.0
    assert n[0, 0, 0] == 7.0


def test_kept_blocks_are_bounded():
    results = [_results.new_result((480, 640, 3)) for _ in range(5)]
    del results
    gc.collect()
    assert len(_results._kept[480 * 640 * 3 * 4]) == _results.KEEP
    results = [_results.new_result((s, 640, 3)) for s in range(100, 2000, 100)]
    del results
    gc.collect()
    assert _results.kept_bytes() <= _results.BUDGET
    assert all(len(kept) <= _results.KEEP for kept in _results._kept.values())
    small = _results.new_result((8, 8, 3))
    assert small.base is None  # small results are plain np.empty
    _results.release()
    assert _results.kept_bytes() == 0


def test_threads_taking_and_freeing_results_get_right_normals():
    frames = [frame(seed) for seed in range(4)]
    expected = [surfnorm.estimate(z, K, threads=1, out=np.empty(z.shape + (3,), np.float32)) for z in frames]
    errors = []

    def work(t):
        try:
            for i in range(12):
                k = (t + i) % len(frames)
                n = surfnorm.estimate(frames[k], K, threads=1)
                if not np.array_equal(n, expected[k]):
                    errors.append((t, i))
                del n
        except Exception as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(t,)) for t in range(6)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert errors == []
