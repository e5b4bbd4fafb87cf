"""Generates the Aloha-AgileX URDF and SRDFs from a kinematic table.

The chain is the RoboTwin 2.0 aloha-agilex arm (two ARX5-style 6-DoF arms, the joint table below);
geometry is primitive boxes and cylinders so that SAPIEN and mplib load the robot without meshes.
The committed files under ``rsb_maniskill/assets/aloha_agilex/`` are the output of
``python -m rsb_maniskill.agents.aloha_urdf`` and a test checks that they match this generator.

Frames: the robot root ``base_link`` sits on the table top (z = 0) at the near edge, facing +x;
the left arm (``fl_``) is at +y, the right arm (``fr_``) at -y.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rsb_maniskill.robot import ARMS, FINGER_TRAVEL, PREFIX

ASSET_DIR = Path(__file__).resolve().parent.parent / "assets" / "aloha_agilex"
URDF_NAME = "aloha_agilex.urdf"
SRDF_NAME = "aloha_agilex.srdf"  # read by SAPIEN beside the URDF (at most 31 pairs)
MPLIB_SRDF_NAME = "aloha_agilex_mplib.srdf"  # full never-collide list for mplib

ARM_PREFIXES = tuple(PREFIX[a] for a in ARMS)  # the contract's joint-name prefixes
ARM_BASE_XYZ = {"fl": (0.0, 0.30, 0.04), "fr": (0.0, -0.30, 0.04)}
HEAD_CAMERA_XYZ = (-0.05, 0.0, 0.62)
HEAD_CAMERA_LOOK = (0.5, 0.0, -0.866)  # 60 degrees down: blocks and zone fill the view
WRIST_CAMERA_XYZ = (0.07, 0.032, 0.065)
WRIST_CAMERA_PITCH = 0.4
TCP_OFFSET = 0.12  # along link6 x

LINK_DENSITY = 900.0  # kg/m^3: hollow aluminium links average out light
FINGER_DENSITY = 1200.0
DRIVE_DAMPING = 0.0  # URDF <dynamics>; ManiSkill controllers set the drive gains

# (name, type, xyz, rpy, axis, (lower, upper)) of one arm; RoboTwin chain, ARX5-like limits.
ARM_JOINTS = (
    ("joint1", "revolute", (0.0, 0.0, 0.058), (0.0, 0.0, 0.0), (0, 0, 1), (-2.6, 2.6)),
    ("joint2", "revolute", (0.025013, 0.00060169, 0.042), (0.0, 0.0, 0.0), (0, 1, 0), (0.0, 3.14)),
    ("joint3", "revolute", (-0.26396, 0.0044548, 0.0), (-3.1416, 0.0, -0.015928), (0, 1, 0), (0.0, 3.14)),
    ("joint4", "revolute", (0.246, -0.00025, -0.06), (0.0, 0.0, 0.0), (0, 1, 0), (-1.67, 1.67)),
    ("joint5", "revolute", (0.06775, 0.0015, -0.0855), (0.0, 0.0, -0.015928), (0, 0, 1), (-1.67, 1.67)),
    ("joint6", "revolute", (0.03095, 0.0, 0.0855), (-3.1416, 0.0, 0.0), (1, 0, 0), (-1.57, 1.57)),
    ("joint7", "prismatic", (0.08457, 0.024493, 0.0), (0.0, 0.0, 0.0), (0, 1, 0), (0.0, FINGER_TRAVEL)),
    ("joint8", "prismatic", (0.08457, -0.024496, 0.0), (0.0, 0.0, 0.0), (0, -1, 0), (0.0, FINGER_TRAVEL)),
)
JOINT_EFFORT = {"revolute": 60.0, "prismatic": 40.0}
JOINT_VELOCITY = {"revolute": 3.14, "prismatic": 0.2}

COLORS = {
    "body": (0.22, 0.24, 0.28, 1.0),
    "mount": (0.35, 0.36, 0.40, 1.0),
    "arm": (0.12, 0.12, 0.13, 1.0),
    "joint": (0.55, 0.56, 0.60, 1.0),
    "gripper": (0.70, 0.71, 0.74, 1.0),
    "pad": (0.15, 0.15, 0.15, 1.0),
    "camera": (0.05, 0.05, 0.06, 1.0),
}


@dataclass
class Shape:
    """A primitive: ``box`` (size) or ``cylinder`` (radius, length along its local z)."""

    kind: str
    dims: tuple[float, ...]
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    color: str = "arm"
    collide: bool = True

    def volume(self) -> float:
        if self.kind == "box":
            return float(np.prod(self.dims))
        r, h = self.dims
        return math.pi * r * r * h

    def local_inertia(self, mass: float) -> np.ndarray:
        if self.kind == "box":
            x, y, z = self.dims
            return mass / 12.0 * np.diag([y * y + z * z, x * x + z * z, x * x + y * y])
        r, h = self.dims
        ixx = mass * (3 * r * r + h * h) / 12.0
        return np.diag([ixx, ixx, mass * r * r / 2.0])


@dataclass
class Link:
    name: str
    shapes: list[Shape] = field(default_factory=list)
    density: float = LINK_DENSITY


def _rpy_matrix(rpy) -> np.ndarray:
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def _segment_box(end, width: float, height: float, pad: float, color: str = "arm") -> Shape:
    """A box from the link origin to ``end`` (the next joint), ``pad`` longer at both ends."""
    end = np.asarray(end, dtype=float)
    length = float(np.linalg.norm(end))
    yaw = math.atan2(end[1], end[0])
    pitch = -math.atan2(end[2], math.hypot(end[0], end[1]))
    mid = tuple(float(v) for v in end / 2.0)
    return Shape("box", (length + 2 * pad, width, height), mid, (0.0, pitch, yaw), color)


def _arm_links(prefix: str) -> list[Link]:
    j = {row[0]: row for row in ARM_JOINTS}
    links = [
        Link(f"{prefix}_base_link", [
            Shape("box", (0.11, 0.11, 0.04), (0.0, 0.0, -0.02), color="mount"),
            Shape("cylinder", (0.045, 0.058), (0.0, 0.0, 0.029), color="joint"),
        ]),
        Link(f"{prefix}_link1", [Shape("cylinder", (0.035, 0.05), (0.012, 0.0, 0.02), color="joint")]),
        Link(f"{prefix}_link2", [
            _segment_box(j["joint3"][2], 0.045, 0.045, 0.02),
            Shape("cylinder", (0.03, 0.06), (0.0, 0.0, 0.0), (math.pi / 2, 0.0, 0.0), "joint"),
        ]),
        Link(f"{prefix}_link3", [
            _segment_box(j["joint4"][2], 0.04, 0.04, 0.015),
            Shape("cylinder", (0.028, 0.055), (0.0, 0.0, 0.0), (math.pi / 2, 0.0, 0.0), "joint"),
        ]),
        Link(f"{prefix}_link4", [_segment_box(j["joint5"][2], 0.035, 0.035, 0.01)]),
        Link(f"{prefix}_link5", [_segment_box(j["joint6"][2], 0.035, 0.035, 0.01, "joint")]),
        Link(f"{prefix}_link6", [
            Shape("cylinder", (0.025, 0.04), (0.02, 0.0, 0.0), (0.0, math.pi / 2, 0.0), "gripper"),
            Shape("box", (0.045, 0.115, 0.035), (0.0625, 0.0, 0.0), color="gripper"),
            Shape("box", (0.02, 0.09, 0.025), (WRIST_CAMERA_XYZ[0] - 0.02, 0.0, WRIST_CAMERA_XYZ[2]), color="camera",
                  collide=False),
        ]),
    ]
    # Fingers: at q = 0 the inner faces meet on the gripper midplane (closed); q opens each side.
    for name, sign in (("link7", 1.0), ("link8", -1.0)):
        y0 = abs(j["joint7"][2][1])
        links.append(Link(f"{prefix}_{name}", [
            Shape("box", (0.06, 0.008, 0.022), (0.03, sign * (-y0 + 0.004), 0.0), color="pad"),
        ], density=FINGER_DENSITY))
    links.append(Link(f"{prefix}_tcp_link"))
    links.append(Link(f"{prefix}_camera_link"))
    return links


def _robot_links() -> list[Link]:
    base = Link("base_link", [
        # Body column behind the table edge, down to the floor, and the head-camera mast.
        Shape("box", (0.22, 0.5, 0.80), (-0.16, 0.0, -0.36), color="body"),
        Shape("box", (0.04, 0.04, 0.60), (-0.09, 0.0, 0.32), color="mount", collide=False),
        Shape("box", (0.12, 0.03, 0.03), (-0.06, 0.0, 0.62), color="mount", collide=False),
    ])
    links = [base, Link("head_camera_link", [
        Shape("box", (0.03, 0.09, 0.025), (-0.025, 0.0, 0.0), color="camera", collide=False),
    ])]
    for prefix in ARM_PREFIXES:
        links += _arm_links(prefix)
    return links


def _fmt(v) -> str:
    return " ".join(f"{float(x):.6g}" for x in v)


def _look_rpy(direction) -> tuple[float, float, float]:
    d = np.asarray(direction, dtype=float)
    d /= np.linalg.norm(d)
    return (0.0, -math.asin(d[2]), math.atan2(d[1], d[0]))


def _joints() -> list[tuple]:
    """(name, type, parent, child, xyz, rpy, axis, limits, mimic) for every joint."""
    out = [("head_camera_joint", "fixed", "base_link", "head_camera_link", HEAD_CAMERA_XYZ,
            _look_rpy(HEAD_CAMERA_LOOK), None, None, None)]
    for p in ARM_PREFIXES:
        out.append((f"{p}_base_joint", "fixed", "base_link", f"{p}_base_link", ARM_BASE_XYZ[p], (0, 0, 0),
                    None, None, None))
        parent = f"{p}_base_link"
        for name, jtype, xyz, rpy, axis, lim in ARM_JOINTS:
            child = f"{p}_link{name[-1]}"
            mimic = f"{p}_joint7" if name == "joint8" else None
            out.append((f"{p}_{name}", jtype, parent if name != "joint8" else f"{p}_link6", child, xyz, rpy, axis, lim,
                        mimic))
            if name not in ("joint7", "joint8"):
                parent = child
        out.append((f"{p}_tcp_joint", "fixed", f"{p}_link6", f"{p}_tcp_link", (TCP_OFFSET, 0, 0), (0, 0, 0),
                    None, None, None))
        out.append((f"{p}_camera_joint", "fixed", f"{p}_link6", f"{p}_camera_link", WRIST_CAMERA_XYZ,
                    (0.0, WRIST_CAMERA_PITCH, 0.0), None, None, None))
    return out


def _inertial(link: Link) -> str:
    solid = [s for s in link.shapes if s.collide]
    if not solid:  # frames only (tcp, cameras): tiny mass keeps PhysX happy
        return ('<inertial><origin xyz="0 0 0"/><mass value="0.01"/>'
                '<inertia ixx="1e-6" ixy="0" ixz="0" iyy="1e-6" iyz="0" izz="1e-6"/></inertial>')
    masses = [link.density * s.volume() for s in solid]
    total = sum(masses)
    com = sum(m * np.asarray(s.xyz) for m, s in zip(masses, solid)) / total
    inertia = np.zeros((3, 3))
    for m, s in zip(masses, solid):
        rot = _rpy_matrix(s.rpy)
        d = np.asarray(s.xyz) - com
        inertia += rot @ s.local_inertia(m) @ rot.T + m * (d @ d * np.eye(3) - np.outer(d, d))
    i = inertia
    return (f'<inertial><origin xyz="{_fmt(com)}"/><mass value="{total:.6g}"/>'
            f'<inertia ixx="{i[0,0]:.6g}" ixy="{i[0,1]:.6g}" ixz="{i[0,2]:.6g}" '
            f'iyy="{i[1,1]:.6g}" iyz="{i[1,2]:.6g}" izz="{i[2,2]:.6g}"/></inertial>')


def _geometry(s: Shape) -> str:
    if s.kind == "box":
        return f'<geometry><box size="{_fmt(s.dims)}"/></geometry>'
    return f'<geometry><cylinder radius="{s.dims[0]:.6g}" length="{s.dims[1]:.6g}"/></geometry>'


def build_urdf() -> str:
    """The robot's URDF as a string (deterministic)."""
    lines = ['<?xml version="1.0"?>', "<!-- Generated by rsb_maniskill/agents/aloha_urdf.py: do not edit. -->",
             '<robot name="aloha_agilex">']
    for cname, rgba in COLORS.items():
        lines.append(f'  <material name="{cname}"><color rgba="{_fmt(rgba)}"/></material>')
    for link in _robot_links():
        lines.append(f'  <link name="{link.name}">')
        lines.append(f"    {_inertial(link)}")
        for s in link.shapes:
            origin = f'<origin xyz="{_fmt(s.xyz)}" rpy="{_fmt(s.rpy)}"/>'
            lines.append(f'    <visual>{origin}{_geometry(s)}<material name="{s.color}"/></visual>')
            if s.collide:
                lines.append(f"    <collision>{origin}{_geometry(s)}</collision>")
        lines.append("  </link>")
    for name, jtype, parent, child, xyz, rpy, axis, lim, mimic in _joints():
        lines.append(f'  <joint name="{name}" type="{jtype}">')
        lines.append(f'    <parent link="{parent}"/><child link="{child}"/>')
        lines.append(f'    <origin xyz="{_fmt(xyz)}" rpy="{_fmt(rpy)}"/>')
        if axis is not None:
            lines.append(f'    <axis xyz="{_fmt(axis)}"/>')
            lines.append(f'    <limit lower="{lim[0]:.6g}" upper="{lim[1]:.6g}" '
                         f'effort="{JOINT_EFFORT[jtype]:.6g}" velocity="{JOINT_VELOCITY[jtype]:.6g}"/>')
            lines.append(f'    <dynamics damping="{DRIVE_DAMPING}" friction="0"/>')
        if mimic:
            lines.append(f'    <mimic joint="{mimic}" multiplier="1" offset="0"/>')
        lines.append("  </joint>")
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


