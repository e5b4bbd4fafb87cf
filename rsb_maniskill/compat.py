"""The ManiSkill and SAPIEN internals this pack reads or sets, in one place.

ManiSkill 3.0.1 and SAPIEN 3.0.x (the pinned versions, pyproject.toml) have no public API for
these; each accessor names what it touches, so a version bump is checked here and in
``tests/test_compat.py`` rather than across the package. Modules outside this one never touch a
private ManiSkill or SAPIEN attribute.
"""
from __future__ import annotations

from contextlib import contextmanager
from typing import Any, Iterator

MANISKILL_VERSION = "3.0.1"  # what these accessors are written against
SAPIEN_VERSION_PREFIX = "3.0."


def physx_bodies(entity: Any) -> list[Any]:
    """The per-env PhysX bodies behind a ManiSkill ``Actor`` or ``Link`` (``_bodies``)."""
    return entity._bodies


def entities(actor: Any) -> list[Any]:
    """The per-env SAPIEN entities behind a ManiSkill ``Actor`` (``_objs``)."""
    return actor._objs


def controller_target_qpos(controller: Any) -> Any:
    """A PD joint controller's current joint targets, (B, joints) (``_target_qpos``): set at reset,
    before the first step writes the drive targets."""
    return controller._target_qpos


def render_cameras(camera: Any) -> list[Any]:
    """The per-env SAPIEN camera components behind a ManiSkill ``RenderCamera`` (``_render_cameras``)."""
    return camera._render_cameras


def forget_camera_pose(camera: Any) -> None:
    """After a per-env ``set_local_pose``: drop the ``RenderCamera``'s cached local pose (``_cached_local_pose``)."""
    camera._cached_local_pose = None


@contextmanager
def obs_mode(env: Any, mode: str) -> Iterator[None]:
    """Steps inside the block compute the observation of ``mode`` (``BaseEnv._obs_mode``); the
    env's own mode comes back after it."""
    old = env._obs_mode
    env._obs_mode = mode
    try:
        yield
    finally:
        env._obs_mode = old


def check_versions() -> list[str]:
    """What differs from the versions the accessors are written against (empty when all match)."""
    import sapien

    import mani_skill

    out = []
    if mani_skill.__version__ != MANISKILL_VERSION:
        out.append(f"mani_skill {mani_skill.__version__} (written against {MANISKILL_VERSION})")
    if not sapien.__version__.startswith(SAPIEN_VERSION_PREFIX):
        out.append(f"sapien {sapien.__version__} (written against {SAPIEN_VERSION_PREFIX}x)")
    return out
