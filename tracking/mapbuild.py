"""A marker map built from views of the markers (issue 16; docs/tracking.md, "Building a map"):
the markers' poses in a world fixed by one of them, from their detected corners in many images
(a survey video's frames, or photos), without measuring anything but the printed sizes.

Each view's markers are posed alone (IPPE for a square); views and markers are chained from the
origin marker outward (a view posed by the markers already placed, then its new markers placed
by it); then all view and marker poses are adjusted together (bundle adjustment on the corners'
reprojection, a robust Huber loss, Levenberg-Marquardt with the views eliminated:
``tracking.bundle``). The scale is the printed
markers' sides, so the map is in millimetres. Then per marker: its pose covariance, how many views
saw it, its reprojection RMS, and whether it moved during the survey (its views before and after
the middle fit poses farther apart than their uncertainty allows).

World frame: the origin marker's (x right along its top edge, y down, z into the wall, the
cv2.aruco marker frame), mm. Corners in cv2.aruco order.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from calibration.camera import undistort_points

from .bundle import bundle_adjust
from .markermap import MarkerMap, marker_corners_world, square_corners
from .pnp import transform_from_rvec_tvec

log = logging.getLogger(__name__)

MIN_VIEWS = 3
"""A marker seen in fewer views is kept but flagged: its pose rests on too little."""
MOVED_MM = 10.0
"""A marker whose views before and after the survey's middle fit positions farther apart than
this (mm), and than 5 sd of the difference, is flagged as moved."""
MAX_ITER = 100
"""The bundle adjustment's step budget (it warns when it runs out)."""
MAX_MOVED = 5
"""At most this many moved markers are split in two and adjusted again (each costs one more
adjustment); more are still flagged, by the last adjustment's test."""
HUBER_PX = 1.0
"""The bundle adjustment's robust loss turns from squares to absolute values past this, pixels."""


@dataclass
class MarkerInfo:
    """One marker of a built map.

    Attributes:
        n_views: views that saw it.
        rms_px: reprojection RMS of its corners after adjustment, pixels.
        covariance: (6, 6) of (rotation vector, rad; position, mm) of ``T_world_from_marker``,
            the pose beside it (zeros for the origin marker, which fixes the world).
        flags: why not to trust it: 'seen in N views', 'moved by N mm during the survey'.
    """

    n_views: int
    rms_px: float
    covariance: np.ndarray
    flags: list = field(default_factory=list)


@dataclass
class BuiltMap:
    """A map built from views: the ``MarkerMap``, per marker a ``MarkerInfo``, the posed views'
    ``T_world_from_cam`` (view index -> (4, 4)), the views no marker of the map could pose, and
    the overall reprojection RMS, pixels."""

    marker_map: MarkerMap
    info: dict
    cameras: dict
    unposed: list
    rms_px: float


