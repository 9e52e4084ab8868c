"""The report's overlay and 3D view (issue 17): each colour as the caption names it (OpenCV
takes BGR), labels inside the frame, markers drawn only where detected, the full-resolution
video and the preview written; the 3D view's data survives its embedding in the page. The
report as a whole in a headless browser: tests/test_process.py."""

import json
import re

import cv2
import numpy as np
import pytest

from calibration.camera import CameraCalibration
from tracking.markermap import MarkerMap
from tracking.markers import MarkerDetector
from wearable_gaze.formats.eye_samples import EyeSamples
from wearable_gaze.formats.targets import target_record
from wearable_gaze.pipeline.report import overlay as ov
from wearable_gaze.pipeline.report import view3d
from wearable_gaze.pipeline.types import Target

W, H = 640, 480
CAMERA = CameraCalibration(np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]]), np.zeros(5), (W, H))
# what each colour name of the caption must look like, (R, G, B) -> bool
LOOKS = {"orange": lambda r, g, b: (r > 200) & (g > 90) & (g < 190) & (b < 70),
         "magenta": lambda r, g, b: (r > 200) & (g < 70) & (b > 200),
         "green": lambda r, g, b: (g > 150) & (r < 70) & (b < 70),
         "red": lambda r, g, b: (r > 180) & (g < 60) & (b < 60)}


class _Eye:
    """An eye calibration that maps any reading to one normalised image point."""

    def __init__(self, q):
        self.q = np.asarray(q, float)

    def image_points(self, raw):
        return np.tile(self.q, (len(raw), 1))


def _inputs(marker_map=None, q_left=(0.1, -0.05), q_right=(-0.2, 0.1)):
    eyes = EyeSamples(np.array([0.0]), np.array([0]), np.zeros((1, 2, 2)), np.array([[True, True]]))
    return ov.OverlayInputs(CAMERA, [_Eye(q_left), _Eye(q_right)], eyes, marker_map, None)


def _target(index=0, position=(0.0, 0.0, 1000.0)):
    x, y, z = position
    return Target.from_row(target_record(index, 0.0, 1.0, (x, y, z), (10.0, 10.0, 50.0), 10, "voxel", "ok",
                                         crb_mm=5.0, fixations=[0]))


def _ring_color(img, center, radius):
    """The mean (R, G, B) of the drawn pixels at ``radius`` +-1.5 px around ``centre``."""
    yy, xx = np.mgrid[:img.shape[0], :img.shape[1]]
    ring = np.abs(np.hypot(xx - center[0], yy - center[1]) - radius) < 1.5
    ring &= img.sum(axis=2) > 200                                  # drawn, not the black background
    assert ring.sum() > 20, "nothing drawn at the gaze point"
    b, g, r = img[ring].mean(axis=0)
    return r, g, b


def test_each_eyes_gaze_circle_has_the_colour_the_caption_names():
    marks = ov.frame_marks(_inputs(), [], ov.OverlayTargets([], np.zeros(0), np.zeros(0, int)), np.eye(4), 0.0, 2.0)
    assert [e for e, _ in marks.gaze] == [0, 1]
    px = {e: p for e, p in marks.gaze}
    np.testing.assert_allclose(px[0], [320 + 50, 240 - 25], atol=1e-6)   # K (0.1, -0.05, 1)
    img = ov.draw_marks(np.zeros((H, W, 3), np.uint8), marks)
    text = ov.caption()
    radius = 14 * W / 1280
    for e, (what, name, _) in enumerate(ov.EYE_COLORS):
        assert f"{name} {what}" in text
        rgb = _ring_color(img, px[e], radius)
        assert LOOKS[name](*rgb), (what, name, rgb)


def _label_box(img, rgb_test, exclude):
    """Bounding box (x0, y0, x1, y1) of the pixels passing ``rgb_test`` outside ``exclude``
    ((x0, y0, x1, y1)), or None."""
    b, g, r = (img[..., k].astype(int) for k in range(3))
    hit = rgb_test(r, g, b)
    x0, y0, x1, y1 = exclude
    hit[max(y0, 0):y1, max(x0, 0):x1] = False
    ys, xs = np.nonzero(hit)
    return (xs.min(), ys.min(), xs.max(), ys.max()) if len(xs) else None


