"""Everyday objects as unions of convex parts, described with numpy only (no simulator).

Each category builds a model from a variant index: size, colour and one shape parameter change
with the variant. A model is authored at rest: z up, its bottom on z = 0, centred on the origin,
its long side along x. Grasp frames say where the tool centre point (TCP) goes, in the object
frame, and along which horizontal direction the fingers close; the expert may also close along
the opposite direction (the gripper is symmetric). Parts, grasps and models are ``geometry.py``'s.

Sizes are toy-sized on purpose: every object fits the 11.2 x 9.7 cm inside a layout cell, stands
at most 7.5 cm tall and is at most 6.5 cm wide where it is grasped, and rises at most 3 cm
above the TCP (the Aloha gripper opens 9.5 cm).
"""
from __future__ import annotations

from functools import lru_cache
from typing import Callable

import numpy as np

from rsb_maniskill.objects.geometry import Q_Y, Q_Z, Grasp, ObjectModel, Part, box, ellipsoid, frustum, hull, ring

NUM_VARIANTS = 3
SCALES = (0.92, 1.0, 1.07)
MAX_HEIGHT = 0.075
MAX_GRASP_WIDTH = 0.065
MAX_ABOVE_TCP = 0.030  # the fingers' base is 3.5 cm above the TCP
TCP_BELOW_TOP = 0.015  # the pads take the top 1.5 cm and what lies below it
MIN_TCP_Z = 0.030  # fingertips 2.46 cm below the TCP stay ~5 mm above the table


def _grasp_across(width: float, top: float, x: float = 0.0, y: float = 0.0, yaw: float = np.pi / 2) -> Grasp:
    """Fingers closing across the object (along y by default) at its top, as the blocks are held."""
    return Grasp((x, y, max(MIN_TCP_Z, top - TCP_BELOW_TOP)), yaw, width)


def _round_grasps(width: float, top: float, n: int = 4) -> tuple[Grasp, ...]:
    """A round object can be held from any side: n closing directions over half a turn."""
    return tuple(_grasp_across(width, top, yaw=float(a)) for a in np.linspace(0, np.pi, n, endpoint=False))


# ---------------------------------------------------------------------- categories
# Each builder: (scale, palette colour, shape parameter in [0, 1]) -> (parts, grasps).
_Builder = Callable[[float, tuple, float], tuple[list[Part], tuple[Grasp, ...]]]

BLACK, WHITE, SILVER = (0.08, 0.08, 0.08), (0.92, 0.92, 0.9), (0.75, 0.76, 0.78)


def _toy_car(s, c, k):
    L, W = 0.080 * s, 0.038 * s
    wheel_r = 0.009 * s
    body_h = 0.018 * s
    z0 = wheel_r * 0.9
    parts = [box(L / 2, W / 2, body_h / 2, z=z0 + body_h / 2, rgb=c)]
    cab = (0.35 + 0.2 * k) * L
    parts.append(box(cab / 2, W / 2 * 0.85, 0.008 * s, x=-0.05 * L, z=z0 + body_h + 0.008 * s, rgb=(0.6, 0.8, 0.95)))
    for x in (-0.32 * L, 0.32 * L):
        for y in (-W / 2, W / 2):
            parts.append(Part("cylinder", (wheel_r, 0.004 * s), (x, y, wheel_r), Q_Y, BLACK, collide=False))
    # one collision box stands in for the four wheels (fewer contacts to solve each step); it
    # stays inside the body's width so the fingertips close on the body, not on it
    parts.append(box(0.32 * L + wheel_r, W / 2 * 0.9, z0 / 2, z=z0 / 2, visible=False))
    return parts, (_grasp_across(W, z0 + body_h + 0.01 * s),)


def _shoe(s, c, k):
    L, W = 0.088 * s, 0.036 * s
    sole = box(L / 2, W / 2, 0.005 * s, rgb=WHITE)
    h = (0.040 + 0.010 * k) * s
    upper = np.concatenate([ring(W / 2, 0.010 * s, 16, sx=L / W / 2) + [0, 0, 0],
                            ring(W / 2 * 0.8, h * 0.55, 16, sx=L / W / 2 * 0.75) + [-0.1 * L, 0, 0],
                            ring(W / 2 * 0.75, h, 12, sx=1.0) + [-0.28 * L, 0, 0]])
    parts = [sole, hull(upper, c),
             box(0.012 * s, W / 2 * 0.7, 0.0015 * s, x=-0.28 * L, z=h, rgb=BLACK, collide=False)]
    return parts, (_grasp_across(W, h, x=-0.22 * L),)


