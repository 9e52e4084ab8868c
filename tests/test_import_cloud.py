"""Pupil Cloud's Timeseries export (``--format pupil-cloud``, issue 26): a 2D-only tracker's gaze
as one cyclopean view line per sample, on the real Invisible export and through the simulator."""

import json
import shutil

import numpy as np
import pytest
from helpers import one_line_error, run_import

from calibration.cvcompat import undistort_points
from wearable_gaze.formats.devices import detect_format, pupil_cloud
from wearable_gaze.formats.eye_rays import read_eye_rays

FOLLOW = "gazemapper_example2/data/follow/2024-11-08_11-27-53-8deee3c8"


def test_angles_and_directions_are_inverse_and_in_opencv_axes(rng):
    d = rng.normal(size=(200, 3))
    d[:, 2] = np.abs(d[:, 2]) + 0.2
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    az, el = pupil_cloud.angles_from_direction(d)
    assert np.allclose(pupil_cloud.direction_from_angles(az, el), d, atol=1e-12)
    right_up = pupil_cloud.direction_from_angles([10.0], [20.0])[0]
    assert right_up[0] > 0 and right_up[1] < 0 and right_up[2] > 0        # x right, y down: up is -y


def test_the_real_invisible_export_imports_as_cyclopean_lines(real_data, tmp_path):
    src = real_data / FOLLOW
    assert detect_format(src) == "pupil-cloud"
    rep = run_import(pupil_cloud, src, tmp_path / "s")
    gaze = src / "gaze.csv"
    rows = gaze.read_text().splitlines()[1:]
    blink = sum(1 for r in rows if r.split(",")[7].strip())
    assert rep["read"]["gaze.csv rows"] == len(rows) == 23958
    assert rep["dropped"]["inside a blink (blink id)"] == blink
    assert rep["eye_samples_written"] == len(rows) - blink
    assert rep["rays"] == "cyclopean" and rep["pose_source"] == "still_head"
    assert any("direction but no depth" in n for n in rep["notes"])
    assert abs(rep["clock_offset_s"] - 1731061673.794) < 1e-6
    samples = read_eye_rays(tmp_path / "s" / "eye_rays.csv")
    assert samples.left_valid.all() and not samples.right_valid.any()
    assert np.allclose(samples.left_origin_mm, 0.0)
    # the directions are the export's pixels undistorted through its camera, to 1e-3 deg
    K, D = pupil_cloud.read_scene_camera(src / "scene_camera.json")
    keep = [r.split(",") for r in rows if not r.split(",")[7].strip()]
    xy = undistort_points(np.array([[float(c[3]), float(c[4])] for c in keep[::97]]), K, D)
    d = np.column_stack([xy, np.ones(len(xy))])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    cos = np.sum(d * samples.left_direction[::97], axis=1)
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 1e-3
    for name in ("device_fixations.csv", "device_blinks.csv"):
        assert (tmp_path / "s" / name).read_bytes() == (src / name.removeprefix("device_")).read_bytes()


def test_write_then_read_gives_the_written_directions(tmp_path):
    from helpers import walkabout_recording

    sim = walkabout_recording(tmp_path / "sim")
    pupil_cloud.write_recording(sim, tmp_path / "rec")
    rep = run_import(pupil_cloud, tmp_path / "rec", tmp_path / "out")
    got = read_eye_rays(tmp_path / "out" / "eye_rays.csv")
    want = pupil_cloud._cyclopean(sim)
    ok = np.all(np.isfinite(want), axis=1)
    assert rep["eye_samples_written"] == int(ok.sum()) == len(got.t_s)
    assert np.allclose(got.t_s, sim.t[ok], atol=1e-6)
    assert np.allclose(got.left_direction, want[ok], atol=1e-7)
    # the cyclopean direction's error is the two eyes' mean: it points at the gazed point to ~1 deg
    g = sim.gaze_head_mm[ok] / np.linalg.norm(sim.gaze_head_mm[ok], axis=1, keepdims=True)
    err = np.degrees(np.arccos(np.clip(np.sum(g * got.left_direction, axis=1), -1, 1)))
    assert 0.05 < np.median(err) < 2.0
    assert rep["pose_source"] == "still_head"
    with_markers = run_import(pupil_cloud, tmp_path / "rec", tmp_path / "out2", markers=sim.marker_map)
    assert with_markers["pose_source"] == "scene_video"


def test_damaged_exports_are_one_line(tmp_path):
    from helpers import walkabout_recording

    sim = walkabout_recording(tmp_path / "sim")
    pupil_cloud.write_recording(sim, tmp_path / "rec")
    for i, (name, edit, needle) in enumerate([
            ("scene_camera.json", lambda s: json.dumps({"camera_matrix": "x"}), "camera_matrix"),
            ("gaze.csv", lambda s: s.replace(",1700", ",abc", 1), "not integer nanoseconds"),
            ("gaze.csv", lambda s: s.replace("azimuth [deg]", "az").replace("gaze x [px]", "gx"), "columns")]):
        bad = tmp_path / f"bad{i}"
        shutil.copytree(tmp_path / "rec", bad)
        (bad / name).write_text(edit((bad / name).read_text()))
        one_line_error(pupil_cloud, bad, tmp_path / f"out{i}", needle)


