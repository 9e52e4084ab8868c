"""Pupil Core (formats/devices/pupil_core.py): the Tufts gaze-depth table (Pupil-Core columns, a
rejection test), malformed exports, the head-pose direction, and simulated sessions written as a
Player export by the module's writer and read back."""

import json
import shutil

import cv2
import numpy as np
import pytest
from helpers import one_line_error, run_import, walkabout_recording

from wearable_gaze.formats.devices import detect_format
from wearable_gaze.formats.devices import pupil_core as pc
from wearable_gaze.formats.eye_rays import read_device_gaze, read_eye_rays
from wearable_gaze.formats.poses import read_poses_csv
from wearable_gaze.formats.video import read_frame_times

TUFTS = "tufts_gaze_depth/test.csv"
SAMPLE_DROPS = ("gaze_timestamp", "confidence", "eye centres outside", "no usable eye", "repeated", "out of order",
                "no head pose", "fewer cells")


def sample_drops(report):
    return sum(n for k, n in report["dropped"].items() if k.startswith(SAMPLE_DROPS))


# a plausible binocular row: eye0 (right) at +x, eye1 (left) at -x, 62 mm apart, looking ahead
RIGHT = [31.0, 16.0, -22.0, 0.05, 0.02, 0.998]
LEFT = [-31.0, 15.0, -21.0, 0.08, 0.02, 0.996]


def write_gaze(folder, rows, columns=None):
    """A gaze_positions.csv of ``rows`` (dicts: 't', 'conf', 'e0', 'e1' (6 cells or None), 'gp')."""
    columns = columns or pc.GAZE_COLUMNS
    folder.mkdir(parents=True, exist_ok=True)
    lines = [",".join(columns)]
    for r in rows:
        cells = {"gaze_timestamp": r.get("t", ""), "world_index": 0, "confidence": r.get("conf", 0.99),
                 "norm_pos_x": 0.5, "norm_pos_y": 0.5, "base_data": "1.0-0 1.0-1"}
        for a, v in zip("xyz", r.get("gp", (10.0, 20.0, 900.0)), strict=True):
            cells[f"gaze_point_3d_{a}"] = v
        for e in (0, 1):
            vals = r.get(f"e{e}", RIGHT if e == 0 else LEFT)
            for name, v in zip(pc.EYE_COLUMNS[e], vals or [""] * 6, strict=True):
                cells[name] = v
        lines.append(",".join(str(cells[c]) for c in columns))
    (folder / pc.GAZE_FILE).write_text("\n".join(lines) + "\n")
    return folder


# --- the Tufts table: Pupil-Core columns, messy rows -----------------------------------------------

