"""Scene videos and their frame timestamps (docs/session.md, "scene video" and
``scene_timestamps.csv``; listed in docs/formats.md).

Video frames are read as grey images (``gray_frames``, every k-th: ``sampled_gray_frames``; ``open_video``
for a capture to step through) and written
through ``open_video_writer`` (OpenCV's FFMPEG backend: mp4v, MJPG, FFV1, which browsers do not
play) or, for a browser, ``BrowserVideoWriter`` (H.264 in MP4 through PyAV). The frame-timestamp CSV (columns
``frame, t``; ``t`` in s on the session clock) has one reader, ``read_frame_times``, and one
writer, ``write_frame_times``; a recorder that streams it writes ``FRAME_TIME_HEADER`` and one
``frame_time_line`` per frame, the same text.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from calibration.images import to_gray
from estimator.deprecation import module_getattr

from ..errors import UserError
from .tables import read_table, write_table

FRAME_TIME_COLUMNS = ["frame", "t"]
FRAME_TIME_FORMATS = {"t": ".6f"}
FRAME_TIME_HEADER = ",".join(FRAME_TIME_COLUMNS) + "\n"

log = logging.getLogger(__name__)


def gray_frames(path):
    """Yield every frame of a video as a (H, W) uint8 grey image."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    try:
        while True:
            ok, frame = cap.read()
            if not ok:
                return
            yield to_gray(frame)
    finally:
        cap.release()


def video_fps(path) -> float:
    """A video's frame rate (30 when it does not say)."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    try:
        return float(cap.get(cv2.CAP_PROP_FPS) or 30.0)
    finally:
        cap.release()


def gray_frames_at(path, frames) -> dict:
    """{frame index: (H, W) uint8 grey image} of the frames ``frames`` (indices from 0) of a video,
    decoded in order (the frames between are skipped undecoded); an index past its end is absent."""
    import cv2

    want, out = set(int(i) for i in frames), {}
    cap = cv2.VideoCapture(str(path))
    try:
        i = 0
        while want - set(out) and i <= max(want) and cap.grab():
            if i in want:
                ok, frame = cap.retrieve()
                if ok:
                    out[i] = to_gray(frame)
            i += 1
    finally:
        cap.release()
    return out


def sampled_gray_frames(path, max_frames: int, refused: str | None = None):
    """Yield (frame index, (H, W) uint8 grey image) of every k-th frame of a video, k = its frame
    count // ``max_frames`` (at least 1): about ``max_frames`` frames spread over it; the frames
    between are skipped undecoded.

    Raises:
        UserError: OpenCV cannot open ``path`` as a video (``refused`` is the message, naming the fix).
    """
    import cv2

    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise UserError(refused or f"{path}: OpenCV cannot open this video; check that it plays, or re-encode it")
    try:
        step = max((int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) or 1) // max_frames, 1)
        i = 0
        while cap.grab():
            if i % step == 0:
                ok, frame = cap.retrieve()
                if ok:
                    yield i, to_gray(frame)
            i += 1
    finally:
        cap.release()


def open_video(video: Path, image_size):
    """(capture, fps, frame count or 0) of a video whose frames are ``image_size`` (width, height),
    the size of the camera calibration that will measure them.

    Raises:
        UserError: no such file, a video OpenCV cannot open, or frames of another size.
    """
    import cv2

    if not video.is_file():
        raise UserError(f"{video}: no such video; check the path")
    cap = cv2.VideoCapture(str(video))
    if not cap.isOpened():
        raise UserError(f"{video}: OpenCV cannot open this video (corrupt, or a codec FFMPEG lacks); re-encode it, "
                        "e.g. ffmpeg -i IN -c:v mpeg4 OUT.mp4")
    w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
    if (w, h) != tuple(image_size):
        cap.release()
        raise UserError(f"{video} is {w}x{h} but the camera calibration is for {image_size[0]}x"
                        f"{image_size[1]}; calibrate this camera at this resolution (calibrate-camera)")
    return cap, cap.get(cv2.CAP_PROP_FPS) or 30.0, int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) or 0


def open_video_writer(path, codec: str, fps: float, size, is_color: bool = True, refused: str | None = None):
    """A ``cv2.VideoWriter`` (FFMPEG backend) on ``path`` with the four-character ``codec``
    ('mp4v', 'MJPG', 'FFV1'), ``fps`` frames per second and frames of ``size`` (width, height).
    The caller releases it.

    Raises:
        UserError: OpenCV refused to open it (``refused`` is the message, naming the fix).
    """
    import cv2

    writer = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*codec), float(fps),
                             tuple(int(v) for v in size), isColor=is_color)
    if not writer.isOpened():
        writer.release()
        raise UserError(refused or f"cannot write {codec} video {path}: OpenCV's FFMPEG backend refused it")
    return writer


BROWSER_CODEC = "libx264"
"""The browser video's encoder: H.264 (High profile, yuv420p), which every browser plays in MP4."""
BROWSER_CRF = 28
"""... its constant quality (x264's CRF: 23 is its default, higher is smaller; 28 keeps drawn
lines and labels sharp at a few hundred kB a minute at 640 px)."""


