"""Viewing in rerun (issue 17): the records built from our results (pure functions, no rerun
needed: they run in CI), the one-line refusal when rerun-sdk is missing, and, where rerun-sdk
is installed (an optional extra, not in CI), ``process --rerun`` and ``live --rerun`` saving an
.rrd that is read back and checked against the results."""

import contextlib
import io
import json
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from estimator import BinocularSamples
from estimator.result import covariance_ellipsoid
from tracking.markermap import MarkerMap
from wearable_gaze.cli import main
from wearable_gaze.errors import UserError
from wearable_gaze.pipeline.report.rerun_view import (
    RERUN_MISSING,
    SPAWN,
    ellipsoid_axes,
    head_path,
    line_of_sight_axes,
    marker_outlines,
    parse_rerun_dest,
    quaternions_xyzw,
    target_ellipsoids,
    view_line_segments,
)
from wearable_gaze.pipeline.types import Target


def _random_covariances(rng, n):
    A = rng.normal(size=(n, 3, 3)) * [[30.0], [60.0], [400.0]]
    return A @ np.swapaxes(A, 1, 2) + 1e-3 * np.eye(3)


def test_ellipsoid_axes_reproduce_the_covariance_as_a_proper_rotation(rng):
    C = _random_covariances(rng, 50)
    half, R = ellipsoid_axes(C)
    k2 = 7.814727903251178                                          # chi2(3) at 95 %
    assert np.allclose(np.linalg.det(R), 1.0)
    assert np.allclose(np.swapaxes(R, 1, 2) @ R, np.eye(3), atol=1e-12)
    assert np.all(np.diff(half, axis=1) >= 0)
    back = R @ (half[:, :, None] ** 2 / k2 * np.eye(3)) @ np.swapaxes(R, 1, 2)
    assert np.allclose(back, C, rtol=1e-9, atol=1e-6)
    for c, h in zip(C, half, strict=True):                          # the estimator's own 95 % radii
        assert np.allclose(h, covariance_ellipsoid(np.zeros(3), c).radii_mm)


def test_quaternions_are_xyzw_and_rotate_as_the_matrices(rng):
    q = quaternions_xyzw(Rotation.from_euler("z", 90, degrees=True).as_matrix())
    assert np.allclose(q, [[0, 0, np.sqrt(0.5), np.sqrt(0.5)]])     # rerun's order: x, y, z, w
    R = Rotation.random(20, random_state=1).as_matrix()
    v = rng.normal(size=3)
    q = quaternions_xyzw(R)
    for Rk, qk in zip(R, q, strict=True):
        x, y, z, w = qk                                             # v' = q v q*, written out
        u = np.array([x, y, z])
        rotated = 2 * (u @ v) * u + (w * w - u @ u) * v + 2 * w * np.cross(u, v)
        assert np.allclose(rotated, Rk @ v)


def test_line_of_sight_axes_point_the_third_axis_at_the_target(rng):
    P = rng.normal(size=(30, 3)) * 1000 + [0, 0, 2000]
    V = rng.normal(size=(30, 3)) * 100
    R = line_of_sight_axes(P, V)
    assert np.allclose(np.linalg.det(R), 1.0) and np.allclose(np.swapaxes(R, 1, 2) @ R, np.eye(3), atol=1e-12)
    u = (P - V) / np.linalg.norm(P - V, axis=1, keepdims=True)
    assert np.allclose(R[:, :, 2], u)
    assert np.allclose(line_of_sight_axes([0, -5, 0], [0, 0, 0])[0][:, 2], [0, -1, 0])   # along the helper axis


def _target(index, pos, cov=None, axes=None, status="ok"):
    axes = covariance_ellipsoid(pos, cov).radii_mm if axes is None else np.asarray(axes, float)
    return Target(index, np.asarray(pos, float), cov, axes, status, 100, 0.0, 1.0, (index,), "voxel", 5.0)


