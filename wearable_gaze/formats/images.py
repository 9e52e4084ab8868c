"""Still images: the calibration recordings' board views and wall images, a ``track --reference``
photo, the camera calibration's preview (docs/session.md, calibration/; listed in docs/formats.md).

One reader, ``read_gray_image`` (any format OpenCV decodes: ``IMAGE_EXT``), and one writer,
``write_image`` (atomic; the format from the name's suffix, PNG for every file the program
writes).
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from estimator.deprecation import module_getattr

from ..errors import UserError
from .atomic import atomic_path

IMAGE_EXT = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm"}
JPEG_START, JPEG_END, JPEG_SCAN = b"\xff\xd8", b"\xff\xd9", b"\xff\xda"      # SOI, EOI, SOS markers

log = logging.getLogger(__name__)


def read_gray_image(path, what: str = "image", fix: str = "pass a PNG, JPEG, BMP or TIFF image") -> np.ndarray:
    """The image at ``path`` as (H, W) uint8 grey (a colour image converted by OpenCV).

    Raises:
        UserError: one line, ``PATH: missing or unreadable WHAT (no such file, or not a readable
            image); FIX`` (``what`` says which image, ``fix`` what to do).
    """
    path = Path(path)
    try:
        data = path.read_bytes() if path.is_file() else b""
    except OSError:
        data = b""
    if data[:2] == JPEG_START and not jpeg_complete(data):
        raise UserError(f"{path}: truncated {what} (its JPEG data ends before the end-of-image marker: an incomplete "
                        f"copy); copy it again, or {fix}")
    with _quiet_stderr():                   # libjpeg and libpng print their warnings on fd 2 themselves
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE) if data else None
    if img is None:
        raise UserError(f"{path}: missing or unreadable {what} (no such file, or not a readable image); {fix}")
    return img


def jpeg_complete(data: bytes) -> bool:
    """Whether JPEG ``data`` has its end-of-image marker after the start of its last scan (a
    truncated copy has not: libjpeg decodes it anyway, grey where the data ran out, with a
    "Premature end of JPEG file" on stderr). Markers cannot occur inside a scan's data (a 0xFF
    byte there is stuffed as FF 00), so bytes after the marker (some cameras' trailers) are fine."""
    return data.rfind(JPEG_END) > data.rfind(JPEG_SCAN)


@contextlib.contextmanager
def _quiet_stderr():
    """File descriptor 2 sent to the null device for the block (C libraries' own warnings)."""
    sys.stderr.flush()
    saved, null = os.dup(2), os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(null)


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


if not TYPE_CHECKING:      # old names (issue 30), for one release; unseen by mypy
    __getattr__ = module_getattr(globals(), {"read_grey_image": "read_gray_image"})
