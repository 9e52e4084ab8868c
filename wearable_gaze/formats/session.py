"""The session folder (documented in docs/session.md): what the simulator writes, the live app
records and ``wearable-gaze process`` reads.

Readers check the manifest and every file it names, and say exactly what is missing or wrong.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import UserError
from .atomic import write_text
from .jsonio import load_json
from .tables import read_table, write_table

FORMAT = "wearable-gaze-session"
VERSION = 1
MARKER_MAP_FORMAT = "wearable-gaze-marker-map"
CAMERA_FORMAT = "wearable-gaze-camera"

EYE_COLUMNS = ["t", "counter", "left_x", "left_y", "right_x", "right_y", "left_valid", "right_valid"]
POSE_COLUMNS = ["t", "frame", "qw", "qx", "qy", "qz", "tx", "ty", "tz"]


def write_json(path, obj) -> None:
    """JSON, indented, atomically."""
    write_text(path, json.dumps(obj, indent=1) + "\n")


# --- eye samples ---------------------------------------------------------------------------------

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


EYE_FORMATS = {"t": ".6f", "left_x": ".2f", "left_y": ".2f", "right_x": ".2f", "right_y": ".2f"}


def write_eye_csv(path, eye: EyeSamples, extra: dict | None = None) -> None:
    cols = eye.columns()
    cols.update(extra or {})
    write_table(path, cols, EYE_FORMATS)


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


# --- poses ---------------------------------------------------------------------------------------

def pose_columns(t, frames, T_world_from_cam) -> dict:
    """Columns of a pose table: quaternion (w, x, y, z) and translation (mm) of
    ``T_world_from_cam`` (N, 4, 4) at times t (N,) and frame numbers (N,)."""
    T = np.asarray(T_world_from_cam, float).reshape(-1, 4, 4)
    ok = np.all(np.isfinite(T.reshape(len(T), -1)), axis=1)
    q = np.full((len(T), 4), np.nan)                           # x, y, z, w; NaN (empty) without a pose
    if ok.any():
        q[ok] = Rotation.from_matrix(T[ok, :3, :3]).as_quat()
    q *= np.where(q[:, 3:4] < 0, -1.0, 1.0)                  # w >= 0: one sign per rotation
    return {"t": np.asarray(t, float), "frame": np.asarray(frames).astype(int),
            "qw": q[:, 3], "qx": q[:, 0], "qy": q[:, 1], "qz": q[:, 2],
            "tx": T[:, 0, 3], "ty": T[:, 1, 3], "tz": T[:, 2, 3]}


POSE_FORMATS = {"t": ".6f", "qw": ".12f", "qx": ".12f", "qy": ".12f", "qz": ".12f",
                "tx": ".6f", "ty": ".6f", "tz": ".6f"}


def write_poses_csv(path, t, frames, T_world_from_cam, extra: dict | None = None) -> None:
    cols = pose_columns(t, frames, T_world_from_cam)
    cols.update(extra or {})
    write_table(path, cols, POSE_FORMATS)


def read_poses_csv(path, text_columns=("status",)) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """(t (N,), frame (N,), T_world_from_cam (N, 4, 4) with NaN where there is no pose, extra
    columns)."""
    tab = read_table(path, POSE_COLUMNS, text_columns, "pose CSV",
                     empty_ok=("qw", "qx", "qy", "qz", "tx", "ty", "tz"))
    q = np.column_stack([tab["qx"], tab["qy"], tab["qz"], tab["qw"]])
    T = np.full((len(q), 4, 4), np.nan)
    ok = np.all(np.isfinite(q), axis=1) & (np.linalg.norm(q, axis=1) > 0)
    T[ok] = np.eye(4)
    if ok.any():
        T[ok, :3, :3] = Rotation.from_quat(q[ok]).as_matrix()
        T[ok, :3, 3] = np.column_stack([tab["tx"], tab["ty"], tab["tz"]])[ok]
    return tab["t"], tab["frame"].astype(int), T, {k: v for k, v in tab.items() if k not in POSE_COLUMNS}


# --- camera and marker map -----------------------------------------------------------------------

def camera_dict(camera_matrix, dist_coeffs, image_size, model: str = "pinhole", rms_px=None, **extra) -> dict:
    """The camera JSON (docs/formats.md): intrinsics, distortion, image size [w, h]."""
    d = {"format": CAMERA_FORMAT, "version": 1, "model": model,
         "camera_matrix": np.asarray(camera_matrix, float).tolist(),
         "dist_coeffs": np.asarray(dist_coeffs, float).ravel().tolist(),
         "image_size": [int(image_size[0]), int(image_size[1])], "rms_px": rms_px}
    d.update(extra)
    return d


def marker_map_dict(dictionary: str, marker_size_mm: float, markers: dict, labels: dict | None = None) -> dict:
    """The marker map JSON (docs/formats.md): per id its ``T_world_from_marker`` (4x4, mm)."""
    labels = labels or {}
    return {"format": MARKER_MAP_FORMAT, "version": 1, "dictionary": dictionary,
            "marker_size_mm": float(marker_size_mm),
            "markers": [{"id": int(i), "T_world_from_marker": np.round(np.asarray(T, float), 9).tolist(),
                         **({"label": labels[i]} if i in labels else {})}
                        for i, T in sorted(markers.items())]}


# --- video -------------------------------------------------------------------------------------

def grey_frames(path):
    """Yield every frame of a video as a (H, W) uint8 grey image."""
    import cv2  # noqa: PLC0415

    cap = cv2.VideoCapture(str(path))
    try:
        while True:
            ok, frame = cap.read()
            if not ok:
                return
            yield cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY) if frame.ndim == 3 else frame
    finally:
        cap.release()


# --- the session ---------------------------------------------------------------------------------

@dataclass
class Session:
    """A loaded session folder (lazy: large files are opened on demand).

    Attributes:
        root: the folder.
        manifest: ``session.json``.
    """

    root: Path
    manifest: dict

    def path(self, key: str) -> Path | None:
        rel = self.manifest.get("files", {}).get(key)
        return None if rel is None else self.root / rel

    def frame_times(self) -> np.ndarray:
        tab = read_table(self.path("scene_timestamps"), ["frame", "t"], what="frame-timestamp CSV")
        t = tab["t"]
        bad = np.flatnonzero(np.diff(t) <= 0)
        if len(bad):
            raise UserError(f"{self.path('scene_timestamps')} line {bad[0] + 3}: frame times must increase")
        return t

    def eye_samples(self) -> EyeSamples:
        return read_eye_csv(self.path("eye_samples"))[0]

    def marker_map(self) -> dict | None:
        p = self.path("marker_map")
        return None if p is None else load_json(p, "marker-map")

    @property
    def image_size(self) -> tuple[int, int]:
        w, h = self.manifest["image_size"]
        return int(w), int(h)


def load_session(root) -> Session:
    """Open a session folder and check its manifest and the files it names.

    Raises:
        UserError: naming what is missing or wrong.
    """
    root = Path(root)
    if not root.is_dir():
        raise UserError(f"{root}: no such session folder; record one or run 'wearable-gaze simulate -o {root}'")
    man = load_json(root / "session.json", "session")        # schema: format, version, files inside root
    for key, rel in man["files"].items():
        if not (root / rel).exists():
            raise UserError(f"{root / rel}: listed in session.json as {key} but missing; restore the file or "
                            f"remove 'files.{key}' from the manifest")
    return Session(root, man)
