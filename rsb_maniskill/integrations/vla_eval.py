"""RSB as a vla-eval benchmark: ``benchmark: "rsb_maniskill.integrations.vla_eval:RSBBenchmark"``.

For users of allenai's vla-evaluation-harness (``vla-eval run --no-docker -c rsb.yaml``, or
``vla_eval.evaluate(server, config)``): each suite is a task, and episode i of a task is protocol
episode i of that suite (seed 10,000,000 + i, test split, unseen templates), the episode ``rsb eval``
runs as episode i, so ``episodes_per_task`` is ``rsb eval -n``. Observations and actions follow an
explicit layout (``policies/remote/vla_eval_layout.py``, presets ``lerobot`` and ``robotwin``), the
same one ``rsb eval remote -a protocol=vla-eval`` uses.

Each episode's ``metrics`` are its ``rsb eval`` record (suite, seed, question, instruction, grasp and
placement flags, ...) plus ``gsr`` and ``tsr``; vla-eval aggregates the flags as ``mean_<key>``, with
no nSG and no intervals: ``rsb report <output_dir>`` reads the results file into the paper's tables
with Wilson intervals (``reporting/vla_eval_results.py``).

Rendering: vla-eval asks for an observation after every step. With ``render_every`` k (a chunking
server's ``chunk_size``) the cameras are rendered only every k steps; the other steps' observations
carry the state and the instruction, which a ``PredictModelServer`` answering from its chunk does not
read (vla-eval's RoboTwin benchmark does the same).
"""
from __future__ import annotations

from typing import Any, ClassVar, Sequence

import numpy as np
from vla_eval.benchmarks.base import StepBenchmark, StepResult
from vla_eval.render import DEFAULT_RENDER_MODE, assert_lavapipe_vulkan, configure_sapien_render

from rsb_maniskill.batch import single_env_obs
from rsb_maniskill.env_ids import TASK_MAX_EPISODE_STEPS, resolve_env_ids
from rsb_maniskill.evaluation.metrics import outcome
from rsb_maniskill.evaluation.protocol import (
    EPISODES_PER_SUITE,
    ShuffledDonors,
    apply_instruction_mode,
    check_ablation_mode,
    eval_seeds,
)
from rsb_maniskill.evaluation.records import RECORD_FLAGS, VLA_EVAL_RUNNER, build_record
from rsb_maniskill.policies.remote.vla_eval_layout import make_layout
from rsb_maniskill.robot import sensor_uid

LAVAPIPE_ICD_ENV = "RSB_LAVAPIPE_ICD"  # `render: cpu`: a lavapipe ICD other than the system's


