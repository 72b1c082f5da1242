"""The PyTorch backend: parity with the NumPy backend, gradients, shapes, dtypes, devices, errors."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch", reason="the torch extra is not installed")

import surfnorm  # noqa: E402
import surfnorm.torch as st  # noqa: E402
from surfnorm import InputError  # noqa: E402
from surfnorm.io import threef2n  # noqa: E402
from surfnorm.metrics import mean_angular_error  # noqa: E402
from surfnorm.reference import official_figures  # noqa: E402

from .naive_torch_3f2n import three_f2n as naive_three_f2n  # noqa: E402
from .surfaces import camera, plane, sphere  # noqa: E402

TOL = 1e-4  # per component, float32 (acceptance criterion of issues 7 and 16)
K = np.array([[100.0, 0, 15.5], [0, 100.0, 11.5], [0, 0, 1]])
TORCH_METHODS = list(st.methods())
CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device on this machine")


def nchw(n: torch.Tensor) -> np.ndarray:
    """(B, 3, H, W) tensor -> (B, H, W, 3) float32 array, as the NumPy backend returns."""
    return n.detach().permute(0, 2, 3, 1).float().numpy()


def load(root, names):
    frames = [threef2n.read_frame(root, name) for name in names]
    depth = np.stack([f.depth for f in frames])
    masks = np.stack([f.mask for f in frames])
    Ks = np.stack([f.K.matrix for f in frames])
    return frames, depth, masks, Ks


def variants(name):
    """(method, options) pairs covering every option value of ``name`` at least once."""
    opts = st.methods()[name]
    out = [(name, {}), (name + "+mnr", {})]
    if "dlf" in opts:
        out += [
            (name, {"dlf": "alpha", "tau": 0.5}),
            (name, {"dlf": "beta", "truncate": False}),
            (name + "+mnr", {"dlf": "gamma", "mnr_dlf": "1d"}),
            (name + "+mnr", {"mnr_dlf": "beta"}),
        ]
    if "border" in opts:
        out += [(name, {"border": "reflect"})]
    if "mnr_dlf" in opts:
        out += [(name, {"mnr_dlf": "gamma"})]
    if "window" in opts:
        out += [(name, {"window": 5}), (name + "+mnr", {"window": 7, "mnr_dlf": "beta"})]
    if "max_window" in opts:
        out += [(name, {"max_window": 7}), (name, {"window": 3, "max_window": 15, "fill": -2.0})]
    if "tau" in opts and "dlf" not in opts:  # auto: d2nt_v3's tau where it picks d2nt_v3
        out += [(name, {"tau": 0.5}), (name + "+mnr", {"mnr_dlf": "gamma", "fill": 1.0})]
    if "base" in opts:
        out += [
            (name, {"base": "3f2n"}),
            (name, {"base": "3f2n", "border": "reflect", "iterations": 1}),
            (name, {"iterations": None}),
        ]
    return out


def assert_parity(depth, masks, Ks, method, options, names):
    """The torch backend on a batch equals surfnorm.estimate frame by frame to TOL per component."""
    got = nchw(
        st.estimate(
            torch.from_numpy(depth)[:, None],
            torch.from_numpy(Ks),
            method=method,
            mask=None if masks is None else torch.from_numpy(masks)[:, None],
            **options,
        )
    )
    for i, name in enumerate(names):
        ref = surfnorm.estimate(depth[i], Ks[i], method=method, mask=None if masks is None else masks[i], **options)
        g = got[i]
        if method.startswith("3f2n"):
            # 3F2N can land exactly on one neighbour's candidate, which makes the normal perpendicular to
            # the line of sight: there rounding alone picks its sign (both backends are right), so compare
            # such edge-on normals up to sign.
            H, W = ref.shape[:2]
            v, u = np.mgrid[0:H, 0:W]
            ray = np.stack([(u - Ks[i][0, 2]) / Ks[i][0, 0], (v - Ks[i][1, 2]) / Ks[i][1, 1], np.ones((H, W))], -1)
            ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
            edge_on = np.abs(np.einsum("hwc,hwc->hw", ref, ray)) < 1e-3
            flip = edge_on & ((g * ref).sum(-1) < 0)
            g = np.where(flip[..., None], -g, g)
        err = np.abs(g - ref).max()
        assert err <= TOL, f"{method} {options} on {name}: max error {err:.2e}"
    return got


class TestParity:
    """Issue 7, acceptance 1: the torch backend on the CPU matches the NumPy backend to 1e-4 per component."""

    @pytest.mark.slow
    @pytest.mark.parametrize("name", TORCH_METHODS)
    def test_shipped_frames(self, name):
        root = threef2n.sample_root()
        names = threef2n.find_frames(root)
        _, depth, masks, Ks = load(root, names)
        # one whole frame with the default options; with the foreground mask (gaps) and MNR after it
        # (test_twelve_frames covers all of them where the 12-frame sample is present)
        assert_parity(depth[:1], None, Ks[:1], name, {}, names[:1])
        assert_parity(depth[:1], masks[:1], Ks[:1], name + "+mnr", {}, names[:1])
        # every option on a corner of each frame (image border, silhouette, background)
        Ks_crop = Ks.copy()
        Ks_crop[:, 0, 2] -= 64
        crop = (slice(None), slice(0, 120), slice(64, 224))
        for method, options in variants(name)[2:]:
            assert_parity(
                np.ascontiguousarray(depth[crop]), np.ascontiguousarray(masks[crop]), Ks_crop, method, options, names
            )

    @pytest.mark.slow
    @pytest.mark.parametrize("name", TORCH_METHODS)
    def test_twelve_frames(self, shared_sample, name):
        names = threef2n.find_frames(shared_sample)
        assert len(names) == 12
        for chunk in (names[:4], names[4:8], names[8:]):  # batches of 4 (float64 temporaries of SDA-SNE)
            _, depth, masks, Ks = load(shared_sample, chunk)
            assert_parity(depth, None, Ks, name, {}, chunk)
            assert_parity(depth, masks, Ks, name + "+mnr", {}, chunk)

    def test_every_registered_method_runs_in_torch(self):
        # Issue 16, acceptance 1: every method of surfnorm.methods() (the parity tests above take their
        # list from st.methods(), so a method missing here would be missing there too), except those whose
        # registry entry declares that they have no torch twin (torch=False, issue 29): those are NUMPY_ONLY.
        declared = tuple(name for name, info in surfnorm.methods().items() if not info.torch)
        assert st.NUMPY_ONLY == declared
        assert list(st.methods()) == [name for name in surfnorm.methods() if name not in declared]
        assert set(st._KERNELS) == set(st.methods())  # no torch kernel without a registry entry that declares it
        # the methods of issue 16 all keep their torch twin
        issue_16 = ["d2nt_basic", "d2nt_v2", "d2nt_v3", "cp2tv", "3f2n_mean", "3f2n_median", "sne_roadseg"]
        issue_16 += ["sda_sne", "plane_svd", "plane_pca", "vector_svd", "area_weighted", "angle_weighted"]
        assert set(issue_16 + ["adaptive_fit", "auto"]) <= set(st.methods())

    def test_a_method_without_torch_twin_names_itself(self, monkeypatch):
        """A registered method declared ``torch=False``: surfnorm.torch.estimate raises an InputError that says so."""
        from surfnorm.methods import _REGISTRY, Method

        entry = Method("numpy_only_test", "averaging", "test", "no twin", kernel="x.y", torch=False)
        monkeypatch.setitem(_REGISTRY, "numpy_only_test", entry)
        monkeypatch.setattr(st, "NUMPY_ONLY", (*st.NUMPY_ONLY, "numpy_only_test"))
        assert "numpy_only_test" not in st.methods()
        for name in ("numpy_only_test", "numpy_only_test+mnr"):
            with pytest.raises(InputError, match=r"numpy_only_test.*no torch kernel.*surfnorm\.estimate"):
                st.estimate(torch.ones(1, 1, 4, 4), torch.eye(3), method=name)

    def test_options_match_the_numpy_backend(self):
        for name in TORCH_METHODS:
            assert st.methods()[name] == surfnorm.methods()[name].options, name

    def test_constants_match_the_numpy_kernels(self):
        # one source, surfnorm._constants (loads no Numba), which both backends import (tests/test_project.py)
        from surfnorm.kernels import plane_fit, sda
        from surfnorm.torch import _plane_fit, _sda

        assert _sda.SDA_PENALTY == sda.SDA_PENALTY and _sda.MAX_ITERATIONS == sda.MAX_ITERATIONS
        assert (_plane_fit._NEWTON_STEPS, _plane_fit._NEWTON_TOL) == (plane_fit._NEWTON_STEPS, plane_fit._NEWTON_TOL)
        from surfnorm.kernels import _schedule, _windows, adaptive_fit, auto, sensor_noise
        from surfnorm.torch import _adaptive

        homes = {  # each constant where the NumPy side uses it
            adaptive_fit: ("ALPHA", "KAPPA", "RHO_FLOOR", "N_WIDEN", "MIN_POINTS", "TIE"),
            sensor_noise: ("N_BINS", "MIN_SAMPLES", "noise_step", "_MAX_GAP", "_MAX_SPREAD", "_CLIP_SIGMAS"),
            _windows: ("RADII", "_TABLE"),
            _schedule: ("MAX_UNREACHED",),
        }
        homes[sensor_noise] += ("_CLIP_ROUNDS",)
        for module, names in homes.items():
            for name in names:
                assert getattr(_adaptive, name) == getattr(module, name), (module.__name__, name)
        assert _adaptive._SHIFTS == tuple(map(tuple, adaptive_fit._SHIFTS.tolist()))
        assert (_adaptive.CLEAN_FLOOR, _adaptive.NOISY_FLOOR) == (auto.CLEAN_FLOOR, auto.NOISY_FLOOR)
        assert (
            _adaptive.MAX_WINDOW == adaptive_fit.MAX_WINDOW == surfnorm.methods()["adaptive_fit"].options["max_window"]
        )
        for r_max in (1, 3, 7, 15, 20, 63):
            widen, grow = _adaptive._ladder_tables(r_max)
            np.testing.assert_array_equal(widen, _windows.widen_table(r_max))
            np.testing.assert_array_equal(grow, _windows.growth_table(r_max))


def scene_with_holes(h=40, w=52, seed=0):
    """A small random scene: two tilted planes with a step between them, noise, holes and invalid values."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:h, 0:w]
    depth = np.where(u < w // 2, 2.0 + 0.01 * u + 0.005 * v, 3.0 - 0.02 * v) + 0.002 * rng.standard_normal((h, w))
    depth = depth.astype(np.float32)
    depth[rng.random((h, w)) < 0.05] = 0.0
    depth[5:9, 10:14] = np.nan
    depth[0, w - 3] = -1.0
    mask = rng.random((h, w)) > 0.03
    return depth, mask


SENSOR_SAMPLE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "sensor-sample"
SENSOR_FRAMES = (
    sorted(p.name for p in SENSOR_SAMPLE.iterdir() if (p / "depth.npy").is_file()) if SENSOR_SAMPLE.is_dir() else []
)


def read_sensor(name):
    """A frame of the sensor sample: float32 depth (0 where invalid) and K."""
    k = json.loads((SENSOR_SAMPLE / name / "K.json").read_text())
    return np.load(SENSOR_SAMPLE / name / "depth.npy"), np.array(
        [[k["fx"], 0, k["cx"]], [0, k["fy"], k["cy"]], [0, 0, 1]]
    )


def sensor_like(h=48, w=64, seed=0, step=0.008, sigma=0.01, holes=0.05):
    """Depth as a sensor gives it: two tilted planes with a step and a ball in front, noise, quantised to
    ``step``, holes. Its noise profile has samples in several depth bins, so the radius, the widening, the
    growth (around the holes) and the quadrant windows (at the step and the ball's rim) all come into play."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:h, 0:w]
    z = np.where(u < w // 2, 1.5 + 0.01 * u + 0.004 * v, 2.4 - 0.012 * v)
    ball = (u - 0.7 * w) ** 2 + (v - 0.5 * h) ** 2 < (0.2 * h) ** 2
    z = np.where(
        ball, 1.2 - 0.2 * np.sqrt(np.clip(1 - ((u - 0.7 * w) ** 2 + (v - 0.5 * h) ** 2) / (0.2 * h) ** 2, 0, 1)), z
    )
    z = np.round((z + sigma * rng.standard_normal(z.shape)) / step) * step
    z[rng.random(z.shape) < holes] = 0.0
    z[3:7, 5:12] = 0.0
    return z.astype(np.float32)


def torch_normals(depth, Ks, method, masks=None, **options):
    return nchw(
        st.estimate(
            torch.from_numpy(depth)[:, None],
            torch.from_numpy(Ks),
            method=method,
            mask=None if masks is None else torch.from_numpy(masks)[:, None],
            **options,
        )
    )


class TestAdaptive:
    """adaptive_fit and auto: the same data-dependent choices as the NumPy kernel, per frame of a batch."""

    @staticmethod
    def numpy_tables(depth, K, mask=None, window=None, max_window=31):
        from surfnorm.kernels._windows import radius_table
        from surfnorm.kernels.sensor_noise import noise_profile

        valid = np.isfinite(depth) & (depth > 0) & (True if mask is None else mask)
        f = np.sqrt(K[0, 0] * K[1, 1])
        profile = noise_profile(depth, valid, f)
        return profile, radius_table(profile.depths, profile.rho, window=window, max_window=max_window)

    @staticmethod
    def torch_tables(depth, K, mask=None, window=None, max_window=31):
        from surfnorm.torch import _adaptive

        d = torch.from_numpy(depth)[None].double()
        valid = torch.isfinite(d) & (d > 0)
        if mask is not None:
            valid = valid & torch.from_numpy(mask)[None]
        f = torch.tensor([np.sqrt(K[0, 0] * K[1, 1])], dtype=torch.float64)
        return _adaptive.noise_tables(torch.where(valid, d, 1.0), valid, f, window=window, r_max=(max_window - 1) // 2)

    def scenes(self):
        f = threef2n.read_frame(threef2n.sample_root(), "Medium/Trex/000001")
        sparse = sensor_like(seed=4, holes=0.8)  # too few valid pixels: windows grow
        yield "3F2N frame", f.depth, f.K.matrix, None
        yield "3F2N frame, foreground", f.depth, f.K.matrix, f.mask
        yield "sensor-like", sensor_like(seed=1), K, None
        rng = np.random.default_rng(3)  # dense, with random holes: the bins of the pixel scale's stencils alone
        holes = np.where(
            rng.random(f.depth.shape) < 0.2, 0.0, f.depth * (1.0 + 1e-4 * rng.standard_normal(f.depth.shape))
        )
        yield "3F2N frame, white noise, random holes", holes.astype(np.float32), f.K.matrix, f.mask
        lines = np.zeros_like(holes)
        lines[1::3] = holes[1::3]  # LiDAR-like lines: sparse, every stencil in the bins
        yield "3F2N frame on every third row", lines.astype(np.float32), f.K.matrix, f.mask
        yield "sparse", sparse, K, None
        yield "flat", np.full((40, 50), 2.0, np.float32), K, None  # one depth: no depth range
        yield "tiny", sensor_like(8, 9, seed=2), K, None  # too few samples: no profile, NaN floor
        yield "no valid depth", np.zeros((20, 24), np.float32), K, None

    def test_noise_tables_as_numpy(self):
        from surfnorm._constants import KAPPA
        from surfnorm.kernels.sensor_noise import kappa_gain

        for label, depth, Kf, mask in self.scenes():
            for window, max_window in ((None, 31), (None, 9), (5, 31)):
                profile, (z0, inv_step, radius, rho) = self.numpy_tables(depth, Kf, mask, window, max_window)
                got = self.torch_tables(depth, Kf, mask, window, max_window)
                msg = f"{label}, window {window}, max_window {max_window}"
                assert (np.isnan(profile.floor) and np.isnan(got.floor.item())) or profile.floor == got.floor.item(), (
                    msg
                )
                np.testing.assert_array_equal(got.radius[0].numpy(), radius, err_msg=msg)
                np.testing.assert_allclose(got.rho[0].numpy(), rho, rtol=1e-13, atol=0, err_msg=msg)
                np.testing.assert_allclose(
                    [got.z0.item(), got.inv_step.item()], [z0, inv_step], rtol=1e-13, err_msg=msg
                )
                assert got.kappa.item() == pytest.approx(KAPPA * kappa_gain(profile), rel=1e-12), msg
                assert got.correlation.item() == pytest.approx(profile.correlation, rel=1e-12), msg

    def test_noise_tables_kappa_follows_correlation_and_rho(self):
        """The torch tables' kappa is KAPPA times kappa_gain of the NumPy profile, from 1 (white noise) to more than
        1.5 (correlated noise): a 3F2N frame through three presets."""
        from surfnorm._constants import KAPPA
        from surfnorm.bench.simulate import simulate
        from surfnorm.kernels.sensor_noise import kappa_gain

        f = threef2n.read_frame(threef2n.sample_root(), "Medium/Trex/000001")
        seen = []
        for sensor, seed in (("smooth_error", 0), ("stereo_sgbm", 1), ("kinect_v1", 2)):
            depth = simulate(f.depth, f.K, sensor, seed=seed, mask=f.mask, normals=f.normals)
            profile, _ = self.numpy_tables(depth, f.K.matrix)
            got = self.torch_tables(depth, f.K.matrix)
            assert got.kappa.item() == pytest.approx(KAPPA * kappa_gain(profile), rel=1e-12), sensor
            seen.append(kappa_gain(profile))
        assert max(seen) > 1.5 and min(seen) == 1.0, seen

    def test_noise_tables_white_noise_share_as_numpy(self):
        """The torch tables' white noise share and adaptive_fit's weight are the NumPy profile's: a plane with white
        noise of 0.005-0.03 % of depth (shares between 0 and 1, and 1), the tables' scenes (a clean 3F2N frame: 0);
        and the weight is the sum of the white noise's and the smooth error's shares where both are partial."""
        from surfnorm.kernels.sensor_noise import adaptive_weight, white_noise_share
        from surfnorm.torch import _adaptive

        Kp = camera(320, 240, fov_deg=60)
        z, _, hit = plane(Kp, 240, 320, [0.4, 0.3, -1.0], 2.0)
        rng = np.random.default_rng(5)
        cases = list(self.scenes())
        for percent in (0.005, 0.007, 0.01, 0.03):
            noisy = np.where(hit, z * (1.0 + percent / 100.0 * rng.standard_normal(z.shape)), 0.0)
            cases.append((f"plane, {percent} %", noisy.astype(np.float32), Kp, None))
        seen = []
        for name, depth, Km, mask in cases:
            profile, _ = self.numpy_tables(depth, Km, mask)
            got = self.torch_tables(depth, Km, mask)
            assert got.white_noise.item() == pytest.approx(white_noise_share(profile), abs=1e-12), name
            assert _adaptive.adaptive_weight(got).item() == pytest.approx(adaptive_weight(profile), abs=1e-12), name
            seen.append(got.white_noise.item())
        assert min(seen) == 0.0 and max(seen) == 1.0 and any(0.0 < s < 1.0 for s in seen), seen
        half = got._replace(
            floor=torch.full_like(got.floor, 0.03),
            smooth=torch.zeros_like(got.smooth),
            terraced=torch.zeros_like(got.terraced),
            grid=torch.zeros_like(got.grid),
            smooth_error=torch.full_like(got.smooth_error, 0.25),
            white_noise=torch.full_like(got.white_noise, 0.5),
        )
        assert _adaptive.adaptive_weight(half).item() == pytest.approx(0.75)  # not the larger share, nor the reading's

    def test_choices_differ_across_the_scene(self):
        # the parity tests on sensor_like() scenes are only worth something if the scene exercises every choice
        from surfnorm.torch import _adaptive

        depth = sensor_like(seed=1)
        z = torch.from_numpy(depth)[None].double()
        valid = z > 0
        cam = tuple(torch.tensor(c, dtype=torch.float64).view(1, 1, 1) for c in (K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
        _, choice = _adaptive.choices(torch.where(valid, z, 1.0), valid, cam)
        radii = set(choice.radius.tolist())
        assert len(radii) >= 3, radii
        assert (choice.shift >= 0).sum() > 20  # quadrant windows
        assert set(range(4)) <= set(choice.shift.tolist())

    @pytest.mark.slow
    @pytest.mark.parametrize("seed", [1, 2, 3])
    @pytest.mark.parametrize("method", ["adaptive_fit", "auto"])
    def test_sensor_like_batch(self, method, seed):
        # a batch of four different frames: each gets its own noise profile and choice, as if run alone (auto:
        # adaptive_fit, d2nt_v3, adaptive_fit, and the blend of both: noise floors 0.55, 0.003, 0.5, 0.15)
        depth = np.stack(
            [
                sensor_like(seed=seed),
                sensor_like(seed=seed + 10, sigma=0.0, step=1e-6, holes=0.0),
                sensor_like(seed=seed + 20, holes=0.5),
                sensor_like(seed=seed + 30, sigma=0.003, step=0.004),
            ]
        )
        Ks = np.stack([K, K, K, K])
        names = ["noisy", "clean", "sparse", "between"]
        assert_parity(depth, None, Ks, method, {}, names)
        masks = np.random.default_rng(seed).random(depth.shape) > 0.1
        assert_parity(depth, masks, Ks, method + "+mnr", {"fill": -3.0}, names)

    @pytest.mark.parametrize("stride", [1, 2, 4])
    def test_strides(self, stride):
        # every frame at the same stride, whatever its density (the default chooses per frame: above)
        from surfnorm.kernels._schedule import choose_stride

        depth = np.stack([sensor_like(seed=5), sensor_like(seed=6, holes=0.5), sensor_like(seed=7, holes=0.2)])
        depth[2][::4, ::4] = 0.0  # no cell has a valid corner; the even rows and columns have valid pixels near all
        assert [choose_stride(d > 0) for d in depth] == [4, 1, 2]  # otherwise the default shows nothing new
        assert_parity(depth, None, np.stack([K, K, K]), "adaptive_fit", {"stride": stride}, ["a", "sparse", "b"])

    def test_auto_chooses_per_frame(self):
        from surfnorm.camera import Intrinsics
        from surfnorm.kernels.auto import choose

        f = threef2n.read_frame(threef2n.sample_root(), "Medium/Trex/000001")
        clean = f.depth[100:260, 200:400].copy()
        noise = np.random.default_rng(0).standard_normal(clean.shape).astype(np.float32)
        quantised = (np.round(clean * 1000 / 4) * 4 / 1000).astype(np.float32)  # to 4 mm
        noisy = np.where(clean > 0, quantised + 0.002 * noise, 0).astype(np.float32)
        between = np.where(clean > 0, quantised + 0.0005 * noise, 0).astype(np.float32)
        Kc = f.K.matrix.copy()
        Kc[0, 2] -= 200
        Kc[1, 2] -= 100
        cam = Intrinsics.from_matrix(Kc)
        picks = [choose(d, d > 0, cam) for d in (clean, noisy, between)]
        assert picks == ["d2nt_v3", "adaptive_fit", "blend"]  # otherwise this test shows nothing
        depth, Ks = np.stack([clean, noisy, between, clean]), np.stack([Kc, Kc, Kc, Kc])
        got = assert_parity(depth, None, Ks, "auto", {}, ["clean", "noisy", "between", "clean again"])
        np.testing.assert_array_equal(got[0], nchw(st.estimate(torch.from_numpy(clean), Kc, method="d2nt_v3"))[0])
        # noisy: adaptive_fit's normals, but where the consistency check took d2nt_v3's (the same pixels as NumPy's)
        from surfnorm.kernels import auto as auto_module

        record: dict = {}
        auto_module.auto(noisy, noisy > 0, cam, np.empty(noisy.shape + (3,), np.float32), record=record)
        took = record.get("took_d2nt", np.zeros(noisy.shape, bool))
        fitted = nchw(st.estimate(torch.from_numpy(noisy), Kc, method="adaptive_fit"))[0]
        detail = nchw(st.estimate(torch.from_numpy(noisy), Kc, method="d2nt_v3"))[0]
        np.testing.assert_array_equal(got[1], np.where(took[..., None], detail, fitted))
        np.testing.assert_array_equal(got[3], got[0])

    def test_auto_checks_its_estimators_as_numpy_does(self, monkeypatch):
        # the consistency check (surfnorm.kernels.auto.consistency): the same pixels take d2nt_v3's normal, on the
        # gathered path and the masked one, with the blend's weight and without
        from surfnorm.camera import Intrinsics
        from surfnorm.kernels import auto as auto_module
        from surfnorm.torch import _adaptive

        from .test_auto import tree_crop

        frames = [tree_crop(noise, seed)[:2] for noise, seed in ((1e-4, 0), (4e-5, 1), (0.0, 2))]
        weights = []
        for z, Kc in frames:
            record: dict = {}
            out = np.empty(z.shape + (3,), np.float32)
            auto_module.auto(z, z > 0, Intrinsics.from_matrix(Kc), out, record=record)
            weights.append((record["weight"], float(record.get("took_d2nt", np.zeros(1)).mean())))
        # at t 1 and inside the blend band (the crop without noise reads 0.11), each with pixels taken
        assert weights[0][0] == 1.0 and 0.0 < weights[2][0] < 1.0, weights
        assert min(took for _, took in weights) > 0.1, weights
        depth, Ks = np.stack([z for z, _ in frames]), np.stack([Kc for _, Kc in frames])
        gathered = assert_parity(depth, None, Ks, "auto", {}, ["checked", "lower noise", "without noise"])
        monkeypatch.setattr(_adaptive, "_GATHER_ON_CPU", False)
        np.testing.assert_array_equal(torch_normals(depth, Ks, "auto", fill=0.0), gathered)

    @pytest.mark.slow
    @pytest.mark.parametrize("method", ["adaptive_fit", "auto"])
    def test_masked_path_as_gathered_path(self, method, monkeypatch):
        # other devices work on all pixels (and frames) with masks; the CPU on the ones concerned: same normals
        from surfnorm.torch import _adaptive

        depth = np.stack(
            [
                sensor_like(seed=5),
                sensor_like(seed=6, sigma=0.0, step=1e-6),
                sensor_like(seed=7, holes=0.6),
                sensor_like(seed=8, sigma=0.003, step=0.004),
            ]
        )
        Ks = np.stack([K, K, K, K])
        for fill in (0.0, 1.0):
            gathered = torch_normals(depth, Ks, method, fill=fill)
            monkeypatch.setattr(_adaptive, "_GATHER_ON_CPU", False)
            masked = torch_normals(depth, Ks, method, fill=fill)
            monkeypatch.setattr(_adaptive, "_GATHER_ON_CPU", True)
            np.testing.assert_array_equal(masked, gathered)

    @pytest.mark.slow
    @pytest.mark.skipif(not SENSOR_FRAMES, reason=f"the sensor sample is not at {SENSOR_SAMPLE}")
    @pytest.mark.parametrize("name", SENSOR_FRAMES or ["none"])
    def test_sensor_sample(self, name):
        # adaptive_fit on the whole frame; auto (which runs adaptive_fit on all of them but the rendered one)
        # on a quarter of it, with its own noise floor
        depth, Kf = read_sensor(name)
        assert_parity(depth[None], None, Kf[None], "adaptive_fit", {}, [name])
        H, W = depth.shape
        crop = np.ascontiguousarray(depth[H // 4 : H // 4 + H // 2, W // 4 : W // 4 + W // 2])
        Kc = Kf.copy()
        Kc[0, 2] -= W // 4
        Kc[1, 2] -= H // 4
        assert_parity(crop[None], None, Kc[None], "auto", {}, [name + " (crop)"])


class TestAdaptiveGradients:
    """The choices carry no gradient; given them, the fit is differentiable and the gradient flows through it."""

    @pytest.mark.slow
    def test_gradcheck_through_chosen_windows(self):
        # big enough to have a noise profile (several radii, widening, quadrant windows), small enough for gradcheck
        depth = sensor_like(12, 16, seed=3, holes=0.05).astype(np.float64)
        depth[depth == 0] = np.nan
        z = torch.from_numpy(depth).requires_grad_()
        # the window sums are differences of integral images, whose rounding (~1e-13 here) any depth moves: with
        # eps = 1e-6 that is 1e-7 in the numerical Jacobian, well inside gradcheck's tolerance. fast_mode checks
        # random projections of the Jacobian (the full one takes a minute on this 2-core machine class).
        assert torch.autograd.gradcheck(
            lambda d: st.estimate(d, K, method="adaptive_fit"), (z,), eps=1e-6, fast_mode=True
        )

    @pytest.mark.slow
    @pytest.mark.parametrize("method", ["adaptive_fit", "auto"])
    def test_same_normals_with_and_without_a_graph(self, method):
        # with a graph the chosen windows are summed once more from integral images that carry it
        depth = np.stack([sensor_like(seed=8), sensor_like(seed=9, holes=0.5)]).astype(np.float64)
        z = torch.from_numpy(depth)[:, None]
        plain = st.estimate(z, K, method=method)
        graph = st.estimate(z.clone().requires_grad_(), K, method=method)
        assert graph.requires_grad
        torch.testing.assert_close(graph.detach(), plain, rtol=0, atol=0)

    def test_gradient_only_from_the_chosen_window(self):
        # a pixel's normal depends on the depths of its window only: a finite window, not the whole frame
        depth = sensor_like(h=112, w=144, seed=1).astype(np.float64)
        z = torch.from_numpy(depth).requires_grad_()
        n = st.estimate(z, np.array([[100.0, 0, 71.5], [0, 100.0, 55.5], [0, 0, 1]]), method="adaptive_fit")
        far = 2 * 15 + 4  # a window of radius up to max_window // 2, shifted by its radius (the edge test's
        # quadrants), about a fitted pixel up to four rows and columns away (stride 4: its cell's corners)
        for v, u in ((56, 72), (60, 30), (40, 101)):
            (g,) = torch.autograd.grad(n[0, 2, v, u], z, retain_graph=True)
            # window sums are differences of integral images: elsewhere their gradients cancel, to rounding (1e-17)
            rows, cols = torch.nonzero(g.abs() > 1e-12 * g.abs().max(), as_tuple=True)
            assert len(rows) > 8
            assert (rows - v).abs().max() <= far and (cols - u).abs().max() <= far, (v, u)

    @pytest.mark.parametrize("seed,expected", [(1, "adaptive_fit"), (11, "d2nt_v3")])
    def test_auto_gradient_is_its_choice(self, seed, expected):
        noisy = expected == "adaptive_fit"
        # noisy: noise of 2.5 times the quantisation's step, so that auto runs adaptive_fit alone (with noise of the
        # step's size its normals are checked against d2nt_v3's: a mix of both)
        depth = sensor_like(seed=seed, **({"sigma": 0.02} if noisy else {"sigma": 0.0, "step": 1e-6})).astype(
            np.float64
        )
        from surfnorm.camera import Intrinsics
        from surfnorm.kernels.auto import decide

        decision = decide(depth.astype(np.float32), depth > 0, Intrinsics.from_matrix(K))
        assert decision.method == expected and not decision.checked, str(decision)
        grads = []
        for method in ("auto", expected):
            z = torch.from_numpy(depth).requires_grad_()
            (
                st.estimate(z, K, method=method)
                * torch.linspace(0.5, 1.5, 3 * depth.size, dtype=torch.float64).view(1, 3, *depth.shape)
            ).sum().backward()
            grads.append(z.grad)
        torch.testing.assert_close(grads[0], grads[1], rtol=0, atol=0)
        assert (grads[0] != 0).sum() > depth.size // 2


class TestSDA:
    """SDA-SNE's dynamic programming: every frame of a batch stops on its own, as the NumPy kernel's loop."""

    def test_frames_of_a_batch_stop_on_their_own(self):
        from surfnorm.kernels.sda import sda_gradients

        planar = np.full((30, 40), 2.0, dtype=np.float32)  # nothing moves: the first pass stops it
        rough, mask = scene_with_holes(30, 40)
        depth = np.stack([planar, rough])
        valid = np.isfinite(depth) & (depth > 0)
        passes = [sda_gradients(depth[i], valid[i], iterations=None)[2] for i in range(2)]
        assert passes[0] < passes[1]  # otherwise the test shows nothing
        Ks = np.stack([K, K])
        for options in ({"iterations": None}, {"iterations": 4}, {"iterations": None, "base": "3f2n"}):
            batch = nchw(
                st.estimate(torch.from_numpy(depth)[:, None], torch.from_numpy(Ks), method="sda_sne", **options)
            )
            for i in range(2):
                ref = surfnorm.estimate(depth[i], K, method="sda_sne", **options)
                np.testing.assert_allclose(batch[i], ref, rtol=0, atol=TOL, err_msg=str(options))


class TestSmallScenes:
    """Every method and option against the NumPy backend on small random scenes with holes and a step."""

    @pytest.mark.slow
    @pytest.mark.parametrize("method,options", [v for name in TORCH_METHODS for v in variants(name)])
    def test_parity(self, method, options):
        scenes = [scene_with_holes(seed=s) for s in (1, 2)]
        depth = np.stack([d for d, _ in scenes])
        masks = np.stack([m for _, m in scenes])
        Ks = np.stack([K, K])
        assert_parity(depth, masks, Ks, method, options, ["seed 1", "seed 2"])


class TestThreeFilters:
    """3F2N against a naive per-pixel reference, and against the authors' figures."""

    @pytest.mark.parametrize("third", ["mean", "median"])
    @pytest.mark.parametrize("border", ["one-sided", "reflect"])
    def test_naive_reference_with_gaps_and_borders(self, third, border):
        f = threef2n.read_frame(threef2n.sample_root(), "Medium/Trex/000001")
        depth = f.depth[150:180, 300:340].copy()  # crosses the silhouette
        depth[5, 7] = np.nan
        depth[12:14, 20:23] = 0.0
        depth[0, 3] = -1.0
        valid = np.isfinite(depth) & (depth > 0)
        cam = f.K
        cx, cy = cam.cx - 300, cam.cy - 150
        Kc = np.array([[cam.fx, 0, cx], [0, cam.fy, cy], [0, 0, 1]])
        ref = np.array(naive_three_f2n(depth, valid, cam.fx, cam.fy, cx, cy, third=third, border=border))
        got = nchw(st.estimate(torch.from_numpy(depth), Kc, method=f"3f2n_{third}", border=border))[0]
        # Where n is perpendicular to the viewing ray, "facing the camera" does not fix its sign and rounding
        # decides it. That happens by construction where a gradient is one-sided or 0 (image border with
        # reflect, beside a gap) and the mean/median equals the candidate of that same neighbour:
        # n_z,q = -n_x (u - c_x) / f_x exactly, so n . P = 0. Compare up to sign there.
        v, u = np.mgrid[0 : depth.shape[0], 0 : depth.shape[1]]
        ray = np.stack(((u - cx) / cam.fx, (v - cy) / cam.fy, np.ones(u.shape)), axis=-1)
        ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
        # Such normals, and every normal within ORIENTATION_TIE of edge-on, now get a fixed sign from the rule of
        # surfnorm.kernels._rows.facing_sign, which the naive reference (n . P < 0 only) does not apply.
        from surfnorm._choices import ORIENTATION_TIE

        cos = np.abs(np.einsum("hwc,hwc->hw", ref, ray))
        edge_on = (cos < 1.01 * ORIENTATION_TIE) & (np.abs(ref).sum(-1) > 0)  # not fill
        assert edge_on.sum() < 0.1 * edge_on.size
        np.testing.assert_allclose(got[~edge_on], ref[~edge_on], atol=1e-6)
        np.testing.assert_allclose(np.abs(got[edge_on]), np.abs(ref[edge_on]), atol=1e-6)
        # well inside the band: the rule's sign (the first of n_z, n_y, n_x beyond the band made negative)
        inside = edge_on & (cos < 0.99 * ORIENTATION_TIE)
        t = ORIENTATION_TIE
        key = np.where(
            np.abs(ref[..., 2]) > t, ref[..., 2], np.where(np.abs(ref[..., 1]) > t, ref[..., 1], ref[..., 0])
        )
        expected = np.where((key > 0)[..., None], -ref, ref)
        np.testing.assert_allclose(got[inside], expected[inside], atol=1e-6)

    @pytest.mark.slow
    @pytest.mark.parametrize("third", ["mean", "median"])
    def test_authors_figures_on_shipped_frames(self, third):
        root = threef2n.sample_root()
        names = threef2n.find_frames(root)
        frames, depth, _, Ks = load(root, names)
        got = nchw(
            st.estimate(
                torch.from_numpy(depth)[:, None], torch.from_numpy(Ks), method=f"3f2n_{third}", border="reflect"
            )
        )
        for i, f in enumerate(frames):
            e_a = mean_angular_error(got[i], f.normals, f.mask)
            assert abs(e_a - official_figures(f.name)[f"3f2n_{third}"]) < 1e-4, f.name

    def test_faces_the_camera(self):
        d, _, hit = sphere(camera(40, 30), 30, 40, (0.1, 0.0, 3.0), 1.0)
        n = st.estimate(torch.from_numpy(d), camera(40, 30), method="3f2n_median")[0]
        assert bool((n[2][torch.from_numpy(hit)] < 0).all())


class TestClosedForm:
    @pytest.mark.parametrize("name", TORCH_METHODS)
    def test_tilted_plane(self, name):
        Kp = camera(32, 24)
        d, normals, hit = plane(Kp, 24, 32, (0.3, -0.2, -1.0), 2.0)
        assert hit.all()
        n = nchw(st.estimate(torch.from_numpy(d), Kp, method=name))[0]
        # SDA-SNE's one-sided differences are exact only where depth is linear in the pixel coordinates,
        # which a tilted plane seen in perspective is not (the NumPy backend gives the same normals)
        atol = 5e-3 if name.startswith("sda_sne") else 1e-4
        np.testing.assert_allclose(n[1:-1, 1:-1], normals[1:-1, 1:-1], atol=atol, err_msg=name)


def random_depth(h=6, w=7, seed=0):
    g = torch.Generator().manual_seed(seed)
    return (1.0 + torch.rand(h, w, generator=g, dtype=torch.float64)).requires_grad_()


class TestGradients:
    """Issue 7, acceptance 2: gradcheck in float64 on small random depth for each method."""

    @pytest.mark.slow
    @pytest.mark.parametrize(
        "method,options",
        [v for name in TORCH_METHODS for v in variants(name)[:2]]
        + [
            ("d2nt_v2", {"dlf": "beta", "truncate": False}),
            ("d2nt_v3", {"dlf": "alpha"}),
            ("cp2tv", {"border": "reflect"}),
            ("3f2n_mean", {"border": "reflect"}),
            ("sne_roadseg", {"border": "reflect"}),
            ("sda_sne", {"base": "3f2n"}),
            ("sda_sne", {"iterations": None}),
            ("sda_sne", {"border": "reflect"}),
            ("plane_svd", {"window": 5}),
            ("plane_pca", {"window": 5}),
            ("vector_svd", {"window": 5}),
        ],
    )
    def test_gradcheck(self, method, options):
        z = random_depth()
        Kt = torch.tensor(K, dtype=torch.float64)
        mask = torch.ones(6, 7, dtype=torch.bool)
        mask[2, 3] = False  # a gap: one-sided differences and mirrored Laplacians around it
        # SDA-SNE's choices are piecewise constant in depth, and its energies come close to ties on random depth:
        # with border="reflect" a step of 1e-6 (gradcheck's default) flips one choice at pixel (0, 3) of this
        # input, where 1e-8 finds the analytical Jacobian to 6e-8
        eps = 1e-8 if method.startswith("sda_sne") else 1e-6
        assert torch.autograd.gradcheck(
            lambda d: st.estimate(d, Kt, method=method, mask=mask, **options), (z,), eps=eps
        )

    def test_truncated_softmin_passes_gradient_to_the_chosen_side_only(self):
        # a step: right of column 3 the depth jumps; the truncated softmin takes the left difference at (2, 3)
        z = torch.full((5, 8), 2.0, dtype=torch.float64)
        z[:, 4:] = 4.0  # smoothness 0 on the left of (2, 3), about 2 on the right: |s_2 - s_1| > 1
        z = z + 0.01 * torch.arange(8, dtype=torch.float64)  # a gentle slope, so the gradient is not zero
        z.requires_grad_()
        n = st.estimate(z, torch.tensor(K), method="d2nt_v2")
        (g,) = torch.autograd.grad(n[0, 0, 2, 3], z)
        assert g[2, 2] != 0 and g[2, 4] == 0

    def test_mnr_passes_gradient_through_the_selected_normal(self):
        z = random_depth(7, 7, seed=3).detach()
        z.requires_grad_()
        Kt = torch.tensor(K, dtype=torch.float64)
        raw = st.estimate(z, Kt, method="d2nt_v2")
        refined = st.estimate(z, Kt, method="d2nt_v2+mnr")
        # find a pixel whose refined normal came from a neighbour, and check the gradient equals that neighbour's
        for v in range(1, 6):
            for u in range(1, 6):
                if not torch.equal(refined[0, :, v, u], raw[0, :, v, u]):
                    for dv, du in ((0, -1), (0, 1), (-1, 0), (1, 0)):
                        if torch.equal(refined[0, :, v, u], raw[0, :, v + dv, u + du]):
                            (g_ref,) = torch.autograd.grad(refined[0, 2, v, u], z, retain_graph=True)
                            (g_raw,) = torch.autograd.grad(raw[0, 2, v + dv, u + du], z, retain_graph=True)
                            assert torch.equal(g_ref, g_raw)
                            return
        pytest.fail("MNR kept every normal of the random depth; pick another seed")

    @pytest.mark.parametrize("name", TORCH_METHODS)
    def test_invalid_pixels_get_zero_gradient(self, name):
        z = random_depth().detach()
        z[1, 1] = float("nan")
        z[4, 5] = 0.0
        z.requires_grad_()
        n = st.estimate(z, torch.tensor(K), method=name)
        n.sum().backward()
        assert torch.isfinite(z.grad).all() and z.grad[1, 1] == 0 and z.grad[4, 5] == 0
        assert (z.grad != 0).sum() > z.numel() // 2  # the valid pixels do get a gradient

    @pytest.mark.slow
    @pytest.mark.parametrize("name", TORCH_METHODS)
    def test_finite_gradient_on_a_real_frame(self, name):
        # a corner of a sample frame: silhouette (depth steps of x100), background, holes from the mask
        f = threef2n.read_frame(threef2n.sample_root(), "Medium/Trex/000001")
        z = torch.from_numpy(f.depth[120:160, 180:240].astype(np.float64)).requires_grad_()
        Kc = f.K.matrix.copy()
        Kc[0, 2] -= 180
        Kc[1, 2] -= 120
        n = st.estimate(z, Kc, method=name, mask=torch.from_numpy(f.mask[120:160, 180:240]))
        (n * torch.linspace(0.5, 1.5, n.numel(), dtype=n.dtype).view(n.shape)).sum().backward()
        assert torch.isfinite(z.grad).all()


class TestModule:
    @pytest.mark.parametrize(
        "method,options",
        [
            ("d2nt_v3", {}),
            ("d2nt_v2", {"dlf": "alpha", "fill": float("nan")}),
            ("3f2n_mean+mnr", {"border": "reflect"}),
        ],
    )
    def test_function_and_module_identical(self, method, options):
        z = random_depth(12, 15).detach()[None, None].float()
        mask = torch.rand(12, 15, generator=torch.Generator().manual_seed(1)) > 0.1
        layer = st.DepthToNormal(method=method, **options)
        torch.testing.assert_close(
            layer(z, K, mask=mask),
            st.estimate(z, K, method=method, mask=mask, **options),
            rtol=0,
            atol=0,
            equal_nan=True,
        )

    def test_module_only_stores_options(self):
        layer = st.DepthToNormal(method="d2nt_v2", tau=0.5)
        assert list(layer.parameters()) == [] and list(layer.buffers()) == []
        assert "method='d2nt_v2'" in repr(layer) and "tau=0.5" in repr(layer)

    def test_module_checks_options_when_built(self):
        with pytest.raises(InputError, match="tau: expected a positive finite number, got -1"):
            st.DepthToNormal(method="d2nt_v2", tau=-1)


class TestShapesDtypesDevices:
    def test_plain_image_gives_batch_of_one(self):
        n = st.estimate(torch.full((24, 32), 2.0), K, method="d2nt_basic")
        assert n.shape == (1, 3, 24, 32) and n.dtype == torch.float32
        torch.testing.assert_close(n[0, :, 5, 5], torch.tensor([0.0, 0.0, -1.0]))

    def test_batch_with_one_K_per_frame(self):
        root = threef2n.sample_root()
        names = threef2n.find_frames(root)[:2]
        _, depth, _, Ks = load(root, names)
        Ks[1, 0, 2] += 7.0  # a different principal point for the second frame
        both = st.estimate(torch.from_numpy(depth)[:, None], torch.from_numpy(Ks), method="d2nt_basic")
        for i in range(2):
            alone = st.estimate(torch.from_numpy(depth[i]), Ks[i], method="d2nt_basic")
            torch.testing.assert_close(both[i], alone[0], rtol=0, atol=0)

    def test_one_mask_for_the_whole_batch(self):
        z = torch.full((2, 1, 10, 12), 2.0)
        mask = torch.ones(10, 12, dtype=torch.bool)
        mask[:, :4] = False
        n = st.estimate(z, K, method="d2nt_v3", mask=mask)
        assert bool((n[:, :, :, :4] == 0).all()) and bool((n[:, 2, :, 4:] < 0).all())
        n2 = st.estimate(z, K, method="d2nt_v3", mask=mask.expand(2, 1, 10, 12))
        torch.testing.assert_close(n, n2, rtol=0, atol=0)

    @pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
    def test_low_precision_computed_in_float32(self, dtype):
        z = (2.0 + torch.rand(1, 1, 20, 24, generator=torch.Generator().manual_seed(2))).to(dtype)
        n = st.estimate(z, K, method="d2nt_v2")
        assert n.dtype == dtype
        ref = st.estimate(z.float(), K, method="d2nt_v2")
        torch.testing.assert_close(n.float(), ref.to(dtype).float(), rtol=0, atol=0)

    def test_float64_and_integer_depth(self):
        z = torch.full((1, 1, 10, 12), 2000, dtype=torch.int32)
        assert st.estimate(z, K, method="d2nt_basic").dtype == torch.float32
        n = st.estimate(z.double(), K, method="d2nt_basic")
        assert n.dtype == torch.float64
        torch.testing.assert_close(n[0, :, 5, 5], torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64))

    def test_fill_and_invalid_depth(self):
        z = torch.full((1, 1, 10, 12), 2.0)
        z[0, 0, 3, 3] = float("nan")
        z[0, 0, 5, 6] = 0.0
        z[0, 0, 7, 2] = -1.0
        z[0, 0, 8, 9] = float("inf")
        for name in TORCH_METHODS:
            n = st.estimate(z, K, method=name, fill=float("nan"))
            for v, u in ((3, 3), (5, 6), (7, 2), (8, 9)):
                assert bool(n[0, :, v, u].isnan().all()), name
            ok = ~n.isnan().any(1)
            torch.testing.assert_close(n.norm(dim=1)[ok], torch.ones(int(ok.sum())))

    def test_input_not_modified(self):
        z = random_depth().detach()
        before = z.clone()
        st.estimate(z, K, method="3f2n_median+mnr")
        assert torch.equal(z, before)

    def test_import_surfnorm_does_not_import_torch(self):
        code = "import sys, surfnorm; surfnorm.methods(); assert 'torch' not in sys.modules, 'torch imported'"
        subprocess.run([sys.executable, "-c", code], check=True)

    @CUDA
    @pytest.mark.parametrize("name", TORCH_METHODS)
    def test_cuda_matches_cpu_without_host_sync(self, name):
        root = threef2n.sample_root()
        _, depth, masks, Ks = load(root, threef2n.find_frames(root))
        z, m = torch.from_numpy(depth)[:, None], torch.from_numpy(masks)[:, None]
        cpu = st.estimate(z, torch.from_numpy(Ks), method=name, mask=m)
        zc, mc, Kc = z.cuda(), m.cuda(), torch.from_numpy(Ks).cuda()
        torch.cuda.synchronize()
        torch.cuda.set_sync_debug_mode("error")
        try:
            gpu = st.estimate(zc, Kc, method=name, mask=mc)
        finally:
            torch.cuda.set_sync_debug_mode("default")
        assert gpu.device.type == "cuda"
        torch.testing.assert_close(gpu.cpu(), cpu, rtol=0, atol=TOL)

    @CUDA
    @pytest.mark.parametrize("name", TORCH_METHODS)
    def test_cuda_gradient_matches_cpu(self, name):
        depth, mask = scene_with_holes(20, 24, seed=3)
        z = torch.from_numpy(depth.astype(np.float64)).requires_grad_()
        zc = z.detach().cuda().requires_grad_()
        m = torch.from_numpy(mask)
        weights = torch.linspace(0.5, 1.5, 3 * 20 * 24, dtype=torch.float64).view(1, 3, 20, 24)
        (st.estimate(z, K, method=name, mask=m) * weights).sum().backward()
        (st.estimate(zc, K, method=name, mask=m.cuda()) * weights.cuda()).sum().backward()
        torch.testing.assert_close(zc.grad.cpu(), z.grad, rtol=1e-6, atol=1e-8)

    @CUDA
    def test_cuda_batch_of_sixteen_every_method(self):
        # the benchmark's shape on the GPU: a batch of 16 at 480x640 gives the frames' CPU results
        root = threef2n.sample_root()
        _, depth, masks, Ks = load(root, threef2n.find_frames(root)[:1])
        z = torch.from_numpy(depth)[:, None].repeat(16, 1, 1, 1)
        for name in TORCH_METHODS:
            cpu = st.estimate(z[:1], Ks[0], method=name)
            gpu = st.estimate(z.cuda(), torch.from_numpy(Ks[0]).cuda(), method=name)
            torch.testing.assert_close(gpu.cpu(), cpu.expand(16, -1, -1, -1), rtol=0, atol=TOL, msg=name)


