"""Model servers the vla-eval tests serve: subclasses of vla-eval's own ``PredictModelServer``, served by
its own loop (``vla_eval.api.serve_background``, 127.0.0.1, a free port, stopped by the test)."""
from __future__ import annotations

from typing import Any, Callable

import numpy as np
from vla_eval.model_servers.predict import PredictModelServer
from vla_eval.specs import RAW

from rsb_maniskill.policies.reference import ExpertPolicy
from rsb_maniskill.policies.remote.vla_eval_layout import VlaEvalLayout
from rsb_maniskill.robot import ACTION_DIM, ALOHA14_GRIPPER_INDEX


class Server(PredictModelServer):
    """Keeps every observation ``predict`` read; declares ``action_spec`` (default ``raw``)."""

    def __init__(self, action_spec: dict | None = None, observation_spec: dict | None = None, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.action_spec = {"actions": RAW} if action_spec is None else action_spec
        self.observation_spec = observation_spec or {}
        self.seen: list[dict] = []

    def get_action_spec(self) -> dict:
        return self.action_spec

    def get_observation_spec(self) -> dict:
        return self.observation_spec

    def predict(self, obs: dict, ctx: Any) -> dict:
        self.seen.append(obs)
        return self.reply(obs, ctx)

    def reply(self, obs: dict, ctx: Any) -> dict:
        raise NotImplementedError


class CountingServer(Server):
    """Chunks of ``horizon`` Aloha-14 actions: action t of call c is 0.01 * c + 0.001 * t in every
    slot, so a test sees which call and which step each action came from. ``text``: sent beside them."""

    def __init__(self, horizon: int = 5, text: str | None = None, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.horizon, self.text = horizon, text

    def reply(self, obs: dict, ctx: Any) -> dict:
        if "fail" in obs.get("task_description", ""):
            raise ValueError("told to fail")
        c = len(self.seen) - 1  # this call, from 0
        chunk = np.repeat(0.01 * c + 0.001 * np.arange(self.horizon, dtype=np.float32)[:, None], ACTION_DIM, axis=1)
        return {"actions": chunk, **({"text": self.text} if self.text else {})}


class RandomServer(Server):
    """Seeded random chunks: arm joints uniform in [-1, 1] rad, grippers in [0, 1]."""

    def __init__(self, horizon: int = 5, seed: int = 0, **kwargs: Any) -> None:
        super().__init__(chunk_size=horizon, **kwargs)
        self.horizon, self.rng = horizon, np.random.default_rng(seed)

    def reply(self, obs: dict, ctx: Any) -> dict:
        chunk = self.rng.uniform(-1, 1, (self.horizon, ACTION_DIM)).astype(np.float32)
        grippers = list(ALOHA14_GRIPPER_INDEX.values())
        chunk[:, grippers] = (chunk[:, grippers] + 1) / 2
        return {"actions": chunk}


class OracleServer(Server):
    """The scripted expert's chunks, in ``layout``'s wire format, for the env ``env_of()`` returns: the
    one the client or benchmark steps (it waits for each reply, so the two never touch it at once).
    ``chunk_size``: None replies whole chunks; a large one makes vla-eval buffer them (one action per
    observation) and call ``predict`` when the buffer is empty, i.e. after the chunk was executed."""

    def __init__(self, env_of: Callable[[], Any], layout: VlaEvalLayout, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.env_of, self.layout, self.expert = env_of, layout, None

    def reply(self, obs: dict, ctx: Any) -> dict:
        if ctx.is_first:
            self.expert = ExpertPolicy(self.env_of())
            self.expert.reset(obs["task_description"], {})
        chunk = self.expert.act({})
        state = obs.get(self.layout.state_key) if self.layout.state_key else None
        return {"actions": self.layout.wire_actions(chunk, state)}
