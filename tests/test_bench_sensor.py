"""surfnorm bench --sensor: the sensor benchmark on small folders built here, bad folders, and one real frame."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from surfnorm.bench import peers as peers_mod
from surfnorm.bench.peers import Peer
from surfnorm.bench.sensor import (
    find_sensor_frames,
    make_entries,
    read_sensor_frame,
    run_simulated,
    sensor_bench,
    sim_tables,
)
from surfnorm.cli import app
from surfnorm.errors import DataFileError, InputError
from surfnorm.io.threef2n import sample_root

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
SENSOR_SAMPLE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "sensor-sample"
H, W = 60, 80
FX = FY = 100.0
CX, CY = (W - 1) / 2, (H - 1) / 2


def has_rgbd_normals() -> bool:
    try:
        import cv2
    except ImportError:
        return False
    return hasattr(cv2, "RgbdNormals") and hasattr(cv2, "depthTo3d")


def plane_scene(step: float = 0.0):
    """A floor-like tilted plane (top half) and a wall facing the camera at an angle (bottom half), metres.

    Plane i: n_i . X = c_i, so depth z = c_i / (n_i . ray). Returns depth, unit normals (2, 3), masks (2, H, W).
    """
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    ray = np.stack([(u - CX) / FX, (v - CY) / FY, np.ones_like(u)], axis=-1)
    normals = np.array([[0.0, -0.6, -0.8], [0.3, 0.0, -np.sqrt(1 - 0.09)]])
    offsets = np.array([-1.6, -2.0])
    masks = np.zeros((2, H, W), bool)
    masks[0, : H // 2] = True
    masks[1, H // 2 :] = True
    z = np.zeros((H, W))
    for n, c, m in zip(normals, offsets, masks):
        z[m] = (c / (ray @ n))[m]
    if step:
        z = np.round(z / step) * step
    # the reference pixels: away from the border between the planes, as the sample's eroded pieces
    masks[0, H // 2 - 3 :] = False
    masks[1, : H // 2 + 3] = False
    return z.astype(np.float32), normals, masks


def write_frame(folder: Path, depth, *, planes=None, gt=None):
    folder.mkdir(parents=True)
    np.save(folder / "depth.npy", depth)
    (folder / "K.json").write_text(json.dumps({"fx": FX, "fy": FY, "cx": CX, "cy": CY}))
    if planes is not None:
        np.savez(folder / "planes.npz", normals=planes[0], masks=planes[1])
    if gt is not None:
        np.save(folder / "gt.npy", gt)


@pytest.fixture
def folder(tmp_path):
    """Three frames: exact planes, the same planes in 4 cm steps (about 2 pixel spacings), and a rendered-style frame with gt.npy."""
    root = tmp_path / "frames"
    z, n, m = plane_scene()
    write_frame(root / "a_exact", z, planes=(n, m))
    zq, _, _ = plane_scene(step=0.04)
    write_frame(root / "b_steps", zq, planes=(n, m))
    gt = np.zeros((H, W, 3), np.float32)
    gt[: H // 2] = n[0]
    gt[H // 2 :] = n[1]
    gt[H // 2 - 3 : H // 2 + 3] = 0  # no ground truth where a stencil would straddle both planes
    write_frame(root / "c_rendered", z, gt=gt)
    return root


class TestSensorBench:
    @pytest.mark.slow
    def test_report_table_json_and_figure(self, folder, tmp_path):
        names = ["d2nt_basic", "plane_pca:window=7"] + (["opencv_fals_w7"] if has_rgbd_normals() else [])
        result, paths = sensor_bench(folder, tmp_path / "R", names=names, repeats=2)
        assert result["frames"] == ["a_exact", "b_steps", "c_rendered"]
        assert result["errors"] == []
        recs = {(r["frame"], r["entry"]): r for r in result["records"]}
        assert len(recs) == 3 * len(names)
        for name in ["d2nt_basic", "plane_pca window=7"]:
            # exact planes: every method recovers the normals (away from the planes' border)
            assert recs[("a_exact", name)]["angle"] < 0.05
            assert recs[("a_exact", name)]["coverage"] == 1.0
            assert recs[("c_rendered", name)]["metric"] == "gt" and recs[("c_rendered", name)]["angle"] < 0.05
            assert recs[("b_steps", name)]["metric"] == "planes"
            assert recs[("b_steps", name)]["calls"] == 2 and recs[("b_steps", name)]["ms"] > 0
        # steps of 2 pixel spacings: a 3x3 stencil suffers, a 7x7 plane fit much less
        assert recs[("b_steps", "d2nt_basic")]["angle"] > 5.0
        assert recs[("b_steps", "plane_pca window=7")]["angle"] < recs[("b_steps", "d2nt_basic")]["angle"] / 2
        text = paths["report"].read_text()
        assert "| d2nt_basic | " in text and "| plane_pca window=7 | " in text and "c_rendered*" in text
        assert "## Coverage" in text
        doc = json.loads(paths["results"].read_text())
        assert doc["frames"] == result["frames"] and len(doc["records"]) == len(result["records"])
        assert doc["meta"]["threads"]["numba"] == "1"
        assert paths["figure"].read_bytes()[:8] == PNG_MAGIC
        assert not [p for p in (tmp_path / "R").iterdir() if p.name.startswith(".")]  # no temporary left
        # what the default ran on each frame and what it decided on, as surfnorm.auto_decision says
        for frame in result["frames"]:
            d = doc["decisions"][frame]
            row = f"| {frame} | {d['method']} | {d['weight']:.3f} | {d['reading']:.3f} |"
            assert row in text and f"| {d['upsampled']} | {d['correlation']:.2f} |" in text
            assert f"| {d['smooth_error']:.2f} | {d['white_noise']:.2f} |" in text

    @pytest.mark.slow
    def test_absent_peer_is_reported_and_a_failing_one_recorded(self, folder, tmp_path, monkeypatch):
        def missing():
            raise ImportError("No module named 'nolib'")

        def broken():
            def run(depth, cam, mask, clean=True):
                raise RuntimeError("boom")

            return run

        fake = (
            Peer("nolib_peer", "nolib", "a library that is not installed", missing),
            Peer("broken_peer", "opencv", "a peer that raises", broken),
        )
        monkeypatch.setattr(peers_mod, "SENSOR_PEERS", fake)
        result, paths = sensor_bench(
            folder / "a_exact", tmp_path / "R", names=["d2nt_basic", "nolib_peer", "broken_peer"], repeats=1
        )
        assert result["frames"] == ["a_exact"]  # a frame folder itself is a dataset of one frame
        assert "nolib_peer" in result["absent"] and "ImportError" in result["absent"]["nolib_peer"]
        assert result["errors"] == [{"frame": "a_exact", "entry": "broken_peer", "error": "RuntimeError: boom"}]
        text = paths["report"].read_text()
        assert "## Absent peers" in text and "- nolib_peer: ImportError" in text
        assert "- broken_peer on a_exact: RuntimeError: boom" in text
        assert "| broken_peer | failed |" in text

    def test_entries_run_on_one_thread_unless_they_say_threads(self, folder, monkeypatch):
        """Timing is one thread per library: surfnorm's entries pass threads=1 to estimate (its own default is
        every core), an entry may name threads=N or threads=all, and the default method also runs on every
        core where there are several."""
        from surfnorm import _api

        seen = []
        real = _api._workers
        monkeypatch.setattr(_api, "_workers", lambda threads: seen.append(threads) or real(threads))
        entries, _ = make_entries(["adaptive_fit", "adaptive_fit:threads=3", "auto:threads=all"])
        assert [e.label for e in entries] == [
            "adaptive_fit",
            "adaptive_fit threads=3",
            f"auto threads={os.cpu_count()}",
        ]
        frame = read_sensor_frame(folder / "b_steps")
        one, three, every = (e.normals(frame.depth, frame.K, frame.depth > 0) for e in entries)
        assert seen == [1, 3, os.cpu_count()]
        np.testing.assert_array_equal(one, three)  # row bands: the same bits
        with pytest.raises(InputError, match="threads=N"):
            make_entries(["auto:threads=0"])
        monkeypatch.setattr(os, "cpu_count", lambda: 4)
        labels = [e.label for e in make_entries(None, peer_libraries=[])[0]]
        assert labels.count("auto threads=4") == 1 and "auto" in labels
        monkeypatch.setattr(os, "cpu_count", lambda: 1)
        assert not [x for x in (e.label for e in make_entries(None, peer_libraries=[])[0]) if "threads" in x]

    @pytest.mark.slow
    def test_cli(self, folder, tmp_path):
        out = tmp_path / "R"
        res = CliRunner().invoke(
            app, ["bench", "--sensor", str(folder), "--out", str(out), "--methods", "d2nt_basic", "--repeats", "1"]
        )
        assert res.exit_code == 0, res.output
        assert "| d2nt_basic |" in res.output
        assert {p.name for p in out.iterdir()} == {"report.md", "results.json", "sensor.png", "uncertainty.png"}
        assert "## Uncertainty" in (out / "report.md").read_text()

    def test_cli_refuses_a_dataset_without_3f2n_frames(self, folder, tmp_path):
        empty = tmp_path / "empty"
        empty.mkdir()
        out = tmp_path / "R"
        res = CliRunner().invoke(
            app,
            [
                "bench",
                str(empty),
                "--sensor",
                str(folder),
                "--out",
                str(out),
                "--methods",
                "d2nt_basic",
                "--repeats",
                "1",
            ],
        )
        assert res.exit_code == 2
        assert res.output.count("\n") == 1
        assert (
            f"dataset: expected 3F2N frames (Easy|Medium|Hard/<object>/depth/*.bin) for the calibration of sigma, "
            f"found none under {empty} but Hard/room, Medium/chair"
        ) in " ".join(res.output.split())


class TestBadFolders:
    def test_no_frame(self, tmp_path):
        (tmp_path / "empty" / "sub").mkdir(parents=True)
        with pytest.raises(InputError, match="found none in"):
            find_sensor_frames(tmp_path / "empty")
        with pytest.raises(InputError, match="expected a folder"):
            find_sensor_frames(tmp_path / "nothing-here")

    def test_bad_files_name_the_file(self, tmp_path):
        z, n, m = plane_scene()
        write_frame(tmp_path / "f", z, planes=(n, m))
        (tmp_path / "f" / "planes.npz").write_bytes(b"not a zip")
        with pytest.raises(DataFileError, match=r"planes\.npz: cannot read"):
            read_sensor_frame(tmp_path / "f")
        np.savez(tmp_path / "f" / "planes.npz", normals=n)
        with pytest.raises(DataFileError, match=r"planes\.npz: expected arrays 'normals'"):
            read_sensor_frame(tmp_path / "f")
        np.savez(tmp_path / "f" / "planes.npz", normals=n, masks=m[:, :10])
        with pytest.raises(DataFileError, match=r"planes\.npz: expected normals \(P, 3\) and masks"):
            read_sensor_frame(tmp_path / "f")
        (tmp_path / "f" / "planes.npz").unlink()
        with pytest.raises(DataFileError, match="found neither"):
            read_sensor_frame(tmp_path / "f")
        np.save(tmp_path / "f" / "gt.npy", np.zeros((3, 3, 3)))
        with pytest.raises(DataFileError, match=r"gt\.npy: expected normals of shape"):
            read_sensor_frame(tmp_path / "f")
        (tmp_path / "f" / "depth.npy").write_bytes(b"garbage")
        with pytest.raises(DataFileError, match=r"depth\.npy: cannot read"):
            read_sensor_frame(tmp_path / "f")
        np.save(tmp_path / "f" / "depth.npy", np.zeros((4, 4), np.float32))
        with pytest.raises(DataFileError, match=r"depth\.npy: expected some valid"):
            read_sensor_frame(tmp_path / "f")
        np.save(tmp_path / "f" / "depth.npy", z)
        (tmp_path / "f" / "K.json").unlink()
        with pytest.raises(DataFileError, match=r"K\.json"):
            read_sensor_frame(tmp_path / "f")

    def test_cli_bad_folder_is_one_line_exit_2(self, tmp_path):
        (tmp_path / "empty").mkdir()
        res = CliRunner().invoke(app, ["bench", "--sensor", str(tmp_path / "empty"), "--out", str(tmp_path / "R")])
        assert res.exit_code == 2
        assert "found none in" in res.output and "Traceback" not in res.output

    def test_unknown_method_or_library(self):
        with pytest.raises(InputError, match="methods: expected registered methods"):
            make_entries(["no_such_method"])
        with pytest.raises(InputError, match="options of method 'plane_pca'"):
            make_entries(["plane_pca:windw=5"])
        with pytest.raises(InputError, match="peers: expected some of"):
            make_entries(None, peer_libraries=["nolib"])


def test_simulated_sensors_small():
    entries, _ = make_entries(["d2nt_basic"])
    result = run_simulated(sample_root(), entries, ["exact", "kinect_v1"], levels=["Easy"], seed=0)
    recs = {(r["sensor"], r["entry"]): r for r in result["records"]}
    exact, kinect = recs[("exact", "d2nt_basic")], recs[("kinect_v1", "d2nt_basic")]
    assert exact["depth_coverage"] == 1.0 and 0.9 < kinect["depth_coverage"] < 1.0
    # depth terraces several pixel spacings high ruin a 3x3 stencil; exact depth does not
    assert exact["e_a"] < 10.0 < kinect["e_a"]
    text = sim_tables(result)
    assert "| d2nt_basic | " in text and "### kinect_v1" in text
    with pytest.raises(InputError, match="sensors: expected some of"):
        run_simulated(sample_root(), entries, ["kinect_v9"])


@pytest.mark.slow
@pytest.mark.skipif(not (SENSOR_SAMPLE / "redwood_00000").is_dir(), reason="sensor sample not beside the repository")
def test_one_real_frame_matches_the_published_peer_score(tmp_path):
    names = ["d2nt_v3"] + (["opencv_fals_w7"] if has_rgbd_normals() else [])
    result, _ = sensor_bench(SENSOR_SAMPLE / "redwood_00000", tmp_path / "R", names=names, repeats=1)
    recs = {r["entry"]: r for r in result["records"]}
    # the sample README's figure for OpenCV FALS w7 (11.9), and the for the default d2nt_v3 (25.7)
    assert recs["d2nt_v3"]["angle"] == pytest.approx(25.7, abs=0.1)
    assert recs["d2nt_v3"]["coverage"] > 0.9
    if has_rgbd_normals():
        assert recs["opencv_fals_w7"]["angle"] == pytest.approx(11.9, abs=0.1)


def test_speed_vs_linemod_without_opencv_says_so_and_exits_2(monkeypatch, capsys):
    """benchmarks/speed_vs_linemod.py needs OpenCV's RgbdNormals: without it, one line naming it, and exit 2."""
    import importlib.util

    import surfnorm.bench.sensor as sensor

    path = Path(__file__).resolve().parent.parent / "benchmarks" / "speed_vs_linemod.py"
    spec = importlib.util.spec_from_file_location("speed_vs_linemod", path)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    monkeypatch.setattr(peers_mod, "single_thread", lambda: {})
    monkeypatch.setattr(sensor, "make_entries", lambda names: ([], {"opencv_linemod_w5": "cv2 has no RgbdNormals"}))
    assert script.main([]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert err.startswith("speed_vs_linemod: OpenCV's RgbdNormals is needed") and "cv2 has no RgbdNormals" in err


@pytest.mark.parametrize("variant", ["decimated", "binned"])
def test_decimated_fit_keeps_a_tilted_planes_normal_and_its_holes(variant):
    """benchmarks/decimated_fit.py: the default on a half-size frame (every other row and column, or 2x2 blocks of
    mean inverse depth, which is affine on a plane: the block's centre's), intrinsics halved, its normals repeated
    2x2, gives a plane's own normal at every pixel with depth (a principal point or a focal length left at the
    frame's would tilt it), and no normal where the frame has no depth."""
    from surfnorm.camera import Intrinsics

    run = getattr(_benchmark_script("decimated_fit"), variant)
    H, W = 61, 83  # odd sides: the repeat is cut back to the frame (binned: the last row and column get none)
    cam = Intrinsics(300.0, 310.0, 47.3, 25.8)
    n = np.array([0.3, -0.4, -1.0])
    n /= np.linalg.norm(n)
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    ray = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], axis=-1)
    z = (-2.0 / (ray @ n)).astype(np.float32)  # the plane n . P = -2 (in front of the camera, facing it)
    z[10:14, 20:30] = 0.0
    got = run(z, cam)
    assert got.shape == (H, W, 3)
    assert np.all(got[10:14, 20:30] == 0.0)
    has = z > 0
    if variant == "binned":
        assert np.all(got[-1] == 0.0) and np.all(got[:, -1] == 0.0)
        has[-1], has[:, -1] = False, False
    cos = got[has] @ n
    # float32 depth: up to 0.06 degrees; a principal point left at the frame's tilts every normal by 0.32-0.35 degrees
    # here, a focal length by 18 (a quarter-pixel error of the binned centre shows less than the rounding: not tested)
    assert np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).max() < 0.15


