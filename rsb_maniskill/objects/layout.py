"""Where candidates stand: a grid of cells in the arms' common reach, one candidate a cell,
each turned and shifted inside its cell as far as its footprint allows (no overlaps).

Cell identity, position jitter and yaw are drawn from the episode's batched RNG, so the layout
is a function of the episode seed and independent of which candidate is the answer. Numpy only:
:func:`episode_layouts` gives episodes' layouts without the simulator (the pinned episodes,
``rsb_maniskill/audit/golden.py``, digest them).
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from rsb_maniskill.objects.family import Layout

ROWS_X = 0.35  # the two rows sit at ROWS_X -/+ pitch_x / 2 (robot frame, metres)
REACH_Y = 0.63  # width of the band of cells across the table
CELL_MARGIN = 0.004  # each footprint stays this far inside its cell
_JITTER_STEPS = np.array([1.0, 0.75, 0.5, 0.25, 0.0])


def grid(layout: Layout) -> np.ndarray:
    """(C, 2) cell centres, row by row (blocks: 2 x 7 cells of 10 x 9 cm)."""
    px, py = layout.pitch
    cols = int(REACH_Y / py + 1e-6)
    ys = (np.arange(cols) - (cols - 1) / 2) * py
    return np.array([(x, y) for x in (ROWS_X - px / 2, ROWS_X + px / 2) for y in ys], dtype=np.float32)


def _extent(a: np.ndarray, b: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Half sizes along x and y of a (2a x 2b) rectangle turned by theta."""
    c, s = np.abs(np.cos(theta)), np.abs(np.sin(theta))
    return a * c + b * s, a * s + b * c


Draws = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def draw(rng: Any, layout: Layout, n: int) -> Draws:
    """What a layout draws, in this order: cells (n), position jitter (n, 2), yaw jitter (n) and
    base-yaw choice (n), each with a leading env dimension when ``rng`` is ManiSkill's batched
    episode RNG (a ``RandomState`` per env), without when it is one ``RandomState``."""
    slots = rng.permutation(len(grid(layout)))[..., :n]
    u_pos = rng.uniform(-1.0, 1.0, size=(n, 2))
    u_yaw = rng.uniform(-1.0, 1.0, size=(n,))
    u_base = rng.randint(0, len(layout.yaw_choices), size=(n,))
    return slots, u_pos, u_yaw, u_base


def place(rng: Any, layout: Layout, half_extents: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cells (b, N), positions (b, N, 2) and yaws (b, N) for candidates with footprint half sizes
    ``half_extents`` (b, N, 2). ``rng`` is ManiSkill's batched episode RNG of the envs placed."""
    return arrange(draw(rng, layout, half_extents.shape[1]), layout, half_extents)


def arrange(draws: Draws, layout: Layout, half_extents: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cells, positions and yaws from the draws of ``b`` episodes (leading dimension b) and the
    candidates' footprints (b, N, 2): the geometry, no randomness."""
    cells = grid(layout)
    slots, u_pos, u_yaw, u_base = draws
    cx, cy = layout.pitch[0] / 2 - CELL_MARGIN, layout.pitch[1] / 2 - CELL_MARGIN
    hx, hy = half_extents[..., 0], half_extents[..., 1]

    # base yaw: the drawn choice if the footprint fits the cell that way, else the next that fits
    choices = np.asarray(layout.yaw_choices)
    base = np.full(hx.shape, np.nan)
    for shift in range(len(choices)):
        cand = choices[(u_base + shift) % len(choices)]
        ex, ey = _extent(hx, hy, cand)
        ok = np.isnan(base) & (ex <= cx + 1e-9) & (ey <= cy + 1e-9)
        base[ok] = cand[ok]
    if np.isnan(base).any():
        raise ValueError(f"a candidate footprint {half_extents[np.isnan(base)][0]} does not fit a "
                         f"{layout.pitch} m cell in any of the yaws {layout.yaw_choices}")
    a = np.where(np.isclose(np.abs(np.sin(base)), 1.0), hy, hx)  # half size along x after the base turn
    b = np.where(np.isclose(np.abs(np.sin(base)), 1.0), hx, hy)

    # yaw jitter: the largest step of yaw_jitter that still fits
    theta_max = np.zeros(hx.shape)
    for f in _JITTER_STEPS[::-1]:
        ex, ey = _extent(a, b, np.full(hx.shape, f * layout.yaw_jitter))
        theta_max = np.where((ex <= cx) & (ey <= cy), f * layout.yaw_jitter, theta_max)
    theta = u_yaw * theta_max
    ex, ey = _extent(a, b, theta)
    slack = np.stack([np.clip(cx - ex, 0, None), np.clip(cy - ey, 0, None)], -1)
    xy = cells[slots] + u_pos * np.minimum(layout.pos_jitter, slack)
    return slots, xy.astype(np.float32), (base + theta).astype(np.float32)


def episode_layouts(family: Any, candidates: Sequence[Sequence[str]],
                    seeds: Sequence[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`place` for the episodes ``seeds`` whose candidates are ``candidates`` (asset keys of
    ``family``), without the simulator: at a seeded reset ManiSkill's episode RNG of an env is
    ``np.random.RandomState(seed)``, so reseeding one such generator per episode draws the same
    numbers. Footprints are the family's shapes, as the task's candidate pool reads them."""
    rng = np.random.RandomState()
    draws = []
    for seed in seeds:
        rng.seed(int(seed))
        draws.append(draw(rng, family.layout, len(candidates[0])))
    shapes = {k: family.shape(k).half_extents for k in {k for keys in candidates for k in keys}}
    half = np.array([[shapes[k] for k in keys] for keys in candidates], dtype=np.float32)
    return arrange(tuple(np.stack(d) for d in zip(*draws)), family.layout, half)
