"""Square fiducial markers (ArUco, AprilTag via ``cv2.aruco``): detection with sub-pixel corners."""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Iterable
from typing import NamedTuple

import cv2
import numpy as np
from numpy.typing import ArrayLike

from calibration.camera import aruco_dictionary as get_dictionary
from calibration.cvcompat import detect_markers
from calibration.images import to_gray

from .corners import refine_markers

log = logging.getLogger(__name__)


class MarkerDetection(NamedTuple):
    """One detected marker (immutable; unpacks as ``marker_id, corners_px``).

    Attributes:
        marker_id: the dictionary id decoded from the marker's bits.
        corners_px: (4, 2) float64, read-only: the black square's corners in pixels of the
            (distorted) image, OpenCV's convention (pixel ``(u, v)``'s centre at integer ``u, v``),
            ``cv2.aruco`` order: top-left, top-right, bottom-right, bottom-left of the printed marker.
    """

    marker_id: int
    corners_px: np.ndarray


def detection(marker_id: int, corners_px: ArrayLike) -> MarkerDetection:
    """A ``MarkerDetection`` from an id and (4, 2) corners, px (checked, copied, read-only)."""
    c = np.array(corners_px, dtype=np.float64)
    if c.shape != (4, 2):
        raise ValueError(f"marker {marker_id}: corners_px must have shape (4, 2), got {c.shape}")
    c.setflags(write=False)
    return MarkerDetection(int(marker_id), c)


def split_repeated(detections: Iterable[MarkerDetection]) -> tuple[dict[int, np.ndarray], list[int], int]:
    """({id: (4, 2) corners px} of the ids detected exactly once, the ids detected more than once
    (sorted), how many detections those were). An id seen more than once is ambiguous: at most one
    of them is the marker a map or a board means."""
    found = list(detections)
    seen = Counter(d.marker_id for d in found)
    repeated = sorted(i for i, n in seen.items() if n > 1)
    unique = {d.marker_id: d.corners_px for d in found if seen[d.marker_id] == 1}
    return unique, repeated, sum(seen[i] for i in repeated)


def unique_by_id(detections: Iterable[MarkerDetection]) -> dict[int, np.ndarray]:
    """{id: (4, 2) corners px} of the markers whose id was detected exactly once; the ambiguous
    repeated ones are left out, with a log line (``split_repeated``)."""
    unique, repeated, _ = split_repeated(detections)
    if repeated:
        log.info("marker ids seen more than once, left out as ambiguous: %s", repeated)
    return unique


