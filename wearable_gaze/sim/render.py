"""A small OpenCV renderer: textured planes seen through a pinhole camera with lens distortion.

Each plane is a rectangle ``size_mm`` in its own frame (x right, y down along the texture, z its
normal), placed by ``T_world_from_plane``. Texture pixel centre ``(i + 0.5, j + 0.5)`` sits at
``((i + 0.5) w / W, (j + 0.5) h / H)`` mm in the plane frame.

For a camera ray ``r = (x, y, 1)`` (undistorted normalised coordinates, camera frame), the plane
point it meets is a homography of ``r``: ``[u, v, 1] ~ M^-1 r`` with ``M = [R0 R1 t]`` the first
two axes and origin of the plane in the camera frame. The rays of every (distorted) image pixel
are computed once per camera with ``cv2.undistortPoints`` (iterated to 1e-10); a plane then costs a few array
operations over its bounding box and one ``cv2.remap``. Anti-aliasing: textures are minified
through a Gaussian pyramid level matched to their footprint, sampled bilinearly, and plane
borders carry fractional coverage. Occlusion: per-pixel depth along the ray.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import cv2
import numpy as np

from estimator.frames import invert


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
                          dist=(-0.28, 0.09, 0.0, 0.0, -0.012)) -> "Camera":
        """The default scene camera: wide (90 deg horizontal), barrel distortion, 1280x720."""
        f = 0.5 * width / np.tan(np.deg2rad(hfov_deg) / 2)
        K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1.0]])
        return cls(K, np.asarray(dist, float), (int(width), int(height)))

    def project(self, pts_cam_mm) -> np.ndarray:
        """Pixel coordinates (N, 2) of camera-frame points (N, 3), with distortion."""
        p = np.asarray(pts_cam_mm, np.float64).reshape(-1, 1, 3)
        px, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), self.camera_matrix, self.dist_coeffs)
        return px.reshape(-1, 2)

    @functools.cached_property
    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Undistorted normalised coordinates (x, y), each (H, W) float64, of every pixel centre."""
        w, h = self.image_size
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        pts = np.stack([u.ravel(), v.ravel()], -1).reshape(-1, 1, 2)
        und = cv2.undistortPoints(pts, self.camera_matrix, self.dist_coeffs,
                                  criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10))
        und = und.reshape(h, w, 2)
        return und[..., 0].copy(), und[..., 1].copy()

    @functools.cached_property
    def field_limits(self) -> tuple[float, float]:
        """Largest |x| and |y| of the normalised rays at the image border, times 1.2: beyond
        them the distortion model is not trusted to be monotonic."""
        xs, ys = self.rays
        return (max(abs(xs[:, 0]).max(), abs(xs[:, -1]).max()) * 1.2,
                max(abs(ys[0]).max(), abs(ys[-1]).max()) * 1.2)

    @functools.cached_property
    def rays32(self) -> tuple[np.ndarray, np.ndarray]:
        """``rays`` as float32 (for ``cv2.remap`` at sub-pixel positions)."""
        return tuple(r.astype(np.float32) for r in self.rays)


@dataclass(frozen=True, eq=False)
class Plane:
    """A textured rectangle in the world.

    Attributes:
        T_world_from_plane: (4, 4) pose of the plane frame (x, y in the plane, z its normal), mm.
        size_mm: (width, height) of the rectangle, mm.
        texture: (H, W) uint8 grey texture covering the whole rectangle.
        name: a label.
        supersample: samples per pixel along each axis (area sampling: each pixel is the mean of
            ``supersample^2`` samples). Markers use 3: gradient-based corner refinement is
            biased toward the inside of a blurred L-corner, so their edges must be as sharp as
            a real pixel's box integration makes them.
    """

    T_world_from_plane: np.ndarray
    size_mm: tuple[float, float]
    texture: np.ndarray
    name: str = ""
    supersample: int = 1
    _pyramid: list = field(default_factory=list, repr=False)

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


