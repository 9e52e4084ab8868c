"""Tobii Pro Glasses 2 and 3 import (wearable_gaze/formats/devices/tobii_g2.py, tobii_g3.py,
tobii_common.py): the real G2 sample (counts, frame, the nine poster targets), write -> read round
trips of both formats, and malformed recordings (one clear line, or a counted drop)."""

from __future__ import annotations

import csv
import gzip
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers import one_line_error, run_import

from calibration.camera import CameraCalibration
from estimator.likelihood import MLConfig, ml_point
from estimator.lines import BinocularSamples
from wearable_gaze.formats.devices import tobii_common, tobii_g2, tobii_g3
from wearable_gaze.formats.devices.common import ImportOptions, SessionImport, SimulatedRecording
from wearable_gaze.formats.eye_rays import read_device_gaze, read_eye_rays
from wearable_gaze.formats.video import open_video_writer

G2_SAMPLE = "glassesvalidator_tobii_g2_example"


# --- the real Tobii Pro Glasses 2 sample ----------------------------------------------------------

@pytest.fixture
def g2_real(real_data, tmp_path):
    """(sample folder, imported session, import report) of the real G2 sample."""
    root = real_data / G2_SAMPLE
    if not root.is_dir():
        pytest.skip(f"{root} not found")
    return root, tmp_path / "session", run_import(tobii_g2, root / "recording", tmp_path / "session")


def test_g2_real_counts_match_the_recording(g2_real):
    """966 gidx groups (docs/devices/tobii-pupil.md 1.5): the last one has only left-eye lines
    (incomplete, = rec_et_samples 965 complete); 23 samples precede the first vts line (video
    time -959.5 ms .. 0); of the other 942, two have both eyes lost (status 16) and three a
    left eye with status 1: 940 samples written, every line kind counted, the 0.54 s gap found."""
    _, out, rep = g2_real
    assert rep["read"]["livedata pc lines"] == 1931 and rep["read"]["livedata gd lines"] == 1931
    assert rep["read"]["livedata gp3 lines"] == 965 and rep["read"]["livedata vts lines"] == 30
    assert rep["dropped"] == {"gap: samples missing from the device's stream": 26,
                              "sample: before the first video sync (vts)": 23,
                              "left eye: status 1": 3, "left eye: status 16": 2, "right eye: status 16": 2,
                              "sample: no valid eye": 2,
                              "sample: incomplete gidx group (an eye's pc or gd line missing)": 1}
    assert rep["eye_samples_written"] == 940 == 966 - 1 - 23 - 2
    assert rep["largest_gap_s"] == pytest.approx(0.5397, abs=1e-3)
    assert rep["pose_source"] == "still_head" and any("still head" in n for n in rep["notes"])
    assert rep["clock_offset_s"] == pytest.approx(85.374512) and rep["vts_offset_spread_ms"] == 0
    man = json.loads((out / "session.json").read_text())
    assert man["eye_rate_hz"] == pytest.approx(50.0, abs=0.1)
    rays = read_eye_rays(out / "eye_rays.csv")
    assert rays.left_valid.sum() == 937 and rays.right_valid.sum() == 940
    # the first kept sample is the first after vts 0 (ts 85374512): ts 85394431 -> 19.919 ms
    assert rays.t_s[0] == pytest.approx(0.019919, abs=1e-6)


def test_g2_real_format_is_detected(g2_real):
    """The Tobii project folder and the recording folder inside it are both tobii-g2 (and no
    other format's files match them)."""
    from wearable_gaze.formats.devices import detect_format

    root = g2_real[0] / "recording"
    assert detect_format(root) == "tobii-g2" == detect_format(root / "recordings" / "t3ic6aq")
    assert not tobii_g3.detect(root) and not tobii_g2.detect(root / "recordings")


