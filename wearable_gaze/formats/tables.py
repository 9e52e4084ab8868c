"""Numeric CSV tables (eye samples, timestamps, poses): a reader of whole files (``read_table``), a
streaming one for long device files (``csv_header``, ``iter_csv_chunks``, ``chunk_numbers``: memory
flat in the file's length, gzip aware), both naming the file, line and column of the first problem,
and one atomic writer (``TableWriter``). A format's ``Checks`` (its required columns, those whose
empty cells mean no value, those in squared units) are applied by its writer before a row is
written and by its reader after: whatever a writer writes, its reader accepts.
"""

from __future__ import annotations

import csv
import gzip
import io
import zlib
from array import array
from dataclasses import dataclass
from operator import itemgetter
from pathlib import Path

import numpy as np

from ..errors import UserError
from .atomic import atomic_path

MAX_ABS = 1e10
"""The largest plausible magnitude of a table's value (ten billion seconds, millimetres or sensor
counts)."""
MAX_ABS_SQUARED = MAX_ABS ** 2
"""... of a value in squared units (a variance or covariance, mm^2): its standard deviation within
``MAX_ABS``. A vergence-only depth whose view lines are nearly parallel has a variance of 1e12
mm^2 (a 1 km standard deviation): honest, and far beyond ``MAX_ABS``."""


@dataclass(frozen=True)
class Checks:
    """What the numeric columns of one CSV format may hold: the one check that its writer
    applies to the values it is about to write (``write_table(checks=)``, ``TableWriter``) and
    its reader to the cells it read (``read_table(checks=)``).

    Attributes:
        required: the numeric columns every file has.
        empty_ok: columns whose empty cell (NaN when written) means "no value".
        squared: columns in squared units (covariances, mm^2), bounded by ``MAX_ABS_SQUARED``;
            the others by ``max_abs``.
        what: what the file is, for messages ("pose CSV").
        max_abs: the bound of the other columns.
    """

    required: tuple
    empty_ok: tuple = ()
    squared: tuple = ()
    what: str = "table"
    max_abs: float = MAX_ABS

    def bound(self, name: str) -> float:
        return MAX_ABS_SQUARED if name in self.squared else self.max_abs

    def problem(self, name: str, values: np.ndarray, empty: np.ndarray) -> tuple[int, str] | None:
        """The first value of column ``name`` this format does not allow, as (row index, why),
        or None: not a finite number (NaN allowed where ``empty`` and the column is
        ``empty_ok``), or beyond ``bound(name)``."""
        if name not in self.required or not len(values):
            return None
        bad = np.flatnonzero(~np.isfinite(values) & ~(empty & (name in self.empty_ok)))
        if len(bad):
            return int(bad[0]), "is not a finite number"
        huge = np.flatnonzero(np.abs(np.nan_to_num(values)) > self.bound(name))
        if len(huge):
            return int(huge[0]), f"is beyond +-{self.bound(name):g}, not a plausible value"
        return None

    def check_written(self, path, columns: dict, first_row: int = 0) -> None:
        """Refuse values about to be written as ``path`` that its reader would refuse.

        Raises:
            UserError: one line naming the file, column, row and value.
        """
        for name in self.required:
            if name not in columns:
                continue
            v = np.asarray(columns[name])
            if v.dtype.kind not in "fiub":
                continue
            v = v.astype(float)
            found = self.problem(name, v, np.isnan(v))
            if found is not None:
                i, why = found
                raise UserError(f"{path}: the {self.what} would hold {v[i]:g} in column {name}, row "
                                f"{first_row + i + 1}, which {why}; not written, as its reader would refuse it "
                                "(a fault in the step that computed it: please report it)")