def sapien_disabled_pairs() -> list[tuple[str, str]]:
    """Non-adjacent link pairs whose primitives overlap by construction (SAPIEN: at most 31)."""
    pairs = []
    for p in ARM_PREFIXES:
        chain = ["base_link", f"{p}_base_link"] + [f"{p}_link{i}" for i in range(1, 7)]
        pairs += [(chain[i], chain[i + 2]) for i in range(len(chain) - 2)]
        pairs += [(f"{p}_link5", f"{p}_link7"), (f"{p}_link5", f"{p}_link8"), (f"{p}_link7", f"{p}_link8")]
    return pairs


def mplib_disabled_pairs() -> list[tuple[str, str]]:
    """Pairs mplib may ignore: the SAPIEN pairs, every pair inside one arm's wrist/gripper group,
    and the fixed base against the shoulders (they cannot move relative to each other)."""
    pairs = set(sapien_disabled_pairs())
    for p in ARM_PREFIXES:
        wrist = [f"{p}_link{i}" for i in range(4, 9)]
        pairs |= set(itertools.combinations(wrist, 2))
        static = ["base_link", f"{p}_base_link", f"{p}_link1"]
        pairs |= set(itertools.combinations(static, 2))
        pairs.add(("base_link", f"{p}_link2"))
    pairs.add(("fl_base_link", "fr_base_link"))
    return sorted(tuple(sorted(pair)) for pair in pairs)


def _srdf(pairs) -> str:
    lines = ['<?xml version="1.0"?>', "<!-- Generated by rsb_maniskill/agents/aloha_urdf.py: do not edit. -->",
             '<robot name="aloha_agilex">']
    lines += [f'  <disable_collisions link1="{a}" link2="{b}" reason="Default"/>' for a, b in pairs]
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


def build_files() -> dict[str, str]:
    """File name -> content of every generated asset."""
    return {
        URDF_NAME: build_urdf(),
        SRDF_NAME: _srdf(sapien_disabled_pairs()),
        MPLIB_SRDF_NAME: _srdf(mplib_disabled_pairs()),
    }


def write_files(out_dir: Path = ASSET_DIR) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in build_files().items():
        path = out_dir / name
        path.write_text(text)
        written.append(path)
    return written


if __name__ == "__main__":
    for path in write_files():
        print(f"wrote {path}")