def build_marker_map(views, K, dist, dictionary: str, sizes, origin: int | None = None,
                     model: str = "pinhole", prior: MarkerMap | None = None) -> BuiltMap:
    """The marker map of ``views``.

    Args:
        views: per image, {marker id: (4, 2) corners, px} (one detection per id: repeated ids
            left out by the caller).
        K, dist: the camera matrix (3, 3) and distortion coefficients of the images; ``model``
            their lens model ('pinhole' or 'fisheye').
        dictionary: the markers' ``cv2.aruco`` dictionary name (kept in the map).
        sizes: the printed side, mm: one number, or {id: side} with every id seen.
        origin: the marker whose frame is the world (default: the one seen in most views).
        prior: an earlier ``MarkerMap`` to extend or refine: its markers start where it put them,
            its world is kept (``origin``, by default the one of its markers seen most, stays
            where it was), new markers are added, and markers these views do not see are kept
            as they were, with their sizes (``n_views`` 0).

    Raises:
        ValueError: no marker seen, the origin never seen (or not in ``prior``), a seen id
            without a size.
    """
    obs = _normalised(views, K, dist, model)
    ids = sorted({i for v in obs for i in v})
    if not ids:
        raise ValueError("no marker was detected in any view")
    size = {i: float(sizes) for i in ids} if np.isscalar(sizes) else {i: float(sizes[i]) for i in ids if i in sizes}
    missing = [i for i in ids if i not in size]
    if missing:
        raise ValueError(f"no printed size for marker(s) {missing}: give one for every id seen")
    counts = {i: sum(i in v for v in obs) for i in ids}
    prior_map, prior = prior, {int(i): np.asarray(T, float) for i, T in (prior.poses if prior else {}).items()}
    choices = [i for i in ids if i in prior] if prior else ids
    if not choices:
        raise ValueError(f"none of the earlier map's markers is in a view (seen: {ids})")
    origin = max(choices, key=lambda i: (counts[i], -i)) if origin is None else int(origin)
    if origin not in counts or (prior and origin not in prior):
        raise ValueError(f"the origin marker {origin} is in no view (seen: {ids})" if origin not in counts else
                         f"the origin marker {origin} is not in the earlier map")
    start = {i: T for i, T in prior.items() if i in counts} if prior else {origin: np.eye(4)}
    markers, cams = _chain(obs, size, origin, start)
    _refine_initial(obs, size, origin, markers, cams)
    adj, moved = _adjust_moving(obs, size, origin, markers, cams, float(K[0, 0]), markers[origin])
    info = _marker_info(obs, size, origin, adj, moved)
    for i, T in prior.items():                       # not seen now: kept as the earlier map had it
        if i not in adj.markers:
            adj.markers[i] = T
            info[i] = MarkerInfo(0, float("nan"), np.zeros((6, 6)))
    unposed = [k for k in range(len(obs)) if k not in adj.cams]
    rms = float(np.sqrt(np.mean(adj.residuals ** 2))) if len(adj.residuals) else float("nan")
    log.info("map of %d markers from %d views (%d unposed), RMS %.2f px", len(adj.markers), len(adj.cams),
             len(unposed), rms)
    common = float(max(set(size.values()), key=list(size.values()).count))            # the commonest size
    sides = {**{i: prior_map.size_of(i) for i in prior}, **size} if prior else size
    mm = MarkerMap(dictionary, common, dict(adj.markers), {}, {i: v for i, v in sides.items() if v != common})
    return BuiltMap(mm, info, {k: np.linalg.inv(T) for k, T in adj.cams.items()}, unposed, rms)


def similarity_transform(A, B) -> np.ndarray:
    """The similarity (4, 4) (scale times rotation, translation) that best maps points ``A``
    (N, 3) onto ``B`` (N, 3) in least squares (Umeyama 1991): ``B ~ T[:3, :3] @ A + T[:3, 3]``;
    its scale is the cube root of the upper block's determinant."""
    A, B = np.asarray(A, float), np.asarray(B, float)
    ma, mb = A.mean(0), B.mean(0)
    Ac, Bc = A - ma, B - mb
    U, S, Vt = np.linalg.svd(Bc.T @ Ac / len(A))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    s = np.trace(np.diag(S) @ D) / (Ac ** 2).sum(1).mean()
    T = np.eye(4)
    T[:3, :3] = s * (U @ D @ Vt)
    T[:3, 3] = mb - T[:3, :3] @ ma
    return T


def similarity_errors(A, B) -> tuple[np.ndarray, float]:
    """How far points ``A`` (N, 3) (a built map's corners) lie from ``B`` (N, 3) (the same points
    measured, or true) after the best similarity transform of ``A`` onto ``B``
    (``similarity_transform``): per point the distance, mm, and the transform's scale (a print's
    scale differs from nominal by a few per cent)."""
    T = similarity_transform(A, B)
    A, B = np.asarray(A, float), np.asarray(B, float)
    return np.linalg.norm(A @ T[:3, :3].T + T[:3, 3] - B, axis=1), float(np.cbrt(np.linalg.det(T[:3, :3])))


