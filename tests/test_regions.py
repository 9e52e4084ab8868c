"""Uncertainty drawn as it is (issue 27): the report's 3D view, its top view and targets.ply draw
each target's 95 % credible region, its distance interval along the line of sight (symmetric in
inverse depth, so longer on the far side) by its lateral extent, never the Gaussian ellipsoid
that runs behind the head; the views are scaled to the head path and the targets; an interval
with no far end, or a direction without a point, is drawn as a ray to the edge of the axes.

The far target here is the demo's third (lab-walkabout at 750a466): seen from 3.66 m, the
relative sd of its distance 0.246, so its 95 % interval is 2.47-7.08 m while its 95 % ellipsoid's
long semi-axis is 8.1 m: the ellipsoid reaches 4.4 m behind the head."""

import numpy as np
import pytest
from scipy.stats import chi2

from estimator.errormodel import FAR_SIDE_K, K95
from estimator.errormodel_regions import Sight
from estimator.region import ray_exit, region_mesh, region_of_direction
from wearable_gaze.formats.targets import record_region, target_record
from wearable_gaze.pipeline.report import page as report
from wearable_gaze.pipeline.report import plots as report_plots
from wearable_gaze.pipeline.report.page import ReportData
from wearable_gaze.pipeline.report.regions import region_lines, scene_box
from wearable_gaze.pipeline.steps.export import targets_mesh
from wearable_gaze.pipeline.types import Poses, Target

SEEN_FROM = np.array([-15.0, 69.0, -22.0])
FAR = np.array([1461.0, 221.0, 3324.0])         # the demo's target 2, mm
HEAD = np.column_stack([np.linspace(-150, 150, 61), np.zeros(61), np.linspace(-50, 50, 61)]) + SEEN_FROM


def _record(index, position, seen_from=SEEN_FROM, rel_sd=0.2464, long95=8106.0, lateral95=63.0, **extra):
    """A target record as process writes it (``target_record`` with the error model's sight): a
    covariance long along the line of sight (``long95``: its 95 % semi-axis), narrow across."""
    X = np.asarray(position, float)
    u = (X - seen_from) / np.linalg.norm(X - seen_from)
    C = (lateral95 / K95) ** 2 * (np.eye(3) - np.outer(u, u)) + (long95 / K95) ** 2 * np.outer(u, u)
    radii = K95 * np.sqrt(np.linalg.eigvalsh(C))
    rec = target_record(index, 0.0, 1.0, X, radii, 200, "voxel", "ok", C, 100.0, [index], sight=Sight(
        np.asarray(seen_from, float), FAR_SIDE_K, rel_sd))
    return rec | extra


def _data(records, head=HEAD) -> ReportData:
    """The report's data of ``records`` with a head path and no view lines (as ``report_data``
    reads them: a ``Target`` and a region from each record)."""
    targets = [Target.from_row(r) for r in records]
    regions = {t.index: record_region(r) for t, r in zip(targets, records, strict=True)}
    return ReportData(targets, None, np.zeros(0, int), np.zeros(0, int), head, head.mean(axis=0), {},
                      np.zeros((0, 3)), np.zeros((0, 3)), {}, {}, [],
                      {k: r for k, r in regions.items() if r is not None})


def _direction_only(index, unit, cone95_deg, depth95_mm) -> dict:
    """A ``direction-only`` record as process writes it: no point, no covariance, its
    ``direction`` (seen from, unit, 95 % cone, 95 % depth interval with a null far end: none)."""
    rec = target_record(index, 0.0, 1.0, np.full(3, np.nan), np.full(3, np.nan), 50, "voxel", "direction-only")
    return rec | {"direction": {"seen_from_mm": SEEN_FROM.tolist(), "unit": list(unit), "cone95_deg": cone95_deg,
                                "depth95_mm": list(depth95_mm), "spread_deg": 0.5, "n_samples": 50}}


def _poses(head=HEAD) -> Poses:
    T = np.tile(np.eye(4), (len(head), 1, 1))
    T[:, :3, 3] = head
    return Poses(np.arange(len(head)) * 0.1, np.arange(len(head)), T)


def _distances(P, seen_from=SEEN_FROM, towards=FAR):
    """(distance from ``seen_from``, component along the line of sight) of points (N, 3)."""
    P = np.asarray(P, float).reshape(-1, 3)
    u = (towards - seen_from) / np.linalg.norm(towards - seen_from)
    return np.linalg.norm(P - seen_from, axis=1), (P - seen_from) @ u


def _scene_points(region: dict) -> np.ndarray:
    return np.concatenate([np.reshape(region["rings"], (-1, 3)), np.reshape(region["sides"], (-1, 3)),
                           np.reshape(region["axis"], (-1, 3))])


