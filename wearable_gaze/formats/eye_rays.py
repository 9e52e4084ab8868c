"""Eye rays (``eye_rays.csv``, docs/session.md): what a device importer gives instead of raw
eye-sensor readings. One row per eye sample: the time and, per eye, the view line in the head
frame (the scene camera's frame, OpenCV axes: x right, y down, z forward; mm), ready to be moved
into the world with the head poses. The device's own calibration made these lines; the session
then needs no eye calibration.

Columns: ``t`` (s, session clock), then for ``left`` and ``right``: ``_ox, _oy, _oz`` (the eye's
centre, mm), ``_dx, _dy, _dz`` (unit direction) and ``_valid`` (1/0; an invalid eye's cells are
empty).

The device's own 3D gaze (``device_gaze.csv``: ``t`` and the gazed point ``x, y, z`` in the head
frame, mm) is kept beside it for comparison only: it is never an input to the estimators.

One reader and one writer each: ``read_eye_rays`` / ``EyeRaysWriter``, ``read_device_gaze`` /
``DeviceGazeWriter``.
"""

from __future__ import annotations

import numpy as np

from estimator.lines import BinocularSamples

from ..errors import UserError
from .tables import TableWriter, _cells, read_table

SIDES = ("left", "right")
RAY_COLUMNS = ["t"] + [f"{s}_{k}" for s in SIDES for k in ("ox", "oy", "oz", "dx", "dy", "dz", "valid")]
RAY_FORMATS = {"t": ".6f", **{f"{s}_{k}": ".4f" for s in SIDES for k in ("ox", "oy", "oz")},
               **{f"{s}_{k}": ".8f" for s in SIDES for k in ("dx", "dy", "dz")}}
GAZE_COLUMNS = ["t", "x", "y", "z"]
GAZE_FORMATS = {"t": ".6f", "x": ".3f", "y": ".3f", "z": ".3f"}


def ray_columns(t, left_origin_mm, left_direction, left_valid, right_origin_mm, right_direction,
                right_valid) -> dict:
    """The ``eye_rays.csv`` columns of n samples: t (n,) s; per eye origin (n, 3) mm, direction
    (n, 3) and valid (n,) bool, head frame. An invalid eye's cells are written empty."""
    t = np.asarray(t, float).reshape(-1)
    cols = {"t": t}
    for side, o, d, v in (("left", left_origin_mm, left_direction, left_valid),
                          ("right", right_origin_mm, right_direction, right_valid)):
        v = np.asarray(v, bool).reshape(-1)
        o = np.where(v[:, None], np.asarray(o, float).reshape(-1, 3), np.nan)
        d = np.asarray(d, float).reshape(-1, 3)
        with np.errstate(invalid="ignore", divide="ignore"):
            d = np.where(v[:, None], d / np.linalg.norm(d, axis=1, keepdims=True), np.nan)
        for k, c in zip(("ox", "oy", "oz"), o.T, strict=True):
            cols[f"{side}_{k}"] = c
        for k, c in zip(("dx", "dy", "dz"), d.T, strict=True):
            cols[f"{side}_{k}"] = c
        cols[f"{side}_valid"] = v
    return cols


RAY_HEADER = ",".join(RAY_COLUMNS) + "\n"
"""The header line of ``eye_rays.csv`` (for a writer that streams lines: the live recorder)."""


def ray_csv_line(t: float, left, left_valid: bool, right, right_valid: bool) -> str:
    """One ``eye_rays.csv`` row, newline included: ``t`` s; ``left``, ``right`` (6,) each eye's
    centre (mm) then direction, head frame (an invalid eye's cells are written empty)."""
    return ray_csv_lines([t], [left], [left_valid], [right], [right_valid])


