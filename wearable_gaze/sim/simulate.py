"""Write a complete simulated session folder from a scenario (docs/session.md, docs/scenarios.md).

Everything random comes from ``numpy.random.SeedSequence(seed)`` split by purpose, so the same
seed and scenario give the same bytes.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from estimator import BinocularSamples

from .. import __version__
from ..errors import UserError
from ..formats.atomic import atomic_folder
from ..formats.board import write_board
from ..formats.camera import camera_dict, write_camera
from ..formats.eye_samples import EyeSamples, write_eye_csv
from ..formats.jsonio import read_json_text
from ..formats.markermap import marker_map_dict, write_marker_map
from ..formats.poses import write_poses_csv
from ..formats.serial_protocol import encode_stream
from ..formats.session import FORMAT, VERSION, write_manifest
from ..formats.tables import write_table
from ..formats.truth import write_truth_eyes, write_truth_moved_markers, write_truth_targets
from ..formats.video import open_video_writer, write_frame_times
from ..formats.viewlines import write_viewlines_csv
from ..formats.walls import EYE_CSV, write_walls
from .camera import Camera
from .eyes import EyeModel, gaze_points, plan_gaze
from .motion import make_motion
from .noise import SensorNoise
from .render import render
from .world import CalibrationWall, Target, board_plane, fixed_point, lab_room, look_at, moved_pose, waypoint_path

VIDEO_EXT = {"mp4v": ".mp4", "MJPG": ".avi", "FFV1": ".avi"}

log = logging.getLogger(__name__)


def scene_camera(scn: dict) -> Camera:
    c = scn["camera"]
    w, h = c["resolution"]
    return Camera.wide_scene_camera(int(w), int(h), float(c["hfov_deg"]), c["dist_coeffs"])


def make_targets(scn: dict, rng: np.random.Generator) -> list:
    """The scenario's targets: given points first, then random ones (stratified in depth, within
    +-35 deg of straight ahead horizontally and +-15 deg vertically). A moving target sweeps
    from its point to a second point 1.2 m to the right and back, holding still at each end
    (2 s, or a sixth of a short session)."""
    spec = scn["targets"]
    pts = [np.asarray(p, float) for p in spec["points_mm"]]
    n_rand = int(spec["random_count"])
    if n_rand:
        lo, hi = spec["random_depth_mm"]
        depths = lo + (hi - lo) * (np.arange(n_rand) + rng.uniform(0.2, 0.8, n_rand)) / n_rand
        rng.shuffle(depths)
        for d in depths:
            yaw, pitch = np.deg2rad(rng.uniform(-35, 35)), np.deg2rad(rng.uniform(-15, 15))
            pts.append(d * np.array([np.sin(yaw) * np.cos(pitch), np.sin(pitch), np.cos(yaw) * np.cos(pitch)]))
    moving = set(spec["moving"])
    start = np.asarray(scn["head"]["start_mm"], float)
    out = []
    for i, p in enumerate(pts):
        if i in moving:
            T = scn["duration_s"]
            q = p + np.array([1200.0, 0, 0])
            h = min(2.0, T / 6)
            times = [0, h, T / 2 - h / 2, T / 2 + h / 2, T - h, T]
            path = waypoint_path([p, p, q, q, p, p], times)
            out.append(Target(f"target {i}", path, spec["size_mm"], tuple(start), moving=True))
        else:
            out.append(Target(f"target {i}", fixed_point(p), spec["size_mm"], tuple(start)))
    return out


def build_world(scn: dict, rng: np.random.Generator, targets) -> World:  # noqa: F821
    """The scenario's room (drawn from ``rng``) with ``targets``, and its moved marker, if any."""
    room = scn["room"]
    if room["layout"] == "lab":
        world = lab_room(rng, room["size_mm"], room["eye_height_mm"], room["back_mm"],
                         int(room["markers_per_wall"]), room["dictionary"], room["marker_size_mm"],
                         int(room["posters_per_wall"]))
    else:
        from .world import World
        world = World(dictionary=room["dictionary"], marker_size_mm=room["marker_size_mm"])
    world.targets = list(targets)
    mv = scn.get("moved_marker")
    if mv is not None:
        i = int(mv["id"])
        world.move_marker(i, float(mv["at_s"]), moved_pose(world.markers[i], mv["shift_mm"], mv["turn_deg"]))
    return world


