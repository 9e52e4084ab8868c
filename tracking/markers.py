"""Square fiducial markers (ArUco, AprilTag via ``cv2.aruco``): detection with sub-pixel corners."""

from __future__ import annotations

import cv2
import numpy as np

from calibration.camera import aruco_dictionary as get_dictionary

from .corners import refine_marker_corners


def marker_modules(name: str) -> int:
    """Modules across a marker of the dictionary, border included (6 for 4x4)."""
    return get_dictionary(name).markerSize + 2


class MarkerDetector:
    """``cv2.aruco.ArucoDetector`` with sub-pixel corners: OpenCV's CORNER_REFINE_SUBPIX, then
    (``edge_refine``) the unbiased edge-line refinement of ``tracking.corners``.

    ``detect(image)`` returns {id: (4, 2) corners in pixels, cv2.aruco order (top-left,
    top-right, bottom-right, bottom-left of the printed marker)}.
    """

    def __init__(self, dictionary: str, edge_refine: bool = True, params: "cv2.aruco.DetectorParameters | None" = None):
        self.dictionary = dictionary
        self.modules = marker_modules(dictionary)
        p = params or cv2.aruco.DetectorParameters()
        p.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        self._det = cv2.aruco.ArucoDetector(get_dictionary(dictionary), p)
        self.edge_refine = edge_refine

    def detect(self, image) -> dict:
        img = np.asarray(image)
        grey = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img
        corners, ids, _ = self._det.detectMarkers(grey)
        out = {}
        if ids is None:
            return out
        for c, i in zip(corners, ids.ravel()):
            c = c.reshape(4, 2).astype(float)
            if self.edge_refine:
                c = refine_marker_corners(grey, c, self.modules)
            out[int(i)] = c
        return out
