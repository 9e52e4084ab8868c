"""Synthetic ground truth shared by the tests."""

import contextlib
import io

import numpy as np

from estimator import BinocularSamples, ViewLines, perturb_directions


def random_rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def random_transform(rng, scale_mm=500.0):
    T = np.eye(4)
    T[:3, :3] = random_rotation(rng)
    T[:3, 3] = rng.normal(scale=scale_mm, size=3)
    return T


def lines_toward(target, origins, sigma_rad=0.0, rng=None, sample_index=None):
    d = np.asarray(target, float) - origins
    if sigma_rad > 0:
        d = perturb_directions(d, sigma_rad, rng)
    return ViewLines(origins, d, "world", sample_index)


def walkabout_samples(target, rng, n=300, sigma_deg=1.0, ipd=64.0):
    """A wider, irregular geometry than the paper's: head swaying over +-150 mm in x, +-80 mm
    in y and +-100 mm in z, head yawing so the eye baseline turns."""
    t = np.arange(n) / 60.0
    heads = np.column_stack([150 * np.sin(0.7 * t), 80 * np.sin(1.3 * t + 1), 100 * np.sin(0.4 * t)])
    yaw = 0.3 * np.sin(0.5 * t)
    half = np.column_stack([np.cos(yaw), np.zeros(n), -np.sin(yaw)]) * ipd / 2
    lo, ro = heads - half, heads + half
    s = np.deg2rad(sigma_deg)
    X = np.asarray(target, float)
    ld = perturb_directions(X - lo, s, rng) if s > 0 else X - lo
    rd = perturb_directions(X - ro, s, rng) if s > 0 else X - ro
    return BinocularSamples.from_arrays(t, lo, ld, ro, rd)


def eye_record_bytes(i: int, rate_hz: float = 60.0) -> bytes:
    """Record ``i`` of a synthetic recorder stream in the default protocol: counter i, time
    i / rate_hz s, the right eye invalid every 7th record."""
    from wearable_gaze.formats.serial_protocol import DEFAULT_PROTOCOL, EyeRecord

    return DEFAULT_PROTOCOL.format(EyeRecord(i, i / rate_hz, (2000.0 + i, 1990.5), (2010.25, 1980.0), True,
                                             i % 7 != 0))


def drain_reader(reader, n: int, timeout: float = 5.0) -> list:
    """Up to ``n`` records from an ``EyeReader``'s queue, waiting at most ``timeout`` s."""
    import queue
    import time

    out, t0 = [], time.monotonic()
    while len(out) < n and time.monotonic() - t0 < timeout:
        try:
            out.append(reader.queue.get(timeout=0.05)[1])
        except queue.Empty:
            pass
    return out


def rendered_marker_scene(rng, dictionary="DICT_4X4_50", side_mm=120.0, n_markers=4,
                          x_mm=(-600, 600), y_mm=(-300, 300), z_mm=(1000, 2000)):
    """``n_markers`` markers (ids 0..n-1) turned up to 40 degrees at random positions in front of
    the simulator's wide scene camera at the origin, rendered with noise.

    Returns:
        (grey image (H, W) uint8, {id: (4, 2) projected true corners, px}).
    """
    from estimator.frames import rotation_about_axis
    from tracking.markermap import marker_corners_world
    from wearable_gaze.sim.camera import Camera
    from wearable_gaze.sim.noise import finish
    from wearable_gaze.sim.planes import marker_plane
    from wearable_gaze.sim.render import render

    cam = Camera.wide_scene_camera()
    planes, truth = [], {}
    for mid in range(n_markers):
        T = np.eye(4)
        T[:3, :3] = rotation_about_axis(rng.normal(size=3), np.deg2rad(rng.uniform(0, 40)))
        T[:3, 3] = [rng.uniform(*x_mm), rng.uniform(*y_mm), rng.uniform(*z_mm)]
        planes.append(marker_plane(dictionary, mid, side_mm, T))
        truth[mid] = cam.project(marker_corners_world(side_mm, T))
    return finish(render(cam, np.eye(4), planes)), truth


def run_import(module, src, out, **options) -> dict:
    """Import ``src`` with a device ``module`` (formats/devices: its ``NAME`` and
    ``read_recording``) into the session folder ``out``, ``ImportOptions(**options)``; the
    import report (import_report.json)."""
    import json
    from pathlib import Path

    from wearable_gaze.formats.devices.common import ImportOptions, SessionImport

    with SessionImport(out, module.NAME, src) as imp:
        module.read_recording(src, imp, ImportOptions(**options))
    return json.loads((Path(out) / "import_report.json").read_text())


def one_line_error(module, src, out, *fragments, match=None, **options) -> str:
    """Import as ``run_import`` does, expecting a ``UserError`` of one line (no traceback) that
    holds each of ``fragments`` and matches the regular expression ``match``; its message."""
    import pytest

    from wearable_gaze.errors import UserError

    with pytest.raises(UserError, match=match) as err:
        run_import(module, src, out, **options)
    msg = str(err.value)
    assert "\n" not in msg and "Traceback" not in msg, msg
    for f in fragments:
        assert f in msg, msg
    return msg