def read_table(path, required, text_columns=(), what: str = "table", fix: str = "", empty_ok=(),
               max_abs: float = MAX_ABS, rows_required: bool = True, checks: Checks | None = None) -> dict:
    """Read a CSV with a header into {column: (N,) array}.

    Args:
        path: the file.
        required: numeric columns that must be present (extra columns are read if numeric,
            else ignored).
        text_columns: columns kept as strings.
        what: what the file is, for messages ("eye-sample CSV").
        fix: a hint appended to "missing file" messages.
        empty_ok: columns whose empty cells mean "no value" (NaN), e.g. a frame without a pose.
        max_abs: largest plausible magnitude of a required column's values (``MAX_ABS``).
        rows_required: False where a header alone is a valid file (no records): then the
            required columns come back empty.
        checks: the format's ``Checks``, the ones its writer applied (then ``required``,
            ``empty_ok``, ``what`` and ``max_abs`` are taken from it).

    Raises:
        UserError: missing file or column, a repeated column, an empty file, a file that is not
            UTF-8 text, a cell that is not a finite number or beyond ``max_abs``.
    """
    path = Path(path)
    if checks is None:
        checks = Checks(tuple(required), tuple(empty_ok), (), what, max_abs)
    required, what = list(checks.required), checks.what
    names, reader = open_csv(path, required, what, fix or f"pass a {what} (check the path)")
    rows = [r for r in reader if any(c.strip() for c in r)]
    if not rows:
        if not rows_required:
            return {c: np.zeros(0) for c in required}
        raise UserError(f"{path}: the {what} has a header but no data rows; add one row per record")
    width = len(names)
    short = [i for i, r in enumerate(rows) if len(r) < width]
    if short and any(c in required for c in names[len(rows[short[0]]):]):
        i = short[0]
        raise UserError(f"{path} line {i + 2}: {len(rows[i])} cells, the header has {width} "
                        "(truncated file?); complete or remove the row")
    out = {}
    for j, name in enumerate(names):
        if not name:
            continue
        cells = [(r[j].strip() if j < len(r) else "") for r in rows]
        if name in text_columns:
            out[name] = np.array(cells, dtype=object)
            continue
        vals = _numeric_column(path, name, cells, checks)
        if vals is not None:
            out[name] = vals
    return out


def _numeric_column(path: Path, name: str, cells: list[str], checks: Checks) -> np.ndarray | None:
    """A column's cells (data rows from file line 2) as an (N,) float array, checked by
    ``checks``; None for a column that is not numeric and not required.

    Raises:
        UserError: a required column's cell that is not a number; a cell ``checks`` refuses.
    """
    try:
        empty_is_nan = name in checks.empty_ok
        vals = np.array([float(c) if c or not empty_is_nan else np.nan for c in cells], float) \
            if cells else np.zeros(0)
    except ValueError:
        if name not in checks.required:
            return None
        for i, c in enumerate(cells):
            try:
                float(c)
            except ValueError:
                raise not_a_number(path, i + 2, name, c) from None
        raise AssertionError("unreachable: a cell failed float() once") from None
    found = checks.problem(name, vals, np.array([c == "" for c in cells], bool))
    if found is not None:
        i, why = found
        raise UserError(f"{path} line {i + 2}, column {name}: '{printable(cells[i])}' {why}; "
                        + ("write a finite number there" if "finite" in why else "fix the cell"))
    return vals


def open_csv(path, required, what: str, fix: str):
    """Open a CSV and check its header: (column names, a ``csv.reader`` over the data rows).

    Raises:
        UserError: missing file ("no such file; " + ``fix``), empty file, missing columns.
    """
    path = Path(path)
    _require_file(path, fix)
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
    names = check_header(path, header, what, required,
                         f"write a header line with columns {', '.join(required)} and the data below it")
    return names, _rows(path, reader, what)


def _require_file(path: Path, fix: str) -> None:
    if not path.is_file():
        raise UserError(f"{path}: {'a folder, not a file' if path.is_dir() else 'no such file'}; {fix}")


