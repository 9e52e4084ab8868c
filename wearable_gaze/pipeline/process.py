"""``wearable-gaze process``: a recorded session in, fixated 3D targets out (docs/processing.md).

Steps, each skipped when its inputs and settings are unchanged since the last run (``force``
redoes them): camera calibration, eye calibration, head tracking, view lines, segmentation and
estimation, plots and report. A step that cannot run records why; the steps that do not depend
on it still run, and whatever was computed is kept. A failed step invalidates every step after
it: their outputs from an earlier run are removed, so no file in the output folder is ever an
older run's result presented as this one's.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from pathlib import Path

from estimator.segments import SegmentConfig
from estimator.slippage import seen_bias
from tracking.timeline import MAX_POSE_GAP_S

from ..errors import UserError
from ..formats.aois import read_aois
from ..formats.atomic import remove_temporaries
from ..formats.board import BOARD_FILE, read_board
from ..formats.camera import load_camera
from ..formats.devices.common import read_import_report
from ..formats.eye_rays import read_eye_rays
from ..formats.eye_samples import read_eye_csv
from ..formats.eyes import load_eyes, write_eyes
from ..formats.jsonio import load_json, write_json
from ..formats.markermap import load_marker_map
from ..formats.person import person_correction_deg, read_person
from ..formats.poses import read_poses_csv, write_poses_csv
from ..formats.session import MANIFEST, load_session
from ..formats.sfmmap import FEATURES as SFM_FEATURES
from ..formats.sfmmap import MAP_JSON as SFM_JSON
from ..formats.sfmmap import load_sfm_map
from ..formats.targets import read_targets
from ..formats.viewlines import read_viewlines_csv, write_viewlines_csv
from ..formats.walls import read_walls
from .aoi import aoi_outlines, aoi_step, mesh_paths
from .calibrate import (
    calibrate_camera_files,
    calibrate_eyes,
    correct_head_lines,
    head_lines_to_world,
    head_view_lines,
    read_eye_recordings,
    view_lines,
)
from .device import device_comparison, device_points, device_poses, report_notes, still_head_poses, world_words
from .errorbudget import depth_assumption, pose_model, session_bias, session_prior, targets_bias_note, with_bias
from .export import export_files, write_fixations_step
from .fixations import find_targets, write_targets_step
from .live_replay import replay_recording
from .mapping import build_map_files
from .process_options import applicable, check_map_options, report_truth, truth_frame
from .report import OverlayInputs, load_truth, session_title, write_report
from .segmentation import segment_view_lines
from .steps import GOOD, OTHER_FILES, OUTPUTS, ProcessResult, Steps
from .track import frame_times, track_video
from .truth_match import TruthFrame
from .types import Poses, Target

log = logging.getLogger(__name__)

BUILT_MAP = "built_map.json"
"""The map ``--build-map`` builds from the session's video, in the output folder."""

@dataclass(frozen=True)
class _Settings:
    method: str
    sigma_deg: float
    overlay: bool
    report: bool
    track_every: int
    segment_config: SegmentConfig
    person: Path | None = None
    build_map: tuple | None = None      # (marker side mm, dictionary) to build a map from the video
    sfm_map: Path | None = None         # a markerless map folder to localise the video's frames in
    overlay_video: bool = False         # the report also writes the full-resolution overlay_full.mp4
    map_kind: str = "session"           # the map tracked in: session, given, built, markerless
    aois: Path | None = None            # an AOI file (docs/aois.md): the AOI step runs
    aoi_specs: tuple = ()               # ... its areas, read once (``formats.aois.read_aois``)


