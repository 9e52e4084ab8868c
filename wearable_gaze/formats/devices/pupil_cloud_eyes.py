"""Neon's ``3d_eye_states.csv`` in a Pupil Cloud Timeseries export (``pupil_cloud``): per-eye
view lines, turned from optical to visual axes as the native Neon import does (``neon``).

Fields (Pupil Labs' export docs): ``timestamp [ns]`` (the eye video frame's, as ``gaze.csv``'s),
``eye ball center {left,right} {x,y,z} [mm]`` and ``optical axis {left,right} {x,y,z}``, in the
scene camera's frame with OpenCV axes (as the native recording: ``neon.T_HEAD_FROM_NEON_SCENE``
is the identity). The kappa offset is Neon's method (b) (``neon.KAPPA_DEPTH_MM``): each eye's axis
made to meet the export's own gaze ray (``gaze.csv``, the same time stamp) at that depth, fitted
on at most ``neon.MAX_FIT_SAMPLES`` binocular samples evenly spread; the report says so.

Per eye, a sample is dropped (and counted) when a value is not finite, the axis does not point
forward, or the centre lies beyond ``neon.MAX_CENTER_MM``; a sample whose eye distance lies
outside ``neon.IED_RANGE_MM`` loses both eyes. The table is read whole (about 110 bytes a row:
80 MB for an hour at 200 Hz).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from calibration.kappa import apply_kappa, fit_kappa_cyclopean, vergence_summary
from estimator.deprecation import module_getattr, renamed_kwargs

from ...errors import UserError
from ..tables import csv_header, iter_csv_chunks, write_table
from .neon import IED_RANGE_MM, KAPPA_DEPTH_MM, MAX_CENTER_MM, MAX_FIT_SAMPLES

EYE_STATES = "3d_eye_states.csv"
T_COL = "timestamp [ns]"
SIDES = ("left", "right")
CENTER_COLS = {s: [f"eye ball center {s} {a} [mm]" for a in "xyz"] for s in SIDES}
AXIS_COLS = {s: [f"optical axis {s} {a}" for a in "xyz"] for s in SIDES}
MATCH_NS = 5_000_000        # a gaze sample within 5 ms of an eye state is the same eye frame's


def int_times(cells, path: Path, lines) -> np.ndarray:
    """(n,) int64 nanoseconds of a column's ``cells`` (Cloud's ``timestamp [ns]``), exact.

    Raises:
        UserError: naming the file line (``lines``, one per cell) of the first cell that is not
            an integer.
    """
    try:
        return np.array([int(c) for c in cells], np.int64)
    except ValueError:
        bad = next(i for i, c in enumerate(cells) if not c.strip().lstrip("-").isdigit())
        raise UserError(f"{path} line {lines[bad]}: '{T_COL}' is {cells[bad][:30]!r}, not integer nanoseconds; "
                        "download the export again") from None


def read_eye_states(path: Path, chunk: int = 20000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t_ns (n,) int64, centres (2, n, 3) mm, optical axes (2, n, 3)), left then right; NaN where
    a cell is empty or not a number.

    Raises:
        UserError: a missing column, a time that is not integer nanoseconds.
    """
    cols = [T_COL] + [c for s in SIDES for c in CENTER_COLS[s] + AXIS_COLS[s]]
    head = csv_header(path, "Pupil Cloud 3d_eye_states CSV", "download the export again", cols)
    idx = [head.index(c) for c in cols]
    ts, vals = [], []
    for rows, lines in iter_csv_chunks(path, "Pupil Cloud 3d_eye_states CSV", chunk):
        whole = [(r, ln) for r, ln in zip(rows, lines, strict=True) if len(r) > max(idx)]
        ts.append(int_times([r[idx[0]] for r, _ in whole], path, [ln for _, ln in whole]))
        whole = [r for r, _ in whole]
        vals.append(np.array([[float(r[k]) if r[k].strip() else np.nan for k in idx[1:]] for r in whole], float))
    t = np.concatenate(ts) if ts else np.zeros(0, np.int64)
    v = np.concatenate(vals).reshape(-1, 12) if vals else np.zeros((0, 12))
    centers = np.stack([v[:, 0:3], v[:, 6:9]])
    axes = np.stack([v[:, 3:6], v[:, 9:12]])
    return t, centers, axes