def _render_frame(camera, world, T, t, noise, scn) -> np.ndarray:
    n_blur = int(scn["camera"]["motion_blur_samples"])
    gain = float(scn["camera"]["gain"])
    if n_blur <= 1:
        img = render(camera, T(t), world.planes_at(t))
    else:
        exposure = 0.5 / scn["camera"]["fps"]
        ts = t + (np.arange(n_blur) / (n_blur - 1) - 0.5) * exposure
        img = sum(render(camera, T(s), world.planes_at(s)) for s in ts) / n_blur
    return noise.apply(img, gain)


def _board_views(camera: Camera, spec: dict, n: int, rng: np.random.Generator):
    """Poses of a calibration board filling different parts of the image (every corner in view,
    20 px from the border), tilted up to 40 deg."""
    w, h = camera.image_size
    K = camera.camera_matrix
    out = []
    tries = 0
    while len(out) < n and tries < 200 * n:
        tries += 1
        plane, obj = board_plane(spec, np.eye(4))
        extent = obj.max(axis=0) - obj.min(axis=0)
        depth = rng.uniform(2.2, 4.0) * max(extent[:2])
        u, v = rng.uniform(0.15, 0.85) * w, rng.uniform(0.15, 0.85) * h
        center = depth * np.array([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], 1.0])
        T = look_at(center, 2 * center)                   # facing the camera, z away from it
        axis = rng.normal(size=3)
        axis[2] = 0
        from estimator.frames import rotation_about_axis
        T[:3, :3] = rotation_about_axis(axis, np.deg2rad(rng.uniform(10, 40))) @ T[:3, :3]
        T[:3, 3] = center - T[:3, :3] @ ((obj.min(axis=0) + obj.max(axis=0)) / 2)
        pts = (T[:3, :3] @ obj.T).T + T[:3, 3]
        if np.any(pts[:, 2] < 100):
            continue
        px = camera.project(pts)
        if np.all((px > 20) & (px < np.array([w, h]) - 20)):
            out.append(T)
    return out


def load_scenario(spec) -> dict:
    """A named scenario or the path of a scenario JSON file -> the parsed scenario (not yet
    resolved). Raises ``UserError`` for a missing or malformed file."""
    from .scenario import NAMED

    if spec in NAMED:
        return spec
    p = Path(spec)
    if not p.suffix.lower() == ".json" and not p.exists():
        raise UserError(f"unknown scenario {ascii(str(spec))}: use one of {', '.join(NAMED)} or a scenario JSON file")
    return read_json_text(p, "scenario file (docs/scenarios.md)")


def simulate_scenario(scenario, out_dir, seed: int = 0, duration_s=None, resolution=None, progress=None) -> dict:
    """``wearable-gaze simulate``: resolve a named scenario or JSON file with the command-line
    overrides and write its session. Returns the manifest."""
    from .scenario import NAMED, resolve

    is_file = isinstance(scenario, (str, Path)) and str(scenario) not in NAMED
    scn = resolve(load_scenario(scenario) if isinstance(scenario, (str, Path)) else scenario,
                  duration_s, resolution, source=scenario if is_file else "scenario")
    return simulate(scn, out_dir, seed, progress)


def simulate(scenario: dict, out_dir, seed: int = 0, progress=None) -> dict:
    """Write the session of a resolved scenario to ``out_dir`` (which must not exist or be empty).

    The folder is built under a temporary name beside ``out_dir`` and renamed at the end, so a
    failure leaves nothing half-written.

    Returns:
        the manifest.
    """
    out_dir = Path(out_dir)
    with atomic_folder(out_dir) as tmp:
        log.info("simulating %g s (seed %d) into %s", float(scenario["duration_s"]), int(seed), out_dir)
        manifest = _simulate_into(scenario, tmp, int(seed), progress)
    return manifest