@dataclass(frozen=True)
class _SessionFiles:
    """The session's files, resolved once from its manifest (None: the session has none)."""

    root: Path
    camera_views: Path
    eye_calibration: Path
    has_recording: bool
    video: Path | None
    markers: Path | None
    stamps: Path | None
    eye_samples: Path | None
    eye_rays: Path | None = None            # an imported session: the device's rays, head frame
    head_poses: Path | None = None          # ... the device's head poses
    device_gaze: Path | None = None         # ... the device's own 3D gaze (comparison only)
    pose_source: str | None = None          # ... 'device', 'scene_video' or 'still_head'
    eye_rate_hz: float | None = None
    import_report: Path | None = None
    clock_offset_s: float = 0.0             # ... the device's clock at session time 0, s
    truth_targets: Path | None = None       # a simulated session's truth, shown in the report
    truth_head_poses: Path | None = None
    truth_map: Path | None = None           # ... its true marker map (the truth's frame)
    truth_moved: Path | None = None         # ... the markers moved during it
    live_poses: Path | None = None          # a live --device recording: the pose each sample took live

    @classmethod
    def of(cls, s) -> _SessionFiles:
        files = s.manifest["files"]
        return cls(s.root, s.root / files.get("camera_views", "calibration/camera"),
                   s.root / files.get("eye_calibration", "calibration/eye"), s.manifest.get("has_recording", True),
                   s.path("scene_video"), s.path("marker_map"), s.path("scene_timestamps"), s.path("eye_samples"),
                   s.path("eye_rays"), s.path("head_poses"), s.path("device_gaze"),
                   s.manifest.get("source", {}).get("pose_source"), s.manifest.get("eye_rate_hz"),
                   s.path("import_report"), float(s.manifest.get("source", {}).get("clock_offset_s", 0.0)),
                   s.path("truth_targets"), s.path("truth_head_poses"),
                   s.path("truth_markers") or (s.path("truth_targets") and s.path("marker_map")),
                   s.path("truth_moved_markers"), s.path("live_poses"))


class _Values:
    """The session's inputs and the steps' outputs as values, each read once, when a step first
    needs it: from the session, or from the file a step wrote or was given (what a cached step
    leaves: a run gives the same results whether the steps before it ran or were cached)."""

    def __init__(self, f: _SessionFiles, cam_path: Path, eyes_path: Path, out: Path):
        self._values = {}
        self._load = {"camera": lambda: load_camera(cam_path), "eyes": lambda: load_eyes(eyes_path),
                      "eye_samples": lambda: read_eye_csv(f.eye_samples)[0],
                      "eye_rays": lambda: read_eye_rays(f.eye_rays),
                      "marker_map": lambda: load_marker_map(f.markers or out / BUILT_MAP),   # given, or built
                      "poses": lambda: Poses(*read_poses_csv(out / "poses.csv")),
                      "targets": lambda: [Target.from_row(r) for r in read_targets(out / "targets.json")]}

    def __getitem__(self, key: str):
        if key not in self._values:
            self._values[key] = self._load[key]()
        return self._values[key]

    def set(self, key: str, value) -> None:
        self._values[key] = value