def _normalised(views, K, dist, model: str = "pinhole") -> list:
    """Each view's corners as normalised image coordinates (undistorted to convergence,
    ``calibration.camera.undistort_points``: OpenCV's default 5 iterations left the simulated
    survey's map, k1 = -0.28, 2.6 mm off its true shape)."""
    out = []
    for v in views:
        out.append({int(i): undistort_points(np.asarray(c, np.float64).reshape(4, 2), K, dist, model)
                    for i, c in v.items()})
    return out


def _ippe(corners_norm, side: float) -> list:
    """IPPE's solutions for one marker seen alone: [(reprojection RMS in normalised units,
    T_cam_from_marker (4, 4)), ...], the best first (planar IPPE: our corners, y down, are not in
    IPPE_SQUARE's order)."""
    n, rvecs, tvecs, errs = cv2.solvePnPGeneric(square_corners(side), corners_norm, np.eye(3), None,
                                                flags=cv2.SOLVEPNP_IPPE)
    return sorted(((float(e), transform_from_rvec_tvec(rvecs[k], tvecs[k])) for k, e in
                   zip(range(n), np.ravel(errs), strict=True)), key=lambda c: c[0])


def _image(R, t, X) -> tuple[np.ndarray, np.ndarray]:
    """Points ``X`` (4, 3) or (n, 4, 3), world, in views ``R`` (n, 3, 3), ``t`` (n, 3) (their
    ``T_cam_from_world``): (n, 4, 2) normalised image coordinates and (n, 4) depths."""
    Xc = X @ np.swapaxes(R, 1, 2) + t[:, None]
    return Xc[..., :2] / Xc[..., 2:3], Xc[..., 2]


def _reproj(T_world_from_marker, side: float, cams: dict, seen: dict) -> float:
    """Sum of squared corner reprojection errors (normalised) of a marker placed at
    ``T_world_from_marker`` in the views ``seen`` {view: corners} posed by ``cams``."""
    T = np.array([cams[k] for k in seen])
    uv, z = _image(T[:, :3, :3], T[:, :3, 3], marker_corners_world(side, T_world_from_marker))
    return float(np.sum((uv - np.array(list(seen.values()))) ** 2)) if np.all(z > 0) else np.inf


def _refine_initial(obs: list, size: dict, origin: int, markers: dict, cams: dict, rounds: int = 2) -> None:
    """Before the adjustment, undo the chaining's worst guesses (in place): each marker is placed
    where one of its views' two IPPE solutions puts it that reprojects best in all its views,
    then each view is posed again from all its markers; ``rounds`` times. A small marker seen
    face-on has two IPPE solutions a few degrees apart, and the chain may have taken the wrong
    one, a local minimum the adjustment cannot leave."""
    for _ in range(rounds):
        for i in markers:
            if i == origin:
                continue
            seen = {k: obs[k][i] for k in cams if i in obs[k]}
            cands = [np.linalg.inv(cams[k]) @ T for k, c in seen.items() for _, T in _ippe(c, size[i])]
            markers[i] = min(cands + [markers[i]], key=lambda T: _reproj(T, size[i], cams, seen))
        for k in cams:
            cams[k] = _pose_view(obs[k], size, markers)


def _pose_view(view: dict, size: dict, markers: dict) -> np.ndarray | None:
    """T_cam_from_world (4, 4) of a view from the placed markers it sees (PnP on all their
    corners, started from the best single-marker pose), or None when it sees none."""
    known = [i for i in view if i in markers]
    if not known:
        return None
    best = min((_ippe(view[i], size[i])[0] + (i,) for i in known), key=lambda c: c[0])     # (rms, T, id)
    T = best[1] @ np.linalg.inv(markers[best[2]])
    if len(known) > 1:
        obj = np.concatenate([marker_corners_world(size[i], markers[i]) for i in known])
        img = np.concatenate([view[i] for i in known])
        rvec, _ = cv2.Rodrigues(T[:3, :3])
        ok, rvec, tvec = cv2.solvePnP(obj, img, np.eye(3), None, rvec, T[:3, 3].copy(), useExtrinsicGuess=True,
                                      flags=cv2.SOLVEPNP_ITERATIVE)
        if ok:
            T = transform_from_rvec_tvec(rvec, tvec)
    return T


