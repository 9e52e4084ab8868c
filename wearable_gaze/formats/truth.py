"""The simulator's ground truth of a session, ``truth/`` (docs/session.md, truth/; listed in
docs/formats.md), in the formats of its own: ``targets.json`` (each target's position or path
and its fixation intervals; ``demo`` and the accuracy tests compare the estimates with it) and
``eyes.json`` (the simulated eyes: rotation centres, noise, bias, sensor models) and, when a
marker moved during the session, ``moved_markers.json`` (its time and both poses). The other truth
files are in the program's formats and go through their modules: ``camera.json``
(formats/camera.py), ``markers.json`` (the true map, formats/markermap.py), ``head_poses.csv``
(formats/poses.py), ``viewlines.csv`` (formats/viewlines.py), ``gaze.csv`` (a table,
formats/tables.py).

One reader and one writer each: ``read_truth_targets`` / ``write_truth_targets``,
``read_truth_eyes`` / ``write_truth_eyes``, ``read_truth_moved_markers`` /
``write_truth_moved_markers``.
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
    return _truth_list(path, "targets", "simulator's truth targets file")


def _truth_list(path, key: str, what: str) -> list:
    """The list under ``key`` of a truth JSON file (``what`` it is, for messages)."""
    d = read_json_text(path, what)
    if not isinstance(d, dict) or not isinstance(d.get(key), list):
        raise UserError(f"{path}: no '{key}' list; simulate the session again (wearable-gaze simulate)")
    return d[key]


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


def write_truth_moved_markers(path, moved: list[dict]) -> None:
    """Write truth/moved_markers.json: per marker moved during the session a dict with ``id``,
    ``at_s`` (the time of the move, s: frames at or after it see the new pose), ``shift_mm`` (3,)
    and ``turn_deg`` (the move in the marker's own frame, as the scenario gave it),
    ``T_world_from_marker_before`` and ``T_world_from_marker_after`` (4, 4), and
    ``corners_before_mm`` and ``corners_after_mm`` (4, 3), world frame, mm. The session's
    markers.json has the pose before the move."""
    write_json(path, {"version": 1, "moved_markers": moved})


def read_truth_moved_markers(path) -> list[dict]:
    """The moved markers of a truth/moved_markers.json (the dicts ``write_truth_moved_markers``
    wrote).

    Raises:
        UserError: a missing or malformed file.
    """
    return _truth_list(path, "moved_markers", "simulator's truth moved markers file")
