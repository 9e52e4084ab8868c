"""Every fixation answered (issue 27): lines that fix a direction but no point (far targets with
diverging rays, one cyclopean line per sample from a still head) give a ``direction-only``
answer with its 95 % cone and a depth interval that may have no far end, in ``estimate``,
``process``'s targets and exports, and the live session."""

import numpy as np
import pytest

from estimator import BinocularSamples, Status, estimate, make_estimator, perturb_directions
from estimator.direction import GazeDirection, gaze_direction
from estimator.errormodel import ErrorModel
from estimator.frames import rotation_about_axis
from estimator.result import NEAR_POINT_MM, GazeEstimate, near_point_check
from wearable_gaze.formats.jsonio import validate
from wearable_gaze.pipeline.types import Target

FAR = np.array([900.0, -300.0, 8000.0])
"""A target 8 m away: the eyes converge by 0.46 deg, less than a 0.3 deg outward bias per eye."""


def _rotate(d, yaw_deg):
    """Directions (N, 3) turned about the vertical axis (+: toward +x, the right)."""
    return d @ rotation_about_axis([0, 1, 0], np.deg2rad(yaw_deg)).T


def diverging(point, rng, n=90, bias_deg=0.3, sigma_deg=0.5, head_mm=None, t0=0.0):
    """``n`` samples at 60 Hz of two eyes 64 mm apart looking at ``point`` (3,) mm, each turned
    ``bias_deg`` outward (a diverging vergence bias), ``sigma_deg`` of noise; the head at
    ``head_mm`` (N, 3) (default still at the origin). World frame."""
    head = np.zeros((n, 3)) if head_mm is None else head_mm
    lo, ro = head - [32.0, 0, 0], head + [32.0, 0, 0]
    dl = perturb_directions(_rotate(point - lo, -bias_deg), np.deg2rad(sigma_deg), rng)
    dr = perturb_directions(_rotate(point - ro, bias_deg), np.deg2rad(sigma_deg), rng)
    return BinocularSamples.from_arrays(t0 + np.arange(n) / 60.0, lo, dl, ro, dr)


@pytest.mark.parametrize("method", ["ml", "voxel"])
def test_diverging_rays_of_a_far_target_give_its_direction_not_a_failure(method, rng):
    s = diverging(FAR, rng)
    e = estimate(s, method, 0.5, error_model=ErrorModel(bias_deg=0.3))
    assert e.status is Status.DIRECTION_ONLY and e.position_mm is None and e.covariance_mm2 is None
    g = e.direction
    assert g is not None and g.n_samples == len(s) and g.contains(FAR)
    assert 0.1 < g.cone95_deg < 1.5
    near, far = g.depth95_mm
    assert NEAR_POINT_MM <= near < np.linalg.norm(FAR) and far == np.inf        # only a lower bound
    d = e.to_dict()
    assert d["status"] == "direction-only" and d["position_mm"] is None
    assert d["direction"]["depth95_mm"][1] is None and GazeDirection.from_dict(d["direction"]).contains(FAR)
    assert estimate(s.select(slice(0, 2)), method, 0.5).status is not Status.DIRECTION_ONLY     # 2: too few


def test_one_line_per_sample_from_a_still_head_is_a_direction_with_no_depth(rng):
    """A 2D-only tracker (Pupil Cloud without eye states) with a still head: every line from one
    origin; the direction is all there is, and the depth interval is the whole of it."""
    n = 120
    o = np.zeros((n, 3))
    d = perturb_directions(np.tile(FAR / np.linalg.norm(FAR), (n, 1)), np.deg2rad(0.8), rng)
    s = BinocularSamples.from_arrays(np.arange(n) / 100.0, o, d, np.full((n, 3), np.nan), np.full((n, 3), np.nan))
    e = estimate(s, "voxel", 1.0, error_model=ErrorModel())
    assert e.status is Status.DIRECTION_ONLY and e.direction.contains(FAR)
    assert e.direction.depth95_mm == (NEAR_POINT_MM, np.inf)
    assert e.direction.spread_deg == pytest.approx(0.8, rel=0.2)


