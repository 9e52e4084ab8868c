"""The streaming half of the Aria MPS importer (``aria.py``): CSVs read in chunks of rows
(``tables.iter_csv_chunks``; a 1 kHz trajectory is 3.6 M rows an hour, never loaded whole), and
the closed-loop trajectory merged with the eye samples, keeping only the poses around them (memory
flat in the file's length).

Columns of ``closed_loop_trajectory.csv`` used (by name; projectaria_tools
website/docs-technical-specs/mps/data_formats/slam/mps_trajectory.mdx): ``tracking_timestamp_us``
(device clock, us), ``t{x,y,z}_world_device`` (m) and ``q{x,y,z,w}_world_device`` (Hamilton,
scalar last) of T_world_device (p_world = R p_device + t), ``graph_uid`` (the SLAM world; rows of
another world than the first are dropped), ``quality_score`` (< 1 counted, kept).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from tracking.timeline import interpolate_poses

from ...errors import UserError
from ..tables import chunk_numbers, csv_header, iter_csv_chunks
from .common import SessionImport

TIME = "tracking_timestamp_us"
POSE_COLS = ("tx_world_device", "ty_world_device", "tz_world_device",
             "qx_world_device", "qy_world_device", "qz_world_device", "qw_world_device")
CHUNK_ROWS = 4096


def mps_header(path: Path, what: str, fix: str, required=()) -> list[str]:
    """The checked column names of an MPS CSV (``tables.csv_header``)."""
    return csv_header(path, what, fix, required, f"is it an MPS {what}?")


def in_order(path: Path, what: str, t_us: np.ndarray, last: float) -> np.ndarray:
    """(n,) bool: a repeated time (of the row before); raises if times go back."""
    prev = np.concatenate([[last], t_us[:-1]])
    if np.any(t_us < prev):
        i = int(np.flatnonzero(t_us < prev)[0])
        raise UserError(f"{path}: {TIME} goes back from {prev[i]:.0f} to {t_us[i]:.0f}; the {what} must be in "
                        "time order as MPS writes it (re-download or sort the rows)")
    return t_us == prev


# --- the trajectory ----------------------------------------------------------------------------

class TrajectoryStream:
    """The closed-loop trajectory streamed in chunks; keeps only the poses around the eye
    samples asked for. Poses come out as ``T_world_from_ariaworld @ T_ariaworld_from_device(mm)
    @ T_device_from_head``, the device pose interpolated (tracking.timeline.interpolate_poses).

    Args:
        path: the CSV; imp: counts and drops go there; t_ref_us: device time of t = 0 (s) of
        ``poses_at``; progress: progress(bytes read, size).
    """

    def __init__(self, path: Path, imp: SessionImport, t_ref_us: float, T_world_from_ariaworld: np.ndarray,
                 T_device_from_head: np.ndarray, progress=None):
        self.path, self.imp, self.t_ref_us = path, imp, t_ref_us
        self.T_left, self.T_right = T_world_from_ariaworld, T_device_from_head
        names = mps_header(path, "trajectory CSV", "pass the MPS folder with trajectory/closed_loop_trajectory.csv",
                           (TIME, *POSE_COLS))
        self.index = {n: j for j, n in enumerate(names) if n}
        self._chunks = iter_csv_chunks(path, "trajectory CSV", CHUNK_ROWS, progress)
        self.t = np.zeros(0)                  # s from t_ref_us
        self.T = np.zeros((0, 4, 4))          # T_world_from_device, our world, mm
        self.eof, self.graph_uid, self.t_first, self.t_last_us = False, None, None, -np.inf
        self.n_kept = self.n_low_quality = 0

    def _read_chunk(self) -> None:
        chunk = next(self._chunks, None)
        if chunk is None:
            self.eof = True
            return
        rows = chunk[0]
        imp, gi = self.imp, self.index.get("graph_uid")
        imp.count("trajectory rows", len(rows))
        cols, whole, ok = chunk_numbers(rows, self.index, (TIME, *POSE_COLS))
        imp.drop("trajectory row truncated (missing cells)", int(np.sum(~whole)))
        imp.drop("trajectory row with NaN or a non-number", int(np.sum(whole & ~ok)))
        if gi is not None:
            uid = np.array([r[gi].strip() if len(r) > gi else "" for r in rows], dtype=object)
            if self.graph_uid is None and ok.any():
                self.graph_uid = str(uid[np.flatnonzero(ok)[0]])
            other = ok & (uid != self.graph_uid)
            imp.drop("trajectory row in another SLAM world (graph_uid)", int(other.sum()))
            ok &= ~other
        q = np.column_stack([cols[c] for c in POSE_COLS[3:]])
        unit = np.abs(np.linalg.norm(np.nan_to_num(q), axis=1) - 1.0) <= 1e-3
        imp.drop("trajectory row with a non-unit quaternion", int(np.sum(ok & ~unit)))
        ok &= unit
        t_us = cols[TIME][ok]
        dup = in_order(self.path, "trajectory CSV", t_us, self.t_last_us)
        imp.drop("trajectory row with a repeated time", int(dup.sum()))
        sel = np.flatnonzero(ok)[~dup]
        if "quality_score" in self.index:
            quality = chunk_numbers(rows, self.index, ("quality_score",))[0]["quality_score"]
            self.n_low_quality += int(np.sum(quality[sel] < 1))
        if not len(sel):
            return
        T = np.tile(np.eye(4), (len(sel), 1, 1))
        T[:, :3, :3] = Rotation.from_quat(q[sel]).as_matrix()
        T[:, :3, 3] = np.column_stack([cols[c][sel] for c in POSE_COLS[:3]]) * 1000.0
        self.t_last_us = float(cols[TIME][sel[-1]])
        self.n_kept += len(sel)
        t = (cols[TIME][sel] - self.t_ref_us) / 1e6
        self.t_first = t[0] if self.t_first is None else self.t_first
        self.t, self.T = np.concatenate([self.t, t]), np.concatenate([self.T, self.T_left @ T])

    def close(self) -> None:
        """Stop reading (the eye samples ended before the trajectory)."""
        self._chunks.close()

    def _prune(self, tq: np.ndarray) -> None:
        """Keep only the poses around ``tq`` (both neighbours of each) and all from the last
        one's earlier neighbour on (later eye samples may need them)."""
        j = np.searchsorted(self.t, tq, side="right")
        keep = np.unique(np.clip(np.concatenate([j - 1, j, np.arange(max(j[-1] - 1, 0), len(self.t))]), 0,
                                 len(self.t) - 1))
        self.t, self.T = self.t[keep], self.T[keep]

    def poses_at(self, tq: np.ndarray, max_gap_s: float):
        """T_world_from_head (n, 4, 4) at sorted times ``tq`` (s from t_ref_us), ok (n,), and the
        reason of each unanswered one."""
        while not self.eof and (not len(self.t) or self.t[-1] < tq[-1] + max_gap_s):
            self._read_chunk()
            if len(self.t):
                self._prune(tq)
        T, ok = interpolate_poses(self.t, self.T, tq, max_gap_s) if len(self.t) else (None, np.zeros(len(tq), bool))
        first = np.inf if self.t_first is None else self.t_first
        last = self.t[-1] if self.eof and len(self.t) else np.inf
        why = np.where(tq < first, "no head pose: before the trajectory starts",
                       np.where(tq > last, "no head pose: after the trajectory ends",
                                "no head pose within max_pose_gap_s (a gap in the trajectory)"))
        if len(self.t):
            j = np.searchsorted(self.t, tq[-1], side="right")
            self.t, self.T = self.t[max(j - 1, 0):], self.T[max(j - 1, 0):]
        if T is not None:
            T = T @ self.T_right
        return T, ok, why
