import os
from pathlib import Path

import numpy as np
import pytest

REAL_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"

# No timed progress lines off a terminal (wearable_gaze/progress.py) unless a test asks for them:
# what a test reads on stderr must not hang on how fast this machine runs a step.
os.environ["WEARABLE_GAZE_PROGRESS_S"] = "0"

# The floor subset (``pytest -m floors``): what ``.ci/run`` also runs with the declared floor
# versions (constraints/floors.txt) and with OpenCV 5.0: tracking, calibration, the Tobii importers
# (and their round trips through ``process``) and one short ``process`` of a video with empty frames
# (test_opencv_compat.py). A test there whose figure is a property of the
# newest OpenCV itself, not of this project, is marked ``newest_opencv`` with the reason, and
# the floor run leaves it out.
FLOOR_MODULES = {"test_opencv_compat.py", "test_tracking.py", "test_calibration.py", "test_import_tobii.py"}


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.path.name in FLOOR_MODULES:
            item.add_marker(pytest.mark.floors)


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


PROCESS_SCENARIO = {"base": "lab-walkabout", "duration_s": 12.0,
                    "room": {"size_mm": [4500.0, 2700.0, 5500.0], "markers_per_wall": 5},
                    "targets": {"random_count": 3, "random_depth_mm": [700.0, 3000.0]},
                    "calibration": {"camera_views": 10}}


@pytest.fixture(scope="session")
def processed(tmp_path_factory):
    """A simulated 12 s session (``PROCESS_SCENARIO``, seed 321) processed once for the whole
    run (about a minute), shared by tests/test_process.py and tests/test_exports.py:
    (session folder, output folder, ``ProcessResult``). No test writes into either folder (one
    that processes again works on a copy, e.g. test_process_stale's), so no result depends on
    the order the tests run in."""
    from wearable_gaze.pipeline.process.session import process_session
    from wearable_gaze.sim.simulate import simulate_scenario

    base = tmp_path_factory.mktemp("proc")
    root = base / "session"
    simulate_scenario(PROCESS_SCENARIO, root, seed=321)
    res = process_session(root, base / "out")
    return root, base / "out", res


DEVICE_SCENARIO = {"base": "lab-walkabout", "duration_s": 7.0, "targets": {"random_count": 2},
                   "camera": {"resolution": [640, 360]}, "calibration": {"camera_views": 0}}
"""test_live.py's scenario, at 640x360 (at 320x180 marker poses are too coarse for its targets)."""


@pytest.fixture(scope="session")
def device_session(tmp_path_factory):
    """``DEVICE_SCENARIO`` simulated once (seed 77), served by the device emulators of
    tests/test_live_pupil_core.py and tests/test_live_neon.py; read only, never written."""
    from wearable_gaze.sim.simulate import simulate_scenario

    root = tmp_path_factory.mktemp("device") / "session"
    simulate_scenario(DEVICE_SCENARIO, root, seed=77)
    return root


AOIS = Path(__file__).resolve().parent / "data" / "aois"
"""AOI files of the real samples (tests/data/aois/README.md)."""
G2_SAMPLE = "glassesvalidator_tobii_g2_example"


@pytest.fixture(scope="session")
def g2_processed(tmp_path_factory):
    """The real Tobii G2 sample (12 targets) imported and processed once per run with its poster's
    areas of interest (``AOIS``): (base folder, its ``s`` the session and ``out`` the outputs;
    ``ProcessResult``). Shared by tests/test_import_real.py and tests/test_report_browser.py."""
    from wearable_gaze.pipeline.importer import import_recording
    from wearable_gaze.pipeline.process.session import process_session

    src = real_data_root() / G2_SAMPLE
    if not src.is_dir():
        pytest.skip(f"the real Tobii G2 sample is not at {src}")
    base = tmp_path_factory.mktemp("g2")
    import_recording(src / "recording", base / "s")
    return base, process_session(base / "s", base / "out", aois=AOIS / "tobii_g2_glassesvalidator_poster.json")