def one_eye_first(point, rng, n_first=3, near_mm=15.0):
    """``diverging(point)`` from a still head after ``n_first`` samples of the left eye alone whose
    lines meet ``near_mm`` in front of it, on its line to ``point``: its origin moves 0.2 mm a
    sample, as a Tobii G3's eye centre does (the real gaze-only sample's fixation at 13.64 s began
    with three left-eye samples that meet 15-20 mm ahead of that eye)."""
    later = diverging(point, rng, n=66, t0=n_first / 60.0)
    lo = later.left_origin_mm[0] + np.outer(np.arange(n_first), [0.0, 0.2, 0.0])
    u = point - later.left_origin_mm[0]
    d = later.left_origin_mm[0] + near_mm * u / np.linalg.norm(u) - lo
    nan = np.full((n_first, 3), np.nan)
    first = BinocularSamples.from_arrays(np.arange(n_first) / 60.0, lo, d, nan, nan)
    return BinocularSamples.concatenate([first, later])


@pytest.mark.parametrize("method", ["ml", "voxel"])
def test_one_eyes_first_lines_meeting_near_it_do_not_hold_a_far_fixations_answer(method, rng):
    """The voxel estimator laid its box where the first three (left-eye) lines met, 15 mm ahead
    of that eye, and then weighed every binocular sample against that box: all were 'outliers'
    (weight 0), the box kept its point and the fixation came out 'too-near' (no target) although
    its 69 lines look 8 m away. A box whose posterior rejects most samples is dropped now; both
    methods answer the far fixation by its direction."""
    s = one_eye_first(FAR, rng)
    e = estimate(s, method, 0.5, error_model=ErrorModel(bias_deg=0.3))
    assert e.status is Status.DIRECTION_ONLY, (e.status, e.position_mm, e.reason)
    assert e.direction.contains(FAR) and e.direction.depth95_mm[1] == np.inf
    if method == "voxel":
        est = make_estimator("voxel", 0.5)
        for i in range(len(s)):
            est.update(s.sample(i))
        assert est._buf.weight_sum == pytest.approx(est.weights.sum())      # kept in step


def one_eye_fan(meet_mm, rng, n=60):
    """(samples, (n, 3) origins mm, the point mm): ``n`` samples at 60 Hz of the left eye alone
    from a still head, its origin moving 1.2 mm as an eye model's centre does, whose lines (0.2 deg
    of noise) meet ``meet_mm`` in front of it on its line to ``FAR``."""
    lo = np.array([-32.0, 0, 0]) + np.outer(np.linspace(0, 1.2, n), [0.0, 1.0, 0.0])
    near = lo[0] + meet_mm * (FAR - lo[0]) / np.linalg.norm(FAR - lo[0])
    nan = np.full((n, 3), np.nan)
    s = BinocularSamples.from_arrays(np.arange(n) / 60.0, lo, perturb_directions(near - lo, np.deg2rad(0.2), rng),
                                     nan, nan)
    return s, lo, near


@pytest.mark.parametrize("method", ["ml", "voxel"])
def test_one_eyes_lines_from_a_still_head_meeting_near_it_are_a_direction_not_wrong_lines(method, rng):
    """A fixation the other eye lost, from a still head: one eye's lines, their origin moving
    1.2 mm as an eye model's centre does, meet 15 mm in front of it. That is no parallax (the lines
    were seen from one place), so the point says nothing about the lines being wrong: the
    fixation is answered by its direction, not 'too-near' (which needs lines from more than one
    place: the two eyes' lines meeting 40 mm ahead stay 'too-near', tests/test_import.py)."""
    s, lo, near = one_eye_fan(15.0, rng)
    e = estimate(s, method, 0.5)
    assert e.status is Status.DIRECTION_ONLY, (e.status, e.position_mm, e.reason)
    assert "seen from one place" in e.reason and e.direction.depth95_mm == (NEAR_POINT_MM, np.inf)
    both = BinocularSamples.from_arrays(s.t_s, lo, s.left_direction, lo + [64.0, 0, 0],
                                        perturb_directions(near - lo - [64.0, 0, 0], np.deg2rad(0.2), rng))
    assert estimate(both, method, 0.5).status is Status.TOO_NEAR          # two eyes' lines meeting there
    # their depth interval, all of it nearer than the near point, was (70 mm, 20 mm): far before near
    assert gaze_direction(both).depth95_mm == (NEAR_POINT_MM, np.inf)