def test_tufts_rows_are_counted_with_reasons_and_never_used(real_data, tmp_path):
    src = real_data / TUFTS
    rep = run_import(pc, src, tmp_path / "s")
    d = rep["dropped"]
    # the research's own counts (docs/devices/tobii-pupil.md 3.7): Pupil's default centres and eye1 far away
    assert d["left eye (eye1): eye centre is Pupil's default (-40.0, 15.0, -20.0) mm (3D eye model not fitted)"] == 4025
    assert d["right eye (eye0): eye centre is Pupil's default (20.0, 15.0, -20.0) mm (3D eye model not fitted)"] == 1460
    assert d["left eye (eye1): eye centre more than 100 mm from the world camera"] == 3744
    # the rows whose eye0 is the default have eye1 at its default too: no eye left
    assert d["no usable eye (per-eye reasons above, or no eye cells)"] == 1460
    assert d["eye centres outside 40-80 mm apart"] == 874
    assert d["right eye (eye0): gaze normal points backwards (z < 0)"] == 1483
    assert d["left eye (eye1): gaze normal points backwards (z < 0)"] == 508
    assert rep["read"] == {"test.csv rows": 10957}
    assert rep["eye_samples_written"] == 8623 == 10957 - sample_drops(rep)
    assert rep["pose_source"] == "still_head" and rep["clock_offset_s"] == 0.0
    assert any("no gaze_timestamp" in n and "invented" in n for n in rep["notes"])
    assert any("no confidence column" in n for n in rep["notes"])
    rays = read_eye_rays(tmp_path / "s" / "eye_rays.csv")
    # nothing implausible got in: no default centre, none beyond 100 mm, binocular pairs 40-80 mm apart
    for o, v, prior in ((rays.right_origin_mm, rays.right_valid, pc.EYE_PRIOR_MM[0]),
                        (rays.left_origin_mm, rays.left_valid, pc.EYE_PRIOR_MM[1])):
        assert not np.any(np.all(np.abs(o[v] - prior) < 1e-3, axis=1))
        assert np.linalg.norm(o[v], axis=1).max() <= 100.0
    both = rays.left_valid & rays.right_valid
    sep = np.linalg.norm(rays.left_origin_mm[both] - rays.right_origin_mm[both], axis=1)
    assert 40.0 - 1e-3 <= sep.min() and sep.max() <= 80.0 + 1e-3
    # eye0 is the right eye: right origins at +x of the left ones in every binocular sample
    assert np.all(rays.right_origin_mm[both, 0] > rays.left_origin_mm[both, 0])
    assert (both.sum(), (rays.right_valid & ~rays.left_valid).sum(), (rays.left_valid & ~rays.right_valid).sum()) \
        == (323, 6817, 1483)        # checked by an independent numpy pass over the file
    # invented times: file order at 200 Hz, the dropped rows' slots left empty
    k = rays.t_s * pc.UNTIMED_RATE_HZ
    assert np.allclose(k, np.round(k), atol=1e-6) and round(k[-1]) == 10956


def test_tufts_through_import_and_process_shows_its_rays_measure_no_depth(real_data, tmp_path):
    from wearable_gaze.pipeline.importer import import_recording
    from wearable_gaze.pipeline.process.session import process_session

    manifest, _ = import_recording(real_data / TUFTS, tmp_path / "s", "pupil-core")
    assert manifest["source"]["pose_source"] == "still_head"
    res = process_session(tmp_path / "s", tmp_path / "out", overlay=False, report=False)
    labels_mm = 1000 * np.genfromtxt(real_data / TUFTS, delimiter=",", skip_header=1)[:, -1]
    dist = [np.linalg.norm(t["position_mm"]) for t in res.targets if t["status"] == "ok"]
    # the kept rows' lines meet within ~0.2 m of the world camera (research: median 0.019 m), while
    # every label is a target 1.18-6.92 m away: the table's eye rays do not measure depth. Most
    # fixations are monocular, a still head's lines from one eye centre (origins within 4 mm):
    # answered by their direction alone ('direction-only'), also where those lines meet nearer
    # than anyone fixates (0-56 mm: the eye centre they share, no parallax; these were
    # 'too-near', not answered, before: 25 of 78 fixations); a target whose 95 % region reaches
    # past twice its distance is 'unresolved', its point no answer either
    assert max(dist, default=0.0) < 200.0 and labels_mm.min() > 1000.0
    assert {t["status"] for t in res.targets} <= {"ok", "too-near", "unresolved", "direction-only"}
    from estimator import Status, estimate
    from wearable_gaze.formats.viewlines import read_viewlines_csv
    fix = [seg.samples for seg in read_viewlines_csv(tmp_path / "out" / "viewlines.csv") if seg.key >= 0]
    ests = [estimate(f, "ml") for f in fix]
    status = [e.status for e in ests]
    one_place = [e for e in ests if "seen from one place" in e.reason]
    assert len(fix) >= 3 and len(one_place) >= 5, status
    assert all(e.status is Status.DIRECTION_ONLY and e.direction.depth95_mm[0] >= 70 for e in one_place)
    assert all(st in (Status.OK, Status.TOO_NEAR, Status.DIRECTION_ONLY) for st in status)
    assert sum(t["status"] == "ok" for t in res.targets) <= sum(st == Status.OK for st in status)


