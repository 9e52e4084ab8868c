"""The file formats, one module each in wearable_gaze/formats (issue 13).

tests/data/formats_1390a4c/ holds files the code of commit 1390a4c wrote, before the formats had
their modules (a simulated session, seed 5, 1.5 s, 12 board views; calibrate-camera, calibrate-eyes,
track and the marker-sheet template on it; eye_calibration.csv cut to its first 40 rows; the same
session's board.json, walls.json, truth/targets.json and truth/eyes.json (as truth_*.json) and the
targets.json, targets.csv, estimates.csv and target_labels.npy of ``process`` on it; targets_ml.*:
three rows, one without an estimate, written by 1390a4c's targets writer). Each is read with its
format's reader and written with its writer: the bytes must be the old ones. The
live recorder's streamed rows must be the table writer's rows, and each format's name and the
video writer must live only in wearable_gaze/formats.
"""

import json
import os
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.camera import CameraCalibration
from estimator.frames import rotation_about_axis
from wearable_gaze.errors import UserError
from wearable_gaze.formats.board import read_board, write_board
from wearable_gaze.formats.camera import calibration_dict, camera_dict, load_camera, write_camera
from wearable_gaze.formats.eye_samples import EYE_HEADER, EyeSamples, eye_csv_line, read_eye_csv, write_eye_csv
from wearable_gaze.formats.eyes import eyes_dict, load_eyes, write_eyes
from wearable_gaze.formats.images import read_gray_image, write_image
from wearable_gaze.formats.jsonio import load_json
from wearable_gaze.formats.markermap import (
    load_marker_map,
    marker_map_dict,
    marker_map_template,
    write_marker_map,
)
from wearable_gaze.formats.poses import read_poses_csv, write_poses_csv
from wearable_gaze.formats.session import write_manifest
from wearable_gaze.formats.tables import read_table
from wearable_gaze.formats.targets import (
    ESTIMATE_COLUMNS,
    read_estimates,
    read_target_labels,
    read_targets,
    write_estimates,
    write_target_labels,
    write_targets,
)
from wearable_gaze.formats.truth import read_truth_eyes, read_truth_targets, write_truth_eyes, write_truth_targets
from wearable_gaze.formats.video import (
    FRAME_TIME_HEADER,
    frame_time_line,
    gray_frames,
    open_video_writer,
    read_frame_times,
    sampled_gray_frames,
    write_frame_times,
)
from wearable_gaze.formats.walls import read_walls, write_walls
from wearable_gaze.pipeline.types import Target

ROOT = Path(__file__).resolve().parents[1]
OLD = ROOT / "tests" / "data" / "formats_1390a4c"


def _ints(extra: dict, names) -> dict:
    return {k: (v.astype(int) if k in names else v) for k, v in extra.items()}


@pytest.mark.parametrize("name, extra", [("eye.csv", ()), ("eye_calibration.csv", ("recording", "target"))])
def test_eye_csv_written_back_as_the_old_code_wrote_it(tmp_path, name, extra):
    eye, cols = read_eye_csv(OLD / name, extra)
    write_eye_csv(tmp_path / name, eye, _ints(cols, extra))
    assert (tmp_path / name).read_bytes() == (OLD / name).read_bytes()


def test_frame_times_written_back_as_the_old_code_wrote_them(tmp_path):
    write_frame_times(tmp_path / "ts.csv", *read_frame_times(OLD / "scene_timestamps.csv"))
    assert (tmp_path / "ts.csv").read_bytes() == (OLD / "scene_timestamps.csv").read_bytes()


@pytest.mark.parametrize("name", ["head_poses.csv", "poses.csv"])
def test_poses_written_back_as_the_old_code_wrote_them(tmp_path, name):
    """A quaternion read from 12 decimals and written again from its rotation matrix may move in
    the last decimal; every other cell, the header and the line ends are the old bytes."""
    t, frames, T, extra = read_poses_csv(OLD / name)
    write_poses_csv(tmp_path / name, t, frames, T, _ints(extra, ("n_markers", "n_points")))
    ours = (tmp_path / name).read_bytes().split(b"\r\n")
    old = (OLD / name).read_bytes().split(b"\r\n")
    assert len(ours) == len(old) > 3 and ours[0] == old[0]
    for a, b in zip(ours[1:-1], old[1:-1], strict=True):
        ca, cb = a.split(b","), b.split(b",")
        assert ca[:2] == cb[:2] and ca[6:] == cb[6:] and [len(c) for c in ca] == [len(c) for c in cb]
        if cb[2] == b"":
            assert ca[2:6] == cb[2:6]
        else:
            assert np.allclose(np.array(ca[2:6], float), np.array(cb[2:6], float), rtol=0, atol=2e-12)
    assert ours[-1] == old[-1] == b""


