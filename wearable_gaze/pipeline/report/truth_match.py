"""Estimates paired with a simulated session's true targets (``truth/targets.json``): the one
matching the demo, the report, ``batch``'s report, the tests and the benchmarks use; and the truth
moved into the world of the map a run used (``TruthFrame``: a built, surveyed or markerless map
has a world of its own), before any comparison."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimator.frames import similarity_transform


def match_positions(positions, truth: list, ids=None) -> list:
    """Pairs (truth entry, index into ``positions`` or None): each true fixed target (a truth
    entry with ``position_mm``) with the nearest estimate (M, 3) within 30 % of its distance
    + 100 mm; each id of ``ids`` (M,) (default: each estimate) used once."""
    P = np.asarray(positions, float).reshape(-1, 3)
    ids = list(range(len(P))) if ids is None else list(ids)
    pairs: list[tuple[dict, int | None]] = []
    used = set()
    for tt in truth:
        if "position_mm" not in tt:
            continue
        X = np.asarray(tt["position_mm"])
        best = None
        for k, p in enumerate(P):
            if ids[k] in used or not np.isfinite(p[0]):
                continue
            d = np.linalg.norm(p - X)
            if best is None or d < best[0]:
                best = (d, k)
        if best is not None and best[0] < 0.3 * np.linalg.norm(X) + 100:
            used.add(ids[best[1]])
            pairs.append((tt, best[1]))
        else:
            pairs.append((tt, None))
    return pairs


def match_targets(found: list, truth: list) -> list:
    """``match_positions`` for target records (targets.json, summary.json, live target messages:
    ``target``, ``position_mm``, null for none): pairs (truth entry, record or None)."""
    pairs = match_positions([f["position_mm"] or [np.nan] * 3 for f in found], truth, [f["target"] for f in found])
    return [(tt, None if k is None else found[k]) for tt, k in pairs]


# --- the truth in the frame of the map a run used ------------------------------------------------

MAP_NAMES = {"session": "the session's marker map", "given": "the marker map given (--markers)",
             "built": "the map built from the video (--build-map)", "markerless": "the markerless map (--map)"}
"""What each kind of map a run used is called in the report's note."""


@dataclass(frozen=True)
class TruthFrame:
    """A simulated session's truth (in the frame of its true marker map) moved into the world of
    the map a run used: a map built from the video, a surveyed one, or a markerless one, each with
    a world of its own (its origin marker's, its scale the printed sides'), so that the estimates
    and the truth are compared in one frame. No ``TruthFrame`` at all: the map used is the truth's.

    Attributes:
        map_kind: the map used: a key of ``MAP_NAMES``.
        T_map_from_truth: (4, 4) the similarity (scale times rotation, translation mm) fitted
            through the corners of the markers both maps share; None when they share none (then
            the truth cannot be compared: ``reason`` says why).
        rms_mm: the fit's RMS corner residual, mm (the used map's shape error, as the truth sees it).
        markers: the ids of the markers the fit used.
        reason: why there is no fit ('' with one).
    """

    map_kind: str
    T_map_from_truth: np.ndarray | None = None
    rms_mm: float = float("nan")
    markers: tuple = ()
    reason: str = ""

    def _similarity(self) -> np.ndarray:
        """``T_map_from_truth``, which the methods that move the truth need (a frame without a
        fit moves nothing: its callers check ``T_map_from_truth`` first)."""
        assert self.T_map_from_truth is not None
        return self.T_map_from_truth

    @property
    def scale(self) -> float:
        """The similarity's scale (the used map's millimetre over the truth's)."""
        return float(np.cbrt(np.linalg.det(self._similarity()[:3, :3])))

    def points(self, pts_truth) -> np.ndarray:
        """(N, 3) points of the truth's frame, mm, in the used map's world."""
        T = self._similarity()
        return np.asarray(pts_truth, float).reshape(-1, 3) @ T[:3, :3].T + T[:3, 3]

    def poses(self, T_truth_from_cam) -> np.ndarray:
        """(N, 4, 4) poses of the truth's frame (truth/head_poses.csv; NaN rows kept) in the used
        map's world: the positions moved by the similarity, the rotations turned by its rotation."""
        T, S = np.array(T_truth_from_cam, float).reshape(-1, 4, 4), self._similarity()
        T[:, :3, :3] = np.einsum("ij,njk->nik", S[:3, :3] / self.scale, T[:, :3, :3])
        T[:, :3, 3] = self.points(T[:, :3, 3])
        return T

    def targets(self, truth: list) -> list:
        """Truth target entries (truth/targets.json) with ``position_mm`` (3,) and ``path_mm``
        (K, 3) moved into the used map's world; the rest of each entry as it was."""
        out = []
        for tt in truth:
            moved = dict(tt)
            if "position_mm" in tt:
                moved["position_mm"] = self.points(tt["position_mm"])[0].tolist()
            if "path_mm" in tt:
                moved["path_mm"] = self.points(tt["path_mm"]).tolist()
            out.append(moved)
        return out

    def note(self) -> str:
        """The sentence the report (and whatever compares with the truth) says about it."""
        name = MAP_NAMES.get(self.map_kind, self.map_kind)
        if self.T_map_from_truth is None:
            return f"Simulated truth not compared: {name} has its own world, and {self.reason}."
        return (f"Simulated truth moved into the world of {name} by the similarity (Umeyama) through the corners of "
                f"the {len(self.markers)} marker(s) both maps share: scale {self.scale:.4f}, corners' RMS "
                f"{self.rms_mm:.1f} mm.")

    def record(self) -> dict:
        """The JSON object summary.json keeps (``from_record`` reads it back)."""
        d: dict = {"map": self.map_kind, "markers": [int(i) for i in self.markers],
                   "note": self.note()}
        if self.T_map_from_truth is not None:
            d.update(T_map_from_truth=np.round(self.T_map_from_truth, 9).tolist(), rms_mm=round(self.rms_mm, 3))
        return d

    @classmethod
    def from_record(cls, d: dict | None) -> TruthFrame | None:
        """A ``record``'s frame (None: no record, the truth's own map was used)."""
        if not d:
            return None
        T = d.get("T_map_from_truth")
        return cls(d["map"], None if T is None else np.asarray(T, float), float(d.get("rms_mm", "nan")),
                   tuple(d.get("markers", ())), "" if T is not None else d.get("note", ""))


def fit_truth_frame(truth_corners: dict, map_corners: dict, map_kind: str, exclude=()) -> TruthFrame | None:
    """The truth moved into a map's world (``TruthFrame``) by the similarity
    (``estimator.frames.similarity_transform``) through the corners of the markers both have:
    ``truth_corners`` and ``map_corners`` {id: (4, 3) corners, mm, each in its own world}; markers
    ``exclude`` (moved during the session) left out. None when every shared marker's corners
    agree within 1e-6 mm (the map used is the truth's: nothing to move)."""
    ids = sorted(set(truth_corners) & set(map_corners) - set(exclude))
    if not ids:
        return TruthFrame(map_kind, reason="it shares no marker with the simulated room")
    A = np.concatenate([np.asarray(truth_corners[i], float) for i in ids])
    B = np.concatenate([np.asarray(map_corners[i], float) for i in ids])
    if np.allclose(A, B, rtol=0.0, atol=1e-6):
        return None
    T = similarity_transform(A, B)
    rms = float(np.sqrt(np.mean(np.sum((A @ T[:3, :3].T + T[:3, 3] - B) ** 2, axis=1))))
    return TruthFrame(map_kind, T, rms, tuple(ids))
