"""The per-sample gaze export ``gaze.csv`` (docs/formats.md, "gaze.csv"): one row per eye
sample of the session (``eye.csv`` or, imported, ``eye_rays.csv``), in its order, for users of
Pupil Player, Neon/Cloud and gazeMapper.

Columns (``GAZE_COLUMNS``: name -> the dtype pandas reads it as, with no options):

- ``sample`` (int64): the row of the session's eye samples, from 0.
- ``t_s`` (float64): the session clock (the scene video's), s. ``device_t_s`` (float64): the
  device's clock, s (``t_s`` + the import's ``clock_offset_s``; our recorder's clock is the
  session clock: the same as ``t_s``).
- ``gaze_x_px, gaze_y_px`` (float64): the 2D gaze in the scene video, pixels (distorted, as in the
  video; OpenCV's origin, the top-left pixel's centre at 0, 0): the cyclopean view line (from
  the mean of the valid eyes' centres along the mean of their directions, head frame) projected
  at the running 3D estimate's depth on that line where there is one (``gaze_depth_mm``, float64;
  empty where there is none), else at ``NOMINAL_DEPTH_MM``. Empty without a valid eye or a camera
  calibration.
- ``left_origin_x_mm .. _z_mm``, ``left_dir_x .. _z`` (float64) and the same for ``right``:
  each eye's view line in the world frame (the marker map's; centre mm, unit direction), empty
  for an invalid eye or a sample without a head pose.
- ``fixation_id`` (int64): the fixation of the sample (viewlines.csv's ``segment``,
  fixations.csv's ``fixation_id``), -1 none. ``target_id`` (int64): its target (targets.json),
  -1 none.
- ``est_x_mm, est_y_mm, est_z_mm`` (float64, world mm), ``est_radius95_mm`` (float64): the
  running 3D estimate: the sample's fixation's estimate from its view lines up to this sample
  (the last row of estimates.csv of that fixation at or before ``t_s``, as a live session would
  have shown it); empty where none (outside fixations, a moving fixation, before the first
  usable estimate).
- quality flags (int64, 1 or 0): ``left_valid``, ``right_valid`` (the eye's sample is valid),
  ``pose_ok`` (a head pose within 0.1 s: the sample has world view lines), ``in_image`` (the 2D
  gaze lies inside the scene image).

One writer, ``write_gaze_csv``, and one reader, ``read_gaze_csv``.
"""

from __future__ import annotations

import numpy as np

from .tables import Checks, TableWriter, read_table

NOMINAL_DEPTH_MM = 1000.0
"""The depth at which a sample's 2D gaze is projected when there is no 3D estimate."""

_RAY = [f"{side}_{kind}_{axis}{unit}" for side in ("left", "right")
        for kind, unit in (("origin", "_mm"), ("dir", "")) for axis in "xyz"]
GAZE_COLUMNS = {"sample": "int64", "t_s": "float64", "device_t_s": "float64", "gaze_x_px": "float64",
                "gaze_y_px": "float64", "gaze_depth_mm": "float64", **dict.fromkeys(_RAY, "float64"),
                "fixation_id": "int64", "target_id": "int64", "est_x_mm": "float64", "est_y_mm": "float64",
                "est_z_mm": "float64", "est_radius95_mm": "float64", "left_valid": "int64", "right_valid": "int64",
                "pose_ok": "int64", "in_image": "int64"}
"""The columns of gaze.csv, in order, with the dtype pandas reads each as."""
GAZE_FORMATS = ({"t_s": ".6f", "device_t_s": ".6f", "gaze_x_px": ".2f", "gaze_y_px": ".2f", "gaze_depth_mm": ".1f",
                 "est_x_mm": ".1f", "est_y_mm": ".1f", "est_z_mm": ".1f", "est_radius95_mm": ".1f"}
                | {k: ".3f" for k in _RAY if "origin" in k} | {k: ".7f" for k in _RAY if "_dir_" in k})
_EMPTY_OK = tuple(k for k, d in GAZE_COLUMNS.items() if d == "float64" and k not in ("t_s", "device_t_s"))
GAZE_CHECKS = Checks(tuple(GAZE_COLUMNS), _EMPTY_OK, (), "gaze export (gaze.csv)")
"""What gaze.csv may hold, checked by its writer and its reader."""


CHUNK_ROWS = 20000
"""gaze.csv is written this many rows at a time (a long session's text never all in memory)."""


def write_gaze_csv(path, columns: dict) -> None:
    """Write gaze.csv, atomically: ``columns`` maps each name of ``GAZE_COLUMNS`` to its (N,)
    values (NaN: an empty cell; the int64 columns hold whole numbers)."""
    out = {}
    for name, dtype in GAZE_COLUMNS.items():
        v = np.asarray(columns[name])
        out[name] = v.astype(np.int64) if dtype == "int64" else v.astype(float)
    n = len(out["sample"])
    with TableWriter(path, list(GAZE_COLUMNS), GAZE_FORMATS, GAZE_CHECKS) as w:
        for i in range(0, n, CHUNK_ROWS):
            w.write({k: v[i:i + CHUNK_ROWS] for k, v in out.items()})


def read_gaze_csv(path) -> dict:
    """The columns of a gaze.csv, {name: (N,) array} in ``GAZE_COLUMNS``'s dtypes (NaN where
    empty).

    Raises:
        UserError: a missing file or column, a cell that is not a number (one line).
    """
    cols = read_table(path, list(GAZE_COLUMNS), rows_required=False, checks=GAZE_CHECKS)
    return {k: cols[k].astype(np.int64) if d == "int64" else cols[k] for k, d in GAZE_COLUMNS.items()}
