"""``process``'s options checked against each other and against the session (docs/processing.md,
"Options that cannot apply"): which marker map a run uses (the session's, one given with
``--markers``, one built from the video with ``--build-map``, or a markerless one with ``--map``),
the options that do nothing for this session (each said in one line, and reset so that it changes
nothing, not even a cached step's fingerprint), and a simulated session's truth moved into the
world of the map used (``truth_match.TruthFrame``).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from tracking.markermap import square_corners

from ...errors import UserError
from ...formats.markermap import load_marker_map
from ...formats.sfmmap import load_sfm_map
from ...formats.truth import read_truth_moved_markers
from ..report.page import ReportTruth
from ..report.truth_match import TruthFrame, fit_truth_frame
from ..steps.aoi import check_aois


def check_map_options(markers, build_map, sfm_map, overlay: bool, overlay_video: bool) -> Path | None:
    """The options that contradict each other refused, and the map ``markers`` (a marker-map
    JSON, ``wearable-gaze map``) or ``sfm_map`` (a markerless map folder) read once to check it,
    before any step. Returns the path of ``markers``.

    Raises:
        UserError: two of ``markers``, ``build_map``, ``sfm_map`` (each chooses the map);
            ``overlay_video`` without ``overlay``; a map that is missing or cannot be read.
    """
    given = [opt for opt, v in (("--markers MAP", markers), ("--build-map MM", build_map),
                                ("--map SFM_FOLDER", sfm_map)) if v is not None]
    if len(given) > 1:
        raise UserError(f"{' and '.join(given)} each choose the map the video is tracked in: give one (--markers: a "
                        "map from 'wearable-gaze map'; --build-map: one built from this session's video; --map: a "
                        "markerless one)")
    if overlay_video and not overlay:
        raise UserError("--overlay-video writes the overlay that --no-overlay leaves out: give one of them")
    if sfm_map is not None:
        load_sfm_map(sfm_map)
    if markers is None:
        return None
    markers = Path(markers)
    if not markers.is_file():
        raise UserError(f"--markers {markers}: {'is a folder' if markers.is_dir() else 'no such file'}; pass a marker "
                        "map JSON (from 'wearable-gaze map', or measured: docs/session.md, Marker map)")
    load_marker_map(markers)
    return markers


def applicable(f, cfg, markers: Path | None, eyes_given: bool, rerun_frames: int) -> tuple:
    """(``f``, ``cfg``, notes): the session's files ``f`` with the map this run uses in place of
    its ``markers`` (``--markers``; none when ``--build-map`` builds one), the settings ``cfg``
    with each option that cannot apply to this session reset to its default (and ``map_kind``
    set), and one line per such option or replaced map. ``f`` and ``cfg`` are
    ``session_cache.SessionFiles`` and ``stepconf.ProcessConfig``."""
    notes = []
    imported, video = f.eye_rays is not None, f.video is not None
    own_poses = imported and f.pose_source in ("device", "still_head")        # no tracking at all
    why = ("its head poses are the device's" if f.pose_source == "device" else "its head is taken as still") \
        if own_poses else "it has no scene video"
    used = {"--markers": markers, "--build-map": cfg.build_map, "--map": cfg.sfm_map}
    if own_poses or not video:
        notes += [f"{opt}: not used: the session's video is not tracked ({why})" for opt, v in used.items()
                  if v is not None]
        used = dict.fromkeys(used)
    markers, build_map, sfm_map = used.values()
    kind = "given" if markers else "built" if build_map else "markerless" if sfm_map else "session"
    if markers is not None:
        f = dataclasses.replace(f, markers=markers)
    elif build_map is not None and f.markers is not None:
        notes.append(f"--build-map: the session's own marker map ({f.markers.name}) is not used: the map built from "
                     "its video is (OUT/built_map.json)")
        f = dataclasses.replace(f, markers=None)
    overlay_possible = video and f.eye_samples is not None     # the overlay draws the raw eye samples on the video
    overlay, overlay_video = cfg.overlay, cfg.overlay_video
    what = "it has no scene video" if not video else "an imported session's eye rays are drawn in the plots only"
    if overlay_video and not overlay_possible:
        notes.append(f"--overlay-video: no overlay is written for this session ({what})")
        overlay_video = False
    if not overlay and not overlay_possible:
        notes.append(f"--no-overlay: there is no overlay to leave out ({what})")
        overlay = True
    if eyes_given and imported:
        notes.append("--eyes: not used: the device calibrated an imported session's eyes (its eye rays are used)")
    if rerun_frames and not video:
        notes.append("--rerun-frames: no scene frames to show: the session has no scene video")
    if cfg.aois is not None:                # a bad AOI file stops the run before any step
        check_aois(cfg.aoi_specs, cfg.aois, has_marker_map=f.markers is not None or kind == "built")
    cfg = dataclasses.replace(cfg, build_map=build_map, sfm_map=sfm_map, overlay=overlay, overlay_video=overlay_video,
                              map_kind=kind)
    return f, cfg, notes


def truth_frame(f, cfg, built: Path, used_map) -> TruthFrame | None:
    """The truth of a simulated session (``f.truth_targets``; its true marker map
    ``f.truth_map``, the markers of ``f.truth_moved`` left out) moved into the world of the map
    the run used (``cfg.map_kind``): ``cfg.sfm_map``, ``f.markers`` or the ``built`` one (for a
    marker map, its contents ``used_map()``, as tracking read them). ``f``, ``cfg``: ``process``'s
    ``SessionFiles`` and ``ProcessConfig`` (after ``applicable``). None: no truth or no truth map,
    or the map used is the truth's (the same file, or the same corners)."""
    truth_map, moved, map_kind = f.truth_map, f.truth_moved, cfg.map_kind
    used = cfg.sfm_map or f.markers or built
    if f.truth_targets is None or truth_map is None or not truth_map.is_file():
        return None
    if map_kind != "markerless" and Path(used).read_bytes() == truth_map.read_bytes():
        return None                                             # not parsed again: the session's own map
    truth = load_marker_map(truth_map)
    exclude = [m["id"] for m in read_truth_moved_markers(moved)] if moved is not None and moved.is_file() else []
    if map_kind == "markerless":
        corners = markerless_corners(load_sfm_map(used)[1])
        if corners is None:
            return TruthFrame("markerless", reason="its file records no marker it was placed by (scaled by a distance, "
                                                   "or built before such markers were recorded)")
    else:
        mm = used_map()
        corners = {i: mm.corners(i) for i in mm.poses}
    return fit_truth_frame({i: truth.corners(i) for i in truth.poses}, corners, map_kind, exclude)


def markerless_corners(meta: dict) -> dict | None:
    """{id: (4, 3) corners, world mm} of the markers that placed a markerless map (its
    sfm_map.json ``scaled_by``), or None: placed by a distance, or recorded without them."""
    s = meta.get("scaled_by", {})
    if "corners_mm" in s:
        return {int(i): c for i, c in s["corners_mm"].items()}
    if s.get("kind") == "marker" and s.get("markers") and "size_mm" in s:
        return {int(s["markers"][0]): square_corners(float(s["size_mm"]))}       # the world is that marker's frame
    return None


def report_truth(truth: ReportTruth | None, frame: TruthFrame | None) -> tuple[ReportTruth | None, list]:
    """(the report's truth in the world of the map used, the notes saying so): unchanged without a
    ``frame``; none when it cannot be moved."""
    if truth is None or frame is None:
        return truth, []
    if frame.T_map_from_truth is None:
        return None, [frame.note()]
    head = None if truth.head_mm is None else frame.points(truth.head_mm)
    return ReportTruth(frame.targets(truth.targets), head), [frame.note()]
