"""The simulator's ground truth of a session, ``truth/`` (docs/session.md, truth/; listed in
docs/formats.md), in the formats of its own: ``targets.json`` (each target's position or path
and its fixation intervals; ``demo`` and the accuracy tests compare the estimates with it) and
``eyes.json`` (the simulated eyes: rotation centres, noise, bias, sensor models). The other truth
files are in the program's formats and go through their modules: ``camera.json``
(formats/camera.py), ``head_poses.csv`` (formats/poses.py), ``viewlines.csv``
(formats/viewlines.py), ``gaze.csv`` (a table, formats/tables.py).

One reader and one writer each: ``read_truth_targets`` / ``write_truth_targets``,
``read_truth_eyes`` / ``write_truth_eyes``.
"""

from __future__ import annotations

import logging

from ..errors import UserError
from .jsonio import read_json_text, write_json

log = logging.getLogger(__name__)


def write_truth_targets(path, targets: list[dict]) -> None:
    """Write truth/targets.json: per target a dict with ``index``, ``name``, ``moving``,
    ``fixations_s`` ([start, end] pairs, s) and ``position_mm`` (3,) or, moving, ``path_t_s``
    (K,) and ``path_mm`` (K, 3), world frame, mm."""
    write_json(path, {"version": 1, "targets": targets})


def read_truth_targets(path) -> list[dict]:
    """The targets of a truth/targets.json (the dicts ``write_truth_targets`` wrote).

    Raises:
        UserError: a missing or malformed file.
    """
    d = read_json_text(path, "simulator's truth targets file")
    if not isinstance(d, dict) or not isinstance(d.get("targets"), list):
        raise UserError(f"{path}: no 'targets' list; simulate the session again (wearable-gaze simulate)")
    return d["targets"]


def write_truth_eyes(path, eyes: dict) -> None:
    """Write truth/eyes.json: the dict of ``sim.eyes.EyeModel.to_dict`` (``centres_mm`` (2, 3),
    scene-camera frame, mm; ``sigma_deg``; ``bias_deg`` (2, 2); ``sensors``)."""
    write_json(path, eyes)


def read_truth_eyes(path) -> dict:
    """The dict of a truth/eyes.json (as ``write_truth_eyes`` wrote it).

    Raises:
        UserError: a missing or malformed file.
    """
    return read_json_text(path, "simulator's truth eyes file")
