"""Letter textures on block faces (objects/textures.py): the base colour, a black letter in the middle,
the stroke width the candidate robustness axis varies."""
from __future__ import annotations

import numpy as np

from rsb_maniskill.objects.textures import STROKE, TEXTURE_SIZE, letter_texture


def _dark(img: np.ndarray) -> int:
    return int((img[..., :3].max(axis=-1) < 60).sum())


def test_base_colour_opaque_and_a_black_letter_in_the_middle():
    img = letter_texture("A", (0.2, 0.6, 1.0))
    assert img.shape == (TEXTURE_SIZE, TEXTURE_SIZE, 4) and img.dtype == np.uint8
    assert (img[..., 3] == 255).all()
    assert tuple(img[2, 2, :3]) == (51, 153, 255)  # a corner: the base colour
    ys, xs = np.nonzero(img[..., :3].max(axis=-1) < 60)  # the letter's black strokes
    assert len(ys) > 0.05 * TEXTURE_SIZE**2
    margin = TEXTURE_SIZE // 8
    assert min(ys.min(), xs.min()) >= margin and max(ys.max(), xs.max()) < TEXTURE_SIZE - margin
    assert abs(ys.mean() - TEXTURE_SIZE / 2) < 12 and abs(xs.mean() - TEXTURE_SIZE / 2) < 12  # centred


def test_letters_differ_and_a_wider_stroke_darkens_more():
    a, b = letter_texture("A", (1, 1, 1)), letter_texture("B", (1, 1, 1))
    assert not np.array_equal(a, b)
    assert _dark(letter_texture("A", (1, 1, 1), stroke=STROKE // 2)) < _dark(a) < _dark(
        letter_texture("A", (1, 1, 1), stroke=2 * STROKE))


def test_the_stroke_scales_with_the_texture_size():
    small, large = letter_texture("C", (1, 1, 1), size=64), letter_texture("C", (1, 1, 1), size=256)
    ratio = (_dark(large) / 256**2) / (_dark(small) / 64**2)  # the same share of the face is ink
    assert 0.7 < ratio < 1.3
