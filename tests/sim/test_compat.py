"""The ManiSkill / SAPIEN internals behind rsb_maniskill.compat, on the pinned versions, in a real env."""
from __future__ import annotations

import ast
from pathlib import Path

import gymnasium as gym
import numpy as np

import rsb_maniskill  # noqa: F401
from rsb_maniskill import compat

PACKAGE = Path(rsb_maniskill.__file__).parent


def compat_internals() -> set[str]:
    """The private ManiSkill / SAPIEN attributes compat.py reads or sets (``obj._name``), from its source."""
    tree = ast.parse((PACKAGE / "compat.py").read_text())
    return {n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute)
            and n.attr.startswith("_") and not n.attr.startswith("__")}


def test_pinned_versions():
    assert compat.check_versions() == [], "update rsb_maniskill/compat.py and the pins of pyproject.toml together"


def test_accessors_on_a_real_env():
    env = gym.make("RSB-Math-4", obs_mode="state", render_backend="none")
    env.reset(seed=0)
    base = env.unwrapped
    block = base.pool.actors[0]
    assert len(compat.physx_bodies(block)) == 1 and len(compat.entities(block)) == 1
    assert compat.physx_bodies(block)[0].entity is compat.entities(block)[0]
    finger = base.agent.fingers["left"][0]
    assert compat.physx_bodies(finger)[0].entity.name.endswith("link7")
    arm = base.agent.controller.controllers["arm"]
    target = compat.controller_target_qpos(arm)[0].cpu().numpy()
    qpos = base.agent.robot.get_qpos()[0, arm.active_joint_indices].cpu().numpy()
    np.testing.assert_allclose(target, qpos, atol=1e-4)
    with compat.obs_mode(base, "state_dict"):
        obs, *_ = env.step(base.agent.rest_action().numpy())
        assert isinstance(obs, dict)
    obs, *_ = env.step(base.agent.rest_action().numpy())
    assert not isinstance(obs, dict) and obs.ndim == 2
    env.close()


def test_no_module_outside_compat_touches_the_internals():
    private = compat_internals()
    assert {"_bodies", "_episode_seed", "_batched_episode_rng", "_render_device", "_obs_mode"} <= private
    offenders = []
    for path in PACKAGE.rglob("*.py"):
        if path.name == "compat.py":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Call) and \
                    getattr(node.value.func, "id", None) == "super":
                continue  # a task's override of a ManiSkill hook calling the base's: ManiSkill's task API
            # obj._name, or getattr(obj, "_name")
            name = node.attr if isinstance(node, ast.Attribute) else getattr(node, "value", None)
            if isinstance(name, str) and name in private:
                offenders.append(f"{path.relative_to(PACKAGE)}:{node.lineno} {name}")
    assert offenders == [], offenders
