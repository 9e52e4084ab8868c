"""The markerless map folder (``wearable-gaze map --markerless``; docs/formats.md, "Markerless
map"): a room's 3D points with the features they were seen with, for ``track --map`` and
``process --map`` to localise frames against (``tracking.localise``).

    sfm/sfm_map.json      what the map is: world frame, scale, the camera, the survey's views,
                          quality figures (schemas/sfm-map.schema.json)
    sfm/features.npz      points_world_mm (P, 3) float64 mm; descriptors (M, 128) uint8 (RootSIFT
                          times 512, as COLMAP stores SIFT); point_of (M,) int32, each descriptor's
                          point
    sfm/colmap/           pycolmap's own reconstruction (cameras, images, points3D .bin), in its
                          arbitrary unit, for COLMAP's viewer; ``T_world_from_sfm`` maps it to ours
    sfm/sfm_top_view.png  the points and the survey path from above

One reader, ``load_sfm_map``, and one writer, ``write_sfm_map`` (into a folder being built).
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from tracking.localise import FeatureMap, colmap_descriptors

from ..errors import UserError
from .jsonio import load_json, write_json

FORMAT = "wearable-gaze-sfm-map"
MAP_JSON, FEATURES = "sfm_map.json", "features.npz"


def is_sfm_map(path) -> bool:
    """Whether ``path`` is a markerless map folder (it holds ``sfm_map.json``)."""
    return Path(path).is_dir() and (Path(path) / MAP_JSON).is_file()


def write_sfm_map(folder, fmap: FeatureMap, meta: dict) -> None:
    """Write ``fmap`` and ``meta`` (the JSON's fields besides format and version) into ``folder``."""
    folder = Path(folder)
    np.savez_compressed(folder / FEATURES, points_world_mm=fmap.points_world,
                        descriptors=colmap_descriptors(fmap.descriptors), point_of=fmap.point_of.astype(np.int32))
    write_json(folder / MAP_JSON, {"format": FORMAT, "version": 1, **meta})


def load_sfm_map(folder) -> tuple[FeatureMap, dict]:
    """(the map's points and descriptors, its JSON) of a markerless map folder.

    Raises:
        UserError: not such a folder, a malformed JSON or features file.
    """
    folder = Path(folder)
    if not is_sfm_map(folder):
        raise UserError(f"{folder}: not a markerless map folder (no {MAP_JSON}); build one with "
                        "wearable-gaze map --markerless VIDEO --camera CAMERA -o FOLDER")
    meta = load_json(folder / MAP_JSON, "sfm-map")
    try:
        with np.load(folder / FEATURES) as z:
            pts, desc, idx = z["points_world_mm"], z["descriptors"], z["point_of"]
        d = desc.astype(np.float32) / 512
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        fmap = FeatureMap(pts, d, idx)
    except (OSError, KeyError, ValueError, zipfile.BadZipFile) as exc:
        raise UserError(f"{folder / FEATURES}: not a features file of a markerless map ({exc}); rebuild the "
                        "map with wearable-gaze map --markerless") from None
    if len(fmap.points_world) != meta["points"]:
        raise UserError(f"{folder / FEATURES}: {len(fmap.points_world)} points but {MAP_JSON} says "
                        f"{meta['points']}; the two files are of different maps: rebuild the map")
    return fmap, meta