def test_marker_map_written_back_as_the_old_code_wrote_it(tmp_path):
    mm = load_marker_map(OLD / "markers.json")
    write_marker_map(tmp_path / "m.json", marker_map_dict(mm.dictionary, mm.marker_size_mm, mm.poses, mm.labels))
    assert (tmp_path / "m.json").read_bytes() == (OLD / "markers.json").read_bytes()
    write_marker_map(tmp_path / "t.json", marker_map_template("DICT_4X4_50", 100.0, [0, 1, 2, 7]))
    assert (tmp_path / "t.json").read_bytes() == (OLD / "sheet_map_template.json").read_bytes()


def test_camera_files_written_back_as_the_old_code_wrote_them(tmp_path):
    cal = load_camera(OLD / "camera.json")                         # calibrate-camera's, with its report
    raw = json.loads((OLD / "camera.json").read_text())
    write_camera(tmp_path / "c.json", calibration_dict(cal, trusted=raw["trusted"], warnings=raw["warnings"]))
    assert (tmp_path / "c.json").read_bytes() == (OLD / "camera.json").read_bytes()
    cam = load_camera(OLD / "truth_camera.json")                   # the simulator's
    source = json.loads((OLD / "truth_camera.json").read_text())["source"]
    write_camera(tmp_path / "t.json", camera_dict(cam.camera_matrix, cam.dist_coeffs, cam.image_size, cam.model,
                                                  cam.rms_px, source=source))
    assert (tmp_path / "t.json").read_bytes() == (OLD / "truth_camera.json").read_bytes()


def test_eyes_json_written_back_as_the_old_code_wrote_it(tmp_path):
    raw = json.loads((OLD / "eyes.json").read_text())
    camera = calibration_dict(CameraCalibration.from_dict(raw["camera"]))
    write_eyes(tmp_path / "e.json", eyes_dict(camera, raw["walls"], load_eyes(OLD / "eyes.json")))
    assert (tmp_path / "e.json").read_bytes() == (OLD / "eyes.json").read_bytes()


def test_manifest_written_as_the_old_code_wrote_it(tmp_path):
    write_manifest(tmp_path, json.loads((OLD / "session.json").read_text()))
    assert (tmp_path / "session.json").read_bytes() == (OLD / "session.json").read_bytes()


def test_board_json_written_back_as_the_old_code_wrote_it(tmp_path):
    rec = read_board(OLD)
    assert rec.path == OLD / "board.json" and rec.views == ()                      # no images in OLD
    assert (rec.spec.type, rec.spec.cols, rec.spec.rows) == (rec.board["type"], rec.board["cols"], rec.board["rows"])
    assert rec.truth_T_cam_from_board.shape == (12, 4, 4)
    write_board(tmp_path, rec.board, (), rec.truth_T_cam_from_board)
    assert (tmp_path / "board.json").read_bytes() == (OLD / "board.json").read_bytes()


def test_board_views_are_the_folders_images_and_written_as_png(tmp_path):
    views = [np.full((30, 40), 50 * k, np.uint8) for k in range(3)]
    write_board(tmp_path, {"type": "chessboard", "cols": 9, "rows": 6, "square_mm": 25.0}, iter(views))
    (tmp_path / "notes.txt").write_text("not a view")
    rec = read_board(tmp_path)
    assert [p.name for p in rec.views] == ["view_000.png", "view_001.png", "view_002.png"]
    assert all(np.array_equal(read_gray_image(p), v) for p, v in zip(rec.views, views, strict=True))
    assert rec.truth_T_cam_from_board is None and "truth" not in (tmp_path / "board.json").read_text()
    (tmp_path / "board.json").write_text('{"version": 1, "board": {"type": "chessboard", "cols": 9, "rows": 1, '
                                         '"square_mm": 25}}')
    with pytest.raises(UserError, match=r"board.json: field 'board.rows' .*whole number 2-100"):
        read_board(tmp_path)


def test_walls_json_written_back_as_the_old_code_wrote_it(tmp_path):
    rec = read_walls(OLD)                                   # OLD holds eye_calibration.csv and walls.json
    assert rec.csv_path == OLD / "eye_calibration.csv" and rec.walls_path == OLD / "walls.json"
    assert [w.image for w in rec.walls] == rec.images == [OLD / f"wall_{r}.png" for r in range(3)]
    w = rec.walls[1]
    assert w.recording == 1 and w.dictionary == w.entry["dictionary"] and w.image_name == "wall_1.png"
    assert np.array_equal(w.targets_wall_mm, w.entry["targets_wall_mm"]) and w.targets_wall_mm.shape[1] == 2
    assert list(w.markers_wall_mm) == [int(k) for k in w.entry["markers_wall_mm"]]
    write_walls(tmp_path, [w.entry for w in rec.walls])
    assert (tmp_path / "walls.json").read_bytes() == (OLD / "walls.json").read_bytes()


