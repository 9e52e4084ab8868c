"""A small OpenCV renderer: textured planes (``sim.planes``) seen through a pinhole camera with
lens distortion (``sim.camera``). Sensor noise is in ``sim.noise``, textures in ``sim.textures``.

Two paths, both exact in geometry:

- Shell planes (a room's walls, floor and ceiling: ``Plane.shell``) are drawn with
  ``cv2.warpPerspective`` into an undistorted pinhole canvas, which one ``cv2.remap`` then
  distorts into the image. Seen from inside a convex room they never hide each other and lie
  behind everything else, so they need no depth test.
- Every other plane (markers, boards, cards) is drawn per pixel: for a camera ray
  ``r = (x, y, 1)`` (undistorted normalised coordinates of a pixel centre, computed once per
  camera with ``cv2.undistortPoints`` iterated to 1e-10) the plane point it meets is a
  homography of ``r``: ``[u, v, 1] ~ M^-1 r`` with ``M = [R0 R1 t]`` the plane's first two axes
  and origin in the camera frame; ``cv2.perspectiveTransform`` gives texel coordinates and one
  ``cv2.remap`` samples the texture. Occlusion: a depth buffer along the rays.

Anti-aliasing: textures are minified through a Gaussian pyramid level matched to their
footprint; markers are area-sampled (the level box-filtered over one pixel's footprint, or
``supersample`` x ``supersample`` samples per pixel), so that detected corners are unbiased; plane
borders carry fractional coverage. One-sided planes facing away are culled.
"""

from __future__ import annotations

import cv2
import numpy as np

from estimator.frames import invert

from .camera import Camera


def render(camera: Camera, T_world_from_cam, planes, background: float = 110.0) -> np.ndarray:
    """Render planes (nearest wins) into a float32 (H, W) grey image, values 0-255.

    Args:
        camera: intrinsics and distortion.
        T_world_from_cam: (4, 4) camera pose.
        planes: iterable of ``Plane``.
        background: grey level where no plane is seen.
    """
    w, h = camera.image_size
    T_cam_from_world = invert(T_world_from_cam)
    planes = list(planes)
    shell = [p for p in planes if p.shell]
    if shell:
        img = _render_shell(camera, T_cam_from_world, shell, background)
    else:
        img = np.full((h, w), background, np.float32)
    exact = [p for p in planes if not p.shell]
    if not exact:
        return img
    Ts = np.einsum("ij,pjk->pik", T_cam_from_world, np.stack([p.T_world_from_plane for p in exact]))
    boxes = _bboxes(camera, Ts, np.array([p.size_mm for p in exact], float))
    seen = [b for b in boxes if b is not None]
    if not seen:
        return img
    # depth buffer over the union of the boxes only, origin (dx, dy)
    dx, dy = min(b[0] for b in seen), min(b[1] for b in seen)
    depth = np.full((max(b[3] for b in seen) - dy, max(b[2] for b in seen) - dx), np.inf, np.float32)
    for plane, T_cam_from_plane, bbox in zip(exact, Ts, boxes, strict=True):
        if bbox is None:
            continue
        z_axis, origin = T_cam_from_plane[:3, 2], T_cam_from_plane[:3, 3]
        if abs(z_axis @ origin) < 1e-9:            # det [x y t] = z . t: seen edge-on
            continue
        x0, y0, x1, y1 = bbox
        premult, coverage, ray_depth = _draw_exact(camera, plane, T_cam_from_plane, bbox)
        sub_d = depth[y0 - dy:y1 - dy, x0 - dx:x1 - dx]
        sub_i = img[y0:y1, x0:x1]
        nearer = ray_depth < sub_d
        np.copyto(sub_i, premult + (1 - coverage) * sub_i, where=nearer & (coverage > 0))
        np.copyto(sub_d, ray_depth, where=nearer & (coverage >= 0.5))
    return img