def test_integral_positions_order_columns_by_remainder():
    """The integral rows' columns ordered by their remainder modulo the stride: in order at stride 1, the even columns
    then the odd ones at stride 2, and a window edge one place further per fitted pixel at stride 4 (what the box sums
    of its rows read)."""
    from surfnorm.kernels._windows import integral_positions

    for W in (7, 8, 640, 641):
        for stride in (1, 2):
            by_remainder = np.concatenate([np.arange(k, W + 1, stride) for k in range(stride)])
            np.testing.assert_array_equal(integral_positions(W, stride), by_remainder.argsort(kind="stable"))
        np.testing.assert_array_equal(integral_positions(W, 1), np.arange(W + 1))
        pos = integral_positions(W, 4)
        assert sorted(pos) == list(range(W + 1))
        u = np.arange(W + 1 - 4)
        np.testing.assert_array_equal(pos[u + 4], pos[u] + 1)


@pytest.mark.parametrize("name", ["decimated_fit"])
def test_benchmark_script_refuses_an_unknown_sensor_in_one_line(name, monkeypatch, capsys):
    script = _benchmark_script(name)
    monkeypatch.setattr(peers_mod, "single_thread", lambda: {})
    monkeypatch.setattr(peers_mod, "steady_allocator", lambda: "unchanged")
    assert script.main(["--sensors", "kinect_v1,kinect_v9"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert err.startswith(f"{name}: --sensors: expected some of kinect_v1, ") and err.endswith("got kinect_v9")


def test_entries_parse_options_as_the_command_line_does():
    """The benchmark's ``name:opt=val`` is surfnorm.methods.parse_method, the parser of ``estimate -m``."""
    entries, _ = make_entries(["plane_pca:window=5:fill=nan"])
    assert entries[0].label == "plane_pca window=5 fill=nan"
    with pytest.raises(InputError, match=r"^method: expected NAME or NAME:option=value.*'plane_pca:window'"):
        make_entries(["plane_pca:window"])


def test_peers_on_one_thread_after_open3d_loaded_its_tbb():
    """Open3D loads a TBB older than Numba's threading layer accepts; limiting the peers to one thread must not
    turn Numba's warning about it into an error (the CLI treats an unexpected warning as a bug). In a fresh
    process: the layer starts once per process."""
    import subprocess
    import sys

    pytest.importorskip("open3d")
    code = "import open3d; from surfnorm.bench.peers import single_thread; print(single_thread()['numba'])"
    done = subprocess.run([sys.executable, "-W", "error", "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "1"


def test_timed_calls_keep_freed_memory_so_none_pays_for_fresh_pages():
    """After single_thread (every benchmark's setup), a large temporary allocated and freed again comes back
    without page faults; before it, glibc hands a block of that size from the system each time (so a peer that
    allocates its temporaries per call, OpenCV's LINEMOD, paid for them on some runs and not on others). In a fresh
    process, since the setting is the process's; Linux with glibc only (elsewhere the setting is not made)."""
    import subprocess
    import sys

    if not sys.platform.startswith("linux"):
        pytest.skip("glibc's mallopt: Linux only")
    code = """
import resource, sys, numpy as np
def faults():
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(5):
        a = np.empty(48 << 20, np.uint8); a.fill(1); del a  # 48 MiB: above glibc's largest own threshold
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
faults()
plain = faults()
from surfnorm.bench.peers import single_thread
setting = single_thread()["malloc"]
faults()
print(setting, plain, faults())
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    words = done.stdout.split()
    if words[0] == "unchanged":
        pytest.skip(f"the C library is not glibc: {done.stdout.strip()}")
    plain, steady = int(words[-2]), int(words[-1])
    assert plain >= 5 * (48 << 20) // (2 << 20), plain  # each fill faults its pages in (4 KiB or 2 MiB ones)
    assert steady < plain // 20, (plain, steady)


def test_alternating_medians_runs_each_call_once_a_round_in_turned_orders():
    from surfnorm.bench.sensor import alternating_medians

    order = []
    calls = {name: (lambda name=name: order.append(name)) for name in ("a", "b", "c")}
    ms = alternating_medians(calls, 3, warm_up=2)
    assert order == ["a", "a", "b", "b", "c", "c"] + ["a", "b", "c", "c", "b", "a", "a", "b", "c"]
    assert set(ms) == {"a", "b", "c"} and all(0.0 <= v < 1e3 for v in ms.values())


def test_linemod_entry_is_the_sensor_benchmarks_peer_or_one_line_naming_the_script(monkeypatch, capsys):
    from surfnorm.bench import sensor

    entries, absent = sensor.make_entries(["opencv_linemod_w5"])
    got = sensor.linemod_entry("some_script")
    if absent:
        assert got is None
    else:
        assert got is not None and got.label == entries[0].label == "opencv_linemod_w5"
    monkeypatch.setattr(sensor, "make_entries", lambda names: ([], {"opencv_linemod_w5": "No module named 'cv2'"}))
    capsys.readouterr()
    assert sensor.linemod_entry("some_script") is None
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "some_script: OpenCV's RgbdNormals is needed (pip install opencv-contrib-python-headless), "
        "got opencv_linemod_w5: No module named 'cv2'"
    ]


def _benchmark_script(name: str):
    """The module of ``benchmarks/<name>.py``."""
    import importlib.util

    path = Path(__file__).resolve().parent.parent / "benchmarks" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    return script


def test_sensor_folder_matchers_find_a_known_disparity():
    """benchmarks/sensor_folder.py's stereo matchers on a textured pair shifted by 12.25 pixels, with a textureless
    band across it: with either, most textured pixels away from the borders get that disparity within a quarter
    pixel, and the left border (no match in the right image) none. In the band SGBM carries the disparity across
    (its smoothness terms) and the block matcher gives none (``matcher`` reaches OpenCV)."""
    import cv2

    script = _benchmark_script("sensor_folder")
    rng = np.random.default_rng(3)
    H, W, d = 120, 200, 12.25
    texture = cv2.GaussianBlur(rng.integers(0, 256, (H, 2 * W)).astype(np.float32), (0, 0), 1.2)
    texture = (texture - texture.mean()) * 2.5 + 128.0
    texture[50:70] = 128.0
    u = np.arange(W) + 40.0
    left, right = (np.stack([np.interp(u + s, np.arange(2 * W), row) for row in texture]) for s in (0.0, d))
    pair = [np.repeat(np.clip(x, 0, 255).astype(np.uint8)[..., None], 3, axis=2) for x in (left, right)]
    maps = {m: script.stereo_disparity(pair[0], pair[1], largest=d, matcher=m) for m in ("sgbm", "bm")}
    textured = np.r_[15:40, 80:105]
    for disparity in maps.values():
        assert disparity.shape == (H, W)
        assert np.mean(np.abs(disparity[textured, 50:-15] - d) <= 0.25) > 0.9
        assert not (disparity[:, :8] > 0).any()
    band = np.s_[56:64, 50:-15]
    assert np.mean(np.abs(maps["sgbm"][band] - d) <= 0.25) > 0.9
    assert not (maps["bm"][band] > 0).any()


def test_sensor_folder_stereo_takes_a_pfm_ground_truth_and_doffs(tmp_path):
    """A Middlebury-style frame: a textured slanted plane seen by a pair whose principal points differ by doffs,
    its ground-truth disparity in a PFM file (inf where unknown, rows stored bottom up). The folder's depth is
    f B / (d + doffs) of the matcher's disparity, its ground truth's the same of the PFM's (inf: none), and its
    reference plane is the slanted plane."""
    pytest.importorskip("open3d")
    import cv2

    from tests.test_io_depth import pfm_bytes

    script = _benchmark_script("sensor_folder")
    rng = np.random.default_rng(5)
    H, W, fx, baseline, doffs = 160, 240, 400.0, 0.2, 20.0
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    depth = 1.0 / (0.55 + 0.0006 * (u - W / 2))  # a plane: inverse depth affine in the pixel, 1.4-2.3 m
    gt = fx * baseline / depth - doffs  # the disparity in the images, 15-37 px
    texture = cv2.GaussianBlur(rng.integers(0, 256, (H, 2 * W)).astype(np.float64), (0, 0), 1.2)
    texture = np.clip((texture - texture.mean()) * 2.5 + 128.0, 0, 255)
    left = texture[:, 40 : 40 + W]
    # the right image at x holds what the left one holds at the u with u - d(u) = x (d changes along the row)
    right = np.stack([np.interp(u[i], u[i] - gt[i], left[i]) for i in range(H)])
    for name, img in (("l.png", left), ("r.png", right)):
        cv2.imwrite(str(tmp_path / name), np.repeat(np.clip(img, 0, 255).astype(np.uint8)[..., None], 3, axis=2))
    stored = gt.astype(np.float32)
    stored[:, :12] = np.inf  # Middlebury's unknown
    (tmp_path / "gt.pfm").write_bytes(pfm_bytes(stored))
    out = tmp_path / "frame"
    argv = ["stereo", str(out), str(tmp_path / "l.png"), str(tmp_path / "r.png"), str(tmp_path / "gt.pfm")]
    argv += ["--fx", str(fx), "--baseline", str(baseline), "--doffs", str(doffs), "--source", "test"]
    assert script.main(argv) == 0
    gt_depth, got = np.load(out / "gt_depth.npy"), np.load(out / "depth.npy")
    np.testing.assert_allclose(gt_depth[:, 12:], depth[:, 12:], rtol=1e-5)
    assert not gt_depth[:, :12].any()
    inner = np.s_[10:-10, 60:-10]
    assert np.mean(np.abs(got[inner] / depth[inner] - 1.0) < 0.02) > 0.9  # depth, not f B / d (1.5-2.3x off)
    planes = np.load(out / "planes.npz")
    n = np.array([0.0006 * fx, 0.0, 0.55 - 0.0006 * (W / 2 - (W - 1) / 2)])  # eq. (2) at the image centre
    assert planes["masks"].shape[0] >= 1 and planes["masks"][0].sum() > 5000
    assert np.degrees(np.arccos(abs(planes["normals"][0] @ n) / np.linalg.norm(n))) < 1.0
    meta = json.loads((out / "meta.json").read_text())
    assert "f B / (d + 20)" in meta["depth"]
    # what made the depth, for a later matcher on the pair (sensor_variants.py's wls)
    assert meta["stereo"] == {
        "matcher": "sgbm",
        "block": 5,
        "largest": float(stored[:, 12:].max()),
        "baseline": 0.2,
        "doffs": 20.0,
    }


def test_sensor_folder_refuses_a_pfm_ground_truth_it_cannot_read(tmp_path, capsys):
    """A truncated PFM ground truth: one line naming the file and what is wrong, exit 2, nothing written."""
    script = _benchmark_script("sensor_folder")
    (tmp_path / "gt.pfm").write_bytes(b"Pf\n3 2\n-1.0\n" + bytes(10))
    out = tmp_path / "frame"
    argv = ["stereo", str(out), "l.png", "r.png", str(tmp_path / "gt.pfm"), "--fx", "450", "--baseline", "0.16"]
    assert script.main(argv + ["--source", "test"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"error: {tmp_path / 'gt.pfm'}: expected 24 bytes of pixels for 3 x 2, got 10 (truncated)"
    assert not out.exists()


def test_sensor_variants_fill_quantise_and_complete_a_plane_keeping_its_reference(tmp_path, capsys):
    """benchmarks/sensor_variants.py on two frames of one tilted plane: a dense one with a square hole and a sparse
    one (every fourth row, LiDAR-like). Filled, the hole lies within 1 % of the plane, the rest as it was; in 8 bits the depth takes at most 256 values, each within half a level of the true depth; each
    completion of the sparse frame gives dense depth on the plane, the nearest sample exactly a sample's depth.
    K.json and planes.npz are the source's; the variants that do not apply are said (wls: on a frame that is not an
    SGBM stereo folder); a variant it does not know, wls without OpenCV's contrib modules and a folder without frames,
    one line and exit 2."""
    import cv2

    script = _benchmark_script("sensor_variants")
    H, W, f = 120, 160, 300.0
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    plane = (1.0 / (0.5 + 0.0008 * (u - W / 2) + 0.0005 * (v - H / 2))).astype(np.float32)  # 1.6-2.4 m
    src = tmp_path / "src"
    dense, sparse = plane.copy(), np.zeros_like(plane)
    dense[40:60, 60:90] = 0.0
    sparse[::4] = plane[::4]
    for name, z in (("dense", dense), ("sparse", sparse)):
        (src / name).mkdir(parents=True)
        np.save(src / name / "depth.npy", z)
        (src / name / "K.json").write_text(json.dumps({"fx": f, "fy": f, "cx": (W - 1) / 2, "cy": (H - 1) / 2}))
        np.savez_compressed(src / name / "planes.npz", normals=np.array([[0.0, 0.0, -1.0]]), masks=z[None] > 0)
    out = tmp_path / "out"
    assert script.main([str(src), str(out)]) == 0
    said = capsys.readouterr().out
    assert "dense: completed_inpaint left out: not a sparse frame (97% valid)" in said
    assert "sparse: filled left out: not a dense frame with holes (25% valid)" in said
    made = sorted(p.name for p in out.iterdir())
    assert made == [
        "dense_8bit",
        "dense_filled",
        "sparse_8bit",
        "sparse_completed_inpaint",
        "sparse_completed_ipbasic",
        "sparse_completed_nearest",
    ]
    for name in made:
        source = src / name.split("_")[0]
        assert (out / name / "K.json").read_text() == (source / "K.json").read_text()
        assert (out / name / "planes.npz").read_bytes() == (source / "planes.npz").read_bytes()
        assert "sensor_variants.py" in json.loads((out / name / "meta.json").read_text())["variant"]
    filled = np.load(out / "dense_filled" / "depth.npy")
    assert (filled > 0).all()
    np.testing.assert_array_equal(filled[dense > 0], plane[dense > 0])
    np.testing.assert_allclose(filled[40:60, 60:90], plane[40:60, 60:90], rtol=1e-2)  # within 2.5 cm at 2 m
    levels = np.load(out / "dense_8bit" / "depth.npy")
    assert len(np.unique(levels[levels > 0])) <= 256 and not levels[40:60, 60:90].any()
    step = (plane.max() - plane.min()) / 255
    assert np.abs(levels - dense)[dense > 0].max() <= 0.5001 * step
    nearest = np.load(out / "sparse_completed_nearest" / "depth.npy")
    assert (nearest > 0).all() and np.isin(nearest, plane[::4]).all()
    for name in ("sparse_completed_inpaint", "sparse_completed_ipbasic"):
        z = np.load(out / name / "depth.npy")
        inner = np.s_[8:-8, 8:-8]
        assert (z[inner] > 0).all()
        assert np.median(np.abs(z[inner] / plane[inner] - 1.0)) < 0.01
    assert script.main([str(src), str(tmp_path / "x"), "--variants", "filled,blurred"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        "sensor_variants: --variants: expected some of filled, 8bit, completed_inpaint, completed_nearest, "
        "completed_ipbasic, wls, got 'blurred'"
    )
    if not hasattr(cv2, "ximgproc"):
        assert script.main([str(src), str(tmp_path / "x"), "--variants", "wls"]) == 2
        err = capsys.readouterr().err.strip()
        assert err == "sensor_variants: wls needs OpenCV's contrib modules (opencv-contrib-python-headless)"
    assert script.variant("wls", src / "dense", dense) == (
        "not an SGBM stereo frame of sensor_folder.py (raw_left.png, raw_right.png, meta.json's stereo)"
    )
    assert script.main([str(tmp_path / "none"), str(tmp_path / "x"), "--variants", "8bit"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("sensor_variants: sensor dataset: expected a folder of frame folders") and "\n" not in err
    assert err.endswith(f"got {tmp_path / 'none'}")
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize("block", ["4", "3", "0"])
def test_sensor_folder_refuses_a_block_the_matcher_cannot_take(block, tmp_path, capsys):
    """An even block, or one under 5 for the block matcher: one line naming --block, what it takes and what it got;
    exit 2, nothing written."""
    script = _benchmark_script("sensor_folder")
    out = tmp_path / "frame"
    argv = ["stereo", str(out), "l.png", "r.png", "gt.png", "--fx", "450", "--baseline", "0.16"]
    argv += ["--matcher", "bm", "--block", block, "--source", "test"]
    assert script.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert err == f"error: --block: expected an odd side of at least 5 for bm, got {block}"
    assert not out.exists()


def test_rooms_are_planes_seen_from_the_camera():
    """benchmarks/rooms.py's rooms: every pixel's point lies on the plane its normal names (n . P = -distance, for the
    floor, back wall or side wall), the normals face the camera, the floor and back wall are seen, and some of the
    surface at more than 75 degrees from the line of sight."""
    script = _benchmark_script("rooms")
    K = script.intrinsics()
    for pitch, height, turn, back, side in script.ROOMS:
        depth, normals, view = script.room(pitch, height, turn, back, side)
        assert (depth > 0).all()
        v, u = np.mgrid[0 : script.H, 0 : script.W]
        P = np.stack([(u - K[0, 2]) / K[0, 0] * depth, (v - K[1, 2]) / K[1, 1] * depth, depth], axis=-1)
        offset = -(P * normals).sum(-1)  # the plane's distance from the camera, for the plane of each pixel
        np.testing.assert_allclose(np.linalg.norm(normals, axis=-1), 1.0, rtol=1e-12)
        assert ((P * normals).sum(-1) < 0).all()  # facing the camera
        for distance in (height, back):  # the floor and the back wall are in every view (the side wall not always)
            assert np.isclose(offset, distance, rtol=1e-9).sum() > 1000
        assert (
            np.isclose(offset, height, rtol=1e-9).sum()
            + np.isclose(offset, back, rtol=1e-9).sum()
            + np.isclose(offset, side, rtol=1e-9).sum()
            == depth.size
        )
        assert view.max() > 75.0


def test_rooms_refuses_an_unknown_sensor(capsys):
    """One line naming --sensors, what it takes and what it got; exit 2."""
    script = _benchmark_script("rooms")
    assert script.main(["--sensors", "kinect_v1,sonar", "--methods", "auto"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert err.startswith("rooms: --sensors: expected some of kinect_v1, ") and err.endswith("got sonar")
    for steps, tail in (("1,x", "got x"), ("0", "got 0"), ("-2,1", "got -2")):
        assert script.main([f"--steps={steps}", "--methods", "auto"]) == 2
        err = capsys.readouterr().err.strip()
        assert err == f"rooms: --steps: expected millimetres above 0, {tail}", err
    for white, tail in (("0.01,x", "got x"), ("0", "got 0"), ("6", "got 6")):
        assert script.main([f"--white={white}", "--methods", "auto"]) == 2
        err = capsys.readouterr().err.strip()
        assert err == f"rooms: --white: expected percents above 0 and at most 5, {tail}", err
    assert script.main(["--steps", "1", "--white", "0.01", "--methods", "auto"]) == 2
    assert capsys.readouterr().err.strip() == "rooms: --steps, --white: expected one of them, got both"


@pytest.mark.parametrize(
    ("option", "value", "title"), [("--steps", "2", "2 mm"), ("--white", "0.01", "white noise 0.01 %")]
)
def test_rooms_quantised_or_with_small_white_noise(capsys, option, value, title):
    """--steps: the exact depth of the rooms in steps of Q millimetres; --white: with white noise of P percent of
    depth; one table per value. On planes stored in whole millimetres (its grid) or with white noise of 0.01 % (a
    floor of about 0.05 point spacings, under CLEAN_FLOOR) the default is adaptive_fit's, far below d2nt_v3's, which
    follows the steps or the noise."""
    script = _benchmark_script("rooms")
    assert script.main([option, value, "--methods", "auto,d2nt_v3,adaptive_fit"]) == 0
    out = capsys.readouterr().out
    assert f"### {title}: e_A" in out
    cells = [line.split("|") for line in out.splitlines()]
    rows = {
        c[1].strip(): float(c[-2]) for c in cells if len(c) > 8 and c[1].strip() in ("auto", "d2nt_v3", "adaptive_fit")
    }
    assert rows["auto"] <= 1.1 * rows["adaptive_fit"] + 0.05 and rows["d2nt_v3"] > 5 * rows["auto"], rows


def test_families_deliver_what_they_say():
    """benchmarks/families.py's families on a tilted plane: upsampling keeps the low sensor's depth at the pixels it
    was taken from (bilinearly: between them the depth is linear along a row; to the nearest pixel: constant over a
    cell; bicubically: another curve through them); the low sensor's intrinsics put those pixels' points where the
    frame's put them; the millimetre families
    are whole millimetres; the warp is a relative error of about 0.2 % RMS; invalid pixels stay invalid."""
    script = _benchmark_script("families")
    H, W, k = 96, 120, 3
    K = np.array([[100.0, 0.0, 59.5], [0.0, 100.0, 47.5], [0.0, 0.0, 1.0]])
    v, u = np.mgrid[0:H, 0:W]
    z = (2.0 / (1.0 + 0.002 * (u - 60) + 0.001 * (v - 48))).astype(np.float32)  # a plane
    valid = np.ones(z.shape, bool)
    valid[:5, :7] = False
    low = script.low_resolution(np.where(valid, z, 0.0), k, np.random.default_rng(0))
    assert low.shape == (H // k, W // k)
    for family in ("upsampled_linear", "upsampled_nearest", "upsampled_cubic"):
        got = script.degrade(family, k, z, valid, np.random.default_rng(0))
        assert got.dtype == np.float32 and (got[~valid] == 0).all()
        inner = got[k + k // 2 : -k : k, k + k // 2 : -k : k]  # away from the invalid corner and the borders
        np.testing.assert_allclose(inner, low[1:-1, 1:-1], rtol=1e-6)
    linear = script.degrade("upsampled_linear", k, z, valid, np.random.default_rng(0))
    row = linear[40, 10:100].astype(np.float64)
    second = row[:-2] - 2 * row[1:-1] + row[2:]
    assert (np.abs(second) < 1e-5).mean() > 0.6  # linear inside each cell; kinks where the cells meet
    nearest = script.degrade("upsampled_nearest", k, z, valid, np.random.default_rng(0))
    assert (nearest[30:33, 30:33] == nearest[31, 31]).all()  # one cell, one depth
    cubic = script.degrade("upsampled_cubic", k, z, valid, np.random.default_rng(0))
    assert not np.array_equal(cubic, linear)  # the same samples, another curve between them
    Kn = script.native_camera(K, k)
    i, j = 7, 11  # low pixel (row i, column j) is the frame's (i k + k // 2, j k + k // 2)
    np.testing.assert_allclose(
        [(j - Kn[0, 2]) / Kn[0, 0], (i - Kn[1, 2]) / Kn[1, 1]],
        [(j * k + k // 2 - K[0, 2]) / K[0, 0], (i * k + k // 2 - K[1, 2]) / K[1, 1]],
        rtol=1e-12,
    )
    # a factor halfway between whole ones: the pixel nearest each sample's centre, (i + 0.5) k - 0.5
    np.testing.assert_array_equal(script.sampled(10, 2.5), [1, 3, 6, 8])
    for n in (96, 120, 7):
        for whole in (2, 3, 4, 5):
            np.testing.assert_array_equal(script.sampled(n, whole), np.arange(n)[whole // 2 :: whole])
    half = script.low_resolution(np.where(valid, z, 0.0), 2.5, np.random.default_rng(0))
    assert half.shape == (38, 48)
    got = script.degrade("upsampled_linear", 2.5, z, valid, np.random.default_rng(0))
    assert got.shape == z.shape and (got[~valid] == 0).all()
    Kh = script.native_camera(K, 2.5)
    np.testing.assert_allclose((j - Kh[0, 2]) / Kh[0, 0], ((j + 0.5) * 2.5 - 0.5 - K[0, 2]) / K[0, 0], rtol=1e-12)
    assert script.parse_family("upsampled_cubic:7.5") == ("upsampled_cubic", 7.5)
    assert script.parse_family("upsampled_cubic:8") == ("upsampled_cubic", 8)
    for family in ("median_mm", "tof_mm"):
        got = script.degrade(family, 0, z, valid, np.random.default_rng(0)).astype(np.float64)
        mm = got[valid] * 1000.0
        np.testing.assert_allclose(mm, np.round(mm), atol=1e-3)
        assert (got[~valid] == 0).all()
    warp = script.degrade("smooth_warp", 0, z, valid, np.random.default_rng(0))
    relative = warp[valid] / z[valid] - 1.0
    assert 0.0015 < relative.std() < 0.0025


def _plane_beside_a_step(H, W, column):
    """A tilted plane, 1.5 times as deep from ``column`` on (a step of half the depth), float32, with a hole (no
    depth) in its top-left corner: (z, valid, v, u)."""
    v, u = np.mgrid[0:H, 0:W]
    plane = 2.0 / (1.0 + 0.002 * (u - 50) + 0.001 * (v - 40))
    valid = np.ones((H, W), bool)
    valid[:6, :8] = False
    z = np.where(valid, np.where(u < column, plane, 1.5 * plane), 0.0).astype(np.float32)
    return z, valid, v, u


def test_families_of_noise_filters_and_mixed_pixels():
    """The families after the sensor on a plane beside a step: white noise of the percent asked for; whole
    millimetres without noise; 1 % of outliers far beyond the noise; the bilateral filter keeps the step and
    removes most of the noise; mixed pixels lie between the two sides at the step and nowhere else; the blur moves
    the plane by nothing beyond rounding away from the step and never mixes an invalid pixel's 0 into a valid one."""
    script = _benchmark_script("families")
    H, W = 80, 100
    z, valid, v, u = _plane_beside_a_step(H, W, 50)
    rng = np.random.default_rng
    for percent in (0.01, 0.2):
        relative = script.degrade("white", percent, z, valid, rng(0))[valid] / z[valid] - 1.0
        assert 0.9 * percent < 100.0 * relative.std() < 1.1 * percent
        shared = script.degrade("correlated", percent, z, valid, rng(0)) / np.where(valid, z, 1.0) - 1.0
        assert 0.9 * percent < 100.0 * shared[valid].std() < 1.1 * percent
        # smoothed over about a pixel: neighbours' errors go together (a Gaussian of 1 pixel: correlation exp(-1/4))
        along = np.corrcoef(shared[10:, 10:-1].ravel(), shared[10:, 11:].ravel())[0, 1]
        assert 0.7 < along < 0.85, along
    mm = script.degrade("mm", 0, z, valid, rng(0)).astype(np.float64)
    np.testing.assert_allclose(mm[valid] * 1000.0, np.round(z[valid] * 1000.0), atol=2e-3)
    relative = np.abs(script.degrade("outliers", 0, z, valid, rng(0))[valid] / z[valid] - 1.0)
    assert 0.005 < (relative > 0.02).mean() < 0.015 and relative.max() < 0.2 + 1e-6
    away = valid & (np.abs(u - 50) > 4) & (v > 8) & (v < H - 4) & (u > 10) & (u < W - 4)
    filtered = script.degrade("bilateral", 0, z, valid, rng(0))
    assert (np.abs(filtered[away] / z[away] - 1.0)).std() < 0.5 * 0.004
    assert (filtered[40, 46] < 1.05 * z[40, 46]) and (filtered[40, 54] > 0.95 * z[40, 54])  # the step kept
    flying = script.degrade("flying", 0, z, valid, rng(0))
    mixed = valid & (np.abs(flying / np.where(valid, z, 1.0) - 1.0) > 0.02)
    assert (flying[~valid] == 0).all() and mixed.any() and (np.abs(u[mixed] - 50) <= 1).all()
    assert (flying[mixed] > z[:, 49].min() * 0.99).all() and (flying[mixed] < z[:, 50].max() * 1.01).all()
    blurred = script.degrade("blurred", 0, z, valid, rng(0))
    far = away & (np.abs(u - 50) > 7)  # beyond the Gaussian's reach of the step
    np.testing.assert_allclose(blurred[far], z[far], rtol=1e-4)
    assert (blurred[~valid] == 0).all() and blurred[6, 0] > 0.99 * z[6, 0]  # next to the hole: not pulled to 0
    assert script.parse_family("blurred") == ("blurred", 0) and script.parse_family("blurred:0.7") == ("blurred", 0.7)
    np.testing.assert_array_equal(script.degrade("blurred", 1.5, z, valid, rng(0)), blurred)  # 1.5 px by default
    assert script.parse_family("mm") == ("mm", 0) and script.parse_family("mm:2") == ("mm", 2.0)
    whole = script.degrade("mm", 0, z, valid, rng(0))
    np.testing.assert_array_equal(script.degrade("mm", 1.0, z, valid, rng(0)), whole)  # 1 mm by default
    steps = script.degrade("mm", 4.0, z, valid, rng(0)).astype(np.float64)
    assert (steps[~valid] == 0).all() and np.abs(steps[valid] - z[valid]).max() <= 0.002 + 1e-6
    np.testing.assert_allclose(steps[valid] / 0.004, np.round(steps[valid] / 0.004), atol=1e-3)  # on the 4 mm grid
    assert script.parse_family("dropped:20") == ("dropped", 20.0)
    dropped = script.degrade("dropped", 20.0, z, valid, rng(0))
    kept = valid & (dropped > 0)
    assert (dropped[~valid] == 0).all() and 0.17 < 1.0 - kept.sum() / valid.sum() < 0.23
    assert 0.004 < 100.0 * (dropped[kept] / z[kept] - 1.0).std() < 0.006  # white noise of 0.005 %
    wider = script.degrade("blurred", 3.0, z, valid, rng(0))  # reaches further from the step
    near = valid & (np.abs(u - 50) == 6) & (v > 8) & (v < H - 4)
    assert (np.abs(wider[near] / z[near] - 1.0) > np.abs(blurred[near] / z[near] - 1.0) + 1e-3).all()


def test_families_written_later_deliver_what_they_say():
    """The seven families written later, on a plane beside a step: half floats are float16's values; the disparity
    families lie on their disparity grid (1/16 px then whole millimetres, 1/8 px) within the noise asked for, and the
    structured light's error is shared by neighbours (terraces); the block offsets are constant over each 7x7 block;
    5 % dropped with 0.2 % noise; the bilateral filter smooths and keeps the step; mixed pixels at the step only, in
    whole millimetres; invalid pixels stay invalid."""
    script = _benchmark_script("families")
    H, W, f = 84, 105, 100.0
    z, valid, v, u = _plane_beside_a_step(H, W, 49)
    away = valid & (np.abs(u - 49) > 4) & (v > 8) & (v < H - 4) & (u > 10) & (u < W - 4)

    def got(family):
        out = script.degrade(family, 0, z, valid, np.random.default_rng(0), f)
        assert out.dtype == np.float32 and (out[~valid] == 0).all(), family
        return out.astype(np.float64)

    np.testing.assert_array_equal(got("float16"), z.astype(np.float16).astype(np.float64))
    stereo = got("disparity16_mm")
    np.testing.assert_allclose(stereo[valid] * 1000.0, np.round(stereo[valid] * 1000.0), atol=1e-3)
    moved = f * 0.05 / stereo[valid] - f * 0.05 / z[valid]  # pixels of disparity
    assert 0.04 < moved.std() < 0.07 and np.abs(moved).max() < 0.35  # 0.05 px of noise and 1/16 px steps
    light = got("structured_light")
    disparity = f * 0.075 / light[valid]
    np.testing.assert_allclose(disparity * 8.0, np.round(disparity * 8.0), atol=1e-3)  # on the 1/8 px grid
    assert 0.02 < (disparity - f * 0.075 / z[valid]).std() < 0.08
    # a tilted plane (its disparity changes by about 0.0075 px a column): terraces several pixels wide
    same = (light[:, 1:] == light[:, :-1])[(away & (u < 45))[:, 1:]]
    assert same.mean() > 0.6
    relative = got("blocks") / np.where(valid, z, 1.0) - 1.0
    block = relative[14:21, 14:21]  # one whole 7x7 block, away from the step and the hole
    assert np.ptp(block) < 1e-6 and 0.002 < relative[away].std() < 0.004
    noisy = got("dropped_noisy")
    kept = valid & (noisy > 0)
    assert 0.03 < 1.0 - kept.sum() / valid.sum() < 0.07
    assert 0.0018 < (noisy[kept] / z[kept] - 1.0).std() < 0.0022
    filtered = got("bilateral_mm")
    assert (filtered[away] / z[away] - 1.0).std() < 0.5 * 0.002
    assert filtered[40, 45] < 1.05 * z[40, 45] and filtered[40, 53] > 0.95 * z[40, 53]  # the step kept
    flying = got("tof_flying_mm")
    np.testing.assert_allclose(flying[valid] * 1000.0, np.round(flying[valid] * 1000.0), atol=1e-3)
    mixed = valid & (np.abs(flying / np.where(valid, z, 1.0) - 1.0) > 0.02)
    assert mixed.any() and (np.abs(u[mixed] - 49) <= 1).all()
    for family in script.FAMILIES[script.FAMILIES.index("float16") : script.FAMILIES.index("scan_inpaint")]:
        assert script.parse_family(family) == (family, 0)


def test_families_of_completed_scanlines():
    """The two completion families on a plane beside a step: the samples (surfnorm.bench.processing.scanlines) lie on
    every 4th row only, about half of each row's valid pixels, within the noise asked for of the depth; inpainted,
    every valid pixel gets depth, within 0.4 % of the plane in the median away from the step (2 % at most); by Ku
    et al.'s recipe too, with each side of the
    step kept (dilation of inverse depth keeps the nearer side up to the step); invalid pixels stay invalid."""
    from surfnorm.bench.processing import scanlines

    script = _benchmark_script("families")
    H, W = 84, 105
    z, valid, v, u = _plane_beside_a_step(H, W, 49)
    samples = scanlines(z, valid, np.random.default_rng(0), every=4, noise=0.01)
    rows = np.flatnonzero((samples > 0).any(axis=1))
    assert np.ptp(rows % 4) == 0 and rows.size == H // 4
    kept = samples > 0
    assert 0.4 < kept[rows].mean() < 0.6 and not (kept & ~valid).any()
    assert 0.008 < (samples[kept] / z[kept] - 1.0).std() < 0.012
    away = valid & (np.abs(u - 49) > 6) & (v > 10) & (v < H - 6) & (u > 12) & (u < W - 6)
    for family in ("scan_inpaint", "scan_ipbasic"):
        assert script.parse_family(family) == (family, 0)
        out = script.degrade(family, 0, z, valid, np.random.default_rng(0))
        assert out.dtype == np.float32 and (out[~valid] == 0).all() and (out[valid] > 0).all(), family
        # on the plane away from the step, within about 1 cm at 2 m (the filling's error: the samples' is 0.02 %)
        assert np.median(np.abs(out[away] / z[away] - 1.0)) < 0.004, family
        assert np.abs(out[away] / z[away] - 1.0).max() < 0.02, family
    ipbasic = script.degrade("scan_ipbasic", 0, z, valid, np.random.default_rng(0))
    assert ipbasic[40, 45] < 1.05 * z[40, 45] and ipbasic[40, 53] > 0.95 * z[40, 53]


@pytest.mark.slow
def test_stereo_matchers_table(capsys):
    """benchmarks/stereo_matchers.py on one frame: a row per matcher, the default's ratio to the better estimator
    computed from the row's own cells; a bad matcher is one line naming --matchers, exit 2."""
    script = _benchmark_script("stereo_matchers")
    assert script.main(["--matchers", "sgbm:9,bm:9", "--methods", "auto,adaptive_fit,d2nt_v3", "--frames", "1"]) == 0
    rows = [
        line.split("|")[1:-1]
        for line in capsys.readouterr().out.splitlines()
        if line.startswith("| sgbm") or line.startswith("| bm")
    ]
    assert [r[0].strip() for r in rows] == ["sgbm:9", "bm:9"]
    for r in rows:
        auto, fit, d2nt = (float(c) for c in r[1:4])
        assert float(r[4]) == pytest.approx(auto / min(fit, d2nt), abs=2e-3) and r[5].strip() == "-"
    for arg in ("sgbm:4", "bm:3", "census:5", "sgbm:x", "sgbm:23"):
        assert script.main(["--matchers", arg]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "--matchers" in err and repr(arg) in err, err


def test_families_refuses_an_unknown_family_or_factor(capsys):
    """One line naming --families, what it takes and what it got; exit 2."""
    script = _benchmark_script("families")
    for arg, tail in (
        ("median_mm,sonar", "got 'sonar'"),
        ("upsampled_linear:1", "with K from 2 to 16, whole or halfway (7.5), got 'upsampled_linear:1'"),
        ("upsampled_linear:7.3", "with K from 2 to 16, whole or halfway (7.5), got 'upsampled_linear:7.3'"),
        ("upsampled_cubic:x", "with K from 2 to 16, whole or halfway (7.5), got 'upsampled_cubic:x'"),
        ("tof_mm:2", "tof_mm takes no factor, got 'tof_mm:2'"),
        ("white:0", "with P a percent above 0 and at most 5, got 'white:0'"),
        ("white:x", "with P a percent above 0 and at most 5, got 'white:x'"),
        ("white", "with P a percent above 0 and at most 5, got 'white'"),
        ("correlated:9", "expected correlated:P with P a percent above 0 and at most 5, got 'correlated:9'"),
        ("blurred:0", "expected blurred:S with S pixels above 0 and at most 10, got 'blurred:0'"),
        ("mm:0", "expected mm:Q with Q millimetres above 0 and at most 20, got 'mm:0'"),
        ("mm:x", "expected mm:Q with Q millimetres above 0 and at most 20, got 'mm:x'"),
        ("dropped", "expected dropped:H with H a percent above 0 and at most 90, got 'dropped'"),
        ("dropped:95", "expected dropped:H with H a percent above 0 and at most 90, got 'dropped:95'"),
    ):
        assert script.main(["--families", arg, "--methods", "auto"]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and err.startswith("families: --families: ") and err.endswith(tail), err


def test_resized_frames_enlarge_a_frame_with_its_reference_and_intrinsics(tmp_path, capsys):
    """resized_frames.py --enlarge: a frame resized K times larger (7.5: a phone's depth at its colour's size), its
    pixel i at (i + 0.5) K - 0.5 of the larger frame along the same ray, its planes' masks resized with it: the
    default's normals of an enlarged plane scene still lie on its planes. Frames too large are left out."""
    import surfnorm
    from surfnorm.bench.sensor import read_sensor_frame, score_frame

    script = _benchmark_script("resized_frames")
    z, n, m = plane_scene()
    write_frame(tmp_path / "frames" / "a", z, planes=(n, m))
    f = read_sensor_frame(tmp_path / "frames" / "a")
    big = script.enlarged(f, 2.5)
    assert big.depth.shape == (150, 200) and big.planes[1].shape == (2, 150, 200) and big.depth.dtype == np.float32
    for j in (0, 13, 79):
        assert ((j + 0.5) * 2.5 - 0.5 - big.K.cx) / big.K.fx == pytest.approx((j - f.K.cx) / f.K.fx, abs=1e-12)
    assert m.sum(axis=(1, 2)) * 6.25 == pytest.approx(big.planes[1].sum(axis=(1, 2)), rel=0.05)
    assert score_frame(surfnorm.estimate(big.depth, big.K), big)[1] < 1.0
    assert script.main([str(tmp_path / "frames"), "--enlarge", "--factors", "2.5,4", "--methods", "auto"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert sum(line.startswith("| 2.5 | a |") or line.startswith("| 4 | a |") for line in out) == 2, out
    script.ENLARGED_MAX = 1000  # 80 pixels x 16
    assert script.main([str(tmp_path / "frames"), "--enlarge", "--factors", "16", "--methods", "auto"]) == 2
    captured = capsys.readouterr()
    assert "(left out: a: over 1000 pixels along a side when enlarged)" in captured.out
    want = f"resized_frames: {tmp_path / 'frames'}: no frame to resize (dense, and small enough)"
    assert captured.err.strip() == want and captured.err.count("\n") == 1


def test_resized_frames_resize_and_score_every_factor(tmp_path, capsys):
    """benchmarks/resized_frames.py: a frame's depth every K-th pixel, resized back (exact on a plane's rows where
    depth is linear), no depth where a low pixel had none; one table row per frame and factor; bad factors: exit 2."""
    script = _benchmark_script("resized_frames")
    z, n, m = plane_scene()
    z[10:14, 20:30] = 0.0
    up = script.resized(z, 4)
    assert up.shape == z.shape and up.dtype == np.float32
    assert np.all(up[10:14, 20:30] == 0.0) and np.mean(up > 0) > 0.9
    np.testing.assert_array_equal(up[z == 0], 0.0)
    write_frame(tmp_path / "frames" / "a", z, planes=(n, m))
    assert script.main([str(tmp_path / "frames"), "--factors", "4,8", "--methods", "auto,d2nt_v3"]) == 0
    rows = [
        line for line in capsys.readouterr().out.splitlines() if line.startswith("| 4 |") or line.startswith("| 8 |")
    ]
    assert len(rows) == 4 and all(len(r.split("|")) == 7 for r in rows), rows
    cubic = script.resized(z, 4, "cubic")  # bicubic: another resize, the same holes
    assert cubic.dtype == np.float32 and np.array_equal(cubic > 0, up > 0) and not np.array_equal(cubic, up)
    asked = []
    resized = script.resized
    script.resized = lambda depth, k, interpolation: asked.append(interpolation) or resized(depth, k, interpolation)
    try:
        args = [str(tmp_path / "frames"), "--factors", "8", "--interpolation", "cubic", "--methods", "auto"]
        assert script.main(args) == 0
    finally:
        script.resized = resized
    assert asked == ["cubic"]
    assert sum(line.startswith("| 8 |") for line in capsys.readouterr().out.splitlines()) == 2
    assert script.main([str(tmp_path / "frames"), "--interpolation", "area"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "resized_frames: --interpolation: expected linear or cubic, got 'area'", err
    for bad in ("1", "4,x", "", "17", "7.3"):
        assert script.main([str(tmp_path / "frames"), "--factors", bad]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("resized_frames: --factors: expected numbers from 2 to 16, whole or halfway (7.5)")
        assert err.count("\n") == 0 and err.endswith(f"got {bad!r}")
    assert script.parse_factors("4,7.5,8") == [4, 7.5, 8]
    np.testing.assert_array_equal(script._sampled(10, 2.5), [1, 3, 6, 8])
    np.testing.assert_array_equal(script._sampled(97, 4), np.arange(97)[2::4])


def test_benchmark_scripts_read_the_checkouts_frames_and_refuse_in_one_line(tmp_path, capsys):
    """surfnorm.bench.scripts: the 3F2N root a script reads (given; the checkout's 12 sample frames; else the
    package's), and its own list with its methods, refused in one line naming the script."""
    from surfnorm.bench.scripts import script_entries, threef2n_root
    from surfnorm.errors import InputError
    from surfnorm.io.threef2n import sample_root

    repo = Path(__file__).resolve().parent.parent
    assert threef2n_root(str(tmp_path), repo) == tmp_path
    assert threef2n_root(None, repo) == repo / "tests" / "data" / "3f2n-sample"
    assert threef2n_root(None, tmp_path) == Path(sample_root())  # a folder without tests/data: the package's frames
    parsed, entries = script_entries("demo_script", "auto,d2nt_v3", lambda: [1, 2])
    assert parsed == [1, 2] and [e.label for e in entries] == ["auto", "d2nt_v3"]
    assert script_entries("demo_script", "no_such_method", lambda: [1]) is None
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("demo_script: methods: expected registered methods"), err

    def refused():
        raise InputError("--things: expected a thing, got 'x'")

    assert script_entries("demo_script", "auto", refused) is None
    assert capsys.readouterr().err.strip() == "demo_script: --things: expected a thing, got 'x'"
