"""``wearable-gaze process``: a recorded session in, fixated 3D targets out (docs/processing.md).

Steps, each skipped when its inputs and settings are unchanged since the last run (``force``
redoes them): camera calibration, eye calibration, head tracking, view lines, segmentation and
estimation, exports, areas of interest (when asked for), plots and report. A step that cannot run
records why; the steps that do not depend on it still run, and whatever was computed is kept. A
failed step invalidates every step after it: their outputs from an earlier run are removed, so no
file in the output folder is ever an older run's result presented as this one's.

Each step is a plain function, ``run_<step>(conf, inputs, progress)`` (``pipeline.process.session_steps``),
of its frozen configuration (``pipeline.process.stepconf``, derived from the one ``ProcessConfig`` built
here from the options) and its inputs as values. ``SessionCache`` is the one explicit cache of
values: each read once, only when a step that runs needs it. ``stepcache.Steps`` runs a step or
skips it (its fingerprint), and keeps the output folder consistent.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from functools import partial
from pathlib import Path

from estimator.segments import SegmentConfig
from tracking.timeline import MAX_POSE_GAP_S

from ...errors import UserError
from ...formats.aois import read_aois
from ...formats.atomic import remove_temporaries
from ...formats.devices.common import read_import_report
from ...formats.jsonio import load_json, write_json
from ...formats.marker_detections import NAME as DETECTIONS
from ...formats.person import person_correction_deg, read_person
from ...formats.session import MANIFEST, load_session
from ...formats.sfmmap import FEATURES as SFM_FEATURES
from ...formats.sfmmap import MAP_JSON as SFM_JSON
from ..report.truth_match import TruthFrame
from ..steps.aoi import AoiConfig, mesh_paths
from ..steps.device import world_words
from ..steps.errorbudget import depth_assumption, pose_model, session_prior
from .options import applicable, check_map_options, truth_frame
from .session_cache import SessionCache, SessionFiles
from .session_steps import (
    BUILT_MAP,
    AoiFolderInputs,
    CameraInputs,
    TrackingInputs,
    run_aoi,
    run_camera,
    run_export,
    run_eyes,
    run_report,
    run_targets,
    run_tracking,
    run_viewlines,
)
from .stepcache import GOOD, OTHER_FILES, OUTPUTS, ProcessResult, Steps
from .stepconf import CameraConfig, EyesConfig, ProcessConfig

log = logging.getLogger(__name__)


def process_session(session, out=None, method: str = "voxel", camera=None, eyes=None,
                    force: bool = False, sigma_deg: float = 1.0, overlay: bool = True,
                    report: bool = True, track_every: int = 2,
                    segment_config: SegmentConfig | None = None, progress_factory=None,
                    person=None, build_map: tuple | None = None, sfm_map=None,
                    overlay_video: bool = False, rerun: str | None = None, rerun_frames: int = 0,
                    markers=None, aois=None) -> ProcessResult:
    """Process one session folder (docs/session.md) into ``out`` (default SESSION/processed).

    Args:
        method, sigma_deg, overlay, report, track_every, segment_config, person, build_map,
            sfm_map, overlay_video, aois: the settings (``stepconf.ProcessConfig``, built here).
        camera, eyes, markers: files given in place of the camera and eye calibrations and of
            the session's marker map.
        force: redo every step. ``progress_factory``: name -> context manager yielding a
            progress(done, total) callback.
        rerun, rerun_frames: also log the results to rerun (``_view_in_rerun``).

    Returns:
        ProcessResult: this run's targets, what failed (``problems``) and what ran (``status``);
        ``exit_status`` 2: no target, 3: targets but a step failed (``outcome`` 'partial').

    Raises:
        UserError: the session cannot be read; contradicting options, a bad map, person or AOI
            file (``check_map_options``, ``_config``: all before any step).
    """
    s = load_session(session)
    markers = check_map_options(markers, build_map, sfm_map, overlay, overlay_video)
    conf = _config(method=method, sigma_deg=sigma_deg, overlay=overlay, report=report,
                   track_every=track_every, segment_config=segment_config, person=person,
                   build_map=build_map, sfm_map=sfm_map, overlay_video=overlay_video, aois=aois)
    camera, eyes = _recorded_calibrations(s, camera, eyes)
    res, steps = _start(s, out, force, progress_factory, [camera, eyes, markers])
    f, conf = _for_session(s, conf, markers, eyes is not None, rerun_frames, res)
    cache = SessionCache(f, res.out, _path(camera), _path(eyes))
    _run_steps(steps, cache, conf, res)
    if rerun is not None:
        _view_in_rerun(rerun, rerun_frames, res, s, f, cache.camera_path)
    return _finish(res, s, res.out, method)


def _config(person, build_map, sfm_map, aois, **settings) -> ProcessConfig:
    """``process_session``'s settings (``stepconf.ProcessConfig``), built once: the person's
    correction (``formats.person``) checked and the AOI file's areas read here."""
    person, aois = _path(person), _path(aois)
    correction = person_correction_deg(read_person(person)) if person is not None else None
    specs = tuple(read_aois(aois)) if aois is not None else ()
    return ProcessConfig(person=person, correction_deg=correction,
                         build_map=_map_to_build(build_map), sfm_map=_path(sfm_map), aois=aois,
                         aoi_specs=specs, **settings)