def test_target_ellipsoids_from_covariance_or_along_the_line_of_sight(rng):
    cov = _random_covariances(rng, 1)[0]
    with_cov = _target(0, [100.0, 0.0, 2000.0], cov)
    assert Target.from_row(_target(1, [0.0, 300.0, 1500.0], cov).row()).covariance_mm2 is not None   # kept in files
    row = _target(1, [0.0, 300.0, 1500.0], cov).row()
    from_file = Target.from_row({**row, "covariance_mm2": None})                # a record without one: semi-axes only
    no_point = _target(2, [np.nan] * 3, None, [np.nan] * 3, status="no-estimate")
    ell = target_ellipsoids([with_cov, from_file, no_point], {1: np.array([0.0, 0.0, 0.0])})
    assert list(ell["index"]) == [0, 1] and list(ell["from_covariance"]) == [True, False]
    half, R = ellipsoid_axes(cov)
    assert np.allclose(ell["half_sizes"][0], half[0])
    R0 = Rotation.from_quat(ell["quaternions"][0]).as_matrix()
    assert np.allclose(R0 @ np.diag(half[0] ** 2) @ R0.T, R[0] @ np.diag(half[0] ** 2) @ R[0].T)
    R1 = Rotation.from_quat(ell["quaternions"][1]).as_matrix()
    assert np.allclose(ell["half_sizes"][1], from_file.axes95_mm)
    assert np.allclose(R1[:, 2], np.array([0.0, 300.0, 1500.0]) / np.linalg.norm([0.0, 300.0, 1500.0]))
    assert len(target_ellipsoids([from_file])["index"]) == 0        # no covariance, no viewpoint: left out


def _lines_through(X, n, rng, invalid_right=()):
    lo = rng.normal(size=(n, 3)) * 50 + [-32, 0, 0]
    ro = rng.normal(size=(n, 3)) * 50 + [32, 0, 0]
    ld, rd = X - lo, X - ro
    rv = np.ones(n, bool)
    rv[list(invalid_right)] = False
    return BinocularSamples.from_arrays(np.arange(n) / 60.0, lo, ld, ro, rd, right_valid=rv)


def test_view_line_segments_run_from_the_eyes_through_the_target(rng):
    X = np.array([200.0, -100.0, 1800.0])
    s = _lines_through(X, 40, rng, invalid_right=[3, 4, 5])
    segs = view_line_segments(s, X, max_lines=1000, overshoot=1.2)
    assert segs.shape == (40 + 37, 2, 3)
    o, e = segs[:, 0], segs[:, 1]
    assert np.allclose(o[:40], s.left_origin_mm)
    d = (e - o) / np.linalg.norm(e - o, axis=1, keepdims=True)
    t = np.einsum("ij,ij->i", X - o, d)
    assert np.allclose(o + t[:, None] * d, X, atol=1e-6)            # each segment passes through X ...
    assert np.allclose(np.linalg.norm(e - o, axis=1), 1.2 * np.linalg.norm(X - o, axis=1))   # ... and beyond
    assert len(view_line_segments(s, X, max_lines=10)) == 10 + sum(s.right_valid[np.linspace(0, 39, 10).round()
                                                                                  .astype(int)])
    assert len(view_line_segments(s, -X)) < len(view_line_segments(s, X))   # lines pointing away: left out


def test_head_path_is_split_at_gaps_and_drops_lone_frames():
    T = np.tile(np.eye(4), (10, 1, 1))
    T[:, 0, 3] = np.arange(10) * 10.0
    T[3] = np.nan
    T[5] = np.nan                                                   # frame 4 alone between two gaps
    strips = head_path(T)
    assert [s[:, 0].tolist() for s in strips] == [[0.0, 10.0, 20.0], [60.0, 70.0, 80.0, 90.0]]
    assert head_path(np.full((3, 4, 4), np.nan)) == []


def test_marker_outlines_are_closed_squares_of_the_printed_size():
    T = np.eye(4)
    T[:3, 3] = [100.0, 0.0, 2000.0]
    mm = MarkerMap("DICT_4X4_50", 80.0, {3: T, 1: np.eye(4)}, {}, {1: 120.0})
    ids, out = marker_outlines(mm)
    assert ids == [1, 3] and out.shape == (2, 5, 3)
    assert np.allclose(out[:, 0], out[:, 4])
    sides = np.linalg.norm(np.diff(out, axis=1), axis=2)
    assert np.allclose(sides[0], 120.0) and np.allclose(sides[1], 80.0)


@pytest.mark.parametrize("value, expected", [(None, (SPAWN, None)), (SPAWN, (SPAWN, None)),
                                             ("out.rrd", ("file", "out.rrd")),
                                             ("rerun+http://127.0.0.1:9876/proxy",
                                              ("connect", "rerun+http://127.0.0.1:9876/proxy"))])
def test_rerun_destination_forms(value, expected):
    assert parse_rerun_dest(value) == expected


@pytest.mark.parametrize("value", ["my-session", ".rrd", "http://127.0.0.1:9876", "out.rr"])
def test_a_bad_rerun_destination_says_what_is_expected(value):
    with pytest.raises(UserError, match="ending .rrd.*rerun\\+http"):
        parse_rerun_dest(value)