def walkabout_recording(root):
    """A 4 s simulated lab-walkabout session (seed 1) written in ``root`` and read back as a
    ``SimulatedRecording``, for the device writers' round trips."""
    from wearable_gaze.formats.devices.common import read_simulated_recording
    from wearable_gaze.sim.simulate import simulate_scenario

    simulate_scenario({"base": "lab-walkabout", "duration_s": 4.0, "calibration": {"camera_views": 4}}, root, seed=1)
    return read_simulated_recording(root)


class TimedLog(io.StringIO):
    """A stream that is not a terminal and keeps when each line was written (``times``). Used in
    place of sys.stderr to test progress lines."""

    def __init__(self):
        super().__init__()
        self.times = []

    def write(self, text):
        import time

        self.times += [time.monotonic()] * text.count("\n")
        return super().write(text)


def slow_down(monkeypatch, owner, name: str, seconds: float = 1.0, result=None, raises=None):
    """Make ``owner.name`` (a module's function) take ``seconds`` first: then it returns what the
    real one returns, or ``result`` when given, or raises ``raises`` when given."""
    import time

    real = getattr(owner, name)

    def slow(*args, **kwargs):
        time.sleep(seconds)
        if raises is not None:
            raise raises
        return result if result is not None else real(*args, **kwargs)
    monkeypatch.setattr(owner, name, slow)


def same_target(p1, cov1, p2, cov2, origin=None, floor_deg: float = 0.5, threshold: float = 11.34) -> bool:
    """The covariance-overlap test that ``estimator.merge``'s likelihood ratio on the pooled lines
    replaced (moved here from estimator/segments.py: only tests use it, to show the merge keeps
    apart what this test would join). Whether two estimates (3,) with covariances (3, 3) mm^2 are one target seen twice:
    Mahalanobis distance below the chi-square 99 % point (3 dof). Each covariance gets an
    isotropic floor of ``floor_deg`` times the distance from ``origin`` (the head, default the
    world origin): calibration biases shift a whole fixation's lines together, which the
    covariance of its random noise does not cover. Without covariances: within 5 % of the
    distance."""
    p1, p2 = np.asarray(p1, float), np.asarray(p2, float)
    o = np.zeros(3) if origin is None else np.asarray(origin, float)
    dist = 0.5 * (np.linalg.norm(p1 - o) + np.linalg.norm(p2 - o))
    if cov1 is None or cov2 is None:
        return bool(np.linalg.norm(p1 - p2) < 0.05 * dist)
    floor = (np.deg2rad(floor_deg) * dist) ** 2 * np.eye(3)
    d = p1 - p2
    return bool(d @ np.linalg.solve(np.asarray(cov1) + np.asarray(cov2) + 2 * floor, d) < threshold)


CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run"]


@contextlib.contextmanager
def chromium_page(html_path, viewport=(1200, 900)):
    """The page ``html_path`` loaded in headless Chromium (Debian's, driven by playwright, never
    its own browsers; the test is skipped without them), closed on leaving. Yields (page, seen):
    ``seen["errors"]`` collects console errors and uncaught page errors, ``seen["remote"]`` every
    request that would leave the machine (not ``file:`` or ``data:``)."""
    import shutil

    import pytest

    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        pytest.skip("Debian's chromium is not installed (.ci/run installs it)")
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is in the test extra: pip install -e "
                                   "'.[test]'")
    seen: dict = {"errors": [], "remote": []}
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=browser, args=CHROMIUM_ARGS)
        try:
            page = b.new_page(viewport={"width": viewport[0], "height": viewport[1]})
            page.on("console", lambda m: seen["errors"].append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: seen["errors"].append(str(e)))
            page.on("request", lambda r: seen["remote"].append(r.url)
                    if not r.url.startswith(("file:", "data:")) else None)
            page.goto(html_path.as_uri(), wait_until="load")
            yield page, seen
        finally:
            b.close()


def screenshot_bgr(locator) -> np.ndarray:
    """A playwright element's screenshot as a BGR image (H, W, 3) uint8."""
    import cv2

    return cv2.imdecode(np.frombuffer(locator.screenshot(), np.uint8), cv2.IMREAD_COLOR)


def color_pixels(img, hex_color: str, tol: int = 40) -> int:
    """How many pixels of a BGR image are within ``tol`` (per channel) of ``hex_color``
    ('#rrggbb')."""
    r, g, b = (int(hex_color[k:k + 2], 16) for k in (1, 3, 5))
    return int(np.sum(np.all(np.abs(img.astype(int) - [b, g, r]) <= tol, axis=2)))


def run_live_device(url: str, session, rec, duration_s: float = 7.5) -> tuple[list, int, str]:
    """``wearable-gaze live --device url`` with ``session``'s camera calibration and marker map,
    recorded into ``rec``, quiet: (its JSON messages, its exit status, its stderr)."""
    import contextlib
    import json

    from wearable_gaze.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["live", "--device", url, "--camera-calib", str(session / "truth" / "camera.json"),
                     "--markers", str(session / "markers.json"), "--record", str(rec), "--duration",
                     str(duration_s), "--quiet"])
    return [json.loads(x) for x in out.getvalue().splitlines()], code, err.getvalue()


def recorded_rays(rec):
    """A live recording's eye rays (eye_rays.csv): (times (N,) s, (N, 12) both eyes' origins and
    directions)."""
    from wearable_gaze.formats.eye_rays import read_eye_rays

    r = read_eye_rays(rec / "eye_rays.csv")
    return r.t_s, np.hstack([r.left_origin_mm, r.left_direction, r.right_origin_mm, r.right_direction])