def _chain(obs: list, size: dict, origin: int, start: dict) -> tuple[dict, dict]:
    """Initial poses: markers ``T_world_from_marker`` and views ``T_cam_from_world``, chained from
    the markers of ``start`` (the origin's alone, or an earlier map's): repeatedly, the unposed view
    that sees the most placed markers is posed by them, and the markers it alone sees so far are
    placed by it."""
    markers = dict(start)
    cams: dict = {}
    while True:
        todo = [(sum(i in markers for i in v), k) for k, v in enumerate(obs) if k not in cams]
        todo = [x for x in todo if x[0] > 0]
        if not todo:
            return markers, cams
        _, k = max(todo)
        T = _pose_view(obs[k], size, markers)
        cams[k] = T
        for i, c in obs[k].items():
            if i not in markers:
                markers[i] = np.linalg.inv(T) @ _ippe(c, size[i])[0][1]


def _unpack(x, cam_keys, marker_keys) -> tuple[dict, dict]:
    """Poses from the parameter vector: per view (rvec, tvec) of T_cam_from_world, then per
    marker (rvec, tvec) of T_world_from_marker."""
    p = x.reshape(-1, 6)
    cams = {k: transform_from_rvec_tvec(p[j, :3], p[j, 3:]) for j, k in enumerate(cam_keys)}
    n = len(cam_keys)
    markers = {i: transform_from_rvec_tvec(p[n + j, :3], p[n + j, 3:]) for j, i in enumerate(marker_keys)}
    return cams, markers


def _pack(T) -> np.ndarray:
    rvec, _ = cv2.Rodrigues(np.ascontiguousarray(T[:3, :3]))
    return np.concatenate([rvec.ravel(), T[:3, 3]])


def _residuals(x, prob: dict) -> np.ndarray:
    """(8 per observation) corner reprojection errors, pixels (normalised times the focal length),
    all observations at once: ``prob`` holds each observation's view row, marker row (-1: the
    origin, whose pose is ``prob["origin"]``), marker-frame corners (n, 4, 3) and observed
    corners (n, 4, 2)."""
    p = x.reshape(-1, 6)
    n_c = prob["n_cams"]
    Rc, tc = Rotation.from_rotvec(p[:n_c, :3]).as_matrix(), p[:n_c, 3:]
    To = prob["origin"]
    Rm = np.concatenate([Rotation.from_rotvec(p[n_c:, :3]).as_matrix(), To[None, :3, :3]]) if len(p) > n_c else \
        To[None, :3, :3]
    tm = np.concatenate([p[n_c:, 3:], To[None, :3, 3]])
    m, c = prob["marker"], prob["cam"]
    Xw = prob["local"] @ np.swapaxes(Rm[m], 1, 2) + tm[m][:, None]
    return prob["focal"] * (_image(Rc[c], tc[c], Xw)[0] - prob["seen"]).ravel()


@dataclass
class _Adjusted:
    """The bundle adjustment's outcome: poses, residuals (pixels, 8 per observation ``pairs``),
    and the markers' information with the views marginalised (``tracking.bundle``)."""

    markers: dict
    cams: dict
    residuals: np.ndarray
    information: np.ndarray
    pairs: list
    marker_keys: list


def _adjust(obs, size, origin, markers, cams, focal, T_origin) -> _Adjusted:
    """Bundle adjustment of every posed view and placed marker but the origin, which stays at
    ``T_origin`` (Huber loss, ``HUBER_PX``; ``tracking.bundle``)."""
    cam_keys = sorted(cams)
    marker_keys = sorted(i for i in markers if i != origin)
    pairs = [(k, i) for k in cam_keys for i in obs[k] if i in markers]
    prob = {"n_cams": len(cam_keys), "focal": focal,
            "cam": np.array([cam_keys.index(k) for k, _ in pairs]),
            "marker": np.array([marker_keys.index(i) if i != origin else -1 for _, i in pairs]),
            "local": np.array([square_corners(size[i]) for _, i in pairs]),
            "seen": np.array([obs[k][i] for k, i in pairs]), "origin": T_origin}

    def fun(v, o):
        return _residuals(np.concatenate([v.ravel(), o.ravel()]), prob).reshape(-1, 8)
    fit = bundle_adjust(fun, np.array([_pack(cams[k]) for k in cam_keys]),
                        np.array([_pack(markers[i]) for i in marker_keys]).reshape(-1, 6), prob["cam"], prob["marker"],
                        HUBER_PX, MAX_ITER)
    if not fit.converged:
        log.warning("the map's bundle adjustment stopped after %d steps before converging", fit.iterations)
    cams, adjusted = _unpack(np.concatenate([fit.views.ravel(), fit.objects.ravel()]), cam_keys, marker_keys)
    adjusted[origin] = T_origin
    return _Adjusted(adjusted, cams, fit.residuals.ravel(), fit.information, pairs, marker_keys)


