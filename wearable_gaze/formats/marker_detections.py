"""The tracking step's marker detections, ``.marker_detections.npz`` (docs/formats.md, "Outputs
of process"): every marker the detector found in each scene-video frame it ran on, kept so that
the report's overlay draws them without detecting them again.

``MarkerDetections`` holds them as flat arrays and reads as a mapping {frame number:
[``MarkerDetection``]} (a frame the detector ran on and found nothing in: an empty list; a frame it
did not run on is not a key). The file is NumPy's ``.npz`` (no pickled objects): ``frames`` (K,)
int64, increasing; ``counts`` (K,) int64, each frame's detections; ``marker_id`` (M,) int64 and
``corners_px`` (M, 4, 2) float64 (the distorted image's pixels, OpenCV's convention,
``cv2.aruco``'s corner order), frame by frame in ``frames``' order.

One writer, ``write_marker_detections``, and one reader, ``read_marker_detections``.
"""

from __future__ import annotations

import zipfile
from collections.abc import Iterator, Mapping

import numpy as np

from tracking.markers import MarkerDetection, detection

from ..errors import UserError
from .atomic import atomic_path

NAME = ".marker_detections.npz"
"""Its name in the output folder."""


class MarkerDetections(Mapping):
    """{frame number: [``MarkerDetection``]} over flat arrays (see the module's docstring for each
    one's shape and unit); read-only."""

    def __init__(self, frames, counts, marker_id, corners_px):
        self.frames = np.asarray(frames, np.int64).reshape(-1)
        self.counts = np.asarray(counts, np.int64).reshape(-1)
        self.marker_id = np.asarray(marker_id, np.int64).reshape(-1)
        self.corners_px = np.asarray(corners_px, float).reshape(-1, 4, 2)
        if len(self.counts) != len(self.frames) or int(self.counts.sum()) != len(self.marker_id) \
                or len(self.corners_px) != len(self.marker_id) or np.any(self.counts < 0):
            raise ValueError(f"{len(self.frames)} frames with {len(self.counts)} counts summing to "
                             f"{int(self.counts.sum())}, for {len(self.marker_id)} ids and "
                             f"{len(self.corners_px)} corners")
        if np.any(np.diff(self.frames) <= 0):
            raise ValueError("frames must increase")
        self._start = np.concatenate([[0], np.cumsum(self.counts)])
        self._row = {int(f): k for k, f in enumerate(self.frames)}

    @classmethod
    def of(cls, found: dict) -> MarkerDetections:
        """From {frame: [``MarkerDetection``]} (frames in any order)."""
        frames = sorted(int(f) for f in found)
        dets = [d for f in frames for d in found[f]]
        return cls(frames, [len(found[f]) for f in frames], [d.marker_id for d in dets],
                   np.array([d.corners_px for d in dets], float).reshape(-1, 4, 2))

    def __getitem__(self, frame) -> list[MarkerDetection]:
        k = self._row[int(frame)]
        a, b = self._start[k], self._start[k + 1]
        return [detection(int(i), c) for i, c in zip(self.marker_id[a:b], self.corners_px[a:b], strict=True)]

    def __iter__(self) -> Iterator[int]:
        return iter(int(f) for f in self.frames)

    def __len__(self) -> int:
        return len(self.frames)

    def __contains__(self, frame) -> bool:
        return isinstance(frame, (int, np.integer)) and int(frame) in self._row


def write_marker_detections(path, detections: MarkerDetections) -> None:
    """Write ``detections`` as a ``.npz`` file, atomically."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, frames=detections.frames, counts=detections.counts, marker_id=detections.marker_id,
                 corners_px=detections.corners_px)


def read_marker_detections(path) -> MarkerDetections:
    """The detections of a file ``write_marker_detections`` wrote.

    Raises:
        UserError: not such a file (one line, naming what is wrong).
    """
    try:
        with np.load(path, allow_pickle=False) as z:
            return MarkerDetections(z["frames"], z["counts"], z["marker_id"], z["corners_px"])
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
        raise UserError(f"{path}: not the tracking step's marker detections ({exc}); run 'wearable-gaze process' "
                        "again (--force)") from None