def ray_csv_lines(t, left, left_valid, right, right_valid) -> str:
    """``eye_rays.csv`` rows, each with its newline, converted in one batch (the live recorder's,
    once a flush period, not once a sample): ``t`` (n,) s; ``left``, ``right`` n (6,) each eye's
    centre (mm) then direction, head frame; ``left_valid``, ``right_valid`` (n,) bool."""
    if not len(t):
        return ""
    lo, ro = np.asarray(left, float).reshape(-1, 6), np.asarray(right, float).reshape(-1, 6)
    cols = _cells(ray_columns(t, lo[:, :3], lo[:, 3:], left_valid, ro[:, :3], ro[:, 3:], right_valid), RAY_FORMATS)
    return "".join(",".join(row) + "\n" for row in zip(*cols, strict=True))


class EyeRaysWriter(TableWriter):
    """``eye_rays.csv`` written in chunks (``with EyeRaysWriter(path) as w: w.add(...)``)."""

    def __init__(self, path):
        super().__init__(path, RAY_COLUMNS, RAY_FORMATS)

    def add(self, t, left_origin_mm, left_direction, left_valid, right_origin_mm, right_direction, right_valid):
        """Append n samples (see ``ray_columns``)."""
        self.write(ray_columns(t, left_origin_mm, left_direction, left_valid, right_origin_mm, right_direction,
                               right_valid))


def read_eye_rays(path) -> BinocularSamples:
    """``eye_rays.csv`` -> ``BinocularSamples`` in the head frame (``frame="head"``).

    Raises:
        UserError: a malformed file, times that do not increase, a valid eye without a finite
            unit direction.
    """
    coords = [c for c in RAY_COLUMNS if not c.endswith("_valid") and c != "t"]
    tab = read_table(path, RAY_COLUMNS, what="eye-ray CSV", empty_ok=coords)
    t = tab["t"]
    if np.any(np.diff(t) <= 0):
        i = int(np.flatnonzero(np.diff(t) <= 0)[0])
        raise UserError(f"{path} line {i + 3}: t = {t[i + 1]:.6f} does not increase (line {i + 2} has t = {t[i]:.6f}); "
                        "the rows must be in time order (re-run 'wearable-gaze import')")
    arrays = []
    for side in SIDES:
        v = tab[f"{side}_valid"] != 0
        o = np.column_stack([tab[f"{side}_o{a}"] for a in "xyz"])
        d = np.column_stack([tab[f"{side}_d{a}"] for a in "xyz"])
        bad = v & ~(np.all(np.isfinite(o), axis=1) & np.all(np.isfinite(d), axis=1)
                    & (np.abs(np.linalg.norm(np.nan_to_num(d), axis=1) - 1) < 1e-3))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise UserError(f"{path} line {i + 2}: the {side} eye is marked valid but its ray is empty or its "
                            f"direction not a unit vector; set {side}_valid to 0 or fix the ray")
        arrays += [o, d, v]
    return BinocularSamples.from_arrays(t, arrays[0], arrays[1], arrays[3], arrays[4], arrays[2], arrays[5],
                                        frame="head")


class DeviceGazeWriter(TableWriter):
    """``device_gaze.csv`` (the device's own 3D gaze point, head frame, mm) written in chunks."""

    def __init__(self, path):
        super().__init__(path, GAZE_COLUMNS, GAZE_FORMATS)

    def add(self, t, points_mm) -> None:
        """Append n gazed points: t (n,) s, points (n, 3) mm in the head frame (NaN: none)."""
        p = np.asarray(points_mm, float).reshape(-1, 3)
        self.write({"t": np.asarray(t, float).reshape(-1), "x": p[:, 0], "y": p[:, 1], "z": p[:, 2]})


def read_device_gaze(path) -> tuple[np.ndarray, np.ndarray]:
    """``device_gaze.csv`` -> (t (N,) s, points (N, 3) mm in the head frame, NaN where none)."""
    tab = read_table(path, GAZE_COLUMNS, what="device-gaze CSV", empty_ok=("x", "y", "z"), rows_required=False)
    return tab["t"], np.column_stack([tab["x"], tab["y"], tab["z"]]).reshape(-1, 3)
