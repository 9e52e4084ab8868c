"""The eye-calibration recording of a session: ``calibration/eye/``, with ``walls.json``
describing each wall recording, the scene camera's image of each wall and
``eye_calibration.csv`` (the eye samples with ``recording`` and ``target`` columns,
``formats/eye_samples.py``) (docs/session.md, calibration/eye; listed in docs/formats.md).

One reader, ``read_walls`` (walls.json checked against schemas/walls.schema.json through
``jsonio``, each wall typed, its image path resolved inside the folder), and one writer,
``write_walls`` (the wall images, then walls.json).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import UserError
from .images import write_image
from .jsonio import inside, load_json, write_json

WALLS_FILE = "walls.json"
EYE_CSV = "eye_calibration.csv"

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Wall:
    """One wall recording of walls.json (wall frame: x right, y down, origin at the centre dot; mm).

    Attributes:
        recording: its number in the ``recording`` column of eye_calibration.csv (default: its
            position in walls.json).
        image: its image file, inside the folder.
        image_name: ``image`` as walls.json gives it.
        distance_mm: the nominal wall distance, or None.
        targets_wall_mm: (K, 2) the dots, in the order of the ``target`` column.
        dictionary: the reference markers' ``cv2.aruco`` dictionary.
        marker_size_mm: their side.
        markers_wall_mm: {id: (2,) centre} of the reference markers, in file order.
        entry: the recording's object as walls.json holds it (the simulator's truth too).
    """

    recording: int
    image: Path
    image_name: str
    distance_mm: float | None
    targets_wall_mm: np.ndarray
    dictionary: str
    marker_size_mm: float
    markers_wall_mm: dict
    entry: dict


@dataclass(frozen=True)
class WallsRecording:
    """An eye-calibration recording: its eye_calibration.csv, walls.json and walls (in file order)."""

    csv_path: Path
    walls_path: Path
    walls: tuple

    @property
    def images(self) -> list[Path]:
        """Each wall's image file."""
        return [w.image for w in self.walls]


def eye_calibration_folder(src) -> tuple[Path, Path]:
    """(folder, eye_calibration.csv) of a session folder, its calibration/eye folder or the CSV.

    Raises:
        UserError: none of these holds an eye_calibration.csv.
    """
    src = Path(src)
    if src.is_file() and src.suffix.lower() == ".csv":
        return src.parent, src
    for cand in (src / "calibration" / "eye", src):
        if (cand / EYE_CSV).is_file():
            return cand, cand / EYE_CSV
    raise UserError(f"{src}: no {EYE_CSV} here or in calibration/eye/; pass a session folder, its "
                    "calibration/eye folder or the CSV (docs/session.md)")


def read_walls(src) -> WallsRecording:
    """The eye-calibration recording of a session folder, its calibration/eye folder or the CSV
    (the CSV itself is read by ``formats.eye_samples.read_eye_csv``).

    Raises:
        UserError: no eye_calibration.csv; walls.json missing or invalid, or an image path that
            leaves the folder (one line: the file, the field, the fix).
    """
    folder, csv_path = eye_calibration_folder(src)
    walls_path = folder / WALLS_FILE
    d = load_json(walls_path, "walls")
    walls = tuple(
        Wall(int(e.get("recording", r)), inside(folder, e["image"], walls_path, "walls", ["recordings", r, "image"]),
             e["image"], e.get("distance_mm"), np.asarray(e["targets_wall_mm"], float), e["dictionary"],
             float(e["marker_size_mm"]), {int(k): np.asarray(c, float) for k, c in e["markers_wall_mm"].items()}, e)
        for r, e in enumerate(d["recordings"]))
    return WallsRecording(csv_path, walls_path, walls)


def write_walls(folder, entries: list[dict], images=None) -> None:
    """Write ``images`` (one (H, W) grey image per entry, or None: none) under each entry's
    ``image`` name in ``folder``, then walls.json with the ``entries`` (docs/session.md)."""
    folder = Path(folder)
    if images is not None:
        for e, img in zip(entries, images, strict=True):
            write_image(folder / e["image"], img)
    write_json(folder / WALLS_FILE, {"version": 1, "recordings": entries})