@pytest.mark.parametrize("method", ["ml", "voxel"])
def test_one_eyes_lines_from_a_still_head_give_no_point_however_far_they_meet(method, rng):
    """The same one-eye fan whose lines cross 180 mm ahead (beyond the near point, where a point
    used to pass as 'ok'): seen from one place, their crossing is the eye centre's motion and
    the noise, no depth; the fixation is answered by its direction."""
    e = estimate(one_eye_fan(180.0, rng)[0], method, 0.5)
    assert e.status is Status.DIRECTION_ONLY, (e.status, e.position_mm, e.reason)
    assert "seen from one place" in e.reason


def test_a_near_point_at_the_centre_of_the_eye_most_lines_come_from_is_no_point_not_wrong_lines(rng):
    """The real G3 gaze-only sample's last fixation: 16 left-eye lines from a still head (its
    centre moving 0.2 mm a sample) and 3 right-eye lines 18 deg below them; ``voxel``'s peak was
    the left eye's own centre, 6 mm ahead of it, where its lines all meet: no depth, and no sign
    of wrong lines. Such a point is no point (answered by the direction); a point 40 mm ahead of
    both eyes (swapped eyes) stays 'too-near'."""
    n = 16
    lo = np.array([-32.0, 0, 0]) + np.outer(np.arange(n) * 0.2, [0.0, 1.0, 0.0])
    ld = perturb_directions(FAR - lo, np.deg2rad(0.3), rng)
    ro = np.full((3, 3), [32.0, 0, 0])
    rd = perturb_directions(np.tile(FAR - [32.0, 0, 0] + [0, 2600.0, 0], (3, 1)), np.deg2rad(1.5), rng)
    origins, directions = np.concatenate([lo, ro]), np.concatenate([ld, rd])
    for point, want in ((lo.mean(axis=0) + [0, 0, 6.0], Status.DEGENERATE), ([0.0, 0.0, 40.0], Status.TOO_NEAR)):
        e = GazeEstimate("voxel", Status.OK, np.array(point), np.eye(3), n + 3, n + 3)
        checked = near_point_check(e, origins, directions)
        assert checked.status is want, (point, checked.status, checked.reason)
    assert "the eye most of them come from" in near_point_check(
        GazeEstimate("voxel", Status.OK, lo.mean(axis=0) + [0, 0, 6.0], np.eye(3), n + 3, n + 3),
        origins, directions).reason


@pytest.mark.slow
def test_the_cone_holds_the_true_direction_95_percent_of_the_time(rng):
    """Each eye's bias drawn from the error model's (0.2 deg per axis), noise 0.5 deg: the true
    direction lies in 92-98 % of the 95 % cones (the cone sums the spread over the fixation and
    the bias as the cyclopean mean sees it)."""
    model = ErrorModel(bias_deg=0.2)
    hits = []
    for _ in range(400):
        X = np.array([rng.uniform(-2000, 2000), rng.uniform(-800, 800), rng.uniform(3000, 8000)])
        n = int(rng.integers(20, 120))
        lo, ro = np.tile([-32.0, 0, 0], (n, 1)), np.tile([32.0, 0, 0], (n, 1))
        dl, dr = (perturb_directions(np.tile(X - o[0], (1, 1)), np.deg2rad(0.2), rng) for o in (lo, ro))
        s = BinocularSamples.from_arrays(np.arange(n) / 60.0, lo, perturb_directions(np.repeat(dl, n, 0),
                                                                                  np.deg2rad(0.5), rng),
                                         ro, perturb_directions(np.repeat(dr, n, 0), np.deg2rad(0.5), rng))
        hits.append(gaze_direction(s, model).contains(X))
    assert 0.92 <= np.mean(hits) <= 0.98, np.mean(hits)