def process_session(session, out=None, method: str = "voxel", camera=None, eyes=None, force: bool = False,
                    sigma_deg: float = 1.0, overlay: bool = True, report: bool = True, track_every: int = 2,
                    segment_config: SegmentConfig | None = None, progress_factory=None, person=None,
                    build_map: tuple | None = None, sfm_map=None, overlay_video: bool = False, rerun: str | None = None,
                    rerun_frames: int = 0, markers=None, aois=None) -> ProcessResult:
    """Process one session folder (docs/session.md) into ``out`` (default SESSION/processed).

    Args:
        session: the session folder.
        method: estimator for each target ('voxel', 'ml', 'paper', 'lse').
        camera, eyes: calibration files to use instead of calibrating from the session.
        force: redo every step.
        sigma_deg: angular noise of a view line assumed by the estimators.
        overlay, report: write the overlay video and report.html.
        track_every: track one frame in this many, SLERP the rest (2: 15 poses a second at 30
            fps, far finer than head motion; 1 tracks every frame).
        segment_config: fixation segmentation settings (default ``SegmentConfig()``).
        progress_factory: name -> context manager yielding a progress(done, total) callback.
        person: a person.json (``learn-bias``) whose per-eye correction the view lines get.
        build_map: (marker side, mm; dictionary name): a map built from the session's own scene
            video (``pipeline.mapping``, written as built_map.json) before tracking, used in place
            of the session's map if it has one (a note says so).
        sfm_map: a markerless map folder (``map --markerless``): the scene video's frames are
            localised in it (``tracking.localise``) instead of tracked by the session's markers.
        overlay_video: the report also writes overlay_full.mp4, the overlay at full resolution.
        markers: a marker map (``map``) to track the video in, in place of the session's.
        rerun: also log the results to rerun (``pipeline.rerun_view``): an .rrd file, a viewer's
            address, or 'spawn'; ``rerun_frames``: with it, one scene frame in this many (0: none).
        aois: an AOI file (docs/aois.md): the AOI step writes its tables (``pipeline.aoi``).

    Returns:
        ProcessResult: ``targets`` holds only what this run estimated; ``problems`` says what
        failed, ``status`` what ran; ``exit_status`` is 2 when no target could be estimated, 3
        when targets were but a step failed (``outcome`` 'partial').

    Raises:
        UserError: the session cannot be read; contradicting options, a bad map (``check_map_options``).
    """
    s = load_session(session)
    markers = check_map_options(markers, build_map, sfm_map, overlay, overlay_video)       # before any step
    person = Path(person) if person is not None else None
    correction = person_correction_deg(read_person(person)) if person else None       # checked before any step
    aoi_specs = tuple(read_aois(aois)) if aois is not None else ()                   # ... read once
    out = _output_folder(s.root, out, s.manifest["files"].values())
    res = ProcessResult(out)
    camera, eyes = _recorded_calibrations(s, camera, eyes)
    steps = Steps(out, force, res, progress_factory, [p for p in (camera, eyes, markers) if p is not None])
    for p in remove_temporaries(out, [f for fs in OUTPUTS.values() for f in fs] + list(OTHER_FILES)):
        log.warning("removed %s, a temporary file left by an earlier run that was stopped", p)
    if s.manifest.get("complete") is False:
        res.problems.append(_cut_short(s))
    f = _SessionFiles.of(s)
    if segment_config is None:          # the window follows the eye rate: 8 samples at 60 Hz, 2 at 10 Hz
        segment_config = SegmentConfig.for_rate(f.eye_rate_hz) if f.eye_rate_hz else SegmentConfig()
    cfg = _Settings(method, sigma_deg, overlay, report, track_every, segment_config, person,
                    None if build_map is None else (float(build_map[0]), str(build_map[1])),
                    None if sfm_map is None else Path(sfm_map), overlay_video, aois=aois and Path(aois),
                    aoi_specs=aoi_specs)
    f, cfg, res.summary["notes"] = applicable(f, cfg, markers, eyes is not None, rerun_frames)
    if correction is not None:
        res.summary["person"] = {"file": str(cfg.person), "correction_deg": correction.tolist()}
    cam_path = Path(camera) if camera else out / "camera.json"
    eyes_path = Path(eyes) if eyes else out / "eyes.json"
    vals = _Values(f, cam_path, eyes_path, out)
    try:
        _calibration_steps(f, steps, vals, cam_path if camera else None, eyes_path if eyes else None, out)
        if f.has_recording:
            _recording_steps(f, out, steps, res, vals, cam_path, eyes_path, cfg, correction)
        else:
            res.problems.append("session: a calibration-only session has no recording to process")
            for name in ("tracking", "viewlines", "targets", "export", "report"):
                steps.status[name] = "no_recording"
    except BaseException:
        steps.finish(aborted=True)
        raise
    steps.finish()
    if rerun is not None:
        _view_in_rerun(rerun, rerun_frames, res, s, f, out, cam_path)
    return _finish(res, s, out, method)