def _card_box(s, c, k):
    L, W, H = 0.066 * s, 0.046 * s, 0.020 * s
    parts = [box(L / 2, W / 2, H / 2, rgb=WHITE),
             box(L / 2 * 0.82, W / 2 * 0.78, 0.0008, z=H + 0.0008, rgb=c, collide=False),
             Part("cylinder", (0.008 * s, 0.0008), (0, 0, H + 0.0017), Q_Z, WHITE, collide=False),
             Part("sphere", (0.004 * s,), (0, 0, H + 0.001), rgb=(0.8, 0.05, 0.05), collide=False)]
    return parts, (_grasp_across(W, H),)


def _mug(s, c, k):
    r, h = 0.026 * s, 0.060 * s
    parts = [Part("cylinder", (r, h / 2), (0, 0, h / 2), Q_Z, c),
             Part("cylinder", (r * 0.85, 0.001), (0, 0, h + 0.0005), Q_Z, (0.25, 0.15, 0.1), collide=False),
             box(0.004 * s, 0.004 * s, h * 0.3, x=r + 0.012 * s, z=h * 0.5, rgb=c),
             box(0.008 * s, 0.004 * s, 0.004 * s, x=r + 0.006 * s, z=h * (0.2 + 0.05 * k), rgb=c, collide=False),
             box(0.008 * s, 0.004 * s, 0.004 * s, x=r + 0.006 * s, z=h * 0.8, rgb=c, collide=False)]
    return parts, (_grasp_across(2 * r, h),)


def _can(s, c, k):
    r, h = 0.024 * s, (0.060 + 0.006 * k) * s
    parts = [Part("cylinder", (r, h / 2), (0, 0, h / 2), Q_Z, c),
             Part("cylinder", (r * 0.98, 0.004), (0, 0, h - 0.004), Q_Z, SILVER, collide=False),
             Part("cylinder", (r * 1.002, 0.006 * s), (0, 0, h * 0.5), Q_Z, WHITE, collide=False)]
    return parts, _round_grasps(2 * r, h)


def _bottle(s, c, k):
    r, hb = 0.021 * s, (0.040 + 0.006 * k) * s
    neck = np.concatenate([ring(r, hb, 16), ring(0.008 * s, hb + 0.010 * s, 16)])
    parts = [Part("cylinder", (r, hb / 2), (0, 0, hb / 2), Q_Z, c),
             hull(neck, c),
             Part("cylinder", (0.0085 * s, 0.004 * s), (0, 0, hb + 0.014 * s), Q_Z, WHITE),
             Part("cylinder", (r * 1.003, 0.008 * s), (0, 0, hb * 0.5), Q_Z, WHITE, collide=False)]
    return parts, _round_grasps(2 * r, hb + 0.010)  # pads high on the body, the neck between them


def _book(s, c, k):
    L, W, H = 0.074 * s, 0.054 * s, (0.016 + 0.006 * k) * s
    parts = [box(L / 2, W / 2, H / 2, rgb=(0.95, 0.93, 0.85)),
             box(L / 2 + 0.001, W / 2 + 0.001, 0.0015, z=0.0015, rgb=c, collide=False),
             box(L / 2 + 0.001, W / 2 + 0.001, 0.0015, z=H - 0.0015, rgb=c, collide=False),
             box(0.0015, W / 2 + 0.001, H / 2, x=-L / 2 - 0.0005, rgb=c, collide=False)]
    return parts, (_grasp_across(W, H),)


def _banana(s, c, k):
    parts, bend = [], 0.25 + 0.1 * k
    r = 0.0105 * s
    angles = np.linspace(-2 * bend, 2 * bend, 5)
    R = 0.042 * s / np.sin(2 * bend)
    pts = np.stack([R * np.sin(angles), R * (np.cos(angles) - 1) + R * (1 - np.cos(2 * bend)) / 2], 1)
    for i in range(4):
        (x0, y0), (x1, y1) = pts[i], pts[i + 1]
        ang = np.arctan2(y1 - y0, x1 - x0)
        q = (np.cos(ang / 2), 0.0, 0.0, np.sin(ang / 2))
        rr = r * (0.8 if i in (0, 3) else 1.0)
        parts.append(Part("capsule", (rr, np.hypot(x1 - x0, y1 - y0) / 2), ((x0 + x1) / 2, (y0 + y1) / 2, r), q, c))
    parts.append(Part("sphere", (0.004 * s,), (*pts[0], r), rgb=(0.3, 0.2, 0.1), collide=False))
    parts.append(Part("sphere", (0.004 * s,), (*pts[-1], r), rgb=(0.3, 0.2, 0.1), collide=False))
    yc = float(R * (1 - np.cos(2 * bend)) / 2)
    return parts, (_grasp_across(2 * r, 2 * r, y=yc),)


