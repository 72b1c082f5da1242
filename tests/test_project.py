"""The project's own bookkeeping: one source for the constants both backends use, names in pyproject.toml that
exist, and the Numba that the package declares."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"


# --- constants shared by the NumPy kernels and the PyTorch backend --------------------------------------------------


def test_kernels_use_the_shared_constants():
    """surfnorm._constants is the one source: the kernels hold the same values (tests/test_torch.py: the torch side)."""
    from surfnorm import _constants as C
    from surfnorm.kernels import _schedule, _windows, adaptive_fit, auto, plane_fit, sda, sensor_noise

    # each constant in the module that uses it
    homes = {
        adaptive_fit: ("ALPHA", "KAPPA", "RHO_FLOOR", "MAX_WINDOW", "N_WIDEN", "MIN_POINTS", "TIE"),
        sensor_noise: ("N_BINS", "MIN_SAMPLES", "noise_step", "_MAX_GAP", "_MAX_SPREAD", "_CLIP_SIGMAS"),
        _windows: ("RADII", "_TABLE"),
        _schedule: ("MAX_UNREACHED",),
    }
    homes[sensor_noise] += ("_CLIP_ROUNDS", "SMOOTH_SHARE", "_SMOOTH_GAUSS", "_FOURTH_RMS", "_SMOOTH_SAMPLES")
    for module, names in homes.items():
        for name in names:
            assert getattr(module, name) == getattr(C, name), (module.__name__, name)
    assert tuple(map(tuple, adaptive_fit._SHIFTS.tolist())) == C.SHIFTS
    for name in ("CLEAN_FLOOR", "NOISY_FLOOR", "TERRACED_LOW", "TERRACED_HIGH"):
        assert getattr(auto, name) == getattr(C, name), name
    assert (plane_fit._NEWTON_STEPS, plane_fit._NEWTON_TOL) == (C.NEWTON_STEPS, C.NEWTON_TOL)
    assert sda.SDA_PENALTY == C.SDA_PENALTY


def test_the_registry_defaults_are_the_shared_ones():
    import surfnorm
    from surfnorm import _constants as C

    info = surfnorm.methods()
    assert info["d2nt_v3"].options["dlf"] == C.DLF_DEFAULT
    assert info["d2nt_v3"].options["mnr_dlf"] == C.MNR_DLF_DEFAULT
    assert info["d2nt_v2"].options["truncate"] is C.TRUNCATE_DEFAULT
    assert info["adaptive_fit"].options["max_window"] == C.MAX_WINDOW


def test_plane_svd_characteristic_has_one_home():
    """The Numba kernel compiles the same Python function that the torch backend runs on tensors."""
    from surfnorm import _plane_svd
    from surfnorm.kernels import plane_fit

    assert plane_fit.plane_svd_characteristic.py_func is _plane_svd.plane_svd_characteristic
    args = (0.3, -0.2, 1.5, 2.0, 0.1, -0.3, 1.7, 0.2, 0.9)
    assert plane_fit.plane_svd_characteristic(*args) == _plane_svd.plane_svd_characteristic(*args)
    torch = pytest.importorskip("torch")
    from surfnorm.torch import _plane_fit

    assert _plane_fit.plane_svd_characteristic is _plane_svd.plane_svd_characteristic
    got = _plane_fit.plane_svd_characteristic(*(torch.tensor([a], dtype=torch.float64) for a in args))
    assert tuple(float(t) for t in got) == _plane_svd.plane_svd_characteristic(*args)


# --- pyproject.toml names modules that exist ------------------------------------------------------------------------


def _pyproject() -> dict:
    try:
        import tomllib
    except ImportError:  # Python 3.10
        tomllib = pytest.importorskip("tomli")
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))


def _module_exists(name: str) -> bool:
    """Whether ``name`` (``surfnorm.x.y`` or a ``surfnorm.x.*`` pattern) is a module or package under src/."""
    path = SRC.joinpath(*name.removesuffix(".*").split("."))
    if name.endswith(".*"):
        return (path / "__init__.py").is_file()
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def test_mypy_overrides_name_modules_that_exist():
    overrides = _pyproject()["tool"]["mypy"]["overrides"]
    names = [m for o in overrides for m in ([o["module"]] if isinstance(o["module"], str) else o["module"])]
    ours = [m for m in names if m == "surfnorm" or m.startswith("surfnorm.")]
    assert "surfnorm.kernels.*" in ours
    missing = [m for m in ours if not _module_exists(m)]
    assert not missing, f"pyproject.toml [[tool.mypy.overrides]] names modules that do not exist under src/: {missing}"


def test_the_module_check_tells_a_module_from_a_dead_name():
    assert _module_exists("surfnorm.kernels.*") and _module_exists("surfnorm._config")
    assert _module_exists("surfnorm.torch") and _module_exists("surfnorm.io.depth")
    assert not _module_exists("surfnorm.orientation") and not _module_exists("surfnorm.adaptive_fit")
    assert not _module_exists("surfnorm.methods.*")


# --- Numba: the versions the package declares and checks ---------------------------------------------------------


def _numba_specs() -> list[str]:
    """The numba requirement of [project] dependencies and of [build-system] requires, as written."""
    data = _pyproject()
    found = []
    for requirement in data["project"]["dependencies"] + data["build-system"]["requires"]:
        if requirement.replace(" ", "").startswith("numba") and not requirement.startswith("numba-"):
            found.append(requirement.replace(" ", "")[len("numba") :])
    return found


def test_numba_is_bounded_alike_in_dependencies_build_requires_and_the_check():
    from surfnorm._numba_internals import NUMBA_SUPPORTED

    (low, high) = NUMBA_SUPPORTED
    expected = f">={low[0]}.{low[1]},<{high[0]}.{high[1]}"
    assert _numba_specs() == [expected, expected]


def test_the_installed_numba_is_inside_the_declared_bound():
    """Fails where an environment (CI, a fresh clone) installed a Numba that pyproject.toml does not allow."""
    import numba

    specifiers = pytest.importorskip("packaging.specifiers")
    spec = specifiers.SpecifierSet(_numba_specs()[0])
    assert spec.contains(numba.__version__, prereleases=True), f"numba {numba.__version__} is outside {spec}"


@pytest.mark.parametrize("version", ["0.58.1", "0.69.0", "0.70.0rc1", "1.0.0"])
def test_an_unknown_numba_is_refused_with_the_supported_range(version, monkeypatch):
    import importlib.util

    import numba

    from surfnorm._numba_internals import NUMBA_SUPPORTED, check_numba_version

    (low, high) = NUMBA_SUPPORTED
    with pytest.raises(ImportError, match=rf"numba>={low[0]}\.{low[1]},<{high[0]}\.{high[1]}.*found numba {version}"):
        check_numba_version(version)
    # and at import: the module, loaded afresh under that version, refuses to load
    monkeypatch.setattr(numba, "__version__", version)
    spec = importlib.util.spec_from_file_location("numba_internals_check", SRC / "surfnorm" / "_numba_internals.py")
    module = importlib.util.module_from_spec(spec)
    with pytest.raises(ImportError, match=f"found numba {version}"):
        spec.loader.exec_module(module)


@pytest.mark.parametrize("version", ["0.59.0", "0.68.1", "0.68.2rc1"])
def test_a_supported_numba_passes_the_check(version):
    from surfnorm._numba_internals import check_numba_version

    check_numba_version(version)
