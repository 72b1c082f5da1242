"""One frame on several threads (row bands): the same bits as one thread, for every method and option."""

import numpy as np
import pytest

import surfnorm
from surfnorm import InputError, _api, _bands
from surfnorm.camera import Intrinsics
from surfnorm.methods import resolve

# a principal point that is not a half-integer: a band must not shift it (see surfnorm._bands)
K = np.array([[97.3, 0, 21.713], [0, 103.9, 17.291], [0, 0, 1]])


def scene(h, w, seed, holes=0.08):
    """Two tilted planes, a sphere cap and a depth step, with random holes (0, NaN, negative)."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    z = 3.0 + 0.011 * u + 0.007 * v
    z = np.where(u > 0.6 * w, z + 0.8 - 0.02 * v, z)
    r2 = (u - 0.3 * w) ** 2 + (v - 0.5 * h) ** 2
    z = np.where(r2 < (0.2 * h) ** 2, z - 0.01 * np.sqrt(np.maximum((0.2 * h) ** 2 - r2, 0)), z)
    z = (z + rng.normal(0, 0.002, z.shape)).astype(np.float32)
    bad = rng.random(z.shape) < holes
    z[bad] = rng.choice(np.array([0.0, np.nan, -1.0], np.float32), size=int(bad.sum()))
    z[h // 3, :] = 0.0  # a whole empty row
    return z


def option_sets(name):
    """The option combinations that change a method's code path."""
    info = surfnorm.methods()[name].options
    sets = [{}, {"fill": np.nan}]
    if "border" in info:
        sets.append({"border": "reflect"})
    if "dlf" in info:
        sets += [{"dlf": "alpha"}, {"dlf": "gamma", "truncate": False}]
    if "mnr_dlf" in info:
        sets.append({"mnr_dlf": "1d", "fill": 0.5})
    if "base" in info:
        sets += [{"base": "3f2n"}, {"iterations": None}, {"iterations": 0, "border": "reflect"}]
    if "window" in info:
        sets.append({"window": 5})
    return sets


def interleaved_bands(parts):
    """A ``bands`` function that runs the given row bands one after another, last band first."""

    def bands(stage, n_rows, weights=None):
        spans = [(a, min(b, n_rows)) for a, b in parts if a < n_rows]
        results = {}
        for a, b in reversed(spans):
            results[a] = stage(a, b)
        return [results[a] for a, _ in spans]

    return bands


SHAPES = [(37, 53), (64, 45), (9, 71)]
# Band edges next to the image border, next to each other (one-row bands) and in the middle.
PARTS = [[(0, 1), (1, 2), (2, 5), (5, 6), (6, 20), (20, 35), (35, 36), (36, 10**6)], [(0, 13), (13, 10**6)]]


@pytest.mark.slow
@pytest.mark.parametrize("name", list(surfnorm.methods()))
def test_bands_same_bits_as_one_sweep(name):
    """Every stage of every method computes any row band exactly as a sweep over all rows does."""
    cam = Intrinsics.from_matrix(K)
    for seed, (h, w) in enumerate(SHAPES):
        z = scene(h, w, seed)
        mask = np.random.default_rng(seed + 10).random(z.shape) > 0.05
        for options in option_sets(name):
            for suffix in ("", "+mnr"):
                method, refined, clean = resolve(name + suffix, dict(options))
                for user_mask in (None, mask):
                    valid = _api._valid(z, user_mask)
                    one = _api._run(method, refined, dict(clean), z, valid, cam)
                    for parts in PARTS:
                        banded = _api._run(
                            method,
                            refined,
                            dict(clean),
                            z,
                            _api._valid(z, user_mask),
                            cam,
                            bands=interleaved_bands(parts),
                        )
                        np.testing.assert_array_equal(
                            banded.view(np.uint32),
                            one.view(np.uint32),
                            err_msg=f"{name}{suffix} {options} {(h, w)} {parts}",
                        )