def _apple(s, c, k):
    r = 0.027 * s
    pts = ellipsoid(r, r, r * 0.95, z_floor=0.004)
    parts = [hull(pts, c, visible=False),
             Part("sphere", (r,), (0, 0, r * 0.95 - 0.004), rgb=c, collide=False),
             Part("cylinder", (0.0015, 0.006), (0, 0, 1.9 * r), Q_Z, (0.35, 0.22, 0.1), collide=False),
             box(0.006, 0.003, 0.0008, x=0.005, z=1.9 * r - 0.001, rgb=(0.2, 0.6, 0.15), collide=False)]
    return parts, _round_grasps(2 * r, 1.9 * r - 0.004)


def _toy_duck(s, c, k):
    body = ellipsoid(0.030 * s, 0.021 * s, 0.015 * s, z_floor=0.003)
    head = ellipsoid(0.012 * s, 0.012 * s, 0.012 * s) + [0.015 * s, 0, 0.022 * s]
    beak_x = 0.015 * s + 0.012 * s
    parts = [hull(body, c), hull(head, c),
             box(0.006 * s, 0.005 * s, 0.0025 * s, x=beak_x + 0.003 * s, z=0.034 * s, rgb=(0.95, 0.45, 0.05)),
             Part("sphere", (0.002 * s,), (0.022 * s, 0.008 * s, 0.04 * s), rgb=BLACK, collide=False),
             Part("sphere", (0.002 * s,), (0.022 * s, -0.008 * s, 0.04 * s), rgb=BLACK, collide=False)]
    return parts, (_grasp_across(0.042 * s, 0.030 * s, x=-0.010 * s),)


def _remote(s, c, k):
    L, W, H = (0.086 + 0.006 * k) * s, 0.034 * s, 0.016 * s
    parts = [box(L / 2, W / 2, H / 2, rgb=c)]
    for i in range(3):
        for j in (-1, 1):
            parts.append(box(0.003, 0.004, 0.0008, x=-0.01 + 0.012 * i, y=0.007 * j, z=H + 0.0008,
                              rgb=(0.7, 0.7, 0.72), collide=False))
    parts.append(Part("cylinder", (0.004, 0.0008), (0.03 * s, 0, H + 0.0008), Q_Z, (0.85, 0.1, 0.1), collide=False))
    return parts, (_grasp_across(W, H),)


def _sponge(s, c, k):
    L, W, H = 0.074 * s, 0.046 * s, (0.026 + 0.006 * k) * s
    parts = [box(L / 2, W / 2, H * 0.35, rgb=c),
             box(L / 2, W / 2, H * 0.15, z=H * 0.85, rgb=(0.15, 0.55, 0.2))]
    return parts, (_grasp_across(W, H),)


def _tennis_ball(s, c, k):
    r = 0.029 * s
    pts = ellipsoid(r, r, r, z_floor=0.003, n=8)
    parts = [hull(pts, c, visible=False), Part("sphere", (r,), (0, 0, r - 0.003), rgb=c, collide=False),
             Part("capsule", (0.0015, r * 0.55), (0, 0, 2 * r - 0.0033), rgb=WHITE, collide=False)]
    return parts, _round_grasps(2 * r, 1.6 * r)


def _cup(s, c, k):
    r0, r1, h = 0.021 * s, (0.027 + 0.002 * k) * s, 0.062 * s
    parts = [hull(frustum(r0, r1, h), c),
             Part("cylinder", (r1 * 0.9, 0.0006), (0, 0, h + 0.0004), Q_Z, (0.95, 0.95, 0.95), collide=False)]
    return parts, _round_grasps(2 * r1, h)