def _path(p) -> Path | None:
    return Path(p) if p is not None else None


def _map_to_build(build_map) -> tuple | None:
    """``--build-map``'s (marker side mm, dictionary), or None."""
    return None if build_map is None else (float(build_map[0]), str(build_map[1]))


def _start(s, out, force: bool, progress_factory, given: list) -> tuple[ProcessResult, Steps]:
    """The output folder made (``_output_folder``), cleared of an interrupted run's temporary
    files; the result, and the steps' runner, which never removes a file ``given`` (None: none)."""
    out = _output_folder(s.root, out, s.manifest["files"].values())
    res = ProcessResult(out)
    steps = Steps(out, force, res, progress_factory, [p for p in given if p is not None])
    for p in remove_temporaries(out, [f for fs in OUTPUTS.values() for f in fs] + list(OTHER_FILES)):
        log.warning("removed %s, a temporary file left by an earlier run that was stopped", p)
    if s.manifest.get("complete") is False:
        res.problems.append(_cut_short(s))
    return res, steps


def _for_session(s, conf: ProcessConfig, markers: Path | None, eyes_given: bool, rerun_frames: int,
                 res: ProcessResult) -> tuple[SessionFiles, ProcessConfig]:
    """The session's files and this run's settings for them (``ProcessConfig.for_session``,
    ``process_options.applicable``); the notes on options that cannot apply, and the person's
    correction, in the summary."""
    f = SessionFiles.of(s)
    conf = conf.for_session(f.eye_rate_hz)
    f, conf, res.summary["notes"] = applicable(f, conf, markers, eyes_given, rerun_frames)
    if conf.correction_deg is not None:
        res.summary["person"] = {"file": str(conf.person),
                                 "correction_deg": conf.correction_deg.tolist()}
    return f, conf


def _run_steps(steps: Steps, cache: SessionCache, conf: ProcessConfig, res: ProcessResult) -> None:
    """The steps in order, then every output that is not this run's removed (``Steps.finish``),
    also when one raises."""
    try:
        _calibration_steps(steps, cache)
        if cache.files.has_recording:
            _recording_steps(steps, cache, conf, res)
        else:
            res.problems.append("session: a calibration-only session has no recording to process")
            for name in ("tracking", "viewlines", "targets", "export", "report"):
                steps.status[name] = "no_recording"
    except BaseException:
        steps.finish(aborted=True)
        raise
    steps.finish()


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


def _view_in_rerun(rerun: str, frames_every: int, res: ProcessResult, s, f: SessionFiles,
                   cam_path: Path) -> None:
    """The results logged to rerun (``pipeline.report.rerun_view``): ``rerun`` is an .rrd file, a
    viewer's address, or 'spawn'; one scene frame in ``frames_every`` is shown (0: none). A viewer
    that cannot be reached is a problem, the results are kept."""
    from ..report.rerun_view import view_processed  # rerun-sdk: an optional extra
    out = res.out
    try:
        res.summary["rerun"] = view_processed(rerun, out, res.found or None, cam_path, f.markers or out / BUILT_MAP,
                                              s.path("truth_targets"), s.path("truth_head_poses"), f.video, f.stamps,
                                              frames_every, TruthFrame.from_record(res.summary.get("truth_frame")))
    except UserError as exc:
        res.problems.append(f"rerun: {exc}")


def _calibration_steps(steps: Steps, cache: SessionCache) -> None:
    """1. camera, 2. eyes: calibrated from the session into OUT, or the files given checked once
    and kept as values. An imported session needs neither: the device calibrated its eyes, and
    its camera file (if any) is taken as given."""
    f = cache.files
    if cache.camera_given is not None:
        steps.external("camera", cache.camera_path, lambda: cache.camera)
    elif f.eye_rays is not None:
        steps.status["camera"] = "device"
    else:
        steps.run("camera", [f.camera_views], {}, run_camera, CameraConfig(),
                  partial(CameraInputs, f.camera_views, cache.camera_path))
    if f.eye_rays is not None:
        steps.status["eyes"] = "device"
    elif cache.eyes_given is not None:
        steps.external("eyes", cache.eyes_path, lambda: cache.eyes)
    else:
        steps.run("eyes", [f.eye_calibration, cache.camera_path], {}, run_eyes, EyesConfig(),
                  cache.eyes_inputs)