def test_g2_real_frame_mapping_reproduces_the_devices_2d_gaze(g2_real):
    """The unit's own rotation from et.tslv (1.07 deg from the nominal flip) maps gp3 onto gp to
    0.058 px median (the research's oracle 2; the bare flip gives 11.8 px): the TSLV reader, the
    intrinsics and the frame mapping are right. The camera file holds the unit's intrinsics."""
    _, out, rep = g2_real
    conv = rep["frames"]["position_convention"]
    assert conv["confirmed"] and conv["median_reprojection_px"]["R p + position"] < 0.1
    T = np.array(rep["frames"]["T_cam_from_glasses"])
    assert np.degrees(np.arccos((np.trace(T[:3, :3] @ tobii_common.T_CAM_FROM_GLASSES_NOMINAL[:3, :3].T) - 1) / 2)) \
        == pytest.approx(1.07, abs=0.02)
    cam = json.loads((out / "camera.json").read_text())
    assert np.allclose(np.array(cam["camera_matrix"])[[0, 1, 0, 1], [0, 1, 2, 2]],
                       [1134.88, 1134.56, 936.444, 547.498], atol=1e-3)
    assert cam["image_size"] == [1920, 1080]
    assert np.allclose(cam["dist_coeffs"], [0.10012, -0.373436, -0.00093747, 0.00054785, 0.35531], atol=1e-6)


def test_g2_real_rays_are_in_the_head_frame(g2_real):
    """In our frame (x right, y down, z forward) the wearer's left eye is at -x, both eyes below
    (+y) and behind (-z) the scene camera, IPD 64.9 mm (median); the device's gp3 is the midpoint of
    the two rays' common perpendicular (oracle 1: median 0.28 mm), so rays and gp3 went through the
    same mapping."""
    _, out, _ = g2_real
    r = read_eye_rays(out / "eye_rays.csv")
    both = r.left_valid & r.right_valid
    lo, ro = r.left_origin_mm[both], r.right_origin_mm[both]
    assert np.median(lo[:, 0]) < -25 and np.median(ro[:, 0]) > 25
    assert np.all(np.median(np.vstack([lo, ro]), axis=0)[1:] * [1, -1] > 15)
    assert np.median(np.linalg.norm(lo - ro, axis=1)) == pytest.approx(64.9, abs=0.3)
    tg, g = read_device_gaze(out / "device_gaze.csv")
    ld, rd = r.left_direction[both], r.right_direction[both]
    w0 = lo - ro
    a, b, c, d, e = (np.einsum("ij,ij->i", x, y) for x, y in ((ld, ld), (ld, rd), (rd, rd), (ld, w0), (rd, w0)))
    s, t = (b * e - c * d) / (a * c - b * b), (a * e - b * d) / (a * c - b * b)
    mid = (lo + s[:, None] * ld + ro + t[:, None] * rd) / 2
    ok = np.isfinite(g[both, 0])
    assert np.array_equal(tg, r.t_s)
    assert np.median(np.linalg.norm(mid[ok] - g[both][ok], axis=1)) < 0.5


def _poster_intervals(root: Path):
    with open(root / "recording" / "analysisInterval_from_3e0a114.tsv", newline="") as fh:
        rows = list(csv.DictReader(fh, delimiter="\t"))
    with open(root / "poster_config" / "targetPositions.csv", newline="") as fh:
        pos = {int(p["ID"]): (float(p["x"]) * 10, float(p["y"]) * 10) for p in csv.DictReader(fh)}
    return [(int(r["target"]), float(r["start_timestamp"]) / 1e3, float(r["end_timestamp"]) / 1e3) for r in rows], pos


def _expected_angles(pos: dict, distance_mm: float) -> dict:
    """Angles (deg) between neighbouring targets of the flat poster seen from ``distance_mm`` in
    front of target 5 (the poster's origin), perpendicular."""
    p = {k: np.array([x - pos[5][0], y - pos[5][1], distance_mm]) for k, (x, y) in pos.items()}
    u = {k: v / np.linalg.norm(v) for k, v in p.items()}
    return {(i, j): np.degrees(np.arccos(np.clip(u[i] @ u[j], -1, 1))) for i, j in NEIGHBORS}


NEIGHBORS = [(1, 2), (2, 3), (4, 5), (5, 6), (7, 8), (8, 9), (1, 4), (4, 7), (2, 5), (5, 8), (3, 6), (6, 9)]
ACCURACY_DEG = 1.43
"""Tobii Pro Glasses 2 accuracy in use: 1.43 deg (mean over 9-point grids, 3 wearers, 1-3 m;
95 % CI 1.21-1.64; J. MacInnes, github.com/jeffmacinnes/glassesCalibration,
analysis/calibrationAnalyses.md). Tobii's "0.5 deg" holds only just after calibration."""
BASELINE_MM = 63.0


