"""python -m surfnorm.precompile: every kernel compiled ahead, into a cache that works from a read-only install."""

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

import surfnorm
from surfnorm import InputError
from surfnorm.precompile import main, precompile, variants

PACKAGE = Path(surfnorm.__file__).resolve().parent

# A first call that reports how many surfnorm functions Numba compiled (0: all loaded from the cache).
FIRST_CALL = """
import numba.core.event as ev, numpy as np, surfnorm
rec = ev.RecordingListener()
ev.register("numba:compile", rec)
z = np.full((40, 50), 2.0, np.float32)
z[3, 4] = 0
K = [[40.0, 0, 24.5], [0, 40.0, 19.5], [0, 0, 1]]
for method in ("cp2tv", "cp2tv+mnr"):
    surfnorm.estimate(z, K, method=method)
    surfnorm.estimate(z, K, method=method, mask=z > 0, threads=2)
print(sum(1 for _, e in rec.buffer if e.is_start and e.data["dispatcher"].py_func.__module__.startswith("surfnorm")))
"""


def test_variants_cover_the_kernel_choices():
    for name in surfnorm.methods():
        kinds = variants(name)
        assert {"method": name} in kinds and {"method": name + "+mnr"} in kinds
        assert {"method": name, "mask": True} in kinds
    assert {"method": "plane_svd", "window": 5} in variants("plane_svd")
    for name in ("auto", "adaptive_fit", "d2nt_v3"):  # sigma's kernels: the clean frame's and the noisy one's
        assert {"method": name, "uncertainty": True} in variants(name)
    assert not any(v.get("uncertainty") for v in variants("plane_svd"))
    sda = variants("sda_sne")
    assert {"method": "sda_sne", "scale_invariant": True} in sda and {"method": "sda_sne", "base": "3f2n"} in sda
    assert {"method": "sda_sne", "base": "3f2n", "scale_invariant": True} in sda


def test_unknown_method_is_an_input_error(capsys):
    with pytest.raises(InputError, match="methods: expected some of .*got nope"):
        precompile(["nope"])
    assert main(["nope", "--quiet"]) == 2
    assert "surfnorm.precompile: methods: expected some of" in capsys.readouterr().err


def _as_unprivileged():
    """A prefix that runs a command as an unprivileged user when we are root (root may write anywhere)."""
    if os.geteuid() != 0:
        return []
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        pytest.skip("running as root without setpriv: a read-only directory cannot be made read-only for us")
    return [setpriv, "--reuid=65534", "--regid=65534", "--clear-groups"]


@pytest.mark.slow
def test_read_only_install_precompiles_into_the_user_cache():
    """A package directory nobody may write to: Numba falls back to the user-wide cache, both for
    ``python -m surfnorm.precompile`` and for the first call after it, which then compiles nothing."""
    prefix = _as_unprivileged()
    # not pytest's tmp_path: its parents are private to us, and the unprivileged user must reach the package
    tmp_path = Path(tempfile.mkdtemp(prefix="surfnorm-ro-"))
    site = tmp_path / "site"
    shutil.copytree(PACKAGE, site / "surfnorm", ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc"))
    home = tmp_path / "home"
    home.mkdir()
    for path in [site, *site.rglob("*")]:
        path.chmod(0o555 if path.is_dir() else 0o444)
    home.chmod(0o777)
    tmp_path.chmod(0o755)
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CACHE")}
    env.update(PYTHONPATH=str(site), HOME=str(home), XDG_CACHE_HOME=str(home / "cache"), PYTHONDONTWRITEBYTECODE="1")
    try:
        run = subprocess.run(
            prefix + [sys.executable, "-m", "surfnorm.precompile", "--quiet", "cp2tv"],
            env=env,
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=900,
        )
        assert run.returncode == 0, run.stderr
        assert not list(site.rglob("*.nbi")), "nothing may be written into a read-only package"
        assert list((home / "cache" / "numba").rglob("*.nbi")), "the user-wide cache holds the compiled kernels"
        first = subprocess.run(
            prefix + [sys.executable, "-c", FIRST_CALL],
            env=env,
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=900,
        )
        assert first.returncode == 0, first.stderr
        assert first.stdout.split()[-1] == "0", "after precompiling, the first call compiles nothing"
    finally:
        for path in [site, *site.rglob("*")]:
            path.chmod(0o755 if path.is_dir() else 0o644)
        shutil.rmtree(tmp_path)


@pytest.mark.slow
def test_nowhere_writable_but_the_temp_directory():
    """A read-only package and no writable home: Numba's own locations all fail (it then refused to define any
    kernel: "no locator available"); surfnorm caches into a private directory in the temporary directory, so
    the second process compiles nothing."""
    prefix = _as_unprivileged()
    tmp_path = Path(tempfile.mkdtemp(prefix="surfnorm-nohome-"))
    site, tmp = tmp_path / "site", tmp_path / "tmp"
    shutil.copytree(PACKAGE, site / "surfnorm", ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc"))
    tmp.mkdir()
    for path in [site, *site.rglob("*")]:
        path.chmod(0o555 if path.is_dir() else 0o444)
    tmp.chmod(0o1777)
    tmp_path.chmod(0o755)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_CACHE", "XDG_", "HOME", "TMP"))}
    env.update(PYTHONPATH=str(site), HOME=str(tmp_path / "no-home"), TMPDIR=str(tmp), PYTHONDONTWRITEBYTECODE="1")
    call = FIRST_CALL.replace('("cp2tv", "cp2tv+mnr")', '("d2nt_basic",)')
    try:
        for expected in ("compiled", "0"):
            run = subprocess.run(
                prefix + [sys.executable, "-c", call],
                env=env,
                cwd=tmp_path,
                capture_output=True,
                text=True,
                timeout=900,
            )
            assert run.returncode == 0, run.stderr[-2000:]
            assert (run.stdout.split()[-1] == "0") == (expected == "0"), run.stdout
        cache = [p for p in tmp.iterdir() if p.name.startswith("surfnorm-numba-")]
        assert len(cache) == 1 and list(cache[0].rglob("*.nbi")), "cached in the temporary directory"
        assert oct(cache[0].stat().st_mode & 0o777) == "0o700", "private to its user"
        assert not list(site.rglob("*.nbi"))
    finally:
        for path in [site, *site.rglob("*")]:
            path.chmod(0o755 if path.is_dir() else 0o644)
        shutil.rmtree(tmp_path)
