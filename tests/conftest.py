import os
from pathlib import Path

import pytest

# The full 12-frame sample lies beside the repository (../shared) on developer
# machines and in CI; tests over it run only where it exists.
SHARED_SAMPLE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "3f2n-sample"
SHARED_REFERENCE = Path(__file__).resolve().parents[1].parent / "shared" / "reference" / "3f2n-sample-official.json"

os.environ.setdefault("NUMBA_NUM_THREADS", "2")


@pytest.fixture(scope="session")
def shared_sample():
    if not SHARED_SAMPLE.is_dir():
        pytest.skip(f"the 12-frame 3F2N sample is not at {SHARED_SAMPLE}")
    return SHARED_SAMPLE