def _bowl(s, c, k):
    r0, r1, h = 0.018 * s, 0.030 * s, (0.026 + 0.004 * k) * s
    parts = [hull(frustum(r0, r1, h), c),
             Part("cylinder", (r1 * 0.88, 0.0006), (0, 0, h + 0.0004), Q_Z, (0.97, 0.97, 0.95), collide=False)]
    return parts, _round_grasps(2 * r1, h)


def _die(s, c, k):
    a = 0.016 * s
    parts = [box(a, a, a, rgb=c)]
    pip = dict(rgb=BLACK if c != BLACK else WHITE, collide=False)
    for dx, dy in ((0, 0), (-0.5, -0.5), (0.5, 0.5)):  # three on top
        parts.append(Part("cylinder", (0.0028 * s, 0.0006), (dx * a, dy * a, 2 * a + 0.0003), Q_Z, **pip))
    for dx, dy in ((-0.5, -0.5), (0.5, 0.5), (-0.5, 0.5), (0.5, -0.5)):  # four facing -y
        parts.append(Part("cylinder", (0.0028 * s, 0.0006), (dx * a, -a - 0.0003, a + dy * a), Q_Y, **pip))
    for dx in (-0.5, 0.5):  # two facing -x
        parts.append(Part("cylinder", (0.0028 * s, 0.0006), (-a - 0.0003, dx * a, a + dx * a), (1, 0, 0, 0), **pip))
    return parts, (_grasp_across(2 * a, 2 * a), _grasp_across(2 * a, 2 * a, yaw=0.0))


def _stapler(s, c, k):
    L, W = 0.084 * s, 0.028 * s
    back = (0.028 + 0.004 * k) * s  # height of the arm's hinge end
    parts = [box(L / 2, W / 2, 0.005 * s, rgb=BLACK),
             hull(np.array([[-L / 2, -W / 2 * 0.9, 0.010 * s], [-L / 2, W / 2 * 0.9, 0.010 * s],
                             [L / 2 * 0.95, -W / 2 * 0.9, 0.014 * s], [L / 2 * 0.95, W / 2 * 0.9, 0.014 * s],
                             [-L / 2, -W / 2 * 0.9, back], [-L / 2, W / 2 * 0.9, back],
                             [L / 2 * 0.95, -W / 2 * 0.9, 0.030 * s], [L / 2 * 0.95, W / 2 * 0.9, 0.030 * s]]), c),
             box(0.006 * s, W / 2 * 0.6, 0.0025 * s, x=-L / 2 + 0.006 * s, z=0.0075 * s, rgb=SILVER)]
    return parts, (_grasp_across(W, 0.030 * s),)


def _glasses_case(s, c, k):
    L, W, H = 0.082 * s, 0.034 * s, (0.028 + 0.004 * k) * s
    pts = np.concatenate([ring(W / 2, z, 20, sx=L / W) * [1, 1, 1] for z in (0.0,)] +
                         [ring(W / 2 * 0.98, H * f, 20, sx=L / W * 0.99) for f in (0.5,)] +
                         [ring(W / 2 * 0.7, H, 20, sx=L / W * 0.92)])
    parts = [hull(pts, c), box(L / 2 * 0.9, 0.0008, 0.0008, y=-W / 2 * 0.98, z=H * 0.5, rgb=SILVER, collide=False)]
    return parts, (_grasp_across(W, H),)


def _tape_roll(s, c, k):
    r, h = 0.028 * s, (0.022 + 0.004 * k) * s
    parts = [Part("cylinder", (r, h / 2), (0, 0, h / 2), Q_Z, c),
             Part("cylinder", (r * 0.62, 0.0008), (0, 0, h + 0.0002), Q_Z, (0.8, 0.68, 0.5), collide=False),
             Part("cylinder", (r * 0.55, 0.0009), (0, 0, h + 0.0004), Q_Z, (0.15, 0.15, 0.15), collide=False)]
    return parts, _round_grasps(2 * r, h)


