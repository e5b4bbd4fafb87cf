"""Procedural textures: black letter strokes on a block face, drawn with OpenCV."""
from __future__ import annotations

import cv2
import numpy as np

TEXTURE_SIZE = 128
STROKE = 13  # pixels at 128 px: bold enough to read at 320x240 from the head camera


def letter_texture(letter: str, base_rgb: tuple[float, float, float], size: int = TEXTURE_SIZE,
                   stroke: int = STROKE) -> np.ndarray:
    """(size, size, 4) uint8 RGBA: ``letter`` in black, centred, on ``base_rgb``, with a thin border;
    ``stroke``: the letter's line width in pixels at 128 px (the candidate robustness axis varies it)."""
    img = np.empty((size, size, 4), np.uint8)
    img[..., :3] = (np.asarray(base_rgb) * 255).astype(np.uint8)
    img[..., 3] = 255
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, size / 36.0
    thickness = max(1, round(stroke * size / 128))
    (w, h), _ = cv2.getTextSize(letter, font, scale, thickness)
    org = ((size - w) // 2, (size + h) // 2)
    cv2.putText(img, letter, org, font, scale, (0, 0, 0, 255), thickness, cv2.LINE_AA)
    return img
