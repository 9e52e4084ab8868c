"""A marker map's adjustment (``tracking.mapbuild``; docs/tracking.md, "Building a map"): all
view and marker poses adjusted together (bundle adjustment on the corners' reprojection, a robust
Huber loss, ``tracking.bundle``), and the markers that moved during the survey found and split
in two (before and after), the split chosen among the suspects by the fit it gives. Also the
single-marker poses (IPPE) and a view posed by its placed markers, which the chaining shares.

World frame: the map's (the origin marker's), mm; views ``T_cam_from_world`` (4, 4); image
points in normalised coordinates (undistorted), residuals in pixels (times the focal length).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from .bundle import bundle_adjust, huber_cost
from .markermap import marker_corners_world, square_corners
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
MAX_SUSPECTS = 4
"""At most this many markers' splits are tried for each move found (each costs one adjustment,
started from the last one's poses): the flagged ones and their neighbours at the move."""
TRIAL_ITER = 30
"""The step budget of each suspect's trial adjustment; the best one's, if it has not converged,
is then carried on to ``MAX_ITER``."""
HUBER_PX = 1.0
"""The bundle adjustment's robust loss turns from squares to absolute values past this, pixels."""


def ippe(corners_norm: ArrayLike, side: float) -> list:
    """IPPE's solutions for one marker seen alone: [(reprojection RMS in normalised units,
    T_cam_from_marker (4, 4)), ...], the best first (planar IPPE: our corners, y down, are not in
    IPPE_SQUARE's order)."""
    n, rvecs, tvecs, errs = cv2.solvePnPGeneric(square_corners(side), corners_norm, np.eye(3), None,
                                                flags=cv2.SOLVEPNP_IPPE)
    return sorted(((float(e), transform_from_rvec_tvec(rvecs[k], tvecs[k])) for k, e in
                   zip(range(n), np.ravel(errs), strict=True)), key=lambda c: c[0])


def project(R_cam_from_world, t_cam_from_world, pts_world) -> tuple[np.ndarray, np.ndarray]:
    """Points ``pts_world`` (4, 3) or (n, 4, 3), mm, in n views, each ``T_cam_from_world`` given
    as its rotation (n, 3, 3) and translation (n, 3) mm: (n, 4, 2) normalised image
    coordinates and (n, 4) depths, mm."""
    pts_cam = pts_world @ np.swapaxes(R_cam_from_world, 1, 2) + t_cam_from_world[:, None]
    return pts_cam[..., :2] / pts_cam[..., 2:3], pts_cam[..., 2]


def pose_view(view: dict, size: dict, markers: dict) -> np.ndarray | None:
    """T_cam_from_world (4, 4) of a view from the placed markers it sees (PnP on all their
    corners, started from the best single-marker pose), or None when it sees none."""
    known = [i for i in view if i in markers]
    if not known:
        return None
    best = min((ippe(view[i], size[i])[0] + (i,) for i in known), key=lambda c: c[0])     # (rms, T, id)
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


def unpack_poses(x, cam_keys, marker_keys) -> tuple[dict, dict]:
    """Poses from the parameter vector: per view (rvec, tvec) of T_cam_from_world, then per
    marker (rvec, tvec) of T_world_from_marker."""
    p = x.reshape(-1, 6)
    cams = {k: transform_from_rvec_tvec(p[j, :3], p[j, 3:]) for j, k in enumerate(cam_keys)}
    n = len(cam_keys)
    markers = {i: transform_from_rvec_tvec(p[n + j, :3], p[n + j, 3:]) for j, i in enumerate(marker_keys)}
    return cams, markers


def pack_pose(T) -> np.ndarray:
    """(6,) (rvec, rad; tvec, mm) of a rigid transform (4, 4)."""
    rvec, _ = cv2.Rodrigues(np.ascontiguousarray(T[:3, :3]))
    return np.concatenate([rvec.ravel(), T[:3, 3]])