def _draw_exact(camera: Camera, plane, T_cam_from_plane, bbox):
    """One non-shell plane drawn per pixel over its bounding box ``(x0, y0, x1, y1)``: the
    premultiplied grey (h, w), its coverage 0-1 (h, w) and each pixel's depth along z (h, w), mm
    (inf where the plane is behind the camera), all float32."""
    M = T_cam_from_plane[:3, [0, 1, 3]]
    x0, y0, x1, y1 = bbox
    ss = max(int(plane.supersample), 1)
    rays = camera.sample_rays(ss)[y0 * ss:y1 * ss, x0 * ss:x1 * ss]
    Mi = _inv3(M)                           # ray (x, y, 1) -> plane (u, v, 1) mm, homogeneous
    tex_h, tex_w = plane.texture.shape[:2]
    su, sv = tex_w / plane.size_mm[0], tex_h / plane.size_mm[1]
    # level-0 continuous texel coordinates (0 .. W across the rectangle)
    P = Mi * np.array([[su], [sv], [1.0]])
    texels = cv2.perspectiveTransform(rays, P)
    inv_depth = cv2.transform(rays, Mi[2:3])       # Mi[2] . (x, y, 1): 1 / depth
    out = _sample_texture(plane, rays, texels, ss)
    if inv_depth.min() <= 0:
        behind = inv_depth <= 0
        out[behind] = 0
        inv_depth[behind] = 1e-30
    ray_depth = np.float32(1.0) / inv_depth        # ray parameter: depth along z, mm
    if ss > 1:                   # box filter: mean of the ss x ss samples of each pixel
        size = (x1 - x0, y1 - y0)
        out = cv2.resize(out, size, interpolation=cv2.INTER_AREA)
        ray_depth = cv2.resize(ray_depth, size, interpolation=cv2.INTER_AREA)
    return out[..., 0], out[..., 1], ray_depth