def _one_line(capsys):
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_without_rerun_sdk_process_and_live_refuse_with_one_line_before_any_work(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "rerun", None)                 # `import rerun` fails as when not installed
    out = tmp_path / "out"
    code = main(["process", str(tmp_path / "session"), "-o", str(out), "--rerun", str(tmp_path / "x.rrd")])
    assert code == 2
    assert _one_line(capsys) == f"wearable-gaze process: {RERUN_MISSING}"
    assert list(tmp_path.iterdir()) == []                           # nothing read, nothing written
    code = main(["live", "--serial", "loop://", "--camera", str(tmp_path / "v.mp4"), "--camera-calib",
                 str(tmp_path / "c.json"), "--eyes", str(tmp_path / "e.json"), "--markers", str(tmp_path / "m.json"),
                 "--rerun"])
    assert code == 2
    assert _one_line(capsys) == f"wearable-gaze live: {RERUN_MISSING}"
    assert list(tmp_path.iterdir()) == []


def test_a_bad_rerun_option_is_refused_before_any_work(tmp_path, capsys):
    code = main(["process", str(tmp_path / "s"), "-o", str(tmp_path / "out"), "--rerun", "view"])
    assert code == 2 and "--rerun 'view'" in _one_line(capsys)
    (tmp_path / "d.rrd").mkdir()
    code = main(["process", str(tmp_path / "s"), "-o", str(tmp_path / "out"), "--rerun", str(tmp_path / "d.rrd")])
    if code == 2:
        line = _one_line(capsys)
        assert "is a folder" in line or RERUN_MISSING in line
    code = main(["process", str(tmp_path / "s"), "-o", str(tmp_path / "out"), "--rerun-frames", "5"])
    assert code == 2 and "--rerun-frames needs --rerun" in _one_line(capsys)
    assert not (tmp_path / "out").exists()


# --- with rerun-sdk installed ------------------------------------------------------------------------

def _rerun():
    try:
        import rerun
        import rerun.chunk
    except ImportError:
        pytest.skip("rerun-sdk is not installed (an optional extra: pip install 'wearable-gaze[rerun]')")
    return rerun


def _read_rrd(path) -> dict:
    """{entity path: [record batch, ...]} of every non-static chunk and static chunk of an .rrd."""
    import rerun.chunk

    out = {}
    for ch in rerun.chunk.RrdReader(str(path)).store().stream().to_chunks():
        out.setdefault(ch.entity_path, []).append(ch.to_record_batch())
    return out


def _column(batches, name):
    vals = []
    for rb in batches:
        if name in rb.schema.names:
            vals += rb.column(rb.schema.get_field_index(name)).to_pylist()
    return vals


@pytest.fixture(scope="module")
def rerun_session(tmp_path_factory):
    _rerun()
    from wearable_gaze.sim.simulate import simulate_scenario

    base = tmp_path_factory.mktemp("rerun")
    simulate_scenario({"base": "lab-walkabout", "duration_s": 5.0, "calibration": {"camera_views": 6}},
                      base / "session", seed=3, resolution=(640, 360))
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = main(["process", str(base / "session"), "-o", str(base / "out"), "--no-overlay",
                     "--rerun", str(base / "process.rrd"), "--rerun-frames", "15"])
    assert code == 0, err.getvalue()
    return base


