"""The camera file (docs/formats.md, "Camera JSON"): our JSON, written by ``calibrate-camera`` and
the simulator, and OpenCV FileStorage YAML/XML camera files read as the same fields.

One reader, ``load_camera`` (both kinds, checked against schemas/camera.schema.json through
``jsonio``), and one writer, ``write_camera`` (the dict of ``camera_dict``).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from calibration.camera import CameraCalibration

from ..errors import UserError
from .jsonio import load_json, validate, write_json

FORMAT = "wearable-gaze-camera"
PREVIEW_SUFFIX = "_undistorted.png"        # calibrate-camera's preview beside its camera JSON: NAME_undistorted.png

log = logging.getLogger(__name__)


def preview_path(camera_json) -> Path:
    """The undistortion preview written beside a camera JSON: ``NAME.json`` -> ``NAME_undistorted.png``."""
    camera_json = Path(camera_json)
    return camera_json.with_name(camera_json.stem + PREVIEW_SUFFIX)


def is_preview(path) -> bool:
    """Whether ``path`` is the preview of a camera JSON beside it (``NAME_undistorted.png`` next to
    a ``NAME.json`` whose format is ours): an output of ``calibrate-camera``, not a photo."""
    path = Path(path)
    if not path.name.endswith(PREVIEW_SUFFIX):
        return False
    try:
        d = json.loads(path.with_name(path.name[:-len(PREVIEW_SUFFIX)] + ".json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(d, dict) and d.get("format") == FORMAT


def camera_dict(camera_matrix, dist_coeffs, image_size, model: str = "pinhole", rms_px=None, **extra) -> dict:
    """The camera JSON object: ``camera_matrix`` (3, 3) K in px, ``dist_coeffs`` (k,) OpenCV or
    fisheye coefficients, ``image_size`` (width, height) px, then the ``extra`` fields in the
    order given (``std``, ``board``, ``views``, ``trusted``, ``warnings``, ``source`` ...)."""
    d = {"format": FORMAT, "version": 1, "model": model,
         "camera_matrix": np.asarray(camera_matrix, float).tolist(),
         "dist_coeffs": np.asarray(dist_coeffs, float).ravel().tolist(),
         "image_size": [int(image_size[0]), int(image_size[1])], "rms_px": rms_px}
    d.update(extra)
    return d


def calibration_dict(cal: CameraCalibration, **extra) -> dict:
    """The camera JSON object of a calibration with its report (``std``, ``board``, ``views``),
    then ``extra`` (e.g. ``trusted``, ``warnings``)."""
    return camera_dict(cal.camera_matrix, cal.dist_coeffs, cal.image_size, cal.model, cal.rms_px,
                       std=cal.std, board=cal.board, views=cal.views, **extra)


def write_camera(path, camera: dict) -> None:
    """Write a camera JSON object (from ``camera_dict`` or ``calibration_dict``), atomically."""
    write_json(path, camera)


def load_camera(path) -> CameraCalibration:
    """A camera file: our JSON, or an OpenCV FileStorage YAML/XML (``camera_matrix`` and
    ``distortion_coefficients`` / ``dist_coeffs``, ``image_width`` / ``image_height``). Both are
    checked against the camera schema (wearable_gaze/formats/schemas/camera.schema.json)."""
    path = Path(path)
    if not path.is_file():
        what = "a folder" if path.is_dir() else "no such camera file"
        raise UserError(f"{path}: {what}; pass a camera JSON, or run 'wearable-gaze calibrate-camera' to make one")
    if path.suffix.lower() == ".json":
        d = load_json(path, "camera")
    else:
        d = _read_opencv_camera(path)
        validate(d, "camera", path)
    try:
        return CameraCalibration.from_dict(d)
    except ValueError as exc:
        raise UserError(f"{path}: {exc} (see docs/formats.md, camera JSON)") from None


def _read_opencv_camera(path: Path) -> dict:
    """The fields of an OpenCV FileStorage camera file as a camera-JSON dict (not yet checked)."""
    import cv2

    bad = UserError(f"{path}: not a camera JSON or an OpenCV YAML/XML camera file OpenCV can parse; pass "
                    "camera.json from 'wearable-gaze calibrate-camera' (docs/calibration.md)")
    head = path.read_bytes()[:64].lstrip()
    if not head.startswith((b"%YAML", b"<?xml", b"<opencv_storage")) and path.suffix.lower() not in (
            ".yml", ".yaml", ".xml"):
        raise bad
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError):         # OpenCV's parser raises SystemError on some garbage
        raise bad from None
    if not fs.isOpened():
        raise bad
    try:
        K = _fs_mat(fs, ("camera_matrix", "cameraMatrix", "K", "M1"))
        D = _fs_mat(fs, ("distortion_coefficients", "dist_coeffs", "distCoeffs", "D", "D1"))
        w, h = (fs.getNode(k).real() for k in ("image_width", "image_height"))
        model = "fisheye" if fs.getNode("model").isString() and fs.getNode("model").string() == "fisheye" else "pinhole"
    except (cv2.error, SystemError):
        raise bad from None
    finally:
        fs.release()
    if K is None or K.shape != (3, 3):
        raise UserError(f"{path}: no 3x3 camera_matrix in this OpenCV file; add one (docs/calibration.md)")
    if not (w and h):        # a guess from the principal point was off by 9x43 px on OpenCV's own tutorial file
        raise UserError(f"{path}: no image_width and image_height in this OpenCV file, and a calibration holds for "
                        "one image size only; add them (the size of the images it was made from, e.g. "
                        "'image_width: 640' and 'image_height: 480')")
    size = [int(round(v)) if np.isfinite(v) and abs(v) < 1e9 else -1 for v in (w, h)]
    return {"camera_matrix": K.tolist(), "dist_coeffs": [] if D is None else D.ravel().tolist(),
            "image_size": size, "model": model}


def _fs_mat(fs, names):
    """The first of ``names`` that is a matrix node of the FileStorage ``fs``, as float64, or None."""
    for n in names:
        node = fs.getNode(n)
        if not node.empty() and node.isMap():
            m = node.mat()
            if m is not None:
                return np.asarray(m, float)
    return None