class MarkerDetector:
    """``cv2.aruco.ArucoDetector`` with sub-pixel corners.

    Args:
        dictionary: a ``cv2.aruco`` dictionary name, or a ``cv2.aruco.Dictionary``.
        refine: 'edges' (default: ``cv2.cornerSubPix``, then the unbiased edge-line refinement of
            ``tracking.corners``), 'subpix', 'none', or 'apriltag' (OpenCV's AprilTag quad
            refinement, full size: it also finds steeply turned AprilTags the others miss, but
            costs ~270 ms a 720p frame; for photos, not for tracking).
        params: ``cv2.aruco.DetectorParameters`` (default: OpenCV's).
        downscale: find markers on an image this many times smaller (markers 24 px and up are
            still found), then refine their corners on the full image; default 2 for images 1200
            px wide or more, else 1. Finding is most of the cost, so this is ~3x faster at 720p.
        small_frames: find markers in an image under 1200 px wide as in the half-size image of a
            larger one (two threshold windows, 3 and 13 px, with OpenCV's own parameters): for
            video frames (tracking). On a simulated 640x360 walk: 928 of the 934 markers of 100
            frames, at 3.7 against 5.1 ms of CPU a frame (issue 27).

    ``detect(image)`` returns every marker found, as a list of ``MarkerDetection`` (id, (4, 2)
    corners px), repeated ids included (a photo may hold several tags of one id): the caller decides
    what a repeated id means (``MarkerPoseEstimator`` drops an id seen twice that its map lists once;
    ``detect_unique`` keeps only ids seen once). Corners are in OpenCV's pixel convention for every
    ``refine``.
    """

    def __init__(self, dictionary: str | cv2.aruco.Dictionary, refine: str = "edges",
                 params: cv2.aruco.DetectorParameters | None = None, downscale: int | None = None,
                 small_frames: bool = False) -> None:
        if refine not in ("edges", "subpix", "none", "apriltag"):
            raise ValueError(f"refine must be edges, subpix, none or apriltag, got {refine!r}")
        dic = get_dictionary(dictionary) if isinstance(dictionary, str) else dictionary
        self.modules = dic.markerSize + 2
        own = params is None
        params = cv2.aruco.DetectorParameters() if params is None else params
        params.cornerRefinementMethod = (cv2.aruco.CORNER_REFINE_APRILTAG if refine == "apriltag"
                                         else cv2.aruco.CORNER_REFINE_NONE)
        self._det = cv2.aruco.ArucoDetector(dic, params)
        # on the half-size image, OpenCV's third threshold window (23 px there, 46 here) adds a
        # third of the cost and, measured, almost no markers: two windows
        small = cv2.aruco.DetectorParameters() if own else params
        if own:
            small.adaptiveThreshWinSizeMin, small.adaptiveThreshWinSizeMax, small.adaptiveThreshWinSizeStep = 3, 13, 10
            small.cornerRefinementMethod = params.cornerRefinementMethod
        self._det_small = cv2.aruco.ArucoDetector(dic, small)
        self.refine = refine
        self.downscale = downscale
        self.small_frames = small_frames

    def detect(self, image: np.ndarray) -> list[MarkerDetection]:
        """Every marker in ``image`` ((H, W) grey or (H, W, 3) BGR), in the detector's order."""
        img = np.asarray(image)
        if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
            raise ValueError(f"image must have shape (H, W) or (H, W, 3), got {img.shape}")
        gray = to_gray(img)
        k = self.downscale or (2 if gray.shape[1] >= 1200 and self.refine != "apriltag" else 1)
        small = gray if k == 1 else cv2.resize(gray, (gray.shape[1] // k, gray.shape[0] // k),
                                               interpolation=cv2.INTER_AREA)
        full = k == 1 and not (self.small_frames and gray.shape[1] < 1200)
        c, ids = detect_markers(self._det if full else self._det_small, small)
        if len(ids) == 0:
            return []
        if self.refine == "apriltag":
            # OpenCV's AprilTag quad refinement returns AprilTag's pixel convention (a pixel's
            # centre at +0.5): back to OpenCV's (centre at the integer coordinate)
            c -= 0.5
        # pixel centres: small-image pixel i covers full-image pixels k i .. k i + k - 1
        c = c * k + (k - 1) / 2
        if self.refine in ("edges", "subpix"):
            win = max(2, min(5, int(np.min(np.linalg.norm(np.diff(c, axis=1), axis=2)) / (2 * self.modules))))
            pts = cv2.cornerSubPix(gray, c.reshape(-1, 1, 2).astype(np.float32), (win, win), (-1, -1),
                                   (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.01))
            c = pts.reshape(-1, 4, 2).astype(float)
        if self.refine == "edges":
            c = refine_markers(gray, c, self.modules)
        return [detection(i, ci) for i, ci in zip(ids, c, strict=True)]

    def detect_unique(self, image: np.ndarray) -> dict[int, np.ndarray]:
        """{id: (4, 2) corners px} of the markers in ``image`` whose id is seen exactly once
        (``unique_by_id``): for a board or a wall where each id is printed once."""
        return unique_by_id(self.detect(image))


# Dictionaries tried, in this order, when no marker of the expected one is found (a map naming
# another dictionary than the printed one): the smallest of each family first, so that a tie
# names it; AprilTag 16h5 is left out (its few bits give false detections in texture).
COMMON_DICTIONARIES = ("DICT_4X4_50", "DICT_4X4_1000", "DICT_5X5_1000", "DICT_6X6_1000", "DICT_7X7_1000",
                       "DICT_ARUCO_ORIGINAL", "DICT_APRILTAG_25h9", "DICT_APRILTAG_36h11", "DICT_ARUCO_MIP_36h12")


def likely_dictionary(images: Iterable[np.ndarray], exclude: str | None = None) -> tuple[str, int] | None:
    """The dictionary of ``COMMON_DICTIONARIES`` (other than ``exclude``) that finds the most
    markers in ``images`` (a few (H, W) grey or (H, W, 3) BGR images), with that count; None
    when none finds any. Ties go to the one listed first. Costs one detection per dictionary
    and image (no corner refinement)."""
    images = list(images)
    best = None
    for name in COMMON_DICTIONARIES:
        if name == exclude:
            continue
        detector = MarkerDetector(name, refine="none")
        n = sum(len(detector.detect(img)) for img in images)
        if n and (best is None or n > best[1]):
            best = (name, n)
    return best