def _recording_steps(steps: Steps, cache: SessionCache, conf: ProcessConfig,
                     res: ProcessResult) -> None:
    """3. head tracking, 4. view lines (with the person's correction, if any), 5. fixations and
    targets, 6. exports, 7. areas of interest (when asked for), 8. plots, overlay, report."""
    _tracking_step(steps, cache, conf)
    frame = _truth_frame(steps, cache, conf, res)
    _viewlines_step(steps, cache, conf, res)
    _targets_step(steps, cache, conf, res)
    _export_step(steps, cache, conf)
    if conf.aois is not None:
        _aoi_step(steps, cache, conf)
    if conf.report:
        _report_step(steps, cache, conf, frame)


def _tracking_step(steps: Steps, cache: SessionCache, conf: ProcessConfig) -> None:
    """3. head poses: the device's, a live recording's (the poses it used), a still head's, or
    tracked in the scene video: in a markerless map, in a map built from the video first, or in
    the marker map."""
    f, track, every = cache.files, conf.tracking_conf(), conf.track_every
    video = [f.video, cache.camera_path]
    if f.eye_rays is not None and (f.pose_source == "device" or f.live_poses is not None):
        device = f.pose_source == "device"
        source, given = ("device", f.head_poses) if device else ("live", f.live_poses)
        steps.run("tracking", [given], {"source": source}, run_tracking, track,
                  partial(TrackingInputs, cache.poses_path, head_poses=given))
    elif f.eye_rays is not None and f.pose_source == "still_head":
        steps.run("tracking", [f.eye_rays], {"source": "still_head"}, run_tracking, track,
                  cache.still_head_inputs)
    elif conf.sfm_map is not None and f.video is not None:
        sfm = [conf.sfm_map / SFM_JSON, conf.sfm_map / SFM_FEATURES]
        steps.run("tracking", video + sfm + [f.stamps], {"every": every, "map": "markerless"},
                  run_tracking, track, partial(cache.markerless_inputs, conf.sfm_map))
    elif f.markers is None and conf.build_map is not None and f.video is not None:
        params = {"every": every, "build_map": conf.build_map}
        if steps.run("tracking", video + [f.stamps], params, run_tracking, track,
                     cache.video_inputs) and "tracking" in steps.outputs:
            cache.marker_map = steps.outputs["tracking"].room        # the map built: not read again
    elif f.markers is None:
        steps.fail("tracking", f"the session has no marker map (markers.json); {_no_map_fix(f)}")
    else:
        steps.run("tracking", video + [f.markers, f.stamps], {"every": every}, run_tracking, track,
                  cache.marker_inputs)
    tracked = steps.outputs.get("tracking")
    if tracked is not None and tracked.poses is not None:    # tracked in this run: not read back
        cache.detections = tracked.poses.detections


def _no_map_fix(f: SessionFiles) -> str:
    """What to do about a session without a marker map."""
    if f.eye_rays is not None:
        return "re-import it with --markers markers.json"
    return ("build a map from its video with --build-map MM, or localise it in a markerless map "
            "with --map sfm/, or track it with 'wearable-gaze track --reference' and go on from "
            "those poses with 'wearable-gaze viewlines --poses' (docs/processing.md, Step by step)")


def _truth_frame(steps: Steps, cache: SessionCache, conf: ProcessConfig,
                 res: ProcessResult) -> TruthFrame | None:
    """A simulated session's truth moved into the world of the map tracked in
    (``process_options.truth_frame``), recorded in the summary; None: no tracking, or no move."""
    if steps.status.get("tracking") not in GOOD:
        return None
    frame = truth_frame(cache.files, conf, cache.out / BUILT_MAP, lambda: cache.marker_map)
    if frame is not None:
        res.summary["truth_frame"] = frame.record()
    return frame


def _viewlines_step(steps: Steps, cache: SessionCache, conf: ProcessConfig,
                    res: ProcessResult) -> None:
    """4. view lines in the world; their counts go into the summary, as written."""
    f = cache.files
    live = f.eye_rays is not None and f.live_poses is not None   # only the poses live gave: no gap
    vconf = conf.viewlines_conf(0.0 if live else MAX_POSE_GAP_S)
    paths = cache.eye_paths() + [cache.poses_path]
    if steps.run("viewlines", paths, conf.person_record(), run_viewlines, vconf,
                 cache.viewlines_inputs):                 # the counts as written: changed_output
        res.summary["viewlines"] = load_json(cache.viewline_counts, "viewlines-counts")


