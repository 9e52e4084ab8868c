"""Scene-camera intrinsics: board detection, calibration with view rejection, frame selection,
undistortion.

Pure functions on arrays (images in, numbers out); reading files is the application's job.
Pixel coordinates follow OpenCV (origin at the centre of the top-left pixel).
"""

from __future__ import annotations

import logging
import re
from contextlib import contextmanager
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import ArrayLike

from estimator._checks import check_points

from . import cvcompat
from .images import to_gray

log = logging.getLogger(__name__)

ARUCO_DICTS = {name: getattr(cv2.aruco, name) for name in dir(cv2.aruco) if name.startswith("DICT_")}


def aruco_dictionary(name: str):
    """``cv2.aruco`` predefined dictionary by name; ValueError naming the choice otherwise."""
    if name not in ARUCO_DICTS:
        raise ValueError(f"unknown marker dictionary {name!r}: use a cv2.aruco name such as DICT_4X4_50 "
                         "or DICT_APRILTAG_36h11")
    return cv2.aruco.getPredefinedDictionary(ARUCO_DICTS[name])


@dataclass(frozen=True)
class BoardSpec:
    """A calibration board.

    Attributes:
        type: 'chessboard' or 'charuco'.
        cols, rows: inner corners (chessboard) or squares (ChArUco), as OpenCV counts them.
        square_mm: square side, mm.
        marker_mm: ChArUco marker side, mm.
        dictionary: ChArUco ``cv2.aruco`` dictionary name.
    """

    type: str
    cols: int
    rows: int
    square_mm: float
    marker_mm: float = 0.0
    dictionary: str = ""

    def to_dict(self) -> dict:
        d = {"type": self.type, "cols": self.cols, "rows": self.rows, "square_mm": self.square_mm}
        if self.type == "charuco":
            d.update(marker_mm=self.marker_mm, dictionary=self.dictionary)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> BoardSpec:
        spec = cls(str(d["type"]), int(d["cols"]), int(d["rows"]), float(d["square_mm"]),
                   float(d.get("marker_mm", 0.0)), str(d.get("dictionary", "")))
        spec.validate()
        return spec

    def validate(self) -> None:
        if self.type not in ("chessboard", "charuco"):
            raise ValueError(f"board type must be chessboard or charuco, got {self.type!r}")
        if self.cols < 2 or self.rows < 2 or not self.square_mm > 0:
            raise ValueError("a board needs at least 2x2 corners and a positive square size")
        if self.type == "charuco":
            aruco_dictionary(self.dictionary)
            if not 0 < self.marker_mm < self.square_mm:
                raise ValueError("a ChArUco marker must be smaller than its square")

    def charuco_board(self):
        return cv2.aruco.CharucoBoard((self.cols, self.rows), self.square_mm, self.marker_mm,
                                      aruco_dictionary(self.dictionary))

    def object_points(self) -> np.ndarray:
        """(N, 3) every corner of the board in its frame, mm (chessboard: row by row)."""
        if self.type == "chessboard":
            return np.array([[c * self.square_mm, r * self.square_mm, 0.0]
                             for r in range(self.rows) for c in range(self.cols)])
        return np.asarray(self.charuco_board().getChessboardCorners(), float)


def parse_board(text: str) -> BoardSpec:
    """``chessboard:COLSxROWS:SQUARE_MM`` or ``charuco:COLSxROWS:SQUARE_MM:MARKER_MM:DICT``.

    Raises:
        ValueError: saying which part is wrong.
    """
    m = re.fullmatch(r"chessboard:(\d+)x(\d+):([\d.]+)", text.strip())
    if m:
        spec = BoardSpec("chessboard", int(m[1]), int(m[2]), float(m[3]))
    else:
        m = re.fullmatch(r"charuco:(\d+)x(\d+):([\d.]+):([\d.]+):(\w+)", text.strip())
        if not m:
            raise ValueError(f"board {text!r}: expected chessboard:COLSxROWS:SQUARE_MM (inner corners) or "
                             "charuco:COLSxROWS:SQUARE_MM:MARKER_MM:DICT (squares), e.g. chessboard:9x6:25")
        spec = BoardSpec("charuco", int(m[1]), int(m[2]), float(m[3]), float(m[4]), m[5])
    spec.validate()
    return spec


