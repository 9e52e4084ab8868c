"""The Aria gen1 MPS importer (formats/devices/aria.py): the real sample with the research's
reference answers (docs/devices/aria-mps.md 3.4-3.5), malformed inputs, and the writer's round trip."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers import one_line_error, run_import, walkabout_recording
from roundtrip import rms, roundtrip_errors

from estimator.api import estimate
from estimator.likelihood import angular_residuals
from estimator.lines import BinocularSamples, ViewLines
from wearable_gaze.formats.devices import aria, aria_trajectory, detect_format
from wearable_gaze.formats.eye_rays import read_device_gaze, read_eye_rays
from wearable_gaze.formats.poses import read_poses_csv
from wearable_gaze.formats.tables import read_table

GAZE = "eye_gaze_vergence/generalized_gaze.csv"
TRAJ = "trajectory/closed_loop_trajectory.csv"


@pytest.fixture
def sample(real_data):
    src = real_data / "aria_mps_sample_gen1"
    if not src.is_dir():
        pytest.skip(f"Aria sample not found at {src}")
    return src


@pytest.fixture
def copy(sample, tmp_path):
    """A writable copy of the sample without its point cloud (not read)."""
    dst = tmp_path / "mps"
    shutil.copytree(sample, dst, ignore=shutil.ignore_patterns("*.gz", "LICENSE", "*.md"))
    return dst


def run(src, out, **options):
    """Import ``src`` into ``out``: (report, rays, (t, T) head poses, (t, points) device gaze)."""
    report = run_import(aria, src, out, **options)
    t, _, T, _ = read_poses_csv(out / "head_poses.csv")
    dev = read_device_gaze(out / "device_gaze.csv") if (out / "device_gaze.csv").is_file() else None
    return report, read_eye_rays(out / "eye_rays.csv"), (t, T), dev


def edit(path: Path, fn) -> None:
    """Rewrite a CSV's lines (header at index 0) with ``fn(lines) -> lines``."""
    lines = path.read_text().splitlines()
    path.write_text("\n".join(fn(lines)) + "\n")


def set_cell(line: str, index: int, value: str) -> str:
    cells = line.split(",")
    cells[index] = value
    return ",".join(cells)


def source_gaze(src):
    return read_table(src / GAZE, ["tracking_timestamp_us", "left_yaw_rads_cpf", "right_yaw_rads_cpf",
                                   "pitch_rads_cpf", "depth_m"], text_columns=("session_uid",), max_abs=1e12)


def world_lines(rays, T):
    R, t = T[:, :3, :3], T[:, :3, 3]
    return [(np.einsum("nij,nj->ni", R, o) + t, np.einsum("nij,nj->ni", R, d))
            for o, d in ((rays.left_origin_mm, rays.left_direction), (rays.right_origin_mm, rays.right_direction))]


def closest_midpoints(o1, d1, o2, d2):
    """Midpoints of the two lines' closest approach, and whether both lie ahead of the eyes."""
    w = o1 - o2
    a, b, c = (d1 * d1).sum(1), (d1 * d2).sum(1), (d2 * d2).sum(1)
    dd, e = (d1 * w).sum(1), (d2 * w).sum(1)
    s1, s2 = (b * e - c * dd) / (a * c - b * b), (a * e - b * dd) / (a * c - b * b)
    return (o1 + s1[:, None] * d1 + o2 + s2[:, None] * d2) / 2, (s1 > 0) & (s2 > 0)


# --- the real sample -------------------------------------------------------------------------