class BrowserVideoWriter:
    """An H.264 MP4 video that browsers play (``<video>``), written frame by frame through PyAV
    (libx264, yuv420p, the index at the front: it starts playing before it is all loaded).

    Args:
        path: the file to write (.mp4).
        fps: frames per second.
        size: (width, height) of the frames given, px; odd sizes lose their last row or column
            (yuv420p needs even ones).

    Raises:
        UserError: PyAV is missing or its FFmpeg has no H.264 encoder (the fix named).
    """

    def __init__(self, path, fps: float, size):
        from fractions import Fraction

        try:
            import av
        except ImportError:
            raise UserError("the overlay video needs PyAV: pip install av") from None
        if BROWSER_CODEC not in av.codecs_available:
            raise UserError(f"PyAV's FFmpeg has no {BROWSER_CODEC} encoder: pip install --force-reinstall av "
                            "(its wheels carry one)")
        self._av = av
        self.width, self.height = int(size[0]) // 2 * 2, int(size[1]) // 2 * 2
        self.container = av.open(str(path), mode="w", format="mp4", options={"movflags": "+faststart"})
        self.stream = self.container.add_stream(BROWSER_CODEC, rate=Fraction(float(fps)).limit_denominator(1001))
        self.stream.width, self.stream.height, self.stream.pix_fmt = self.width, self.height, "yuv420p"
        self.stream.options = {"crf": str(BROWSER_CRF), "preset": "veryfast"}
        self.frames = 0

    def write(self, frame_bgr: np.ndarray) -> None:
        """Append one frame, (H, W, 3) uint8 BGR."""
        f = self._av.VideoFrame.from_ndarray(np.ascontiguousarray(frame_bgr[:self.height, :self.width]),
                                             format="bgr24")
        self.container.mux(self.stream.encode(f))
        self.frames += 1

    def close(self) -> None:
        """Flush the encoder and close the file."""
        self.container.mux(self.stream.encode(None))
        self.container.close()


def frame_time_line(frame: int, t: float) -> str:
    """One row of the frame-timestamp CSV: frame number, time (s, 6 decimals), newline."""
    return f"{frame},{t:.6f}\n"


def write_frame_times(path, frames, t) -> None:
    """Write the frame-timestamp CSV: frame numbers (N,) and times (N,), s, atomically."""
    write_table(path, {"frame": np.asarray(frames), "t": np.asarray(t, float)}, FRAME_TIME_FORMATS)


def read_frame_times(path) -> tuple[np.ndarray, np.ndarray]:
    """(frame (N,) int, t (N,) s) of a frame-timestamp CSV, in file order.

    Raises:
        UserError: a time that does not increase (pose interpolation needs them in order).
    """
    tab = read_table(path, FRAME_TIME_COLUMNS, what="frame-timestamp CSV")
    t = tab["t"]
    bad = np.flatnonzero(np.diff(t) <= 0)
    if len(bad):
        raise UserError(f"{path} line {bad[0] + 3}: frame times must increase; fix or remove the row")
    return tab["frame"].astype(int), t


if not TYPE_CHECKING:      # old names (issue 30), for one release; unseen by mypy
    __getattr__ = module_getattr(globals(), {"grey_frames": "gray_frames", "grey_frames_at": "gray_frames_at",
                                             "sampled_grey_frames": "sampled_gray_frames"})
