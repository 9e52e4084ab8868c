"""The exports and schemas of issue 17: every file ``process`` writes is documented with its
format (``formats.outputs``, docs/formats.md) and validates against it; gaze.csv and
fixations.csv load into pandas with their documented dtypes; targets.ply loads in Open3D with
the targets' 95 % credible regions; one target record for targets.json, estimate --json and the live
messages. Uses the session ``processed`` once for the whole run (tests/conftest.py)."""

import json
import re
from pathlib import Path

import numpy as np
import pytest

from estimator.aoi import fixation_duration_s, sample_interval_s
from estimator.region import RING_POINTS
from wearable_gaze.cli import main
from wearable_gaze.formats.camera import load_camera
from wearable_gaze.formats.jsonio import validate
from wearable_gaze.formats.marker_detections import read_marker_detections
from wearable_gaze.formats.outputs import PROCESS_OUTPUTS, check_output, output_spec
from wearable_gaze.formats.ply import read_ply
from wearable_gaze.formats.poses import read_poses_csv
from wearable_gaze.formats.tables import read_table
from wearable_gaze.formats.targets import read_estimates, read_target_labels, read_targets, record_region
from wearable_gaze.pipeline.process.stepcache import OTHER_FILES, OUTPUTS

pd = pytest.importorskip("pandas", reason="pandas comes with the neon extra (pip install -e '.[test]')")

DOCS = Path(__file__).resolve().parents[1] / "docs" / "formats.md"


def _dtype_ok(series, want: str) -> bool:
    if want == "str":
        return pd.api.types.is_string_dtype(series) or series.dtype == object
    return str(series.dtype) == want


def _check_csv(path: Path, spec) -> None:
    """A CSV of the output folder in pandas: the documented columns, each in its dtype (a file
    with a header alone has no dtypes to check)."""
    df = pd.read_csv(path)
    want = {**spec.columns, **{k: v for k, v in spec.optional_columns.items() if k in df.columns}}
    assert list(df.columns) == list(want), (path.name, list(df.columns))
    if len(df):
        bad = {c: str(df[c].dtype) for c, d in want.items() if not _dtype_ok(df[c], d)}
        assert not bad, (path.name, bad)


def _documented_names() -> set:
    text = DOCS.read_text(encoding="utf-8")
    section = text[text.index("## Outputs of process"):]
    section = section[:section.index("\n## ", 5)]
    return {m for row in section.splitlines() if row.startswith("| `") for m in re.findall(r"^\| `([^`]+)`", row)}


def test_every_output_of_process_is_documented_with_its_format():
    """The steps' outputs, the list of formats (``formats.outputs``) and the table of
    docs/formats.md name the same files: a step that writes a new file fails here until it is
    given a format and documented."""
    written = {f for fs in OUTPUTS.values() for f in fs} | set(OTHER_FILES)
    listed = {o.name for o in PROCESS_OUTPUTS}
    assert written == listed, (written - listed, listed - written)
    assert _documented_names() == listed, (listed - _documented_names(), _documented_names() - listed)
    for o in PROCESS_OUTPUTS:
        assert (o.kind == "json") == (o.schema is not None) and (o.kind == "csv") == bool(o.columns), o.name


def test_every_file_in_the_output_folder_validates_against_its_format(processed):
    _, out, res = processed
    files = sorted(p for p in out.iterdir() if p.is_file())
    for name in ("gaze.csv", "fixations.csv", "targets.ply", "targets.json", "targets.csv", "summary.json",
                 ".steps.json", ".viewlines_counts.json", "poses.csv", "viewlines.csv", "target_labels.npy",
                 ".marker_detections.npz"):
        assert (out / name).is_file(), name
    n_lines = len(pd.read_csv(out / "viewlines.csv"))
    for p in files:
        spec = check_output(p)                       # an undocumented file, a bad schema or header: UserError
        if spec.kind == "csv":
            _check_csv(p, spec)
        elif spec.kind == "npy":
            labels = read_target_labels(p)
            assert labels.shape == (n_lines,) and labels.dtype.kind == "i"
        elif spec.kind == "npz":                         # the tracking step's marker detections
            _, frames, _, cols = read_poses_csv(out / "poses.csv")
            dets = read_marker_detections(p)
            status = dict(zip(frames.tolist(), cols["status"], strict=True))
            assert set(dets) <= set(status) and len(dets) > len(frames) // 3
            assert all(status[f] != "interpolated" for f in dets)
            assert all(f in dets for f, st in status.items() if st == "ok")
            n_markers = dict(zip(frames.tolist(), cols["n_markers"], strict=True))
            assert all(len(dets[f]) >= n_markers[f] for f in dets)
        elif spec.kind == "ply":
            assert read_ply(p).vertices_mm.shape[1] == 3
        elif spec.kind in ("png", "webp", "html"):
            magic = {"png": b"\x89PNG", "webp": b"RIFF", "html": b"<!"}[spec.kind]
            assert p.read_bytes()[:len(magic)].upper() == magic.upper(), p.name
    with pytest.raises(Exception, match="not a file 'wearable-gaze process' writes"):
        check_output(out / "something_new.csv")