def render(camera: Camera, T_world_from_cam, planes, background: float = 110.0) -> np.ndarray:
    """Render planes (nearest wins) into a float32 (H, W) grey image, values 0-255.

    Args:
        camera: intrinsics and distortion.
        T_world_from_cam: (4, 4) camera pose.
        planes: iterable of ``Plane``.
        background: grey level where no plane is seen.
    """
    w, h = camera.image_size
    xs, ys = camera.rays
    img = np.full((h, w), background, np.float32)
    depth = np.full((h, w), np.inf, np.float32)
    T_cam_from_world = invert(T_world_from_cam)
    for plane in planes:
        T = T_cam_from_world @ plane.T_world_from_plane
        M = np.column_stack([T[:3, 0], T[:3, 1], T[:3, 3]])
        if abs(np.linalg.det(M)) < 1e-9:
            continue                                   # seen edge-on
        bbox = _bbox(camera, T, plane.size_mm)
        if bbox is None:
            continue
        x0, y0, x1, y1 = bbox
        ss = max(int(plane.supersample), 1)
        if ss == 1:
            x = xs[y0:y1, x0:x1]
            y = ys[y0:y1, x0:x1]
        else:
            # rays at the sub-pixel sample positions, interpolated from the smooth per-pixel map
            off = (np.arange(ss) + 0.5) / ss - 0.5
            gx = (np.arange(x0, x1)[:, None] + off[None]).ravel().astype(np.float32)
            gy = (np.arange(y0, y1)[:, None] + off[None]).ravel().astype(np.float32)
            mx, my = np.meshgrid(gx, gy)
            xs32, ys32 = camera.rays32
            x = cv2.remap(xs32, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
            y = cv2.remap(ys32, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
        Mi = np.linalg.inv(M)
        den = Mi[2, 0] * x + Mi[2, 1] * y + Mi[2, 2]  # 1 / (ray parameter s), r = (x, y, 1)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = 1.0 / den
            u_mm = (Mi[0, 0] * x + Mi[0, 1] * y + Mi[0, 2]) * s
            v_mm = (Mi[1, 0] * x + Mi[1, 1] * y + Mi[1, 2]) * s
        tex_h, tex_w = plane.texture.shape[:2]
        su, sv = tex_w / plane.size_mm[0], tex_h / plane.size_mm[1]
        # footprint: texels per sample at the box centre -> pyramid level
        cy, cx = x.shape[0] // 2, x.shape[1] // 2
        k = _pyramid_level(u_mm, v_mm, cy, cx, su, sv)
        lev, k = plane.level(k)
        f = 2.0**k                  # exact: pyrDown rounds odd sizes up, so tex_w / width is not
        # level-0 continuous texel coordinates (0 .. W across the rectangle); cv2.pyrDown centres
        # level-k pixel i on level-0 pixel 2^k i, so its index coordinate is (p - 0.5) / 2^k
        pu = u_mm * su
        pv = v_mm * sv
        mu = ((pu - 0.5) / f).astype(np.float32)
        mv = ((pv - 0.5) / f).astype(np.float32)
        front = (s > 0) & np.isfinite(s)
        colour = cv2.remap(lev, mu, mv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        # coverage: 1 inside the rectangle, a ramp one (level) texel wide centred on its border
        cov = (np.clip(np.minimum(pu, tex_w - pu) / f + 0.5, 0, 1)
               * np.clip(np.minimum(pv, tex_h - pv) / f + 0.5, 0, 1))
        cov = np.where(front, cov, 0.0).astype(np.float32)
        s = np.where(front, s, np.inf)
        premult = cov * colour
        if ss > 1:
            bh, bw = y1 - y0, x1 - x0
            cov = cov.reshape(bh, ss, bw, ss).mean(axis=(1, 3))
            premult = premult.reshape(bh, ss, bw, ss).mean(axis=(1, 3))
            s = s.reshape(bh, ss, bw, ss).min(axis=(1, 3))
        sub_d = depth[y0:y1, x0:x1]
        take = (cov > 0) & (s < sub_d)
        sub_i = img[y0:y1, x0:x1]
        sub_i[take] = (premult + (1 - cov) * sub_i)[take]
        solid = take & (cov >= 0.5)
        sub_d[solid] = s[solid]
    return img


def _pyramid_level(u, v, cy, cx, su, sv) -> int:
    try:
        du = np.hypot((u[cy, cx + 1] - u[cy, cx]) * su, (v[cy, cx + 1] - v[cy, cx]) * sv)
        dv = np.hypot((u[cy + 1, cx] - u[cy, cx]) * su, (v[cy + 1, cx] - v[cy, cx]) * sv)
    except IndexError:
        return 0
    scale = max(du, dv)
    if not np.isfinite(scale) or scale <= 1.5:
        return 0
    return int(np.floor(np.log2(scale / 1.5))) + 1


def _bbox(camera: Camera, T_cam_from_plane, size_mm):
    """Pixel bounding box (x0, y0, x1, y1) of a plane, padded; the whole image when a corner is
    behind the camera or projects wildly (distortion models fold far outside the image)."""
    w, h = camera.image_size
    W, H = size_mm
    # sample the border densely: a distorted straight edge bulges
    t = np.linspace(0, 1, 9)
    edge = np.concatenate([np.column_stack([t * W, 0 * t]), np.column_stack([W + 0 * t, t * H]),
                           np.column_stack([t * W, H + 0 * t]), np.column_stack([0 * t, t * H])])
    pts = (T_cam_from_plane @ np.column_stack([edge, np.zeros(len(edge)), np.ones(len(edge))]).T).T[:, :3]
    if np.all(pts[:, 2] <= 0):
        return None
    if np.any(pts[:, 2] <= 1e-6):
        return 0, 0, w, h
    n = pts[:, :2] / pts[:, 2:3]
    # beyond the field where the distortion model is monotonic, fall back to the whole image
    lim_x, lim_y = camera.field_limits
    if np.any(np.abs(n[:, 0]) > lim_x) or np.any(np.abs(n[:, 1]) > lim_y):
        inside = (np.abs(n[:, 0]) <= lim_x) & (np.abs(n[:, 1]) <= lim_y)
        if not inside.any():
            return _whole_if_crossing(n, lim_x, lim_y, w, h)
        return 0, 0, w, h
    px = camera.project(pts)
    x0 = int(np.floor(px[:, 0].min())) - 2
    y0 = int(np.floor(px[:, 1].min())) - 2
    x1 = int(np.ceil(px[:, 0].max())) + 3
    y1 = int(np.ceil(px[:, 1].max())) + 3
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if x1 <= x0 or y1 <= y0:
        return None
    return x0, y0, x1, y1


def _whole_if_crossing(n, lim_x, lim_y, w, h):
    """All border samples outside the valid field: the plane may still cover the whole view."""
    if n[:, 0].min() < -lim_x and n[:, 0].max() > lim_x or n[:, 1].min() < -lim_y and n[:, 1].max() > lim_y:
        return 0, 0, w, h
    return None


def finish(img: np.ndarray, rng: np.random.Generator | None = None, noise_std: float = 2.0,
           gain: float = 1.0) -> np.ndarray:
    """Exposure (``gain``), Gaussian sensor noise (grey levels) and 8-bit quantisation."""
    out = img * gain
    if rng is not None and noise_std > 0:
        out = out + rng.normal(0.0, noise_std, size=out.shape).astype(np.float32)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


# --- textures ---------------------------------------------------------------------------------

ARUCO_DICTS = {name: getattr(cv2.aruco, name) for name in dir(cv2.aruco) if name.startswith("DICT_")}


def aruco_dictionary(name: str):
    """``cv2.aruco`` predefined dictionary by name (``DICT_4X4_50``, ``DICT_APRILTAG_36h11``...)."""
    if name not in ARUCO_DICTS:
        raise ValueError(f"unknown ArUco dictionary {name!r}: use one of cv2.aruco's DICT_* names")
    return cv2.aruco.getPredefinedDictionary(ARUCO_DICTS[name])


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
                 supersample=3)


def marker_corners_world(side_mm: float, T_world_from_marker) -> np.ndarray:
    """(4, 3) world corners of a marker's black square in ``cv2.aruco`` order: top-left,
    top-right, bottom-right, bottom-left."""
    s = side_mm / 2
    c = np.array([[-s, -s, 0, 1], [s, -s, 0, 1], [s, s, 0, 1], [-s, s, 0, 1.0]])
    return (np.asarray(T_world_from_marker, float) @ c.T).T[:, :3]