def test_tufts_folder_without_gaze_positions_names_the_fix(real_data, tmp_path):
    one_line_error(pc, real_data / "tufts_gaze_depth", tmp_path / "s",
                   match="no gaze_positions.csv.*pass the CSV file itself")


# --- detection and malformed exports ---------------------------------------------------------------

def test_detect_finds_recordings_exports_and_nothing_else(tmp_path):
    write_gaze(tmp_path / "rec" / "exports" / "003", [{"t": 1.0}])
    assert pc.detect(tmp_path / "rec") and pc.detect(tmp_path / "rec" / "exports" / "003")
    assert detect_format(tmp_path / "rec") == "pupil-core"
    (tmp_path / "bare").mkdir()
    (tmp_path / "bare" / "info.player.json").write_text("{}")
    assert pc.detect(tmp_path / "bare")
    assert not pc.detect(tmp_path / "rec" / "exports" / "003" / pc.GAZE_FILE)
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "gaze.csv").write_text("t\n1\n")
    assert not pc.detect(tmp_path / "other")


def test_the_last_export_is_read_and_named(tmp_path):
    write_gaze(tmp_path / "rec" / "exports" / "000", [{"t": 1.0}])
    write_gaze(tmp_path / "rec" / "exports" / "001", [{"t": 1.0}, {"t": 1.01}])
    rep = run_import(pc, tmp_path / "rec", tmp_path / "s")
    assert rep["eye_samples_written"] == 2
    assert any("read the last, exports/001" in n for n in rep["notes"])


def test_bad_rows_are_counted_per_reason(tmp_path):
    rows = [{"t": 10.00}, {"t": 10.01, "conf": 0.3}, {"t": "nan"}, {"t": ""},
            {"t": 10.02, "e0": [20.0, 15.0, -20.0] + RIGHT[3:]},            # right eye default -> left only
            {"t": 10.03, "e1": [-250.0, 20.0, -300.0] + LEFT[3:]},           # left too far -> right only
            {"t": 10.04, "e0": RIGHT[:3] + [0.0, 0.0, -1.0]},                 # right looks backwards
            {"t": 10.05, "e0": RIGHT[:3] + [0.5, 0.5, 0.5]},                  # not a unit normal
            {"t": 10.06, "e0": ["nan"] * 3 + RIGHT[3:]},                      # NaN centre
            {"t": 10.07, "e0": [5.0] + RIGHT[1:], "e1": [-5.0] + LEFT[1:]},  # 10 mm apart -> both go
            {"t": 10.08, "e0": None},                                          # monocular left: kept
            {"t": 10.09, "e0": None, "e1": None},                              # no eye cells
            {"t": 10.10}, {"t": 10.10, "e1": None},                            # repeat: the binocular stays
            {"t": 11.50}, {"t": 10.20}, {"t": 12.0}]                           # 10.20 < 11.50 - 1 s: too late
    rep = run_import(pc, write_gaze(tmp_path / "exp", rows), tmp_path / "s")
    d = rep["dropped"]
    assert d["confidence below 0.6"] == 1 and d["gaze_timestamp empty or not finite"] == 2
    assert d["right eye (eye0): eye centre is Pupil's default (20.0, 15.0, -20.0) mm (3D eye model not fitted)"] == 1
    assert d["left eye (eye1): eye centre more than 100 mm from the world camera"] == 1
    assert d["right eye (eye0): gaze normal points backwards (z < 0)"] == 1
    assert d["right eye (eye0): gaze normal not a unit vector"] == 1
    assert d["right eye (eye0): non-finite centre or normal"] == 1
    assert d["eye centres outside 40-80 mm apart"] == 1
    assert d["no usable eye (per-eye reasons above, or no eye cells)"] == 1
    assert d["repeated gaze_timestamp (the sample with more eyes, then more confidence, kept)"] == 1
    assert d["gaze_timestamp more than 1 s out of order"] == 1
    assert rep["read"][f"{pc.GAZE_FILE} rows"] == len(rows)
    assert rep["eye_samples_written"] == len(rows) - sample_drops(rep) == 10
    r = read_eye_rays(tmp_path / "s" / "eye_rays.csv")
    t = r.t_s + rep["clock_offset_s"]
    assert rep["clock_offset_s"] == 10.0
    assert np.allclose(t, [10.0, 10.02, 10.03, 10.04, 10.05, 10.06, 10.08, 10.10, 11.5, 12.0])
    assert r.left_valid.tolist() == [1, 1, 0, 1, 1, 1, 1, 1, 1, 1]
    assert r.right_valid.tolist() == [1, 0, 1, 0, 0, 0, 0, 1, 1, 1]
    assert np.allclose(r.right_origin_mm[0], RIGHT[:3]) and np.allclose(r.left_origin_mm[0], LEFT[:3])
    tg, g = read_device_gaze(tmp_path / "s" / "device_gaze.csv")
    assert np.allclose(tg, r.t_s) and np.isnan(g[6]).all() and np.allclose(g[0], [10, 20, 900])


