"""Textured rectangles of the simulated world (``Plane``: pose, size, texture, its pyramid and
area-sampled levels) and printed markers as planes.

Each plane is a rectangle ``size_mm`` in its own frame (x right, y down along the texture, z its
normal, pointing away from the side that is seen), placed by ``T_world_from_plane``. Texture
pixel centre ``(i + 0.5, j + 0.5)`` sits at ``((i + 0.5) w / W, (j + 0.5) h / H)`` mm in the plane
frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from calibration.camera import aruco_dictionary


@dataclass(frozen=True, eq=False)
class Plane:
    """A textured rectangle in the world.

    Attributes:
        T_world_from_plane: (4, 4) pose of the plane frame (x, y in the plane, z its normal), mm.
        size_mm: (width, height) of the rectangle, mm.
        texture: (H, W) uint8 grey texture covering the whole rectangle.
        name: a label.
        supersample: samples per pixel along each axis (area sampling: each pixel is the mean of
            ``supersample^2`` samples). Markers use 2: gradient-based corner refinement is
            biased toward the inside of a blurred L-corner, so their edges must be as sharp as
            a real pixel's box integration makes them.
        shell: part of the convex enclosure (a room's walls, floor, ceiling). Seen from inside
            a convex room no shell plane hides another and every other plane is in front of
            them, so shell planes skip the depth test and take the fast path: drawn by
            ``cv2.warpPerspective`` into an undistorted canvas that one ``cv2.remap`` distorts.
    """

    T_world_from_plane: np.ndarray
    size_mm: tuple[float, float]
    texture: np.ndarray
    name: str = ""
    supersample: int = 1
    shell: bool = False
    max_texel_step: float = 1.5
    box_prefilter: bool = False
    _pyramid: list = field(default_factory=list, repr=False)
    _pyramid2: list = field(default_factory=list, repr=False)

    def corners_world(self) -> np.ndarray:
        """(4, 3) corners in the world frame: (0,0), (w,0), (w,h), (0,h) of the plane frame, mm."""
        w, h = self.size_mm
        c = np.array([[0, 0, 0, 1], [w, 0, 0, 1], [w, h, 0, 1], [0, h, 0, 1.0]])
        return (self.T_world_from_plane @ c.T).T[:, :3]

    def level(self, k: int) -> tuple[np.ndarray, int]:
        """Texture pyramid level ``k`` (0 is the texture itself), each level Gaussian-filtered and
        halved (``cv2.pyrDown``), and the level actually returned (a small texture has fewer)."""
        if not self._pyramid:
            self._pyramid.append(np.ascontiguousarray(self.texture, dtype=np.float32))
        while len(self._pyramid) <= k:
            prev = self._pyramid[-1]
            if min(prev.shape[:2]) < 4:
                break
            self._pyramid.append(cv2.pyrDown(prev))
        k = min(k, len(self._pyramid) - 1)
        return self._pyramid[k], k

    def boxed(self, k: int, ksize: int) -> tuple[np.ndarray, int, float]:
        """``level2(k)`` zero-padded and box-filtered with a ``ksize`` square (cached): the
        texture convolved with one pixel's footprint. Returns the image, the level and the
        index offset to add to level-``k`` index coordinates (padding minus the even-kernel
        half-texel shift of ``cv2.boxFilter``'s anchor)."""
        cache = self.__dict__.setdefault("_boxed", {})
        lev, k = self.level2(k)
        key = (k, ksize)
        if key not in cache:
            pad = ksize
            img = cv2.copyMakeBorder(lev, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=0)
            if ksize > 1:
                img = cv2.boxFilter(img, -1, (ksize, ksize), normalize=True, borderType=cv2.BORDER_CONSTANT)
            cache[key] = (img, pad - ((ksize - 1) / 2 - ksize // 2))
        img, shift = cache[key]
        return img, k, shift

    def level2(self, k: int) -> tuple[np.ndarray, int]:
        """``level(k)`` as a 2-channel float32 image (colour, 1): sampled with a zero border it
        gives premultiplied colour and coverage."""
        lev, k = self.level(k)
        while len(self._pyramid2) <= k:
            self._pyramid2.append(None)
        if self._pyramid2[k] is None:
            self._pyramid2[k] = np.dstack([lev, np.ones_like(lev)])
        return self._pyramid2[k], k


MARKER_SUPERSAMPLE = 1


def marker_plane(dictionary: str, marker_id: int, side_mm: float, T_world_from_marker,
                 quiet_zone_modules: float = 1.0, px_per_module: int = 32) -> Plane:
    """A printed marker: the black square of side ``side_mm`` centred on the marker frame origin
    (x right, y down, z into the wall, as ``cv2.aruco``'s object points), with a white quiet zone.

    ``T_world_from_marker`` (4, 4) places the marker centre. The plane's own frame starts at the
    top-left of the quiet zone.
    """
    d = aruco_dictionary(dictionary)
    modules = d.markerSize + 2
    side_px = modules * px_per_module
    img = cv2.aruco.generateImageMarker(d, int(marker_id), side_px, borderBits=1)
    q = int(round(quiet_zone_modules * px_per_module))
    tex = cv2.copyMakeBorder(img, q, q, q, q, cv2.BORDER_CONSTANT, value=255)
    mm_per_px = side_mm / side_px
    total = tex.shape[0] * mm_per_px
    shift = np.eye(4)
    shift[:2, 3] = -total / 2
    return Plane(np.asarray(T_world_from_marker, float) @ shift, (total, total), tex, f"marker {marker_id}",
                 supersample=MARKER_SUPERSAMPLE, box_prefilter=MARKER_SUPERSAMPLE == 1)