@pytest.mark.parametrize("px", [(W - 3.0, 2.0), (2.0, H - 2.0), (W - 1.0, H - 1.0), (0.0, 0.0)])
def test_a_target_label_at_the_border_is_drawn_whole_inside_the_frame(px):
    marks = ov.FrameMarks(targets=[(7, np.array(px), 2345.0)])
    img = ov.draw_marks(np.zeros((H, W, 3), np.uint8), marks)
    s = W / 1280
    text = "target 7: 2.35 m"
    (tw, th), _ = cv2.getTextSize(text, ov.FONT, 0.9 * s, max(int(round(2 * s)), 1))
    arm = int(round(40 * s)) // 2 + 2                                 # the cross, drawn at the point itself
    box = _label_box(img, lambda r, g, b: (r > 150) & (g < 90) & (b < 90),
                     (int(px[0]) - arm, int(px[1]) - arm, int(px[0]) + arm + 1, int(px[1]) + arm + 1))
    assert box is not None, "the label was not drawn"
    assert box[2] - box[0] + 1 >= 0.9 * tw and box[3] - box[1] + 1 >= 0.6 * th, (box, tw, th)


def test_label_origin_keeps_the_box_inside(rng):
    for _ in range(200):
        w, h = rng.integers(200, 2000, 2)
        tw, th = rng.integers(5, 180), rng.integers(5, 60)
        anchor = rng.uniform(-50, [w + 50, h + 50])
        x, y = ov.label_origin((tw, th), anchor, (w, h))
        assert 0 <= x and x + tw <= w and 0 <= y - th and y <= h, (anchor, (x, y), (tw, th), (w, h))


def _marker_frame(marker_id=3, side=120, at=(40, 40)):
    """A white frame with one DICT_4X4_50 marker (white border included) at ``at``."""
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    img = np.full((H, W, 3), 255, np.uint8)
    m = cv2.aruco.generateImageMarker(d, marker_id, side)
    img[at[1] + 20:at[1] + 20 + side, at[0] + 20:at[0] + 20 + side] = m[..., None]
    return img


def test_markers_are_drawn_where_detected_not_projected_from_the_map():
    T7 = np.eye(4)
    T7[:3, 3] = [0, 0, 1000]                                         # in the map, right in front of the camera
    mm = MarkerMap("DICT_4X4_50", 100.0, {3: np.eye(4), 7: T7}, {})
    frame = _marker_frame()
    found = MarkerDetector(mm.dictionary).detect(cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY))
    marks = ov.frame_marks(_inputs(mm), found, ov.OverlayTargets([], np.zeros(0), np.zeros(0, int)), np.eye(4), 9.0,
                           2.0)
    assert [(i, in_map) for i, _, in_map in marks.markers] == [(3, True)]
    img = ov.draw_marks(frame, marks)
    b, g, r = (img[..., k].astype(int) for k in range(3))
    green = g - np.maximum(r, b) > 60                               # anti-aliased on white: greenish
    ys, xs = np.nonzero(green)
    assert len(xs) > 100
    assert xs.max() < 40 + 20 + 120 + 10 and ys.max() < 40 + 20 + 120 + 10      # around marker 3 only
    assert not green[180:300, 260:380].any()                                  # nothing where 7 would project


def test_nothing_is_drawn_outside_the_calibrated_field():
    fisheyeish = CameraCalibration(CAMERA.camera_matrix, np.array([-0.4, 0.15, 0, 0, -0.02]), (W, H))
    r = ov.field_radius(fisheyeish)
    far = np.array([[3.0 * r * 1000, 0.0, 1000.0], [0.0, 0.0, -1000.0], [10.0, 0.0, 50.0]])
    assert np.all(np.isnan(ov.project_in_view(fisheyeish, far, r)))
    assert np.all(np.isfinite(ov.project_in_view(fisheyeish, [[0.0, 0.0, 1000.0]], r)))


def _read_all(path):
    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, f = cap.read()
        if not ok:
            break
        frames.append(f)
    cap.release()
    return frames