@pytest.mark.slow
def test_a_walking_2d_only_session_finds_its_targets_within_twice_the_binocular_error(tmp_path_factory, tmp_path):
    """Issue 26: the simulated walk exported with 2D gaze only (one cyclopean line per sample),
    its scene video tracked with the room's markers: the head's motion alone fixes each target,
    within 2x the RMS error of the same session's binocular processing."""
    from roundtrip import rms, roundtrip_errors

    nat, got, report = roundtrip_errors("pupil-cloud", tmp_path_factory.getbasetemp(), tmp_path)
    assert report["pose_source"] == "scene_video" and report["rays"] == "cyclopean"
    assert np.all(np.isfinite(got)) and rms(got) <= 2.0 * rms(nat), (got, nat)
    # the report says where the depth came from, and how far the head moved in each fixation
    import re

    from wearable_gaze.pipeline.process.session import process_session

    process_session(tmp_path / "imported", tmp_path / "out", overlay=False)
    page = (tmp_path / "out" / "report.html").read_text()
    assert "comes from the head&#x27;s motion alone" in page or "comes from the head's motion alone" in page
    head = re.findall(r"<th>(.*?)</th>", page.split('id="targets"')[1].split("</tr>")[0])
    k = head.index("head travel in each fixation (mm)")
    rows = page.split('id="targets"')[1].split("</table>")[0].split("<tr>")[2:]
    travel = [float(v) for r in rows for v in re.findall(r"<td>(.*?)</td>", r)[k].split(", ") if v]
    assert travel and max(travel) > 100                                  # the walk: the head moved


def test_an_export_with_neon_eye_states_gives_per_eye_visual_axes(tmp_path):
    """With ``3d_eye_states.csv`` (Neon) each eye is its own line, turned into a visual axis by
    the kappa offset fitted on the export's gaze ray at 1 m: the simulated eyes' axes already
    point at the target, so the fitted offsets are small and the rays meet in front."""
    from helpers import walkabout_recording

    sim = walkabout_recording(tmp_path / "sim")
    pupil_cloud.write_recording(sim, tmp_path / "rec", eye_states=True)
    rep = run_import(pupil_cloud, tmp_path / "rec", tmp_path / "out")
    assert rep["rays"] == "binocular" and rep["kappa"]["method"] == "cyclopean-ray"
    assert rep["kappa"]["depth_mm"] == 1000.0
    for side in ("left", "right"):
        assert np.all(np.abs(rep["kappa"][f"{side}_deg"]) < 2.0), rep["kappa"]
    assert rep["kappa"]["rays_after"]["in_front_share"] > 0.9
    got = read_eye_rays(tmp_path / "out" / "eye_rays.csv")
    assert got.left_valid.sum() > 0.9 * len(got.t_s) and got.right_valid.sum() > 0.9 * len(got.t_s)
    assert np.allclose(got.left_origin_mm[got.left_valid], sim.rays.left_origin_mm[np.isin(sim.t, got.t_s)][
        got.left_valid], atol=1e-3)
    assert any("kappa offset" in n for n in rep["notes"])


def test_export_recording_eye_states_writes_a_neon_export_that_imports_per_eye(tmp_path, capsys):
    """``export-recording --format pupil-cloud --eye-states`` (the CLI) writes the Neon layout
    with ``3d_eye_states.csv``; without the option, Invisible's (2D gaze only): each imports
    as what it is, binocular or cyclopean."""
    from helpers import walkabout_recording

    from wearable_gaze.cli import main

    walkabout_recording(tmp_path / "sim")
    for extra, rays in (([], "cyclopean"), (["--eye-states"], "binocular")):
        rec = tmp_path / f"rec{len(extra)}"
        assert main(["export-recording", str(tmp_path / "sim"), "-o", str(rec), "--format", "pupil-cloud",
                     *extra]) == 0
        assert (rec / "3d_eye_states.csv").is_file() == bool(extra)
        assert run_import(pupil_cloud, rec, tmp_path / f"out{len(extra)}")["rays"] == rays


def test_the_real_invisible_export_goes_through_process_with_a_direction_per_target(real_data, tmp_path):
    """Issue 26/27: one cyclopean line per sample from a still head (no video) fixes each
    fixation's direction, never its depth: every fixation the segmenter finds is a
    direction-only target whose depth interval is the whole of it (before: no target at all,
    exit status 2)."""
    from wearable_gaze.pipeline.process.session import process_session

    run_import(pupil_cloud, real_data / FOLLOW, tmp_path / "s")
    res = process_session(tmp_path / "s", tmp_path / "out", overlay=False, report=False)
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["failed_steps"] == [] and res.exit_status == 0
    assert len(res.targets) >= 20
    for t in res.targets:
        assert t["status"] == "direction-only" and t["position_mm"] is None
        d = t["direction"]
        assert d["unit"][2] > 0.8 and 0 < d["cone95_deg"] < 6.0            # ahead; 1.2-4.8 deg measured
        assert d["depth95_mm"] == [70.0, None]                               # a still head: no depth
