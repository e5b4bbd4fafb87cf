"""The command line's one vocabulary (commands/vocab.py), held over every sub-command's parser:
``--out`` for what a command writes, ``-o`` the obs mode, ``-n`` episodes per suite, suites as
``--suites`` (or positional), ``--instruction`` vs ``--instruction-set``; old spellings only as
aliases that say so; an unknown option answered in one line naming that command's help."""
from __future__ import annotations

import argparse

import pytest

from rsb_maniskill.cli import build_parser, main
from rsb_maniskill.commands.vocab import GOES_IN, is_old_spelling

# The commands that write files (their path in the parser tree).
WRITERS = {"demo", "audit", "generate", "merge", "eval", "backbone", "report", "leaderboard", "export lerobot",
           "dataset build", "data download"}
# Spellings that may live on only as old-spelling aliases.
RETIRED = {"--num", "--episodes", "--suite", "--instructions", "--export"}


def _commands() -> dict[str, argparse.ArgumentParser]:
    found = {}

    def walk(parser: argparse.ArgumentParser, path: list[str]) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    if sub.prefix_chars == "-":  # rsb replay hands everything to ManiSkill's parser
                        found[" ".join([*path, name])] = sub
                        walk(sub, [*path, name])

    walk(build_parser(), [])
    return found


COMMANDS = _commands()


def _options(parser: argparse.ArgumentParser, old: bool = False) -> dict[str, argparse.Action]:
    return {s: a for a in parser._actions if is_old_spelling(a) == old for s in a.option_strings}


def test_the_walk_finds_every_command():
    assert WRITERS <= set(COMMANDS)
    assert {"questions", "stats", "doctor", "verify"} <= set(COMMANDS)


@pytest.mark.parametrize("path", sorted(WRITERS))
def test_a_command_that_writes_takes_out(path):
    assert "--out" in _options(COMMANDS[path]), f"rsb {path} writes but has no --out"


@pytest.mark.parametrize("path", sorted(COMMANDS))
def test_the_short_flags_mean_one_thing(path):
    options = _options(COMMANDS[path])
    if "-o" in options:
        assert options["-o"].option_strings == ["-o", "--obs-mode"], f"rsb {path}: -o is not the obs mode"
    if "--obs-mode" in options:
        assert "-o" in options["--obs-mode"].option_strings
    if "-n" in options:
        assert options["-n"].option_strings == ["-n", "--num-episodes"], f"rsb {path}: -n is not episodes per suite"
        assert "per suite" in options["-n"].help, f"rsb {path}: -n's help does not say what it counts"


@pytest.mark.parametrize("path", sorted(COMMANDS))
def test_suites_and_instructions_are_spelled_one_way(path):
    parser = COMMANDS[path]
    options = _options(parser)
    assert not RETIRED & set(options), f"rsb {path}: {RETIRED & set(options)} outside an alias"
    if any(a.dest == "suites" for a in parser._actions):
        assert "--suites" in options, f"rsb {path} takes suites without --suites"
    if "--instruction" in options:  # the protocol's instruction modes, never the template set
        assert set(options["--instruction"].choices or ()) <= {"normal", "blank", "shuffled", "counterfactual"}


@pytest.mark.parametrize("path", sorted(COMMANDS))
def test_an_old_spelling_is_a_hidden_alias_of_a_new_one(path):
    parser = COMMANDS[path]
    new = _options(parser)
    for spelling, action in _options(parser, old=True).items():
        assert action.help == argparse.SUPPRESS
        assert action.new_name in new and new[action.new_name].dest == action.dest, (path, spelling)


def test_an_old_spelling_still_works_and_says_what_replaces_it(capsys):
    args = build_parser().parse_args(["generate", "RSB-Math-4", "--num", "3", "--instructions", "unseen"])
    assert args.num == 3 and args.instructions == "unseen" and args.suites == ["RSB-Math-4"]
    err = capsys.readouterr().err.splitlines()
    assert err == [f"rsb generate: --num is now --num-episodes; the old spelling goes in {GOES_IN}",
                   f"rsb generate: --instructions is now --instruction-set; the old spelling goes in {GOES_IN}"]
    args = build_parser().parse_args(["demo", "--suite", "RSB-Direct-4", "--episodes", "2"])
    assert args.suites == ["RSB-Direct-4"] and args.episodes == 2
    args = build_parser().parse_args(["report", "-o", "page.html", "dir"])
    assert args.out == "page.html"
    assert "rsb report: -o is now --out" in capsys.readouterr().err


def test_suites_positional_or_option_give_the_same(capsys):
    parse = build_parser().parse_args
    for cmd in (["generate"], ["questions"], ["audit"], ["verify"], ["demo"]):
        assert parse([*cmd, "RSB-Math-4"]).suites == parse([*cmd, "--suites", "RSB-Math-4"]).suites == ["RSB-Math-4"]


@pytest.mark.parametrize("argv", [["eval", "oracle", "--bogus"], ["report", "dir", "--bogus"],
                                  ["export", "lerobot", "x.h5", "--out", "d", "--bogus"]])
def test_an_unknown_option_is_one_line_naming_that_commands_help(argv, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    command = " ".join(argv[:2] if argv[0] == "export" else argv[:1])
    assert err == [f"rsb {command}: error: unrecognized arguments: --bogus (see rsb {command} --help)"]