def check_header(path, header, what: str, required, empty_fix: str,
                 columns_fix: str = "add them to the header line") -> list[str]:
    """The column names of a CSV's header row (cells stripped), checked.

    Raises:
        UserError: no header ("... is empty; " + ``empty_fix``), a column named twice, a
            ``required`` column missing ("...; " + ``columns_fix``).
    """
    names = [h.strip() for h in header or ()]
    if not any(names):
        raise UserError(f"{path}: the {what} is empty; {empty_fix}")
    dup = sorted({n for n in names if n and names.count(n) > 1})
    if dup:
        raise UserError(f"{path}: column {printable(dup[0])} appears more than once in the {what} header; "
                        "remove the repeated column")
    missing = [c for c in required if c not in names]
    if missing:
        has = printable(", ".join(n for n in names if n), 120)
        raise UserError(f"{path}: missing column(s) {', '.join(missing)} in the {what} header (it has: {has}); "
                        f"{columns_fix}")
    return names


def not_a_number(path, line: int, name: str, cell: str, fix: str = "write a number there") -> UserError:
    """The error of a cell that should hold a number."""
    return UserError(f"{path} line {line}, column {name}: '{printable(cell)}' is not a number; {fix}")


def _rows(path, reader, what):
    """The rows of a ``csv.reader``, a malformed row turned into a ``UserError``."""
    try:
        yield from reader
    except csv.Error as exc:
        raise UserError(f"{path} line {reader.line_num}: the {what} is not valid CSV ({exc})") from None


# --- streaming ---------------------------------------------------------------------------------

_GZIP_ERRORS = (EOFError, gzip.BadGzipFile, zlib.error)


def _open_text(path: Path, errors: str = "strict"):
    """A CSV file as text (UTF-8, a BOM skipped), gunzipped on the fly when it ends in .gz."""
    if path.suffix == ".gz":
        return gzip.open(path, "rt", newline="", encoding="utf-8-sig", errors=errors)
    return open(path, newline="", encoding="utf-8-sig", errors=errors)


def _raw_position(fh) -> int:
    """How far into the file on disk a text handle has read, bytes."""
    raw = getattr(fh.buffer, "fileobj", None)            # a GzipFile: its compressed file
    return (raw or fh.buffer).tell()


def csv_header(path, what: str, fix: str, required=(), columns_fix: str = "add them to the header line") -> list[str]:
    """The column names of a CSV or gzipped CSV (its first line), checked (``check_header``).

    Raises:
        UserError: missing file or empty file ("...; " + ``fix``), not gzip data where the name
            ends in .gz, a header that is not CSV, a repeated column, a ``required`` column missing.
    """
    path = Path(path)
    _require_file(path, fix)
    try:
        with _open_text(path, errors="replace") as fh:
            header = next(csv.reader(fh), None)
    except csv.Error as exc:
        raise UserError(f"{path} line 1: the {what} header is not CSV ({exc})") from None
    except _GZIP_ERRORS as exc:
        raise UserError(f"{path}: the {what} is not a complete gzip file ({exc}); is the file damaged?") from None
    return check_header(path, header, what, required, fix, columns_fix)


def iter_csv_chunks(path, what: str, rows_per_chunk: int, progress=None, errors: str = "strict"):
    """Stream the data rows of a CSV (gunzipped when its name ends in .gz; UTF-8, a BOM skipped):
    yield (rows, lines), ``rows_per_chunk`` rows at a time: rows as lists of cells (empty lines
    skipped; rows shorter or longer than the header as they are) and the file line of each (an
    ``array('q')``). Check the header first with ``csv_header``. ``progress(bytes read, file
    size)`` after each chunk; ``errors='replace'`` reads bytes that are not UTF-8 as U+FFFD
    instead of refusing the file.

    Raises:
        UserError: a row that is not CSV, bytes that are not UTF-8, broken gzip data (one line
            naming the file and line).
    """
    path = Path(path)
    total = path.stat().st_size
    with _open_text(path, errors) as fh:
        reader = csv.reader(fh)
        rows, lines = [], array("q")
        try:
            next(reader, None)
            for row in reader:
                if row:
                    rows.append(row)
                    lines.append(reader.line_num)
                    if len(rows) >= rows_per_chunk:
                        box, rows, lines = [(rows, lines)], [], array("q")
                        yield box.pop()         # no reference kept here while the caller works on it
                        if progress:
                            progress(min(_raw_position(fh), total), total)
        except csv.Error as exc:
            raise UserError(f"{path} line {reader.line_num}: the {what} is not valid CSV ({exc})") from None
        except UnicodeDecodeError:
            raise UserError(f"{path} after line {reader.line_num}: the {what} is not UTF-8 text; is the file "
                            "damaged?") from None
        except _GZIP_ERRORS as exc:
            raise UserError(f"{path} after line {reader.line_num}: the {what} is not a complete gzip file ({exc}); "
                            "is the file damaged or cut short?") from None
    if rows:
        yield rows, lines
    if progress:
        progress(total, total)