def test_real_sample_counts_clock_and_labels(sample, tmp_path):
    assert detect_format(sample) == "aria-mps"
    report, rays, (tp, T), (tg, _) = run(sample, tmp_path / "s")
    assert report["read"] == {"eye gaze rows": 123, "trajectory rows": 11517}
    assert report["eye_samples_written"] == 114 == len(rays)
    assert report["dropped"] == {"no head pose: before the trajectory starts": 7,
                                 "no head pose: after the trajectory ends": 2}
    labels = report["eye_labels"]
    assert labels["swapped"] and labels["rows_diverging_as_labelled"] == 117
    assert labels["rows_diverging_as_labelled"] + labels["rows_converging_as_labelled"] == 123
    assert report["eye_gaze"]["file"] == GAZE and report["eye_gaze"]["model"] == "per-eye"
    assert report["trajectory"]["graph_uid"] == "ea7288b8-b6a0-012d-8156-257aba6bd796"
    assert any("swapped: 117 of 123" in n for n in report["notes"])
    assert any("general model, not calibrated to this wearer" in n for n in report["notes"])    # a caveat said
    # clock: session t = 0 at the first imported sample (device 149.202622 s), 10 Hz, no offset to poses
    assert report["clock_offset_s"] == pytest.approx(149.202622, abs=1e-9)
    assert rays.t_s[0] == 0.0 and np.allclose(np.diff(rays.t_s), 0.1, atol=1e-6)
    assert np.array_equal(tp, rays.t_s) and np.array_equal(tg, rays.t_s)
    assert np.all(np.isfinite(T.reshape(len(T), -1))), "every imported sample has a head pose"
    manifest = json.loads((tmp_path / "s" / "session.json").read_text())
    assert manifest["eye_rate_hz"] == 10.0 and manifest["source"]["pose_source"] == "device"
    assert np.allclose(report["frames"]["T_device_from_cpf"][1], [0.793353381, 0.0, -0.608761376, -49.148367],
                       atol=1e-6)


def test_real_sample_device_gaze_is_depth_along_the_combined_direction(sample, tmp_path):
    _, rays, _, (_, dev) = run(sample, tmp_path / "s")
    g = source_gaze(sample)
    keep = np.isin(np.round(g["tracking_timestamp_us"]), np.round(rays.t_s * 1e6 + 149202622))
    assert keep.sum() == 114
    yaw = np.arctan((np.tan(g["left_yaw_rads_cpf"]) + np.tan(g["right_yaw_rads_cpf"])) / 2)[keep]
    d_cpf = np.column_stack([np.tan(yaw), np.tan(g["pitch_rads_cpf"][keep]), np.ones(keep.sum())])
    d_cpf /= np.linalg.norm(d_cpf, axis=1, keepdims=True)
    expected = d_cpf * g["depth_m"][keep, None] * 1000 * [-1, -1, 1]        # CPF m -> head mm
    assert np.abs(dev - expected).max() < 2e-3
    # the swapped per-eye lines meet, in front, at that very point (below the 4 m cap)
    mid, ahead = closest_midpoints(rays.left_origin_mm, rays.left_direction, rays.right_origin_mm,
                                   rays.right_direction)
    below = g["depth_m"][keep] < 3.999
    assert ahead.sum() >= 105
    assert np.abs(mid - dev)[ahead & below].max() < 0.01
    assert np.allclose(rays.left_origin_mm, [-31.5, 0, 0]) and np.allclose(rays.right_origin_mm, [31.5, 0, 0])


def test_real_sample_head_motion_and_frames(sample, tmp_path):
    report, rays, (_, T), _ = run(sample, tmp_path / "s")
    up = np.degrees(np.arccos(np.clip(T[:, 1, 1], -1, 1)))          # head +y against world +y (down)
    assert np.median(up) == pytest.approx(4.9, abs=0.3)
    t = rays.t_s + report["clock_offset_s"]

    def travel(a, b):
        sel = (t > a - 0.05) & (t < b + 0.05)
        p = T[sel, :3, 3]
        return sel.sum(), np.linalg.norm(p.max(0) - p.min(0))

    n, moving = travel(151.3, 151.7)                                 # fixation F0: the head walks
    assert n == 5 and moving == pytest.approx(400, abs=30)
    n, still = travel(159.6, 160.4)                                   # F1: the head holds still
    assert n == 9 and still < 40
    assert np.sum(np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1)) == pytest.approx(7800, abs=200)


