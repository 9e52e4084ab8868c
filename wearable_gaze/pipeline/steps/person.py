"""``wearable-gaze learn-bias``: a person's per-eye gaze bias learned from a validation session
(targets at known places fixated at known times), applied to that person's later sessions by
``process --person`` and ``viewlines --person`` (docs/calibration.md, "Per-person bias").

Learning. For every eye sample inside a validation target's fixation (its first ``settle_s``
left out: the eye is still landing), the sample's head-frame view line (calibrated with the
session's eyes.json, or an imported session's eye rays), and the known target brought into the
head frame by the head pose at that sample (the processed session's poses.csv). The per-eye
correction is ``calibration.kappa.fit_kappa_targets`` over those pairs: the median Fick-angle
difference between the direction eye -> target and the measured direction.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from calibration.kappa import angular_errors_deg, apply_kappa, fit_kappa_targets
from tracking.timeline import MAX_POSE_GAP_S, interpolate_poses

from ...errors import UserError, check_output
from ...formats.eye_rays import read_eye_rays
from ...formats.eye_samples import read_eye_csv
from ...formats.eyes import load_eyes
from ...formats.person import read_validation, write_person
from ...formats.poses import read_poses_csv
from ...formats.session import load_session
from .calibrate import head_view_lines

log = logging.getLogger(__name__)

SETTLE_S = 0.1          # left out at the start of each fixation interval: the eye is still landing


def _head_samples(s, processed: Path, eyes):
    """The session's eye samples as head-frame view lines: an imported session's eye rays, or
    the raw samples calibrated with ``eyes`` (default: PROCESSED/eyes.json, or the eyes a live
    recording carries)."""
    rays = s.path("eye_rays")
    if rays is not None:
        return read_eye_rays(rays)
    samples = s.path("eye_samples")
    if samples is None:
        raise UserError(f"{s.root}: the session has no eye samples or eye rays; a validation needs a recording")
    if eyes is None:
        files = s.manifest["files"]
        eyes = s.root / files["eyes"] if "eyes" in files and "eye_calibration" not in files else processed / "eyes.json"
        if not Path(eyes).is_file():
            raise UserError(f"{eyes}: no eye calibration; run 'wearable-gaze process {s.root}' first, or pass --eyes "
                            "eyes.json")
    return head_view_lines(read_eye_csv(samples)[0], load_eyes(eyes))


def validation_pairs(head, poses_t, T_world_from_cam, targets, settle_s: float = SETTLE_S):
    """The samples inside the targets' fixations, with each target in the head frame.

    Args:
        head: ``BinocularSamples`` in the head frame.
        poses_t, T_world_from_cam: (M,) s and (M, 4, 4) head poses.
        targets: ``read_validation`` dicts (world frame, mm; intervals in s).

    Returns:
        (idx (K,) sample indices, points (K, 3) targets in the head frame, mm, target (K,) index).
    """
    idx_parts, tgt_parts = [], []
    for k, tg in enumerate(targets):
        for a, b in tg["fixations_s"]:
            sel = np.flatnonzero((head.t_s >= a + settle_s) & (head.t_s <= b))
            idx_parts.append(sel)
            tgt_parts.append(np.full(len(sel), k))
    idx, tgt = np.concatenate(idx_parts), np.concatenate(tgt_parts)
    if not len(idx):
        return idx, np.zeros((0, 3)), tgt
    T_wc, ok = interpolate_poses(poses_t, T_world_from_cam, head.t_s[idx], MAX_POSE_GAP_S)
    idx, tgt, T_wc = idx[ok], tgt[ok], T_wc[ok]
    pos = np.array([t["position_mm"] for t in targets], float)
    R, p = T_wc[:, :3, :3], T_wc[:, :3, 3]
    pts = np.einsum("nji,nj->ni", R, pos[tgt] - p)      # R^T (x - p): world -> head, per sample
    return idx, pts, tgt


def learn_bias(session, validation, processed=None, eyes=None, settle_s: float = SETTLE_S) -> dict:
    """The per-eye correction of the person recorded in ``session`` from its validation targets.

    Args:
        session: the validation session's folder (processed: its poses.csv exists).
        validation: validation.json, or a simulator's truth/targets.json.
        processed: the folder ``process`` wrote (default SESSION/processed).
        eyes: eyes.json to calibrate the raw samples with (default: PROCESSED/eyes.json).
        settle_s: left out at the start of each fixation, s.

    Returns:
        the person.json dict (``write_person``): per eye ``correction_deg`` (h, v), ``spread_deg``,
        ``samples``, ``targets``, ``rms_before_deg``, ``rms_after_deg``.

    Raises:
        UserError: unreadable inputs, too few samples inside the fixations.
    """
    s = load_session(session)
    processed = Path(processed) if processed is not None else s.root / "processed"
    targets = read_validation(validation)
    poses_csv = processed / "poses.csv"
    if not poses_csv.is_file():
        raise UserError(f"{poses_csv}: no head poses; run 'wearable-gaze process {s.root}' first (or pass "
                        "--processed DIR, the folder it wrote)")
    t, _, T, _ = read_poses_csv(poses_csv)
    head = _head_samples(s, processed, eyes)
    idx, pts, tgt = validation_pairs(head, t, T, targets, settle_s)
    eyes_lr = ((head.left_origin_mm[idx], head.left_direction[idx]), (head.right_origin_mm[idx],
                                                                      head.right_direction[idx]))
    try:
        fit = fit_kappa_targets(*eyes_lr[0], *eyes_lr[1], pts)
    except ValueError as exc:
        raise UserError(f"{validation}: too few eye samples with a head pose inside the targets' fixations "
                        f"({exc}); check that the validation's times are on the session's clock") from None
    out = []
    for name, (c, d), k in zip(("left", "right"), eyes_lr, (fit.left, fit.right), strict=True):
        before = angular_errors_deg(c, d, pts)
        after = angular_errors_deg(c, apply_kappa(d, k.kappa_deg), pts)
        ok = np.isfinite(before)
        out.append({"eye": name, "correction_deg": [round(float(v), 4) for v in k.kappa_deg],
                    "spread_deg": [round(float(v), 4) for v in k.spread_deg], "samples": k.n,
                    "targets": int(len(np.unique(tgt[ok]))),
                    "rms_before_deg": round(float(np.sqrt(np.mean(before[ok] ** 2))), 4),
                    "rms_after_deg": round(float(np.sqrt(np.mean(after[ok] ** 2))), 4)})
        log.info("%s eye: correction (%.3f, %.3f) deg from %d samples; RMS %.3f -> %.3f deg", name,
                 *k.kappa_deg, k.n, out[-1]["rms_before_deg"], out[-1]["rms_after_deg"])
    return {"session": str(s.root), "validation": str(validation), "eyes": out}


def learn_bias_file(session, validation, out, processed=None, eyes=None) -> dict:
    """``learn_bias`` written to ``out`` (person.json); returns the dict written.

    Raises:
        UserError: ``out`` is one of the files read, the defaulted ones too (PROCESSED/poses.csv,
            PROCESSED/eyes.json, the session's files), before any work.
    """
    s = load_session(session)
    done = Path(processed) if processed is not None else s.root / "processed"
    check_output(out, [done / "poses.csv", done / "eyes.json", eyes, validation,
                       *(s.root / rel for rel in s.manifest["files"].values())], "-o")
    person = learn_bias(session, validation, processed, eyes)
    write_person(out, person)
    return person


def format_person(person: dict) -> str:
    """The table ``learn-bias`` prints."""
    lines = [f"{'eye':<6} {'correction h, v (deg)':>22} {'samples':>8} {'targets':>8} {'RMS before':>11} "
             f"{'RMS after':>10}"]
    for e in person["eyes"]:
        h, v = e["correction_deg"]
        lines.append(f"{e['eye']:<6} {h:>+10.3f} {v:>+10.3f} {e['samples']:>9} {e['targets']:>8} "
                     f"{e['rms_before_deg']:>9.3f} d {e['rms_after_deg']:>8.3f} d")
    return "\n".join(lines)
