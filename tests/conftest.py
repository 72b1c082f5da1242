import os
import sys
from pathlib import Path

import pytest

# The 12-frame 3F2N sample, compressed inside the repository (tests/data/3f2n-sample/README.md), and the
# official figures of those frames (the file that surfnorm.reference reads).
SAMPLE = Path(__file__).resolve().parent / "data" / "3f2n-sample"
SHARED_REFERENCE = Path(__file__).resolve().parents[1] / "src" / "surfnorm" / "data" / "official-3f2n-sample.json"

os.environ.setdefault("NUMBA_NUM_THREADS", "2")


@pytest.fixture(scope="session")
def shared_sample():
    """The 12-frame 3F2N sample (tests/data/3f2n-sample), in the dataset's layout."""
    return SAMPLE


def pytest_terminal_summary(terminalreporter):
    """Print how many documentation examples ran, and which were marked not run (tests/test_examples.py); with
    ``--every-module``, the modules that no selected test ran."""
    module = sys.modules.get("tests.test_examples") or sys.modules.get("test_examples")
    if module is not None and any(module.COUNTS.values()):
        for line in module.summary_lines():
            terminalreporter.write_line(line)
    touched = getattr(terminalreporter.config, "_surfnorm_touched", None)
    if touched is not None:
        missing = getattr(terminalreporter.config, "_surfnorm_missing", [])
        if missing:
            terminalreporter.write_line(f"--every-module: no selected test ran code of {', '.join(missing)}", red=True)
        else:
            terminalreporter.write_line(
                "--every-module: the selected tests ran code of every module under src/surfnorm"
            )


# --- make test-fast: the tests not marked slow run code of every module ---------------------------------------------------

SRC_PACKAGE = Path(__file__).resolve().parents[1] / "src" / "surfnorm"


def pytest_addoption(parser):
    parser.addoption(
        "--every-module",
        action="store_true",
        help="fail unless the selected tests run code of every module under src/surfnorm (make test-fast)",
    )


def _needs_a_call(path: Path) -> bool:
    """Whether a module has a plain Python function (no decorator: not a Numba kernel) that a test can call.

    Such a module counts as run only once one of its functions ran; one without (constants, kernels that Numba
    compiles, packages' ``__init__``) counts once it is imported.
    """
    import ast

    tree = ast.parse(path.read_text(encoding="utf-8"))
    nodes = [n for n in tree.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))]
    nodes += [m for n in tree.body if isinstance(n, ast.ClassDef) for m in n.body if isinstance(m, ast.FunctionDef)]
    return any(isinstance(n, ast.FunctionDef) and not n.decorator_list for n in nodes)


class _Touched:
    """Which modules of src/surfnorm ran code, read from a C profiler (``cProfile``) that runs while the tests do.

    A module whose functions are all compiled by Numba (or that has none) counts once imported; any other counts
    once one of its functions (or methods) ran on the main thread.
    """

    def __init__(self):
        import cProfile

        files = sorted(SRC_PACKAGE.rglob("*.py"))
        self.imported_only = {str(p) for p in files if not _needs_a_call(p)}
        self.files = {str(p) for p in files}
        self.profile = cProfile.Profile()
        self.profile.enable()

    def left(self) -> list[str]:
        """The modules (paths) that no test ran, as above."""
        self.profile.disable()
        codes = [e.code for e in self.profile.getstats() if not isinstance(e.code, str)]  # (str: a C function)
        called = {c.co_filename for c in codes if c.co_name != "<module>"}
        imported = {os.path.realpath(m.__file__) for m in list(sys.modules.values()) if getattr(m, "__file__", None)}
        return [f for f in sorted(self.files) if f not in called and not (f in self.imported_only and f in imported)]


def pytest_configure(config):
    if config.getoption("--every-module", default=False):
        config._surfnorm_touched = _Touched()


def pytest_sessionfinish(session, exitstatus):
    touched = getattr(session.config, "_surfnorm_touched", None)
    if touched is None:
        return
    missing = touched.left()
    if missing:
        session.config._surfnorm_missing = [str(Path(p).relative_to(SRC_PACKAGE.parent)) for p in missing]
        if session.exitstatus == 0:
            session.exitstatus = 1
