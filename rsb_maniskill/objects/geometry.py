"""Object geometry as numpy: convex parts, grasp frames and the model they make (no simulator).

The vocabulary of ``catalog.py``'s everyday objects, read by the families (``family.py``), the
actor builder (``everyday.py``) and the expert: a :class:`Part` is one convex collision or visual
piece, a :class:`Grasp` where the TCP goes and how the fingers close, an :class:`ObjectModel` the
parts and grasps of one object with its footprint and height. The point helpers below build
parts' vertices (rings, frustums, ellipsoids).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

DENSITY = 400.0  # kg/m^3: light enough for the gripper, heavy enough to rest

Q_Y = (0.70710678, 0.0, 0.0, 0.70710678)  # part x axis -> y (cylinders and capsules run along x)
Q_Z = (0.70710678, 0.0, -0.70710678, 0.0)  # part x axis -> z


@dataclass(frozen=True)
class Part:
    """One convex piece. ``dims``: box half sizes; cylinder and capsule (radius, half length)
    along the part's x axis; sphere (radius,); hull: flat xyz points of its vertices."""

    shape: str
    dims: tuple[float, ...]
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    rgb: tuple[float, float, float] = (0.5, 0.5, 0.5)
    collide: bool = True
    visible: bool = True


@dataclass(frozen=True)
class Grasp:
    """TCP position in the object frame and the fingers' closing direction (yaw in the object's
    xy plane); ``width`` is the object's width between the pads."""

    pos: tuple[float, float, float]
    yaw: float
    width: float


@dataclass(frozen=True)
class ObjectModel:
    """One object: its parts and grasps; the footprint and height follow from the collision parts."""

    key: str  # "mug:1"
    name: str  # "mug"
    parts: tuple[Part, ...]
    grasps: tuple[Grasp, ...]
    density: float = DENSITY
    half_extents: tuple[float, float] = field(init=False)  # footprint (x, y) half sizes
    height: float = field(init=False)

    def __post_init__(self) -> None:
        pts = np.concatenate([part_points(p) for p in self.parts if p.collide])
        lo, hi = pts.min(0), pts.max(0)
        if abs(lo[2]) > 2e-3:
            raise ValueError(f"{self.key}: collision bottom at z = {lo[2]:.4f}, must rest on z = 0")
        object.__setattr__(self, "half_extents", (float(max(-lo[0], hi[0])), float(max(-lo[1], hi[1]))))
        object.__setattr__(self, "height", float(hi[2]))


# ---------------------------------------------------------------------- point and part helpers
def rot(q: tuple[float, ...]) -> np.ndarray:
    """The rotation matrix of a (w, x, y, z) quaternion."""
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def part_points(p: Part) -> np.ndarray:
    """Points on the part's surface (exact corners for boxes and hulls), in the object frame."""
    if p.shape == "box":
        local = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * p.dims
    elif p.shape in ("cylinder", "capsule"):
        r, h = p.dims
        a = np.linspace(0, 2 * np.pi, 24, endpoint=False)
        circle = np.stack([np.zeros_like(a), r * np.cos(a), r * np.sin(a)], 1)
        local = np.concatenate([circle + [-h, 0, 0], circle + [h, 0, 0]])
        if p.shape == "capsule":
            local = np.concatenate([local, [[-h - r, 0, 0], [h + r, 0, 0]]])
    elif p.shape == "sphere":
        local = np.concatenate([np.eye(3), -np.eye(3)]) * p.dims[0]
    elif p.shape == "hull":
        local = np.asarray(p.dims, dtype=float).reshape(-1, 3)
    else:
        raise ValueError(f"unknown part shape {p.shape!r}")
    return local @ rot(p.quat).T + np.asarray(p.pos)


def ring(r: float, z: float, n: int = 24, sx: float = 1.0, sy: float = 1.0) -> np.ndarray:
    """n points of a horizontal circle of radius r at height z (an ellipse when scaled by sx, sy)."""
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.stack([sx * r * np.cos(a), sy * r * np.sin(a), np.full_like(a, z)], 1)


def hull(points: np.ndarray, rgb, pos=(0.0, 0.0, 0.0), collide=True, visible=True) -> Part:
    """The convex hull of ``points`` as a part (vertices rounded to 1e-6 m)."""
    return Part("hull", tuple(np.round(np.asarray(points, float).reshape(-1), 6)), pos, rgb=rgb,
                collide=collide, visible=visible)


def frustum(r0: float, r1: float, h: float, z0: float = 0.0, n: int = 24, sx: float = 1.0) -> np.ndarray:
    """Points of a truncated cone: radius r0 at height z0, r1 at z0 + h."""
    return np.concatenate([ring(r0, z0, n, sx), ring(r1, z0 + h, n, sx)])


def ellipsoid(ax: float, ay: float, az: float, z_floor: float = 0.0, n: int = 12) -> np.ndarray:
    """Points of an ellipsoid resting on z = 0, its bottom cut flat ``z_floor`` up (so it does not roll)."""
    pts = []
    for t in np.linspace(0, np.pi, n):
        for a in np.linspace(0, 2 * np.pi, 2 * n, endpoint=False):
            pts.append((ax * np.sin(t) * np.cos(a), ay * np.sin(t) * np.sin(a), az + az * np.cos(t)))
    pts = np.array(pts)
    pts[:, 2] = np.maximum(pts[:, 2], z_floor) - z_floor
    return pts


def box(hx, hy, hz, x=0.0, y=0.0, z=None, rgb=(0.5, 0.5, 0.5), **kw) -> Part:
    """A box part of half sizes (hx, hy, hz), resting on z = 0 unless its centre height z is given."""
    return Part("box", (hx, hy, hz), (x, y, hz if z is None else z), rgb=rgb, **kw)
