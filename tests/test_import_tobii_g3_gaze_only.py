"""A Tobii Pro Glasses 3 recording without recording.g3 and without video (tobii_g3.py): the
real EyeDentify3D sample (../shared/data/real/eyedentify3d_tobii_g3, PROVENANCE.md: gazedata.gz,
imudata.gz, eventdata.gz only) through import and process, and the files it keeps."""

import json
import shutil

import numpy as np
import pytest

from wearable_gaze.formats.devices import detect_format
from wearable_gaze.formats.eye_rays import read_device_gaze, read_eye_rays
from wearable_gaze.formats.tables import read_table
from wearable_gaze.formats.targets import read_target_paths, write_target_paths
from wearable_gaze.pipeline.importer import import_recording
from wearable_gaze.pipeline.process.session import process_session

G3 = "eyedentify3d_tobii_g3"


@pytest.fixture(scope="module")
def g3(tmp_path_factory, real_data_module):
    src = real_data_module / G3
    if not src.is_dir():
        pytest.skip(f"Tobii G3 sample not found at {src}")
    base = tmp_path_factory.mktemp("g3")
    manifest, report = import_recording(src, base / "s")
    return src, base / "s", manifest, report


def test_g3_without_recording_g3_is_detected_and_imported_with_a_still_head(g3):
    src, s, manifest, rep = g3
    assert detect_format(src) == "tobii-g3" and manifest["source"]["device"] == "tobii-g3"
    assert rep["missing_files"] == ["recording.g3", "scenevideo.mp4"] and rep["pose_source"] == "still_head"
    assert any("no recording.g3" in n and "nominal flip" in n and "still" in n for n in rep["notes"])
    assert rep["frames"]["position_convention"] == {"convention": "nominal flip", "confirmed": False}
    # PROVENANCE.md: 6,547 gaze lines at 100 Hz (median step 10.01 ms), t = 0.0067 ... 65.585 s
    assert rep["gazedata_lines"] == 6547 and rep["read"]["gazedata gaze lines"] == 6547
    assert manifest["eye_rate_hz"] == pytest.approx(100.0, abs=0.1)
    rays = read_eye_rays(s / "eye_rays.csv")
    assert rays.t_s[0] == pytest.approx(0.006684) and rays.t_s[-1] == pytest.approx(65.585314)
    assert rep["dropped"]["sample: no valid eye"] == 412 and len(rays) == 6547 - 412


def test_g3_real_eyes_ipd_and_the_device_gaze_on_the_cyclopean_ray(g3):
    """PROVENANCE.md: 5,347 samples have both eyes and gaze3d; IPD median 60.1 mm; the left eye's
    origin is on the wearer's left (glasses x +28.5 mm: ours, x right, negative); gaze3d lies on
    the cyclopean ray (from the origins' midpoint along the normalised sum of the directions):
    median 0.002 deg, p90 0.029 deg."""
    _, s, _, _ = g3
    rays = read_eye_rays(s / "eye_rays.csv")
    _, gaze = read_device_gaze(s / "device_gaze.csv")
    both = rays.left_valid & rays.right_valid & np.all(np.isfinite(gaze), axis=1)
    assert both.sum() == 5347
    ipd = np.linalg.norm(rays.left_origin_mm[both] - rays.right_origin_mm[both], axis=1)
    assert np.median(ipd) == pytest.approx(60.1, abs=0.05)
    assert np.median(rays.left_origin_mm[rays.left_valid, 0]) < -25 < 25 < np.median(
        rays.right_origin_mm[rays.right_valid, 0])
    mid = 0.5 * (rays.left_origin_mm[both] + rays.right_origin_mm[both])
    fused = rays.left_direction[both] + rays.right_direction[both]
    fused /= np.linalg.norm(fused, axis=1, keepdims=True)
    v = gaze[both] - mid
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    angle = np.degrees(np.arccos(np.clip(np.sum(v * fused, axis=1), -1, 1)))
    assert np.median(angle) < 0.0025 and np.percentile(angle, 90) < 0.03


