"""RSB observations and actions on vla-eval's wire: one convention for both directions of the integration.

vla-eval (allenai's vla-evaluation-harness, ``vla_eval/types.py``) leaves an observation's keys to
the benchmark; its servers read ``images`` (camera name -> HWC uint8), ``task_description`` and a
proprioceptive state, and reply ``actions`` (one action, or a (T, D) chunk). What the numbers mean
is a convention between the benchmark and the checkpoint, so it is explicit here:

- ``cameras``: the camera names, a naming of ``rsb export lerobot`` (``export/naming.py``): ``rsb``
  (``cam_high``, ``cam_left_wrist``, ``cam_right_wrist``) or ``robotwin`` (``head_camera``,
  ``left_camera``, ``right_camera``).
- ``state_key``: where the Aloha-14 joint state goes (``state`` for the LeRobot bridge, ``joint_state``
  for RoboTwin-trained servers), or None for none.
- ``gripper``: ``open`` (1 = open, 0 = closed: Aloha-14 as RSB exports it, RoboTwin) or ``closed``
  (1 = closed), for the state sent and the actions read.
- ``joints``: ``absolute`` joint targets, or ``delta``: arm joints relative to the state of the
  observation the chunk was predicted from, grippers absolute (dexbotic's RoboTwin convention).

Actions are 14 numbers in the Aloha layout [left arm 6, left gripper, right arm 6, right gripper]
(``rsb_maniskill.robot``); the presets ``lerobot`` and ``robotwin`` are the two datasets
``rsb export lerobot`` writes. :meth:`VlaEvalLayout.action_spec` / :meth:`~VlaEvalLayout.observation_spec`
state this in vla-eval's ``DimSpec`` terms, and :func:`check_server_spec` stops a run whose server
declares something else.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass, replace
from typing import Any, Mapping

import numpy as np

from rsb_maniskill.export.naming import NAMINGS, camera_key
from rsb_maniskill.policies.remote.openpi import aloha14_from_qpos
from rsb_maniskill.robot import (
    ACTION_DIM,
    ALOHA14_ARM_SLICE,
    ALOHA14_GRIPPER_INDEX,
    ARMS,
    CAMERAS,
    from_aloha14,
    sensor_uid,
    to_aloha14,
)

INSTALL_HINT = "vla-eval's protocol needs `pip install 'vla-eval>=0.8,<0.9'` (extra: rsb_maniskill[vla_eval])"
GRIPPERS = ("open", "closed")
JOINTS = ("absolute", "delta")
NO_STATE = "none"  # state_key value (YAML, -a) that sends no state
_ARM_SLOTS = np.r_[tuple(ALOHA14_ARM_SLICE[a] for a in ARMS)]
_GRIPPER_SLOTS = [ALOHA14_GRIPPER_INDEX[a] for a in ARMS]
# Action formats of vla-eval's specs (vla_eval/specs.py and its servers) that are RSB's 14 joint numbers
_JOINT_FORMATS = {"absolute": "absolute_joint_positions_with_grippers", "delta": "delta_joint_positions_with_grippers"}
_GRIPPER_FORMATS = {"open": {"continuous_01"}, "closed": {"continuous_01", "binary_close_01"}}


def vla_eval_module(name: str) -> Any:
    """``vla_eval.<name>`` (imported on first use), or ImportError with the install hint."""
    try:
        return importlib.import_module(f"vla_eval.{name}")
    except ImportError as err:  # pragma: no cover - depends on the install
        raise ImportError(INSTALL_HINT) from err


@dataclass(frozen=True)
class VlaEvalLayout:
    """The four conventions of the module doc; see :data:`PRESETS` for the two datasets' values."""

    cameras: str = "rsb"
    state_key: str | None = "state"
    gripper: str = "open"
    joints: str = "absolute"

    def __post_init__(self) -> None:
        for field, value, valid in (("cameras", self.cameras, NAMINGS), ("gripper", self.gripper, GRIPPERS),
                                    ("joints", self.joints, JOINTS)):
            if value not in valid:
                raise ValueError(f"vla-eval layout: {field} must be one of {', '.join(valid)}, got {value!r}")
        if self.state_key in (NO_STATE, ""):
            object.__setattr__(self, "state_key", None)
        if self.joints == "delta" and self.state_key is None:
            raise ValueError("vla-eval layout: joints=delta adds the state back, so it needs a state_key")

    def describe(self) -> str:
        return (f"cameras={self.cameras}, state_key={self.state_key or NO_STATE}, gripper={self.gripper}, "
                f"joints={self.joints}")

    # ------------------------------------------------------------ observations
    def state(self, qpos: Any) -> np.ndarray:
        """obs["agent"]["qpos"] -> the 14 numbers sent, float32 (gripper in this layout's polarity)."""
        s = aloha14_from_qpos(qpos)
        if self.gripper == "closed":
            s[..., _GRIPPER_SLOTS] = 1.0 - s[..., _GRIPPER_SLOTS]
        return s

    def observation(self, obs: Mapping[str, Any], instruction: str, images: bool = True) -> dict[str, Any]:
        """One env's nested observation (numpy) -> vla-eval's observation dict. ``images=False`` leaves
        the cameras out (a step whose observation a chunking server does not read); an observation
        without ``sensor_data`` (state obs modes) has none to send."""
        out: dict[str, Any] = {"task_description": instruction}
        sensors = obs.get("sensor_data") or {}
        if images and sensors:
            missing = [c for c in CAMERAS if "rgb" not in sensors.get(sensor_uid(c), {})]
            if missing:
                raise ValueError(f"vla-eval layout: the observation lacks the rgb image of {', '.join(missing)}; "
                                 "use an rgb obs mode")
            out["images"] = {camera_key(c, self.cameras): _uint8(sensors[sensor_uid(c)]["rgb"]) for c in CAMERAS}
        if self.state_key is not None:
            out[self.state_key] = self.state(_numpy(obs["agent"]["qpos"]))
        return out

    # ------------------------------------------------------------ actions
    def env_actions(self, actions: Any, state: Any = None) -> np.ndarray:
        """A server's (T, 14) chunk (or one (14,) action) in this layout -> env actions (T, 14).

        ``state``: the layout's state of the observation the chunk was predicted from (``joints=delta``)."""
        a = np.array(actions, dtype=np.float32)
        if a.ndim == 1:
            a = a[None]
        if a.ndim != 2 or a.shape[1] != ACTION_DIM:
            raise ValueError(f"vla-eval server replied actions of shape {np.shape(actions)}; RSB takes "
                             f"(T, {ACTION_DIM}) in the Aloha-14 layout ({self.describe()})")
        if self.gripper == "closed":
            a[:, _GRIPPER_SLOTS] = 1.0 - a[:, _GRIPPER_SLOTS]
        if self.joints == "delta":
            if state is None:
                raise ValueError("vla-eval layout: joints=delta needs the state the chunk was predicted from")
            a[:, _ARM_SLOTS] += np.asarray(state, dtype=np.float32)[_ARM_SLOTS]
        return from_aloha14(a)

    def wire_actions(self, env_actions: Any, state: Any = None) -> np.ndarray:
        """Inverse of :meth:`env_actions`: env actions (T, 14) -> this layout (what a server replies)."""
        a = to_aloha14(np.asarray(env_actions, dtype=np.float32))
        if self.joints == "delta":
            a[..., _ARM_SLOTS] -= np.asarray(state, dtype=np.float32)[_ARM_SLOTS]
        if self.gripper == "closed":
            a[..., _GRIPPER_SLOTS] = 1.0 - a[..., _GRIPPER_SLOTS]
        return a

    # ------------------------------------------------------------ vla-eval specs
    def action_spec(self) -> dict[str, Any]:
        """What RSB consumes, as vla-eval's ``{component: DimSpec}``; ``raw`` (servers that leave the
        convention to the checkpoint, e.g. the LeRobot bridge) is accepted."""
        specs = vla_eval_module("specs")
        fmt = _JOINT_FORMATS[self.joints]
        accepts = {fmt, specs.RAW.format} | ({"joint_positions"} if self.joints == "absolute" else set())
        return {"actions": specs.DimSpec("actions", ACTION_DIM, fmt, accepts=frozenset(accepts),
                                         description=f"Aloha-14 joint targets ({self.describe()})")}

    def observation_spec(self, images: bool = True) -> dict[str, Any]:
        """What RSB sends, as vla-eval's ``{component: DimSpec}``."""
        specs = vla_eval_module("specs")
        out = {"image": specs.IMAGE_RGB} if images else {}
        out["language"] = specs.LANGUAGE
        if self.state_key is not None:
            out["state"] = specs.DimSpec("state", ACTION_DIM, specs.RAW.format,
                                         description=f"Aloha-14 joint state under {self.state_key!r}, "
                                                     f"gripper {self.gripper}=1")
        return out