def _simulate_into(scn: dict, root: Path, seed: int, progress) -> dict:
    seeds = np.random.SeedSequence(seed).spawn(8)
    rng_world, rng_targets, rng_motion, rng_eyes, rng_gaze, rng_noise, rng_calib, rng_meas = (
        np.random.default_rng(s) for s in seeds)
    camera = scene_camera(scn)
    w, h = camera.image_size
    fps = float(scn["camera"]["fps"])
    eyes_spec = scn["eyes"]
    eye_model = EyeModel.make(rng_eyes, eyes_spec["ipd_mm"], eyes_spec["centre_offset_mm"],
                              eyes_spec["sigma_deg"], eyes_spec["bias_deg"])
    noise = SensorNoise(camera.image_size, rng_noise, float(scn["camera"]["noise_std"]))
    files = {}
    manifest = {"format": FORMAT, "version": VERSION, "producer": f"wearable-gaze simulate {__version__}",
                "scenario": scn, "seed": seed, "image_size": [w, h], "fps": fps,
                "eye_rate_hz": float(eyes_spec["rate_hz"]), "has_recording": bool(scn["session"]),
                "files": files}
    truth = root / "truth"
    truth.mkdir()
    write_camera(truth / "camera.json", camera_dict(camera.camera_matrix, camera.dist_coeffs, camera.image_size,
                                                  rms_px=0.0, source="simulation ground truth"))
    write_truth_eyes(truth / "eyes.json", eye_model.to_dict())
    files["truth_camera"] = "truth/camera.json"
    files["truth_eyes"] = "truth/eyes.json"

    # --- calibration recordings ----------------------------------------------------------------
    cal = scn["calibration"]
    steps = []
    if cal["eye"]:
        steps.append("eye calibration")
    if cal["camera_views"] > 0:
        steps.append("camera views")
    n_frames = int(round(scn["duration_s"] * fps)) if scn["session"] else 0
    total = n_frames + len(cal["walls"]) * int(bool(cal["eye"])) + int(cal["camera_views"])
    done = [0]

    def tick(k=1):
        done[0] += k
        if progress:
            progress(done[0], total)

    if cal["eye"]:
        files["eye_calibration"] = _eye_calibration(root, scn, camera, eye_model, noise, rng_calib, tick)
    if cal["camera_views"] > 0:
        files["camera_views"] = _camera_views(root, scn, camera, noise, rng_calib, tick)

    if scn["session"]:
        _session_recording(root, scn, camera, eye_model, noise, files, manifest,
                           (rng_world, rng_targets, rng_motion, rng_gaze, rng_meas), tick)
    write_manifest(root, manifest)
    return manifest


