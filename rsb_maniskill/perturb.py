"""Robustness axes: their names, their levels and what each level does (a leaf: numpy only).

One owner for the env (``perturb={"camera": 2}``), the semantic sampler (the language axes), the
evaluator (``rsb eval --perturb camera=2``, ``--sweep camera``) and the audit. Level 0 is today's
episode, byte for byte; levels 1-3 perturb more and more. Every value an axis draws is a function
of (suite, split, seed, axis, level) only (``semantic.stable.axis_rng``, the generators these
draw functions are given), never of the layout's RNG, so the same seed keeps its question, answer
and layout at every level and the levels compare like with like. See docs/robustness.md.
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

LEVELS: tuple[int, ...] = (0, 1, 2, 3)
# What the robot sees and where it starts; none changes the question or the candidates' identity.
VISUAL_AXES: dict[str, str] = {
    "camera": "head-camera pose: position and orientation jitter",
    "lighting": "light intensity, direction and colour",
    "table": "table (the background of every camera) colour",
    "clutter": "non-candidate flat everyday objects in free cells (never named, never in the answer zone)",
    "noise": "Gaussian noise on the rgb and depth images",
    "candidate": "candidate appearance: block shade, letter stroke, object colour",
    "robot_init": "robot initial joint state",
}
# How the instruction is worded; none changes the question, the options or which one is correct.
LANGUAGE_AXES: dict[str, str] = {
    "lang_reference": "candidates referred to by synonyms and descriptions (\"the crimson cube\")",
    "lang_layout": "option layout (\"option A: 12\", \"A <- 12\", \"12 is A\")",
    "lang_distractor": "irrelevant sentences added",
    "lang_order": "the question placed after the options",
}
AXES: dict[str, str] = {**VISUAL_AXES, **LANGUAGE_AXES}

# Magnitudes per level (index = level).
CAMERA_SHIFT = (0.0, 0.015, 0.03, 0.05)  # m, each axis of the head camera's position
CAMERA_TURN = (0.0, 0.025, 0.05, 0.08)  # rad, each of roll / pitch / yaw
LIGHT_GAIN = ((1.0, 1.0), (0.75, 1.3), (0.5, 1.6), (0.3, 2.0))  # intensity factor range
LIGHT_TILT = (0.0, 0.25, 0.5, 0.8)  # rad, main light direction
LIGHT_TINT = (0.0, 0.1, 0.2, 0.35)  # per-channel colour factor deviation
TABLE_MIX = (0.0, 0.3, 0.6, 0.9)  # how far the table colour moves towards a drawn colour
TABLE_PALETTE = ((0.85, 0.82, 0.78), (0.35, 0.22, 0.14), (0.55, 0.58, 0.62), (0.20, 0.30, 0.45),
                 (0.45, 0.55, 0.35), (0.75, 0.62, 0.50), (0.15, 0.15, 0.17), (0.70, 0.45, 0.40))
CLUTTER_COUNT = (0, 1, 2, 4)  # flat objects on the table
NOISE_RGB = (0.0, 3.0, 8.0, 16.0)  # std of the rgb noise, 0-255 scale
NOISE_DEPTH = (0.0, 2.0, 5.0, 10.0)  # std of the depth noise, mm
CANDIDATE_SHADE = (0.0, 0.12, 0.22, 0.35)  # brightness factor deviation (colour names stay true)
CANDIDATE_STROKE = ((13, 13), (10, 16), (8, 18), (6, 20))  # letter stroke range (px at 128 px)
OBJECT_RECOLOUR = (0.0, 0.2, 0.4, 0.6)  # how far an object's parts move towards a drawn colour
ROBOT_JOINT_JITTER = (0.0, 0.03, 0.06, 0.10)  # rad, each arm joint's start from the rest pose


class PerturbError(ValueError):
    """A perturbation that does not exist: the message names the fix."""


def check_axis(axis: str) -> str:
    if axis not in AXES:
        raise PerturbError(f"unknown perturbation axis {axis!r}; valid: {', '.join(AXES)}")
    return axis


def check_level(axis: str, level: Any) -> int:
    if isinstance(level, bool) or not isinstance(level, (int, np.integer, str)) or str(level).strip() not in {
            str(v) for v in LEVELS}:
        raise PerturbError(f"perturbation level of {axis!r} must be one of {', '.join(map(str, LEVELS))}, "
                           f"got {level!r}")
    return int(level)


def parse_perturb(value: Mapping[str, Any] | str | None) -> dict[str, int]:
    """``{"camera": 2}``, ``"camera=2,noise=1"`` or None -> the axes at a level above 0, checked.

    Level 0 entries are dropped: level 0 is the unperturbed episode. PerturbError names the fix."""
    if value is None:
        return {}
    if isinstance(value, str):
        items = {}
        for part in filter(None, (p.strip() for p in value.split(","))):
            axis, sep, level = part.partition("=")
            if not sep:
                raise PerturbError(f"perturbation {part!r} must look like AXIS=LEVEL (e.g. camera=2)")
            if axis.strip() in items:
                raise PerturbError(f"axis {axis.strip()!r} is given twice ({axis.strip()}={items[axis.strip()]} and "
                                   f"{part}): give each axis one level")
            items[axis.strip()] = level.strip()
        value = items
    if not isinstance(value, Mapping):
        raise PerturbError(f"perturb must be a dict like {{'camera': 2}}, got {type(value).__name__}")
    out = {}
    for axis, level in value.items():
        lv = check_level(check_axis(axis), level)
        if lv:
            out[axis] = lv
    return out


def visual(perturb: Mapping[str, int]) -> dict[str, int]:
    return {a: lv for a, lv in perturb.items() if a in VISUAL_AXES}


def language(perturb: Mapping[str, int]) -> dict[str, int]:
    return {a: lv for a, lv in perturb.items() if a in LANGUAGE_AXES}


def label(perturb: Mapping[str, int]) -> str:
    """``{"camera": 2}`` -> ``"camera=2"``; no perturbation -> ``"none"`` (a record's ``perturb`` key)."""
    return ",".join(f"{a}={lv}" for a, lv in sorted(perturb.items())) or "none"


# ---------------------------------------------------------------------------------- visual draws
def camera_offset(rng: np.random.Generator, level: int) -> tuple[np.ndarray, np.ndarray]:
    """(xyz shift in m, roll / pitch / yaw in rad) of the head camera in its mount's frame (x forward:
    never backwards, into the camera's housing)."""
    shift = rng.uniform(-1, 1, 3) * CAMERA_SHIFT[level]
    shift[0] = abs(shift[0])
    return shift, rng.uniform(-1, 1, 3) * CAMERA_TURN[level]


def lighting(rng: np.random.Generator, level: int) -> dict[str, np.ndarray | float]:
    """Intensity factor, colour factors (3) and the tilt (two angles) of the main light."""
    lo, hi = LIGHT_GAIN[level]
    gain = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
    tint = 1.0 + rng.uniform(-1, 1, 3) * LIGHT_TINT[level]
    tilt = rng.uniform(-1, 1, 2) * LIGHT_TILT[level]
    return dict(gain=gain, tint=tint / tint.max(), tilt=tilt)


def table_colour(rng: np.random.Generator, level: int, base: tuple[float, ...]) -> np.ndarray:
    target = np.asarray(TABLE_PALETTE[int(rng.integers(len(TABLE_PALETTE)))])
    return (1 - TABLE_MIX[level]) * np.asarray(base[:3]) + TABLE_MIX[level] * target


def shade_factor(rng: np.random.Generator, level: int) -> float:
    """A block's brightness factor: its hue, and so its colour name, stays."""
    return float(1.0 + rng.uniform(-1, 1) * CANDIDATE_SHADE[level])


def letter_stroke(rng: np.random.Generator, level: int) -> int:
    lo, hi = CANDIDATE_STROKE[level]
    return int(rng.integers(lo, hi + 1))


def recolour(rng: np.random.Generator, level: int, rgb: np.ndarray) -> np.ndarray:
    """An everyday object's part colour moved towards a drawn colour (names say no colour)."""
    target = rng.uniform(0.05, 0.95, 3)
    return (1 - OBJECT_RECOLOUR[level]) * np.asarray(rgb) + OBJECT_RECOLOUR[level] * target


def joint_offsets(rng: np.random.Generator, level: int, n: int) -> np.ndarray:
    return rng.uniform(-1, 1, n) * ROBOT_JOINT_JITTER[level]
