"""The ManiSkill and SAPIEN internals this pack reads or sets, in one place.

ManiSkill and SAPIEN at the versions pyproject.toml pins have no public API for these; each
accessor names what it touches, so a version bump is checked here and in ``tests/sim/test_compat.py``
rather than across the package. Modules outside this one never touch a private ManiSkill or
SAPIEN attribute (the test lists the attributes this module reads and looks for them elsewhere).
"""
from __future__ import annotations

import logging
from contextlib import contextmanager
from typing import Any, Callable, Iterator, Mapping, Sequence


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


def needed_textures(env: Any) -> dict[str, list[str]]:
    """Camera name -> the shader textures the env's obs mode reads (rgb: ``Color`` only), by the rule of
    ManiSkill's ``Camera.get_obs`` (a texture is read when one of its modalities is asked for; state
    modes read rgb and depth only, ``sensor_data`` and ``pointcloud`` every texture)."""
    from mani_skill.sensors.camera import Camera

    mode, visual = env.obs_mode, env.obs_mode_struct.visual
    if mode in ("sensor_data", "pointcloud"):
        wanted = None
    elif mode in ("state", "state_dict"):
        wanted = {"rgb", "depth"}
    else:
        wanted = {m for m in ("rgb", "depth", "position", "segmentation", "normal", "albedo") if getattr(visual, m)}
    out = {}
    for name, sensor in env.scene.sensors.items():
        if isinstance(sensor, Camera):
            names = sensor.config.shader_config.texture_names
            out[name] = [t for t, modalities in names.items() if wanted is None or wanted & set(modalities)]
    return out


def batched_obs(envs: Sequence[Any], infos: Sequence[Mapping[str, Any]], pictures: Mapping[str, Mapping[str, Any]],
                join: Callable[[list], Any], sensor_hook: Callable[[int, dict], dict] | None = None) -> Any:
    """ManiSkill's observation of K one-env envs at once, their cameras rendered elsewhere: ``pictures``
    (camera name -> texture -> (K, H, W, C), env order, ``sim/camera_group.py``). What ``BaseEnv.get_obs``
    builds for one env (``_get_obs_with_sensor_data``, then ``_flatten_raw_obs``), built once for all K:
    the state parts of each env (agent, task extra with its info, camera parameters) joined with
    ``join``; the camera part made from the K-row pictures in one go by ManiSkill's own texture
    transforms (``BaseEnv._get_obs_sensor_data`` of env 0, its cameras handed the K rows), so one dtype
    conversion and no per-env slicing. A task's own sensor-data step (``_get_obs_sensor_data``
    overridden, e.g. image noise drawn per env) is ``sensor_hook(i, env i's rows)``. Each picture is
    copied once first: the observation's images are its own, as a scene's own render gives them.
    Not for ``pointcloud``."""
    from mani_skill.envs.sapien_env import BaseEnv

    first = envs[0]
    if first.obs_mode in ("none", "state", "state_dict", "pointcloud"):
        raise ValueError(f"batched_obs builds camera observations, not {first.obs_mode!r}")
    # the group's pictures are overwritten by its next render: the observation gets its own (as each
    # scene's get_picture gives a fresh one), and ManiSkill's transforms view or convert that
    own = {name: {tex: _own_copy(x) for tex, x in texs.items()} for name, texs in pictures.items()}
    with pictures_from(first, own):
        sensor_data = BaseEnv._get_obs_sensor_data(first, first.obs_mode != "sensor_data")
    if sensor_hook is not None:
        sensor_data = _per_env_hook(sensor_data, len(envs), sensor_hook)
    raw = dict(agent=join([e._get_obs_agent() for e in envs]),
               extra=join([e._get_obs_extra(info) for e, info in zip(envs, infos)]),
               sensor_param=join([e.get_sensor_params() for e in envs]),
               sensor_data=sensor_data)
    return first._flatten_raw_obs(raw)


def _own_copy(x: Any) -> Any:
    """A copy of a picture; on the CPU through numpy (a plain memcpy: 0.1 ms for four 320x240 RGBA
    pictures where ``Tensor.clone`` took 1.4-5 ms on the 2-core machine)."""
    import torch

    if x.device.type == "cpu":
        return torch.from_numpy(x.numpy().copy())
    return x.clone()


def _per_env_hook(data: dict, k: int, hook: Callable[[int, dict], dict]) -> dict:
    """``hook(i, rows of env i)`` for each env, its results written into the K-row tensors."""
    for i in range(k):
        rows = {name: {key: x[i:i + 1] for key, x in texs.items()} for name, texs in data.items()}
        out = hook(i, rows)
        for name, texs in out.items():
            for key, x in texs.items():
                data[name][key][i:i + 1] = x
    return data


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


# ManiSkill's observation modes, known without importing it (seconds): a bad ``-o`` is refused before the
# simulator loads. ``BaseEnv.SUPPORTED_OBS_MODES`` ("any_textures": camera textures joined by '+') and
# ``envs.utils.observations``' ``ALL_VISUAL_TEXTURES`` and ``parse_obs_mode_to_struct`` rule, at the pinned
# version; tests/commands/test_first_hour.py compares them with ManiSkill's own.
OBS_MODES = ("state", "state_dict", "none", "sensor_data", "any_textures", "pointcloud")
CAMERA_TEXTURES = ("rgb", "depth", "segmentation", "position", "normal", "albedo")
_TEXTURE_MODES = ("rgbd", "pointcloud", "sensor_data")  # names parse_obs_mode_to_struct reads as textures
_NOT_TEXTURES = ("state", "state_dict", "none", "pointcloud")  # what it lets stand beside textures


def obs_mode_supported(mode: str, supported: Sequence[str] = OBS_MODES) -> bool:
    """Whether an env whose ``SUPPORTED_OBS_MODES`` is ``supported`` takes ``mode``, as ``BaseEnv.__init__``
    decides: one of them, or (with ``any_textures``) camera textures joined by '+'."""
    if mode in supported and mode != "any_textures":
        return True
    if "any_textures" not in supported:
        return False
    return mode in _TEXTURE_MODES or all(t in CAMERA_TEXTURES or t in _NOT_TEXTURES for t in mode.split("+"))


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


def _not_the_cpu_render_fallback(record: logging.LogRecord) -> bool:
    return "Rendering might be disabled" not in record.getMessage()


def quiet_cpu_render_fallback() -> None:
    """Drops ManiSkill's "CUDA device was not found ... Rendering might be disabled" warning (its
    logger in ``mani_skill.utils.logging_utils``, printed at every env made without CUDA). Call it
    only where rendering was checked to work on the CPU (lavapipe): there the warning is wrong."""
    from mani_skill.utils.logging_utils import logger

    if _not_the_cpu_render_fallback not in logger.filters:
        logger.addFilter(_not_the_cpu_render_fallback)