@dataclass
class BoardView:
    """The board found in one image.

    Attributes:
        name: the view's label (file name, frame number).
        object_points: (N, 3) board-frame corners, mm.
        image_points: (N, 2) their pixel positions (distorted image).
        ids: (N,) corner indices on the board.
        reason: why the board was not usable ('' when it was).
    """

    name: str
    object_points: np.ndarray
    image_points: np.ndarray
    ids: np.ndarray
    reason: str = ""

    @property
    def ok(self) -> bool:
        return not self.reason


def detect_board(image, spec: BoardSpec, name: str = "", min_corners: int = 8) -> BoardView:
    """Find the board's corners in an image.

    Chessboard: ``cv2.findChessboardCorners`` then ``cv2.cornerSubPix`` (5x5 window, as OpenCV's
    own calibration test). ChArUco: ``cv2.aruco.CharucoDetector`` and ``board.matchImagePoints``.
    """
    gray = to_gray(image)
    empty = BoardView(name, np.zeros((0, 3)), np.zeros((0, 2)), np.zeros(0, int))
    if spec.type == "chessboard":
        ok, corners = cv2.findChessboardCorners(gray, (spec.cols, spec.rows))
        if not ok:
            empty.reason = f"no {spec.cols}x{spec.rows} chessboard found"
            return empty
        corners = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1),
                                   (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.1))
        return BoardView(name, spec.object_points(), corners.reshape(-1, 2).astype(float),
                         np.arange(spec.cols * spec.rows))
    board = spec.charuco_board()
    ch_corners, ch_ids = cvcompat.detect_charuco(cv2.aruco.CharucoDetector(board), gray)
    if len(ch_ids) < min_corners:
        empty.reason = f"{len(ch_ids)} ChArUco corners found, need {min_corners}"
        return empty
    obj, img = board.matchImagePoints(ch_corners, ch_ids)
    return BoardView(name, obj.reshape(-1, 3).astype(float), img.reshape(-1, 2).astype(float),
                     ch_ids.ravel().astype(int))


@dataclass
class CameraCalibration:
    """Intrinsics and the calibration's own report.

    Attributes:
        camera_matrix: (3, 3) K, pixels.
        dist_coeffs: (k,) OpenCV coefficients (pinhole) or (4,) fisheye coefficients.
        image_size: (width, height).
        model: 'pinhole' or 'fisheye'.
        rms_px: overall reprojection RMS of the views used, px.
        views: per view: name, used, rms_px, reason.
        board: the board description.
        std: standard deviations of fx, fy, cx, cy (px) and the coefficients, when known.
    """

    camera_matrix: np.ndarray
    dist_coeffs: np.ndarray
    image_size: tuple
    model: str = "pinhole"
    rms_px: float | None = None
    views: list = field(default_factory=list)
    board: dict | None = None
    std: dict | None = None

    @classmethod
    def from_dict(cls, d: dict) -> CameraCalibration:
        """Raises ValueError naming the missing or malformed key."""
        for key in ("camera_matrix", "dist_coeffs", "image_size"):
            if key not in d:
                raise ValueError(f"missing '{key}'")
        K = np.asarray(d["camera_matrix"], float)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise ValueError("'camera_matrix' must be a 3x3 matrix with positive focal lengths")
        D = np.asarray(d["dist_coeffs"], float).ravel()
        model = d.get("model", "pinhole")
        if model not in ("pinhole", "fisheye"):
            raise ValueError(f"'model' must be pinhole or fisheye, got {model!r}")
        if model == "fisheye" and len(D) != 4 or model == "pinhole" and len(D) not in (0, 4, 5, 8, 12, 14):
            raise ValueError(f"'dist_coeffs' has {len(D)} values, which the {model} model does not take")
        size = d["image_size"]
        if len(size) != 2 or min(size) <= 0:
            raise ValueError("'image_size' must be [width, height]")
        return cls(K, D, (int(size[0]), int(size[1])), model, d.get("rms_px"), d.get("views", []), d.get("board"),
                   d.get("std"))

    def undistort_points(self, px: ArrayLike) -> np.ndarray:
        """(N, 2) distorted pixels -> (N, 2) undistorted normalised coordinates (x/z, y/z)."""
        return undistort_points(px, self.camera_matrix, self.dist_coeffs, self.model)

    def project(self, pts_cam_mm: ArrayLike) -> np.ndarray:
        """(N, 3) camera-frame points -> (N, 2) distorted pixels."""
        p = check_points(pts_cam_mm, "pts_cam_mm").reshape(-1, 1, 3)
        if self.model == "fisheye":
            px, _ = cv2.fisheye.projectPoints(p, np.zeros(3), np.zeros(3), self.camera_matrix, self.dist_coeffs)
        else:
            px, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), self.camera_matrix, self.dist_coeffs)
        return px.reshape(-1, 2)


