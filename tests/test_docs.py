"""The documentation: the generated method -> kernel page, and the names the pages cite exist."""

import importlib
import re
from pathlib import Path

import pytest

import surfnorm

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted((ROOT / "docs").rglob("*.md")) + [ROOT / "README.md", ROOT / "CHANGELOG.md"]


def test_kernel_page_lists_every_method():
    """The method -> kernel page of the documentation is generated from the registry: every method, a source file."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("docs_hooks", ROOT / "docs" / "hooks.py")
    if importlib.util.find_spec("mkdocs") is None:
        pytest.skip("mkdocs is not installed (the docs extra)")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    page = hooks.kernels_page()
    rows = [line for line in page.split("\n## Options")[0].splitlines() if line.startswith("| `")]
    assert [row.split("`")[1] for row in rows] == list(surfnorm.methods())
    for row in rows:  # each names a function and the file and line where it is defined
        assert re.search(r"`src/surfnorm/[\w/]+\.py:\d+`", row), row


def _resolve(dotted: str):
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):  # the longest importable module, then attributes
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for name in parts[i:]:
            obj = getattr(obj, name)
        return obj
    raise ImportError(dotted)


def test_names_in_the_pages_exist():
    """Every ``surfnorm.<module>.<name>`` the pages cite imports: a module moved or renamed fails here."""
    names = set()
    for page in PAGES:
        names |= set(re.findall(r"(?<![\w.])(surfnorm(?:\.[A-Za-z_]\w*)+)", page.read_text(encoding="utf-8")))
    assert len(names) > 20
    missing = []
    for name in sorted(names):
        try:
            _resolve(name)
        except (ImportError, AttributeError):
            missing.append(name)
    assert not missing, f"names cited in the documentation that do not exist: {missing}"
