"""Method options everywhere: ``-m NAME:opt=val`` in estimate and convert, ``surfnorm methods NAME``, the registry's text."""

import warnings

import numpy as np
import pytest
from typer.testing import CliRunner

import surfnorm
from surfnorm import IntrinsicsWarning
from surfnorm.cli import app
from surfnorm.io import read_depth, read_intrinsics, write_sample
from surfnorm.methods import _REGISTRY, options_of, parse_method

runner = CliRunner()


@pytest.fixture(scope="module")
def frame(tmp_path_factory):
    folder = tmp_path_factory.mktemp("frame")
    png, js = write_sample("3f2n-easy", folder / "frame.png", depth_scale=1000)
    return png, js


def test_estimate_takes_method_options_as_the_library_does(frame, tmp_path):
    png, js = frame
    result = runner.invoke(
        app,
        [
            "estimate",
            str(png),
            str(tmp_path / "out"),
            "-m",
            "plane_pca:window=5",
            "-k",
            str(js),
            "--depth-scale",
            "1000",
        ],
    )
    assert result.exit_code == 0, result.output
    expected = surfnorm.estimate(read_depth(png, depth_scale=1000), read_intrinsics(js), method="plane_pca", window=5)
    np.testing.assert_array_equal(np.load(tmp_path / "out.npy"), expected)
    default = surfnorm.estimate(read_depth(png, depth_scale=1000), read_intrinsics(js), method="plane_pca")
    assert not np.array_equal(expected, default)  # the option took effect


def test_convert_takes_method_options(frame, tmp_path):
    png, js = frame
    result = runner.invoke(
        app,
        [
            "convert",
            str(png),
            str(tmp_path / "n"),
            "-m",
            "d2nt_v2:dlf=beta,tau=0.5",
            "-k",
            str(js),
            "--depth-scale",
            "1000",
        ],
    )
    assert result.exit_code == 0, result.output
    (out,) = (tmp_path / "n").rglob("*.npy")
    expected = surfnorm.estimate(
        read_depth(png, depth_scale=1000), read_intrinsics(js), method="d2nt_v2", dlf="beta", tau=0.5, threads=1
    )
    np.testing.assert_array_equal(np.load(out), expected)


@pytest.mark.parametrize(
    "spec, needle",
    [
        ("plane_pca:window=4", "window: expected an odd integer >= 3"),
        ("plane_pca:colour=red", "unknown option(s) colour"),
        ("plane_pca:window", "expected NAME or NAME:option=value"),
    ],
)
def test_bad_method_options_are_one_line_exit_2(frame, tmp_path, spec, needle):
    png, js = frame
    result = runner.invoke(app, ["estimate", str(png), str(tmp_path / "o"), "-m", spec, "-k", str(js)])
    assert result.exit_code == 2
    assert needle in result.output and len(result.output.strip().splitlines()) == 1


def test_parse_method():
    assert parse_method("auto") == ("auto", {})
    assert parse_method("d2nt_v3+mnr") == ("d2nt_v3+mnr", {})
    assert parse_method("plane_pca:window=11:fill=nan")[1]["window"] == 11
    assert np.isnan(parse_method("plane_pca:fill=nan")[1]["fill"])
    assert parse_method("d2nt_v2:truncate=false,dlf=alpha") == ("d2nt_v2", {"truncate": False, "dlf": "alpha"})
    assert parse_method("adaptive_fit:window=None") == ("adaptive_fit", {"window": None})


def test_methods_name_prints_every_option_with_its_meaning():
    result = runner.invoke(app, ["methods", "adaptive_fit"], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    for o in options_of("adaptive_fit"):
        assert o.name in result.output
        assert " ".join(o.doc.split()[:4]) in " ".join(result.output.split())
    assert {"stride", "window", "max_window", "fill"} <= {o.name for o in options_of("adaptive_fit")}
    sda = runner.invoke(app, ["methods", "sda_sne"], env={"COLUMNS": "200"})
    assert "iterations" in sda.output and "base" in sda.output


def test_methods_unknown_name_is_one_line_exit_2():
    result = runner.invoke(app, ["methods", "nope"])
    assert result.exit_code == 2 and "nope" in result.output


def test_no_registered_option_lacks_a_meaning_or_its_values():
    for name, method in _REGISTRY.items():
        for o in options_of(name + "+mnr"):
            assert len(o.doc) > 20, (name, o.name)
            assert o.allowed, (name, o.name)
        assert set(method.options) <= {o.name for o in options_of(name)}


def test_the_methods_page_shows_every_option_of_every_method():
    import importlib.util
    from pathlib import Path

    if importlib.util.find_spec("mkdocs") is None:
        pytest.skip("mkdocs is not installed (the docs extra)")
    root = Path(__file__).resolve().parents[1]
    spec = importlib.util.spec_from_file_location("docs_hooks", root / "docs" / "hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    page = hooks.options_section()
    for name in surfnorm.methods():
        assert f"`{name}`" in page
        for o in options_of(name):
            assert o.doc.replace("|", "\\|") in page
    assert hooks.OPTIONS_MARKER in (root / "docs" / "methods.md").read_text()


def test_estimate_warns_in_one_line_where_the_intrinsics_do_not_fit(tmp_path):
    png, _ = write_sample("realsense-d435", tmp_path / "frame.png")
    args = ["estimate", str(png), str(tmp_path / "o"), "--fx", "525", "--fy", "525", "--cx", "319.5", "--cy", "239.5"]
    with warnings.catch_warnings():
        warnings.simplefilter("default", IntrinsicsWarning)  # the suite ignores it (pyproject.toml)
        result = runner.invoke(app, args + ["--depth-scale", "1000", "-m", "d2nt_basic"])
    assert result.exit_code == 0, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("warning: K: intrinsics that do not fit the frame"), lines


def test_sample_writes_a_frame_and_refuses_an_unknown_name(tmp_path):
    result = runner.invoke(app, ["sample", "3f2n-hard", str(tmp_path / "f.png")])
    assert result.exit_code == 0, result.output
    depth, K = surfnorm.io.sample_frame("3f2n-hard")
    assert read_intrinsics(tmp_path / "f.json") == K
    assert abs(read_depth(tmp_path / "f.png", depth_scale=1000) - depth).max() <= 0.0005 + 1e-6
    bad = runner.invoke(app, ["sample", "kinect", str(tmp_path / "g.png")])
    assert bad.exit_code == 2 and "name: expected one of realsense-d435" in bad.output
    assert not (tmp_path / "g.png").exists()
