"""The pose CSV (docs/formats.md, "Pose CSV"): ``poses.csv`` of ``track`` and the simulator's
``truth/head_poses.csv``. One row per frame: ``t`` (s), ``frame``, the quaternion ``qw, qx, qy,
qz`` (w >= 0) and translation ``tx, ty, tz`` (mm) of ``T_world_from_cam``, empty where the
frame has no pose, then extra columns (``n_markers``, ``n_points``, ``reproj_rms_px``,
``status``).

One reader, ``read_poses_csv``, and one writer, ``write_poses_csv``.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import UserError
from .tables import Checks, _cells, read_table, write_table

POSE_COLUMNS = ["t", "frame", "qw", "qx", "qy", "qz", "tx", "ty", "tz"]
POSE_FORMATS = {"t": ".6f", "qw": ".12f", "qx": ".12f", "qy": ".12f", "qz": ".12f",
                "tx": ".6f", "ty": ".6f", "tz": ".6f"}
POSE_CHECKS = Checks(tuple(POSE_COLUMNS), ("qw", "qx", "qy", "qz", "tx", "ty", "tz"), (), "pose CSV")
"""What a pose CSV may hold, checked by its writer and its reader."""

POSE_HEADER = ",".join(POSE_COLUMNS) + "\n"
"""The header line of a pose CSV (for a writer that streams lines: the live recorder)."""

log = logging.getLogger(__name__)


def pose_columns(t, frames, T_world_from_cam) -> dict:
    """Columns of a pose table: quaternion (w, x, y, z) and translation (mm) of
    ``T_world_from_cam`` (N, 4, 4) at times t (N,) and frame numbers (N,)."""
    T = np.asarray(T_world_from_cam, float).reshape(-1, 4, 4)
    ok = np.all(np.isfinite(T.reshape(len(T), -1)), axis=1)
    q = np.full((len(T), 4), np.nan)                           # x, y, z, w; NaN (empty) without a pose
    if ok.any():
        q[ok] = Rotation.from_matrix(T[ok, :3, :3]).as_quat()
    q *= np.where(q[:, 3:4] < 0, -1.0, 1.0)                  # w >= 0: one sign per rotation
    return {"t": np.asarray(t, float), "frame": np.asarray(frames).astype(int),
            "qw": q[:, 3], "qx": q[:, 0], "qy": q[:, 1], "qz": q[:, 2],
            "tx": T[:, 0, 3], "ty": T[:, 1, 3], "tz": T[:, 2, 3]}


def pose_csv_line(t: float, frame: int, T_world_from_cam) -> str:
    """One pose CSV row, newline included: time ``t`` s, ``frame``, the pose (4, 4) mm (None or
    NaN: no pose, its cells empty)."""
    return pose_csv_lines([t], [frame], [T_world_from_cam])


def pose_csv_lines(t, frames, T_world_from_cam) -> str:
    """Pose CSV rows, each with its newline, converted in one batch (the live recorder's, once a
    flush period, not once an eye sample): times ``t`` (N,) s, ``frames`` (N,), poses (4, 4) mm,
    a sequence of N (None or NaN: no pose, its cells empty)."""
    if not len(t):
        return ""
    T = np.stack([np.full((4, 4), np.nan) if x is None else np.asarray(x, float) for x in T_world_from_cam])
    cols = _cells(pose_columns(t, frames, T), POSE_FORMATS)
    return "".join(",".join(row) + "\n" for row in zip(*cols, strict=True))


def write_poses_csv(path, t, frames, T_world_from_cam, extra: dict | None = None) -> None:
    """Write poses ``T_world_from_cam`` (N, 4, 4), mm, NaN where none, at times ``t`` (N,), s,
    and ``frames`` (N,), then the ``extra`` columns, as a pose CSV, atomically."""
    cols = pose_columns(t, frames, T_world_from_cam)
    cols.update(extra or {})
    write_table(path, cols, POSE_FORMATS, POSE_CHECKS)


def read_poses_csv(path, text_columns=("status",)) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """(t (N,), frame (N,), T_world_from_cam (N, 4, 4) with NaN where there is no pose, extra
    columns). Times must increase strictly.

    Raises:
        UserError: a time that does not increase (rows swapped or repeated), naming its line.
    """
    tab = read_table(path, POSE_COLUMNS, text_columns, checks=POSE_CHECKS)
    bad = np.flatnonzero(np.diff(tab["t"]) <= 0)
    if len(bad):
        i = bad[0]
        raise UserError(f"{path} line {i + 3}: time {float(tab['t'][i + 1])!r} s does not increase after "
                        f"{float(tab['t'][i])!r} s; poses must be sorted in time: sort the rows and remove "
                        "repeated times")
    q = np.column_stack([tab["qx"], tab["qy"], tab["qz"], tab["qw"]])
    T = np.full((len(q), 4, 4), np.nan)
    ok = np.all(np.isfinite(q), axis=1) & (np.linalg.norm(q, axis=1) > 0)
    T[ok] = np.eye(4)
    if ok.any():
        T[ok, :3, :3] = Rotation.from_quat(q[ok]).as_matrix()
        T[ok, :3, 3] = np.column_stack([tab["tx"], tab["ty"], tab["tz"]])[ok]
    return tab["t"], tab["frame"].astype(int), T, {k: v for k, v in tab.items() if k not in POSE_COLUMNS}