def _recorded_calibrations(s, camera, eyes) -> tuple:
    """(camera, eyes): the files given, else those a live recording carries (the calibrations it
    ran with: a ``camera``/``eyes`` file without the recordings to calibrate from), else None."""
    files = s.manifest["files"]
    if camera is None and "camera" in files and "camera_views" not in files:
        camera = s.root / files["camera"]
    if eyes is None and "eyes" in files and "eye_calibration" not in files:
        eyes = s.root / files["eyes"]
    return camera, eyes


def _cut_short(s) -> str:
    """The problem line of a session whose recording was cut short (``complete: false``)."""
    counts = ", ".join(f"{s.manifest[k]} {w}" for k, w in (("n_frames", "frames"), ("n_eye_samples", "eye samples"))
                       if isinstance(s.manifest.get(k), int))
    return (f"session: {s.root / 'session.json'} says the recording was cut short (complete: "
            f"false{'; ' + counts + ' saved' if counts else ''}); processing what was recorded")


def _view_in_rerun(rerun: str, frames_every: int, res: ProcessResult, s, f: _SessionFiles, out: Path,
                   cam_path: Path) -> None:
    """The results logged to rerun (``pipeline.rerun_view``); a viewer that cannot be reached is a
    problem, the results are kept."""
    from .rerun_view import view_processed  # rerun-sdk: an optional extra
    try:
        res.summary["rerun"] = view_processed(rerun, out, res.found or None, cam_path, f.markers or out / BUILT_MAP,
                                              s.path("truth_targets"), s.path("truth_head_poses"), f.video, f.stamps,
                                              frames_every, TruthFrame.from_record(res.summary.get("truth_frame")))
    except UserError as exc:
        res.problems.append(f"rerun: {exc}")


def _calibration_steps(f: _SessionFiles, steps: Steps, vals: _Values, camera: Path | None, eyes: Path | None,
                       out: Path) -> None:
    """1. camera, 2. eyes: calibrated from the session into OUT, or the files given (``camera``,
    ``eyes``) checked once and kept as values. An imported session needs neither: the device
    calibrated its eyes, and its camera file (if any) is taken as given."""
    cam_path, eyes_path = camera or out / "camera.json", eyes or out / "eyes.json"
    if f.eye_rays is not None:
        if camera is not None:
            steps.external("camera", cam_path, lambda p: vals.set("camera", load_camera(p)))
        else:
            steps.status["camera"] = "device"
        steps.status["eyes"] = "device"
        return
    if camera is None:
        board_file = f.camera_views / BOARD_FILE

        def do_camera(cb):
            if not board_file.is_file():
                raise UserError(f"{board_file}: no camera-calibration recording in the session; pass --camera "
                                "camera.json")
            board = read_board(f.camera_views)
            calibrate_camera_files(board.views, board.spec, cam_path, progress=cb)
        steps.run("camera", [f.camera_views], {}, do_camera)
    else:
        steps.external("camera", cam_path, lambda p: vals.set("camera", load_camera(p)))
    if eyes is None:
        def do_eyes(cb):
            cam = vals["camera"]
            write_eyes(eyes_path, calibrate_eyes(read_eye_recordings(read_walls(f.eye_calibration)), cam, progress=cb))
        steps.run("eyes", [f.eye_calibration, cam_path], {}, do_eyes)
    else:
        steps.external("eyes", eyes_path, lambda p: vals.set("eyes", load_eyes(p)))


