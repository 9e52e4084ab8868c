"""The AOI step's three tables (docs/formats.md, "AOI tables"; docs/aois.md):

- ``aoi_fixations.csv``: one row per fixation, in time order: ``fixation_id``, ``start_s``,
  ``end_s`` (its first and last sample, session clock, s), ``duration_s`` (the time it counts
  for in the measures, s: one sample interval per sample, gaps up to 75 ms counted whole, a
  longer one (a blink) left out: ``estimator.aoi.fixation_duration_s``, as fixations.csv's),
  ``target_id`` (-1 none), ``aoi`` (the assigned area's name, ``none`` when no area reaches the
  assignment level), then ``p_<name>`` for each area in the AOI file's order and ``p_none``
  (probabilities; empty where the fixation has no gaze distribution);
- ``aoi_metrics.csv``: one row per area: ``aoi``, ``group`` (may be empty), ``dwell_s``,
  ``dwell_weighted_s``, ``visits``, ``revisits``, ``fixations``, ``first_fixation_s`` (time to
  first fixation from the session's first sample; empty if never looked at),
  ``first_fixation_duration_s`` (empty likewise), ``share`` (dwell over the session's length);
- ``aoi_transitions.csv``: one row per ordered pair of areas with a transition: ``from``, ``to``,
  ``count`` (visit to visit), ``weighted`` (probability-weighted, over consecutive fixations).

One writer and one reader for each: ``write_aoi_fixations``/``read_aoi_fixations``,
``write_aoi_metrics``/``read_aoi_metrics``, ``write_aoi_transitions``/``read_aoi_transitions``.
"""

from __future__ import annotations

import numpy as np

from .tables import Checks, open_csv, read_table, write_table

METRIC_NUMBERS = ("dwell_s", "dwell_weighted_s", "visits", "revisits", "fixations", "first_fixation_s",
                  "first_fixation_duration_s", "share")
METRIC_CHECKS = Checks(METRIC_NUMBERS, ("first_fixation_s", "first_fixation_duration_s"), (), "AOI metrics table")
FIXATION_NUMBERS = ("fixation_id", "start_s", "end_s", "duration_s", "target_id")
TRANSITION_CHECKS = Checks(("count", "weighted"), (), (), "AOI transitions table")
_FMT = {"start_s": ".4f", "end_s": ".4f", "duration_s": ".4f", "dwell_s": ".4f", "dwell_weighted_s": ".4f",
        "first_fixation_s": ".4f", "first_fixation_duration_s": ".4f", "share": ".5f", "weighted": ".5f"}


def _fixation_checks(names) -> Checks:
    p = tuple(f"p_{n}" for n in (*names, "none"))
    return Checks((*FIXATION_NUMBERS, *p), p, (), "AOI fixations table")


def write_aoi_fixations(path, rows: dict, names) -> None:
    """``rows``: the columns (``fixation_id``, ``start_s``, ``end_s``, ``duration_s`` (the time
    its samples stand for, ``estimator.aoi.fixation_duration_s``), ``target_id``, ``aoi`` (names),
    ``probabilities`` (N, K + 1)) for the areas ``names`` (K,)."""
    P = np.asarray(rows["probabilities"], float).reshape(-1, len(names) + 1)
    start, end = np.asarray(rows["start_s"], float), np.asarray(rows["end_s"], float)
    cols = {"fixation_id": np.asarray(rows["fixation_id"], int), "start_s": start, "end_s": end,
            "duration_s": np.asarray(rows["duration_s"], float),
            "target_id": np.asarray(rows["target_id"], int), "aoi": np.asarray(rows["aoi"], object)}
    cols |= {f"p_{n}": P[:, j] for j, n in enumerate((*names, "none"))}
    write_table(path, cols, _FMT | {f"p_{n}": ".5f" for n in (*names, "none")}, _fixation_checks(names))


def read_aoi_fixations(path) -> dict:
    """aoi_fixations.csv's columns ({name: (N,) array}; ``p_*`` NaN where empty)."""
    header, _ = open_csv(path, FIXATION_NUMBERS, "AOI fixations table", "run 'wearable-gaze aoi' to make one")
    names = [k[2:] for k in header if k.startswith("p_") and k != "p_none"]
    return read_table(path, FIXATION_NUMBERS, text_columns=("aoi",), rows_required=False,
                      checks=_fixation_checks(names))


def write_aoi_metrics(path, rows: list[dict]) -> None:
    """One dict per area with ``aoi``, ``group`` and ``METRIC_NUMBERS``."""
    cols = {"aoi": np.array([r["aoi"] for r in rows], object), "group": np.array([r["group"] for r in rows], object)}
    cols |= {k: np.array([r[k] for r in rows], float if "_s" in k or k == "share" else int) for k in METRIC_NUMBERS}
    write_table(path, cols, _FMT, METRIC_CHECKS)


def read_aoi_metrics(path) -> dict:
    """aoi_metrics.csv's columns ({name: (N,) array}; NaN where empty)."""
    return read_table(path, METRIC_NUMBERS, text_columns=("aoi", "group"), rows_required=False, checks=METRIC_CHECKS)


def write_aoi_transitions(path, rows: list[dict]) -> None:
    """One dict per ordered pair: ``from``, ``to``, ``count``, ``weighted``."""
    cols = {"from": np.array([r["from"] for r in rows], object), "to": np.array([r["to"] for r in rows], object),
            "count": np.array([r["count"] for r in rows], int),
            "weighted": np.array([r["weighted"] for r in rows], float)}
    write_table(path, cols, _FMT, TRANSITION_CHECKS)


def read_aoi_transitions(path) -> dict:
    """aoi_transitions.csv's columns."""
    return read_table(path, ("count", "weighted"), text_columns=("from", "to"), rows_required=False,
                      checks=TRANSITION_CHECKS)
