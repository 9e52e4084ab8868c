"""The simulator's scene camera: a pinhole with OpenCV distortion, the undistorted ray of every
pixel (and of sub-pixel samples), and the undistorted canvas that the renderer draws shell planes
into (``sim.render``). Camera frame: OpenCV axes (x right, y down, z forward), mm.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from calibration.cvcompat import undistort_points

CANVAS_AREA = 0.25


@dataclass(frozen=True, eq=False)
class Camera:
    """A pinhole camera with OpenCV distortion.

    Attributes:
        camera_matrix: (3, 3) K, pixels.
        dist_coeffs: (k,) OpenCV distortion coefficients (k1, k2, p1, p2[, k3, ...]).
        image_size: (width, height) in pixels.
    """

    camera_matrix: np.ndarray
    dist_coeffs: np.ndarray
    image_size: tuple[int, int]

    @classmethod
    def wide_scene_camera(cls, width: int = 1280, height: int = 720, hfov_deg: float = 90.0,
                          dist=(-0.28, 0.09, 0.0, 0.0, -0.012)) -> Camera:
        """The default scene camera: wide (90 deg horizontal), barrel distortion, 1280x720."""
        f = 0.5 * width / np.tan(np.deg2rad(hfov_deg) / 2)
        K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1.0]])
        return cls(K, np.asarray(dist, float), (int(width), int(height)))

    def project(self, pts_cam_mm) -> np.ndarray:
        """Pixel coordinates (N, 2) of camera-frame points (N, 3), with distortion."""
        p = np.asarray(pts_cam_mm, np.float64).reshape(-1, 1, 3)
        px, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), self.camera_matrix, self.dist_coeffs)
        return px.reshape(-1, 2)

    def distort(self, xy) -> np.ndarray:
        """Pixels (N, 2) of undistorted normalised coordinates (N, 2) (OpenCV's model)."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        d = self.dist_coeffs
        if len(d) > 5 or len(d) < 4:
            return self.project(np.column_stack([xy, np.ones(len(xy))]))
        k1, k2, p1, p2 = d[:4]
        k3 = d[4] if len(d) > 4 else 0.0
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        rad = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        K = self.camera_matrix
        return np.column_stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]])

    @functools.cached_property
    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Undistorted normalised coordinates (x, y), each (H, W) float64, of every pixel centre."""
        w, h = self.image_size
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        pts = np.stack([u.ravel(), v.ravel()], -1).reshape(-1, 1, 2)
        und = undistort_points(pts, self.camera_matrix, self.dist_coeffs, 40, 1e-10).reshape(h, w, 2)
        return und[..., 0].copy(), und[..., 1].copy()

    @functools.cached_property
    def field_limits(self) -> tuple[float, float]:
        """Largest |x| and |y| of the normalised rays at the image border, times 1.2: beyond
        them the distortion model is not trusted to be monotonic."""
        xs, ys = self.rays
        return (max(abs(xs[:, 0]).max(), abs(xs[:, -1]).max()) * 1.2,
                max(abs(ys[0]).max(), abs(ys[-1]).max()) * 1.2)

    @functools.cached_property
    def canvas(self) -> tuple[np.ndarray, tuple[int, int], np.ndarray, np.ndarray]:
        """The undistorted pinhole canvas that shell planes are drawn into: its (3, 3) matrix
        ``K_c``, its size (w, h), and the float32 (H, W) maps from image pixels to canvas pixels.
        Its focal length is scaled so that it covers the whole distorted field with
        ``CANVAS_AREA`` times the image's pixel count: walls and floors are textures whose
        detail need not be sharper than that, and the warp's cost is proportional to it."""
        xs, ys = self.rays
        w, h = self.image_size
        x0, x1, y0, y1 = xs.min(), xs.max(), ys.min(), ys.max()
        f = self.camera_matrix[0, 0]
        fc = min(f, np.sqrt(CANVAS_AREA * w * h / ((x1 - x0) * (y1 - y0))))
        Kc = np.array([[fc, 0, -x0 * fc + 1.0], [0, fc, -y0 * fc + 1.0], [0, 0, 1.0]])
        size = (int(np.ceil((x1 - x0) * fc)) + 3, int(np.ceil((y1 - y0) * fc)) + 3)
        mx = (fc * xs + Kc[0, 2]).astype(np.float32)
        my = (fc * ys + Kc[1, 2]).astype(np.float32)
        return Kc, size, mx, my

    @functools.cached_property
    def rays2(self) -> np.ndarray:
        """``rays`` as one float32 (H, W, 2) array."""
        xs, ys = self.rays
        return np.dstack([xs, ys]).astype(np.float32)

    def sample_rays(self, ss: int) -> np.ndarray:
        """(H ss, W ss, 2) float32 rays at ``ss`` x ``ss`` sample positions per pixel (pixel
        centre + ((i + 0.5) / ss - 0.5)), interpolated from the smooth per-pixel map; cached."""
        if ss == 1:
            return self.rays2
        cache = self.__dict__.setdefault("_sample_rays", {})
        if ss not in cache:
            w, h = self.image_size
            off = (np.arange(ss) + 0.5) / ss - 0.5
            gx = (np.arange(w)[:, None] + off[None]).ravel().astype(np.float32)
            gy = (np.arange(h)[:, None] + off[None]).ravel().astype(np.float32)
            mx, my = np.meshgrid(gx, gy)
            cache[ss] = cv2.remap(self.rays2, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return cache[ss]