class RSBBenchmark(StepBenchmark):
    """RSB suites for vla-eval (see the module doc).

    Args:
        suites: suite ids, or a name ``rsb eval --suites`` takes (``paper``: the paper's six).
        episodes: protocol episodes per suite (``episodes_per_task`` of the config must not exceed it;
            shuffled instructions pair within these, as ``rsb eval -n``).
        preset, cameras, state_key, gripper, joints: the observation / action layout.
        render_every: render the cameras every k steps (a chunking server's ``chunk_size``).
        obs_mode: ``rgb`` (cameras and state) or ``state_dict`` (state only: no renderer).
        camera_size: [width, height] of the three cameras (default 320 x 240).
        instruction_mode: ``normal``, ``blank`` or ``shuffled``, as ``rsb eval --instruction``.
        policy_name: the records' ``policy`` field, a row of ``rsb report``'s tables.
        max_steps: step cap (default the task's 300).
        data_dir: question data (default ``$RSB_DATA_DIR``, else the hub cache).
    """

    render_backends = frozenset({"gpu", "cpu"})
    _render_mode: ClassVar[str] = DEFAULT_RENDER_MODE

    @classmethod
    def configure_render(cls, mode: str) -> dict[str, str]:
        applied = configure_sapien_render(mode, LAVAPIPE_ICD_ENV)
        cls._render_mode = mode
        return applied

    def __init__(self, suites: str | Sequence[str] = "paper", episodes: int = EPISODES_PER_SUITE,
                 preset: str = "lerobot", cameras: str | None = None, state_key: str | None = None,
                 gripper: str | None = None, joints: str | None = None, render_every: int = 1,
                 obs_mode: str = "rgb", camera_size: Sequence[int] | None = None, instruction_mode: str = "normal",
                 policy_name: str = VLA_EVAL_RUNNER, max_steps: int = TASK_MAX_EPISODE_STEPS,
                 data_dir: str | None = None) -> None:
        super().__init__()
        self.suites = resolve_env_ids([suites] if isinstance(suites, str) else list(suites))
        self.layout = make_layout(preset, cameras=cameras, state_key=state_key, gripper=gripper, joints=joints)
        check_ablation_mode(instruction_mode, "the vla-eval benchmark")
        if obs_mode != "state_dict" and "rgb" not in obs_mode:
            raise ValueError(f"obs_mode must be an rgb mode or state_dict, got {obs_mode!r}")
        for name, value in (("episodes", episodes), ("render_every", render_every), ("max_steps", max_steps)):
            if int(value) < 1:
                raise ValueError(f"{name} must be >= 1, got {value}")
        self.episodes, self.render_every, self.max_steps = int(episodes), int(render_every), int(max_steps)
        self.obs_mode, self.instruction_mode, self.policy_name = obs_mode, instruction_mode, policy_name
        self.env_kwargs: dict[str, Any] = {"data_dir": data_dir} if data_dir else {}
        if camera_size is not None:
            self.env_kwargs["camera_size"] = tuple(int(v) for v in camera_size)
        self._env: Any = None
        self._suite: str | None = None
        self._donors: Any = None
        self._observations: Any = None

    # ------------------------------------------------------------------ env
    def _env_for(self, suite: str) -> Any:
        if self._suite != suite:
            from rsb_maniskill.evaluation import jobs

            self.cleanup()
            job = jobs.EvalJob(suite_id=suite, seeds=(), label=self.policy_name, policy="remote",
                               obs_mode=self.obs_mode, env_kwargs=self.env_kwargs)
            self._env, self._suite, self._donors = jobs.make_env(job), suite, None
        return self._env

    def _shown(self, seed: int, own: str) -> str:
        donor = None
        if self.instruction_mode == "shuffled":
            if self._donors is None:
                self._donors = ShuffledDonors.of_env(self._env, self._suite, self.episodes)
            donor = self._donors(seed, own)[1]
        return apply_instruction_mode(own, self.instruction_mode, donor)

    def cleanup(self) -> None:
        if self._env is not None:
            self._env.close()
        self._env, self._suite, self._observations = None, None, None

    # ------------------------------------------------------------------ StepBenchmark
    def get_tasks(self) -> list[dict[str, Any]]:
        return [{"name": s, "suite": s} for s in self.suites]

    def reset(self, task: dict[str, Any]) -> Any:
        from rsb_maniskill.evaluation.runner import Observations

        if self._render_mode == "cpu" and "rgb" in self.obs_mode:
            assert_lavapipe_vulkan(type(self).__name__)
        suite, i = task["suite"], int(task.get("episode_idx", 0))
        if not 0 <= i < self.episodes:
            raise ValueError(f"episode {i} of {suite} is not one of the protocol's {self.episodes} (params.episodes): "
                             "episodes_per_task must not exceed it")
        env = self._env_for(suite)
        self._seed = eval_seeds(suite, i + 1)[i]
        self._observations = Observations(env)
        obs, self._info = self._observations.reset(seed=self._seed)
        base = env.unwrapped
        self._own = base.get_language_instruction()[0]
        self._spec = base.episode_specs[0]
        self._given = self._shown(self._seed, self._own)
        self._steps, self._chunk_state = 0, None
        return self._observed(single_env_obs(obs), rendered=True)

    def _observed(self, obs: dict, rendered: bool) -> tuple[dict, bool]:
        if rendered and self.layout.state_key is not None:
            self._chunk_state = self.layout.state(obs["agent"]["qpos"])
        if rendered and "sensor_data" in obs:
            self._recorder.record_video(obs["sensor_data"][sensor_uid("head")]["rgb"])
        return obs, rendered

    def step(self, action: dict[str, Any]) -> StepResult:
        a = np.asarray(action.get("actions", action.get("action")), dtype=np.float32)
        if a.ndim == 2 and a.shape[0] != 1:
            raise ValueError(f"RSBBenchmark steps one action at a time, the server sent a chunk of {a.shape[0]}: "
                             "give the model server a chunk_size, so that it answers each observation with one action")
        env_action = self.layout.env_actions(a.reshape(-1), self._chunk_state)
        _, terminated, truncated, self._info = self._observations.step(env_action)
        self._steps += 1
        done = bool(np.any(_numpy(terminated))) or bool(np.any(_numpy(truncated))) or self._steps >= self.max_steps
        due = not done and self._steps % self.render_every == 0
        obs = self._observations.current() if due else self._observations.obs
        success = bool(_numpy(self._info["success"]).reshape(-1)[0])
        self._recorder.record_step(done=done, success=success)
        return StepResult(obs=self._observed(single_env_obs(obs), due), reward=float(success), done=done,
                          info={"success": success})

    def make_obs(self, raw_obs: Any, task: dict[str, Any]) -> dict[str, Any]:
        obs, rendered = raw_obs
        return self.layout.observation(obs, self._given, images=rendered)

    def get_step_result(self, step_result: StepResult) -> dict[str, Any]:
        extra: dict[str, Any] = {"runner": VLA_EVAL_RUNNER}
        if self.instruction_mode != "normal":
            extra["original_instruction"] = self._own
        if hasattr(self._spec, "to_dict"):
            extra["episode"] = self._spec.to_dict()
        record = build_record(suite_id=self._suite, seed=self._seed, spec=self._spec, instruction=self._given,
                              instruction_mode=self.instruction_mode, info=self._info, steps=self._steps,
                              policy=self.policy_name, extra=extra)
        return {**record, "gsr": outcome(record) != "no_grasp", "tsr": bool(record["success"])}

    def get_metric_keys(self) -> dict[str, str]:
        return {key: "mean" for key in ("gsr", "tsr", *RECORD_FLAGS)}

    def get_metadata(self) -> dict[str, Any]:
        from rsb_maniskill import __version__

        return {"max_steps": self.max_steps, "max_episodes_per_task": self.episodes, "suites": list(self.suites),
                "rsb_version": __version__, "render_mode": self._render_mode}

    def get_action_spec(self) -> dict[str, Any]:
        return self.layout.action_spec()

    def get_observation_spec(self) -> dict[str, Any]:
        return self.layout.observation_spec(images="rgb" in self.obs_mode)


def _numpy(x: Any) -> np.ndarray:
    return x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)
