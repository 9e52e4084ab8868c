"""The marker map JSON (docs/session.md, "Marker map"; listed in docs/formats.md): where each
printed marker is in the world, as ``T_world_from_marker`` (4x4, mm) or its four ``corners_mm``.

One reader, ``load_marker_map`` (schemas/marker-map.schema.json through ``jsonio``, then the
checks a schema cannot make: ids in the dictionary, each once, rigid poses, square corners,
millimetres), and one writer, ``write_marker_map`` (the dict of ``marker_map_dict``, or the
template to fill in of ``marker_map_template``). The map itself is ``tracking.markermap.MarkerMap``.
"""

from __future__ import annotations

import logging

import numpy as np

from calibration.camera import aruco_dictionary
from tracking.markermap import MarkerMap, MarkerMapError, pose_from_corners

from ..errors import UserError
from .jsonio import load_json, write_json

FORMAT = "wearable-gaze-marker-map"
TEMPLATE_HELP = ("Measure each marker's four corners (top-left, top-right, bottom-right, bottom-left of the printed "
                 "square) in the room's frame, in mm, or give T_world_from_marker; see docs/formats.md.")

log = logging.getLogger(__name__)


def marker_map_dict(dictionary: str, marker_size_mm: float, poses: dict, labels: dict | None = None,
                    extra: dict | None = None, sizes: dict | None = None, camera: dict | None = None) -> dict:
    """The marker map JSON object: per id (ascending) its ``T_world_from_marker`` (4, 4), mm,
    rounded to 1e-9, its ``size_mm`` when ``sizes`` gives it another than ``marker_size_mm``, its
    label when ``labels`` has one, and the fields ``extra[id]`` gives (a built map's
    ``n_views``, ``rms_px``, ``covariance``, ``flags``; docs/formats.md); ``camera``: a built
    map's ``camera_intrinsics`` object (the intrinsics it was built with, refined or not)."""
    labels, extra = labels or {}, extra or {}
    other = {i: float(v) for i, v in (sizes or {}).items() if float(v) != float(marker_size_mm)}
    return {"format": FORMAT, "version": 1, "dictionary": dictionary,
            "marker_size_mm": float(marker_size_mm), **({"camera_intrinsics": camera} if camera else {}),
            "markers": [{"id": int(i), "T_world_from_marker": np.round(np.asarray(T, float), 9).tolist(),
                         **({"size_mm": other[i]} if i in other else {}),
                         **({"label": labels[i]} if i in labels else {}), **extra.get(i, {})}
                        for i, T in sorted(poses.items())]}


def marker_map_template(dictionary: str, marker_size_mm: float, ids) -> dict:
    """A marker map to fill in: each id with an empty label and four zero corners (mm)."""
    return {"format": FORMAT, "version": 1, "dictionary": dictionary, "marker_size_mm": marker_size_mm,
            "_help": TEMPLATE_HELP,
            "markers": [{"id": int(i), "label": "", "corners_mm": [[0, 0, 0]] * 4} for i in ids]}


def write_marker_map(path, marker_map: dict) -> None:
    """Write a marker map JSON object (``marker_map_dict`` or ``marker_map_template``), atomically."""
    write_json(path, marker_map)


def load_marker_map(path) -> MarkerMap:
    """A marker map JSON, checked against its schema, then loaded (rigid poses, square corners)."""
    try:
        return marker_map_from_dict(load_json(path, "marker-map"))
    except MarkerMapError as exc:
        raise UserError(f"{path}: {exc}; fix the marker map (see docs/session.md, marker map)") from None


def read_map_intrinsics(path) -> dict | None:
    """A built map's ``camera_intrinsics`` object (checked against the schema), None when it has
    none (a measured map, or one built before it existed)."""
    return load_json(path, "marker-map").get("camera_intrinsics")


def marker_map_from_dict(d: dict) -> MarkerMap:
    """Check and load a parsed marker map. Each marker gives ``T_world_from_marker`` (4x4) or
    ``corners_mm`` (4x3, cv2.aruco order).

    Raises:
        MarkerMapError: unknown dictionary, duplicate ids, ids beyond the dictionary, a pose
            that is not a rigid transform, corners that are not a square of the stated size,
            sizes that look like metres.
    """
    if not isinstance(d, dict):
        raise MarkerMapError("expected a JSON object")
    if d.get("format", FORMAT) != FORMAT:
        raise MarkerMapError(f"'format' is {d.get('format')!r}, expected {FORMAT!r}")
    name = d.get("dictionary")
    try:
        dic = aruco_dictionary(str(name))
    except ValueError as exc:
        raise MarkerMapError(str(exc)) from None
    size = d.get("marker_size_mm")
    if not isinstance(size, (int, float)) or not size > 0:
        raise MarkerMapError(f"'marker_size_mm' must be a positive number of millimetres, got {size!r}")
    if size < 5:
        raise MarkerMapError(f"'marker_size_mm' is {size}: that is a marker smaller than 5 mm; sizes are in "
                             f"millimetres (a {size * 1000:g} mm marker is written {size * 1000:g}, not {size})")
    markers = d.get("markers")
    if not isinstance(markers, list) or not markers:
        raise MarkerMapError("'markers' must be a non-empty list")
    n_ids = dic.bytesList.shape[0]
    poses, labels, sizes = {}, {}, {}
    for k, m in enumerate(markers):
        if not isinstance(m, dict) or "id" not in m:
            raise MarkerMapError(f"markers[{k}]: needs an 'id'")
        i = m["id"]
        if not isinstance(i, int) or not 0 <= i < n_ids:
            raise MarkerMapError(f"markers[{k}]: id {i!r} is not in {name} (0-{n_ids - 1})")
        if i in poses:
            raise MarkerMapError(f"marker {i} appears twice; each id may be placed once")
        own = m.get("size_mm", size)
        if not isinstance(own, (int, float)) or not 5 <= own <= 100000:
            raise MarkerMapError(f"marker {i}: 'size_mm' must be the printed side in millimetres (5 or more), "
                                 f"got {own!r}")
        if own != size:
            sizes[i] = float(own)
        poses[i] = _marker_pose(m, float(own), i)
        if "label" in m:
            labels[i] = str(m["label"])
    return MarkerMap(str(name), float(size), poses, labels, sizes)


def _marker_pose(m: dict, size: float, i: int) -> np.ndarray:
    """(4, 4) ``T_world_from_marker`` of marker entry ``m`` (id ``i``), checked rigid."""
    if "T_world_from_marker" in m:
        T = np.asarray(m["T_world_from_marker"], float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise MarkerMapError(f"marker {i}: T_world_from_marker must be a 4x4 matrix")
        R = T[:3, :3]
        if (np.abs(R @ R.T - np.eye(3)).max() > 1e-4 or np.linalg.det(R) < 0
                or np.abs(T[3] - [0, 0, 0, 1]).max() > 1e-9):
            raise MarkerMapError(f"marker {i}: T_world_from_marker is not a rigid transform (rotation "
                                 "part must be orthonormal, last row 0 0 0 1)")
        return T
    if "corners_mm" in m:
        return pose_from_corners(np.asarray(m["corners_mm"], float), size, i)
    raise MarkerMapError(f"marker {i}: give T_world_from_marker or corners_mm")
