"""The one place for OpenCV calls whose behaviour differs between the supported releases.

The project supports OpenCV 4.14 to 5.1 (``pyproject.toml``; the floors are tested by ``.ci/run``
with ``constraints/floors.txt``). Releases before 4.14 are not supported: they read a marker's
cells differently (a cell about half white counts as black, where 4.14 and 5.x count it as a
wrong bit; 5.x's ``validBitIdThreshold``), and on a simulated survey OpenCV 4.10 found a marker 17
in two slivers of wall texture, which moved the whole built map by 350 mm; their ChArUco corners
also lie +0.5 px from OpenCV's pixel convention (measured on 4.10; 4.14 and 5.x agree).
Where a call's signature or result differs across that range, the
rest of the code calls the function here instead, which gives one behaviour on every release:

- ``detect_markers``: ``ArucoDetector.detectMarkers`` returns ``ids`` as ``None`` when it finds
  nothing in OpenCV 4.14, and as an empty array in 5.1 (and may give candidates but no id);
  here it is always an (N,) int array with (N, 4, 2) corners.
- ``detect_charuco``: the same for ``CharucoDetector.detectBoard``'s corner ids.
- ``FISHEYE_RECOMPUTE_EXTRINSIC`` and ``silence_logging``: names that moved between releases.
- ``undistort_points`` / ``undistort_points_fisheye``: iterated undistortion to a given accuracy.
  OpenCV 5 takes ``criteria=`` on ``undistortPoints``; OpenCV 4 has ``undistortPointsIter`` for
  that and rejects the keyword.

Pure functions over arrays, like the rest of the library.
"""

from __future__ import annotations

import re

import cv2
import numpy as np
from numpy.typing import ArrayLike


def opencv_version(text: str | None = None) -> tuple[int, int]:
    """(major, minor) of the OpenCV in use (or of ``text``, such as '4.14.0')."""
    m = re.match(r"(\d+)\.(\d+)", text if text is not None else cv2.__version__)
    if m is None:
        raise ValueError(f"cannot read an OpenCV version from {text!r}")
    return int(m.group(1)), int(m.group(2))


def marker_ids(ids: ArrayLike | None) -> np.ndarray:
    """A detector's ids as an (N,) int64 array: ``None`` (OpenCV 4) and an empty array (OpenCV 5)
    both give shape (0,)."""
    if ids is None:
        return np.zeros(0, np.int64)
    return np.asarray(ids).reshape(-1).astype(np.int64)


def detect_markers(detector: cv2.aruco.ArucoDetector, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``detector.detectMarkers(image)`` as ((N, 4, 2) float64 corners px, (N,) int64 ids).

    Args:
        detector: a ``cv2.aruco.ArucoDetector``.
        image: (H, W) uint8 grey image.
    Returns:
        The corners in the detector's order and convention, and their ids; N = 0 when nothing is
        found, whatever the OpenCV release returns for that (``None``, an empty array, or
        candidates without an id).
    """
    corners, ids, _ = detector.detectMarkers(image)
    ids = marker_ids(ids)
    if len(ids) == 0:
        return np.zeros((0, 4, 2)), ids
    c = np.array([np.asarray(q, np.float64).reshape(4, 2) for q in corners])
    if len(c) != len(ids):
        raise RuntimeError(f"OpenCV returned {len(c)} marker corner sets for {len(ids)} ids")
    return c, ids


def detect_charuco(detector: cv2.aruco.CharucoDetector, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``detector.detectBoard(image)``'s ChArUco corners as ((N, 1, 2) float32 px, (N, 1) int32
    ids); N = 0 (empty arrays of those shapes) when none is found, on every supported release."""
    ch_corners, ch_ids, _, _ = detector.detectBoard(image)
    if ch_ids is None or len(ch_ids) == 0 or ch_corners is None:
        return np.zeros((0, 1, 2), np.float32), np.zeros((0, 1), np.int32)
    return (np.asarray(ch_corners, np.float32).reshape(-1, 1, 2),
            np.asarray(ch_ids, np.int32).reshape(-1, 1))


def _criteria(iterations: int, eps: float) -> tuple[int, int, float]:
    return (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, int(iterations), float(eps))


def undistort_points(px: ArrayLike, camera_matrix: ArrayLike, dist_coeffs: ArrayLike, iterations: int = 50,
                     eps: float = 1e-10) -> np.ndarray:
    """(N, 2) distorted pixels -> (N, 2) undistorted normalised coordinates (x/z, y/z), pinhole
    model, the iteration run to ``eps`` or ``iterations`` steps on every OpenCV release."""
    p = np.ascontiguousarray(np.asarray(px, np.float64).reshape(-1, 1, 2))
    K = np.asarray(camera_matrix, np.float64)
    D = np.asarray(dist_coeffs, np.float64)
    crit = _criteria(iterations, eps)
    if hasattr(cv2, "undistortPointsIter"):          # OpenCV 4.x: criteria only here
        out = cv2.undistortPointsIter(p, K, D, None, None, crit)
    else:                                            # OpenCV 5.x: undistortPoints takes them
        out = cv2.undistortPoints(p, K, D, criteria=crit)
    return np.asarray(out, np.float64).reshape(-1, 2)


def undistort_points_fisheye(px: ArrayLike, camera_matrix: ArrayLike, dist_coeffs: ArrayLike, iterations: int = 50,
                             eps: float = 1e-10) -> np.ndarray:
    """(N, 2) distorted pixels -> (N, 2) undistorted normalised coordinates, OpenCV's fisheye
    model (``cv2.fisheye.undistortPoints`` takes ``criteria=`` from 4.6 on, and in 5.x)."""
    p = np.ascontiguousarray(np.asarray(px, np.float64).reshape(-1, 1, 2))
    out = cv2.fisheye.undistortPoints(p, np.asarray(camera_matrix, np.float64),
                                      np.asarray(dist_coeffs, np.float64), criteria=_criteria(iterations, eps))
    return np.asarray(out, np.float64).reshape(-1, 2)


#: ``cv2.fisheye.calibrate``'s flag to re-estimate the views' poses at each step: OpenCV 4.14 has it
#: only as ``cv2.fisheye.CALIB_RECOMPUTE_EXTRINSIC`` (value 2), 5.0 only as
#: ``cv2.CALIB_RECOMPUTE_EXTRINSIC`` (1 << 23), 5.1 as both (1 << 23).
FISHEYE_RECOMPUTE_EXTRINSIC = getattr(cv2.fisheye, "CALIB_RECOMPUTE_EXTRINSIC", None) or cv2.CALIB_RECOMPUTE_EXTRINSIC


def silence_logging() -> None:
    """OpenCV's own log lines off (``cv2.utils.logging``; ``cv2.setLogLevel``, whose level 0 is
    silent, where a build lacks it)."""
    log = getattr(getattr(cv2, "utils", None), "logging", None)
    if log is not None:
        log.setLogLevel(log.LOG_LEVEL_SILENT)
    elif hasattr(cv2, "setLogLevel"):
        cv2.setLogLevel(0)
