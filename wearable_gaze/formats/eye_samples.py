"""The eye-sample CSV (docs/session.md, "eye samples"; listed in docs/formats.md): one row per
binocular sample, columns ``EYE_COLUMNS`` (time in s on the scene video's clock, the recorder's
counter, raw counts per eye, validity per eye), then any extra columns (the calibration
recordings add ``recording`` and ``target``).

One reader, ``read_eye_csv``, and one writer, ``write_eye_csv``; a recorder that streams the
file writes ``EYE_HEADER`` and one ``eye_csv_line`` per sample, in the number formats of
``EYE_FORMATS``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..errors import UserError
from .tables import read_table, write_table

EYE_COLUMNS = ["t", "counter", "left_x", "left_y", "right_x", "right_y", "left_valid", "right_valid"]
EYE_FORMATS = {"t": ".6f", "left_x": ".2f", "left_y": ".2f", "right_x": ".2f", "right_y": ".2f"}
EYE_HEADER = ",".join(EYE_COLUMNS) + "\n"

log = logging.getLogger(__name__)


@dataclass
class EyeSamples:
    """Raw binocular eye-tracker samples.

    Attributes:
        t: (N,) times, s, on the scene video's clock.
        counter: (N,) recorder sample counter.
        raw: (N, 2, 2) raw counts [sample, eye (left, right), (x, y)].
        valid: (N, 2) bool per eye.
    """

    t: np.ndarray
    counter: np.ndarray
    raw: np.ndarray
    valid: np.ndarray

    def __len__(self):
        return len(self.t)

    def columns(self) -> dict:
        return {"t": self.t, "counter": self.counter.astype(int), "left_x": self.raw[:, 0, 0],
                "left_y": self.raw[:, 0, 1], "right_x": self.raw[:, 1, 0], "right_y": self.raw[:, 1, 1],
                "left_valid": self.valid[:, 0], "right_valid": self.valid[:, 1]}


def write_eye_csv(path, eye: EyeSamples, extra: dict | None = None) -> None:
    """Write ``eye`` and the ``extra`` columns ({name: (N,) values}) as an eye-sample CSV, atomically."""
    cols = eye.columns()
    cols.update(extra or {})
    write_table(path, cols, EYE_FORMATS)


def eye_csv_line(t: float, counter: int, left, right, left_valid: bool, right_valid: bool) -> str:
    """One row of the eye-sample CSV (no extra columns), newline included: time ``t`` (s), the
    recorder's ``counter``, ``left`` and ``right`` raw counts (x, y), validity per eye."""
    f = EYE_FORMATS
    return (f"{format(t, f['t'])},{counter},{format(left[0], f['left_x'])},"
            f"{format(left[1], f['left_y'])},{format(right[0], f['right_x'])},"
            f"{format(right[1], f['right_y'])},{int(left_valid)},{int(right_valid)}\n")


def read_eye_csv(path, extra_required=(), text_columns=()) -> tuple[EyeSamples, dict]:
    """Eye samples and any extra columns. Times must increase strictly."""
    tab = read_table(path, EYE_COLUMNS + list(extra_required), text_columns, "eye-sample CSV",
                     "record eye samples with columns " + ", ".join(EYE_COLUMNS) + " (docs/session.md)")
    t = tab["t"]
    bad = np.flatnonzero(np.diff(t) <= 0)
    if len(bad):
        i = bad[0]
        raise UserError(f"{path} line {i + 3}: time {float(t[i + 1])!r} s does not increase after {float(t[i])!r} s; "
                        "eye samples must be sorted in time: sort them and remove repeated times")
    raw = np.stack([np.column_stack([tab["left_x"], tab["left_y"]]),
                    np.column_stack([tab["right_x"], tab["right_y"]])], axis=1)
    valid = np.column_stack([tab["left_valid"] != 0, tab["right_valid"] != 0])
    eye = EyeSamples(t, tab["counter"].astype(np.int64), raw, valid)
    return eye, {k: v for k, v in tab.items() if k not in EYE_COLUMNS}