def _targets_step(steps: Steps, cache: SessionCache, conf: ProcessConfig,
                  res: ProcessResult) -> None:
    """5. fixations and targets, with the session's error model (``errorbudget``: the poses'
    error, the gaze-bias prior of the calibration or the device)."""
    f = cache.files
    rep = read_import_report(f.import_report) if f.import_report is not None else None
    prior = session_prior(f.eye_rays is not None, cache.eyes_path, rep)
    base = pose_model(f.eye_rays is None or f.pose_source not in ("device", "still_head"))
    tconf = conf.targets_conf(still_head=f.pose_source == "still_head")
    params = {"method": tconf.method, "sigma": tconf.sigma_deg, "seg": tconf.segment.__dict__,
              **({"merge_within_s": tconf.merge_within_s} if math.isfinite(tconf.merge_within_s) else {}),
              "error_model": dataclasses.asdict(base), "bias_prior": dataclasses.asdict(prior),
              "bias": "seen", **({"replay": "live"} if f.live_poses is not None else {})}
    inputs = partial(cache.targets_inputs, prior, base, depth_assumption(rep, f.pose_source))
    if not steps.run("targets", [cache.raw_viewlines], params, run_targets, tconf, inputs):
        return
    if "targets" in steps.outputs:                             # found in this run: not read back
        cache.targets = steps.outputs["targets"].targets
    res.found = cache.targets
    if not any(t.fixated for t in res.found):  # a too-near point is no target (target_status)
        n = res.summary.get("viewlines", {}).get("written", "the")
        res.problems.append(f"targets: no target could be estimated from {n} view lines (no "
                            f"fixation of {tconf.segment.min_fixation_s:g} s or more gave an "
                            "estimate or a direction)")


def _export_step(steps: Steps, cache: SessionCache, conf: ProcessConfig) -> None:
    """6. exports for other tools: gaze.csv (per eye sample) and targets.ply
    (``pipeline.steps.export``); the 2D gaze needs the scene camera's calibration."""
    cam_ok = steps.status.get("camera") in GOOD and cache.camera_path.is_file()
    paths = [cache.out / n for n in ("viewlines.csv", "target_labels.npy", "estimates.csv",
                                     "targets.json", "target_paths.csv", "poses.csv")]
    paths += cache.eye_paths() + ([cache.camera_path] if cam_ok else [])
    params = {"camera": cam_ok, "clock_offset_s": cache.files.clock_offset_s,
              "person": conf.person_record().get("person")}
    steps.run("export", paths, params, run_export, conf.export_conf(),
              partial(cache.export_inputs, cam_ok))


def _aoi_step(steps: Steps, cache: SessionCache, conf: ProcessConfig) -> None:
    """7. the areas of interest (``pipeline.steps.aoi``): their tables and plot, marker areas placed by
    the map the video was tracked in."""
    out, built = cache.out, cache.out / BUILT_MAP
    marker_map = cache.files.markers or (built if built.is_file() else None)
    paths = [conf.aois, *mesh_paths(conf.aoi_specs)]
    paths += [out / n for n in ("fixations.csv", "viewlines.csv", "targets.json")]
    paths += [marker_map] if marker_map else []
    steps.run("aoi", paths, {}, run_aoi, AoiConfig(),
              partial(AoiFolderInputs, out, conf.aoi_specs, marker_map))


def _report_step(steps: Steps, cache: SessionCache, conf: ProcessConfig,
                 frame: TruthFrame | None) -> None:
    """8. the plots, the overlay (drawn when the camera is calibrated and the eye samples are
    raw) and report.html (``pipeline.report.page``)."""
    f, out = cache.files, cache.out
    overlay = steps.status.get("camera") in GOOD and f.eye_samples is not None
    paths = [out / "targets.csv", out / "viewlines.csv", out / "poses.csv"]
    paths += [f.video, out / DETECTIONS] if conf.overlay and f.video else []
    paths += [p for p in (f.import_report, f.truth_targets, f.truth_head_poses, f.markers) if p]
    paths += [conf.sfm_map / SFM_FEATURES] if conf.sfm_map is not None else []
    if conf.aois is not None:                                  # the 3D view's areas
        paths += [conf.aois, *mesh_paths(conf.aoi_specs)]
    params: dict = {"overlay": conf.overlay, "pose_source": f.pose_source}
    params |= {"overlay_video": True} if conf.overlay_video else {}
    params |= {"aois": True} if conf.aois else {}
    params |= {"truth_frame": frame.record()} if frame else {}
    rconf = conf.report_conf(world_words(f.pose_source, conf.map_kind))
    steps.run("report", paths, params, run_report, rconf,
              partial(cache.report_inputs, conf, frame, overlay))


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