def test_g3_imu_and_sync_events_are_kept(g3):
    src, s, manifest, rep = g3
    assert manifest["files"]["device_imu"] == "device/imudata.gz"
    assert (s / "device" / "imudata.gz").read_bytes() == (src / "imudata.gz").read_bytes()
    ev = read_table(s / manifest["files"]["device_events"], ["t"], text_columns=("type", "direction", "value"))
    # PROVENANCE.md: 18 syncport out events, 0.11, 0.61, ... 2.61 s, then pulses at about 10 ... 60 s
    assert len(ev["t"]) == 18 and rep["events"]["events"] == 18 and set(ev["type"]) == {"syncport"}
    assert set(ev["direction"]) == {"out"} and ev["t"][0] == pytest.approx(0.114832)
    np.testing.assert_allclose(ev["t"][:6], [0.11, 0.61, 1.11, 1.61, 2.11, 2.61], atol=0.01)
    assert [int(v) for v in ev["value"][:2]] == [1, 0]


def test_g3_goes_through_process_with_no_failed_step(g3):
    """A still head: the lines' vergence only. process wrote moving targets' paths with depth
    variances up to 5.6e11 mm^2 (a depth sd of 750 m along near-parallel lines) and its export and
    report then refused target_paths.csv (the reader's 1e10 bound is for mm, not mm^2)."""
    _, s, _, _ = g3
    res = process_session(s, s.parent / "out")
    summary = json.loads((s.parent / "out" / "summary.json").read_text())
    assert summary["failed_steps"] == [] and summary["problems"] == []
    assert len(res.targets) > 0 and (s.parent / "out" / "report.html").is_file()
    for t in res.targets:                                          # each has a direction, ahead
        d = np.asarray(t["position_mm"] if t["position_mm"] is not None else t["direction"]["unit"], float)
        assert np.all(np.isfinite(d)) and d[2] > 0
        assert t.get("moving") or t["direction"]["cone95_deg"] > 0    # a static one: its direction and cone


def test_g3_answers_every_fixation_of_its_still_head(g3):
    """Issue 27: with a still head the eyes' vergence alone fixes depth, and a far fixation's rays
    meet behind the head or not at all: such a fixation was dropped ('degenerate', no target);
    now every static fixation is a target with its direction, and those are direction-only."""
    from wearable_gaze.formats.fixations_table import read_fixations_csv

    _, s, _, _ = g3
    out = s.parent / "out"
    if not (out / "fixations.csv").is_file():
        process_session(s, out)
    fx = read_fixations_csv(out / "fixations.csv")
    assert len(fx["fixation_id"]) >= 30 and (fx["target_id"] >= 0).all(), list(fx["status"])
    assert "direction-only" in set(fx["status"])


def test_target_paths_keep_a_still_heads_depth_variance(tmp_path):
    cov = np.diag([1e4, 1e4, 5.64308e11])[None]
    write_target_paths(tmp_path / "p.csv", {3: (np.array([1.0]), np.array([[0.0, 0.0, 15000.0]]), cov)})
    t, x, c = read_target_paths(tmp_path / "p.csv")[3]
    assert c[0, 2, 2] == pytest.approx(5.64308e11)


def test_g3_with_a_recording_g3_without_calibration_keeps_imu_and_events(g3, tmp_path):
    src = tmp_path / "rec"
    shutil.copytree(g3[0], src, ignore=shutil.ignore_patterns("*.md", "LICENSE"))
    (src / "recording.g3").write_text(json.dumps({"gaze": {"file": "gazedata.gz"}, "imu": {"file": "imudata.gz"},
                                                  "events": {"file": "eventdata.gz"}, "scenecamera": {}}))
    manifest, rep = import_recording(src, tmp_path / "s")
    assert rep["missing_files"] == ["scenevideo.mp4"] and rep["events"]["events"] == 18
    assert "device_imu" in manifest["files"] and not any("no recording.g3" in n for n in rep["notes"])
