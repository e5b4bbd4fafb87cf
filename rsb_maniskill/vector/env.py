"""K CPU-physics RSB envs in one process, with ManiSkill's batched conventions and one render call.

ManiSkill runs several envs in one process only on GPU physics, which RSB's expert and determinism do
not use (the CPU backend rebuilds the scene at every reset). :class:`RSBVectorEnv` holds K one-env
RSB envs of the CPU backend and speaks like a ManiSkill env with ``num_envs = K``: torch tensors with
a leading env dim, ``reset(seed=[...], options={"env_idx": [...]})`` resetting the envs named, each
with its own seed and options, and the RSB task contract per env (``get_language_instruction()``,
``episode_specs``, ``info["success"]`` / ``["grasped_any"]`` / ... rows). Each env's episode is the
one its seed gives in any process: the same record with K = 1 or 16, whichever slot runs it.

Rendering is the cost it exists for: the envs step without rendering their cameras, then every
camera of every env renders in one call (``sim/camera_group.py``, a SAPIEN ``RenderSystemGroup``) where
CUDA rendering exists, else each scene renders its own (lavapipe), with the same API and the same
images (:func:`make_renderer`; ``renderer="group"`` or ``"per_scene"`` forces one). The group is
built again after any env's reset (its scene is new); :class:`GroupRenderer` counts what that costs.

With the group, the K observations are built once (``compat.batched_obs``): the group's (K, H, W, C)
pictures go through ManiSkill's texture transforms in one go, the state parts of the K envs are
joined once, and the envs step and reset computing no observation of their own (obs mode ``none``):
the same observation, key for key and value for value, as each env's own joined (measured with a
zero-cost stand-in group, ``benchmarks/batched_render.py --fake-render``: docs/gpu.md).
"""
from __future__ import annotations

import time
import warnings
from contextlib import contextmanager, nullcontext
from typing import Any, Callable, Iterator, Mapping, Sequence

import numpy as np

from rsb_maniskill import compat
from rsb_maniskill.env_ids import CPU_SIM_BACKEND

RENDERERS = ("auto", "group", "per_scene")  # make_renderer's choices
NO_CAMERA_MODES = ("none", "state", "state_dict")  # ManiSkill obs modes that read no camera
# What a sub-env's step or reset computes while its cameras wait for the render: nothing (the
# observation is built afterwards for all K; ManiSkill's reward and info never read it).
STATE_MODE = "none"
PER_ENV_OPTIONS = ("variant",)  # reset options the RSB tasks read per env (a sequence: one per env reset)


class PerSceneRenderer:
    """Each env's scene renders its own cameras (ManiSkill's path; the one lavapipe has)."""

    name = "per_scene"

    def scenes_changed(self) -> None:
        pass

    def render(self, bases: Sequence[Any]) -> None:
        return None  # the envs render their own inside get_obs

    def close(self) -> None:
        pass


class GroupRenderer:
    """All cameras of all envs in one call through a :class:`~rsb_maniskill.sim.camera_group.CameraGroup`,
    built at the first render after any env's scene was rebuilt. ``factory`` builds it from the envs'
    ``unwrapped`` (tests give a fake); ``rebuilds`` / ``rebuild_s`` count what rebuilding costs."""

    name = "group"

    def __init__(self, factory: Callable[[Sequence[Any]], Any] | None = None, *, fallback: bool = False) -> None:
        if factory is None:
            from rsb_maniskill.sim.camera_group import CameraGroup

            factory = CameraGroup
        self.factory = factory
        self.fallback = fallback  # renderer="auto": a group SAPIEN refuses to build means per scene, with a warning
        self.failed: str | None = None
        self.group: Any = None
        self.rebuilds = 0
        self.rebuild_s = 0.0

    def scenes_changed(self) -> None:
        self.group = None

    def render(self, bases: Sequence[Any]) -> dict[str, dict[str, Any]] | None:
        if self.failed is not None:
            return None
        if self.group is None:
            t0 = time.perf_counter()
            try:
                self.group = self.factory(bases)
            except Exception as err:
                if not self.fallback:
                    raise
                self.failed = f"{type(err).__name__}: {err}"
                warnings.warn(f"rendering K envs in one call failed ({self.failed}); each scene renders its own",
                              RuntimeWarning, stacklevel=2)
                return None
            self.rebuilds += 1
            self.rebuild_s += time.perf_counter() - t0
        return self.group.render()

    def close(self) -> None:
        self.group = None


