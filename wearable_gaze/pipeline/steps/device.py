"""``process`` on an imported session (docs/importers.md): the eye rays the device computed
replace the eye calibration, and the head poses come from the device, from tracking the scene
video, or, with neither, from the assumption of a still head (the head frame is the world: only
the two eyes' vergence fixes a depth, and the report says so). After the targets are found, each
is set beside the device's own 3D gaze over the same samples (``device_comparison.csv``)."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from tracking.surface import first_surface
from tracking.timeline import MAX_POSE_GAP_S, interpolate_poses, nearest_in_time

from ...errors import UserError
from ...formats.devices.common import read_import_report
from ...formats.eye_rays import read_device_gaze
from ...formats.ply import read_ply
from ...formats.poses import read_poses_csv, write_poses_csv
from ...formats.session import MANIFEST
from ...formats.targets import write_device_comparison
from ..types import Poses

log = logging.getLogger(__name__)

STILL_HEAD_RATE_HZ = 20.0        # the identity poses of a still head: finer than any gap test
POSE_NOTES = {
    "device": "Head poses: the device's own (its world frame is kept).",
    "scene_video": "Head poses: tracked in the scene video with the device's camera calibration and the marker map.",
    "still_head": "Head poses: none (the device gives none and the session has no scene video with a marker map): "
                  "the head is taken as still and its frame as the world, so only the two eyes' vergence fixes a "
                  "depth; beyond about a metre such depths are poor.",
}


WORLDS = {"device": "the device's own world (its SLAM map's frame; grey dots: its map points, where it gives them)",
          "still_head": "the head's frame (the head taken as still)",
          "markerless": "the markerless map's world (grey dots: its points)"}
"""The report's words for the world frame, by pose source or map kind; else the marker map's."""


def world_words(pose_source: str | None, map_kind: str) -> str:
    """What the report's positions and 3D view are in (``WORLDS``)."""
    return WORLDS.get(pose_source or "", WORLDS.get(map_kind, "the marker map's world (grey squares: its markers)"))


CYCLOPEAN_NOTE = ("One gaze line per sample (a 2D-only tracker's cyclopean ray, no vergence): a target's depth "
                  "comes from the head's motion alone, and the table gives how far the head moved during each of "
                  "its fixations; where the head stood still a fixation has a direction, never a depth.")


def report_notes(pose_source: str | None, no_overlay: bool, import_report: Path | None) -> list[str]:
    """What the report must say first about an imported session: where the head poses came
    from (``POSE_NOTES``), that its depths come from head motion alone when its rays are
    cyclopean (``CYCLOPEAN_NOTE``), the import's notes (kappa, eye labels, fallbacks) and what it
    dropped; ``no_overlay``: an overlay was asked for but an imported session has none."""
    notes = [POSE_NOTES[pose_source]] if pose_source else []
    if no_overlay:
        notes.append("No overlay video: an imported session's eye rays are drawn in the plots only.")
    if import_report is not None:
        rep = read_import_report(import_report)
        notes += [CYCLOPEAN_NOTE] if rep.get("rays") == "cyclopean" else []
        notes += [f"Import ({rep['device']}): {n}" for n in rep.get("notes", [])]
        if rep.get("dropped"):
            notes.append(f"Import ({rep['device']}): dropped " + ", ".join(f"{n} ({why})" for why, n in
                                                                          rep["dropped"].items()))
    return notes


def device_poses(head_poses: Path, out: Path) -> None:
    """The device's head poses (head_poses.csv, ``T_world_from_head``) as the tracking step's
    poses.csv, with status 'device'."""
    t, frame, T, _ = read_poses_csv(head_poses)
    ok = np.all(np.isfinite(T.reshape(len(T), -1)), axis=1)
    if not ok.any():
        raise UserError(f"{head_poses}: the device's head poses are all empty; re-import the recording")
    status = np.where(ok, "device", "no pose").astype(object)
    write_poses_csv(out, t, frame, T, {"status": status})


