"""Bundle adjustment for maps of few objects seen in many views (``tracking.mapbuild``): each
observation's residuals depend on one view's 6 parameters and one object's 6 (or none: an object
that fixes the world). Levenberg-Marquardt on the Huber-weighted normal equations with the views
eliminated by the Schur complement, so each step solves a dense system of the objects alone
(6 x 23 unknowns for a 24-marker room however many views). Optionally a few parameters shared by
every observation (a camera's intrinsics, ``tracking.mapintrinsics``) are adjusted too: they join
the objects' system (6 x 23 + 6 unknowns). The Jacobian is numerical, per parameter for all views
(or objects) at once: 12 residual evaluations a step, and one per shared parameter.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

log = logging.getLogger(__name__)


@dataclass
class BundleResult:
    """Attributes:
        views: (V, 6) adjusted view parameters. objects: (M, 6) adjusted object parameters.
        residuals: (N, R) at the solution (the residual function's units).
        information: (6M + P, 6M + P) the objects' and the shared parameters' information with
            the views marginalised (the Schur complement of the Huber-weighted ``J^T J``,
            undamped): its inverse times the residuals' mean square per degree of freedom is
            their covariance.
        iterations: steps taken. converged: the cost stopped falling before ``max_iter``.
        shared: (P,) the adjusted shared parameters (empty when there were none).
    """

    views: np.ndarray
    objects: np.ndarray
    residuals: np.ndarray
    information: np.ndarray
    iterations: int
    converged: bool
    shared: np.ndarray = field(default_factory=lambda: np.zeros(0))


def _huber_weights(r, k: float) -> np.ndarray:
    a = np.abs(r)
    return np.where(a <= k, 1.0, k / np.maximum(a, 1e-300))


def huber_cost(r, k: float) -> float:
    """Huber's cost of residuals ``r`` with threshold ``k`` (the adjustment's robust loss)."""
    a = np.abs(r)
    return float(np.sum(np.where(a <= k, 0.5 * a * a, k * a - 0.5 * k * k)))


_NormalEquations = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
"""``_normal_equations``' blocks: Hvv, B, Hoo, gv, go."""


def _jacobians(fun, views, objs, shared, r0,
               eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N, R, 6) d residuals / d its view's parameters, (N, R, 6) / its object's (zeros for a
    fixed object) and (N, R, P) / the shared parameters, forward differences, each parameter
    moved in every view (object) at once."""
    Jv = np.empty(r0.shape + (6,))
    Jo = np.zeros(r0.shape + (6,))
    Js = np.empty(r0.shape + (len(shared),))
    for j in range(6):
        v = views.copy()
        v[:, j] += eps
        Jv[..., j] = (fun(v, objs, shared) - r0) / eps
        if len(objs):
            o = objs.copy()
            o[:, j] += eps
            Jo[..., j] = (fun(views, o, shared) - r0) / eps
    for j in range(len(shared)):
        g = shared.copy()
        g[j] += eps
        Js[..., j] = (fun(views, objs, g) - r0) / eps
    return Jv, Jo, Js


def _normal_equations(Jv, Jo, Js, r, w, view_of, obj_of, V: int, M: int) -> _NormalEquations:
    """The weighted normal equations' blocks, the shared parameters (P) counted with the objects:
    Hvv (V, 6, 6), B (V, 6, 6M + P), Hoo (6M + P, 6M + P), gv (V, 6), go (6M + P,)."""
    WJv, WJo, WJs = Jv * w[..., None], Jo * w[..., None], Js * w[..., None]
    Hvv = np.zeros((V, 6, 6))
    np.add.at(Hvv, view_of, np.einsum("nri,nrj->nij", WJv, Jv))
    gv = np.zeros((V, 6))
    np.add.at(gv, view_of, np.einsum("nri,nr->ni", WJv, r))
    Hvo = np.zeros((V, M, 6, 6))
    Hoo = np.zeros((M, 6, 6))
    go = np.zeros((M, 6))
    m = obj_of >= 0
    np.add.at(Hvo, (view_of[m], obj_of[m]), np.einsum("nri,nrj->nij", WJv[m], Jo[m]))
    np.add.at(Hoo, obj_of[m], np.einsum("nri,nrj->nij", WJo[m], Jo[m]))
    np.add.at(go, obj_of[m], np.einsum("nri,nr->ni", WJo[m], r[m]))
    P = Js.shape[-1]
    Hvs = np.zeros((V, 6, P))
    np.add.at(Hvs, view_of, np.einsum("nri,nrj->nij", WJv, Js))
    Hos = np.zeros((M, 6, P))
    np.add.at(Hos, obj_of[m], np.einsum("nri,nrj->nij", WJo[m], Js[m]))
    H = np.zeros((6 * M + P, 6 * M + P))
    for k in range(M):
        H[6 * k:6 * k + 6, 6 * k:6 * k + 6] = Hoo[k]
    H[:6 * M, 6 * M:] = Hos.reshape(6 * M, P)
    H[6 * M:, :6 * M] = H[:6 * M, 6 * M:].T
    H[6 * M:, 6 * M:] = np.einsum("nri,nrj->ij", WJs, Js)
    B = np.concatenate([Hvo.transpose(0, 2, 1, 3).reshape(V, 6, 6 * M), Hvs], axis=2)
    g = np.concatenate([go.ravel(), np.einsum("nri,nr->i", WJs, r)])
    return Hvv, B, H, gv, g


def _schur(inv_vv, B, Hoo):
    """The objects' system with the views eliminated: S (6M + P, 6M + P) = Hoo - sum_v B_v^T
    inv_vv B_v, B (V, 6, 6M + P) the view-object (and view-shared) blocks side by side."""
    IB = inv_vv @ B                                    # (V, 6, 6M + P); then one product, not a 3-operand einsum
    return Hoo - np.tensordot(B, IB, axes=([0, 1], [0, 1]))


def _schur_step(Hvv, B, Hoo, gv, go, lam: float) -> tuple[np.ndarray, np.ndarray]:
    """The damped step (dv (V, 6), do (6M + P,)): Marquardt's damping of each diagonal."""
    inv = np.linalg.inv(Hvv + lam * np.eye(6)[None] * np.maximum(np.einsum("vii->vi", Hvv), 1e-12)[:, :, None])
    S = _schur(inv, B, Hoo)
    diag = np.maximum(np.diag(Hoo), 1e-12)
    rhs = go - np.einsum("vai,vab,vb->i", B, inv, gv)
    do = np.linalg.solve(S + lam * np.diag(diag), -rhs) if len(go) else np.zeros(0)
    dv = -np.einsum("vab,vb->va", inv, gv + np.einsum("vai,i->va", B, do))
    return dv, do


