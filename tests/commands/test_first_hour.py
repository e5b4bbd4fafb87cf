"""The first hour: each command's help says what it does and what its defaults cost, and a mistake in
the arguments is refused in one line, in a second, before the simulator loads."""
from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest
from cli_probe import probe

from rsb_maniskill.cli import build_parser, main
from rsb_maniskill.compat import CAMERA_TEXTURES, OBS_MODES, obs_mode_supported
from rsb_maniskill.env_ids import PAPER_SUITES, SUITE_GROUPS
from rsb_maniskill.evaluation.protocol import EPISODES_PER_SUITE

REPO = Path(__file__).resolve().parents[2]


def commands(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()
             ) -> list[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    """Every command and sub-command of ``parser``, by its words (``("data", "download")``)."""
    found = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found.append(((*path, name), sub))
                found += commands(sub, (*path, name))
    return found


def help_of(capsys, *words: str) -> str:
    capsys.readouterr()
    assert main([*words, "--help"]) == 0
    return " ".join(capsys.readouterr().out.split())  # argparse's line breaks out of the way


def test_every_command_says_what_it_does(capsys):
    every = commands(build_parser())
    assert len(every) > 15
    missing = [" ".join(words) for words, sub in every if not (sub.description or "").strip()]
    assert missing == [], f"commands whose --help has no description line: {missing}"
    assert "The whole pipeline on one suite" in help_of(capsys, "demo")


def test_eval_help_names_the_default_suites_and_what_they_cost(capsys):
    text = help_of(capsys, "eval")
    n_suites = len(SUITE_GROUPS["paper"])
    assert n_suites == len(PAPER_SUITES) == 6
    total = f"{EPISODES_PER_SUITE * n_suites:,}"  # 3,000
    assert f"(default: paper: {n_suites} suites)" in text
    assert f"{n_suites} suites x {EPISODES_PER_SUITE} episodes = {total} episodes, hours on a CPU machine" in text
    assert f"episodes per suite (default {EPISODES_PER_SUITE}: {total} episodes on the default suites" in text


def test_demo_help_takes_one_suite(capsys):
    text = help_of(capsys, "demo")
    assert "one suite id" in text and "more are refused" in text and "(default: RSB-Math-4: 1 suite)" in text
    capsys.readouterr()
    assert main(["demo", "RSB-Math-4", "RSB-Math-10"]) == 2
    assert "give one suite, got 2" in capsys.readouterr().err


def test_an_unknown_flag_and_a_bad_obs_mode_are_the_lines_the_troubleshooting_page_shows(capsys):
    """One line naming the command and its help, no usage block; the page quotes those very lines."""
    page = (REPO / "docs" / "troubleshooting.md").read_text()
    capsys.readouterr()
    assert main(["eval", "oracle", "--bogus"]) == 2
    err = capsys.readouterr().err
    assert err == "rsb eval: error: unrecognized arguments: --bogus (see rsb eval --help)\n"
    assert f"\n{err}```" in page
    assert main(["eval", "oracle", "-o", "myresults"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and f"\n{err}```" in page


def test_the_obs_modes_known_without_maniskill_are_maniskills():
    """compat.OBS_MODES and obs_mode_supported decide -o before ManiSkill loads: they must be its own."""
    from mani_skill.envs.sapien_env import BaseEnv
    from mani_skill.envs.utils.observations import ALL_VISUAL_TEXTURES, parse_obs_mode_to_struct

    from rsb_maniskill.registration import served_by
    from rsb_maniskill.tasks import TASK_CLASSES

    assert OBS_MODES == BaseEnv.SUPPORTED_OBS_MODES and list(CAMERA_TEXTURES) == ALL_VISUAL_TEXTURES
    assert {cls.SUPPORTED_OBS_MODES for cls in served_by(TASK_CLASSES).values()} == {OBS_MODES}

    def maniskill_takes(mode: str) -> bool:
        if mode in OBS_MODES and mode != "any_textures":
            return True
        try:
            parse_obs_mode_to_struct(mode)
            return True
        except (AssertionError, ValueError, KeyError):
            return False

    modes = ["state", "state_dict", "none", "sensor_data", "pointcloud", "rgb", "rgbd", "rgb+depth", "state+rgb",
             "depth+normal+albedo", "pointcloud+rgb", "bogus", "rgb+bogus", "", "+", "myresults", "rgb+"]
    assert {m: obs_mode_supported(m) for m in modes} == {m: maniskill_takes(m) for m in modes}


@pytest.mark.parametrize("obs_mode, phrase", [
    ("bogus", "-o bogus: not an obs mode; use one of state, state_dict, none, sensor_data, pointcloud"),
    ("myresults", "-o is the obs mode: the results folder is --out myresults"),
    ("rbg", "(did you mean rgb?)"),
])
def test_a_bad_obs_mode_is_refused_before_the_simulator_loads(obs_mode, phrase):
    found, lines, stderr = probe("eval", "oracle", "--suites", "RSB-Math-4", "-o", obs_mode)  # its own process
    assert found == {"status": 2, "heavy": []}, stderr[-2000:]
    assert len(lines) == 1 and lines[0].startswith("rsb eval: error: ") and phrase in lines[0], stderr
    assert lines[0].endswith("(see rsb eval --help)")


@pytest.mark.parametrize("name", ["two\nlines", "a\ttab", "nul\x00", "line\u2028separator", "bell\x07"])
def test_a_name_with_a_control_character_is_a_usage_error(name, capsys, tmp_path):
    for command in (["eval", "oracle"], ["backbone", "arithmetic"]):
        capsys.readouterr()
        assert main([*command, "--suites", "RSB-Math-4", "--name", name, "--out", str(tmp_path / "r")]) == 2
        err = capsys.readouterr().err
        assert len(err.splitlines()) == 1 and "holds a control character" in err and f"{name!r}" in err, err
    assert list(tmp_path.iterdir()) == []


def test_a_name_of_any_script_is_still_a_name(capsys):
    from rsb_maniskill.commands.eval_args import name_problem

    for name in ("pi0 (blank)", "政策", "👩\u200d💻 policy", "é", "a|b"):
        assert name_problem(name) is None, name


def test_the_help_states_its_figures_from_the_constants_that_own_them():
    """No episode count or suite count typed into eval's help texts: they come from the protocol."""
    source = (REPO / "rsb_maniskill" / "commands" / "eval.py").read_text()
    register = source[source.index("def register("):source.index("\ndef ", source.index("def register(") + 1)]
    assert not re.search(r"\b(500|3,000|3000)\b", register), "a figure typed into eval's help"