def test_process_rerun_saves_the_session_as_logged(rerun_session):
    base = rerun_session
    rrd = _read_rrd(base / "process.rrd")
    from wearable_gaze.formats.poses import read_poses_csv
    from wearable_gaze.formats.truth import read_truth_targets

    assert _column(rrd["/world"], "ViewCoordinates:xyz")                     # the frame said
    assert "millimetres" in _column(rrd["/notes"], "TextDocument:text")[0][0]
    t, _, T, _ = read_poses_csv(base / "out" / "poses.csv")
    posed = np.all(np.isfinite(T.reshape(len(T), -1)), axis=1)
    trans = np.array(_column(rrd["/world/head"], "Transform3D:translation"))[:, 0]
    times = np.array([v.total_seconds() for v in _column(rrd["/world/head"], "session_time")])
    order = np.argsort(times)
    assert len(trans) == posed.sum() > 50
    assert np.allclose(times[order], t[posed], atol=1e-6)
    assert np.allclose(trans[order], T[posed, :3, 3], atol=1e-2)             # float32 in rerun
    assert len(_column(rrd["/world/head/camera"], "EncodedImage:blob")) == -(-150 // 15)
    assert _column(rrd["/world/head/camera"], "Pinhole:resolution") == [[[640.0, 360.0]]]
    rows = json.loads((base / "out" / "targets.json").read_text())["targets"]
    assert rows
    for r in rows:
        path = f"/world/targets/{r['target']}"
        assert np.allclose(_column(rrd[path], "Points3D:positions")[0][0], [r["x_mm"], r["y_mm"], r["z_mm"]], atol=0.01)
        half = _column(rrd[f"{path}/ellipsoid95"], "Ellipsoids3D:half_sizes")[0][0]
        assert np.allclose(half, [r["axis1_mm"], r["axis2_mm"], r["axis3_mm"]], rtol=1e-5)   # 95 %, as targets.json
        strips = np.array(_column(rrd[f"{path}/view_lines"], "LineStrips3D:strips")[0], float)
        assert len(strips) > 20
        X = np.array([r["x_mm"], r["y_mm"], r["z_mm"]])
        d = (strips[:, 1] - strips[:, 0]) / np.linalg.norm(strips[:, 1] - strips[:, 0], axis=1, keepdims=True)
        miss = np.linalg.norm(np.cross(X - strips[:, 0], d), axis=1)
        assert np.median(miss) < 0.05 * np.linalg.norm(X - strips[:, 0], axis=1).mean()   # lines aim at it
        q = _column(rrd[f"{path}/ellipsoid95"], "Ellipsoids3D:quaternions")[0][0]
        if half[2] > 2 * half[1]:                   # depth is the least certain: the long axis along the lines
            long_axis = Rotation.from_quat(q).apply([0.0, 0.0, 1.0])
            mean_d = d.mean(axis=0) / np.linalg.norm(d.mean(axis=0))
            assert np.degrees(np.arccos(min(abs(long_axis @ mean_d), 1.0))) < 5.0
    truth = [tt for tt in read_truth_targets(base / "session" / "truth" / "targets.json") if "position_mm" in tt]
    assert np.allclose(_column(rrd["/world/truth/targets"], "Points3D:positions")[0],
                       [tt["position_mm"] for tt in truth], atol=0.01)
    assert len(_column(rrd["/world/markers"], "LineStrips3D:strips")[0]) > 10
    summary = json.loads((base / "out" / "summary.json").read_text())
    assert summary["rerun"] == str(base / "process.rrd")


def test_live_rerun_streams_head_estimates_and_targets(rerun_session):
    from wearable_gaze.sim.emulate import RecorderEmulator

    base = rerun_session
    emu = RecorderEmulator((base / "session" / "eye_serial.bin").read_bytes())
    url = emu.listen_tcp()
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["live", "--serial", url, "--camera", str(base / "session" / "scene.mp4"), "--camera-calib",
                     str(base / "out" / "camera.json"), "--eyes", str(base / "out" / "eyes.json"), "--markers",
                     str(base / "session" / "markers.json"), "--quiet", "--rerun", str(base / "live.rrd")])
    emu.stop()
    assert code == 0, err.getvalue()
    msgs = [json.loads(x) for x in out.getvalue().splitlines()]
    rrd = _read_rrd(base / "live.rrd")
    est = [m for m in msgs if m["type"] == "estimate"]
    logged = np.array(_column(rrd["/world/gaze/estimate"], "Points3D:positions"))[:, 0]
    assert len(est) > 20 and len(logged) == len(est)                  # every estimate, none dropped
    t_logged = sorted(v.total_seconds() for v in _column(rrd["/world/gaze/estimate"], "session_time"))
    assert np.allclose(t_logged, sorted(m["t"] for m in est), atol=1e-6)
    assert len(_column(rrd["/world/head"], "Transform3D:translation")) > 20
    for m in (m for m in msgs if m["type"] == "target"):
        path = f"/world/targets/{m['target']}/fixation_{m['fixation']}"
        assert np.allclose(_column(rrd[path], "Points3D:positions")[0][0], m["position_mm"], atol=0.1)
        if m["ellipsoid95_radii_mm"] is not None:
            half = _column(rrd[f"{path}/ellipsoid95"], "Ellipsoids3D:half_sizes")[0][0]
            assert np.allclose(half, m["ellipsoid95_radii_mm"], atol=0.06)
        assert f"{path}/view_lines" in rrd


def test_process_with_a_viewer_that_cannot_be_reached_keeps_its_results_and_says_so(rerun_session):
    base = rerun_session
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["process", str(base / "session"), "-o", str(base / "out"), "--no-overlay",
                     "--rerun", "rerun+http://127.0.0.1:9/proxy"])                # nothing listens on port 9
    assert code == 0                                                              # the targets were found
    ours = [ln for ln in err.getvalue().splitlines() if ln.startswith("wearable-gaze process:")]
    assert len(ours) == 1 and "rerun: the rerun viewer could not be reached" in ours[0] and "--rerun out.rrd" in ours[0]
    summary = json.loads((base / "out" / "summary.json").read_text())
    assert "rerun" not in summary and any(p.startswith("rerun:") for p in summary["problems"])
    assert (base / "out" / "targets.json").is_file()