class TestCompile:
    @pytest.mark.slow
    @pytest.mark.parametrize("method", ["d2nt_v3", "3f2n_median+mnr"])
    def test_traces_as_one_graph(self, method):
        # fullgraph=True fails on any graph break, e.g. a Python branch on a tensor value or .item();
        # the aot_eager backend traces forward and backward without compiling C++ (seconds, not minutes)
        torch._dynamo.reset()
        fn = torch.compile(
            lambda z, k: st.estimate(z, k, method=method), fullgraph=True, dynamic=False, backend="aot_eager"
        )
        z = random_depth(8, 9).detach()[None, None].float().requires_grad_()
        Kt = torch.tensor(K, dtype=torch.float32)
        out = fn(z, Kt)
        torch.testing.assert_close(out, st.estimate(z, Kt, method=method), rtol=0, atol=1e-6)
        (g,) = torch.autograd.grad(out[..., 2:-2, 2:-2].sum(), z)
        (g_ref,) = torch.autograd.grad(st.estimate(z, Kt, method=method)[..., 2:-2, 2:-2].sum(), z)
        torch.testing.assert_close(g, g_ref, rtol=1e-5, atol=1e-6)

    @pytest.mark.slow
    @pytest.mark.filterwarnings("ignore:`torch.jit.script_method` is deprecated:DeprecationWarning")
    def test_inductor(self):
        # the default backend generates and compiles C++ on the CPU (needs a C compiler)
        torch._dynamo.reset()
        fn = torch.compile(lambda z, k: st.estimate(z, k, method="d2nt_basic"), fullgraph=True, dynamic=False)
        z = random_depth(8, 9).detach()[None, None].float()
        Kt = torch.tensor(K, dtype=torch.float32)
        torch.testing.assert_close(fn(z, Kt), st.estimate(z, Kt, method="d2nt_basic"), rtol=0, atol=1e-5)


