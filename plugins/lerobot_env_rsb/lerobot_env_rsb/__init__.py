"""``--env.type=rsb`` for LeRobot's scripts (``lerobot-eval``, ``lerobot-train``'s eval).

LeRobot imports every installed distribution named ``lerobot_env_*``; importing this one
registers :class:`RSBEnvConfig`. The envs themselves are ``rsb_maniskill.integrations.lerobot_env``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig
from lerobot.utils.constants import ACTION, OBS_IMAGES, OBS_STATE

from rsb_maniskill.env_ids import CONTROL_FREQ, TASK_MAX_EPISODE_STEPS
from rsb_maniskill.evaluation.protocol import EPISODES_PER_SUITE, LEROBOT_SEED_BASE
from rsb_maniskill.export.naming import DEFAULT_NAMING, camera_key
from rsb_maniskill.robot import ACTION_DIM, CAMERA_SIZE, CAMERAS

__all__ = ["RSBEnvConfig"]


@EnvConfig.register_subclass("rsb")
@dataclass
class RSBEnvConfig(EnvConfig):
    """RSB suites with the paper's evaluation protocol (episode i = protocol episode i).

    ``task``: suite ids, comma-separated, or a group (``paper``, ``paper-objects``, ``all``).
    ``naming``: camera keys, ``rsb`` (``cam_high``, ...: what ``rsb export lerobot`` writes) or
    ``robotwin`` (``head_camera``, ...: LeRobot's RoboTwin env). ``instruction_mode``: ``normal``,
    ``blank`` or ``shuffled``. ``seed_base`` must equal ``--seed`` (LeRobot's default, 1000).
    ``records_dir``: where ``episodes.jsonl`` goes (records with the benchmark version), for
    ``rsb report``. ``renderer``: ``auto`` / ``group`` / ``per_scene``, how the sub-envs of
    ``--eval.batch_size`` render (one call for all cameras where CUDA renders; see docs/lerobot.md).
    """

    task: str = "RSB-Math-4"
    fps: int = CONTROL_FREQ
    episode_length: int = TASK_MAX_EPISODE_STEPS
    obs_type: str = "pixels_agent_pos"
    naming: str = DEFAULT_NAMING
    instruction_mode: str = "normal"
    camera_width: int = CAMERA_SIZE[0]
    camera_height: int = CAMERA_SIZE[1]
    seed_base: int = LEROBOT_SEED_BASE
    episodes: int = EPISODES_PER_SUITE
    records_dir: str | None = "outputs/rsb_eval"
    policy_name: str = "lerobot"
    data_dir: str | None = None
    renderer: str = "auto"
    features: dict[str, PolicyFeature] = field(
        default_factory=lambda: {ACTION: PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_DIM,))})
    features_map: dict[str, str] = field(default_factory=lambda: {ACTION: ACTION, "agent_pos": OBS_STATE})

    def __post_init__(self) -> None:
        for cam in CAMERAS:
            key = camera_key(cam, self.naming)
            self.features[f"pixels/{key}"] = PolicyFeature(
                type=FeatureType.VISUAL, shape=(self.camera_height, self.camera_width, 3))
            self.features_map.setdefault(f"pixels/{key}", f"{OBS_IMAGES}.{key}")
        if self.obs_type == "pixels_agent_pos":
            self.features["agent_pos"] = PolicyFeature(type=FeatureType.STATE, shape=(ACTION_DIM,))
        elif self.obs_type != "pixels":
            raise ValueError(f"unsupported obs_type {self.obs_type!r}; RSB supports pixels_agent_pos and pixels")

    @property
    def gym_kwargs(self) -> dict:
        return {"instruction_mode": self.instruction_mode, "naming": self.naming, "obs_type": self.obs_type,
                "camera_size": (self.camera_width, self.camera_height), "episode_length": self.episode_length,
                "seed_base": self.seed_base, "episodes": self.episodes, "records_dir": self.records_dir,
                "policy_name": self.policy_name, "data_dir": self.data_dir}

    def create_envs(self, n_envs: int, use_async_envs: bool = False):
        from rsb_maniskill.integrations.lerobot_env import create_rsb_envs

        self.check_policy()
        return create_rsb_envs(self.task, n_envs, use_async_envs, renderer=self.renderer, **self.gym_kwargs)

    def check_policy(self, policy_path: str | None = None) -> None:
        """Under ``lerobot-eval --policy.path=P`` (no ``--rename_map``): fails at once, naming the expected keys and
        shapes, when P's policy takes observations this env does not give (rather than deep in the
        policy at the first step)."""
        import sys
        from pathlib import Path

        from lerobot.configs import parser
        from lerobot.configs.policies import PreTrainedConfig

        from rsb_maniskill.integrations.lerobot_env import check_policy_features

        if policy_path is None:
            # only lerobot-eval without a rename map evaluates the policy on these keys as they are
            # (lerobot-train's --policy.path is a base model to fine-tune, with its own features)
            if Path(sys.argv[0]).name not in ("lerobot-eval", "lerobot_eval.py") or any(
                    a.startswith("--rename_map") for a in sys.argv):
                return
            policy_path = parser.get_path_arg("policy")
        if not policy_path:
            return
        features = PreTrainedConfig.from_pretrained(policy_path).input_features
        check_policy_features({k: tuple(f.shape) for k, f in features.items()}, self.naming, self.obs_type,
                              (self.camera_width, self.camera_height))
