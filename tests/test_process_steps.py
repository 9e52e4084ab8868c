"""``process`` composes the steps over typed values (issue 13): it reads each input of the session
and each output of an earlier step once, hands the contents to the steps (the commands' file-level
wrappers are not used), and a cached run reads none of them."""

import json
import shutil
from collections import Counter

import numpy as np
import pytest

import wearable_gaze.pipeline.process.session as process_mod
import wearable_gaze.pipeline.process.session_cache as cache_mod
import wearable_gaze.pipeline.steps.calibrate as calibrate_mod
import wearable_gaze.pipeline.steps.track as track_mod
from wearable_gaze.pipeline.process.session import process_session
from wearable_gaze.pipeline.process.stepcache import ON_REQUEST, STEPS
from wearable_gaze.pipeline.types import TARGET_KEYS, Target
from wearable_gaze.sim.simulate import simulate_scenario

SMALL = {"base": "lab-walkabout", "duration_s": 4.0, "camera": {"resolution": [640, 360]}}
LOADERS = ("load_session", "load_camera", "load_eyes", "read_eye_csv", "load_marker_map", "read_poses_csv",
           "read_targets")


@pytest.fixture(scope="module")
def small_session(tmp_path_factory):
    root = tmp_path_factory.mktemp("steps") / "session"
    simulate_scenario(SMALL, root, seed=0)
    return root


def _count_loads(monkeypatch) -> Counter:
    calls = Counter()

    def counted(name, fn):
        def wrapper(*args, **kwargs):
            calls[name] += 1
            return fn(*args, **kwargs)
        return wrapper
    for name in LOADERS:                    # the session is loaded by process, every other file by its cache
        mod = process_mod if name == "load_session" else cache_mod
        monkeypatch.setattr(mod, name, counted(name, getattr(mod, name)))
    return calls


def test_each_input_is_read_once_and_handed_to_the_steps(small_session, tmp_path, monkeypatch):
    s = tmp_path / "s"
    shutil.copytree(small_session, s)

    def wrapper_called(*args, **kwargs):
        raise AssertionError("process called a command's file-level wrapper, which reads its files again")
    for mod, name in ((calibrate_mod, "calibrate_eyes_files"), (calibrate_mod, "viewlines_files"),
                      (track_mod, "track_video_files")):
        monkeypatch.setattr(mod, name, wrapper_called)
    calls = _count_loads(monkeypatch)
    res = process_session(s, s / "processed")                    # with the overlay: it reads camera, eyes,
    assert res.found and res.problems == [] and (s / "processed" / "overlay.mp4").is_file()   # samples, map
    # camera.json: eyes, tracking and overlay; eye.csv: view lines and overlay; the map: tracking and overlay
    assert calls == {"load_session": 1, "load_camera": 1, "load_eyes": 1, "read_eye_csv": 1, "load_marker_map": 1,
                     "read_poses_csv": 1}, calls
    assert [t.row() for t in res.found] == res.targets == json.loads((s / "processed" / "targets.json").read_text())[
        "targets"]

    calls.clear()
    again = process_session(s, s / "processed")                  # every step cached: only the targets are read
    assert set(again.skipped) == set(STEPS) - set(ON_REQUEST)
    assert calls == {"load_session": 1, "read_targets": 1}, calls
    assert again.targets == res.targets


def test_a_target_is_its_row_of_targets_json():
    row = {"target": 2, "t_start": 0.05, "t_end": 15.2, "position_mm": [77.52124581513759, -97.3, 1045.1],
           "ellipsoid95_radii_mm": [2.07, 2.08, 32.0], "n_samples": 326, "method": "voxel", "status": "ok",
           "covariance_mm2": [[1.0, 0.1, 0.0], [0.1, 1.0, 0.0], [0.0, 0.0, 120.0]], "crb_mm": 11.43,
           "fixations": [0, 4]}
    t = Target.from_row(row)
    assert t.index == 2 and t.fixations == (0, 4) and t.ok
    np.testing.assert_array_equal(t.position_mm, [77.52124581513759, -97.3, 1045.1])
    np.testing.assert_array_equal(t.covariance_mm2, row["covariance_mm2"])
    assert t.row() == row and list(t.row()) == list(TARGET_KEYS)
    assert json.dumps(t.row()) == json.dumps(row)                  # plain Python values: the same JSON text
    nan = Target.from_row(row | {"position_mm": None, "covariance_mm2": None, "status": "no_estimate"})
    assert not nan.ok and nan.row()["position_mm"] is None and nan.covariance_mm2 is None


def test_the_settings_are_one_frozen_config_with_named_presets():
    """``process``'s settings are built once, frozen (a step cannot change them under the next),
    and the presets are complete configurations differing from the default only where named."""
    import dataclasses

    from wearable_gaze.pipeline.process.stepconf import PRESETS, ProcessConfig, preset

    conf = ProcessConfig()
    with pytest.raises(dataclasses.FrozenInstanceError):
        conf.method = "ml"                                   # type: ignore[misc]
    assert PRESETS["default"] == conf and all(isinstance(c, ProcessConfig) for c in PRESETS.values())
    quick = preset("quick", sigma_deg=2.0)
    changed = {f.name for f in dataclasses.fields(conf) if getattr(quick, f.name) != getattr(conf, f.name)}
    assert changed == {"method", "overlay", "track_every", "sigma_deg"}, changed
    assert conf.for_session(10.0).segment_config.window == 2 and conf.for_session(None).segment_config.window == 8
    assert conf.targets_conf().segment is not None and conf.tracking_conf().every == 2
    with pytest.raises(KeyError):
        preset("no such preset")
