"""Feature names of RSB data in LeRobot: one owner for the keys that datasets and envs share.

Two namings, so that a policy trained on one dataset evaluates on the env with no feature mapping:

- ``"rsb"`` (default): the Aloha keys of LeRobot's own Aloha datasets (``cam_high``,
  ``cam_left_wrist``, ``cam_right_wrist``).
- ``"robotwin"``: the keys of LeRobot's RoboTwin 2.0 env and datasets (``head_camera``,
  ``left_camera``, ``right_camera``), the same Aloha-AgileX robot.

Camera names on the RSB side are the robot's (``robot.CAMERAS``: the task's sensors without
``_camera``). State and action are the Aloha 14-number layout in both namings
(``rsb_maniskill.robot.to_aloha14``).
"""
from __future__ import annotations

CAMERA_KEYS: dict[str, dict[str, str]] = {  # naming -> camera -> key
    "rsb": {"head": "cam_high", "left_wrist": "cam_left_wrist", "right_wrist": "cam_right_wrist"},
    "robotwin": {"head": "head_camera", "left_wrist": "left_camera", "right_wrist": "right_camera"},
}
NAMINGS = tuple(CAMERA_KEYS)
DEFAULT_NAMING = "rsb"


def check_naming(naming: str) -> str:
    if naming not in CAMERA_KEYS:
        raise ValueError(f"unknown naming {naming!r}; valid: {', '.join(NAMINGS)}")
    return naming


def camera_key(camera: str, naming: str = DEFAULT_NAMING) -> str:
    """``"head"`` -> ``"cam_high"`` (rsb) or ``"head_camera"`` (robotwin)."""
    return CAMERA_KEYS[check_naming(naming)][camera]


def video_key(camera: str, naming: str = DEFAULT_NAMING) -> str:
    """The dataset feature of a camera: ``observation.images.<camera_key>``."""
    return f"observation.images.{camera_key(camera, naming)}"