def test_g2_real_nine_targets_reproduce_the_poster_grid(g2_real):
    """Nine targets from the nine published fixation intervals (analysisInterval, video time), each
    the ML point (robust mixture loss, sigma 0.5 deg) of the interval's imported rays with the
    head still. What a 63 mm baseline at arm's length can show:

    - directions: seen from the eyes' midpoint, the nine points keep the poster's row/column order
      (azimuth increases left to right in every row, elevation top to bottom in every column), each
      row and column is straight within 2 x 1.43 deg = 2.86 deg (two targets each off by the
      device's accuracy, ``ACCURACY_DEG``, in opposite directions), and every neighbour angle
      matches the flat poster's (104.7 x 91.6 mm spacing) seen from the estimates' median distance
      within the same 2.86 deg. (Measured: horizontal 8.1-10.1 deg, vertical 5.3-6.2 deg against
      7.8 / 6.8-6.9 deg expected at 761 mm: the device compresses the vertical.)
    - depths: a vergence error of +/- 2 x 1.43 deg at 63 mm moves a point at the protocol's
      600 mm (validationSetup.txt) to 407-1143 mm: every depth lies in that band (measured
      546-963 mm). The mm grid itself is not asserted: depth is this poorly fixed.
    - the device's own gp3 (median per interval) points the same way within 0.5 deg: with a still
      head our estimate is vergence from the same rays.
    """
    root, out, _ = g2_real
    intervals, pos = _poster_intervals(root)
    rays = read_eye_rays(out / "eye_rays.csv")
    tg, g3 = read_device_gaze(out / "device_gaze.csv")
    points, gp3, views = {}, {}, []
    for target, a, b in intervals:
        s = rays.select((rays.t_s >= a) & (rays.t_s <= b))
        est = ml_point(s.lines(), MLConfig(sigma_deg=0.5, loss="mixture"))
        assert est.ok and len(s) >= 45, (target, est.status, len(s))
        points[target] = est.position_mm
        gp3[target] = np.nanmedian(g3[(tg >= a) & (tg <= b)], axis=0)
        views.append(np.concatenate([s.left_origin_mm[s.left_valid], s.right_origin_mm[s.right_valid]]))
    assert sorted(points) == list(range(1, 10))
    view = np.mean(np.vstack(views), axis=0)
    dist = {k: np.linalg.norm(p - view) for k, p in points.items()}
    u = {k: (p - view) / dist[k] for k, p in points.items()}
    az = {k: np.degrees(np.arctan2(v[0], v[2])) for k, v in u.items()}
    el = {k: np.degrees(np.arctan2(v[1], v[2])) for k, v in u.items()}
    tol = 2 * ACCURACY_DEG
    for row in ((1, 2, 3), (4, 5, 6), (7, 8, 9)):
        assert az[row[0]] < az[row[1]] < az[row[2]], row
        assert np.ptp([el[k] for k in row]) < tol, row
    for col in ((1, 4, 7), (2, 5, 8), (3, 6, 9)):
        assert el[col[0]] < el[col[1]] < el[col[2]], col
        assert np.ptp([az[k] for k in col]) < tol, col
    expected = _expected_angles(pos, float(np.median(list(dist.values()))))
    for (i, j), want in expected.items():
        got = np.degrees(np.arccos(np.clip(u[i] @ u[j], -1, 1)))
        assert abs(got - want) < tol, ((i, j), got, want)
    v0 = BASELINE_MM / 600.0
    near, far = BASELINE_MM / (v0 + np.radians(tol)), BASELINE_MM / (v0 - np.radians(tol))
    assert (near, far) == pytest.approx((407, 1143), abs=1)
    assert all(near < d < far for d in dist.values()), dist
    for k in points:
        ug = (gp3[k] - view) / np.linalg.norm(gp3[k] - view)
        assert np.degrees(np.arccos(np.clip(ug @ u[k], -1, 1))) < 0.5, k


# --- write -> read round trips ---------------------------------------------------------------------