def still_head_poses(t, out: Path) -> None:
    """Identity poses (the head frame is the world) every 1/``STILL_HEAD_RATE_HZ`` s over the
    span of the eye samples' times t (N,), s, as poses.csv with status 'still_head'."""
    grid = np.arange(t[0] - 1.0 / STILL_HEAD_RATE_HZ, t[-1] + 2.0 / STILL_HEAD_RATE_HZ, 1.0 / STILL_HEAD_RATE_HZ)
    T = np.broadcast_to(np.eye(4), (len(grid), 4, 4))
    write_poses_csv(out, grid, np.arange(len(grid)), T, {"status": np.full(len(grid), "still_head", object)})


def device_comparison(device_gaze: Path, samples, targets: list, poses: Poses, out: Path) -> list[dict]:
    """Each target beside the device's own 3D gaze over the target's samples: the distance of
    our estimate from the head and the device's gaze depth (median over the samples, mm). Written
    to ``out`` (device_comparison.csv) and returned as rows."""
    t_g, p_g = read_device_gaze(device_gaze)
    rows = []
    for tg in targets:
        if tg.samples is None or not np.all(np.isfinite(tg.position_mm)):
            continue
        ts = samples.t_s[tg.samples]
        T, ok = interpolate_poses(poses.t, poses.T_world_from_cam, ts, MAX_POSE_GAP_S)
        head = T[ok, :3, 3]
        ours = float(np.median(np.linalg.norm(tg.position_mm - head, axis=1))) if ok.any() else np.nan
        depth = np.linalg.norm(nearest_in_time(t_g, p_g, ts, 0.1), axis=1)
        depth = depth[np.isfinite(depth)]
        dev = float(np.median(depth)) if len(depth) else np.nan
        rows.append({"target": tg.index, "n_samples": tg.n_samples, "ours_distance_mm": ours,
                     "device_depth_mm": dev, "ours_x_mm": float(tg.position_mm[0]),
                     "ours_y_mm": float(tg.position_mm[1]), "ours_z_mm": float(tg.position_mm[2])})
    write_device_comparison(out, rows)
    return rows


def surface_reference(points_mm, device_gaze: Path, poses: Poses, t) -> tuple[np.ndarray, np.ndarray]:
    """Reference gazed points where a map of the scene exists (Aria's SLAM points): the first
    surface of the cloud along the device's own gaze direction at each time ``t`` (N,), s
    (``tracking.surface.first_surface``). Returns (N, 3) points and (N, 3) head positions, world
    frame, mm; NaN where the device gave no gaze, no pose is near, or no surface is found."""
    t = np.asarray(t, float)
    t_g, p_g = read_device_gaze(device_gaze)
    T, ok = interpolate_poses(poses.t, poses.T_world_from_cam, t, MAX_POSE_GAP_S)
    d_head = np.where(ok[:, None], nearest_in_time(t_g, p_g, t, 1e-4), np.nan)     # the same samples' gaze
    with np.errstate(invalid="ignore", divide="ignore"):
        d_head = d_head / np.linalg.norm(d_head, axis=1, keepdims=True)
    origin = np.where(ok[:, None], T[:, :3, 3], np.nan)
    d_world = np.einsum("nij,nj->ni", np.nan_to_num(T[:, :3, :3]), np.nan_to_num(d_head))
    d_world[~np.all(np.isfinite(d_head), axis=1)] = np.nan
    depth = first_surface(points_mm, np.nan_to_num(origin), np.where(np.isfinite(d_world), d_world, 0.0))
    depth[~(ok & np.all(np.isfinite(d_world), axis=1))] = np.nan
    return origin + depth[:, None] * d_world, origin


def device_points(root: Path) -> np.ndarray | None:
    """An imported session's device map points (``device_points.ply``, Aria's SLAM points):
    (P, 3) world frame, mm; None when it has none."""
    manifest = json.loads((Path(root) / MANIFEST).read_text(encoding="utf-8"))
    rel = manifest.get("files", {}).get("device_points")
    if rel is None or not (Path(root) / rel).is_file():
        return None
    return read_ply(Path(root) / rel).vertices_mm