def test_real_sample_conventions_fit_the_head_motion(sample, tmp_path):
    """The research's frame-and-clock check (aria-mps.md 3.4): 5-sample windows with >= 100 mm of
    head travel, ML on the 10 per-eye world lines; median RMS residual 0.78 deg with the right
    conventions, > 1.4 deg with any wrong one (labels, mirrored yaw, flipped pitch, CAD pose)."""
    _, rays, (_, T), _ = run(sample, tmp_path / "s")
    (ol, dl), (orr, dr) = world_lines(rays, T)
    rms = []
    for a in range(len(rays) - 4):
        i = np.arange(a, a + 5)
        if np.linalg.norm(T[i[-1], :3, 3] - T[i[0], :3, 3]) < 100:
            continue
        est = estimate(BinocularSamples.from_arrays(rays.t_s[i], ol[i], dl[i], orr[i], dr[i]), method="ml")
        if est.position_mm is not None:
            lines = ViewLines(np.vstack([ol[i], orr[i]]), np.vstack([dl[i], dr[i]]), "world")
            rms.append(np.degrees(np.sqrt(np.mean(angular_residuals(est.position_mm, lines) ** 2))))
    assert len(rms) >= 90
    assert np.median(rms) < 1.0


def test_small_chunks_give_the_same_session(sample, tmp_path, monkeypatch):
    """Streaming: the trajectory merged chunk by chunk (7 gaze rows against 101 pose rows at a
    time) gives exactly the session read in large chunks."""
    _, rays0, (_, T0), (_, dev0) = run(sample, tmp_path / "a")
    monkeypatch.setattr(aria, "CHUNK_ROWS", 7)
    monkeypatch.setattr(aria_trajectory, "CHUNK_ROWS", 101)
    report, rays, (_, T), (_, dev) = run(sample, tmp_path / "b")
    assert report["eye_samples_written"] == 114 and report["eye_labels"]["swapped"]
    assert np.array_equal(rays.t_s, rays0.t_s) and np.array_equal(rays.left_direction, rays0.left_direction)
    assert np.array_equal(T, T0) and np.array_equal(dev, dev0)


# --- labels and models ------------------------------------------------------------------------

def test_label_swap_is_decided_per_file(copy, sample, tmp_path):
    """A file whose yaw columns are already the right way round is not swapped, and gives the
    same lines as the original."""
    _, rays0, _, _ = run(sample, tmp_path / "a")
    edit(copy / GAZE, lambda ls: [ls[0].replace("left_yaw_rads_cpf", "TMP").replace("right_yaw_rads_cpf",
                                                                                     "left_yaw_rads_cpf")
                                  .replace("TMP", "right_yaw_rads_cpf")] + ls[1:])
    report, rays, _, _ = run(copy, tmp_path / "b")
    assert not report["eye_labels"]["swapped"] and report["eye_labels"]["rows_diverging_as_labelled"] == 6
    for side in ("left", "right"):
        assert np.abs(getattr(rays, f"{side}_direction") - getattr(rays0, f"{side}_direction")).max() < 1e-7


def test_pre_2024_model_gives_one_cyclopean_line(copy, tmp_path):
    shutil.rmtree(copy / "eye_gaze_vergence")
    report, rays, _, (_, dev) = run(copy, tmp_path / "s")
    assert report["eye_gaze"] == {"file": "eye_gaze/generalized_eye_gaze.csv", "model": "pre-2024",
                                  "session_uids": ["8d34a429-0122-49a7-9eec-751da9d37d9f"]}
    assert len(rays) == 114 and rays.left_valid.all() and not rays.right_valid.any()
    assert np.allclose(rays.left_origin_mm, 0) and np.isnan(dev).all()      # depth_m is empty in this model
    # first posed row: yaw 0.894797 -> x = -tan(yaw) in our axes
    g = read_table(copy / "eye_gaze/generalized_eye_gaze.csv", ["tracking_timestamp_us", "yaw_rads_cpf",
                   "pitch_rads_cpf"], text_columns=("session_uid",), empty_ok=("depth_m",))
    i = int(np.flatnonzero(g["tracking_timestamp_us"] == 149202622)[0])
    d = np.array([-np.tan(g["yaw_rads_cpf"][i]), -np.tan(g["pitch_rads_cpf"][i]), 1.0])
    assert np.allclose(rays.left_direction[0], d / np.linalg.norm(d), atol=1e-7)
    (copy / "eye_gaze/generalized_eye_gaze.csv").unlink()                   # then the oldest layout
    report, rays2, _, _ = run(copy, tmp_path / "s2")
    assert report["eye_gaze"]["file"] == "eye_gaze/eyegaze.csv"
    assert np.abs(rays2.left_direction - rays.left_direction).max() < 1e-6