def tiny_recording(root: Path, n: int = 300, rate: float = 50.0, seed: int = 0) -> SimulatedRecording:
    """A small simulated recording: fixations on random points 0.4-3 m ahead, 5 % of eyes lost,
    and a 10-frame 320x240 video (frame i at i / 10 s)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    gaze = np.repeat(rng.uniform([-400, -300, 400], [400, 300, 3000], (n // 50 + 1, 3)), 50, axis=0)[:n]
    eyes = []
    for x in (-32.0, 32.0):
        o = np.array([x, 30.0, -25.0]) + rng.normal(0, 0.5, (n, 3))
        d = gaze - o + rng.normal(0, 3.0, (n, 3))
        v = rng.random(n) > 0.05
        eyes += [o, np.where(v[:, None], d, np.nan), v]
    rays = BinocularSamples.from_arrays(t, eyes[0], eyes[1], eyes[3], eyes[4], eyes[2], eyes[5], frame="head")
    K = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])
    cam = CameraCalibration(K, np.array([-0.2, 0.05, 0.001, -0.001, 0.01]), (320, 240))
    video = root / "video.mp4"
    w = open_video_writer(video, "mp4v", 10.0, (320, 240))
    for i in range(10):
        w.write(np.full((240, 320, 3), 20 * i, np.uint8))
    w.release()
    return SimulatedRecording(t, rays, np.tile(np.eye(4), (n, 1, 1)), gaze, cam, video, np.arange(10) / 10.0,
                              None, (320, 240), rate, 10.0)


@pytest.mark.parametrize(("module", "origin_tol_mm", "dir_tol_rad", "gaze_tol_mm"),
                         [(tobii_g2, 0.01, 1e-4, 0.02), (tobii_g3, 1e-3, 2e-6, 2e-3)])
def test_write_read_round_trip(tmp_path, module, origin_tol_mm, dir_tol_rad, gaze_tol_mm):
    """The writer's recording imports back to the same rays and device gaze within the format's
    rounding (G2: pc/gp3 0.01 mm, gd 1e-4; G3 as written: 0.001 mm, 1e-6), the same valid eyes,
    the same times; the scene video and the unit's intrinsics come along (G3's camera sits 10, -30,
    5 mm from the glasses' origin: the import must find the position convention on its own)."""
    sim = tiny_recording(tmp_path)
    module.write_recording(sim, tmp_path / "rec")
    assert module.detect(tmp_path / "rec")
    rep = run_import(module, tmp_path / "rec", tmp_path / "out")
    r = read_eye_rays(tmp_path / "out" / "eye_rays.csv")
    keep = sim.rays.left_valid | sim.rays.right_valid
    s = sim.rays.select(keep)
    assert rep["dropped"]["sample: no valid eye"] == int((~keep).sum())
    assert np.allclose(r.t_s, s.t_s, atol=1e-6)
    for side in ("left", "right"):
        v = getattr(s, f"{side}_valid")
        assert np.array_equal(getattr(r, f"{side}_valid"), v)
        assert np.abs(getattr(r, f"{side}_origin_mm")[v] - getattr(s, f"{side}_origin_mm")[v]).max() < origin_tol_mm
        cos = np.einsum("ij,ij->i", getattr(r, f"{side}_direction")[v], getattr(s, f"{side}_direction")[v])
        assert np.arccos(np.clip(cos, -1, 1)).max() < dir_tol_rad
    _, g = read_device_gaze(tmp_path / "out" / "device_gaze.csv")
    assert np.abs(g - sim.gaze_head_mm[keep]).max() < gaze_tol_mm
    conv = rep["frames"]["position_convention"]
    assert conv["confirmed"]
    if module is tobii_g3:
        assert conv["convention"] == "R p + position"
    cam = json.loads((tmp_path / "out" / "camera.json").read_text())
    assert np.allclose(cam["camera_matrix"], sim.camera.camera_matrix, atol=1e-4)
    assert np.allclose(cam["dist_coeffs"], sim.camera.dist_coeffs, atol=1e-6)
    assert (tmp_path / "out" / "scene.mp4").is_file()
    with open(tmp_path / "out" / "scene_timestamps.csv") as fh:
        assert [float(row["t"]) for row in csv.DictReader(fh)] == pytest.approx(list(sim.frame_times))
    assert rep["pose_source"] == "still_head" and any("marker map" in n for n in rep["notes"])


def test_markers_make_the_pose_source_the_scene_video(tmp_path):
    """Video, the device's camera and a marker map: poses come from tracking the scene video."""
    sim = tiny_recording(tmp_path)
    tobii_g3.write_recording(sim, tmp_path / "rec")
    markers = tmp_path / "markers.json"
    markers.write_text(json.dumps({"format": "wearable-gaze-marker-map", "version": 1, "dictionary": "DICT_4X4_50",
                                   "marker_size_mm": 100.0,
                                   "markers": [{"id": 0, "T_world_from_marker": np.eye(4).tolist()}]}))
    rep = run_import(tobii_g3, tmp_path / "rec", tmp_path / "out", markers=markers)
    assert rep["pose_source"] == "scene_video"
    assert (tmp_path / "out" / "markers.json").is_file()


