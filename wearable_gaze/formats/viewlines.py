"""The view-line CSV: what ``wearable-gaze estimate`` reads and ``viewlines`` writes.

Format (documented in docs/formats.md): a header line, then one binocular sample per row.
Columns, in any order (extra columns ignored):

    t                                   sample time, seconds
    left_ox, left_oy, left_oz           left eye rotation centre, world frame, mm
    left_dx, left_dy, left_dz           left view direction, world frame (need not be unit)
    right_ox ... right_dz               the same for the right eye
    segment (optional)                  rows with equal values form one independent estimate

One eye's six cells may all be empty (a monocular sample); partly empty is an error.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimator import BinocularSamples

from ..errors import UserError
from .atomic import atomic_path
from .tables import open_csv, printable

EYE_COLUMNS = {side: [f"{side}_{k}" for k in ("ox", "oy", "oz", "dx", "dy", "dz")] for side in ("left", "right")}
REQUIRED = ["t", *EYE_COLUMNS["left"], *EYE_COLUMNS["right"]]
MAX_ABS = 1e10          # s, mm, or direction components (a direction need not be unit, but 1e200 overflows)


@dataclass(frozen=True)
class Segment:
    """The samples of one segment (``key`` is None when the file has no ``segment`` column)."""

    key: object
    samples: BinocularSamples
    first_line: int


def _segment_value(text: str):
    try:
        return int(text)
    except ValueError:
        return text


def read_viewlines_csv(path) -> list[Segment]:
    """Read a view-line CSV into segments in order of first appearance.

    Raises ``UserError`` naming the line and column of the first problem: a missing file or
    column, an empty file, text where a number belongs, a non-finite value, a partly empty eye,
    a zero direction.
    """
    path = Path(path)
    names, reader = open_csv(path, REQUIRED, "view-line CSV", "pass a view-line CSV (see docs/formats.md)")
    col = {n: i for i, n in enumerate(names)}
    if "left_valid" in col or "right_valid" in col:      # eye_rays.csv's columns (formats/eye_rays.py)
        raise UserError(f"{path}: an eye-ray CSV (an imported session's eye_rays.csv: each eye's "
                        "rays in the head frame, not view lines in the world); run 'wearable-gaze "
                        "process SESSION' and pass its processed/viewlines.csv")
    has_segment = "segment" in col
    rows: dict = {}
    order = []
    for line_no, row in enumerate(reader, start=2):
        if not any(cell.strip() for cell in row):
            continue
        if len(row) < len(names) and any(c in REQUIRED for c in names[len(row):]):
            raise UserError(f"{path} line {line_no}: {len(row)} cells, the header has {len(names)} "
                            "(truncated file?); complete or remove the row")
        t = _number(path, line_no, "t", row[col["t"]])
        left, right = (_eye(path, line_no, side, cols, row, col)
                       for side, cols in EYE_COLUMNS.items())
        if left is None and right is None:
            raise UserError(f"{path} line {line_no}: both eyes' cells are empty; give at least one "
                            "eye's six values or remove the row")
        key = _segment_value(row[col["segment"]].strip()) if has_segment else None
        if key not in rows:
            rows[key] = []
            order.append((key, line_no))
        rows[key].append((t, left, right))
    if not order:
        raise UserError(f"{path}: the header has no data rows below it; add one row per binocular sample")
    return [_segment(key, rows[key], first) for key, first in order]


def _number(path: Path, line_no: int, name: str, cell: str,
            allow_empty: bool = False) -> float | None:
    """The finite, plausible number in the cell of column ``name``; None for an empty cell when
    ``allow_empty``; else a ``UserError`` naming the line and column."""
    cell = cell.strip()
    if cell == "" and allow_empty:
        return None
    try:
        v = float(cell)
    except ValueError:
        raise UserError(f"{path} line {line_no}, column {name}: '{printable(cell)}' is not a "
                        "number; write a number there") from None
    if not np.isfinite(v):
        raise UserError(f"{path} line {line_no}, column {name}: '{printable(cell)}' is not a "
                        "finite number; write a finite number there")
    if abs(v) > MAX_ABS:
        raise UserError(f"{path} line {line_no}, column {name}: {cell} is beyond +-{MAX_ABS:g}, "
                        "not a plausible time, position (mm) or direction; fix the cell")
    return v


def _eye(path: Path, line_no: int, side: str, cols, row: list, col: dict) -> list | None:
    """One eye's six values (origin mm, direction) of a row, or None when all six are empty."""
    vals = [_number(path, line_no, c, row[col[c]], allow_empty=True) for c in cols]
    if all(v is None for v in vals):
        return None
    empty = [c for c, v in zip(cols, vals, strict=True) if v is None]
    if empty:
        raise UserError(f"{path} line {line_no}, column {empty[0]}: empty, but other {side}-eye "
                        f"cells are not; leave all six {side}_* cells empty for a monocular sample")
    if not np.linalg.norm(vals[3:]) > 1e-12:
        raise UserError(f"{path} line {line_no}, columns {side}_dx..{side}_dz: the direction is "
                        "zero; fix the direction or leave that eye's six cells empty")
    return vals


def _segment(key, rows: list, first_line: int) -> Segment:
    """A segment from its rows ``(t, left six values or None, right six or None)``."""
    nan6 = [np.nan] * 6
    t = np.array([x[0] for x in rows])
    left = np.array([x[1] if x[1] is not None else nan6 for x in rows])
    right = np.array([x[2] if x[2] is not None else nan6 for x in rows])
    samples = BinocularSamples.from_arrays(t, left[:, :3], left[:, 3:], right[:, :3], right[:, 3:])
    return Segment(key, samples, first_line)


def write_viewlines_csv(path, samples: BinocularSamples, segment=None) -> None:
    """Write samples (world frame) in the view-line CSV format, atomically. ``segment``: None,
    one value for all rows, or an (N,) sequence."""
    if samples.frame != "world":
        raise ValueError(f"samples must be in the world frame, got {samples.frame!r}")
    n = len(samples)
    seg = None if segment is None else (list(segment) if np.ndim(segment) else [segment] * n)
    with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(REQUIRED + (["segment"] if seg is not None else []))
        for i in range(n):
            cells = [repr(float(samples.t_s[i]))]
            for o, d, v in ((samples.left_origin_mm, samples.left_direction, samples.left_valid),
                            (samples.right_origin_mm, samples.right_direction, samples.right_valid)):
                cells += [f"{x:.6f}" for x in o[i]] + [f"{x:.9f}" for x in d[i]] if v[i] else [""] * 6
            w.writerow(cells + ([seg[i]] if seg is not None else []))