def adjustment_problem(obs, size, origin, markers, cams, T_origin: ArrayLike) -> dict:
    """The observations of every posed view (``cams``) of a placed marker (``markers``) as arrays:
    ``cam_keys``, ``marker_keys`` (the origin left out: it stays at ``T_origin``), ``pairs``
    [(view, marker)], and per pair its view row ``cam``, marker row ``marker`` (-1: the origin),
    marker-frame corners ``local`` (n, 4, 3), mm, and observed corners ``seen`` (n, 4, 2) as
    ``obs`` holds them; ``n_cams``, ``origin`` (T_origin)."""
    cam_keys = sorted(cams)
    marker_keys = sorted(i for i in markers if i != origin)
    pairs = [(k, i) for k in cam_keys for i in obs[k] if i in markers]
    return {"cam_keys": cam_keys, "marker_keys": marker_keys, "pairs": pairs, "n_cams": len(cam_keys),
            "cam": np.array([cam_keys.index(k) for k, _ in pairs]),
            "marker": np.array([marker_keys.index(i) if i != origin else -1 for _, i in pairs]),
            "local": np.array([square_corners(size[i]) for _, i in pairs]).reshape(-1, 4, 3),
            "seen": np.array([obs[k][i] for k, i in pairs]).reshape(-1, 4, 2), "origin": T_origin}


def camera_corners(views, objs, prob: dict) -> np.ndarray:
    """(n, 4, 3) every observation's marker corners in its view's camera frame, mm: views (V, 6)
    (rvec, tvec) of their T_cam_from_world, markers (M, 6) of T_world_from_marker, the origin's
    pose and the observations in ``prob`` (``adjustment_problem``)."""
    Rc, tc = Rotation.from_rotvec(views[:, :3]).as_matrix(), views[:, 3:]
    To = prob["origin"]
    Rm = np.concatenate([Rotation.from_rotvec(objs[:, :3]).as_matrix(), To[None, :3, :3]]) if len(objs) else \
        To[None, :3, :3]
    tm = np.concatenate([objs[:, 3:], To[None, :3, 3]])
    m, c = prob["marker"], prob["cam"]
    Xw = prob["local"] @ np.swapaxes(Rm[m], 1, 2) + tm[m][:, None]
    return Xw @ np.swapaxes(Rc[c], 1, 2) + tc[c][:, None]


@dataclass
class Adjusted:
    """The bundle adjustment's outcome: poses, residuals (pixels, 8 per observation ``pairs``),
    the markers' information with the views marginalised (``tracking.bundle``), and whether it
    converged (else it stopped at its step budget)."""

    markers: dict
    cams: dict
    residuals: np.ndarray
    information: np.ndarray
    pairs: list
    marker_keys: list
    converged: bool = True


@dataclass
class StepTally:
    """The adjustment's work for a ``progress(done, total)`` callback (None: no reports), in steps:
    each bundle adjustment adds its step budget to the total when it starts and gives back what it
    did not use when it ends (a trial's budget is ``TRIAL_ITER``, the others' ``MAX_ITER``); other
    work (a search for moved markers: a step a marker; the map's first guesses refined) adds its
    own steps."""

    progress: Callable[[int, int], None] | None = None
    done: int = 0
    total: int = 0
    base: int = 0                   # the steps done before the adjustment running now

    def begin(self, max_iter: int):
        """The ``progress(step, max_iter)`` callback of one adjustment (None without progress)."""
        progress = self.progress
        if progress is None:
            return None
        self.total += max_iter
        self.base = self.done

        def step(it: int, _max_iter: int) -> None:
            self.done = self.base + it
            progress(self.done, self.total)
        return step

    def work(self, n: int):
        """The ``tick()`` callback of ``n`` more steps of other work, one a call (None without
        progress)."""
        progress = self.progress
        if progress is None:
            return None
        self.total += n

        def tick() -> None:
            self.done += 1
            progress(self.done, self.total)
        return tick

    def end(self, max_iter: int, iterations: int) -> None:
        """The adjustment begun with ``max_iter`` ended after ``iterations`` steps."""
        if self.progress is not None:
            self.total -= max_iter - iterations
            self.done = self.base + iterations
            self.progress(self.done, self.total)


