"""The exports of ``process`` for other tools (docs/formats.md, "Outputs of process"): the
fixations table (``fixations.csv``, written by the targets step), the per-sample gaze export
(``gaze.csv``) and the 3D view of the targets and the head path (``targets.ply``), written by
the export step from the files of the steps before it."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from estimator import BinocularSamples
from estimator.aoi import fixation_durations_s
from estimator.deprecation import module_getattr
from estimator.frames import rotate_directions, transform_points
from estimator.region import ray_exit, region_mesh
from estimator.result import covariance_ellipsoid
from tracking.timeline import MAX_POSE_GAP_S, interpolate_poses

from ...errors import UserError
from ...formats.fixations_table import write_fixations_csv
from ...formats.gaze_export import GAZE_COLUMNS, NOMINAL_DEPTH_MM, write_gaze_csv
from ...formats.ply import PlyMesh, write_ply
from ...formats.tables import read_table
from ...formats.targets import read_estimates, read_target_labels, read_target_paths, record_region
from ..report.regions import anchor_points, scene_box
from ..types import Poses, Target, TargetsResult

log = logging.getLogger(__name__)

COLORS = np.array([[214, 39, 40], [31, 119, 180], [44, 160, 44], [148, 103, 189], [255, 127, 14], [140, 86, 75],
                    [227, 119, 194], [23, 190, 207]], np.uint8)
"""The targets' colours, in turn (the report's)."""
HEAD_COLOR = (128, 128, 128)


def fixation_rows(result: TargetsResult) -> list[dict]:
    """One row of fixations.csv per fixation of the targets step (``formats.fixations_table``):
    its times, duration (``estimator.aoi.fixation_durations_s``: the time its view lines stand
    for, as the AOI measures and the targets' dwell count it), samples, target, own estimate and
    covariance (a moving one's path at its middle knot), motion and status."""
    target_of = {f: tg.index for tg in result.targets for f in tg.fixations}
    durations = fixation_durations_s(result.samples.t_s, result.labels, [f.index for f in result.fixations])
    rows = []
    for f, duration in zip(result.fixations, durations, strict=True):
        t = result.samples.t_s[f.samples]
        pos = cov = None
        if f.trajectory is not None:
            pos, cov = f.trajectory.middle()
            status = "moving"
        else:
            status = f.estimate.status.value if f.estimate is not None else "no-estimate"
            if f.estimate is not None and f.estimate.ok:
                pos, cov = f.estimate.position_mm, f.estimate.covariance_mm2
        rows.append({"fixation_id": f.index, "start_s": float(t.min()), "end_s": float(t.max()),
                     "duration_s": float(duration), "n_samples": len(f.samples),
                     "target_id": target_of.get(f.index, -1), "motion": f.motion,
                     "status": status, "position_mm": pos, "covariance_mm2": cov,
                     "direction": f.estimate.direction if f.estimate is not None else None})
    return rows


def write_fixations_step(out: Path, result: TargetsResult) -> None:
    """fixations.csv in ``out`` (the targets step writes it beside targets.json)."""
    write_fixations_csv(out / "fixations.csv", fixation_rows(result))


def export_files(out: Path, head: BinocularSamples, poses: Poses, targets: list, camera=None,
                 clock_offset_s: float = 0.0) -> None:
    """The export step: gaze.csv and targets.ply in ``out``, from the session's eye samples as
    view lines in the head frame ``head`` (N,) (with the per-person correction if any), the head
    poses, the targets, the scene ``camera`` (None: no 2D gaze) and the files the targets step
    wrote (viewlines.csv, target_labels.npy, estimates.csv)."""
    vl = read_table(out / "viewlines.csv", ["t", "segment"], what="view-line CSV (viewlines.csv)")
    tlabels = read_target_labels(out / "target_labels.npy")
    cols = gaze_columns(head, poses, vl["t"], vl["segment"].astype(int), tlabels, read_estimates(out / "estimates.csv"),
                        camera, clock_offset_s)
    write_gaze_csv(out / "gaze.csv", cols)
    write_ply(out / "targets.ply", targets_mesh(targets, poses, read_target_paths(out / "target_paths.csv")))


def gaze_columns(head: BinocularSamples, poses: Poses, vl_t, fixation: np.ndarray, target: np.ndarray,
                 running: dict, camera=None, clock_offset_s: float = 0.0) -> dict:
    """The columns of gaze.csv (``GAZE_COLUMNS``) of the eye samples ``head`` (N,) in the head
    (scene camera) frame: the samples with a head pose and a valid eye are the view lines of
    viewlines.csv (times ``vl_t`` (M,), fixation labels ``fixation`` (M,), target labels
    ``target`` (M,)), in order; ``running`` the columns of estimates.csv.

    Raises:
        UserError: viewlines.csv is not the view lines of these samples (an older run's).
    """
    n = len(head)
    T_wc, pose_ok = interpolate_poses(poses.t, poses.T_world_from_cam, head.t_s, MAX_POSE_GAP_S)
    kept = np.flatnonzero(pose_ok & (head.left_valid | head.right_valid))
    if len(kept) != len(vl_t) or not np.allclose(head.t_s[kept], vl_t, rtol=0, atol=1e-5):
        raise UserError("viewlines.csv does not hold the view lines of this session's eye samples; run "
                        "'wearable-gaze process' again with --force")
    cols = {"sample": np.arange(n), "t_s": head.t_s, "device_t_s": head.t_s + clock_offset_s,
            "left_valid": head.left_valid.astype(int), "right_valid": head.right_valid.astype(int),
            "pose_ok": pose_ok.astype(int)}
    for side in ("left", "right"):
        o, d = getattr(head, f"{side}_origin_mm"), getattr(head, f"{side}_direction")
        ow, dw = np.full((n, 3), np.nan), np.full((n, 3), np.nan)
        ok = pose_ok & getattr(head, f"{side}_valid")
        ow[ok], dw[ok] = transform_points(T_wc[ok], o[ok]), rotate_directions(T_wc[ok], d[ok])
        for j, a in enumerate("xyz"):
            cols[f"{side}_origin_{a}_mm"], cols[f"{side}_dir_{a}"] = ow[:, j], dw[:, j]
    fix, tgt = np.full(n, -1), np.full(n, -1)
    fix[kept], tgt[kept] = fixation, target
    cols["fixation_id"], cols["target_id"] = fix, tgt
    est = _running(head.t_s, fix, running)
    for j, a in enumerate("xyz"):
        cols[f"est_{a}_mm"] = est[:, j]
    cols["est_radius95_mm"] = est[:, 3]
    cols |= _gaze_px(head, T_wc, est[:, :3], camera)
    assert set(cols) == set(GAZE_COLUMNS)
    return cols


def _running(t: np.ndarray, fix: np.ndarray, running: dict) -> np.ndarray:
    """(N, 4) the running estimate (x, y, z mm, radius95 mm) of each sample: its fixation's last
    row of estimates.csv at or before its time (the file's times are rounded to 0.1 ms); NaN none."""
    out = np.full((len(t), 4), np.nan)
    rt, seg = np.asarray(running["t"], float), np.asarray(running["segment"], float)
    vals = np.column_stack([running[k] for k in ("x", "y", "z", "radius95_mm")]) if len(rt) else np.zeros((0, 4))
    for k in np.unique(fix[fix >= 0]):
        rows = np.flatnonzero(seg == k)
        if not len(rows):
            continue
        rows = rows[np.argsort(rt[rows], kind="stable")]
        idx = np.flatnonzero(fix == k)
        j = np.searchsorted(rt[rows], t[idx] + 5e-5, side="right") - 1
        have = j >= 0
        out[idx[have]] = vals[rows[j[have]]]
    return out


def _gaze_px(head: BinocularSamples, T_wc: np.ndarray, est_world: np.ndarray, camera) -> dict:
    """The 2D gaze columns: the cyclopean view line (head frame) projected at the running
    estimate's depth on it, or at ``NOMINAL_DEPTH_MM``; NaN without a valid eye or a camera. The
    depth column holds the estimate's depth only (empty where there is none: no placeholder)."""
    n = len(head)
    valid = np.column_stack([head.left_valid, head.right_valid]).astype(float)
    w = np.where(valid.sum(1) > 0, valid.sum(1), np.nan)[:, None]
    o = (np.nan_to_num(head.left_origin_mm) * valid[:, :1] + np.nan_to_num(head.right_origin_mm) * valid[:, 1:]) / w
    d = np.nan_to_num(head.left_direction) * valid[:, :1] + np.nan_to_num(head.right_direction) * valid[:, 1:]
    with np.errstate(invalid="ignore", divide="ignore"):
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        T_cw = np.linalg.inv(np.where(np.isfinite(T_wc), T_wc, np.eye(4)))
        est_cam = transform_points(T_cw, np.nan_to_num(est_world))
        depth = np.einsum("ij,ij->i", est_cam - o, d)
    have = np.all(np.isfinite(est_world), axis=1) & np.isfinite(depth) & (depth > 0)
    depth = np.where(have & np.all(np.isfinite(d), axis=1), depth, np.nan)
    px = np.full((n, 2), np.nan)
    p = o + np.where(have, depth, NOMINAL_DEPTH_MM)[:, None] * d
    front = np.all(np.isfinite(p), axis=1) & (np.nan_to_num(p[:, 2]) > 1.0)
    if camera is not None and front.any():
        px[front] = camera.project(p[front])
    inside = np.zeros(n, int)
    if camera is not None:
        wd, ht = camera.image_size
        with np.errstate(invalid="ignore"):
            inside = ((px[:, 0] >= -0.5) & (px[:, 0] < wd - 0.5) & (px[:, 1] >= -0.5)
                      & (px[:, 1] < ht - 0.5)).astype(int)
    return {"gaze_x_px": px[:, 0], "gaze_y_px": px[:, 1], "gaze_depth_mm": depth, "in_image": inside}


ELLIPSOID_SUBDIVISIONS = 2
"""An ellipsoid is an icosphere subdivided this often (162 vertices, 320 triangles)."""


def icosphere(subdivisions: int = ELLIPSOID_SUBDIVISIONS) -> tuple[np.ndarray, np.ndarray]:
    """A unit sphere's triangle mesh: vertices (V, 3) on the sphere, faces (F, 3), outward."""
    p = (1 + 5 ** 0.5) / 2
    v = [(-1, p, 0), (1, p, 0), (-1, -p, 0), (1, -p, 0), (0, -1, p), (0, 1, p), (0, -1, -p), (0, 1, -p),
         (p, 0, -1), (p, 0, 1), (-p, 0, -1), (-p, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6),
         (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10),
         (8, 6, 7), (9, 8, 1)]
    verts = [np.array(x, float) / np.linalg.norm(x) for x in v]
    for _ in range(subdivisions):
        mid: dict[tuple[int, int], int] = {}
        nf: list[tuple[int, int, int]] = []
        for a, b, c in f:
            ab, bc, ca = (_midpoint(verts, mid, i, j) for i, j in ((a, b), (b, c), (c, a)))
            nf += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        f = nf
    return np.array(verts), np.array(f, int)


def _midpoint(verts: list, cache: dict, i: int, j: int) -> int:
    key = (min(i, j), max(i, j))
    if key not in cache:
        m = verts[i] + verts[j]
        verts.append(m / np.linalg.norm(m))
        cache[key] = len(verts) - 1
    return cache[key]


def targets_mesh(targets: list[Target], poses: Poses, paths: dict | None = None) -> PlyMesh:
    """targets.ply's mesh: per static target, a lone vertex at its point (without one, its line of
    sight over its region as an edge) and its 95 % credible region (``formats.targets.
    record_region``: its distance interval along the line of sight by its lateral extent, a
    frustum of the cone of sight, ``estimator.region.region_mesh``; one with no far end reaches
    the edge of the box of the head path and the targets, ``regions.scene_box``, and stays open
    there), or, without one, its 95 % ellipsoid (``estimator.result.covariance_ellipsoid``: the
    unit icosphere scaled by the semi-axes along the covariance's eigenvectors), in the target's
    colour; then each moving target's path (``paths``: target_paths.csv's, {index: (t, (K, 3)
    positions, covariances)}) as edges in its colour; then the head path, the scene camera's
    positions at its posed frames, as edges."""
    parts = _MeshParts()
    sphere = icosphere()
    head = poses.T_world_from_cam[:, :3, 3]
    regions = {tg.index: record_region(tg.row()) for tg in targets
               if not tg.moving and tg.index not in (paths or {})}
    lo, hi = scene_box(head, np.reshape([t.position_mm for t in targets], (-1, 3)),
                       *(np.asarray(p[1], float) for p in (paths or {}).values()),
                       anchor_points([r for t in targets if not np.all(np.isfinite(t.position_mm))
                                      and (r := regions.get(t.index)) is not None]))
    for tg in targets:
        region = regions.get(tg.index)
        if np.all(np.isfinite(tg.position_mm)) or region is not None:
            _add_target(parts, tg, region, lo, hi, sphere)
    for index, (_, pos, _) in sorted((paths or {}).items()):
        first = parts.add(np.asarray(pos, float), COLORS[index % len(COLORS)])
        parts.add_path_edges(first, len(pos))
        parts.notes.append(f"target {index}'s path (a moving target): vertices {first}-"
                           f"{parts.n - 1}, the edges")
    posed = np.flatnonzero(np.all(np.isfinite(poses.T_world_from_cam[:, :3, 3]), axis=1))
    if len(posed):
        first = parts.add(poses.T_world_from_cam[posed, :3, 3], np.array(HEAD_COLOR, np.uint8))
        parts.add_path_edges(first, len(posed))
        parts.notes.append(f"head path (scene camera positions at posed frames): vertices {first}-"
                           f"{parts.n - 1}, the edges")
    return PlyMesh(_cat(parts.vertices, (0, 3), float), _cat(parts.colors, (0, 3), np.uint8),
                   _cat(parts.faces, (0, 3), int), _cat(parts.edges, (0, 2), int),
                   ["wearable-gaze targets.ply (docs/formats.md)", *parts.notes])


class _MeshParts:
    """targets.ply's mesh as it is built: blocks of vertices (each (k, 3) mm), their colours
    ((k, 3) uint8), faces and edges (indices into all vertices so far), one note per part."""

    def __init__(self):
        self.vertices: list[np.ndarray] = []
        self.colors: list[np.ndarray] = []
        self.faces: list[np.ndarray] = []
        self.edges: list[np.ndarray] = []
        self.notes: list[str] = []
        self.n = 0                                  # vertices so far

    def add(self, points: np.ndarray, color: np.ndarray) -> int:
        """Append vertices (k, 3) in one colour (3,); the index of the first."""
        first = self.n
        self.vertices.append(points)
        self.colors.append(np.repeat(color[None], len(points), 0))
        self.n += len(points)
        return first

    def add_path_edges(self, first: int, count: int) -> None:
        """Edges joining ``count`` vertices from ``first`` in turn."""
        self.edges.append(np.column_stack([np.arange(first, first + count - 1),
                                           np.arange(first + 1, first + count)]))


def _add_target(parts: _MeshParts, tg: Target, region, lo: np.ndarray, hi: np.ndarray,
                sphere: tuple[np.ndarray, np.ndarray]) -> None:
    """A static target's part of targets.ply (see ``targets_mesh``): its point or line of sight,
    then its credible region or else its ellipsoid (the unit ``sphere``'s (vertices, faces)
    scaled), in its colour, and its note."""
    color = COLORS[tg.index % len(COLORS)]
    text = f"target {tg.index} ({tg.status}):"
    if np.all(np.isfinite(tg.position_mm)):
        first = parts.add(np.asarray(tg.position_mm, float)[None], color)
        text += f" vertex {first} (its point)"
    elif region is not None:                      # no point: its line of sight as an edge
        reach = region.far_mm if region.closed else ray_exit(region.origin_mm, region.direction,
                                                              lo, hi)
        ends = np.stack([region.point_at(region.near_mm),
                         region.point_at(max(reach, region.near_mm))])
        first = parts.add(ends, color)
        parts.edges.append(np.array([[first, first + 1]]))
        text += f" vertices {first}-{first + 1} (its line of sight over its region, the edge)"
    if region is not None:
        rv, rf, _ = region_mesh(region, ray_exit(region.origin_mm, region.direction, lo, hi))
        parts.faces.append(rf + parts.n)
        first = parts.add(rv, color)
        what = (f"{region.near_mm:.0f}-{region.far_mm:.0f} mm" if region.closed else
                f"{region.near_mm:.0f} mm on, no far end: open, cut at the box's edge")
        text += (f", its 95 % credible region (distance from {_xyz(region.origin_mm)} {what}) "
                 f"vertices {first}-{parts.n - 1}")
    elif tg.covariance_mm2 is not None and np.all(np.isfinite(tg.covariance_mm2)):
        unit, faces = sphere
        ell = covariance_ellipsoid(tg.position_mm, tg.covariance_mm2, 0.95)
        parts.faces.append(faces + parts.n)
        first = parts.add(tg.position_mm + (unit * ell.radii_mm) @ ell.axes.T, color)
        text += f", its 95 % ellipsoid vertices {first}-{parts.n - 1}"
    parts.notes.append(text)


def _xyz(p) -> str:
    return "(" + ", ".join(f"{v:.0f}" for v in p) + ")"


def _cat(parts: list, shape: tuple, dtype) -> np.ndarray:
    return np.concatenate(parts).astype(dtype) if parts else np.zeros(shape, dtype)


if not TYPE_CHECKING:      # old names (issue 30), for one release; unseen by mypy
    __getattr__ = module_getattr(globals(), {"COLOURS": "COLORS", "HEAD_COLOUR": "HEAD_COLOR"})
