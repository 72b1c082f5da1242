"""Kernels compiled ahead of time (surfnorm._aot, surfnorm._aot_build): the same bits as the JIT, no compiling.

The wheel's build compiles the default method's kernels (python -m surfnorm._aot_build, a few minutes); here two
small kernels are built the same way into a copy of the package, so that the whole path (pycc, the exported
wrappers, the index, the choice at run time) is exercised in seconds. benchmarks/cold_start.py checks the full
build: the first call's normals in a new environment against the JIT's.
"""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import surfnorm
from surfnorm import _aot
from surfnorm._aot import Kernel, jit_only
from surfnorm._config import njit

PACKAGE = Path(surfnorm.__file__).resolve().parent
KERNELS = ["surfnorm._validate._valid_loop", "surfnorm.kernels.sensor_noise._depth_range"]

BUILD = """
import sys
from pathlib import Path
import numpy as np
from surfnorm._aot import jit_only
from surfnorm._aot_build import build
from surfnorm.kernels.sensor_noise import _depth_range
from surfnorm._validate import valid_map

def warm_up():
    with jit_only():
        z = np.ones((4, 5), np.float32)
        _depth_range(z, valid_map(z, None))

build(Path(sys.argv[1]), verbose=False, names=set(sys.argv[2:]), warm_up=warm_up)
"""

CHECK = """
import json
import numba.core.event as ev
import numpy as np
from surfnorm import _aot
from surfnorm.kernels.sensor_noise import _depth_range
from surfnorm._validate import _valid_kernels, valid_map

rec = ev.RecordingListener()
ev.register("numba:compile", rec)
rng = np.random.default_rng(0)
z = rng.normal(2.0, 1.5, (37, 53)).astype(np.float32)
z[3, 4], z[5, 6], z[7, 8] = np.nan, np.inf, -np.inf
valid = valid_map(z, None)
zmin, zmax = _depth_range(z, valid)
compiled = [e.data["dispatcher"].py_func.__name__ for _, e in rec.buffer if e.is_start]
used = sorted(type(f).__name__ for f in _valid_kernels()[0]._chosen.values())
with _aot.jit_only():
    valid_jit = valid_map(z, None)
    zmin_jit, zmax_jit = _depth_range(z, valid_jit)
other = valid_map(z.astype(np.float32)[:, ::2], None)  # another layout: not exported, so the JIT's
print(json.dumps({"available": _aot.available(), "compiled": compiled, "used": used,
                  "same": bool(np.array_equal(valid, valid_jit)) and (zmin, zmax) == (zmin_jit, zmax_jit),
                  "other": bool(np.array_equal(other, valid_jit[:, ::2]))}))
"""