@pytest.mark.slow
@pytest.mark.parametrize("name", list(surfnorm.methods()))
def test_threads_same_bits_as_one_thread(name, monkeypatch):
    """estimate(threads=N) on one frame: the same bits as threads=1, bands on real threads."""
    monkeypatch.setattr(_bands, "MIN_ROWS", 4)
    z = scene(61, 47, 7)
    mask = np.random.default_rng(3).random(z.shape) > 0.05
    for options in option_sets(name)[:3]:
        for suffix in ("", "+mnr"):
            for kwargs in ({}, {"mask": mask}, {"scale_invariant": True}):
                one = surfnorm.estimate(z, K, method=name + suffix, threads=1, **kwargs, **options)
                for threads in (2, 3, 7):
                    many = surfnorm.estimate(z, K, method=name + suffix, threads=threads, **kwargs, **options)
                    np.testing.assert_array_equal(
                        many.view(np.uint32),
                        one.view(np.uint32),
                        err_msg=f"{name}{suffix} {options} {kwargs} threads={threads}",
                    )


def test_bands_really_split_one_frame(monkeypatch):
    """threads=3 on a 300-row frame runs the kernels on three row bands (at least MIN_ROWS each)."""
    seen = []
    real = _bands.on_threads

    def spy(workers):
        bands = real(workers)

        def recording(stage, n_rows):
            seen.append(_bands.spans(n_rows, workers))
            return bands(stage, n_rows)

        return recording if workers > 1 else bands

    monkeypatch.setattr(_api, "on_threads", spy)
    z = scene(300, 40, 1)
    surfnorm.estimate(z, K, method="d2nt_v3", threads=3)
    assert seen and all(s == [(0, 100), (100, 200), (200, 300)] for s in seen)
    seen.clear()
    surfnorm.estimate(z[:63], K, method="d2nt_v3", threads=3)  # fewer than 2 * MIN_ROWS rows: one band
    assert seen and all(s == [(0, 63)] for s in seen)