class TestErrors:
    def test_method(self):
        with pytest.raises(
            InputError,
            match=r"method: expected one of d2nt_basic, .*angle_weighted, adaptive_fit, auto \(optionally followed by '\+mnr'\) in the torch backend, got 'plane_fit'",
        ):
            st.estimate(torch.ones(5, 5), K, method="plane_fit")
        with pytest.raises(InputError, match="method: expected a method name"):
            st.estimate(torch.ones(5, 5), K, method=3)

    def test_options(self):
        with pytest.raises(
            InputError,
            match=r"options of method 'd2nt_basic': expected some of border, fill, got unknown option\(s\) tau",
        ):
            st.estimate(torch.ones(5, 5), K, method="d2nt_basic", tau=1.0)
        with pytest.raises(InputError, match="dlf: expected one of"):
            st.estimate(torch.ones(5, 5), K, method="d2nt_v2", dlf="delta")

    def test_depth(self):
        with pytest.raises(
            InputError, match="depth: expected a tensor of shape \\(B, 1, H, W\\) or \\(H, W\\), got None"
        ):
            st.estimate(None, K)
        with pytest.raises(
            InputError,
            match=r"depth: expected a tensor of shape \(B, 1, H, W\) or \(H, W\), got a tensor of shape \(2, 5, 5\)",
        ):
            st.estimate(torch.ones(2, 5, 5), K)
        with pytest.raises(InputError, match=r"got a tensor of shape \(1, 2, 5, 5\)"):
            st.estimate(torch.ones(1, 2, 5, 5), K)
        with pytest.raises(InputError, match="depth: expected real-valued depth .* a boolean tensor is a mask"):
            st.estimate(torch.ones(5, 5, dtype=torch.bool), K)
        with pytest.raises(InputError, match="depth: expected real-valued depth"):
            st.estimate(torch.ones(5, 5, dtype=torch.complex64), K)
        with pytest.raises(InputError, match="depth: expected at least 3x3 pixels"):
            st.estimate(torch.ones(2, 5), K)
        with pytest.raises(InputError, match="depth: expected at least one frame in the batch"):
            st.estimate(torch.ones(0, 1, 5, 5), K)
        with pytest.raises(InputError, match="depth: expected a tensor of shape .* got object"):
            st.estimate(object(), K)

    def test_mask(self):
        with pytest.raises(
            InputError, match=r"mask: expected shape \(H, W\) = \(5, 6\) to match depth, got a tensor of shape \(6, 5\)"
        ):
            st.estimate(torch.ones(5, 6), K, mask=torch.ones(6, 5, dtype=torch.bool))
        with pytest.raises(InputError, match=r"mask: expected shape \(2, 1, 5, 6\) or \(5, 6\) to match depth"):
            st.estimate(torch.ones(2, 1, 5, 6), K, mask=torch.ones(3, 1, 5, 6, dtype=torch.bool))
        with pytest.raises(InputError, match="mask: expected a boolean tensor"):
            st.estimate(torch.ones(5, 6), K, mask=torch.ones(5, 6, dtype=torch.complex64))

    def test_K(self):
        with pytest.raises(
            InputError,
            match=r"K: expected shape \(3, 3\) or \(2, 3, 3\) for 2 frame\(s\), got a tensor of shape \(3, 3, 3\)",
        ):
            st.estimate(torch.ones(2, 1, 5, 5), torch.ones(3, 3, 3))
        with pytest.raises(InputError, match="K: expected positive focal lengths"):
            st.estimate(torch.ones(5, 5), [[-1.0, 0, 2], [0, 1, 2], [0, 0, 1]])
        with pytest.raises(InputError, match=r"K\[1\]: expected positive focal lengths"):
            st.estimate(torch.ones(2, 1, 5, 5), np.stack([K, -K]))
        with pytest.raises(InputError, match="K: expected a real"):
            st.estimate(torch.ones(5, 5), torch.ones(3, 3, dtype=torch.bool))


def test_adaptive_fit_refuses_a_fixed_window_wider_than_max_window_as_numpy_does():
    z = torch.rand(20, 30, dtype=torch.float32) + 1
    K = [[50.0, 0, 15], [0, 50.0, 10], [0, 0, 1]]
    with pytest.raises(InputError, match=r"window: expected at most max_window \(5\), got 9"):
        st.estimate(z, K, method="adaptive_fit", window=9, max_window=5)