def _adjust(obs, size, origin, markers, cams, focal, T_origin, max_iter: int = MAX_ITER,
            tally: StepTally | None = None) -> Adjusted:
    """Bundle adjustment of every posed view and placed marker but the origin, which stays at
    ``T_origin`` (Huber loss, ``HUBER_PX``; ``tracking.bundle``); its steps counted in ``tally``."""
    prob = adjustment_problem(obs, size, origin, markers, cams, T_origin)
    cam_keys, marker_keys, pairs = prob["cam_keys"], prob["marker_keys"], prob["pairs"]

    def fun(v, o):          # corner reprojection errors, pixels (normalised times the focal length)
        Xc = camera_corners(v, o, prob)
        return focal * (Xc[..., :2] / Xc[..., 2:3] - prob["seen"]).reshape(-1, 8)
    fit = bundle_adjust(fun, np.array([pack_pose(cams[k]) for k in cam_keys]),
                        np.array([pack_pose(markers[i]) for i in marker_keys]).reshape(-1, 6), prob["cam"],
                        prob["marker"], HUBER_PX, max_iter, None if tally is None else tally.begin(max_iter))
    if tally is not None:
        tally.end(max_iter, fit.iterations)
    if not fit.converged and max_iter == MAX_ITER:
        log.warning("the map's bundle adjustment stopped after %d steps before converging", fit.iterations)
    cams, adjusted = unpack_poses(np.concatenate([fit.views.ravel(), fit.objects.ravel()]), cam_keys, marker_keys)
    adjusted[origin] = T_origin
    return Adjusted(adjusted, cams, fit.residuals.ravel(), fit.information, pairs, marker_keys, fit.converged)


def marker_covariances(adj: Adjusted) -> dict:
    """{marker id: (6, 6)} the markers' parameter covariance: the inverse of their information
    (the views marginalised) times the residuals' mean square per degree of freedom, pixels^2."""
    n_par = 6 * len(adj.marker_keys) + 6 * len(adj.cams)
    dof = max(len(adj.residuals) - n_par, 1)
    S = adj.information
    C = np.linalg.pinv(S) * float(np.sum(adj.residuals ** 2)) / dof if S.size else S
    return {i: C[6 * j:6 * j + 6, 6 * j:6 * j + 6] for j, i in enumerate(adj.marker_keys)}


def adjust_with_moves(obs, size, origin, markers, cams, focal, T_origin: np.ndarray,
                      tally: StepTally | None = None
                      ) -> tuple[Adjusted, dict, float]:
    """``_adjust``, and then while a marker (not the origin) moved during the survey (``_moved``),
    one marker becomes two for another adjustment: its views after the move see a second marker
    (id ``-1 - i``) where it went, so that its move does not drag the views and markers beside
    it. Which one: a marker moved while in view with its neighbours drags them too, and they
    can be flagged in its place, so each suspect (``_suspects``: the flagged markers and those
    seen with the surest at its move) is split in turn at its own best cut, adjusted again
    from the last adjustment's poses, and the split whose adjustment has the least robust cost
    is kept. Returns the last adjustment with each moved marker's pose after the move under its
    own id (the second marker dropped, its observations counted), {id: mm moved}, and the
    reprojection RMS before any split, pixels. ``tally``: where the adjustments' steps and the
    markers checked for a move are counted, for a progress callback."""
    obs, size, tally = list(obs), dict(size), tally or StepTally()
    moved: dict[int, float] = {}
    adj = _adjust(obs, size, origin, markers, cams, focal, T_origin, tally=tally)
    rms_unsplit = residual_rms(adj.residuals)
    while True:
        found = {i: v for i, v in _moved(obs, size, adj.markers, adj.cams, tally.work(len(adj.markers))).items()
                 if i >= 0 and i != origin and i not in moved}
        log.debug("moved markers found: %s", {i: (round(v[0]), round(v[1]), v[2]) for i, v in found.items()})
        if not found:
            break
        if len(moved) == MAX_MOVED:
            moved.update({i: v[0] for i, v in found.items()})    # flagged, not split
            break
        trials = []
        for i, cut in _suspects(obs, size, adj, found, origin, moved):
            o, s, m = _split(obs, size, adj, i, cut)
            trial = _adjust(o, s, origin, m, adj.cams, focal, T_origin, TRIAL_ITER, tally)
            log.debug("moved marker: split of %d at view %d, cost %.4g, RMS %.3f px (converged: %s)", i, cut,
                      huber_cost(trial.residuals, HUBER_PX), residual_rms(trial.residuals), trial.converged)
            trials.append((huber_cost(trial.residuals, HUBER_PX), i, o, s, trial))
        _, i, obs, size, adj = min(trials, key=lambda t: t[0])
        if not adj.converged:                             # the best split's adjustment, finished
            adj = _adjust(obs, size, origin, adj.markers, adj.cams, focal, T_origin, tally=tally)
        moved[i] = found.get(i, (0.0,))[0]
    for i in [j for j in moved if -1 - j in adj.markers]:
        moved[i] = float(np.linalg.norm(adj.markers[-1 - i][:3, 3] - adj.markers[i][:3, 3]))   # as adjusted
        adj.markers[i] = adj.markers.pop(-1 - i)
        if moved[i] <= MOVED_MM:          # a first adjustment's doubt the last one does not bear out
            del moved[i]
        adj.pairs = [(k, i if j == -1 - i else j) for k, j in adj.pairs]
    return adj, moved, rms_unsplit


