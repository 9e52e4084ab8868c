"""The round trip of issue 14: simulator -> device format -> importer -> ``process``, compared
with ``process`` on the simulator's own session (camera and eye calibration, head tracking from
the scene video). Each device's test calls ``roundtrip_errors``; the native run is shared."""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

import numpy as np

from wearable_gaze.formats.devices.common import ImportOptions
from wearable_gaze.pipeline.importer import export_recording, import_recording
from wearable_gaze.pipeline.process.session import process_session
from wearable_gaze.pipeline.report.truth_match import match_targets
from wearable_gaze.sim.simulate import simulate_scenario

SCENARIO = {"base": "lab-walkabout", "duration_s": 12.0,
            "room": {"size_mm": [4500.0, 2700.0, 5500.0], "markers_per_wall": 5},
            "targets": {"random_count": 3, "random_depth_mm": [700.0, 3000.0]},
            "calibration": {"camera_views": 10}}
SEED = 321


def target_errors(session: Path, targets: list[dict]) -> np.ndarray:
    """(K,) distance, mm, from each fixated truth target (>= 1 s of fixation) to its match among
    ``targets`` (rows of targets.json); inf where none matched."""
    truth = json.loads((session / "truth" / "targets.json").read_text())["targets"]
    fixated = [t for t in truth if sum(b - a for a, b in t["fixations_s"]) >= 1.0]
    errs = []
    for tt, f in match_targets(targets, fixated):
        errs.append(np.inf if f is None else
                    float(np.linalg.norm(np.array(f["position_mm"]) - tt["position_mm"])))
    return np.array(errs)


@lru_cache(maxsize=1)
def native(base: str) -> tuple[Path, np.ndarray]:
    """The simulated session (made once per test run under ``base``) and the errors of
    ``process`` on it."""
    root = Path(base) / "session"
    if not (root / "session.json").is_file():
        simulate_scenario(SCENARIO, root, seed=SEED)
    res = process_session(root, Path(base) / "native", overlay=False, report=False)
    return root, target_errors(root, res.targets)


def roundtrip_errors(fmt: str, base: Path, work: Path, markers: bool = True, **options):
    """(native errors (K,), imported errors (K,), import report) for format ``fmt``. ``base``: a
    folder shared by the test run (``tmp_path_factory.getbasetemp()``); ``work``: this test's."""
    session, native_err = native(str(base))
    if fmt == "pupil-core" and "marker_size_mm" not in options:      # Pupil's head poses are in marker sides
        options["marker_size_mm"] = json.loads((session / "markers.json").read_text())["marker_size_mm"]
    export_recording(session, work / "recording", fmt)
    opts = ImportOptions(markers=session / "markers.json" if markers else None, **options)
    _, report = import_recording(work / "recording", work / "imported", fmt, opts)
    res = process_session(work / "imported", work / "out", overlay=False, report=False)
    return native_err, target_errors(session, res.targets), report


def rms(errors: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(errors))))