def test_a_far_targets_drawn_region_stays_within_its_interval_not_behind_the_head():
    rec = _record(2, FAR)
    near, far = rec["depth"]["interval95_mm"]
    D = rec["depth"]["distance_mm"]
    assert near == pytest.approx(2468, abs=5) and far == pytest.approx(7079, abs=10)
    assert D - rec["ellipsoid95_radii_mm"][2] < -4000           # the ellipsoid: 4.4 m behind the head
    # targets.ply: the point, then the region's vertices, every one within the interval, in front
    mesh = targets_mesh([Target.from_row(rec)], _poses())
    region = mesh.vertices_mm[1:1 + 2 + 2 * 24]
    dist, along = _distances(region)
    assert dist.min() == pytest.approx(near, abs=0.01) and dist.max() == pytest.approx(far, abs=0.01)
    assert np.all(along > 0.99 * near)
    # the 3D view: what it draws of the region lies within the interval and within the box
    d = _data([rec])
    scene = report._scene(d, None, None)
    t = scene["targets"][0]
    assert t["ellipsoid"] is None and t["region"] is not None
    dist, along = _distances(_scene_points(t["region"]))
    assert np.all(dist >= near - 1) and np.all(dist <= far + 1) and np.all(along > 0.99 * near - 1)
    # the top view: every point drawn in the target's colour lies in front of the head
    fig = report_plots.figure_top(d, report.color)
    ax = fig.axes[0]
    u = (FAR - SEEN_FROM)[[0, 2]]
    drawn = [ln.get_xydata() for ln in ax.lines if ln.get_color() == report.color(2)]
    drawn += [p.get_path().transformed(p.get_patch_transform()).vertices for p in ax.patches]
    P = np.concatenate(drawn)
    assert len(P) > 10 and np.all((P - SEEN_FROM[[0, 2]]) @ u > 0)
    report_plots._plt().close(fig)


def test_the_views_are_scaled_to_the_head_path_and_the_targets_not_to_the_ellipsoids():
    """The real Aria sample's target (0.31 relative sd, a 95 % semi-axis of 14 m) made the top
    view span +-40 m; the axes hold the head path and the targets."""
    recs = [_record(0, FAR, long95=40000.0), _record(1, [-300.0, 100.0, 1500.0])]
    d = _data(recs)
    pts = np.vstack([HEAD, FAR, [-300.0, 100.0, 1500.0]])
    lo, hi = d.box()
    assert np.all(lo <= pts.min(axis=0)) and np.all(hi >= pts.max(axis=0))
    assert np.all(hi - lo <= (pts.max(axis=0) - pts.min(axis=0)).max() * 1.5 + 1000.0)
    assert np.allclose(np.array(report._scene(d, None, None)["box"]), [lo, hi], atol=0.5)
    fig = report_plots.figure_top(d, report.color)
    x0, x1 = fig.axes[0].get_xlim()
    z0, z1 = fig.axes[0].get_ylim()
    assert x0 <= pts[:, 0].min() and x1 >= pts[:, 0].max() and z0 <= pts[:, 2].min() and z1 >= pts[:, 2].max()
    assert max(x1 - x0, z1 - z0) < 6000.0                   # the scene is 3.6 m across; the ellipsoid 80 m
    report_plots._plt().close(fig)
    fig = report_plots.figure_3d(d, report.color)
    ax = fig.axes[0]
    assert ax.get_xlim() == pytest.approx((lo[0], hi[0])) and ax.get_ylim() == pytest.approx((lo[2], hi[2]))
    assert ax.get_zlim() == pytest.approx((-hi[1], -lo[1]))
    report_plots._plt().close(fig)