def _recording_steps(f: _SessionFiles, out: Path, steps: Steps, res: ProcessResult, vals: _Values, cam_path: Path,
                     eyes_path: Path, cfg: _Settings, correction=None) -> None:
    """3. head tracking, 4. view lines (with the per-person ``correction``, if any), 5. fixations
    and targets, 6. plots, overlay, report."""
    poses_path = out / "poses.csv"
    _tracking_step(f, steps, vals, cam_path, poses_path, cfg)
    frame = truth_frame(f, cfg, out / BUILT_MAP, lambda: vals["marker_map"]) if (
        steps.status.get("tracking") in GOOD) else None
    if frame is not None:
        res.summary["truth_frame"] = frame.record()
    raw_vl, counts_path = out / ".viewlines_unsegmented.csv", out / ".viewlines_counts.json"

    def do_viewlines(cb):
        if f.eye_rays is not None:
            gap = 0.0 if f.live_poses is not None else MAX_POSE_GAP_S    # a live recording: only the poses live gave
            result = head_lines_to_world(vals["eye_rays"], vals["poses"], gap, poses_path, correction)
        else:
            result = view_lines(vals["eye_samples"], vals["eyes"], vals["poses"], MAX_POSE_GAP_S, poses_path,
                                correction)
        write_viewlines_csv(raw_vl, result.samples)
        write_json(counts_path, result.counts)
    eye_inputs = [f.eye_rays] if f.eye_rays is not None else [f.eye_samples, eyes_path]
    person = {} if correction is None else {"person": correction.tolist()}
    if steps.run("viewlines", eye_inputs + [poses_path], person, do_viewlines):
        res.summary["viewlines"] = load_json(counts_path, "viewlines-counts")     # as written: steps.changed_output

    rep = read_import_report(f.import_report) if f.import_report is not None else None
    prior = session_prior(f.eye_rays is not None, eyes_path, rep)
    base = pose_model(f.eye_rays is None or f.pose_source not in ("device", "still_head"))

    def do_targets(cb):
        samples = read_viewlines_csv(raw_vl)[0].samples
        labels = segment_view_lines(samples, cfg.segment_config)
        budget: dict | None = session_bias(prior, seen_bias(samples, labels))    # the bias sized from the lines
        if f.live_poses is not None:          # a live recording: the targets live published (live_replay.py)
            result, budget = replay_recording(vals["eye_rays"], f.live_poses, cfg.method), None
        else:
            result = find_targets(samples, labels, cfg.method, cfg.sigma_deg, cb, with_bias(base, budget))
        write_targets_step(out, result, cfg.method, budget, depth_assumption(rep, f.pose_source))
        write_fixations_step(out, result)
        if f.device_gaze is not None:
            device_comparison(f.device_gaze, samples, result.targets, vals["poses"], out / "device_comparison.csv")
        vals.set("targets", result.targets)
    params = {"method": cfg.method, "sigma": cfg.sigma_deg, "seg": cfg.segment_config.__dict__,
              "error_model": dataclasses.asdict(base), "bias_prior": dataclasses.asdict(prior), "bias": "seen"} | (
                  {"replay": "live"} if f.live_poses is not None else {})     # a folder processed before is redone
    if steps.run("targets", [raw_vl], params, do_targets):
        res.found = vals["targets"]
        if not any(t.fixated for t in res.found):        # a too-near point is no target (target_status.FIXATED)
            n = res.summary.get("viewlines", {}).get("written", "the")
            res.problems.append(f"targets: no target could be estimated from {n} view lines (no fixation of "
                                f"{cfg.segment_config.min_fixation_s:g} s or more gave an estimate or a direction)")
    _export_step(f, out, steps, vals, cam_path, eye_inputs, correction)
    if cfg.aois is not None:
        _aoi_step(f, out, steps, cfg.aois, cfg.aoi_specs)
    if cfg.report:
        _report_step(f, out, steps, vals, eyes_path, cfg, frame)


def _aoi_step(f: _SessionFiles, out: Path, steps: Steps, aois: Path, specs: tuple) -> None:
    """7. the areas of interest (``pipeline.aoi``): their tables and plot, marker areas placed by
    the map the video was tracked in."""
    built = out / BUILT_MAP
    marker_map = f.markers if f.markers is not None else built if built.is_file() else None
    inputs = [aois, *mesh_paths(specs), *(out / n for n in ("fixations.csv", "viewlines.csv", "targets.json"))]
    steps.run("aoi", inputs + ([marker_map] if marker_map else []), {},
              lambda cb: aoi_step(out, specs, out, marker_map))