def test_personalized_file_is_preferred_and_several_session_uids_are_noted(copy, tmp_path):
    pers = copy / "eye_gaze_vergence" / "personalized_gaze.csv"        # found after the general file
    shutil.copyfile(copy / GAZE, pers)
    edit(pers, lambda ls: ls[:60] + [ln.rsplit(",", 1)[0] + ",second-calibration" for ln in ls[60:]])
    report, rays, _, _ = run(copy, tmp_path / "s")
    assert report["eye_gaze"]["file"] == "eye_gaze_vergence/personalized_gaze.csv"
    assert not any("general model" in n for n in report["notes"])                       # calibrated: no caveat
    assert len(report["eye_gaze"]["session_uids"]) == 2 and len(rays) == 114
    assert any("2 session_uid values" in n for n in report["notes"])
    assert any(n.endswith("; not read: eye_gaze/eyegaze.csv, eye_gaze/generalized_eye_gaze.csv, " + GAZE)
               for n in report["notes"])


# --- malformed inputs ---------------------------------------------------------------------------

def test_missing_or_wrong_files_give_one_line(copy, tmp_path):
    (copy / TRAJ).rename(copy / "moved.csv")
    one_line_error(aria, copy, tmp_path / "bad", "closed_loop_trajectory.csv")
    (copy / "moved.csv").rename(copy / TRAJ)
    edit(copy / TRAJ, lambda ls: [ls[0].replace("qw_world_device", "qw")] + ls[1:])
    one_line_error(aria, copy, tmp_path / "bad", "missing column(s) qw_world_device")
    edit(copy / TRAJ, lambda ls: [ls[0].replace("qw", "qw_world_device")] + ls[1:])
    for p in copy.glob("eye_gaze*/*.csv"):
        edit(p, lambda ls: [ls[0].replace("pitch_rads_cpf", "pitch")] + ls[1:])
    one_line_error(aria, copy, tmp_path / "bad", "missing column(s) pitch_rads_cpf of an MPS eye-gaze CSV")
    shutil.rmtree(copy / "eye_gaze")
    shutil.rmtree(copy / "eye_gaze_vergence")
    one_line_error(aria, copy, tmp_path / "bad", "no MPS eye-gaze CSV")



@pytest.mark.parametrize("column", ["pitch_rads_cpf", "right_yaw_rads_cpf"])
def test_a_per_eye_file_with_a_column_deleted_is_refused_not_replaced(copy, tmp_path, column):
    """The per-eye (vergence) file with a column deleted (a damaged copy) was skipped, and the
    import went on from the pre-2024 file (one cyclopean line, no device depth) with only a
    'not read' note; it is one line naming the file and the column."""
    def drop(ls):
        i = ls[0].split(",").index(column)
        return [",".join(c for j, c in enumerate(ln.split(",")) if j != i) for ln in ls]
    edit(copy / GAZE, drop)
    msg = one_line_error(aria, copy, tmp_path / "bad", f"missing column(s) {column} of an MPS eye-gaze CSV")
    assert "generalized_gaze.csv" in msg

def test_gen2_and_wrong_units_are_refused(copy, tmp_path):
    gen2 = ",yaw_rads_cpf,left_pitch_rads_cpf,right_pitch_rads_cpf"
    edit(copy / GAZE, lambda ls: [ls[0] + gen2] + [ln + ",0,0,0" for ln in ls[1:]])
    one_line_error(aria, copy, tmp_path / "bad", "Gen2", "--format aria-gen2")
    edit(copy / GAZE, lambda ls: [ln.rsplit(",", 3)[0] for ln in ls])
    edit(copy / GAZE, lambda ls: ls[:1] + [set_cell(ln, 0, str(int(ln.split(",")[0]) / 1e6)) for ln in ls[1:]])
    one_line_error(aria, copy, tmp_path / "bad", "microseconds")


