"""The fixations table ``fixations.csv`` (docs/formats.md, "fixations.csv"): one row per
fixation ``process`` found, in time order.

Columns (``FIXATION_COLUMNS``: name -> the dtype pandas reads it as, with no options; str: pandas 2's
object, pandas 3's str):
``fixation_id`` (int64; viewlines.csv's ``segment``, gaze.csv's ``fixation_id``), ``start_s``,
``end_s`` (float64, session clock, s; first and last sample), ``duration_s`` (float64, s: the
time its samples stand for, one sample interval each, gaps up to 75 ms counted whole, a longer one
not: ``estimator.aoi.fixation_duration_s``, Tobii's I-VT convention), ``n_samples``
(int64, its view lines), ``target_id`` (int64, the target it was merged into, -1 none),
``x_mm, y_mm, z_mm`` (float64, world frame): the fixation's own estimate from its own view lines
(a moving fixation: its path's point at the middle knot), ``cov_xx_mm2, cov_xy_mm2, cov_xz_mm2,
cov_yy_mm2, cov_yz_mm2, cov_zz_mm2`` (float64, mm^2): the unique terms of its covariance; empty
where there is none; ``direction_x, direction_y, direction_z`` (float64, world frame, unit) and
``cone95_deg`` (float64): a ``direction-only`` fixation's answer, its cyclopean direction and its
95 % cone's half-angle (``estimator.direction``), empty for the others; ``motion`` (str: ``static``
or ``moving``) and ``status`` (str: the estimate's status, ``ok``, ``direction-only`` or why not;
``moving`` for a moving fixation).

One writer, ``write_fixations_csv``, and one reader, ``read_fixations_csv``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .tables import Checks, read_table, write_table

COV_COLUMNS = tuple(f"cov_{k}_mm2" for k in ("xx", "xy", "xz", "yy", "yz", "zz"))
COV_INDEX = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
DIRECTION_COLUMNS = ("direction_x", "direction_y", "direction_z", "cone95_deg")
FIXATION_COLUMNS = {"fixation_id": "int64", "start_s": "float64", "end_s": "float64", "duration_s": "float64",
                    "n_samples": "int64", "target_id": "int64", "x_mm": "float64", "y_mm": "float64",
                    "z_mm": "float64", **dict.fromkeys(COV_COLUMNS, "float64"),
                    **dict.fromkeys(DIRECTION_COLUMNS, "float64"), "motion": "str", "status": "str"}
"""The columns of fixations.csv, in order, with the dtype pandas reads each as."""
FIXATION_FORMATS = {"start_s": ".4f", "end_s": ".4f", "duration_s": ".4f", "x_mm": ".1f", "y_mm": ".1f",
                    "z_mm": ".1f"} | dict.fromkeys(COV_COLUMNS, ".6g") | dict.fromkeys(DIRECTION_COLUMNS[:3], ".6f") | {
                    "cone95_deg": ".3f"}
_TEXT = tuple(k for k, d in FIXATION_COLUMNS.items() if d == "str")
_NUMBERS = [k for k in FIXATION_COLUMNS if k not in _TEXT]
FIXATION_CHECKS = Checks(tuple(_NUMBERS), ("x_mm", "y_mm", "z_mm", *COV_COLUMNS, *DIRECTION_COLUMNS), COV_COLUMNS,
                         "fixations table (fixations.csv)")
"""What fixations.csv may hold, checked by its writer and its reader (covariances in mm^2)."""


def fixation_columns(rows: list[dict]) -> dict:
    """The columns of fixations.csv from one dict per fixation: ``fixation_id``, ``start_s``,
    ``end_s``, ``duration_s``, ``n_samples``, ``target_id``, ``motion``, ``status``, ``position_mm`` ((3,) or
    None), ``covariance_mm2`` ((3, 3) or None) and, optionally, ``direction``
    (``estimator.direction.GazeDirection`` or None)."""
    pos = np.array([r["position_mm"] if r["position_mm"] is not None else np.full(3, np.nan) for r in rows],
                   float).reshape(-1, 3)
    cov = np.array([r["covariance_mm2"] if r["covariance_mm2"] is not None else np.full((3, 3), np.nan)
                    for r in rows], float).reshape(-1, 3, 3)
    start = np.array([r["start_s"] for r in rows], float)
    end = np.array([r["end_s"] for r in rows], float)
    cols = {"fixation_id": np.array([r["fixation_id"] for r in rows], int), "start_s": start, "end_s": end,
            "duration_s": np.array([r["duration_s"] for r in rows], float),
            "n_samples": np.array([r["n_samples"] for r in rows], int),
            "target_id": np.array([r["target_id"] for r in rows], int)}
    cols |= {f"{a}_mm": pos[:, j] for j, a in enumerate("xyz")}
    cols |= {name: cov[:, i, j] for name, (i, j) in zip(COV_COLUMNS, COV_INDEX, strict=True)}
    g = [r.get("direction") for r in rows]
    unit = np.array([d.unit if d is not None else np.full(3, np.nan) for d in g], float).reshape(-1, 3)
    cols |= {name: unit[:, j] for j, name in enumerate(DIRECTION_COLUMNS[:3])}
    cols |= {"cone95_deg": np.array([d.cone95_deg if d is not None else np.nan for d in g], float)}
    cols |= {k: np.array([str(r[k]) for r in rows], object) for k in _TEXT}
    return cols


def write_fixations_csv(path, rows: list[dict]) -> None:
    """Write fixations.csv, atomically, from one dict per fixation (``fixation_columns``); a
    header alone when there is no fixation."""
    write_table(path, fixation_columns(rows), FIXATION_FORMATS, FIXATION_CHECKS)


def read_fixations_csv(path) -> dict:
    """The columns of a fixations.csv, {name: (N,) array} in ``FIXATION_COLUMNS``'s dtypes (NaN
    where empty; the direction columns NaN in a file written before they existed); a header
    alone is no fixation, not an error.

    Raises:
        UserError: a missing file or column, a cell that is not a number (one line).
    """
    older = dataclasses.replace(FIXATION_CHECKS, required=tuple(c for c in _NUMBERS if c not in DIRECTION_COLUMNS))
    cols = read_table(path, _NUMBERS, text_columns=_TEXT, rows_required=False, checks=older)
    for k in _TEXT:
        cols.setdefault(k, np.zeros(0, object))
    for k in DIRECTION_COLUMNS:                    # a file written before they existed: none
        cols.setdefault(k, np.full(len(cols["fixation_id"]), np.nan))
    return {k: cols[k].astype(np.int64) if d == "int64" else cols[k] for k, d in FIXATION_COLUMNS.items()}
