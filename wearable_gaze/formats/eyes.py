"""The eye calibration file ``eyes.json`` (docs/calibration.md; listed in docs/formats.md): the
two eye calibrations (left, right) of ``calibrate-eyes``, with the camera and wall recordings
they were made with.

One reader, ``load_eyes`` (checked against schemas/eyes.schema.json through ``jsonio``), and one
writer, ``write_eyes`` (the dict of ``eyes_dict``).
"""

from __future__ import annotations

import logging

from calibration.eyes import EyeCalibration

from ..errors import UserError
from .jsonio import load_json, write_json

FORMAT = "wearable-gaze-eyes"

log = logging.getLogger(__name__)


def eyes_dict(camera: dict, walls: list, eyes) -> dict:
    """The eyes JSON object: the ``camera`` JSON object used, the per-recording ``walls`` report
    and the ``eyes`` (left, right ``EyeCalibration``)."""
    return {"format": FORMAT, "version": 1, "camera": camera, "walls": walls, "eyes": [e.to_dict() for e in eyes]}


def write_eyes(path, eyes: dict) -> None:
    """Write an eyes JSON object (from ``eyes_dict``), atomically."""
    write_json(path, eyes)


def load_eyes(path) -> list[EyeCalibration]:
    """The two eye calibrations (left, right) of an eyes.json, checked against its schema."""
    d = load_json(path, "eyes")
    try:
        return [EyeCalibration.from_dict(e) for e in d["eyes"]]
    except ValueError as exc:
        raise UserError(f"{path}: malformed eye calibration ({exc}); run 'wearable-gaze calibrate-eyes'") from None
