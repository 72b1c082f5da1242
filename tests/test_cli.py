import numpy as np
from typer.testing import CliRunner

from surfnorm.cli import app
from surfnorm.io.threef2n import sample_root

runner = CliRunner()
FRAME = sample_root() / "Easy" / "android"


def test_estimate_writes_npy_and_png(tmp_path):
    out = tmp_path / "android"
    result = runner.invoke(app, ["estimate", str(FRAME / "depth" / "000001.bin.gz"), str(out),
                                 "--params", str(FRAME / "params.txt"), "--method", "d2nt_basic"])
    assert result.exit_code == 0, result.output
    n = np.load(tmp_path / "android.npy")
    assert n.shape == (480, 640, 3) and n.dtype == np.float32
    assert (tmp_path / "android.png").stat().st_size > 1000
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary files left


def test_usage_errors_exit_2_with_one_line(tmp_path):
    lone = tmp_path / "lone.bin.gz"  # a depth file with no 3F2N params.txt beside it
    lone.write_bytes((FRAME / "depth" / "000001.bin.gz").read_bytes())
    cases = [
        ["estimate", str(FRAME / "depth" / "000001.bin.gz"), str(tmp_path / "x"), "--params", str(FRAME / "params.txt"), "--method", "nope"],
        ["estimate", str(tmp_path / "missing.bin"), str(tmp_path / "x"), "--params", str(FRAME / "params.txt")],
        ["estimate", str(lone), str(tmp_path / "x")],
        ["estimate", str(FRAME / "depth" / "000001.bin.gz"), str(tmp_path / "x"), "--fx", "-1", "--fy", "1", "--cx", "1", "--cy", "1"],
    ]
    expected = ["method: expected one of", "missing.bin", "intrinsics",
                "intrinsics.fx: expected a positive focal length"]
    for args, text in zip(cases, expected):
        result = runner.invoke(app, args)
        assert result.exit_code == 2, (args, result.output)
        assert text in result.output, result.output
        assert "Traceback" not in result.output


def test_methods_lists_registry():
    result = runner.invoke(app, ["methods"])
    assert result.exit_code == 0
    assert "d2nt_v3" in result.output and "depth-to-normal" in result.output


def test_demo_table_and_pictures(tmp_path):
    result = runner.invoke(app, ["demo", str(tmp_path / "demo")])
    assert result.exit_code == 0, result.output
    assert "d2nt_v3" in result.output and "[1.240]" in result.output  # authors' figure for Easy/android
    pngs = sorted(p.name for p in (tmp_path / "demo").iterdir())
    assert "Easy_android_000001_d2nt_v3_normals.png" in pngs and "Easy_android_000001_d2nt_v3_error.png" in pngs
    assert "Hard_batman_000001_cp2tv_plus_mnr_error.png" in pngs