def test_overlay_video_is_full_resolution_and_the_preview_small(tmp_path):
    """Both videos H.264 (browsers play it): the full one every frame at full size, the report's
    every third frame (10 fps of 30) at 640 px, the whole video long."""
    import av
    video = tmp_path / "scene.mp4"
    n = 8
    wr = cv2.VideoWriter(str(video), cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (W, H))
    for _ in range(n):
        wr.write(_marker_frame())
    wr.release()
    mm = MarkerMap("DICT_4X4_50", 100.0, {3: np.eye(4)}, {})
    inp = _inputs(mm)
    inp = ov.OverlayInputs(inp.camera, inp.eyes, inp.eye_samples, mm, video)
    t = np.arange(n) / 30.0
    targets = ov.OverlayTargets([_target(5, (100.0, 50.0, 1000.0))], t, np.full(n, 5))
    names = ov.write_overlays(tmp_path, inp, targets, t, np.arange(n), np.repeat(np.eye(4)[None], n, axis=0),
                              video=True)
    assert names == (ov.PREVIEW_NAME, ov.VIDEO_NAME)
    for name in names:
        with av.open(str(tmp_path / name)) as c:
            assert c.streams.video[0].codec_context.name == "h264"
    frames = _read_all(tmp_path / ov.VIDEO_NAME)
    assert len(frames) == n and frames[0].shape == (H, W, 3)
    u, v = 320 + 50, 240 + 25                                          # the target (100, 50, 1000) mm
    patch = frames[0][v - 3:v + 4, u - 3:u + 4].reshape(-1, 3).astype(int)
    assert any(LOOKS["red"](r, g, b) for b, g, r in patch), "no red cross at the target"
    small = _read_all(tmp_path / ov.PREVIEW_NAME)
    assert small[0].shape == (ov.PREVIEW_WIDTH * H // W, ov.PREVIEW_WIDTH, 3)
    assert len(small) == len(range(0, n, round(30.0 / ov.PREVIEW_FPS)))


def test_the_preview_alone_finds_its_markers_without_refining_their_corners(tmp_path, monkeypatch):
    """The markers are drawn where found; at the preview's 640 px their corners' sub-pixel
    refinement shows nothing and cost a third of the overlay's marker detection. Without the
    full-resolution video it is not run (bench_report_cost.py), and the markers are still found."""
    import tracking.markers as markers

    def refuse(*a, **k):
        raise AssertionError("corners refined for the preview")
    found = []
    detect = markers.MarkerDetector.detect
    monkeypatch.setattr(markers, "refine_markers", refuse)
    monkeypatch.setattr(markers.MarkerDetector, "detect",
                        lambda self, img: found.append(detect(self, img)) or found[-1])
    video = tmp_path / "scene.mp4"
    n = 4
    wr = cv2.VideoWriter(str(video), cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (W, H))
    for _ in range(n):
        wr.write(_marker_frame())
    wr.release()
    mm = MarkerMap("DICT_4X4_50", 100.0, {3: np.eye(4)}, {})
    inp = _inputs(mm)
    inp = ov.OverlayInputs(inp.camera, inp.eyes, inp.eye_samples, mm, video)
    t = np.arange(n) / 30.0
    targets = ov.OverlayTargets([], t, np.full(n, -1))
    names = ov.write_overlays(tmp_path, inp, targets, t, np.arange(n), np.repeat(np.eye(4)[None], n, axis=0))
    assert names == (ov.PREVIEW_NAME, None)
    assert found and all([d.marker_id for d in f] == [3] for f in found)


def test_the_3d_views_data_survives_its_embedding():
    tg = view3d.SceneTarget(2, "#2ca02c", np.array([1.0, 2.0, 3000.0]), np.diag([10.0, 20.0, 300.0]),
                            np.array([[[0, 0, 0], [1, 2, 3000]]], float), truth_mm=np.array([0.0, 0.0, 2900.0]))
    scene = view3d.scene([tg], np.array([[0.0, 0, 0], [5, 5, 5], [np.nan, 0, 0]]),
                         [np.zeros((4, 3))], other_truth=[("</script><b>x", [1, 2, 3])])
    block = view3d.html_block(scene, has_truth=True)
    m = re.search(r'<script type="application/json" id="view3d-data">(.*?)</script>', block, re.S)
    assert json.loads(m.group(1)) == scene                           # "</" escaped: the script is not cut short
    assert scene["targets"][0]["truth"] == [0, 0, 2900] and scene["head"] == [[0, 0, 0], [5, 5, 5]]
    assert "http" not in view3d.viewer_script()                       # nothing fetched: works offline
    assert scene["points"] == []
    # a markerless map's points: thinned, rounded to 1 mm, non-finite rows dropped
    P = np.random.default_rng(0).uniform(-2000, 2000, (10000, 3))
    P[5] = np.nan
    pts = view3d.scene([tg], np.zeros((1, 3)), points_mm=P)["points"]
    assert len(pts) == view3d.MAX_ROOM_POINTS and all(len(p) == 3 and isinstance(p[0], int) for p in pts)
    assert pts[0] == [round(v) for v in P[0]] and [None] not in pts


def test_process_overlay_video_option_reaches_the_report_step(tmp_path, monkeypatch):
    from wearable_gaze.cli import main
    from wearable_gaze.pipeline.process import session as process
    from wearable_gaze.pipeline.process.stepcache import ProcessResult

    seen = []

    def fake(*args, **kwargs):
        seen.append(kwargs)
        return ProcessResult(tmp_path)
    monkeypatch.setattr(process, "process_session", fake)
    (tmp_path / "s").mkdir()
    main(["process", str(tmp_path / "s"), "--overlay-video"])
    main(["process", str(tmp_path / "s")])
    assert [k["overlay_video"] for k in seen] == [True, False]


def test_a_targets_distance_is_from_where_it_was_looked_at():
    """The report's "distance from the head" was the distance from the head's mean position over
    the session: on the real Aria sample (a 7.7 m walk) 0.76 m for a target looked at from 2.1 m.
    It is the median distance from the eyes at the target's own samples (the mean position only
    for a target without samples)."""
    from types import SimpleNamespace

    from wearable_gaze.pipeline.report.page import ReportData

    x = np.linspace(0.0, 10000.0, 101)                         # the head walks 10 m along x
    orig = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    tlabels = np.where(x < 500, 0, -1)                          # target 0 looked at from the first 0.5 m
    d = ReportData([], None, tlabels, None, orig, orig.mean(axis=0), {}, orig, None, {}, {}, [])
    seen = SimpleNamespace(index=0, position_mm=np.array([250.0, 0.0, 2000.0]))
    assert abs(d.distance_m(seen) - np.median(np.hypot(250.0 - x[x < 500], 2000.0)) / 1000) < 1e-12
    unseen = SimpleNamespace(index=1, position_mm=np.array([5000.0, 0.0, 2000.0]))
    assert abs(d.distance_m(unseen) - 2.0) < 1e-12


def test_the_3d_and_top_views_of_54_targets_number_them_and_keep_their_layout(tmp_path):
    """A real G2 recording (gazeMapper example 2) gives 54 targets: a legend naming each was taller
    than the axes and matplotlib's constrained layout collapsed them (a warning, a 3D view with no
    room). Beyond ``MAX_LEGEND_TARGETS`` each target is numbered beside it and the legend says
    what the marks are; no layout warning."""
    import warnings

    from test_regions import _data, _record

    from wearable_gaze.pipeline.report import page as report
    from wearable_gaze.pipeline.report import plots as report_plots

    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-1500, 1500, 54), rng.uniform(-500, 500, 54), rng.uniform(800, 4000, 54)])
    d = _data([_record(k, p) for k, p in enumerate(pts)])
    assert report_plots._numbered(d) and not report_plots._numbered(_data([_record(0, pts[0])]))
    for make, name in ((report_plots.figure_3d, "3d.png"), (report_plots.figure_top, "top.png")):
        fig = make(d, report.color)
        ax = fig.axes[0]
        legend = [t.get_text() for t in ax.get_legend().get_texts()]
        assert len(legend) <= 6 and any("54 targets" in t for t in legend), legend
        numbers = {t.get_text().strip() for t in ax.texts}
        assert {str(k) for k in range(54)} <= numbers
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            report_plots._save(fig, tmp_path / name)
        assert not [str(w.message) for w in caught if "layout" in str(w.message)]
        assert (tmp_path / name).stat().st_size > 0


