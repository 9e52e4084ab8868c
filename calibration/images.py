"""Image helpers shared by the libraries and the application: one colour-to-grey conversion.

Images are numpy arrays as OpenCV reads them: (H, W) grey or (H, W, 3) BGR, uint8 (or any dtype
``cv2.cvtColor`` takes).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np
from numpy.typing import ArrayLike

from estimator.deprecation import module_getattr


def to_gray(image: ArrayLike) -> np.ndarray:
    """The grey (H, W) image of an (H, W, 3) BGR image (``cv2.COLOR_BGR2GRAY``: OpenCV's luma
    weights); an (H, W) image is returned as it is (no copy)."""
    img = np.asarray(image)
    return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img


if not TYPE_CHECKING:      # old names (issue 30), for one release; unseen by mypy
    __getattr__ = module_getattr(globals(), {"to_grey": "to_gray"})
