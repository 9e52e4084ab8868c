"""A marker map built from views of the markers (issue 16; docs/tracking.md, "Building a map"):
the markers' poses in a world fixed by one of them, from their detected corners in many images
(a survey video's frames, or photos), without measuring anything but the printed sizes.

Each view's markers are posed alone (IPPE for a square); views and markers are chained from the
origin marker outward (a view posed by the markers already placed, then its new markers placed
by it); then, when the survey holds enough views, the camera's intrinsics are refined with all
view and marker poses (``tracking.mapintrinsics``), and the corners normalised again with them;
then all view and marker poses are adjusted together, and moved markers split in two
(``tracking.mapadjust``: bundle adjustment on the corners' reprojection, a robust Huber loss,
Levenberg-Marquardt with the views eliminated, ``tracking.bundle``). The scale is the printed
markers' sides, so the map is in millimetres. Then per marker: its pose covariance, how many views
saw it, its reprojection RMS, and whether it moved during the survey (its views before and after
the middle fit poses farther apart than their uncertainty allows).

World frame: the origin marker's (x right along its top edge, y down, z into the wall, the
cv2.aruco marker frame), mm. Corners in cv2.aruco order.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from calibration.camera import undistort_points
from estimator.frames import similarity_transform

from .mapadjust import (
    MIN_VIEWS,
    Adjusted,
    StepTally,
    adjust_with_moves,
    ippe,
    marker_covariances,
    pose_view,
    project,
    residual_rms,
)
from .mapintrinsics import IntrinsicsRefinement, refine_intrinsics
from .markermap import MarkerMap, marker_corners_world

log = logging.getLogger(__name__)

POOR_FIT = 3.0
"""After a moved marker's split, a map whose reprojection RMS is over this many times its markers'
median RMS still fits its views poorly: which marker moved is then uncertain, and its flags say so
(a clean fit's ratio is about 1)."""
REFINE_ROUNDS = 2
"""The chain's first guesses are refined this many times before the adjustment (``_refine_initial``)."""


@dataclass
class MarkerInfo:
    """One marker of a built map.

    Attributes:
        n_views: views that saw it.
        rms_px: reprojection RMS of its corners after adjustment, pixels.
        covariance: (6, 6) of (rotation vector, rad; position, mm) of ``T_world_from_marker``,
            the pose beside it (zeros for the origin marker, which fixes the world).
        flags: why not to trust it: 'seen in N views', 'moved by N mm during the survey', and
            after a move 'the map fits its views poorly ...' (``POOR_FIT``).
    """

    n_views: int
    rms_px: float
    covariance: np.ndarray
    flags: list = field(default_factory=list)


@dataclass
class BuiltMap:
    """A map built from views: the ``MarkerMap``, per marker a ``MarkerInfo``, the posed views'
    ``T_world_from_cam`` (view index -> (4, 4)), the views no marker of the map could pose, the
    overall reprojection RMS, pixels, after the moved markers were split, and before (the same
    when none was), and the intrinsics it was built with (refined or not, and why)."""

    marker_map: MarkerMap
    info: dict
    cameras: dict
    unposed: list
    rms_px: float
    rms_unsplit_px: float = float("nan")
    intrinsics: IntrinsicsRefinement | None = None


def build_marker_map(views, K, dist, dictionary: str, sizes, origin: int | None = None,
                     model: str = "pinhole", prior: MarkerMap | None = None, image_size=None,
                     refine: bool = True, progress=None) -> BuiltMap:
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
        image_size: (width, height) of the images, px (default: twice the principal point).
        refine: refine the intrinsics when the survey can (``tracking.mapintrinsics``): the map
            is then built, and its moved markers sought, with the refined ones.
        progress: ``progress(done, total)`` as the work goes (``tracking.mapadjust.StepTally``):
            the chain's first guesses refined (a step per marker and view, each round), the
            bundle adjustments' steps (the first, then each moved marker's trials), the markers
            checked for a move.

    Raises:
        ValueError: no marker seen, the origin never seen (or not in ``prior``), a seen id
            without a size.
    """
    obs = _normalized(views, K, dist, model)
    ids = sorted({i for v in obs for i in v})
    if not ids:
        raise ValueError("no marker was detected in any view")
    size = _marker_sizes(ids, sizes)
    prior_poses = {int(i): np.asarray(T, float) for i, T in (prior.poses if prior else {}).items()}
    origin = _choose_origin(obs, ids, prior_poses, origin)
    seen = set(ids)
    start = ({i: T for i, T in prior_poses.items() if i in seen} if prior_poses
             else {origin: np.eye(4)})
    markers, cams = _chain(obs, size, origin, start)
    tally = StepTally(progress)
    _refine_initial(obs, size, origin, markers, cams,
                    tick=tally.work(REFINE_ROUNDS * (len(markers) + len(cams))))
    intr, markers, cams = _intrinsics(views, size, origin, markers, cams, K, dist, model, image_size, refine)
    if intr.refined:
        K, dist = intr.camera_matrix, intr.dist_coeffs
        obs = _normalized(views, K, dist, model)
    adj, moved, rms_unsplit = adjust_with_moves(obs, size, origin, markers, cams, float(K[0, 0]),
                                                 markers[origin], tally)
    rms = residual_rms(adj.residuals)
    info = _marker_info(obs, size, origin, adj, moved, rms)
    _keep_unseen(prior_poses, adj.markers, info)
    unposed = [k for k in range(len(obs)) if k not in adj.cams]
    log.info("map of %d markers from %d views (%d unposed), RMS %.2f px (%.2f px before the moved "
             "markers were split)", len(adj.markers), len(adj.cams), len(unposed), rms, rms_unsplit)
    cameras = {k: np.linalg.inv(T) for k, T in adj.cams.items()}
    marker_map = _marker_map(dictionary, size, adj.markers, prior if prior_poses else None)
    return BuiltMap(marker_map, info, cameras, unposed, rms, rms_unsplit, intr)


def _keep_unseen(prior_poses: dict, markers: dict, info: dict) -> None:
    """The earlier map's markers these views do not see, added to ``markers`` {id: (4, 4)
    T_world_from_marker} as the earlier map had them, with no views in ``info``."""
    for i, T in prior_poses.items():
        if i not in markers:
            markers[i] = T
            info[i] = MarkerInfo(0, float("nan"), np.zeros((6, 6)))


def _marker_map(dictionary: str, size: dict[int, float], markers: dict,
                prior: MarkerMap | None) -> MarkerMap:
    """The map of ``markers`` {id: (4, 4) T_world_from_marker}: the commonest size as its
    marker size, the others (and the earlier map's markers' own) as exceptions."""
    common = float(max(set(size.values()), key=list(size.values()).count))
    sides = size
    if prior is not None:
        sides = {**{int(i): prior.size_of(i) for i in prior.poses}, **size}
    exceptions = {i: v for i, v in sides.items() if v != common}
    return MarkerMap(dictionary, common, dict(markers), {}, exceptions)


def _marker_sizes(ids: list[int], sizes) -> dict[int, float]:
    """{id: printed side, mm} of every id seen, from one number or {id: side}.

    Raises:
        ValueError: a seen id without a size.
    """
    one_size = bool(np.isscalar(sizes))
    if one_size:
        size = {i: float(sizes) for i in ids}
    else:
        size = {i: float(sizes[i]) for i in ids if i in sizes}
    missing = [i for i in ids if i not in size]
    if missing:
        raise ValueError(f"no printed size for marker(s) {missing}: give one for every id seen")
    return size


def _choose_origin(obs: list, ids: list[int], prior_poses: dict, origin: int | None) -> int:
    """The marker whose frame is the world: ``origin``, or the one seen in most views (of the
    earlier map's markers when there is one; ties to the lowest id).

    Raises:
        ValueError: no earlier marker seen, the origin never seen or not in the earlier map.
    """
    counts = {i: sum(i in v for v in obs) for i in ids}
    choices = [i for i in ids if i in prior_poses] if prior_poses else ids
    if not choices:
        raise ValueError(f"none of the earlier map's markers is in a view (seen: {ids})")
    origin = max(choices, key=lambda i: (counts[i], -i)) if origin is None else int(origin)
    if origin not in counts:
        raise ValueError(f"the origin marker {origin} is in no view (seen: {ids})")
    if prior_poses and origin not in prior_poses:
        raise ValueError(f"the origin marker {origin} is not in the earlier map")
    return origin


def _intrinsics(views, size, origin, markers, cams, K, dist, model, image_size, refine: bool):
    """``refine_intrinsics`` of the views' pixel corners (repeated ids left out by the caller),
    or the given intrinsics kept when not ``refine``."""
    if not refine:
        K, dist = np.asarray(K, float), np.asarray(dist, float).ravel()
        return IntrinsicsRefinement(K, dist, K, dist, False, "not asked to (refinement off)", len(cams), 0, {},
                                    model=model), markers, cams
    px = [{int(i): np.asarray(c, np.float64).reshape(4, 2) for i, c in v.items()} for v in views]
    return refine_intrinsics(px, size, origin, markers, cams, K, dist, model, image_size)


def similarity_errors(A, B) -> tuple[np.ndarray, float]:
    """How far points ``A`` (N, 3) (a built map's corners) lie from ``B`` (N, 3) (the same points
    measured, or true) after the best similarity transform of ``A`` onto ``B``
    (``similarity_transform``): per point the distance, mm, and the transform's scale (a print's
    scale differs from nominal by a few per cent)."""
    T = similarity_transform(A, B)
    A, B = np.asarray(A, float), np.asarray(B, float)
    return np.linalg.norm(A @ T[:3, :3].T + T[:3, 3] - B, axis=1), float(np.cbrt(np.linalg.det(T[:3, :3])))


def _normalized(views, K, dist, model: str = "pinhole") -> list:
    """Each view's corners as normalised image coordinates (undistorted to convergence,
    ``calibration.camera.undistort_points``: OpenCV's default 5 iterations left the simulated
    survey's map, k1 = -0.28, 2.6 mm off its true shape)."""
    out = []
    for v in views:
        out.append({int(i): undistort_points(np.asarray(c, np.float64).reshape(4, 2), K, dist, model)
                    for i, c in v.items()})
    return out