def test_walls_image_outside_its_folder_is_refused(tmp_path):
    d = json.loads((OLD / "walls.json").read_text())
    d["recordings"][2]["image"] = "sub/../../x.png"
    (tmp_path / "walls.json").write_text(json.dumps(d))
    (tmp_path / "eye_calibration.csv").write_bytes((OLD / "eye_calibration.csv").read_bytes())
    with pytest.raises(UserError, match=r"field 'recordings\[2\]\.image'"):
        read_walls(tmp_path)
    (tmp_path / "link.png").symlink_to(tmp_path.parent / "elsewhere.png")      # a link that leaves the folder
    d["recordings"][2]["image"] = "link.png"
    (tmp_path / "walls.json").write_text(json.dumps(d))
    with pytest.raises(UserError, match=r"field 'recordings\[2\]\.image' .*leaves the folder"):
        read_walls(tmp_path)
    with pytest.raises(UserError, match="no eye_calibration.csv"):
        read_walls(tmp_path / "nowhere")


@pytest.mark.parametrize("name", ["targets", "targets_ml"])
def test_version_1_targets_are_read_into_records_and_written_as_version_2(tmp_path, name):
    """A targets.json of version 1 (flat rows, NaN for none) reads into the records of version 2,
    every value kept; written back (directly, and through ``Target``) it is version 2, valid
    against its schema, and reads back to the same records; targets.csv holds them flattened."""
    old = json.loads((OLD / f"{name}.json").read_text())
    rows = read_targets(OLD / f"{name}.json")
    assert len(rows) == len(old["targets"]) >= 1
    for r, o in zip(rows, old["targets"], strict=True):
        for got, keys in ((r["position_mm"], ("x_mm", "y_mm", "z_mm")),
                          (r["ellipsoid95_radii_mm"], ("axis1_mm", "axis2_mm", "axis3_mm"))):
            want = [o[k] for k in keys]
            assert got == want if np.all(np.isfinite(want)) else got is None
        assert r["fixations"] == [int(f) for f in o["fixations"].split(";")] and r["covariance_mm2"] is None
        assert (r["crb_mm"] is None) == (not np.isfinite(o["crb_mm"]))
    for k, some in enumerate((rows, [Target.from_row(r).row() for r in rows])):
        out = tmp_path / str(k)
        write_targets(out, some, old["method"])
        obj = load_json(out / "targets.json", "targets")
        assert obj["version"] == 2 and obj["method"] == old["method"] and read_targets(out / "targets.json") == rows
        csv_old = read_table(OLD / f"{name}.csv", ["x_mm", "y_mm", "z_mm"], ("fixations", "status"),
                             empty_ok=("x_mm", "y_mm", "z_mm", "crb_mm", "axis3_mm"))
        csv_new = read_table(out / "targets.csv", ["x_mm", "y_mm", "z_mm"], ("fixations", "status"),
                             empty_ok=("x_mm", "y_mm", "z_mm", "crb_mm", "ellipsoid95_r3_mm"))
        for c in ("x_mm", "y_mm", "z_mm", "crb_mm", "fixations", "status"):
            np.testing.assert_array_equal(csv_new[c], csv_old[c])
        np.testing.assert_array_equal(csv_new["ellipsoid95_r3_mm"], csv_old["axis3_mm"])


def test_estimates_and_target_labels_written_back_as_the_old_code_wrote_them(tmp_path):
    est = read_estimates(OLD / "estimates.csv")
    assert list(est) == list(ESTIMATE_COLUMNS) and len(est["t"]) > 3
    write_estimates(tmp_path / "estimates.csv", _ints(est, ("segment",)))
    assert (tmp_path / "estimates.csv").read_bytes() == (OLD / "estimates.csv").read_bytes()
    write_estimates(tmp_path / "none.csv", {k: np.zeros(0) for k in ESTIMATE_COLUMNS})    # no fixation: a header
    assert all(len(v) == 0 for v in read_estimates(tmp_path / "none.csv").values())
    labels = read_target_labels(OLD / "target_labels.npy")
    assert labels.ndim == 1 and labels.min() == -1
    write_target_labels(tmp_path / "labels.npy", labels)
    assert (tmp_path / "labels.npy").read_bytes() == (OLD / "target_labels.npy").read_bytes()
    (tmp_path / "bad.npy").write_text("no array")
    with pytest.raises(UserError, match="not a target_labels.npy"):
        read_target_labels(tmp_path / "bad.npy")


