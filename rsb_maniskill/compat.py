"""The ManiSkill and SAPIEN internals this pack reads or sets, in one place.

ManiSkill and SAPIEN at the versions pyproject.toml pins have no public API for these; each
accessor names what it touches, so a version bump is checked here and in ``tests/test_compat.py``
rather than across the package. Modules outside this one never touch a private ManiSkill or
SAPIEN attribute (the test lists the attributes this module reads and looks for them elsewhere).
"""
from __future__ import annotations

from contextlib import contextmanager
from typing import Any, Iterator, Mapping


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


def episode_seeds(env: Any) -> Any:
    """Each parallel env's episode seed, (B,) int64 (``BaseEnv._episode_seed``)."""
    return env._episode_seed


def batched_episode_rng(env: Any) -> Any:
    """The per-env episode RNGs, ``RandomState(seed)`` each at a seeded reset; index it by env
    (``BaseEnv._batched_episode_rng``, a ``BatchedRNG``; ``objects.layout.SeededRNG`` is the same
    without ManiSkill)."""
    return env._batched_episode_rng


def render_device(env: Any) -> Any:
    """The SAPIEN device the env renders with (``BaseEnv._render_device``)."""
    return env._render_device


def hidden_objects(env: Any) -> list[Any]:
    """The actors an env hides from its sensors while they render (``BaseEnv._hidden_objects``)."""
    return env._hidden_objects


@contextmanager
def pictures_from(env: Any, pictures: Mapping[str, Mapping[str, Any]]) -> Iterator[None]:
    """Inside the block the env's observation takes its camera pictures from ``pictures`` (camera
    name -> texture name -> (1, H, W, C) tensor, rendered elsewhere: ``sim/camera_group.py``) rather
    than rendering its own scene; the rest of ManiSkill's observation (texture transforms, the task's
    own sensor-data hook, parameters, flattening) runs as usual.

    ``BaseEnv._get_obs_sensor_data`` calls ``scene.update_render``, each sensor's ``capture``, then
    ``Camera.get_obs`` reads ``RenderCamera.get_picture(names)``: these three are shadowed on the
    instances for the block, and restored after it."""
    scene = env.scene
    patched: list[Any] = [scene]
    scene.update_render = lambda *args, **kwargs: None
    try:
        for name, sensor in scene.sensors.items():
            if name not in pictures:
                continue
            own = pictures[name]
            sensor.capture = lambda: None
            sensor.camera.get_picture = lambda names, own=own: [own[n] for n in ([names] if isinstance(names, str)
                                                                                 else names)]
            patched += [sensor, sensor.camera]
        yield
    finally:
        for obj in patched:
            for attr in ("update_render", "capture", "get_picture"):
                obj.__dict__.pop(attr, None)


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
    """What differs from the ManiSkill and SAPIEN versions pyproject.toml pins, the ones these
    accessors are written against (empty when all match, or when the package is not installed)."""
    import sapien
    from packaging.specifiers import SpecifierSet

    import mani_skill

    from rsb_maniskill.version import requirements

    pins = requirements()
    out = []
    for dist, module in (("mani-skill", mani_skill), ("sapien", sapien)):
        spec = pins.get(dist)
        if spec and module.__version__.split("+")[0] not in SpecifierSet(spec):
            out.append(f"{dist} {module.__version__} (written against {spec})")
    return out
