import numpy as np
import pytest
from typer.testing import CliRunner

from surfnorm.cli import app
from surfnorm.io.threef2n import sample_root

runner = CliRunner()
FRAME = sample_root() / "Easy" / "android"


def test_estimate_writes_npy_and_png(tmp_path):
    out = tmp_path / "android"
    result = runner.invoke(
        app,
        [
            "estimate",
            str(FRAME / "depth" / "000001.bin.gz"),
            str(out),
            "--params",
            str(FRAME / "params.txt"),
            "--method",
            "d2nt_basic",
        ],
    )
    assert result.exit_code == 0, result.output
    n = np.load(tmp_path / "android.npy")
    assert n.shape == (480, 640, 3) and n.dtype == np.float32
    assert (tmp_path / "android.png").stat().st_size > 1000
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary files left


def test_usage_errors_exit_2_with_one_line(tmp_path):
    lone = tmp_path / "lone.bin.gz"  # a depth file with no 3F2N params.txt beside it
    lone.write_bytes((FRAME / "depth" / "000001.bin.gz").read_bytes())
    cases = [
        [
            "estimate",
            str(FRAME / "depth" / "000001.bin.gz"),
            str(tmp_path / "x"),
            "--params",
            str(FRAME / "params.txt"),
            "--method",
            "nope",
        ],
        ["estimate", str(tmp_path / "missing.bin"), str(tmp_path / "x"), "--params", str(FRAME / "params.txt")],
        ["estimate", str(lone), str(tmp_path / "x")],
        [
            "estimate",
            str(FRAME / "depth" / "000001.bin.gz"),
            str(tmp_path / "x"),
            "--fx",
            "-1",
            "--fy",
            "1",
            "--cx",
            "1",
            "--cy",
            "1",
        ],
    ]
    expected = [
        "method: expected one of",
        "missing.bin",
        "intrinsics",
        "intrinsics.fx: expected a positive focal length",
    ]
    for args, text in zip(cases, expected):
        result = runner.invoke(app, args)
        assert result.exit_code == 2, (args, result.output)
        assert text in result.output, result.output
        assert "Traceback" not in result.output


def test_methods_lists_registry(monkeypatch):
    import surfnorm.cli

    monkeypatch.setattr(surfnorm.cli.console, "width", 400)  # one line per method
    result = runner.invoke(app, ["methods"])
    assert result.exit_code == 0
    assert "d2nt_v3" in result.output and "depth-to-normal" in result.output
    assert "surfnorm.kernels.d2nt_v3.d2nt_v3" in result.output and "surfnorm.kernels.sda.sda_sne" in result.output


@pytest.mark.slow
def test_demo_table_and_pictures(tmp_path):
    result = runner.invoke(app, ["demo", str(tmp_path / "demo")])
    assert result.exit_code == 0, result.output
    assert "d2nt_v3" in result.output and "[1.240]" in result.output  # authors' figure for Easy/android
    pngs = sorted(p.name for p in (tmp_path / "demo").iterdir())
    assert "Easy_android_000001_d2nt_v3_normals.png" in pngs and "Easy_android_000001_d2nt_v3_error.png" in pngs
    assert "Hard_batman_000001_cp2tv_plus_mnr_error.png" in pngs


# ---------------------------------------------------------------------------- issue 14: the one-line promise


def _one_line_exit_2(args, needle):
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 2, (args, result.output)
    assert "Traceback" not in result.output and "╭" not in result.output, result.output  # no traceback, no box
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), (args, result.stderr)
    assert needle in lines[0], (args, lines[0])
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    return lines[0]


