"""The per-eye bias of a session's error model (``estimator.errormodel.ErrorModel.bias_deg``),
sized from the data: docs/processing.md, "The error model".

Where the bias comes from, in order:

1. the prior, what is known before the session's lines are looked at:
   - a session calibrated here: the eye calibration's leave-one-out residuals (eyes.json,
     ``estimator.errormodel.bias_from_calibration``);
   - an imported session: its device kind's published accuracy (``DEVICE_PRIORS``, each with its
     source; per wearer calibrated, a general model, or a kappa offset taken at a distance);
   - neither: ``estimator.errormodel.DEFAULT_BIAS_DEG`` (0.5 deg: the accuracy head-worn trackers
     reach after a calibration), and the record says it is no measurement;
2. the bias the session's own lines show (``estimator.slippage.seen_bias``: how each eye's
   residuals over a fixation sit off its point beyond their noise): the glasses' slippage after
   the calibration, and whatever the prior missed.

The bias is ``sqrt(prior^2 + slip^2)`` with ``slip^2 = max(0, seen^2 - prior^2)``: the lines' bias
beyond the prior's (they see the calibration's own error too, which must not count twice), so the
larger of the two. Per eye and axis, degrees.

The slip rests on the combinations of the eyes' angles the lines fix (``SeenBias.seen``, mostly
two: the eyes' differences); the eyes' common turn, which moves a point sideways and which no
point's lines show, is taken alike. A size drawn from two numbers is known to two degrees of
freedom: the error model carries them (``ErrorModel.slip_dof``) and the regions are Student's
(``estimator.errormodel_regions``). On the 0.5 deg sessions of benchmarks/coverage.py the targets
outside their 95 % regions were those of sessions whose eyes' differences happened to be small
and their common turn large (the lines showed 0.14-0.25 deg, the common turn was 0.57-0.75 deg).

An assumption that fixes a depth (``depth_assumption``) is named next to each target: a Neon
import's kappa offset taken where the 2D gaze ray is at a fixed depth, or a still head (no
parallax). Its uncertainty is in the bias prior of that kind, so the depth interval carries it.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass, replace
from pathlib import Path

from estimator.errormodel import DEFAULT_BIAS_DEG, ErrorModel, bias_from_calibration
from estimator.merge import MERGE_POSE_DEG
from estimator.slippage import SeenBias

log = logging.getLogger(__name__)

MEAN_TO_AXIS = math.sqrt(2.0 / math.pi)
"""A published accuracy is a mean angular offset; for a 2D Gaussian offset of std ``s`` per axis
the mean size is ``s sqrt(pi / 2)``: per axis std = accuracy x this (0.80)."""

TRACKED_POSITION_MM = 3.0
"""Per axis std of the head position's error over one fixation when the poses are tracked in the
scene video, mm (``ErrorModel.pose_position_mm``): on 8 simulated walking and swaying sessions
(benchmarks/coverage.py, 640x360 video, 6 markers a wall) the tracked head positions were off the
true ones by a per-axis RMS of 2.4-8.9 mm per session (median 4.5, most of it along the walk or
sway); part of a frame's error averages out over a fixation. On the small-bias sessions of
benchmarks/coverage.py (``ml`` on each true target's fixations) the 95 % regions held 85 % of the
targets without it, the misses near ones (about 1 m) off sideways; with 3 mm, 97 %. Sizing it from
the tracking's own residuals is left to do."""


@dataclass(frozen=True)
class BiasPrior:
    """What is known of a session's per-eye bias before its lines are looked at.

    Attributes:
        deg: per eye and axis std, degrees.
        basis: 'calibration' (leave-one-out here), 'per-wearer calibrated', 'general model',
            'kappa at a distance' (the device's) or 'conservative' (no figure).
        source: where the figure comes from (a citation, or why there is none).
        published: the figure is a published one (False: a documented conservative value).
    """

    deg: float
    basis: str
    source: str
    published: bool


def _accuracy(mean_deg: float, basis: str, source: str, published: bool = True) -> BiasPrior:
    return BiasPrior(round(mean_deg * MEAN_TO_AXIS, 4), basis, source, published)


DEVICE_PRIORS = {
    ("tobii-g2", None): _accuracy(
        0.5, "per-wearer calibrated",
        "Tobii Pro Glasses 2 product description, technical specifications: gaze accuracy 0.5 deg (ideal "
        "conditions); as cited, not re-read (no public copy of its specification text was found)"),
    ("tobii-g3", None): _accuracy(
        0.6, "per-wearer calibrated",
        "Tobii Pro Glasses 3 product description, technical specifications: gaze accuracy 0.6 deg (ideal "
        "conditions); as cited, not re-read (no public copy of its specification text was found)"),
    ("pupil-core", None): _accuracy(
        1.5, "per-wearer calibrated",
        "Kassner, Patera & Bulling 2014, Pupil (UbiComp adjunct): 0.6 deg accuracy (0.08 deg precision) for "
        "the 2D pipeline in the lab; Pupil Labs' Core best practices: the 2D pipeline under 1 deg in ideal "
        "conditions, the 3D pipeline (the importer reads it) slightly less accurate, no figure given; "
        "1.5 deg taken (a conservative value)",
        published=False),
    ("pupil-neon", "kappa at a distance"): _accuracy(
        1.8, "kappa at a distance",
        "Baumann & Dierkes 2023, Neon accuracy test report (Pupil Labs, doi:10.5281/zenodo.10420388): mean "
        "gaze accuracy 1.8 deg without offset correction (as cited, not re-read); the per-eye axes here add "
        "the kappa offset fitted at a fixed depth"),
    ("pupil-neon", None): _accuracy(
        1.8, "general model",
        "Baumann & Dierkes 2023, Neon accuracy test report (Pupil Labs, doi:10.5281/zenodo.10420388): mean "
        "gaze accuracy 1.8 deg without offset correction (as cited, not re-read)"),
    ("pupil-cloud", None): _accuracy(
        1.8, "general model",
        "Baumann & Dierkes 2023, Neon accuracy test report (doi:10.5281/zenodo.10420388): 1.8 deg without "
        "offset correction, as cited (Pupil Cloud exports Neon's gaze; an Invisible recording's is no better: "
        "Tonsen, Baumann & Dierkes 2020, arXiv:2009.00508)"),
    ("aria-mps", "general model"): BiasPrior(
        2.0, "general model",
        "no published per-eye accuracy of Aria's general eye-gaze model was found; 2.0 deg per axis is a "
        "conservative value (the MPS sample's per-eye rays read about 2.7 deg too divergent, docs/estimators.md)",
        False),
    ("aria-mps", None): BiasPrior(
        1.0, "per-wearer calibrated",
        "no published accuracy of Aria's personalized eye-gaze model was found; 1.0 deg per axis is a "
        "conservative value", False),
}
"""(device, variant) -> prior; variant None is the device's default (``device_prior``). Checked
against the public text that could be searched (issue 27): Kassner et al. 2014's 0.6 deg and Pupil
Labs' Core best practices (2D under 1 deg, 3D less accurate) read as cited; the Neon accuracy test
report exists as cited (Baumann & Dierkes 2023, Zenodo), its 1.8 deg figure not re-read; no public
copy of the Tobii Pro Glasses 2/3 specifications was found (0.5 and 0.6 deg as cited, not re-read);
Project Aria publishes no eye-gaze accuracy (its MPS eye-gaze pages give formats, not errors), so
its two values are conservative ones and say so."""
DEVICE_PRIORS[("aria-gen2", "general model")] = DEVICE_PRIORS[("aria-mps", "general model")]
DEVICE_PRIORS[("aria-gen2", None)] = DEVICE_PRIORS[("aria-mps", None)]


def device_prior(report: dict | None) -> BiasPrior:
    """The bias prior of an imported session from its import report (``import_report.json``):
    its device's entry in ``DEVICE_PRIORS``, the variant read from the report (a kappa offset
    fitted at a depth; Aria's general model); ``DEFAULT_BIAS_DEG`` for a device without one."""
    report = report or {}
    device = str(report.get("device", ""))
    variant = None
    if (report.get("kappa") or {}).get("depth_mm"):
        variant = "kappa at a distance"
    elif any("general model" in str(n) for n in report.get("notes", [])):
        variant = "general model"
    prior = DEVICE_PRIORS.get((device, variant)) or DEVICE_PRIORS.get((device, None))
    if prior is None:
        return BiasPrior(DEFAULT_BIAS_DEG, "conservative",
                         f"no accuracy figure for device {device or 'unknown'!r}: a conservative value "
                         "(estimator bias after a calibration, 0.5-1 deg)", False)
    return prior


def calibration_prior(eyes_path: Path) -> BiasPrior:
    """The bias prior of a session calibrated here: ``bias_from_calibration`` of each eye's
    leave-one-out RMS error in eyes.json; ``DEFAULT_BIAS_DEG`` when it has none (no warning when
    there is no eyes.json: the eye step failed and said so, and no target will use it)."""
    if not Path(eyes_path).is_file():
        return BiasPrior(DEFAULT_BIAS_DEG, "conservative", "no eye calibration", False)
    try:
        eyes = json.loads(Path(eyes_path).read_text(encoding="utf-8"))["eyes"]
        loo = [e.get("report", {}).get("loo_rms_deg") for e in eyes]
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        log.warning("%s: no leave-one-out errors (%s); a conservative eye bias", eyes_path, exc)
        loo = []
    if not any(v is not None and math.isfinite(v) for v in loo):
        return BiasPrior(DEFAULT_BIAS_DEG, "conservative", "the eye calibration has no leave-one-out errors",
                         False)
    rms = [None if v is None else round(v, 3) for v in loo]
    return BiasPrior(round(bias_from_calibration(loo), 4), "calibration",
                     f"the eye calibration's leave-one-out RMS errors {rms} deg", True)


def session_bias(prior: BiasPrior, seen: SeenBias | None) -> dict:
    """The session's bias record: ``bias_deg`` (per eye and axis, degrees: the larger of the
    prior and what the lines showed, module docstring), ``slip_deg`` (the lines' part beyond the
    prior), the prior's ``prior_deg``, ``basis``, ``source`` and ``published``, and ``seen`` (the
    lines' ``SeenBias.record``, or None)."""
    seen_deg = seen.deg if seen is not None and seen.groups else 0.0
    slip = math.sqrt(max(seen_deg**2 - prior.deg**2, 0.0))
    return {"bias_deg": round(math.hypot(prior.deg, slip), 4), "slip_deg": round(slip, 4), "prior_deg": prior.deg,
            "basis": prior.basis, "source": prior.source, "published": prior.published,
            "seen": None if seen is None else seen.record()}


def session_prior(imported: bool, eyes_path: Path, import_report: dict | None = None) -> BiasPrior:
    """``device_prior`` of an ``imported`` session's ``import_report``, else ``calibration_prior``
    of ``eyes_path``."""
    return device_prior(import_report) if imported else calibration_prior(eyes_path)


def pose_model(tracked: bool) -> ErrorModel:
    """The error model's head-pose terms, before its bias: head poses ``tracked`` in the scene
    video have the merge test's per-fixation angular offset (``estimator.merge.MERGE_POSE_DEG``)
    and a per-fixation position error (``TRACKED_POSITION_MM``); a device's own poses (SLAM) or a
    still head neither."""
    return ErrorModel(pose_offset_deg=MERGE_POSE_DEG if tracked else 0.0,
                      pose_position_mm=TRACKED_POSITION_MM if tracked else 0.0)


def session_error_model(imported: bool, eyes_path: Path, tracked: bool = True, seen: SeenBias | None = None,
                        import_report: dict | None = None) -> ErrorModel:
    """The error model of the targets' covariances and merges: its bias is ``session_bias`` of
    the session's prior (``session_prior``) and the bias ``seen`` in its lines (None: the prior
    alone), the lines' part of it with its degrees of freedom (``slip_deg``, ``slip_dof``: the
    combinations of the eyes' angles it rests on), its head-pose terms ``pose_model(tracked)``."""
    return with_bias(pose_model(tracked), session_bias(session_prior(imported, eyes_path, import_report), seen))


def with_bias(base: ErrorModel, record: dict) -> ErrorModel:
    """``base`` with the bias of ``session_bias``'s ``record``: its ``bias_deg``, and its
    ``slip_deg`` with the degrees of freedom it rests on (``ErrorModel.slip_dof``: the
    combinations of the eyes' angles the lines fixed, ``SeenBias.seen``; ``inf`` without a slip)."""
    slip = min(float(record["slip_deg"]), float(record["bias_deg"]))
    seen = (record.get("seen") or {}).get("seen")
    dof = float(seen) if slip > 0 and seen else math.inf
    return replace(base, bias_deg=record["bias_deg"], slip_deg=slip, slip_dof=dof)


def depth_assumption(report: dict | None, pose_source: str | None) -> str | None:
    """The assumption that fixes the targets' depths, in words (None: none): a kappa offset fitted
    where the device's 2D gaze ray is at a fixed depth (the depths near it follow from it), a
    still head (depth from vergence alone, no parallax)."""
    parts = []
    depth = ((report or {}).get("kappa") or {}).get("depth_mm")
    if depth:
        parts.append(f"kappa offset taken at {float(depth) / 1000:g} m (the device's 2D gaze ray): depths near it "
                     "follow from that assumption")
    if pose_source == "still_head":
        parts.append("head taken as still (no head poses): depth from vergence alone")
    return "; ".join(parts) or None


def bias_note(record: dict) -> str:
    """The report's sentence on the bias (``session_bias``'s record): its size, its prior and the
    prior's source (saying so when it is a conservative value, not a published or measured one),
    and what the session's lines showed."""
    seen = record.get("seen") or {}
    prior = (f"prior {record['prior_deg']:.2f} deg ({record['basis']}: {record['source']}"
             + ("" if record["published"] else "; a conservative value, not a published or measured figure") + ")")
    lines = (f"the session's lines showed {seen['deg']:.2f} deg (standard error {seen['se_deg']:.2f}, "
             f"{seen['groups']} fixations, {seen['left_out']} left out)" if seen.get("se_deg") is not None else
             "the session's lines had no fixation to show it")
    return (f"Error model: a per-eye bias of {record['bias_deg']:.2f} deg per axis: {prior}; {lines}"
            + (f", {record['slip_deg']:.2f} deg beyond the prior (slippage)." if record.get("slip_deg") else "."))


def targets_bias_note(targets_json: Path) -> list[str]:
    """``bias_note`` of a targets.json's ``error_model`` ([] when it has none)."""
    try:
        record = json.loads(Path(targets_json).read_text(encoding="utf-8"))["error_model"]
        return [bias_note(record)]
    except (OSError, ValueError, KeyError, TypeError):
        return []