def _session(rng):
    """Four fixations at 60 Hz with 0.2 s saccades between them: a near one (1 m) that fixes a
    point, then three far ones (6-8 m) whose rays diverge (0.3 deg outward per eye); a still head."""
    points = [np.array([200.0, 0.0, 1000.0]), np.array([-1500.0, 200.0, 7000.0]), FAR,
              np.array([2500.0, 400.0, 6000.0])]
    parts, labels, t0 = [], [], 0.0
    for k, X in enumerate(points):
        parts.append(diverging(X, rng, n=90, bias_deg=0.0 if k == 0 else 0.3, t0=t0))
        labels += [k] * 90
        t0 += 1.7
    return BinocularSamples.concatenate(parts), np.array(labels), points


def test_find_targets_answers_every_fixation_and_each_has_a_direction(rng):
    from wearable_gaze.pipeline.steps.export import fixation_rows
    from wearable_gaze.pipeline.steps.fixations import find_targets

    samples, labels, points = _session(rng)
    res = find_targets(samples, labels, "voxel", 0.5, error_model=ErrorModel(bias_deg=0.3))
    assert len(res.targets) == 4 and [t.fixations for t in res.targets] == [(0,), (1,), (2,), (3,)]
    assert res.targets[0].status == "ok"
    for tg, X in zip(res.targets[1:], points[1:], strict=True):
        assert tg.status == "direction-only" and tg.fixated and not np.isfinite(tg.position_mm).any()
        assert tg.direction.contains(X) and tg.direction.depth95_mm[1] == np.inf
    assert res.targets[0].direction is not None and res.targets[0].direction.contains(points[0])
    rows = fixation_rows(res)
    assert [r["status"] for r in rows] == ["ok"] + ["direction-only"] * 3
    assert all(r["direction"] is not None for r in rows[1:])


def test_a_direction_only_target_in_every_export(rng, tmp_path):
    """targets.json (schema-checked, read back), targets.csv, fixations.csv and targets.ply."""
    from wearable_gaze.formats.fixations_table import read_fixations_csv
    from wearable_gaze.formats.tables import read_table
    from wearable_gaze.formats.targets import TARGET_CSV_CHECKS, read_targets
    from wearable_gaze.pipeline.steps.export import targets_mesh, write_fixations_step
    from wearable_gaze.pipeline.steps.fixations import find_targets, write_targets_step
    from wearable_gaze.pipeline.types import Poses

    samples, labels, points = _session(rng)
    res = find_targets(samples, labels, "voxel", 0.5, error_model=ErrorModel(bias_deg=0.3))
    write_targets_step(tmp_path, res, "voxel")
    write_fixations_step(tmp_path, res)
    recs = read_targets(tmp_path / "targets.json")
    assert [r["status"] for r in recs] == ["ok"] + ["direction-only"] * 3
    back = [Target.from_row(r) for r in recs]
    for tg, X in zip(back[1:], points[1:], strict=True):
        assert tg.direction.contains(X) and tg.status == "direction-only"
    csv = read_table(tmp_path / "targets.csv", ["direction_x", "direction_y", "direction_z", "cone95_deg",
                                                "depth95_near_mm", "depth95_far_mm"], text_columns=("status",),
                     checks=TARGET_CSV_CHECKS)
    assert np.all(np.isfinite(csv["cone95_deg"])) and np.isnan(csv["depth95_far_mm"][1:]).all()
    assert np.allclose(csv["direction_z"][2], back[2].direction.unit[2], atol=1e-6)
    fx = read_fixations_csv(tmp_path / "fixations.csv")
    assert list(fx["status"]) == ["ok"] + ["direction-only"] * 3 and np.isfinite(fx["cone95_deg"][1:]).all()
    mesh = targets_mesh(back, Poses(np.zeros(1), np.zeros(1, int), np.full((1, 4, 4), np.nan)))
    assert len(mesh.edges) == 3 and any("direction-only" in n for n in mesh.comments)
    ray = mesh.vertices_mm[mesh.edges[1]]
    u = (ray[1] - ray[0]) / np.linalg.norm(ray[1] - ray[0])
    assert np.allclose(u, back[2].direction.unit, atol=1e-9)


