"""Sensor noise, exposure and 8-bit quantisation of rendered frames (grey levels 0-255)."""

from __future__ import annotations

import cv2
import numpy as np


class SensorNoise:
    """Gaussian sensor noise (grey levels) for a stream of frames.

    Drawing 10^6 normal deviates per frame costs more than rendering it, so one bank twice the
    frame's size is drawn from the seeded generator and each frame takes a window at a random
    offset: per-pixel noise with the right distribution, fixed by the seed.
    """

    def __init__(self, image_size: tuple[int, int], rng: np.random.Generator, std: float = 2.0):
        w, h = image_size
        self.size = (int(w), int(h))
        self.std = float(std)
        self.rng = rng
        self.bank = (rng.standard_normal((2 * h, 2 * w), dtype=np.float32) * np.float32(std)
                     if std > 0 else None)

    def apply(self, img: np.ndarray, gain: float = 1.0) -> np.ndarray:
        """``img * gain + noise``, rounded and saturated to uint8 (H, W)."""
        h, w = img.shape[:2]
        if self.bank is None:
            return cv2.convertScaleAbs(img, alpha=gain)
        oy, ox = self.rng.integers(0, self.bank.shape[0] - h), self.rng.integers(0, self.bank.shape[1] - w)
        return cv2.addWeighted(img, float(gain), self.bank[oy:oy + h, ox:ox + w], 1.0, 0.0, dtype=cv2.CV_8U)


def finish(img: np.ndarray, rng: np.random.Generator | None = None, noise_std: float = 2.0,
           gain: float = 1.0) -> np.ndarray:
    """Exposure (``gain``), Gaussian sensor noise (grey levels) and 8-bit quantisation."""
    out = img * gain
    if rng is not None and noise_std > 0:
        out = out + rng.normal(0.0, noise_std, size=out.shape).astype(np.float32)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)
