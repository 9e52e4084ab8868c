"""Procedural grey textures (H, W) uint8 for the simulated world: plaster and carpet noise, a
feature-rich poster, a gaze-target card, a chessboard."""

from __future__ import annotations

import cv2
import numpy as np


def noise_texture(rng: np.random.Generator, size_px: tuple[int, int], blob_px: float = 8.0,
                  contrast: float = 45.0, mean: float = 140.0) -> np.ndarray:
    """Smooth random texture (H, W) uint8 (plaster, carpet): Gaussian noise low-passed to blobs
    of about ``blob_px`` texels, so walls have texture for feature matching but no false
    markers."""
    w, h = size_px
    small = rng.standard_normal((max(h // 4, 2), max(w // 4, 2))).astype(np.float32)
    tex = cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
    tex = cv2.GaussianBlur(tex, (0, 0), blob_px / 4)
    tex *= contrast / (tex.std() + 1e-6)
    return np.clip(tex + mean, 0, 255).astype(np.uint8)


def poster_texture(rng: np.random.Generator, size_px: tuple[int, int]) -> np.ndarray:
    """A feature-rich poster (H, W) uint8: random filled shapes, lines and text on a light
    ground (for the homography tracker and for realism)."""
    w, h = size_px
    img = np.full((h, w), int(rng.integers(190, 235)), np.uint8)
    for _ in range(40):
        c = int(rng.integers(0, 255))
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        r = int(rng.integers(max(w // 40, 2), max(w // 8, 3)))
        kind = rng.integers(0, 3)
        if kind == 0:
            cv2.circle(img, (x, y), r, c, -1, cv2.LINE_AA)
        elif kind == 1:
            cv2.rectangle(img, (x, y), (x + r, y + int(rng.integers(r // 2 + 1, 2 * r + 2))), c, -1)
        else:
            cv2.line(img, (x, y), (int(rng.integers(0, w)), int(rng.integers(0, h))), c,
                     max(w // 150, 1), cv2.LINE_AA)
    for i in range(4):
        txt = "".join(chr(int(rng.integers(65, 91))) for _ in range(6))
        cv2.putText(img, txt, (w // 12, (i + 1) * h // 5), cv2.FONT_HERSHEY_SIMPLEX, w / 500, 20,
                    max(w // 250, 1), cv2.LINE_AA)
    return img


def target_texture(px: int = 128) -> np.ndarray:
    """A gaze-target card (px, px) uint8: a bullseye on white."""
    img = np.full((px, px), 245, np.uint8)
    c = (px // 2, px // 2)
    for r, col in [(0.45, 30), (0.33, 245), (0.2, 30), (0.07, 245)]:
        cv2.circle(img, c, int(r * px), col, -1, cv2.LINE_AA)
    return img


def chessboard_texture(cols: int, rows: int, px_per_square: int = 40) -> np.ndarray:
    """A chessboard with ``cols`` x ``rows`` inner corners, one white square of margin around it:
    (rows + 3) x (cols + 3) squares, uint8."""
    sq = np.indices((rows + 1, cols + 1)).sum(axis=0) % 2
    board = np.where(sq == 0, 0, 255).astype(np.uint8)
    board = cv2.copyMakeBorder(board, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=255)
    return cv2.resize(board, None, fx=px_per_square, fy=px_per_square, interpolation=cv2.INTER_NEAREST)