def _eye_calibration(root, scn, camera, eye_model, noise, rng, tick) -> str:
    cal = scn["calibration"]
    d = root / "calibration" / "eye"
    d.mkdir(parents=True)
    rate = float(scn["eyes"]["rate_hz"])
    per = max(int(round(cal["dwell_s"] * rate)), 3)
    rows = {k: [] for k in ("recording", "target", "t", "raw", "valid")}
    walls, images = [], []
    t0 = 0.0
    log.info("eye calibration: %d walls, %g s per target", len(cal["walls"]), cal["dwell_s"])
    for r, spec in enumerate(cal["walls"]):
        wall = CalibrationWall.spanning(spec["distance_mm"], spec["tilt_deg"], spec["grid"], cal["span_deg"])
        world = wall.world()
        images.append(noise.apply(render(camera, np.eye(4), world.planes)))
        name = f"wall_{r}.png"
        pts = wall.to_world(wall.targets_wall())
        t = t0 + np.arange(per * len(pts)) / rate
        target = np.repeat(np.arange(len(pts)), per)
        gaze = pts[target].copy()
        # the first saccade's worth of samples of each target still travels from the previous one
        n_sac = int(np.ceil(0.05 * rate))
        for k in range(1, len(pts)):
            for j in range(n_sac):
                a = (j + 1) / (n_sac + 1)
                gaze[k * per + j] = (1 - a) * pts[k - 1] + a * pts[k]
        raw, _, _ = eye_model.measure(gaze, rng, with_bias=False)
        rows["recording"].append(np.full(len(t), r))
        rows["target"].append(target)
        rows["t"].append(t)
        rows["raw"].append(raw)
        valid = np.ones((len(t), 2), bool)
        if scn["eyes"]["blink_rate_hz"] > 0:             # the odd blink during calibration too
            for tb in t[0] + np.cumsum(rng.exponential(1 / scn["eyes"]["blink_rate_hz"], 50)):
                valid[(t >= tb) & (t < tb + 0.15)] = False
        raw[~valid] = 0.0
        rows["valid"].append(valid)
        entry = wall.to_dict()
        entry.update({"recording": r, "image": name, "head_still": True,
                      "truth_T_cam_from_wall": wall.T_world_from_wall.tolist(), "truth_tilt_deg": wall.tilt_deg})
        walls.append(entry)
        t0 = t[-1] + 2.0
        tick()
    raw = np.concatenate(rows["raw"])
    eye = EyeSamples(np.concatenate(rows["t"]), np.arange(len(raw)), raw, np.concatenate(rows["valid"]))
    write_eye_csv(d / EYE_CSV, eye, {"recording": np.concatenate(rows["recording"]),
                                     "target": np.concatenate(rows["target"])})
    write_walls(d, walls, images)
    return "calibration/eye"


def _camera_views(root, scn, camera, noise, rng, tick) -> str:
    cal = scn["calibration"]
    spec = cal["camera_board"]
    d = root / "calibration" / "camera"
    d.mkdir(parents=True)
    poses = _board_views(camera, spec, int(cal["camera_views"]), rng)
    log.info("rendering %d views of the calibration board", len(poses))

    def views():
        for T in poses:
            plane, _ = board_plane(spec, T)
            yield noise.apply(render(camera, np.eye(4), [plane], background=float(rng.uniform(60, 160))))
            tick()
    write_board(d, spec, views(), poses)
    return "calibration/camera"


def _session_recording(root, scn, camera, eye_model, noise, files, manifest, rngs, tick):
    rng_world, rng_targets, rng_motion, rng_gaze, rng_meas = rngs
    rate = float(scn["eyes"]["rate_hz"])
    dur = float(scn["duration_s"])
    targets = make_targets(scn, rng_targets)
    world = build_world(scn, rng_world, targets)
    es = scn["eyes"]
    t_eye = np.arange(int(np.floor(dur * rate))) / rate
    plan = plan_gaze(t_eye, len(targets), [tg.moving for tg in targets], rng_gaze, es["fixation_s"],
                     es["blink_rate_hz"], es["dropout_rate"], es["order"])
    gaze_w = gaze_points(t_eye, plan, targets, es["pursuit_lag_s"])

    def gaze_fn(tt):
        return np.column_stack([np.interp(tt, t_eye, gaze_w[:, i]) for i in range(3)])

    motion = make_motion(scn["head"], dur, rng_motion, gaze_fn)
    T_eye = motion.poses(t_eye)
    R_cw = np.transpose(T_eye[:, :3, :3], (0, 2, 1))
    gaze_c = np.einsum("nij,nj->ni", R_cw, gaze_w - T_eye[:, :3, 3])
    raw, true_c, noisy_c = eye_model.measure(gaze_c, rng_meas, with_bias=True)
    valid = plan.valid.copy()
    behind = gaze_c[:, 2] <= 0
    valid[behind] = False
    raw = np.where(valid[..., None], raw, 0.0)

    eye = EyeSamples(t_eye, np.arange(len(t_eye)) % 65536, raw, valid)
    log.info("%d eye samples at %g Hz, %d targets, %d markers", len(t_eye), rate, len(targets), len(world.markers))
    write_eye_csv(root / "eye.csv", eye)
    (root / "eye_serial.bin").write_bytes(encode_stream(t_eye, raw, valid))
    files["eye_samples"] = "eye.csv"
    files["eye_serial"] = "eye_serial.bin"
    labels = {}
    true_map = marker_map_dict(world.dictionary, world.marker_size_mm, world.markers, labels)
    write_marker_map(root / "markers.json", true_map)
    write_marker_map(root / "truth" / "markers.json", true_map)     # kept when markers.json is replaced or removed
    files["marker_map"] = "markers.json"
    files["truth_markers"] = "truth/markers.json"

    truth = root / "truth"
    _write_truth_lines(truth, t_eye, plan, gaze_w, T_eye, eye_model.centers, true_c, noisy_c, valid)
    _write_truth_targets(truth, targets, plan, t_eye, dur)
    files["truth_gaze"] = "truth/gaze.csv"
    files["truth_viewlines"] = "truth/viewlines.csv"
    files["truth_targets"] = "truth/targets.json"
    if world.moves:
        write_truth_moved_markers(truth / "moved_markers.json", _moved_truth(world))
        files["truth_moved_markers"] = "truth/moved_markers.json"
    video, n_frames = _write_scene_video(root, scn, camera, world, motion, noise, tick)
    files["scene_video"] = video
    files["scene_timestamps"] = "scene_timestamps.csv"
    files["truth_head_poses"] = "truth/head_poses.csv"
    manifest["n_frames"] = n_frames
    manifest["n_eye_samples"] = len(t_eye)