def _marker_covariances(adj: _Adjusted) -> dict:
    """{marker id: (6, 6)} the markers' parameter covariance: the inverse of their information
    (the views marginalised) times the residuals' mean square per degree of freedom, pixels^2."""
    n_par = 6 * len(adj.marker_keys) + 6 * len(adj.cams)
    dof = max(len(adj.residuals) - n_par, 1)
    S = adj.information
    C = np.linalg.pinv(S) * float(np.sum(adj.residuals ** 2)) / dof if S.size else S
    return {i: C[6 * j:6 * j + 6, 6 * j:6 * j + 6] for j, i in enumerate(adj.marker_keys)}


def _adjust_moving(obs, size, origin, markers, cams, focal, T_origin) -> tuple[_Adjusted, dict]:
    """``_adjust``, and then while a marker (not the origin) moved during the survey (``_moved``),
    the one that moved most surely becomes two for another adjustment: its views after the move
    see a second marker (id ``-1 - i``) where it went, so that its move does not drag the
    views and markers beside it. Returns the last adjustment with each moved marker's pose after
    the move under its own id (the second marker dropped, its observations counted), and {id:
    mm moved}."""
    obs, size, markers, moved = list(obs), dict(size), dict(markers), {}
    for _ in range(MAX_MOVED + 1):
        adj = _adjust(obs, size, origin, markers, cams, focal, T_origin)
        found = {i: v for i, v in _moved(obs, size, adj.markers, adj.cams).items() if i >= 0 and i != origin}
        if len(moved) == MAX_MOVED:
            moved.update({i: v[0] for i, v in found.items() if i not in moved})    # flagged, not split
            break
        if not found:
            break
        i = max(found, key=lambda j: found[j][1])
        moved[i] = found[i][0]
        for k in [k for k in sorted(adj.cams) if k >= found[i][2] and i in obs[k]]:
            obs[k] = {(-1 - j if j == i else j): c for j, c in obs[k].items()}
        size[-1 - i] = size[i]
        markers, cams = dict(adj.markers), dict(adj.cams)
        markers[-1 - i] = markers[i]
    for i in [j for j in moved if -1 - j in adj.markers]:
        moved[i] = float(np.linalg.norm(adj.markers[-1 - i][:3, 3] - adj.markers[i][:3, 3]))   # as adjusted
        adj.markers[i] = adj.markers.pop(-1 - i)
        if moved[i] <= MOVED_MM:          # a first adjustment's doubt the last one does not bear out
            del moved[i]
        adj.pairs = [(k, i if j == -1 - i else j) for k, j in adj.pairs]
    return adj, moved


def _marker_info(obs, size, origin, adj: _Adjusted, moved: dict) -> dict:
    """Per marker: views, RMS, covariance, flags (seen too rarely, moved)."""
    cov = _marker_covariances(adj)
    for i in [j for j in moved if -1 - j in cov]:     # the pose after the move: the second marker's
        cov[i] = cov.pop(-1 - i)
    per = {i: [] for i in adj.markers}
    for r, (_, i) in enumerate(adj.pairs):
        per[i].append(adj.residuals[8 * r:8 * r + 8])
    info = {}
    for i in sorted(adj.markers):
        r = np.concatenate(per[i]) if per[i] else np.zeros(0)
        info[i] = MarkerInfo(len(per[i]), float(np.sqrt(np.mean(r ** 2))) if len(r) else float("nan"),
                             cov.get(i, np.zeros((6, 6))))
        if len(per[i]) < MIN_VIEWS:
            info[i].flags.append(f"seen in {len(per[i])} view(s)")
    for i, mm in moved.items():
        info[i].flags.append(f"moved by {mm:.0f} mm during the survey (its pose after the move kept)")
    return info