def test_bad_gaze_rows_are_counted(copy, tmp_path):
    def damage(ls):
        ls[20] = set_cell(ls[20], 3, "nan")                 # pitch NaN
        ls[21] = set_cell(ls[21], 1, "")                    # left yaw empty
        ls[22] = set_cell(ls[22], 2, "abc")                 # not a number
        ls[23] = set_cell(ls[23], 3, "1.5")                 # pitch 86 deg
        ls[24] = set_cell(ls[24], 11, "0.2")                # the left eye 200 mm from CPF
        ls.insert(31, ls[30])                               # a repeated row
        ls[-1] = ls[-1][:25]                                # a truncated last line
        return ls
    edit(copy / GAZE, damage)
    report, rays, _, _ = run(copy, tmp_path / "s")
    d = report["dropped"]
    assert d["gaze row with NaN or a non-number"] == 3
    assert d["gaze angle of 80 deg or more"] == 1
    assert d["eye position over 50 mm from CPF"] == 1
    assert d["gaze row with a repeated time"] == 1
    assert d["gaze row truncated (missing cells)"] == 1
    assert d["no head pose: before the trajectory starts"] == 7 and d["no head pose: after the trajectory ends"] == 1
    assert report["read"]["eye gaze rows"] == 124
    assert len(rays) == 114 - 5
    assert sum(d.values()) + len(rays) == 124


def test_gaze_times_going_back_give_one_line(copy, tmp_path):
    edit(copy / GAZE, lambda ls: ls[:40] + [ls[41], ls[40]] + ls[42:])
    one_line_error(aria, copy, tmp_path / "bad", "goes back", "time order")


def test_bad_trajectory_rows_are_counted_and_gaps_drop_samples(copy, tmp_path):
    t_col = 1

    def damage(ls):
        ls[3000] = set_cell(ls[3000], 3, "nan")                       # NaN translation
        ls[3001] = set_cell(ls[3001], 9, "0.1")                       # qw: not a unit quaternion
        ls[3002] = set_cell(ls[3002], 0, "another-world")             # another graph_uid
        ls.insert(3004, ls[3003])                                     # a repeated time
        t = np.array([int(ln.split(",")[t_col]) for ln in ls[1:]])
        gap = np.flatnonzero((t > 155_000_000) & (t < 155_450_000)) + 1
        del ls[gap[0]:gap[-1] + 1]                                    # a 0.45 s hole
        ls[-1] = ls[-1][:40]                                          # a truncated last line
        return ls
    edit(copy / TRAJ, damage)
    report, rays, (_, T), _ = run(copy, tmp_path / "s", max_pose_gap_s=0.05)
    d = report["dropped"]
    assert d["trajectory row with NaN or a non-number"] == 1
    assert d["trajectory row with a non-unit quaternion"] == 1
    assert d["trajectory row in another SLAM world (graph_uid)"] == 1
    assert d["trajectory row with a repeated time"] == 1
    assert d["trajectory row truncated (missing cells)"] == 1
    # gaze at 155.002622 ... 155.402622 s: 5 samples with a neighbouring pose over 50 ms away
    assert d["no head pose within max_pose_gap_s (a gap in the trajectory)"] == 5
    assert len(rays) == 109 and np.all(np.isfinite(T))


def test_trajectory_times_going_back_give_one_line(copy, tmp_path):
    edit(copy / TRAJ, lambda ls: ls[:500] + [ls[501], ls[500]] + ls[502:])
    one_line_error(aria, copy, tmp_path / "bad", "goes back")


def test_a_damaged_file_gives_one_line(copy, tmp_path):
    data = (copy / TRAJ).read_bytes()
    (copy / TRAJ).write_bytes(data[:200000] + b"\xff\xfe" + data[200000:])
    one_line_error(aria, copy, tmp_path / "bad", "not UTF-8")