def _write_truth_lines(truth: Path, t_eye, plan, gaze_w, T_eye, centers_head, true_c, noisy_c, valid) -> None:
    """truth/gaze.csv (the gazed point, each eye's centre, true and measured direction, world frame)
    and truth/viewlines.csv (the measured lines of the samples that fixate a target).

    Args:
        t_eye: (N,) sample times, s.  plan: the gaze plan (target, phase per sample).
        gaze_w: (N, 3) gazed points, world, mm.  T_eye: (N, 4, 4) ``T_world_from_head`` per sample.
        centers_head: (2, 3) eye centres, head frame, mm.
        true_c, noisy_c: (N, 2, 3) true and measured directions, head frame.  valid: (N, 2) bool.
    """
    centers_w = np.einsum("nij,ej->nei", T_eye[:, :3, :3], centers_head) + T_eye[:, None, :3, 3]
    true_w = np.einsum("nij,nej->nei", T_eye[:, :3, :3], true_c)
    noisy_w = np.einsum("nij,nej->nei", T_eye[:, :3, :3], noisy_c)
    cols = {"t": t_eye, "target": plan.target, "phase": plan.phase,
            "gaze_x": gaze_w[:, 0], "gaze_y": gaze_w[:, 1], "gaze_z": gaze_w[:, 2]}
    for e, side in enumerate(("left", "right")):
        for k, ax in enumerate("xyz"):
            cols[f"{side}_o{ax}"] = centers_w[:, e, k]
        for k, ax in enumerate("xyz"):
            cols[f"{side}_true_d{ax}"] = true_w[:, e, k]
        for k, ax in enumerate("xyz"):
            cols[f"{side}_meas_d{ax}"] = noisy_w[:, e, k]
    write_table(truth / "gaze.csv", cols)
    use = (plan.target >= 0) & valid.any(axis=1)
    nan = np.full((len(t_eye), 3), np.nan)
    samples = BinocularSamples.from_arrays(
        t_eye, centers_w[:, 0], np.where(valid[:, :1], noisy_w[:, 0], nan),
        centers_w[:, 1], np.where(valid[:, 1:], noisy_w[:, 1], nan))
    write_viewlines_csv(truth / "viewlines.csv", samples.select(np.flatnonzero(use)), plan.target[use])


