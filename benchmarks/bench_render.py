"""Renderer speed on one core: frames of the lab-walkabout session (1280x720, distorted wide
camera, room of six textured planes, 24 markers, target cards, sensor noise), against the
per-pixel path for every plane (no undistorted canvas for the walls) measured in the same run.

    python benchmarks/bench_render.py [--frames 150] [--resolution 1280x720]

Target (issue 3): >= 50 frames per second at 1280x720 on one core.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import _onecore  # noqa: F401  (first: pins one core before numpy and OpenCV load)
import numpy as np

from wearable_gaze.sim.motion import make_motion
from wearable_gaze.sim.noise import SensorNoise
from wearable_gaze.sim.render import render
from wearable_gaze.sim.scenario import resolve
from wearable_gaze.sim.simulate import build_world, make_targets, scene_camera


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--resolution", default="1280x720")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    w, h = (int(v) for v in args.resolution.split("x"))
    scn = resolve("lab-walkabout", resolution=(w, h))
    rng = np.random.default_rng(args.seed)
    cam = scene_camera(scn)
    targets = make_targets(scn, rng)
    world = build_world(scn, rng, targets)
    dur = args.frames / scn["camera"]["fps"]
    motion = make_motion(scn["head"], dur, rng, lambda t: np.tile(targets[0].at(0.0), (len(t), 1)))
    t_frames = np.arange(args.frames) / scn["camera"]["fps"]
    poses = motion.poses(t_frames)
    noise = SensorNoise(cam.image_size, rng)
    render(cam, poses[0], world.planes_at(0.0))           # build the per-camera caches once

    def run(planes_at, n):
        t0 = time.perf_counter()
        for i in range(n):
            noise.apply(render(cam, poses[i], planes_at(t_frames[i])))
        return (time.perf_counter() - t0) / n

    per_frame = run(world.planes_at, args.frames)
    flat = [dataclasses.replace(p, shell=False) if p.shell else p for p in world.planes]

    def planes_flat(t):
        return flat + [tg.plane(t) for tg in world.targets]

    n_base = max(args.frames // 5, 5)
    base = run(planes_flat, n_base)
    fps = 1 / per_frame
    print(f"renderer, {w}x{h}, one core, {args.frames} frames of lab-walkabout "
          f"({len(world.planes)} static planes, {len(world.markers)} markers)")
    print(f"  this renderer:        {per_frame * 1e3:7.1f} ms/frame = {fps:6.1f} fps")
    print(f"  per-pixel baseline:   {base * 1e3:7.1f} ms/frame = {1 / base:6.1f} fps  ({n_base} frames)")
    print(f"  speed-up: {base / per_frame:.1f}x; target >= 50 fps: {'PASS' if fps >= 50 else 'FAIL'}")


if __name__ == "__main__":
    main()