def test_rows_out_of_order_within_a_second_are_sorted_across_chunks(tmp_path, monkeypatch):
    monkeypatch.setattr(pc, "CHUNK_ROWS", 3)
    t = [5.00, 5.01, 5.03, 5.02, 5.05, 5.04, 5.06, 5.08, 5.07]       # the swaps straddle the 3-row chunks
    rep = run_import(pc, write_gaze(tmp_path / "exp", [{"t": x} for x in t]), tmp_path / "s")
    r = read_eye_rays(tmp_path / "s" / "eye_rays.csv")
    assert np.allclose(r.t_s + 5.0, sorted(t)) and rep["dropped"] == {}
    assert rep["clock_offset_s"] == 5.0


@pytest.mark.parametrize("mutate, match", [
    (lambda p: p.write_text(",".join(c for c in pc.GAZE_COLUMNS if c != "gaze_normal1_z") + "\n1,2\n"),
     "missing column.*gaze_normal1_z"),
    (lambda p: p.write_text(p.read_text().replace("0.996", "abc", 1)), "line 2, column gaze_normal1_z: 'abc'"),
])
def test_structural_problems_give_one_line(tmp_path, mutate, match):
    exp = write_gaze(tmp_path / "exp", [{"t": 1.0}, {"t": 1.01}])
    mutate(exp / pc.GAZE_FILE)
    one_line_error(pc, exp, tmp_path / "s", match=match)


def test_a_truncated_last_row_is_dropped_and_counted(tmp_path):
    exp = write_gaze(tmp_path / "exp", [{"t": 1.0}, {"t": 1.01}, {"t": 1.02}])
    text = (exp / pc.GAZE_FILE).read_text()
    (exp / pc.GAZE_FILE).write_text(text[:text.rstrip().rfind(",") - 40])
    rep = run_import(pc, exp, tmp_path / "s")
    assert rep["dropped"] == {"row with fewer cells than the header (truncated file?)": 1}
    assert rep["eye_samples_written"] == 2


def test_an_export_with_no_usable_row_says_why(tmp_path):
    exp = write_gaze(tmp_path / "exp", [{"t": 1.0, "conf": 0.1}, {"t": 1.1, "conf": 0.2}])
    one_line_error(pc, exp, tmp_path / "s", match="no usable eye sample.*2 confidence below 0.6")


def test_old_recordings_and_empty_folders_name_the_fix(tmp_path):
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "pupil_data").write_bytes(b"\x80")
    one_line_error(pc, tmp_path / "old", tmp_path / "s1", match="older than v1.8.*Pupil Player")
    (tmp_path / "empty").mkdir()
    one_line_error(pc, tmp_path / "empty", tmp_path / "s2", match="no gaze_positions.csv.*Raw Data Exporter")


# --- head poses ------------------------------------------------------------------------------------