def _export_step(f: _SessionFiles, out: Path, steps: Steps, vals: _Values, cam_path: Path, eye_inputs: list,
                 correction=None) -> None:
    """6. exports for other tools: gaze.csv (per eye sample) and targets.ply (``pipeline.export``);
    the 2D gaze needs the scene camera's calibration."""
    cam_ok = steps.status.get("camera") in GOOD and cam_path.is_file()

    def do_export(cb):
        head = vals["eye_rays"] if f.eye_rays is not None else head_view_lines(vals["eye_samples"], vals["eyes"])
        head = correct_head_lines(head, correction) if correction is not None else head
        export_files(out, head, vals["poses"], vals["targets"], vals["camera"] if cam_ok else None, f.clock_offset_s)
    inputs = [out / n for n in ("viewlines.csv", "target_labels.npy", "estimates.csv", "targets.json",
                                "target_paths.csv", "poses.csv")]
    params = {"camera": cam_ok, "clock_offset_s": f.clock_offset_s,
              "person": None if correction is None else correction.tolist()}
    steps.run("export", inputs + eye_inputs + ([cam_path] if cam_ok else []), params, do_export)


def _tracking_step(f: _SessionFiles, steps: Steps, vals: _Values, cam_path: Path, poses_path: Path,
                   cfg: _Settings) -> None:
    """3. head poses: the device's, a still head's, or tracked in the scene video."""
    if f.eye_rays is not None and f.pose_source == "device":
        steps.run("tracking", [f.head_poses], {"source": "device"}, lambda cb: device_poses(f.head_poses, poses_path))
        return
    if f.eye_rays is not None and f.live_poses is not None:          # a live recording: the poses it used
        steps.run("tracking", [f.live_poses], {"source": "live"}, lambda cb: device_poses(f.live_poses, poses_path))
        return
    if f.eye_rays is not None and f.pose_source == "still_head":
        steps.run("tracking", [f.eye_rays], {"source": "still_head"},
                  lambda cb: still_head_poses(vals["eye_rays"].t_s, poses_path))
        return

    def do_tracking(cb):
        cam, mm = vals["camera"], vals["marker_map"]
        poses = track_video(f.video, cam, mm, frame_times(f.video, f.stamps), cfg.track_every, cb)
        write_poses_csv(poses_path, poses.t, poses.frame, poses.T_world_from_cam, poses.columns)
    if cfg.sfm_map is not None and f.video is not None:
        def localise(cb):
            poses = track_video(f.video, vals["camera"], load_sfm_map(cfg.sfm_map)[0], frame_times(f.video, f.stamps),
                                cfg.track_every, cb)
            write_poses_csv(poses_path, poses.t, poses.frame, poses.T_world_from_cam, poses.columns)
        steps.run("tracking", [f.video, cam_path, cfg.sfm_map / SFM_JSON, cfg.sfm_map / SFM_FEATURES, f.stamps],
                  {"every": cfg.track_every, "map": "markerless"}, localise)
    elif f.markers is None and cfg.build_map is not None and f.video is not None:
        def build_and_track(cb):                   # vals["marker_map"] then reads the map built here
            build_map_files([f.video], cam_path, poses_path.parent / BUILT_MAP, cfg.build_map[1], cfg.build_map[0],
                            progress=cb)
            do_tracking(cb)
        steps.run("tracking", [f.video, cam_path, f.stamps], {"every": cfg.track_every, "build_map": cfg.build_map},
                  build_and_track)
    elif f.markers is None:
        fix = ("re-import it with --markers markers.json" if f.eye_rays is not None else
               "build a map from its video with --build-map MM, or localise it in a markerless map with "
               "--map sfm/, or track it with 'wearable-gaze track --reference' and go on from those poses "
               "with 'wearable-gaze viewlines --poses' (docs/processing.md, Step by step)")
        steps.fail("tracking", f"the session has no marker map (markers.json); {fix}")
    else:
        steps.run("tracking", [f.video, cam_path, f.markers, f.stamps], {"every": cfg.track_every}, do_tracking)


