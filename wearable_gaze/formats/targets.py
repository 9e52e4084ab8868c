"""The targets ``process`` found: ``targets.json`` and ``targets.csv`` (docs/processing.md,
docs/formats.md "Targets").

Both hold the same rows, one per target, keyed by ``TARGET_COLUMNS``: ``target`` (index),
``x_mm, y_mm, z_mm`` (world frame, mm), ``axis1_mm..axis3_mm`` (95 % ellipsoid semi-axes, mm),
``n_samples``, ``t_start, t_end`` (s), ``fixations`` (``;``-separated indices), ``method``,
``status``, ``crb_mm``. A value that does not exist (no usable estimate) is NaN in the JSON and an
empty cell in the CSV. targets.json adds ``version`` and ``method``; targets.csv rounds to 0.1 mm
and 1 ms, for spreadsheets.

One writer, ``write_targets`` (both files), and one reader, ``read_targets`` (the rows of
targets.json, exact). The rows are plain dicts here; ``pipeline.types.Target`` converts
(``Target.row`` / ``Target.from_row``).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from ..errors import UserError
from .jsonio import write_json
from .tables import write_table

TARGET_COLUMNS = ("target", "x_mm", "y_mm", "z_mm", "axis1_mm", "axis2_mm", "axis3_mm", "n_samples", "t_start",
                  "t_end", "fixations", "method", "status", "crb_mm")
TARGET_FORMATS = {k: ".1f" for k in ("x_mm", "y_mm", "z_mm", "axis1_mm", "axis2_mm", "axis3_mm", "crb_mm")} | {
    "t_start": ".3f", "t_end": ".3f"}
TARGET_FILES = ("targets.csv", "targets.json")

log = logging.getLogger(__name__)


def write_targets(out, rows: list[dict], method: str) -> None:
    """Write ``rows`` (keys ``TARGET_COLUMNS``, plain Python values) as ``out``/targets.csv and
    ``out``/targets.json (with ``method``, the estimator), each atomically."""
    out = Path(out)
    write_table(out / "targets.csv", {k: np.array([r[k] for r in rows]) for k in TARGET_COLUMNS}, TARGET_FORMATS)
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
