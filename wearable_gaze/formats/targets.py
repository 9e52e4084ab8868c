"""The files of ``process``'s targets step: the targets it found, ``targets.json`` and
``targets.csv`` (docs/processing.md, docs/formats.md "Targets"), the target of every view line,
``target_labels.npy``, and the fixations' running estimates, ``estimates.csv``.

targets.json and targets.csv hold the same rows, one per target, keyed by ``TARGET_COLUMNS``: ``target`` (index),
``x_mm, y_mm, z_mm`` (world frame, mm), ``axis1_mm..axis3_mm`` (95 % ellipsoid semi-axes, mm),
``n_samples``, ``t_start, t_end`` (s), ``fixations`` (``;``-separated indices), ``method``,
``status``, ``crb_mm``. A value that does not exist (no usable estimate) is NaN in the JSON and an
empty cell in the CSV. targets.json adds ``version`` and ``method``; targets.csv rounds to 0.1 mm
and 1 ms, for spreadsheets. A moving target (smooth pursuit) has ``"moving": true`` in its
targets.json row, status ``moving`` and as its point the path's position at its middle time;
targets.csv then has a last column ``moving`` (1 or 0) for every row. A session without a moving
target writes neither (the files of earlier versions, byte for byte); a row without the key is a
static target.

``target_paths.csv`` holds the moving targets' paths, one row per knot: ``target``, ``t`` (s),
``x, y, z`` (world frame, mm) and the covariance terms ``cxx, cxy, cxz, cyy, cyz, czz`` (mm^2);
a header alone when no target moves. ``write_target_paths`` and ``read_target_paths``.

One writer, ``write_targets`` (both files), and one reader, ``read_targets`` (the rows of
targets.json, exact). ``target_labels.npy`` has ``write_target_labels`` and
``read_target_labels``. ``estimates.csv`` has one row per usable estimate while a fixation's view
lines were fed in, as a live session would: ``t`` (s, the last line fed), ``segment`` (the
fixation), ``x, y, z`` (world frame, mm) and ``radius95_mm``, a header alone when no fixation gave
an estimate; ``write_estimates`` and ``read_estimates``. ``device_comparison.csv`` (an imported
session) sets each target beside the device's own 3D gaze: ``target``, ``n_samples``,
``ours_distance_mm`` (our estimate's distance from the head, median over the target's samples),
``device_depth_mm`` (the device's gaze depth, median over the same samples), ``ours_x_mm..z``;
``write_device_comparison`` and ``read_device_comparison``. The rows are plain dicts here;
``pipeline.types.Target`` converts (``Target.row`` / ``Target.from_row``).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from ..errors import UserError
from .atomic import atomic_path
from .jsonio import write_json
from .tables import read_table, write_table

TARGET_COLUMNS = ("target", "x_mm", "y_mm", "z_mm", "axis1_mm", "axis2_mm", "axis3_mm", "n_samples", "t_start",
                  "t_end", "fixations", "method", "status", "crb_mm")
TARGET_FORMATS = {k: ".1f" for k in ("x_mm", "y_mm", "z_mm", "axis1_mm", "axis2_mm", "axis3_mm", "crb_mm")} | {
    "t_start": ".3f", "t_end": ".3f"}
MOVING_COLUMN = "moving"
PATH_COLUMNS = ("target", "t", "x", "y", "z", "cxx", "cxy", "cxz", "cyy", "cyz", "czz")
PATH_FORMATS = {"t": ".4f", "x": ".1f", "y": ".1f", "z": ".1f"} | {k: ".6g" for k in PATH_COLUMNS[5:]}
_COV_INDEX = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
ESTIMATE_COLUMNS = ("t", "segment", "x", "y", "z", "radius95_mm")
ESTIMATE_FORMATS = {"t": ".4f", "x": ".1f", "y": ".1f", "z": ".1f", "radius95_mm": ".1f"}

log = logging.getLogger(__name__)


def write_targets(out, rows: list[dict], method: str) -> None:
    """Write ``rows`` (keys ``TARGET_COLUMNS``, and ``moving`` on a moving target's row; plain
    Python values) as ``out``/targets.csv and ``out``/targets.json (with ``method``, the
    estimator), each atomically."""
    out = Path(out)
    columns = {k: np.array([r[k] for r in rows]) for k in TARGET_COLUMNS}
    if any(r.get(MOVING_COLUMN) for r in rows):
        columns[MOVING_COLUMN] = np.array([int(bool(r.get(MOVING_COLUMN))) for r in rows])
    write_table(out / "targets.csv", columns, TARGET_FORMATS)
    write_json(out / "targets.json", {"version": 1, "method": method, "targets": rows})


def read_targets(path) -> list[dict]:
    """The rows of a targets.json written by ``write_targets``, in file order.

    Raises:
        UserError: a missing file, or one that is not a targets.json.
    """
    path = Path(path)
    try:
        rows = json.loads(path.read_text(encoding="utf-8"))["targets"]     # NaN: a value that does not exist
    except FileNotFoundError:
        raise UserError(f"{path}: no such file; run the targets step of 'wearable-gaze process' again") from None
    except (ValueError, KeyError, TypeError, UnicodeDecodeError) as exc:
        raise UserError(f"{path}: not a targets.json ({type(exc).__name__}: {exc}); run the targets step of "
                        "'wearable-gaze process' again (--force)") from None
    return rows


def write_target_paths(path, paths: dict) -> None:
    """Write target_paths.csv, atomically: ``paths`` maps a target index to its path as
    (t (K,) s, positions (K, 3) world mm, covariances (K, 3, 3) mm^2); rows in target order."""
    cols = {k: [] for k in PATH_COLUMNS}
    for index in sorted(paths):
        t, pos, cov = (np.asarray(a, float) for a in paths[index])
        cols["target"].append(np.full(len(t), int(index)))
        cols["t"].append(t)
        for j, name in enumerate("xyz"):
            cols[name].append(pos[:, j])
        for name, (i, j) in zip(PATH_COLUMNS[5:], _COV_INDEX, strict=True):
            cols[name].append(cov[:, i, j])
    out = {k: np.concatenate(v) if v else np.zeros(0, int if k == "target" else float) for k, v in cols.items()}
    write_table(path, out, PATH_FORMATS)


def read_target_paths(path) -> dict:
    """The paths of a target_paths.csv: {target index: (t (K,), positions (K, 3), covariances
    (K, 3, 3))}; a header alone is no path, not an error.

    Raises:
        UserError: a missing file or column, a cell that is not a number (one line).
    """
    cols = read_table(path, list(PATH_COLUMNS), what="target-path CSV (target_paths.csv)", rows_required=False)
    out = {}
    for index in dict.fromkeys(int(v) for v in cols["target"]):
        sel = cols["target"] == index
        cov = np.zeros((int(sel.sum()), 3, 3))
        for name, (i, j) in zip(PATH_COLUMNS[5:], _COV_INDEX, strict=True):
            cov[:, i, j] = cov[:, j, i] = cols[name][sel]
        out[index] = (cols["t"][sel], np.column_stack([cols[k][sel] for k in "xyz"]), cov)
    return out


def write_target_labels(path, labels: np.ndarray) -> None:
    """Write target_labels.npy: the target index of every view line of viewlines.csv (N,), -1
    none (NumPy's .npy format), atomically."""
    with atomic_path(path) as tmp:
        np.save(tmp, labels)


def read_target_labels(path) -> np.ndarray:
    """The (N,) target index of every view line, -1 none, of a target_labels.npy.

    Raises:
        UserError: a file that is not a NumPy array file.
    """
    try:
        return np.load(path)
    except (OSError, ValueError) as exc:
        raise UserError(f"{path}: not a target_labels.npy ({exc}); run the targets step of 'wearable-gaze process' "
                        "again (--force)") from None


def write_estimates(path, columns: dict) -> None:
    """Write the columns ``ESTIMATE_COLUMNS`` ((N,) each; N may be 0) as estimates.csv, atomically."""
    write_table(path, {k: np.asarray(columns[k]) for k in ESTIMATE_COLUMNS}, ESTIMATE_FORMATS)


def read_estimates(path) -> dict:
    """The columns of an estimates.csv, (N,) float each; a header alone (no fixation gave an
    estimate) is no estimate, not an error.

    Raises:
        UserError: a missing file, a missing column, a cell that is not a number (one line).
    """
    return read_table(path, list(ESTIMATE_COLUMNS), what="running-estimate CSV (estimates.csv)", rows_required=False)


DEVICE_COLUMNS = ("target", "n_samples", "ours_distance_mm", "device_depth_mm", "ours_x_mm", "ours_y_mm", "ours_z_mm")


def write_device_comparison(path, rows: list[dict]) -> None:
    """device_comparison.csv: one row per target with ``DEVICE_COLUMNS`` (mm; NaN: none)."""
    cols = {k: np.array([r[k] for r in rows], float if k.endswith("_mm") else int) for k in DEVICE_COLUMNS}
    write_table(path, cols, {k: ".1f" for k in DEVICE_COLUMNS if k.endswith("_mm")})


def read_device_comparison(path) -> dict:
    """device_comparison.csv -> {column: (N,) array} (``DEVICE_COLUMNS``; NaN where empty)."""
    mm = tuple(k for k in DEVICE_COLUMNS if k.endswith("_mm"))
    return read_table(path, list(DEVICE_COLUMNS), what="device-comparison CSV", empty_ok=mm, rows_required=False)