def test_targets_reader_says_what_is_wrong(tmp_path):
    with pytest.raises(UserError, match="no such file"):
        read_targets(tmp_path / "targets.json")
    (tmp_path / "targets.json").write_text('{"version": 1}')
    with pytest.raises(UserError, match="not a targets.json"):
        read_targets(tmp_path / "targets.json")
    (tmp_path / "targets.json").write_text('{"version": 2, "method": "ml", "targets": [{"target": 0}]}')
    with pytest.raises(UserError, match=r"targets.json: field 'targets\[0\]' of the targets file .*missing key"):
        read_targets(tmp_path / "targets.json")


def test_truth_files_written_back_as_the_old_code_wrote_them(tmp_path):
    write_truth_targets(tmp_path / "targets.json", read_truth_targets(OLD / "truth_targets.json"))
    assert (tmp_path / "targets.json").read_bytes() == (OLD / "truth_targets.json").read_bytes()
    write_truth_eyes(tmp_path / "eyes.json", read_truth_eyes(OLD / "truth_eyes.json"))
    assert (tmp_path / "eyes.json").read_bytes() == (OLD / "truth_eyes.json").read_bytes()


def test_images_written_atomically_and_read_grey(tmp_path, monkeypatch):
    rng = np.random.default_rng(0)
    gray = rng.integers(0, 256, (24, 32), dtype=np.uint8)
    write_image(tmp_path / "a.png", gray)
    cv2.imwrite(str(tmp_path / "b.png"), gray)
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()      # the same PNG bytes
    assert np.array_equal(read_gray_image(tmp_path / "a.png"), gray)
    color = rng.integers(0, 256, (24, 32, 3), dtype=np.uint8)
    write_image(tmp_path / "c.png", color)
    back = read_gray_image(tmp_path / "c.png").astype(int)            # the decoder's own conversion: within 1
    assert back.shape == (24, 32) and np.abs(back - cv2.cvtColor(color, cv2.COLOR_BGR2GRAY)).max() <= 1
    with pytest.raises(UserError, match=r"x\.png: missing or unreadable wall image .*; record it again$"):
        read_gray_image(tmp_path / "x.png", "wall image", "record it again")
    (tmp_path / "bad.png").write_bytes(b"\x89PNG garbage")
    with pytest.raises(UserError, match="not a readable image"):
        read_gray_image(tmp_path / "bad.png")
    monkeypatch.setattr(cv2, "imwrite", lambda *a, **k: False)          # a full disk: OpenCV says False
    with pytest.raises(UserError, match="could not write"):
        write_image(tmp_path / "a.png", np.zeros((4, 4), np.uint8))
    assert np.array_equal(read_gray_image(tmp_path / "a.png"), gray)        # the old file is kept
    with pytest.raises(UserError, match="could not write"):
        write_image(tmp_path / "new.png", gray)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png", "b.png", "bad.png", "c.png"]   # nothing left
    monkeypatch.undo()
    with pytest.raises(UserError, match=r"\.png suffix"):
        write_image(tmp_path / "d.unknown", gray)
    assert not list(tmp_path.glob("*.unknown"))


def test_live_eye_rows_are_the_old_table_rows():
    """The recorder streams rows (LF) that are, cell for cell, the rows the table writer wrote (CRLF)."""
    eye, _ = read_eye_csv(OLD / "eye.csv")
    lines = [eye_csv_line(eye.t[i], eye.counter[i], eye.raw[i, 0], eye.raw[i, 1], eye.valid[i, 0], eye.valid[i, 1])
             for i in range(len(eye))]
    assert EYE_HEADER + "".join(lines) == (OLD / "eye.csv").read_bytes().decode().replace("\r\n", "\n")
    frames, t = read_frame_times(OLD / "scene_timestamps.csv")
    assert FRAME_TIME_HEADER + "".join(frame_time_line(f, s) for f, s in zip(frames, t, strict=True)) == \
        (OLD / "scene_timestamps.csv").read_bytes().decode().replace("\r\n", "\n")


def _calibration():
    K = np.array([[640.5, 0, 639.2], [0, 641.0, 360.7], [0, 0, 1]])
    return CameraCalibration(K, np.array([-0.28, 0.09, 1e-4, -2e-4, -0.01]), (1280, 720), "pinhole", 0.062,
                             [{"view": "view_000.png", "used": True, "rms_px": 0.05, "n_points": 54, "reason": None},
                              {"view": "view_001.png", "used": False, "rms_px": None, "n_points": 0,
                               "reason": "board not found"}],
                             {"type": "chessboard", "cols": 9, "rows": 6, "square_mm": 30.0},
                             {"fx": 0.54, "fy": 0.54, "cx": 0.65, "cy": 0.63, "dist": [6e-4, 1e-3, 6e-5, 4e-5, 7e-4]})


