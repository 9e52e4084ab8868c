import os
from pathlib import Path

import numpy as np
import pytest

REAL_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"


@pytest.fixture
def rng():
    return np.random.default_rng(0)


def real_data_root() -> Path:
    """../shared/data/real (or $WEARABLE_GAZE_REAL_DATA), or skip the test with the reason."""
    root = Path(os.environ.get("WEARABLE_GAZE_REAL_DATA", REAL_DATA))
    if not root.is_dir():
        pytest.skip(f"real test data not found at {root} (set WEARABLE_GAZE_REAL_DATA)")
    return root


@pytest.fixture
def real_data():
    """../shared/data/real, or skip with the reason."""
    return real_data_root()


@pytest.fixture(scope="module")
def real_data_module():
    """The same, for module-scoped fixtures."""
    return real_data_root()