def _suspects(obs, size, adj: Adjusted, found: dict, origin: int, moved: dict) -> list:
    """[(id, first view after its move)] of the markers whose split is tried, at most
    ``MAX_SUSPECTS``: the surest of the flagged ones ``found`` ({id: (mm, chi2, first view after
    the move)}), then, surest first by their own views posed without them (``_cut_without``), the
    other flagged ones and the markers seen with the surest in its ``2 * MIN_VIEWS`` views on
    each side of its cut whose own views so posed split into poses over ``MOVED_MM`` and 5 sd
    apart (the origin and markers already split left out)."""
    flagged = sorted(found, key=lambda j: -found[j][1])
    f, cut = flagged[0], found[flagged[0]][2]
    seen = [k for k in sorted(adj.cams) if f in obs[k]]
    c = next((n for n, k in enumerate(seen) if k >= cut), len(seen))
    near = {j for k in seen[max(c - 2 * MIN_VIEWS, 0):c + 2 * MIN_VIEWS] for j in obs[k]}
    ranked = []
    for j in sorted((near | set(found)) - set(moved) - {origin, f}):
        views = [k for k in sorted(adj.cams) if j in obs[k]]
        if j < 0 or len(views) < 2 * MIN_VIEWS:
            continue
        first = found[j][2] if j in found else cut
        m = min(max(next((n for n, k in enumerate(views) if k >= first), len(views)), MIN_VIEWS),
                len(views) - MIN_VIEWS)
        n, dist, chi2 = _cut_without(obs, size, adj.markers, adj.cams, j, views, m)
        if j in found or (dist > MOVED_MM and chi2 > 25.0):
            ranked.append((chi2, j, first if j in found else views[n]))
    ranked.sort(reverse=True)
    log.debug("moved marker: suspects beside %d: %s", f, [(j, round(x)) for x, j, _ in ranked])
    return [(f, cut)] + [(j, k) for _, j, k in ranked][:MAX_SUSPECTS - 1]


def _split(obs, size, adj: Adjusted, i: int, cut: int) -> tuple[list, dict, dict]:
    """Marker ``i`` made two at view ``cut``: (the observations with its views from ``cut`` on
    seeing marker ``-1 - i``, the sizes, the markers to start the next adjustment from: both
    halves fitted to their views as ``adj`` posed them)."""
    after = [k for k in sorted(adj.cams) if k >= cut and i in obs[k]]
    before = [k for k in sorted(adj.cams) if k < cut and i in obs[k]]
    obs = list(obs)
    for k in after:
        obs[k] = {(-1 - j if j == i else j): c for j, c in obs[k].items()}
    size = {**size, -1 - i: size[i]}
    markers = dict(adj.markers)
    markers[i] = fit_marker(obs, size[i], i, adj.markers[i], adj.cams, before)[0] if before else adj.markers[i]
    markers[-1 - i] = fit_marker(obs, size[i], -1 - i, adj.markers[i], adj.cams, after)[0]
    return obs, size, markers


def residual_rms(r) -> float:
    """RMS of residuals ``r`` (pixels), NaN for none."""
    return float(np.sqrt(np.mean(np.square(r)))) if len(r) else float("nan")


