"""Numeric CSV tables (eye samples, timestamps, poses): one reader that names the file, line and
column of the first problem, and one atomic writer."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from ..errors import UserError
from .atomic import atomic_path


def read_table(path, required, text_columns=(), what: str = "table", fix: str = "", empty_ok=(),
               max_abs: float = 1e10, rows_required: bool = True) -> dict:
    """Read a CSV with a header into {column: (N,) array}.

    Args:
        path: the file.
        required: numeric columns that must be present (extra columns are read if numeric,
            else ignored).
        text_columns: columns kept as strings.
        what: what the file is, for messages ("eye-sample CSV").
        fix: a hint appended to "missing file" messages.
        empty_ok: columns whose empty cells mean "no value" (NaN), e.g. a frame without a pose.
        max_abs: largest plausible magnitude of a required column's values (1e10: ten billion
            seconds, millimetres or sensor counts).
        rows_required: False where a header alone is a valid file (no records): then the
            required columns come back empty.

    Raises:
        UserError: missing file or column, a repeated column, an empty file, a file that is not
            UTF-8 text, a cell that is not a finite number or beyond ``max_abs``.
    """
    path = Path(path)
    names, reader = open_csv(path, required, what, fix or f"pass a {what} (check the path)")
    rows = [r for r in reader if any(c.strip() for c in r)]
    if not rows:
        if not rows_required:
            return {c: np.zeros(0) for c in required}
        raise UserError(f"{path}: the {what} has a header but no data rows; add one row per record")
    out = {}
    width = len(names)
    short = [i for i, r in enumerate(rows) if len(r) < width]
    if short and any(c in required for c in names[len(rows[short[0]]):]):
        i = short[0]
        raise UserError(f"{path} line {i + 2}: {len(rows[i])} cells, the header has {width} (truncated file?); "
                        "complete or remove the row")
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
                    raise UserError(f"{path} line {i + 2}, column {name}: '{printable(c)}' is not a number; write a "
                                    "number there") from None
        bad = np.flatnonzero(~np.isfinite(vals) & ~(np.array([c == "" for c in cells], bool) & (name in empty_ok)))
        if len(bad) and name in required:
            raise UserError(f"{path} line {bad[0] + 2}, column {name}: '{printable(cells[bad[0]])}' is not a finite "
                            "number; write a finite number there")
        huge = np.flatnonzero(np.abs(np.nan_to_num(vals)) > max_abs)
        if len(huge) and name in required:
            raise UserError(f"{path} line {huge[0] + 2}, column {name}: {cells[huge[0]]} is beyond +-{max_abs:g}, "
                            "not a plausible value; fix the cell")
        out[name] = vals
    return out


def open_csv(path, required, what: str, fix: str):
    """Open a CSV and check its header: (column names, a ``csv.reader`` over the data rows).

    Raises:
        UserError: missing file ("no such file; " + ``fix``), empty file, missing columns.
    """
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: {'a folder, not a file' if path.is_dir() else 'no such file'}; {fix}")
    data = path.read_bytes()
    if data[:2] in (b"\xff\xfe", b"\xfe\xff") or b"\x00" in data[:4096]:
        raise UserError(f"{path}: the {what} is UTF-16 or binary, not text; save it as UTF-8 CSV")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise UserError(f"{path}: the {what} is not UTF-8 text (byte {exc.start}); save it as UTF-8 CSV") from None
    reader = csv.reader(io.StringIO(text, newline=""))
    try:
        header = next(reader, None)
    except csv.Error as exc:
        raise UserError(f"{path} line 1: the {what} header is not CSV ({exc})") from None
    if header is None or not any(h.strip() for h in header):
        raise UserError(f"{path}: the {what} is empty; write a header line with columns {', '.join(required)} and "
                        "the data below it")
    names = [h.strip() for h in header]
    dup = sorted({n for n in names if n and names.count(n) > 1})
    if dup:
        raise UserError(f"{path}: column {printable(dup[0])} appears more than once in the {what} header; "
                        "remove the repeated column")
    missing = [c for c in required if c not in names]
    if missing:
        has = printable(", ".join(n for n in names if n), 120) if any(names) else "nothing"
        raise UserError(f"{path}: missing column(s) {', '.join(missing)} in the {what} header (it has: {has}); "
                        "add them to the header line")
    return names, _rows(path, reader, what)


def _rows(path, reader, what):
    """The rows of a ``csv.reader``, a malformed row turned into a ``UserError``."""
    try:
        yield from reader
    except csv.Error as exc:
        raise UserError(f"{path} line {reader.line_num}: the {what} is not valid CSV ({exc})") from None


def printable(text: str, limit: int = 60) -> str:
    """``text`` with control and non-ASCII characters escaped, cut to ``limit`` characters: safe
    to echo in a one-line message."""
    out = text.encode("ascii", "backslashreplace").decode("ascii")
    out = "".join(c if c.isprintable() else repr(c)[1:-1] for c in out)
    return out if len(out) <= limit else out[:limit - 3] + "..."


def _cells(columns: dict, formats: dict) -> list[list[str]]:
    """The cells of {name: (N,) values}, column by column: ``formats[name]`` ('.3f') where
    given, else ``repr`` for floats (empty for NaN), 1/0 for booleans, ``str`` otherwise."""
    cols = []
    for name, v in columns.items():
        fmt = formats.get(name)
        if fmt is not None:
            cols.append(["" if isinstance(x, float) and np.isnan(x) else format(x, fmt) for x in v])
        elif isinstance(v, np.ndarray) and v.dtype.kind == "f":
            cols.append(["" if np.isnan(x) else repr(float(x)) for x in v])
        elif isinstance(v, np.ndarray) and v.dtype.kind == "b":
            cols.append(["1" if x else "0" for x in v])
        else:
            cols.append([str(x) for x in v])
    return cols


class TableWriter:
    """A CSV written in chunks, atomically: rows go to a temporary sibling and the file appears
    under its name only when the ``with`` block ends without an error (memory stays flat in the
    table's length; a reader never sees half a table).

    Use: ``with TableWriter(path, names, formats) as w: w.write({name: (n,) values}); ...``
    """

    def __init__(self, path, names, formats: dict | None = None):
        self.path = Path(path)
        self.names = list(names)
        self.formats = formats or {}
        self.n_rows = 0
        self._ctx = self._fh = self._w = None

    def __enter__(self) -> TableWriter:
        self._ctx = atomic_path(self.path)
        tmp = self._ctx.__enter__()
        self._fh = open(tmp, "w", newline="", encoding="utf-8")
        self._w = csv.writer(self._fh)
        self._w.writerow(self.names)
        return self

    def write(self, columns: dict) -> None:
        """Append rows: {name: (n,) values} for every column of the header."""
        missing = [c for c in self.names if c not in columns]
        if missing:
            raise ValueError(f"{self.path.name}: chunk lacks column(s) {', '.join(missing)}")
        cols = _cells({k: columns[k] for k in self.names}, self.formats)
        n = len(cols[0]) if cols else 0
        if any(len(c) != n for c in cols):
            raise ValueError(f"{self.path.name}: the chunk's columns differ in length")
        self._w.writerows(zip(*cols, strict=True))
        self.n_rows += n

    def __exit__(self, exc_type, exc, tb):
        self._fh.close()
        return self._ctx.__exit__(exc_type, exc, tb)


def write_table(path, columns: dict, formats: dict | None = None) -> None:
    """Write {name: (N,) values} as a CSV, atomically. ``formats``: name -> format spec
    ('.3f'); default ``repr`` for floats, ``str`` otherwise."""
    with TableWriter(path, list(columns), formats) as w:
        if columns:
            w.write(columns)
