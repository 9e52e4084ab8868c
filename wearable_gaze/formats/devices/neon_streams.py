"""Neon's native binary streams read in ranges, with memory flat in the recording's length
(used by ``formats/devices/neon.py``; docs/importers.md "Pupil Labs Neon").

A Neon stream ``<base>`` is a sequence of parts ``<base> ps1.raw``, ``ps2.raw``, ... of fixed-size
records, each with a ``.time`` file of little-endian int64 Unix ns (``worn`` uses gaze's ``.time``
files; ``gaze_200hz.raw``/``worn_200hz.raw`` pair with ``gaze_200hz.time``). Pupil Labs' reader
(``pupil_labs.neon_recording``) finds and orders the parts (``find_sorted_multipart_files``); the
record layout is ``<base>.dtype`` where the folder has it, else the reader's built-in dtype,
exactly as the reader's ``Array.load_array`` picks it. The reader then loads a whole stream with
``np.fromfile``; here a part is memory-mapped (``np.memmap``) for each range or lookup, only the
records asked for are copied out, and the mapping is closed again, so neither the Python heap nor
the resident set grows with the recording's length.

Records and times are matched per part: part k's i-th record has part k's i-th time, and each part
is cut to the shorter of its ``.raw`` and ``.time``; ``Stream.cut`` counts the records and times
cut. (The reader cuts the concatenation of all parts once, which is the same for a single part
but shifts every later part's times when an earlier part is short.)
"""

from __future__ import annotations

import ast
import logging
from pathlib import Path

import numpy as np

from ...errors import UserError

log = logging.getLogger(__name__)

TIME_DTYPE = np.dtype("<i8")
LOOKAHEAD = 8
"""``in_time_order`` compares a time with the next this many: a run of up to half as many
damaged times far ahead is dropped alone."""
CALIBRATION_BYTES = 803
"""The size of calibration.bin's one record (``neon.CALIBRATION_DTYPE``, the reader's ``calib.py``)."""


def vendor():
    """Pupil Labs' reader module, or a UserError saying which extra to install."""
    try:
        import pupil_labs.neon_recording as nr
        import pupil_labs.neon_recording.utils  # noqa: F401
    except ImportError:
        raise UserError("the pupil-neon importer needs Pupil Labs' reader: pip install 'wearable-gaze[neon]'") from None
    return nr


def stream_pairs(src: Path, base: str) -> list[tuple[Path, Path]]:
    """The (``.raw``, ``.time``) files of stream ``base`` in part order, as the reader pairs them:
    ``<base>_200hz.raw`` with ``gaze_200hz.time`` when both exist (gaze and worn), else the
    ``<base> ps*.raw`` parts that have a ``.time`` file."""
    nr = vendor()
    if base in ("gaze", "worn"):
        raw, time = src / f"{base}_200hz.raw", src / "gaze_200hz.time"
        if raw.exists() and time.exists():
            return [(raw, time)]
    return [(Path(r), Path(t)) for r, t in nr.utils.find_sorted_multipart_files(src, base)]


def record_dtype(raw: Path, fallback: np.dtype) -> np.dtype:
    """The record layout of ``raw``: its stream's ``.dtype`` file (``<basename>.dtype``, the
    basename cut at " ps") where present, else ``fallback`` (the reader's built-in dtype)."""
    dtype_file = raw.parent / f"{raw.stem.split(' ps')[0]}.dtype"
    if not dtype_file.is_file():
        return np.dtype(fallback)
    try:
        return np.dtype(ast.literal_eval(dtype_file.read_text()))
    except (ValueError, TypeError, SyntaxError) as exc:
        raise UserError(f"{dtype_file}: not a readable record layout ({exc.__class__.__name__}); copy the file "
                        "again from the recording") from None


