"""ArUco head tracking speed on one core: detection (markers found at half size, corners refined
at full size: cornerSubPix and edge lines) and the joint pose (SQPnP + RANSAC + LM, covariance)
per 1280x720 frame of a
rendered lab-walkabout session, against OpenCV's default detector settings with the same pose
step, measured in the same run. Decoding the video is not counted.

    python benchmarks/bench_tracking.py [--frames 150]

Target (issue 5): >= 60 frames per second, detection and pose included.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import _onecore  # noqa: F401  (first: pins one core before numpy and OpenCV load)
import cv2
import numpy as np
from _args import size_and_seed

from tracking.markers import MarkerDetector, detection
from tracking.pose import MarkerPoseEstimator, rotation_angle_deg
from wearable_gaze.formats.camera import load_camera
from wearable_gaze.formats.markermap import load_marker_map
from wearable_gaze.formats.poses import read_poses_csv
from wearable_gaze.formats.session import load_session
from wearable_gaze.formats.video import gray_frames
from wearable_gaze.sim.simulate import simulate_scenario


def main():
    args = size_and_seed(__doc__, "--frames", int, 150, 4, "frames tracked")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "s"
        simulate_scenario({"base": "lab-walkabout", "duration_s": args.frames / 30.0,
                           "calibration": {"eye": False, "camera_views": 0}}, root, args.seed)
        s = load_session(root)
        cam = load_camera(root / "truth" / "camera.json")
        mm = load_marker_map(s.path("marker_map"))
        _, _, T_true, _ = read_poses_csv(root / "truth" / "head_poses.csv")
        frames = list(gray_frames(s.path("scene_video")))

    def run(detector):
        est = MarkerPoseEstimator(mm, cam)
        rot, tr, n_markers = [], [], []
        t0 = time.perf_counter()
        results = [est.estimate(detector.detect(f)) for f in frames]
        dt = (time.perf_counter() - t0) / len(frames)
        for r, T in zip(results, T_true, strict=True):
            if r.ok:
                rot.append(rotation_angle_deg(r.T_world_from_cam[:3, :3], T[:3, :3]))
                tr.append(np.linalg.norm(r.T_world_from_cam[:3, 3] - T[:3, 3]))
                n_markers.append(len(r.markers))
        return dt, np.array(rot), np.array(tr), np.mean(n_markers), len(rot)

    class OpenCVDefault:
        """The baseline: cv2.aruco.ArucoDetector with default parameters and SUBPIX, full size."""

        def __init__(self):
            p = cv2.aruco.DetectorParameters()
            p.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
            self.det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, mm.dictionary)), p)

        def detect(self, gray):
            c, ids, _ = self.det.detectMarkers(gray)
            # every detection, as MarkerDetector.detect returns them
            return [] if ids is None else [detection(i, q.reshape(4, 2)) for i, q in zip(ids.ravel(), c, strict=True)]

    ours = run(MarkerDetector(mm.dictionary))
    base = run(OpenCVDefault())
    print(f"ArUco tracking, 1280x720, one core, {len(frames)} frames of lab-walkabout")
    for name, (dt, rot, tr, nm, n) in (("ours (edges)", ours), ("OpenCV default + SUBPIX", base)):
        print(f"  {name:<24} {dt * 1e3:6.1f} ms/frame = {1 / dt:6.1f} fps; posed {n}/{len(frames)}, "
              f"{nm:.1f} markers; rotation error median {np.median(rot):.3f} deg, translation median "
              f"{np.median(tr):.2f} mm")
    print(f"  speed-up {base[0] / ours[0]:.2f}x; target >= 60 fps: {'PASS' if 1 / ours[0] >= 60 else 'FAIL'}")


if __name__ == "__main__":
    main()
