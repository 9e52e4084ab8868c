"""``wearable-gaze process``: a recorded session in, fixated 3D targets out (docs/processing.md).

Steps, each skipped when its inputs and settings are unchanged since the last run (``force``
redoes them): camera calibration, eye calibration, head tracking, view lines, segmentation and
estimation, plots and report. A step that cannot run records why; the steps that do not depend
on it still run, and whatever was computed is kept.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from estimator import BinocularSamples, cramer_rao_bound, make_estimator, run_estimator
from estimator.segments import SegmentConfig, same_target, segment_fixations

from .atomic import write_text
from .calibrate_cmd import calibrate_camera_files, calibrate_eyes_files, viewlines_files
from .errors import UserError
from .session import load_session, read_json, write_json
from .tables import write_table
from .track_cmd import track_video
from .viewlines_csv import read_viewlines_csv, write_viewlines_csv

STEPS = ("camera", "eyes", "tracking", "viewlines", "targets", "report")


@dataclass
class ProcessResult:
    out: Path
    targets: list = field(default_factory=list)
    problems: list = field(default_factory=list)
    skipped: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    summary: dict = field(default_factory=dict)


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
    """Runs steps with caching and problem recording."""

    def __init__(self, out: Path, force: bool, result: ProcessResult, progress_factory):
        self.out = out
        self.force = force
        self.result = result
        self.progress_factory = progress_factory
        self.state_path = out / ".steps.json"
        self.state = {} if force or not self.state_path.is_file() else json.loads(self.state_path.read_text())

    def run(self, name, inputs, params, outputs, fn):
        """Run ``fn(progress)`` unless its fingerprint matches and its outputs exist. Returns
        True when the outputs are usable."""
        fp = _fingerprint(inputs, params)
        if not self.force and self.state.get(name) == fp and all(Path(o).exists() for o in outputs):
            self.result.skipped.append(name)
            return True
        t0 = time.perf_counter()
        try:
            if self.progress_factory is not None:
                with self.progress_factory(name) as cb:
                    fn(cb)
            else:
                fn(None)
        except UserError as exc:
            self.result.problems.append(f"{name}: {exc}")
            self.state.pop(name, None)
            self._save()
            return False
        self.result.timings[name] = time.perf_counter() - t0
        self.state[name] = fp
        self._save()
        return True

    def _save(self):
        write_text(self.state_path, json.dumps(self.state, indent=1))


def _board_text(board: dict) -> str:
    if board["type"] == "chessboard":
        return f"chessboard:{board['cols']}x{board['rows']}:{board['square_mm']}"
    return (f"charuco:{board['cols']}x{board['rows']}:{board['square_mm']}:{board['marker_mm']}:"
            f"{board['dictionary']}")


def process_session(session, out=None, method: str = "voxel", camera=None, eyes=None, force: bool = False,
                    sigma_deg: float = 1.0, overlay: bool = True, report: bool = True, track_every: int = 2,
                    segment_config: SegmentConfig = SegmentConfig(), progress_factory=None) -> ProcessResult:
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
        progress_factory: name -> context manager yielding a progress(done, total) callback.

    Raises:
        UserError: the session itself cannot be read.
    """
    s = load_session(session)
    root = s.root
    out = Path(out) if out is not None else root / "processed"
    out.mkdir(parents=True, exist_ok=True)
    res = ProcessResult(out)
    steps = _Steps(out, force, res, progress_factory)
    files = s.manifest["files"]
    # a live recording carries the calibrations it ran with
    if camera is None and "camera" in files and "camera_views" not in files:
        camera = root / files["camera"]
    if eyes is None and "eyes" in files and "eye_calibration" not in files:
        eyes = root / files["eyes"]

    # 1. camera
    cam_path = Path(camera) if camera else out / "camera.json"
    if camera is None:
        views = root / files.get("camera_views", "calibration/camera")
        board_file = views / "board.json"

        def do_camera(cb):
            if not board_file.is_file():
                raise UserError(f"{board_file}: no camera-calibration recording in the session; pass --camera camera.json")
            board = read_json(board_file, "board description")["board"]
            calibrate_camera_files([views], _board_text(board), cam_path, progress=cb)
        cam_ok = steps.run("camera", [views], {}, [cam_path], do_camera)
    else:
        cam_ok = cam_path.is_file()
        if not cam_ok:
            res.problems.append(f"camera: {cam_path}: no such file")

    # 2. eyes
    eyes_path = Path(eyes) if eyes else out / "eyes.json"
    eyes_ok = False
    if eyes is None and cam_ok:
        cal_dir = root / files.get("eye_calibration", "calibration/eye")
        eyes_ok = steps.run("eyes", [cal_dir, cam_path], {}, [eyes_path],
                            lambda cb: calibrate_eyes_files(root, cam_path, eyes_path, progress=cb))
    elif eyes is not None:
        eyes_ok = eyes_path.is_file()
        if not eyes_ok:
            res.problems.append(f"eyes: {eyes_path}: no such file")

    if not s.manifest.get("has_recording", True):
        res.problems.append("session: a calibration-only session has no recording to process")
        return _finish(res, s, out, method, report=False)

    # 3. head tracking
    poses_path = out / "poses.csv"
    video = s.path("scene_video")
    ov_path = out / "overlay.webm"
    track_ok = False
    if cam_ok and s.path("marker_map") is not None:
        track_ok = steps.run("tracking", [video, cam_path, s.path("marker_map"), s.path("scene_timestamps")],
                             {"every": track_every}, [poses_path],
                             lambda cb: track_video(video, cam_path, poses_path, markers=s.path("marker_map"),
                                                    timestamps=s.path("scene_timestamps"), progress=cb,
                                                    every=track_every))
    elif s.path("marker_map") is None:
        res.problems.append("tracking: the session has no marker map (markers.json); track it with "
                            "'wearable-gaze track --reference' and pass the poses")

    # 4. view lines
    raw_vl = out / ".viewlines_unsegmented.csv"
    vl_path = out / "viewlines.csv"
    vl_ok = False
    if eyes_ok and track_ok:
        def do_viewlines(cb):
            counts = viewlines_files(s.path("eye_samples"), eyes_path, poses_path, raw_vl)
            write_json(out / ".viewlines_counts.json", counts)
        vl_ok = steps.run("viewlines", [s.path("eye_samples"), eyes_path, poses_path], {}, [raw_vl], do_viewlines)
        if (out / ".viewlines_counts.json").is_file():
            res.summary["viewlines"] = json.loads((out / ".viewlines_counts.json").read_text())

    # 5. segmentation and estimation
    tg_path = out / "targets.csv"
    if vl_ok:
        params = {"method": method, "sigma": sigma_deg, "seg": segment_config.__dict__}
        steps.run("targets", [raw_vl], params, [tg_path, vl_path, out / "estimates.csv", out / "targets.json"],
                  lambda cb: _targets(raw_vl, out, method, sigma_deg, segment_config, cb))
    if tg_path.is_file():
        res.targets = json.loads((out / "targets.json").read_text())["targets"]

    # 6. plots, overlay, report
    if report and vl_ok and tg_path.is_file():
        from .report import write_report  # noqa: PLC0415

        inputs = [tg_path, vl_path, poses_path] + ([video] if overlay else [])
        steps.run("report", inputs, {"overlay": overlay}, [out / "report.html"],
                  lambda cb: write_report(out, s, cam_path if cam_ok else None, eyes_path, overlay, cb))
    return _finish(res, s, out, method, report)