def _sample_texture(plane, rays, texels, ss: int) -> np.ndarray:
    """The plane's (premultiplied grey, coverage) float32 (h, w, 2) sampled at level-0 continuous
    texel coordinates ``texels`` (h, w, 2), from the pyramid level matched to the footprint."""
    if plane.box_prefilter and ss == 1:
        # area sampling without supersampling: a level with 3-6 texels per pixel, box-filtered
        # over one pixel's footprint, then sampled bilinearly at the pixel centre
        scale = _footprint(texels, rays.shape[0] // 2, rays.shape[1] // 2)
        k = 0 if not np.isfinite(scale) or scale < 6 else int(np.floor(np.log2(scale / 3)))
        box = max(1, int(round(scale / 2.0**k))) if np.isfinite(scale) else 1
        lev, k, shift = plane.boxed(k, box)
    else:
        # footprint: texels per sample at the box centre -> pyramid level
        center_row, center_col = rays.shape[0] // 2, rays.shape[1] // 2
        k = _pyramid_level(texels, center_row, center_col, plane.max_texel_step * ss)
        lev, k = plane.level2(k)
        shift = 0.0
    f = 2.0**k                  # exact: pyrDown rounds odd sizes up, so tex_w / width is not
    # cv2.pyrDown centres level-k pixel i on level-0 pixel 2^k i, so the index coordinate
    # of continuous texel coordinate p is (p - 0.5) / 2^k
    if k or shift:
        mp = (texels - np.float32(0.5)) * np.float32(1 / f) + np.float32(shift)
    else:
        mp = texels - np.float32(0.5)
    # (colour, 1) sampled with a zero border: premultiplied colour and a coverage ramp one
    # (level) texel wide centred on the rectangle's border
    return cv2.remap(lev, mp, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def _render_shell(camera: Camera, T_cam_from_world, planes, background: float) -> np.ndarray:
    """Shell planes drawn into the undistorted canvas (warpPerspective of the pyramid level
    matched to the footprint, masked by the near-clipped polygon), then distorted into the
    image by one remap. Shell edges are not anti-aliased beyond what that remap's bilinear
    interpolation gives: they are room seams, not measured features."""
    Kc, (cw, ch), mx, my = camera.canvas
    canvas = np.full((ch, cw), background, np.float32)
    Kc_inv = np.linalg.inv(Kc)
    for plane in planes:
        T = T_cam_from_world @ plane.T_world_from_plane
        M = np.column_stack([T[:3, 0], T[:3, 1], T[:3, 3]])
        if abs(np.linalg.det(M)) < 1e-9:
            continue
        pts_cam = _corners_plane(plane.size_mm) @ T[:3, :3].T + T[:3, 3]
        poly = _clip_near(pts_cam)
        if len(poly) < 3:
            continue
        pix = (Kc @ (poly / poly[:, 2:3]).T).T[:, :2]
        x0, y0 = np.maximum(np.floor(pix.min(axis=0)).astype(int) - 1, 0)
        x1, y1 = np.minimum(np.ceil(pix.max(axis=0)).astype(int) + 2, (cw, ch))
        if x1 <= x0 or y1 <= y0:
            continue
        bw, bh = x1 - x0, y1 - y0
        # pixels to draw: the clipped polygon (only needed when the plane reaches behind the
        # camera; otherwise the texture's own extent masks it, BORDER_TRANSPARENT)
        clipped = len(poly) != 4 or np.any(np.abs(poly - pts_cam) > 1e-9)
        if clipped:
            inside = np.zeros((bh, bw), np.uint8)
            pts = np.rint((pix - (x0, y0)) * 16).astype(np.int64).clip(-2**27, 2**27).astype(np.int32)
            cv2.fillConvexPoly(inside, pts, 255, cv2.LINE_8, shift=4)
        tex_h, tex_w = plane.texture.shape[:2]
        su, sv = tex_w / plane.size_mm[0], tex_h / plane.size_mm[1]
        # canvas pixel -> plane mm (homogeneous)
        G = _inv3(M) @ Kc_inv
        k = _footprint_level(G, su, sv, (x0 + x1) / 2, (y0 + y1) / 2)
        lev, k = plane.level(k)
        f = 2.0**k
        A = np.array([[su / f, 0, -0.5 / f], [0, sv / f, -0.5 / f], [0, 0, 1.0]]) @ G
        # warp in horizontal strips, each only as wide as the polygon there: a wall seen
        # obliquely covers a fraction of its bounding box
        step = max(64, -(-bh // 6))
        for ys in range(y0, y1, step):
            ye = min(ys + step, y1)
            xs, xe = _strip_extent(pix, ys - 1, ye + 1, x0, x1)
            if xe <= xs:
                continue
            shift = np.array([[1, 0, xs], [0, 1, ys], [0, 0, 1.0]])
            sub = canvas[ys:ye, xs:xe]
            if clipped:
                color = cv2.warpPerspective(lev, A @ shift, (xe - xs, ye - ys),
                                             flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                             borderMode=cv2.BORDER_REPLICATE)
                cv2.copyTo(color, inside[ys - y0:ye - y0, xs - x0:xe - x0], sub)
            else:
                cv2.warpPerspective(lev, A @ shift, (xe - xs, ye - ys), dst=sub,
                                    flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                    borderMode=cv2.BORDER_TRANSPARENT)
    return cv2.remap(canvas, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _strip_extent(pix: np.ndarray, ya: float, yb: float, x0: int, x1: int) -> tuple[int, int]:
    """Integer x range [xs, xe) of a convex polygon (N, 2) within the band ya <= y <= yb,
    clamped to [x0, x1)."""
    xs_in = []
    n = len(pix)
    for i in range(n):
        a, b = pix[i], pix[(i + 1) % n]
        if ya <= a[1] <= yb:
            xs_in.append(a[0])
        for yl in (ya, yb):
            if (a[1] - yl) * (b[1] - yl) < 0:
                t = (yl - a[1]) / (b[1] - a[1])
                xs_in.append(a[0] + t * (b[0] - a[0]))
    if not xs_in:
        return 0, 0
    return max(int(np.floor(min(xs_in))) - 1, x0), min(int(np.ceil(max(xs_in))) + 2, x1)


def _corners_plane(size_mm) -> np.ndarray:
    w, h = size_mm
    return np.array([[0, 0, 0], [w, 0, 0], [w, h, 0], [0, h, 0.0]])


def _clip_near(poly: np.ndarray, near: float = 10.0) -> np.ndarray:
    """Clip a convex polygon (N, 3), camera frame, mm, to z >= near (Sutherland-Hodgman)."""
    out = []
    n = len(poly)
    for i in range(n):
        a, b = poly[i], poly[(i + 1) % n]
        ina, inb = a[2] >= near, b[2] >= near
        if ina:
            out.append(a)
        if ina != inb:
            t = (near - a[2]) / (b[2] - a[2])
            out.append(a + t * (b - a))
    return np.array(out).reshape(-1, 3)


def _footprint_level(G, su, sv, px, py) -> int:
    """Pyramid level for the texel footprint of one canvas pixel at (px, py) of the box."""
    def texel(x, y):
        q = G @ np.array([x, y, 1.0])
        return np.array([q[0] * su, q[1] * sv]) / q[2]
    c = texel(px, py)
    scale = max(np.linalg.norm(texel(px + 1, py) - c), np.linalg.norm(texel(px, py + 1) - c))
    if not np.isfinite(scale) or scale <= 1.5:
        return 0
    return int(np.floor(np.log2(scale / 1.5))) + 1


def _inv3(M) -> np.ndarray:
    """Inverse of a (3, 3) matrix by cofactors (the rows of M^-1 are cross products of M's
    columns over det M): an order of magnitude cheaper than ``np.linalg.inv`` for one 3x3."""
    (a0, b0, c0), (a1, b1, c1), (a2, b2, c2) = M.tolist()
    r0 = (b1 * c2 - b2 * c1, b2 * c0 - b0 * c2, b0 * c1 - b1 * c0)
    r1 = (c1 * a2 - c2 * a1, c2 * a0 - c0 * a2, c0 * a1 - c1 * a0)
    r2 = (a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0)
    det = a0 * r0[0] + a1 * r0[1] + a2 * r0[2]
    return np.array([r0, r1, r2]) / det


def _footprint(pp, cy, cx) -> float:
    """Texels per sample at (cy, cx) of texel coordinates ``pp`` (H, W, 2)."""
    try:
        return max(np.hypot(*(pp[cy, cx + 1] - pp[cy, cx])), np.hypot(*(pp[cy + 1, cx] - pp[cy, cx])))
    except IndexError:
        return float("nan")


def _pyramid_level(pp, cy, cx, max_step: float = 1.5) -> int:
    """Pyramid level for the texel footprint of one sample at (cy, cx) of texel coordinates
    ``pp`` (H, W, 2): the coarsest level whose sample step is at most ``max_step`` texels."""
    try:
        du = np.hypot(*(pp[cy, cx + 1] - pp[cy, cx]))
        dv = np.hypot(*(pp[cy + 1, cx] - pp[cy, cx]))
    except IndexError:
        return 0
    scale = max(du, dv)
    if not np.isfinite(scale) or scale <= max_step:
        return 0
    return int(np.floor(np.log2(scale / max_step))) + 1


def _bbox(camera: Camera, T_cam_from_plane, size_mm):
    """Pixel bounding box (x0, y0, x1, y1) of a plane, padded, or None when it is not in view.

    The rectangle is clipped to the near plane and to the field where the distortion model is
    trusted (``Camera.field_limits``); the clipped outline, sampled densely because a distorted
    straight edge bulges, is projected."""
    w, h = camera.image_size
    pts = _corners_plane(size_mm) @ T_cam_from_plane[:3, :3].T + T_cam_from_plane[:3, 3]
    lim = np.array(camera.field_limits)
    if np.all(pts[:, 2] > 1.0):
        n = pts[:, :2] / pts[:, 2:3]
        if np.any(np.all(n > lim, axis=0)) or np.any(np.all(n < -lim, axis=0)):
            return None                                # wholly beyond one side of the field
        inside = np.all(np.abs(n) <= lim)
    else:
        inside = False
    if not inside:
        poly = _clip_near(pts, 1.0)
        if len(poly) < 3:
            return None
        n = poly[:, :2] / poly[:, 2:3]
        for axis in (0, 1):
            for sign in (1.0, -1.0):
                n = _clip_half_plane(n, axis, sign, lim[axis])
                if len(n) < 3:
                    return None
    t = _EDGE_T
    edge = (n[:, None, :] + t[None, :, None] * (np.roll(n, -1, axis=0) - n)[:, None, :]).reshape(-1, 2)
    px = camera.project(np.column_stack([edge, np.ones(len(edge))]))
    x0 = int(np.floor(px[:, 0].min())) - 2
    y0 = int(np.floor(px[:, 1].min())) - 2
    x1 = int(np.ceil(px[:, 0].max())) + 3
    y1 = int(np.ceil(px[:, 1].max())) + 3
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if x1 <= x0 or y1 <= y0:
        return None
    return x0, y0, x1, y1


def _bboxes(camera: Camera, Ts: np.ndarray, sizes: np.ndarray) -> list:
    """``_bbox`` of many planes (P, 4, 4) camera-from-plane, sizes (P, 2): culling and the
    common case (wholly in front and inside the trusted field) in one batch, the rest one by
    one."""
    P = len(Ts)
    w, h = camera.image_size
    half = np.column_stack([sizes / 2, np.zeros(P)])
    c = np.einsum("pij,pj->pi", Ts[:, :3, :3], half) + Ts[:, :3, 3]
    r = 0.5 * np.hypot(sizes[:, 0], sizes[:, 1])
    zf = c[:, 2] + r
    lim = np.array(camera.field_limits)
    # one-sided: a plane's seen side is the one its z axis points away from (printed markers,
    # cards and boards); facing away, it is culled
    facing = np.einsum("pi,pi->p", c, Ts[:, :3, 2]) > 0
    keep = facing & (zf > 0)
    keep &= (np.abs(c[:, 0]) - r <= lim[0] * zf) & (np.abs(c[:, 1]) - r <= lim[1] * zf)
    corners = np.zeros((P, 4, 3))
    corners[:, 1, 0] = corners[:, 2, 0] = sizes[:, 0]
    corners[:, 2, 1] = corners[:, 3, 1] = sizes[:, 1]
    pts = np.einsum("pij,pkj->pki", Ts[:, :3, :3], corners) + Ts[:, None, :3, 3]
    front = np.all(pts[..., 2] > 1.0, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        n = pts[..., :2] / pts[..., 2:3]
    simple = keep & front & np.all(np.abs(n) <= lim, axis=(1, 2))
    out = [None] * P
    idx = np.flatnonzero(simple)
    if len(idx):
        nn = n[idx]
        t = _EDGE_T[None, None, :, None]
        edge = (nn[:, :, None, :] + t * (np.roll(nn, -1, axis=1) - nn)[:, :, None, :]).reshape(len(idx), -1, 2)
        px = camera.distort(edge.reshape(-1, 2)).reshape(len(idx), -1, 2)
        lo = np.floor(px.min(axis=1)).astype(int) - 2
        hi = np.ceil(px.max(axis=1)).astype(int) + 3
        for j, i in enumerate(idx):
            x0, y0 = max(lo[j, 0], 0), max(lo[j, 1], 0)
            x1, y1 = min(hi[j, 0], w), min(hi[j, 1], h)
            if x1 > x0 and y1 > y0:
                out[i] = (x0, y0, x1, y1)
    for i in np.flatnonzero(keep & ~simple):
        out[i] = _bbox(camera, Ts[i], sizes[i])
    return out


_EDGE_T = np.linspace(0, 1, 9)[:-1]


def _clip_half_plane(poly: np.ndarray, axis: int, sign: float, lim: float) -> np.ndarray:
    """Clip a convex polygon (N, 2) to sign * p[axis] <= lim."""
    out = []
    n = len(poly)
    for i in range(n):
        a, b = poly[i], poly[(i + 1) % n]
        ina, inb = sign * a[axis] <= lim, sign * b[axis] <= lim
        if ina:
            out.append(a)
        if ina != inb:
            t = (lim - sign * a[axis]) / (sign * (b[axis] - a[axis]))
            out.append(a + t * (b - a))
    return np.array(out).reshape(-1, 2)
