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

REPO = Path(__file__).resolve().parents[2]
HEAVY = ("torch", "sapien", "mani_skill")


def _run(code: str) -> dict:
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, cwd=REPO,
                         env={**os.environ, "PYTHONPATH": str(REPO)}, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("stmt", ["import rsb_maniskill", "import rsb_maniskill.semantic",
                                  "import rsb_maniskill.env_ids",
                                  "from rsb_maniskill.semantic import EpisodeSampler; "
                                  "EpisodeSampler('RSB-Math-4').episode(0)",
                                  "import rsb_maniskill.motionplan.generate, rsb_maniskill.evaluation.metrics",
                                  "import rsb_maniskill.export.lerobot, rsb_maniskill.export.merge",
                                  # rsb eval's own process, on state and no --env-arg: only its worker loads them
                                  "from rsb_maniskill.commands.eval_args import check_env_settings; "
                                  "check_env_settings(['RSB-Math-4', 'RSB-General-10'], {}, 'state')"])
def test_imports_are_light(stmt):
    got = _run(f"""
        import json, sys
        {stmt}
        print(json.dumps([m for m in {HEAVY!r} if m in sys.modules]))
    """)
    assert got == [], f"{stmt} loaded {got}"


@pytest.mark.parametrize("argv", [["--help"], ["--version"], ["questions", "RSB-Math-4", "-n", "2"], ["stats"],
                                  ["audit", "RSB-Direct-4", "-n", "300"], ["verify", "RSB-Math-4"]])
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
        instr = env.unwrapped.get_language_instruction()[0][:20]
        print(json.dumps(dict(n=len(env.unwrapped.pool.actors), instr=instr)))
    """)
    assert got["n"] == 10 and got["instr"]


@pytest.mark.parametrize("order", ["maniskill_first", "pack_first"])
def test_the_robot_is_registered_for_maniskills_own_envs(order):
    """ManiSkill's envs take ``robot_uids="aloha_agilex"``: importing the pack after ManiSkill
    registers the robot, and ``import rsb_maniskill.agents`` does it in the other order."""
    imports = ("import mani_skill.envs, rsb_maniskill" if order == "maniskill_first"
               else "import rsb_maniskill, mani_skill.envs, rsb_maniskill.agents")
    got = _run(f"""
        import json, gymnasium as gym
        {imports}
        env = gym.make("Empty-v1", robot_uids="aloha_agilex", obs_mode="state", render_backend="none")
        env.reset(seed=0)
        print(json.dumps(dict(uid=env.unwrapped.agent.uid, dof=int(env.unwrapped.agent.robot.dof[0]))))
    """)
    assert got == {"uid": "aloha_agilex", "dof": 16}


def test_lazy_entries_match_maniskills_and_ids_live_in_one_leaf():
    """The lazy entries say what ManiSkill's ``register_env`` says once the simulator loads (limit,
    kwargs, wrappers, a vector entry point). That the tasks never import the registry module is an
    import-linter contract (pyproject.toml, make lint)."""
    got = _run("""
        import json, gymnasium as gym
        import rsb_maniskill
        from rsb_maniskill.env_ids import ENVS_AND_ALIASES
        def view(uid):
            s = gym.spec(uid)
            return [s.max_episode_steps, s.kwargs, [w.name for w in s.additional_wrappers],
                    s.vector_entry_point is not None]
        lazy = {uid: view(uid) for uid in ENVS_AND_ALIASES}
        gym.make("RSB-Math-4", obs_mode="state", render_backend="none").close()
        print(json.dumps(dict(lazy=lazy, loaded={uid: view(uid) for uid in ENVS_AND_ALIASES})))
    """)
    from rsb_maniskill.semantic.suites import SUITE_IDS

    # blocks, objects, their test-split aliases, the table
    assert got["lazy"] == got["loaded"] and len(got["lazy"]) == 4 * len(SUITE_IDS) + 1
    assert got["lazy"]["RSB-Math-4-Test"][1] == {"suite_id": "RSB-Math-4", "split": "test"}
    assert all(v[3] for v in got["lazy"].values())


def test_one_suite_resolver():
    from rsb_maniskill.env_ids import PAPER_SUITES, SUITE_GROUPS, resolve_env_ids

    assert resolve_env_ids(["paper"]) == list(PAPER_SUITES)
    assert resolve_env_ids("RSB-Direct-4, paper,RSB-Math-4") == ["RSB-Direct-4", *PAPER_SUITES]
    assert resolve_env_ids(["paper-objects"]) == [s + "-Objects" for s in PAPER_SUITES]
    assert resolve_env_ids(["rsb_maniskill:RSB-Math-10-Objects"]) == ["RSB-Math-10-Objects"]
    assert len(resolve_env_ids(["all", "all-objects"])) == 16
    with pytest.raises(ValueError, match=r"unknown suite 'RSB-Math-5'.*" + ", ".join(SUITE_GROUPS)):
        resolve_env_ids(["RSB-Math-5"])
    # the paper release's task names (a RoboTwin 2.0 fork) name the suites of this pack
    assert resolve_env_ids(["rsb_math", "rsb_math_10blocks,rsb_hardmath", "rsb_hardmath_10blocks", "rsb_general",
                            "rsb_general_10blocks"]) == list(PAPER_SUITES)
    assert resolve_env_ids(["RSB-Math-4,", " RSB-Math-10", "rsb_math"]) == ["RSB-Math-4", "RSB-Math-10"]


def test_every_command_takes_the_same_suite_list():
    """Space- and comma-separated names, groups and release names, resolved at parse time."""
    from rsb_maniskill.cli import build_parser

    parser = build_parser()
    for argv in (["eval", "oracle", "--suites"], ["dataset", "build", "--out", "x", "--suites"], ["generate"],
                 ["audit"], ["stats", "--suites"], ["questions"], ["verify"]):
        args = parser.parse_args([*argv, "rsb_math,RSB-Direct-4", "RSB-Math-4-Objects"])
        assert args.suites == ["RSB-Math-4", "RSB-Direct-4", "RSB-Math-4-Objects"], argv
