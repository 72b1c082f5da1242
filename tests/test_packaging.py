"""The version is written once, and the licence is the one pyproject declares."""

import re
from importlib import metadata
from pathlib import Path

import pytest

import surfnorm

ROOT = Path(__file__).resolve().parents[1]


def test_version_written_once():
    pyproject = (ROOT / "pyproject.toml").read_text()
    project = pyproject.split("\n[project]\n")[1].split("\n[")[0]
    assert re.search(r"^version\s*=", project, re.M) is None  # no second copy in pyproject
    assert 'dynamic = ["version"]' in pyproject and 'version = {attr = "surfnorm.__version__"}' in pyproject
    assert re.fullmatch(r"\d+\.\d+\.\d+([ab]|rc|\.dev)?\d*", surfnorm.__version__)
    try:
        installed = metadata.version("surfnorm")
    except metadata.PackageNotFoundError:
        pytest.skip("surfnorm is not installed, only on the path")
    assert installed == surfnorm.__version__


def test_license_is_the_declared_mit():
    assert 'license = "MIT"' in (ROOT / "pyproject.toml").read_text()
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("MIT License\n") and "Copyright (c) 2026 the surfnorm authors" in text
    assert 'THE SOFTWARE IS PROVIDED "AS IS", WITHOUT WARRANTY OF ANY KIND' in text