def _toothpaste(s, c, k):
    L, W, H = 0.076 * s, 0.030 * s, 0.018 * s
    pts = np.concatenate([ring(W / 2, 0, 12, sx=1.0, sy=1.0) * [0.5, 1, 1] + [L / 2 - 0.005, 0, 0],
                          np.array([[-L / 2, -W / 2 * 1.1, 0.002], [-L / 2, W / 2 * 1.1, 0.002],
                                    [-L / 2, -W / 2 * 1.1, 0.006], [-L / 2, W / 2 * 1.1, 0.006]]),
                          ring(W / 2, H, 12, sx=1.0, sy=1.0) * [0.5, 1, 0] + [L / 2 - 0.005, 0, H],
                          ring(W / 2 * 0.9, H * 0.9, 12) * [0.5, 1, 0] + [0, 0, H * 0.9]])
    pts[:, 2] = np.maximum(pts[:, 2], 0.0)
    parts = [hull(pts, WHITE),
             Part("cylinder", (0.009 * s, 0.008 * s), (L / 2 + 0.008 * s - 0.004, 0, 0.009 * s), rgb=c),
             box(0.012 * s, W / 2 * 0.8, 0.0006, x=0.005, z=H + 0.0006, rgb=c, collide=False)]
    return parts, (_grasp_across(W, H, x=0.005),)


def _crayon_box(s, c, k):
    L, W, H = 0.070 * s, 0.042 * s, 0.022 * s
    parts = [box(L / 2, W / 2, H / 2, rgb=c)]
    tips = ((0.9, 0.1, 0.1), (0.1, 0.3, 0.9), (0.1, 0.7, 0.2), (0.95, 0.5, 0.05), (0.6, 0.1, 0.7))
    for i, t in enumerate(tips):
        y = (-0.4 + 0.2 * i) * W
        parts.append(Part("capsule", (0.0035, 0.004), (L / 2 + 0.003, y, H * 0.55), rgb=t, collide=False))
    parts.append(box(L / 2 * 0.6, W / 2 * 0.6, 0.0006, z=H + 0.0006, rgb=(0.1, 0.4, 0.15), collide=False))
    return parts, (_grasp_across(W, H),)


def _plant_pot(s, c, k):
    r0, r1, h = 0.020 * s, 0.027 * s, 0.036 * s
    leaves = ellipsoid(0.020 * s, 0.020 * s, (0.010 + 0.003 * k) * s) + [0, 0, h - 0.004 * s]
    parts = [hull(frustum(r0, r1, h), c),
             hull(leaves, (0.15, 0.55 + 0.1 * k, 0.2))]
    return parts, _round_grasps(2 * r1, h + 0.010)


def _spray_bottle(s, c, k):
    W, D, hb = 0.044 * s, 0.030 * s, 0.040 * s
    body = np.concatenate([ring(D / 2, 0, 16, sx=W / D) , ring(D / 2, hb, 16, sx=W / D * 0.9)])
    parts = [hull(body, c),
             Part("cylinder", (0.008 * s, 0.003 * s), (0, 0, hb + 0.003 * s), Q_Z, WHITE),
             box(0.014 * s, 0.007 * s, 0.006 * s, x=0.006 * s, z=hb + 0.012 * s, rgb=WHITE),
             box(0.003 * s, 0.003 * s, 0.003 * s, x=0.021 * s, z=hb + 0.012 * s, rgb=(0.2, 0.2, 0.2), collide=False)]
    return parts, (_grasp_across(D, hb + 0.005),)


def _wallet(s, c, k):
    L, W, H = 0.078 * s, (0.046 + 0.004 * k) * s, 0.014 * s
    parts = [box(L / 2, W / 2, H / 2, rgb=c),
             box(L / 2 * 0.94, 0.0006, 0.0006, y=-W / 2 * 0.9, z=H + 0.0006, rgb=(0.85, 0.8, 0.6), collide=False),
             box(0.006, 0.008, 0.0012, x=L / 2 * 0.7, z=H + 0.0008, rgb=SILVER, collide=False)]
    return parts, (_grasp_across(W, H),)