def test_the_live_session_answers_a_far_fixation_by_its_direction():
    """A still head looking 6 m away with a diverging bias: no usable point, so before, the
    fixation gave no target; now its target is direction-only and its message is valid."""
    from test_live_parts import _eyes, _record

    from wearable_gaze.live.messages import target_message
    from wearable_gaze.pipeline.steps.live_estimation import GazeEstimation

    eyes = _eyes()
    est = GazeEstimation(eyes, "voxel")
    rng = np.random.default_rng(4)
    bias = np.array([[-0.006, 0.0], [0.006, 0.0]])            # ~0.35 deg outward per eye
    for k in range(120):
        rec = _record(eyes, k, k / 60.0, np.eye(4), FAR, noise=bias + rng.normal(0, 0.004, (2, 2)))
        est.add(k / 60.0, rec, np.eye(4))
    done = est.end_fixation()
    assert done is not None
    target = est.finish(done)
    assert target is not None and target.status == "direction-only" and target.direction.contains(FAR)
    msg = target_message(target)
    validate(msg, "live-message", "live message")
    assert msg["status"] == "direction-only" and msg["position_mm"] is None and msg["direction"]["cone95_deg"] > 0



def statuses_everywhere(res, out) -> tuple[list, list, list, int, int]:
    """The targets' statuses in process's table (``format_result``), targets.json and
    report.html, and the fixated-target counts of the table and the report."""
    import json
    import re

    from wearable_gaze.pipeline.process.stepcache import format_result

    text = format_result(res)
    table = re.findall(r"^\s*\d+ .*?\d+\.\d-\d+\.\d\s+\S+\s+(\S+)", text, flags=re.M)      # after the dwell
    records = [r["status"] for r in json.loads((out / "targets.json").read_text())["targets"]]
    page = (out / "report.html").read_text()
    report = re.findall(r'<span class="status">([^<]*)</span>', page)
    n_table = int(re.match(r"(\d+) fixated target", text).group(1))
    n_report = int(re.search(r"(\d+) fixated target", page).group(1))
    return table, records, report, n_table, n_report


@pytest.mark.slow
def test_process_answers_every_fixation_of_a_still_head_looking_far(tmp_path):
    """A simulated still head looking at targets 4-8 m away, each eye 0.3 deg outward: the
    rays of the far fixations diverge. Every fixation the segmenter finds is a target with a
    direction (before: the diverging ones were dropped), the status the same in the table, the
    report and targets.json."""
    from wearable_gaze.formats.fixations_table import read_fixations_csv
    from wearable_gaze.formats.targets import read_targets
    from wearable_gaze.formats.truth import read_truth_targets
    from wearable_gaze.pipeline.process.session import process_session
    from wearable_gaze.sim.simulate import simulate_scenario

    scn = {"base": "lab-walkabout", "duration_s": 12.0, "camera": {"resolution": [640, 360]},
           "eyes": {"bias_deg": [[-0.3, 0.0], [0.3, 0.0]]}, "head": {"motion": "fixed"},
           "targets": {"random_count": 4, "random_depth_mm": [4000.0, 8000.0]}, "calibration": {"camera_views": 6}}
    simulate_scenario(scn, tmp_path / "s", seed=5)
    res = process_session(tmp_path / "s", tmp_path / "out", overlay=False)
    out = tmp_path / "out"
    fx = read_fixations_csv(out / "fixations.csv")
    recs = {r["target"]: r for r in read_targets(out / "targets.json")}
    assert len(fx["fixation_id"]) >= 3
    assert (fx["target_id"] >= 0).all(), fx["status"]                      # every fixation answered
    assert "direction-only" in set(fx["status"])
    truth = [tt for tt in read_truth_targets(tmp_path / "s" / "truth" / "targets.json") if "position_mm" in tt]
    for k in range(len(fx["fixation_id"])):
        rec = recs[int(fx["target_id"][k])]
        g = GazeDirection.from_dict(rec["direction"])
        mid = 0.5 * (fx["start_s"][k] + fx["end_s"][k])
        tt = next(tt for tt in truth if any(a <= mid <= b for a, b in tt["fixations_s"]))
        assert g.contains(tt["position_mm"]), (rec["status"], g)
    table, records, report, n_table, n_report = statuses_everywhere(res, out)
    assert table == records == report and n_table == n_report == len(records)