PRESETS: dict[str, VlaEvalLayout] = {
    # vla-eval's LeRobot bridge serving a checkpoint trained on `rsb export lerobot` (naming rsb)
    "lerobot": VlaEvalLayout(),
    # RoboTwin 2.0's keys (vla-eval's RoboTwin benchmark; `rsb export lerobot --naming robotwin`)
    "robotwin": VlaEvalLayout(cameras="robotwin", state_key="joint_state"),
}
LAYOUT_OPTIONS = ("cameras", "state_key", "gripper", "joints")


def make_layout(preset: str = "lerobot", **options: Any) -> VlaEvalLayout:
    """A preset with ``options`` (``cameras``, ``state_key``, ``gripper``, ``joints``) that are not None
    replacing its values."""
    if preset not in PRESETS:
        raise ValueError(f"unknown vla-eval preset {preset!r}; known: {', '.join(PRESETS)}")
    unknown = set(options) - set(LAYOUT_OPTIONS)
    if unknown:
        raise ValueError(f"unknown vla-eval layout options {sorted(unknown)}; known: {', '.join(LAYOUT_OPTIONS)}")
    return replace(PRESETS[preset], **{k: v for k, v in options.items() if v is not None})


class SpecMismatch(ValueError):
    """A server declares actions or observations that RSB's layout does not give or take."""