def _report_step(f: _SessionFiles, out: Path, steps: Steps, vals: _Values, eyes_path: Path, cfg: _Settings,
                 frame=None) -> None:
    has_map = f.markers is not None or (out / BUILT_MAP).is_file()

    def overlay_inputs() -> OverlayInputs:
        return OverlayInputs(vals["camera"], vals["eyes"] if eyes_path.is_file() else None, vals["eye_samples"],
                             vals["marker_map"] if has_map else None, f.video)
    cam_ok = steps.status.get("camera") in GOOD and f.eye_samples is not None   # the overlay draws raw eye samples
    inputs = [out / "targets.csv", out / "viewlines.csv", out / "poses.csv"] + ([f.video] if cfg.overlay and f.video
                                                                                 else [])
    extra = [p for p in (f.import_report, f.truth_targets, f.truth_head_poses, f.markers) if p]
    extra += [cfg.sfm_map / SFM_FEATURES] if cfg.sfm_map is not None else []
    extra += [cfg.aois, *mesh_paths(cfg.aoi_specs)] if cfg.aois is not None else []      # the 3D view's areas

    def do_report(cb):
        truth, truth_notes = report_truth(load_truth(f.truth_targets, f.truth_head_poses), frame)
        points = load_sfm_map(cfg.sfm_map)[0].points_world if cfg.sfm_map is not None else device_points(f.root)
        mm = vals["marker_map"] if has_map else None
        notes = report_notes(f.pose_source, f.eye_rays is not None and cfg.overlay, f.import_report)
        notes += targets_bias_note(out / "targets.json")
        write_report(out, session_title(f.root), overlay_inputs if cfg.overlay and cam_ok else None, cb,
                     notes + truth_notes, truth, mm, cfg.overlay_video, points,
                     world=world_words(f.pose_source, cfg.map_kind), aois=aoi_outlines(cfg.aoi_specs, mm))
    steps.run("report", inputs + extra, {"overlay": cfg.overlay, "pose_source": f.pose_source}
              | ({"overlay_video": True} if cfg.overlay_video else {}) | ({"aois": True} if cfg.aois else {})
              | ({"truth_frame": frame.record()} if frame else {}), do_report)


def _output_folder(root: Path, out, inputs=()) -> Path:
    """The output folder (``out``, default ROOT/processed), made; one that is a session, or in one
    of its input folders (the folder of a manifest's file, ``inputs``, below ``root``), is refused:
    process would mix its outputs into that session, or into that folder's inputs.

    Raises:
        UserError: ``out`` holds a session manifest, or is in a folder of the session's inputs.
    """
    out = Path(out) if out is not None else root / "processed"
    if (out / MANIFEST).is_file():
        raise UserError(f"-o {out}: is a session folder (it has {MANIFEST}); process would mix its outputs into that "
                        "session: choose a new folder (the default is SESSION/processed)")
    for rel in inputs:
        folder = (root / rel) if (root / rel).is_dir() else (root / rel).parent
        if folder.resolve() != root.resolve() and out.resolve().is_relative_to(folder.resolve()):
            raise UserError(f"-o {out}: is in the session's input folder {folder}; process would write among its "
                            "inputs: choose a folder outside it (the default is SESSION/processed)")
    out.mkdir(parents=True, exist_ok=True)
    return out


def _finish(res: ProcessResult, s, out: Path, method: str) -> ProcessResult:
    summary = {"version": 1, "session": str(s.root), "method": method, "outcome": res.outcome,
               "targets": res.targets,
               "problems": res.problems, "failed_steps": res.failed, "steps_not_done": res.not_done,
               "removed_outputs": res.removed, "steps_skipped": res.skipped,
               "timings_s": {k: round(v, 3) for k, v in res.timings.items()}}
    summary.update(res.summary)
    if res.status.get("report") in GOOD and (out / "report.html").is_file():
        summary["report"] = str(out / "report.html")
    res.summary = summary
    write_json(out / "summary.json", summary)
    return res
