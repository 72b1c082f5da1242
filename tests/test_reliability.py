"""Issue 27 (reliability II): never replace an input, every magnitude, caches that load, hostile files and folders."""

import numpy as np
import pytest
from typer.testing import CliRunner

from surfnorm.cli import app

runner = CliRunner()
CAMERA = ["--fx", "525", "--fy", "525", "--cx", "31.5", "--cy", "23.5"]


def _plane(h=48, w=64):
    v, u = np.mgrid[0:h, 0:w]
    return 1.0 + 0.002 * u + 0.001 * v


def _one_line_exit_2(args, needle=""):
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 2, (args, result.output)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), (args, result.stderr)
    assert needle in lines[0], (args, lines[0])
    return lines[0]


# ---------------------------------------------------------------------------- row 1: never replace an input


@pytest.fixture
def frames(tmp_path, monkeypatch):
    import cv2

    z = np.rint(_plane() * 1000).astype(np.uint16)
    cv2.imwrite(str(tmp_path / "frame.png"), z)
    np.save(tmp_path / "d.npy", _plane().astype(np.float32))
    cv2.imwrite(str(tmp_path / "m.png"), np.full(z.shape, 255, np.uint8))
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.mark.parametrize(
    "args",
    [
        ["frame.png", "frame", "--depth-scale", "1000"],  # frame.png: the png8 picture's name
        ["frame.png", "frame", "--depth-scale", "1000", "--overwrite"],  # --overwrite never replaces an input
        ["d.npy", "d"],  # d.npy: the float32 normals' name
        ["d.npy", "d", "--overwrite", "-f", "npy"],
        ["d.npy", "m", "--mask", "m.png", "--overwrite"],  # the mask is read too
    ],
)
def test_estimate_never_replaces_a_file_it_reads(frames, args):
    before = {p.name: p.read_bytes() for p in frames.iterdir()}
    line = _one_line_exit_2(["estimate", *args, *CAMERA], "output:")
    assert "reads" in line
    assert {p.name: p.read_bytes() for p in frames.iterdir()} == before  # nothing written, nothing replaced


def test_estimate_refuses_an_existing_output_unless_overwrite(frames):
    (frames / "out.png").write_bytes(b"precious")
    line = _one_line_exit_2(["estimate", "d.npy", "out", *CAMERA], "out.png exists")
    assert "--overwrite" in line
    assert (frames / "out.png").read_bytes() == b"precious" and not (frames / "out.npy").exists()
    result = runner.invoke(app, ["estimate", "d.npy", "out", *CAMERA, "--overwrite"])
    assert result.exit_code == 0, result.output
    assert (frames / "out.png").read_bytes() != b"precious" and np.load(frames / "out.npy").shape == (48, 64, 3)


def test_estimate_refuses_an_output_that_links_to_its_input(frames):
    (frames / "link.npy").symlink_to(frames / "d.npy")
    before = (frames / "d.npy").read_bytes()
    _one_line_exit_2(["estimate", "d.npy", "link", "-f", "npy", "--overwrite", *CAMERA], "reads")
    assert (frames / "d.npy").read_bytes() == before


# ---------------------------------------------------------------------------- row 2: depth of any magnitude

K = [[525.0, 0, 31.5], [0, 525.0, 23.5], [0, 0, 1]]
MAGNITUDES = [2.0**-200, 1e-60, 1e-43, 1e-39, 1e39, 1e60, 2.0**200]


def _surface():
    v, u = np.mgrid[0:48, 0:64]
    return 1.0 + 0.002 * u + 0.001 * v + 0.0003 * np.sin(u / 3.0) * np.cos(v / 4.0)


def _method_names():
    import surfnorm

    return list(surfnorm.methods())


@pytest.mark.parametrize("mode", ["faithful", "scale_invariant", "disparity"])
@pytest.mark.parametrize("method", _method_names())
def test_float64_depth_of_any_magnitude_gives_what_it_gives_at_one(method, mode):
    import surfnorm

    kw = {"scale_invariant": True} if mode == "scale_invariant" else {"disparity": True} if mode == "disparity" else {}
    depth = 1.0 / _surface() if mode == "disparity" else _surface()
    ref = surfnorm.estimate(depth, K, method=method, **kw)
    assert not (ref == 0).all(axis=-1).any()
    for s in MAGNITUDES:
        n = surfnorm.estimate(depth * s, K, method=method, **kw)
        filled = (n == 0).all(axis=-1)
        assert not filled.any(), (s, filled.mean())  # never silent fill
        assert np.abs(n - ref).mean() < 2e-3, (s, np.abs(n - ref).max())


@pytest.mark.parametrize("method", _method_names())
def test_both_backends_agree_at_any_magnitude(method):
    torch = pytest.importorskip("torch")
    import surfnorm
    import surfnorm.torch as st

    for s in (1.0, 1e-60, 1e-39, 1e39, 1e60):
        depth = _surface() * s
        n = surfnorm.estimate(depth, K, method=method)
        t = st.estimate(torch.tensor(depth), torch.tensor(K), method=method)[0].permute(1, 2, 0).numpy()
        assert not (t == 0).all(axis=-1).any(), s
        assert np.abs(n - t).mean() < 2e-3, (s, np.abs(n - t).max())