def _show(spec: Mapping[str, Any]) -> str:
    return " + ".join(f"{k} {s.dims or '?'}x{s.format}" for k, s in spec.items()) or "nothing"


def check_server_spec(server_info: Mapping[str, Any], layout: VlaEvalLayout) -> None:
    """Stop (one line naming both) when the HELLO of a server declares an action or state spec that
    ``layout`` cannot meet: actions must be 14 numbers of a joint format (or ``raw``); a declared
    state must be 14 numbers of ``raw`` / ``joint_positions``, and the layout must send one."""
    specs = vla_eval_module("specs")
    name = server_info.get("model_server", "the server")
    declared = {k: specs.DimSpec.from_dict(v) for k, v in (server_info.get("action_spec") or {}).items()}
    ours = layout.action_spec()
    ok_formats = set(ours["actions"].accepts) | _GRIPPER_FORMATS[layout.gripper]
    dims = sum(s.dims for s in declared.values())
    if declared and (dims not in (0, ACTION_DIM) or any(s.format not in ok_formats for s in declared.values())):
        raise SpecMismatch(f"vla-eval server {name} declares actions {_show(declared)}; RSB ({layout.describe()}) "
                           f"takes {_show(ours)}: serve a checkpoint trained on RSB's joint actions, or set "
                           "the layout options (gripper, joints) to the checkpoint's")
    obs = {k: specs.DimSpec.from_dict(v) for k, v in (server_info.get("observation_spec") or {}).items()}
    state = obs.get("state")
    if state is None:
        return
    sent = layout.observation_spec().get("state")
    if sent is None or state.dims not in (0, ACTION_DIM) or state.format not in (specs.RAW.format, "joint_positions"):
        raise SpecMismatch(f"vla-eval server {name} reads state {_show({'state': state})}; RSB "
                           f"({layout.describe()}) sends {_show({'state': sent}) if sent else 'no state'}")


def _numpy(x: Any) -> np.ndarray:
    return x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)


def _uint8(image: Any) -> np.ndarray:
    img = _numpy(image)
    return np.ascontiguousarray(img if img.dtype == np.uint8 else img.astype(np.uint8))