def _write_truth_targets(truth: Path, targets, plan, t_eye, dur: float) -> None:
    """truth/targets.json: each target's name, fixation spans (s) and position (or path, mm)."""
    tg_out = []
    for k, tg in enumerate(targets):
        sel = np.flatnonzero(plan.target == k)
        spans = np.split(sel, np.flatnonzero(np.diff(sel) > 1) + 1) if len(sel) else []
        entry = {"index": k, "name": tg.name, "moving": tg.moving,
                 "fixations_s": [[float(t_eye[s[0]]), float(t_eye[s[-1]])] for s in spans if len(s)]}
        if tg.moving:
            ts = np.linspace(0, dur, int(dur * 10) + 1)
            entry["path_t_s"] = ts.tolist()
            entry["path_mm"] = tg.path(ts).tolist()
        else:
            entry["position_mm"] = tg.at(0.0).tolist()
        tg_out.append(entry)
    write_truth_targets(truth / "targets.json", tg_out)


def _moved_truth(world) -> list[dict]:
    """truth/moved_markers.json's entries: each moved marker's id, time, the move in its own frame
    (``world.moved_pose``'s shift and turn), both poses and both sets of corners."""
    out = []
    for i, m in sorted(world.moves.items()):
        T_old_from_new = np.linalg.inv(m.T_world_from_marker_before) @ m.T_world_from_marker_after
        out.append({"id": i, "at_s": m.at_s, "shift_mm": T_old_from_new[:3, 3].round(9).tolist(),
                    "turn_deg": round(float(np.degrees(np.arctan2(T_old_from_new[1, 0], T_old_from_new[0, 0]))), 9),
                    "T_world_from_marker_before": m.T_world_from_marker_before.tolist(),
                    "T_world_from_marker_after": m.T_world_from_marker_after.tolist(),
                    "corners_before_mm": world.marker_corners()[i].tolist(),
                    "corners_after_mm": world.marker_corners(m.at_s)[i].tolist()})
    return out


def _write_scene_video(root: Path, scn: dict, camera: Camera, world, motion, noise, tick) -> tuple[str, int]:
    """The scene video, scene_timestamps.csv and truth/head_poses.csv (with the markers in view);
    returns the video's file name and the frame count."""
    fps = float(scn["camera"]["fps"])
    n_frames = int(round(float(scn["duration_s"]) * fps))
    t_frames = np.arange(n_frames) / fps
    T_frames = motion.poses(t_frames)
    codec = scn["camera"]["codec"]
    video = root / f"scene{VIDEO_EXT[codec]}"
    log.info("rendering %d frames of %dx%d to %s", n_frames, *camera.image_size, video.name)
    writer = open_video_writer(video, codec, fps, camera.image_size, is_color=False, refused=(
        f"cannot write {codec} video {video}: OpenCV's FFMPEG backend refused it; try --scenario with camera.codec "
        "MJPG"))
    visible = np.zeros(n_frames, int)
    corners = world.marker_corners()
    try:
        for i, t in enumerate(t_frames):
            writer.write(_render_frame(camera, world, lambda s: motion.poses([s])[0], t, noise, scn))
            visible[i] = _count_visible(camera, T_frames[i], world.marker_corners(t) if world.moves else corners)
            tick()
    finally:
        writer.release()
    write_frame_times(root / "scene_timestamps.csv", np.arange(n_frames), t_frames)
    write_poses_csv(root / "truth" / "head_poses.csv", t_frames, np.arange(n_frames), T_frames,
                    {"n_markers": visible})
    return video.name, n_frames


def _count_visible(camera: Camera, T_world_from_cam, corners: dict) -> int:
    """Markers whose four corners are in front of the camera and inside the image."""
    T = np.linalg.inv(T_world_from_cam)
    w, h = camera.image_size
    n = 0
    for c in corners.values():
        p = (T[:3, :3] @ c.T).T + T[:3, 3]
        if np.all(p[:, 2] > 50):
            px = camera.project(p)
            n += bool(np.all((px >= 0) & (px < [w, h])))
    return n