def test_the_preview_draws_the_tracking_steps_detections_and_detects_nothing_again(tmp_path, monkeypatch):
    """Given the tracking step's detections (every other frame, as ``process --track-every 2``
    detects), the preview shows only those frames, every k-th for at most ``PREVIEW_FPS``, draws
    their markers where tracking found them (here a marker where the image has none) and runs no
    detector; without them, as before."""
    import tracking.markers as markers
    from tracking.markers import MarkerDetection

    video = tmp_path / "scene.mp4"
    n = 24
    wr = cv2.VideoWriter(str(video), cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (W, H))
    for _ in range(n):
        wr.write(np.full((H, W, 3), 255, np.uint8))                # no marker in the image
    wr.release()
    box = np.array([[300.0, 200.0], [420.0, 200.0], [420.0, 320.0], [300.0, 320.0]])
    dets = {f: [MarkerDetection(3, box)] for f in range(0, n, 2)}
    assert ov.preview_frames(range(n), 30.0, dets) == (set(range(0, n, 4)), 7.5)
    assert ov.preview_frames(range(n), 30.0) == (set(range(0, n, 3)), 10.0)
    assert ov.preview_frames(range(n), 25.0, {f: [] for f in range(0, n, 2)}) == (set(range(0, n, 4)), 6.25)

    def refuse(*a, **k):
        raise AssertionError("markers detected again")
    monkeypatch.setattr(markers.MarkerDetector, "detect", refuse)
    mm = MarkerMap("DICT_4X4_50", 100.0, {3: np.eye(4)}, {})
    base = _inputs(mm)
    inp = ov.OverlayInputs(base.camera, base.eyes, base.eye_samples, mm, video, dets)
    t = np.arange(n) / 30.0
    names = ov.write_overlays(tmp_path, inp, ov.OverlayTargets([], t, np.full(n, -1)), t, np.arange(n),
                              np.repeat(np.eye(4)[None], n, axis=0))
    assert names == (ov.PREVIEW_NAME, None)
    small = _read_all(tmp_path / ov.PREVIEW_NAME)
    assert len(small) == n // 4
    s = ov.PREVIEW_WIDTH / W
    edge = small[0][int(260 * s) - 3:int(260 * s) + 4, int(300 * s) - 2:int(300 * s) + 3].reshape(-1, 3).astype(int)
    assert any(g - max(r, b) > 60 for b, g, r in edge), "no green outline where tracking found the marker"