@pytest.mark.parametrize("position_sign", [1.0, -1.0])
def test_the_position_convention_is_decided_by_reprojection(tmp_path, position_sign):
    """3D gaze written with either reading of the unit's position (R p + t, or R (p - t)) is
    mapped back with that reading: the 2D gaze decides, and the other reading is off."""
    sim = tiny_recording(tmp_path)
    cam = tobii_common.writer_camera(sim, (10.0, -30.0, 5.0))
    name = "R p + position" if position_sign > 0 else "R (p - position)"
    T = tobii_common.t_cam_from_glasses(cam, name)
    g_glasses = tobii_common.apply(np.linalg.inv(T), sim.gaze_head_mm)
    g2 = tobii_common.project_norm(sim.gaze_head_mm, cam)
    T_found, rep = tobii_common.choose_convention(cam, g_glasses, g2, None)
    assert rep["convention"] == name and rep["confirmed"]
    assert np.allclose(T_found, T)
    other = [v for k, v in rep["median_reprojection_px"].items() if k != name][0]
    assert other > 10 * rep["median_reprojection_px"][name]


def test_the_import_streams_in_chunks(tmp_path):
    """A recording longer than a chunk reaches the session in pieces of at most ``CHUNK`` samples
    (never the whole recording at once)."""
    n = 2 * tobii_common.CHUNK + 500
    sim = tiny_recording(tmp_path, n=n)
    tobii_g2.write_recording(sim, tmp_path / "rec")
    sizes = []

    class Spy(SessionImport):
        def add_rays(self, t, *a):
            sizes.append(len(t))
            super().add_rays(t, *a)

    with Spy(tmp_path / "out", "tobii-g2", tmp_path / "rec") as imp:
        tobii_g2.read_recording(tmp_path / "rec", imp, ImportOptions())
    assert len(sizes) >= 3 and max(sizes) <= tobii_common.CHUNK
    assert sum(sizes) == imp.n_rays > 0.9 * n


# --- malformed recordings --------------------------------------------------------------------------

GOOD = ('{{"ts":{ts},"s":0,"gidx":{g},"pc":[31.80,-23.30,-29.20],"eye":"left"}}',
        '{{"ts":{ts},"s":0,"gidx":{g},"gd":[0.0400,0.1100,0.9931],"eye":"left"}}',
        '{{"ts":{ts},"s":0,"gidx":{g},"pc":[-33.20,-22.50,-26.60],"eye":"right"}}',
        '{{"ts":{ts},"s":0,"gidx":{g},"gd":[0.1000,0.1200,0.9877],"eye":"right"}}',
        '{{"ts":{ts},"s":0,"gidx":{g},"gp3":[70.00,100.00,900.00]}}')


def g2_folder(root: Path, extra=(), n: int = 50, replace=None) -> Path:
    """A G2 recording folder of ``n`` good samples at 50 Hz after one vts line, with the lines
    ``replace[i]`` instead of sample i's and ``extra`` lines appended."""
    seg = root / "rec" / "segments" / "1"
    seg.mkdir(parents=True)
    lines = ['{"ts":1000000,"s":0,"vts":0}']
    for i in range(n):
        ts = 1_000_000 + 20_000 * i
        lines += (replace or {}).get(i, [s.format(ts=ts, g=i) for s in GOOD])
    with gzip.open(seg / "livedata.json.gz", "wt") as fh:
        fh.write("\n".join(lines + list(extra)) + "\n")
    return root / "rec"


