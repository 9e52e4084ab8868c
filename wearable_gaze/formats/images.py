"""Still images: the calibration recordings' board views and wall images, a ``track --reference``
photo, the camera calibration's preview (docs/session.md, calibration/; listed in docs/formats.md).

One reader, ``read_grey_image`` (any format OpenCV decodes: ``IMAGE_EXT``), and one writer,
``write_image`` (atomic; the format from the name's suffix, PNG for every file the program
writes).
"""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np

from ..errors import UserError
from .atomic import atomic_path

IMAGE_EXT = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm"}

log = logging.getLogger(__name__)


def read_grey_image(path, what: str = "image", fix: str = "pass a PNG, JPEG, BMP or TIFF image") -> np.ndarray:
    """The image at ``path`` as (H, W) uint8 grey (a colour image converted by OpenCV).

    Raises:
        UserError: one line, ``PATH: missing or unreadable WHAT (no such file, or not a readable
            image); FIX`` (``what`` says which image, ``fix`` what to do).
    """
    path = Path(path)
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) if path.is_file() else None
    if img is None:
        raise UserError(f"{path}: missing or unreadable {what} (no such file, or not a readable image); {fix}")
    return img


def write_image(path, img: np.ndarray) -> None:
    """Write ``img`` ((H, W) grey or (H, W, 3) BGR, uint8) to ``path`` atomically, in the format
    of its suffix (.png).

    Raises:
        UserError: OpenCV could not encode or write it (nothing is left under ``path``).
    """
    path = Path(path)
    with atomic_path(path) as tmp:
        try:
            ok = cv2.imwrite(str(tmp), img)
        except cv2.error as exc:
            raise UserError(f"{path}: OpenCV could not encode this image (shape {np.shape(img)}): "
                            f"{str(exc).strip().splitlines()[-1]}; give the name a .png suffix") from None
        if not ok:
            raise UserError(f"{path}: OpenCV could not write this image (shape {np.shape(img)}); check the free space "
                            "and that the folder can be written")


def image_files(folder) -> list[Path]:
    """The image files (``IMAGE_EXT``, any case) directly in ``folder``, sorted by name."""
    return sorted(q for q in Path(folder).iterdir() if q.suffix.lower() in IMAGE_EXT)