def undistort_points(px: ArrayLike, camera_matrix: ArrayLike, dist_coeffs: ArrayLike,
                     model: str = "pinhole") -> np.ndarray:
    """(N, 2) distorted pixels -> (N, 2) undistorted normalised coordinates, iterated to 1e-10."""
    p = np.asarray(px, np.float64)
    if p.size == 0:
        return np.zeros((0, 2))
    p = check_points(p, "px", 2).reshape(-1, 1, 2)
    if model == "fisheye":
        return cvcompat.undistort_points_fisheye(p, camera_matrix, dist_coeffs, 50, 1e-10)
    return cvcompat.undistort_points(p, camera_matrix, dist_coeffs, 50, 1e-10)


def undistort_image(image, cal: CameraCalibration, alpha: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The undistorted image and its new (3, 3) camera matrix (``alpha`` 0 keeps only valid
    pixels, 1 keeps every source pixel)."""
    w, h = cal.image_size
    if cal.model == "fisheye":
        K2 = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(cal.camera_matrix, cal.dist_coeffs, (w, h),
                                                                    np.eye(3), balance=alpha)
        m1, m2 = cv2.fisheye.initUndistortRectifyMap(cal.camera_matrix, cal.dist_coeffs, np.eye(3), K2, (w, h),
                                                     cv2.CV_32FC1)
    else:
        K2, _ = cv2.getOptimalNewCameraMatrix(cal.camera_matrix, cal.dist_coeffs, (w, h), alpha)
        m1, m2 = cv2.initUndistortRectifyMap(cal.camera_matrix, cal.dist_coeffs, None, K2, (w, h), cv2.CV_32FC1)
    return cv2.remap(np.asarray(image), m1, m2, cv2.INTER_LINEAR), K2


@contextmanager
def _one_thread():
    """OpenCV on one thread: its parallel sums make calibrateCamera's result differ in the 11th
    digit from run to run, which the rest of a session's processing then carries on."""
    n = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(n)


def _calibrate_once(views, image_size, model, flags):
    with _one_thread():
        return _calibrate_views(views, image_size, model, flags)


def _calibrate_views(views, image_size, model, flags):
    obj = [v.object_points.astype(np.float32).reshape(-1, 1, 3) for v in views]
    img = [v.image_points.astype(np.float32).reshape(-1, 1, 2) for v in views]
    if model == "fisheye":                           # cv2.fisheye wants (1, N, c) point arrays
        obj = [o.reshape(1, -1, 3) for o in obj]
        img = [i.reshape(1, -1, 2) for i in img]
        rms, K, D, rv, tv = cv2.fisheye.calibrate(
            obj, img, tuple(image_size), np.zeros((3, 3)), np.zeros((4, 1)),
            flags=flags | cvcompat.FISHEYE_RECOMPUTE_EXTRINSIC,
            criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-10))
        std = None
    else:
        rms, K, D, rv, tv, std, _, _ = cv2.calibrateCameraExtended(obj, img, tuple(image_size), None, None,
                                                                   flags=flags)
        std = std.ravel()
    per = []
    for v, r, t in zip(views, rv, tv, strict=True):
        if model == "fisheye":
            px, _ = cv2.fisheye.projectPoints(v.object_points.reshape(-1, 1, 3), r, t, K, D)
        else:
            px, _ = cv2.projectPoints(v.object_points, r, t, K, D)
        per.append(float(np.sqrt(np.mean(np.sum((px.reshape(-1, 2) - v.image_points) ** 2, axis=1)))))
    return float(rms), K, D.ravel(), per, std