def pupil_pose_row(T_world_from_cam, marker_mm):
    """A head_pose_tracker_poses.csv row as Pupil computes it: solvePnP gives the extrinsics of the
    world in the camera (T_cam_from_world); get_camera_pose writes -rvec and -R^T t."""
    T_cw = np.linalg.inv(T_world_from_cam)
    T_cw[:3, 3] /= marker_mm
    rvec = cv2.Rodrigues(T_cw[:3, :3])[0].ravel()
    return [*(-rvec), *(-(T_cw[:3, :3].T @ T_cw[:3, 3])), 0.0, 0.0, 0.0]


def write_poses(exp, t, rows, side=1.0):
    lines = [",".join(pc.POSE_COLUMNS)] + [",".join(map(str, [ti, *r])) for ti, r in zip(t, rows, strict=True)]
    (exp / pc.POSES_FILE).write_text("\n".join(lines) + "\n")
    sq = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]]) * side
    model = [",".join(pc.MODEL_COLUMNS)] + [",".join(map(str, [i, *(sq + i).ravel()])) for i in (7, 9)]
    (exp / pc.MODEL_FILE).write_text("\n".join(model) + "\n")


def test_head_poses_are_camera_in_world_scaled_by_the_marker_size(tmp_path, rng):
    from scipy.spatial.transform import Rotation

    t = 100.0 + np.arange(6) / 30
    truth = np.tile(np.eye(4), (6, 1, 1))
    truth[:, :3, :3] = Rotation.from_rotvec(rng.normal(0, 0.4, (6, 3))).as_matrix()
    truth[:, :3, 3] = rng.normal(0, 500, (6, 3))
    rows = [pupil_pose_row(T, 42.0) for T in truth]
    rows[3] = ["nan"] * 9                                                 # the tracker lost the markers
    exp = write_gaze(tmp_path / "exp", [{"t": x} for x in 100.0 + np.arange(0, 0.2, 0.005)])
    write_poses(exp, t, rows)
    rep = run_import(pc, exp, tmp_path / "s", marker_size_mm=42.0)
    tp, _, T, _ = read_poses_csv(tmp_path / "s" / "head_poses.csv")
    assert np.allclose(tp, t - 100.0)
    ok = np.arange(6) != 3
    assert np.allclose(T[ok], truth[ok], atol=1e-6) and np.isnan(T[3]).all()
    assert rep["pose_source"] == "device"
    assert rep["dropped"]["head pose row without a pose (the tracker lost the markers)"] == 1
    # eye samples need a valid pose within 0.05 s on both sides: none after the last pose (+0.1667 s),
    # none in the gap of the lost pose (0.0667-0.1333 s) farther than 0.05 s from either end
    r = read_eye_rays(tmp_path / "s" / "eye_rays.csv")
    gone = [0.07, 0.075, 0.08, 0.12, 0.125, 0.13, 0.17, 0.175, 0.18, 0.185, 0.19, 0.195]
    assert np.allclose(r.t_s, [x for x in np.arange(0, 0.2, 0.005) if not np.isclose(gone, x).any()])
    assert rep["dropped"]["no head pose within 0.05 s"] == len(gone)


def test_head_poses_without_marker_size_or_in_mm_give_one_line(tmp_path):
    exp = write_gaze(tmp_path / "exp", [{"t": 1.0}])
    write_poses(exp, [1.0], [pupil_pose_row(np.eye(4), 1.0)])
    one_line_error(pc, exp, tmp_path / "s1", match="pass --marker-size-mm")
    write_poses(exp, [1.0], [pupil_pose_row(np.eye(4), 1.0)], side=50.0)
    one_line_error(pc, exp, tmp_path / "s2", match="sides are 50 units, not 1", marker_size_mm=50.0)


# --- simulated sessions written as a Player export ----------------------------------------------------

@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    return walkabout_recording(tmp_path_factory.mktemp("pupil_sim") / "session")


