"""The processing report: plots (matplotlib, no display needed), the overlay video and
report.html tying them together."""

from __future__ import annotations

import html
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from calibration.camera import CameraCalibration
from estimator import angular_log_likelihood
from tracking.markermap import MarkerMap

from ..formats.atomic import atomic_path, write_text
from ..formats.eye_samples import EyeSamples
from ..formats.poses import read_poses_csv
from ..formats.targets import (
    read_device_comparison,
    read_estimates,
    read_target_labels,
    read_target_paths,
    read_targets,
)
from ..formats.video import open_video
from ..formats.viewlines import read_viewlines_csv
from .types import Target

PLOTS = ("plot_depth_vs_observations.png", "plot_density_slices.png", "plot_3d.png", "plot_top_view.png")
REPORT_FILES = ("report.html", *PLOTS, "overlay.webp", "overlay_error.txt")   # everything write_report writes
COLOURS = ["#d62728", "#1f77b4", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf"]


def _plt():
    import matplotlib  # noqa: PLC0415
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    return plt


def _save(fig, path: Path):
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight")
    _plt().close(fig)


def _finish(fig, ax, path: Path, title: str, *labels: str) -> None:
    """Axis labels (x, y and, on a 3D plot, z), the legend and the title; then save."""
    for set_label, text in zip((ax.set_xlabel, ax.set_ylabel, getattr(ax, "set_zlabel", None)), labels, strict=False):
        set_label(text)
    ax.legend(fontsize=7)
    ax.set_title(title)
    _save(fig, path)


@dataclass(frozen=True)
class _ReportData:
    """What the plots read from the processing outputs (world frame, mm).

    Attributes:
        targets: the targets of targets.json.
        samples: the view lines (N,), sorted by time; tlabels (N,): target index, -1 none.
        head: (M, 3) head positions with a pose; centre (3,): their mean.
        est: the running estimates (estimates.csv columns).
        orig, cyc: (N, 3) each sample's origin and direction (left eye, else right).
        paths: the moving targets' paths (target_paths.csv): {index: (t (K,), positions (K, 3),
            covariances (K, 3, 3))}; {} without the file.
    """

    targets: list
    samples: object
    tlabels: np.ndarray
    head: np.ndarray
    centre: np.ndarray
    est: dict
    orig: np.ndarray
    cyc: np.ndarray
    paths: dict


def _report_data(out: Path, T_p: np.ndarray) -> _ReportData:
    from estimator import BinocularSamples  # noqa: PLC0415

    targets = [Target.from_row(r) for r in read_targets(out / "targets.json")]
    samples = BinocularSamples.concatenate([s.samples for s in read_viewlines_csv(out / "viewlines.csv")])
    samples = samples.select(np.argsort(samples.t_s, kind="stable"))
    labels = out / "target_labels.npy"
    tlabels = read_target_labels(labels) if labels.is_file() else np.full(len(samples), -1)
    head = T_p[np.isfinite(T_p[:, 0, 0]), :3, 3]
    est = read_estimates(out / "estimates.csv")
    cyc = samples.left_direction.copy()
    cyc[~samples.left_valid] = samples.right_direction[~samples.left_valid]
    orig = np.where(samples.left_valid[:, None], samples.left_origin_mm, samples.right_origin_mm)
    paths = read_target_paths(out / "target_paths.csv") if (out / "target_paths.csv").is_file() else {}
    return _ReportData(targets, samples, tlabels, head, head.mean(axis=0) if len(head) else np.zeros(3), est,
                       orig, cyc, paths)


@dataclass(frozen=True)
class OverlayInputs:
    """What the overlay draws on the scene video besides the targets and poses.

    Attributes:
        camera: the scene camera's calibration.
        eyes: the (left, right) eye calibrations, or None (no gaze points drawn).
        eye_samples: the session's raw eye samples.
        marker_map: the session's marker map, or None.
        video: the scene video file.
    """

    camera: CameraCalibration
    eyes: list | None
    eye_samples: EyeSamples
    marker_map: MarkerMap | None
    video: Path


def write_report(out: Path, title: str, overlay=None, progress=None, notes=()) -> None:
    """The plots (``PLOTS``), the overlay and report.html in ``out``, from the outputs of the
    earlier steps there. ``title``: the session's name. ``overlay``: None (no overlay),
    or a function returning its ``OverlayInputs`` (called here: a failure to load them, like any
    failure of the overlay, is written to overlay_error.txt and the report made without it).
    ``notes``: sentences the reader must see first (where the head poses came from, ...)."""
    out = Path(out)
    t_p, _, T_p, _ = read_poses_csv(out / "poses.csv")
    d = _report_data(out, T_p)
    images = [_plot_depth(d, out), _plot_density(d, out)]
    if progress:
        progress(2, 5)
    images += [_plot_3d(d, out), _plot_top(d, out)]
    if progress:
        progress(3, 5)
    video_name = None
    for name in ("overlay.webp", "overlay_error.txt"):        # an earlier run's: this report may have neither
        (out / name).unlink(missing_ok=True)
    if overlay is not None:
        try:
            video_name = _overlay(out, overlay(), d.targets, t_p, T_p)
        except Exception as exc:  # noqa: BLE001  (a report without a video is still a report)
            write_text(out / "overlay_error.txt", f"{type(exc).__name__}: {exc}\n")
    if progress:
        progress(4, 5)
    _html(out, title, d.targets, images, video_name, notes, _device_rows(out))


def _plot_depth(d: _ReportData, out: Path) -> tuple[str, str]:
    """Depth against the number of observations, per fixation (running estimate, 95 % band)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4))
    for k in np.unique(d.est["segment"]).astype(int):
        sel = d.est["segment"] == k
        P = np.column_stack([d.est["x"][sel], d.est["y"][sel], d.est["z"][sel]])
        depth = np.linalg.norm(P - d.centre, axis=1) / 1000
        n = np.arange(1, sel.sum() + 1) * max(int(np.sum(d.tlabels >= 0) / max(len(d.est["t"]), 1)), 1)
        ax.plot(n, depth, "-o", ms=3, color=COLOURS[k % len(COLOURS)], label=f"fixation {k}")
        r = d.est["radius95_mm"][sel] / 1000
        ax.fill_between(n, depth - r, depth + r, color=COLOURS[k % len(COLOURS)], alpha=0.15)
    ax.set_xlabel("observations (binocular samples)")
    ax.set_ylabel("estimated distance from the head (m)")
    ax.set_title("Running estimate per fixation (band: 95 % radius)")
    if len(d.est["t"]):
        ax.legend(fontsize=7, ncol=2)
    _save(fig, out / "plot_depth_vs_observations.png")
    return ("plot_depth_vs_observations.png", "Depth against the number of observations")


def _plot_density(d: _ReportData, out: Path) -> tuple[str, str]:
    """Log-likelihood slices (horizontal) through each of the first four static targets (a moving
    one's lines meet no one point)."""
    plt = _plt()
    static = [tg for tg in d.targets if not tg.moving][:4]
    n_t = max(len(static), 1)
    fig, axes = plt.subplots(1, min(n_t, 4), figsize=(3.2 * min(n_t, 4), 3.2), squeeze=False)
    for i, tg in enumerate(static):
        ax = axes[0, i]
        X = tg.position_mm
        lines = d.samples.select(np.flatnonzero(d.tlabels == tg.index)).lines()
        half = max(1.5 * (tg.axes95_mm[2] if np.isfinite(tg.axes95_mm[2]) else 100.0), 30.0)
        gx, gz = np.meshgrid(np.linspace(-half, half, 45), np.linspace(-half, half, 45))
        P = X + np.column_stack([gx.ravel(), np.zeros(gx.size), gz.ravel()])
        ll = angular_log_likelihood(P, lines.origins_mm, lines.directions, np.deg2rad(1.0)).reshape(gx.shape)
        ax.imshow(np.maximum(ll - ll.max(), -30), origin="lower", cmap="magma", aspect="auto",
                  extent=(X[0] - half, X[0] + half, X[2] - half, X[2] + half))
        ax.plot(X[0], X[2], "c+", ms=10)
        ax.set_title(f"target {tg.index}: y = {X[1]:.0f} mm", fontsize=8)
        ax.set_xlabel("x (mm)", fontsize=7)
        ax.set_ylabel("z (mm)", fontsize=7)
        ax.tick_params(labelsize=6)
    _save(fig, out / "plot_density_slices.png")
    return ("plot_density_slices.png", "Log-likelihood of the gazed point (to -30), horizontal slice through each "
            "target: narrow across the view lines, long along them")


def _plot_3d(d: _ReportData, out: Path) -> tuple[str, str]:
    """3D view: head path, every 10th view line of each target, the targets (a moving one as its
    path)."""
    plt = _plt()
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    ax.plot(d.head[:, 0], d.head[:, 2], -d.head[:, 1], "k-", lw=1, label="head")
    for i, tg in enumerate(d.targets):
        X = tg.position_mm
        c = COLOURS[i % len(COLOURS)]
        for a, b in _line_segments(tg, d, d.cyc):
            ax.plot([a[0], b[0]], [a[2], b[2]], [-a[1], -b[1]], color=c, lw=0.3, alpha=0.5)
        if tg.index in d.paths:
            P = d.paths[tg.index][1]
            ax.plot(P[:, 0], P[:, 2], -P[:, 1], "-", color=c, lw=2, label=f"target {i} (moving: its path)")
        else:
            ax.scatter([X[0]], [X[2]], [-X[1]], color=c, s=40, label=f"target {i}")
    _finish(fig, ax, out / "plot_3d.png", "Head path, view lines and targets", "x (mm)", "z (mm)", "up (mm)")
    return ("plot_3d.png", "3D view: head trajectory, view lines, targets")


def _plot_top(d: _ReportData, out: Path) -> tuple[str, str]:
    """Top view: head path, view lines, targets with their largest 95 % semi-axis; a moving
    target as its path, with the 95 % interval of its depth (largest semi-axis) at every 10th
    knot."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 6))
    ax.plot(d.head[:, 0], d.head[:, 2], "k-", lw=1, label="head")
    for i, tg in enumerate(d.targets):
        X = tg.position_mm
        c = COLOURS[i % len(COLOURS)]
        for a, b in _line_segments(tg, d, d.cyc):
            ax.plot([a[0], b[0]], [a[2], b[2]], color=c, lw=0.3, alpha=0.4)
        if tg.index in d.paths:
            _top_path(ax, plt, d.paths[tg.index], c, f"target {i} (moving: its path)")
            continue
        r = tg.axes95_mm[2] if np.isfinite(tg.axes95_mm[2]) else 0
        ax.add_patch(plt.Circle((X[0], X[2]), r, fill=False, color=c, lw=1))
        ax.plot(X[0], X[2], "o", color=c, label=f"target {i} ({np.linalg.norm(X - d.centre) / 1000:.2f} m)")
    ax.set_aspect("equal")
    _finish(fig, ax, out / "plot_top_view.png", "Top view (circles: largest 95 % semi-axis)", "x (mm)", "z (mm)")
    return ("plot_top_view.png", "Top view")


def _top_path(ax, plt, path, colour, label: str) -> None:
    """A moving target's path seen from above, circles of its largest 95 % semi-axis on every
    10th knot."""
    _, P, cov = path
    ax.plot(P[:, 0], P[:, 2], "-", color=colour, lw=2, label=label)
    k95 = np.sqrt(7.8147)                                   # chi-square 95 %, 3 dof
    for k in range(0, len(P), 10):
        r = k95 * np.sqrt(max(np.linalg.eigvalsh(cov[k])[-1], 0.0))
        ax.add_patch(plt.Circle((P[k, 0], P[k, 2]), r, fill=False, color=colour, lw=0.5))


def _line_segments(tg, d: _ReportData, directions, every: int = 10):
    """Every ``every``-th view line of a target, from the eye to the target's distance (a moving
    target's: its path's point at the line's time)."""
    for j in np.flatnonzero(d.tlabels == tg.index)[::every]:
        X = tg.position_mm
        if tg.index in d.paths:
            t, P, _ = d.paths[tg.index]
            X = np.array([np.interp(d.samples.t_s[j], t, P[:, m]) for m in range(3)])
        yield d.orig[j], d.orig[j] + directions[j] * np.linalg.norm(X - d.orig[j])


OVERLAY_FPS = 15.0
OVERLAY_WIDTH = 428
OVERLAY_MAX_S = 60.0


def _overlay(out, inp: OverlayInputs, targets, t_p, T_p) -> str | None:
    """An animated WebP (plays in any browser, no codec needed): the marker map and world
    axes, each eye's gaze point (eq. 1-2), the fixated target's estimate projected. 15 frames
    per second, 428 px wide, the first 60 s of the session."""
    from PIL import Image  # noqa: PLC0415  (Pillow comes with matplotlib)

    m = inp.marker_map
    corners = [m.corners(i) for i in m.poses] if m is not None else []
    cap, fps, _ = open_video(inp.video, inp.camera.image_size)
    step = max(int(round(fps / OVERLAY_FPS)), 1)
    w, h = inp.camera.image_size
    size = (OVERLAY_WIDTH, int(round(h * OVERLAY_WIDTH / w)))
    frames = []
    i = 0
    while i < len(T_p) and t_p[i] - t_p[0] <= OVERLAY_MAX_S:
        if i % step:
            if not cap.grab():
                break
            i += 1
            continue
        ok, frame = cap.read()
        if not ok:
            break
        img = _overlay_frame(frame, inp, corners, targets, T_p[i], t_p[i])
        small = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
        frames.append(Image.fromarray(cv2.cvtColor(small, cv2.COLOR_BGR2RGB)))
        i += 1
    cap.release()
    if not frames:
        return None
    name = "overlay.webp"
    with atomic_path(out / name) as tmp:
        frames[0].save(tmp, format="WEBP", save_all=True, append_images=frames[1:],
                       duration=int(round(1000 * step / fps)), loop=0, method=0, quality=60)
    return name


def _overlay_frame(frame, inp: OverlayInputs, corners, targets, T, t) -> np.ndarray:
    """One overlay frame: ``frame`` (BGR) with the markers and the targets fixated around time
    ``t`` drawn at head pose ``T`` (T_world_from_cam, NaN without a pose), and the gaze points."""
    cam, eye, img = inp.camera, inp.eye_samples, frame.copy()
    if np.isfinite(T[0, 0]):
        Tcw = np.linalg.inv(T)
        for c in corners:
            pc = c @ Tcw[:3, :3].T + Tcw[:3, 3]
            if np.all(pc[:, 2] > 100):
                px = cam.project(pc)
                if np.all(np.isfinite(px)) and np.abs(px).max() < 1e5:
                    cv2.polylines(img, [np.round(px).astype(np.int32)], True, (0, 200, 0), 3, cv2.LINE_AA)
        for tg in targets:
            if tg.t_start - 0.2 <= t <= tg.t_end + 0.2:
                pc = Tcw[:3, :3] @ tg.position_mm + Tcw[:3, 3]
                uv = _pixel(cam.project(pc[None])[0]) if pc[2] > 100 else None
                if uv is not None:
                    cv2.drawMarker(img, uv, (0, 0, 255), cv2.MARKER_CROSS, 50, 5)
                    cv2.putText(img, f"target {tg.index}: {np.linalg.norm(pc) / 1000:.2f} m",
                                (uv[0] + 15, uv[1] - 15), cv2.FONT_HERSHEY_SIMPLEX, 1.3, (0, 0, 255), 3)
    if inp.eyes is not None:
        j = int(np.searchsorted(eye.t, t))
        if j < len(eye.t):
            for e, col in ((0, (255, 128, 0)), (1, (255, 0, 255))):
                if eye.valid[j, e]:
                    q = inp.eyes[e].image_points(eye.raw[j:j + 1, e])
                    uv = _pixel(cam.project(np.column_stack([q, np.ones(1)]))[0])
                    if uv is not None:
                        cv2.circle(img, uv, 14, col, 3, cv2.LINE_AA)
    return img


def _pixel(px, limit: float = 1e5) -> tuple[int, int] | None:
    """A projected point (2,) as OpenCV drawing coordinates, or None when it is not finite or
    absurdly far outside any image (OpenCV takes only 32-bit integer coordinates)."""
    px = np.asarray(px, float)
    if not np.all(np.isfinite(px)) or np.abs(px).max() > limit:
        return None
    return int(round(px[0])), int(round(px[1]))


def _device_rows(out: Path) -> str:
    """The table of device_comparison.csv (an imported session's targets beside the device's own
    3D gaze), or '' without one."""
    path = out / "device_comparison.csv"
    if not path.is_file():
        return ""
    tab = read_device_comparison(path)
    rows = "".join(f"<tr><td>{int(k)}</td><td>{int(n)}</td><td>{a:.0f}</td><td>{b:.0f}</td></tr>"
                   for k, n, a, b in zip(tab["target"], tab["n_samples"], tab["ours_distance_mm"],
                                         tab["device_depth_mm"], strict=True))
    return ("<h2>Beside the device's own 3D gaze</h2><p>Distance from the head to each target: ours from the view "
            "lines integrated over the head's motion, the device's from its per-sample vergence depth (median over "
            "the target's samples), mm.</p><table><tr><th>target</th><th>samples</th><th>ours</th><th>device</th>"
            f"</tr>{rows}</table>")


def _html(out: Path, name: str, targets, images, video_name, notes=(), device_table: str = "") -> None:
    rows = "".join(
        "<tr><td>{}</td><td>{:.0f}, {:.0f}, {:.0f}</td><td>{:.0f} / {:.0f} / {:.0f}</td><td>{}</td><td>{:.1f}-{:.1f}"
        "</td><td>{}</td><td>{:.0f}</td><td>{}</td></tr>".format(
            t.index, *t.position_mm, *t.axes95_mm, t.n_samples, t.t_start, t.t_end,
            html.escape(";".join(map(str, t.fixations))), t.crb_mm,
            "moving: the point is its path's middle (target_paths.csv)" if t.moving else html.escape(t.status))
        for t in targets)
    imgs = "".join(f'<figure><img src="{html.escape(n)}" alt="{html.escape(c)}"><figcaption>{html.escape(c)}'
                   f"</figcaption></figure>" for n, c in images)
    video = (f'<h2>Overlay</h2><img src="{video_name}" alt="overlay video" width="{OVERLAY_WIDTH * 2}">'
             "<p>Scene video (animated): green, the markers of the map; circles, each eye's gaze point (orange "
             "left, magenta right); red cross, the estimated 3D target.</p>"
             if video_name else "<p>No overlay video.</p>")
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>wearable-gaze report</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto}}img{{max-width:100%}}
table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:4px 8px}}figure{{margin:1em 0}}</style></head>
<body><h1>Gaze targets: {html.escape(str(name))}</h1>
{"".join(f"<p><b>{html.escape(n)}</b></p>" for n in notes)}
<p>{len(targets)} fixated target(s). Positions in the world frame{"" if notes else " of the marker map"}, mm.</p>
<table><tr><th>target</th><th>position (x, y, z)</th><th>95 % semi-axes</th><th>samples</th><th>time (s)</th>
<th>fixations</th><th>Cramér-Rao bound (mm)</th><th>status</th></tr>{rows}</table>
{device_table}
{video}
<h2>Plots</h2>{imgs}
<script>
// after loading, record how many images actually loaded (tests read it from a headless browser)
window.addEventListener("load", () => {{
  const im = Array.from(document.images);
  document.body.dataset.images = im.filter(i => i.complete && i.naturalWidth > 0).length + "/" + im.length;
}});
</script>
</body></html>
"""
    write_text(out / "report.html", page)
