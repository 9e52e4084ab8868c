"""Numeric CSV tables (eye samples, timestamps, poses): one reader that names the file, line and
column of the first problem, and one atomic writer."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from .atomic import atomic_path
from .errors import UserError


def read_table(path, required, text_columns=(), what: str = "table", fix: str = "", empty_ok=()) -> dict:
    """Read a CSV with a header into {column: (N,) array}.

    Args:
        path: the file.
        required: numeric columns that must be present (extra columns are read if numeric,
            else ignored).
        text_columns: columns kept as strings.
        what: what the file is, for messages ("eye-sample CSV").
        fix: a hint appended to "missing file" messages.
        empty_ok: columns whose empty cells mean "no value" (NaN), e.g. a frame without a pose.

    Raises:
        UserError: missing file or column, empty file, a cell that is not a finite number.
    """
    path = Path(path)
    names, reader = open_csv(path, required, what, fix or f"expected a {what}")
    rows = [r for r in reader if any(c.strip() for c in r)]
    out = {}
    width = len(names)
    for j, name in enumerate(names):
        if not name:
            continue
        cells = [(r[j].strip() if j < len(r) else "") for r in rows]
        if name in text_columns:
            out[name] = np.array(cells, dtype=object)
            continue
        try:
            vals = np.array([float(c) if c or name not in empty_ok else np.nan for c in cells], float) \
                if cells else np.zeros(0)
        except ValueError:
            if name not in required:
                continue
            for i, c in enumerate(cells):
                try:
                    float(c)
                except ValueError:
                    raise UserError(f"{path} line {i + 2}, column {name}: {c!r} is not a number") from None
        bad = np.flatnonzero(~np.isfinite(vals) & ~(np.array([c == "" for c in cells], bool) & (name in empty_ok)))
        if len(bad) and name in required:
            raise UserError(f"{path} line {bad[0] + 2}, column {name}: {cells[bad[0]]!r} is not a finite number")
        out[name] = vals
    short = [i for i, r in enumerate(rows) if len(r) < width]
    if short and any(c in required for c in names[min(len(rows[short[0]]), width - 1):]):
        i = short[0]
        raise UserError(f"{path} line {i + 2}: {len(rows[i])} cells, the header has {width} (truncated file?)")
    return out


def open_csv(path, required, what: str, fix: str):
    """Open a CSV and check its header: (column names, a ``csv.reader`` over the data rows).

    Raises:
        UserError: missing file ("no such file; " + ``fix``), empty file, missing columns.
    """
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: no such file; {fix}")
    text = path.read_text(encoding="utf-8-sig", errors="replace")
    reader = csv.reader(io.StringIO(text))
    header = next(reader, None)
    if header is None or not any(h.strip() for h in header):
        raise UserError(f"{path}: the {what} is empty; expected a header line with columns {', '.join(required)}")
    names = [h.strip() for h in header]
    missing = [c for c in required if c not in names]
    if missing:
        raise UserError(f"{path}: missing column(s) {', '.join(missing)} in the {what} header "
                        f"(it has: {', '.join(n for n in names if n) or 'nothing'})")
    return names, reader


def write_table(path, columns: dict, formats: dict | None = None) -> None:
    """Write {name: (N,) values} as a CSV, atomically. ``formats``: name -> format spec
    ('.3f'); default ``repr`` for floats, ``str`` otherwise."""
    formats = formats or {}
    names = list(columns)
    n = len(next(iter(columns.values()))) if names else 0
    cols = []
    for name in names:
        v = columns[name]
        fmt = formats.get(name)
        if fmt is not None:
            cols.append(["" if isinstance(x, float) and np.isnan(x) else format(x, fmt) for x in v])
        elif isinstance(v, np.ndarray) and v.dtype.kind == "f":
            cols.append(["" if np.isnan(x) else repr(float(x)) for x in v])
        elif isinstance(v, np.ndarray) and v.dtype.kind == "b":
            cols.append(["1" if x else "0" for x in v])
        else:
            cols.append([str(x) for x in v])
    with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(names)
        for i in range(n):
            w.writerow([c[i] for c in cols])