def calibrate_camera(views, image_size, spec: BoardSpec | None = None, model: str = "pinhole", flags: int = 0,
                     reject: bool = True, reject_factor: float = 3.0, reject_floor_px: float = 1.0,
                     min_views: int = 3) -> CameraCalibration:
    """Calibrate from board views, rejecting bad ones with the reason.

    A view is rejected when the board was not found, or (``reject``) when its reprojection RMS
    exceeds ``reject_factor`` times the median of the views and ``reject_floor_px``; the
    calibration is then repeated without it (one view at a time, worst first).

    Args:
        views: ``BoardView`` list (as ``detect_board`` returns, failures included).
        image_size: (width, height).
        model: 'pinhole' (``cv2.calibrateCamera``) or 'fisheye' (``cv2.fisheye.calibrate``).
        flags: OpenCV calibration flags.

    Raises:
        ValueError: fewer than ``min_views`` usable views (the message says how many and why).
    """
    if model not in ("pinhole", "fisheye"):
        raise ValueError(f"model must be pinhole or fisheye, got {model!r}")
    report = {v.name: {"view": v.name, "used": False, "rms_px": None, "n_points": len(v.image_points),
                       "reason": v.reason} for v in views}
    use = [v for v in views if v.ok]
    if len(use) < min_views:
        reasons = "; ".join(f"{v.name}: {v.reason}" for v in views if not v.ok)[:300]
        raise ValueError(f"{len(use)} usable board views, need at least {min_views}"
                         + (f" ({reasons})" if reasons else ""))
    while True:
        rms, K, D, per, std = _calibrate_once(use, image_size, model, flags)
        worst = int(np.argmax(per))
        limit = max(reject_factor * float(np.median(per)), reject_floor_px)
        if not reject or per[worst] <= limit or len(use) <= min_views:
            break
        report[use[worst].name]["reason"] = (f"reprojection RMS {per[worst]:.2f} px > {limit:.2f} px "
                                             "(blurred, moved or misdetected)")
        report[use[worst].name]["rms_px"] = per[worst]
        log.info("camera calibration: view %s left out: %s", use[worst].name, report[use[worst].name]["reason"])
        use = use[:worst] + use[worst + 1:]
    for v, e in zip(use, per, strict=True):
        report[v.name].update(used=True, rms_px=e, reason="")
    log.info("camera calibration (%s): %d of %d views used, RMS %.3f px, fx %.1f fy %.1f px", model, len(use),
             len(views), rms, K[0, 0], K[1, 1])
    cal = CameraCalibration(K, D, (int(image_size[0]), int(image_size[1])), model, rms, list(report.values()),
                            spec.to_dict() if spec else None)
    if std is not None:             # OpenCV's standard deviations: fx, fy, cx, cy, then the coefficients
        cal.std = {"fx": float(std[0]), "fy": float(std[1]), "cx": float(std[2]), "cy": float(std[3]),
                   "dist_coeffs": std[4:4 + len(D)].tolist()}
    return cal


def select_frames(views, image_size, n: int, grid: int = 4) -> list:
    """Pick up to ``n`` usable views that together cover the image: greedily the view adding
    most not-yet-covered cells of a ``grid`` x ``grid`` partition (ties: more corners), then
    the views that differ most in board orientation. For long videos with many similar frames.
    """
    w, h = image_size
    cand = [v for v in views if v.ok]
    cells = []
    for v in cand:
        ij = np.clip((v.image_points / [w, h] * grid).astype(int), 0, grid - 1)
        cells.append(set(map(tuple, ij)))
    chosen: list[int] = []
    covered: set[tuple] = set()
    while len(chosen) < min(n, len(cand)):
        best, best_key = None, None
        for i, c in enumerate(cells):
            if i in chosen:
                continue
            key = (len(c - covered), len(cand[i].image_points))
            if best_key is None or key > best_key:
                best, best_key = i, key
        if best is None or best_key is None or best_key[0] == 0:    # (never None: one is left)
            break
        chosen.append(best)
        covered |= cells[best]
    # fill up with the views whose apparent board shape (corner spread direction) differs most
    rest = [i for i in range(len(cand)) if i not in chosen]
    while len(chosen) < min(n, len(cand)) and rest:
        def shape(i):
            p = cand[i].image_points
            return np.cov((p - p.mean(axis=0)).T).ravel() / (np.trace(np.cov(p.T)) + 1e-9)
        far = max(rest, key=lambda i: min(np.linalg.norm(shape(i) - shape(j)) for j in chosen) if chosen else 0)
        chosen.append(far)
        rest.remove(far)
    return [cand[i] for i in sorted(chosen)]