def _moved(obs, size, markers, cams) -> dict:
    """{marker id: (mm, chi2, first view after the move)} of the markers that moved during the
    survey: split its views (in view order) where two poses fit them best (views fixed), those
    two poses' positions are more than ``MOVED_MM`` and 5 sd apart (chi2: the squared
    Mahalanobis distance between them)."""
    out = {}
    order = sorted(cams)
    for i in markers:
        seen = [k for k in order if i in obs[k]]
        if len(seen) < 2 * MIN_VIEWS:
            continue
        fit = {}

        def cost(m, i=i, seen=seen, fit=fit):
            if m not in fit:
                fit[m] = [_fit_marker(obs, size[i], i, markers[i], cams, part) for part in (seen[:m], seen[m:])]
            return fit[m][0][2] + fit[m][1][2]
        cuts = range(MIN_VIEWS, len(seen) - MIN_VIEWS + 1)
        step = max(len(cuts) // 10, 1)
        m = min(cuts[::step], key=cost)
        m = min(range(max(m - step, cuts[0]), min(m + step, cuts[-1]) + 1), key=cost)
        (Ta, Ca, _), (Tb, Cb, _) = fit[m]
        d = Ta[:3, 3] - Tb[:3, 3]
        dist, chi2 = float(np.linalg.norm(d)), float(d @ np.linalg.solve(Ca + Cb + 1e-9 * np.eye(3), d))
        if dist > MOVED_MM and chi2 > 25.0:
            out[i] = (dist, chi2, seen[_cut_without(obs, size, markers, cams, i, seen, m)])
    return out


def _cut_without(obs, size, markers, cams, i, seen, m) -> int:
    """Where a moved marker's views ``seen`` split, judged with each view posed by its other
    markers (views that see none keep their pose): the adjustment before the split posed the
    views after a move partly by the moved marker itself, so views next to the move side
    with it and the best cut with those poses can fall a few views early. Returns the cut's
    index into ``seen`` (``m``, the first guess, when no cut fits better)."""
    own = {k: _pose_view({j: c for j, c in obs[k].items() if j != i}, size, markers) for k in seen}
    own = {k: cams[k] if T is None else T for k, T in own.items()}
    fit = {}

    def cost(c):
        if c not in fit:
            fit[c] = sum(_fit_marker(obs, size[i], i, markers[i], own, part)[2] for part in (seen[:c], seen[c:]))
        return fit[c]
    return min(range(MIN_VIEWS, len(seen) - MIN_VIEWS + 1), key=lambda c: (cost(c), c != m))


def _fit_marker(obs, side, i, T0, cams, keys):
    """A marker's pose fitted to its corners in views ``keys`` (views fixed), from ``T0``:
    (T_world_from_marker, its position's covariance (3, 3), mm^2, the sum of squared
    residuals, normalised)."""
    R = np.array([cams[k][:3, :3] for k in keys])
    t = np.array([cams[k][:3, 3] for k in keys])
    seen = np.array([obs[k][i] for k in keys])

    def res(x):
        return (_image(R, t, marker_corners_world(side, transform_from_rvec_tvec(x[:3], x[3:])))[0] - seen).ravel()
    fit = least_squares(res, _pack(T0), method="lm")
    J = fit.jac
    s2 = float(np.sum(fit.fun ** 2)) / max(len(fit.fun) - 6, 1)
    C = np.linalg.pinv(J.T @ J) * s2
    return transform_from_rvec_tvec(fit.x[:3], fit.x[3:]), C[3:, 3:], float(np.sum(fit.fun ** 2))