# key -> (name in instructions, builder, colour palette of the variants)
CATEGORIES: dict[str, tuple[str, _Builder, tuple[tuple[float, float, float], ...]]] = {
    "toy_car": ("toy car", _toy_car, ((0.85, 0.1, 0.1), (0.1, 0.3, 0.85), (0.95, 0.75, 0.1))),
    "shoe": ("shoe", _shoe, ((0.15, 0.25, 0.6), (0.8, 0.15, 0.2), (0.25, 0.25, 0.25))),
    "card_box": ("box of playing cards", _card_box, ((0.7, 0.1, 0.1), (0.1, 0.2, 0.65), (0.1, 0.45, 0.2))),
    "mug": ("mug", _mug, ((0.95, 0.95, 0.92), (0.2, 0.45, 0.8), (0.85, 0.35, 0.2))),
    "can": ("soda can", _can, ((0.8, 0.05, 0.05), (0.1, 0.5, 0.2), (0.15, 0.25, 0.7))),
    "bottle": ("bottle", _bottle, ((0.2, 0.55, 0.85), (0.3, 0.65, 0.3), (0.6, 0.35, 0.15))),
    "book": ("book", _book, ((0.55, 0.1, 0.12), (0.1, 0.25, 0.5), (0.15, 0.4, 0.2))),
    "banana": ("banana", _banana, ((0.95, 0.85, 0.15), (0.9, 0.8, 0.2), (0.75, 0.85, 0.2))),
    "apple": ("apple", _apple, ((0.8, 0.08, 0.08), (0.45, 0.75, 0.2), (0.9, 0.75, 0.2))),
    "toy_duck": ("rubber duck", _toy_duck, ((0.98, 0.85, 0.1), (0.95, 0.95, 0.95), (0.95, 0.55, 0.75))),
    "remote": ("remote control", _remote, ((0.12, 0.12, 0.14), (0.45, 0.45, 0.48), (0.9, 0.9, 0.9))),
    "sponge": ("sponge", _sponge, ((0.95, 0.85, 0.3), (0.9, 0.55, 0.2), (0.45, 0.65, 0.9))),
    "tennis_ball": ("tennis ball", _tennis_ball, ((0.8, 0.9, 0.15), (0.7, 0.85, 0.2), (0.9, 0.95, 0.3))),
    "cup": ("paper cup", _cup, ((0.95, 0.95, 0.95), (0.85, 0.2, 0.2), (0.3, 0.55, 0.85))),
    "bowl": ("bowl", _bowl, ((0.9, 0.9, 0.85), (0.25, 0.45, 0.75), (0.8, 0.45, 0.25))),
    "die": ("die", _die, ((0.95, 0.95, 0.95), (0.85, 0.1, 0.1), (0.1, 0.3, 0.75))),
    "stapler": ("stapler", _stapler, ((0.15, 0.15, 0.15), (0.75, 0.1, 0.1), (0.2, 0.35, 0.7))),
    "glasses_case": ("glasses case", _glasses_case, ((0.15, 0.15, 0.2), (0.5, 0.3, 0.15), (0.6, 0.15, 0.3))),
    "tape_roll": ("roll of tape", _tape_roll, ((0.75, 0.6, 0.35), (0.2, 0.5, 0.85), (0.85, 0.25, 0.25))),
    "toothpaste": ("toothpaste tube", _toothpaste, ((0.1, 0.35, 0.8), (0.8, 0.1, 0.1), (0.1, 0.6, 0.4))),
    "crayon_box": ("box of crayons", _crayon_box, ((0.95, 0.8, 0.1), (0.1, 0.55, 0.3), (0.9, 0.45, 0.1))),
    "plant_pot": ("potted plant", _plant_pot, ((0.72, 0.36, 0.2), (0.9, 0.9, 0.88), (0.3, 0.3, 0.35))),
    "spray_bottle": ("spray bottle", _spray_bottle, ((0.2, 0.6, 0.9), (0.3, 0.75, 0.35), (0.9, 0.5, 0.7))),
    "wallet": ("wallet", _wallet, ((0.35, 0.2, 0.1), (0.1, 0.1, 0.1), (0.55, 0.4, 0.25))),
}
CATEGORY_KEYS: tuple[str, ...] = tuple(CATEGORIES)
MODEL_KEYS: tuple[str, ...] = tuple(f"{c}:{v}" for c in CATEGORY_KEYS for v in range(NUM_VARIANTS))


def category_name(key: str) -> str:
    """Instruction name of a category or model key ("mug" for "mug" or "mug:2")."""
    return CATEGORIES[key.split(":")[0]][0]


@lru_cache(maxsize=None)
def model(key: str) -> ObjectModel:
    """The model of ``"category:variant"``; deterministic, built once per process."""
    cat, _, var = key.partition(":")
    if cat not in CATEGORIES or not var.isdigit() or not 0 <= int(var) < NUM_VARIANTS:
        raise KeyError(f"unknown object {key!r}; keys look like 'mug:0' .. 'mug:{NUM_VARIANTS - 1}', "
                       f"categories: {', '.join(CATEGORY_KEYS)}")
    v = int(var)
    name, build, palette = CATEGORIES[cat]
    parts, grasps = build(SCALES[v], palette[v], v / (NUM_VARIANTS - 1))
    return ObjectModel(key, name, tuple(parts), tuple(grasps))