def _reproj(T_world_from_marker, side: float, cams: dict, seen: dict) -> float:
    """Sum of squared corner reprojection errors (normalised) of a marker placed at
    ``T_world_from_marker`` in the views ``seen`` {view: corners} posed by ``cams``."""
    T = np.array([cams[k] for k in seen])
    uv, z = project(T[:, :3, :3], T[:, :3, 3], marker_corners_world(side, T_world_from_marker))
    return float(np.sum((uv - np.array(list(seen.values()))) ** 2)) if np.all(z > 0) else np.inf


def _refine_initial(obs: list, size: dict, origin: int, markers: dict, cams: dict, rounds: int = REFINE_ROUNDS,
                    tick=None) -> None:
    """Before the adjustment, undo the chaining's worst guesses (in place): each marker is placed
    where one of its views' two IPPE solutions puts it that reprojects best in all its views,
    then each view is posed again from all its markers; ``rounds`` times. A small marker seen
    face-on has two IPPE solutions a few degrees apart, and the chain may have taken the wrong
    one, a local minimum the adjustment cannot leave. ``tick()``: called for each marker and view,
    each round."""
    for _ in range(rounds):
        for i in markers:
            if tick is not None:
                tick()
            if i == origin:
                continue
            seen = {k: obs[k][i] for k in cams if i in obs[k]}
            cands = [np.linalg.inv(cams[k]) @ T for k, c in seen.items() for _, T in ippe(c, size[i])]
            markers[i] = min(cands + [markers[i]], key=lambda T: _reproj(T, size[i], cams, seen))
        for k in cams:
            if tick is not None:
                tick()
            cams[k] = pose_view(obs[k], size, markers)


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
        T = pose_view(obs[k], size, markers)
        assert T is not None                         # it sees placed markers
        cams[k] = T
        for i, c in obs[k].items():
            if i not in markers:
                markers[i] = np.linalg.inv(T) @ ippe(c, size[i])[0][1]