def test_gaze_csv_loads_in_pandas_and_matches_the_view_lines(processed):
    _, out, _ = processed
    g = pd.read_csv(out / "gaze.csv")
    assert {c: str(g[c].dtype) for c in g.columns} == output_spec("gaze.csv").columns
    counts = json.loads((out / ".viewlines_counts.json").read_text())
    assert len(g) == counts["samples"] and np.array_equal(g["sample"], np.arange(len(g)))
    assert np.all(np.diff(g["t_s"]) > 0) and np.allclose(g["device_t_s"], g["t_s"])      # no clock offset here
    # the samples with a pose and a valid eye are the rows of viewlines.csv, world rays and labels alike
    kept = g[(g.pose_ok == 1) & ((g.left_valid == 1) | (g.right_valid == 1))]
    vl = pd.read_csv(out / "viewlines.csv")
    assert len(kept) == len(vl) == counts["written"]
    np.testing.assert_allclose(kept["t_s"], vl["t"], atol=1e-6)
    for side in ("left", "right"):
        for a in "xyz":
            np.testing.assert_allclose(kept[f"{side}_origin_{a}_mm"], vl[f"{side}_o{a}"], atol=2e-3, equal_nan=True)
            np.testing.assert_allclose(kept[f"{side}_dir_{a}"], vl[f"{side}_d{a}"], atol=2e-7, equal_nan=True)
    assert np.array_equal(kept["fixation_id"], vl["segment"])
    assert np.array_equal(kept["target_id"], read_target_labels(out / "target_labels.npy"))
    assert np.all(g.loc[g.pose_ok == 0, "fixation_id"] == -1) and np.all(g.loc[g.pose_ok == 0, "left_dir_x"].isna())
    # the running estimate: its fixation's last row of estimates.csv at or before the sample
    est = read_estimates(out / "estimates.csv")
    have = g[g.est_x_mm.notna()]
    assert len(have) > 0.7 * (g.fixation_id >= 0).sum() and np.all(have.fixation_id >= 0)
    for _, r in have.sample(50, random_state=0).iterrows():
        rows = np.flatnonzero((est["segment"] == r.fixation_id) & (est["t"] <= r.t_s + 5e-5))
        assert len(rows) and np.allclose([r.est_x_mm, r.est_y_mm, r.est_z_mm, r.est_radius95_mm],
                                         [est[k][rows[-1]] for k in ("x", "y", "z", "radius95_mm")], atol=0.051)


def test_the_2d_gaze_falls_on_the_fixated_target_in_the_scene_video(processed):
    """In a fixation, a sample's 2D gaze (its cyclopean line at the estimate's depth) lies near
    the target's point projected into the scene camera at that sample's head pose: within a few
    degrees of eye noise, in pixels."""
    _, out, _ = processed
    g = pd.read_csv(out / "gaze.csv")
    cam = load_camera(out / "camera.json")
    t, _, T, _ = read_poses_csv(out / "poses.csv")
    targets = {r["target"]: np.array(r["position_mm"]) for r in read_targets(out / "targets.json")}
    fx = cam.camera_matrix[0, 0]
    errs = []
    for _, r in g[(g.target_id >= 0) & g.est_x_mm.notna()].iloc[::10].iterrows():
        k = int(np.argmin(np.abs(t - r.t_s)))
        if abs(t[k] - r.t_s) > 0.02 or not np.isfinite(T[k, 0, 0]):
            continue
        Tcw = np.linalg.inv(T[k])
        px = cam.project((Tcw[:3, :3] @ targets[r.target_id] + Tcw[:3, 3])[None])[0]
        errs.append(np.hypot(*(px - [r.gaze_x_px, r.gaze_y_px])))
    assert len(errs) > 30
    assert np.median(errs) < fx * np.radians(2.0), (np.median(errs), fx)
    w, h = cam.image_size
    inside = (g.gaze_x_px >= -0.5) & (g.gaze_x_px < w - 0.5) & (g.gaze_y_px >= -0.5) & (g.gaze_y_px < h - 0.5)
    assert np.array_equal(inside.astype(int), g.in_image) and g.in_image.mean() > 0.8
    assert g.gaze_depth_mm[g.est_x_mm.isna()].isna().all()           # no placeholder depth where there is no estimate
    assert g.gaze_depth_mm[g.est_x_mm.notna() & g.left_valid.astype(bool)].notna().mean() > 0.95