def test_an_open_interval_is_drawn_as_a_ray_to_the_edge_of_the_axes():
    """The Aria sample's second target: 95 % interval 1.35 m to no far end. Its region is a ray:
    dashed, to the box's edge, with an arrow; so is a direction without a point."""
    rec = _record(1, FAR, rel_sd=0.6717)
    assert rec["depth"]["interval95_mm"][1] is None
    direction = _direction_only(3, [0.6, 0.0, 0.8], 1.5, [800.0, None])
    d = _data([rec, direction])
    lo, hi = d.box()
    scene = report._scene(d, None, None)
    for t, u in zip(scene["targets"], [(FAR - SEEN_FROM) / np.linalg.norm(FAR - SEEN_FROM), [0.6, 0.0, 0.8]],
                    strict=True):
        g = t["region"]
        assert g["open"] and g["cut"] and g["far_mm"] is None
        end = np.array(g["axis"][1], float)
        assert np.min(np.minimum(np.abs(end - lo), np.abs(end - hi))) < 1.0            # on the box's edge
        assert np.allclose((end - SEEN_FROM) / np.linalg.norm(end - SEEN_FROM), u, atol=1e-3)
    fig = report_plots.figure_top(d, report.color)
    ax = fig.axes[0]
    x0, x1 = ax.get_xlim()
    for k in (1, 3):
        dashed = [ln for ln in ax.lines if ln.get_color() == report.color(k) and ln.get_linestyle() == "--"
                  and len(ln.get_xydata()) == 2]                      # the line of sight
        assert dashed
        reach = dashed[0].get_xydata()[1]
        z0, z1 = ax.get_ylim()
        assert min(abs(reach[0] - x0), abs(reach[0] - x1), abs(reach[1] - z0), abs(reach[1] - z1)) < 1.0
    arrows = [a for a in ax.texts if getattr(a, "arrow_patch", None) is not None]
    assert len(arrows) == 2
    assert "dashed: no far end (95 %)" in [t.get_text() for t in ax.get_legend().get_texts()]
    report_plots._plt().close(fig)


def test_targets_ply_holds_each_region_closed_or_open():
    """targets.ply: a closed region is a frustum of the cone of sight from its near to its far
    end (capped both ends), an open one reaches the box's edge and stays open; a direction
    without a point has its region too; the comments say which vertices are which."""
    closed, open_ = _record(0, FAR), _record(1, [-300.0, 100.0, 1500.0], rel_sd=0.6717)
    # a direction-only record in other words (read tolerantly): flat keys, an infinite far end
    direction = {"target": 2, "position_mm": None, "covariance_mm2": None, "direction_world": [0.0, 0.0, 1.0],
                 "cone_half_angle_deg": 2.0, "seen_from_mm": SEEN_FROM.tolist(),
                 "depth_interval_mm": [500.0, float("inf")]}
    targets = [Target.from_row(r) for r in (closed, open_)]
    mesh = targets_mesh(targets, _poses())
    n = 24
    assert len(mesh.faces) == (4 * n) + (3 * n)                        # capped both ends; the open one, near only
    lo, hi = scene_box(HEAD, [FAR, [-300.0, 100.0, 1500.0]])
    v = mesh.vertices_mm
    near1 = open_["depth"]["interval95_mm"][0]
    dist, _ = _distances(v[1 + 2 + 2 * n + 1:1 + 2 + 2 * n + 1 + 1 + 2 * n], towards=np.array([-300.0, 100.0, 1500.0]))
    assert dist.min() == pytest.approx(near1, abs=0.01)
    r = record_region(open_)
    assert dist.max() == pytest.approx(ray_exit(r.origin_mm, r.direction, lo, hi), abs=0.01)
    assert "no far end" in mesh.comments[2] and "credible region" in mesh.comments[1]
    # a direction-only record: a cone from 0.5 m to the edge, half-angle 2 deg
    rd = record_region(direction)
    assert rd is not None and not rd.closed and np.degrees(rd.half_angles_rad) == pytest.approx([2.0, 2.0])
    rv, rf, _ = region_mesh(rd, 3000.0)
    dist = np.linalg.norm(rv - SEEN_FROM, axis=1)
    ang = np.degrees(np.arccos(np.clip((rv - SEEN_FROM) @ [0.0, 0.0, 1.0] / dist, -1, 1)))
    assert ang.max() == pytest.approx(2.0, abs=1e-6) and dist.min() == pytest.approx(500.0)
    assert dist.max() == pytest.approx(3000.0) and len(rf) == 3 * 24                  # open: no far cap


def test_a_region_is_the_lateral_marginal_at_the_points_distance():
    """Across the line of sight, the region's 95 % half-angle is the covariance's 2D marginal
    (sqrt chi2(2) sds) seen from where the lines were: a stretch along the line of sight leaves
    it; the rings are exactly their distance from the apex."""
    rec = _record(0, FAR, lateral95=63.0)
    r = record_region(rec)
    D = rec["depth"]["distance_mm"]
    sd = 63.0 / K95
    assert np.tan(r.half_angles_rad) * D == pytest.approx([np.sqrt(chi2.ppf(0.95, 2)) * sd] * 2, rel=1e-6)
    ring = r.ring(5000.0)
    assert np.linalg.norm(ring - r.origin_mm, axis=1) == pytest.approx(np.full(24, 5000.0))
    assert region_of_direction(SEEN_FROM, [0, 0, 0], 0.1) is None
    lines = region_lines(r, *scene_box(HEAD, FAR))
    assert lines.cut and not lines.open and len(lines.rings) == 1       # the far end past the box: cut