def make_renderer(choice: Any = "auto", obs_mode: str = "rgb") -> PerSceneRenderer | GroupRenderer:
    """The renderer of a vector env: ``"group"`` (one call; raises where CUDA rendering is absent),
    ``"per_scene"``, or ``"auto"``: the group where CUDA rendering exists and the obs mode renders
    cameras, else per scene. A renderer object is used as it is."""
    if not isinstance(choice, str):
        return choice
    if choice not in RENDERERS:
        raise ValueError(f"renderer must be one of {', '.join(RENDERERS)}, got {choice!r}")
    if choice == "per_scene" or (choice == "auto" and obs_mode in NO_CAMERA_MODES):
        return PerSceneRenderer()
    from rsb_maniskill.sim.camera_group import group_rendering_unavailable

    why = group_rendering_unavailable()
    if why is None:
        return GroupRenderer(fallback=choice == "auto")
    if choice == "group":
        raise RuntimeError(f"renderer='group': {why}; use renderer='per_scene' (or 'auto')")
    return PerSceneRenderer()


def episode_seeds(seed: int | Sequence[int] | None, n: int) -> list[int | None]:
    """One seed per env reset, as ManiSkill gives K envs: a list (one each), an int ``s`` (env 0
    gets ``s``, the others seeds drawn from ``RandomState(s)``), or None (unseeded)."""
    if seed is None:
        return [None] * n
    if np.iterable(seed):
        seeds = [int(s) for s in seed]
        if len(seeds) != n:
            raise ValueError(f"{len(seeds)} seeds for {n} envs to reset: give one seed per env, or one int")
        return seeds
    return [int(seed)] + [int(s) for s in np.random.RandomState(int(seed)).randint(2**31, size=n - 1)]


def env_options(options: Mapping[str, Any], position: int, n: int) -> dict[str, Any]:
    """The reset options of the ``position``-th env reset of ``n``: :data:`PER_ENV_OPTIONS` given as a
    sequence hand each env its own entry; everything else goes to every env as it is."""
    out = dict(options)
    for key in PER_ENV_OPTIONS:
        value = out.get(key)
        if value is not None and not isinstance(value, (int, np.integer)):
            value = list(value)
            if len(value) != n:
                raise ValueError(f"reset option {key!r} has {len(value)} entries for {n} envs to reset")
            out[key] = value[position]
    return out


def _cat(parts: Sequence[Any]) -> Any:
    """Per-env values (leading dim 1) joined along the env dim: nested dicts (the keys all envs have:
    after a partial reset only the envs reset carry ``reconfigure``), tensors, arrays; anything else
    as a list of the envs' values."""
    first = parts[0]
    if isinstance(first, Mapping):
        return {k: _cat([p[k] for p in parts]) for k in first if all(k in p for p in parts)}
    if hasattr(first, "detach"):
        import torch

        return torch.cat([p if p.dim() else p[None] for p in parts])
    if isinstance(first, np.ndarray):
        return np.concatenate([p if p.ndim else p[None] for p in parts])
    return list(parts)


def _row(value: Any, i: int) -> Any:
    """Env ``i``'s part of a batched value, leading dim 1 kept (a nested dict, a tensor)."""
    if isinstance(value, Mapping):
        return {k: _row(v, i) for k, v in value.items()}
    if hasattr(value, "detach") or isinstance(value, np.ndarray):
        return value[i:i + 1] if value.ndim else value
    if isinstance(value, list):
        return value[i]
    return value