def test_process_hands_the_tracking_steps_detections_to_the_overlay(tmp_path, monkeypatch):
    """``process`` keeps the markers tracking detected (``.marker_detections.npz``) and the
    report's overlay draws them, detecting nothing again: when tracking ran in the same run (its
    values) and when it was cached (the file read back)."""
    import json

    from wearable_gaze.formats.marker_detections import read_marker_detections
    from wearable_gaze.pipeline.process.session import process_session
    from wearable_gaze.sim.simulate import simulate_scenario

    class Refuse:
        def __init__(self, *a, **k):
            pass

        def detect(self, image):
            raise AssertionError("the overlay detected markers again")
    session = tmp_path / "s"
    simulate_scenario({"base": "lab-walkabout", "duration_s": 4.0, "camera": {"resolution": [320, 180]}}, session,
                      seed=0)
    monkeypatch.setattr(ov, "MarkerDetector", Refuse)
    out = tmp_path / "out"
    for run in range(2):
        res = process_session(session, out)
        assert res.status["report"] == "done" and res.status["tracking"] == ("done", "cached")[run]
        assert (out / ov.PREVIEW_NAME).stat().st_size > 0 and not (out / "overlay_error.txt").exists()
        (out / "report.html").unlink()                         # the report alone is redone next
    dets = read_marker_detections(out / ".marker_detections.npz")
    assert len(dets) > 0 and sum(len(v) for v in dets.values()) > len(dets)
    assert ".marker_detections.npz" in json.loads((out / ".steps.json").read_text())["tracking"]["outputs"]


def test_the_tracking_steps_detections_are_the_markers_the_overlays_detector_finds(processed):
    """On the shared processed session, in the frames the report's preview shows, the markers
    tracking kept are those the overlay's own detector finds, refined as the full-resolution video
    refines them: the same ids at the same corners, so the same outlines at the same pixels; the
    preview's quick, unrefined detection (what the overlay drew before it was given them) finds
    the same markers, their corners within 2.5 px of these (1.7 px median)."""
    from calibration.images import to_gray
    from wearable_gaze.formats.marker_detections import read_marker_detections
    from wearable_gaze.formats.markermap import load_marker_map
    from wearable_gaze.formats.poses import read_poses_csv

    session, out, _ = processed
    dets = read_marker_detections(out / ".marker_detections.npz")
    mm = load_marker_map(session / "markers.json")
    _, frames, T, _ = read_poses_csv(out / "poses.csv")
    shown, _ = ov.preview_frames(frames[np.isfinite(T[:, 0, 0])], 30.0, dets)
    refined, quick = MarkerDetector(mm.dictionary, refine="edges"), MarkerDetector(mm.dictionary, refine="none")
    cap, i, compared, off = cv2.VideoCapture(str(session / "scene.mp4")), 0, 0, []
    while compared < 12 and cap.grab():
        if i in shown and dets[i]:
            frame = cap.retrieve()[1]
            mine = sorted((d.marker_id, d.corners_px.tolist()) for d in dets[i])
            assert mine == sorted((d.marker_id, d.corners_px.tolist()) for d in refined.detect(frame)), i
            marks = [ov.FrameMarks([(k, np.array(c), k in mm.poses) for k, c in m]) for m in (mine, [
                (d.marker_id, d.corners_px.tolist()) for d in refined.detect(frame)])]
            assert np.array_equal(ov.draw_marks(frame, marks[0]), ov.draw_marks(frame, marks[1]))
            fast = {d.marker_id: d.corners_px for d in quick.detect(to_gray(frame))}
            assert sorted(fast) == [k for k, _ in mine]
            off += [np.abs(np.array(c) - fast[k]).max() for k, c in mine]
            compared += 1
        i += 1
    cap.release()
    assert compared == 12 and max(off) < 2.5
