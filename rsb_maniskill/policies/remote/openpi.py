"""The ``openpi-aloha`` preset: RSB observations and actions in the layout of openpi's Aloha policies.

openpi's Aloha configs (``pi0_aloha``, ``pi05_aloha`` and fine-tunes built on
``LeRobotAlohaDataConfig``) read, through ``openpi.policies.aloha_policy.AlohaInputs``::

    images/cam_high, images/cam_left_wrist, images/cam_right_wrist   uint8 (3, H, W)
    state    (14,) [left arm 6, left gripper, right arm 6, right gripper], gripper 0 closed .. 1 open
    prompt   str

and return ``actions`` (T, 14) in the same layout, absolute joint targets (``AbsoluteActions`` has
already added the state back when the model predicts deltas). Everything openpi does beyond that
(joint flips and the Interbotix gripper maps of ``adapt_to_pi``, delta actions, normalisation,
resizing to 224) happens inside the server, on both the state going in and the actions coming out.

Here the state is the one ``AlohaAgilex.aloha14_state()`` gives and ``rsb export lerobot`` writes
(arm joint angles in radians, finger opening / travel), and the actions go through
:func:`~rsb_maniskill.agents.aloha.from_aloha14` (gripper 0..1 -> the env's -1..1), so a policy
fine-tuned on an RSB export sees at evaluation what it saw in training. Images are letterboxed
to ``image_size`` as ``openpi_client.image_tools.resize_with_pad`` does (PIL, bilinear, zero pad).
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from rsb_maniskill.export.naming import camera_key
from rsb_maniskill.robot import (
    ALOHA14_GRIPPER_INDEX,
    ALOHA14_JOINT_NAMES,
    ARMS,
    FINGER_JOINT_NAMES,
    FINGER_TRAVEL,
    QPOS_JOINT_NAMES,
    sensor_uid,
)
from rsb_maniskill.robot import CAMERAS as ROBOT_CAMERAS

# Env camera -> openpi Aloha camera, the names `rsb export lerobot` gives them too.
CAMERAS = {sensor_uid(c): camera_key(c, "rsb") for c in ROBOT_CAMERAS}
DEFAULT_IMAGE_SIZE = 224  # what openpi's clients send (pi0 / pi0.5 resize to 224 x 224 anyway)
DEFAULT_ACTION_HORIZON = 10  # actions executed per chunk, as openpi's ALOHA sim example


def _index(name: str) -> int:
    return QPOS_JOINT_NAMES.index(name)


# Aloha-14 slot -> qpos index; the grippers read the driven finger (the other one mimics it).
_ALOHA_FROM_QPOS = [_index(n) for n in ALOHA14_JOINT_NAMES]
_GRIPPER_SLOTS = tuple(ALOHA14_GRIPPER_INDEX[a] for a in ARMS)


def _gripper_travel() -> float:
    return float(FINGER_TRAVEL)


def aloha14_from_qpos(qpos: Any) -> np.ndarray:
    """obs["agent"]["qpos"] (..., 16) -> Aloha state (..., 14), float32: what ``aloha14_state()``
    computes from the simulator, computed from the observation a policy gets."""
    q = np.asarray(qpos, dtype=np.float32)
    if q.shape[-1] != len(QPOS_JOINT_NAMES):
        raise ValueError(f"openpi-aloha: expected qpos of the Aloha-AgileX agent ({len(QPOS_JOINT_NAMES)} joints), "
                         f"got shape {q.shape}")
    state = q[..., _ALOHA_FROM_QPOS].copy()
    state[..., _GRIPPER_SLOTS] = np.clip(state[..., _GRIPPER_SLOTS] / _gripper_travel(), 0.0, 1.0)
    return state


def qpos_from_aloha14(state: Any) -> np.ndarray:
    """Inverse of :func:`aloha14_from_qpos` (both fingers of a gripper get its opening)."""
    s = np.asarray(state, dtype=np.float32)
    if s.shape[-1] != 14:
        raise ValueError(f"openpi-aloha: 'state' must hold 14 numbers (Aloha layout), got shape {s.shape}")
    q = np.zeros((*s.shape[:-1], len(QPOS_JOINT_NAMES)), dtype=np.float32)
    q[..., _ALOHA_FROM_QPOS] = s
    fingers = [_index(FINGER_JOINT_NAMES[a][0]) for a in ARMS]
    mimics = [_index(FINGER_JOINT_NAMES[a][1]) for a in ARMS]
    q[..., fingers] *= _gripper_travel()
    q[..., mimics] = q[..., fingers]
    return q


def resize_with_pad(image: np.ndarray, height: int, width: int) -> np.ndarray:
    """(H, W, C) uint8 -> (height, width, C), aspect kept, zero padding: ``openpi_client.image_tools``'s
    ``resize_with_pad`` (itself tf.image.resize_with_pad), without depending on openpi."""
    from PIL import Image

    image = np.asarray(image)
    if image.shape[:2] == (height, width):
        return image
    pil = Image.fromarray(image)
    cur_w, cur_h = pil.size
    ratio = max(cur_w / width, cur_h / height)
    new_h, new_w = int(cur_h / ratio), int(cur_w / ratio)
    resized = pil.resize((new_w, new_h), resample=Image.BILINEAR)
    canvas = Image.new(resized.mode, (width, height), 0)
    canvas.paste(resized, (max(0, int((width - new_w) / 2)), max(0, int((height - new_h) / 2))))
    return np.asarray(canvas)


def _as_uint8(image: Any) -> np.ndarray:
    if hasattr(image, "detach"):
        image = image.detach().cpu().numpy()
    image = np.asarray(image)
    if np.issubdtype(image.dtype, np.floating):  # openpi_client.image_tools.convert_to_uint8
        image = (255 * image).astype(np.uint8)
    return image.astype(np.uint8, copy=False)


def _image_size(size: int | Sequence[int] | None) -> tuple[int, int] | None:
    if size is None:
        return None
    hw = (size, size) if isinstance(size, (int, np.integer)) else tuple(size)
    if len(hw) != 2 or not all(isinstance(v, (int, np.integer)) and v > 0 for v in hw):
        raise ValueError(f"openpi-aloha: image_size must be a positive int or [height, width], got {size!r}")
    return int(hw[0]), int(hw[1])


class OpenpiAloha:
    """Maps between the env's observation / action layout and openpi's Aloha one, both ways.

    Client side (``RemotePolicy(preset="openpi-aloha")``): :meth:`request` builds what an openpi
    Aloha server reads, :meth:`env_actions` turns its reply into env actions. Server side
    (``serve --preset openpi-aloha``): :meth:`obs_from_request` rebuilds the nested env observation
    from an openpi Aloha client's request, :meth:`aloha_actions` turns env actions into its reply.

    Args:
        image_size: images are letterboxed to this (int, or [height, width]); None sends them as
            rendered (240 x 320 by default).
    """

    name = "openpi-aloha"
    action_horizon = DEFAULT_ACTION_HORIZON  # a client's default number of actions executed per chunk

    def __init__(self, image_size: int | Sequence[int] | None = DEFAULT_IMAGE_SIZE) -> None:
        self.image_size = _image_size(image_size)

    # ------------------------------------------------------------ client side
    def request(self, obs: Mapping[str, Any], instruction: str) -> dict[str, Any]:
        """Env observation (one env, rgb obs mode) -> openpi Aloha request."""
        sensors = obs.get("sensor_data") or {}
        missing = [c for c in CAMERAS if c not in sensors or "rgb" not in sensors[c]]
        if missing or "agent" not in obs:
            raise ValueError(f"openpi-aloha needs the rgb observation of the three cameras and the agent state "
                             f"(obs_mode='rgb'); missing: {', '.join(missing) or 'agent'}")
        images = {}
        for cam, key in CAMERAS.items():
            rgb = _as_uint8(sensors[cam]["rgb"])
            if self.image_size is not None:
                rgb = resize_with_pad(rgb, *self.image_size)
            images[key] = np.ascontiguousarray(rgb.transpose(2, 0, 1))  # HWC -> CHW
        qpos = obs["agent"]["qpos"]
        if hasattr(qpos, "detach"):
            qpos = qpos.detach().cpu().numpy()
        return {"images": images, "state": aloha14_from_qpos(qpos), "prompt": instruction}

    def env_actions(self, actions: Any) -> np.ndarray:
        """Reply's Aloha chunk (T, >= 14) -> env actions (T, 14)."""
        from rsb_maniskill.agents.aloha import from_aloha14

        a = np.asarray(actions, dtype=np.float32)
        if a.ndim == 1:
            a = a[None]
        if a.ndim != 2 or a.shape[1] < 14:
            raise ValueError(f"openpi-aloha: expected an action chunk of shape (T, 14) in the Aloha layout, "
                             f"got {a.shape}")
        return from_aloha14(a[:, :14])

    # ------------------------------------------------------------ server side
    def obs_from_request(self, request: Mapping[str, Any]) -> dict[str, Any]:
        """openpi Aloha request -> the env's nested observation (images HWC; cameras sent as they came)."""
        images = request.get("images")
        if not isinstance(images, Mapping) or "state" not in request:
            raise ValueError("openpi-aloha: a request needs 'images' (a dict of cameras) and 'state'; "
                             f"got keys {sorted(map(str, request))}")
        unknown = set(images) - set(CAMERAS.values())
        if unknown:
            raise ValueError(f"openpi-aloha: unknown cameras {sorted(unknown)}; expected {sorted(CAMERAS.values())}")
        sensor_data = {}
        for cam, key in CAMERAS.items():
            if key in images:
                img = _as_uint8(images[key])
                if img.ndim != 3 or img.shape[0] != 3:
                    raise ValueError(f"openpi-aloha: images/{key} must be (3, H, W) as openpi sends them, "
                                     f"got {img.shape}")
                sensor_data[cam] = {"rgb": np.ascontiguousarray(img.transpose(1, 2, 0))}
        # openpi's Aloha requests carry no joint velocities: the obs has none rather than made-up ones.
        return {"agent": {"qpos": qpos_from_aloha14(request["state"])}, "sensor_data": sensor_data}

    def aloha_actions(self, actions: Any) -> np.ndarray:
        """Env actions (T, 14) -> Aloha layout (T, 14), gripper 0 closed .. 1 open."""
        from rsb_maniskill.agents.aloha import to_aloha14

        return to_aloha14(np.asarray(actions, dtype=np.float32))


PRESETS = {"openpi-aloha": OpenpiAloha}


def make_preset(name: str, **kwargs: Any) -> OpenpiAloha:
    """The preset called ``name``; unknown names raise ValueError listing the known ones."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; known: {', '.join(PRESETS)}")
    return PRESETS[name](**kwargs)


def check_preset_args(policy_kwargs: Mapping[str, Any], obs_mode: str) -> None:
    """Before any env is built: a ``remote`` policy's preset arguments and the obs mode they need."""
    if policy_kwargs.get("preset") is None:
        if policy_kwargs.get("image_size") is not None:
            raise ValueError("image_size applies to a preset: add -a preset=openpi-aloha")
        return
    size = {"image_size": policy_kwargs["image_size"]} if policy_kwargs.get("image_size") is not None else {}
    make_preset(policy_kwargs["preset"], **size)
    if "rgb" not in obs_mode:
        raise ValueError(f"preset {policy_kwargs['preset']!r} sends camera images: "
                         f"use an rgb obs mode, not {obs_mode!r}")