def test_estimate_on_a_truncated_pfm_is_one_line_exit_2(tmp_path):
    """A PFM file cut short: one line naming it and what is wrong, exit 2, nothing written."""
    bad = tmp_path / "disp.pfm"
    bad.write_bytes(b"Pf\n3 2\n-1.0\n" + bytes(10))
    args = ["estimate", bad, tmp_path / "out", "--disparity", "--fx", "500", "--fy", "500", "--cx", "1", "--cy", "1"]
    _one_line_exit_2(args, "disp.pfm: expected 24 bytes of pixels for 3 x 2, got 10 (truncated)")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["disp.pfm"]


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    depth = tmp_path / "d.bin.gz"
    depth.write_bytes((FRAME / "depth" / "000001.bin.gz").read_bytes())
    (tmp_path / "empty").mkdir()
    (tmp_path / "afile").write_text("x")
    (tmp_path / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
    (tmp_path / "bad.yaml").write_text(
        "%YAML:1.0\ncamera_matrix: !!opencv-matrix\n  rows: 3\n  cols: 3\n  dt: d\n  data: [1, 0, 1, 0, 1, 1, 0, 0]\n"
    )
    monkeypatch.chdir(tmp_path)
    return tmp_path


CAMERA = ["--fx", 500, "--fy", 500, "--cx", 319.5, "--cy", 239.5]
# Every command with each class of usage error: (arguments, words of the one line). 34 cases.
USAGE_ERRORS = [
    # unknown command or option at the top
    (["nope"], "No such command 'nope'"),
    (["--bogus"], "No such option: --bogus"),
    # estimate
    (["estimate", "d.bin.gz", "o", "--bogus"], "No such option: --bogus"),
    (["estimate", "d.bin.gz", "o", "--fx", "abc", "--fy", 1, "--cx", 1, "--cy", 1], "Invalid value for '--fx'"),
    (["estimate", "d.bin.gz", "o", "--depth-scale", "x"], "Invalid value for '--depth-scale'"),
    (["estimate", "d.bin.gz"], "Missing argument"),
    (["estimate"], "Missing argument"),
    (["estimate", "d.bin.gz", "o", "extra"], "unexpected extra argument"),
    (["estimate", "d.bin.gz", "o", "--method"], "Option '--method' requires an argument"),
    (["estimate", "missing.bin", "o", *CAMERA], "missing.bin: cannot read depth file"),
    (
        ["estimate", "d.bin.gz", "o", "-k", "bad.yaml"],
        "bad.yaml: expected 9 numbers (a 3x3 matrix) in camera_matrix.data, got 8",
    ),
    (["estimate", "d.bin.gz", "o", "-k", "deep.json"], "deep.json: expected lists and mappings at most 16 deep"),
    (["estimate", "d.bin.gz", "o", "--method", "nope", *CAMERA], "method: expected one of"),
    # convert
    (["convert", "d.bin.gz", "out", "--jobs", "abc"], "Invalid value for '--jobs'"),
    (["convert", "d.bin.gz", "out", "--bogus"], "No such option: --bogus"),
    (["convert", "d.bin.gz"], "Missing argument"),
    (["convert"], "Missing argument"),
    (["convert", "d.bin.gz", "out", "extra"], "unexpected extra argument"),
    (["convert", "nothing", "out", *CAMERA], "inputs: expected a depth file, a folder or a glob pattern"),
    (["convert", "d.bin.gz", "out", "-k", "bad.yaml"], "bad.yaml: expected 9 numbers"),
    (["convert", "d.bin.gz", "out", "-k", "deep.json"], "deep.json: expected lists and mappings at most 16 deep"),
    (
        ["convert", "d.bin.gz", "out", *CAMERA, "--cluster", "not a url"],
        "cluster address: expected a Dask scheduler address",
    ),
    (["convert", "d.bin.gz", "afile", *CAMERA], "output_dir: expected a folder, got the file"),
    # bench
    (["bench", "--out", "rep", "--repeats", "x"], "Invalid value for '--repeats'"),
    (["bench", "--out", "rep", "--bogus"], "No such option: --bogus"),
    (["bench"], "Missing option '--out'"),
    (["bench", "empty", "--out", "rep", "extra"], "unexpected extra argument"),
    (["bench", "empty", "--out", "rep"], "dataset: expected frames in the 3F2N layout"),
    (["bench", "--out", "rep", "--levels", "Trivial"], "levels: expected some of Easy, Medium, Hard"),
    # demo
    (["demo", "--bogus"], "No such option: --bogus"),
    (["demo", "a", "b"], "unexpected extra argument"),
    (["demo", "afile"], "afile"),
    # methods
    (["methods", "auto", "extra"], "unexpected extra argument"),
    (["methods", "extra"], "got 'extra'"),
    (["methods", "--bogus"], "No such option: --bogus"),
]


@pytest.mark.slow
@pytest.mark.parametrize("args, needle", USAGE_ERRORS, ids=[" ".join(map(str, a))[:60] for a, _ in USAGE_ERRORS])
def test_every_command_usage_error_is_one_line_exit_2(workdir, args, needle):
    _one_line_exit_2(args, needle)


def test_a_bug_is_one_line_too(workdir, monkeypatch):
    import surfnorm.io.depth

    def broken(*a, **k):
        raise TypeError("a bug")

    monkeypatch.setattr(surfnorm.io.depth, "read_depth", broken)
    result = runner.invoke(app, ["estimate", "d.bin.gz", "o", *map(str, CAMERA)])
    assert result.exit_code == 1 and "Traceback" not in result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "unexpected TypeError: a bug" in lines[0] and "SURFNORM_TRACEBACK=1" in lines[0]


def test_params_txt_is_found_the_same_from_a_relative_and_an_absolute_path(tmp_path, monkeypatch):
    (tmp_path / "ok.bin.gz").write_bytes((FRAME / "depth" / "000001.bin.gz").read_bytes())
    (tmp_path / "params.txt").write_text((FRAME / "params.txt").read_text())
    monkeypatch.chdir(tmp_path)
    relative = runner.invoke(app, ["estimate", "ok.bin.gz", "rel", "-f", "npy"])
    absolute = runner.invoke(app, ["estimate", str(tmp_path / "ok.bin.gz"), "abs", "-f", "npy"])
    assert relative.exit_code == 0 and absolute.exit_code == 0, relative.output + absolute.output
    assert (tmp_path / "rel.npy").read_bytes() == (tmp_path / "abs.npy").read_bytes()
    # the 3F2N layout <object>/depth/<frame>: params.txt in the folder above, from inside depth/ too
    monkeypatch.chdir(FRAME / "depth")
    inside = runner.invoke(app, ["estimate", "000001.bin.gz", str(tmp_path / "in"), "-f", "npy"])
    assert inside.exit_code == 0, inside.output
    assert (tmp_path / "in.npy").read_bytes() == (tmp_path / "abs.npy").read_bytes()
