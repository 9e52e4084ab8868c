"""The session folder and its manifest ``session.json`` (docs/session.md): what the simulator
writes, the live app records and ``wearable-gaze process`` reads.

One reader, ``load_session`` (the manifest checked against schemas/session.schema.json through
``jsonio``, and every file it names present), and one writer of the manifest,
``write_manifest``. The files inside have their own modules: eye_samples (eye CSV), poses,
video (scene video, frame timestamps), markermap, camera, eyes, viewlines, serial_protocol.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import UserError
from .eye_samples import EyeSamples, read_eye_csv
from .jsonio import load_json, write_json
from .video import read_frame_times

FORMAT = "wearable-gaze-session"
VERSION = 1
MANIFEST = "session.json"

log = logging.getLogger(__name__)


def write_manifest(root, manifest: dict) -> None:
    """Write a session folder's manifest ``ROOT/session.json`` (format ``FORMAT``), atomically."""
    write_json(Path(root) / MANIFEST, manifest)


# --- the session ---------------------------------------------------------------------------------

@dataclass
class Session:
    """A loaded session folder (lazy: large files are opened on demand).

    Attributes:
        root: the folder.
        manifest: ``session.json``.
    """

    root: Path
    manifest: dict

    def path(self, key: str) -> Path | None:
        rel = self.manifest.get("files", {}).get(key)
        return None if rel is None else self.root / rel

    def frame_times(self) -> np.ndarray:
        """(N,) frame times of the scene video, s (checked to increase by ``read_frame_times``)."""
        return read_frame_times(self.path("scene_timestamps"))[1]

    def eye_samples(self) -> EyeSamples:
        return read_eye_csv(self.path("eye_samples"))[0]

    def marker_map(self) -> dict | None:
        p = self.path("marker_map")
        return None if p is None else load_json(p, "marker-map")

    @property
    def image_size(self) -> tuple[int, int]:
        w, h = self.manifest["image_size"]
        return int(w), int(h)


def load_session(root) -> Session:
    """Open a session folder and check its manifest and the files it names.

    Raises:
        UserError: naming what is missing or wrong.
    """
    root = Path(root)
    if root.is_file():
        raise UserError(f"{root}: a file, and no such session folder; a device's recording is imported first: "
                        f"wearable-gaze import {root} -o SESSION (docs/importers.md)")
    if not root.is_dir():
        raise UserError(f"{root}: no such session folder; record one or run 'wearable-gaze simulate -o {root}'")
    if not (root / MANIFEST).exists():
        raise UserError(f"{root}: not a session folder: no such file {MANIFEST}; a device's recording is imported "
                        f"first: wearable-gaze import {root} -o SESSION (docs/importers.md)")
    man = load_json(root / MANIFEST, "session")        # schema: format, version, files inside root
    for key, rel in man["files"].items():
        if not (root / rel).exists():
            raise UserError(f"{root / rel}: listed in session.json as {key} but missing; restore the file or "
                            f"remove 'files.{key}' from the manifest")
    return Session(root, man)
