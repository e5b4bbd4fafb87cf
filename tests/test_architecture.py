"""The house holds: the root keeps entry points and leaves, commands live in commands/ under the
command contracts, a leaf imports nothing of the pack, protocol numbers have one owner."""
from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

import rsb_maniskill

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

PACKAGE = Path(rsb_maniskill.__file__).parent
REPO = PACKAGE.parent
ENTRY_POINTS = {"__init__", "cli", "registration", "replay"}  # what users and gym start from
ROOT_ABOVE_LEAVES = {"env_ids"}  # names suites x families: the one root module above the leaves (its docstring says so)


def _contracts() -> dict[str, dict]:
    config = tomllib.loads((REPO / "pyproject.toml").read_text())
    return {c["id"]: c for c in config["tool"]["importlinter"]["contracts"]}


def _pack_imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("rsb_maniskill"):
            found.add(node.module)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.startswith("rsb_maniskill"))
    return found


def test_the_root_holds_entry_points_and_the_leaves_of_the_bottom_floors():
    floors = _contracts()["floors"]["layers"]
    bottom = {name.strip() for layer in floors[-2:] for name in layer.split("|")}
    root = {p.stem for p in PACKAGE.glob("*.py")}
    assert root - ENTRY_POINTS - ROOT_ABOVE_LEAVES <= bottom, root - ENTRY_POINTS - ROOT_ABOVE_LEAVES - bottom


def test_a_module_that_calls_itself_a_leaf_imports_nothing_of_the_pack_but_leaves():
    floors = _contracts()["floors"]["layers"]
    bottom = {f"rsb_maniskill.{name.strip()}" for layer in floors[-2:] for name in layer.split("|")}
    for path in PACKAGE.glob("*.py"):
        doc = ast.get_docstring(ast.parse(path.read_text())) or ""
        if re.search(r"\ba leaf\b", doc) and "Not a leaf" not in doc:
            assert _pack_imports(path) <= bottom, f"{path.name} says it is a leaf but imports {_pack_imports(path)}"


def test_every_command_module_lives_in_commands_under_the_command_contracts():
    from rsb_maniskill.cli import _COMMAND_MODULES

    apart = set(_contracts()["commands-apart"]["modules"])
    for name in _COMMAND_MODULES:
        assert name.startswith("rsb_maniskill.commands."), name
        assert name in apart, f"{name} is not in the 'commands-apart' contract of pyproject.toml"
    forbidden = _contracts()["no-commands-below"]["forbidden_modules"]
    assert "rsb_maniskill.commands" in forbidden


def test_the_protocol_episode_count_is_never_written_out():
    """EPISODES_PER_SUITE (evaluation/protocol.py) is the one owner; text that states it imports it."""
    from rsb_maniskill.evaluation.protocol import EPISODES_PER_SUITE

    pattern = re.compile(rf"\b{EPISODES_PER_SUITE}\b[^.]{{0,40}}\bepisodes\b|\bprotocol's {EPISODES_PER_SUITE}\b")
    for path in PACKAGE.rglob("*.py"):
        if path.name == "protocol.py" and path.parent.name == "evaluation":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and pattern.search(node.value):
                if node.value.strip().startswith(("Paper", "The paper")):
                    continue  # quoting the paper's own protocol
                raise AssertionError(f"{path.relative_to(PACKAGE)}:{node.lineno} writes the protocol's count out")