def test_fixations_csv_loads_in_pandas_with_one_row_per_fixation(processed):
    _, out, _ = processed
    f = pd.read_csv(out / "fixations.csv")
    spec = output_spec("fixations.csv").columns
    assert list(f.columns) == list(spec)
    assert all(_dtype_ok(f[c], d) for c, d in spec.items()), f.dtypes
    vl = pd.read_csv(out / "viewlines.csv")
    segs = sorted(int(s) for s in vl.segment.unique() if s >= 0)
    assert list(f.fixation_id) == segs and len(segs) >= 4
    for _, r in f.iterrows():
        t = vl.t[vl.segment == r.fixation_id]
        assert (r.start_s, r.end_s, r.n_samples) == (pytest.approx(t.min(), abs=1e-4), pytest.approx(t.max(), abs=1e-4),
                                                      len(t))
        # the time its samples stand for (the AOI measures' convention), not end - start
        assert r.duration_s == pytest.approx(fixation_duration_s(t, sample_interval_s(vl.t)), abs=2e-4)
    targets = read_targets(out / "targets.json")
    assert {(fx, t["target"]) for t in targets for fx in t["fixations"]} == set(zip(f.fixation_id, f.target_id,
                                                                                    strict=True))
    ok = f[f.status == "ok"]
    assert len(ok) == len(f) and set(f.motion) == {"static"}
    for _, r in ok.iterrows():
        C = np.array([[r.cov_xx_mm2, r.cov_xy_mm2, r.cov_xz_mm2], [r.cov_xy_mm2, r.cov_yy_mm2, r.cov_yz_mm2],
                      [r.cov_xz_mm2, r.cov_yz_mm2, r.cov_zz_mm2]])
        assert np.all(np.linalg.eigvalsh(C) > 0)
    # a target of one fixation is estimated from that fixation's lines alone: the same point
    for t in targets:
        if len(t["fixations"]) == 1:
            r = f[f.fixation_id == t["fixations"][0]].iloc[0]
            np.testing.assert_allclose([r.x_mm, r.y_mm, r.z_mm], t["position_mm"], atol=0.051)


def test_targets_ply_loads_in_open3d_with_the_95_percent_regions_and_the_head_path(processed):
    from estimator._open3d import Open3DUnavailable, import_open3d
    try:
        o3d = import_open3d()
    except Open3DUnavailable as exc:
        pytest.skip(str(exc))
    _, out, _ = processed
    mesh = o3d.io.read_triangle_mesh(str(out / "targets.ply"))
    ours = read_ply(out / "targets.ply")
    V = np.asarray(mesh.vertices)
    np.testing.assert_allclose(V, ours.vertices_mm, atol=1e-9)
    assert mesh.has_vertex_colors() and ours.comments[0].startswith("wearable-gaze targets.ply")
    assert (out / "targets.ply").read_text().splitlines()[2].startswith("comment units: mm")
    targets = read_targets(out / "targets.json")
    regions = [record_region(t) for t in targets]
    n_ring = RING_POINTS
    assert all(r is not None and r.closed for r in regions) and len(regions) >= 3
    assert len(np.asarray(mesh.triangles)) == 4 * n_ring * len(regions)      # frustums capped at both ends
    n = 0
    for t in targets:
        np.testing.assert_allclose(V[n], t["position_mm"], atol=1e-3)     # the target's point
        k = 2 + 2 * n_ring
        region = V[n + 1:n + 1 + k]
        n += 1 + k
        # its 95 % region: from the near to the far end of its interval, seen from where it was
        near, far = t["depth"]["interval95_mm"]
        dist = np.linalg.norm(region - t["depth"]["seen_from_mm"], axis=1)
        assert dist.min() == pytest.approx(near, abs=2e-3) and dist.max() == pytest.approx(far, abs=2e-3)
        assert np.all(np.asarray(mesh.vertex_colors)[n - k:n] == np.asarray(mesh.vertex_colors)[n - k - 1])
    t, _, T, _ = read_poses_csv(out / "poses.csv")
    posed = np.isfinite(T[:, 0, 3])
    np.testing.assert_allclose(V[n:], T[posed, :3, 3], atol=1e-3)
    assert len(ours.edges) == posed.sum() - 1 and np.all(np.diff(ours.edges, axis=1) == 1)


