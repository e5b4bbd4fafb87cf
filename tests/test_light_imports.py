"""The package, its semantic engine and the light commands load no torch, SAPIEN or ManiSkill;
`import rsb_maniskill` still registers every env, and gymnasium finds them by qualified id."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
HEAVY = ("torch", "sapien", "mani_skill")


def _run(code: str) -> dict:
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, cwd=REPO,
                         env={**os.environ, "PYTHONPATH": str(REPO)}, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("stmt", ["import rsb_maniskill", "import rsb_maniskill.semantic",
                                  "from rsb_maniskill.semantic import EpisodeSampler; EpisodeSampler('RSB-Math-4').episode(0)",
                                  "import rsb_maniskill.motionplan.generate, rsb_maniskill.evaluation.metrics"])
def test_imports_are_light(stmt):
    got = _run(f"""
        import json, sys
        {stmt}
        print(json.dumps([m for m in {HEAVY!r} if m in sys.modules]))
    """)
    assert got == [], f"{stmt} loaded {got}"


@pytest.mark.parametrize("argv", [["--help"], ["questions", "RSB-Math-4", "-n", "2"], ["stats"],
                                  ["audit", "RSB-Direct-4", "-n", "300"]])
def test_light_commands_load_no_simulator(argv):
    got = _run(f"""
        import contextlib, io, json, sys
        from rsb_maniskill.cli import main
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            try:
                main({argv!r})
            except SystemExit:
                pass
        print(json.dumps([m for m in {HEAVY!r} if m in sys.modules]))
    """)
    assert got == [], f"rsb {' '.join(argv)} loaded {got}"


def test_import_registers_every_env_and_make_loads_the_simulator():
    got = _run("""
        import json, sys, gymnasium as gym
        import rsb_maniskill
        from rsb_maniskill.registration import ENVS
        registered = all(uid in gym.registry for uid in ENVS)
        env = gym.make("RSB-Direct-4", obs_mode="state", render_backend="none")
        obs, _ = env.reset(seed=0)
        print(json.dumps(dict(registered=registered, spec_id=env.unwrapped.spec.id,
                              limit=env.unwrapped.spec.max_episode_steps or env._max_episode_steps,
                              loaded="mani_skill" in sys.modules)))
    """)
    assert got["registered"] and got["loaded"] and got["spec_id"] == "rsb_maniskill:RSB-Direct-4"
    assert got["limit"] == 300


def test_qualified_id_needs_no_import():
    """What ManiSkill's replay tool does with a recorded id: gym.make in a process that imported
    nothing of the pack."""
    got = _run("""
        import json, gymnasium as gym
        env = gym.make("rsb_maniskill:RSB-Math-10", obs_mode="state", render_backend="none")
        env.reset(seed=3)
        print(json.dumps(dict(n=len(env.unwrapped.pool.actors), instr=env.unwrapped.get_language_instruction()[0][:20])))
    """)
    assert got["n"] == 10 and got["instr"]
