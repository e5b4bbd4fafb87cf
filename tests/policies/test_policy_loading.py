"""Policy interface: load_policy specs and their errors, the built-in table, chunk checks, the random policy."""
from __future__ import annotations

import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from rsb_maniskill.policies.interface import Policy, as_chunk, policy_name
from rsb_maniskill.policies.reference import ExpertPolicy, RandomPolicy
from rsb_maniskill.policies.registry import (
    POLICIES,
    builtin_policies,
    load_policy,
    policy_spec,
    register_policy,
    resolve_factory,
)


class ConstantPolicy:
    name = "constant"

    def __init__(self, value=0.0, dim=14, horizon=2):
        self.value, self.dim, self.horizon = value, dim, horizon

    def reset(self, instruction, obs):
        self.instruction = instruction

    def act(self, obs):
        return np.full((self.horizon, self.dim), self.value, dtype=np.float32)


@pytest.fixture
def user_module(monkeypatch):
    mod = types.ModuleType("rsb_test_user_policies")
    mod.ConstantPolicy = ConstantPolicy
    mod.make_policy = lambda **kw: ConstantPolicy(**kw)
    mod.not_a_factory = 42
    mod.make_broken = lambda: object()
    mod.ns = types.SimpleNamespace(make=lambda: ConstantPolicy(value=3.0))
    monkeypatch.setitem(sys.modules, mod.__name__, mod)
    return mod.__name__


def test_load_policy_from_spec(user_module):
    p = load_policy(f"{user_module}:make_policy", value=1.5, horizon=3)
    assert isinstance(p, Policy) and policy_name(p) == "constant"
    assert p.act({}).shape == (3, 14) and float(p.act({})[0, 0]) == 1.5
    assert isinstance(load_policy(f"{user_module}:ConstantPolicy"), ConstantPolicy)
    assert load_policy(f"{user_module}:ns.make").value == 3.0  # dotted attribute path


@pytest.mark.parametrize(
    "spec,err,match",
    [
        ("no_colon_here", ValueError, "package.module:factory"),
        (":make_policy", ValueError, "both parts"),
        ("rsb_test_user_policies:", ValueError, "both parts"),
        ("rsb_no_such_module_xyz:make", ImportError, "rsb_no_such_module_xyz"),
        ("rsb_test_user_policies:missing", AttributeError, "missing"),
        ("rsb_test_user_policies:not_a_factory", TypeError, "not callable"),
        ("rsb_test_user_policies:make_broken", TypeError, "reset and act"),
    ],
)
def test_load_policy_errors(user_module, spec, err, match):
    with pytest.raises(err, match=match):
        load_policy(spec)


def test_builtin_registry():
    assert "random" in builtin_policies()
    register_policy("constant-test", lambda: ConstantPolicy(value=2.0))
    try:
        assert load_policy("constant-test").value == 2.0
    finally:
        del POLICIES["constant-test"]
    with pytest.raises(ValueError):
        register_policy("bad:name", ConstantPolicy)


def _fake_env(space, num_envs=1):
    return types.SimpleNamespace(action_space=space, unwrapped=types.SimpleNamespace(num_envs=num_envs))


def test_builtin_table():
    """One table: every name resolves to its factory, says whether it needs the env, and its obs mode."""
    assert builtin_policies() == ("blind", "leftmost", "oracle", "random", "remote")
    assert resolve_factory("random") == RandomPolicy.for_env
    for name in builtin_policies():
        assert callable(resolve_factory(name))
    assert {n: policy_spec(n).obs_mode for n in builtin_policies()} == {
        "blind": "state", "leftmost": "state", "oracle": "state", "random": "state", "remote": "rgb"}
    assert policy_spec("my_pkg.policies:make").obs_mode == "rgb" and not policy_spec("my_pkg.policies:make").needs_env
    # the privileged baselines are built with the env, and only with a one-env env
    space = np.zeros((2, 14))  # unused by the expert's constructor
    assert isinstance(load_policy("oracle", env=_fake_env(space)), ExpertPolicy)
    assert load_policy("blind", env=_fake_env(space)).blind
    with pytest.raises(ValueError, match="built with the env"):
        load_policy("oracle")
    with pytest.raises(ValueError, match="one env at a time"):
        load_policy("blind", env=_fake_env(space, num_envs=4))
    # and `rsb eval` says so before building anything
    from rsb_maniskill.commands.eval import check_policy_spec
    from rsb_maniskill.commands.eval_args import EvalError

    check_policy_spec("random", num_envs=4)
    with pytest.raises(EvalError, match="use --num-procs, not --num-envs"):
        check_policy_spec("oracle", num_envs=4)


def test_naming_a_policy_imports_nothing():
    """The table holds module paths: importing it loads neither the reference policies nor the websocket client."""
    code = ("import sys, rsb_maniskill.policies.registry as p; p.policy_spec('remote'); "
            "print([m for m in ('rsb_maniskill.policies.remote.client', "
            "'rsb_maniskill.policies.reference') if m in sys.modules])")
    repo = Path(__file__).resolve().parents[2]
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=repo, timeout=120,
                         env={"PYTHONPATH": str(repo), "PATH": ""})
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def test_random_policy_from_box():
    import gymnasium as gym

    space = gym.spaces.Box(low=np.full(14, -0.5, np.float32), high=np.ones(14, np.float32), dtype=np.float32)
    p = load_policy("random", env=_fake_env(space), chunk_size=4, seed=1)
    p.reset("anything", {})
    a = p.act({})
    assert a.shape == (4, 14) and a.dtype == np.float32
    assert (a >= -0.5).all() and (a <= 1.0).all() and a.std() > 0
    same_seed = [RandomPolicy(-np.ones(2), np.ones(2), seed=5).act({}) for _ in range(2)]
    assert np.array_equal(*same_seed)


def test_as_chunk():
    assert as_chunk(np.zeros(14)).shape == (1, 14)  # a single action is a chunk of one
    assert as_chunk([[0.0] * 3] * 2, 3).shape == (2, 3)
    with pytest.raises(ValueError, match="dim 13"):
        as_chunk(np.zeros((2, 13)), 14)
    with pytest.raises(ValueError, match="T >= 1"):
        as_chunk(np.zeros((0, 14)), 14)
    with pytest.raises(ValueError, match="shape"):
        as_chunk(np.zeros((2, 3, 14)), 14)
    with pytest.raises(ValueError, match="NaN"):
        as_chunk(np.full((1, 14), np.nan), 14)