@renamed_kwargs({"centres": "centers"})
def eye_validity(centers, axes, drops) -> np.ndarray:
    """(2, n) bool: each eye's sample is usable; the reasons for the rest are added to ``drops``."""
    ok = np.ones(centers.shape[:2], bool)
    for e, side in enumerate(SIDES):
        for reason, bad in (("not finite", ~(np.all(np.isfinite(centers[e]), axis=1)
                                             & np.all(np.isfinite(axes[e]), axis=1))),
                            ("axis not pointing forward", np.nan_to_num(axes[e][:, 2]) <= 0),
                            (f"centre beyond {MAX_CENTER_MM:g} mm", np.linalg.norm(np.nan_to_num(centers[e]),
                                                                                  axis=1) > MAX_CENTER_MM)):
            bad = bad & ok[e]
            drops[f"{side} eye: {reason}"] += int(bad.sum())
            ok[e] &= ~bad
    both = ok.all(axis=0)
    ied = np.linalg.norm(np.nan_to_num(centers[0] - centers[1]), axis=1)
    odd = both & ((ied < IED_RANGE_MM[0]) | (ied > IED_RANGE_MM[1]))
    drops[f"sample: eye distance outside {IED_RANGE_MM[0]:g}-{IED_RANGE_MM[1]:g} mm"] += int(odd.sum())
    ok[:, odd] = False
    return ok


@renamed_kwargs({"centres": "centers"})
def visual_axes(src: Path, centers, axes, ok, gaze_dirs) -> tuple[np.ndarray, dict]:
    """Kappa (b) on at most ``MAX_FIT_SAMPLES`` binocular samples: (visual axes (2, n, 3), the
    report's ``kappa`` entry)."""
    both = np.flatnonzero(ok.all(axis=0) & np.all(np.isfinite(gaze_dirs), axis=1))
    pick = both[np.linspace(0, len(both) - 1, min(len(both), MAX_FIT_SAMPLES)).astype(int)] if len(both) else both
    try:
        fit = fit_kappa_cyclopean(centers[0][pick], axes[0][pick], centers[1][pick], axes[1][pick],
                                  gaze_dirs[pick], KAPPA_DEPTH_MM)
    except ValueError as exc:
        raise UserError(f"{src / EYE_STATES}: cannot fit the kappa offset from the export's gaze ({exc}); import "
                        "the native recording with --kappa-recording instead") from None
    vis = np.stack([apply_kappa(axes[e], k.kappa_deg) for e, k in enumerate((fit.left, fit.right))])
    report = {"method": fit.method, "depth_mm": fit.depth_mm, "samples": {"left": fit.left.n, "right": fit.right.n},
              "left_deg": fit.left.kappa_deg.round(4).tolist(), "right_deg": fit.right.kappa_deg.round(4).tolist(),
              "source": "the export's gaze ray (gaze.csv) at a fixed depth",
              "rays_before": vergence_summary(centers[0][pick], axes[0][pick], centers[1][pick], axes[1][pick]),
              "rays_after": vergence_summary(centers[0][pick], vis[0][pick], centers[1][pick], vis[1][pick])}
    return vis, report


@renamed_kwargs({"centres": "centers"})
def write_eye_states(path: Path, t_ns, centers, optical_axes, section: str, recording: str) -> None:
    """``3d_eye_states.csv`` as Cloud writes it (the writer's side, for the round trip): t_ns (n,),
    centres and optical axes (2, n, 3) in the scene camera's frame (NaN: an eye without data)."""
    cols = {"section id": [section] * len(t_ns), "recording id": [recording] * len(t_ns), T_COL: t_ns,
            "pupil diameter left [mm]": np.full(len(t_ns), 3.5), "pupil diameter right [mm]": np.full(len(t_ns), 3.5)}
    formats = {T_COL: "d"}
    for e, s in enumerate(SIDES):
        for k, c in enumerate(CENTER_COLS[s]):
            cols[c] = centers[e][:, k]
            formats[c] = ".4f"
    for e, s in enumerate(SIDES):
        for k, c in enumerate(AXIS_COLS[s]):
            cols[c] = optical_axes[e][:, k]
            formats[c] = ".8f"
    write_table(path, cols, formats)


if not TYPE_CHECKING:      # old names (issue 30), for one release; unseen by mypy
    __getattr__ = module_getattr(globals(), {"CENTRE_COLS": "CENTER_COLS"})