def test_one_target_record_for_targets_json_estimate_json_and_the_live_messages(processed, tmp_path, capsys):
    """targets.json, ``estimate --json --targets`` and summary.json hold the same record (the
    schema of each checks it), with the same keys in the same order."""
    _, out, res = processed
    records = read_targets(out / "targets.json")
    assert json.loads((out / "summary.json").read_text())["targets"] == res.targets
    capsys.readouterr()
    assert main(["estimate", str(out / "viewlines.csv"), "--targets", "--method", "ml", "--json"]) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines() if x.strip()]
    for x in lines:
        validate(x, "estimate-line", "estimate --json")
    got = [x for x in lines if "target" in x]
    assert len(got) == len(records)
    assert all(list(g) == [*r, "covariance_model"] for g, r in zip(got, records, strict=True))
    cols = read_table(out / "targets.csv", ["target", "x_mm", "cov_zz_mm2", "ellipsoid95_r3_mm", "distance_mm",
                                            "depth68_near_mm", "depth95_far_mm"], ("fixations",))
    for j, r in enumerate(records):
        assert cols["x_mm"][j] == pytest.approx(r["position_mm"][0], abs=0.051)
        assert cols["cov_zz_mm2"][j] == pytest.approx(r["covariance_mm2"][2][2], rel=1e-5)
        assert cols["fixations"][j] == ";".join(map(str, r["fixations"]))
        d = r["depth"]                                   # the error model's: every target has its depth
        assert cols["distance_mm"][j] == pytest.approx(d["distance_mm"], abs=0.051)
        assert cols["depth68_near_mm"][j] == pytest.approx(d["interval68_mm"][0], abs=0.051)
        assert d["interval95_mm"][0] < d["interval68_mm"][0] < d["distance_mm"] < d["interval68_mm"][1]
        assert d["distance_mm"] == pytest.approx(np.linalg.norm(np.subtract(r["position_mm"], d["seen_from_mm"])))
    capsys.readouterr()
    assert main(["estimate", str(out / "viewlines.csv"), "--targets", "--method", "lse", "--json"]) == 0
    assert not any("depth" in json.loads(x) for x in capsys.readouterr().out.splitlines() if x.strip())  # no model


def test_the_export_formats_round_trip_through_their_one_reader(tmp_path, monkeypatch):
    """gaze.csv (written in chunks), fixations.csv (also with no fixation) and targets.ply read
    back what was written, to their number formats; a damaged file is one line."""
    from wearable_gaze.errors import UserError
    from wearable_gaze.formats import gaze_export
    from wearable_gaze.formats.fixations_table import read_fixations_csv, write_fixations_csv
    from wearable_gaze.formats.ply import PlyMesh, write_ply

    rng = np.random.default_rng(0)
    n = 25
    cols = {k: (rng.integers(-1, 5, n) if d == "int64" else rng.normal(0, 100, n))
            for k, d in gaze_export.GAZE_COLUMNS.items()}
    cols["est_x_mm"][::3] = np.nan
    monkeypatch.setattr(gaze_export, "CHUNK_ROWS", 7)                       # 4 chunks
    gaze_export.write_gaze_csv(tmp_path / "gaze.csv", cols)
    back = gaze_export.read_gaze_csv(tmp_path / "gaze.csv")
    for k, d in gaze_export.GAZE_COLUMNS.items():
        if d == "int64":
            assert back[k].dtype == np.int64 and np.array_equal(back[k], cols[k]), k
        else:
            step = float("1e-" + gaze_export.GAZE_FORMATS[k][1:-1]) if k in gaze_export.GAZE_FORMATS else 0.0
            np.testing.assert_allclose(back[k], cols[k], atol=step, equal_nan=True, err_msg=k)
    assert len(pd.read_csv(tmp_path / "gaze.csv")) == n
    rows = [{"fixation_id": 0, "start_s": 0.5, "end_s": 1.25, "duration_s": 0.75, "n_samples": 40, "target_id": 2,
             "motion": "static", "status": "ok", "position_mm": [1.0, 2.0, 1500.0],
             "covariance_mm2": np.diag([4.0, 9.0, 400.0])},
            {"fixation_id": 1, "start_s": 2.0, "end_s": 2.5, "duration_s": 0.3, "n_samples": 12, "target_id": -1,
             "motion": "static", "status": "insufficient-data", "position_mm": None, "covariance_mm2": None}]
    write_fixations_csv(tmp_path / "fixations.csv", rows)
    f = read_fixations_csv(tmp_path / "fixations.csv")
    assert list(f["target_id"]) == [2, -1] and list(f["status"]) == ["ok", "insufficient-data"]
    assert list(f["duration_s"]) == [0.75, 0.3] and f["cov_zz_mm2"][0] == 400.0 and np.isnan(f["x_mm"][1])
    write_fixations_csv(tmp_path / "none.csv", [])
    assert all(len(v) == 0 for v in read_fixations_csv(tmp_path / "none.csv").values())
    mesh = PlyMesh(rng.normal(0, 1000, (5, 3)), rng.integers(0, 256, (5, 3)), np.array([[0, 1, 2]]),
                   np.array([[3, 4]]), ["a comment"])
    write_ply(tmp_path / "m.ply", mesh)
    got = read_ply(tmp_path / "m.ply")
    np.testing.assert_allclose(got.vertices_mm, mesh.vertices_mm, atol=5e-4)
    assert np.array_equal(got.colors, mesh.colors) and got.comments == ["a comment"]
    assert np.array_equal(got.faces, mesh.faces) and np.array_equal(got.edges, mesh.edges)
    (tmp_path / "bad.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2 3 0 0 0\n")
    with pytest.raises(UserError, match=r"bad.ply: not a targets.ply"):
        read_ply(tmp_path / "bad.ply")