def test_no_usable_pose_gives_one_line(copy, tmp_path):
    edit(copy / TRAJ, lambda ls: ls[:1])
    one_line_error(aria, copy, tmp_path / "bad", "no usable pose row")


# --- the writer's round trip ---------------------------------------------------------------------

@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    return walkabout_recording(tmp_path_factory.mktemp("aria_sim") / "session")


def test_write_then_read_gives_back_the_rays(sim, tmp_path):
    aria.write_recording(sim, tmp_path / "mps")
    assert detect_format(tmp_path / "mps") == "aria-mps"
    report, rays, (_, T), (_, dev) = run(tmp_path / "mps", tmp_path / "s")
    both = sim.rays.left_valid & sim.rays.right_valid
    assert len(rays) == both.sum() and report["dropped"] == {"gaze row with NaN or a non-number": int((~both).sum())}
    assert not report["eye_labels"]["swapped"]
    assert np.allclose(rays.t_s, sim.t[both] - sim.t[both][0], atol=1e-6)
    assert report["clock_offset_s"] == pytest.approx(aria.SIM_T0_US / 1e6 + sim.t[both][0], abs=1e-6)
    r = sim.rays.select(both)
    c = np.mean(np.concatenate([sim.rays.left_origin_mm[sim.rays.left_valid],
                                sim.rays.right_origin_mm[sim.rays.right_valid]]), axis=0)
    assert np.abs(rays.left_origin_mm + c - r.left_origin_mm).max() < 1e-3
    assert np.abs(rays.right_origin_mm + c - r.right_origin_mm).max() < 1e-3
    # per-eye yaw exact; the pitch shared: the mean of the two eyes' (the model's only loss)
    pitch = [np.arctan(d[:, 1] / d[:, 2]) for d in (r.left_direction, r.right_direction)]
    for side, p_own in zip(("left", "right"), pitch, strict=True):
        got, want = getattr(rays, f"{side}_direction"), getattr(r, f"{side}_direction")
        assert np.abs(np.arctan(got[:, 0] / got[:, 2]) - np.arctan(want[:, 0] / want[:, 2])).max() < 1e-7
        assert np.abs(np.arctan(got[:, 1] / got[:, 2]) - (pitch[0] + pitch[1]) / 2).max() < 1e-7
        assert np.abs(p_own - (pitch[0] + pitch[1]) / 2).max() > 1e-3          # the loss is real here
    Tc = np.eye(4)
    Tc[:3, 3] = c
    want = sim.T_world_from_head[both] @ Tc
    # the 1 kHz trajectory is resampled from the 60 Hz poses: reading it back interpolates across
    # the kinks at the samples (a turn rate change of 0.6 rad/s over 1 ms: ~1.6e-4 rad)
    assert np.abs(T[:, :3, 3] - want[:, :3, 3]).max() < 0.2
    assert np.abs(T[:, :3, :3] - want[:, :3, :3]).max() < 5e-4
    # the device's gaze: along MPS's combined direction, at the written lines' vergence depth (MPS's
    # crossing in CPF's XZ plane, capped at 4 m; within 1 % of the lines' 3D closest approach)
    mid, ahead = closest_midpoints(rays.left_origin_mm, rays.left_direction, rays.right_origin_mm,
                                   rays.right_direction)
    ok = np.isfinite(dev[:, 0]) & (np.linalg.norm(dev, axis=1) < 3999)
    assert ok.sum() > len(rays) / 2 and ahead[ok].all()
    tan = [d[:, 0] / d[:, 2] for d in (rays.left_direction, rays.right_direction)]
    comb = np.column_stack([(tan[0] + tan[1]) / 2, rays.left_direction[:, 1] / rays.left_direction[:, 2],
                            np.ones(len(rays))])
    comb /= np.linalg.norm(comb, axis=1, keepdims=True)
    assert np.abs(dev[ok] / np.linalg.norm(dev[ok], axis=1, keepdims=True) - comb[ok]).max() < 1e-6
    assert np.allclose(np.linalg.norm(dev[ok], axis=1), np.linalg.norm(mid[ok], axis=1), rtol=0.01)


