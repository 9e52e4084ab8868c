"""``wearable-gaze process``: a recorded session in, fixated 3D targets out (docs/processing.md).

Steps, each skipped when its inputs and settings are unchanged since the last run (``force``
redoes them): camera calibration, eye calibration, head tracking, view lines, segmentation and
estimation, plots and report. A step that cannot run records why; the steps that do not depend
on it still run, and whatever was computed is kept. A failed step invalidates every step after
it: their outputs from an earlier run are removed, so no file in the output folder is ever an
older run's result presented as this one's.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from estimator import BinocularSamples, cramer_rao_bound, make_estimator, run_estimator
from estimator.segments import SegmentConfig, same_target, segment_fixations

from ..errors import UserError
from ..formats.atomic import atomic_path, remove_temporaries, write_text
from ..formats.camera import load_camera
from ..formats.eyes import load_eyes
from ..formats.jsonio import load_json, write_json
from ..formats.session import load_session
from ..formats.tables import write_table
from ..formats.viewlines import read_viewlines_csv, write_viewlines_csv
from .calibrate import calibrate_camera_files, calibrate_eyes_files, viewlines_files
from .report import REPORT_FILES
from .track import track_video

log = logging.getLogger(__name__)

STEPS = ("camera", "eyes", "tracking", "viewlines", "targets", "report")
# the files each step writes into the output folder ...
OUTPUTS = {
    "camera": ("camera.json", "camera_undistorted.png"),
    "eyes": ("eyes.json",),
    "tracking": ("poses.csv",),
    "viewlines": (".viewlines_unsegmented.csv", ".viewlines_counts.json"),
    "targets": ("viewlines.csv", "estimates.csv", "targets.csv", "targets.json", "target_labels.npy"),
    "report": REPORT_FILES,
}
# ... and the steps whose outputs it reads
NEEDS = {"camera": (), "eyes": ("camera",), "tracking": ("camera",), "viewlines": ("eyes", "tracking"),
         "targets": ("viewlines",), "report": ("targets",)}
OPTIONAL = ("overlay.webp", "overlay_error.txt")     # written or not: not needed to skip a step
OTHER_FILES = ("summary.json", ".steps.json")
GOOD = ("done", "cached", "external")          # a step's outputs (or the file given instead) are usable


@dataclass
class ProcessResult:
    """What ``process_session`` did.

    Attributes:
        out: the output folder.
        targets: the targets estimated in this run (rows of targets.json); empty when the
            targets step failed or could not run.
        problems: one line per problem, ``"step: what went wrong"``.
        skipped: steps whose outputs were up to date.
        timings: seconds per step run.
        summary: the contents of summary.json.
        status: per step: done, cached, external (a file given instead), failed, not_done (a step
            it needs failed), no_recording (a calibration-only session), or absent (not asked for).
        removed: outputs of an earlier run removed because this run invalidated them.
    """

    out: Path
    targets: list = field(default_factory=list)
    problems: list = field(default_factory=list)
    skipped: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    summary: dict = field(default_factory=dict)
    status: dict = field(default_factory=dict)
    removed: list = field(default_factory=list)

    @property
    def failed(self) -> list:
        return [s for s in STEPS if self.status.get(s) == "failed"]

    @property
    def not_done(self) -> list:
        return [s for s in STEPS if self.status.get(s) == "not_done"]

    @property
    def exit_status(self) -> int:
        """2 when no target could be estimated (docs/processing.md), else 0."""
        return 0 if self.targets else 2


def _fingerprint(paths, params) -> str:
    h = hashlib.sha1()
    for p in paths:
        p = Path(p)
        if p.is_dir():
            for q in sorted(p.rglob("*")):
                if q.is_file():
                    st = q.stat()
                    h.update(f"{q}:{st.st_size}:{st.st_mtime_ns}".encode())
        elif p.exists():
            st = p.stat()
            h.update(f"{p}:{st.st_size}:{st.st_mtime_ns}".encode())
        else:
            h.update(f"{p}:missing".encode())
    h.update(json.dumps(params, sort_keys=True, default=str).encode())
    return h.hexdigest()


class _Steps:
    """Runs steps with caching and problem recording, and keeps the output folder consistent:
    a step being redone has no outputs until it succeeds, and the outputs of a step that failed
    or could not run (or depends on one that did) are removed."""

    def __init__(self, out: Path, force: bool, result: ProcessResult, progress_factory, protect=()):
        self.out = out
        self.force = force
        self.result = result
        self.progress_factory = progress_factory
        self.protect = {Path(p).resolve() for p in protect}      # files given as inputs: never removed
        self.state_path = out / ".steps.json"
        self.status = result.status
        self.given = set()                                        # steps replaced by a file given
        self.current = None
        self.state = {} if force else self._load_state()

    def _load_state(self) -> dict:
        if not self.state_path.is_file():
            return {}
        try:
            state = json.loads(self.state_path.read_text(encoding="utf-8"))
            if not isinstance(state, dict) or not all(isinstance(v, str) for v in state.values()):
                raise ValueError("not a {step: fingerprint} object")
        except (ValueError, UnicodeDecodeError) as exc:            # JSONDecodeError is a ValueError
            log.warning("%s is unreadable (%s); redoing every step", self.state_path, exc)
            return {}
        return state

    def run(self, name, inputs, params, fn) -> bool:
        """Run ``fn(progress)`` unless its fingerprint matches and its outputs exist. Returns
        True when the outputs are usable."""
        bad = [d for d in NEEDS[name] if self.status.get(d) not in GOOD]
        if bad:
            self.status[name] = "not_done"
            return False
        fp = _fingerprint(inputs, params)
        needed = [self.out / o for o in OUTPUTS[name] if o not in OPTIONAL]
        if not self.force and self.state.get(name) == fp and all(o.is_file() for o in needed):
            self.result.skipped.append(name)
            self.status[name] = "cached"
            return True
        self.current = name
        self._remove(name)                        # redone: no output of the old run until it succeeds
        t0 = time.perf_counter()
        try:
            if self.progress_factory is not None:
                with self.progress_factory(name) as cb:
                    fn(cb)
            else:
                fn(None)
        except UserError as exc:
            self.fail(name, str(exc))
            return False
        finally:
            self.current = None
        self.result.timings[name] = time.perf_counter() - t0
        self.status[name] = "done"
        self.state[name] = fp
        self._save()
        return True

    def external(self, name, path: Path, load) -> bool:
        """The step is replaced by a file the user gave (its outputs in OUT are left alone),
        checked once here with ``load(path)`` rather than by every step that reads it."""
        self.given.add(name)
        if not path.is_file():
            self.fail(name, f"{path}: no such file; check the --{name} path, or leave the option out to calibrate "
                            "from the session")
            return False
        try:
            load(path)
        except UserError as exc:
            self.fail(name, str(exc))
            return False
        self.status[name] = "external"
        return True

    def fail(self, name, message: str | None = None) -> None:
        self.status[name] = "failed"
        if message:
            self.result.problems.append(f"{name}: {message}")
        self._remove(name)

    def finish(self, aborted: bool = False) -> None:
        """Mark what did not run and remove every output that is no longer this run's: of a
        step that failed, of one that needs a failed one, of one not run whose inputs were
        redone. ``aborted``: an exception is on its way out of the step running now."""
        if aborted and self.current is not None:
            self.status[self.current] = "failed"
        for name in STEPS:
            st = self.status.get(name)
            upstream = [self.status.get(d) for d in NEEDS[name]]
            if st is None and any(u not in GOOD for u in upstream):
                if aborted or any(u in ("failed", "not_done") for u in upstream):
                    self.status[name] = "not_done"
            if self.status.get(name) in ("failed", "not_done", "no_recording") or (st is None and "done" in upstream):
                self._remove(name)

    def _remove(self, name) -> None:
        if name in self.given:
            return
        if self.state.pop(name, None) is not None:
            self._save()
        for f in OUTPUTS[name]:
            p = self.out / f
            if p.is_file() and p.resolve() not in self.protect:
                p.unlink()
                self.result.removed.append(p.name)
                log.info("removed %s: step '%s' is not valid in this run", p, name)

    def _save(self):
        write_text(self.state_path, json.dumps(self.state, indent=1))


def _board_text(board: dict) -> str:
    if board["type"] == "chessboard":
        return f"chessboard:{board['cols']}x{board['rows']}:{board['square_mm']}"
    return (f"charuco:{board['cols']}x{board['rows']}:{board['square_mm']}:{board['marker_mm']}:"
            f"{board['dictionary']}")


@dataclass(frozen=True)
class _Settings:
    method: str
    sigma_deg: float
    overlay: bool
    report: bool
    track_every: int
    segment_config: SegmentConfig


def process_session(session, out=None, method: str = "voxel", camera=None, eyes=None, force: bool = False,
                    sigma_deg: float = 1.0, overlay: bool = True, report: bool = True, track_every: int = 2,
                    segment_config: SegmentConfig | None = None, progress_factory=None) -> ProcessResult:
    """Process one session folder (docs/session.md) into ``out`` (default SESSION/processed).

    Args:
        session: the session folder.
        method: estimator for each target ('voxel', 'ml', 'paper', 'lse').
        camera, eyes: calibration files to use instead of calibrating from the session.
        force: redo every step.
        sigma_deg: angular noise of a view line assumed by the estimators.
        overlay, report: write the overlay video and report.html.
        track_every: track one frame in this many, SLERP the rest (2: 15 poses a second at 30
            fps, far finer than head motion; 1 tracks every frame).
        segment_config: fixation segmentation settings (default ``SegmentConfig()``).
        progress_factory: name -> context manager yielding a progress(done, total) callback.

    Returns:
        ProcessResult: ``targets`` holds only what this run estimated; ``problems`` says what
        failed, ``status`` what ran; ``exit_status`` is 2 when no target could be estimated.

    Raises:
        UserError: the session itself cannot be read.
    """
    s = load_session(session)
    out = Path(out) if out is not None else s.root / "processed"
    out.mkdir(parents=True, exist_ok=True)
    res = ProcessResult(out)
    files = s.manifest["files"]
    # a live recording carries the calibrations it ran with
    if camera is None and "camera" in files and "camera_views" not in files:
        camera = s.root / files["camera"]
    if eyes is None and "eyes" in files and "eye_calibration" not in files:
        eyes = s.root / files["eyes"]
    steps = _Steps(out, force, res, progress_factory, [p for p in (camera, eyes) if p is not None])
    for p in remove_temporaries(out, [f for fs in OUTPUTS.values() for f in fs] + list(OTHER_FILES)):
        log.warning("removed %s, a temporary file left by an earlier run that was stopped", p)
    if s.manifest.get("complete") is False:
        counts = ", ".join(f"{s.manifest[k]} {w}" for k, w in (("n_frames", "frames"), ("n_eye_samples", "eye samples"))
                           if isinstance(s.manifest.get(k), int))
        res.problems.append(f"session: {s.root / 'session.json'} says the recording was cut short (complete: "
                            f"false{'; ' + counts + ' saved' if counts else ''}); processing what was recorded")
    cfg = _Settings(method, sigma_deg, overlay, report, track_every, segment_config or SegmentConfig())
    try:
        _run_steps(s, out, steps, res, camera, eyes, cfg)
    except BaseException:
        steps.finish(aborted=True)
        raise
    steps.finish()
    return _finish(res, s, out, method)


def _run_steps(s, out: Path, steps: _Steps, res: ProcessResult, camera, eyes, cfg: _Settings) -> None:
    root, files = s.root, s.manifest["files"]
    # 1. camera
    cam_path = Path(camera) if camera else out / "camera.json"
    if camera is None:
        views = root / files.get("camera_views", "calibration/camera")
        board_file = views / "board.json"

        def do_camera(cb):
            if not board_file.is_file():
                raise UserError(f"{board_file}: no camera-calibration recording in the session; pass --camera "
                                "camera.json")
            board = load_json(board_file, "board")["board"]        # schema: wearable_gaze/formats/schemas/board
            calibrate_camera_files([views], _board_text(board), cam_path, progress=cb)
        steps.run("camera", [views], {}, do_camera)
    else:
        steps.external("camera", cam_path, load_camera)

    # 2. eyes
    eyes_path = Path(eyes) if eyes else out / "eyes.json"
    if eyes is None:
        cal_dir = root / files.get("eye_calibration", "calibration/eye")
        steps.run("eyes", [cal_dir, cam_path], {},
                  lambda cb: calibrate_eyes_files(root, cam_path, eyes_path, progress=cb))
    else:
        steps.external("eyes", eyes_path, load_eyes)

    if not s.manifest.get("has_recording", True):
        res.problems.append("session: a calibration-only session has no recording to process")
        for name in ("tracking", "viewlines", "targets", "report"):
            steps.status[name] = "no_recording"
        return

    # 3. head tracking
    poses_path = out / "poses.csv"
    video, markers, stamps = s.path("scene_video"), s.path("marker_map"), s.path("scene_timestamps")
    if markers is None:
        steps.fail("tracking", "the session has no marker map (markers.json); track it with "
                               "'wearable-gaze track --reference' and pass the poses")
    else:
        steps.run("tracking", [video, cam_path, markers, stamps], {"every": cfg.track_every},
                  lambda cb: track_video(video, cam_path, poses_path, markers=markers, timestamps=stamps,
                                         progress=cb, every=cfg.track_every))

    # 4. view lines
    raw_vl, counts_path = out / ".viewlines_unsegmented.csv", out / ".viewlines_counts.json"

    def do_viewlines(cb):
        write_json(counts_path, viewlines_files(s.path("eye_samples"), eyes_path, poses_path, raw_vl))
    if steps.run("viewlines", [s.path("eye_samples"), eyes_path, poses_path], {}, do_viewlines):
        res.summary["viewlines"] = json.loads(counts_path.read_text(encoding="utf-8"))

    # 5. segmentation and estimation
    params = {"method": cfg.method, "sigma": cfg.sigma_deg, "seg": cfg.segment_config.__dict__}
    if steps.run("targets", [raw_vl], params,
                 lambda cb: _targets(raw_vl, out, cfg.method, cfg.sigma_deg, cfg.segment_config, cb)):
        res.targets = json.loads((out / "targets.json").read_text(encoding="utf-8"))["targets"]
        if not res.targets:
            n = res.summary.get("viewlines", {}).get("written", "the")
            res.problems.append(f"targets: no target could be estimated from {n} view lines (no fixation of "
                                f"{cfg.segment_config.min_fixation_s:g} s or more gave an estimate)")

    # 6. plots, overlay, report
    if cfg.report:
        from .report import write_report  # noqa: PLC0415

        cam_ok = steps.status.get("camera") in GOOD
        inputs = [out / "targets.csv", out / "viewlines.csv", poses_path] + ([video] if cfg.overlay else [])
        steps.run("report", inputs, {"overlay": cfg.overlay},
                  lambda cb: write_report(out, s, cam_path if cam_ok else None, eyes_path, cfg.overlay, cb))


def _finish(res: ProcessResult, s, out: Path, method: str) -> ProcessResult:
    summary = {"version": 1, "session": str(s.root), "method": method, "targets": res.targets,
               "problems": res.problems, "failed_steps": res.failed, "steps_not_done": res.not_done,
               "removed_outputs": res.removed, "steps_skipped": res.skipped,
               "timings_s": {k: round(v, 3) for k, v in res.timings.items()}}
    summary.update(res.summary)
    if res.status.get("report") in GOOD and (out / "report.html").is_file():
        summary["report"] = str(out / "report.html")
    res.summary = summary
    write_json(out / "summary.json", summary)
    return res


TARGET_COLUMNS = ("target", "x_mm", "y_mm", "z_mm", "axis1_mm", "axis2_mm", "axis3_mm", "n_samples", "t_start",
                  "t_end", "fixations", "method", "status", "crb_mm")
TARGET_FORMATS = {k: ".1f" for k in ("x_mm", "y_mm", "z_mm", "axis1_mm", "axis2_mm", "axis3_mm", "crb_mm")} | {
    "t_start": ".3f", "t_end": ".3f"}


def _targets(vl_path: Path, out: Path, method: str, sigma_deg: float, config: SegmentConfig, progress) -> None:
    """Segment the view lines into fixations, estimate each, merge fixations of one target."""
    samples = read_viewlines_csv(vl_path)[0].samples
    labels = segment_fixations(samples, config)
    write_viewlines_csv(out / "viewlines.csv", samples, labels)
    n_seg = int(labels.max()) + 1 if (labels >= 0).any() else 0
    fixations = []
    running = {"t": [], "segment": [], "x": [], "y": [], "z": [], "radius95_mm": []}
    for k in range(n_seg):
        idx = np.flatnonzero(labels == k)
        fixations.append({"segment": k, "idx": idx,
                          "estimate": _running_estimate(samples.select(idx), k, method, sigma_deg, running)})
        if progress:
            progress(k + 1, n_seg + 1)
    write_table(out / "estimates.csv", {k: np.array(v) for k, v in running.items()},
                {"t": ".4f", "x": ".1f", "y": ".1f", "z": ".1f", "radius95_mm": ".1f"})
    targets = _merge(fixations, samples, method, sigma_deg)
    rows = [_target_row(i, tg, samples, method, sigma_deg) for i, tg in enumerate(targets)]
    write_table(out / "targets.csv", {k: np.array([r[k] for r in rows]) for k in TARGET_COLUMNS}, TARGET_FORMATS)
    write_json(out / "targets.json", {"version": 1, "method": method, "targets": [
        {k: (v.item() if isinstance(v, np.generic) else v) for k, v in r.items()} for r in rows]})
    # the merged-target label of every view line, for the report
    tlabels = np.full(len(samples), -1)
    for i, tg in enumerate(targets):
        tlabels[tg["idx"]] = i
    with atomic_path(out / "target_labels.npy") as tmp:
        np.save(tmp, tlabels)


def _running_estimate(sub: BinocularSamples, k: int, method: str, sigma_deg: float, running: dict):
    """The estimator fed one fixation's samples in ~20 chunks, as a live session would; each
    usable estimate appended to ``running``. Returns the last estimate."""
    stream = make_estimator(method, sigma_deg)
    bounds = np.unique(np.linspace(0, len(sub), min(21, len(sub) + 1)).astype(int))
    e = None
    for j0, j1 in zip(bounds[:-1], bounds[1:], strict=True):
        e = stream.add(sub.select(slice(j0, j1)))
        if e.ok:
            running["t"].append(float(sub.t_s[j1 - 1]))
            running["segment"].append(k)
            for a, v in zip("xyz", e.position_mm, strict=True):
                running[a].append(float(v))
            running["radius95_mm"].append(_radius95(e))
    return e


def _target_row(i: int, tg: dict, samples: BinocularSamples, method: str, sigma_deg: float) -> dict:
    """One row of targets.csv / targets.json."""
    e = tg["estimate"]
    pos = e.position_mm if e.ok else np.full(3, np.nan)
    radii = e.ellipsoid(0.95).radii_mm.tolist() if e.covariance_mm2 is not None else [np.nan] * 3
    t = samples.t_s[tg["idx"]]
    crb = _crb(samples.select(tg["idx"]), e.position_mm, sigma_deg) if e.ok else None
    return {"target": i, "x_mm": pos[0], "y_mm": pos[1], "z_mm": pos[2],
            "axis1_mm": radii[0], "axis2_mm": radii[1], "axis3_mm": radii[2],
            "n_samples": len(tg["idx"]), "t_start": float(t.min()), "t_end": float(t.max()),
            "fixations": ";".join(str(f) for f in tg["segments"]), "method": method,
            "status": e.status.value if hasattr(e.status, "value") else str(e.status),
            "crb_mm": float(np.sqrt(np.trace(crb))) if crb is not None else np.nan}


def _crb(samples: BinocularSamples, point_mm, sigma_deg: float):
    """Cramér-Rao bound (3, 3) of the lines actually used, at the point; None if degenerate."""
    try:
        return cramer_rao_bound(samples.lines().origins_mm, point_mm, sigma_deg)
    except ValueError:
        return None


def _radius95(e) -> float:
    if e.covariance_mm2 is None:
        return float("nan")
    return float(e.ellipsoid(0.95).radii_mm.max())


def _merge(fixations, samples: BinocularSamples, method: str, sigma_deg: float) -> list:
    """Fixations of one target (``estimator.segments.same_target``) are merged and re-estimated
    from all their lines; revisits are common."""
    targets = []
    for f in fixations:
        e = f["estimate"]
        if e is None or not e.ok:
            continue
        merged = False
        for tg in targets:
            te = tg["estimate"]
            close = same_target(e.position_mm, e.covariance_mm2, te.position_mm, te.covariance_mm2,
                                origin=samples.left_origin_mm[f["idx"][0]] if samples.left_valid[f["idx"][0]]
                                else samples.right_origin_mm[f["idx"][0]])
            if close:
                tg["idx"] = np.concatenate([tg["idx"], f["idx"]])
                tg["segments"].append(f["segment"])
                tg["idx"] = np.sort(tg["idx"])
                tg["estimate"] = run_estimator(samples.select(tg["idx"]), method, sigma_deg)[1]
                merged = True
                break
        if not merged:
            targets.append({"idx": f["idx"], "segments": [f["segment"]], "estimate": e})
    return targets


def format_result(res: ProcessResult) -> str:
    """The text ``process`` prints: this run's targets, and what failed or was not done."""
    lines = [f"{len(res.targets)} fixated target(s) in {res.out}:"]
    lines.append(f"{'target':>6} {'x mm':>8} {'y mm':>8} {'z mm':>8} {'95% semi-axes mm':>20} {'samples':>8} "
                 f"{'time s':>12}")
    for t in res.targets:
        lines.append(f"{t['target']:>6} {t['x_mm']:>8.0f} {t['y_mm']:>8.0f} {t['z_mm']:>8.0f} "
                     f"{t['axis1_mm']:>6.0f} {t['axis2_mm']:>6.0f} {t['axis3_mm']:>6.0f} {t['n_samples']:>8} "
                     f"{t['t_start']:>5.1f}-{t['t_end']:<5.1f}")
    if res.failed:
        lines.append("FAILED: " + ", ".join(res.failed) + " (the problems are listed on stderr and in summary.json)")
    if res.not_done:
        lines.append("not done, as they need a failed step: " + ", ".join(res.not_done))
    if res.removed:
        lines.append(f"removed {len(res.removed)} output(s) of an earlier run that this run invalidated (listed in "
                     "summary.json)")
    if res.skipped:
        lines.append("unchanged, not redone: " + ", ".join(res.skipped) + " (--force redoes them)")
    if "report" in res.summary:
        lines.append(f"report: {res.summary['report']}")
    return "\n".join(lines)