def test_camera_json_of_a_calibration_round_trips_in_its_field_order(tmp_path):
    cal = _calibration()
    d = calibration_dict(cal, trusted=False, warnings=["fx and fy differ"])
    assert list(d) == ["format", "version", "model", "camera_matrix", "dist_coeffs", "image_size", "rms_px", "std",
                       "board", "views", "trusted", "warnings"]
    write_camera(tmp_path / "a.json", d)
    back = load_camera(tmp_path / "a.json")
    write_camera(tmp_path / "b.json", calibration_dict(back, trusted=False, warnings=["fx and fy differ"]))
    assert (tmp_path / "a.json").read_bytes() == (tmp_path / "b.json").read_bytes()
    assert np.array_equal(back.camera_matrix, cal.camera_matrix) and back.views == cal.views and back.std == cal.std


@pytest.mark.parametrize("suffix", [".yml", ".xml"])
def test_opencv_camera_files_read_as_camera_json(tmp_path, suffix):
    cal = _calibration()
    path = tmp_path / f"cam{suffix}"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 1280)
    fs.write("image_height", 720)
    fs.write("camera_matrix", cal.camera_matrix)
    fs.write("distortion_coefficients", cal.dist_coeffs.reshape(1, -1))
    fs.release()
    got = load_camera(path)
    assert np.array_equal(got.camera_matrix, cal.camera_matrix) and np.array_equal(got.dist_coeffs, cal.dist_coeffs)
    assert got.image_size == (1280, 720) and got.model == "pinhole"
    (tmp_path / "bad.yml").write_text("%YAML:1.0\n---\nimage_width: 1280\n")
    with pytest.raises(UserError, match="no 3x3 camera_matrix"):
        load_camera(tmp_path / "bad.yml")