def _marker_info(obs, size, origin, adj: Adjusted, moved: dict, rms: float) -> dict:
    """Per marker: views, RMS, covariance, flags (seen too rarely, moved; after a move, the map's
    fit, ``rms`` px over all its residuals, still poor: ``POOR_FIT``)."""
    cov = marker_covariances(adj)
    for i in [j for j in moved if -1 - j in cov]:     # the pose after the move: the second marker's
        cov[i] = cov.pop(-1 - i)
    per: dict[int, list[np.ndarray]] = {i: [] for i in adj.markers}
    for k, (_, i) in enumerate(adj.pairs):
        per[i].append(adj.residuals[8 * k:8 * k + 8])
    info = {}
    for i in sorted(adj.markers):
        r = np.concatenate(per[i]) if per[i] else np.zeros(0)
        info[i] = MarkerInfo(len(per[i]), residual_rms(r), cov.get(i, np.zeros((6, 6))))
        if len(per[i]) < MIN_VIEWS:
            info[i].flags.append(f"seen in {len(per[i])} view(s)")
    for i, mm in moved.items():
        info[i].flags.append(f"moved by {mm:.0f} mm during the survey (its pose after the move kept)")
    typical = float(np.nanmedian([m.rms_px for m in info.values()]))
    if moved and rms > POOR_FIT * typical:
        log.warning("after the moved markers' split the map still fits its views poorly: RMS %.2f px, its markers' "
                    "median %.2f px", rms, typical)
        for i in moved:
            info[i].flags.append(f"the map fits its views poorly after the split (RMS {rms:.2f} px, its markers' "
                                 f"median {typical:.2f} px): which marker moved is uncertain")
        for i in [j for j, m in info.items() if m.rms_px > POOR_FIT * typical and j not in moved]:
            info[i].flags.append(f"fits its views poorly (RMS {info[i].rms_px:.2f} px, the map's median "
                                 f"{typical:.2f} px): it may have moved during the survey")
    return info