def _moved(obs, size, markers, cams, tick=None) -> dict:
    """{marker id: (mm, chi2, first view after the move)} of the markers that moved during the
    survey: split its views (in view order) where two poses fit them best (views fixed), those
    two poses' positions are more than ``MOVED_MM`` and 5 sd apart (chi2: the squared
    Mahalanobis distance between them). ``tick()``: called as each marker is checked."""
    out = {}
    order = sorted(cams)
    for i in markers:
        if tick is not None:
            tick()
        seen = [k for k in order if i in obs[k]]
        if len(seen) < 2 * MIN_VIEWS:
            continue
        fit: dict = {}

        def cost(m, i=i, seen=seen, fit=fit):
            if m not in fit:
                fit[m] = [fit_marker(obs, size[i], i, markers[i], cams, part) for part in (seen[:m], seen[m:])]
            return fit[m][0][2] + fit[m][1][2]
        cuts = range(MIN_VIEWS, len(seen) - MIN_VIEWS + 1)
        step = max(len(cuts) // 10, 1)
        m = min(cuts[::step], key=cost)
        m = min(range(max(m - step, cuts[0]), min(m + step, cuts[-1]) + 1), key=cost)
        (Ta, Ca, _), (Tb, Cb, _) = fit[m]
        d = Ta[:3, 3] - Tb[:3, 3]
        dist, chi2 = float(np.linalg.norm(d)), float(d @ np.linalg.solve(Ca + Cb + 1e-9 * np.eye(3), d))
        if dist > MOVED_MM and chi2 > 25.0:
            out[i] = (dist, chi2, seen[_cut_without(obs, size, markers, cams, i, seen, m)[0]])
    return out


def _cut_without(obs, size, markers, cams, i, seen, m) -> tuple[int, float, float]:
    """Where a moved marker's views ``seen`` split, judged with each view posed by its other
    markers (views that see none keep their pose): the adjustment before the split posed the
    views after a move partly by the moved marker itself, so views next to the move side
    with it and the best cut with those poses can fall a few views early. Returns the cut's
    index into ``seen`` (``m``, the first guess, when no cut fits better), and how far apart
    the two halves' positions are there: mm, and chi2 (their squared Mahalanobis distance)."""
    own = {k: pose_view({j: c for j, c in obs[k].items() if j != i}, size, markers) for k in seen}
    own = {k: cams[k] if T is None else T for k, T in own.items()}
    fit = {}

    def cost(c):
        if c not in fit:
            fit[c] = [fit_marker(obs, size[i], i, markers[i], own, part) for part in (seen[:c], seen[c:])]
        return fit[c][0][2] + fit[c][1][2]
    c = min(range(MIN_VIEWS, len(seen) - MIN_VIEWS + 1), key=lambda c: (cost(c), c != m))
    (Ta, Ca, _), (Tb, Cb, _) = fit[c]
    d = Ta[:3, 3] - Tb[:3, 3]
    return c, float(np.linalg.norm(d)), float(d @ np.linalg.solve(Ca + Cb + 1e-9 * np.eye(3), d))


def fit_marker(obs, side, i, T0, cams, keys):
    """A marker's pose fitted to its corners in views ``keys`` (views fixed), from ``T0``:
    (T_world_from_marker, its position's covariance (3, 3), mm^2, the sum of squared
    residuals, normalised)."""
    R = np.array([cams[k][:3, :3] for k in keys])
    t = np.array([cams[k][:3, 3] for k in keys])
    seen = np.array([obs[k][i] for k in keys])

    def res(x):
        return (project(R, t, marker_corners_world(side, transform_from_rvec_tvec(x[:3], x[3:])))[0] - seen).ravel()
    fit = least_squares(res, pack_pose(T0), method="lm")
    J = fit.jac
    s2 = float(np.sum(fit.fun ** 2)) / max(len(fit.fun) - 6, 1)
    C = np.linalg.pinv(J.T @ J) * s2
    return transform_from_rvec_tvec(fit.x[:3], fit.x[3:]), C[3:, 3:], float(np.sum(fit.fun ** 2))