def bundle_adjust(fun, views, objs, view_of, obj_of, huber: float, max_iter: int = 100,
                  progress=None, shared=None) -> BundleResult:
    """Minimise the Huber cost of ``fun(views (V, 6), objects (M, 6)) -> (N, R)`` residuals, where
    observation n depends on view ``view_of[n]`` and object ``obj_of[n]`` (-1: a fixed one).
    With ``shared`` (P,), parameters every observation depends on, adjusted too from there: the
    residuals are then ``fun(views, objects, shared)``.

    Stops when a step lowers the cost by less than 1e-10 of it, or after ``max_iter`` steps;
    ``progress(steps taken, max_iter)`` is called after each."""
    views, objs = np.array(views, float), np.array(objs, float).reshape(-1, 6)
    common = np.zeros(0) if shared is None else np.array(shared, float).ravel()
    residuals_of = (lambda v, o, _: fun(v, o)) if shared is None else fun
    V, M = len(views), len(objs)
    res = residuals_of(views, objs, common)
    cost, lam, converged, it = huber_cost(res, huber), 1e-3, False, 0
    while it < max_iter:
        it += 1
        weights = _huber_weights(res, huber)
        blocks = _normal_equations(*_jacobians(residuals_of, views, objs, common, res), res, weights, view_of, obj_of,
                                   V, M)
        while True:
            dv, do = _schur_step(*blocks, lam)
            nv, no, ng = views + dv, objs + do[:6 * M].reshape(M, 6), common + do[6 * M:]
            nr = residuals_of(nv, no, ng)
            ncost = huber_cost(nr, huber) if np.all(np.isfinite(nr)) else np.inf
            if ncost <= cost:
                break
            lam *= 10.0
            if lam > 1e8:
                break
        if not ncost <= cost:
            converged = True                     # no step lowers the cost: at the minimum
            break
        small = cost - ncost <= 1e-10 * cost
        views, objs, common, res, cost, lam = nv, no, ng, nr, ncost, max(lam / 10.0, 1e-9)
        if progress is not None:
            progress(it, max_iter)
        if small:
            converged = True
            break
    weights = _huber_weights(res, huber)
    Hvv, B, Hoo, _, _ = _normal_equations(*_jacobians(residuals_of, views, objs, common, res), res, weights, view_of,
                                          obj_of, V, M)
    S = _schur(np.linalg.pinv(Hvv), B, Hoo)
    log.debug("bundle adjustment: %d steps, cost %.4g, converged %s", it, cost, converged)
    return BundleResult(views, objs, res, S, it, converged, common)