class RSBVectorEnv:
    """K one-env RSB envs of ``env_id`` on the CPU backend, stepped and rendered as one batch.

    Args:
        env_id: an RSB id (``RSB-Math-4``, ...); ``kwargs`` go to every env's ``gym.make``
            (``obs_mode``, ``split``, ``camera_size``, ``render_mode``, ...); ``sim_backend`` must be
            the CPU one.
        num_envs: K.
        renderer: ``"auto"``, ``"group"``, ``"per_scene"`` (:func:`make_renderer`) or a renderer.

    ``envs`` are the K gym envs (``envs[i].unwrapped`` is env i's task, for policies that read the
    simulator of one env, like the scripted expert). ``unwrapped`` is this object.
    """

    def __init__(self, env_id: str, num_envs: int, *, renderer: Any = "auto", **kwargs: Any) -> None:
        import gymnasium as gym
        from gymnasium.vector.utils import batch_space

        import rsb_maniskill  # noqa: F401  (registers the RSB ids)

        if int(num_envs) < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        backend = kwargs.pop("sim_backend", CPU_SIM_BACKEND)
        if backend != CPU_SIM_BACKEND:
            raise ValueError(f"RSBVectorEnv runs the CPU backend ({CPU_SIM_BACKEND}); for {backend!r} make one "
                             f"ManiSkill env with num_envs={num_envs}")
        kwargs.pop("num_envs", None)
        self.env_id = env_id
        self.num_envs = int(num_envs)
        self.envs: list[Any] = []
        try:
            for _ in range(self.num_envs):
                self.envs.append(gym.make(env_id, num_envs=1, sim_backend=CPU_SIM_BACKEND, **kwargs))
        except BaseException:
            self.close()
            raise
        self.bases = [e.unwrapped for e in self.envs]
        first = self.bases[0]
        self.obs_mode = first.obs_mode
        self.render_mode = first.render_mode
        self.device = first.device
        self.renderer = make_renderer(renderer, self.obs_mode)
        self.single_action_space = self.envs[0].action_space
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.cameras = self.obs_mode not in NO_CAMERA_MODES
        self._infos: list[dict] = [{} for _ in self.envs]
        self._last: list[tuple | None] = [None] * self.num_envs  # a held env's last (obs, reward, term, trunc)
        self.held: set[int] = set()  # envs whose episode ended: not stepped until their next reset
        self._held_obs: list[Any] = [None] * self.num_envs  # a held env's observation, rendered once
        self._skipping = False
        self._info: Any = None  # the joined info of the last step or reset (get_obs reads the envs' own)
        self.spec = self.envs[0].spec

    # ------------------------------------------------------------------ gym
    @property
    def unwrapped(self) -> RSBVectorEnv:
        return self

    def reset(self, seed: int | Sequence[int] | None = None, options: Mapping[str, Any] | None = None
              ) -> tuple[Any, dict]:
        """Reset the envs of ``options["env_idx"]`` (default: all), each with its seed (:func:`episode_seeds`)
        and options (:func:`env_options`); returns the observation and info of all K envs."""
        options = dict(options or {})
        idx = options.pop("env_idx", None)
        idx = list(range(self.num_envs)) if idx is None else [int(i) for i in np.asarray(
            idx.cpu() if hasattr(idx, "cpu") else idx).reshape(-1)]
        seeds = episode_seeds(seed, len(idx))
        for position, (i, s) in enumerate(zip(idx, seeds)):
            self.held.discard(i)
            self._last[i] = self._held_obs[i] = None
            with self._state_only(self.bases[i]):
                _, self._infos[i] = self.envs[i].reset(seed=s, options=env_options(options, position, len(idx)))
        self.renderer.scenes_changed()  # a CPU reset builds a fresh scene
        info = self._info = _cat(self._infos)
        return (self._no_obs() if self._skipping and self.cameras else self.get_obs(info)), info

    def step(self, action: Any) -> tuple[Any, Any, Any, Any, dict]:
        """One control step of every env: ``action`` (K, action_dim). Like a ManiSkill env of K, no
        env resets by itself: an ended env keeps stepping until it is reset, unless :meth:`hold` stopped it."""
        a = action.detach().cpu().numpy() if hasattr(action, "detach") else np.asarray(action, np.float32)
        if a.ndim == 1 and self.num_envs == 1:
            a = a[None]
        if a.shape[0] != self.num_envs:
            raise ValueError(f"action of shape {tuple(a.shape)} for {self.num_envs} envs: want ({self.num_envs}, "
                             f"{self.single_action_space.shape[-1]})")
        rewards, terms, truncs, obs = [], [], [], []
        for i, env in enumerate(self.envs):
            if i in self.held and self._last[i] is not None:
                o, r, term, trunc = self._last[i]
            else:
                with self._state_only(self.bases[i]):
                    o, r, term, trunc, self._infos[i] = env.step(a[i:i + 1])
                self._last[i] = (o, r, term, trunc)
            obs.append(o)
            rewards.append(r)
            terms.append(term)
            truncs.append(trunc)
        info = self._info = _cat(self._infos)
        if not self.cameras:
            out = _cat(obs)
        else:
            out = self._no_obs() if self._skipping else self.get_obs(info)
        return out, _cat(rewards), _cat(terms), _cat(truncs), info

    def _no_obs(self) -> dict:
        return {}  # skip_observations: a camera env's step or reset computed no observation

    def get_obs(self, info: Mapping[str, Any] | None = None) -> Any:
        """The observation of every env now (cameras rendered now: in one call with the group, and then
        built once for all K); without ``info``, each env's is computed now, as ManiSkill's ``get_obs()`` does."""
        if info is None:
            infos = [base.get_info() for base in self.bases]
        elif info is self._info:  # the last step's or reset's: each env's own, not cut out again
            infos = list(self._infos)
        else:
            infos = [_row(info, i) for i in range(self.num_envs)]
        pictures = self.renderer.render(self.bases) if self.cameras else None
        if pictures is not None and self.obs_mode != "pointcloud":
            return compat.batched_obs(self.bases, infos, pictures, _cat, self._sensor_hook())
        obs = []
        for i, base in enumerate(self.bases):
            if i in self.held and self._held_obs[i] is not None:  # not stepped since: the same observation
                obs.append(self._held_obs[i])
                continue
            own = None if pictures is None else {n: {t: x[i:i + 1] for t, x in texs.items()}
                                                  for n, texs in pictures.items()}
            with nullcontext() if own is None else compat.pictures_from(base, own):
                obs.append(base.get_obs(infos[i]))
            self._held_obs[i] = obs[-1] if i in self.held else None
        return _cat(obs)

    def _sensor_hook(self) -> Callable[[int, dict], dict] | None:
        """The RSB tasks' own step on camera data (``_get_obs_sensor_data``: image noise of the
        ``noise`` robustness axis, drawn per env and step), for env i's rows; None where no env adds any."""
        if not any(getattr(base, "axes", None) is not None and base.axes.level("noise") for base in self.bases):
            return None
        return lambda i, rows: self.bases[i].axes.add_noise(rows) if self.bases[i].axes.level("noise") else rows

    def hold(self, i: int) -> None:
        """Stop stepping env ``i`` until its next reset (its episode ended and its record is taken):
        later steps give its last step's values again and cost no physics, nor (per scene) a render."""
        self.held.add(int(i))

    @contextmanager
    def skip_observations(self) -> Iterator[None]:
        """Steps and resets inside the block render nothing; a camera env's return no observation (an
        empty dict), a state env's its state as usual; :meth:`get_obs` renders when asked (the
        evaluator's render on demand)."""
        old, self._skipping = self._skipping, True
        try:
            yield
        finally:
            self._skipping = old

    def _state_only(self, base: Any) -> Any:
        """A sub-env's step or reset computes no camera: the group (or get_obs) renders afterwards."""
        return compat.obs_mode(base, STATE_MODE) if self.cameras else nullcontext()

    def render(self) -> Any:
        """``env.render()`` of every env, joined (B, H, W, 3): the human camera, per scene (videos)."""
        return _cat([env.render() for env in self.envs])

    def close(self) -> None:
        renderer = getattr(self, "renderer", None)
        if renderer is not None:
            renderer.close()
        for env in self.envs:
            env.close()
        self.envs = []

    # ------------------------------------------------------------------ the RSB task contract, per env
    def get_language_instruction(self) -> list[str]:
        return [text for base in self.bases for text in base.get_language_instruction()]

    @property
    def episode_specs(self) -> list[Any]:
        return [base.episode_specs[0] for base in self.bases]

    @property
    def episode_variants(self) -> list[Any]:
        return [base.episode_variants[0] for base in self.bases]

    def episode_spec(self, seed: int) -> Any:
        return self.bases[0].episode_spec(seed)

    def episode_categories(self, spec: Any) -> dict[str, str]:
        return self.bases[0].episode_categories(spec)

    def episode_variant(self, seed: int, index: int) -> Any:
        return self.bases[0].episode_variant(seed, index)

    @property
    def suite_id(self) -> str:
        return self.bases[0].suite_id

    @property
    def n_choices(self) -> int:
        return self.bases[0].n_choices

    def __repr__(self) -> str:
        return f"RSBVectorEnv({self.env_id!r}, num_envs={self.num_envs}, renderer={self.renderer.name!r})"


def make_vector_env(env_id: str, num_envs: int, *, renderer: Any = "auto", log: Callable[[str], None] | None = None,
                    **kwargs: Any) -> RSBVectorEnv:
    """:class:`RSBVectorEnv`; ``log`` gets one line naming the renderer chosen and why."""
    env = RSBVectorEnv(env_id, num_envs, renderer=renderer, **kwargs)
    if log is not None:
        log(f"vector env: {num_envs} CPU envs of {env_id}, rendering {env.renderer.name.replace('_', ' ')}")
    return env

