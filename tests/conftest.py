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
    """Print how many documentation examples ran, and which were marked not run (tests/test_examples.py)."""
    module = sys.modules.get("tests.test_examples") or sys.modules.get("test_examples")
    if module is not None and any(module.COUNTS.values()):
        for line in module.summary_lines():
            terminalreporter.write_line(line)