def _finish(res: ProcessResult, s, out: Path, method: str, report: bool) -> ProcessResult:
    summary = {"version": 1, "session": str(s.root), "method": method, "targets": res.targets,
               "problems": res.problems, "steps_skipped": res.skipped,
               "timings_s": {k: round(v, 3) for k, v in res.timings.items()}}
    summary.update({k: v for k, v in res.summary.items()})
    if (out / "report.html").is_file():
        summary["report"] = str(out / "report.html")
    res.summary = summary
    write_json(out / "summary.json", summary)
    return res


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
        sub = samples.select(idx)
        # the running estimate: the estimator fed in ~20 chunks, as a live session would
        stream = make_estimator(method, sigma_deg)
        bounds = np.unique(np.linspace(0, len(idx), min(21, len(idx) + 1)).astype(int))
        e = None
        for j0, j1 in zip(bounds[:-1], bounds[1:], strict=True):
            e = stream.add(sub.select(slice(j0, j1)))
            if e.ok:
                running["t"].append(float(sub.t_s[j1 - 1]))
                running["segment"].append(k)
                for a, v in zip("xyz", e.position_mm, strict=True):
                    running[a].append(float(v))
                running["radius95_mm"].append(_radius95(e))
        fixations.append({"segment": k, "idx": idx, "estimate": e})
        if progress:
            progress(k + 1, n_seg + 1)
    write_table(out / "estimates.csv", {k: np.array(v) for k, v in running.items()},
                {"t": ".4f", "x": ".1f", "y": ".1f", "z": ".1f", "radius95_mm": ".1f"})
    targets = _merge(fixations, samples, method, sigma_deg)
    rows = []
    for i, tg in enumerate(targets):
        e = tg["estimate"]
        radii = e.ellipsoid(0.95).radii_mm.tolist() if e.covariance_mm2 is not None else [np.nan] * 3
        t = samples.t_s[tg["idx"]]
        crb = _crb(samples.select(tg["idx"]), e.position_mm, sigma_deg) if e.ok else None
        rows.append({"target": i, "x_mm": e.position_mm[0] if e.ok else np.nan,
                     "y_mm": e.position_mm[1] if e.ok else np.nan, "z_mm": e.position_mm[2] if e.ok else np.nan,
                     "axis1_mm": radii[0], "axis2_mm": radii[1], "axis3_mm": radii[2],
                     "n_samples": len(tg["idx"]), "t_start": float(t.min()), "t_end": float(t.max()),
                     "fixations": ";".join(str(f) for f in tg["segments"]), "method": method,
                     "status": e.status.value if hasattr(e.status, "value") else str(e.status), "crb_mm": float(np.sqrt(np.trace(crb))) if crb is not None else np.nan})
    cols = {k: np.array([r[k] for r in rows]) for k in (rows[0] if rows else
            {"target": 0, "x_mm": 0, "y_mm": 0, "z_mm": 0, "axis1_mm": 0, "axis2_mm": 0, "axis3_mm": 0,
             "n_samples": 0, "t_start": 0, "t_end": 0, "fixations": 0, "method": 0, "status": 0, "crb_mm": 0})}
    if not rows:
        cols = {k: np.array([]) for k in cols}
    write_table(out / "targets.csv", cols, {k: ".1f" for k in ("x_mm", "y_mm", "z_mm", "axis1_mm", "axis2_mm",
                                                                "axis3_mm", "crb_mm")} | {"t_start": ".3f", "t_end": ".3f"})
    write_json(out / "targets.json", {"version": 1, "method": method, "targets": [
        {k: (v.item() if isinstance(v, np.generic) else v) for k, v in r.items()} for r in rows]})
    # the merged-target label of every view line, for the report
    tlabels = np.full(len(samples), -1)
    for i, tg in enumerate(targets):
        tlabels[tg["idx"]] = i
    np.save(out / "target_labels.npy", tlabels)


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
    lines = [f"{len(res.targets)} fixated target(s) in {res.out}:"]
    lines.append(f"{'target':>6} {'x mm':>8} {'y mm':>8} {'z mm':>8} {'95% semi-axes mm':>20} {'samples':>8} {'time s':>12}")
    for t in res.targets:
        lines.append(f"{t['target']:>6} {t['x_mm']:>8.0f} {t['y_mm']:>8.0f} {t['z_mm']:>8.0f} "
                     f"{t['axis1_mm']:>6.0f} {t['axis2_mm']:>6.0f} {t['axis3_mm']:>6.0f} {t['n_samples']:>8} "
                     f"{t['t_start']:>5.1f}-{t['t_end']:<5.1f}")
    if res.skipped:
        lines.append("unchanged, not redone: " + ", ".join(res.skipped) + " (--force redoes them)")
    if "report" in res.summary:
        lines.append(f"report: {res.summary['report']}")
    return "\n".join(lines)