def test_bad_samples_are_counted_with_reasons(tmp_path):
    """Non-zero status, NaN, an eye centre 200 mm away, a backwards direction, a line that is
    not JSON, a time that is not a number, and an eye whose gd line is missing: each is counted
    under its reason, the good eye of the same sample is kept, and nothing crashes."""
    bad = {
        3: [s.format(ts=1_060_000, g=3).replace('"s":0', '"s":16') for s in GOOD[:2]]
        + [s.format(ts=1_060_000, g=3) for s in GOOD[2:]],
        5: [GOOD[0].format(ts=1_100_000, g=5).replace("31.80", "200.00")] + [s.format(ts=1_100_000, g=5)
                                                                               for s in GOOD[1:]],
        7: [GOOD[0].format(ts=1_140_000, g=7), GOOD[1].format(ts=1_140_000, g=7).replace("0.9931", "NaN")]
        + [s.format(ts=1_140_000, g=7) for s in GOOD[2:]],
        9: [s.format(ts=1_180_000, g=9) for s in GOOD[:3]] + [GOOD[3].format(ts=1_180_000, g=9)
                                                              .replace("0.9877", "-0.9877")] + [GOOD[4].format(
                                                                  ts=1_180_000, g=9)],
        11: [s.format(ts=1_220_000, g=11) for s in GOOD if '"right"' not in s or '"pc"' in s],
    }
    src = g2_folder(tmp_path, extra=['{"ts":2000000,"s":0,"gidx":', "not json",
                                     '{"ts":"2020000","s":0,"gidx":60,"pc":[1,2,3],"eye":"left"}'], replace=bad)
    rep = run_import(tobii_g2, src, tmp_path / "out")
    d = rep["dropped"]
    assert d["left eye: status 16"] == 1
    assert d["left eye: implausible eye centre (over 100 mm from the scene camera)"] == 1
    assert d["left eye: non-finite values"] == 1
    assert d["right eye: direction points backwards"] == 1
    assert d["sample: incomplete gidx group (an eye's pc or gd line missing)"] == 1
    assert d["line: unparsable JSON"] == 2 and d["line: eye-sample line without an integer ts"] == 1
    assert rep["eye_samples_written"] == 49
    r = read_eye_rays(tmp_path / "out" / "eye_rays.csv")
    assert r.left_valid.sum() == 46 and r.right_valid.sum() == 48



def test_g2_sync_lines_with_a_garbage_time_are_counted_not_a_crash(tmp_path):
    """A ``vts`` line whose ``ts`` or ``vts`` is not an integer (a damaged copy: the first one,
    read by the prepass, and a later one) is counted and skipped; the clock comes from the good
    sync lines (it was an internal error: ``'>' not supported between 'str' and 'int'``)."""
    src = g2_folder(tmp_path, n=50)
    live = src / "segments" / "1" / "livedata.json.gz"
    lines = gzip.open(live, "rt").read().splitlines()
    lines = ['{"ts":"abc","s":0,"vts":5}'] + lines[:100] + ['{"ts":1400000,"s":0,"vts":"x"}'] + lines[100:]
    with gzip.open(live, "wt") as fh:
        fh.write("\n".join(lines) + "\n")
    rep = run_import(tobii_g2, src, tmp_path / "out")
    assert rep["dropped"]["line: video sync (vts) line without an integer ts or vts"] == 2
    assert rep["eye_samples_written"] == 50 and rep["clock_offset_s"] == pytest.approx(1.0)


def test_g2_one_line_with_a_garbage_time_does_not_move_its_sample(tmp_path):
    """A sample whose first line (left ``pc``) has a damaged ``ts`` far ahead took that time: on the
    real recording it sat at t ~ 1e5 s in eye_rays.csv and the gap counter reported 4,999,282
    samples missing (in a recording longer than one chunk every later sample would be dropped as
    'time not increasing'). The sample's time is the median of its lines' times."""
    bad = {20: [GOOD[0].format(ts=99_999_999_999, g=20)] + [s.format(ts=1_400_000, g=20) for s in GOOD[1:]]}
    rep = run_import(tobii_g2, g2_folder(tmp_path, replace=bad), tmp_path / "out")
    assert rep["eye_samples_written"] == 50 and not any(k.startswith("gap") for k in rep["dropped"])
    t = read_eye_rays(tmp_path / "out" / "eye_rays.csv").t_s
    np.testing.assert_allclose(np.diff(t), 0.02, atol=1e-9)

@pytest.mark.parametrize(("make", "needle"), [
    (lambda root: (root / "rec").mkdir(), "no recording"),
    (lambda root: (root / "rec" / "segments" / "1").mkdir(parents=True), "no livedata.json.gz"),
    (lambda root: [(root / "rec" / "recordings" / k / "segments" / "1").mkdir(parents=True) for k in "ab"],
     "2 recordings"),
    (lambda root: [(root / "rec" / "segments" / k).mkdir(parents=True) for k in "12"], "2 segments"),
])
def test_g2_structural_problems_are_one_line(tmp_path, make, needle):
    make(tmp_path)
    one_line_error(tobii_g2, tmp_path / "rec", tmp_path / "out", needle)


