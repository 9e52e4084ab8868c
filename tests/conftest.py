import os
from pathlib import Path

import numpy as np
import pytest

REAL_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"


@pytest.fixture
def rng():
    return np.random.default_rng(0)


@pytest.fixture
def real_data():
    """../shared/data/real, or skip with the reason."""
    root = Path(os.environ.get("WEARABLE_GAZE_REAL_DATA", REAL_DATA))
    if not root.is_dir():
        pytest.skip(f"real test data not found at {root} (set WEARABLE_GAZE_REAL_DATA)")
    return root
