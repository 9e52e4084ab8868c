"""The segmentation step: which view lines belong to one fixation (``estimator.segments``), as
``process`` runs it and as ``wearable-gaze fixations`` runs it on a view-line CSV, so that the
step-by-step commands (``viewlines`` -> ``fixations`` -> ``estimate --targets``) and ``process``
give the same targets (docs/processing.md, "Fixations").

The labels are written in the view-line CSV's ``segment`` column (docs/formats.md): 0, 1, 2...
for the fixations in time order, -1 for the rows in no fixation (saccades, blinks, gaps), which
no estimate ever uses.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from estimator import BinocularSamples
from estimator.segments import SegmentConfig, segment_fixations

from ...formats.viewlines import read_viewlines_csv, write_viewlines_csv

log = logging.getLogger(__name__)

NO_FIXATION = -1
SETTINGS = tuple(f.name for f in dataclasses.fields(SegmentConfig))


def segment_view_lines(samples: BinocularSamples, config: SegmentConfig) -> np.ndarray:
    """The segmentation step: fixation labels (N,) int of world view lines (N,) in time order,
    0, 1, 2... in time order and -1 (``NO_FIXATION``) for saccades, blinks and gaps. ``process``
    and ``fixations`` both call this."""
    return segment_fixations(samples, config)


def measured_rate_hz(t_s: np.ndarray) -> float | None:
    """The sample rate of times ``t_s`` (N,) s: one over the median positive interval between
    consecutive samples (dropped samples leave the median at the nominal interval); None with
    fewer than two distinct times."""
    dt = np.diff(np.asarray(t_s, float))
    dt = dt[dt > 0]
    return float(1.0 / np.median(dt)) if len(dt) else None


def segment_config(eye_rate_hz: float | None, settings: Mapping | None = None) -> SegmentConfig:
    """The settings for eye samples at ``eye_rate_hz`` (``SegmentConfig.for_rate``; the defaults
    without a rate), with ``settings`` (field name -> value, e.g. ``{'jump_deg': 4.0}``)
    overriding; a ``window`` given there wins over the rate's."""
    settings = dict(settings or {})
    unknown = sorted(set(settings) - set(SETTINGS))
    if unknown:
        raise ValueError(f"unknown segmentation setting(s) {unknown}; known: {list(SETTINGS)}")
    window = settings.pop("window", None)
    cfg = SegmentConfig.for_rate(eye_rate_hz, **settings) if eye_rate_hz else SegmentConfig(**settings)
    return dataclasses.replace(cfg, window=int(window)) if window is not None else cfg


def read_in_time_order(path) -> tuple[BinocularSamples, list]:
    """All the rows of a view-line CSV as one set of samples in time order (the rows of each
    segment keep their order; the segments are interleaved back by time, a stable sort, so a
    file written in time order comes back in its row order), and the segment value of each row
    (None for a file without a ``segment`` column)."""
    segments = read_viewlines_csv(path)
    samples = BinocularSamples.concatenate([s.samples for s in segments])
    keys = [s.key for s in segments for _ in range(len(s.samples))]
    order = np.argsort(samples.t_s, kind="stable")
    return samples.select(order), [keys[i] for i in order]


def fixations_file(viewlines_csv, out_csv, config: SegmentConfig | Mapping | None = None,
                   eye_rate_hz: float | None = None) -> dict:
    """``wearable-gaze fixations``: segment a view-line CSV and write it to ``out_csv`` with a
    ``segment`` column of fixation labels (-1: saccades, blinks, gaps), through
    ``formats.viewlines``.

    Args:
        viewlines_csv: the view lines (a ``segment`` column already there is replaced).
        out_csv: the file to write (atomically).
        config: a ``SegmentConfig`` used as it is, or settings overriding the rate's
            (``segment_config``); None: the rate's settings.
        eye_rate_hz: the eye samples' rate, for the window; None: measured from the file's times
            (``process`` uses the session's declared rate: give it here to match exactly).

    Returns:
        {'rows', 'fixations', 'unlabelled', 'rate_hz', 'config'}: rows written, fixations found,
        rows in no fixation, the rate used (None: none known) and the settings (a dict).
    """
    samples, keys = read_in_time_order(viewlines_csv)
    if any(k is not None for k in keys):
        log.info("%s has a segment column; it is replaced by this segmentation", viewlines_csv)
    rate = eye_rate_hz if eye_rate_hz is not None else measured_rate_hz(samples.t_s)
    cfg = config if isinstance(config, SegmentConfig) else segment_config(rate, config)
    labels = segment_view_lines(samples, cfg)
    write_viewlines_csv(Path(out_csv), samples, labels)
    n_fix = int(labels.max()) + 1 if len(labels) else 0
    return {"rows": len(labels), "fixations": max(n_fix, 0), "unlabelled": int((labels == NO_FIXATION).sum()),
            "rate_hz": rate, "config": dataclasses.asdict(cfg)}