def test_round_trip_through_process_finds_the_targets_as_well_as_the_native_session(tmp_path_factory, tmp_path):
    native, imported, report = roundtrip_errors("aria-mps", tmp_path_factory.getbasetemp(), tmp_path, markers=False)
    assert report["pose_source"] == "device" and not report["eye_labels"]["swapped"]
    assert np.all(np.isfinite(imported)), "every fixated target found"
    assert rms(imported) <= 1.1 * rms(native)


def test_real_sample_through_process_beats_the_devices_own_depth_where_the_head_moves(sample, tmp_path):
    """Import, then ``process``: fixations are found where the gaze holds still (the rate's
    segmentation window: 2 samples at 10 Hz), every fixation of 5 or more samples has an
    estimate from both ``ml`` and ``voxel``, and where the head travels >= 300 mm during the
    fixation (F0: 400 mm in 0.5 s) the ``ml`` depth is nearer the reference than the device's own
    median ``depth_m``, and within 25 % of it where that travel is across the line of sight
    (parallax; a walk toward the point gives little: the fixation at 0.4-1.0 s, found since the
    segmentation is made in the world (issue 27), travels 447 mm, 164 mm across, and its ``ml``
    depth is 2106 mm against 3604 mm, depth_m 1123 mm). Reference: the first surface of MPS's
    semi-dense points (dist_std <= 20 mm) along the device's gaze direction, median over the
    fixation (research: F0 ml 2093 mm, reference 2382 mm, depth_m 1260 mm)."""
    from wearable_gaze.formats.viewlines import read_viewlines_csv
    from wearable_gaze.pipeline.process.session import process_session
    from wearable_gaze.pipeline.steps.device import surface_reference
    from wearable_gaze.pipeline.types import Poses

    run(sample, tmp_path / "s")
    res = process_session(tmp_path / "s", tmp_path / "out", overlay=False, report=False)
    fixations = [seg for seg in read_viewlines_csv(tmp_path / "out" / "viewlines.csv") if seg.key >= 0]
    assert len(res.targets) >= 1 and any(len(f.samples) >= 5 for f in fixations)
    poses = Poses(*read_poses_csv(tmp_path / "out" / "poses.csv"))
    cloud = aria.read_point_cloud(sample)
    moved = moved_across = 0
    for f in fixations:
        if len(f.samples) < 5:
            continue
        est = {m: estimate(f.samples, m) for m in ("ml", "voxel")}
        assert all(e.ok for e in est.values()), {m: e.reason for m, e in est.items()}
        ref, head = surface_reference(cloud, tmp_path / "s" / "device_gaze.csv", poses, f.samples.t_s)
        travel = np.linalg.norm(head[-1] - head[0])
        if travel < 300:
            continue
        moved += 1
        o = np.nanmedian(head, axis=0)
        ref_depth = np.linalg.norm(np.nanmedian(ref, axis=0) - o)
        t_g, p_g = read_device_gaze(tmp_path / "s" / "device_gaze.csv")
        dev_depth = np.median(np.linalg.norm(p_g[np.isin(np.round(t_g, 4), np.round(f.samples.t_s, 4))], axis=1))
        ml_depth = np.linalg.norm(est["ml"].position_mm - o)
        sight = (np.nanmedian(ref, axis=0) - o) / ref_depth
        across = np.linalg.norm(np.cross(head[-1] - head[0], sight))
        if across >= 300:
            assert abs(ml_depth - ref_depth) < 0.25 * ref_depth, (ml_depth, ref_depth)
            moved_across += 1
        assert abs(ml_depth - ref_depth) < abs(dev_depth - ref_depth), (ml_depth, dev_depth, ref_depth)
    assert moved >= 1 and moved_across >= 1