class Stream:
    """One stream's parts, memory-mapped, records and times matched per part.

    Attributes:
        n: records usable (the sum over parts of the shorter of ``.raw`` and ``.time``).
        cut: records or times cut because a part's ``.raw`` and ``.time`` differ in length.
        dtype: the record layout.
    """

    def __init__(self, pairs: list[tuple[Path, Path]], fallback: np.dtype):
        self.parts: list[tuple[Path, Path, int]] = []     # (.raw, .time, records used)
        self.cut = 0
        self.dtype = np.dtype(fallback)
        for i, (raw, time) in enumerate(pairs):
            dt = record_dtype(raw, fallback)
            if i == 0:
                self.dtype = dt
            elif dt != self.dtype:
                raise UserError(f"{raw}: its record layout differs from the stream's first part; copy the "
                                "recording folder again")
            n_raw, rest = divmod(raw.stat().st_size, dt.itemsize)
            if rest:
                raise UserError(f"{raw}: ends in a partial {dt.itemsize}-byte record (the file was cut short); cut "
                                f"it to whole records with: truncate -s {n_raw * dt.itemsize} '{raw}'")
            n_time = time.stat().st_size // TIME_DTYPE.itemsize
            n = min(n_raw, n_time)
            self.cut += abs(n_raw - n_time)
            if n:
                self.parts.append((raw, time, n))
        self.starts = np.cumsum([0] + [n for _, _, n in self.parts])
        self.n = int(self.starts[-1])

    def _map(self, k: int, times_only: bool = False):
        """Part k mapped: (records, times) memmaps of its first n entries (records None with ``times_only``)."""
        raw, time, n = self.parts[k]
        return (None if times_only else np.memmap(raw, self.dtype, "r", shape=(n,)),
                np.memmap(time, TIME_DTYPE, "r", shape=(n,)))

    def _spans(self, a: int, b: int):
        """(part, lo, hi, out_lo) for the global records a..b-1 (clipped to the stream)."""
        a, b = max(0, a), min(b, self.n)
        for k, (s, e) in enumerate(zip(self.starts[:-1], self.starts[1:], strict=True)):
            lo, hi = max(a, s), min(b, e)
            if lo < hi:
                yield k, lo - s, hi - s, lo - a

    def read(self, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
        """Records a..b-1 (global, across parts): (times (m,) int64 ns, records (m,) of ``dtype``), copies."""
        m = max(0, min(b, self.n) - max(a, 0))
        t, rec = np.empty(m, np.int64), np.empty(m, self.dtype)
        for k, lo, hi, o in self._spans(a, b):
            records, times = self._map(k)
            t[o:o + hi - lo] = times[lo:hi]
            rec[o:o + hi - lo] = records[lo:hi]
            del records, times
        return t, rec

    def searchsorted(self, t_ns: np.ndarray, side: str = "left") -> np.ndarray:
        """``np.searchsorted`` of ``t_ns`` in the stream's times (taken as increasing across parts)."""
        t_ns = np.asarray(t_ns, np.int64)
        out = np.zeros(len(t_ns), np.int64)
        for k in range(len(self.parts)):
            times = self._map(k, times_only=True)[1]
            out += np.searchsorted(times, t_ns, side=side)
            del times
        return out

    def take(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Times and records at the global indices ``idx`` (each in 0..n-1)."""
        idx = np.asarray(idx, np.int64)
        t, rec = np.empty(len(idx), np.int64), np.empty(len(idx), self.dtype)
        for k, (s, e) in enumerate(zip(self.starts[:-1], self.starts[1:], strict=True)):
            sel = (idx >= s) & (idx < e)
            if sel.any():
                records, times = self._map(k)
                t[sel] = times[idx[sel] - s]
                rec[sel] = records[idx[sel] - s]
                del records, times
        return t, rec


def open_stream(src: Path, base: str, fallback: np.dtype) -> Stream | None:
    """Stream ``base`` of the Neon folder ``src``, or None when it has no part with a ``.time`` file."""
    pairs = stream_pairs(src, base)
    return Stream(pairs, fallback) if pairs else None


def read_calibration(rec, src: Path):
    """calibration.bin by the vendor's reader ``rec`` (None: the folder ``src`` has none).

    Raises:
        UserError: a file shorter than one record, a serial number that is not UTF-8, or a scene
            camera matrix that is not finite and positive (a damaged copy; the reader failed with an
            IndexError on a short one, a UnicodeDecodeError on a bad serial).
    """
    path = Path(src) / "calibration.bin"
    if not path.is_file():
        return None
    size = path.stat().st_size
    fix = "copy it again from the recording, or delete it and give the scene camera's calibration with --camera"
    if size < CALIBRATION_BYTES:
        raise UserError(f"{path}: {size} bytes, shorter than Neon's {CALIBRATION_BYTES}-byte calibration record "
                        f"(a damaged copy); {fix}")
    cal = rec.calibration
    try:
        str(cal.serial)                          # the vendor's reader decodes it as UTF-8 when asked
    except UnicodeDecodeError:
        raise UserError(f"{path}: the serial number is not UTF-8 text (a damaged copy); {fix}") from None
    K = np.asarray(cal.scene_camera_matrix, float)
    if not (np.all(np.isfinite(K)) and K[0, 0] > 0 and K[1, 1] > 0):
        raise UserError(f"{path}: the scene camera matrix is not finite and positive (a damaged copy); {fix}")
    return cal


def in_time_order(t_ns: np.ndarray, t_next: np.ndarray, t_max: int | None) -> tuple[np.ndarray, int | None]:
    """Which of a chunk's times (n,) int64 ns to keep: each must be above every earlier kept time
    (``t_max``: the latest before the chunk, None at the start) and below the lower median of the
    ``LOOKAHEAD`` times after it (``t_next``: the times after the chunk's last, up to LOOKAHEAD).
    The second test drops a time far ahead that the stream comes back from (a damaged time), which
    would otherwise make every later sample "not increasing"; a time that goes back is dropped by
    the first. Returns (keep (n,) bool, the latest kept time)."""
    lo = np.iinfo(np.int64).min if t_max is None else int(t_max)
    following = np.concatenate([t_ns[1:], t_next, np.full(LOOKAHEAD, np.iinfo(np.int64).max)]).astype(np.int64)
    window = np.lib.stride_tricks.sliding_window_view(following, LOOKAHEAD)[:len(t_ns)]
    ahead = t_ns >= np.sort(window, axis=1)[:, (LOOKAHEAD - 1) // 2]
    run = np.maximum.accumulate(np.where(ahead, np.iinfo(np.int64).min, t_ns))
    keep = ~ahead & (t_ns > np.maximum(np.concatenate([[lo], run[:-1]]), lo))
    latest = max(lo, int(run[-1])) if len(t_ns) else lo
    return keep, (None if latest == np.iinfo(np.int64).min else latest)