def test_write_then_read_gives_the_same_rays_poses_and_gaze(sim, tmp_path):
    pc.write_recording(sim, tmp_path / "rec")
    size = json.loads(sim.marker_map.read_text())["marker_size_mm"]
    rep = run_import(pc, tmp_path / "rec", tmp_path / "s", marker_size_mm=size)
    assert rep["clock_offset_s"] == pytest.approx(pc.PUPIL_EPOCH_S + sim.t[0])
    r = read_eye_rays(tmp_path / "s" / "eye_rays.csv")
    i = np.searchsorted(sim.t - sim.t[0], r.t_s - 1e-9)
    assert np.allclose((sim.t - sim.t[0])[i], r.t_s, atol=1e-9)
    written = sim.rays.left_valid | sim.rays.right_valid
    assert len(r.t_s) >= written.sum() - 2                                   # at most the ends lack a pose
    assert (r.left_valid == sim.rays.left_valid[i]).all() and (r.right_valid == sim.rays.right_valid[i]).all()
    for got, want, v in ((r.left_origin_mm, sim.rays.left_origin_mm, r.left_valid),
                         (r.left_direction, sim.rays.left_direction, r.left_valid),
                         (r.right_origin_mm, sim.rays.right_origin_mm, r.right_valid),
                         (r.right_direction, sim.rays.right_direction, r.right_valid)):
        assert np.allclose(got[v], want[i][v], atol=1e-4)
    assert np.linalg.norm(r.right_origin_mm[r.right_valid][:, 0]).min() > 0        # the right eye at +x
    tp, _, T, _ = read_poses_csv(tmp_path / "s" / "head_poses.csv")
    j = np.searchsorted(sim.t - sim.t[0], tp - 1e-9)
    same = np.isclose((sim.t - sim.t[0])[np.clip(j, 0, len(sim.t) - 1)], tp, atol=1e-9)
    assert same.sum() > 0.9 * len(tp) and np.allclose(T[same], sim.T_world_from_head[j[same]], atol=1e-6)
    tg, g = read_device_gaze(tmp_path / "s" / "device_gaze.csv")
    both = sim.rays.left_valid[i] & sim.rays.right_valid[i]
    assert np.allclose(g[both], sim.gaze_head_mm[i][both], atol=1e-3) and np.isnan(g[~both]).all()


def test_without_poses_the_world_video_is_tracked_or_the_head_is_still(sim, tmp_path):
    pc.write_recording(sim, tmp_path / "rec")
    exp = tmp_path / "rec" / "exports" / "000"
    (exp / pc.POSES_FILE).unlink()
    rep = run_import(pc, tmp_path / "rec", tmp_path / "still")
    assert rep["pose_source"] == "still_head" and any("--camera" in n and "--markers" in n for n in rep["notes"])
    cam = tmp_path / "camera.json"
    shutil.copyfile(sim.video.parent / "truth" / "camera.json", cam)
    rep = run_import(pc, tmp_path / "rec", tmp_path / "tracked", camera=cam, markers=sim.marker_map)
    assert rep["pose_source"] == "scene_video"
    _, ft = read_frame_times(tmp_path / "tracked" / "scene_timestamps.csv")
    assert np.allclose(ft, sim.frame_times - sim.t[0], atol=1e-6)
    assert (tmp_path / "tracked" / "scene.mp4").stat().st_size == sim.video.stat().st_size
    assert (tmp_path / "tracked" / "markers.json").is_file() and (tmp_path / "tracked" / "camera.json").is_file()


def test_round_trip_through_process_finds_the_targets_as_well_as_the_native_session(tmp_path_factory, tmp_path):
    from roundtrip import native, rms, roundtrip_errors

    base = tmp_path_factory.getbasetemp()
    size = json.loads((native(str(base))[0] / "markers.json").read_text())["marker_size_mm"]
    nat, got, report = roundtrip_errors("pupil-core", base, tmp_path, marker_size_mm=size)
    assert report["pose_source"] == "device" and report["dropped"].keys() <= {"no head pose within 0.05 s"}
    assert np.all(np.isfinite(got)) and rms(got) <= 1.1 * rms(nat)