def test_real_sample_keeps_its_point_cloud_and_the_report_draws_it(sample, tmp_path):
    """Issue 28: the import keeps MPS's well-placed semi-dense points (device_points.ply, our world
    frame), and the report's 3D view draws them: they surround the walk."""
    import json
    import re

    from wearable_gaze.formats.ply import read_ply
    from wearable_gaze.pipeline.process.session import process_session

    run(sample, tmp_path / "s")
    pts = read_ply(tmp_path / "s" / "device_points.ply").vertices_mm
    cloud = aria.read_point_cloud(sample)
    assert 1000 < len(pts) <= min(len(cloud), aria.MAX_KEPT_POINTS)
    assert np.all(np.isin(pts[:, 0].round(3), cloud[:, 0].round(3)))                 # the cloud's own points
    process_session(tmp_path / "s", tmp_path / "out", overlay=False)
    page = (tmp_path / "out" / "report.html").read_text()
    scene = json.loads(re.search(r'<script type="application/json" id="view3d-data">(.*?)</script>', page,
                                 re.S).group(1))
    drawn = np.asarray(scene["points"], float)
    head = np.asarray(scene["head"], float)
    assert len(drawn) > 1000
    assert np.all(np.abs(np.median(drawn, axis=0) - np.median(head, axis=0)) < 10000)   # around the walk


def test_real_sample_walk_fixations_are_found_in_the_world(sample, tmp_path):
    """Issue 27: the wearer walks (0.75 m/s) and looks down at near surfaces; the eye-in-world
    direction turns 25-40 deg/s while a point is held, so the direction rule (3 deg between
    window medians) found 2 fixations. The world test (one still point explains both windows'
    rays, at a depth the fixation's own lines allow) finds 4 (the lines of 1.9-7.5 s fix a point
    1.3-1.4 m away, which the after-window at 7.6 s misses by 2.4 deg, over the 2.19 deg
    threshold; the two parts are one moving target: the gaze wanders 2-3 deg over the object)
    and ``process`` answers 3 targets. Every one has its direction (the moving one's where the
    gaze pointed at its path's middle knot, ``path_direction``), and the SLAM surface's median
    point over its samples lies in its 95 % cone (0.05-0.6 deg off its axis; cones 3.6-3.9 deg);
    each one whose head travels 0.3 m or more over a fixation is nearer that surface
    (``surface_reference``) than Aria's own ``depth_m`` (benchmarks/real_aria_targets.py).
    Skipped without ../shared (the ``sample`` fixture)."""
    from wearable_gaze.formats.viewlines import read_viewlines_csv
    from wearable_gaze.pipeline.process.session import process_session
    from wearable_gaze.pipeline.steps.device import surface_reference
    from wearable_gaze.pipeline.types import Poses

    run(sample, tmp_path / "s")
    res = process_session(tmp_path / "s", tmp_path / "out", overlay=False, report=False)
    segments = {seg.key: seg.samples for seg in read_viewlines_csv(tmp_path / "out" / "viewlines.csv") if seg.key >= 0}
    assert len(segments) >= 3 and len(res.found) >= 3
    assert all(t.direction is not None for t in res.found)
    poses = Poses(*read_poses_csv(tmp_path / "out" / "poses.csv"))
    cloud = aria.read_point_cloud(sample)
    t_g, p_g = read_device_gaze(tmp_path / "s" / "device_gaze.csv")
    moved = 0
    for tg in res.found:
        parts = [segments[k] for k in tg.fixations]
        heads = [surface_reference(cloud, tmp_path / "s" / "device_gaze.csv", poses, p.t_s)[1] for p in parts]
        t = np.concatenate([p.t_s for p in parts])
        ref, head = surface_reference(cloud, tmp_path / "s" / "device_gaze.csv", poses, t)
        g = tg.direction
        assert g.contains(np.nanmedian(ref, axis=0)), (tg.index, g)         # the surface it looked at
        if max(np.linalg.norm(h[-1] - h[0]) for h in heads) < 300:
            continue
        moved += 1
        o = np.nanmedian(head, axis=0)
        ref_depth = np.linalg.norm(np.nanmedian(ref, axis=0) - o)
        dev_depth = np.median(np.linalg.norm(p_g[np.isin(np.round(t_g, 4), np.round(t, 4))], axis=1))
        ours = np.linalg.norm(tg.position_mm - o)
        assert abs(ours - ref_depth) < abs(dev_depth - ref_depth), (tg.index, ours, dev_depth, ref_depth)
    assert moved >= 2