def _run(code, site, cache, *args, **env):
    full = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "SURFNORM_AOT"))}
    full.update(PYTHONPATH=str(site), NUMBA_CACHE_DIR=str(cache), **env)
    done = subprocess.run([sys.executable, "-c", code, *args], env=full, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    if shutil.which(os.environ.get("CC", "cc")) is None and shutil.which("gcc") is None:
        pytest.skip("no C compiler: Numba's AOT compiler needs one to link its runtime")
    root = tmp_path_factory.mktemp("aot")
    shutil.copytree(
        PACKAGE,
        root / "surfnorm",
        ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc", "data", "_aot_*.so", "_aot_*.pyd", _aot.INDEX),
    )
    _run(BUILD, root, root / "build-cache", str(root / "surfnorm"), *KERNELS)
    return root


@pytest.mark.slow
def test_build_writes_one_module_per_level_and_an_index(built):
    index = json.loads((built / "surfnorm" / _aot.INDEX).read_text())
    assert sorted(index["kernels"]) == sorted(KERNELS)
    assert index["source"] == _aot.source_hash(built / "surfnorm")
    for module in index["modules"]:
        assert list((built / "surfnorm").glob(module + ".*")), module
    if index["arch"] == "x86_64":
        assert index["modules"] == ["_aot_x86_64_v4", "_aot_x86_64_v3", "_aot_x86_64"]


@pytest.mark.slow
@pytest.mark.parametrize("level", ["1", "_aot_x86_64_v3", "_aot_x86_64"])
def test_aot_code_runs_without_compiling_and_gives_the_jit_bits(built, tmp_path, level):
    """Every level this machine can run (the host's best, AVX2 where it has more, and the baseline), in a new
    process with an empty cache."""
    index = json.loads((built / "surfnorm" / _aot.INDEX).read_text())
    if level not in ("1", *index["modules"]):
        pytest.skip(f"{level} is not a level of {index['arch']}")
    needs = {module: features for module, _, features in _aot.LEVELS.get(index["arch"], [])}.get(level, ())
    if needs and _aot._host_level([(level, "", needs)]) is None:
        pytest.skip(f"this CPU cannot run {level}")
    out = json.loads(_run(CHECK, built, tmp_path / "cache", SURFNORM_AOT=level).splitlines()[-1])
    assert out["available"]
    assert out["compiled"] == [], "the AOT code ran: nothing compiled before jit_only()"
    assert "CPUDispatcher" not in out["used"]
    assert out["same"] and out["other"]


@pytest.mark.slow
def test_changed_sources_or_switch_off_fall_back_to_the_jit(built, tmp_path):
    out = json.loads(_run(CHECK, built, tmp_path / "cache", SURFNORM_AOT="0").splitlines()[-1])
    assert not out["available"] and out["compiled"] and out["same"]
    changed = tmp_path / "site"
    shutil.copytree(built / "surfnorm", changed / "surfnorm", ignore=shutil.ignore_patterns("__pycache__"))
    with open(changed / "surfnorm" / "kernels" / "gradients.py", "a") as f:
        f.write("\n# edited after the build\n")
    out = json.loads(_run(CHECK, changed, tmp_path / "cache2").splitlines()[-1])
    assert not out["available"], "AOT code built from other sources must not run"
    assert "_valid_loop" in out["compiled"] and out["same"]


def test_kernel_runs_the_aot_code_for_exported_types_only(monkeypatch):
    """The choice at run time, with a stand-in AOT module: exported types -> AOT, others -> JIT; under
    jit_only(), the JIT."""

    def twice(x, out):
        for i in range(x.shape[0]):
            out[i] = 2.0 * x[i]

    dispatcher = njit(cache=False)(twice)
    kernel = Kernel(dispatcher)
    calls = []

    def fake(x, out):
        calls.append("aot")
        twice(x, out)

    x = np.arange(5.0)
    out = np.empty(5)
    from numba import typeof

    exported = str((typeof(x), typeof(out)))
    monkeypatch.setitem(_aot._state, "loaded", True)
    monkeypatch.setitem(
        _aot._state, "module", (type("M", (), {"k0": staticmethod(fake)}), {kernel.name: [["k0", exported]]})
    )
    kernel(x, out)
    assert calls == ["aot"] and not dispatcher.signatures
    kernel(x.astype(np.float32), out)  # not exported: the JIT compiles it
    assert calls == ["aot"] and len(dispatcher.signatures) == 1
    with jit_only():
        kernel(x, out)
    assert calls == ["aot"] and len(dispatcher.signatures) == 2
    kernel(x, out)
    assert calls == ["aot", "aot"]
    np.testing.assert_array_equal(out, 2 * x)
    assert kernel.py_func is twice and kernel.__name__ == "twice"


def test_the_build_refuses_a_process_that_has_loaded_numba(capsys):
    """python -m surfnorm._aot_build must run in a new process (it sets Numba's cache folder before importing it)."""
    import numba  # noqa: F401 - loaded, as in any process that has run a kernel

    from surfnorm._aot_build import main

    assert main([]) == 2
    assert "run it in a new process" in capsys.readouterr().err
