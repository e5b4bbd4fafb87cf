"""A plugin distribution adds a suite, a candidate family, a policy and a wire protocol with one module."""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

PLUGIN = '''
"""An installed plugin: importing it registers what it adds."""
from rsb_maniskill.objects.family import BlockFamily, register_family
from rsb_maniskill.policies.registry import register_policy
from rsb_maniskill.policies.remote import register_protocol
from rsb_maniskill.semantic.suites import SuiteSource, register_suite


def pool(split, data_dir=None):
    from rsb_maniskill.semantic import math_source
    from rsb_maniskill.semantic.pools import Pool

    qs = math_source.math_pool(split)[:40]
    return Pool("Sums", split, qs, (None,) * len(qs), {"math": len(qs)})


class Bricks(BlockFamily):
    name, suffix = "bricks", "-Bricks"


class Still:
    def reset(self, instruction, obs):
        pass

    def act(self, obs):
        return [[0.0] * 14]


class EchoClient(Still):
    def __init__(self, **kwargs):
        self.kwargs = kwargs


register_suite(SuiteSource("Sums", "plugin sums", "forty sums", "MIT", pool="rsb_demo_plugin:pool", choices=(4,)))
register_family(Bricks())
register_policy("still", "rsb_demo_plugin:Still")
register_protocol("echo", "rsb_demo_plugin:EchoClient")
'''

CHECK = '''
import gymnasium as gym
import rsb_maniskill
from rsb_maniskill import env_ids, plugins
from rsb_maniskill.policies.registry import load_policy
from rsb_maniskill.policies.remote import remote_policy
from rsb_maniskill.semantic import EpisodeSampler

print(plugins.load_plugins())
print("RSB-Sums-4" in env_ids.ENVS, "RSB-Sums-4-Bricks" in env_ids.ENVS, "RSB-Math-10-Bricks" in env_ids.ENVS)
print(gym.spec("RSB-Sums-4").id, env_ids.resolve_env_ids("all")[-1])
spec = EpisodeSampler("RSB-Sums-4", split="test").sample(3)
print(spec.n_choices, all(o in spec.instruction for o in spec.options))
print(type(load_policy("still")).__name__, remote_policy(protocol="echo", host="h").kwargs)
'''


def _install(tmp: Path, module: str = PLUGIN) -> dict:
    (tmp / "rsb_demo_plugin.py").write_text(textwrap.dedent(module))
    info = tmp / "rsb_demo_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: rsb-demo-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[rsb_maniskill.plugins]\ndemo = rsb_demo_plugin\n")
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp), str(REPO)]))


def test_a_plugin_module_adds_a_suite_a_family_a_policy_and_a_protocol(tmp_path):
    env = _install(tmp_path)
    out = subprocess.run([sys.executable, "-c", CHECK], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0] == "['demo']"
    assert lines[1] == "True True True"  # the suite in every family, the family on every suite
    assert lines[2].startswith("RSB-Sums-4 ")
    assert lines[3] == "4 True"  # a four-option episode of the plugin's questions
    assert lines[4] == "Still {'host': 'h'}"


def test_a_broken_plugin_is_named_in_one_line_and_skipped(tmp_path):
    env = _install(tmp_path, "raise RuntimeError('half installed')\n")
    code = "from rsb_maniskill import env_ids; print(len(env_ids.ENVS))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr
    assert "plugin 'demo' (rsb_demo_plugin) failed to load and is skipped: RuntimeError: half installed" in out.stderr
    bare = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          env=dict(os.environ, PYTHONPATH=str(REPO)))
    assert out.stdout == bare.stdout  # the built-in ids, untouched