def test_spans_cover_every_row_once():
    rng = np.random.default_rng(0)
    for n_rows in (1, 31, 64, 65, 960, 2161):
        weightings = [None, rng.random(n_rows), np.r_[np.zeros(n_rows // 2), np.ones(n_rows - n_rows // 2)]]
        for workers in (1, 2, 3, 16):
            for weights in weightings:
                parts = _bands.spans(n_rows, workers, weights=weights)
                assert parts[0][0] == 0 and parts[-1][1] == n_rows
                assert all(a < b for a, b in parts) and all(p[1] == q[0] for p, q in zip(parts, parts[1:]))
                assert len(parts) <= workers
                assert len(parts) == 1 or min(b - a for a, b in parts) >= _bands.MIN_ROWS


def test_weighted_spans_share_the_work():
    """Rows weighted by their cost (a frame whose upper half is empty): the bands carry equal sums of it."""
    weights = np.r_[np.zeros(480), np.ones(480)]
    assert _bands.spans(960, 2, weights=weights) == [(0, 720), (720, 960)]
    assert _bands.spans(960, 2) == [(0, 480), (480, 960)]
    # all the work in the last rows: every band still has MIN_ROWS rows
    assert _bands.spans(200, 3, weights=np.r_[np.zeros(199), 1.0]) == [(0, 136), (136, 168), (168, 200)]


@pytest.mark.parametrize("threads", [0, -1, 1.5, True, "2"])
def test_threads_checked_for_one_frame(threads):
    with pytest.raises(InputError, match="threads: expected a positive integer"):
        surfnorm.estimate(np.full((8, 8), 2.0), K, threads=threads)


def test_stack_still_runs_frames_side_by_side():
    """A stack keeps its behaviour (frames on threads, each frame on one thread); same bits as frame by frame."""
    stack = np.stack([scene(40, 30, s) for s in range(5)])
    out = surfnorm.estimate(stack, K, method="sda_sne", threads=2)
    for i in range(5):
        np.testing.assert_array_equal(out[i], surfnorm.estimate(stack[i], K, method="sda_sne", threads=1))


def test_the_caller_runs_the_first_band_and_every_band_ends_before_an_error_is_raised():
    """One band on the calling thread, the others on the pool: all have ended when the call returns or raises,
    and the error raised is the first band's (in band order) among those that failed."""
    import threading
    import time

    from surfnorm._bands import split_with_caller

    caller = threading.get_ident()
    ran = {}

    def work(i):
        time.sleep(0.02 * (3 - i))  # the later bands end first
        ran[i] = threading.get_ident()

    split_with_caller(work, 3)
    assert sorted(ran) == [0, 1, 2] and ran[0] == caller and ran[1] != caller and ran[2] != caller

    ended = set()

    def failing(i):
        time.sleep(0.05 if i == 2 else 0.0)
        ended.add(i)
        if i >= 1:
            raise ValueError(f"band {i}")

    with pytest.raises(ValueError, match="band 1"):
        split_with_caller(failing, 3)
    assert ended == {0, 1, 2}  # band 2, the slowest, had ended before the error was raised

    def first_fails(i):
        if i == 0:
            raise KeyError("band 0")
        time.sleep(0.05)
        ended.add(10 + i)

    with pytest.raises(KeyError, match="band 0"):
        split_with_caller(first_fails, 2)
    assert 11 in ended


def test_a_part_runs_once_on_whichever_thread_takes_it_first_and_its_owner_runs_it_if_nobody_did():
    import threading

    from surfnorm._bands import Offers, Part

    calls = []
    part = Part(lambda: calls.append(threading.get_ident()) or 42)
    threads = [threading.Thread(target=part.take) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert part.result() == 42 and len(calls) == 1  # taken by one of the threads, not run again

    alone = Part(lambda: 7)
    assert alone.result() == 7  # nobody took it: run here

    def fails():
        raise ZeroDivisionError("in the part")

    broken = Part(fails)
    assert broken.take()
    with pytest.raises(ZeroDivisionError, match="in the part"):  # raised where the result is asked for
        broken.result()

    offers = Offers()
    offers.help()  # nobody measuring: returns at once (bands run one after another would wait for ever)
    offers.open()
    helped = []
    helper = threading.Thread(target=lambda: (offers.help(), helped.append("returned")))
    helper.start()
    first = offers.offer(Part(lambda: threading.get_ident()))
    assert first.result() == helper.ident or first.result() == threading.get_ident()
    offers.close()
    helper.join(timeout=5)
    assert helped == ["returned"]  # help returns once the offers are closed

    # a part the measuring band waits for soonest goes first; not waiting, a band runs what is offered and returns
    order = []
    offers = Offers()
    offers.open()
    offers.offer(Part(lambda: order.append("rows")))
    offers.offer(Part(lambda: order.append("samples")), first=True)
    offers.help(wait=False)
    assert order == ["samples", "rows"]
    offers.help(wait=False)  # nothing left, measuring still open: returns at once
    offers.close()


def test_a_finished_part_runs_nowhere_after_finish_returns():
    """``finish``: a part that nobody took is given up (never run); one that runs elsewhere is waited for (the
    calling band gives its ring back only then)."""
    import threading

    from surfnorm._bands import Part

    calls = []
    idle = Part(lambda: calls.append("ran"))
    idle.finish()
    assert not idle.take() and calls == []  # given up: nobody runs it any more
    with pytest.raises(RuntimeError, match="given up"):
        idle.result()

    release, started, ended = threading.Event(), threading.Event(), []

    def slow():
        started.set()
        release.wait(5)
        ended.append("end")

    busy = Part(slow)
    runner = threading.Thread(target=busy.take)
    runner.start()
    assert started.wait(5)
    finished = []
    waiter = threading.Thread(target=lambda: (busy.finish(), finished.append(list(ended))))
    waiter.start()
    waiter.join(timeout=0.2)
    assert waiter.is_alive() and finished == []  # still running elsewhere: finish waits
    release.set()
    waiter.join(timeout=5)
    runner.join(timeout=5)
    assert finished == [["end"]]  # returned only after the part's end


def test_bands_waiting_for_the_noise_never_wait_for_ever_when_measuring_it_fails(monkeypatch):
    """The band measuring the noise offers parts of it to the others (Offers); when it fails, the others still
    return and the error reaches the caller, on every number of bands."""
    import threading

    from surfnorm.kernels import adaptive_fit as af

    def broken(z, valid, f, offers=None, *, sparse=None):
        raise RuntimeError("noise measurement failed")

    monkeypatch.setattr(af, "noise_profile", broken)
    rng = np.random.default_rng(0)
    z = rng.uniform(1.0, 2.0, (120, 90)).astype(np.float32)
    cam = Intrinsics(100.0, 100.0, 45.0, 60.0)
    outcome = []

    def run():
        for workers in (2, 3):
            try:
                af.adaptive_fit(z, z > 0, cam, np.empty(z.shape + (3,), np.float32), bands=_bands.on_threads(workers))
            except RuntimeError as exc:
                outcome.append(str(exc))

    t = threading.Thread(target=run)
    t.start()
    t.join(timeout=60)
    assert not t.is_alive(), "a band waited for ever"
    assert outcome == ["noise measurement failed"] * 2