def test_g2_not_gzip_and_truncated(tmp_path):
    """A livedata file that is not gzip is one line; a truncated one (the recording unit lost
    power) is read up to the cut, with a note saying so."""
    src = g2_folder(tmp_path / "a")
    live = src / "segments" / "1" / "livedata.json.gz"
    data = live.read_bytes()
    live.write_bytes(b"plain text, not gzip\n")
    one_line_error(tobii_g2, src, tmp_path / "out_a", "not a gzip file")
    live.write_bytes(data[: len(data) * 2 // 3])
    rep = run_import(tobii_g2, src, tmp_path / "out_b")
    assert any("truncated" in n for n in rep["notes"])
    assert 0 < rep["eye_samples_written"] < 50



def test_g2_livedata_cut_mid_line_is_noted_as_cut(tmp_path):
    """A livedata copy cut mid-line but gzipped whole (the real recording cut at half its lines)
    was read up to the cut with only "1 (line: unparsable JSON)" to show for it; the docs promise a
    note that the file was cut short, as for a truncated gzip."""
    src = g2_folder(tmp_path)
    live = src / "segments" / "1" / "livedata.json.gz"
    text = gzip.open(live, "rt").read()
    with gzip.open(live, "wt") as fh:
        fh.write(text[: len(text) // 2].rstrip("\n")[:-5])
    rep = run_import(tobii_g2, src, tmp_path / "out")
    assert any("ends in a partial line" in n and "cut short" in n for n in rep["notes"]), rep["notes"]
    assert 0 < rep["eye_samples_written"] < 50

def test_g2_all_samples_invalid_is_one_line(tmp_path):
    src = g2_folder(tmp_path, replace={i: [s.format(ts=1_000_000 + 20_000 * i, g=i).replace('"s":0', '"s":16')
                                           for s in GOOD] for i in range(50)})
    one_line_error(tobii_g2, src, tmp_path / "out", "no usable eye sample", "status 16")


def test_g2_video_without_calibration_is_one_line(tmp_path):
    src = g2_folder(tmp_path)
    (src / "segments" / "1" / "fullstream.mp4").write_bytes(b"")
    one_line_error(tobii_g2, src, tmp_path / "out", "--camera")


def test_g3_problems(tmp_path):
    """G3: absent eyes and ``"data": {}`` are counted; a missing gaze file, a recording.g3 that
    is not JSON and a malformed camera calibration are one line each."""
    sim = tiny_recording(tmp_path)
    tobii_g3.write_recording(sim, tmp_path / "rec")
    rep = run_import(tobii_g3, tmp_path / "rec", tmp_path / "out")
    lost = ~sim.rays.left_valid & ~sim.rays.right_valid
    assert rep["dropped"]["left eye: absent"] == int((~sim.rays.left_valid).sum())
    assert rep["dropped"]["sample: no valid eye"] == int(lost.sum()) > 0
    assert rep["read"]["gazedata gaze lines"] == len(sim.t)
    meta_path = tmp_path / "rec" / "recording.g3"
    meta = json.loads(meta_path.read_text())
    for i, (change, needle) in enumerate([
            (lambda m: m["scenecamera"]["camera-calibration"].pop("focal-length"), "malformed"),
            (lambda m: m["gaze"].update(file="nothere.gz"), "no such file"),
            (None, "not valid JSON")]):
        m = json.loads(json.dumps(meta))
        if change is None:
            meta_path.write_text("{ not json")
        else:
            change(m)
            meta_path.write_text(json.dumps(m))
        one_line_error(tobii_g3, tmp_path / "rec", tmp_path / f"bad{i}", needle)
    shutil.rmtree(tmp_path / "rec")


@pytest.mark.parametrize("fmt", ["tobii-g2", "tobii-g3"])
def test_roundtrip_through_process_finds_the_targets(fmt, tmp_path_factory, tmp_path):
    """Simulator -> Tobii recording -> import (scene video + the unit's camera + the room's
    markers: poses tracked by process) -> process finds the simulated targets as well as the
    native session does (RMS error within 1.1x, issue 14)."""
    from roundtrip import rms, roundtrip_errors

    nat, got, report = roundtrip_errors(fmt, tmp_path_factory.getbasetemp(), tmp_path)
    assert report["pose_source"] == "scene_video"
    assert report["frames"]["position_convention"]["confirmed"]
    assert np.all(np.isfinite(got)) and rms(got) <= 1.1 * rms(nat), (got, nat)