def test_gaze_columns_of_hand_made_samples_carry_the_device_clock_and_the_world_lines():
    """gaze.csv's columns from six hand-made samples (no session): ``device_t_s`` is the session's
    clock plus the import's offset, each eye's world line is its head-frame line moved by the head
    pose at its time, and the running estimate is its fixation's last row of estimates.csv at or
    before the sample (issue 30, planted faults ``export-clock-offset-sign`` and
    ``pose-slerp-transposed``)."""
    from estimator import BinocularSamples
    from estimator.frames import rotate_directions, rotation_about_axis, transform_points
    from wearable_gaze.pipeline.steps.export import gaze_columns
    from wearable_gaze.pipeline.types import Poses

    rng = np.random.default_rng(39)
    n = 6
    t = 10.0 + np.arange(n) / 60.0
    eyes = {"left": np.array([-32.0, 30.0, -20.0]), "right": np.array([32.0, 30.0, -20.0])}
    dirs = {side: rng.normal([0.0, 0.0, 1.0], 0.1, (n, 3)) for side in eyes}
    head = BinocularSamples.from_arrays(t, np.tile(eyes["left"], (n, 1)), dirs["left"],
                                        np.tile(eyes["right"], (n, 1)), dirs["right"], frame="head")
    T = np.eye(4)
    T[:3, :3] = rotation_about_axis([0.3, 1.0, 0.2], 0.6)
    T[:3, 3] = [400.0, -150.0, 2000.0]
    poses = Poses(9.95 + 0.05 * np.arange(5), np.arange(5), np.stack([T] * 5))      # a still head
    fixation = np.array([0, 0, 0, 1, 1, -1])
    running = {"t": np.array([10.0, 10.02, 10.05]), "segment": np.array([0, 0, 1]),
               "x": np.array([1.0, 2.0, 3.0]), "y": np.zeros(3), "z": np.full(3, 1500.0),
               "radius95_mm": np.array([50.0, 40.0, 30.0])}
    cols = gaze_columns(head, poses, t, fixation, fixation + 10 * (fixation >= 0), running, clock_offset_s=12.5)
    np.testing.assert_allclose(cols["device_t_s"], t + 12.5, rtol=0, atol=1e-12)
    for side, o in eyes.items():
        world_o = np.column_stack([cols[f"{side}_origin_{a}_mm"] for a in "xyz"])
        world_d = np.column_stack([cols[f"{side}_dir_{a}"] for a in "xyz"])
        np.testing.assert_allclose(world_o, transform_points(T, np.tile(o, (n, 1))), atol=1e-9)
        unit = dirs[side] / np.linalg.norm(dirs[side], axis=1, keepdims=True)
        np.testing.assert_allclose(world_d, rotate_directions(T, unit), atol=1e-12)
    assert cols["fixation_id"].tolist() == [0, 0, 0, 1, 1, -1]
    assert cols["target_id"].tolist() == [10, 10, 10, 11, 11, -1]
    np.testing.assert_array_equal(cols["est_x_mm"], [1.0, 1.0, 2.0, 3.0, 3.0, np.nan])
    np.testing.assert_array_equal(cols["est_radius95_mm"], [50.0, 50.0, 40.0, 30.0, 30.0, np.nan])
    assert np.all(np.isnan(cols["gaze_x_px"])) and not cols["in_image"].any()     # no camera: no 2D gaze