def chunk_numbers(rows, index: dict, names, lines=None, path=None,
                  fix: str = "write a number there") -> tuple[dict, np.ndarray, np.ndarray]:
    """The named columns of a chunk of rows as numbers.

    Args:
        rows: lists of cells (``iter_csv_chunks``).
        index: {column name: cell index} of the header (its widest index is the width a row
            needs to be whole).
        names: the columns wanted (in ``index``).
        lines, path: the rows' file lines and the file: given, a cell that is neither empty
            nor a number raises (the first one, in file order), else it is NaN.

    Returns:
        ({name: (n,) float}, NaN where empty or not a number or the row is not whole; whole (n,)
        bool: the row has every header cell; finite (n,) bool: whole and every named cell finite).

    Raises:
        UserError: with ``lines``, a cell that is not a number (``not_a_number`` + ``fix``).
    """
    width = max(index.values(), default=-1) + 1
    whole = np.fromiter((len(r) >= width for r in rows), bool, len(rows))
    kept = rows if whole.all() else [r for r, w in zip(rows, whole, strict=True) if w]
    out, finite, bad = {}, whole.copy(), []
    for k, name in enumerate(names):
        cells = list(map(itemgetter(index[name]), kept))        # one column at a time: memory
        try:
            v = np.array(cells, dtype=float)
        except ValueError:
            vals = [_float(c) for c in cells]
            if lines is not None and None in vals:
                bad.append((vals.index(None), k))
            v = np.array([np.nan if x is None else x for x in vals], float)
        out[name] = np.full(len(rows), np.nan)
        out[name][whole] = v
        finite &= np.isfinite(out[name])
    if bad:
        i, k = min(bad)
        raise not_a_number(path, np.asarray(lines)[whole][i], names[k], kept[i][index[names[k]]], fix)
    return out, whole, finite


def _float(cell: str) -> float | None:
    """A cell's number: NaN if empty, None if not a number."""
    try:
        return float(cell)
    except ValueError:
        return np.nan if not cell.strip() else None


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

    Use: ``with TableWriter(path, names, formats) as w: w.write({name: (n,) values}); ...``;
    with ``checks`` (the format's ``Checks``), a chunk holding a value its reader would refuse
    raises ``UserError`` and no file is written.
    """

    def __init__(self, path, names, formats: dict | None = None, checks: Checks | None = None):
        self.path = Path(path)
        self.names = list(names)
        self.formats = formats or {}
        self.checks = checks
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
        if self.checks is not None:
            self.checks.check_written(self.path, columns, self.n_rows)
        cols = _cells({k: columns[k] for k in self.names}, self.formats)
        n = len(cols[0]) if cols else 0
        if any(len(c) != n for c in cols):
            raise ValueError(f"{self.path.name}: the chunk's columns differ in length")
        self._w.writerows(zip(*cols, strict=True))
        self.n_rows += n

    def __exit__(self, exc_type, exc, tb):
        self._fh.close()
        return self._ctx.__exit__(exc_type, exc, tb)


def write_table(path, columns: dict, formats: dict | None = None, checks: Checks | None = None) -> None:
    """Write {name: (N,) values} as a CSV, atomically. ``formats``: name -> format spec
    ('.3f'); default ``repr`` for floats, ``str`` otherwise. ``checks``: the format's
    ``Checks``: a value its reader would refuse raises ``UserError``, nothing written."""
    if checks is not None:
        checks.check_written(path, columns)
    with TableWriter(path, list(columns), formats) as w:
        if columns:
            w.write(columns)