def test_an_opencv_camera_file_without_an_image_size_is_one_line(real_data, tmp_path, capsys):
    """OpenCV's tutorial_camera_params.yml gives no image_width/height: its size was guessed as
    2 * principal point + 1 = 649x523, so ``map`` on the tutorial's 640x480 photos stopped with "the
    camera calibration is for 649x523", a size the file never states. It is one line asking for the
    size, at load and through the CLI."""
    from wearable_gaze.cli import main

    d = real_data / "opencv_aruco_charuco_tutorial"
    with pytest.raises(UserError, match="no image_width and image_height") as err:
        load_camera(d / "tutorial_camera_params.yml")
    assert "\n" not in str(err.value)
    assert main(["map", str(d / "singlemarkersoriginal.jpg"), "--camera", str(d / "tutorial_camera_params.yml"),
                 "--size-mm", "40", "--dict", "DICT_6X6_250", "-o", str(tmp_path / "map.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert "image_width" in err and "649x523" not in err and len(err.splitlines()) == 1

def test_live_streamed_rows_are_the_table_writers_rows(tmp_path):
    """The recorder writes eye samples and frame times row by row (LF); the table writer (CRLF)
    writes the same cells, and the reader gives the same values for both."""
    rng = np.random.default_rng(0)
    n = 7
    eye = EyeSamples(np.cumsum(rng.uniform(0.001, 0.02, n)), np.arange(n) % 5, rng.uniform(-50, 4000, (n, 2, 2)),
                     rng.random((n, 2)) > 0.3)
    write_eye_csv(tmp_path / "table.csv", eye)
    lines = [eye_csv_line(eye.t[i], eye.counter[i], eye.raw[i, 0], eye.raw[i, 1], eye.valid[i, 0], eye.valid[i, 1])
             for i in range(n)]
    (tmp_path / "stream.csv").write_text(EYE_HEADER + "".join(lines))
    table = (tmp_path / "table.csv").read_bytes().decode()
    assert table.replace("\r\n", "\n") == (tmp_path / "stream.csv").read_text()
    a, _ = read_eye_csv(tmp_path / "table.csv")
    b, _ = read_eye_csv(tmp_path / "stream.csv")
    for k in ("t", "counter", "raw", "valid"):
        assert np.array_equal(getattr(a, k), getattr(b, k)), k
    t = np.cumsum(rng.uniform(0.01, 0.04, n))
    write_frame_times(tmp_path / "ft_table.csv", np.arange(n), t)
    (tmp_path / "ft_stream.csv").write_text(FRAME_TIME_HEADER + "".join(frame_time_line(i, t[i]) for i in range(n)))
    assert (tmp_path / "ft_table.csv").read_bytes().decode().replace("\r\n", "\n") == \
        (tmp_path / "ft_stream.csv").read_text()


def test_marker_map_template_filled_in_loads(tmp_path):
    write_marker_map(tmp_path / "template.json", marker_map_template("DICT_4X4_50", 150.0, [3, 5]))
    with pytest.raises(UserError, match="marker 3: corners"):        # four zero corners: to be measured first
        load_marker_map(tmp_path / "template.json")
    d = json.loads((tmp_path / "template.json").read_text())
    T = np.eye(4)
    T[:3, :3] = rotation_about_axis([0, 1, 0], 0.3)
    T[:3, 3] = [400.0, -20.0, 1800.0]
    s = 75.0
    corners = np.array([[-s, -s, 0], [s, -s, 0], [s, s, 0], [-s, s, 0]]) @ T[:3, :3].T + T[:3, 3]
    for m in d["markers"]:
        m["corners_mm"] = corners.tolist()
    d["markers"][1]["corners_mm"] = (corners + [0, 0, 500.0]).tolist()
    (tmp_path / "filled.json").write_text(json.dumps(d))
    mm = load_marker_map(tmp_path / "filled.json")
    assert sorted(mm.poses) == [3, 5] and np.allclose(mm.poses[3], T, atol=1e-9)
    assert np.allclose(mm.poses[5][:3, 3], T[:3, 3] + [0, 0, 500.0], atol=1e-9)


def test_video_writer_and_grey_frames(tmp_path):
    frames = [np.full((48, 64), 40 * k, np.uint8) for k in range(4)]
    w = open_video_writer(tmp_path / "v.avi", "FFV1", 10.0, (64, 48), is_color=False)
    for f in frames:
        w.write(f)
    w.release()
    got = list(gray_frames(tmp_path / "v.avi"))
    assert len(got) == 4 and all(np.array_equal(g, f) for g, f in zip(got, frames, strict=True))
    with pytest.raises(UserError, match="use another name"):
        open_video_writer(tmp_path / "no_such_folder" / "v.avi", "FFV1", 10.0, (64, 48), refused="use another name")
    w = open_video_writer(tmp_path / "ten.avi", "FFV1", 10.0, (64, 48), is_color=False)
    for k in range(10):
        w.write(np.full((48, 64), 20 * k, np.uint8))
    w.release()
    got = list(sampled_gray_frames(tmp_path / "ten.avi", 3))          # every 10 // 3 = 3rd frame
    assert [i for i, _ in got] == [0, 3, 6, 9] and all(np.all(g == 20 * i) for i, g in got)
    with pytest.raises(UserError, match="not a video"):
        list(sampled_gray_frames(tmp_path / "nothing.avi", 3, refused="not a video"))


FORMAT_NAMES = ("wearable-gaze-camera", "wearable-gaze-marker-map", "wearable-gaze-eyes", "wearable-gaze-session")


def test_each_format_has_its_one_home():
    """A format's name, the video writer and hand-written CSV/JSON of a format appear only in
    wearable_gaze/formats; the tracking library holds no file format."""
    offenders = []
    for p in sorted((ROOT / "wearable_gaze").rglob("*.py")):
        rel = p.relative_to(ROOT).as_posix()
        if rel.startswith("wearable_gaze/formats/"):
            continue
        text = p.read_text(encoding="utf-8")
        for needle in (*FORMAT_NAMES, "cv2.VideoWriter(", '"frame,t', "EYE_FORMATS", "FileStorage(", "cv2.imread(",
                       "cv2.imwrite(", "truth_T_cam_from_board", '"recordings"', "TARGET_FORMATS"):
            if needle in text:
                offenders.append(f"{rel}: {needle}")
    for p in sorted((ROOT / "tracking").rglob("*.py")):
        text = p.read_text(encoding="utf-8")
        if any(n in text for n in FORMAT_NAMES) or re.search(r"def (to|from)_dict\b", text):
            offenders.append(f"{p.relative_to(ROOT).as_posix()}: file format code in the tracking library")
    assert offenders == []


def test_each_format_module_names_its_doc():
    docs = (ROOT / "docs" / "formats.md").read_text(encoding="utf-8")
    for name in ("camera", "eyes", "markermap", "eye_samples", "poses", "video", "session", "viewlines",
                 "serial_protocol", "jsonio", "tables", "atomic", "board", "walls", "images", "targets", "truth"):
        module = (ROOT / "wearable_gaze" / "formats" / f"{name}.py").read_text(encoding="utf-8")
        doc = module.split('"""')[1]
        assert "docs/" in doc or name in ("jsonio", "tables", "atomic"), name
        assert f"formats/{name}.py" in docs, f"docs/formats.md does not name formats/{name}.py"


def test_atomic_writes_take_the_umask_without_changing_it(tmp_path):
    from wearable_gaze.formats.atomic import _umask, write_text

    old = os.umask(0o027)
    try:
        assert _umask() == 0o027
        write_text(tmp_path / "a.txt", "x")
        assert (tmp_path / "a.txt").stat().st_mode & 0o777 == 0o640
        assert _umask() == 0o027
    finally:
        os.umask(old)


def test_a_header_only_estimates_csv_is_empty_but_a_broken_one_is_one_line(tmp_path):
    """estimates.csv goes through the one CSV reader: a header alone is no estimate; a file that is
    not UTF-8, or lacks a column, is a UserError naming it (the file was once pre-read outside the
    reader, and a Latin-1 byte there ended in an internal error)."""
    header = ",".join(ESTIMATE_COLUMNS) + "\n"
    (tmp_path / "h.csv").write_text(header)
    assert all(len(v) == 0 for v in read_estimates(tmp_path / "h.csv").values())
    (tmp_path / "latin1.csv").write_bytes(header.encode() + b"1,2,\xe9\n")
    with pytest.raises(UserError, match="not UTF-8"):
        read_estimates(tmp_path / "latin1.csv")
    (tmp_path / "short.csv").write_text("t,segment\n")
    with pytest.raises(UserError, match="missing column"):
        read_estimates(tmp_path / "short.csv")



def test_an_estimate_without_a_covariance_is_read_back(tmp_path):
    """``process --method lse`` (or ``paper`` on a short fixation) writes estimates.csv with an
    empty radius95_mm (no covariance); its own reader refused that cell, so on the real Aria sample
    the export and report steps failed ("radius95_mm: '' is not a number"). Empty reads as NaN."""
    cols = {"t": [0.1, 0.2], "segment": [0, 0], "x": [1.0, 2.0], "y": [3.0, 4.0], "z": [5.0, 6.0],
            "radius95_mm": [float("nan"), 12.5]}
    write_estimates(tmp_path / "e.csv", cols)
    assert tmp_path.joinpath("e.csv").read_text().splitlines()[1].endswith(",")
    back = read_estimates(tmp_path / "e.csv")
    assert np.isnan(back["radius95_mm"][0]) and back["radius95_mm"][1] == 12.5 and list(back["x"]) == [1.0, 2.0]

# --- the streaming CSV reader (tables.csv_header, iter_csv_chunks, chunk_numbers) ------------------

def _stream_csv(path, data: bytes):
    """Write ``data`` to ``path``, gzipped when its name ends in .gz."""
    import gzip

    path.write_bytes(gzip.compress(data) if path.suffix == ".gz" else data)
    return path


@pytest.mark.parametrize("name", ["t.csv", "t.csv.gz"])
def test_streaming_reader_gives_chunks_with_their_lines_plain_or_gzipped(tmp_path, name):
    """Rows come in chunks of the size asked for, blank lines skipped, each with its file line; a
    BOM is skipped and a .gz file read through; progress ends at the file's size; a truncated row
    is not whole and its cells are NaN, the rest of its chunk intact."""
    from wearable_gaze.formats.tables import chunk_numbers, csv_header, iter_csv_chunks

    rows = [f"{i},{i / 10},{2 * i}" for i in range(10)]
    rows[7] = "7,0.7"                                           # truncated: a cell short
    text = "\ufefft, x ,y\n" + "\n".join(rows[:5]) + "\n\n" + "\n".join(rows[5:]) + "\n"
    path = _stream_csv(tmp_path / name, text.encode("utf-8"))
    names = csv_header(path, "test CSV", "pass one", ("t", "x"))
    assert names == ["t", "x", "y"]
    seen = []
    chunks = list(iter_csv_chunks(path, "test CSV", 4, progress=lambda done, total: seen.append((done, total))))
    assert [len(r) for r, _ in chunks] == [4, 4, 2]
    assert [ln for _, lines in chunks for ln in lines] == [2, 3, 4, 5, 6, 8, 9, 10, 11, 12]
    done = [a for a, _ in seen]
    assert len(seen) == 3 and seen[-1] == (path.stat().st_size,) * 2 and done == sorted(done)
    index = {n: j for j, n in enumerate(names)}
    v, whole, finite = chunk_numbers(chunks[1][0], index, ("t", "x", "y"))
    assert whole.tolist() == [True, True, True, False] == finite.tolist()
    assert v["t"][:3].tolist() == [4, 5, 6] and np.isnan(v["t"][3]) and np.isnan(v["y"][3])
    assert v["y"][:3].tolist() == [8, 10, 12] and v["x"][:3].tolist() == [0.4, 0.5, 0.6]


def test_streaming_reader_non_numbers_are_nan_or_one_line_naming_the_first(tmp_path):
    """Without line numbers a cell that is not a number is NaN (an empty one too); with them the
    first in file order is a UserError naming the file, its line and its column."""
    from wearable_gaze.formats.tables import chunk_numbers, iter_csv_chunks

    path = _stream_csv(tmp_path / "n.csv", b"a,b\n1,2\n3,\n\n5,x\ny,7\n")
    rows, lines = next(iter_csv_chunks(path, "test CSV", 100))
    v, whole, finite = chunk_numbers(rows, {"a": 0, "b": 1}, ("a", "b"))
    assert whole.all() and finite.tolist() == [True, False, False, False]
    assert v["a"][:3].tolist() == [1, 3, 5] and np.isnan(v["b"][1:3]).all() and np.isnan(v["a"][3])
    with pytest.raises(UserError) as err:
        chunk_numbers(rows, {"a": 0, "b": 1}, ("a", "b"), lines, path, "fix it")
    assert str(err.value) == f"{path} line 5, column b: 'x' is not a number; fix it"


@pytest.mark.parametrize("name", ["bad.csv", "bad.csv.gz"])
def test_streaming_reader_a_bad_byte_or_broken_csv_is_one_line(tmp_path, name):
    """A byte that is not UTF-8 is one line naming the file and where (plain or gzipped); read
    with errors='replace' it becomes U+FFFD; a row that is not CSV (an unclosed quote running
    past the csv module's field limit) names its line."""
    from wearable_gaze.formats.tables import iter_csv_chunks

    good = "".join(f"{i},{i}\n" for i in range(3000)).encode()
    path = _stream_csv(tmp_path / name, b"a,b\n" + good + b"1,\xe9\n")
    with pytest.raises(UserError) as err:
        list(iter_csv_chunks(path, "test CSV", 64))
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(f"{path} after line ") and "the test CSV is not UTF-8 text" in msg
    assert int(msg.split("after line ")[1].split(":")[0]) <= 3001
    rows = [r for chunk, _ in iter_csv_chunks(path, "test CSV", 64, errors="replace") for r in chunk]
    assert rows[-1] == ["1", "\ufffd"] and len(rows) == 3001
    path = _stream_csv(tmp_path / name, b"a,b\n1,2\n3,\"4" + b"5\n" * 70000)
    with pytest.raises(UserError, match="line [0-9]+: the test CSV is not valid CSV .*field limit"):
        list(iter_csv_chunks(path, "test CSV", 64))


def test_streaming_reader_a_cut_gzip_file_and_header_problems_are_one_line(tmp_path):
    """A gzip file cut short, a .gz that is not gzip, and the header checks (the same messages
    as read_table's: one function) are one line each."""
    from wearable_gaze.formats.tables import csv_header, iter_csv_chunks, read_table

    data = b"a,b\n" + "".join(f"{i},{i * 7 % 13}\n" for i in range(20000)).encode()
    path = _stream_csv(tmp_path / "cut.csv.gz", data)
    path.write_bytes(path.read_bytes()[:len(path.read_bytes()) // 2])
    with pytest.raises(UserError, match="cut.csv.gz after line [0-9]+: the test CSV is not a complete gzip file"):
        list(iter_csv_chunks(path, "test CSV", 1000))
    (tmp_path / "not.csv.gz").write_bytes(b"a,b\n1,2\n")
    with pytest.raises(UserError, match="not.csv.gz: the test CSV is not a complete gzip file"):
        csv_header(tmp_path / "not.csv.gz", "test CSV", "pass one")
    with pytest.raises(UserError, match="nothere.csv: no such file; pass one"):
        csv_header(tmp_path / "nothere.csv", "test CSV", "pass one")
    _stream_csv(tmp_path / "empty.csv", b"\n")
    with pytest.raises(UserError, match="empty.csv: the test CSV is empty; pass one"):
        csv_header(tmp_path / "empty.csv", "test CSV", "pass one")
    for head, required in ((b"a,b,a\n", ()), (b"a,b\n", ("a", "c"))):
        p = _stream_csv(tmp_path / "h.csv", head + b"1,2,3\n")
        with pytest.raises(UserError) as streamed:
            csv_header(p, "test CSV", "pass one", required)
        with pytest.raises(UserError) as whole:
            read_table(p, required, what="test CSV")
        assert str(streamed.value) == str(whole.value) and "\n" not in str(whole.value)
    with pytest.raises(UserError, match=r"missing column\(s\) c in the test CSV header \(it has: a, b\); is it X\?"):
        csv_header(p, "test CSV", "pass one", ("c",), "is it X?")
