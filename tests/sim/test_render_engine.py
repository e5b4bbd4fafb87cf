"""Any number of envs in one process: the process keeps one render engine, so SAPIEN's render
objects stop opening Vulkan instances (NVIDIA drivers refuse new ones after a few dozen).

lavapipe never refuses, but the Vulkan loader logs a driver search for every instance it creates
(``VK_LOADER_DEBUG=driver``): counting those lines is the CPU-side check of the same design. On a
GPU machine the many-env test is the real check (without the fix it dies at the third env).
"""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SCAN = "Searching for driver manifest files"  # one loader line per vkCreateInstance
MARK = "RSB-FIRST-ENV-DONE"


def _run(code: str, timeout: int = 900) -> str:
    env = dict(os.environ, VK_LOADER_DEBUG="driver", PYTHONPATH=str(REPO))
    # one stream, so the marker lands between the loader lines it separates
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(code).replace("@MARK@", MARK)], stdout=subprocess.PIPE,
                         stderr=subprocess.STDOUT, text=True, env=env, timeout=timeout, cwd=str(REPO))
    assert out.returncode == 0, out.stdout[-3000:]
    return out.stdout


def _scans_after_mark(log: str) -> tuple[int, int]:
    before, _, after = log.partition(MARK)
    return before.count(SCAN), after.count(SCAN)


@pytest.fixture(scope="module")
def loader_logs_instances():
    """The loader's log must show instance creation here, or the counting tests prove nothing."""
    log = _run("""
        import sys, rsb_maniskill.sim.render, sapien
        for _ in range(3):
            sapien.render.RenderMaterial(base_color=[1, 0, 0, 1])  # no engine held: one instance each
        print("@MARK@", file=sys.stderr, flush=True)
        for _ in range(3):
            sapien.render.RenderMaterial(base_color=[1, 0, 0, 1])
    """)
    before, after = _scans_after_mark(log)
    if before == 0:
        pytest.skip("this Vulkan loader does not log driver searches with VK_LOADER_DEBUG=driver")
    assert after > 0  # without a held engine, every render object opens an instance
    return True


def test_state_envs_open_one_vulkan_instance(loader_logs_instances):
    """RSB envs with ``render_backend="none"`` (what evaluation and generation use for state runs)
    open no Vulkan instance after the first env, however many are made."""
    log = _run("""
        import sys, gymnasium as gym, rsb_maniskill
        for i in range(6):
            env_id = ("RSB-Math-4", "RSB-Math-10", "RSB-Direct-10")[i % 3]
            env = gym.make(env_id, obs_mode="state", render_backend="none")
            env.reset(seed=i)
            env.close()
            if i == 0:
                print("@MARK@", file=sys.stderr, flush=True)
    """)
    before, after = _scans_after_mark(log)
    assert before > 0 and after == 0, (before, after)


@pytest.mark.slow
def test_a_hundred_envs_in_one_process(loader_logs_instances):
    """>= 100 make/reset/step/close cycles in one process: every render setting the docs mention,
    and the 8 suites x 3 instruction modes as `rsb eval` builds them."""
    data = os.environ.get("RSB_DATA_DIR", "")
    log = _run(f"""
        import sys, gymnasium as gym, numpy as np, rsb_maniskill
        from rsb_maniskill.evaluation.jobs import EvalJob, make_env
        from rsb_maniskill.evaluation.protocol import EVAL_SEED_BASE
        from rsb_maniskill.semantic import SUITE_IDS
        suites = [s for s in SUITE_IDS if {bool(data)!r} or s.split("-")[1] in ("Math", "Direct")]
        settings = [dict(obs_mode="state", render_backend="none"), dict(obs_mode="state"),
                    dict(obs_mode="rgb"), dict(obs_mode="rgb", render_mode="rgb_array")]
        made = 0
        def cycle(env):
            global made
            env.reset(seed=EVAL_SEED_BASE + made)
            env.step(env.action_space.sample())
            if env.unwrapped.render_mode:
                assert env.render().shape[-1] == 3
            env.close()
            made += 1
            if made == 1:
                print("@MARK@", file=sys.stderr, flush=True)
        while made < 100:
            for suite in suites:
                for mode in ("normal", "blank", "shuffled"):
                    obs = "state" if mode != "shuffled" else "rgb"
                    cycle(make_env(EvalJob(suite_id=suite, seeds=(EVAL_SEED_BASE,), policy="random", label="random",
                                           instruction_mode=mode, obs_mode=obs)))
                for kw in settings:
                    cycle(gym.make(suite, **kw))
        cycle(gym.make("RSB-TableTop-v1", obs_mode="rgb"))
        print("envs made:", made)
    """, timeout=1800)
    made = int(log.split("envs made:")[1].split()[0])
    before, after = _scans_after_mark(log)
    assert made >= 100 and before > 0 and after == 0, (made, before, after)