def test_one_status_per_target_and_a_too_near_point_is_not_counted(real_data, tmp_path):
    """Issue 27 on the Tufts import (a still head, an eye model whose lines meet 40 mm ahead):
    moving fixations whose point is too near were 'too-near' in the table and targets.json but
    'moving' in the report, and counted among the fixated targets."""
    from wearable_gaze.pipeline.importer import import_recording
    from wearable_gaze.pipeline.process.session import process_session

    import_recording(real_data / "tufts_gaze_depth" / "test.csv", tmp_path / "s", "pupil-core")
    res = process_session(tmp_path / "s", tmp_path / "out", overlay=False)
    table, records, report, n_table, n_report = statuses_everywhere(res, tmp_path / "out")
    assert "too-near" in records
    assert table == records == report
    assert n_table == n_report == sum(st != "too-near" for st in records) < len(records)


def test_the_live_session_publishes_the_status_process_gives(rng):
    """A static fixation whose lines meet 40 mm in front of the eyes: process calls its target
    'too-near'; the live session published it 'ok' (the estimator's status), now 'too-near' too."""
    from wearable_gaze.pipeline.steps.live_estimation import FinishedFixation, GazeEstimation
    from wearable_gaze.pipeline.steps.target_status import estimate_status

    near = np.array([5.0, 0.0, 40.0])
    s = diverging(near, rng, n=60, bias_deg=0.0, sigma_deg=0.2)
    e = make_estimator("voxel", 0.2).add(s)                    # the live stream's own estimate: ok
    assert e.ok
    lines = tuple(s.sample(i) for i in range(len(s)))
    target = GazeEstimation(None, "voxel").finish(FinishedFixation(0, lines, e, 0.0, 1.0, len(s)))
    assert target.status == estimate_status(e, s) == "too-near" and not target.fixated


def test_a_point_seen_while_walking_around_it_has_the_direction_of_the_point(rng):
    """An ``ok`` target's direction is toward its point, its cone from the point's covariance
    (``estimate.static_direction``, ``estimator.direction.point_direction``): a head walking 80 deg
    around a point 1.5 m away turns the gaze by 80 deg, so the mean of the gaze directions (the
    direction of a target without a point) has a cone of tens of degrees that says nothing."""
    from wearable_gaze.pipeline.steps.estimate import static_direction
    from wearable_gaze.pipeline.steps.target_status import estimate_status

    P = np.array([0.0, 800.0, 1500.0])
    t = np.arange(0, 5.0, 0.1)
    ang = np.deg2rad(-40 + 16 * t)
    head = P + np.column_stack([-1500 * np.sin(ang), -800 + 0 * t, -1500 * np.cos(ang)])
    arrays = []
    for dx in (-32.0, 32.0):
        o = head + np.column_stack([dx * np.cos(ang), 0 * t, -dx * np.sin(ang)])
        arrays += [o, perturb_directions((P - o) / np.linalg.norm(P - o, axis=1, keepdims=True), np.deg2rad(1.0), rng)]
    s = BinocularSamples.from_arrays(t, *arrays)
    model = ErrorModel(bias_deg=0.3)
    e = estimate(s, "ml", 1.0, error_model=model)
    status = estimate_status(e, s)
    assert status == "ok", status
    g = static_direction(e, s, status, model)
    mean = gaze_direction(s, model)
    assert g.contains(P) and g.cone95_deg < 3.0, g
    assert mean.cone95_deg > 20.0, mean
    near, far = g.depth95_mm
    assert near < np.linalg.norm(P - g.origin_mm) < far < 2 * near
