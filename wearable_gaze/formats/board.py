"""The camera-calibration recording of a session: ``calibration/camera/``, views of a board
(images) and ``board.json`` describing the board (docs/session.md, calibration/camera; listed in
docs/formats.md).

One reader, ``read_board`` (board.json checked against schemas/board.schema.json through
``jsonio``, the board as a ``BoardSpec``, the folder's images as its views), and one writer,
``write_board`` (the views as ``view_NNN.png``, then board.json).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibration.camera import BoardSpec

from ..errors import UserError
from .images import image_files, write_image
from .jsonio import load_json, write_json

BOARD_FILE = "board.json"

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class BoardRecording:
    """A camera-calibration recording.

    Attributes:
        path: its board.json.
        spec: the board.
        board: the board object as board.json holds it.
        views: the image files of the folder (``formats.images.IMAGE_EXT``), sorted by name.
        truth_T_cam_from_board: (K, 4, 4) the simulator's true board pose in each view, mm, or
            None.
    """

    path: Path
    spec: BoardSpec
    board: dict
    views: tuple
    truth_T_cam_from_board: np.ndarray | None = None


def _spec(board: dict, source) -> BoardSpec:
    """The ``BoardSpec`` of board.json's ``board`` object (``source``: the file)."""
    try:
        if board["type"] == "chessboard":
            spec = BoardSpec("chessboard", int(board["cols"]), int(board["rows"]), float(board["square_mm"]))
        else:
            spec = BoardSpec("charuco", int(board["cols"]), int(board["rows"]), float(board["square_mm"]),
                             float(board["marker_mm"]), board["dictionary"])
        spec.validate()
    except ValueError as exc:
        raise UserError(f"{source}: {exc}; fix the board (docs/session.md)") from None
    return spec


def read_board(folder) -> BoardRecording:
    """The recording in ``folder`` (a session's calibration/camera).

    Raises:
        UserError: board.json missing or invalid (one line: the file, the field, the fix).
    """
    folder = Path(folder)
    path = folder / BOARD_FILE
    d = load_json(path, "board")
    truth = d.get("truth_T_cam_from_board")
    return BoardRecording(path, _spec(d["board"], path), d["board"], tuple(image_files(folder)),
                          None if truth is None else np.asarray(truth, float).reshape(-1, 4, 4))


def write_board(folder, board: dict, views=(), truth_T_cam_from_board=None) -> None:
    """Write a recording into ``folder``: each of ``views`` ((H, W) grey images, an iterable) as
    view_000.png, view_001.png, ..., then board.json with the ``board`` object (docs/session.md)
    and, when given, the true board poses (K, 4, 4), mm."""
    folder = Path(folder)
    for i, img in enumerate(views):
        write_image(folder / f"view_{i:03d}.png", img)
    d = {"version": 1, "board": board}
    if truth_T_cam_from_board is not None:
        d["truth_T_cam_from_board"] = [np.asarray(T, float).tolist() for T in truth_T_cam_from_board]
    write_json(folder / BOARD_FILE, d)
